"""Online noise calibration (fusion_pf/filter/calibration.py): leave-one-out residuals per quality band."""

import math

import numpy as np
import pytest

from fusion_pf.errors import InputError
from fusion_pf.filter.calibration import FLOOR, PRIOR_COUNT, QUALITY_BINS, WINDOW, NoiseCalibration, quality_bin
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
