"""Online noise calibration (fusion_pf/filter/calibration.py): residuals against the prediction or leave-one-out, per quality band."""

import math

import numpy as np
import pytest

from fusion_pf.errors import InputError
from fusion_pf.filter.calibration import (
    BORROW_MIN,
    FLOOR,
    PRIOR_COUNT,
    QUALITY_BINS,
    WINDOW,
    NoiseCalibration,
    quality_bin,
    starting_sigma,
)
from fusion_pf.filter.likelihood import DEFAULT_NOISE_PX, MIN_QUALITY, effective_sigma
from fusion_pf.frame import Measurement


def _run(frames: int, truth: dict, prior: dict, rng: int = 0, scale: float = 1.0, **kw) -> NoiseCalibration:
    """Feed ``frames`` frames of sources with true per-axis noise ``truth[(source, quality)]``."""
    cal = NoiseCalibration(lambda m: prior[m.source], **kw)
    gen = np.random.default_rng(rng)
    for _ in range(frames):
        palm = gen.uniform(50, 250, 2)
        ms = [Measurement(s, *(palm + gen.normal(0, sd * scale, 2)), quality=q) for (s, q), sd in truth.items()]
        cal.update(ms, {m.source: cal.sigma(m, scale) for m in ms}, scale)
    return cal


def test_three_sources_recover_their_noise_without_ground_truth():
    # three independent sources, true sigma 1, 3 and 9 px; every prior says 5 px
    truth = {("a", 0.9): 1.0, ("b", 0.9): 3.0, ("c", 0.9): 9.0}
    cal = _run(1000, truth, {"a": 5.0, "b": 5.0, "c": 5.0})
    a, b, c = (cal.sigma(Measurement(s, 0, 0, quality=0.9)) for s in "abc")
    # b and c within 25 %; the best source's noise is the hardest to see next to the others' (its share
    # of the residual is 1 / 9 px^2 here) but leaves the wrong prior: ordered, and below half of it
    np.testing.assert_allclose([b, c], [3.0, 9.0], rtol=0.25)
    assert a < b < c and a < 2.5


def test_quality_bands_are_learned_apart():
    # source "s" is exact at quality 0.9 and 30 px off at quality 0.3; "ref" is a 1 px reference
    cal = NoiseCalibration(lambda m: 10.0)
    gen = np.random.default_rng(1)
    for k in range(300):
        palm = gen.uniform(50, 250, 2)
        q = 0.9 if k % 2 else 0.3
        sd = 1.0 if q == 0.9 else 30.0
        ms = [
            Measurement("ref", *(palm + gen.normal(0, 1, 2)), quality=0.9),
            Measurement("s", *(palm + gen.normal(0, sd, 2)), quality=q),
        ]
        cal.update(ms, {m.source: cal.sigma(m) for m in ms})
    good = cal.sigma(Measurement("s", 0, 0, quality=0.9))
    bad = cal.sigma(Measurement("s", 0, 0, quality=0.3))
    assert good < 3.0 and bad > 20.0
    assert quality_bin(0.9) != quality_bin(0.3)


def test_noise_is_learned_in_palm_units():
    # the same recording with a palm twice as large: residuals stored over k^2, sigma returned at the asked scale
    truth = {("a", 0.9): 1.0, ("b", 0.9): 4.0, ("c", 0.9): 4.0}
    one = _run(200, truth, {"a": 2.0, "b": 2.0, "c": 2.0}, scale=1.0)
    two = _run(200, truth, {"a": 2.0, "b": 2.0, "c": 2.0}, scale=2.0)
    m = Measurement("a", 0, 0, quality=0.9)
    assert two.sigma(m) == pytest.approx(one.sigma(m), rel=1e-9)
    assert two.sigma(m, 2.0) == pytest.approx(2.0 * one.sigma(m), rel=1e-9)


def test_a_lone_source_keeps_its_prior_and_few_samples_stay_near_it():
    cal = NoiseCalibration(lambda m: 4.0)
    m = Measurement("a", 10.0, 10.0, quality=0.8)
    for _ in range(20):
        cal.update([m], {"a": 4.0})
    assert cal.samples("a", 0.8) == 0 and cal.sigma(m) == 4.0
    # one residual of a wildly wrong cue: the prior's pseudo-samples and the 10 x bound hold it
    cal.update([m, Measurement("b", 1000.0, 10.0, quality=0.8)], {"a": 4.0, "b": 4.0})
    w = 1 / (PRIOR_COUNT + 1)
    assert cal.sigma(m) == pytest.approx(4.0 ** (1 - w) * 40.0**w)


def test_quality_bins_cover_zero_to_one():
    assert [quality_bin(q) for q in (0.0, 0.2499, 0.25, 0.74, 0.999, 1.0)] == [
        0,
        0,
        1,
        2,
        QUALITY_BINS - 1,
        QUALITY_BINS - 1,
    ]


@pytest.mark.parametrize("kw", [{"window": 0}, {"window": 1.5}, {"prior_count": -1}, {"prior_count": math.nan}])
def test_bad_options_are_named(kw):
    with pytest.raises(InputError, match=next(iter(kw))):
        NoiseCalibration(lambda m: 1.0, **kw)


