"""Resampling schemes and the effective sample size (paper 003 §3.3, resampling phase).

Every resampler is a pure function ``f(weights, rng) -> indices``: it takes the
``(N,)`` particle weights (non-negative, finite, not all zero; they are rescaled
to sum to one) and a random generator, and returns ``(N,)`` int64 indices of the
particles to copy. Nothing else is read or written, so the same weights and seed
give the same indices.

All four schemes run in O(N) or O(N log N) numpy without a per-particle Python
loop:

* ``systematic`` and ``stratified`` never search: the number of ordered uniforms
  below each cumulative weight has a closed form, so the copy counts are a
  difference of two vectors and the indices one ``np.repeat``.
* ``multinomial`` draws ``N`` *sorted* uniforms from exponential spacings
  (O(N), no sort) and inverts the CDF with one ``np.searchsorted``, which is
  several times faster on sorted queries than on random ones.
* ``residual`` (the paper's choice and the default) keeps ``floor(N w_i)`` copies
  of particle ``i`` and draws the remaining ``R = N - sum floor(N w_i)``
  multinomially from the residuals ``N w_i - floor(N w_i)``.

Indices come back sorted (residual: two sorted runs); particles are
exchangeable after resampling, so the order carries no information.
"""

from __future__ import annotations

import functools
from typing import Callable

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.rng import as_rng

#: Particle count from which the inverse CDF uses the compiled merge (if numba is installed).
MERGE_MIN_N = 65536

__all__ = ["MERGE_MIN_N", "RESAMPLERS", "ess", "multinomial", "residual", "stratified", "systematic"]


def _checked(weights: np.ndarray) -> tuple[np.ndarray, float]:
    """Validate ``weights`` and return them as float64 with their sum."""
    w = np.asarray(weights)
    if w.ndim != 1 or w.shape[0] == 0:
        raise InputError(f"weights must be a non-empty (N,) array, got shape {w.shape}")
    if not np.issubdtype(w.dtype, np.number) or np.issubdtype(w.dtype, np.complexfloating):
        raise InputError(f"weights must be real numbers, got dtype {w.dtype}")
    w = w.astype(np.float64, copy=False)
    total = float(w.sum())
    if not np.isfinite(total):
        raise InputError(f"weights must be finite, got a sum of {total} (NaN or inf present)")
    lowest = float(w.min())
    if lowest < 0.0:
        raise InputError(f"weights must be >= 0, got a minimum of {lowest}")
    if total <= 0.0:
        raise InputError("weights must not all be zero (sum must be > 0), got a sum of 0")
    return w, total


def _scaled_cdf(w: np.ndarray) -> np.ndarray:
    """Cumulative weights scaled to end at exactly ``N`` (``N c_i`` for normalised ``c``).

    Entries from the last particle of positive weight on are set to ``N``
    exactly, so rounding never hands a trailing zero-weight particle a copy.
    """
    n = w.shape[0]
    c = np.cumsum(w)
    last = int(np.searchsorted(c, c[-1], side="left"))
    c *= n / c[-1]
    c[last:] = n
    return c


@functools.cache
def _merge_kernel() -> Callable[[np.ndarray, np.ndarray, np.ndarray], None] | None:
    """The compiled O(N + M) merge of :func:`_inverse_cdf`, or None without numba.

    Compiled on first use and cached on disk (``cache=True``), so only the very
    first large resampling on a machine pays the compilation (~0.5 s).
    """
    try:
        import numba
    except ImportError:
        return None

    @numba.njit(cache=True, nogil=True, boundscheck=False)
    def merge(c, u, out):  # pragma: no cover - runs compiled
        i = 0
        for j in range(u.shape[0]):
            x = u[j]
            while c[i] <= x:
                i += 1
            out[j] = i

    return merge


