"""Online calibration of each cue's noise against its own quality, from leave-one-out residuals.

A cue's quality (region shape for the image cues, the joint's confidence for the
skeleton, the presence score for the learned hand) says *when* it is right, but
not by how many pixels: on the realistic synthetic scenes the skeleton joint is
3 px off at confidence 0.9 and 40 px off at 0.3, the depth blob 2 px off at
quality 0.7 and 6-7 px at 0.4, and no fixed ``sigma / sqrt(quality)`` fits both
(paper 003 fixes one noise per source). This module learns ``sigma(source,
quality)`` in the recording being tracked, with no ground truth.

Leave-one-out residual (the "three-cornered hat" of clock metrology, Gray &
Allan 1974, per frame): with independent errors, the other cues' precision-weighted
mean ``z_-s`` has per-axis variance ``V_-s = 1 / sum_(i != s) 1 / sigma_i^2``, so

    E |z_s - z_-s|^2 / 2 = sigma_s^2 + V_-s,

which does not involve ``sigma_s`` on the right: a cue cannot talk itself into
being trusted (fitting a cue to the fused estimate it dominates can). Samples
are kept per source and quality bin (:data:`QUALITY_BINS` equal bins of
[0, 1]) in units of the palm scale ``k`` (the noise of a palm ``k`` times the
reference's is ``k`` times larger), the last :data:`WINDOW` of them, and
summarised by their median (robust to the cue's outliers, which the robust
likelihood handles): ``|r|^2 / 2`` of a 2-D Gaussian residual has median
``ln 2 (sigma^2 + V)``. The result is shrunk towards the configured prior with
:data:`PRIOR_COUNT` pseudo-samples (a weighted geometric mean: noises are scale
parameters) after bounding it to [:data:`FLOOR`, 10 x the prior]. The floor is
the noise of the most precise source measured on real frames (the learned hand
cue, :data:`~fusion_pf.filter.likelihood.DEFAULT_NOISE_PX`): for a heavy-tailed
cue the median measures the core of its error, not its spread (depth at quality
0.5-0.75 on a realistic synthetic scene: 0.25 from the median, 0.96 RMS, in
palm units), and without the floor such a cue is trusted alone.
Frames with a single cue teach nothing, so a lone cue keeps its prior.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Mapping, Sequence

from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement

from .likelihood import DEFAULT_NOISE_PX

__all__ = ["FLOOR", "PRIOR_COUNT", "QUALITY_BINS", "WINDOW", "NoiseCalibration", "quality_bin"]

#: Equal-width quality bins of [0, 1] a noise is learned for.
QUALITY_BINS = 4
#: Residuals kept per source and bin (the most recent).
WINDOW = 100
#: Pseudo-samples of the prior noise in the shrunk estimate.
PRIOR_COUNT = 10
#: Learned noise stays below BOUND x the prior.
BOUND = 10.0
#: Smallest learned noise per axis at palm scale 1, px: the learned hand cue's
#: measured noise (5 % of the palm's length, radial), the most precise source seen.
FLOOR = DEFAULT_NOISE_PX["hand"]


def quality_bin(quality: float) -> int:
    """Index in ``[0, QUALITY_BINS)`` of a quality in [0, 1]."""
    return min(int(quality * QUALITY_BINS), QUALITY_BINS - 1)


class NoiseCalibration:
    """Per-source, per-quality-bin measurement noise learned online (see the module docstring).

    Parameters
    ----------
    prior : callable (Measurement) -> float
        The configured noise of a measurement at palm scale 1, px (e.g. the
        quality-widened default); the starting value and the shrinkage target.
    window : int
        Residuals kept per source and bin (>= 1).
    prior_count : float
        Pseudo-samples of the prior (>= 0).
    floor : float
        Smallest learned noise at palm scale 1, px (> 0); a source whose prior
        is smaller keeps its prior as the floor.
    """

    def __init__(self, prior, *, window: int = WINDOW, prior_count: float = PRIOR_COUNT, floor: float = FLOOR) -> None:
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise InputError(f"window must be an int >= 1, got {window!r}")
        if not (math.isfinite(float(prior_count)) and float(prior_count) >= 0.0):
            raise InputError(f"prior_count must be a finite number >= 0, got {prior_count!r}")
        if isinstance(floor, bool) or not isinstance(floor, (int, float)) or not (math.isfinite(floor) and floor > 0):
            raise InputError(f"floor must be a finite number > 0 px, got {floor!r}")
        self.prior = prior
        self.window = window
        self.prior_count = float(prior_count)
        self.floor = float(floor)
        self._samples: dict[tuple[str, int], deque[float]] = {}  # per key, oldest first
        self._sorted: dict[tuple[str, int], list[float]] = {}  # the same samples, sorted (O(1) median)

    def samples(self, source: str, quality: float) -> int:
        """Residuals held for ``source`` at ``quality``'s bin."""
        return len(self._samples.get((source, quality_bin(quality)), ()))

    def sigma(self, m: Measurement, scale: float = 1.0) -> float:
        """Noise of ``m`` in px at palm scale ``scale``: the bin's learned noise shrunk towards the prior."""
        s0 = self.prior(m)
        key = (m.source, quality_bin(m.quality))
        ordered = self._sorted.get(key)
        if not ordered:
            return s0 * scale
        n = len(ordered)
        var = ordered[n // 2] if n % 2 else 0.5 * (ordered[n // 2 - 1] + ordered[n // 2])
        # sigma_hat within [min(floor, sigma_0), B sigma_0] (a negative median: the others explain the residual)
        learned = min(max(math.sqrt(max(var, 0.0)), min(self.floor, s0)), s0 * BOUND)
        # log sigma = (n0 log sigma_0 + n log sigma_hat) / (n0 + n)
        w = n / (self.prior_count + n)
        return s0 ** (1.0 - w) * learned**w * scale

    def update(self, ms: Sequence[Measurement], sigmas: Mapping[str, float], scale: float = 1.0) -> None:
        """Add this frame's leave-one-out residuals.

        Parameters
        ----------
        ms : sequence of Measurement
            The frame's measurements, one per source (fewer than two: nothing learned).
        sigmas : mapping of str to float
            The noise (px, this frame's scale) each source was fused with.
        scale : float
            The palm scale ``k`` of the frame (> 0): residuals are stored over ``k^2``.
        """
        if len(ms) < 2:
            return
        prec = [1.0 / sigmas[m.source] ** 2 for m in ms]
        total = math.fsum(prec)
        total_u = math.fsum(p * m.u for p, m in zip(prec, ms))
        total_v = math.fsum(p * m.v for p, m in zip(prec, ms))
        for p, m in zip(prec, ms):
            rest = total - p
            # z_-s = sum_(i != s) z_i / sigma_i^2 / sum_(i != s) 1 / sigma_i^2
            du = m.u - (total_u - p * m.u) / rest
            dv = m.v - (total_v - p * m.v) / rest
            # sample of sigma_s^2 = |z_s - z_-s|^2 / (2 ln 2) - V_-s   (median of |r|^2 / 2 = ln 2 (sigma^2 + V))
            sample = ((du * du + dv * dv) / (2.0 * math.log(2.0)) - 1.0 / rest) / (scale * scale)
            key = (m.source, quality_bin(m.quality))
            buf = self._samples.get(key)
            if buf is None:
                buf = self._samples[key] = deque()
                self._sorted[key] = []
            ordered = self._sorted[key]
            if len(buf) == self.window:
                del ordered[bisect.bisect_left(ordered, buf.popleft())]
            buf.append(sample)
            bisect.insort(ordered, sample)
