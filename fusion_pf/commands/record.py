"""``fusion-pf record``: record any source into an MCAP file (docs/recording-format.md)."""

from __future__ import annotations

import argparse
from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers import SOURCE_SPECS
from drivers.encoding import EncodingOptions
from fusion_pf.options import add_options, from_args, option, validate

from ._options import fps_option, parse_size, size_check

NAME = "record"
HELP = "record a source (synthetic scene, OAK camera, recording) into an MCAP file"
DESCRIPTION = (
    "Record SOURCE into OUT.mcap following docs/recording-format.md (chunked, zstd by default). "
    "The file is always finalised: at the end of the source, after --frames/--duration, on "
    "Ctrl-C (exit 130), SIGTERM (exit 143) and SIGHUP (exit 129), and when the source fails "
    "(exit 2, the frames recorded so far are kept). The header reaches the disk at once and every "
    "chunk as soon as it is written, so even a SIGKILL leaves a readable file. A summary (frames, "
    "dropped, bytes) is printed at the end; its frame count is read back from the file, so after "
    "a write failure (full disk: exit 2) it counts only the frames the file really holds. "
    "Several OAK cameras (oak:device=ID1+ID2) are recorded into one multi-camera MCAP: their frames "
    "matched by timestamp (within half a frame period; a frame without a partner is written alone "
    "and counted), the cameras named and posed by --extrinsics (else oak_<id> at the world origin, "
    "with a warning: the recording to calibrate them from)."
)


def _meta(text: str) -> tuple[str, str]:
    key, sep, value = text.partition("=")
    if not sep or not key:
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    return key, value


@dataclass(frozen=True)
class RecordOptions:
    """When ``fusion-pf record`` stops and how the source is set up (validated on construction)."""

    duration: float | None = option(
        None,
        kind="float",
        lo=0.001,
        optional=True,
        unit="s",
        metavar="S",
        show=lambda v: "no limit",
        help="stop after S seconds of capture time",
    )
    frames: int | None = option(
        None, kind="int", lo=1, optional=True, metavar="N", show=lambda v: "no limit", help="stop after N frames"
    )
    size: tuple[int, int] | None = option(
        None,
        optional=True,
        parse=parse_size,
        check=size_check(1, 65535),
        metavar="WxH",
        unit="px",
        show=lambda v: "the source's own, 640x400",
        help="colour/depth size for a camera or synthetic source",
    )
    fps: float | None = fps_option("the source's own, 30", "frame rate for a camera or synthetic source")
    ir_laser: float | None = option(
        None,
        kind="float",
        lo=0.0,
        optional=True,
        unit="mA",
        metavar="MA",
        show=lambda v: "off",
        help="OAK Pro IR dot-projector current, at most the camera's 1200",
    )

    def __post_init__(self) -> None:
        validate(self)


