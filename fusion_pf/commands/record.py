"""``fusion-pf record``: record any source into an MCAP file (docs/recording-format.md)."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

from drivers import SOURCE_SPECS

NAME = "record"
HELP = "record a source (synthetic scene, OAK camera, recording) into an MCAP file"
DESCRIPTION = (
    "Record SOURCE into OUT.mcap following docs/recording-format.md (chunked, zstd by default). "
    "The file is always finalised: at the end of the source, after --frames/--duration, on "
    "Ctrl-C (exit 130), SIGTERM (exit 143) and SIGHUP (exit 129), and when the source fails "
    "(exit 2, the frames recorded so far are kept). The header reaches the disk at once and every "
    "chunk as soon as it is written, so even a SIGKILL leaves a readable file. A summary (frames, "
    "dropped, bytes) is printed at the end; its frame count is read back from the file, so after "
    "a write failure (full disk: exit 2) it counts only the frames the file really holds."
)


def _meta(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, value


def _positive(kind: type) -> Callable[[str], object]:
    def parse(text: str) -> object:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"expected a positive {kind.__name__}, got {text!r}")
        return value

    return parse


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf record``."""
    p.add_argument("source", metavar="SOURCE", help=f"what to record: {SOURCE_SPECS}")
    p.add_argument("output", type=Path, metavar="OUT.mcap", help="MCAP file to write")
    p.add_argument("--duration", type=_positive(float), metavar="S", help="stop after S seconds of capture time")
    p.add_argument("--frames", type=_positive(int), metavar="N", help="stop after N frames")
    p.add_argument(
        "--size",
        metavar="WxH",
        help="colour/depth size in pixels for a camera or synthetic source (default: the source's own, 640x400)",
    )
    p.add_argument(
        "--fps",
        type=_positive(float),
        metavar="F",
        help="frame rate for a camera or synthetic source (default: the source's own, 30)",
    )
    p.add_argument(
        "--ir-laser", type=float, metavar="MA", help="OAK Pro IR dot-projector current in mA, 0-1200 (default: off)"
    )
    p.add_argument(
        "--color-format",
        choices=("raw", "jpeg", "png"),
        default="raw",
        help="colour as RawImage rgb8, or CompressedImage jpeg/png",
    )
    p.add_argument(
        "--depth-format",
        choices=("raw", "png"),
        default="raw",
        help="depth as RawImage 16UC1, or 16-bit PNG CompressedImage",
    )
    p.add_argument("--jpeg-quality", type=int, default=90, metavar="Q", help="JPEG quality 1-100")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd", help="chunk compression")
    p.add_argument(
        "--meta",
        type=_meta,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="extra key/value for the fusion_pf.recording metadata record (repeatable)",
    )
    p.add_argument("--force", action="store_true", help="overwrite OUT.mcap if it exists")


def _one_line(exc: BaseException) -> str:
    from fusion_pf.errors import FusionPFError

    text = " ".join(str(exc).split())
    return text if isinstance(exc, FusionPFError) else f"{type(exc).__name__}: {text}"


def _frames_in(path: Path) -> int:
    """Frames a reader finds in ``path`` (0 when it holds none that can be read)."""
    from drivers.mcap_replay import McapReplay
    from fusion_pf.errors import RecordingError

    try:
        with McapReplay(path) as replay:
            return len(replay)
    except RecordingError:
        return 0


def run(args: argparse.Namespace) -> int:
    """Record until the source ends, a limit is reached, Ctrl-C/SIGTERM/SIGHUP, or the source fails."""
    from fusion_pf.signals import stop_on_terminate

    with stop_on_terminate():
        return _record(args)


def _record(args: argparse.Namespace) -> int:
    import os
    import sys
    import time

    from tqdm import tqdm

    from drivers import ReplaySource, open_source
    from drivers.mcap_record import McapRecorder
    from fusion_pf.errors import RecordingError
    from fusion_pf.signals import sigint_deferred
    from fusion_pf.text import printable

    from ._paths import check_output

    check_output(args.output, force=args.force, inputs=(args.source,))
    overrides = {k: v for k, v in (("size", args.size), ("fps", args.fps)) if v is not None}
    if overrides and args.source.lower().endswith(".mcap"):
        from fusion_pf.errors import InputError

        raise InputError(f"--size/--fps apply to a camera or synthetic source, not to the recording {args.source}")
    if args.ir_laser is not None:
        if not args.source.lower().startswith("oak"):
            from fusion_pf.errors import InputError

            raise InputError(f"--ir-laser applies to an OAK camera source, not to {args.source}")
        overrides["ir_laser"] = args.ir_laser
    source = open_source(args.source, **overrides)
    duration_ns = None if args.duration is None else int(round(args.duration * 1e9))
    failure: BaseException | None = None
    interrupted: int | None = None
    started = time.monotonic()
    with source as src:
        metadata = {"source": args.source}
        source_metadata = getattr(src, "metadata", None)
        if callable(source_metadata):
            metadata.update(source_metadata())
        metadata.update(dict(args.meta))
        total = len(src) if isinstance(src, ReplaySource) else None
        if args.frames is not None:
            total = args.frames if total is None else min(total, args.frames)
        recorder = McapRecorder(
            args.output,
            compression=args.compression,
            color_format=args.color_format,
            depth_format=args.depth_format,
            jpeg_quality=args.jpeg_quality,
            metadata=metadata,
        )
        frames = iter(src)
        try:
            with recorder, tqdm(total=total, unit="frame", desc=src.describe(), disable=None, file=sys.stderr) as bar:
                first_ns = None
                while args.frames is None or recorder.frames_written < args.frames:
                    try:
                        frame = next(frames)
                    except StopIteration:
                        break
                    except Exception as exc:  # any source failure ends the recording, keeping the file
                        failure = exc
                        break
                    first_ns = frame.timestamp_ns if first_ns is None else first_ns
                    if duration_ns is not None and frame.timestamp_ns - first_ns >= duration_ns:
                        break
                    recorder.write(frame)
                    bar.update()
        except KeyboardInterrupt as exc:
            interrupted = getattr(exc, "signum", 2)
            raise
        finally:
            with sigint_deferred():
                frames.close()
                n = _frames_in(args.output) if args.output.exists() else 0
                size = os.path.getsize(args.output) if args.output.exists() else 0
                stats = src.stats
                for note in stats.notes:
                    print(f"fusion-pf: warning: {printable(note)}", file=sys.stderr)
                per_frame = f", {size / n / 1024:.1f} KiB/frame" if n else ""
                status = {None: "", 2: " (interrupted)"}.get(interrupted, f" (terminated by signal {interrupted})")
                lost = recorder.frames_written - n
                unwritten = (
                    f" ({lost} more could not be written: {recorder.error.strerror})"
                    if (recorder.error is not None and lost > 0)
                    else ""
                )
                print(
                    f"recorded {n} frames{status}{unwritten} to {args.output} in {time.monotonic() - started:.1f} s: "
                    f"{stats.dropped} dropped, {stats.missing_depth} without depth, "
                    f"{stats.missing_skeleton} without skeleton; {size} bytes{per_frame}",
                    flush=True,
                )
    if failure is not None:
        raise RecordingError(
            f"source {args.source} failed after {recorder.frames_written} frames ({_one_line(failure)}); "
            f"{args.output} is finalised and keeps those frames"
        )
    return 0
