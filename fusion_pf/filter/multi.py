"""Multi-target tracking: paper 000's multi-modal particle filter with k-means clustering and supervision.

One particle set ``(N, 4)`` of states ``(u, v, du, dv)`` represents all K targets
(paper 000 §III: "the estimation for each one of the arms is merged in a single
[...] multi-modal pdf"). Every particle carries a cluster label (its target).
One :meth:`KMeansParticleFilter.step` per frame runs the paper's sub-systems:

* **propagation** (§III-E): the constant-velocity model of paper 003 eq. 4 (as
  :func:`~fusion_pf.filter.motion.predict`) with a per-target process noise that
  the supervision scales;
* **weight computation** (§III-B): each cluster is weighed with the
  measurements associated to its target (Gaussian likelihood of paper 003 eqs.
  5-7, :class:`~fusion_pf.filter.likelihood.JointLikelihood`); the estimate of
  a target is the likelihood-weighted mean of the *elite* of its cluster, the
  particles whose membership exceeds 80 % of the cluster's mean membership (eq. 8);
* **re-sampling** (§III-C): systematic, per cluster, so every target keeps its
  share ``N / K`` of the particles ("the re-sampling [regenerates] exactly the
  same number of particles for each one of the clusters");
* **clustering** (§III-D): k-means on the particle positions
  (:func:`scipy.cluster.vq.kmeans2`, seeded with the current estimates), the new
  clusters linked to the previous estimates by minimum distance (Hungarian,
  :func:`scipy.optimize.linear_sum_assignment`);
* **supervision** (§III-F): per target the membership of the estimate, the
  cluster spread (eq. 9) and the overlap with the other targets' estimates.
  Far apart and fast: more process noise; strongly overlapping: less
  (conservative); a target whose estimate stays degraded (low membership or
  wide spread) for ``patience`` frames, or whose cluster sits on another
  target's estimate while its own cue is elsewhere (both clusters on the same
  arm), is restarted around its measurement. The track states of paper 004
  (:mod:`fusion_pf.filter.states`) mark joined targets ``combined``; when they
  separate, identities are re-assigned by continuity
  (:func:`~fusion_pf.filter.states.reassign_identities`).

Measurements per target come from the caller, e.g. :func:`fusion_pf.association.associate`.
The baselines -- one independent :class:`~fusion_pf.filter.pf.ParticleFilter`
or :class:`~fusion_pf.filter.kf.KalmanFilter` per target -- are
:class:`IndependentTrackers`.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.optimize import linear_sum_assignment

from fusion_pf.cues.base import Measurement
from fusion_pf.errors import InputError
from fusion_pf.rng import as_rng

from .base import Estimate, Tracker
from .likelihood import DEFAULT_NOISE_PX, JointLikelihood, squared_distance
from .motion import check_process_noise
from .pf import check_timestamp, fused_position
from .states import (
    Evidence,
    StateConfig,
    TrackState,
    TrackStateMachine,
    reassign_identities,
)

__all__ = [
    "IndependentTrackers",
    "KMeansParticleFilter",
    "MultiEstimate",
    "TargetEstimate",
    "cluster_spread",
    "elite_mean",
    "kmeans_clusters",
    "link_clusters",
    "membership",
    "overlap",
]


def kmeans_clusters(
    positions: np.ndarray, centroids: np.ndarray, rng: np.random.Generator | int | None = None, iterations: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """k-means of the particle positions (paper 000 §III-D), seeded with ``centroids``.

    Parameters
    ----------
    positions : ndarray, shape (N, 2)
    centroids : ndarray, shape (K, 2)
        Initial centroids (the current estimates).
    rng : Generator, int or None
        Passed to :func:`scipy.cluster.vq.kmeans2` (only used if it has to reseed).
    iterations : int
        k-means iterations.

    Returns
    -------
    labels : ndarray, shape (N,), int
    centroids : ndarray, shape (K, 2)
        Final centroids (an empty cluster keeps its initial centroid).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c, labels = kmeans2(
            np.asarray(positions, dtype=np.float64),
            np.asarray(centroids, dtype=np.float64),
            iter=iterations,
            minit="matrix",
            missing="warn",
            rng=as_rng(rng),
        )
    return labels.astype(np.int64), c


