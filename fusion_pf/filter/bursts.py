"""Per-frame robustness to cue bursts: a two-state (good / burst) switching model per cue.

The noise calibration (:mod:`fusion_pf.filter.calibration`) learns each cue's
noise and outlier share as an average over the recording. Several cues are right
to 1-2 px most of the time and 3-120 px off in *runs* of frames (issue 23's
matrix: the depth blob taking the torso while the palm is within one noise sigma
of it, the skeleton in lit scenes, the colour blob on the forearm); per frame
the average says nothing about which cue is in such a run.

Model. Every cue ``s`` is, per frame, in one of two hidden states: *good* (its
measurement is the palm plus its calibrated noise) or *burst* (it measures
something else near the palm). Its innovation ``d = z_s - x_pred`` against the
filter's prediction of the frame (mean ``x_pred``, per-axis variance ``P``,
made from the earlier frames only) has the per-axis variance ``V = sigma_s^2 +
P`` when good and ``V + b^2`` in a burst (``b`` one apparent palm length: a
burst lands on the body, the forearm or the other hand, within about a palm).
The state is a Markov chain: a good cue starts a burst with probability
``a_gb`` per frame, a burst ends with ``a_bg``; the forward recursion of the
hidden Markov model carries the burst probability from frame to frame
(:func:`predict_burst`, :func:`burst_posterior`), so a run of frames off the
track is believed sooner than a single one. The two transition probabilities
are learned online, per source, from the expected transitions (the two-slice
posteriors of the forward recursion, :func:`expected_transitions`; an online
Baum-Welch step without the backward pass), shrunk towards :data:`START` and
:data:`END` with :data:`TRANSITION_COUNT` pseudo-transitions.

Cross-cue confirmation (:meth:`BurstFilter.weights`). The prediction follows
whatever the filter fused, and a hand that moves faster than the motion model
puts every cue off it at once. A cue's burst is therefore acted upon only when
the cue is more likely in a burst than not (posterior burst probability at
least one half), another cue of the same frame is in its good state (below one
half), and the good cues together say the two measure different things: the sum
over the good cues ``j`` of :func:`log_ratio` of ``z_s - z_j`` (variance
``sigma_s^2 + sigma_j^2``, the same burst scale) is above 0. A precise good cue
that agrees with the cue vouches for it (the track may be the one that is off,
pulled by a cue whose burst is small: all-close-960, colour right to 0.3 px, the
track on a depth blob 8-12 px off); a good cue much noisier than the burst scale
says almost nothing either way. Then the cue is fused with its noise divided by ``sqrt(w)``, ``w = 1 - P(burst)`` at
least :data:`MIN_WEIGHT` (the weights of iteratively reweighted least squares:
a cue certainly in a burst counts ``MIN_WEIGHT`` of a measurement). Not
acted upon, and nothing learned: a frame with a single cue (nothing confirms),
a frame without a prediction (before the first estimate, after a loss), and
every cue when all of them are off the prediction (a fast hand). Two cues
sharing a bias (colour and the skeleton both on the forearm) are each judged
against the track, not against each other, so the majority does not decide:
the cue that stays on the track is the good one that confirms the others'
burst.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement

__all__ = [
    "BURST_PALMS",
    "END",
    "MIN_WEIGHT",
    "START",
    "TRANSITION_COUNT",
    "BurstFilter",
    "burst_posterior",
    "expected_transitions",
    "log_ratio",
    "predict_burst",
]

#: Scale ``b`` of a burst's offset, apparent palm lengths.
BURST_PALMS = 1.0
#: Prior probability per frame that a good cue starts a burst.
START = 0.05
#: Prior probability per frame that a burst ends.
END = 0.2
#: Pseudo-transitions of the prior in the learned transition probabilities.
TRANSITION_COUNT = 20.0
#: Smallest weight of a cue in a burst (its noise at most ``1 / sqrt(MIN_WEIGHT)`` = 10 x).
MIN_WEIGHT = 0.01
#: Bound of a log-likelihood ratio (keeps ``exp`` finite).
_LOG_BOUND = 700.0


def log_ratio(d2: float, var: float, burst_var: float) -> float:
    """``log N2(d; V + b^2) - log N2(d; V)``: how much better a burst explains an innovation.

    Parameters
    ----------
    d2 : float
        Squared innovation ``|z - x_pred|^2``, px^2 (>= 0).
    var : float
        Per-axis variance ``V`` of a good cue's innovation, px^2 (> 0).
    burst_var : float
        Per-axis variance ``b^2`` a burst adds, px^2 (>= 0).
    """
    wide = var + burst_var
    # log N2(d; s2) = -d^2 / (2 s2) - log(2 pi s2)
    lr = 0.5 * d2 * (1.0 / var - 1.0 / wide) - math.log(wide / var)
    return min(max(lr, -_LOG_BOUND), _LOG_BOUND)


def predict_burst(burst: float, start: float, end: float) -> float:
    """The burst probability one frame later: ``P(b_t) = P(b_(t-1)) (1 - a_bg) + (1 - P(b_(t-1))) a_gb``."""
    return burst * (1.0 - end) + (1.0 - burst) * start


def expected_transitions(burst: float, start: float, end: float, lr: float) -> np.ndarray:
    """The two-slice posterior ``xi[i, j] = P(s_(t-1) = i, s_t = j | z_1..z_t)`` (0 good, 1 burst).

    ``xi[i, j]`` is proportional to ``alpha_(t-1)(i) a_ij L_t(j)`` with ``alpha_(t-1) = (1 - burst,
    burst)``, ``a = [[1 - start, start], [end, 1 - end]]`` and ``L_t(burst) / L_t(good) = exp(lr)``
    (:func:`log_ratio`); its column sums are the filtered state probabilities of frame ``t``.
    """
    alpha = np.array([1.0 - burst, burst])
    a = np.array([[1.0 - start, start], [end, 1.0 - end]])
    # L_t relative to the good state's, scaled so that neither overflows
    like = np.exp(np.array([0.0, lr]) - max(0.0, lr))
    xi = alpha[:, None] * a * like[None, :]
    return xi / xi.sum()


def burst_posterior(burst: float, start: float, end: float, lr: float) -> float:
    """``P(s_t = burst | z_1..z_t)``: the forward recursion's filtered burst probability (prior ``burst`` one frame before)."""
    prior = predict_burst(burst, start, end)
    # P(b | z) = P(b) L_b / (P(b) L_b + P(g) L_g) = 1 / (1 + P(g) / P(b) exp(-lr))
    if prior <= 0.0:
        return 0.0
    if prior >= 1.0:
        return 1.0
    return 1.0 / (1.0 + math.exp(math.log1p(-prior) - math.log(prior) - lr))


