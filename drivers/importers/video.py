"""Import an ordinary video file (mp4, avi, mov, mkv, webm, ...): colour only, decoded with PyAV (FFmpeg).

Timestamps are the decoded frames' presentation times (``pts * time_base``), shifted so the
first frame is at 0, or ``i / fps`` when ``fps`` is given or the file has no timestamps.
A frame whose time does not increase is skipped and counted. There is no depth; the
intrinsics come from a file or flags, else from an assumed horizontal field of view, and the
report says which.
"""

from __future__ import annotations

from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame

from .base import ImportSource, IntrinsicsOption

#: Suffixes :func:`drivers.importers.open_import` treats as video files.
VIDEO_SUFFIXES = (".mp4", ".m4v", ".avi", ".mov", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".mkv")


def open_container(path: Path):
    """``av.open(path)`` with a failure reported as an InputError naming the file."""
    import av

    try:
        return av.open(str(path))
    except av.FFmpegError as exc:
        raise InputError(f"{path} cannot be opened as a video ({exc})") from None


class VideoSource(ImportSource):
    """Colour frames of the first video stream of a file.

    Parameters
    ----------
    path : str or Path
    fps : float, optional
        Force ``i / fps`` timestamps instead of the file's.
    intrinsics : IntrinsicsOption, optional
    """

    kind = "video"

    def __init__(
        self, path: str | Path, *, fps: float | None = None, intrinsics: IntrinsicsOption | None = None
    ) -> None:
        super().__init__(path)
        if fps is not None and not fps > 0:
            raise InputError(f"fps must be > 0, got {fps}")
        self.fps = fps
        self.intrinsics_option = intrinsics or IntrinsicsOption()
        self._container = None
        self._intrinsics = None

    def open(self) -> None:
        container = open_container(self.path)
        if not container.streams.video:
            found = ", ".join(f"{s.type} ({getattr(s.codec_context, 'name', '?')})" for s in container.streams)
            container.close()
            raise InputError(f"{self.path} has no video stream; found {found or 'no streams'}")
        stream = container.streams.video[0]
        width, height = stream.codec_context.width, stream.codec_context.height
        if not width or not height:
            container.close()
            raise InputError(f"{self.path}: video stream {stream.index} has no frame size")
        self._container = container
        self._intrinsics, origin = self.intrinsics_option.resolve(width, height)
        self.total = stream.frames or None
        rate = stream.average_rate
        self.report.append(
            f"video stream {stream.index} ({stream.codec_context.name}, {width}x{height}"
            f"{f', {float(rate):.3g} fps' if rate else ''}), colour only, no depth; intrinsics {origin}"
        )
        others = [f"{s.type} {s.index}" for s in container.streams if s.index != stream.index]
        if others:
            self.report.append(f"streams not imported: {', '.join(others)}")

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
            self._container = None

    def _frames(self) -> Iterator[Frame]:
        container = self._container
        container.seek(0)
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        first = last = None
        skipped = 0
        for i, vf in enumerate(container.decode(stream)):
            if self.fps is not None or vf.pts is None or vf.time_base is None:
                rate = self.fps or (float(stream.average_rate) if stream.average_rate else 30.0)
                t = int(round(i * 1e9 / rate))
            else:
                ns = round(vf.pts * Fraction(vf.time_base) * 1_000_000_000)
                first = ns if first is None else first
                t = ns - first
            if last is not None and t <= last:
                skipped += 1
                continue
            last = t
            yield Frame(t, i, vf.to_ndarray(format="rgb24"), None, self._intrinsics)
        if skipped:
            self.stats.dropped += skipped
            self.stats.notes.append(f"{skipped} video frame(s) skipped: their time did not increase")
