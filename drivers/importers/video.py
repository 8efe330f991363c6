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

import re
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import numpy as np

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
        return av.open(str(path), metadata_errors="replace")  # a damaged tag is not a reason to refuse the file
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
        if stream.codec_context is None:
            container.close()
            raise InputError(
                f"{self.path}: video stream {stream.index} has no decoder (unknown codec or a damaged header)"
            )
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

    def _shortfall(self, stream, seen: int, span_s: float | None) -> tuple[int, int, str]:
        """``(frames missing at the end, frames missing in all, what the header announces)``.

        With a frame count in the header both are that count minus ``seen``.
        Otherwise from its duration: at the end, the time left after the last
        decoded frame (``span_s`` after the first; None without timestamps);
        in all, duration x rate minus ``seen``. A duration is only trusted from
        the video stream (or its Matroska ``DURATION`` tag), or from the
        container when it holds nothing else.
        """
        if stream.frames:
            missing = max(int(stream.frames) - seen, 0)
            return missing, missing, f"{stream.frames} frames"
        rate = float(stream.average_rate) if stream.average_rate else None
        container = self._container
        tag = re.fullmatch(r"(\d+):(\d\d):(\d\d(?:\.\d+)?)", str(stream.metadata.get("DURATION", "")))
        if rate and stream.duration is not None and stream.time_base is not None:
            seconds = float(stream.duration * stream.time_base)
        elif rate and tag is not None:  # Matroska writers tag each track with its duration
            seconds = int(tag[1]) * 3600 + int(tag[2]) * 60 + float(tag[3])
        elif rate and container is not None and container.duration and len(container.streams) == 1:
            seconds = container.duration / 1e6  # AV_TIME_BASE
        else:
            return 0, 0, ""
        announced = f"{seconds:.3f} s at {rate:.3g} fps"
        total = max(int(round(seconds * rate)) - seen, 0)
        if span_s is None:
            return total, total, announced
        # the last frame lasts one period; more than half a period left over is a missing frame
        return max(int(round((seconds - span_s) * rate - 1.0)), 0), total, announced

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
        import av.logging

        container = self._container
        container.seek(0)
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        first = last = None
        times: list[float] = []  # decoded presentation times, s
        rate = self.fps or (float(stream.average_rate) if stream.average_rate else 30.0)
        index = -1
        skipped = 0
        refused: dict[str, int] = {}
        i = -1
        level, repeated = av.logging.get_level(), av.logging.get_skip_repeated()
        av.logging.set_level(av.logging.ERROR)  # what the demuxer and decoder say about damage
        av.logging.set_skip_repeated(False)  # a message the previous video ended with must still be seen
        try:
            with av.logging.Capture(local=False) as logs:  # the decoder's threads log too
                for vf, why in self._decoded(stream):
                    i += 1
                    if vf is None:
                        refused[why] = refused.get(why, 0) + 1
                        continue
                    if vf.pts is not None and vf.time_base is not None:
                        times.append(float(vf.pts * vf.time_base))
                        # its place in the video: from its time, so a frame the demuxer lost leaves a gap
                        index = max(index + 1, int(round((times[-1] - times[0]) * rate)))
                    else:
                        index = max(index + 1, i)
                    if self.fps is not None or vf.pts is None or vf.time_base is None:
                        t = int(round(i * 1e9 / rate))
                    else:
                        ns = round(vf.pts * Fraction(vf.time_base) * 1_000_000_000)
                        first = ns if first is None else first
                        t = ns - first
                    if last is not None and t <= last:
                        skipped += 1
                        continue
                    last = t
                    yield Frame(t, i, vf.to_ndarray(format="rgb24"), None, self._intrinsics, index=index)
        finally:
            av.logging.set_level(level)
            av.logging.set_skip_repeated(repeated)
        for why, n in refused.items():
            self._lose(n, why)
        if skipped:
            self._lose(skipped, "their time did not increase")
        steady, gaps = _gaps(times, rate)
        gaps -= sum(refused.values())
        if gaps > 0:
            self._lose(gaps, "the video's timestamps skip frames the file does not hold (damaged data)")
        seen = i + 1 + max(gaps, 0)
        missing, total, announced = self._shortfall(stream, seen, times[-1] - times[0] if times else None)
        if total > self.path.stat().st_size:  # not even a byte per frame: the header itself is damaged
            self._lose(None, f"the video's header is damaged (it announces {announced})", tail=True)
            missing = total = 0
        if missing and not any(loss.tail for loss in self.stats.losses):
            self._lose(
                missing,
                f"the video is truncated or damaged: it ends after {seen} frames but its header announces {announced}",
                tail=True,
            )
        inside = total - missing
        if inside > 0 and (steady or self.stats.losses):  # a variable-rate video's count is only an estimate
            self._lose(inside, f"frames missing inside the video: its header announces {announced}")
        if not self.stats.losses and logs:
            said = logs[0][2].strip()
            self._lose(
                None, f"the video is damaged (FFmpeg: {said!r}{f' and {len(logs) - 1} more' if len(logs) > 1 else ''})"
            )


def _gaps(times: list[float], rate: float) -> tuple[bool, int]:
    """Whether the video runs at the constant ``rate``, and the frame periods its times skip.

    The rate is constant when every interval between consecutive times is a
    whole number of periods ``1 / rate`` (within a fifth of a period:
    millisecond time bases round); the extra periods are frames the file lost.
    """
    if len(times) < 2:
        return False, 0
    ratio = np.diff(np.asarray(times)) * rate
    if np.any(np.abs(ratio - np.round(ratio)) > 0.2) or np.any(ratio < 0.5):
        return False, 0
    return True, int(np.sum(np.round(ratio) - 1))
