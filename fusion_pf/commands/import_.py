"""``fusion-pf import``: turn another tool's recording into a fusion-pf MCAP recording."""

from __future__ import annotations

import argparse
from pathlib import Path

from .record import _positive

NAME = "import"
HELP = "import a ROS bag, Azure Kinect .mkv, image folder or video into an MCAP recording"
DESCRIPTION = (
    "Convert SRC into OUT.mcap following docs/recording-format.md: colour (RGB), depth registered "
    "to colour in millimetres, the colour intrinsics, capture timestamps in ns, no skeleton. "
    "SRC is a ROS 2 bag (.mcap or bag folder; sensor_msgs Image/CompressedImage/CameraInfo, "
    "topics chosen by type and name, aligned depth preferred, colour and depth paired by time), "
    "a ROS 1 .bag, an Azure Kinect .mkv (depth registered to the colour camera with the attached "
    "calibration), a folder of colour and/or depth images, or a video file (colour only). "
    "What was chosen and assumed (topics, tracks, pairing, intrinsics) is printed."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf import``."""
    from drivers.importers.base import DEFAULT_HFOV_DEG, DEPTH_UNIT_EXAMPLES

    p.add_argument("source", type=Path, metavar="SRC", help="recording, folder or video to import")
    p.add_argument("output", type=Path, metavar="OUT.mcap", help="MCAP file to write")
    ros = p.add_argument_group("ROS bags")
    ros.add_argument("--color-topic", metavar="TOPIC", help="colour image topic; if absent, chosen by type and name")
    ros.add_argument(
        "--depth-topic",
        metavar="TOPIC",
        help="depth image topic, 16UC1 mm or 32FC1 m, or 'none'; if absent, chosen by type and name "
        "(aligned_depth_to_color first)",
    )
    ros.add_argument(
        "--info-topic",
        metavar="TOPIC",
        help="CameraInfo topic of the colour camera; if absent, the one next to the colour topic",
    )
    folder = p.add_argument_group("image folders and videos")
    folder.add_argument(
        "--depth-unit",
        metavar="UNIT",
        help=f"length of one depth count in the depth images, e.g. {DEPTH_UNIT_EXAMPLES}; if absent, 1mm",
    )
    folder.add_argument(
        "--fps",
        type=_positive(float),
        metavar="F",
        help="frame rate giving the timestamps (folders: 30 if absent; videos: replaces the file's own)",
    )
    folder.add_argument(
        "--intrinsics",
        type=Path,
        metavar="FILE",
        help="colour intrinsics, JSON or YAML: width, height, fx, fy, cx, cy; a ROS camera_info "
        "YAML; or an Open3D intrinsic JSON",
    )
    for name in ("fx", "fy", "cx", "cy"):
        folder.add_argument(
            f"--{name}",
            type=float,
            metavar="PX",
            help=f"colour intrinsics {name} in pixels"
            + (" (fy defaults to fx, cx/cy to the image centre)" if name == "fx" else ""),
        )
    folder.add_argument(
        "--hfov",
        type=_positive(float),
        default=DEFAULT_HFOV_DEG,
        metavar="DEG",
        help="horizontal field of view assumed when no intrinsics are given",
    )
    out = p.add_argument_group("output")
    out.add_argument("--frames", type=_positive(int), metavar="N", help="import at most N frames")
    out.add_argument(
        "--color-format",
        choices=("raw", "jpeg", "png"),
        default="raw",
        help="colour as RawImage rgb8, or CompressedImage jpeg/png",
    )
    out.add_argument(
        "--depth-format",
        choices=("raw", "png"),
        default="raw",
        help="depth as RawImage 16UC1, or 16-bit PNG CompressedImage",
    )
    out.add_argument("--jpeg-quality", type=int, default=90, metavar="Q", help="JPEG quality 1-100")
    out.add_argument("--compression", choices=("zstd", "lz4", "none"), default="zstd", help="chunk compression")
    out.add_argument("--force", action="store_true", help="overwrite OUT.mcap if it exists")
    out.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def run(args: argparse.Namespace) -> int:
    """Import SRC into OUT.mcap and print what was chosen and written."""
    from drivers.importers import IntrinsicsOption, open_import, write_recording
    from fusion_pf.errors import InputError

    from ._paths import check_output

    check_output(args.output, force=args.force, inputs=(args.source,))
    if args.fx is None and any(getattr(args, k) is not None for k in ("fy", "cx", "cy")):
        raise InputError("--fy/--cx/--cy need --fx")
    if args.intrinsics is not None and args.fx is not None:
        raise InputError("give the intrinsics either as --intrinsics FILE or as --fx/--fy/--cx/--cy, not both")
    intrinsics = IntrinsicsOption(args.intrinsics, args.fx, args.fy, args.cx, args.cy, args.hfov)
    source = open_import(
        args.source,
        color_topic=args.color_topic,
        depth_topic=args.depth_topic,
        info_topic=args.info_topic,
        depth_unit=args.depth_unit,
        fps=args.fps,
        intrinsics=intrinsics,
    )
    summary = write_recording(
        source,
        args.output,
        max_frames=args.frames,
        progress=False if args.no_progress else None,
        color_format=args.color_format,
        depth_format=args.depth_format,
        jpeg_quality=args.jpeg_quality,
        compression=args.compression,
    )
    for line in summary.report:
        print(f"  {line}")
    print(
        f"imported {summary.frames} frames ({summary.with_depth} with depth) from {args.source} to {args.output} "
        f"in {summary.seconds:.1f} s ({summary.fps:.1f} frames/s); {summary.bytes} bytes"
    )
    return 0
