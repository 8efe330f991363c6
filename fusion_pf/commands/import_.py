"""``fusion-pf import``: turn another tool's recording into a fusion-pf MCAP recording."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drivers.encoding import EncodingOptions
from drivers.importers.base import DEFAULT_HFOV_DEG, DEPTH_UNIT_EXAMPLES, HFOV_RANGE_DEG, parse_depth_unit
from fusion_pf.errors import InputError
from fusion_pf.options import add_options, from_args, option, validate
from fusion_pf.text import printable

from ._options import fps_option

NAME = "import"
HELP = "import a ROS bag, Azure Kinect .mkv, image folder or video into an MCAP recording"
DESCRIPTION = (
    "Convert SRC into OUT.mcap following docs/recording-format.md: colour (RGB), depth registered "
    "to colour in millimetres, the colour intrinsics, capture timestamps in ns, no skeleton. "
    "SRC is a ROS 2 bag (.mcap or bag folder; sensor_msgs Image/CompressedImage/CameraInfo, "
    "topics chosen by type and name, aligned depth preferred, colour and depth paired by time), "
    "a ROS 1 .bag, an Azure Kinect .mkv (depth registered to the colour camera with the attached "
    "calibration), a folder of colour and/or depth images, or a video file (colour only). "
    "What was chosen and assumed (topics, tracks, pairing, intrinsics) is printed. Damaged input "
    "(a packet the video decoder refuses, a truncated video, an unreadable image) is skipped and "
    "counted: the frames skipped and why are printed and the exit status is 3 (partial)."
)


def _text(label: str, value: Any) -> str | None:
    if value is not None and (not isinstance(value, str) or not value):
        raise InputError(f"{label} must be a non-empty string, got {value!r}")
    return value


def _depth_unit(label: str, value: Any) -> str | None:
    value = _text(label, value)
    if value is not None:
        parse_depth_unit(value)
    return value


def _path(label: str, value: Any) -> Path:
    return Path(value)


@dataclass(frozen=True)
class ImportOptions:
    """What ``fusion-pf import`` reads and assumes (validated on construction)."""

    color_topic: str | None = option(
        None, check=_text, metavar="TOPIC", show=lambda v: "chosen by type and name", help="colour image topic"
    )
    depth_topic: str | None = option(
        None,
        check=_text,
        metavar="TOPIC",
        show=lambda v: "chosen by type and name, aligned_depth_to_color first",
        help="depth image topic, 16UC1 mm or 32FC1 m, or 'none'",
    )
    info_topic: str | None = option(
        None,
        check=_text,
        metavar="TOPIC",
        show=lambda v: "the one next to the colour topic",
        help="CameraInfo topic of the colour camera",
    )
    depth_unit: str | None = option(
        None,
        check=_depth_unit,
        metavar="UNIT",
        show=lambda v: "1mm",
        help=f"length of one depth count in the depth images, e.g. {DEPTH_UNIT_EXAMPLES}",
    )
    fps: float | None = fps_option(
        "folders: 30; videos: the file's own", "frame rate giving the timestamps (videos: replaces the file's own)"
    )
    intrinsics: Path | None = option(
        None,
        optional=True,
        check=_path,
        metavar="FILE",
        help="colour intrinsics, JSON or YAML: width, height, fx, fy, cx, cy; a ROS camera_info "
        "YAML; or an Open3D intrinsic JSON",
    )
    fx: float | None = option(
        None,
        kind="float",
        lo=0.001,
        optional=True,
        unit="px",
        metavar="PX",
        help="colour intrinsics fx (fy defaults to fx, cx/cy to the image centre)",
    )
    fy: float | None = option(
        None, kind="float", lo=0.001, optional=True, unit="px", metavar="PX", help="colour intrinsics fy"
    )
    cx: float | None = option(None, kind="float", optional=True, unit="px", metavar="PX", help="colour intrinsics cx")
    cy: float | None = option(None, kind="float", optional=True, unit="px", metavar="PX", help="colour intrinsics cy")
    hfov: float = option(
        DEFAULT_HFOV_DEG,
        kind="float",
        lo=HFOV_RANGE_DEG[0],
        hi=HFOV_RANGE_DEG[1],
        unit="deg",
        metavar="DEG",
        help="horizontal field of view assumed when no intrinsics are given",
    )
    frames: int | None = option(
        None, kind="int", lo=1, optional=True, metavar="N", show=lambda v: "all", help="import at most N frames"
    )

    def __post_init__(self) -> None:
        validate(self)
        if self.fx is None and any(v is not None for v in (self.fy, self.cx, self.cy)):
            raise InputError("--fy/--cx/--cy need --fx")
        if self.intrinsics is not None and self.fx is not None:
            raise InputError("give the intrinsics either as --intrinsics FILE or as --fx/--fy/--cx/--cy, not both")


#: ``--help`` headings and the ImportOptions fields under each (``frames`` goes under "output").
GROUPS = {
    "ROS bags": ("color_topic", "depth_topic", "info_topic"),
    "image folders and videos": ("depth_unit", "fps", "intrinsics", "fx", "fy", "cx", "cy", "hfov"),
}
#: The config classes whose flags the command registers.
CONFIGS = (ImportOptions, EncodingOptions)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf import``."""
    p.add_argument("source", type=Path, metavar="SRC", help="recording, folder or video to import")
    p.add_argument("output", type=Path, metavar="OUT.mcap", help="MCAP file to write")
    names = [f.name for f in dataclasses.fields(ImportOptions)]
    for title, group in GROUPS.items():
        add_options(p, ImportOptions, exclude=[n for n in names if n not in group], title=title)
    out = p.add_argument_group("output")
    add_options(out, ImportOptions, exclude=[n for n in names if n != "frames"])
    add_options(out, EncodingOptions)
    out.add_argument("--force", action="store_true", help="overwrite OUT.mcap if it exists")
    out.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def run(args: argparse.Namespace) -> int:
    """Import SRC into OUT.mcap and print what was chosen and written."""
    from drivers.importers import IntrinsicsOption, open_import, write_recording

    from ._paths import check_output

    opts = from_args(ImportOptions, args)
    encoding = from_args(EncodingOptions, args)
    check_output(args.output, force=args.force, inputs=(args.source, opts.intrinsics))
    intrinsics = IntrinsicsOption(opts.intrinsics, opts.fx, opts.fy, opts.cx, opts.cy, opts.hfov)
    source = open_import(
        args.source,
        color_topic=opts.color_topic,
        depth_topic=opts.depth_topic,
        info_topic=opts.info_topic,
        depth_unit=opts.depth_unit,
        fps=opts.fps,
        intrinsics=intrinsics,
    )
    summary = write_recording(
        source,
        args.output,
        max_frames=opts.frames,
        progress=False if args.no_progress else None,
        **encoding.recorder_kwargs(),
    )
    for line in summary.report:
        print(f"  {line}")
    print(
        f"imported {summary.frames} frames ({summary.with_depth} with depth) from {printable(args.source)} to {printable(args.output)} "
        f"in {summary.seconds:.1f} s ({summary.fps:.1f} frames/s); {summary.bytes} bytes"
    )
    if source.stats.partial:
        import sys

        from fusion_pf.errors import PARTIAL_EXIT_CODE

        print(f"fusion-pf: warning: {printable(source.stats.loss_summary())}", file=sys.stderr)
        return PARTIAL_EXIT_CODE
    return 0