def test_a_cue_below_the_floor_is_learned_at_the_floor():
    # three sources 0.02 px off: the residual medians say ~0.02 px, the floor keeps 0.7 px (a heavy-tailed
    # cue's median sees its core, not its spread: unfloored it would be trusted alone)
    truth = {("a", 0.9): 0.02, ("b", 0.9): 0.02, ("c", 0.9): 0.02}
    a = Measurement("a", 0, 0, quality=0.9)
    w = WINDOW / (PRIOR_COUNT + WINDOW)
    floored = _run(300, truth, {"a": 3.0, "b": 3.0, "c": 3.0})
    assert floored.sigma(a) == pytest.approx(3.0 ** (1 - w) * FLOOR**w)
    bare = _run(300, truth, {"a": 3.0, "b": 3.0, "c": 3.0}, floor=1e-3)
    assert bare.sigma(a) < 0.1 * floored.sigma(a)
    # a source configured below the floor keeps its own prior as the floor
    fine = _run(300, truth, {"a": 0.2, "b": 0.2, "c": 0.2})
    assert fine.sigma(a) == pytest.approx(0.2)


@pytest.mark.parametrize("floor", [0, -1.0, math.inf, math.nan, True, "0.7"])
def test_bad_floor_is_named(floor):
    with pytest.raises(InputError, match="floor"):
        NoiseCalibration(lambda m: 1.0, floor=floor)


def WIDENING(eps):
    """Factor the median of all samples puts on a core's sigma when a share eps of gross errors lies above it."""
    return math.sqrt(math.log(2.0 * (1.0 - eps) / (1.0 - 2.0 * eps)) / math.log(2.0))


def test_core_and_outliers_recover_a_known_mixture():
    # reference: the simulation's own parameters. A 2-D Gaussian core of per-axis sigma 2 px compared with
    # references of varying per-axis variance p, and 20 % gross errors uniform over a 400 px square
    from fusion_pf.filter.calibration import core_and_outliers

    gen = np.random.default_rng(7)
    n, sigma, eps = 20000, 2.0, 0.2
    p = gen.uniform(0.0, 3.0, n)
    d = gen.normal(0.0, 1.0, (n, 2)) * np.sqrt(sigma**2 + p)[:, None]
    gross = gen.random(n) < eps
    d[gross] = gen.uniform(-200, 200, (gross.sum(), 2))
    var, share = core_and_outliers(0.5 * (d**2).sum(axis=1), p)
    # the median of all samples: the core's sigma^2 + p widened by ln(2 (1 - eps) / (1 - 2 eps)) / ln 2, at p's mean
    assert math.sqrt(var) == pytest.approx(math.sqrt(WIDENING(eps) ** 2 * (sigma**2 + 1.5) - 1.5), rel=0.06)
    assert share == pytest.approx(eps, abs=0.02)
    # a clean core: no outliers, the median alone
    clean = d[~gross]
    var0, share0 = core_and_outliers(0.5 * (clean**2).sum(axis=1), p[~gross])
    assert math.sqrt(var0) == pytest.approx(sigma, rel=0.05) and share0 < 0.01
    # references that explain the whole residual: the core variance is 0, not negative
    assert core_and_outliers(np.array([0.1, 0.2, 0.3]), np.array([5.0, 5.0, 5.0]))[0] == 0.0


def test_process_scale_is_the_rms_correction_over_the_configured_noise():
    from fusion_pf.filter.calibration import MIN_PROCESS_SCALE, process_scale

    gen = np.random.default_rng(2)
    # corrections of per-axis std 1.5 px against a configured 3 px: factor 0.5
    c = gen.normal(0.0, 1.5, (50000, 2))
    half = 0.5 * (c**2).sum(axis=1)
    assert process_scale(half, 3.0) == pytest.approx(0.5, rel=0.02)
    # bounded: never above the configured noise, never below MIN_PROCESS_SCALE of it
    assert process_scale(half * 100.0, 3.0) == 1.0
    assert process_scale(half * 1e-6, 3.0) == MIN_PROCESS_SCALE


def _shared_error_frames(cal: NoiseCalibration, frames: int, with_prediction: bool) -> NoiseCalibration:
    """Cues a and b share one 6 px error (both pulled the same way, as colour and depth to the forearm),
    c is 1 px off; the prediction (when given) is 1 px off, and says so."""
    gen = np.random.default_rng(5)
    for _ in range(frames):
        palm = gen.uniform(50, 250, 2)
        shared = gen.normal(0, 6.0, 2)
        ms = [
            Measurement("a", *(palm + shared + gen.normal(0, 0.5, 2)), quality=0.9),
            Measurement("b", *(palm + shared + gen.normal(0, 0.5, 2)), quality=0.9),
            Measurement("c", *(palm + gen.normal(0, 1.0, 2)), quality=0.9),
        ]
        pred = (*(palm + gen.normal(0, 1.0, 2)), 1.0) if with_prediction else None
        cal.update(ms, {m.source: cal.sigma(m) for m in ms}, 1.0, pred)
    return cal


def test_against_the_prediction_two_cues_wrong_the_same_way_do_not_blame_the_third():
    sig = {s: lambda cal, s=s: cal.sigma(Measurement(s, 0, 0, quality=0.9)) for s in "abc"}
    innov = _shared_error_frames(NoiseCalibration(lambda m: 5.0, floor=0.1), 400, with_prediction=True)
    a, b, c = (sig[s](innov) for s in "abc")
    # against the prediction (variance 1 subtracted): c is its own 1 px, a and b their 6 px
    assert c == pytest.approx(1.0, rel=0.25) and a > 4.0 and b > 4.0
    # against each other (leave-one-out, no prediction), a and b agree and c takes the blame
    loo = _shared_error_frames(NoiseCalibration(lambda m: 5.0, floor=0.1), 400, with_prediction=False)
    assert sig["c"](loo) > max(sig["a"](loo), sig["b"](loo))