def link_clusters(centroids: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """Link new clusters to the previous estimates by minimum distance (Hungarian).

    Parameters
    ----------
    centroids : ndarray, shape (K, 2)
        New cluster centroids.
    previous : ndarray, shape (K, 2)
        Previous estimates of the K targets.

    Returns
    -------
    ndarray, shape (K,), int
        ``target_of[c]``: the target cluster ``c`` is linked to.
    """
    d = np.sqrt(((np.asarray(centroids)[:, None, :] - np.asarray(previous)[None, :, :]) ** 2).sum(axis=2))
    rows, cols = linear_sum_assignment(d)
    target_of = np.empty(len(centroids), dtype=np.int64)
    target_of[rows] = cols
    return target_of


def elite_mean(states: np.ndarray, memberships: np.ndarray, fraction: float = 0.8) -> np.ndarray:
    """Elite estimate of one cluster (paper 000 eq. 8).

    The particles whose membership exceeds ``fraction`` times the cluster's mean
    membership, averaged with their memberships as weights.

    Parameters
    ----------
    states : ndarray, shape (n, 4)
        The cluster's particles.
    memberships : ndarray, shape (n,)
        Their (non-negative) memberships / likelihoods.
    fraction : float
        The paper's 0.8.

    Returns
    -------
    ndarray, shape (4,)
    """
    m = np.asarray(memberships, dtype=np.float64)
    # elite = {X_j : Memb(X_j) > 0.8 Memb_mean}
    elite = m > fraction * m.mean()
    if not elite.any():
        return states.mean(axis=0)
    w = m[elite]
    # X_hat = sum_elite Memb_j X_j / sum_elite Memb_j
    return w @ states[elite] / w.sum()


def cluster_spread(positions: np.ndarray, estimate: np.ndarray) -> float:
    """Cluster spread of paper 000 eq. 9: ``var_i = 1/N_i sum sqrt(dist(x_k, x_opt))``.

    ``dist`` is taken as the squared Euclidean distance, so the spread is the
    mean Euclidean distance (px) of the cluster's particles to its estimate.

    Parameters
    ----------
    positions : ndarray, shape (n, 2)
    estimate : ndarray, shape (2,)
    """
    if len(positions) == 0:
        return math.nan
    return float(np.sqrt(squared_distance(positions, estimate)).mean())


def membership(position: np.ndarray, measurements: Sequence[Measurement], noise_px: Mapping[str, float]) -> float:
    """Membership of an estimate in [0, 1]: ``exp(-1/2 mean_s |x - z_s|^2 / sigma_s^2)``.

    The geometric mean over the sources of each source's Gaussian (eq. 6 of
    paper 003, unnormalised, 1 at the cue); nan without measurements.
    """
    if not measurements:
        return math.nan
    d2 = np.array(
        [((position[0] - m.u) ** 2 + (position[1] - m.v) ** 2) / noise_px[m.source] ** 2 for m in measurements]
    )
    return float(math.exp(-0.5 * d2.mean()))


def overlap(positions: np.ndarray, radius_px: float) -> np.ndarray:
    """Pairwise overlap of targets modelled as discs of ``radius_px`` around their estimates.

    ``o_ij = max(0, 1 - d_ij / (2 r))``: 0 when the discs do not touch, 1 when
    the estimates coincide.

    Parameters
    ----------
    positions : ndarray, shape (K, 2)
        Estimates (nan rows overlap nothing).
    radius_px : float

    Returns
    -------
    ndarray, shape (K, K)
        Symmetric, zero diagonal.
    """
    p = np.asarray(positions, dtype=np.float64)
    d = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=2))
    o = np.clip(1.0 - d / (2.0 * radius_px), 0.0, 1.0)
    o[~np.isfinite(o)] = 0.0
    np.fill_diagonal(o, 0.0)
    return o


