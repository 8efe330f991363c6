"""Detections and their association to targets (papers 000 and 004; design ``targets-and-cameras``).

A cue says what it saw, not which target it belongs to: zero or more
:class:`Detection` per frame, each a :class:`~fusion_pf.frame.Measurement`
(position, quality) plus, where the cue knows it, a *label* -- the skeleton's
joint name (certain, ``label_score`` 1) or the hand model's handedness as
``right_hand`` / ``left_hand`` with its score -- and the depth at it.

:func:`associate` gives every target at most one detection per source:

1. compatibility: a hand detection (source ``hand`` or a hand label) is never
   given to a target that is not a hand (the head), a detection labelled
   ``head`` never to a hand; a certain label (``label_score`` 1) goes to its
   target only;
2. per source, a one-to-one assignment over all targets (Hungarian,
   :func:`scipy.optimize.linear_sum_assignment`) minimising the distance to
   each target's prediction, gated (``gates``; for a tracked target also per
   source, ``source_gates``: the pipeline's is a number of standard deviations
   of the target's posterior spread and that cue's noise, with a floor of a
   palm's length); an uncertain label adds (mismatch) or
   removes (match) ``label_score x gate`` of cost, so handedness decides
   between targets at similar distances and cannot pull a target across the
   image; a target without a prediction (uninitialised or lost: acquisition)
   takes a detection no predicted target wants, at the cost of a full gate;
3. a region detection that spans several targets (its ``bbox`` extra holds the
   predictions of two targets that are not combined with each other: one blob
   bridging two hands through the body, or a hand and the torso) measures none
   of them and is given to none, and the targets it holds take no other
   detection of that source (the cue saw them only merged into it; another of
   its regions is something else, e.g. clutter); a combined pair shares it
   (rule 4); the pipeline has the region cues split a region holding two
   hands' predictions into a part per hand first (extras ``part``), so this
   rule is left for what is not split (a hand and the head, hands too close);
4. sharing: a target in the ``combined`` state (paper 004: two joined hands
   make one blob) takes its partner's detection of a source when it got
   none of that source or its own lies farther from its prediction (the
   Hungarian gives each of the pair a detection; the blob they share is the
   nearer one, not a distractor farther out) or, both being hands, its own
   is a *fragment* of the partner's (:func:`fragment`: a region of less than
   :data:`FRAGMENT_AREA` of the partner's area, a sliver of depth beside two
   overlapping hands, not a hand; a hand's region beside the head's is no
   fragment), except when both are parts of
   one region the cue split between them (extras ``part``,
   :func:`fusion_pf.cues.regions.split_region`). No other detection is given
   to two targets.

Detections of one source closer than ``merge_px`` are one detection (the
windows of two nearby targets see the same region).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.optimize import linear_sum_assignment

from ..errors import InputError
from ..frame import Measurement

__all__ = [
    "FRAGMENT_AREA",
    "HANDS",
    "Detection",
    "associate",
    "compatible",
    "fragment",
    "handedness_label",
    "region_area",
]

#: Target names that are hands (the hand cue's detections go to these only).
HANDS = frozenset({"right_hand", "left_hand"})
#: A region detection with less than this fraction of another's area is a fragment of it (:func:`fragment`),
#: and with several targets, of less than this fraction of its window's expected palm area no palm at all
#: (``fusion_pf.pipeline.run._without_fragments``): slivers of depth beside two hands overlapping near the
#: body are 40-460 px^2, the hands 900-4000 (issue 22).
FRAGMENT_AREA = 0.25
#: Cost of a forbidden pairing (larger than any gated cost).
_FORBIDDEN = 1e12


@dataclass(frozen=True, slots=True)
class Detection:
    """One candidate a cue saw in a frame.

    Parameters
    ----------
    measurement : Measurement
        Source, position (full-frame px), quality, extras.
    label : str or None
        The target the cue attributes it to, if it knows: a skeleton joint name,
        the hand model's handedness (``right_hand`` / ``left_hand``).
    label_score : float
        Confidence of the label in [0, 1]; 1 = certain (only that target may take it).
    depth_mm : float or None
        Depth at the detection where the cue measured it.
    """

    measurement: Measurement
    label: str | None = None
    label_score: float = 1.0
    depth_mm: float | None = None

    def __post_init__(self) -> None:
        s = float(self.label_score)
        if not 0.0 <= s <= 1.0:
            raise InputError(f"detection label_score must be in [0, 1], got {self.label_score!r}")
        object.__setattr__(self, "label_score", s)

    @property
    def source(self) -> str:
        """The cue that saw it."""
        return self.measurement.source

    @property
    def u(self) -> float:
        return self.measurement.u

    @property
    def v(self) -> float:
        return self.measurement.v


def handedness_label(handedness: str | None) -> str | None:
    """The target a hand model's handedness (``"right"`` / ``"left"``) names, None when unknown."""
    return None if handedness is None else f"{handedness}_hand"


def compatible(target: str, detection: Detection) -> bool:
    """Whether ``target`` may take ``detection`` at all (rule 1 of the module docstring)."""
    hand = detection.source == "hand" or detection.label in HANDS
    if hand and target not in HANDS:
        return False
    if detection.label == "head" and target != "head":
        return False
    return not (detection.label is not None and detection.label_score >= 1.0 and detection.label != target)


def region_area(m: Measurement) -> float | None:
    """The area of a region cue's measurement (its ``area`` extra, px^2; None for any other)."""
    a = m.extras.get("area")
    return None if a is None else float(cast("float", a))