def test_a_cue_with_gross_errors_learns_its_outlier_probability():
    from fusion_pf.filter.calibration import DEFAULT_EPS, MIN_EPS

    cal = NoiseCalibration(lambda m: 5.0)
    gen = np.random.default_rng(11)
    a, b = Measurement("a", 0, 0, quality=0.9), Measurement("b", 0, 0, quality=0.9)
    assert cal.outlier(a) == DEFAULT_EPS  # nothing learned yet
    for _ in range(WINDOW):
        palm = gen.uniform(50, 250, 2)
        wrong = gen.random() < 0.3  # "b" is on another blob 30 % of the time
        ms = [
            Measurement("a", *(palm + gen.normal(0, 1.0, 2)), quality=0.9),
            Measurement("b", *(palm + gen.normal(0, 1.0, 2) + (80.0 if wrong else 0.0)), quality=0.9),
        ]
        cal.update(ms, {m.source: cal.sigma(m) for m in ms}, 1.0, (*palm, 0.0))
    w = WINDOW / (PRIOR_COUNT + WINDOW)
    assert cal.outlier(b) == pytest.approx((1 - w) * DEFAULT_EPS + w * 0.3, abs=0.06)
    assert cal.outlier(a) < 0.5 * DEFAULT_EPS and cal.outlier(a) >= MIN_EPS
    # the gross errors widen b's core only by the median's factor at 30 % (1.34x)
    assert cal.sigma(b) == pytest.approx(cal.sigma(a) * WIDENING(0.3), rel=0.15)


def test_a_lone_cue_keeps_its_prior_even_with_a_prediction():
    # the prediction was made from that cue alone: nothing to tell its noise from the motion model's misfit
    cal = NoiseCalibration(lambda m: 4.0)
    m = Measurement("a", 110.0, 100.0, quality=0.8)
    for _ in range(20):
        cal.update([m], {"a": 4.0}, 1.0, (100.0, 100.0, 0.0))
    assert cal.samples("a", 0.8) == 0 and cal.sigma(m) == 4.0


def test_the_starting_noise_ranks_cues_by_quality_before_any_residual():
    noise = DEFAULT_NOISE_PX
    blob, joint = Measurement("depth", 0.0, 0.0, quality=0.16), Measurement("skeleton", 0.0, 0.0, quality=0.92)
    # sigma / q: 4 / 0.16 = 25 px, 20 / 0.92 = 21.7 px
    assert starting_sigma(noise["depth"], blob) == pytest.approx(25.0)
    assert starting_sigma(noise["skeleton"], joint) == pytest.approx(20.0 / 0.92)
    # the likelihood's sigma / sqrt(q) ranked the low-quality blob first (10 px < 20.9 px)
    assert effective_sigma(noise["depth"], 0.16, MIN_QUALITY) < effective_sigma(noise["skeleton"], 0.92, MIN_QUALITY)
    assert starting_sigma(noise["depth"], Measurement("depth", 0.0, 0.0, quality=0.0)) == pytest.approx(
        4.0 / MIN_QUALITY
    )
    # the hand cue's quality is its outlier probability: its noise is not widened
    assert starting_sigma(noise["hand"], Measurement("hand", 0.0, 0.0, quality=0.2)) == noise["hand"]
    cal = NoiseCalibration(lambda m: starting_sigma(noise[m.source], m))
    assert cal.sigma(joint) < cal.sigma(blob)


def test_a_cue_off_by_a_few_px_in_runs_is_not_fitted_its_good_half():
    # issue 23, skeleton-lit-320's depth blob: right to 0.5 px half the time, 3-9 px off otherwise; the
    # quantile fit took the good half as the core (0.6 px, 30 % "outliers") and the cue was trusted more
    # than a 1.5 px cue. Reference: the sample's own median error, sqrt(median(|d|^2 / 2) / ln 2), here
    # computed from the simulated errors without the reference variance
    from fusion_pf.filter.calibration import core_and_outliers

    gen = np.random.default_rng(3)
    n = 400
    scale = np.where(gen.random(n) < 0.5, 0.5, gen.uniform(3.0, 9.0, n))
    d = gen.normal(0.0, 1.0, (n, 2)) * scale[:, None]
    p = np.full(n, 0.25)
    ref = gen.normal(0.0, 0.5, (n, 2))
    r = 0.5 * ((d + ref) ** 2).sum(axis=1)
    var, _ = core_and_outliers(r, p)
    expected = math.sqrt(np.median(0.5 * (d**2).sum(axis=1)) / math.log(2.0))
    assert math.sqrt(var) == pytest.approx(expected, rel=0.15)
    assert math.sqrt(var) > 1.5


