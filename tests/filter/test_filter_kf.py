"""The Kalman baseline against filterpy and a hand-worked case."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterpyKF

from fusion_pf.cues.base import Measurement
from fusion_pf.errors import InputError
from fusion_pf.filter import KalmanFilter, ParticleFilter
from fusion_pf.filter.scenario import SCENARIO_NOISE_PX, rmse, run_tracker, scripted_scenario

NOISE = {"colour": 6.0, "depth": 10.0, "skeleton": 15.0}


def test_matches_filterpy_to_1e9_with_sequential_updates_and_dropouts():
    sc = scripted_scenario(150, noise_px=NOISE, dropout=0.35, rng=4)
    ours = KalmanFilter(process_noise=(2.5, 0.7), noise_px=NOISE, init_spread_px=15.0, init_velocity_px=3.0)
    ref = None
    for k, ts in enumerate(sc.timestamps_ns):
        ms = sc.frame(k)
        est = ours.step(int(ts), ms)
        if ref is None:
            if not ms:
                assert est is None
                continue
            prec = np.array([1 / NOISE[m.source] ** 2 for m in ms])
            ref = FilterpyKF(dim_x=4, dim_z=2)
            ref.x = np.r_[prec @ np.array([[m.u, m.v] for m in ms]) / prec.sum(), 0.0, 0.0]
            ref.P = np.diag([225.0, 225.0, 9.0, 9.0])
            ref.F = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
            ref.Q = np.diag([2.5**2, 2.5**2, 0.7**2, 0.7**2])
            ref.H = np.array([[1, 0, 0, 0], [0, 1, 0, 0]], dtype=float)
        else:
            ref.predict()
        for m in ms:
            ref.update(np.array([m.u, m.v]), R=NOISE[m.source] ** 2 * np.eye(2))
        np.testing.assert_allclose([est.u, est.v], ref.x[:2], rtol=0, atol=1e-9)
        np.testing.assert_allclose(ours.P, ref.P, rtol=0, atol=1e-9)
        np.testing.assert_allclose(est.cov, ref.P[:2, :2], rtol=0, atol=1e-9)
        assert math.isnan(est.ess) and est.n_particles == 0 and est.particles is None and not est.resampled


def test_hand_worked_two_steps():
    kf = KalmanFilter(
        process_noise=(3.0, 1.0),
        noise_px={"colour": 6.0},
        prior=(0, 0, 0, 0),
        init_spread_px=10.0,
        init_velocity_px=2.0,
    )
    est = kf.step(0, [Measurement("colour", 6.0, 0.0)])
    # K = 100 / (100 + 36): u = 6 K, P_uu = 100 * 36 / 136
    assert est.u == pytest.approx(600 / 136, abs=1e-12) and est.v == 0.0
    assert est.cov[0, 0] == pytest.approx(3600 / 136, abs=1e-12)
    est = kf.step(1, [])
    # predict: u' = u + du (du = 0), P_uu' = P_uu + P_dudu + q_pos = 3600/136 + 4 + 9
    assert est.u == pytest.approx(600 / 136, abs=1e-12)
    assert est.cov[0, 0] == pytest.approx(3600 / 136 + 4 + 9, abs=1e-12)


def test_kf_is_the_accuracy_reference_the_pf_approaches():
    """Same Gaussian model: a large-N weighted-mean PF lands within 20 % of the optimal KF."""
    sc = scripted_scenario(200, rng=12)
    kf = rmse(run_tracker(KalmanFilter(noise_px=SCENARIO_NOISE_PX), sc), sc.truth, slice(10, None))
    pf = rmse(
        run_tracker(ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=3000, estimator="weighted_mean", rng=0), sc),
        sc.truth,
        slice(10, None),
    )
    assert kf < rmse(sc.measurements["colour"], sc.truth) and pf < 1.2 * kf, (kf, pf)


def test_bad_input():
    with pytest.raises(InputError, match="process_noise"):
        KalmanFilter(noise_px=SCENARIO_NOISE_PX, process_noise=(1.0,))
    kf = KalmanFilter(noise_px=SCENARIO_NOISE_PX)
    with pytest.raises(InputError, match="known sources"):
        kf.step(0, [Measurement("lidar", 1.0, 2.0)])
    kf.step(5, [Measurement("colour", 1.0, 2.0)])
    with pytest.raises(InputError, match="must increase"):
        kf.step(5, [])


def test_auto_frame_period_bridges_dropped_frames_in_whole_steps():
    from fusion_pf.filter.motion import FrameClock

    clock = FrameClock("auto")
    period = 33_333_333
    times = [0, period, 2 * period + 400_000, 5 * period, 6 * period - 300_000]
    steps = [clock.steps(t, last) for last, t in zip([None, *times], times)]
    assert steps == [1.0, 1.0, 1.0, 3.0, 1.0]
    with pytest.raises(InputError, match="frame_period_ns must be a number > 0, 'auto' or None, got 'fast'"):
        FrameClock("fast")
    # a Kalman filter that learns the period predicts across a gap like one told the period
    ms = [Measurement("colour", 10.0 + 3 * k, 20.0 - k) for k in range(4)]
    stamps = [0, period, 2 * period, 5 * period]
    told = KalmanFilter(noise_px=SCENARIO_NOISE_PX, frame_period_ns=period)
    learnt = KalmanFilter(noise_px=SCENARIO_NOISE_PX, frame_period_ns="auto")
    for t, m in zip(stamps, ms):
        told.step(t, [m])
        learnt.step(t, [m])
    np.testing.assert_allclose(learnt.x, told.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(learnt.P, told.P, rtol=0, atol=1e-9)
    paper = KalmanFilter(noise_px=SCENARIO_NOISE_PX)
    for t, m in zip(stamps, ms):
        paper.step(t, [m])
    assert not np.allclose(paper.P, told.P)