#: The config classes whose flags the command registers.
CONFIGS = (RecordOptions, EncodingOptions)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf record``."""
    p.add_argument("source", metavar="SOURCE", help=f"what to record: {SOURCE_SPECS}")
    p.add_argument("output", type=Path, metavar="OUT.mcap", help="MCAP file to write")
    add_options(p, RecordOptions)
    add_options(p, EncodingOptions)
    p.add_argument(
        "--meta",
        type=_meta,
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="extra key/value for the fusion_pf.recording metadata record (repeatable)",
    )
    p.add_argument(
        "--extrinsics",
        type=Path,
        metavar="CAMS.yaml",
        help="several OAK cameras (oak:device=ID1+ID2): camera names and poses, in device order "
        "(default: oak_<id> at the world origin, with a warning)",
    )
    p.add_argument("--force", action="store_true", help="overwrite OUT.mcap if it exists")


class _RigWriter:
    """A :class:`drivers.rig.RigRecorder` as the one-item writer the recording loop uses (an item = a frame set)."""

    def __init__(self, path: Path, poses: dict, **kwargs: object) -> None:
        from drivers.rig import RigRecorder

        self.rig = RigRecorder(path, poses, **kwargs)

    def __enter__(self) -> "_RigWriter":
        self.rig.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        self.rig.__exit__(*exc)

    def write(self, frameset: Any) -> None:  # a fusion_pf.rig.FrameSet
        self.rig.write(frameset.timestamp_ns, {name: view.frame for name, view in frameset.views.items()})

    @property
    def frames_written(self) -> int:
        return self.rig.sets_written

    @property
    def error(self) -> OSError | None:
        return self.rig.recorder.error


def _one_line(exc: BaseException) -> str:
    from fusion_pf.errors import FusionPFError

    text = " ".join(str(exc).split())
    return text if isinstance(exc, FusionPFError) else f"{type(exc).__name__}: {text}"


def _frames_in(path: Path, rig: bool = False) -> int:
    """Frames (instants of a rig) a reader finds in ``path`` (0 when it holds none that can be read)."""
    from drivers.mcap_replay import McapReplay
    from drivers.rig import RigReplay
    from fusion_pf.errors import RecordingError

    try:
        with RigReplay(path) if rig else McapReplay(path) as replay:
            return len(replay)
    except RecordingError:
        return 0


def run(args: argparse.Namespace) -> int:
    """Record until the source ends, a limit is reached, Ctrl-C/SIGTERM/SIGHUP (cli.main), or the source fails."""
    import os
    import sys
    import time

    from tqdm import tqdm

    from drivers import ReplaySource, RigSource, is_rig_spec, open_rig, open_source
    from drivers.mcap_record import McapRecorder
    from fusion_pf.errors import InputError, RecordingError
    from fusion_pf.signals import sigint_deferred
    from fusion_pf.text import printable

    from ._paths import check_output

    opts = from_args(RecordOptions, args)
    encoding = from_args(EncodingOptions, args)
    extrinsics = getattr(args, "extrinsics", None)
    check_output(args.output, force=args.force, inputs=(args.source, *([extrinsics] if extrinsics else [])))
    overrides = {k: v for k, v in (("size", opts.size), ("fps", opts.fps)) if v is not None}
    if overrides and args.source.lower().endswith(".mcap"):
        raise InputError(f"--size/--fps apply to a camera or synthetic source, not to the recording {args.source}")
    if opts.ir_laser is not None:
        if not args.source.lower().startswith("oak"):
            raise InputError(f"--ir-laser applies to an OAK camera source, not to {args.source}")
        overrides["ir_laser"] = opts.ir_laser
    if extrinsics is not None:
        if not args.source.lower().startswith("oak"):
            raise InputError(f"--extrinsics applies to several OAK cameras (oak:device=ID1+ID2), not to {args.source}")
        overrides["extrinsics"] = extrinsics
    rig = is_rig_spec(args.source, **overrides)
    source = open_rig(args.source, **overrides) if rig else open_source(args.source, **overrides)
    duration_ns = None if opts.duration is None else int(round(opts.duration * 1e9))
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
        if opts.frames is not None:
            total = opts.frames if total is None else min(total, opts.frames)
        recorder: McapRecorder | _RigWriter = (
            _RigWriter(args.output, src.poses, metadata=metadata, **encoding.recorder_kwargs())
            if isinstance(src, RigSource)
            else McapRecorder(args.output, metadata=metadata, **encoding.recorder_kwargs())
        )
        frames: Generator[Any, None, None] = iter(src)
        try:
            with recorder, tqdm(total=total, unit="frame", desc=src.describe(), disable=None, file=sys.stderr) as bar:
                first_ns = None
                while opts.frames is None or recorder.frames_written < opts.frames:
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
                n = _frames_in(args.output, rig) if args.output.exists() else 0
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
                what = f"instants of {len(src.cameras)} cameras" if isinstance(src, RigSource) else "frames"
                print(
                    f"recorded {n} {what}{status}{unwritten} to {printable(args.output)} in {time.monotonic() - started:.1f} s: "
                    f"{stats.dropped} dropped, {stats.missing_depth} without depth, "
                    f"{stats.missing_skeleton} without skeleton; {size} bytes{per_frame}",
                    flush=True,
                )
                if isinstance(src, RigSource):
                    print(f"matching: {src.matching()}", flush=True)
    if failure is not None:
        raise RecordingError(
            f"source {args.source} failed after {recorder.frames_written} {'instants' if rig else 'frames'} ({_one_line(failure)}); "
            f"{args.output} is finalised and keeps those frames"
        )
    return 0