def test_difference_weights_are_the_unit_norm_divided_difference():
    from fusion_pf.filter.calibration import difference_weights

    # equal steps: the third difference's binomial coefficients (-1, 3, -3, 1) / sqrt(20), whatever the step
    np.testing.assert_allclose(difference_weights(np.array([0.0, 1.0, 2.0, 3.0])), np.array([-1, 3, -3, 1]) / 20**0.5)
    np.testing.assert_allclose(
        difference_weights(np.array([5e7, 8e7, 1.1e8, 1.4e8])), np.array([-1, 3, -3, 1]) / 20**0.5
    )
    # uneven steps (a dropped frame): unit norm, and blind to any quadratic (columns 1, t, t^2 of the Vandermonde matrix)
    t = np.array([0.0, 1.0, 3.0, 4.0])
    w = difference_weights(t)
    assert float(w @ w) == pytest.approx(1.0)
    np.testing.assert_allclose(np.vander(t, 3).T @ w, 0.0, atol=1e-12)


def _smooth_track(n: int) -> np.ndarray:
    """A palm path over ``n`` frames, px: a slow figure of eight 60 x 40 px wide (0.2-3 px per frame)."""
    k = np.arange(n)
    return np.stack([200 + 60 * np.sin(2 * np.pi * k / 120), 150 + 40 * np.sin(4 * np.pi * k / 120)], axis=1)


def test_white_noise_of_a_moving_biased_cue_is_its_simulated_noise():
    # reference: the simulation's own white noise (0.3 px per axis), under a bias drifting 4 px over 60 frames
    from fusion_pf.filter.calibration import difference_weights, white_noise

    gen = np.random.default_rng(5)
    n = 400
    k = np.arange(n)
    bias = 4.0 * np.stack([np.sin(2 * np.pi * k / 240), np.cos(2 * np.pi * k / 240)], axis=1)
    z = _smooth_track(n) + bias + gen.normal(0.0, 0.3, (n, 2))
    w = difference_weights(np.arange(4.0))
    windows = np.lib.stride_tricks.sliding_window_view(z, 4, axis=0)  # (n - 3, 2, 4)
    d = 0.5 * ((windows @ w) ** 2).sum(axis=1)
    assert math.sqrt(white_noise(d)) == pytest.approx(0.3, rel=0.1)


def _run_moving(
    frames: int, noise: dict, prior: float = 4.0, rng: int = 0, timestamps: bool = True
) -> NoiseCalibration:
    """Cues ``noise[(source, quality)] = per-axis px`` on a moving palm, learned against a prediction whose stated
    variance (9 px^2 per axis) is 9 x its real error's (1 px), as issue 23's far scenes have it."""
    cal = NoiseCalibration(lambda m: prior)
    gen = np.random.default_rng(rng)
    palm = _smooth_track(frames)
    for i in range(frames):
        ms = [Measurement(s, *(palm[i] + gen.normal(0, sd, 2)), quality=q) for (s, q), sd in noise.items()]
        pred = (*(palm[i] + gen.normal(0.0, 1.0, 2)), 9.0)
        t = 1_000_000_000 + i * 33_333_333 if timestamps else None
        cal.update(ms, {m.source: cal.sigma(m) for m in ms}, 1.0, pred, t)
    return cal


def test_a_cue_more_precise_than_the_prediction_is_trusted_below_the_floor():
    # issue 23, far-hand-sharp-960: a 0.05 px cue beside two 2 px ones, against a prediction whose stated
    # variance hides every cue's noise: all three were fitted 0 and fused at the floor. Its own white noise
    # (measured without the prediction) and its slow error (none here) let the floor go down to SLOW_FLOOR of it; a
    # 0.25 px cue is learned at SLOW_FACTOR x its simulated noise; a low-quality cue, whose error is mostly slow bias,
    # keeps the floor
    from fusion_pf.filter.calibration import SELF_QUALITY, SLOW_FACTOR, SLOW_FLOOR

    noise = {("sharp", 0.9): 0.05, ("mid", 0.9): 0.25, ("vague", 0.2): 0.05, ("b", 0.9): 2.0, ("c", 0.9): 2.0}
    assert SLOW_FACTOR * 0.05 < SLOW_FLOOR * FLOOR < SLOW_FACTOR * 0.25 < FLOOR
    assert 0.2 < SELF_QUALITY <= 0.9
    w = WINDOW / (PRIOR_COUNT + WINDOW)
    shrunk = 4.0 ** (1 - w)
    # a cue whose own noise is below the lowest floor counts its WINDOW difference samples as evidence too
    w2 = 2 * WINDOW / (PRIOR_COUNT + 2 * WINDOW)
    shrunk2 = 4.0 ** (1 - w2)
    new, old = _run_moving(300, noise), _run_moving(300, noise, timestamps=False)
    sharp, mid, vague = (Measurement(s, 0, 0, quality=q) for s, q in (("sharp", 0.9), ("mid", 0.9), ("vague", 0.2)))
    # without timestamps (the calibration before): the floor
    for m in (sharp, mid, vague):
        assert old.sigma(m) == pytest.approx(shrunk * FLOOR**w)
    assert new.sigma(sharp) == pytest.approx(shrunk2 * (SLOW_FLOOR * FLOOR) ** w2)
    assert new.sigma(mid) == pytest.approx(shrunk * (SLOW_FACTOR * 0.25) ** w, rel=0.15)
    assert new.sigma(vague) == pytest.approx(shrunk * FLOOR**w)
    assert math.sqrt(new.white("sharp", 0.9)) == pytest.approx(0.05, rel=0.15)
    # the 2 px cues: above the floor, learned from the prediction as before
    b = Measurement("b", 0, 0, quality=0.9)
    assert new.sigma(b) == pytest.approx(old.sigma(b))


