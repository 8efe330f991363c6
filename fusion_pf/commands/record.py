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
    "Ctrl-C (exit 130) and when the source fails (exit 2, the frames recorded so far are kept). "
    "A summary (frames, dropped, bytes) is printed at the end."
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
    p.add_argument("--duration", type=_positive(float), metavar="S",
                   help="stop after S seconds of capture time")
    p.add_argument("--frames", type=_positive(int), metavar="N", help="stop after N frames")
    p.add_argument("--size", metavar="WxH",
                   help="colour/depth size in pixels for a camera or synthetic source "
                        "(default: the source's own, 640x400)")
    p.add_argument("--fps", type=_positive(float), metavar="F",
                   help="frame rate for a camera or synthetic source (default: the source's own, 30)")
    p.add_argument("--ir-laser", type=float, metavar="MA",
                   help="OAK Pro IR dot-projector current in mA, 0-1200 (default: off)")
    p.add_argument("--color-format", choices=("raw", "jpeg", "png"), default="raw",
                   help="colour as RawImage rgb8, or CompressedImage jpeg/png")
    p.add_argument("--depth-format", choices=("raw", "png"), default="raw",
                   help="depth as RawImage 16UC1, or 16-bit PNG CompressedImage")
    p.add_argument("--jpeg-quality", type=int, default=90, metavar="Q", help="JPEG quality 1-100")
    p.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd", help="chunk compression")
    p.add_argument("--meta", type=_meta, action="append", default=[], metavar="KEY=VALUE",
                   help="extra key/value for the fusion_pf.recording metadata record (repeatable)")
    p.add_argument("--force", action="store_true", help="overwrite OUT.mcap if it exists")


def _one_line(exc: BaseException) -> str:
    from fusion_pf.errors import FusionPFError

    text = " ".join(str(exc).split())
    return text if isinstance(exc, FusionPFError) else f"{type(exc).__name__}: {text}"


def run(args: argparse.Namespace) -> int:
    """Record until the source ends, a limit is reached, Ctrl-C, or the source fails."""
    import sys
    import time

    from tqdm import tqdm

    from drivers import ReplaySource, open_source
    from drivers.mcap_record import McapRecorder
    from fusion_pf.errors import RecordingError

    from ._paths import check_output

    check_output(args.output, force=args.force, inputs=(args.source,))
    overrides = {k: v for k, v in (("size", args.size), ("fps", args.fps)) if v is not None}
    if overrides and args.source.lower().endswith(".mcap"):
        from fusion_pf.errors import InputError

        raise InputError(
            f"--size/--fps apply to a camera or synthetic source, not to the recording {args.source}"
        )
    if args.ir_laser is not None:
        if not args.source.lower().startswith("oak"):
            from fusion_pf.errors import InputError

            raise InputError(f"--ir-laser applies to an OAK camera source, not to {args.source}")
        overrides["ir_laser"] = args.ir_laser
    source = open_source(args.source, **overrides)
    duration_ns = None if args.duration is None else int(round(args.duration * 1e9))
    failure: BaseException | None = None
    interrupted = False
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
            args.output, compression=args.compression, color_format=args.color_format,
            depth_format=args.depth_format, jpeg_quality=args.jpeg_quality, metadata=metadata,
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
        except KeyboardInterrupt:
            interrupted = True
            raise
        finally:
            frames.close()
            n = recorder.frames_written
            stats = src.stats
            for note in stats.notes:
                print(f"fusion-pf: warning: {note}", file=sys.stderr)
            per_frame = f", {recorder.bytes_written / n / 1024:.1f} KiB/frame" if n else ""
            status = " (interrupted)" if interrupted else ""
            print(
                f"recorded {n} frames{status} to {args.output} in {time.monotonic() - started:.1f} s: "
                f"{stats.dropped} dropped, {stats.missing_depth} without depth, "
                f"{stats.missing_skeleton} without skeleton; {recorder.bytes_written} bytes{per_frame}"
            )
    if failure is not None:
        raise RecordingError(
            f"source {args.source} failed after {recorder.frames_written} frames ({_one_line(failure)}); "
            f"{args.output} is finalised and keeps those frames"
        )
    return 0
