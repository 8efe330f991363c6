"""``fusion-pf merge``: combine single-camera recordings into one multi-camera recording."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from decimal import Decimal, InvalidOperation
from pathlib import Path
from typing import Any

from drivers.encoding import EncodingOptions
from fusion_pf.errors import InputError
from fusion_pf.options import add_options, from_args, option, validate
from fusion_pf.rig import ALIGNMENTS

NAME = "merge"
HELP = "combine single-camera recordings and their poses (--extrinsics) into one multi-camera MCAP"
DESCRIPTION = (
    "Write the frames of A.mcap, B.mcap, ... (each a single-camera recording in the fusion-pf "
    "convention, from any importer) into OUT.mcap as the cameras of one rig: the i-th recording "
    "becomes the i-th camera of the extrinsics file (YAML or JSON, as written by fusion-pf "
    "calibrate), its topics get the prefix /<camera>, and every camera's pose goes on /tf as a "
    "foxglove.FrameTransform from world. The first recording is the reference clock: a frame of "
    "another camera joins the reference frame nearest in time (within --tolerance-ms) and takes "
    "its timestamp; a frame without one keeps its own time. Nothing is dropped: the summary says "
    "how many frames of each camera had no partner. Recordings from different devices have different "
    "clocks: --clock-offset gives each recording's offset (added to its times before matching), or "
    "--align estimates it (first: the first frames at the same instant; motion: the cross-correlation "
    "of the recordings' motion energy, their frame-to-frame image change); the offset used is printed."
)

#: Units of a clock offset, in nanoseconds.
_UNITS = {"ns": 1, "us": 1_000, "ms": 1_000_000, "s": 1_000_000_000}


def parse_offsets(text: str) -> tuple[int, ...]:
    """``"0,-1.25s,340ms,120000ns"`` -> offsets in integer ns (exact decimal arithmetic)."""
    out = []
    for item in str(text).split(","):
        item = item.strip().lower()
        unit = next((u for u in ("ns", "us", "ms", "s") if item.endswith(u)), None)
        try:
            if unit is None:
                if item.lstrip("+-") != "0":  # zero needs no unit
                    raise InvalidOperation
                item, unit = "0ns", "ns"
            value = Decimal(item[: -len(unit)]) * _UNITS[unit]
        except InvalidOperation:
            raise InputError(
                f"a clock offset must be a number with a unit ns, us, ms or s (e.g. -1.25s, 340ms), got {item!r} in {text!r}"
            ) from None
        if value != value.to_integral_value() or not value.is_finite():
            raise InputError(f"a clock offset must be a whole number of ns, got {item!r}")
        out.append(int(value))
    return tuple(out)


def _check_offsets(label: str, value: Any) -> tuple[int, ...]:
    if isinstance(value, str):
        value = parse_offsets(value)
    if (
        not isinstance(value, tuple)
        or not value
        or not all(isinstance(v, int) and not isinstance(v, bool) for v in value)
    ):
        raise InputError(f"{label} must be one offset per recording (ns), got {value!r}")
    return value


@dataclass(frozen=True)
class MergeOptions:
    """How ``fusion-pf merge`` matches the cameras' frames (validated on construction)."""

    tolerance_ms: float | None = option(
        None,
        kind="float",
        lo=0.0,
        hi=10_000.0,
        optional=True,
        unit="ms",
        metavar="MS",
        show=lambda v: "half the first recording's frame period",
        help="largest time difference between frames of one instant",
    )
    clock_offset: tuple[int, ...] | None = option(
        None,
        optional=True,
        parse=parse_offsets,
        check=_check_offsets,
        metavar="OFFSETS",
        show=lambda v: "none (or --align)",
        help="each recording's clock offset to the first, in input order, added to its times before matching: "
        "numbers with a unit ns, us, ms or s, e.g. 0,-1.25s,340ms",
    )
    align: str = option(
        ALIGNMENTS[0],
        choices=ALIGNMENTS,
        help="estimate each recording's clock offset to the first: by the first frames, or by cross-correlating "
        "the motion energy (frame-to-frame image change); not with --clock-offset",
    )

    def __post_init__(self) -> None:
        validate(self)
        if self.clock_offset is not None and self.align != ALIGNMENTS[0]:
            raise InputError(f"--clock-offset and --align {self.align} are alternatives; give one")


#: The config classes whose flags the command registers.
CONFIGS = (MergeOptions, EncodingOptions)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf merge``."""
    p.add_argument("inputs", type=Path, nargs="+", metavar="IN.mcap", help="single-camera recordings, one per camera")
    p.add_argument(
        "--extrinsics", type=Path, required=True, metavar="CAMS.yaml", help="camera names and poses, in input order"
    )
    p.add_argument("-o", "--output", type=Path, required=True, metavar="OUT.mcap", help="multi-camera MCAP to write")
    add_options(p, MergeOptions)
    add_options(p, EncodingOptions)
    p.add_argument("--force", action="store_true", help="overwrite OUT.mcap if it exists")


def run(args: argparse.Namespace) -> int:
    """Merge; print per camera how many frames were matched."""
    import sys

    from drivers.rig import WEAK_CORRELATION, load_extrinsics, merge
    from fusion_pf.text import printable

    from ._paths import check_output

    options = from_args(MergeOptions, args)
    encoding = from_args(EncodingOptions, args)
    for path in args.inputs:
        if not path.is_file():
            raise InputError(f"recording not found: {path}")
    if len(set(p.resolve() for p in args.inputs)) != len(args.inputs):
        raise InputError("the same recording is given twice; each camera needs its own recording")
    poses = load_extrinsics(args.extrinsics)
    check_output(args.output, force=args.force, inputs=(*args.inputs, args.extrinsics))
    tolerance = None if options.tolerance_ms is None else round(options.tolerance_ms * 1e6)
    report = merge(
        args.inputs,
        poses,
        args.output,
        tolerance_ns=tolerance,
        offsets_ns=options.clock_offset,
        align=options.align,
        recorder_kwargs=encoding.recorder_kwargs(),
    )
    print(f"wrote {report['sets']} instants of {len(poses)} cameras to {args.output}")
    for name, cam in report["cameras"].items():
        source = cam["offset_from"] + (
            f", correlation {cam['correlation']:.2f}" if cam["correlation"] is not None else ""
        )
        print(
            f"  {name:<12} {cam['frames']:>6} frames from {printable(cam['input'])}, {cam['unmatched']} without a partner; "
            f"clock offset {cam['offset_ns'] / 1e6:+.3f} ms ({source})"
        )
    for name, cam in report["cameras"].items():
        if cam["correlation"] is not None and cam["correlation"] < WEAK_CORRELATION:
            print(
                f"fusion-pf: warning: {name}'s clock offset rests on a weak motion correlation "
                f"({cam['correlation']:.2f} < {WEAK_CORRELATION:g}): check it, or give --clock-offset",
                file=sys.stderr,
            )
    if report["background_unflagged"]:
        print(
            f"fusion-pf: warning: {report['background_unflagged']} background frames follow an instant where another "
            "camera already shows the scene; written as ordinary frames",
            file=sys.stderr,
        )
    for note in report["notes"]:
        print(f"fusion-pf: warning: {printable(note)}", file=sys.stderr)
    return 0
