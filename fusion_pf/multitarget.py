"""Running and scoring multi-target trackers on a recording (papers 000, 002, 004).

Per frame the measurements are the whole-frame skin blobs
(:func:`fusion_pf.cues.blobs.skin_blobs`), associated to the targets by
:func:`fusion_pf.filter.multi.associate` (nearest prediction, gated), plus the
skeleton joint named like each target (``right_hand``, ``left_hand``,
``head``), which needs no association. :func:`run_tracker` feeds them to any
tracker with ``predictions()`` and ``step(timestamp_ns, {target: measurements})``
(:class:`~fusion_pf.filter.multi.KMeansParticleFilter`,
:class:`~fusion_pf.filter.multi.IndependentTrackers`); the scores are paper
000's RMSE per target, identity swaps, and frames per track state (paper 004).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np

from fusion_pf.cues.base import Measurement
from fusion_pf.cues.blobs import skin_blobs
from fusion_pf.cues.skin import SkinCue
from fusion_pf.errors import InputError
from fusion_pf.filter.multi import associate
from fusion_pf.filter.states import TrackState
from fusion_pf.frame import Frame
from fusion_pf.score.targets import count_swaps

__all__ = [
    "Associator",
    "FrameInputs",
    "Run",
    "frame_input",
    "frame_inputs",
    "identity_swaps",
    "label_blobs",
    "rmse",
    "run_tracker",
    "state_counts",
]


@dataclass(frozen=True)
class FrameInputs:
    """The measurements and ground truth of one person frame.

    Attributes
    ----------
    timestamp_ns : int
    blobs : list of Measurement
        Unassociated skin blobs.
    labelled : dict of str to list of Measurement
        Measurements that name their target (skeleton joints).
    truths : dict of str to (float, float)
        Ground truth per target (empty without one).
    """

    timestamp_ns: int
    blobs: list[Measurement]
    labelled: dict[str, list[Measurement]]
    truths: dict[str, tuple[float, float]]


def frame_input(frame: Frame, targets: Sequence[str], skin: SkinCue | None, *, skeleton: bool = True) -> FrameInputs:
    """The measurements and ground truth of one person frame (see :func:`frame_inputs`)."""
    blobs = skin_blobs(frame.color, skin) if skin is not None else []
    labelled: dict[str, list[Measurement]] = {}
    for t in targets:
        j = frame.joint(t) if skeleton else None
        labelled[t] = [Measurement("skeleton", j.u, j.v, j.confidence)] if j is not None else []
    truths = {k: (p.u, p.v) for k, p in (frame.ground_truths or {}).items()}
    if not truths and frame.ground_truth is not None:
        truths = {targets[0]: (frame.ground_truth.u, frame.ground_truth.v)}
    return FrameInputs(frame.timestamp_ns, blobs, labelled, truths)


def frame_inputs(
    frames: Iterable[Frame], targets: Sequence[str], skin: SkinCue | None, *, skeleton: bool = True
) -> list[FrameInputs]:
    """Extract the per-frame measurements once (background frames are skipped).

    Parameters
    ----------
    frames : iterable of Frame
    targets : sequence of str
    skin : SkinCue or None
        Whole-frame skin blobs from this cue's model and region steps; None: no blobs.
    skeleton : bool
        Use the skeleton joint of each target (source ``"skeleton"``).
    """
    out = [frame_input(f, targets, skin, skeleton=skeleton) for f in frames if not f.background]
    if not out:
        raise InputError("the recording has no person (non-background) frames to track")
    return out


@dataclass
class Run:
    """One tracker's output over a recording.

    Attributes
    ----------
    estimates : dict of str to ndarray, shape (F, 2)
        Per target (nan while uninitialised).
    states : dict of str to list of TrackState
    evaluations : ndarray, shape (F,)
        Likelihood evaluations per frame.
    """

    estimates: dict[str, np.ndarray]
    states: dict[str, list[TrackState]]
    evaluations: np.ndarray
    restarts: dict[str, int] = field(default_factory=dict)


class Associator:
    """Per frame: blobs to targets (nearest prediction, gated), then one tracker step (see :func:`run_tracker`).

    Parameters
    ----------
    tracker : KMeansParticleFilter, IndependentTrackers or JointScatterSearchPF
        Anything with ``targets``, ``predictions()`` and ``step(t, {target: [Measurement]})``.
    gate_px : float
        Association gate of a tracked target.
    lost_gate_px : float
        Wider gate of a target in the ``lost`` state (paper 004: the lost state
        "tries to use prior information of the target position to retrieve the track").
    """

    def __init__(self, tracker, gate_px: float = 40.0, lost_gate_px: float = 120.0) -> None:
        self.tracker = tracker
        self.gate_px, self.lost_gate_px = float(gate_px), float(lost_gate_px)
        self.gates = np.full(len(tracker.targets), self.gate_px)

    def __call__(self, fi: FrameInputs):
        """Associate ``fi``'s blobs and step the tracker; returns its ``MultiEstimate``."""
        tracker, targets = self.tracker, self.tracker.targets
        ms = {t: list(fi.labelled.get(t, ())) for t in targets}
        if fi.blobs:
            pos = np.array([[b.u, b.v] for b in fi.blobs])
            pred = tracker.predictions()
            first = label_blobs(pos, targets)
            # a target without a prediction yet: its labelled measurement, else the layout rule
            for k, t in enumerate(targets):
                if not np.isfinite(pred[k, 0]):
                    if ms[t]:
                        pred[k] = (ms[t][0].u, ms[t][0].v)
                    elif t in first:
                        pred[k] = pos[first[t]]
            for k, j in enumerate(associate(pred, pos, self.gates)):
                if j >= 0:
                    ms[targets[k]].append(fi.blobs[j])
        out = tracker.step(fi.timestamp_ns, ms)
        for k, t in enumerate(targets):
            self.gates[k] = self.lost_gate_px if out.targets[t].state == TrackState.LOST else self.gate_px
        return out


