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

From :data:`COMPILED_MIN_N` particles on, when numba is installed, ``residual``
and the inverse CDF of ``multinomial`` run as compiled O(N) loops (a merge of two
sorted arrays instead of a binary search per draw). They consume the same
random numbers and return the same indices as the numpy code (tested), only
faster; the first use on a machine compiles them (~1 s, then cached on disk).

Indices come back sorted (residual: two sorted runs); particles are
exchangeable after resampling, so the order carries no information.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from types import SimpleNamespace

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.rng import as_rng

#: Particle count from which residual resampling and the inverse CDF run compiled loops (if numba is installed).
COMPILED_MIN_N = 1024

__all__ = [
    "COMPILED_MIN_N",
    "RESAMPLERS",
    "ess",
    "multinomial",
    "residual",
    "residual_trusted",
    "stratified",
    "systematic",
]


def _checked(weights: np.ndarray) -> tuple[np.ndarray, float]:
    """Validate ``weights`` and return them as float64 with their sum."""
    w = np.asarray(weights)
    if w.ndim != 1 or w.shape[0] == 0:
        raise InputError(f"weights must be a non-empty (N,) array, got shape {w.shape}")
    if w.dtype.kind not in "fiu":
        raise InputError(f"weights must be real numbers, got dtype {w.dtype}")
    w = w.astype(np.float64, copy=False)
    total = float(w.sum())
    if not np.isfinite(total):
        raise InputError(f"weights must be finite with a finite sum, got a sum of {total}")
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
def _kernels() -> SimpleNamespace | None:
    """Compiled O(N) loops for large N, or None without numba.

    ``merge(c, u, out)``: ``out[j]`` = first ``i`` with ``c_i > u_j`` for sorted
    ``u``. ``residual_floor(w, scale, out)``: writes the ``floor(scale w_i)``
    copies into ``out``; returns (copies, sum of residuals).
    ``residual_draws(w, scale, u, out, k)``: the inverse CDF of the residuals
    (recomputed, summed in the same order as ``residual_floor``'s total, so it
    never runs past the end) into ``out[k:]``. Compiled on first use and cached
    on disk (``cache=True``): only the very first large resampling on a machine
    pays the compilation (~1 s).
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

    @numba.njit(cache=True, nogil=True, boundscheck=False)
    def residual_floor(w, scale, out):  # pragma: no cover - runs compiled
        # out has 2 slack slots: two copies are written unconditionally (no
        # branch for the usual 0-2 copies), the next particle overwrites extras
        n = out.shape[0] - 2
        k = 0
        total = 0.0
        for i in range(w.shape[0]):
            x = w[i] * scale
            f = np.floor(x)
            c = min(int(f), n - k)
            out[k] = i
            out[k + 1] = i
            for j in range(2, c):
                out[k + j] = i
            k += c
            total += x - f
        return k, total

    @numba.njit(cache=True, nogil=True, boundscheck=False)
    def residual_draws(w, scale, u, out, k):  # pragma: no cover - runs compiled
        # residuals recomputed as in residual_floor: same values, same running sum
        i = 0
        x = w[0] * scale
        s = x - np.floor(x)
        for j in range(u.shape[0]):
            while s <= u[j]:
                i += 1
                x = w[i] * scale
                s += x - np.floor(x)
            out[k + j] = i

    return SimpleNamespace(merge=merge, residual_floor=residual_floor, residual_draws=residual_draws)


def _inverse_cdf(c: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Index ``i`` with ``c_(i-1) <= u < c_i`` for sorted ``u`` in ``[0, c[-1])``.

    ``np.searchsorted`` (binary search, ~20 ns per query) below
    :data:`COMPILED_MIN_N` particles; above it, when numba is installed, one linear
    merge of the two sorted arrays (~2 ns per element), which is what keeps the
    1e6-particle resampling at parity with compiled libraries.
    """
    np.minimum(u, np.nextafter(c[-1], 0.0), out=u)
    kernels = _kernels() if c.shape[0] >= COMPILED_MIN_N else None
    if kernels is None:
        # i such that c_(i-1) <= u < c_i  (inverse CDF; sorted queries search fast)
        return np.searchsorted(c, u, side="right").astype(np.int64, copy=False)
    out = np.empty(u.shape[0], dtype=np.int64)
    # the same i, walking both sorted arrays once
    kernels.merge(c, u, out)
    return out


