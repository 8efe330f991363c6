"""The compiled step kernels against the numpy functions they replace (an independent computation)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_pf.filter.estimate import map_estimate, robust_mean, weighted_covariance, weighted_mean
from fusion_pf.filter.kernel import ESTIMATOR_CODES, kernels
from fusion_pf.filter.likelihood import JointLikelihood
from fusion_pf.filter.motion import predict
from fusion_pf.filter.pf import ParticleFilter
from fusion_pf.filter.resample import residual, residual_trusted, systematic
from fusion_pf.frame import Measurement

MS = [
    Measurement("colour", 310.0, 190.0, 0.8),
    Measurement("depth", 300.0, 205.0, 0.3),
    Measurement("hand", 305.0, 200.0, 0.95),
]


def _cloud(n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x = rng.normal(0.0, 1.0, (4, n))
    x[:2] = x[:2] * 15.0 + np.array([[305.0], [198.0]])
    return x


@pytest.mark.parametrize("bit_generator", [np.random.PCG64, np.random.SFC64])
def test_predict_matches_eq4(bit_generator):
    x = _cloud(257)
    ref = x.copy()
    std = np.array([3.0, 3.0, 1.0, 1.0])
    theirs, ours = np.random.Generator(bit_generator(5)), np.random.Generator(bit_generator(5))
    predict(ref, std, theirs, dt=2.0)
    given = x.copy()
    kernels().predict(given, np.random.Generator(bit_generator(5)).standard_normal((4, 257)), std, 2.0, 0, 4)
    np.testing.assert_allclose(given, ref, rtol=0, atol=1e-12)
    kernels().predict_drawn(x, ours, np.empty((4, 257)), std, 2.0, 0, 4)
    np.testing.assert_allclose(x, ref, rtol=0, atol=1e-12)
    # the kernel drew exactly numpy's normals from the given generator: both streams are at the same point
    assert ours.random() == theirs.random()


def test_predict_drawn_velocity_rows_only_draw_2n_normals():
    x = _cloud(100)
    std = np.array([0.0, 0.0, 1.0, 2.0])
    rng, ref_rng = np.random.default_rng(3), np.random.default_rng(3)
    expected = x.copy()
    expected[:2] += 1.0 * x[2:]
    expected[2:] += ref_rng.standard_normal((2, 100)) * std[2:, None]
    kernels().predict_drawn(x, rng, np.empty((4, 100)), std, 1.0, 2, 4)
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-12)
    assert rng.random() == ref_rng.random()


@pytest.mark.parametrize("n", [999, 1000])
def test_steps_are_the_same_whichever_side_draws_the_normals(n, monkeypatch):
    import fusion_pf.filter.pf as pf_module

    ms = [Measurement("colour", 100.0, 100.0), Measurement("depth", 103.0, 98.0)]
    runs = []
    for threshold in (1, 10**9):
        monkeypatch.setattr(pf_module, "DRAW_IN_KERNEL_N", threshold)
        pf = ParticleFilter(n_particles=n, resampler="systematic", rng=11)
        runs.append(
            [(e.u, e.v, e.ess) for e in (pf.step(k * 33_333_333, ms) for k in range(5))] + [pf.particles.tobytes()]
        )
    assert runs[0] == runs[1]


@pytest.mark.parametrize("likelihood", ["gaussian", "robust"])
def test_likelihoods_match_numpy(likelihood):
    x = _cloud(500)
    like = JointLikelihood({"colour": 12.0, "depth": 4.0, "hand": 0.7}, likelihood=likelihood)
    ref, lost = like(np.ascontiguousarray(x[:2].T), MS, np.empty(500))
    joint = np.empty(500)
    if likelihood == "gaussian":
        zu, zv, total, c = like.stacked(MS)
        peak = kernels().gaussian(x, zu, zv, -0.5 * total, joint)
        assert (peak - c < np.log(np.finfo(float).tiny)) == lost
    else:
        assert kernels().robust(x, like.mixture_rows(MS), joint) == (not lost)
    np.testing.assert_allclose(joint, ref, rtol=1e-12, atol=1e-9)
    assert joint.max() == 0.0 or likelihood == "robust"


@pytest.mark.parametrize("estimator", sorted(ESTIMATOR_CODES))
def test_weigh_matches_numpy_estimates(estimator):
    n = 400
    x = _cloud(n, 1)
    rng = np.random.default_rng(2)
    logw0 = rng.normal(-np.log(n), 0.5, n)
    joint = -rng.exponential(3.0, n)
    logw, w = logw0.copy(), np.empty(n)
    top_k = 40
    u, v, cuu, cuv, cvv, ess = kernels().weigh(logw, joint, 1, w, x, x[:2], ESTIMATOR_CODES[estimator], top_k)
    ref_w = np.exp(logw0 + joint - (logw0 + joint).max())
    ref_w /= ref_w.sum()
    np.testing.assert_allclose(w, ref_w, rtol=1e-12)
    np.testing.assert_allclose(np.exp(logw), ref_w, rtol=1e-12)
    pos = np.ascontiguousarray(x[:2].T)
    est = {"weighted_mean": weighted_mean, "robust_mean": robust_mean, "map": map_estimate}[estimator]
    np.testing.assert_allclose((u, v), est(pos, ref_w, top_k / n), rtol=1e-12)
    np.testing.assert_allclose([[cuu, cuv], [cuv, cvv]], weighted_covariance(pos, ref_w), rtol=1e-10)
    assert ess == pytest.approx(1.0 / np.sum(ref_w**2), rel=1e-12)
    # mode 0 leaves the weights alone
    before = w.copy()
    kernels().weigh(logw, joint, 0, w, x, x[:2], 0, top_k)
    assert np.array_equal(w, before)


@pytest.mark.parametrize("n", [1, 7, 100, 3000])
def test_systematic_and_residual_match_the_numpy_resamplers(n):
    w = np.random.default_rng(n).exponential(1.0, n) ** 3
    w[: n // 3] = 0.0 if n > 2 else w[: n // 3]
    w /= w.sum()
    x = _cloud(n)
    out, cdf = np.empty_like(x), np.empty(n)
    # trailing zero weights: rounding must never hand them a copy
    for weights in (w, np.where(np.arange(n) < n - n // 2, w, 0.0) if n > 2 else w):
        weights = weights / weights.sum()
        kernels().systematic(weights, np.random.default_rng(9).random(), x, out, cdf)
        assert np.array_equal(out, x[:, systematic(weights, np.random.default_rng(9))])
    assert np.array_equal(residual_trusted(w, np.random.default_rng(4)), residual(w, np.random.default_rng(4)))


def test_default_estimator_is_the_weighted_mean_and_steps_are_repeatable():
    pf = ParticleFilter(n_particles=300, rng=3)
    assert pf.estimator == "weighted_mean"
    runs = []
    for _ in range(2):
        pf = ParticleFilter(n_particles=300, likelihood="robust", resampler="systematic", rng=3)
        runs.append([pf.step(k, MS if k % 3 else MS[:1]) for k in range(20)])
    a, b = ([(e.u, e.v, e.ess, *e.cov.ravel(), *e.particles.ravel()) for e in r] for r in runs)
    assert np.array_equal(np.array(a), np.array(b))
