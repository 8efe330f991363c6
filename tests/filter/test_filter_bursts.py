"""The burst model (fusion_pf/filter/bursts.py): its maths against an independent computation, and the gate in the pipeline."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import multivariate_normal

from fusion_pf.filter.bursts import (
    MIN_WEIGHT,
    BurstFilter,
    burst_posterior,
    expected_transitions,
    log_ratio,
    predict_burst,
)
from fusion_pf.frame import Intrinsics, Measurement
from fusion_pf.pipeline import TrackConfig
from fusion_pf.pipeline.run import CueRow, _FilterStage


@pytest.mark.parametrize(("d2", "var", "burst_var"), [(0.0, 1.0, 350.0), (25.0, 2.0, 350.0), (900.0, 4.0, 100.0)])
def test_log_ratio_is_the_log_of_the_two_gaussian_densities(d2, var, burst_var):
    d = np.array([math.sqrt(d2), 0.0])
    wide = multivariate_normal(mean=[0.0, 0.0], cov=(var + burst_var) * np.eye(2)).logpdf(d)
    good = multivariate_normal(mean=[0.0, 0.0], cov=var * np.eye(2)).logpdf(d)
    assert log_ratio(d2, var, burst_var) == pytest.approx(wide - good, rel=1e-12, abs=1e-12)


def test_forward_recursion_matches_enumerating_the_state_paths():
    # every path of a 3-frame chain enumerated: P(s_3 = burst | z_1..z_3) and the last two-slice posterior
    start, end = 0.07, 0.25
    a = np.array([[1.0 - start, start], [end, 1.0 - end]])
    p0 = np.array([0.8, 0.2])  # before frame 1
    lrs = [-3.0, 4.0, 1.5]  # log L(burst) / L(good) of frames 1-3
    like = [np.array([1.0, math.exp(lr)]) for lr in lrs]
    joint = np.zeros((2, 2, 2))
    for s1 in range(2):
        for s2 in range(2):
            for s3 in range(2):
                prob = (p0 @ a)[s1] * like[0][s1] * a[s1, s2] * like[1][s2] * a[s2, s3] * like[2][s3]
                joint[s1, s2, s3] = prob
    joint /= joint.sum()
    burst = p0[1]
    for lr in lrs[:-1]:
        burst = burst_posterior(burst, start, end, lr)
    xi = expected_transitions(burst, start, end, lrs[-1])
    assert xi == pytest.approx(joint.sum(axis=0), rel=1e-12)
    assert burst_posterior(burst, start, end, lrs[-1]) == pytest.approx(joint[:, :, 1].sum(), rel=1e-12)
    assert predict_burst(0.3, start, end) == pytest.approx(0.3 * (1 - end) + 0.7 * start)


def test_transitions_are_learned_from_a_markov_chain():
    # a cue that starts a burst with 0.1 and leaves it with 0.3 per frame; bursts 30 px off a prediction
    # with 1 px noise: the learned transitions come close to the chain's (the prior is 0.05 / 0.2)
    rng = np.random.default_rng(5)
    bursts = BurstFilter()
    state = 0
    for _ in range(3000):
        state = int(rng.random() < (0.1 if state == 0 else 0.7))
        off = rng.normal(0.0, 1.0, 2) + (30.0 if state else 0.0)
        ms = [Measurement("depth", float(off[0]), float(off[1])), Measurement("skeleton", 0.0, 0.0)]
        bursts.weights(ms, {"depth": 1.0, "skeleton": 1.0}, (0.0, 0.0, 0.01), 20.0)
    a_gb, a_bg = bursts.transitions("depth")
    assert a_gb == pytest.approx(0.1, abs=0.02)
    assert a_bg == pytest.approx(0.3, abs=0.05)


def _weights(bursts, offsets, prediction=(0.0, 0.0, 0.5)):
    ms = [Measurement(s, u, v) for s, (u, v) in offsets.items()]
    return bursts.weights(ms, dict.fromkeys(offsets, 1.0), prediction, 20.0)


def test_no_weight_below_one_while_cues_agree_with_the_track_or_alone_or_all_off_it():
    bursts = BurstFilter()
    rng = np.random.default_rng(1)
    for _ in range(200):  # three cues within their noise of the prediction
        noise = rng.normal(0.0, 1.0, (3, 2))
        w = _weights(bursts, {s: tuple(n) for s, n in zip(("colour", "depth", "skeleton"), noise)})
        assert w == {"colour": 1.0, "depth": 1.0, "skeleton": 1.0}
    assert _weights(bursts, {"depth": (60.0, 0.0)}) == {"depth": 1.0}  # alone: nothing confirms a burst
    # every cue 40 px off the prediction (the hand moved faster than the motion model): none set aside
    assert _weights(bursts, {"colour": (40.0, 1.0), "depth": (41.0, 0.0), "skeleton": (40.0, -1.0)}) == {
        "colour": 1.0,
        "depth": 1.0,
        "skeleton": 1.0,
    }
    assert bursts.bursts == {}


def test_a_cue_off_the_track_is_set_aside_when_another_confirms_even_against_a_majority():
    bursts = BurstFilter()
    for _ in range(5):
        _weights(bursts, {"colour": (0.5, 0.0), "depth": (0.0, 0.3), "skeleton": (-0.4, 0.0)})
    # colour and the skeleton share a 30 px bias (both on the forearm); depth stays on the track
    w = _weights(bursts, {"colour": (30.0, 0.0), "depth": (0.2, 0.0), "skeleton": (29.0, 1.0)})
    assert w["depth"] == 1.0
    assert w["colour"] == w["skeleton"] == MIN_WEIGHT
    assert bursts.bursts == {"colour": 1, "skeleton": 1}


INTR = Intrinsics(320, 200, 250.0, 250.0, 160.0, 100.0)


def _rows(burst: dict[str, tuple[float, float]], frames=range(40, 50), n=70, seed=3):
    """A palm moving on a slow arc seen by three cues with 0.5-1.5 px noise; in ``frames`` the named cues are offset."""
    rng = np.random.default_rng(seed)
    noise = {"colour": 1.5, "depth": 0.5, "skeleton": 1.5}
    rows, truth = [], []
    for k in range(n):
        u, v = 160.0 + 40.0 * math.sin(k / 25.0), 100.0 + 20.0 * math.cos(k / 30.0)
        cues = {}
        for s, sigma in noise.items():
            du, dv = burst.get(s, (0.0, 0.0)) if k in frames else (0.0, 0.0)
            cues[s] = Measurement(s, u + du + rng.normal(0.0, sigma), v + dv + rng.normal(0.0, sigma), 0.9)
        rows.append(CueRow(k, 1_000_000_000 + k * 33_333_333, False, cues, {}, None, None, (0, 0), INTR))
        truth.append((u, v))
    return rows, np.array(truth)


def _errors(rows, truth, gate: bool) -> tuple[np.ndarray, _FilterStage]:
    stage = _FilterStage(TrackConfig(seed=1, burst_gate=gate), None)
    est = []
    for row in rows:
        e = stage(row).estimate
        est.append((e.u, e.v) if e is not None else (np.nan, np.nan))
    return np.hypot(*(np.array(est) - truth).T), stage


def test_a_cue_60_px_off_for_ten_frames_while_two_agree_is_set_aside():
    # depth, the most precise cue, jumps 60 px for 10 frames (onto the torso) while colour and the skeleton
    # stay on the palm: without the gate the filter restarts at the confident depth cue and follows it
    rows, truth = _rows({"depth": (60.0, 0.0)})
    err, stage = _errors(rows, truth, gate=True)
    assert err[40:50].max() < 4.0
    assert stage.bursts is not None and stage.bursts.bursts == {"depth": 10}
    old, _ = _errors(rows, truth, gate=False)
    assert old[40:50].max() > 30.0


def test_the_gate_does_not_fire_while_cues_agree():
    rows, truth = _rows({})
    err, stage = _errors(rows, truth, gate=True)
    old, _ = _errors(rows, truth, gate=False)
    assert stage.bursts is not None and stage.bursts.bursts == {}
    np.testing.assert_array_equal(err, old)  # the same estimates, bit for bit


def test_a_good_cue_that_agrees_vouches_for_a_cue_off_the_track():
    # colour (1 px noise) 6 px off the prediction is more likely in a burst; depth, the other cue, is good
    def colour_weight(depth, depth_sigma):
        bursts = BurstFilter()
        ms = [Measurement("colour", 6.0, 0.0), Measurement("depth", *depth)]
        w = bursts.weights(ms, {"colour": 1.0, "depth": depth_sigma**2}, (0.0, 0.0, 0.5), 20.0)
        assert bursts.probability("colour") >= 0.5 > bursts.probability("depth")
        return w["colour"]

    assert colour_weight((0.5, 0.0), 1.0) < 0.5  # a precise depth on the track: colour is set aside
    assert colour_weight((4.0, 0.0), 3.0) == 1.0  # a noisier depth that agrees with colour: the track may be off
