"""``fusion-pf render``: draw a tracked recording as a video and/or a PNG contact sheet."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

from fusion_pf.options import add_options, from_args, option, validate
from fusion_pf.text import printable

NAME = "render"
HELP = (
    "draw a tracked recording (image, cue points, particles, estimate, state; several cameras: every view "
    "and a top view) as MP4 and/or PNG sheet"
)
DESCRIPTION = (
    "Draw every frame of TRACKED.mcap (the output of fusion-pf track -o): the colour image, the "
    "cue point of every source in /tracker/cues (one colour per source, listed top right; ': -' "
    "when the source gave nothing), the cue window (white), the particles (yellow), the estimate "
    "(red circle) and, when the estimate has one, the track state. -o writes an H.264 MP4 of every "
    "frame; --sheet a PNG contact sheet of every K-th frame (--every). Images narrower than 640 px "
    "are scaled up by an integer factor. The images come from TRACKED.mcap, or, when it has no "
    "colour topic, from the recording named in its metadata 'source', or from --input. A multi-camera "
    "tracker output (/tracker/world) is drawn as one grid per instant: every camera's image with each "
    "target's pixel in it (a ring in the target's colour, thick where that camera measured it, and its "
    "state), and a top view of the rig (world x-z: the cameras from /tf, each target with its trail, "
    "the recording's ground truth as white crosses)."
)


@dataclass(frozen=True)
class RenderOptions:
    """The drawing options of ``fusion-pf render``."""

    every: int = option(10, kind="int", lo=1, hi=1_000_000, metavar="K", help="contact sheet: every K-th frame")
    columns: int = option(6, kind="int", lo=1, hi=100, metavar="N", help="contact sheet: tiles per row")
    tile_width: int = option(320, kind="int", lo=32, hi=4096, unit="px", help="contact sheet: tile width at most")
    fps: float | None = option(
        None,
        kind="float",
        lo=0.001,
        hi=1000.0,
        optional=True,
        metavar="FPS",
        show=lambda v: "from the frame timestamps",
        help="video frame rate",
    )

    def __post_init__(self) -> None:
        validate(self)


#: The config classes whose flags the command registers.
CONFIGS = (RenderOptions,)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf render``."""
    p.add_argument("tracked", type=Path, metavar="TRACKED.mcap", help="output of fusion-pf track -o")
    p.add_argument("-o", "--output", type=Path, metavar="OUT.mp4", help="video of every frame (H.264 MP4)")
    p.add_argument("--sheet", type=Path, metavar="OUT.png", help="contact sheet of every K-th frame")
    add_options(p, RenderOptions)
    p.add_argument(
        "--input",
        type=Path,
        metavar="REC.mcap",
        help="the recording that was tracked (images), when TRACKED.mcap has none",
    )
    p.add_argument("--force", action="store_true", help="overwrite OUT.mp4 / OUT.png if they exist")


def run(args: argparse.Namespace) -> int:
    """Render TRACKED.mcap; returns the exit status."""
    from drivers.render import image_recording, render
    from drivers.render_rig import has_world, render_rig
    from fusion_pf.errors import InputError

    from ._paths import check_distinct, check_output

    if args.output is None and args.sheet is None:
        raise InputError("nothing to write: pass -o OUT.mp4 and/or --sheet OUT.png")
    if not args.tracked.is_file():
        raise InputError(f"{args.tracked} does not exist; expected the output of fusion-pf track -o")
    opts = from_args(RenderOptions, args)
    every = opts.every
    world = has_world(args.tracked)
    images = image_recording(args.tracked, args.input, rig=world)
    for what, out, suffix in (("output", args.output, ".mp4"), ("--sheet", args.sheet, ".png")):
        if out is None:
            continue
        if out.suffix.lower() != suffix:
            raise InputError(f"{what} {out} must end in {suffix}")
        check_output(out, force=args.force, what=what, inputs=(args.tracked, args.input, images))
    check_distinct([("-o", args.output), ("--sheet", args.sheet)])
    drawing = dict(
        video=args.output, sheet=args.sheet, every=every, columns=opts.columns, tile_width=opts.tile_width, fps=opts.fps
    )
    done = render_rig(args.tracked, images, **drawing) if world else render(args.tracked, input_path=images, **drawing)
    w, h = done.size
    parts = []
    if args.output is not None:
        parts.append(f"{printable(args.output)} ({done.frames} frames, {w}x{h}, H.264)")
    if args.sheet is not None:
        parts.append(f"{printable(args.sheet)} ({done.sheet_tiles} tiles, every {every}th frame)")
    unit = "instants" if world else "frames"
    print(f"rendered {done.frames} {unit} ({done.tracked} with tracker output) -> {', '.join(parts)}")
    return 0
