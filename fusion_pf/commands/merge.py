"""``fusion-pf merge``: combine single-camera recordings into one multi-camera recording."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from drivers.encoding import EncodingOptions
from fusion_pf.options import add_options, from_args, option, validate

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
    "how many frames of each camera had no partner."
)


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

    def __post_init__(self) -> None:
        validate(self)


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

    from drivers.rig import load_extrinsics, merge
    from fusion_pf.errors import InputError
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
    report = merge(args.inputs, poses, args.output, tolerance_ns=tolerance, recorder_kwargs=encoding.recorder_kwargs())
    print(f"wrote {report['sets']} instants of {len(poses)} cameras to {args.output}")
    for name, cam in report["cameras"].items():
        print(
            f"  {name:<12} {cam['frames']:>6} frames from {printable(cam['input'])}, {cam['unmatched']} without a partner"
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