class BurstFilter:
    """Each cue's burst probability carried across frames, and the weights it gives (module docstring).

    Parameters
    ----------
    start, end : float
        Prior transition probabilities per frame (good to burst, burst to good), in (0, 1).
    count : float
        Pseudo-transitions of the prior in the learned ones (>= 0).
    """

    def __init__(self, start: float = START, end: float = END, count: float = TRANSITION_COUNT) -> None:
        for name, p in (("start", start), ("end", end)):
            if not (0.0 < float(p) < 1.0):
                raise InputError(f"{name} must be a probability in (0, 1), got {p!r}")
        if not (math.isfinite(float(count)) and float(count) >= 0.0):
            raise InputError(f"count must be a finite number >= 0, got {count!r}")
        self.start, self.end, self.count = float(start), float(end), float(count)
        self._burst: dict[str, float] = {}  # per source, the filtered burst probability of its last frame
        self._counts: dict[str, np.ndarray] = {}  # per source, expected transitions (2, 2)
        self.bursts: dict[str, int] = {}  # per source, frames it was set aside as a burst

    def transitions(self, source: str) -> tuple[float, float]:
        """``(a_gb, a_bg)`` of ``source``: its expected transitions shrunk towards the prior's."""
        n = self._counts.get(source)
        if n is None:
            return self.start, self.end
        c = self.count
        # a_gb = (n_gb + c start) / (n_g. + c), a_bg = (n_bg + c end) / (n_b. + c)
        return (n[0, 1] + c * self.start) / (n[0].sum() + c), (n[1, 0] + c * self.end) / (n[1].sum() + c)

    def probability(self, source: str) -> float:
        """``source``'s burst probability after its last frame (the chain's stationary one before any)."""
        if source in self._burst:
            return self._burst[source]
        a_gb, a_bg = self.transitions(source)
        return a_gb / (a_gb + a_bg)

    def reset(self) -> None:
        """Forget every cue's state (a new track); the learned transitions stay."""
        self._burst.clear()

    def weights(
        self,
        ms: Sequence[Measurement],
        variances: Mapping[str, float],
        prediction: tuple[float, float, float] | None,
        burst_px: float,
    ) -> dict[str, float]:
        """Each measurement's weight in [:data:`MIN_WEIGHT`, 1] this frame (1: fused as calibrated).

        Parameters
        ----------
        ms : sequence of Measurement
            The frame's measurements, one per source.
        variances : mapping of str to float
            Per source the per-axis variance ``sigma^2`` it is fused with this frame, px^2 (> 0).
        prediction : (u, v, var) or None
            The filter's prediction of the frame from the earlier ones and its per-axis variance (px, px^2).
        burst_px : float
            ``b``: the scale of a burst's offset, px (> 0; one apparent palm length).
        """
        seen = {m.source for m in ms}
        for source in self._burst.keys() - seen:
            # a frame without the cue: its state moves on by the chain alone
            self._burst[source] = predict_burst(self._burst[source], *self.transitions(source))
        if prediction is None or len(ms) < 2:
            for m in ms:
                self._burst[m.source] = predict_burst(self.probability(m.source), *self.transitions(m.source))
            return {m.source: 1.0 for m in ms}
        pu, pv, pvar = prediction
        b2 = burst_px * burst_px
        post = {}
        for m in ms:
            before = self.probability(m.source)
            a_gb, a_bg = self.transitions(m.source)
            lr = log_ratio((m.u - pu) ** 2 + (m.v - pv) ** 2, variances[m.source] + pvar, b2)
            xi = expected_transitions(before, a_gb, a_bg, lr)
            counts = self._counts.get(m.source)
            self._counts[m.source] = xi if counts is None else counts + xi
            post[m.source] = self._burst[m.source] = burst_posterior(before, a_gb, a_bg, lr)
        out = {}
        for m in ms:
            good = [j for j in ms if j is not m and post[j.source] < 0.5]
            # sum_j log N2(z_s - z_j; V_sj + b^2) / N2(z_s - z_j; V_sj) over the good cues, V_sj = sigma_s^2 + sigma_j^2
            cross = sum(
                log_ratio((m.u - j.u) ** 2 + (m.v - j.v) ** 2, variances[m.source] + variances[j.source], b2)
                for j in good
            )
            confirmed = post[m.source] >= 0.5 and bool(good) and cross > 0.0
            out[m.source] = max(1.0 - post[m.source], MIN_WEIGHT) if confirmed else 1.0
            if confirmed:
                self.bursts[m.source] = self.bursts.get(m.source, 0) + 1
        return out