def test_a_lone_precise_cue_is_learned_from_its_own_differences():
    # a single cue has no residuals (the prediction was made from it alone), but its own differences measure its white
    # noise without a prediction: a 0.05 px cue alone (`--cues depth` on a far scene) goes from its 4 px prior to the
    # lowest floor its white noise gives, SELF_FLOOR of the floor (no other cue: no slow error); a 2 px cue alone, above
    # that floor, and the same precise cue without timestamps (no differences) keep their prior
    from fusion_pf.filter.calibration import SELF_FLOOR

    w = WINDOW / (PRIOR_COUNT + WINDOW)
    sharp, broad = Measurement("sharp", 0, 0, quality=0.9), Measurement("broad", 0, 0, quality=0.9)
    alone = _run_moving(300, {("sharp", 0.9): 0.05})
    assert alone.samples("sharp", 0.9) == 0
    assert alone.sigma(sharp) == pytest.approx(4.0 ** (1 - w) * (SELF_FLOOR * FLOOR) ** w)
    assert _run_moving(300, {("broad", 0.9): 2.0}).sigma(broad) == 4.0
    assert _run_moving(300, {("sharp", 0.9): 0.05}, timestamps=False).sigma(sharp) == 4.0
    # the same cue jumping 6 px in 1 frame of 10 (a blob switching objects: gen-40018-colour-320's colour-only run,
    # 6.1 px RMSE at a robust white noise of 0.2 px): its mean difference, not the robust fit, keeps its prior
    cal = NoiseCalibration(lambda m: 4.0)
    gen = np.random.default_rng(1)
    palm = _smooth_track(300)
    for i in range(300):
        jump = 6.0 if i % 10 == 0 else 0.0
        z = palm[i] + gen.normal(0.0, 0.05, 2) + jump
        cal.update([Measurement("sharp", *z, quality=0.9)], {"sharp": cal.sigma(sharp)}, 1.0, None, i * 33_333_333)
    assert math.sqrt(cal.white("sharp", 0.9)) < 0.1 and cal.sigma(sharp) == 4.0


def test_white_noise_needs_frames_in_a_row():
    # a cue seen every other frame (another cue seen in each) never has SELF_ORDER + 1 frames in a row
    from fusion_pf.filter.calibration import SELF_MIN

    cal = NoiseCalibration(lambda m: 4.0)
    for i in range(40):
        ms = [Measurement("b", 100.0, 100.0 + i)] + ([Measurement("a", 100.0 + i, 100.0, quality=0.9)] if i % 2 else [])
        cal.update(ms, {"a": 4.0, "b": 4.0}, 1.0, None, i * 33_333_333)
    assert cal.white("a", 0.9) is None and cal.white("b", 1.0) is not None
    # time not moving forward starts again as well
    cal = NoiseCalibration(lambda m: 4.0)
    for i in range(SELF_MIN + 20):
        cal.update([Measurement("a", 100.0, 100.0)], {"a": 4.0}, 1.0, None, (i % 3) * 33_333_333)
    assert cal.white("a", 1.0) is None


def _biased_frames(frames: int, cues: dict, rng: int = 0) -> list[list[Measurement]]:
    """Cues ``cues[source] = (white px per axis, bias (u, v) px)`` on a moving palm."""
    gen = np.random.default_rng(rng)
    palm = _smooth_track(frames)
    out = []
    for i in range(frames):
        ms = []
        for s, (sd, bias) in cues.items():
            z = palm[i] + np.asarray(bias) + gen.normal(0, sd, 2)
            ms.append(Measurement(s, *z, quality=0.9))
        out.append(ms)
    return out


def test_slow_errors_recover_simulated_biases_under_white_noise():
    # reference: the simulation's biases (orthogonal, as independent ones are on average), B_s = |b_s|^2 / 2 per
    # axis: a (0.3 px white, 1 px off on each axis) 1.0, b (3 px white) 0, c (2 px white, 0.5 px off) 0.25
    from fusion_pf.filter.calibration import slow_errors, slow_offset

    cues = {"a": (0.3, (1.0, -1.0)), "b": (3.0, (0.0, 0.0)), "c": (2.0, (0.5, 0.5))}
    found = {s: [] for s in cues}
    for rng in range(20):
        frames = _biased_frames(60, cues, rng)
        z = {s: np.array([[m.u, m.v] for ms in frames for m in ms if m.source == s]) for s in cues}
        offsets = {(x, y): slow_offset(z[x] - z[y]) for x, y in (("a", "b"), ("a", "c"), ("b", "c"))}
        for s, b in slow_errors(offsets).items():
            found[s].append(b)
    assert np.mean(found["a"]) == pytest.approx(1.0, abs=0.15)
    # the clip at 0 of noisy offsets lifts a zero slow error (3 px white over 60 frames) by about 0.2 px^2
    assert 0.0 <= np.mean(found["b"]) < 0.35
    assert np.mean(found["c"]) == pytest.approx(0.25, abs=0.2)
    # two cues only: the split is not identifiable, each gets half the offset
    assert slow_errors({("a", "b"): 2.0}) == {"a": 1.0, "b": 1.0}


