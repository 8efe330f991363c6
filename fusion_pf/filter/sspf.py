"""Scatter-search particle filter (SSPF) of paper 002 §4 (Fig. 3).

A particle filter whose best solutions are improved by scatter search every
frame. A particle holds the states of K targets, shape ``(K, 4)`` (paper 002
§5: face, right and left hand in one particle; K = 1 for one palm). One step:

1. PREDICT: constant-velocity motion (paper 002 eq. 5 = paper 003 eq. 4);
2. EVALUATE: the fitness of every particle, the sum over targets of the
   Gaussian log-likelihood of paper 003 eqs. 5-7, ``-P_k |p_k - z_bar_k|^2 / 2``
   (a target without a cue adds nothing);
3. MAKEREFSET: the ``b/2`` best and the ``b/2`` most diverse particles (greedy
   max-min distance, :func:`diverse_subset`);
4. COMBINE: every pair of the RefSet gives trial solutions -- the midpoint and
   the partitions: for K > 1 every mix of the two solutions' targets (paper 002
   §5: ``(F1, R2, L2)``, ``(F2, R1, L1)``, ... six for K = 3), for K = 1 the
   position of one with the velocity of the other -- EVALUATE;
5. IMPROVE: the best trial solution (paper 002 §5: "the best solution is
   chosen as result of the combination procedure"), if it beats the RefSet's
   worst, is improved by a local search (pattern search on the positions:
   ``+-step`` on each axis of each target, move to the best improving
   neighbour, halve the step when none improves, stop below ``min_step_px``;
   a position moved by ``delta`` moves the velocity by ``delta`` too, since
   it was predicted with it) -- EVALUATE;
6. UPDATEREFSET: better solutions replace the worst; the SS stage repeats
   until no new solution enters the RefSet (at most ``max_rounds``);
7. INCLUDE: the RefSet replaces the worst particles;
8. SELECT and DIFFUSE: systematic resampling by the fitness weights (the
   diffusion is the prediction noise of the next step).

The estimate is the weighted mean of the particles after INCLUDE. The number
of fitness evaluations (``evaluations``, per step) varies from frame to frame
(paper 002: "SSPF is time-adaptive since the number of evaluations of the
weighting function changes in each time step").

:class:`ScatterSearchPF` is the :class:`~fusion_pf.filter.base.Tracker` (one per
target: several targets run one each in the tracking pipeline).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence

import numpy as np

from fusion_pf.cues.base import Measurement
from fusion_pf.errors import InputError
from fusion_pf.rng import as_rng

from .base import Estimate, Tracker
from .estimate import weighted_covariance, weighted_mean
from .likelihood import DEFAULT_NOISE_PX, JointLikelihood
from .motion import DEFAULT_PROCESS_NOISE, FrameClock, check_process_noise, noise_std
from .pf import check_prior, check_timestamp, fused_position
from .resample import systematic

__all__ = ["ScatterSearchPF", "ScatterSearchCore", "diverse_subset"]


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


def _check_int(name: str, value, lo: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lo:
        raise InputError(f"{name} must be an int >= {lo}, got {value!r}")
    return int(value)


class ScatterSearchCore:
    """The SSPF machinery over particles of K targets, shape (N, K, 4) (module docstring).

    Parameters
    ----------
    n_targets : int
        K (>= 1).
    n_particles, refset_size, process_noise, step_px, min_step_px, max_rounds,
    init_spread_px, init_velocity_px, rng
        As for :class:`ScatterSearchPF`.

    Attributes
    ----------
    x : ndarray, shape (N, K, 4)
        The particles (None until initialised).
    evaluations : int
        Fitness evaluations in the last :meth:`update`.
    total_evaluations : int
    """

    def __init__(
        self,
        n_targets: int,
        *,
        n_particles: int,
        refset_size: int,
        process_noise,
        step_px: float,
        min_step_px: float,
        max_rounds: int,
        init_spread_px: float,
        init_velocity_px: float,
        rng,
    ) -> None:
        self.k = _check_int("n_targets", n_targets, 1)
        self.n = _check_int("n_particles", n_particles, 2)
        self.b = _check_int("refset_size", refset_size, 2)
        if self.b % 2 or self.b > self.n:
            raise InputError(f"refset_size must be an even int in [2, n_particles={self.n}], got {refset_size!r}")
        if not (0.0 < float(min_step_px) <= float(step_px) and math.isfinite(float(step_px))):
            raise InputError(f"need 0 < min_step_px <= step_px (finite), got {min_step_px!r} and {step_px!r}")
        self.max_rounds = _check_int("max_rounds", max_rounds, 1)
        self.step_px, self.min_step_px = float(step_px), float(min_step_px)
        self.std_unit = noise_std(check_process_noise(process_noise), 1.0)
        self.init_std = np.array([init_spread_px] * 2 + [init_velocity_px] * 2, dtype=np.float64)
        self.rng = as_rng(rng)
        if self.k > 1:
            # every mix of two solutions' targets but the two solutions themselves
            masks = [m for m in itertools.product((False, True), repeat=self.k) if 0 < sum(m) < self.k]
            self._masks = np.array(masks)[:, :, None]
        else:
            # position of one, velocity of the other (both ways)
            self._masks = np.array([[[True, True, False, False]], [[False, False, True, True]]])
        self.x: np.ndarray | None = None
        self.evaluations = 0
        self.total_evaluations = 0

    def initialise(self, centres: np.ndarray, which: np.ndarray | None = None) -> None:
        """Particles of the targets ``which`` (all by default) ~ N(centre, init spread^2)."""
        if self.x is None:
            self.x = np.zeros((self.n, self.k, 4))
        which = np.arange(self.k) if which is None else which
        noise = self.rng.standard_normal((self.n, len(which), 4))
        self.x[:, which] = centres[which] + self.init_std * noise

    def predict(self, dt: float) -> None:
        """PREDICT (eq. 5 of paper 002): ``x += dt v``, Gaussian noise ``std * sqrt(dt)``."""
        assert self.x is not None, "predict() before initialise()"
        self.x[..., :2] += dt * self.x[..., 2:]
        self.x += self.std_unit * math.sqrt(dt) * self.rng.standard_normal(self.x.shape)

    def fitness(self, states: np.ndarray, z_bar: np.ndarray, precision: np.ndarray) -> np.ndarray:
        """EVALUATE states (M, K, 4): ``sum_k -P_k |p_k - z_bar_k|^2 / 2``; counts M evaluations."""
        self.evaluations += len(states)
        d2 = ((states[..., :2] - z_bar) ** 2).sum(axis=2)
        # log Lh = sum_k -P_k |p_k - z_bar_k|^2 / 2 (+ const)   (paper 003 eqs. 5-7)
        return -0.5 * d2 @ precision

    def improve(self, sol: np.ndarray, fit: float, z_bar, precision) -> tuple[np.ndarray, float]:
        """IMPROVE: pattern search on the positions of one solution (K, 4)."""
        step = self.step_px
        # neighbour m moves target m // 4 along +-u or +-v; the velocity takes the same
        # correction (the position was predicted with it: p = p_prev + v)
        moves = np.zeros((4 * self.k, self.k, 4))
        for t in range(self.k):
            moves[4 * t : 4 * t + 4, t, :2] = ((1.0, 0.0), (-1.0, 0.0), (0.0, 1.0), (0.0, -1.0))
        moves[..., 2:] = moves[..., :2]
        while step >= self.min_step_px:
            nb = sol[None] + step * moves
            f = self.fitness(nb, z_bar, precision)
            j = int(np.argmax(f))
            if f[j] > fit:
                sol, fit = nb[j], float(f[j])
            else:
                step *= 0.5
        return sol, fit

    def scatter_search(self, x: np.ndarray, fit: np.ndarray, z_bar, precision) -> tuple[np.ndarray, np.ndarray]:
        """MAKEREFSET, COMBINE, IMPROVE, UPDATEREFSET until the RefSet stops improving."""
        half = self.b // 2
        best = np.argsort(fit)[::-1][:half]
        ref_idx = np.concatenate([best, diverse_subset(x[..., :2].reshape(len(x), -1), best, half)])
        ref, ref_fit = x[ref_idx].copy(), fit[ref_idx].copy()
        i, j = np.triu_indices(len(ref), 1)
        for _ in range(self.max_rounds):
            a, b = ref[i], ref[j]
            mixes = np.where(self._masks, a[:, None], b[:, None]).reshape(-1, self.k, 4)
            trials = np.concatenate([0.5 * (a + b), mixes])
            tfit = self.fitness(trials, z_bar, precision)
            top = int(np.argmax(tfit))
            if tfit[top] <= ref_fit.min():
                break
            sol, sfit = self.improve(trials[top], float(tfit[top]), z_bar, precision)
            worst = int(np.argmin(ref_fit))
            ref[worst], ref_fit[worst] = sol, sfit
        return ref, ref_fit

    def update(self, z_bar: np.ndarray, precision: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """EVALUATE, scatter search, INCLUDE, estimate, SELECT.

        Parameters
        ----------
        z_bar : ndarray, shape (K, 2)
            Fused cue per target (any finite value where ``precision`` is 0).
        precision : ndarray, shape (K,)
            ``sum_s 1 / sigma_s^2`` of each target's cues (0: no cue).

        Returns
        -------
        estimate : ndarray, shape (K, 4)
            Weighted mean of the particles after INCLUDE.
        cov : ndarray, shape (K, 2, 2)
            Weighted position covariance per target.
        ess : float
        """
        self.evaluations = 0
        x = self.x
        assert x is not None, "update() before initialise()"
        fit = self.fitness(x, z_bar, precision)
        ref, ref_fit = self.scatter_search(x, fit, z_bar, precision)
        # INCLUDE: the RefSet replaces the worst particles
        worst = np.argsort(fit)[: len(ref)]
        x[worst], fit[worst] = ref, ref_fit
        w = np.exp(fit - fit.max())
        w /= w.sum()
        est = np.einsum("n,nkd->kd", w, x)
        cov = np.stack([weighted_covariance(x[:, t, :2], w, est[t, :2]) for t in range(self.k)])
        ess = 1.0 / float(w @ w)
        # SELECT (the next PREDICT's noise is the DIFFUSE stage); the fitness says nothing
        # about a target without a cue, so its components are not selected by the others' weights
        selected = x[systematic(w, self.rng)]
        silent = precision <= 0
        selected[:, silent] = x[:, silent]
        self.x = selected
        self.total_evaluations += self.evaluations
        return est, cov, ess


def _fused(ms: Sequence[Measurement], noise_px: Mapping[str, float]) -> tuple[np.ndarray, float]:
    """``(z_bar, P)``: precision-weighted cue mean and total precision (``(0, 0), 0`` without cues)."""
    if not ms:
        return np.zeros(2), 0.0
    sigma = {m.source: noise_px[m.source] for m in ms}
    return fused_position(ms, sigma), float(sum(1.0 / sigma[m.source] ** 2 for m in ms))


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
        process_noise: tuple[float, float] = DEFAULT_PROCESS_NOISE,
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
        self._core = ScatterSearchCore(
            1,
            n_particles=n_particles,
            refset_size=refset_size,
            process_noise=process_noise,
            step_px=step_px,
            min_step_px=min_step_px,
            max_rounds=max_rounds,
            init_spread_px=init_spread_px,
            init_velocity_px=init_velocity_px,
            rng=rng,
        )
        self.n_particles = self._core.n
        self.process_noise = check_process_noise(process_noise)
        self._like = JointLikelihood(noise_px)
        self.noise_px = self._like.noise_px
        start = check_prior(prior)
        self._clock = FrameClock(frame_period_ns)
        self.reset(start)

    @property
    def particles(self) -> np.ndarray:
        """Current particles, shape (N, 4)."""
        x = self._core.x
        if x is None:
            raise RuntimeError("ScatterSearchPF has no particles before it is initialised")
        return x[:, 0]

    @property
    def evaluations(self) -> int:
        """Fitness evaluations in the last step."""
        return self._core.evaluations

    @property
    def total_evaluations(self) -> int:
        """Fitness evaluations since construction."""
        return self._core.total_evaluations

    def set_process_noise(self, process_noise: tuple[float, float]) -> None:
        """Change the process noise ``(pos px, vel px/frame)`` from the next step on."""
        self.process_noise = check_process_noise(process_noise)
        self._core.std_unit = noise_std(self.process_noise, 1.0)

    def reset(self, prior=None) -> None:
        """Forget the particles and any earlier prior (the :meth:`~fusion_pf.filter.base.Tracker.reset` contract): start at
        ``prior`` (``(u, v)`` or ``(u, v, du, dv)``) when given, else from the next measurement. A prior kept across
        resets started the filter that re-acquires a lost palm at its last start, wherever the palm came back."""
        start = check_prior(prior)
        self._last_ns: int | None = None
        self._core.x = None
        self.initialised = False
        if start is not None:
            self._core.initialise(start[None])
            self.initialised = True

    def step(self, timestamp_ns: int, measurements: Sequence[Measurement]) -> Estimate | None:
        """PREDICT, EVALUATE, scatter search, INCLUDE, estimate, SELECT (module docstring).

        Returns
        -------
        Estimate or None
            None until initialised; ``ess`` is that of the fitness weights.
        """
        t = check_timestamp(timestamp_ns, self._last_ns)
        ms = self._like.check(measurements)
        core = self._core
        core.evaluations = 0
        z_bar, precision = _fused(ms, self.noise_px)
        if not self.initialised:
            if not ms:
                return None
            core.initialise(np.concatenate([z_bar, [0.0, 0.0]])[None])
            self.initialised = True
        elif self._last_ns is not None:
            core.predict(self._clock.steps(t, self._last_ns))
        self._last_ns = t
        assert core.x is not None, "initialised above"
        n = core.n
        if not ms:
            w = np.full(n, 1.0 / n)
            pos = core.x[:, 0, :2]
            est = weighted_mean(pos, w)
            return Estimate(
                t, float(est[0]), float(est[1]), float(n), False, n, weighted_covariance(pos, w), pos.copy()
            )
        est, cov, ess = core.update(z_bar[None], np.array([precision]))
        return Estimate(t, float(est[0, 0]), float(est[0, 1]), ess, True, n, cov[0], core.x[:, 0, :2].copy())
