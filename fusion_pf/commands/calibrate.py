"""``fusion-pf calibrate``: the camera poses of a rig from a ChArUco board seen by its cameras."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from drivers.charuco import BoardSpec
from drivers.rig_calibration import REFINEMENTS
from fusion_pf.options import add_options, from_args, option, validate

NAME = "calibrate"
HELP = "estimate each camera's pose from a ChArUco board in a multi-camera recording; write the extrinsics file"
DESCRIPTION = (
    "Find the ChArUco board in every frame of every camera of REC.mcap (a multi-camera recording, "
    "e.g. from fusion-pf merge or synth --cameras N --board), fit each camera's pose in the board's "
    "frame (world: origin at the board's top-left outer corner, x right, y down, z into the board; "
    "the board and the cameras must not move), print the reprojection error per camera and write the "
    "poses as an extrinsics file (YAML for .yaml/.yml, else JSON) that fusion-pf merge takes. The "
    "board is the one the recording's metadata names (board_squares, board_square_mm, ...), else the "
    "--board-* flags. --refine icp also registers the cameras' depth of the static scene to the best "
    "camera's by open3d's coloured ICP and reports fitness and inlier RMSE per camera pair, keeping a "
    "refinement only where it agrees with the board (fitness >= 0.25 and a board chi-square, the rise "
    "of its squared reprojection residuals over the board fit's in units of their variance, <= 16.81: "
    "the 99 % point for 6 pose parameters), so it never moves a pose away from a precise board fit."
)


def _board_default(field: str) -> Callable[[object], str]:
    """``show`` of a board option: the recording's board, else :class:`drivers.charuco.BoardSpec`'s default."""

    def show(value: object) -> str:
        default = getattr(BoardSpec(), field)
        text = (
            "x".join(map(str, default))
            if isinstance(default, tuple)
            else f"{default:g}"
            if isinstance(default, float)
            else default
        )
        return f"the recording's board, else {text}"

    return show


@dataclass(frozen=True)
class CalibrateOptions:
    """The board and the refinement of ``fusion-pf calibrate`` (validated on construction)."""

    refine: str = option(
        REFINEMENTS[0], choices=REFINEMENTS, help="refine the board poses by coloured ICP of the depth"
    )
    board_squares: str | None = option(
        None,
        kind="str",
        optional=True,
        metavar="CxR",
        show=_board_default("squares"),
        help="board squares (columns x rows)",
    )
    board_square_mm: float | None = option(
        None,
        kind="float",
        lo=1.0,
        hi=10_000.0,
        optional=True,
        unit="mm",
        metavar="MM",
        show=_board_default("square_mm"),
        help="board square side",
    )
    board_marker_mm: float | None = option(
        None,
        kind="float",
        lo=1.0,
        hi=10_000.0,
        optional=True,
        unit="mm",
        metavar="MM",
        show=_board_default("marker_mm"),
        help="board marker side",
    )
    board_dictionary: str | None = option(
        None,
        kind="str",
        optional=True,
        metavar="DICT",
        show=_board_default("dictionary"),
        help="OpenCV ArUco dictionary of the board",
    )

    def __post_init__(self) -> None:
        validate(self)


#: The config classes whose flags the command registers.
CONFIGS = (CalibrateOptions,)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf calibrate``."""
    p.add_argument("recording", type=Path, metavar="REC.mcap", help="multi-camera recording showing the board")
    p.add_argument(
        "-o", "--output", type=Path, required=True, metavar="CAMS.yaml", help="extrinsics file to write (YAML or JSON)"
    )
    add_options(p, CalibrateOptions)
    p.add_argument("--force", action="store_true", help="overwrite the extrinsics file if it exists")


def run(args: argparse.Namespace) -> int:
    """Calibrate, print the reprojection error per camera, write the extrinsics."""
    import dataclasses

    from drivers.rig import RigReplay, extrinsics_document, write_extrinsics
    from drivers.rig_calibration import calibrate, report_lines
    from fusion_pf.errors import InputError

    from ._paths import check_output

    options = from_args(CalibrateOptions, args)
    if not args.recording.is_file():
        raise InputError(f"recording not found: {args.recording}")
    check_output(args.output, force=args.force, what="extrinsics file", inputs=(args.recording,))
    with RigReplay(args.recording) as rig:
        spec = BoardSpec.from_metadata(rig.replays[rig.cameras[0]].metadata()) or BoardSpec()
        given = {
            "squares": options.board_squares,
            "square_mm": options.board_square_mm,
            "marker_mm": options.board_marker_mm,
            "dictionary": options.board_dictionary,
        }
        if given["squares"] is not None:
            try:
                cols, rows = (int(v) for v in given["squares"].lower().split("x"))
            except ValueError:
                raise InputError(f"--board-squares must be CxR, e.g. 7x5, got {given['squares']!r}") from None
            given["squares"] = (cols, rows)  # type: ignore[assignment]
        spec = dataclasses.replace(spec, **{k: v for k, v in given.items() if v is not None})
        results = calibrate(rig, spec, refine=options.refine)
    for line in report_lines(results):
        print(line)
    extra = {
        name: {
            "reprojection_error_px": round(r.board.rms_px, 4),
            "board_corners": r.board.corners,
            **({"refined": "coloured ICP"} if r.icp is not None and r.icp.accepted else {}),
        }
        for name, r in results.items()
    }
    document = extrinsics_document({name: r.pose for name, r in results.items()}, extra)
    document["board"] = spec.metadata()
    document["source"] = str(args.recording)
    write_extrinsics(args.output, document)
    print(f"wrote the poses of {len(results)} cameras to {args.output}")
    return 0