def _inverse_cdf(c: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Index ``i`` with ``c_(i-1) <= u < c_i`` for sorted ``u`` in ``[0, c[-1])``.

    ``np.searchsorted`` (binary search, ~20 ns per query) below
    :data:`MERGE_MIN_N` particles; above it, when numba is installed, one linear
    merge of the two sorted arrays (~2 ns per element), which is what keeps the
    1e6-particle resampling at parity with compiled libraries.
    """
    np.minimum(u, np.nextafter(c[-1], 0.0), out=u)
    merge = _merge_kernel() if c.shape[0] >= MERGE_MIN_N else None
    if merge is None:
        # i such that c_(i-1) <= u < c_i  (inverse CDF; sorted queries search fast)
        return np.searchsorted(c, u, side="right").astype(np.int64, copy=False)
    out = np.empty(u.shape[0], dtype=np.int64)
    # the same i, walking both sorted arrays once
    merge(c, u, out)
    return out


def _sorted_uniforms(m: int, rng: np.random.Generator) -> np.ndarray:
    """``m`` ordered U(0, 1) variates in O(m) from exponential spacings."""
    z = np.cumsum(rng.standard_exponential(m + 1))
    # U_(j) = S_j / S_(m+1), S_j = E_1 + ... + E_j: the order statistics of m uniforms
    return z[:m] * (1.0 / z[m])


def _indices_from_below(below: np.ndarray) -> np.ndarray:
    """Indices from ``below[i]`` = number of ordered uniforms below cdf ``c_i``."""
    counts = np.diff(below, prepend=0)
    # particle i is drawn once per uniform in [c_(i-1), c_i)
    return np.repeat(np.arange(below.shape[0], dtype=np.int64), counts)


def ess(weights: np.ndarray) -> float:
    """Effective sample size ``1 / sum(w_i^2)`` of normalised weights (paper 003 §3.3).

    Parameters
    ----------
    weights : ndarray, shape (N,)
        Non-negative weights; they are rescaled to sum to one first.

    Returns
    -------
    float
        A value in ``[1, N]``: ``N`` for uniform weights, 1 when one particle
        carries all the weight.
    """
    w, total = _checked(weights)
    # ESS = 1 / sum(w_i^2), w normalised
    return float(total * total / np.einsum("i,i->", w, w))


def multinomial(weights: np.ndarray, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """Multinomial resampling: ``N`` independent draws from ``Categorical(w)``.

    Parameters
    ----------
    weights : ndarray, shape (N,)
        Non-negative, finite, not all zero (rescaled to sum to one).
    rng : numpy.random.Generator, int or None
        Random source (see :func:`fusion_pf.rng.as_rng`).

    Returns
    -------
    ndarray, shape (N,), int64
        Ascending indices; the copy counts are ``Multinomial(N, w)``.
    """
    w, _ = _checked(weights)
    rng = as_rng(rng)
    n = w.shape[0]
    c = _scaled_cdf(w)
    u = _sorted_uniforms(n, rng)
    u *= n
    return _inverse_cdf(c, u)


def stratified(weights: np.ndarray, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """Stratified resampling: one uniform in each stratum ``[j/N, (j+1)/N)``.

    Parameters
    ----------
    weights : ndarray, shape (N,)
        Non-negative, finite, not all zero (rescaled to sum to one).
    rng : numpy.random.Generator, int or None
        Random source.

    Returns
    -------
    ndarray, shape (N,), int64
        Ascending indices; particle ``i`` gets ``floor(N w_i)`` or more copies
        in expectation ``N w_i``.
    """
    w, _ = _checked(weights)
    rng = as_rng(rng)
    n = w.shape[0]
    nc = _scaled_cdf(w)
    offsets = rng.random(n)
    # u_j = (j + U_j) / N; #{j : u_j < c} = k + [U_k < N c - k], k = floor(N c)
    k = np.minimum(nc.astype(np.int64), n - 1)
    below = k + (np.take(offsets, k) < nc - k)
    return _indices_from_below(below)


def systematic(weights: np.ndarray, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """Systematic resampling: one uniform shared by all strata, ``u_j = (j + U) / N``.

    Parameters
    ----------
    weights : ndarray, shape (N,)
        Non-negative, finite, not all zero (rescaled to sum to one).
    rng : numpy.random.Generator, int or None
        Random source.

    Returns
    -------
    ndarray, shape (N,), int64
        Ascending indices; particle ``i`` gets ``floor(N w_i)`` or
        ``ceil(N w_i)`` copies.
    """
    w, _ = _checked(weights)
    rng = as_rng(rng)
    n = w.shape[0]
    nc = _scaled_cdf(w)
    offset = rng.random()
    # #{j : (j + U) / N < c} = ceil(N c - U), clipped to [0, N]
    nc -= offset
    below = np.clip(np.ceil(nc, out=nc), 0, n).astype(np.int64)
    return _indices_from_below(below)


def residual(weights: np.ndarray, rng: np.random.Generator | int | None = None) -> np.ndarray:
    """Residual resampling (the paper's scheme, the default).

    Keeps ``floor(N w_i)`` copies of particle ``i`` and draws the remaining
    ``R = N - sum_i floor(N w_i)`` indices multinomially with probabilities
    proportional to the residuals ``N w_i - floor(N w_i)``. Unbiased: the
    expected count of particle ``i`` is ``N w_i``.

    Parameters
    ----------
    weights : ndarray, shape (N,)
        Non-negative, finite, not all zero (rescaled to sum to one).
    rng : numpy.random.Generator, int or None
        Random source.

    Returns
    -------
    ndarray, shape (N,), int64
        The ``floor(N w_i)`` copies in ascending order, then the ``R`` residual
        draws in ascending order.
    """
    w, total = _checked(weights)
    rng = as_rng(rng)
    n = w.shape[0]
    nw = w * (n / total)
    # n_i = floor(N w_i) deterministic copies
    floor_nw = np.floor(nw)
    kept = floor_nw.astype(np.int64)
    n_rest = n - int(kept.sum())
    if n_rest == 0:
        return np.repeat(np.arange(n, dtype=np.int64), kept)
    # r_i = N w_i - n_i, the residual weights
    np.subtract(nw, floor_nw, out=nw)
    c = np.cumsum(nw)
    u = _sorted_uniforms(n_rest, rng)
    u *= c[-1]
    extra = _inverse_cdf(c, u)
    return np.concatenate([np.repeat(np.arange(n, dtype=np.int64), kept), extra])


#: Resamplers by name (``--resampler`` values).
RESAMPLERS: dict[str, Callable[[np.ndarray, np.random.Generator | int | None], np.ndarray]] = {
    "residual": residual,
    "multinomial": multinomial,
    "stratified": stratified,
    "systematic": systematic,
}
