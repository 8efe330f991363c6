"""Interaction events from the per-target tracks (paper 004 §7): joins, contacts, losses, carried objects.

:class:`EventDetector` is fed one :class:`~fusion_pf.pipeline.run.TrackResult`
per frame (with its frame, for the colour analysis) and returns that frame's
:class:`Event` list. The events, their targets and when they are reported:

``join`` / ``separate`` (two hands)
    The hands enter / leave paper 004's ``combined`` state together (§7.1:
    "coincidence of two limbs happens when the trackers associated with them
    make the transition from the normal state to the combined state").
``contact`` (a hand and the head)
    The hand's estimate comes within ``contact_on`` apparent palm lengths of
    the head's (or the two are combined); it counts as ended only beyond
    ``contact_off`` (> ``contact_on``) palm lengths: hysteresis, so a hand
    hovering at the threshold gives one contact.
``disappear`` / ``reappear`` (one target)
    The target's track is lost / held again after a loss. With one target
    these are the only events.
``pick_up`` / ``put_down`` (a hand) and ``exchange`` (giver, taker)
    §7.2's carried object: around each hand that is on its own (not
    combined, no other hand within ``apart`` palm lengths) the colour modes
    that are not the hand's skin (:func:`object_modes`) say whether it holds an
    object. The carriers are compared at the join's two decision points (§7.3.1):
    the last state before the hands join and the first confirmed state of
    both hands after they separate (their colour analysis counted from the
    separation's onset, the first frame they were apart); an object held by one hand before and by
    the other after is an ``exchange`` (no pick-up or put-down is reported
    for it).

Every condition must hold for ``persist`` consecutive frames before its
event is reported (a one-frame flicker of a state is no event); the event
is reported in the frame that confirms it, its ``detail`` holds the frame
the condition began (``onset_frame``). Pairs of combined targets are taken
from the states alone: the combined targets are paired closest first
(paper 004 assumes at most two targets join at a time).

:meth:`EventDetector.update` takes one camera's pixels and frame;
:meth:`EventDetector.decide` takes the same decisions in any space (the
positions and each hand's palm length in one unit, the combined pairs and the
colour analysis given): :mod:`fusion_pf.pipeline.world_events` feeds it world
millimetres.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np

from ..association import HANDS
from ..cues.roi import PALM_LENGTH_MM
from ..errors import InputError
from ..filter.states import TrackState
from ..frame import Frame

if TYPE_CHECKING:
    from .run import TrackResult

__all__ = [
    "EVENTS",
    "Event",
    "EventConfig",
    "EventDetector",
    "Look",
    "Persist",
    "events_cell",
    "object_modes",
    "pair_within",
]

#: Every event name, in the order of the module docstring.
EVENTS = ("join", "separate", "contact", "disappear", "reappear", "pick_up", "put_down", "exchange")
#: States in which a target holds a track.
_HOLDING = (TrackState.TRACKING.value, TrackState.COMBINED.value, TrackState.UNLABELLED.value)
#: The head target's name.
HEAD = "head"
#: The colour analysis of a hand: ``look(hand, position, palm)`` -> the held object's hue (degrees) or None.
Look = Callable[[str, Sequence[float], float], float | None]


@dataclass(frozen=True)
class Event:
    """One interaction event.

    Attributes
    ----------
    frame : int
        The frame that confirmed it.
    timestamp_ns : int
    event : str
        One of :data:`EVENTS`.
    targets : tuple of str
        The targets involved (``join``: both hands; ``contact``: hand, head;
        ``exchange``: giver, taker).
    detail : dict
        ``onset_frame`` and, for object events, ``hue_deg`` of the object's colour mode.
    """

    frame: int
    timestamp_ns: int
    event: str
    targets: tuple[str, ...]
    detail: dict = field(default_factory=dict)

    def as_json(self) -> dict:
        """The ``/tracker/events`` message (docs/recording-format.md)."""
        return {
            "timestamp_ns": self.timestamp_ns,
            "frame": self.frame,
            "event": self.event,
            "targets": list(self.targets),
            "detail": dict(self.detail),
        }


def events_cell(events: Sequence[Event]) -> str:
    """The CSV ``events`` cell: ``event:target+target;...`` (empty without events)."""
    return ";".join(f"{e.event}:{'+'.join(e.targets)}" for e in events)


@dataclass(frozen=True)
class EventConfig:
    """Thresholds of the event detector (lengths in apparent palm lengths, :data:`PALM_LENGTH_MM` at the hand's depth).

    Parameters
    ----------
    persist : int
        Consecutive frames a condition must hold before it is an event (>= 1).
    carry_persist : int
        Consecutive still frames with (without) an object before a hand
        picks it up (puts it down) outside a join: a small object's colour
        region flickers more than a track state.
    contact_on, contact_off : float
        A hand closer to the head than ``contact_on`` palm lengths touches it;
        the contact ends beyond ``contact_off``.
    join_on, join_off : float
        Where joins are decided on distances (tracking in world coordinates,
        :func:`pair_within`; one camera takes them from the tracker's
        ``combined`` state): two targets closer than ``join_on`` palm lengths
        are combined, and apart again beyond ``join_off``.
    region : float
        Radius of the colour-analysis circle around a hand (palm lengths).
    apart : float
        Another hand closer than this (palm lengths) stops the colour analysis
        of both (their circles overlap).
    depth_tolerance_mm : float
        Only pixels within this depth of the hand count (the object is held at
        the hand's depth; the body behind is not).
    skin_hue_deg : float
        Hues within this of the hand's own (its centre's median hue) are skin.
    min_saturation, min_value : int
        HSV (0-255) below which a pixel has no reliable hue.
    min_area : float
        Smallest connected region of one colour mode, as a fraction of the
        palm's apparent area (``palm_px ** 2``), and at least 10 pixels.
    decision_frames : int
        Frames after a separation within which both hands' carriers are decided;
        later, the separation is decided with what is known.
    still : float
        A hand moving less than this (palm lengths per frame) is still: outside
        a separation's decision, a hand takes or leaves an object only while
        still (the climax point of a pick-up or put-down, §7.3.1), so a hand
        passing an object does not take it and a moving hand whose object is
        hidden for a few frames does not put it down.
    """

    persist: int = 2
    carry_persist: int = 4
    contact_on: float = 1.3
    contact_off: float = 1.8
    join_on: float = 1.25
    join_off: float = 1.5
    region: float = 1.1
    apart: float = 2.2
    depth_tolerance_mm: float = 80.0
    skin_hue_deg: float = 25.0
    min_saturation: int = 90
    min_value: int = 40
    min_area: float = 0.08
    decision_frames: int = 20
    still: float = 0.15

    def __post_init__(self) -> None:
        for name in ("persist", "carry_persist", "decision_frames"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise InputError(f"event {name} must be an int >= 1 frame, got {value!r}")
        for on, off in (("contact_on", "contact_off"), ("join_on", "join_off")):
            if not 0.0 < getattr(self, on) <= getattr(self, off):
                raise InputError(f"event {on} must be > 0 and <= {off} ({getattr(self, off)}), got {getattr(self, on)}")


class Persist:
    """A debounced boolean: the reported value changes once the raw value has differed for ``frames`` frames.

    Parameters
    ----------
    frames : int
        Consecutive frames of a new raw value before it is taken (>= 1).
    value : bool or None
        The initial value (None: unknown; the first raw value held for ``frames`` is taken).
    """

    def __init__(self, frames: int, value: bool | None = None) -> None:
        self.frames = frames
        self.value = value
        self._run = 0
        self._raw: bool | None = None
        self.onset = -1

    def update(self, raw: bool, frame: int) -> bool:
        """Feed this frame's raw value; True when the reported value changed in this frame."""
        if raw == self.value:
            self._run = 0
            return False
        if raw != self._raw or self._run == 0:
            self.onset = frame
            self._run = 0
        self._raw = raw
        self._run += 1
        if self._run < self.frames:
            return False
        self.value, self._run = raw, 0
        return True


def _hue_distance(a: np.ndarray | float, b: float) -> np.ndarray:
    """Circular distance of hues in degrees."""
    d = np.abs(np.asarray(a) - np.float32(b)) % np.float32(360.0)
    return np.minimum(d, 360.0 - d)


def object_modes(
    color: np.ndarray,
    depth: np.ndarray | None,
    centre: tuple[float, float],
    palm_px: float,
    z_mm: float | None,
    config: EventConfig,
    clothing_hue: float | None = None,
) -> list[tuple[float, int]]:
    """The colour modes around a hand that are not its skin (paper 004 §7.2.1-7.2.2).

    The circle of radius ``config.region * palm_px`` around ``centre`` is
    selected; pixels farther than ``depth_tolerance_mm`` from the hand's depth
    ``z_mm`` (when there is depth; pixels without depth are kept: a small
    object's depth is mostly holes and flying pixels at its edges), without a reliable hue (saturation, value)
    or with the hand's own hue (the median hue of the palm's centre) or the
    clothing's (``clothing_hue``, e.g. the hue at the skeleton's torso joint:
    sleeves) within ``skin_hue_deg`` are removed. The hue histogram of the rest (2-degree
    bins) is smoothed with a Gaussian kernel (kernel density estimation) and
    its local maxima are the modes; a mode is kept when the pixels within 8
    degrees of it form one connected region of at least ``min_area``
    palm areas (and 10 pixels).

    Returns
    -------
    list of (hue_deg, pixels)
        The kept modes, largest region first.
    """
    h, w = color.shape[:2]
    r = config.region * palm_px
    u, v = centre
    x0, x1 = max(int(math.floor(u - r)), 0), min(int(math.ceil(u + r)) + 1, w)
    y0, y1 = max(int(math.floor(v - r)), 0), min(int(math.ceil(v + r)) + 1, h)
    if x1 - x0 < 3 or y1 - y0 < 3:
        return []
    patch = np.ascontiguousarray(color[y0:y1, x0:x1])
    hsv = cv2.cvtColor(patch, cv2.COLOR_RGB2HSV_FULL)
    hue = hsv[..., 0].astype(np.float32) * np.float32(360.0 / 256.0)
    yy, xx = np.ogrid[y0:y1, x0:x1]
    dist2 = (xx - u) ** 2 + (yy - v) ** 2
    mask = (dist2 <= r * r) & (hsv[..., 1] >= config.min_saturation) & (hsv[..., 2] >= config.min_value)
    if depth is not None and z_mm is not None:
        d = depth[y0:y1, x0:x1].astype(np.float32)
        mask &= (d == 0) | (
            np.abs(d - np.float32(z_mm)) <= config.depth_tolerance_mm
        )  # no depth (holes at edges): kept
    inner = dist2 <= (0.25 * palm_px) ** 2
    if inner.any():
        skin = float(np.median(hue[inner]))
        mask &= _hue_distance(hue, skin) > config.skin_hue_deg
    if clothing_hue is not None:
        mask &= _hue_distance(hue, clothing_hue) > config.skin_hue_deg
    min_pixels = max(10, int(config.min_area * palm_px * palm_px))
    if int(mask.sum()) < min_pixels:
        return []
    hist = np.bincount((hue[mask] / 2.0).astype(np.int64) % 180, minlength=180).astype(np.float64)
    smooth = cv2.GaussianBlur(np.tile(hist, 3)[None, :], (0, 0), 2.0, borderType=cv2.BORDER_REPLICATE)[0, 180:360]
    # pixels within 8 degrees (4 bins) of each bin: a mode with fewer cannot hold a large enough region
    window = np.convolve(np.tile(hist, 3), np.ones(9), mode="same")[180:360]
    peaks = np.flatnonzero((smooth > np.roll(smooth, 1)) & (smooth >= np.roll(smooth, -1)) & (window >= min_pixels))
    modes = []
    for p in peaks:
        hue_deg = 2.0 * p + 1.0
        near = (mask & (_hue_distance(hue, hue_deg) <= 8.0)).astype(np.uint8)
        n, _, stats, _ = cv2.connectedComponentsWithStats(near, connectivity=8)
        largest = int(stats[1:, cv2.CC_STAT_AREA].max()) if n > 1 else 0
        if largest >= min_pixels:
            modes.append((hue_deg, largest))
    return sorted(modes, key=lambda m: -m[1])


@dataclass
class _Pending:
    """A joined pair of hands and, once separated, waiting for its second decision point (§7.3.1).

    ``apart`` holds each hand's latest colour analysis (frame, hue) taken while the pair was apart but its
    separation not yet confirmed: from the separation's onset it is the second decision point's first sample.
    """

    before: dict[str, float | None]
    frame: int
    samples: dict[str, list[float | None]] | None = None
    apart: dict[str, tuple[int, float | None]] = field(default_factory=dict)


class EventDetector:
    """Events of one run, frame by frame (module docstring).

    Parameters
    ----------
    targets : sequence of str
        The tracked targets, in result order (one target: only ``disappear`` / ``reappear``).
    config : EventConfig, optional
    """

    def __init__(self, targets: Sequence[str], config: EventConfig | None = None) -> None:
        if not targets:
            raise InputError("EventDetector needs at least one target")
        self.targets = tuple(targets)
        self.config = config or EventConfig()
        n = self.config.persist
        self.hands = tuple(t for t in self.targets if t in HANDS) if len(self.targets) > 1 else ()
        self._held = {t: Persist(n) for t in self.targets}
        self._seen = {t: False for t in self.targets}
        pairs = [(a, b) for i, a in enumerate(self.hands) for b in self.hands[i + 1 :]]
        self._joined = {p: Persist(n, False) for p in pairs}
        self._contact = {h: Persist(n, False) for h in self.hands} if HEAD in self.targets else {}
        self._carry = {h: Persist(self.config.carry_persist, False) for h in self.hands}
        self._hue: dict[str, float | None] = {h: None for h in self.hands}
        self._candidate_hue: dict[str, float | None] = {h: None for h in self.hands}
        self._palm_px: dict[str, float] = {}
        self._last: dict[str, Sequence[float]] = {}
        self._pending: dict[tuple[str, str], _Pending] = {}
        self.counts = {e: 0 for e in EVENTS}

    def feed(self, result: TrackResult) -> list[Event]:
        """The events of one tracked frame: :meth:`update` with the states, estimates and depths of ``result``.

        ``result.targets`` holds every target with several targets, else
        ``result`` is the one target's; ``result.source_frame`` (set by
        :func:`~fusion_pf.pipeline.run.track`) is the image. A background frame has none.
        """
        if result.background:
            return []
        results = result.targets or {result.target: result}
        states = {t: r.state for t, r in results.items()}
        positions = {t: None if r.estimate is None else (r.estimate.u, r.estimate.v) for t, r in results.items()}
        depths = {t: None if r.xyz_mm is None else float(r.xyz_mm[2]) for t, r in results.items()}
        return self.update(
            states, positions, result.frame, result.timestamp_ns, image=result.source_frame, depths_mm=depths
        )

    def update(
        self,
        states: Mapping[str, str],
        positions: Mapping[str, tuple[float, float] | None],
        frame: int,
        timestamp_ns: int,
        *,
        image: Frame | None = None,
        depths_mm: Mapping[str, float | None] | None = None,
    ) -> list[Event]:
        """The events of one frame from every target's state and estimate.

        Parameters
        ----------
        states : mapping of str to str
            Each target's track state (:class:`~fusion_pf.filter.states.TrackState` value).
        positions : mapping of str to (u, v) or None
            Each target's estimate.
        frame, timestamp_ns : int
        image : Frame, optional
            The frame (colour, depth, intrinsics) for the palm size and the colour analysis;
            without it there are no contact or object events.
        depths_mm : mapping of str to float or None, optional
            Each target's depth (its 3-D ``z``), for the apparent palm size.
        """
        self._update_palms(image, depths_mm or {})
        look = None if image is None else _looker(image, depths_mm or {}, self.config)
        return self.decide(states, positions, frame, timestamp_ns, palms=self._palm_px, look=look)

    def decide(
        self,
        states: Mapping[str, str],
        positions: Mapping[str, Sequence[float] | None],
        frame: int,
        timestamp_ns: int,
        *,
        palms: Mapping[str, float] | None = None,
        look: Look | None = None,
        partners: Mapping[str, str] | None = None,
    ) -> list[Event]:
        """The events of one frame in any space: image pixels (:meth:`update`) or world millimetres.

        Parameters
        ----------
        states : mapping of str to str
            Each target's track state.
        positions : mapping of str to a point or None
            Each target's estimate, in the units of ``palms`` (``(u, v)`` px, ``(x, y, z)`` mm).
        frame, timestamp_ns : int
        palms : mapping of str to float, optional
            Each hand's palm length in those units (the unit of the thresholds of :class:`EventConfig`);
            a hand without one has no contact by distance and no object analysis.
        look : callable, optional
            ``look(hand, position, palm)``: the hue of the object the hand holds (the largest colour mode that
            is not skin, :func:`object_modes`) or None; without it there are no object events.
        partners : mapping of str to str, optional
            The combined targets, each to its partner (paper 004's ``combined`` state); None: taken from
            ``states`` (the combined targets, closest first).
        """
        unknown = sorted(set(states) - set(self.targets))
        if unknown:
            raise InputError(f"events for unknown target {unknown[0]!r}; targets: {', '.join(self.targets)}")
        out: list[Event] = []

        def emit(event: str, targets: Sequence[str], onset: int, **detail: object) -> None:
            out.append(Event(frame, timestamp_ns, event, tuple(targets), {"onset_frame": onset, **detail}))
            self.counts[event] += 1

        for t in self.targets:
            held = states.get(t) in _HOLDING
            p = self._held[t]
            if p.update(held, frame):
                if held and self._seen[t]:
                    emit("reappear", (t,), p.onset)
                elif not held and self._seen[t]:
                    emit("disappear", (t,), p.onset)
                self._seen[t] = self._seen[t] or held
        if not self.hands:
            return out
        partners = _pair_combined(states, positions) if partners is None else partners
        palms = palms or {}
        for pair, p in self._joined.items():
            a, b = pair
            if p.update(partners.get(a) == b, frame):
                if p.value:
                    emit("join", pair, p.onset)
                    self._pending[pair] = _Pending({h: self._hue[h] for h in pair}, frame)
                else:
                    emit("separate", pair, p.onset)
                    pending = self._pending.get(pair)
                    if pending is not None:
                        since = {h: pending.apart.get(h, (-1, None)) for h in pair}
                        pending.frame = frame
                        pending.samples = {h: [hue] if at >= p.onset else [] for h, (at, hue) in since.items()}
        head = positions.get(HEAD) if states.get(HEAD) in _HOLDING else None
        for h, p in self._contact.items():
            pos = positions.get(h) if states.get(h) in _HOLDING else None
            palm = palms.get(h)
            near = partners.get(h) == HEAD
            if pos is not None and head is not None and palm is not None:
                limit = (self.config.contact_off if p.value else self.config.contact_on) * palm
                near = near or math.dist(pos, head) < limit
            if p.update(near, frame) and p.value:
                emit("contact", (h, HEAD), p.onset)
        if look is not None:
            self._objects(states, positions, partners, palms, look, frame, emit)
        return out

    def _update_palms(self, image: Frame | None, depths_mm: Mapping[str, float | None]) -> None:
        if image is None:
            return
        for h in self.hands:
            z = depths_mm.get(h)
            if z is not None and z > 0:
                self._palm_px[h] = image.intrinsics.fx * PALM_LENGTH_MM / z

    def _objects(self, states, positions, partners, palms, look: Look, frame: int, emit) -> None:
        """Carried objects (§7.2) and the decisions of separated pairs (§7.3.1)."""
        cfg = self.config
        changed: dict[str, int] = {}
        for h in self.hands:
            pos, palm = positions.get(h), palms.get(h)
            if states.get(h) != TrackState.TRACKING.value or h in partners or pos is None or palm is None:
                continue
            others = [positions.get(o) for o in self.hands if o != h]
            if any(o is not None and math.dist(o, pos) < cfg.apart * palm for o in others):
                continue
            hue = look(h, pos, palm)
            last, self._last[h] = self._last.get(h), pos
            waiting = [q.samples for pair, q in self._pending.items() if h in pair and q.samples is not None]
            if waiting:
                waiting[0][h].append(hue)  # the second decision point collects, the Persist waits
                continue
            joined = [q for pair, q in self._pending.items() if h in pair]
            if joined:  # the first decision point is taken; apart already: the separation's onset, if confirmed
                joined[0].apart[h] = (frame, hue)
                continue
            p = self._carry[h]
            if hue is not None:
                self._candidate_hue[h] = hue
            still = last is not None and math.dist(pos, last) < cfg.still * palm
            # a hand takes or leaves an object only while still (the climax point of a pick-up or put-down)
            if still and p.update(hue is not None, frame):
                self._hue[h] = self._candidate_hue[h] if p.value else None
                changed[h] = p.onset
        for pair, pending in list(self._pending.items()):
            if pending.samples is None:
                continue
            ready = all(len(v) >= cfg.persist for v in pending.samples.values())
            if not ready and frame - pending.frame < cfg.decision_frames:
                continue
            del self._pending[pair]
            after = {h: _majority(v) for h, v in pending.samples.items()}
            for h in pair:
                self._hue[h] = after[h]
                self._carry[h] = Persist(cfg.carry_persist, after[h] is not None)
            a, b = pair
            before = pending.before
            exchanged = False
            for giver, taker in ((a, b), (b, a)):
                got, had = after[taker], before[giver]
                if had is not None and got is not None and after[giver] is None and before[taker] is None:
                    emit("exchange", (giver, taker), pending.frame, hue_deg=round(float(got), 1))
                    exchanged = True
            for h in () if exchanged else pair:
                if before[h] is None and (now := after[h]) is not None:
                    emit("pick_up", (h,), pending.frame, hue_deg=round(float(now), 1))
                elif before[h] is not None and after[h] is None:
                    emit("put_down", (h,), pending.frame)
        for h, onset in changed.items():
            if self._carry[h].value:
                emit("pick_up", (h,), onset, hue_deg=round(float(self._hue[h] or 0.0), 1))
            else:
                emit("put_down", (h,), onset)


def _looker(image: Frame, depths_mm: Mapping[str, float | None], config: EventConfig) -> Look:
    """The colour analysis of one camera's frame: a hand's largest :func:`object_modes` mode (its hue), or None."""
    clothing = _clothing_hue(image)

    def look(hand: str, position: Sequence[float], palm: float) -> float | None:
        u, v = position
        modes = object_modes(image.color, image.depth, (u, v), palm, depths_mm.get(hand), config, clothing)
        return modes[0][0] if modes else None

    return look


def _majority(samples: Sequence[float | None]) -> float | None:
    """A hand's carrier state from its samples after a separation: the object's hue when at least half saw one."""
    hues = [x for x in samples if x is not None]
    if not samples or 2 * len(hues) < len(samples):
        return None
    return float(np.median(hues))


def _clothing_hue(image: Frame) -> float | None:
    """The hue of the person's clothing: the median hue around the skeleton's torso joint (None without one)."""
    joint = None if image.joints is None else image.joints.get("torso")
    if joint is None:
        return None
    h, w = image.color.shape[:2]
    r = max(2, int(0.02 * w))
    u, v = int(round(joint.u)), int(round(joint.v))
    patch = image.color[max(v - r, 0) : min(v + r + 1, h), max(u - r, 0) : min(u + r + 1, w)]
    if patch.size == 0:
        return None
    hsv = cv2.cvtColor(np.ascontiguousarray(patch), cv2.COLOR_RGB2HSV_FULL)
    return float(np.median(hsv[..., 0])) * 360.0 / 256.0


def pair_within(
    positions: Mapping[str, Sequence[float] | np.ndarray | None], before: Mapping[str, str], on: float, off: float
) -> dict[str, str]:
    """Targets combined by distance, each to its partner: closer than ``on``, or combined ``before`` and closer than
    ``off`` (hysteresis); pairs taken in target order, each target in at most one (paper 004: two at a time)."""
    out: dict[str, str] = {}
    names = [t for t, p in positions.items() if p is not None]
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            pa, pb = positions[a], positions[b]
            if a in out or b in out or pa is None or pb is None:
                continue
            gap = math.dist(pa, pb)
            if gap < on or (before.get(a) == b and gap < off):
                out[a], out[b] = b, a
    return out


def _pair_combined(states: Mapping[str, str], positions: Mapping[str, Sequence[float] | None]) -> dict[str, str]:
    """The combined targets, each to its partner: closest pairs first (paper 004: two at a time)."""
    combined = [t for t, s in states.items() if s == TrackState.COMBINED.value and positions.get(t) is not None]
    pairs = sorted(
        (math.dist(pa, pb), a, b)
        for i, a in enumerate(combined)
        for b in combined[i + 1 :]
        if (pa := positions[a]) is not None and (pb := positions[b]) is not None
    )
    out: dict[str, str] = {}
    for _, a, b in pairs:
        if a not in out and b not in out:
            out[a], out[b] = b, a
    return out