def run_tracker(tracker, inputs: Sequence[FrameInputs], gate_px: float = 40.0, lost_gate_px: float = 120.0) -> Run:
    """Track ``inputs`` with ``tracker``: associate the blobs, step, collect (:class:`Associator`)."""
    targets = tracker.targets
    est = {t: np.full((len(inputs), 2), np.nan) for t in targets}
    states: dict[str, list[TrackState]] = {t: [] for t in targets}
    evals = np.zeros(len(inputs), dtype=np.int64)
    step = Associator(tracker, gate_px, lost_gate_px)
    for i, fi in enumerate(inputs):
        out = step(fi)
        evals[i] = out.evaluations
        for t in targets:
            e = out.targets[t]
            est[t][i] = (e.u, e.v)
            states[t].append(e.state)
    return Run(est, states, evals, dict(getattr(tracker, "restarts", {})))


def label_blobs(positions: np.ndarray, targets: Sequence[str]) -> dict[str, int]:
    """Initial labels of unlabelled blobs from the body layout (paper 004 §5.2's application cues).

    A person facing the camera with the hands lowered: the two lowest blobs
    are the hands, the ``right_hand`` the left one in the image and the
    ``left_hand`` the right one; the ``head`` is, of the other blobs, the one
    horizontally closest to the hands' middle (other skin-coloured clutter,
    e.g. a picture on the wall, is off to the side). Other target names get
    no label.

    Parameters
    ----------
    positions : ndarray, shape (M, 2)
        Blob centroids.
    targets : sequence of str

    Returns
    -------
    dict of str to int
        Blob index per labelled target.
    """
    p = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    order = [int(i) for i in np.argsort(-p[:, 1])]
    hands = sorted(order[:2], key=lambda i: p[i, 0])
    out: dict[str, int] = {}
    if len(hands) == 2:
        if "right_hand" in targets:
            out["right_hand"] = hands[0]
        if "left_hand" in targets:
            out["left_hand"] = hands[1]
    rest = order[2:]
    if "head" in targets and rest and len(hands) == 2:
        middle = p[hands, 0].mean()
        out["head"] = min(rest, key=lambda i: abs(p[i, 0] - middle))
    return out


def _truth(inputs: Sequence[FrameInputs], target: str) -> np.ndarray:
    return np.array([fi.truths.get(target, (math.nan, math.nan)) for fi in inputs], dtype=np.float64)


def rmse(run: Run, inputs: Sequence[FrameInputs], target: str, skip: int = 0) -> float:
    """Root-mean-square position error (px) of ``target`` over frames ``skip..`` with an estimate and a truth."""
    err = run.estimates[target][skip:] - _truth(inputs, target)[skip:]
    d2 = (err**2).sum(axis=1)
    d2 = d2[np.isfinite(d2)]
    return float(math.sqrt(d2.mean())) if len(d2) else math.nan


def identity_swaps(run: Run, inputs: Sequence[FrameInputs], pair: tuple[str, str], min_separation_px: float) -> int:
    """How many times the two targets' estimates swap identities (:func:`fusion_pf.score.targets.count_swaps`)."""
    a, b = pair
    return count_swaps(run.estimates[a], run.estimates[b], _truth(inputs, a), _truth(inputs, b), min_separation_px)


def state_counts(run: Run, target: str) -> dict[str, int]:
    """Frames per track state of ``target`` (every state listed, zeros included)."""
    counts = {s.value: 0 for s in TrackState}
    for s in run.states[target]:
        counts[s.value] += 1
    return counts
