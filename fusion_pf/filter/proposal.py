"""Where particles move to in one step: eq. 4's prior, or the locally optimal (guided) proposal.

Paper 003's filter is a bootstrap filter: particles move with the dynamic
model (eq. 4) and the cues only weight them. When the palm moves further than
the process noise allows, few particles land near the cues and the estimate
lags. The *guided* proposal draws each particle from the distribution it
would have after seeing one measurement, ``p(x_k | x_(k-1), z_k)`` (Doucet,
Godsill & Andrieu, "On sequential Monte Carlo sampling methods for Bayesian
filtering", Statistics and Computing 2000, §II.C: the optimal importance
function), and weights it by ``p(z_k | x_(k-1))``. For eq. 4's position
noise and a Gaussian cue both are closed form; with the manoeuvre mixture
(heavy-tailed position noise) and the robust cue (Gaussian + uniform outlier)
they are mixtures of at most 2 x 2 components, each closed form.

Per particle ``i`` with predicted position ``mu_i = p_(k-1) + dt v_(k-1)``,
position noise components ``j`` (std ``q_j``, prior weight ``pi_j``) and a cue
``z`` with noise ``sigma`` (inlier weight ``1 - eps``):

* inlier component ``(j, in)``: weight ``pi_j (1 - eps) N2(z; mu_i, q_j^2 + sigma^2)``,
  draw ``N2(mu_i + a_j (z - mu_i), s_j^2)`` with ``a_j = q_j^2 / (q_j^2 + sigma^2)``,
  ``s_j^2 = q_j^2 sigma^2 / (q_j^2 + sigma^2)``;
* outlier component ``(j, out)``: weight ``pi_j eps / A``, draw ``N2(mu_i, q_j^2)``;

the incremental log-weight is the log of the summed component weights.
Everything is vectorised over particles; the component is chosen by inverse
CDF on one uniform draw per particle.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from fusion_pf.errors import InputError

__all__ = ["PROPOSALS", "check_manoeuvre", "guided_positions", "prior_positions"]

#: Proposal names (``proposal=`` values).
PROPOSALS = ("prior", "guided")


def check_manoeuvre(manoeuvre) -> tuple[float, float]:
    """Validate ``manoeuvre = (prob, std_px)``: prob in [0, 1), std finite and >= 0."""
    try:
        prob, std = (float(x) for x in manoeuvre)
    except (TypeError, ValueError):
        raise InputError(f"manoeuvre must be a pair (prob, std_px), got {manoeuvre!r}") from None
    if not 0.0 <= prob < 1.0:
        raise InputError(f"manoeuvre probability must be in [0, 1), got {prob}")
    if not (math.isfinite(std) and std >= 0.0):
        raise InputError(f"manoeuvre std must be a finite number >= 0 px, got {std}")
    return prob, std


@functools.lru_cache(maxsize=64)
def _components(q: float, manoeuvre: tuple[float, float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position-noise mixture: log prior weights, variances and velocity gains, each ``(J,)``, read-only (cached).

    Component 0 is eq. 4's position noise ``q``; component 1 (with
    probability ``prob``) adds a manoeuvre, a velocity change ``a ~ N(0, m^2)``
    at the start of the step that moves the position too, so the position
    variance is ``q^2 + m^2`` and, given a position innovation ``e``, the
    velocity changes by ``E[a | e] = m^2 / (q^2 + m^2) e`` (the gain).
    """
    prob, m = manoeuvre
    if prob == 0.0:
        out = np.zeros(1), np.array([q * q]), np.zeros(1)
    else:
        # pi = (1 - prob, prob); variances (q^2, q^2 + m^2); gains (0, m^2 / (q^2 + m^2))
        out = np.log([1.0 - prob, prob]), np.array([q * q, q * q + m * m]), np.array([0.0, m * m / (q * q + m * m)])
    for a in out:
        a.flags.writeable = False
    return out


def prior_positions(
    x: np.ndarray, q: float, manoeuvre: tuple[float, float], rng: np.random.Generator, dt: float = 1.0
) -> None:
    """Eq. 4's position noise plus manoeuvres, in place (the prior proposal).

    Parameters
    ----------
    x : ndarray, shape (4, N)
        Particles (rows u, v, du, dv) already moved by ``M``; positions get
        ``N(0, q^2 dt)``, and with probability ``prob`` a manoeuvre
        ``a ~ N(0, m^2 dt)`` is added to both position and velocity.
    q : float
        Eq. 4 position std per frame step, px.
    manoeuvre : (float, float)
        ``(prob, m)``, ``m`` in px/frame.
    rng : numpy.random.Generator
    dt : float
        Step length in frame steps.
    """
    prob, m = manoeuvre
    n = x.shape[1]
    root = math.sqrt(dt)
    noise = rng.standard_normal((2, n))
    # p_k += q sqrt(dt) N(0, I)
    x[:2] += q * root * noise
    if prob == 0.0:
        return
    hit = np.less(rng.random(n), prob)
    a = rng.standard_normal((2, int(hit.sum()))) * (m * root)
    # with probability prob: a ~ N(0, m^2 dt); p_k += a, v_k += a
    x[:2, hit] += a
    x[2:, hit] += a


