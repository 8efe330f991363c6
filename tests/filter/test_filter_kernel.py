"""The compiled step kernels against the numpy functions they replace (an independent computation)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from fusion_pf.filter.estimate import map_estimate, robust_mean, weighted_covariance, weighted_mean
from fusion_pf.filter.kernel import ESTIMATOR_CODES, kernels, stream
from fusion_pf.filter.likelihood import JointLikelihood
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


def test_normals_are_numpys_float32_ziggurat_on_the_streams_sfc64(stream_normals):
    state = stream(np.random.default_rng(4))
    first = state.copy()
    out = np.empty(300_001, dtype=np.float32)
    # odd chunks: a word's high half is left over between calls, as numpy keeps it
    for lo, hi in ((0, 1), (1, 1000), (1000, 1001), (1001, 300_001)):
        kernels().normals(state, out[lo:hi])
    np.testing.assert_array_equal(out, stream_normals(first, out.shape))
    # the ziggurat's rare branches ran: the tail beyond r = 3.654 (~80 of 3e5 draws)
    assert np.count_nonzero(np.abs(out) > 3.6541529) > 20
    # and the state moved on exactly as numpy's
    np.testing.assert_array_equal(stream_normals(state, (5,)), stream_normals(first, (300_006,))[-5:])


def test_normals_are_standard_normal():
    """Moments and Kolmogorov-Smirnov against scipy's normal (independent of numpy's ziggurat)."""
    out = np.empty(200_000, dtype=np.float32)
    kernels().normals(stream(np.random.default_rng(1)), out)
    z = out.astype(np.float64)
    assert abs(z.mean()) < 5 * np.sqrt(1 / z.size)
    assert abs(z.var() - 1.0) < 5 * np.sqrt(2 / z.size)
    assert abs(scipy.stats.skew(z)) < 5 * np.sqrt(6 / z.size)
    assert abs(scipy.stats.kurtosis(z)) < 5 * np.sqrt(24 / z.size)
    assert scipy.stats.kstest(z, "norm").pvalue > 1e-3
    # same generator seed, same stream; another seed, an uncorrelated one
    other = np.empty(200_000, dtype=np.float32)
    kernels().normals(stream(np.random.default_rng(1)), other)
    assert np.array_equal(out, other)
    kernels().normals(stream(np.random.default_rng(2)), other)
    assert abs(np.corrcoef(z, other)[0, 1]) < 5 / np.sqrt(z.size)


@pytest.mark.parametrize(("lo", "hi"), [(0, 4), (2, 4), (0, 2), (2, 2)])
def test_move_is_eq4_then_the_stacked_gaussian_likelihood(lo, hi, stream_normals):
    n = 257
    x = _cloud(n)
    std = np.array([3.0, 3.0, 1.0, 2.0])
    state = stream(np.random.default_rng(5))
    first = state.copy()
    expected = x.copy()
    expected[:2] += 2.0 * x[2:]
    expected[lo:hi] += stream_normals(state, (hi - lo, n)).astype(np.float64) * std[lo:hi, None]
    like = JointLikelihood({"colour": 12.0, "depth": 4.0, "hand": 0.7})
    zu, zv, total, _ = like.stacked(MS)
    joint = np.empty(n)
    peak = kernels().move(x, state, np.empty((4, n), np.float32), std, 2.0, lo, hi, zu, zv, -0.5 * total, joint)
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-12)
    ref, _ = like(np.ascontiguousarray(expected[:2].T), MS, np.empty(n))
    # unnormalised: step 3's normalisation is left to the weights' (eq. 2)
    np.testing.assert_allclose(joint - peak, ref, rtol=1e-12, atol=1e-9)
    assert peak == joint.max()
    # the stream moved past exactly the normals drawn
    np.testing.assert_array_equal(stream_normals(state, (3,)), stream_normals(first, ((hi - lo) * n + 3,))[-3:])


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
    peak = kernels().shift(logw, joint, True, w)
    np.exp(w, out=w)
    u, v, cuu, cuv, cvv, ess = kernels().weigh(logw, w, peak, True, x, x[:2], ESTIMATOR_CODES[estimator], top_k)
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
    kernels().weigh(logw, w, 0.0, False, x, x[:2], 0, top_k)
    assert np.array_equal(w, before)


@pytest.mark.parametrize("n", [1, 7, 100, 3000])
def test_systematic_and_residual_match_the_numpy_resamplers(n):
    w = np.random.default_rng(n).exponential(1.0, n) ** 3
    w[: n // 3] = 0.0 if n > 2 else w[: n // 3]
    w /= w.sum()
    x = _cloud(n)
    out, cdf, idx = np.empty_like(x), np.empty(n), np.empty(n, np.int64)
    # trailing zero weights: rounding must never hand them a copy
    for weights in (w, np.where(np.arange(n) < n - n // 2, w, 0.0) if n > 2 else w):
        weights = weights / weights.sum()
        kernels().systematic(weights, np.random.default_rng(9).random(), x, out, cdf, idx)
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
