"""``fusion-pf synth``: render the synthetic scene into an MCAP recording."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "synth"
HELP = "render the synthetic RGB-D scene (with skeleton and ground truth) into an MCAP file"
DESCRIPTION = (
    "Render N frames of the seeded synthetic scene (drivers/synth.py: a person in dark clothes "
    "whose bare right palm repeatedly passes in front of the torso, stereo-like depth, a "
    "Kinect-like skeleton that fails during self-occlusion, ground truth on /ground_truth/palm) "
    "into OUT.mcap. The first K frames show the empty scene (background frames). The same seed "
    "and options give the same frames."
)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf synth``."""
    p.add_argument("output", type=Path, metavar="OUT.mcap", help="MCAP file to write")
    p.add_argument("--frames", default="200", metavar="N", help="frames to render, background frames included")
    p.add_argument("--seed", default="0", metavar="S", help="scene and noise seed (non-negative int)")
    p.add_argument("--background-frames", default="0", metavar="K", help="empty-scene frames at the start")
    p.add_argument("--size", default="640x400", metavar="WxH", help="image size in pixels")
    p.add_argument("--fps", default="30", metavar="F", help="frame rate (timestamps 1/F s apart)")
    p.add_argument(
        "--depth-model",
        default="realistic",
        metavar="realistic|basic",
        help="depth sensor model: realistic stereo artefacts (noise ~ z^2, 1/8 px disparity steps, "
        "flying pixels and holes at depth steps, speckle holes, range limits), or basic "
        "(the model recordings/sample.mcap was made with)",
    )
    p.add_argument(
        "--hands",
        default="1",
        metavar="H",
        help="1: one palm sweeping in front of the torso; 2: both hands washing (they join twice "
        "and cross once every 300 frames), ground truth per target (right_hand, left_hand, head)",
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
    p.add_argument("--force", action="store_true", help="overwrite OUT.mcap if it exists")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    """Render and record; the file is finalised even on Ctrl-C."""
    import sys
    import time

    from tqdm import tqdm

    from drivers.mcap_record import McapRecorder
    from drivers.synth import SynthSource

    from ._paths import check_output

    source = SynthSource.from_options(
        {
            "frames": args.frames,
            "seed": args.seed,
            "background_frames": args.background_frames,
            "size": args.size,
            "fps": args.fps,
            "depth_model": args.depth_model,
            "hands": args.hands,
        }
    )
    out: Path = args.output
    check_output(out, force=args.force)
    recorder = McapRecorder(
        out,
        compression=args.compression,
        color_format=args.color_format,
        depth_format=args.depth_format,
        jpeg_quality=args.jpeg_quality,
        metadata=source.metadata(),
    )
    started = time.monotonic()
    with (
        source,
        recorder,
        tqdm(
            total=len(source),
            unit="frame",
            desc=source.describe(),
            disable=True if args.no_progress else None,
            file=sys.stderr,
        ) as bar,
    ):
        for frame in source:
            recorder.write(frame)
            bar.update()
    print(
        f"wrote {recorder.frames_written} frames ({source.background_frames} background) to {out} "
        f"in {time.monotonic() - started:.1f} s: {recorder.bytes_written} bytes"
    )
    return 0
