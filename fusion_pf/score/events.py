"""Scoring of interaction events: reported ``/tracker/events`` against the true ``/ground_truth/events``.

A reported event matches a true one of the same name and targets (``join``,
``separate``: the unordered pair; every other event: the targets in order)
reported within ``tolerance`` frames of it; each event matches at most once,
the closest in time first. Issue 26's target: every true event matched
(``missed == 0``) and no other event reported (``false == 0``).
"""

from __future__ import annotations

import csv
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from ..errors import InputError

__all__ = ["DEFAULT_TOLERANCE", "EventScore", "events_json", "match_events", "parse_events_cell", "read_events"]

#: Frames a reported event may be from the true one (issue 26).
DEFAULT_TOLERANCE = 5
#: Events whose targets are an unordered set.
_UNORDERED = ("join", "separate")


def _key(event: Mapping) -> tuple[str, tuple[str, ...]]:
    try:
        name, targets = str(event["event"]), tuple(str(t) for t in event["targets"])
    except (KeyError, TypeError):
        raise InputError(f"an event must have 'event' and 'targets', got {dict(event)!r}") from None
    return name, tuple(sorted(targets)) if name in _UNORDERED else targets


@dataclass(frozen=True)
class EventScore:
    """Matched, missed and false events.

    Attributes
    ----------
    matched : list of (true, reported, frame offset)
        Offset = reported frame - true frame.
    missed : list of dict
        True events nothing matched.
    false : list of dict
        Reported events that match no true one.
    """

    matched: list[tuple[dict, dict, int]]
    missed: list[dict]
    false: list[dict]

    @property
    def perfect(self) -> bool:
        """Every true event reported and nothing else."""
        return not self.missed and not self.false

    def summary(self) -> str:
        """One line: counts, the largest offset and what was missed or false."""
        offsets = [abs(o) for _, _, o in self.matched]
        worst = max(offsets) if offsets else 0
        line = f"{len(self.matched)} matched (max |offset| {worst} frames), {len(self.missed)} missed, {len(self.false)} false"
        extra = [f"missed {_show(e)}" for e in self.missed] + [f"false {_show(e)}" for e in self.false]
        return line + ("" if not extra else ": " + ", ".join(extra))


def _show(event: Mapping) -> str:
    return f"{event['event']}:{'+'.join(event['targets'])}@{event['frame']}"


def match_events(
    truth: Sequence[Mapping], reported: Sequence[Mapping], tolerance: int = DEFAULT_TOLERANCE
) -> EventScore:
    """Match reported events to true ones (module docstring).

    Parameters
    ----------
    truth, reported : sequence of mapping
        Events with ``frame`` (int), ``event`` and ``targets``.
    tolerance : int
        Largest ``|reported frame - true frame|`` of a match (>= 0).
    """
    if isinstance(tolerance, bool) or not isinstance(tolerance, int) or tolerance < 0:
        raise InputError(f"event tolerance must be an int >= 0 frames, got {tolerance!r}")
    candidates = sorted(
        (abs(int(r["frame"]) - int(t["frame"])), i, j)
        for i, t in enumerate(truth)
        for j, r in enumerate(reported)
        if _key(t) == _key(r) and abs(int(r["frame"]) - int(t["frame"])) <= tolerance
    )
    used_t: set[int] = set()
    used_r: set[int] = set()
    matched = []
    for _, i, j in candidates:
        if i in used_t or j in used_r:
            continue
        used_t.add(i)
        used_r.add(j)
        matched.append((dict(truth[i]), dict(reported[j]), int(reported[j]["frame"]) - int(truth[i]["frame"])))
    matched.sort(key=lambda m: int(m[0]["frame"]))
    missed = [dict(t) for i, t in enumerate(truth) if i not in used_t]
    false = [dict(r) for j, r in enumerate(reported) if j not in used_r]
    return EventScore(matched, missed, false)


def parse_events_cell(frame: int, cell: str) -> list[dict]:
    """The events of one CSV ``events`` cell (``event:target+target;...``) of frame ``frame``."""
    out = []
    for part in filter(None, cell.split(";")):
        name, sep, targets = part.partition(":")
        if not sep or not name or not targets:
            raise InputError(f"CSV events cell of frame {frame} must be 'event:target+target;...', got {cell!r}")
        out.append({"frame": frame, "event": name, "targets": targets.split("+")})
    return out


def read_events(
    path: str | Path, kind: str, read_topic: Callable[[str | Path, str], list[tuple[int, dict]]]
) -> list[dict] | None:
    """The events of a tracker output or a recording; None when it holds none of that kind.

    ``kind`` is ``"events"`` (a tracker output: its ``/tracker/events`` MCAP
    topic, or its CSV's ``events`` column) or ``"true_events"`` (a scripted
    recording's ``/ground_truth/events``); ``read_topic(path, kind)`` reads
    MCAP topics (``drivers.tracker_topics.read_topic``).
    """
    from .inputs import file_kind

    if file_kind(path) == "csv":
        if kind != "events":
            return None
        with open(path, newline="", encoding="ascii") as fh:
            reader = csv.DictReader(fh)
            if "events" not in (reader.fieldnames or ()):
                return None
            return [e for row in reader for e in parse_events_cell(int(row["frame"]), row["events"] or "")]
    messages = read_topic(path, kind)
    return [m for _, m in messages] if messages else None


def events_json(score: EventScore, tolerance: int) -> dict:
    """The events part of ``fusion-pf score --json``."""
    return {
        "tolerance_frames": tolerance,
        "matched": [
            {"event": t["event"], "targets": t["targets"], "frame": t["frame"], "offset": o}
            for t, _, o in score.matched
        ],
        "missed": score.missed,
        "false": score.false,
        "perfect": score.perfect,
    }