def test_two_cues_split_their_slow_offset_by_their_white_noise():
    # issue 23, gen-32683-far-1280: a 0.2 px depth cue and a colour blob 6-8 px off, no third cue beside both; split
    # half each, depth took half of colour's offset as its own slow error and its floor rose 0.33 -> 0.9 px (at palm
    # scale 1), and colour pulled the track 4-6 px. Reference: the simulation's biases, sharp 0 and noisy 2 px per
    # axis (B = 4 px^2)
    from fusion_pf.filter.calibration import slow_errors

    cal = NoiseCalibration(lambda m: 4.0)
    gen = np.random.default_rng(3)
    frames = _biased_frames(200, {"sharp": (0.05, (0.0, 0.0)), "noisy": (1.0, (2.0, 2.0))})
    palm = _smooth_track(200)
    for i, ms in enumerate(frames):
        pred = (*(palm[i] + gen.normal(0.0, 1.0, 2)), 9.0)
        cal.update(ms, {m.source: cal.sigma(m) for m in ms}, 1.0, pred, 1_000_000_000 + i * 33_333_333)
    assert cal.slow("sharp") < 0.1
    assert cal.slow("noisy") == pytest.approx(4.0, rel=0.25)
    # unknown white noise: half each, as before
    assert slow_errors({("a", "b"): 2.0}, {"a": None, "b": 1.0}) == {"a": 1.0, "b": 1.0}
    assert slow_errors({("a", "b"): 2.0}, {"a": 1.0, "b": 3.0}) == {"a": 0.5, "b": 1.5}
    # the bound the reported uncertainty takes: either cue may be the biased one
    assert slow_errors({("a", "b"): 2.0}, {"a": 1.0, "b": 3.0}, whole=True) == {"a": 2.0, "b": 2.0}


def test_unconfident_pairs_count_in_the_uncertainty_slow_error_only():
    # a confident cue 2 px off on each axis beside an unbiased unconfident one (quality 0.3): the floors' slow error
    # (confident pairs) knows nothing of it, the uncertainty's holds the pair's whole offset, B = |b|^2 / 2 = 4 px^2
    cal = NoiseCalibration(lambda m: 4.0)
    gen = np.random.default_rng(5)
    palm = _smooth_track(100)
    for i in range(100):
        ms = [
            Measurement("sure", *(palm[i] + (2.0, 2.0) + gen.normal(0.0, 0.2, 2)), quality=0.9),
            Measurement("unsure", *(palm[i] + gen.normal(0.0, 1.0, 2)), quality=0.3),
        ]
        cal.update(ms, {m.source: cal.sigma(m) for m in ms}, 1.0, None, 1_000_000_000 + i * 33_333_333)
    assert cal.slow("sure") is None and cal.slow("unsure") is None
    assert cal.slow("sure", confident=False) == pytest.approx(4.0, rel=0.2)
    assert cal.slow("unsure", confident=False) == pytest.approx(4.0, rel=0.2)


def test_a_smooth_biased_cue_keeps_its_floor_where_an_unbiased_one_goes_below():
    # issue 23, skeleton-best-960: a confident depth blob with little white noise but 1.2 px of slow error had its
    # floor lowered by its white noise alone (the calibration before, which fails here) and pulled the fused track
    # off. Here a cue with 0.05 px white noise 1.4 px off (B = 1 px^2 per axis): its slow error, seen against two
    # unbiased 2 px cues, keeps it at the floor
    from fusion_pf.filter.calibration import SLOW_FACTOR, SLOW_FLOOR

    cal = NoiseCalibration(lambda m: 4.0)
    gen = np.random.default_rng(1)
    cues = {"biased": (0.05, (1.0, 1.0)), "sharp": (0.05, (0.0, 0.0)), "b": (2.0, (0, 0)), "c": (2.0, (0, 0))}
    frames = _biased_frames(200, cues)
    palm = _smooth_track(200)
    for i, ms in enumerate(frames):
        pred = (*(palm[i] + gen.normal(0.0, 1.0, 2)), 9.0)
        cal.update(ms, {m.source: cal.sigma(m) for m in ms}, 1.0, pred, 1_000_000_000 + i * 33_333_333)
    assert 0.5 < cal.slow("biased") < 1.5
    assert 0.0 <= cal.slow("sharp") < 0.35
    w = WINDOW / (PRIOR_COUNT + WINDOW)
    shrunk = 4.0 ** (1 - w)
    assert SLOW_FACTOR * math.sqrt(0.5) > FLOOR  # the biased cue's white + slow error, with the estimate's slack
    assert cal.sigma(Measurement("biased", 0, 0, quality=0.9)) == pytest.approx(shrunk * FLOOR**w)
    low = max(SLOW_FACTOR * math.sqrt(cal.white("sharp", 0.9) + cal.slow("sharp")), SLOW_FLOOR * FLOOR)
    assert low < FLOOR
    assert cal.sigma(Measurement("sharp", 0, 0, quality=0.9)) == pytest.approx(shrunk * low**w)