def guided_positions(
    mu: np.ndarray,
    velocity: np.ndarray,
    q: float,
    manoeuvre: tuple[float, float],
    z: tuple[float, float],
    sigma: float,
    rng: np.random.Generator,
    *,
    outlier: tuple[float, float] | None = None,
    dt: float = 1.0,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Draw positions from the locally optimal proposal for one cue, in place.

    Parameters
    ----------
    mu : ndarray, shape (2, N)
        Predicted positions ``p_(k-1) + dt v_(k-1)`` (rows u, v); overwritten
        with the drawn positions.
    velocity : ndarray, shape (2, N)
        The particles' velocities; a particle that drew a manoeuvre component
        gets its velocity change (the gain times its position innovation).
    q : float
        Eq. 4 position noise std per frame step, px.
    manoeuvre : (float, float)
        ``(prob, std_px)`` heavy-tail mixture of the position noise.
    z : (float, float)
        The anchor cue, px.
    sigma : float
        Its noise std per axis, px (> 0).
    rng : numpy.random.Generator
    outlier : (eps, area_px2) or None
        Robust cue: outlier probability and the uniform density's area; None:
        a Gaussian cue.
    dt : float
        Step length in frame steps.

    Returns
    -------
    log_evidence : ndarray, shape (N,)
        ``log p(z | x_(k-1))`` per particle (the incremental log-weight).
    expected : ndarray, shape (2, N)
        ``E[x_k | x_(k-1), z]`` per particle: the component means averaged with
        their posterior probabilities (Rao-Blackwellised positions; a point
        estimate from them does not carry the noise of the component draw).
    inlier : bool
        Whether, for some particle, the cue is more likely right than an
        outlier (always True for a Gaussian cue unless the evidence underflows).
    """
    log_pi, var_q, gain = _components(float(q), (float(manoeuvre[0]), float(manoeuvre[1])))
    var_q = var_q * dt
    var_z = sigma * sigma
    total = var_q + var_z
    n = mu.shape[1]
    j = len(var_q)
    log_in_w = math.log1p(-outlier[0]) if outlier is not None else 0.0
    # a_j = q_j^2 / (q_j^2 + sigma^2), s_j = sqrt(q_j^2 sigma^2 / (q_j^2 + sigma^2))
    pull = var_q / total
    spread = np.sqrt(var_q * var_z / total)
    c = j if outlier is None else 2 * j
    log_c = np.empty((c, n))
    # d2_i = |z - mu_i|^2
    du = z[0] - mu[0]
    dv = z[1] - mu[1]
    d2 = du * du
    d2 += dv * dv
    for k in range(j):
        # log pi_j (1 - eps) N2(z; mu_i, q_j^2 + sigma^2)
        np.multiply(d2, -0.5 / total[k], out=log_c[k])
        log_c[k] += log_pi[k] + log_in_w - math.log(2.0 * math.pi * total[k])
    if outlier is not None:
        eps, area = outlier
        for k in range(j):
            # log pi_j eps / A: the cue is an outlier, the particle keeps eq. 4's noise
            log_c[j + k] = log_pi[k] + math.log(eps) - math.log(area)
        # some particle explains the cue at least as well as an outlier does (the outlier row is constant)
        inlier = bool(log_c[:j].max() >= log_c[j, 0])
        pull = np.concatenate([pull, np.zeros(j)])
        spread = np.concatenate([spread, np.sqrt(var_q)])
        gain = np.concatenate([gain, gain])
    else:
        inlier = bool(np.isfinite(log_c).any())
    # log p(z | x_(k-1)) = log sum_c w_c
    peak = log_c.max(axis=0)
    log_c -= peak
    prob = np.exp(log_c, out=log_c)
    norm = prob.sum(axis=0)
    log_evidence = np.log(norm)
    log_evidence += peak
    # E[x_i] = mu_i + (sum_c r_ic a_c) (z - mu_i), r_ic = w_ic / sum_c w_ic
    mean_pull = pull @ prob
    mean_pull /= norm
    expected = np.empty((2, n))
    np.multiply(mean_pull, du, out=expected[0])
    expected[0] += mu[0]
    np.multiply(mean_pull, dv, out=expected[1])
    expected[1] += mu[1]
    # c_i ~ Categorical(w_c / sum w): inverse CDF on one uniform per particle
    cdf = np.cumsum(prob, axis=0, out=prob)
    pick = (cdf < rng.random(n) * norm).sum(axis=0)
    np.minimum(pick, c - 1, out=pick)
    a = pull.take(pick)
    s = spread.take(pick)
    noise = rng.standard_normal((2, n))
    # e_i = a_c (z - mu_i) + s_c N(0, I);  x_i = mu_i + e_i
    eu = a * du
    eu += s * noise[0]
    ev = a * dv
    ev += s * noise[1]
    mu[0] += eu
    mu[1] += ev
    if j > 1:
        g = gain.take(pick)
        # v_i += g_c e_i: the manoeuvre's velocity change given the position innovation
        velocity[0] += g * eu
        velocity[1] += g * ev
    return log_evidence, expected, inlier