def _state_floats(x: np.ndarray) -> tuple[float, float, float, float]:
    """``(u, v, du, dv)`` of a state, shape (4,), as Python floats."""
    return float(x[0]), float(x[1]), float(x[2]), float(x[3])


@dataclass(frozen=True, slots=True)
class TargetEstimate:
    """One target's estimate in one frame.

    Attributes
    ----------
    u, v : float
        Position (nan while uninitialised).
    du, dv : float
        Velocity, px per frame step.
    state : TrackState
        Paper 004 track state.
    membership : float
        Membership of the estimate (nan without a cue).
    spread_px : float
        Cluster spread (eq. 9), px.
    noise_gain : float
        Process-noise factor the supervision chose for the next prediction.
    restarted : bool
        Whether the supervision restarted this target's cluster in this step.
    """

    u: float
    v: float
    du: float
    dv: float
    state: TrackState
    membership: float
    spread_px: float
    noise_gain: float = 1.0
    restarted: bool = False


@dataclass(frozen=True, slots=True)
class MultiEstimate:
    """All targets' estimates of one frame.

    Attributes
    ----------
    timestamp_ns : int
    targets : dict of str to TargetEstimate
    evaluations : int
        Likelihood evaluations (particles weighed) in this step.
    """

    timestamp_ns: int
    targets: dict[str, TargetEstimate]
    evaluations: int


def _check_targets(targets: Sequence[str]) -> tuple[str, ...]:
    t = tuple(targets)
    if not t or len(set(t)) != len(t) or not all(isinstance(x, str) and x for x in t):
        raise InputError(f"targets must be distinct non-empty names, got {list(targets)!r}")
    return t


def _check_measurements(targets: tuple[str, ...], measurements: Mapping[str, Sequence[Measurement]]) -> None:
    unknown = sorted(set(measurements) - set(targets))
    if unknown:
        raise InputError(f"measurements for unknown target {unknown[0]!r}; targets: {', '.join(targets)}")


