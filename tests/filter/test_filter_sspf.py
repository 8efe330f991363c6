"""Scatter-search PF (paper 002 §4): convergence, evaluation count, fewer evaluations than a PF."""

import math

import numpy as np
import pytest

from fusion_pf.cues.base import Measurement
from fusion_pf.errors import InputError
from fusion_pf.filter.pf import ParticleFilter
from fusion_pf.filter.sspf import ScatterSearchPF, diverse_subset

T = 200
#: The filters model the cue as it is simulated: sigma 6 px.
CUE_NOISE = {"colour": 6.0}
FRAME_NS = 33_333_333


def scripted(seed=1):
    """A fast manoeuvring palm (up to ~24 px / frame) and its colour cue (sigma 6 px)."""
    t = np.arange(T)
    truth = np.stack([320 + 150 * np.sin(2 * np.pi * t / 40), 200 + 80 * np.sin(2 * np.pi * t / 27)], 1)
    return truth, truth + np.random.default_rng(seed).normal(0.0, 6.0, (T, 2))


def track(f, z, truth):
    est, evals = [], []
    for k in range(T):
        e = f.step(k * FRAME_NS, [Measurement("colour", *z[k])])
        est.append((e.u, e.v))
        # a ParticleFilter weighs its N particles once per frame (no re-initialisation here)
        evals.append(getattr(f, "evaluations", f.n_particles))
    err = np.hypot(*(np.array(est) - truth).T)[5:]
    return float(np.sqrt((err**2).mean())), float(np.mean(evals))


def test_sspf_converges_on_a_scripted_trajectory():
    truth, z = scripted()
    f = ScatterSearchPF(noise_px=CUE_NOISE, n_particles=30, process_noise=(3.0, 1.0), rng=0)
    r, evals = track(f, z, truth)
    # about the cue's own error (6 sqrt(2) = 8.5 px) or better
    assert r < 9.0
    assert f.total_evaluations == pytest.approx(evals * T)
    # time-adaptive: more than N evaluations per frame, varying
    assert 30 < evals < 1000
    # a PF with the same model loses this target
    r_pf, _ = track(ParticleFilter(noise_px=CUE_NOISE, n_particles=1000, process_noise=(3.0, 1.0), rng=0), z, truth)
    assert r_pf > 5 * r


def test_sspf_needs_fewer_evaluations_than_a_pf_for_the_same_rmse():
    truth, z = scripted()
    model = {"process_noise": (8.0, 3.0), "noise_px": {"colour": 6.0}}
    r_ss, e_ss = track(ScatterSearchPF(n_particles=20, rng=0, **model), z, truth)
    needed = None
    for n in (50, 100, 200, 400, 800, 1600):
        r_pf, e_pf = track(ParticleFilter(n_particles=n, rng=0, **model), z, truth)
        if r_pf <= 1.1 * r_ss:
            needed = e_pf
            break
    assert needed is not None and needed > 2 * e_ss


def test_diverse_subset_is_max_min():
    pts = np.array([[0.0, 0.0], [1.0, 0.0], [10.0, 0.0], [5.0, 0.0], [9.0, 0.0]])
    # from {0}: the farthest is 10, then the point farthest from both (5)
    assert diverse_subset(pts, np.array([0]), 2).tolist() == [2, 3]


def test_no_measurement_predicts_and_bad_parameters():
    f = ScatterSearchPF(noise_px=CUE_NOISE, n_particles=10, prior=(5.0, 5.0), rng=0)
    e = f.step(0, [])
    assert f.evaluations == 0 and math.hypot(e.u - 5.0, e.v - 5.0) < 20
    assert ScatterSearchPF(noise_px=CUE_NOISE, n_particles=10, rng=0).step(0, []) is None
    for kwargs, match in (
        ({"n_particles": 1}, "n_particles"),
        ({"refset_size": 3}, "refset_size"),
        ({"refset_size": 12, "n_particles": 10}, "refset_size"),
        ({"min_step_px": 5.0, "step_px": 1.0}, "min_step_px"),
        ({"max_rounds": 0}, "max_rounds"),
    ):
        with pytest.raises(InputError, match=match):
            ScatterSearchPF(**kwargs)


def test_reset_with_prior_follows_the_tracker_contract():
    f = ScatterSearchPF(noise_px=CUE_NOISE, n_particles=10, init_spread_px=1.0, rng=0)
    with pytest.raises(RuntimeError, match="before it is initialised"):
        _ = f.particles
    f.reset(prior=(50.0, 60.0))
    assert f.initialised
    np.testing.assert_allclose(f.particles[:, :2].mean(axis=0), (50.0, 60.0), atol=2.0)
    e = f.step(0, [])
    assert math.hypot(e.u - 50.0, e.v - 60.0) < 5
    # a plain reset forgets it: the next measurement starts the filter
    f.reset()
    assert not f.initialised and f.step(1, []) is None
