"""The driver contract: sources yield :class:`~fusion_pf.frame.Frame` objects, sinks take them.

Every source is a context manager. Opening it acquires the device or file,
iterating it yields frames in capture order, closing it releases everything
(also after an exception or Ctrl-C)::

    with open_source("recordings/sample.mcap") as src:
        for frame in src:
            ...

Guarantees
----------
Live sources (``live = True``, e.g. the OAK camera)
    * can be iterated once; a second ``iter()`` raises :class:`RecordingError`;
    * are not seekable: ``len()``, ``seek`` and time windows are unavailable;
    * count what they lose in :attr:`Source.stats` (``dropped``) instead of
      hiding it; sequence numbers keep the device's numbering, so gaps show.
Replay sources (``live = False``: MCAP files, synthetic scenes)
    * are re-iterable: every ``iter()`` starts again at the first selected
      frame and yields the same frames;
    * are seekable (:class:`ReplaySource`): ``len()`` is the number of frames,
      ``frames(start=, stop=, start_ns=, end_ns=)`` yields a window.

Sinks (recorders, tracker outputs) are context managers too, and are always
finalised on close, so a file is valid whatever stopped the source.
"""

from __future__ import annotations

import abc
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from typing import TypeVar

from fusion_pf.frame import Frame
from fusion_pf.rig import CameraPose, FrameSet

_SourceT = TypeVar("_SourceT", bound="Source")
_SinkT = TypeVar("_SinkT", bound="Sink")
_RigT = TypeVar("_RigT", bound="RigSource")


@dataclass(frozen=True)
class FrameLoss:
    """Frames a source could not deliver, and why (one damaged chunk, one gap, the truncated tail).

    Attributes
    ----------
    frames : int or None
        How many frames were lost; None when the count cannot be known (the
        frames after the point where a file is truncated).
    reason : str
        Why, e.g. ``"chunk at byte 361 is corrupt (chunk CRC mismatch ...)"``.
    offset : int or None
        Byte offset of the damage in the file, when there is one.
    tail : bool
        True for the end of a truncated file (frames recorded after the cut;
        an unfinished recording has one too).
    """

    frames: int | None
    reason: str
    offset: int | None = None
    tail: bool = False

    def describe(self) -> str:
        """``"<reason> (3 frames)"``, or ``"<reason> (number unknown)"``."""
        if self.frames is None:
            return f"{self.reason} (number unknown)"
        return f"{self.reason} ({self.frames} frame{'s' if self.frames != 1 else ''})"


#: Losses listed one by one in :meth:`SourceStats.loss_summary`; the rest are counted.
_LISTED_LOSSES = 4


@dataclass
class SourceStats:
    """What a source yielded and what it lost (filled in while iterating).

    Attributes
    ----------
    frames : int
        Frames yielded.
    missing_depth : int
        Frames yielded with ``depth=None``.
    missing_skeleton : int
        Frames yielded with ``joints=None``.
    dropped : int
        Frames known to be lost (sequence gaps on live sources, incomplete
        frames a replay had to skip).
    notes : list of str
        Human-readable remarks (e.g. "file truncated after 1.2 s").
    losses : list of FrameLoss
        Every frame a replay could not read, grouped by cause (their known
        counts add up to the replay's share of ``dropped``).
    skipped_parts : dict of str to int
        Malformed or unreadable optional messages left out of yielded frames, by part
        (``"depth"``, ``"skeleton"``, ``"ground truth"``): the frame was
        yielded without it.
    lost_background : int
        How many of the lost frames belong to the recording's leading
        background (empty-scene) section.
    warnings : list of str
        Damage that cost no frame but changes what the frames are taken for,
        e.g. an unreadable recording metadata record (the number of background
        frames is unknown); each makes the run :attr:`partial`.
    """

    frames: int = 0
    missing_depth: int = 0
    missing_skeleton: int = 0
    dropped: int = 0
    notes: list[str] = field(default_factory=list)
    losses: list[FrameLoss] = field(default_factory=list)
    skipped_parts: dict[str, int] = field(default_factory=dict)
    lost_background: int = 0
    warnings: list[str] = field(default_factory=list)

    @property
    def partial(self) -> bool:
        """True when frames were lost, parts of frames were left out, or damage left a warning."""
        return bool(self.dropped or self.losses or any(self.skipped_parts.values()) or self.warnings)

    def loss_summary(self) -> str:
        """One line saying what was lost and why; ``""`` when nothing was.

        Examples
        --------
        ``"skipped 12 frames: chunk at byte 361 is corrupt (chunk CRC mismatch ...) (8 frames); ...
        (4 frames); 3 skeleton messages unreadable (frames kept without skeleton)"``; a count that
        cannot be known (a truncated tail) makes it ``"skipped 12 frames and an unknown number more"``
        (``"skipped an unknown number of frames"`` when it is the only loss). The
        :attr:`warnings` follow (alone when no frame was lost).
        """
        parts = [loss.describe() for loss in self.losses[:_LISTED_LOSSES]]
        rest = self.losses[_LISTED_LOSSES:]
        if rest:
            known = sum(loss.frames or 0 for loss in rest)
            parts.append(f"{known} more frames in {len(rest)} other damaged places")
        for part, n in sorted(self.skipped_parts.items()):
            if n:
                parts.append(f"{n} {part} message{'s' if n != 1 else ''} unreadable (frames kept without {part})")
        if not parts and not self.dropped:
            return "; ".join(self.warnings)
        unknown = any(loss.frames is None for loss in self.losses)
        head = f"skipped {self.dropped} frame{'s' if self.dropped != 1 else ''}"
        if unknown:
            head = f"{head} and an unknown number more" if self.dropped else "skipped an unknown number of frames"
        return f"{head}: " + "; ".join(parts + self.warnings) if parts or self.warnings else head

    def count(self, frame: Frame) -> Frame:
        """Count ``frame`` as yielded and return it."""
        self.frames += 1
        self.missing_depth += frame.depth is None
        self.missing_skeleton += frame.joints is None
        return frame