class KMeansParticleFilter:
    """Paper 000's multi-modal particle filter with k-means clustering and supervision.

    Parameters
    ----------
    targets : sequence of str
        Target names, e.g. ``("right_hand", "left_hand", "head")``.
    n_particles : int
        Total particles N (each target keeps ``N // K``; >= 2 K).
    process_noise : (float, float)
        Nominal ``(pos_px, vel_px)`` per frame step (paper 003 eq. 4).
    noise_px : mapping of str to float
        Per-source measurement noise sigma (px).
    supervision : bool
        Run the supervision (noise adaptation, restarts, identity re-assignment).
    min_membership : float
        Supervision: a target's estimate is degraded below this membership.
    max_spread_px : float
        Supervision: ... or above this cluster spread (eq. 9), px.
    patience : int
        Consecutive degraded frames before a restart.
    radius_px : float
        Disc radius of a target for the overlap (px).
    big_overlap : float
        Overlap from which the process noise is conservative.
    fast_px : float
        Speed (px / frame) above which a separated target gets more noise.
    fast_gain, conservative_gain : float
        Process-noise factors (far and fast / strongly overlapping).
    init_spread_px, init_velocity_px : float
        Spread of a (re)started cluster around its measurement.
    states : StateConfig, optional
        Track-state thresholds (default: merge at ``radius_px``, split at ``1.6 radius_px``).
    coincide_px : float
        A combined pair whose estimates came closer than this has lost its
        identities (the modes coincided); on separation they are re-assigned
        by :func:`~fusion_pf.filter.states.reassign_identities`. A pair that
        stayed farther apart keeps the identities the frame-to-frame cluster
        linking followed (motion continuity through the combined state, e.g.
        two hands crossing).
    rng : Generator, int or None

    Attributes
    ----------
    particles : ndarray, shape (N, 4)
    labels : ndarray, shape (N,), int
        Target index of every particle (-1: the target is not initialised yet).
    restarts : dict of str to int
        Restarts per target so far.
    evaluations : int
        Likelihood evaluations in the last step.
    """

    def __init__(
        self,
        targets: Sequence[str],
        *,
        n_particles: int = 300,
        process_noise: tuple[float, float] = (3.0, 1.0),
        noise_px: Mapping[str, float] = DEFAULT_NOISE_PX,
        supervision: bool = True,
        min_membership: float = 0.02,
        max_spread_px: float = 30.0,
        patience: int = 5,
        radius_px: float = 20.0,
        big_overlap: float = 0.5,
        fast_px: float = 4.0,
        fast_gain: float = 1.5,
        conservative_gain: float = 0.5,
        init_spread_px: float = 10.0,
        init_velocity_px: float = 2.0,
        states: StateConfig | None = None,
        coincide_px: float = 4.0,
        rng: np.random.Generator | int | None = None,
    ) -> None:
        self.targets = _check_targets(targets)
        k = len(self.targets)
        if isinstance(n_particles, bool) or not isinstance(n_particles, (int, np.integer)) or n_particles < 2 * k:
            raise InputError(f"n_particles must be an int >= 2 x {k} targets, got {n_particles!r}")
        for name, value in (
            ("radius_px", radius_px),
            ("max_spread_px", max_spread_px),
            ("fast_gain", fast_gain),
            ("conservative_gain", conservative_gain),
        ):
            if not (math.isfinite(float(value)) and float(value) > 0):
                raise InputError(f"{name} must be a finite number > 0, got {value!r}")
        if isinstance(patience, bool) or not isinstance(patience, (int, np.integer)) or patience < 1:
            raise InputError(f"patience must be an int >= 1, got {patience!r}")
        self.share = int(n_particles) // k
        self.n_particles = self.share * k
        self.process_noise = check_process_noise(process_noise)
        self._like = JointLikelihood(noise_px)
        self.noise_px = self._like.noise_px
        self.supervision = bool(supervision)
        self.min_membership = float(min_membership)
        self.max_spread_px = float(max_spread_px)
        self.patience = int(patience)
        self.radius_px = float(radius_px)
        self.big_overlap = float(big_overlap)
        self.fast_px = float(fast_px)
        self.fast_gain = float(fast_gain)
        self.conservative_gain = float(conservative_gain)
        self.init_spread_px = float(init_spread_px)
        self.init_velocity_px = float(init_velocity_px)
        self.coincide_px = float(coincide_px)
        self.state_config = states or StateConfig(merge_px=self.radius_px, split_px=1.6 * self.radius_px)
        self.rng = as_rng(rng)
        self.particles = np.zeros((self.n_particles, 4))
        self.labels = np.full(self.n_particles, -1, dtype=np.int64)
        self.restarts = {t: 0 for t in self.targets}
        self.evaluations = 0
        self._est = np.full((k, 4), np.nan)
        self._gain = np.ones(k)
        self._degraded = np.zeros(k, dtype=np.int64)
        self._fsm = TrackStateMachine(self.targets, self.state_config)
        self._entry = np.zeros((k, 2))
        self._closest = np.full(k, np.inf)
        self._last_ns: int | None = None

    def predictions(self) -> np.ndarray:
        """Predicted positions ``(u + du, v + dv)`` of the targets, shape (K, 2) (nan: uninitialised)."""
        return self._est[:, :2] + self._est[:, 2:]

    def _start(self, k: int, centre: np.ndarray) -> None:
        """(Re)start target ``k``'s share of particles around ``centre`` (paper 000 §III-A)."""
        idx = np.flatnonzero(self.labels == k)
        if len(idx) < self.share:
            idx = np.concatenate([idx, np.flatnonzero(self.labels < 0)[: self.share - len(idx)]])
        std = np.array([self.init_spread_px] * 2 + [self.init_velocity_px] * 2)
        self.particles[idx] = centre + std * self.rng.standard_normal((len(idx), 4))
        self.labels[idx] = k
        self._est[k] = centre

    def step(self, timestamp_ns: int, measurements: Mapping[str, Sequence[Measurement]]) -> MultiEstimate:
        """One frame: propagate, weigh, estimate, supervise, resample per cluster, cluster.

        Parameters
        ----------
        timestamp_ns : int
            Frame time, increasing.
        measurements : mapping of str to sequence of Measurement
            Each target's measurements (e.g. from
            :func:`fusion_pf.association.associate`); a target may be missing (no cue).

        Returns
        -------
        MultiEstimate
        """
        t = check_timestamp(timestamp_ns, self._last_ns)
        _check_measurements(self.targets, measurements)
        ms = [self._like.check(measurements.get(name, ())) for name in self.targets]
        self._last_ns = t
        k_all = len(self.targets)
        restarted = np.zeros(k_all, dtype=bool)
        for k in range(k_all):
            if not np.isfinite(self._est[k, 0]) and ms[k]:
                self._start(k, self._centre(ms[k]))
        live = self.labels >= 0
        # x_k = M x_(k-1) + gamma (x) sigma_x, gamma scaled per cluster by the supervision (§III-E)
        pos, vel = self.process_noise
        gain = self._gain[self.labels[live]][:, None]
        x = self.particles[live]
        x[:, :2] += x[:, 2:]
        x[:, :2] += gain * pos * self.rng.standard_normal((len(x), 2))
        x[:, 2:] += gain * vel * self.rng.standard_normal((len(x), 2))
        self.particles[live] = x
        loglik = np.zeros(self.n_particles)
        self.evaluations = 0
        for k in range(k_all):
            idx = np.flatnonzero(self.labels == k)
            if ms[k] and len(idx):
                joint, _ = self._like(self.particles[idx, :2], ms[k], np.empty(len(idx)))
                loglik[idx] = joint
                self.evaluations += len(idx)
        like = np.exp(loglik)
        spread = np.full(k_all, np.nan)
        memb = np.full(k_all, np.nan)
        for k in range(k_all):
            idx = np.flatnonzero(self.labels == k)
            if len(idx) == 0:
                continue
            self._est[k] = elite_mean(self.particles[idx], like[idx])
            spread[k] = cluster_spread(self.particles[idx, :2], self._est[k, :2])
            memb[k] = membership(self._est[k, :2], ms[k], self.noise_px)
        if self.supervision:
            restarted = self._supervise(ms, memb, spread)
            # a restarted cluster is not weighed yet: uniform within it
            like[np.isin(self.labels, np.flatnonzero(restarted))] = 1.0
        self._resample(like)
        self._cluster()
        states = self._track_states(ms, memb, spread)
        targets = {
            name: TargetEstimate(
                *_state_floats(self._est[k]),
                state=states[name],
                membership=float(memb[k]),
                spread_px=float(spread[k]),
                noise_gain=float(self._gain[k]),
                restarted=bool(restarted[k]),
            )
            for k, name in enumerate(self.targets)
        }
        return MultiEstimate(t, targets, self.evaluations)

    def _centre(self, ms: Sequence[Measurement]) -> np.ndarray:
        sigma = {m.source: self.noise_px[m.source] for m in ms}
        return np.concatenate([fused_position(ms, sigma), [0.0, 0.0]])

    def _supervise(self, ms: list[list[Measurement]], memb: np.ndarray, spread: np.ndarray) -> np.ndarray:
        """Paper 000 §III-F: adapt the process noise, restart degraded or duplicated clusters."""
        k_all = len(self.targets)
        restarted = np.zeros(k_all, dtype=bool)
        ov = overlap(self._est[:, :2], self.radius_px)
        worst = ov.max(axis=1) if k_all > 1 else np.zeros(k_all)
        speed = np.hypot(self._est[:, 2], self._est[:, 3])
        # separated and fast -> faster; joined with a great overlap -> conservative; else nominal
        self._gain = np.where(
            worst >= self.big_overlap,
            self.conservative_gain,
            np.where((worst == 0.0) & (speed > self.fast_px), self.fast_gain, 1.0),
        )
        bad = (memb < self.min_membership) | (spread > self.max_spread_px)
        # two clusters on one target while their cues are apart: the farther one is on the wrong target
        cue = np.array([self._centre(m)[:2] if m else [np.nan, np.nan] for m in ms])
        for i in range(k_all):
            for j in range(i + 1, k_all):
                if ov[i, j] > self.big_overlap and np.hypot(*(cue[i] - cue[j])) > 2.0 * self.radius_px:
                    off = [np.hypot(*(self._est[n, :2] - cue[n])) for n in (i, j)]
                    bad[(i, j)[int(np.argmax(off))]] = True
        self._degraded = np.where(bad, self._degraded + 1, 0)
        for k in np.flatnonzero(self._degraded >= self.patience):
            if ms[k]:
                self._start(int(k), self._centre(ms[k]))
                self.restarts[self.targets[k]] += 1
                self._degraded[k] = 0
                restarted[k] = True
        return restarted

    def _resample(self, like: np.ndarray) -> None:
        """Systematic resampling within each cluster to exactly ``N / K`` particles (§III-C)."""
        new = np.empty_like(self.particles)
        labels = np.full(self.n_particles, -1, dtype=np.int64)
        for k in range(len(self.targets)):
            idx = np.flatnonzero(self.labels == k)
            if len(idx) == 0:
                continue
            w = like[idx]
            c = np.cumsum(w)
            if not c[-1] > 0:
                c = np.arange(1.0, len(idx) + 1.0)
            # u_j = (j + U) / n, index = first c_i / c_n > u_j
            u = (np.arange(self.share) + self.rng.random()) / self.share
            pick = idx[np.minimum(np.searchsorted(c / c[-1], u, side="right"), len(idx) - 1)]
            new[k * self.share : (k + 1) * self.share] = self.particles[pick]
            labels[k * self.share : (k + 1) * self.share] = k
        self.particles, self.labels = new, labels

    def _cluster(self) -> None:
        """k-means over the live particles (§III-D), clusters linked to the estimates."""
        live = np.flatnonzero(self.labels >= 0)
        ks = np.flatnonzero(np.isfinite(self._est[:, 0]))
        if len(ks) < 2 or len(live) == 0:
            return
        lab, cent = kmeans_clusters(self.particles[live, :2], self._est[ks, :2], self.rng)
        target_of = link_clusters(cent, self._est[ks, :2])
        self.labels[live] = ks[target_of[lab]]

    def _track_states(self, ms, memb, spread) -> dict[str, TrackState]:
        """Paper 004 states; on a separation the identities of the pair are re-assigned."""
        before = dict(self._fsm.statuses)
        ev = {}
        for k, name in enumerate(self.targets):
            pos = None if not np.isfinite(self._est[k, 0]) else (float(self._est[k, 0]), float(self._est[k, 1]))
            ev[name] = Evidence(pos, spread_px=float(spread[k]), likelihood=float(memb[k]), cues=len(ms[k]))
        states = self._fsm.update(ev)
        names = self.targets
        for k, name in enumerate(names):
            s_old, s_new = before[name], self._fsm.statuses[name]
            if s_new.state == TrackState.COMBINED:
                j = s_new.partner
                gap = float(np.hypot(*(self._est[k, :2] - self._est[j, :2])))
                if s_old.state != TrackState.COMBINED:
                    self._entry[k] = self._est[k, :2] - 0.5 * (self._est[k, :2] + self._est[j, :2])
                    self._closest[k] = gap
                self._closest[k] = min(self._closest[k], gap)
            if self.supervision and s_old.state == TrackState.COMBINED and s_new.state == TrackState.UNLABELLED:
                j = s_old.partner
                if (
                    j is not None
                    and j > k
                    and self._fsm.statuses[names[j]].state == TrackState.UNLABELLED
                    and self._closest[k] < self.coincide_px
                ):
                    self._swap_if_needed(k, j)
        return states

    def _swap_if_needed(self, i: int, j: int) -> None:
        """Swap targets ``i`` and ``j`` (estimates, clusters, counters) if continuity says so."""
        order = reassign_identities(self._entry[[i, j]], self._est[[i, j], :2])
        if order[0] == 1:
            for a in (self._est, self._gain, self._degraded):
                a[[i, j]] = a[[j, i]]
            li, lj = self.labels == i, self.labels == j
            self.labels[li], self.labels[lj] = j, i


