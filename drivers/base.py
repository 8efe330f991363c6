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

_SourceT = TypeVar("_SourceT", bound="Source")
_SinkT = TypeVar("_SinkT", bound="Sink")


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
    """

    frames: int = 0
    missing_depth: int = 0
    missing_skeleton: int = 0
    dropped: int = 0
    notes: list[str] = field(default_factory=list)

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
