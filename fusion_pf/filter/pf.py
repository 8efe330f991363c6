"""The data-fusion particle filter of paper 003 (§3.2-3.6).

One :meth:`ParticleFilter.step` per frame runs the paper's phases in order:

1. initialisation (first step only): particles around the first available
   measurements (their precision-weighted mean) or around ``prior``, weights 1/N;
2. dynamic model: constant-velocity prediction (eq. 4), one frame step per call
   (see :mod:`fusion_pf.filter.motion`), optionally with manoeuvres (a
   heavy-tailed mixture, :mod:`fusion_pf.filter.proposal`); with
   ``proposal="guided"`` the particles are drawn from the optimal proposal
   given the frame's most precise cue that the prediction explains instead,
   which removes the bootstrap filter's lag when the palm moves further than
   the process noise;
3. observation model: squared distance per source (eq. 5), per-source
   likelihood (eq. 6, or the robust mixture), each normalised (step 3), joint
   likelihood as their product (eq. 7) -- all as sums of logs -- and the weight
   update (eq. 3) with normalisation (eq. 2);
4. estimation: weighted mean of the particles (or the paper's robust mean of the
   10 % largest-weighted particles, or MAP);
5. resampling: ESS = 1 / sum(w^2); resample (residual by default) when
   ESS < 2/3 N.

A source absent from a frame contributes nothing; a frame without measurements
only predicts. When the particles have lost the target -- Gaussian: the joint
likelihood of every particle underflows float64, where the paper's linear-space
weights would become 0/0; robust: every cue is an outlier for every particle --
the particles are re-initialised around the measurements (counted in
``reinitialisations``) instead of producing NaN weights or ignoring the cues
forever.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement
from fusion_pf.rng import as_rng

from .base import Estimate, Tracker, check_prior, check_timestamp, fused_position
from .estimate import ESTIMATORS
from .kernel import ESTIMATOR_CODES, kernels, stream, warm_up
from .likelihood import DEFAULT_NOISE_PX, DEFAULT_OUTLIER_AREA_PX2, MIN_QUALITY, UNDERFLOW_LOG, JointLikelihood
from .motion import DEFAULT_PROCESS_NOISE, FrameClock, check_process_noise, noise_std, predict
from .proposal import PROPOSALS, check_manoeuvre, guided_positions, prior_positions
from .resample import RESAMPLERS, residual_trusted

__all__ = ["GATE", "PRECISE", "QUALITY_FALL", "ParticleFilter"]

#: Chi-square 99 % point of 2 degrees of freedom, ``-2 ln 0.01``: the guided proposal's anchor gate.
GATE = -2.0 * math.log(0.01)
#: The anchor's displacement measures the velocity when its noise ``sqrt(2) sigma_white / dt`` is at most this
#: share of eq. 4's velocity noise (:meth:`ParticleFilter._velocity`).
PRECISE = 0.5
#: ... and its quality fell by at most this much since the last step (a blob whose confidence falls is changing
#: shape, e.g. dragged onto the forearm: its displacement is not the palm's).
QUALITY_FALL = 0.05


class ParticleFilter(Tracker):
    """Paper 003's data-fusion particle filter over colour, depth and skeleton cues.

    Parameters
    ----------
    n_particles : int
        Number of particles N (>= 1).
    process_noise : (float, float)
        ``(pos_px, vel_px)``: std of the eq. 4 noise on position (px) and
        velocity (px / frame) per frame step.
    noise_px : mapping of str to float
        Per-source measurement noise sigma in px (eq. 6 uses ``rho = sigma^2``).
        Default :data:`~fusion_pf.filter.likelihood.DEFAULT_NOISE_PX`.
    likelihood : {"gaussian", "robust"}
        The paper's Gaussian (eq. 6) or the Gaussian + uniform outlier mixture.
    outlier_prob : float
        Robust only: outlier probability eps per source, in (0, 1).
    use_quality : bool
        Robust only: widen a source's sigma by ``1 / sqrt(max(quality, min_quality))``.
    min_quality : float
        Robust only: quality floor of the widening.
    outlier_area_px2 : float
        Robust only: area of the uniform outlier density (default 1280 x 800).
    resampler : {"residual", "multinomial", "stratified", "systematic"}
        Resampling scheme (paper: residual).
    ess_threshold : float
        Resample when ``ESS < ess_threshold * N`` (paper: 2/3), in [0, 1].
    estimator : {"weighted_mean", "robust_mean", "map"}
        Point estimate: the weighted mean of all particles (default; the
        posterior mean, more accurate at equal N than the paper's robust mean of
        the top 10 %, ``benchmarks/bench.py``), the paper's choice, or MAP.
    top_fraction : float
        Fraction of particles the robust mean averages, in (0, 1].
    init_spread_px : float
        Std of the initial particle positions around the first measurement / prior.
    init_velocity_px : float
        Std of the initial particle velocities (px / frame) around 0 / the prior's.
    proposal : {"prior", "guided"}
        Where particles move to. ``"prior"``: the paper's bootstrap filter,
        eq. 4 then weights from eqs. 5-7. ``"guided"``: the locally optimal
        proposal (Doucet, Godsill & Andrieu 2000) for the most precise source
        of the frame that the prediction explains (the *anchor*, see
        :meth:`_anchor`): each particle is drawn from
        ``p(x_k | x_(k-1), z_anchor)``, exact for eq. 4's Gaussian position
        noise, the manoeuvre mixture and the robust outlier mixture (a mixture
        of up to four Gaussians per particle), and weighted by
        ``p(z_anchor | x_(k-1))`` times the other sources' eqs. 5-7; with the
        robust likelihood, the velocities are drawn given a precise anchor's
        displacement since the last step when its white noise is known
        (:meth:`set_white_noise`, :meth:`_velocity`). Without a
        measurement it is the prior proposal.
    manoeuvre : (float, float)
        ``(prob, std_px)``: with probability ``prob`` a step's position noise
        has std ``std_px`` instead of ``process_noise[0]`` (a heavy-tailed
        eq. 4 for hands that start, stop or turn faster than a constant
        velocity allows); ``prob = 0`` is eq. 4.
    prior : (u, v) or (u, v, du, dv), optional
        State at the first step (which therefore does not predict); without it
        the filter waits for the first measurement.
    frame_period_ns : float, "auto" or None
        None (default, as in the paper): every step is one frame step. A
        number: a step spans ``(t_k - t_(k-1)) / frame_period_ns`` frame steps.
        ``"auto"``: the period is learnt from the timestamps and dropped frames
        are bridged in whole steps (:class:`~fusion_pf.filter.motion.FrameClock`).
    keep_particles : bool
        Copy the particle positions into each :class:`Estimate` (``particles``:
        the set after this step, i.e. after resampling if it happened, matching
        :attr:`log_weights`); False saves that copy (benchmarks, sweeps).
    rng : numpy.random.Generator, int or None
        Random source (see :func:`fusion_pf.rng.as_rng`); an int seed or None
        makes an SFC64 Generator. A Generator is used as given. Eq. 4's
        normals (without manoeuvres) come from a second SFC64 stream seeded
        from it by the first step that draws them
        (:func:`~fusion_pf.filter.kernel.stream`).

    Attributes
    ----------
    particles : ndarray, shape (N, 4)
        Current particles ``(u, v, du, dv)`` after the last step (a view; it is
        overwritten by the next step).
    log_weights : ndarray, shape (N,)
        Their normalised log-weights.
    initialised : bool
        Whether the filter holds a particle set.
    reinitialisations : int
        How many times the particles were re-initialised because they had
        lost the target (module docstring).

    Notes
    -----
    The phases run as a few compiled passes over preallocated ``(4, N)``
    buffers (:mod:`~fusion_pf.filter.kernel`; the normals of eq. 4 come from
    ``rng``, drawn by numpy below 1000 particles and inside the kernel from
    there on, the same numbers either way; systematic resampling copies the
    drawn particles in its own pass): ~20 us per step at N = 100, ~0.06 ms at
    N = 1e3, ~0.35 ms at N = 1e4, ~7 ms at N = 1e5 on one core (interleaved
    with Stone Soup's equivalent step, ``benchmarks/bench.py``: 8-22x faster;
    1e4 is the weakest), dominated from N ~ 1e3 on by the 4 N normal draws
    (~2.5 ns each in the kernel) and the N exponentials of the weights. The kernels are loaded
    from numba's on-disk cache by a background thread started at construction
    (~0.5 s of CPU once per process; after an install or an edit of the kernels
    numba compiles them once, ~5-20 s).
    """

    def __init__(
        self,
        *,
        n_particles: int = 100,
        process_noise: tuple[float, float] = DEFAULT_PROCESS_NOISE,
        noise_px: Mapping[str, float] = DEFAULT_NOISE_PX,
        likelihood: str = "gaussian",
        outlier_prob: float = 0.1,
        use_quality: bool = True,
        min_quality: float = MIN_QUALITY,
        outlier_area_px2: float = DEFAULT_OUTLIER_AREA_PX2,
        resampler: str = "residual",
        ess_threshold: float = 2.0 / 3.0,
        estimator: str = "weighted_mean",
        top_fraction: float = 0.1,
        init_spread_px: float = 20.0,
        init_velocity_px: float = 2.0,
        proposal: str = "prior",
        manoeuvre: tuple[float, float] = (0.0, 0.0),
        prior=None,
        frame_period_ns: float | str | None = None,
        keep_particles: bool = True,
        rng: np.random.Generator | int | None = None,
    ) -> None:
        if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)) or n_particles < 1:
            raise InputError(f"n_particles must be an int >= 1, got {n_particles!r}")
        if resampler not in RESAMPLERS:
            raise InputError(f"resampler must be one of {', '.join(RESAMPLERS)}, got {resampler!r}")
        if estimator not in ESTIMATORS:
            raise InputError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
        if not (0.0 <= float(ess_threshold) <= 1.0):
            raise InputError(f"ess_threshold must be in [0, 1] (fraction of N), got {ess_threshold}")
        if not (0.0 < float(top_fraction) <= 1.0):
            raise InputError(f"top_fraction must be in (0, 1], got {top_fraction}")
        for name, value in (("init_spread_px", init_spread_px), ("init_velocity_px", init_velocity_px)):
            if not (math.isfinite(float(value)) and float(value) >= 0.0):
                raise InputError(f"{name} must be a finite number >= 0, got {value}")
        if proposal not in PROPOSALS:
            raise InputError(f"proposal must be one of {', '.join(PROPOSALS)}, got {proposal!r}")
        self.n_particles = int(n_particles)
        self.process_noise = check_process_noise(process_noise)
        self.proposal = proposal
        self.manoeuvre = check_manoeuvre(manoeuvre)
        self._like = JointLikelihood(
            noise_px,
            likelihood=likelihood,
            outlier_prob=outlier_prob,
            use_quality=use_quality,
            min_quality=min_quality,
            outlier_area_px2=outlier_area_px2,
        )
        self.noise_px = self._like.noise_px
        self.likelihood = likelihood
        self.resampler = resampler
        self._resample = RESAMPLERS[resampler]
        self.ess_threshold = float(ess_threshold)
        self.estimator = estimator
        self._estimator_code = ESTIMATOR_CODES[estimator]
        self.top_fraction = float(top_fraction)
        self._top_k = max(1, math.ceil(self.top_fraction * self.n_particles))
        self.init_spread_px = float(init_spread_px)
        self.init_velocity_px = float(init_velocity_px)
        start = check_prior(prior)
        self._clock = FrameClock(frame_period_ns)
        self.frame_period_ns = self._clock.frame_period_ns
        self.keep_particles = bool(keep_particles)
        self.rng = as_rng(rng, bit_generator=np.random.SFC64)
        # eq. 4's 4 N normals per step come from the kernels' own SFC64 stream, seeded from rng when first used
        self._stream: np.ndarray | None = None
        n = self.n_particles
        # particles stored transposed (4, N): each component is one contiguous row
        self._x = np.empty((4, n))
        self._spare = np.empty((4, n))
        self._noise = np.empty((4, n))
        self._normals = np.empty((4, n), dtype=np.float32)
        self._idx = np.empty(n, dtype=np.int64)
        self._logw = np.empty(n)
        self._w = np.empty(n)
        self._joint = np.empty(n)
        self._std_unit = noise_std(self.process_noise, 1.0)
        self.reinitialisations = 0
        self._expected: np.ndarray | None = None
        # each source's white noise per axis, px (set_white_noise), and the last guided step's anchor
        self._white: dict[str, float] = {}
        self._last_anchor: Measurement | None = None
        # per source its last guided step's measurement, the one before (None: none) and that step's length
        # (frame steps), for _smooth
        self._seen: dict[str, tuple[Measurement, Measurement | None, float]] = {}
        # what _finish does to the weights: 0 nothing, 1 add _joint and normalise, 2 normalise
        self._weighed = 0
        self.reset(start)
        # the compiled step kernels load from numba's cache while the caller gets its first frame
        warm_up()

    @property
    def particles(self) -> np.ndarray:
        """Current particles, shape (N, 4) ``(u, v, du, dv)`` (a view)."""
        return self._x.T

    @property
    def log_weights(self) -> np.ndarray:
        """Normalised log-weights of :attr:`particles`, shape (N,) (a view)."""
        return self._logw

    @property
    def weights(self) -> np.ndarray:
        """Normalised weights of :attr:`particles`, shape (N,) (a view)."""
        return self._w

    def set_process_noise(self, process_noise: tuple[float, float]) -> None:
        """Change the eq. 4 noise ``(pos px, vel px/frame)`` from the next step on."""
        self.process_noise = check_process_noise(process_noise)
        self._std_unit = noise_std(self.process_noise, 1.0)

    def set_white_noise(self, source: str, sigma_px: float | None) -> None:
        """``source``'s white noise per axis, px (the frame-to-frame part of its error; None: unknown).

        The guided proposal measures the velocity with a precise anchor's displacement
        (:meth:`_velocity`); without it the velocity follows eq. 4's walk only.
        """
        if sigma_px is None:
            self._white.pop(source, None)
        elif not (math.isfinite(float(sigma_px)) and float(sigma_px) >= 0.0):
            raise InputError(f"white noise of {source!r} must be a finite number >= 0 px, got {sigma_px}")
        else:
            self._white[source] = float(sigma_px)

    def set_estimator(self, estimator: str) -> None:
        """Use ``estimator`` (one of :data:`~fusion_pf.filter.estimate.ESTIMATORS`) from the next step on."""
        if estimator not in ESTIMATORS:
            raise InputError(f"estimator must be one of {', '.join(ESTIMATORS)}, got {estimator!r}")
        self.estimator = estimator
        self._estimator_code = ESTIMATOR_CODES[estimator]

    def set_outlier_prob(self, source: str, outlier_prob: float) -> None:
        """Robust likelihood: ``source``'s outlier probability from the next step on, in (0, 1)
        (:meth:`~fusion_pf.filter.likelihood.JointLikelihood.set_outlier`)."""
        self._like.set_outlier(source, outlier_prob)

    def predicted(self, timestamp_ns: int) -> tuple[float, float, float] | None:
        """The particles' prediction of the palm at ``timestamp_ns``, before that frame's cues.

        The weighted mean of ``p + dt v`` and its per-axis variance, the particles'
        weighted variance of ``p + dt v`` averaged over the two axes. Eq. 4's
        position noise is left out: it is the most a hand may move in a step (the
        manoeuvres' reach), not the error of a prediction of a hand that moves
        smoothly (issue 23's scenes: the prediction is 1-5 px^2 per axis off, the
        position noise alone 15-240 px^2). None while the filter holds no particles
        or has not stepped yet.

        Returns
        -------
        (u, v, var) or None
            px, px, px^2.
        """
        if not self.initialised or self._last_ns is None:
            return None
        t = check_timestamp(timestamp_ns, self._last_ns)
        dt = self._clock.steps(t, self._last_ns)
        return self._moments(self._x[:2] + dt * self._x[2:])

    def _moments(self, positions: np.ndarray) -> tuple[float, float, float]:
        """Weighted mean ``(u, v)`` of ``positions`` (shape (2, N)) and their per-axis variance."""
        w = self._w
        # mu = sum_i w_i x_i
        mu = positions @ w
        d = positions - mu[:, None]
        # var = sum_i w_i |x_i - mu|^2 / 2
        return float(mu[0]), float(mu[1]), 0.5 * float(np.einsum("ij,ij,j->", d, d, w))

    def reset(self, prior=None) -> None:
        """Forget the particles and any earlier prior (the :meth:`~fusion_pf.filter.base.Tracker.reset` contract): start at
        ``prior`` (``(u, v)`` or ``(u, v, du, dv)``) when given, else from the next measurement. A prior kept across
        resets started the filter that re-acquires a lost palm at its last start, wherever the palm came back."""
        start = check_prior(prior)
        self._last_ns: int | None = None
        self._last_anchor = None
        self._seen = {}
        self.initialised = False
        self._weighed = 0
        if start is not None:
            self._initialise(start)

    def _initialise(self, centre: np.ndarray) -> None:
        """Particles ~ N(centre, spread^2) with weights 1/N (initialisation phase)."""
        std = np.array([self.init_spread_px] * 2 + [self.init_velocity_px] * 2)
        self.rng.standard_normal(out=self._x)
        # x_i = centre + spread (x) N(0, I)
        self._x *= std[:, None]
        self._x += np.asarray(centre, dtype=np.float64)[:, None]
        # w_i = 1 / N
        self._logw.fill(-math.log(self.n_particles))
        self._w.fill(1.0 / self.n_particles)
        self._last_anchor = None
        self._seen = {}
        self.initialised = True

    def _centre_of(self, measurements: Sequence[Measurement]) -> np.ndarray:
        """Initialisation state from measurements: fused position, zero velocity."""
        sigma = {m.source: self._like.noise_px[m.source] for m in measurements}
        return np.concatenate([fused_position(measurements, sigma), [0.0, 0.0]])

    def _update(self, measurements: Sequence[Measurement], top: float | None = None) -> None:
        """Weights from eqs. 5-7 then eq. 3 and eq. 2, re-initialising when the target is lost.

        ``top``: the largest Gaussian log-likelihood when the prediction already computed
        the joint likelihood into ``_joint`` (:meth:`_move`).
        """
        if self._lost(measurements) if top is None else top < UNDERFLOW_LOG:
            self.reinitialisations += 1
            self._initialise(self._centre_of(measurements))
            self._lost(measurements)
        self._weighed = 1

    def _lost(self, measurements: Sequence[Measurement]) -> bool:
        """Normalised joint log-likelihood (eqs. 5-7) into ``_joint``; whether the particles lost the target."""
        k = kernels()
        if self.likelihood == "gaussian":
            zu, zv, total, c = self._like.stacked(measurements)
            # log Lh = -P |p - z_bar|^2 / 2 - C: lost when its maximum underflows float64
            peak = k.gaussian(self._x, zu, zv, -0.5 * total, self._joint)
            return peak - c < UNDERFLOW_LOG
        return not k.robust(self._x, self._like.mixture_rows(measurements), self._joint)

    def step(self, timestamp_ns: int, measurements: Sequence[Measurement]) -> Estimate | None:
        """Run one frame: (initialise |) predict, update, estimate, resample.

        Parameters
        ----------
        timestamp_ns : int
            Frame time; must increase from step to step.
        measurements : sequence of Measurement
            This frame's cues (any subset of the sources in ``noise_px``; a
            missing source contributes nothing).

        Returns
        -------
        Estimate or None
            None until the filter is initialised (no prior, no measurement yet).
        """
        t = check_timestamp(timestamp_ns, self._last_ns)
        ms = self._like.check(measurements)
        if not self.initialised:
            if not ms:
                return None
            self._initialise(self._centre_of(ms))
        elif self._last_ns is not None:
            dt = self._clock.steps(t, self._last_ns)
            if self.proposal == "guided" and ms:
                self._last_ns = t
                self._guided(ms, dt)
                return self._finish(t)
            self._last_anchor = None
            self._seen = {}
            top = self._move(dt, ms)
            if top is not None:
                self._last_ns = t
                self._update(ms, top)
                return self._finish(t)
        self._last_ns = t
        if ms:
            self._update(ms)
        return self._finish(t)

    def _move(self, dt: float, ms: Sequence[Measurement]) -> float | None:
        """The prior proposal: eq. 4 over ``dt`` frame steps (with manoeuvres when configured).

        Without manoeuvres one compiled pass also computes the Gaussian likelihood of ``ms``
        (eqs. 5-7, unnormalised) into ``_joint`` and returns its largest log value; else None.
        """
        std = self._std_unit if dt == 1.0 else self._std_unit * math.sqrt(dt)
        if self.manoeuvre[0] == 0.0:
            # components without noise (std (pos, pos, vel, vel) of 0) draw nothing
            lo = 0 if std[0] > 0.0 else 2
            hi = 4 if std[2] > 0.0 else 2
            gaussian = bool(ms) and self.likelihood == "gaussian"
            # log Lh = -P |p - z_bar|^2 / 2 - C
            zu, zv, total, c = self._like.stacked(ms) if gaussian else (0.0, 0.0, 0.0, 0.0)
            if self._stream is None:
                self._stream = stream(self.rng)
            # x_k = M x_(k-1) + gamma (x) sigma_x   (eq. 4), then log Lh
            peak = kernels().move(
                self._x, self._stream, self._normals, std, float(dt), lo, hi, zu, zv, -0.5 * total, self._joint
            )
            return peak - c if gaussian else None
        # eq. 4 without its position noise, then that noise and the manoeuvres
        predict(self._x, np.array([0.0, 0.0, std[2], std[3]]), self.rng, dt=dt, scratch=self._noise)
        prior_positions(self._x, self.process_noise[0], self.manoeuvre, self.rng, dt)
        return None

    def _guided(self, ms: Sequence[Measurement], dt: float) -> None:
        """Guided step: positions from the anchor cue's optimal proposal, weights from all cues.

        The anchor is the most precise measurement (smallest quality-widened
        sigma); with the Gaussian likelihood it is the product of all cues
        (one Gaussian around their precision-weighted mean, see
        :class:`~fusion_pf.filter.likelihood.JointLikelihood`). When the anchor
        is an outlier for every particle and so are the other cues, the
        particles are re-initialised around the cues as in the prior proposal.
        With the robust likelihood, a precise anchor's displacement since the
        last step also measures the velocity (:meth:`_velocity`), and while the
        anchor is explained a cue the prediction cannot explain (:meth:`_anchor`)
        neither anchors nor weighs.
        """
        std = self._std_unit if dt == 1.0 else self._std_unit * math.sqrt(dt)
        like = self._like
        if like.likelihood == "gaussian":
            prec = np.array([1.0 / like.noise_px[m.source] ** 2 for m in ms])
            # z_bar = sum_phi z_phi / rho_phi / P, sigma^2 = 1 / P   (eq. 7 as one Gaussian)
            z = tuple(prec @ np.array([[m.u, m.v] for m in ms]) / prec.sum())
            sigma, rest, outlier, velocity = 1.0 / math.sqrt(prec.sum()), [], None, None
        else:
            anchor, near = self._anchor(ms, dt)
            explained = bool(near)
            z, sigma = (anchor.u, anchor.v), like.sigma(anchor)
            # a cue the prediction cannot explain while the anchor is explained is an outlier to every particle
            rest = [m for m in (near or ms) if m is not anchor]
            outlier = (like.outlier(anchor), like.outlier_area_px2)
            velocity = self._velocity(anchor, dt, std[2]) if explained else None
            self._last_anchor = anchor if explained else None
            seen = self._seen
            self._seen = {m.source: (m, seen[m.source][0] if m.source in seen else None, dt) for m in ms}
        # velocity: v_k = v_(k-1) + sigma_v N(0, I), or drawn given the anchor's displacement below;
        # positions: mu = p_(k-1) + dt v_(k-1)
        walk = std[2:] if velocity is None else np.zeros(2)
        predict(self._x, np.array([0.0, 0.0, walk[0], walk[1]]), self.rng, dt=dt, scratch=self._noise)
        log_ev, self._expected, inlier = guided_positions(
            self._x[:2], self._x[2:], self.process_noise[0], self.manoeuvre, z, sigma, self.rng, outlier=outlier, dt=dt
        )
        if velocity is not None:
            log_ev += self._measure_velocity(velocity, std[2])
        if rest:
            inlier = (not self._lost(rest)) or inlier
        if not inlier:
            self._expected = None
            self.reinitialisations += 1
            self._initialise(self._centre_of(ms))
            self._update(ms)
            return
        # w_k ∝ w_(k-1) p(z_anchor | x_(k-1)) [p(y | v)] prod_(other phi) p(z_phi | x_k)   (eq. 3, guided proposal)
        self._logw += log_ev
        self._weighed = 1 if rest else 2

    def _smooth(self, m: Measurement, dt: float) -> bool:
        """Whether ``m`` continues its source's path: its white noise is known and its second difference is within the gate.

        The second difference ``a = z_k - z_(k-1) - r (z_(k-1) - z_(k-2))`` over the last two guided steps
        (``r`` the ratio of their lengths) of a cue that follows the palm is white noise of per-axis variance
        ``(1 + (1 + r)^2 + r^2) sigma^2`` plus the palm's acceleration, within the chi-square gate of that
        noise, eq. 4's walk and position noise (``dt^2 walk^2 + dt q^2``); a cue that jumped to another
        blob is beyond it (issue 23, gen-31728-near-360 frame 59: a 2 px depth cue 42 px off its path).
        Only a cue whose white noise is known (:meth:`set_white_noise`: a confident measurement) is judged.
        """
        last, before, step = self._seen.get(m.source, (None, None, 1.0))
        if m.source not in self._white or last is None or before is None:
            return False
        r = dt / step
        # a = z_k - z_(k-1) - r (z_(k-1) - z_(k-2))
        au = m.u - last.u - r * (last.u - before.u)
        av = m.v - last.v - r * (last.v - before.v)
        noise = (1.0 + (1.0 + r) ** 2 + r * r) * self._like.sigma(m) ** 2
        walk = self._std_unit[2]
        return au * au + av * av <= GATE * (noise + dt * dt * walk * walk + dt * self.process_noise[0] ** 2)

    def _velocity(self, anchor: Measurement, dt: float, walk: float) -> tuple[float, float, float] | None:
        """The velocity the anchor's displacement measures, ``(y_u, y_v, sigma_y)`` px/frame, or None.

        A palm seen by a cue whose white noise ``sigma_w`` is far below the motion the model allows
        (issue 23: far hands, a 0.2-0.9 px depth cue) moves, between two frames, by its velocity
        plus ``sqrt(2) sigma_w`` of noise: ``y = (z_k - z_(k-1)) / dt`` measures it with
        ``sigma_y = sqrt(2) sigma_w / dt``, while eq. 4's walk of ``walk`` px/frame per step and the
        particles' selection by the position cue alone let the cloud's velocity lag a hand that turns
        round by 6-12 px/frame. Only when the same source anchored the last step, both anchors were
        explained by the prediction, the displacement is one the motion model allows (within the
        chi-square gate of the cloud's velocity ``v_bar``, spread ``V``, the walk and the position
        noise ``q``: a cloud widened by a jump to another blob explains the jump back, this gate not),
        its white noise is known, ``sigma_y <= PRECISE walk`` and its quality fell by at most
        :data:`QUALITY_FALL` (issue 23's far scenes: a depth blob dragged off the palm at 1.5-5 px/frame,
        its quality falling by 0.09-0.15 at the first frame, while a steady one moves by 0.05 at most).
        """
        last = self._last_anchor
        white = self._white.get(anchor.source)
        if (
            last is None
            or white is None
            or last.source != anchor.source
            or anchor.quality < last.quality - QUALITY_FALL
        ):
            return None
        sigma_y = math.sqrt(2.0) * white / dt
        if not sigma_y <= PRECISE * walk:
            return None
        yu, yv = (anchor.u - last.u) / dt, (anchor.v - last.v) / dt
        mean_u, mean_v, var = self._moments(self._x[2:])
        # the displacement is one the motion model allows: |y - v_bar|^2 <= GATE (sigma_y^2 + V + walk^2 + q^2 / dt)
        if (yu - mean_u) ** 2 + (yv - mean_v) ** 2 > GATE * (
            sigma_y * sigma_y + var + walk * walk + self.process_noise[0] ** 2 / dt
        ):
            return None
        return yu, yv, sigma_y

    def _measure_velocity(self, velocity: tuple[float, float, float], walk: float) -> np.ndarray:
        """Draw the velocities given the anchor's displacement (the optimal proposal); its log-evidence per particle.

        Per particle, prior ``v_k ~ N(v, walk^2)`` (``v`` its velocity before eq. 4's walk, a
        manoeuvre included) and ``y ~ N(v_k, sigma_y^2)``: ``v_k ~ N(v + b (y - v), b sigma_y^2)``
        with ``b = walk^2 / (walk^2 + sigma_y^2)``, evidence ``N2(y; v, walk^2 + sigma_y^2)``.
        """
        yu, yv, sigma_y = velocity
        total = walk * walk + sigma_y * sigma_y
        gain = walk * walk / total
        spread = math.sqrt(gain) * sigma_y
        vel = self._x[2:]
        du = yu - vel[0]
        dv = yv - vel[1]
        # log N2(y; v, T) = -|y - v|^2 / (2 T) - log(2 pi T)
        log_ev = -(du * du + dv * dv) / (2.0 * total) - math.log(2.0 * math.pi * total)
        noise = self.rng.standard_normal((2, self.n_particles))
        # v_k = v + b (y - v) + sqrt(b) sigma_y N(0, I)
        vel[0] += gain * du + spread * noise[0]
        vel[1] += gain * dv + spread * noise[1]
        return log_ev

    def _anchor(self, ms: Sequence[Measurement], dt: float) -> tuple[Measurement, list[Measurement]]:
        """The guided proposal's anchor: the most precise of the cues the prediction can explain; those cues.

        A cue the prediction explains lies within the chi-square 99 % gate of 2 degrees of freedom of
        the bulk of the prediction, ``|z - mu|^2 <= GATE (sigma_eff^2 + P + dt q^2)`` with ``mu`` the
        particles' predicted mean (velocities applied: ``p + dt v``) and ``P`` their bulk's per-axis
        variance (:meth:`_bulk`); a cue that continues its own path (:meth:`_smooth`) within that gate
        of the whole cloud's variance (its manoeuvres too: the track may be the one that is off); and two
        cues outside it that agree with each other (``|z_a - z_b|^2 <= GATE (sigma_a^2 + sigma_b^2)``:
        the track is what is off, issue 23, gen-31615-far-560 frames 114-118, depth and the skeleton on
        the palm, a colour blob leading the track 15-25 px off). Without such a cue, the most precise of
        all (the palm moved beyond the motion model), and every cue weighs. Otherwise a cue outside is an
        outlier to every particle (:meth:`_guided`): a precise cue that jumped to a wrong blob neither
        draws the particles to it through the manoeuvre component (issue 23: a depth blob 38 px off
        pulled the estimate 22 px on skeleton-best, frame 4) nor, as a weight, the step to the particles
        that manoeuvred towards it (gen-31728-near-360 frames 59-83: a 2 px depth cue jumped 42 px to a
        blob beside a broad skeleton, and the track followed it 40-120 px off for 25 frames).

        Explained cues that disagree with each other are not put to a vote. Anchoring instead at the cue, or the
        subset of cues, that best explains the frame (the prediction as prior, the cues left out as outliers) won
        where two cues on the palm stood against a precise one that jumped or drifted (issue 23, tune
        scene tune20-40045-far-560 2.63 -> 1.51 px) but lost as often where two broad, low-quality cues on one
        wrong blob stood against a precise one on the palm: a broad cue costs little to keep and a precise one
        much to drop (tune20-40060-colour-480 frames 58-59, 4-5 -> 28-35 px off). On 180 held-out scenes the fused
        RMSE was 0.8 % worse (geometric mean), two colour scenes 1.7-1.8x; the evidence of one frame cannot tell
        the two apart.
        """
        like = self._like
        positions = self._x[:2] + dt * self._x[2:]
        q2 = dt * self.process_noise[0] ** 2
        bulk_u, bulk_v, bulk = self._bulk(positions)
        mu_u, mu_v, spread = self._moments(positions)

        def explained(m: Measurement) -> bool:
            s2 = like.sigma(m) ** 2
            if (m.u - bulk_u) ** 2 + (m.v - bulk_v) ** 2 <= GATE * (s2 + bulk + q2):
                return True
            # the whole cloud, its manoeuvres too, for a cue that continues its own path
            return (m.u - mu_u) ** 2 + (m.v - mu_v) ** 2 <= GATE * (s2 + spread + q2) and self._smooth(m, dt)

        near = [m for m in ms if explained(m)]
        outside = [m for m in ms if not any(m is n for n in near)]
        # two cues the prediction cannot explain that agree with each other: the track is what is off
        near += [
            m
            for m in outside
            if any(
                o is not m and (m.u - o.u) ** 2 + (m.v - o.v) ** 2 <= GATE * (like.sigma(m) ** 2 + like.sigma(o) ** 2)
                for o in outside
            )
        ]
        return min(near or ms, key=like.expected_variance), near

    def _bulk(self, positions: np.ndarray) -> tuple[float, float, float]:
        """Weighted mean ``(u, v)`` of ``positions`` (shape (2, N)) and the per-axis variance of their bulk.

        The variance from the weighted median of the squared distances to the mean: for a Gaussian
        cloud of per-axis variance ``s^2``, ``|d|^2 / 2`` is exponential with mean ``s^2`` and median
        ``ln 2 s^2``. The weighted variance (:meth:`_moments`) counts the particles that drew a
        manoeuvre and kept its velocity change (a broad anchor does not prune them), so one step with
        a broad anchor widened it 5-8 fold and a wrong blob 40 px off entered the gate.
        """
        w = self._w
        mu = positions @ w
        d2 = np.einsum("ij,ij->j", positions - mu[:, None], positions - mu[:, None])
        order = np.argsort(d2)
        # the smallest d^2 whose cumulative weight reaches one half
        median = float(d2[order[min(int(np.searchsorted(np.cumsum(w[order]), 0.5)), len(order) - 1)]])
        return float(mu[0]), float(mu[1]), median / (2.0 * math.log(2.0))

    def _finish(self, t: int) -> Estimate:
        """Weight update (eqs. 3, 2) when the step had measurements, estimation phase, ESS and resampling."""
        n = self.n_particles
        # guided steps estimate from E[x_k | x_(k-1), z] (Rao-Blackwellised over the proposal's components)
        centres = self._x[:2] if self._expected is None else self._expected
        self._expected = None
        k = kernels()
        peak = 0.0
        if self._weighed:
            # w = exp(log w - max log w), log w with the joint likelihood added first (eq. 3) when _weighed is 1
            peak = k.shift(self._logw, self._joint, self._weighed == 1, self._w)
            np.exp(self._w, out=self._w)
        u, v, cuu, cuv, cvv, ess = k.weigh(
            self._logw, self._w, peak, self._weighed > 0, self._x, centres, self._estimator_code, self._top_k
        )
        self._weighed = 0
        w = self._w
        resampled = ess < self.ess_threshold * n
        if resampled:
            if self.resampler == "systematic":
                # _joint is free once weighed: the kernel's cumulative-weight buffer
                k.systematic(w, self.rng.random(), self._x, self._spare, self._joint, self._idx)
            else:
                idx = residual_trusted(w, self.rng) if self.resampler == "residual" else self._resample(w, self.rng)
                self._x.take(idx, axis=1, mode="clip", out=self._spare)
            self._x, self._spare = self._spare, self._x
            # w_i = 1 / N after resampling
            self._logw.fill(-math.log(n))
            w.fill(1.0 / n)
        particles = np.ascontiguousarray(self._x[:2].T) if self.keep_particles else None
        return Estimate(
            timestamp_ns=t,
            u=u,
            v=v,
            ess=ess,
            resampled=bool(resampled),
            n_particles=n,
            cov=np.array([[cuu, cuv], [cuv, cvv]]),
            particles=particles,
        )