class Source(abc.ABC):
    """A context manager that yields frames.

    Subclasses implement :meth:`open`, :meth:`close` and :meth:`_frames`.
    """

    #: True for a device (iterate once, not seekable), False for a replay.
    live: bool = False

    def __init__(self) -> None:
        self.stats = SourceStats()
        self._opened = False

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire the device or file; raise a FusionPFError when impossible."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release everything; safe to call twice."""

    @abc.abstractmethod
    def _frames(self) -> Iterator[Frame]:
        """Yield frames in capture order (called by ``__iter__``)."""

    def __enter__(self: _SourceT) -> _SourceT:
        self.open()
        self._opened = True
        return self

    def __exit__(self, *exc: object) -> None:
        self._opened = False
        self.close()

    def __iter__(self) -> Generator[Frame, None, None]:
        if not self._opened:
            raise RuntimeError(f"{type(self).__name__} must be used inside a 'with' block")
        for frame in self._frames():
            yield self.stats.count(frame)

    def describe(self) -> str:
        """One line naming the source for messages and progress bars."""
        return type(self).__name__


class ReplaySource(Source):
    """A seekable, re-iterable source (recording or generator)."""

    live = False

    @abc.abstractmethod
    def __len__(self) -> int:
        """Number of frames the source holds."""

    @abc.abstractmethod
    def frames(
        self,
        start: int = 0,
        stop: int | None = None,
        *,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[Frame]:
        """Yield frames with index in ``[start, stop)`` and time in ``[start_ns, end_ns)``."""

    def _frames(self) -> Iterator[Frame]:
        return self.frames()


class Sink(abc.ABC):
    """A context manager that takes frames (and tracker outputs) and writes them.

    :meth:`close` must always leave a valid output, whether the source ended,
    raised, or the user pressed Ctrl-C.
    """

    @abc.abstractmethod
    def open(self) -> None:
        """Create the output."""

    @abc.abstractmethod
    def write(self, frame: Frame) -> None:
        """Write one frame."""

    @abc.abstractmethod
    def close(self) -> None:
        """Finalise the output; safe to call twice."""

    def __enter__(self: _SinkT) -> _SinkT:
        self.open()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class RigSource(abc.ABC):
    """A context manager that yields the :class:`~fusion_pf.rig.FrameSet` of each instant of several posed cameras.

    Live like :class:`Source` (``live = True``: iterated once, losses counted in
    :attr:`stats`); ``fusion-pf record`` writes it with :class:`drivers.rig.RigRecorder`.
    Subclasses implement :meth:`open`, :meth:`close`, :meth:`_sets`, :attr:`stats`
    and :meth:`metadata`, and set :attr:`cameras` and :attr:`poses`.
    """

    live: bool = True
    cameras: tuple[str, ...]
    poses: dict[str, CameraPose]

    def __init__(self) -> None:
        self.rig_notes: list[str] = []
        self._opened = False

    @abc.abstractmethod
    def open(self) -> None:
        """Acquire every camera; raise a FusionPFError when impossible (nothing left open)."""

    @abc.abstractmethod
    def close(self) -> None:
        """Release everything; safe to call twice."""

    @abc.abstractmethod
    def _sets(self) -> Iterator[FrameSet]:
        """Yield frame sets in time order (called by ``__iter__``)."""

    @property
    @abc.abstractmethod
    def stats(self) -> SourceStats:
        """What every camera yielded and lost, added up."""

    @abc.abstractmethod
    def metadata(self) -> dict[str, str]:
        """Provenance for the recording's metadata record (after :meth:`open`)."""

    @abc.abstractmethod
    def matching(self) -> str:
        """One line: the instants so far, how many hold every camera, per camera its frames and those without a partner."""

    def __enter__(self: _RigT) -> _RigT:
        self.open()
        self._opened = True
        return self

    def __exit__(self, *exc: object) -> None:
        self._opened = False
        self.close()

    def __iter__(self) -> Generator[FrameSet, None, None]:
        if not self._opened:
            raise RuntimeError(f"{type(self).__name__} must be used inside a 'with' block")
        yield from self._sets()

    def describe(self) -> str:
        """One line naming the source for messages and progress bars."""
        return type(self).__name__
