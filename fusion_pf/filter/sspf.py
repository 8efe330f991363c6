"""Scatter-search particle filter (SSPF) of paper 002 §4 (Fig. 3).

A particle filter whose best solutions are improved by scatter search every
frame. One :meth:`ScatterSearchPF.step`:

1. PREDICT: constant-velocity motion (paper 002 eq. 5 = paper 003 eq. 4,
   :func:`~fusion_pf.filter.motion.predict`);
2. EVALUATE: the fitness (Gaussian log-likelihood of paper 003 eqs. 5-7,
   ``-P |p - z_bar|^2 / 2``) of every particle;
3. MAKEREFSET: the ``b/2`` best and the ``b/2`` most diverse particles (greedy
   max-min distance to the set);
4. COMBINE: every pair of the RefSet gives trial solutions -- the midpoint and
   the two partition crossings (position of one, velocity of the other, as
   paper 002 §5 combines the parts of two solutions) -- EVALUATE;
5. IMPROVE: the best trial solution (paper 002 §5: "the best solution is
   chosen as result of the combination procedure"), if it beats the RefSet's
   worst, is improved by a local search (pattern search on the position:
   ``+-step`` on each axis, move to the best improving neighbour, halve the
   step when none improves, stop below ``min_step_px``) -- EVALUATE;
6. UPDATEREFSET: better solutions replace the worst; the SS stage repeats
   until no new solution enters the RefSet (at most ``max_rounds``);
7. INCLUDE: the RefSet replaces the worst particles;
8. SELECT and DIFFUSE: systematic resampling by the fitness weights (the
   diffusion is the prediction noise of the next step).

The estimate is the weighted mean of the particles after INCLUDE.
:attr:`ScatterSearchPF.evaluations` counts the fitness evaluations of the last
step: unlike a PF's ``N``, it varies from frame to frame (paper 002: "SSPF is
time-adaptive since the number of evaluations of the weighting function
changes in each time step").
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from fusion_pf.cues.base import Measurement
from fusion_pf.errors import InputError
from fusion_pf.rng import as_rng

from .base import Estimate, Tracker
from .estimate import weighted_covariance, weighted_mean
from .likelihood import DEFAULT_NOISE_PX, JointLikelihood, squared_distance
from .motion import FrameClock, check_process_noise, noise_std, predict
from .pf import check_prior, check_timestamp, fused_position
from .resample import systematic

__all__ = ["ScatterSearchPF", "diverse_subset"]


def diverse_subset(points: np.ndarray, chosen: np.ndarray, count: int) -> np.ndarray:
    """Greedy max-min diversity: ``count`` more indices of ``points`` far from ``chosen``.

    Parameters
    ----------
    points : ndarray, shape (N, d)
    chosen : ndarray, shape (m,), int
        Indices already in the set (m >= 1).
    count : int

    Returns
    -------
    ndarray, shape (count,), int
    """
    d = np.min(((points[:, None, :] - points[chosen][None, :, :]) ** 2).sum(axis=2), axis=1)
    d[chosen] = -1.0
    out = []
    for _ in range(min(count, len(points) - len(chosen))):
        j = int(np.argmax(d))
        out.append(j)
        d = np.minimum(d, ((points - points[j]) ** 2).sum(axis=1))
        d[j] = -1.0
    return np.array(out, dtype=np.int64)


class ScatterSearchPF(Tracker):
    """Paper 002's scatter-search particle filter for one target (module docstring).

    Parameters
    ----------
    n_particles : int
        Particle count N (paper 002: 100).
    refset_size : int
        RefSet size ``b`` (paper 002 §5: 6), even, >= 2, <= N.
    process_noise : (float, float)
        ``(pos_px, vel_px)`` per frame step.
    noise_px : mapping of str to float
        Per-source measurement noise (px); the fitness is Gaussian.
    step_px, min_step_px : float
        Initial and final step of the local search (px).
    max_rounds : int
        Largest number of SS rounds per frame.
    init_spread_px, init_velocity_px : float
        Initial spread around the first measurement / prior.
    prior : (u, v) or (u, v, du, dv), optional
    frame_period_ns : float, "auto" or None
        As for :class:`~fusion_pf.filter.pf.ParticleFilter`.
    rng : Generator, int or None

    Attributes
    ----------
    particles : ndarray, shape (N, 4)
    evaluations : int
        Fitness (likelihood) evaluations in the last step.
    total_evaluations : int
        Since construction.
    """

    def __init__(
        self,
        *,
        n_particles: int = 100,
        refset_size: int = 6,
        process_noise: tuple[float, float] = (3.0, 1.0),
        noise_px: Mapping[str, float] = DEFAULT_NOISE_PX,
        step_px: float = 4.0,
        min_step_px: float = 0.5,
        max_rounds: int = 3,
        init_spread_px: float = 20.0,
        init_velocity_px: float = 2.0,
        prior=None,
        frame_period_ns: float | str | None = None,
        rng: np.random.Generator | int | None = None,
    ) -> None:
        if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)) or n_particles < 2:
            raise InputError(f"n_particles must be an int >= 2, got {n_particles!r}")
        if (isinstance(refset_size, bool) or not isinstance(refset_size, (int, np.integer))
                or refset_size < 2 or refset_size % 2 or refset_size > n_particles):
            raise InputError(f"refset_size must be an even int in [2, n_particles={n_particles}], got {refset_size!r}")
        if not (0.0 < float(min_step_px) <= float(step_px) and math.isfinite(float(step_px))):
            raise InputError(f"need 0 < min_step_px <= step_px (finite), got {min_step_px!r} and {step_px!r}")
        if isinstance(max_rounds, bool) or not isinstance(max_rounds, (int, np.integer)) or max_rounds < 1:
            raise InputError(f"max_rounds must be an int >= 1, got {max_rounds!r}")
        self.n_particles = int(n_particles)
        self.refset_size = int(refset_size)
        self.process_noise = check_process_noise(process_noise)
        self._like = JointLikelihood(noise_px)
        self.noise_px = self._like.noise_px
        self.step_px = float(step_px)
        self.min_step_px = float(min_step_px)
        self.max_rounds = int(max_rounds)
        self.init_spread_px = float(init_spread_px)
        self.init_velocity_px = float(init_velocity_px)
        self.prior = check_prior(prior)
        self._clock = FrameClock(frame_period_ns)
        self.rng = as_rng(rng)
        self._std_unit = noise_std(self.process_noise, 1.0)
        self.evaluations = 0
        self.total_evaluations = 0
        self.reset()

    @property
    def particles(self) -> np.ndarray:
        """Current particles, shape (N, 4) (a view)."""
        return self._x.T

    def reset(self) -> None:
        """Forget the particles; re-initialise from ``prior`` or the next measurement."""
        self._last_ns: int | None = None
        self._x = np.zeros((4, self.n_particles))
        self.initialised = False
        if self.prior is not None:
            self._initialise(self.prior)

    def _initialise(self, centre: np.ndarray) -> None:
        std = np.array([self.init_spread_px] * 2 + [self.init_velocity_px] * 2)
        self._x = centre[:, None] + std[:, None] * self.rng.standard_normal((4, self.n_particles))
        self.initialised = True

    def _fitness(self, states: np.ndarray, z_bar: np.ndarray, precision: float) -> np.ndarray:
        """EVALUATE: ``-P |p - z_bar|^2 / 2`` for states (n, 4); counts n evaluations."""
        self.evaluations += len(states)
        # log Lh = -P |p - z_bar|^2 / 2 (+ const)   (paper 003 eqs. 5-7)
        return -0.5 * precision * squared_distance(states[:, :2], z_bar)

    def _improve(self, sols: np.ndarray, fit: np.ndarray, z_bar, precision) -> tuple[np.ndarray, np.ndarray]:
        """IMPROVE: pattern search on the positions of all ``sols`` (m, 4) at once."""
        sols, fit = sols.copy(), fit.copy()
        step = np.full(len(sols), self.step_px)
        moves = np.array([[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]])
        active = step >= self.min_step_px
        while active.any():
            a = np.flatnonzero(active)
            # neighbours (|a|, 4, 4): +-step on u and v
            nb = np.repeat(sols[a][:, None, :], 4, axis=1)
            nb[:, :, :2] += step[a, None, None] * moves[None]
            f = self._fitness(nb.reshape(-1, 4), z_bar, precision).reshape(len(a), 4)
            best = f.argmax(axis=1)
            fbest = f[np.arange(len(a)), best]
            better = fbest > fit[a]
            sols[a[better]] = nb[better, best[better]]
            fit[a[better]] = fbest[better]
            step[a[~better]] *= 0.5
            active = step >= self.min_step_px
        return sols, fit

    def _scatter_search(self, x: np.ndarray, fit: np.ndarray, z_bar, precision) -> tuple[np.ndarray, np.ndarray]:
        """MAKEREFSET, COMBINE, IMPROVE, UPDATEREFSET until the RefSet stops improving."""
        half = self.refset_size // 2
        best = np.argsort(fit)[::-1][:half]
        ref_idx = np.concatenate([best, diverse_subset(x[:, :2], best, half)])
        ref, ref_fit = x[ref_idx].copy(), fit[ref_idx].copy()
        i, j = np.triu_indices(len(ref), 1)
        for _ in range(self.max_rounds):
            a, b = ref[i], ref[j]
            cross_ab = np.concatenate([a[:, :2], b[:, 2:]], axis=1)
            cross_ba = np.concatenate([b[:, :2], a[:, 2:]], axis=1)
            trials = np.concatenate([0.5 * (a + b), cross_ab, cross_ba])
            tfit = self._fitness(trials, z_bar, precision)
            top = int(np.argmax(tfit))
            if tfit[top] <= ref_fit.min():
                break
            imp, ifit = self._improve(trials[top:top + 1], tfit[top:top + 1], z_bar, precision)
            pool = np.concatenate([ref, imp])
            pfit = np.concatenate([ref_fit, ifit])
            keep = np.argsort(pfit)[::-1][: len(ref)]
            if not (keep >= len(ref)).any():
                break
            ref, ref_fit = pool[keep], pfit[keep]
        return ref, ref_fit

    def step(self, timestamp_ns: int, measurements: Sequence[Measurement]) -> Estimate | None:
        """PREDICT, EVALUATE, scatter search, INCLUDE, estimate, SELECT (module docstring).

        Returns
        -------
        Estimate or None
            None until initialised; ``ess`` is that of the fitness weights.
        """
        t = check_timestamp(timestamp_ns, self._last_ns)
        ms = self._like.check(measurements)
        self.evaluations = 0
        if not self.initialised:
            if not ms:
                return None
            sigma = {m.source: self.noise_px[m.source] for m in ms}
            self._initialise(np.concatenate([fused_position(ms, sigma), [0.0, 0.0]]))
        elif self._last_ns is not None:
            dt = self._clock.steps(t, self._last_ns)
            predict(self._x, self._std_unit * math.sqrt(dt), self.rng, dt=dt)
        self._last_ns = t
        n = self.n_particles
        x = self._x.T.copy()
        if not ms:
            w = np.full(n, 1.0 / n)
            est = weighted_mean(x[:, :2], w)
            self._x = x.T.copy()
            return Estimate(t, float(est[0]), float(est[1]), float(n), False, n,
                            weighted_covariance(x[:, :2], w), x[:, :2].copy())
        prec = np.array([1.0 / self.noise_px[m.source] ** 2 for m in ms])
        precision = float(prec.sum())
        z_bar = prec @ np.array([[m.u, m.v] for m in ms]) / precision
        fit = self._fitness(x, z_bar, precision)
        ref, ref_fit = self._scatter_search(x, fit, z_bar, precision)
        # INCLUDE: the RefSet replaces the worst particles
        worst = np.argsort(fit)[: len(ref)]
        x[worst], fit[worst] = ref, ref_fit
        w = np.exp(fit - fit.max())
        w /= w.sum()
        est = weighted_mean(x[:, :2], w)
        cov = weighted_covariance(x[:, :2], w)
        ess = 1.0 / float(w @ w)
        # SELECT (the next PREDICT's noise is the DIFFUSE stage)
        x = x[systematic(w, self.rng)]
        self._x = x.T.copy()
        self.total_evaluations += self.evaluations
        return Estimate(t, float(est[0]), float(est[1]), ess, True, n, cov, x[:, :2].copy())
