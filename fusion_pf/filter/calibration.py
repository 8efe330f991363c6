"""Online calibration of each cue's noise against its own quality, from its innovations.

A cue's quality (region shape for the image cues, the joint's confidence for the
skeleton, the presence score for the learned hand) says *when* it is right, but
not by how many pixels: on the realistic synthetic scenes the skeleton joint is
3 px off at confidence 0.9 and 40 px off at 0.3, the depth blob 2 px off at
quality 0.7 and 6-7 px at 0.4, and no fixed ``sigma / sqrt(quality)`` fits both
(paper 003 fixes one noise per source). This module learns ``sigma(source,
quality)`` in the recording being tracked, with no ground truth.

Innovation (the filter's own prediction, while it tracks): the prediction
``x_pred`` of frame ``t`` is made from frames before ``t``, so its error is
independent of this frame's cue errors, and with per-axis prediction variance
``P``

    E |z_s - x_pred|^2 / 2 = sigma_s^2 + P

(:func:`innovation_variance`). Each cue is judged against the track alone, not
against the other cues, so two cues that are wrong the same way (colour and
depth both pulled to the forearm) do not make a third, accurate one look noisy,
as a comparison with the others does (fusion scene matrix, issue 23:
skeleton-best 10.8 -> 3.1 px fused, skeleton alone 2.85). Measured and not
kept: Grubbs' three-cornered hat on the pairwise differences (each cue's
variance from the others' disagreement without assumed noises) still assumes
independent errors, and colour and depth errors correlate at 0.84 on
skeleton-best-1280 (fused 5.6 -> 10.8 px there); a shrinkage target pooled over
a source's quality bins, and fewer prior pseudo-samples, were worse on the
tuning scenes.

Leave-one-out residual (the "three-cornered hat" of clock metrology, Gray &
Allan 1974, per frame), used while there is no prediction (before the first
estimate, after a loss): with independent errors, the other cues'
precision-weighted mean ``z_-s`` has per-axis variance ``V_-s = 1 / sum_(i != s)
1 / sigma_i^2``, so ``E |z_s - z_-s|^2 / 2 = sigma_s^2 + V_-s``, which does not
involve ``sigma_s`` on the right.

Samples are kept per source and quality bin (:data:`QUALITY_BINS` equal bins of
[0, 1]) in units of the palm scale ``k`` (the noise of a palm ``k`` times the
reference's is ``k`` times larger), the last :data:`WINDOW` of them, and
summarised by their :data:`QUANTILE` quantile (robust to the cue's gross
outliers, which the robust likelihood handles, yet above the median so that a
heavy-tailed cue's spread is not mistaken for its core): ``|r|^2 / 2`` of a 2-D
Gaussian residual of per-axis variance ``v`` is exponential with mean ``v``, its
``p`` quantile is ``-ln(1 - p) v``. The result is shrunk towards the configured
prior with :data:`PRIOR_COUNT` pseudo-samples (a weighted geometric mean: noises
are scale parameters) after bounding it to [:data:`FLOOR`, 10 x the prior]. The
floor is the noise of the most precise source measured on real frames (the
learned hand cue, :data:`~fusion_pf.filter.likelihood.DEFAULT_NOISE_PX`):
without it a cue whose errors are mostly tiny and sometimes large is trusted
alone. Frames with a single cue teach nothing: the prediction was made from that
cue alone, so its innovation measures the motion model's misfit as much as the
cue (on the real development frames, where only the learned hand cue fires,
learning it made the fused RMSE 11.0 px instead of 10.0).
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from collections.abc import Mapping, Sequence

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement

from .likelihood import DEFAULT_NOISE_PX

__all__ = [
    "FLOOR",
    "PRIOR_COUNT",
    "QUALITY_BINS",
    "QUANTILE",
    "WINDOW",
    "NoiseCalibration",
    "innovation_variance",
    "quality_bin",
]

#: Equal-width quality bins of [0, 1] a noise is learned for.
QUALITY_BINS = 4
#: Residuals kept per source and bin (the most recent).
WINDOW = 100
#: Quantile of the kept samples a noise is read from (0.5: the median).
QUANTILE = 0.7
#: Pseudo-samples of the prior noise in the shrunk estimate.
PRIOR_COUNT = 10
#: Learned noise stays below BOUND x the prior.
BOUND = 10.0
#: Smallest learned noise per axis at palm scale 1, px: the learned hand cue's
#: measured noise (5 % of the palm's length, radial), the most precise source seen.
FLOOR = DEFAULT_NOISE_PX["hand"]


def innovation_variance(
    z: np.ndarray, predicted: tuple[float, float], predicted_var: float, quantile: float = QUANTILE
) -> np.ndarray:
    """One sample per cue of its per-axis noise variance from its innovation against a prediction.

    ``|z - x_pred|^2 / 2`` of a Gaussian cue is exponential with mean ``sigma^2 + P``;
    scaled by its ``quantile``'s factor ``1 / -ln(1 - quantile)``, the ``quantile``
    of many samples minus ``P`` is ``sigma^2``, that is what each sample is made for
    (it may be negative: the prediction's variance explains the innovation).

    Parameters
    ----------
    z : ndarray, shape (n, 2)
        The cues' positions, px.
    predicted : (float, float)
        The prediction ``x_pred``, px, made without these cues.
    predicted_var : float
        Its per-axis variance ``P``, px^2 (>= 0).
    quantile : float
        The quantile the samples will be read at, in (0, 1).

    Returns
    -------
    ndarray, shape (n,)
        ``|z - x_pred|^2 / (2 (-ln(1 - quantile))) - P`` per cue, px^2.
    """
    d = np.asarray(z, dtype=float) - np.asarray(predicted, dtype=float)
    return np.einsum("ij,ij->i", d, d) / (2.0 * -math.log1p(-quantile)) - predicted_var


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
        var = ordered[min(int(QUANTILE * n), n - 1)]
        # sigma_hat within [min(floor, sigma_0), B sigma_0] (a negative quantile: the others explain the residual)
        learned = min(max(math.sqrt(max(var, 0.0)), min(self.floor, s0)), s0 * BOUND)
        # log sigma = (n0 log sigma_0 + n log sigma_hat) / (n0 + n)
        w = n / (self.prior_count + n)
        return s0 ** (1.0 - w) * learned**w * scale

    def update(
        self,
        ms: Sequence[Measurement],
        sigmas: Mapping[str, float],
        scale: float = 1.0,
        prediction: tuple[float, float, float] | None = None,
    ) -> None:
        """Add this frame's innovations (with a prediction), else its leave-one-out residuals.

        Parameters
        ----------
        ms : sequence of Measurement
            The frame's measurements, one per source (fewer than two: nothing learned).
        sigmas : mapping of str to float
            The noise (px, this frame's scale) each source was fused with.
        scale : float
            The palm scale ``k`` of the frame (> 0): residuals are stored over ``k^2``.
        prediction : (u, v, var) or None
            The filter's prediction of this frame made from the earlier ones, px, and its per-axis
            variance, px^2 (:func:`innovation_variance`).
        """
        if len(ms) < 2:
            return
        if prediction is not None:
            z = np.array([(m.u, m.v) for m in ms])
            samples = innovation_variance(z, prediction[:2], prediction[2]) / (scale * scale)
            for m, sample in zip(ms, samples.tolist()):
                self._add((m.source, quality_bin(m.quality)), sample)
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
            # sample of sigma_s^2 = |z_s - z_-s|^2 / (2 c) - V_-s   (p quantile of |r|^2 / 2 = c (sigma^2 + V))
            sample = ((du * du + dv * dv) / (2.0 * -math.log1p(-QUANTILE)) - 1.0 / rest) / (scale * scale)
            self._add((m.source, quality_bin(m.quality)), sample)

    def _add(self, key: tuple[str, int], sample: float) -> None:
        """Keep ``sample`` of ``key``'s variance (the oldest leaves a full window)."""
        buf = self._samples.get(key)
        if buf is None:
            buf = self._samples[key] = deque()
            self._sorted[key] = []
        ordered = self._sorted[key]
        if len(buf) == self.window:
            del ordered[bisect.bisect_left(ordered, buf.popleft())]
        buf.append(sample)
        bisect.insort(ordered, sample)
