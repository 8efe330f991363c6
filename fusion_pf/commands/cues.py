"""``fusion-pf cues``: run every cue on one frame of a recording and show its stages."""

from __future__ import annotations

import argparse
from pathlib import Path

from fusion_pf.cues.registry import CueOptions
from fusion_pf.pipeline import TrackConfig
from fusion_pf.text import printable

NAME = "cues"
HELP = "run the colour, depth, skin and skeleton cues on one frame; write stage contact sheets"
DESCRIPTION = (
    "Run the cues (the registry's: colour Fig. 3, depth Fig. 4 of paper 003, the skin models, the "
    "skeleton joint; skin_lab with --skin-model) on frame K of REC.mcap with the same options, window "
    "and background as 'fusion-pf track', and print each measurement (full-frame pixels), quality, "
    "area and latency, and the error against the ground truth when the recording has one. With "
    "--stages DIR, one PNG contact sheet per cue is written (DIR/frameK_<cue>.png), every stage image "
    "labelled with its paper name, shape and dtype, like the paper's Figures 6-7. Background: the "
    "median of --background EMPTY.mcap; else the recording's own empty-scene frames (metadata "
    "background_frames); else the median of its first --background-k frames. The depth cue first "
    "runs on frame K-1 so its temporal difference (I_d6) is that of frame K."
)

#: The config classes whose flags the command registers (of TrackConfig only WINDOW_OPTIONS).
CONFIGS = (TrackConfig, CueOptions)
#: TrackConfig fields that place the window and build the background (shared with ``track``).
WINDOW_OPTIONS = ("joint", "roi_half_size", "roi_palms", "depth_radius", "background", "background_k")