def test_a_bin_without_residuals_is_no_noisier_than_the_bin_below_once_that_one_is_known():
    # issue 23, far-hand-sharp-960: a 0.2 px cue learned one quality bin lower was fused at its 1 / q
    # prior (15x) in the frames its quality crossed into a bin without residuals
    def prior(m):
        return starting_sigma(5.0, m)

    def fed(frames, quality=0.6):
        cal = NoiseCalibration(prior)
        gen = np.random.default_rng(2)
        for _ in range(frames):
            palm = gen.uniform(50, 250, 2)
            ms = [Measurement(s, *(palm + gen.normal(0, sd, 2)), quality=quality) for s, sd in (("a", 1.0), ("b", 2.0))]
            cal.update(ms, {m.source: cal.sigma(m) for m in ms})
        return cal

    up = Measurement("a", 0.0, 0.0, quality=0.8)
    known = fed(BORROW_MIN)
    assert known.samples("a", 0.8) == 0 and known.samples("a", 0.6) == BORROW_MIN
    below = known.sigma(Measurement("a", 0.0, 0.0, quality=0.6))
    assert below < 0.5 * prior(up)  # learned well below the prior
    assert known.sigma(up) <= below  # the empty bin starts from the bin below
    # fewer residuals below are no evidence: the empty bin keeps its prior
    early = fed(BORROW_MIN - 1)
    assert early.sigma(up) == pytest.approx(prior(up))
    # a less confident bin borrows nothing from a more confident one
    assert known.sigma(Measurement("a", 0.0, 0.0, quality=0.3)) == pytest.approx(prior(Measurement("a", 0, 0, 0.3)))
    # nor from a bin below SELF_QUALITY (the biased low-quality blobs of the lit scenes)
    low = fed(2 * BORROW_MIN, quality=0.4)
    mid = Measurement("a", 0.0, 0.0, quality=0.6)
    assert low.sigma(Measurement("a", 0.0, 0.0, quality=0.4)) < 0.5 * prior(mid)
    assert low.sigma(mid) == pytest.approx(prior(mid))


def _prior5(m: Measurement) -> float:
    return starting_sigma(5.0, m)


def _feed(cal: NoiseCalibration, gen: np.random.Generator, frames: int, quality: float, sd: float) -> None:
    """``frames`` frames of cue "a" at ``quality`` with per-axis noise ``sd`` (px) beside a 2 px cue "b" of quality 0.9."""
    for _ in range(frames):
        palm = gen.uniform(50, 250, 2)
        ms = [Measurement("a", *(palm + gen.normal(0, sd, 2)), quality=quality)]
        ms.append(Measurement("b", *(palm + gen.normal(0, 2.0, 2)), quality=0.9))
        cal.update(ms, {m.source: cal.sigma(m) for m in ms})


def test_a_start_at_a_less_confident_cue_without_its_own_evidence_spreads_by_the_bin_above_widened_by_its_prior():
    # issue 23, gen-31987-far-640 (main b7cd802): the warm-start replay restarted at a 0.2 px depth cue whose
    # quality (0.45) was in a bin with one residual, above it a bin that had learned the cue to 1.5 px: spread
    # by its 14 px prior, the particles let a skeleton and a colour blob 35-52 px off pull the first estimate
    # 10 px (84 % of the scene's squared error, fused 0.92 px against depth's 0.34). Until the bin holds
    # PRIOR_COUNT residuals (the prior outweighs them), a start spreads by the next higher confident bin's
    # noise times the prior's ratio of the two qualities; the noise it is fused with stays its own
    prior = _prior5
    cal = NoiseCalibration(prior)
    gen = np.random.default_rng(2)
    _feed(cal, gen, BORROW_MIN, 0.6, 1.0)
    low, edge = Measurement("a", 0.0, 0.0, quality=0.3), Measurement("a", 0.0, 0.0, quality=0.5)
    assert cal.samples("a", 0.3) == 0 and cal.samples("a", 0.5) == BORROW_MIN
    borrowed = cal.sigma(edge) * prior(low) / prior(edge)
    assert borrowed < 0.5 * prior(low)
    assert cal.start_sigma(low, 2.0) == pytest.approx(2.0 * borrowed)
    assert cal.sigma(low) == pytest.approx(prior(low))  # fused with its own noise: the prior
    assert cal.start_sigma(edge) == cal.sigma(edge)  # a bin with its own evidence starts from it
    # once the bin's own evidence outweighs the prior it decides: a 10 px cue
    _feed(cal, gen, PRIOR_COUNT, 0.3, 10.0)
    assert cal.samples("a", 0.3) == PRIOR_COUNT
    assert cal.start_sigma(low) == cal.sigma(low) > 2.5 * borrowed