class IndependentTrackers:
    """Baseline: one independent single-target filter per target (PF or KF).

    Parameters
    ----------
    targets : sequence of str
    factory : callable () -> Tracker
        Makes one filter (e.g. ``lambda: ParticleFilter(rng=...)``); called once per target.
    states : StateConfig, optional
        Track-state thresholds.

    Attributes
    ----------
    filters : dict of str to Tracker
    evaluations : int
        Likelihood evaluations in the last step (particles weighed; 0 for KFs).
    """

    def __init__(
        self, targets: Sequence[str], factory: Callable[[], Tracker], states: StateConfig | None = None
    ) -> None:
        self.targets = _check_targets(targets)
        self.filters: dict[str, Tracker] = {t: factory() for t in self.targets}
        self._est: dict[str, Estimate | None] = {t: None for t in self.targets}
        self._vel = np.zeros((len(self.targets), 2))
        self._fsm = TrackStateMachine(self.targets, states or StateConfig())
        self.evaluations = 0

    def predictions(self) -> np.ndarray:
        """Predicted positions, shape (K, 2): last estimate plus last displacement (nan: none yet)."""
        out = np.full((len(self.targets), 2), np.nan)
        for k, t in enumerate(self.targets):
            e = self._est[t]
            if e is not None:
                out[k] = (e.u + self._vel[k, 0], e.v + self._vel[k, 1])
        return out

    def step(self, timestamp_ns: int, measurements: Mapping[str, Sequence[Measurement]]) -> MultiEstimate:
        """Step every filter with its own measurements; same output as :class:`KMeansParticleFilter`."""
        _check_measurements(self.targets, measurements)
        self.evaluations = 0
        ev = {}
        for k, t in enumerate(self.targets):
            f = self.filters[t]
            ms = list(measurements.get(t, ()))
            before = getattr(f, "reinitialisations", 0)
            e = f.step(timestamp_ns, ms)
            if hasattr(f, "evaluations"):
                self.evaluations += f.evaluations
            else:
                # a ParticleFilter weighs its N particles once per frame with cues, again after a re-initialisation
                n = getattr(f, "n_particles", 0)
                self.evaluations += n * (bool(ms) + getattr(f, "reinitialisations", 0) - before)
            old = self._est[t]
            if e is not None and old is not None:
                self._vel[k] = (e.u - old.u, e.v - old.v)
            self._est[t] = e
            if e is None:
                ev[t] = Evidence(None, cues=len(ms))
                continue
            spread = math.nan
            if e.particles is not None:
                spread = cluster_spread(e.particles, np.array([e.u, e.v]))
            memb = membership(np.array([e.u, e.v]), ms, f.noise_px) if hasattr(f, "noise_px") else math.nan
            ev[t] = Evidence((e.u, e.v), spread_px=spread, likelihood=memb, cues=len(ms))
        states = self._fsm.update(ev)
        out = {}
        for k, t in enumerate(self.targets):
            e = self._est[t]
            u, v = (e.u, e.v) if e is not None else (math.nan, math.nan)
            evid = ev[t]
            out[t] = TargetEstimate(
                u, v, float(self._vel[k, 0]), float(self._vel[k, 1]), states[t], evid.likelihood, evid.spread_px
            )
        return MultiEstimate(int(timestamp_ns), out, self.evaluations)
