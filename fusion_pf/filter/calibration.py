"""Online calibration of each cue's noise and outlier rate against its own quality, from the recording.

A cue's quality (region shape for the image cues, the joint's confidence for the
skeleton, the presence score for the learned hand) says *when* it is right, but
not by how many pixels: on the realistic synthetic scenes the skeleton joint is
3 px off at confidence 0.9 and 40 px off at 0.3, the depth blob 2 px off at
quality 0.7 and 6-7 px at 0.4, and no fixed ``sigma / sqrt(quality)`` fits both
(paper 003 fixes one noise per source). Which cue is best also changes from
scene to scene (issue 23's matrix: depth, skeleton or colour by a wide margin,
or all close). This module learns, per source and quality bin, the noise
``sigma`` of the cue's *core* and the probability ``eps`` that it is an outlier
(the robust likelihood's Gaussian + uniform mixture), in the recording being
tracked, with no ground truth and no assumed ranking of the cues.

Residuals. While the filter tracks, each cue is compared with the filter's
prediction of the frame (:meth:`~fusion_pf.filter.pf.ParticleFilter.predicted`),
made from the earlier frames only, whose error is independent of this frame's
cue errors: with per-axis prediction variance ``P``, ``|z_s - x_pred|^2 / 2`` of
an inlier is exponential with mean ``sigma_s^2 + P``. Each cue is judged against
the track, not against the other cues, so two cues wrong the same way (colour
and depth both pulled to the forearm) do not make a third, accurate one look
noisy. Without a prediction (before the first estimate, after a loss) the
residual is the leave-one-out one (the "three-cornered hat" of clock metrology,
Gray & Allan 1974, per frame): the other cues' precision-weighted mean ``z_-s``
has per-axis variance ``V_-s = 1 / sum_(i != s) 1 / sigma_i^2`` and
``|z_s - z_-s|^2 / 2`` is exponential with mean ``sigma_s^2 + V_-s``. Either
way a sample is the pair ``(r, p)``: the half squared residual and the variance
of what the cue was compared with.

Robust fit (:func:`core_and_outliers`). A cue's residuals are a mixture of a
core (fraction ``1 - eps``) and gross errors (a cue on the wrong blob). The
median of an exponential of mean ``v`` is ``ln 2 v``, so the core's median of
``r / ln 2 - p`` is ``sigma^2``. The fit takes the median of *all* samples: with
outliers above the core it lies above the core's median, so ``sigma`` is never
below the core's (a share ``eps`` of gross errors widens it by
``sqrt(ln(2 (1 - eps) / (1 - 2 eps)) / ln 2)``, 1.19x at 20 %). It does not
take the core's median as the ``(1 - eps) / 2`` quantile of all samples (the
fit before, refined from ``eps``): that assumes every error beyond the core is
a gross one, and a cue right to under 1 px half the time and 3-40 px off in
runs otherwise (issue 23, skeleton-lit-320's depth blob of quality 0.25-0.5,
15 px RMSE) was fitted a 0.42 px core with 34 % outliers and fused at the
0.73 px floor next to a 1.1 px skeleton, whose track then followed depth's
3-6 px runs (fused 1.80 px against the skeleton's 1.34).
``eps`` is the share of samples beyond the fitted core's 99 % point
(``r > -ln(0.01) (sigma^2 + p)``) less the 1 % a pure core puts there.

Samples are kept in units of the palm scale ``k`` (the noise of a palm ``k``
times the reference's is ``k`` times larger), the last :data:`WINDOW` per source
and quality bin (:data:`QUALITY_BINS` equal bins of [0, 1]). The learned noise is
bounded to [:data:`FLOOR`, :data:`BOUND` x the prior] and shrunk towards the
configured prior with :data:`PRIOR_COUNT` pseudo-samples (a weighted geometric
mean: noises are scale parameters), the outlier probability towards
:data:`~fusion_pf.filter.pf.ParticleFilter`'s default the same way (linearly),
within [:data:`MIN_EPS`, :data:`MAX_EPS`]. The floor is the noise of the most
precise source measured on real frames (the learned hand cue,
:data:`~fusion_pf.filter.likelihood.DEFAULT_NOISE_PX`). Frames with a single
cue add no residual: the prediction was made from that cue alone, so its residual
measures the motion model's misfit as much as the cue (on the real development
frames, where only the learned hand cue fires, learning from it made the fused
RMSE 11.0 px instead of 10.0); the cue's own differences still measure it ("A lone cue").

White noise. A cue more precise than the prediction cannot be learned against
it: the residual is the prediction's error, the fit of every such cue is 0 and
the floor decides (issue 23, far-hand-sharp-960: a 0.2 px depth cue and a
colour cue off by 0.7 px, both fused at the floor, 3.1 px at that palm scale;
fused 1.38 px). A second reference needs no prediction: the cue's own
measurements over :data:`SELF_ORDER` + 1 frames in a row. Their unit-norm
divided difference (:func:`difference_weights`) cancels the palm's motion up to
constant acceleration and keeps the cue's white noise (:func:`white_noise`,
per source and quality bin; on the tune scenes it matches the error of the cues
without bias, e.g. that depth cue 0.19 px against 0.20 px RMSE per axis, the
skeleton 0.96 against 0.95 px on skeleton-lit-320). It does not see a bias that changes slowly, and most of the image
cues' error is one: the colour blob is 0.6-1.6 px off with 0.1-0.3 px of white
noise, the depth blob near the body 1-3 px with 0.3. So the white noise only
lowers the floor, to ``sigma_white /`` :data:`SELF_FLOOR` (a cue's error taken
as at least twice its white noise) and at most to :data:`SELF_FLOOR` of it,
for measurements of quality :data:`SELF_QUALITY` or more (the low-quality colour
blobs of the lighting scenes are the biased ones: without this condition
skeleton-lit-320b was 1.36x worse); the fit against the prediction still
decides above the floor and learns bursts and the outlier share. Tune split of
``benchmarks/fusion_matrix.py``: far-hand-sharp-960 fused 1.38 -> 0.87 px,
ratio mean 1.10 -> 0.99; raising a cue to its white noise where that is above the
floor made it worse (fused 1.06x on the tune split), and is not done.

Lower floors were measured and are not used: :data:`SELF_FLOOR` 0.25 and :data:`SLOW_FLOOR` 0.15 (a far scene's
0.155 px depth cue is fused at 1.27 px in the image with 0.5 / 0.35) made 60 tune scenes 3.7 % better
(geometric mean; far BestMax 47 -> 49 %) but 180 held-out ones 1.3 % worse (lead20-29005-far-800 0.30 -> 1.40
px, 25015-far-960 and 24012-near-1024 1.5x; far BestMax 42 -> 47 %). An ideal constant-acceleration smoother of that depth cue,
its noise and the palm's jerk known, gains 6 % (0.222 -> 0.208 px): far from the body the fused estimate is at
what the motion model can add. What such a scene's fused estimate loses to its depth cue is the skeleton's pull, not
the filter: gen-45667-far-1280 (``--generate 45601:72``, development) is 0.293 px fused (0.291 with 1,000 particles,
0.291 with the skeleton as the only other cue), 0.244 tracked with depth alone, against depth's 0.245. Nor is the
floor lowered to what a pair of cues can verify (the slow offset's own error ``pi / 2 s^2 / n`` of the cue's most
precise pair, in place of :data:`SLOW_FLOOR`, down to 0.1 of the floor): on the 12 far scenes of those seeds
gen-45655-far-1280 went 0.27 -> 0.25 px but gen-45625-far-640 0.32 -> 0.47 (geometric mean 1.032), where a colour
blob whose offset from the 0.3 px depth cue had been small was fused at 0.13 px at palm scale 1 and then drifted
from 0.3-0.6 to 0.9-1.8 px off the palm (frames 54-68), faster than :data:`SLOW_WINDOW` frames show.

Slow error. Two cues' difference cancels the palm's motion; its median over the last
:data:`SLOW_WINDOW` frames is their slow offset (:func:`slow_offset`), and the three-cornered hat
on the offsets splits it per cue (:func:`slow_errors`). Once known, a cue's floor is lowered only to
:data:`SLOW_FACTOR` x its white and slow error together, at most to :data:`SLOW_FLOOR` of the floor.
Tune split: skeleton-best-960 fused 6.37 -> 2.94 px (its confident depth blob, 1.2 px of slow error,
0.54 px estimated, is no longer lowered to twice its white noise), far-hand-sharp-960 0.89 -> 0.77 (the
unbiased depth cue goes lower), ratio mean 1.03 -> 0.94, no scene worse by more than 3 %. With two
cues the split is not identifiable from the offset alone. Half each gave far-hand-sharp-960's depth 0.3 px
of slow error (truth 0) beside colour's 0.33 (truth 0.65), and on issue 23's gen-32683-far-1280 (a 0.2 px
depth cue, a colour blob 6-8 px off, the skeleton never measured with colour) it raised depth's floor
0.33 -> 0.9 px at palm scale 1 and colour pulled the track 4-6 px (fused 1.22 px against depth's 0.24). The
split follows the two cues' white noise instead, ``S_ab w_a / (w_a + w_b)``: a cue whose measurements
scatter more is taken to wander more too (gen-32683 0.33 px; half each while either white noise is
unknown). It is a prior, not a measurement: a smooth cue held off the palm beside a noisy unbiased one
takes too little (held-out near-body and mid scenes 5-10 % worse, two lit tune scenes 22-31 %).

Bins without samples. A cue whose quality enters a bin for the first time has no residuals there,
and the bin's noise was its configured prior, ``sigma / q`` (:func:`starting_sigma`), however well
the cue was known one bin lower: on far-hand-sharp-960 the 0.2 px depth cue, learned at 1.1 px in
quality 0.5-0.75, was fused at 18 px when its quality crossed 0.75 (frames 22-24, 61-66, 100-103),
the 5-6 px skeleton and the biased colour took over and those frames were 2.5-4 px off: two thirds of
the scene's squared error. A more confident measurement of a cue is taken as no noisier than a less
confident one: once the next lower bin, of quality :data:`SELF_QUALITY` or more, holds
:data:`BORROW_MIN` residuals, its noise bounds the target this bin's estimate is shrunk towards
(the bin's own residuals take over as they come, with the weight ``n / (n + PRIOR_COUNT)``; floor
and bound stay the prior's). Fewer residuals below are no evidence (the first frames' fits against
an unsettled prediction: skeleton-lit-400 fused 1.43 -> 1.76 px when any lower bin counted), nor
are the bins below :data:`SELF_QUALITY`, where the biased blobs are (skeleton-best: a colour blob of
quality 0.2 fitted 1.3 px lent it to quality 0.3-0.45, fused 2.22 -> 2.45 px). Default
``track``, seed 0: over the 30 matrix scenes fused new / old geometric mean 0.971 (far-hand-sharp-960
0.78 -> 0.52 px, big-1280 2.39 -> 2.02; worst lighting-bias-960 1.08x); 32 scenes no helper saw
0.98 (worst 1.04x); the sample 0.802 -> 0.738 px.

The first frames of a precise cue. The warm-start replay (``fusion_pf.pipeline.run``) fuses its first 25
frames with what the first pass learned from them, and a cue whose quality straddles a bin boundary
splits those frames between two bins: on issue 23's far scene gen-31351-far-1280 (main 69f87d7) the
0.25 px depth cue, quality 0.68-0.77, had 8 and 16 residuals and too few differences in its bin to
measure its white noise; fitted 0 against the prediction, it stayed near its ``4 / q`` px prior, 5.5-6.9
px in the image beside a 5.7 px skeleton, which anchored the guided proposal 16 px off (one frame, 75 %
of the scene's squared error; fused 1.55 px). Two changes. A confident bin (:data:`SELF_QUALITY` or
more) without :data:`SELF_MIN` differences of its own measures its white noise with those of all the
source's confident bins (white noise is the cue's, not its quality's; the floor and the guided
proposal's velocity measurement use it). And where the cue itself (its white and slow error) sees
no error above the lowest floor (:data:`SLOW_FLOOR` of it, :data:`SELF_FLOOR` before the slow error
is known), its difference samples are evidence of its noise as its residuals are: the learned noise
is the geometric mean of the residuals' fit (within its bounds) and the floor, weighted by their
counts, and both counts weigh it against the prior. The residuals measure such a cue through a
prediction that cannot resolve it (first frames, an unsettled prediction: on held-out
gen-31459-far-1280 3 residuals of a new bin fitted 1.15 px at palm scale 1 beside a 0.04 px white
noise), the differences directly. A cue whose own error is above the lowest floor is learned from
its residuals alone, as before: with the condition "below the floor" instead, the colour blob of
gen-31342-colour-960 (own error 0.64 px at palm scale 1 against the 0.7 px floor, on a wrong blob 12
px off in frames 127-132) was trusted at 2.7-4 px instead of 5.5-8 px, anchored the track there and
the fused RMSE rose 3.59 -> 4.74 px.

A start at a less confident cue (:meth:`NoiseCalibration.start_sigma`). A (re)start spreads the particles
around one cue by its noise (``fusion_pf.pipeline.run``), and a cue whose quality falls into a bin
it has not been learned in is spread by its ``sigma / q`` prior, whatever it was learned at one bin
higher: on issue 23's gen-31987-far-640 (main b7cd802) the warm-start replay restarted at a 0.2 px depth
cue of quality 0.45, one residual in its bin, the bin above learned at 1.5 px; spread by its 14 px prior,
the particles let a skeleton and a colour blob 35-52 px off pull the first estimate 10 px, 84 % of the
scene's squared error (fused 0.92 px against depth's 0.34). While a bin holds fewer than
:data:`PRIOR_COUNT` residuals (its prior outweighs them), a start spreads by the noise of the next
higher bin, of quality :data:`SELF_QUALITY` or more once it holds :data:`BORROW_MIN` residuals, widened
by the prior's ratio of the two qualities (``sigma_above q_above / q``): the prior's shape at the level
the cue was measured. Only the start: the noise the cue is fused with stays the bin's own. Fused with it
too, a depth blob of quality 0.3-0.4, 10-14 px off, entering its bin mid-track, was trusted at 3-4.5 px
and anchored the track 8-12 px off for five frames (gen-32161-far-1024, fused 0.87 -> 2.08 px), and a
colour blob of quality 0.3, 11-17 px off, pulled gen-31975-far-1280's track.

Between bins. A noise learned per quality bin is a step in the quality, and a cue whose quality crosses
a boundary jumps with it: on the far tune scene gen-40141-far-480 the depth cue, learned at 0.31 px
(palm scale 1.7) in quality 0.5-0.75 and at 1.26 px in 0.25-0.5 (19 residuals, shrunk towards its
``4 / q`` prior), was fused at 1.26 px at quality 0.41-0.49 beside a 0.83 px skeleton 1.4-3.4 px off,
and the track followed the skeleton (fused 0.73 px, depth alone 0.65). The noise a cue is fused with
(:meth:`NoiseCalibration.sigma`) therefore goes log-linearly in the quality from its bin's own
(:meth:`NoiseCalibration.bin_sigma`, everything above) at the bin's centre towards the neighbour bin's,
half way at the boundary, once that neighbour holds :data:`BORROW_MIN` residuals; a bin below
:data:`SELF_QUALITY` lends to no other (the biased low-quality blobs, as above), so a measurement
just above :data:`SELF_QUALITY` keeps its bin's own. gen-40141 0.73 -> 0.65 px.
Held-out scenes (``--generate`` 24001-29030, 180 scenes never tuned on), fused new / old geometric mean
0.973 (filter seed 0) and 0.983 (seed 1), ratio mean 0.611 -> 0.589 and 0.605 -> 0.591, fused above the
best cue on its frames on 14 -> 11 and 16 -> 14 scenes; tune scenes 40001-40060 1.009 (one colour scene
lost the hand for 14 frames, 2.9x; 0.991 without it) and 20 far tune scenes 40063-40177 0.994.
A lone cue. A bin without residuals kept its prior, so a cue alone in a recording (``track --cues depth``,
or a cue whose companions never measure) was fused at its ``sigma / q`` prior whatever it measured: on far
scenes a 0.24-0.27 px depth cue was fused at about 15 px in the image and the particle filter, a heavy
smoother of it, was 1.3-1.6 px off (far tune scenes gen-40339-far-1024, gen-40573-far-960,
gen-40699-far-1280, gen-40705-far-1024: 1.57, 1.53, 1.50, 1.32 px). Its own differences need no other cue:
a bin without residuals counts them as evidence as above (the lowest floor its white noise gives, against
the prior by their count), with their *mean* for the white noise instead of the robust fit, since alone
nothing catches a cue's jumps: the colour blob of gen-40018-colour-320, alone 6.1 px off, jumps between
blobs at a robust white noise of 0.2 px and a mean one of 1.2, and keeps its prior (the robust fit made
the filter follow it, 4.17 -> 6.06 px; with the mean 4.47). The four far scenes: 0.24-0.27 px, at or
below depth alone. Tune scenes 40001-40020 with ``--cues depth``: fused new / old geometric mean 0.943,
fused over depth on depth's frames 1.085 -> 0.961 (geometric mean); worse where the cue vanishes and the
track coasts on a velocity that now follows the cue's last frames (gen-40015-far-400 5.8 -> 8.5 px over
5 frames, gen-40013-lit-560 6.0 -> 9.9); ``--cues colour`` 1.005, ``--cues skeleton`` unchanged (its white
noise lies above the lowest floor). Held-out scenes 24001-24030 (never tuned on): ``--cues depth`` 0.912,
fused over depth on its frames 1.084 -> 1.014 (gen-24019-far-1280 1.75 -> 0.22 px; worst
gen-24012-near-1024 16.5 -> 26.5), ``--cues colour`` 1.003; default ``track`` (three cues) over the 180
held-out scenes 0.9996 (filter seed 0); the real development frames and the sample unchanged.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement

from .likelihood import DEFAULT_NOISE_PX, MIN_QUALITY, PROBABILITY_QUALITY

__all__ = [
    "BORROW_MIN",
    "BOUND",
    "DEFAULT_EPS",
    "FLOOR",
    "MAX_EPS",
    "MIN_EPS",
    "MIN_PROCESS_SCALE",
    "MOTION_MIN",
    "MOTION_WINDOW",
    "PRIOR_COUNT",
    "QUALITY_BINS",
    "SELF_FLOOR",
    "SELF_MIN",
    "SELF_ORDER",
    "SELF_QUALITY",
    "SLOW_MIN",
    "SLOW_WINDOW",
    "WINDOW",
    "NoiseCalibration",
    "core_and_outliers",
    "difference_weights",
    "process_scale",
    "quality_bin",
    "slow_errors",
    "slow_offset",
    "starting_sigma",
    "white_noise",
]

#: Equal-width quality bins of [0, 1] a noise is learned for.
QUALITY_BINS = 4
#: Residuals kept per source and bin (the most recent).
WINDOW = 100
#: Pseudo-samples of the prior noise and outlier probability in the shrunk estimates.
PRIOR_COUNT = 5
#: Learned noise stays below BOUND x the prior.
BOUND = 10.0
#: Smallest learned noise per axis at palm scale 1, px: the learned hand cue's
#: measured noise (5 % of the palm's length, radial), the most precise source seen.
FLOOR = DEFAULT_NOISE_PX["hand"]
#: Prior outlier probability of every source (the robust particle filter's default).
DEFAULT_EPS = 0.1
#: Bounds of a learned outlier probability.
MIN_EPS, MAX_EPS = 0.01, 0.5
#: Smallest factor of the learned position process noise (:func:`process_scale`).
MIN_PROCESS_SCALE = 0.3
#: Corrections kept, and needed before the process noise is learned (:func:`process_scale`).
MOTION_WINDOW, MOTION_MIN = 100, 10
#: Order of the differences a cue's white noise is measured with (:func:`difference_weights`): the
#: palm's motion at constant acceleration leaves no trace in them.
SELF_ORDER = 3
#: Difference samples a source and bin needs before its white noise may lower its floor.
SELF_MIN = 10
#: Smallest quality whose white noise may lower the floor (module docstring, "White noise").
SELF_QUALITY = 0.5
#: Lowest floor a cue's white noise may give, as a share of :data:`FLOOR` (module docstring, "White noise").
SELF_FLOOR = 0.5
#: Frames of each pair of cues kept for their slow offset (:func:`slow_offset`).
SLOW_WINDOW = 60
#: A cue's floor is lowered to SLOW_FACTOR x its white and slow error together (module docstring).
SLOW_FACTOR = 1.25
#: Lowest floor a cue's white and slow error may give, as a share of :data:`FLOOR`.
SLOW_FLOOR = 0.35
#: Frames a pair of cues needs before its slow offset counts (:func:`slow_offset`).
SLOW_MIN = 20
#: Residuals a quality bin needs before its noise bounds the next higher bin's shrinkage target
#: (module docstring, "Bins without samples").
BORROW_MIN = 20
#: The lowest quality bin at or above :data:`SELF_QUALITY`: its and the higher bins' white noise is pooled
#: for a confident bin without enough samples of its own (:meth:`NoiseCalibration.white`).
_SELF_BIN = math.ceil(SELF_QUALITY * QUALITY_BINS)
#: ``-ln(1 - 0.99)``: a core residual's ``r / (sigma^2 + p)`` is beyond it 1 % of the time.
_TAIL = -math.log(0.01)


def core_and_outliers(r: np.ndarray, p: np.ndarray) -> tuple[float, float]:
    """The core's per-axis variance and the outlier share of residual samples (module docstring).

    Parameters
    ----------
    r : ndarray, shape (n,)
        Half squared residuals ``|z - x_ref|^2 / 2``, px^2 (n >= 1).
    p : ndarray, shape (n,)
        Per-axis variance of each residual's reference ``x_ref``, px^2 (>= 0).

    Returns
    -------
    (float, float)
        ``sigma^2 >= 0`` of the core, px^2 (at least the core's, module docstring), and
        ``eps`` in [0, MAX_EPS]: the share of samples that are not from it.
    """
    r, p = np.asarray(r, dtype=float), np.asarray(p, dtype=float)
    # the core's median of r is ln 2 (sigma^2 + p): median(r / ln 2 - p) = sigma^2 (above it with outliers)
    var = max(float(np.median(r / math.log(2.0) - p)), 0.0)
    # share beyond the core's 99 % point, less the 1 % the core puts there
    beyond = float(np.mean(r > _TAIL * (var + p)))
    return var, min(max((beyond - 0.01) / 0.99, 0.0), MAX_EPS)


def difference_weights(t: np.ndarray) -> np.ndarray:
    """Unit-norm weights ``w`` of the highest-order divided difference of samples at times ``t``.

    ``sum_i w_i z(t_i)`` vanishes for every polynomial ``z`` of degree below ``len(t) - 1`` (a palm
    moving at constant velocity or acceleration, for ``len(t) = 4``); for white noise of per-axis
    variance ``sigma^2`` on ``z`` it has variance ``sigma^2 sum_i w_i^2 = sigma^2``. The divided
    difference's weights are ``1 / prod_(j != i) (t_i - t_j)`` (for equal steps the binomial
    coefficients ``(-1)^(n-1-i) C(n - 1, i)``), normalised here to unit norm.

    Parameters
    ----------
    t : ndarray, shape (n,)
        Distinct times, any unit (n >= 2).
    """
    t = np.asarray(t, dtype=float)
    gaps = (t[:, None] - t[None, :]) / (t.max() - t.min())
    np.fill_diagonal(gaps, 1.0)
    # w_i = 1 / prod_(j != i) (t_i - t_j), the times scaled by their span
    w = 1.0 / np.prod(gaps, axis=1)
    return w / math.sqrt(float(w @ w))


def white_noise(d: np.ndarray) -> float:
    """Per-axis variance of a cue's white noise from its difference samples ``d``, px^2.

    ``d = |sum_i w_i z_i|^2 / 2`` with :func:`difference_weights` over a cue's measurements
    ``z_i`` of a few frames in a row: for a cue whose error is white noise of per-axis variance
    ``sigma^2`` plus a bias that changes slowly over those frames, exponential with mean
    ``sigma^2``, so ``sigma^2 = median(d) / ln 2``; the few samples around a jump to another blob
    move the median little.

    Parameters
    ----------
    d : ndarray, shape (n,)
        Half squared unit-norm differences, px^2 (n >= 1).
    """
    return float(np.median(d)) / math.log(2.0)


def slow_offset(d: np.ndarray) -> float:
    """Per-axis variance of the slow offset between two cues from their differences ``d``, px^2.

    ``d`` holds ``z_a - z_b`` of frames both cues measured. Over a window short against the
    change of their biases ``b_a``, ``b_b``, its per-axis median is ``b_a - b_b`` plus the median's
    error, of per-axis variance ``pi / 2 s^2 / n`` for white differences of spread ``s`` (estimated
    robustly, ``1.4826 MAD``); gross errors move neither. The slow offset is
    ``|median(d)|^2 / 2 - pi / 2 s^2 / n`` (at least 0): for independent biases it is
    ``B_a + B_b`` with ``B_s`` the per-axis variance of cue ``s``'s slow error.

    Parameters
    ----------
    d : ndarray, shape (n, 2)
        Differences ``z_a - z_b`` (u, v), px (n >= 1).
    """
    d = np.asarray(d, dtype=float)
    med = np.median(d, axis=0)
    # s^2 = (1.4826 MAD)^2 per axis, the median's variance pi / 2 s^2 / n
    spread = (1.4826 * np.median(np.abs(d - med), axis=0)) ** 2
    return max(0.5 * float(med @ med) - 0.5 * math.pi / 2.0 * float(spread.sum()) / len(d), 0.0)


def slow_errors(
    offsets: Mapping[tuple[str, str], float], white: Mapping[str, float | None] | None = None, whole: bool = False
) -> dict[str, float]:
    """Each cue's slow error variance ``B_s`` from the slow offsets of pairs, ``S_ab = B_a + B_b``, px^2.

    The three-cornered hat of clock metrology (Gray & Allan 1974) on the slow parts:
    ``B_a = (S_ab + S_ac - S_bc) / 2`` averaged over the pairs ``(b, c)`` of other cues measured with
    ``a`` and with each other; with one other cue, split by their white noise (the split is not identifiable from
    the offsets: module docstring, "Slow error"), else ``S_ab / 2``; at least 0. It is not
    clipped to the smallest ``S_ab``: a noisy pair's offset would pull it down.

    Parameters
    ----------
    offsets : mapping of (str, str) to float
        :func:`slow_offset` per pair of sources (either order), px^2.
    white : mapping of str to float or None, optional
        Each source's white noise variance: with one other cue the split follows it, ``S_ab w_a / (w_a + w_b)``
        (half each while either is unknown).
    whole : bool
        With one other cue, the whole ``S_ab`` instead of a split: either cue may be the biased one (an
        upper bound, for an uncertainty that must cover the error).
    """
    pair = {frozenset(k): v for k, v in offsets.items()}
    sources = sorted({s for k in offsets for s in k})
    out = {}
    for a in sources:
        others = [b for b in sources if b != a and frozenset((a, b)) in pair]
        if not others:
            continue
        hats = [
            0.5 * (pair[frozenset((a, b))] + pair[frozenset((a, c))] - pair[frozenset((b, c))])
            for i, b in enumerate(others)
            for c in others[i + 1 :]
            if frozenset((b, c)) in pair
        ]
        share = 1.0 if whole else _share(a, others[0], white)
        est = float(np.mean(hats)) if hats else share * pair[frozenset((a, others[0]))]
        out[a] = max(est, 0.0)
    return out


def _share(a: str, b: str, white: Mapping[str, float | None] | None) -> float:
    """``a``'s share of a pair's slow offset: ``w_a / (w_a + w_b)`` of their white noise, else one half."""
    wa, wb = (None, None) if white is None else (white.get(a), white.get(b))
    if wa is None or wb is None or wa + wb <= 0.0:
        return 0.5
    return wa / (wa + wb)


def process_scale(
    corrections: np.ndarray, process_noise_px: float, lo: float = MIN_PROCESS_SCALE, hi: float = 1.0
) -> float:
    """Factor in ``[lo, hi]`` for the configured position process noise, from the filter's corrections.

    Innovation-based adaptive estimation (Mohamed & Schwarz, "Adaptive Kalman filtering for
    INS/GPS", Journal of Geodesy 1999, eq. 33): the process noise is the covariance of the
    state corrections ``K nu``, here the estimate minus the prediction of each frame, so
    ``q_hat^2 = mean(|x_est - x_pred|^2 / 2)`` per axis and the factor is
    ``q_hat / process_noise_px`` within ``[lo, hi]`` (one camera: ``hi = 1``, the configured noise is the most the
    hand may move; a smaller one lets the filter average its cues' white noise).

    Parameters
    ----------
    corrections : ndarray, shape (n,)
        ``|x_est - x_pred|^2 / 2`` of recent frames, px^2 at the scale of ``process_noise_px`` (n >= 1).
    process_noise_px : float
        The configured position process noise per frame step, px (> 0).
    lo : float
        Smallest factor, in (0, 1].
    hi : float
        Largest factor, >= ``lo``.
    """
    q_hat = math.sqrt(float(np.mean(corrections)))
    return min(max(q_hat / process_noise_px, lo), hi)


def quality_bin(quality: float) -> int:
    """Index in ``[0, QUALITY_BINS)`` of a quality in [0, 1]."""
    return min(int(quality * QUALITY_BINS), QUALITY_BINS - 1)


def starting_sigma(sigma: float, m: Measurement, q_min: float = MIN_QUALITY) -> float:
    """The noise ``m``'s learned noise starts from and is shrunk towards: ``sigma / max(q, q_min)``.

    Before a source has residuals, its quality is all that ranks it. The robust likelihood's
    widening ``sigma / sqrt(q)`` (:func:`~fusion_pf.filter.likelihood.effective_sigma`) ranks a
    low-quality depth blob (q 0.16, 36 px off the palm) above a confident skeleton joint (q 0.92,
    2.5 px off) with the default noises 4 and 20 px, and the first frames followed the blob
    (tuned matrix, skeleton-lit-320c: 32 px at the first frame, fused RMSE 4.25 px for a 1.43 px
    skeleton); widening by ``1 / q`` ranks them by quality first. A
    :data:`~fusion_pf.filter.likelihood.PROBABILITY_QUALITY` source (its quality is the outlier
    probability) keeps ``sigma``.

    Parameters
    ----------
    sigma : float
        The source's configured noise at palm scale 1, px (> 0).
    m : Measurement
        The measurement (its source and quality in [0, 1]).
    q_min : float
        Quality floor (> 0): at most ``1 / q_min`` times ``sigma``.
    """
    # sigma_0 = sigma / max(q, q_min)
    return sigma if m.source in PROBABILITY_QUALITY else sigma / max(m.quality, q_min)


class NoiseCalibration:
    """Per-source, per-quality-bin noise and outlier probability learned online (module docstring).

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

    def __init__(
        self,
        prior: Callable[[Measurement], float],
        *,
        window: int = WINDOW,
        prior_count: float = PRIOR_COUNT,
        floor: float = FLOOR,
    ) -> None:
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
        self._samples: dict[tuple[str, int], deque[tuple[float, float]]] = {}  # per key (r, p), oldest first
        self._fits: dict[tuple[str, int], tuple[float, float]] = {}  # per key (sigma^2, eps) of its samples
        self._frame = 0  # frames seen with a timestamp
        self._recent: dict[str, deque[tuple[int, int, float, float, float]]] = {}  # per source (frame, t, u, v, q)
        self._diffs: dict[tuple[str, int], deque[float]] = {}  # per key white_noise samples at palm scale 1
        # per pair z_a - z_b at palm scale 1: of every pair of cues, and of confident measurements (SELF_QUALITY)
        self._pairs: dict[bool, dict[tuple[str, str], deque[tuple[float, float]]]] = {False: {}, True: {}}
        # slow_errors of each (None: to compute)
        self._slow: dict[bool, dict[str, float] | None] = {False: None, True: None}

    def samples(self, source: str, quality: float) -> int:
        """Residuals held for ``source`` at ``quality``'s bin."""
        return len(self._samples.get((source, quality_bin(quality)), ()))

    def _fit(self, key: tuple[str, int]) -> tuple[float, float, int] | None:
        """``(sigma^2, eps, n)`` of ``key``'s samples at palm scale 1 (None without samples)."""
        buf = self._samples.get(key)
        if not buf:
            return None
        fit = self._fits.get(key)
        if fit is None:
            rp = np.array(buf)
            fit = self._fits[key] = core_and_outliers(rp[:, 0], rp[:, 1])
        return fit[0], fit[1], len(buf)

    def white(self, source: str, quality: float) -> float | None:
        """Per-axis variance of ``source``'s white noise in ``quality``'s bin at palm scale 1, px^2 (None before :data:`SELF_MIN` samples).

        :func:`white_noise` of the bin's difference samples (each in the bin of its least
        confident measurement); for a confident bin (:data:`SELF_QUALITY` or more) with fewer than
        :data:`SELF_MIN`, of the samples of all the source's confident bins (module docstring, "Bins
        without samples").
        """
        d = self._white_samples(source, quality)
        return None if d is None else white_noise(d)

    def _white_samples(self, source: str, quality: float) -> np.ndarray | None:
        """The difference samples :meth:`white` measures ``source``'s white noise at ``quality`` with (None: too few)."""
        d = self._diffs.get((source, quality_bin(quality)))
        if d is not None and len(d) >= SELF_MIN:
            return np.fromiter(d, float)
        if quality < SELF_QUALITY:
            return None
        pooled = [x for (s, b), ds in self._diffs.items() if s == source and b >= _SELF_BIN for x in ds]
        return np.array(pooled) if len(pooled) >= SELF_MIN else None

    def slow(self, source: str, confident: bool = True) -> float | None:
        """Per-axis variance of ``source``'s slow error at palm scale 1, px^2 (:func:`slow_errors`; None before
        :data:`SLOW_MIN` frames with another cue): from the pairs of measurements of quality :data:`SELF_QUALITY` or
        more, split by the cues' white noise where only two were measured together (the floors'); with
        ``confident=False`` from every pair whatever its quality, the whole offset where only two were (the reported
        uncertainty's, ``fusion_pf.pipeline.run``: the biased blobs are the less confident ones, and of two cues
        either may be the biased one)."""
        known = self._slow[confident]
        if known is None:
            pairs = self._pairs[confident]
            offsets = {k: slow_offset(np.array(d)) for k, d in pairs.items() if len(d) >= SLOW_MIN}
            white = {s: self.white(s, 1.0) for k in offsets for s in k}
            known = self._slow[confident] = slow_errors(offsets, white, whole=not confident)
        return known.get(source)

    def sigma(self, m: Measurement, scale: float = 1.0) -> float:
        """Noise of ``m`` in px at palm scale ``scale``: its bin's (:meth:`bin_sigma`) at the bin's centre, log-linear in
        the quality towards the neighbour bin's, half way at the boundary, once that neighbour holds :data:`BORROW_MIN`
        residuals and is not below :data:`SELF_QUALITY` under ``m`` (module docstring, "Between bins")."""
        b = quality_bin(m.quality)
        centre = (b + 0.5) / QUALITY_BINS
        n = b + 1 if m.quality > centre else b - 1
        own = self.bin_sigma(m, scale)
        if not 0 <= n < QUALITY_BINS:
            return own
        edge = (b + 1) / QUALITY_BINS if n > b else math.nextafter(b / QUALITY_BINS, 0.0)
        other = replace(m, quality=edge)
        if self.samples(m.source, edge) < BORROW_MIN or edge < min(m.quality, SELF_QUALITY):
            return own
        # log sigma = (1 - t) log sigma_b + t log sigma_n, t = |q - centre_b| / bin width (1/2 at the boundary)
        t = abs(m.quality - centre) * QUALITY_BINS
        return own ** (1.0 - t) * self.bin_sigma(other, scale) ** t

    def bin_sigma(self, m: Measurement, scale: float = 1.0) -> float:
        """Noise of ``m``'s quality bin in px at palm scale ``scale``: the bin's learned core noise shrunk towards the prior.

        The shrinkage target is the configured prior (:attr:`prior`), at most the noise of the same
        source one quality bin lower once that bin holds :data:`BORROW_MIN` residuals (module
        docstring, "Bins without samples"); the bounds stay the prior's.
        """
        s0 = self.prior(m)
        target = s0
        b = quality_bin(m.quality)
        if b > 0 and m.source not in PROBABILITY_QUALITY:
            lower = replace(m, quality=math.nextafter(b / QUALITY_BINS, 0.0))
            if lower.quality >= SELF_QUALITY and self.samples(m.source, lower.quality) >= BORROW_MIN:
                # a more confident measurement is no noisier: the next lower bin's noise bounds this one's target
                target = min(s0, self.bin_sigma(lower))
        fit = self._fit((m.source, b))
        var, n = (fit[0], fit[2]) if fit is not None else (None, 0)
        low = min(self.floor, s0)
        own_samples = 0
        diffs = self._white_samples(m.source, m.quality) if m.quality >= SELF_QUALITY else None
        if diffs is not None:
            # without residuals nothing catches the cue's jumps: their mean, not the robust fit ("A lone cue")
            white = white_noise(diffs) if var is not None else float(np.mean(diffs))
            slow = self.slow(m.source)
            # the cue's error measured from itself: sigma_white / SELF_FLOOR, or SLOW_FACTOR sqrt(sigma_white^2 + B)
            own = math.sqrt(white) / SELF_FLOOR if slow is None else SLOW_FACTOR * math.sqrt(white + slow)
            # the floor down to it, at most to SELF_FLOOR (SLOW_FLOOR with B) of it
            least = (SELF_FLOOR if slow is None else SLOW_FLOOR) * low
            low = min(low, max(own, least))
            if own <= least:
                # the cue itself sees no error above the lowest floor: its difference samples are evidence of its
                # noise, at that floor, as its residuals are of theirs (module docstring, "The first frames of a
                # precise cue")
                own_samples = len(diffs)
        if var is None and not own_samples:
            return target * scale
        # sigma_hat within [low, B sigma_0] (without residuals, the difference samples alone: low)
        learned = low if var is None else min(max(math.sqrt(var), low), s0 * BOUND)
        if own_samples:
            # log sigma_hat = (n log sigma_hat + n_d log low) / (n + n_d)
            learned = learned ** (n / (n + own_samples)) * low ** (own_samples / (n + own_samples))
            n += own_samples
        # log sigma = (n0 log sigma_0 + n log sigma_hat) / (n0 + n)
        w = n / (self.prior_count + n)
        return target ** (1.0 - w) * learned**w * scale

    def start_sigma(self, m: Measurement, scale: float = 1.0) -> float:
        """Noise of ``m`` a (re)start at it spreads the particles by, px at palm scale ``scale`` (module docstring, "A start at a less confident cue").

        :meth:`sigma`; while ``m``'s bin holds fewer than :attr:`prior_count` residuals (its prior outweighs
        them), at most the noise of the next higher bin (of quality :data:`SELF_QUALITY` or more, once it holds
        :data:`BORROW_MIN` residuals) widened by the prior's ratio of the two qualities.
        """
        own = self.sigma(m, scale)
        b = quality_bin(m.quality)
        if (
            b + 1 >= QUALITY_BINS
            or m.source in PROBABILITY_QUALITY
            or self.samples(m.source, m.quality) >= self.prior_count
        ):
            return own
        higher = replace(m, quality=(b + 1) / QUALITY_BINS)
        if higher.quality < SELF_QUALITY or self.samples(m.source, higher.quality) < BORROW_MIN:
            return own
        # sigma_above s0(q) / s0(q_above)
        return min(own, self.sigma(higher, scale) * self.prior(m) / self.prior(higher))

    def outlier(self, m: Measurement) -> float:
        """Outlier probability of ``m``: the bin's learned share shrunk towards :data:`DEFAULT_EPS`."""
        fit = self._fit((m.source, quality_bin(m.quality)))
        if fit is None:
            return DEFAULT_EPS
        _, eps, n = fit
        w = n / (self.prior_count + n)
        # eps = (n0 eps_0 + n eps_hat) / (n0 + n), within [MIN_EPS, MAX_EPS]
        return min(max((1.0 - w) * DEFAULT_EPS + w * eps, MIN_EPS), MAX_EPS)

    def update(
        self,
        ms: Sequence[Measurement],
        sigmas: Mapping[str, float],
        scale: float = 1.0,
        prediction: tuple[float, float, float] | None = None,
        timestamp_ns: int | None = None,
    ) -> None:
        """Add this frame's residuals (against ``prediction`` when given, else leave-one-out) and, with ``timestamp_ns``, each cue's difference sample.

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
            error variance, px^2.
        timestamp_ns : int or None
            The frame's time: a source measured in this frame and the :data:`SELF_ORDER` frames before
            adds a :func:`white_noise` sample (a lone cue too: it needs no other reference).
        """
        if timestamp_ns is not None:
            self._difference(ms, timestamp_ns, scale * scale)
        self._offsets(ms, scale)
        if len(ms) < 2:
            return
        k2 = scale * scale
        if prediction is not None:
            pu, pv, pvar = prediction
            for m in ms:
                # r = |z_s - x_pred|^2 / 2, p = P
                self._add(m, 0.5 * ((m.u - pu) ** 2 + (m.v - pv) ** 2) / k2, pvar / k2)
            return
        prec = [1.0 / sigmas[m.source] ** 2 for m in ms]
        total = math.fsum(prec)
        total_u = math.fsum(p * m.u for p, m in zip(prec, ms))
        total_v = math.fsum(p * m.v for p, m in zip(prec, ms))
        for p, m in zip(prec, ms):
            rest = total - p
            # z_-s = sum_(i != s) z_i / sigma_i^2 / sum_(i != s) 1 / sigma_i^2, V_-s = 1 / sum_(i != s) 1 / sigma_i^2
            du = m.u - (total_u - p * m.u) / rest
            dv = m.v - (total_v - p * m.v) / rest
            self._add(m, 0.5 * (du * du + dv * dv) / k2, 1.0 / rest / k2)

    def _add(self, m: Measurement, r: float, p: float) -> None:
        """Keep the sample ``(r, p)`` of ``m``'s source and bin (the oldest leaves a full window)."""
        key = (m.source, quality_bin(m.quality))
        buf = self._samples.get(key)
        if buf is None:
            buf = self._samples[key] = deque(maxlen=self.window)
        buf.append((r, p))
        self._fits.pop(key, None)

    def _offsets(self, ms: Sequence[Measurement], scale: float) -> None:
        """Keep ``(z_a - z_b) / k`` of each pair of this frame's cues; apart, too, of those of quality
        :data:`SELF_QUALITY` or more."""
        ordered = sorted(ms, key=lambda m: m.source)
        for i, a in enumerate(ordered):
            for b in ordered[i + 1 :]:
                d = ((a.u - b.u) / scale, (a.v - b.v) / scale)
                for confident in (False, True) if min(a.quality, b.quality) >= SELF_QUALITY else (False,):
                    self._pairs[confident].setdefault((a.source, b.source), deque(maxlen=SLOW_WINDOW)).append(d)
                    self._slow[confident] = None

    def _difference(self, ms: Sequence[Measurement], timestamp_ns: int, k2: float) -> None:
        """Keep each source's last :data:`SELF_ORDER` + 1 measurements; over as many frames in a row, a :func:`white_noise` sample."""
        self._frame += 1
        for m in ms:
            recent = self._recent.get(m.source)
            if recent is None:
                recent = self._recent[m.source] = deque(maxlen=SELF_ORDER + 1)
            if recent and (recent[-1][0] != self._frame - 1 or recent[-1][1] >= timestamp_ns):
                recent.clear()  # a frame without the source, or time not moving forward: start again
            recent.append((self._frame, timestamp_ns, m.u, m.v, m.quality))
            if len(recent) <= SELF_ORDER:
                continue
            ftuvq = np.array(recent, dtype=float)
            w = difference_weights(ftuvq[:, 1] - ftuvq[0, 1])
            du, dv = w @ ftuvq[:, 2], w @ ftuvq[:, 3]
            key = (m.source, quality_bin(float(ftuvq[:, 4].min())))
            diffs = self._diffs.get(key)
            if diffs is None:
                diffs = self._diffs[key] = deque(maxlen=self.window)
            # d = |sum_i w_i z_i|^2 / 2 at palm scale 1
            diffs.append(0.5 * (du * du + dv * dv) / k2)