def test_a_sharp_cue_straddling_two_quality_bins_is_trusted_after_the_replay_frames():
    # issue 23, gen-31351-far-1280 (main 69f87d7): a 0.25 px depth cue (0.06 px at palm scale 1) whose quality
    # straddled 0.75 had, after the warm-start replay's 25 frames, 8 and 16 residuals and too few differences in
    # its bin to measure its white noise: fused at 5.5-6.9 px beside a 5.7 px skeleton, which anchored the track
    # 16 px off. Here: 25 frames of a 0.05 px cue of quality 0.8, 0.7 every fifth frame (most windows of
    # SELF_ORDER + 1 frames fall in the lower bin), beside two 2 px cues, against a prediction 1 px off. The
    # differences of both confident bins measure its white noise; as its own white and slow error lie below the
    # lowest floor they count as evidence too, so both bins trust it near that floor
    from fusion_pf.filter.calibration import SELF_MIN, SLOW_FLOOR

    cal = NoiseCalibration(lambda m: 4.0 / m.quality)
    gen = np.random.default_rng(3)
    palm = _smooth_track(25)
    for i in range(25):
        q = 0.7 if i % 5 == 0 else 0.8
        ms = [Measurement("sharp", *(palm[i] + gen.normal(0, 0.05, 2)), quality=q)]
        ms += [Measurement(s, *(palm[i] + gen.normal(0, 2.0, 2)), quality=0.9) for s in ("b", "c")]
        pred = (*(palm[i] + gen.normal(0.0, 1.0, 2)), 9.0)
        cal.update(ms, {m.source: cal.sigma(m) for m in ms}, 1.0, pred, 1_000_000_000 + i * 33_333_333)
    high, low = Measurement("sharp", 0, 0, quality=0.8), Measurement("sharp", 0, 0, quality=0.7)
    assert len(cal._diffs[("sharp", 3)]) < SELF_MIN <= len(cal._diffs[("sharp", 2)])
    assert math.sqrt(cal.white("sharp", 0.8)) == pytest.approx(0.05, rel=0.3)
    for m in (high, low):
        assert cal.sigma(m) < 2.0 * SLOW_FLOOR * FLOOR
    # the 2 px cues keep what they learned (their own noise is above the floor)
    b = Measurement("b", 0, 0, quality=0.9)
    assert cal.sigma(b) > FLOOR


def test_a_cue_below_its_floor_by_itself_outweighs_a_few_residuals_against_a_poor_prediction():
    # issue 23, held-out gen-31459-far-1280 (main 69f87d7 and the pooled white noise alone): 3 residuals of a new
    # quality bin, against the replay's unsettled first predictions, fitted a 0.04 px (white) depth cue 1.15 px at
    # palm scale 1; fused at 13.7 px in the image, it lost the anchor to a 7 px skeleton (fused 3.3 px off). Here
    # a 0.05 px cue against a prediction 1 px off that states 0.1 px: its residuals alone fit about 1.1 px, its
    # differences (its own white and slow error, below the lowest floor) pull its noise below the floor; the 1 px
    # cues, whose own noise is above the floor, are learned from their residuals alone as before
    from fusion_pf.filter.calibration import SLOW_FLOOR

    def run(timestamps: bool) -> NoiseCalibration:
        cal = NoiseCalibration(lambda m: 4.0)
        gen = np.random.default_rng(4)
        palm = _smooth_track(30)
        for i in range(30):
            ms = [Measurement("sharp", *(palm[i] + gen.normal(0, 0.05, 2)), quality=0.9)]
            ms += [Measurement(s, *(palm[i] + gen.normal(0, 1.0, 2)), quality=0.9) for s in ("b", "c")]
            pred = (*(palm[i] + gen.normal(0.0, 1.0, 2)), 0.01)
            t = 1_000_000_000 + i * 33_333_333 if timestamps else None
            cal.update(ms, {m.source: cal.sigma(m) for m in ms}, 1.0, pred, t)
        return cal

    new, old = run(True), run(False)
    sharp, b = Measurement("sharp", 0, 0, quality=0.9), Measurement("b", 0, 0, quality=0.9)
    assert old.sigma(sharp) > 1.0 > FLOOR  # the residuals' fit, shrunk towards the 4 px prior
    assert new.sigma(sharp) < FLOOR  # its differences pull it below the floor
    assert new.sigma(sharp) >= SLOW_FLOOR * FLOOR  # not below the lowest floor either
    assert new.sigma(b) == pytest.approx(old.sigma(b))


def test_the_noise_is_continuous_across_a_bin_boundary_between_two_learned_bins():
    # far tune scene gen-40141-far-480: a depth cue learned at 0.31 px in quality 0.5-0.75 and 1.26 px in 0.25-0.5
    # was fused at 1.26 px at quality 0.41-0.49, and a 0.83 px skeleton 1.4-3.4 px off took the track
    cal = NoiseCalibration(_prior5)
    gen = np.random.default_rng(3)
    _feed(cal, gen, BORROW_MIN, 0.4, 8.0)
    _feed(cal, gen, BORROW_MIN, 0.6, 1.0)

    def at(q):
        return cal.sigma(Measurement("a", 0.0, 0.0, quality=q))

    def own(q):
        return cal.bin_sigma(Measurement("a", 0.0, 0.0, quality=q))

    # each bin's own noise, learned apart: the less confident one noisier
    assert own(0.4) > 2.0 * own(0.6)
    # at a bin's centre its own noise; below the boundary half way (in log) to the bin above
    assert at(0.375) == pytest.approx(own(0.375))
    assert at(0.625) == pytest.approx(own(0.625))
    below = math.nextafter(0.5, 0.0)
    assert at(below) == pytest.approx(math.sqrt(own(below) * own(0.5)), rel=1e-6)
    # log-linear in between: a quarter of the way from the centre, a quarter of the log ratio
    assert math.log(at(0.4375)) == pytest.approx(0.75 * math.log(own(0.4375)) + 0.25 * math.log(own(0.5)), rel=1e-6)
    # monotone from one centre to the other
    qs = np.linspace(0.375, 0.625, 26)
    assert all(a >= b for a, b in zip([at(q) for q in qs], [at(q) for q in qs[1:]]))
    # a bin below SELF_QUALITY lends to no other (the biased low-quality blobs): above the boundary the bin's own
    assert at(0.5) == pytest.approx(own(0.5))
    assert at(0.55) == pytest.approx(own(0.55))