def fragment(m: Measurement, other: Measurement) -> bool:
    """Whether region measurement ``m`` is a fragment beside ``other``: its area below :data:`FRAGMENT_AREA` of ``other``'s (False without both)."""
    a, b = region_area(m), region_area(other)
    return a is not None and b is not None and a < FRAGMENT_AREA * b


def _merge(detections: Sequence[Detection], merge_px: float) -> list[Detection]:
    """``detections`` of one source without near-duplicates (the first of each group is kept)."""
    out: list[Detection] = []
    for d in detections:
        if not any(
            math.hypot(d.u - o.u, d.v - o.v) <= merge_px and d.label == o.label and d.label_score == o.label_score
            for o in out
        ):
            out.append(d)
    return out


def _spanned(
    detection: Detection,
    targets: Sequence[str],
    predictions: Sequence[tuple[float, float] | None],
    partners: Mapping[str, str],
) -> set[str]:
    """The targets whose predictions ``detection``'s region (its ``bbox`` extra) holds when it holds two not combined with each other (else none)."""
    box = detection.measurement.extras.get("bbox")
    if box is None:
        return set()
    x, y, w, h = cast("Sequence[float]", box)  # a region cue's [x, y, w, h], full-frame px
    inside = [t for t, p in zip(targets, predictions) if p is not None and x <= p[0] <= x + w and y <= p[1] <= y + h]
    spans = any(partners.get(a) != b for n, a in enumerate(inside) for b in inside[n + 1 :])
    return set(inside) if spans else set()


def associate(
    targets: Sequence[str],
    predictions: Sequence[tuple[float, float] | None],
    detections: Sequence[Detection],
    *,
    gates: Sequence[float],
    source_gates: Sequence[Mapping[str, float] | None] | None = None,
    partners: Mapping[str, str] | None = None,
    merge_px: float = 1.0,
) -> dict[str, list[Detection]]:
    """Assign ``detections`` to ``targets`` (module docstring).

    Parameters
    ----------
    targets : sequence of str
        Target names.
    predictions : sequence of (u, v) or None
        Per target its predicted position; None: no prediction (acquisition).
    detections : sequence of Detection
        This frame's detections of every cue.
    gates : sequence of float
        Per target the largest accepted distance to its prediction (px, > 0);
        also the cost of an acquisition.
    source_gates : sequence of (mapping of str to float or None), optional
        Per target (None: none) a tighter gate per source, px (> 0): a
        detection of that source farther than it from the prediction is not
        the target's.
    partners : mapping of str to str, optional
        Combined targets: each one's partner (both directions).
    merge_px : float
        Detections of one source closer than this are one.

    Returns
    -------
    dict of str to list of Detection
        Per target, at most one detection per source, in source order of first appearance.
    """
    k = len(targets)
    if len(predictions) != k or len(gates) != k:
        raise InputError(
            f"targets, predictions and gates must have the same length, got {k}, {len(predictions)}, {len(gates)}"
        )
    gate = np.asarray(gates, dtype=np.float64)
    if k and not (np.isfinite(gate).all() and (gate > 0).all()):
        raise InputError(f"gates must be finite numbers > 0 px, got {list(gates)!r}")
    per_source = [{} if g is None else dict(g) for g in (source_gates or [None] * k)]
    if len(per_source) != k or not all(math.isfinite(v) and v > 0 for g in per_source for v in g.values()):
        raise InputError(f"source_gates must hold one mapping of px > 0 (or None) per target, got {source_gates!r}")
    partners = dict(partners or {})
    out: dict[str, list[Detection]] = {t: [] for t in targets}
    sources = list(dict.fromkeys(d.source for d in detections))
    for source in sources:
        dets = _merge([d for d in detections if d.source == source], merge_px)
        cost = np.full((k, len(dets)), _FORBIDDEN)
        spans = [_spanned(d, targets, predictions, partners) for d in dets]
        blind = set().union(*spans)  # this source saw these targets only inside a spanning region
        for i, t in enumerate(targets):
            p = predictions[i]
            for j, d in enumerate(dets):
                if not compatible(t, d) or spans[j] or t in blind:
                    continue
                if d.label == t and d.label_score >= 1.0:
                    cost[i, j] = 0.0  # a certain label needs no gate
                    continue
                if p is None:
                    c = gate[i]
                else:
                    dist = math.hypot(d.u - p[0], d.v - p[1])
                    if dist > min(gate[i], per_source[i].get(source, math.inf)):
                        continue
                    c = dist
                if d.label is not None:
                    c += (-1.0 if d.label == t else 1.0) * d.label_score * gate[i]
                cost[i, j] = c
        rows, cols = linear_sum_assignment(cost)
        got: dict[str, Detection] = {}
        for i, j in zip(rows, cols):
            if cost[i, j] < _FORBIDDEN:
                got[targets[i]] = dets[j]
        own = dict(got)
        for t, q in partners.items():
            if t not in out or q not in own or not compatible(t, own[q]):
                continue
            p = predictions[targets.index(t)]
            if t in own and "part" in own[t].measurement.extras and "part" in own[q].measurement.extras:
                continue  # the cue split the pair's region between them: each keeps its part
            if (
                t not in own
                or (t in HANDS and q in HANDS and fragment(own[t].measurement, own[q].measurement))
                or (
                    p is not None
                    and math.hypot(own[q].u - p[0], own[q].v - p[1]) < math.hypot(own[t].u - p[0], own[t].v - p[1])
                )
            ):
                got[t] = own[q]
        for t, d in got.items():
            out[t].append(d)
    return out
