"""Point estimates from a weighted particle set (paper 003 §3.3, estimation phase).

The paper names three ways to pick the estimate -- the particle with the largest
weight (MAP), the weighted average of all particles, and the robust mean of a
top fraction of particles -- and uses the robust mean of the 10 % largest-weighted
particles. Here the robust mean is the weight-weighted mean *within* that top set
(the weights renormalised over it): equal to the plain mean when the weights
are equal, and smooth when they are not.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from fusion_pf.errors import InputError

__all__ = [
    "ESTIMATORS",
    "dot_product",
    "largest_std",
    "map_estimate",
    "robust_mean",
    "weighted_covariance",
    "weighted_mean",
]


#: From this length on, products are summed with ``einsum`` instead of BLAS.
_BLAS_MAX = 8192


def dot_product(a: np.ndarray, b: np.ndarray) -> float:
    """``sum(a * b)``; from :data:`_BLAS_MAX` on via einsum (threaded BLAS dot stalls ~10 ms at 1e6 on busy cores)."""
    if a.shape[0] < _BLAS_MAX:
        return float(a @ b)
    return float(np.einsum("i,i->", a, b))


def robust_mean(positions: np.ndarray, weights: np.ndarray, top_fraction: float = 0.1) -> np.ndarray:
    """Robust mean of the largest-weighted ``top_fraction`` of the particles.

    Parameters
    ----------
    positions : ndarray, shape (N, d)
        Particle positions (d = 2 image pixels, 3 world mm).
    weights : ndarray, shape (N,)
        Normalised weights.
    top_fraction : float
        Fraction in (0, 1] of particles kept; at least one is.

    Returns
    -------
    ndarray, shape (d,)
        ``sum_(i in top) w_i p_i / sum_(i in top) w_i``.
    """
    if not (0.0 < top_fraction <= 1.0):
        raise InputError(f"top_fraction must be in (0, 1], got {top_fraction}")
    n = weights.shape[0]
    k = max(1, math.ceil(top_fraction * n))
    if k >= n:
        return weighted_mean(positions, weights)
    top = weights.argpartition(n - k)[n - k :]
    w = weights.take(top)
    # x_hat = sum_top w_i p_i / sum_top w_i
    return np.array([dot_product(w, positions[:, j].take(top)) for j in range(positions.shape[1])]) / w.sum()


def weighted_mean(positions: np.ndarray, weights: np.ndarray, top_fraction: float = 1.0) -> np.ndarray:
    """Weighted mean of all particles ``(N, d)``, ``sum_i w_i p_i`` (``top_fraction`` is ignored).

    Returns
    -------
    ndarray, shape (d,)
    """
    # x_hat = sum_i w_i p_i / sum_i w_i
    return np.array([dot_product(weights, positions[:, j]) for j in range(positions.shape[1])]) / weights.sum()


def map_estimate(positions: np.ndarray, weights: np.ndarray, top_fraction: float = 1.0) -> np.ndarray:
    """Position of the particle with the largest weight (``top_fraction`` is ignored).

    Returns
    -------
    ndarray, shape (2,)
    """
    # x_hat = p_argmax(w)
    return np.array(positions[int(np.argmax(weights))], dtype=np.float64)


def weighted_covariance(
    positions: np.ndarray,
    weights: np.ndarray,
    mean: np.ndarray | None = None,
    work: np.ndarray | None = None,
) -> np.ndarray:
    """Weighted covariance of the positions (the posterior's spread), px^2.

    Parameters
    ----------
    positions : ndarray, shape (N, 2)
    weights : ndarray, shape (N,)
        Normalised weights.
    mean : ndarray, shape (2,), optional
        The weighted mean if already known.
    work : ndarray, shape (>= 2, N), optional
        Scratch rows (3 avoid any allocation per call).

    Returns
    -------
    ndarray, shape (2, 2)
        ``sum_i w_i (p_i - m)(p_i - m)^T``.
    """
    if mean is None:
        mean = weighted_mean(positions, weights)
    if work is None:
        work = np.empty((3, weights.shape[0]))
    du = np.subtract(positions[:, 0], mean[0], out=work[0])
    dv = np.subtract(positions[:, 1], mean[1], out=work[1])
    wdu = np.multiply(weights, du, out=work[2]) if work.shape[0] > 2 else weights * du
    # C = sum_i w_i (p_i - m)(p_i - m)^T
    cuu, cuv = dot_product(wdu, du), dot_product(wdu, dv)
    wdv = np.multiply(weights, dv, out=work[0])
    cvv = dot_product(wdv, dv)
    return np.array([[cuu, cuv], [cuv, cvv]])


#: Estimators by name (``estimator=`` values).
ESTIMATORS: dict[str, Callable[[np.ndarray, np.ndarray, float], np.ndarray]] = {
    "robust_mean": robust_mean,
    "map": map_estimate,
    "weighted_mean": weighted_mean,
}


def largest_std(cov: np.ndarray) -> float:
    """Standard deviation along the major axis of a 2 x 2 covariance: the root of its largest eigenvalue.

    Closed form (``np.linalg.eigvalsh`` costs ~100x more on a 2 x 2); 0 when the
    covariance is not positive (rounding).

    Parameters
    ----------
    cov : ndarray, shape (2, 2)
        Symmetric covariance, px^2.
    """
    a, b, d = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
    # lambda_max = (a + d) / 2 + sqrt(((a - d) / 2)^2 + b^2)
    lam = 0.5 * (a + d) + math.hypot(0.5 * (a - d), b)
    return math.sqrt(max(lam, 0.0))
