"""Import an ordinary video file (mp4, avi, mov, mkv, webm, ...): colour only, decoded with PyAV (FFmpeg).

Timestamps are the decoded frames' presentation times (``pts * time_base``), shifted so the
first frame is at 0, or ``i / fps`` when ``fps`` is given or the file has no timestamps.
A frame whose time does not increase is skipped and counted. There is no depth; the
intrinsics come from a file or flags, else from an assumed horizontal field of view, and the
report says which.

Damage is skipped and counted, never a traceback (``stats.losses``, as a damaged MCAP
recording): a packet the decoder refuses costs its frame; a container that cannot be read
further ends the video there; and a video that ends before the length its header announces
(frame count, else duration) is reported as truncated with the frames missing. Frames keep
their place in the video (``Frame.index``), so the frames after a lost one keep their numbers.
"""

from __future__ import annotations

from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame

from ..base import FrameLoss
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

    def _expected(self, stream) -> tuple[int | None, str]:
        """Frames the header announces (its frame count, else duration x rate) and where that came from."""
        if stream.frames:
            return int(stream.frames), f"{stream.frames} frames"
        rate = float(stream.average_rate) if stream.average_rate else None
        container = self._container
        if rate and stream.duration is not None and stream.time_base is not None:
            seconds = float(stream.duration * stream.time_base)
        elif rate and container is not None and container.duration:
            seconds = container.duration / 1e6  # AV_TIME_BASE
        else:
            return None, ""
        return int(round(seconds * rate)), f"{seconds:.3f} s at {rate:.3g} fps"

    def _decoded(self, stream) -> Iterator[tuple[object | None, str | None]]:
        """``(video frame, None)`` per decoded frame, ``(None, why)`` per packet the decoder refuses.

        A container that cannot be demuxed further ends the stream with a
        truncated-tail loss.
        """
        import av

        demuxed = self._container.demux(stream)
        while True:
            try:
                packet = next(demuxed)
            except StopIteration:
                return
            except av.FFmpegError as exc:
                self._lose(None, f"the video cannot be read past this point ({exc})", tail=True)
                packet = None
            try:
                frames = stream.decode(packet)
            except av.FFmpegError as exc:
                yield None, f"a damaged packet the decoder refuses ({exc})"
                continue
            yield from ((vf, None) for vf in frames)
            if packet is None:
                return

    def _lose(self, frames: int | None, reason: str, tail: bool = False) -> None:
        self.stats.losses.append(FrameLoss(frames, reason, tail=tail))
        self.stats.dropped += frames or 0

    def _frames(self) -> Iterator[Frame]:
        container = self._container
        container.seek(0)
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        first = last = None
        skipped = 0
        refused: dict[str, int] = {}
        i = -1
        for vf, why in self._decoded(stream):
            i += 1
            if vf is None:
                refused[why] = refused.get(why, 0) + 1
                continue
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
            yield Frame(t, i, vf.to_ndarray(format="rgb24"), None, self._intrinsics, index=i)
        for why, n in refused.items():
            self._lose(n, why)
        if skipped:
            self._lose(skipped, "their time did not increase")
        expected, announced = self._expected(stream)
        seen = i + 1
        if expected is not None and seen < expected - 1 and not any(loss.tail for loss in self.stats.losses):
            self._lose(
                expected - seen,
                f"the video is truncated or damaged: it ends after {seen} frames but its header announces {announced}",
                tail=True,
            )