def _sorted_uniforms(m: int, rng: np.random.Generator) -> np.ndarray:
    """``m`` ordered U(0, 1) variates in O(m) from exponential spacings."""
    z = rng.standard_exponential(m + 1)
    np.cumsum(z, out=z)
    u = z[:m]
    # U_(j) = S_j / S_(m+1), S_j = E_1 + ... + E_j: the order statistics of m uniforms
    u *= 1.0 / z[m]
    return u


def _indices_from_below(below: np.ndarray) -> np.ndarray:
    """Indices from ``below[i]`` = number of ordered uniforms below cdf ``c_i``."""
    counts = np.diff(below, prepend=0)
    # particle i is drawn once per uniform in [c_(i-1), c_i)
    return np.arange(below.shape[0], dtype=np.int64).repeat(counts)


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
        Ascending indices; particle ``i`` gets ``N w_i`` copies in
        expectation and always fewer than 2 away from it.
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
    kernels = _kernels() if n >= COMPILED_MIN_N else None
    if kernels is None:
        # N w_i
        return _residual_numpy(w * (n / total), rng)
    return _residual_compiled(w, n / total, rng, kernels)


def residual_trusted(w: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """:func:`residual` of weights known to be valid (a filter's own), without the checks.

    Compiled at every N when numba is installed (the same draws and indices as
    the numpy code, which small N otherwise takes).
    """
    n = w.shape[0]
    kernels = _kernels()
    if kernels is None:
        return _residual_numpy(w * (n / float(w.sum())), rng)
    return _residual_compiled(w, n / float(w.sum()), rng, kernels)


def _residual_numpy(nw: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Residual resampling of ``nw = N w`` in numpy (small N)."""
    n = nw.shape[0]
    # n_i = floor(N w_i) deterministic copies
    floor_nw = np.floor(nw)
    kept = floor_nw.astype(np.int64)
    n_rest = n - int(kept.sum())
    copies = np.arange(n, dtype=np.int64).repeat(kept)
    if n_rest == 0:
        return copies
    # r_i = N w_i - n_i, the residual weights
    np.subtract(nw, floor_nw, out=nw)
    c = np.cumsum(nw)
    u = _sorted_uniforms(n_rest, rng)
    u *= c[-1]
    return np.concatenate([copies, _inverse_cdf(c, u)])


def _residual_compiled(w: np.ndarray, scale: float, rng: np.random.Generator, kernels: SimpleNamespace) -> np.ndarray:
    """The same algorithm and random draws as :func:`_residual_numpy` (``nw = scale w``), compiled.

    Two passes over the weights and no (N,) temporary besides the result.
    """
    n = w.shape[0]
    out = np.empty(n + 2, dtype=np.int64)
    # n_i = floor(N w_i) copies; total = sum_i (N w_i - n_i)
    k, total = kernels.residual_floor(w, scale, out)
    if k < n:
        u = _sorted_uniforms(n - k, rng)
        u *= total
        np.minimum(u, np.nextafter(total, 0.0), out=u)
        # i such that sum_(j<i) r_j <= u < sum_(j<=i) r_j
        kernels.residual_draws(w, scale, u, out, k)
    return out[:n]


#: Resamplers by name (``--resampler`` values).
RESAMPLERS: dict[str, Callable[[np.ndarray, np.random.Generator | int | None], np.ndarray]] = {
    "residual": residual,
    "multinomial": multinomial,
    "stratified": stratified,
    "systematic": systematic,
}
