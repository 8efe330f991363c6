"""Resamplers: one property suite over every scheme, plus scheme-specific guarantees."""

from __future__ import annotations

import numpy as np
import particles.resampling as pr
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fusion_pf.errors import InputError
from fusion_pf.filter import resample
from fusion_pf.filter.resample import COMPILED_MIN_N, RESAMPLERS, ess

SCHEMES = sorted(RESAMPLERS)

# non-negative weights with at least one clearly positive entry
weights_st = arrays(
    np.float64,
    st.integers(1, 60),
    elements=st.one_of(st.just(0.0), st.floats(1e-6, 1e3)),
).filter(lambda w: w.sum() > 0)


def _counts(idx: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(idx, minlength=n)


@pytest.mark.parametrize("scheme", SCHEMES)
@settings(max_examples=60, deadline=None)
@given(w=weights_st, seed=st.integers(0, 2**32 - 1))
def test_indices_valid_and_counts_sum_to_n(scheme, w, seed):
    idx = RESAMPLERS[scheme](w, seed)
    n = w.shape[0]
    assert idx.shape == (n,) and idx.dtype == np.int64
    assert idx.min() >= 0 and idx.max() < n
    counts = _counts(idx, n)
    assert counts.sum() == n
    # a particle of zero weight is never copied
    assert not counts[w == 0].any()


@pytest.mark.parametrize("scheme", SCHEMES)
@settings(max_examples=40, deadline=None)
@given(n=st.integers(1, 50), data=st.data())
def test_all_weight_on_one_particle_gives_all_copies(scheme, n, data):
    k = data.draw(st.integers(0, n - 1))
    w = np.zeros(n)
    w[k] = data.draw(st.floats(1e-3, 1e3))
    assert np.array_equal(RESAMPLERS[scheme](w, 7), np.full(n, k))


@pytest.mark.parametrize("scheme", SCHEMES)
def test_same_seed_same_indices_and_rng_is_advanced(scheme):
    w = np.random.default_rng(0).random(200)
    a = RESAMPLERS[scheme](w, 42)
    assert np.array_equal(a, RESAMPLERS[scheme](w, 42))
    rng = np.random.default_rng(42)
    first = RESAMPLERS[scheme](w, rng)
    assert np.array_equal(first, a)
    assert not np.array_equal(RESAMPLERS[scheme](w, rng), first)


@pytest.mark.parametrize("scheme", SCHEMES)
def test_mean_counts_approach_n_w(scheme):
    """Unbiasedness: over D draws the mean count of particle i is N w_i within 5 standard errors."""
    w = np.array([0.31, 0.02, 0.0, 0.17, 0.113, 0.25, 0.047, 0.09])
    n, draws = w.size, 4000
    rng = np.random.default_rng(123)
    counts = np.array([_counts(RESAMPLERS[scheme](w, rng), n) for _ in range(draws)])
    expected = n * w
    # multinomial variance N w (1 - w) bounds every scheme's count variance
    se = np.sqrt(n * w * (1 - w) / draws)
    assert np.all(np.abs(counts.mean(axis=0) - expected) <= 5 * se + 1e-12)


@settings(max_examples=80, deadline=None)
@given(w=weights_st, seed=st.integers(0, 2**32 - 1))
def test_residual_keeps_floor_copies(w, seed):
    n = w.size
    floor_nw = np.floor(w * (n / w.sum()))
    counts = _counts(resample.residual(w, seed), n)
    assert np.all(counts >= floor_nw)
    # the R = N - sum floor(N w) residual draws are all that is added
    assert np.all(counts <= floor_nw + (n - floor_nw.sum()))


@settings(max_examples=80, deadline=None)
@given(w=weights_st, seed=st.integers(0, 2**32 - 1))
def test_systematic_counts_are_floor_or_ceil(w, seed):
    nw = w.size * w / w.sum()
    counts = _counts(resample.systematic(w, seed), w.size)
    assert np.all(counts >= np.floor(nw) - 1e-9) and np.all(counts <= np.ceil(nw) + 1e-9)


@settings(max_examples=80, deadline=None)
@given(w=weights_st, seed=st.integers(0, 2**32 - 1))
def test_stratified_counts_within_two_of_expectation(w, seed):
    nw = w.size * w / w.sum()
    counts = _counts(resample.stratified(w, seed), w.size)
    assert np.all(np.abs(counts - nw) < 2.0)


def test_residual_count_variance_matches_binomial_on_residuals():
    """Independent check: count_i = floor(N w_i) + Binomial(R, r_i / R) marginally."""
    w = np.array([0.26, 0.13, 0.05, 0.31, 0.25])
    n, draws = w.size, 6000
    nw = n * w
    r = nw - np.floor(nw)
    big_r = r.sum()
    p = r / big_r
    rng = np.random.default_rng(9)
    counts = np.array([_counts(resample.residual(w, rng), n) for _ in range(draws)])
    assert np.all(counts >= np.floor(nw))
    var = big_r * p * (1 - p)
    assert np.allclose(counts.mean(axis=0), nw, atol=5 * np.sqrt(var / draws).max())
    # sample variance within 15 % of the binomial variance (6000 draws: rel. s.e. ~2 %)
    assert np.allclose(counts.var(axis=0), var, rtol=0.15)
    # plain multinomial would have variances N w (1 - w): in total, more than twice as large
    assert counts.var(axis=0).sum() < 0.5 * (n * w * (1 - w)).sum()


def test_residual_matches_nchopin_particles_in_distribution():
    """Mean counts of ours and of ``particles.resampling.residual`` agree (same target N w)."""
    w = np.array([0.4, 0.05, 0.2, 0.01, 0.14, 0.2])
    n, draws = w.size, 3000
    # particles draws from the global numpy state; seed it so the test is repeatable
    np.random.seed(2024)
    theirs = np.array([_counts(pr.residual(w, n), n) for _ in range(draws)]).mean(axis=0)
    rng = np.random.default_rng(77)
    ours = np.array([_counts(resample.residual(w, rng), n) for _ in range(draws)]).mean(axis=0)
    se = np.sqrt(n * w * (1 - w) / draws)
    assert np.all(np.abs(ours - theirs) <= 5 * np.sqrt(2) * se)


def test_compiled_paths_equal_numpy_paths():
    """Above COMPILED_MIN_N the inverse CDF and residual run compiled; they must agree with numpy exactly."""
    rng = np.random.default_rng(3)
    n = COMPILED_MIN_N + 1000
    w = rng.random(n) ** 6
    w[rng.random(n) < 0.3] = 0.0  # flat CDF stretches (zero-weight particles)
    for scheme in ("multinomial", "residual"):
        idx = RESAMPLERS[scheme](w, 5)
        assert idx.shape == (n,) and not _counts(idx, n)[w == 0].any()
    c = np.cumsum(w)
    u = np.sort(rng.random(50_000)) * c[-1]
    expected = np.searchsorted(c, np.minimum(u, np.nextafter(c[-1], 0.0)), side="right")
    assert np.array_equal(resample._inverse_cdf(c, u.copy()), expected)
    # the compiled residual makes the same draws as the numpy one, index for index
    scale = n / w.sum()
    compiled = resample._residual_compiled(w, scale, np.random.default_rng(8), resample._kernels())
    assert np.array_equal(compiled, resample._residual_numpy(w * scale, np.random.default_rng(8)))


@pytest.mark.parametrize("scheme", SCHEMES + ["ess"])
@pytest.mark.parametrize(
    ("bad", "message"),
    [
        (np.array([0.5, -0.1, 0.6]), ">= 0"),
        (np.array([0.5, np.nan, 0.5]), "finite"),
        (np.array([0.5, np.inf, 0.5]), "finite"),
        (np.zeros(4), "not all be zero"),
        (np.ones((3, 2)), "(N,) array"),
        (np.ones(0), "(N,) array"),
        (np.array(["a", "b"]), "real numbers"),
    ],
)
def test_bad_weights_raise_one_line_value_error(scheme, bad, message):
    func = ess if scheme == "ess" else RESAMPLERS[scheme]
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")) as info:
        func(bad) if scheme == "ess" else func(bad, 0)
    assert isinstance(info.value, ValueError) and "\n" not in str(info.value)


def test_ess_values():
    assert ess(np.full(10, 0.1)) == pytest.approx(10.0)
    assert ess(np.array([0.0, 3.0, 0.0])) == pytest.approx(1.0)
    w = np.array([0.5, 0.25, 0.25])
    # 1 / (0.25 + 0.0625 + 0.0625) = 8 / 3, invariant to scale
    assert ess(w) == pytest.approx(8 / 3) and ess(7 * w) == pytest.approx(8 / 3)