def _pair(text: str):
    parts = text.replace(" ", "").split(",")
    try:
        if len(parts) != 2:
            raise ValueError
        return tuple(float(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected two comma-separated numbers U,V, got {text!r}") from None


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf cues``: its own, the window's (as ``track``) and the cues'."""
    import dataclasses

    from fusion_pf.options import add_options

    p.add_argument("file", type=Path, metavar="REC.mcap", help="recording to read")
    p.add_argument(
        "--frame",
        type=int,
        default=None,
        metavar="K",
        help="frame index (default: the first frame after the empty-scene frames)",
    )
    p.add_argument(
        "--stages",
        type=Path,
        default=None,
        metavar="DIR",
        help="write one PNG contact sheet per cue here (created if missing)",
    )
    p.add_argument(
        "--prior",
        choices=("joint", "truth", "full"),
        default="joint",
        help="window centre: the skeleton joint, the ground truth (synthetic), or no window",
    )
    p.add_argument("--at", type=_pair, default=None, metavar="U,V", help="window centre in pixels (overrides --prior)")
    p.add_argument(
        "--cues",
        default=None,
        metavar="CUE,...",
        help="cues to run (default: every registered cue the frame can feed; skin_lab with --skin-model)",
    )
    p.add_argument("--json", action="store_true", help="print one JSON document")
    skip = [f.name for f in dataclasses.fields(TrackConfig) if f.name not in WINDOW_OPTIONS]
    add_options(p, TrackConfig, exclude=skip, title="window and background (as fusion-pf track)")
    add_options(p, CueOptions, title="cues")


def _background(config, src, n: int):
    from fusion_pf.cues.background import BackgroundModel
    from fusion_pf.errors import InputError

    from .track import load_background

    if config.background is not None:
        return load_background(config.background), f"{config.background}"
    k = src.info().background_frames
    if k:
        return BackgroundModel.from_frames(src.frames(0, k)), f"{k} empty-scene frames of the recording"
    if config.background_k > n:
        raise InputError(f"--background-k must be in [1, {n}] (frames of the recording), got {config.background_k}")
    return BackgroundModel.from_frames(
        src.frames(0, config.background_k)
    ), f"median of the first {config.background_k} frames"


def _prior(args: argparse.Namespace, config, frame):
    if args.at is not None:
        return args.at
    if args.prior == "full":
        return None
    if args.prior == "truth" and frame.ground_truth is not None:
        return frame.ground_truth.u, frame.ground_truth.v
    joint = frame.joint(config.joint)
    return None if joint is None else (joint.u, joint.v)


def run(args: argparse.Namespace) -> int:
    """Run the cues on one frame; print the measurements; write contact sheets."""
    import json
    import math

    import cv2

    from drivers.mcap_replay import McapReplay
    from fusion_pf.cues import contact_sheet
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.registry import CUES, build_cues
    from fusion_pf.errors import InputError
    from fusion_pf.options import from_args
    from fusion_pf.pipeline import cue_window

    from ._paths import check_folder_outputs

    options = from_args(CueOptions, args)
    config = from_args(TrackConfig, args, cue_options=options)
    if args.stages is not None:
        if args.stages.exists() and not args.stages.is_dir():
            raise InputError(f"--stages {args.stages} is a file; expected a directory")
        args.stages.mkdir(parents=True, exist_ok=True)

    with McapReplay(args.file) as src:
        n = len(src)
        if n == 0:
            raise InputError(f"{args.file} holds no frame")
        k = args.frame if args.frame is not None else min(src.info().background_frames, n - 1)
        if not 0 <= k < n:
            raise InputError(f"--frame must be in [0, {n - 1}], got {k}")
        frame = src.frame(k)
        parts = (
            {"color", "background"}
            | ({"depth"} if frame.depth is not None else set())
            | ({"skeleton"} if frame.joints is not None else set())
        )
        if args.cues is not None:
            names = tuple(s.strip() for s in args.cues.split(",") if s.strip())
        else:
            names = tuple(
                c for c, info in CUES.items() if info.needs <= parts and (c != "skin_lab" or options.skin_model)
            )
        cues = build_cues(names, options)
        background, bg_note = _background(config, src, n)
        if background.color is None or background.color.shape != frame.color.shape:
            raise InputError(f"background size does not match the recording's {frame.size[0]}x{frame.size[1]}")
        roi = cue_window(frame, _prior(args, config, frame), config)
        if k > 0 and "depth" in cues:
            prev = src.frame(k - 1)
            cues["depth"].measure(prev, CueContext(cue_window(prev, _prior(args, config, prev), config), background))
        ctx = CueContext(roi=roi, background=background, joint=config.joint, stages=True)
        results = {name: cue.measure(frame, ctx) for name, cue in cues.items()}

    truth = frame.ground_truth
    sheets = {name: f"frame{k:06d}_{name}.png" for name in results}
    if args.stages is not None:
        check_folder_outputs(args.stages, sheets.values(), (args.file, config.background), "--stages")
    rows = {}
    for name, res in results.items():
        m = res.measurement
        row: dict[str, object] = {
            "u": None,
            "v": None,
            "quality": None,
            "area": None,
            "error_px": None,
            "latency_ms": res.latency_ns / 1e6,
        }
        if m is not None:
            row.update(u=m.u, v=m.v, quality=m.quality, area=m.extras.get("area"))
            if truth is not None:
                row["error_px"] = math.hypot(m.u - truth.u, m.v - truth.v)
        rows[name] = row
        if args.stages is not None and res.stages:
            point = None
            if m is not None and roi is not None:
                point = (m.u - roi.x0, m.v - roi.y0)
            elif m is not None:
                point = (m.u, m.v)
            title = f"{args.file.name} frame {k} - {name}: " + (
                f"u={m.u:.1f} v={m.v:.1f} q={m.quality:.2f}" if m else "no measurement"
            )
            sheet = contact_sheet(res.stages, title=title, point=point, equalize=("I_d1", "I_d2", "I_d3"))
            out = args.stages / sheets[name]
            if not cv2.imwrite(str(out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
                raise InputError(f"cannot write {out}")
            row["sheet"] = str(out)

    doc = {
        "file": str(args.file),
        "frame": k,
        "timestamp_ns": frame.timestamp_ns,
        "background": bg_note,
        "roi": roi.as_list() if roi is not None else None,
        "truth": None if truth is None else {"u": truth.u, "v": truth.v, "occluded": truth.occluded},
        "cues": rows,
    }
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    print(f"frame {k} of {printable(args.file)} ({frame.size[0]}x{frame.size[1]}), background: {bg_note}")
    print(
        f"roi {doc['roi'] if roi is not None else 'full frame'}"
        + ("" if truth is None else f"; truth u={truth.u:.1f} v={truth.v:.1f}{' (occluded)' if truth.occluded else ''}")
    )
    for name, row in rows.items():
        if row["u"] is None:
            text = "none"
        else:
            text = f"u={row['u']:7.1f} v={row['v']:7.1f} quality={row['quality']:.2f}"
            text += f" area={row['area']}" if row["area"] is not None else ""
            text += f" error={row['error_px']:.1f}px" if row["error_px"] is not None else ""
        print(f"{name:9s} {text}  ({row['latency_ms']:.2f} ms)" + (f"  -> {row['sheet']}" if "sheet" in row else ""))
    return 0
