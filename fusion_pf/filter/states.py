"""Track states: the high-level finite state machine of paper 004 §5.2 (Fig. 1).

Every tracker (one per target) is in one of five states:

* ``uninitialised`` -- no estimate yet (paper: "In the beginning, all trackers
  are in the uninitialized state"); it leaves it once the filter holds an
  estimate of good enough quality;
* ``unlabelled`` -- tracking, but the target's identity is not known (after
  initialisation when targets must be labelled, and after two combined
  targets separate, until identities are re-assigned);
* ``tracking`` -- the paper's *normal* state: initialised and labelled;
* ``combined`` -- two targets' estimates are closer than a threshold ("the
  maximum likelihood points of the two distributions have a distance less than
  a threshold"); both follow the joint blob until the modes move apart
  (distance above a second, larger threshold), then both become
  ``unlabelled`` and identities are re-assigned (:func:`reassign_identities`);
* ``lost`` -- the posterior is too poor (the paper "test[s] the posterior
  probabilities against a threshold"); here: best likelihood / membership below
  a threshold, particle spread too wide, the estimate outside the image, or the
  cues silent for ``silent_frames`` frames. A lost track is re-acquired
  (``tracking``) as soon as the evidence is good again.

Everything here is a pure function of the per-frame inputs
(:class:`Evidence`) and the previous :class:`TrackStatus`; :class:`TrackStateMachine`
only holds the thresholds and the current status for convenience.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass, replace
from enum import Enum

import numpy as np
from scipy.optimize import linear_sum_assignment

from fusion_pf.errors import InputError

__all__ = [
    "Evidence",
    "StateConfig",
    "TrackState",
    "TrackStateMachine",
    "TrackStatus",
    "combine_states",
    "reassign_identities",
    "step_state",
]


class TrackState(str, Enum):
    """The five states of paper 004 §5.2 (``tracking`` is the paper's *normal* state)."""

    UNINITIALISED = "uninitialised"
    UNLABELLED = "unlabelled"
    TRACKING = "tracking"
    COMBINED = "combined"
    LOST = "lost"


@dataclass(frozen=True, slots=True)
class StateConfig:
    """Thresholds of the state machine.

    Parameters
    ----------
    max_spread_px : float
        Particle spread (eq. 9 of paper 000, mean distance to the estimate, px)
        above which the track is degraded.
    min_likelihood : float
        Membership / best likelihood of the estimate (in [0, 1]) below which the
        track is degraded; ignored when the evidence gives none (nan).
    silent_frames : int
        Frames without any cue after which the track is lost (>= 1).
    degraded_frames : int
        Consecutive degraded frames (spread, likelihood) before the track is lost (>= 1).
    image_size : (int, int) or None
        ``(width, height)``: an estimate outside ``[0, W) x [0, H)`` is lost at once.
    merge_px, split_px : float
        Combined state: two estimates closer than ``merge_px`` combine; combined
        estimates farther than ``split_px`` (>= ``merge_px``) separate.
    label_split_px : float or None
        Two targets whose own evidence (labels, :func:`combine_states`) lies
        farther apart than this are apart; None: ``split_px``.
    """

    max_spread_px: float = 40.0
    min_likelihood: float = 0.01
    silent_frames: int = 10
    degraded_frames: int = 3
    image_size: tuple[int, int] | None = None
    merge_px: float = 20.0
    split_px: float = 35.0
    label_split_px: float | None = None

    def __post_init__(self) -> None:
        for name in ("max_spread_px", "merge_px", "split_px"):
            value = float(getattr(self, name))
            if not (math.isfinite(value) and value > 0.0):
                raise InputError(f"{name} must be a finite number > 0 px, got {getattr(self, name)!r}")
        if not 0.0 <= float(self.min_likelihood) <= 1.0:
            raise InputError(f"min_likelihood must be in [0, 1], got {self.min_likelihood!r}")
        for name in ("silent_frames", "degraded_frames"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise InputError(f"{name} must be an int >= 1, got {value!r}")
        if self.label_split_px is not None and not (
            math.isfinite(float(self.label_split_px)) and float(self.label_split_px) > 0.0
        ):
            raise InputError(f"label_split_px must be a finite number > 0 px or None, got {self.label_split_px!r}")
        if self.split_px < self.merge_px:
            raise InputError(f"split_px must be >= merge_px ({self.merge_px}), got {self.split_px}")


@dataclass(frozen=True, slots=True)
class Evidence:
    """What the filter tells the state machine about one target in one frame.

    Parameters
    ----------
    position : (float, float) or None
        The estimate ``(u, v)``; None while the filter holds no estimate.
    spread_px : float
        Particle spread around the estimate (paper 000 eq. 9), px; nan if unknown.
    likelihood : float
        Membership / best likelihood of the estimate in [0, 1]; nan if unknown
        (e.g. no cue this frame).
    cues : int
        Number of measurements the target received this frame.
    labelled : bool
        Whether the target's identity is known (False right after initialisation
        of an unlabelled target type or after a separation).
    """

    position: tuple[float, float] | None
    spread_px: float = math.nan
    likelihood: float = math.nan
    cues: int = 1
    labelled: bool = True


@dataclass(frozen=True, slots=True)
class TrackStatus:
    """State of one track plus the counters the transitions need.

    Attributes
    ----------
    state : TrackState
    silent : int
        Consecutive frames without cues.
    degraded : int
        Consecutive frames with a degraded estimate (spread or likelihood).
    partner : int or None
        Index of the target this one is combined with (multi-target only).
    """

    state: TrackState = TrackState.UNINITIALISED
    silent: int = 0
    degraded: int = 0
    partner: int | None = None


def _outside(position: tuple[float, float], size: tuple[int, int] | None) -> bool:
    if size is None:
        return False
    u, v = position
    return not (0.0 <= u < size[0] and 0.0 <= v < size[1])


def step_state(status: TrackStatus, evidence: Evidence, config: StateConfig) -> TrackStatus:
    """One frame of a single target's state machine (paper 004 §5.2, without ``combined``).

    Transitions: ``uninitialised -> tracking`` (or ``unlabelled`` when
    ``evidence.labelled`` is False) once there is a good estimate;
    ``tracking -> lost`` when the estimate leaves the image, the cues have been
    silent for ``silent_frames`` frames, or the estimate has been degraded
    (spread above ``max_spread_px`` or likelihood below ``min_likelihood``) for
    ``degraded_frames`` frames; ``lost -> tracking`` when a good estimate with
    cues is back; ``unlabelled -> tracking`` once labelled. A ``combined``
    status is left to :func:`combine_states` and passed through here.

    Parameters
    ----------
    status : TrackStatus
        The previous frame's status.
    evidence : Evidence
        This frame's evidence.
    config : StateConfig

    Returns
    -------
    TrackStatus
        The new status (the inputs are not modified).
    """
    silent = status.silent + 1 if evidence.cues == 0 else 0
    if evidence.position is None:
        state = TrackState.UNINITIALISED if status.state == TrackState.UNINITIALISED else TrackState.LOST
        return TrackStatus(state, silent, status.degraded, None)
    bad_spread = math.isfinite(evidence.spread_px) and evidence.spread_px > config.max_spread_px
    bad_like = math.isfinite(evidence.likelihood) and evidence.likelihood < config.min_likelihood
    degraded = status.degraded + 1 if (bad_spread or bad_like) else 0
    good = degraded == 0 and evidence.cues > 0 and not _outside(evidence.position, config.image_size)
    lost_now = (
        _outside(evidence.position, config.image_size)
        or silent >= config.silent_frames
        or degraded >= config.degraded_frames
    )
    labelled_state = TrackState.TRACKING if evidence.labelled else TrackState.UNLABELLED
    state = status.state
    if state in (TrackState.UNINITIALISED, TrackState.LOST):
        state = labelled_state if good else state
    elif state in (TrackState.TRACKING, TrackState.UNLABELLED):
        state = TrackState.LOST if lost_now else labelled_state
    elif state == TrackState.COMBINED and lost_now:
        state = TrackState.LOST
    partner = status.partner if state == TrackState.COMBINED else None
    return TrackStatus(state, silent, degraded, partner)


def combine_states(
    statuses: Sequence[TrackStatus],
    positions: Sequence[tuple[float, float] | None],
    config: StateConfig,
    labels: Sequence[tuple[float, float] | None] | None = None,
    apart: Collection[tuple[int, int]] = (),
) -> list[TrackStatus]:
    """The ``combined`` transitions between targets (paper 004 §5.2), after :func:`step_state`.

    Two tracked (``tracking`` / ``unlabelled``) targets whose estimates are
    closer than ``merge_px`` become ``combined`` with each other (closest pairs
    first; the paper assumes at most two targets join at a time). A combined
    pair whose estimates are farther than ``split_px`` apart separates: both
    become ``unlabelled`` (their identities are then re-assigned by the caller,
    :func:`reassign_identities`). A combined target whose partner is lost
    becomes ``tracking`` again.

    ``labels``: where each target's own labelled evidence (its skeleton joint)
    puts it this frame. Two targets whose labels are both known and farther
    than ``label_split_px`` (default ``split_px``) apart are apart whatever
    their estimates say (two estimates held together by one shared blob): a
    combined pair separates, and such a pair does not combine (nor does a
    pair in the frame it separated). ``apart``: pairs ``(i, j)`` the caller
    knows are apart this frame (e.g. a cue saw them as two separate regions),
    with the same effect.

    Parameters
    ----------
    statuses : sequence of TrackStatus, length K
    positions : sequence of (u, v) or None, length K
        This frame's estimates.
    config : StateConfig
    labels : sequence of (u, v) or None, length K, optional
        This frame's label positions (None: no label evidence).
    apart : collection of (int, int)
        Pairs of targets known to be apart this frame (either order).

    Returns
    -------
    list of TrackStatus, length K
    """
    if len(statuses) != len(positions):
        raise InputError(f"statuses and positions must have the same length, got {len(statuses)} and {len(positions)}")
    out = list(statuses)
    k = len(out)

    if labels is not None and len(labels) != k:
        raise InputError(f"statuses and labels must have the same length, got {k} and {len(labels)}")

    def dist(i: int, j: int, at: Sequence[tuple[float, float] | None] = positions) -> float:
        a, b = at[i], at[j]
        return math.inf if a is None or b is None else math.hypot(a[0] - b[0], a[1] - b[1])

    label_split = config.split_px if config.label_split_px is None else config.label_split_px
    known = {frozenset(p) for p in apart}

    def separate(i: int, j: int) -> bool:
        """Whether ``i`` and ``j`` are known apart, or their labels are both known and farther than ``label_split_px`` apart."""
        if frozenset((i, j)) in known:
            return True
        return labels is not None and dist(i, j, labels) < math.inf and dist(i, j, labels) > label_split

    for i in range(k):
        s = out[i]
        if s.state != TrackState.COMBINED:
            continue
        j = s.partner
        if j is None or out[j].state == TrackState.LOST or positions[i] is None:
            out[i] = replace(s, state=TrackState.TRACKING, partner=None)
        elif dist(i, j) > config.split_px or separate(i, j):
            out[i] = replace(s, state=TrackState.UNLABELLED, partner=None)
    active = (TrackState.TRACKING, TrackState.UNLABELLED)
    separated = {
        i for i in range(k) if statuses[i].state == TrackState.COMBINED and out[i].state != TrackState.COMBINED
    }
    pairs = sorted(
        (dist(i, j), i, j)
        for i in range(k)
        for j in range(i + 1, k)
        if out[i].state in active
        and out[j].state in active
        and dist(i, j) < config.merge_px
        and not separate(i, j)
        and not {i, j} <= separated
    )
    for _, i, j in pairs:
        if out[i].state in active and out[j].state in active:
            out[i] = replace(out[i], state=TrackState.COMBINED, partner=j)
            out[j] = replace(out[j], state=TrackState.COMBINED, partner=i)
    return out


def reassign_identities(entry_offsets: np.ndarray, modes: np.ndarray) -> np.ndarray:
    """Give the separating modes of a combined pair back to their targets.

    Continuity of motion relative to the joint blob: a target that entered the
    combination from one side (its offset from the pair's centre when they
    combined) leaves on that side, so the assignment minimises
    ``sum_i |(m_pi(i) - c) - o_i|^2`` over permutations ``pi`` (Hungarian,
    :func:`scipy.optimize.linear_sum_assignment`), ``c`` being the modes' centre.

    Parameters
    ----------
    entry_offsets : ndarray, shape (K, 2)
        Each target's offset from the pair's centre when the pair combined.
    modes : ndarray, shape (K, 2)
        The separated modes (estimates) in the current order.

    Returns
    -------
    ndarray, shape (K,), int
        ``order`` such that target ``i`` takes ``modes[order[i]]``.
    """
    o = np.asarray(entry_offsets, dtype=np.float64)
    m = np.asarray(modes, dtype=np.float64)
    if o.ndim != 2 or o.shape[1] != 2 or m.shape != o.shape:
        raise InputError(f"entry_offsets and modes must both be (K, 2), got {o.shape} and {m.shape}")
    rel = m - m.mean(axis=0)
    # cost_ij = |(m_j - c) - o_i|^2
    cost = ((o[:, None, :] - rel[None, :, :]) ** 2).sum(axis=2)
    rows, cols = linear_sum_assignment(cost)
    order = np.empty(len(o), dtype=np.int64)
    order[rows] = cols
    return order


class TrackStateMachine:
    """The state machine of one or several targets with fixed thresholds.

    Parameters
    ----------
    targets : sequence of str
        Target names (one for single-target tracking).
    config : StateConfig

    Attributes
    ----------
    statuses : dict of str to TrackStatus
        The current status per target.
    """

    def __init__(self, targets: Sequence[str], config: StateConfig | None = None) -> None:
        if not targets or len(set(targets)) != len(targets):
            raise InputError(f"targets must be distinct names, at least one, got {list(targets)!r}")
        self.targets = tuple(targets)
        self.config = config or StateConfig()
        self.statuses: dict[str, TrackStatus] = {t: TrackStatus() for t in self.targets}

    def update(self, evidence: Mapping[str, Evidence]) -> dict[str, TrackState]:
        """Advance every target by one frame.

        Parameters
        ----------
        evidence : mapping of str to Evidence
            One entry per target (a missing target counts as "no estimate, no cue").

        Returns
        -------
        dict of str to TrackState
        """
        unknown = sorted(set(evidence) - set(self.targets))
        if unknown:
            raise InputError(f"evidence for unknown target {unknown[0]!r}; targets: {', '.join(self.targets)}")
        ev = [evidence.get(t, Evidence(None, cues=0)) for t in self.targets]
        stepped = [step_state(self.statuses[t], e, self.config) for t, e in zip(self.targets, ev)]
        if len(self.targets) > 1:
            stepped = combine_states(stepped, [e.position for e in ev], self.config)
        self.statuses = dict(zip(self.targets, stepped))
        return {t: s.state for t, s in self.statuses.items()}

    @property
    def states(self) -> dict[str, TrackState]:
        """The current state per target."""
        return {t: s.state for t, s in self.statuses.items()}
