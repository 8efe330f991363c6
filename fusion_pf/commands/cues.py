"""``fusion-pf cues``: run every cue on one frame of a recording and show its stages."""

from __future__ import annotations

import argparse
from pathlib import Path

NAME = "cues"
HELP = "run the colour, depth, skin and skeleton cues on one frame; write stage contact sheets"
DESCRIPTION = (
    "Run the cue extractors of paper 003 (colour Fig. 3, depth Fig. 4) and the skin models "
    "(rg-chromaticity, explicit RGB, CIE-Lab GMM with --skin-model) on frame K of REC.mcap and "
    "print each measurement (full-frame pixels), quality, area and latency, and the error "
    "against the ground truth when the recording has one. With --stages DIR, one PNG contact "
    "sheet per cue is written (DIR/frameK_<cue>.png), every stage image labelled with its paper "
    "name, shape and dtype, like the paper's Figures 6-7. Background: the median of the frames "
    "of --background EMPTY.mcap; else the recording's own empty-scene frames (metadata "
    "background_frames); else the median of its first --background-frames frames. The depth "
    "cue first runs on frame K-1 so its temporal difference (I_d6) is that of frame K."
)


def _pair(kind: type):
    def parse(text: str):
        parts = text.replace(" ", "").split(",")
        try:
            if len(parts) != 2:
                raise ValueError
            return tuple(kind(p) for p in parts)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected two comma-separated numbers A,B, got {text!r}") from None

    return parse


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf cues``."""
    p.add_argument("file", type=Path, metavar="REC.mcap", help="recording to read")
    p.add_argument("--frame", type=int, default=None, metavar="K",
                   help="frame index (default: the first frame after the empty-scene frames)")
    p.add_argument("--stages", type=Path, default=None, metavar="DIR", help="write one PNG contact sheet per cue here")
    p.add_argument("--background", type=Path, default=None, metavar="EMPTY.mcap",
                   help="recording of the empty scene (median of all its frames)")
    p.add_argument("--background-frames", type=int, default=10, metavar="N",
                   help="without empty-scene frames: median of the first N frames")
    p.add_argument("--prior", choices=("joint", "truth", "full"), default="joint",
                   help="ROI centre: the skeleton joint, the ground truth (synthetic), or no ROI")
    p.add_argument("--at", type=_pair(float), default=None, metavar="U,V", help="ROI centre in pixels (overrides --prior)")
    p.add_argument("--joint", default="right_hand", help="skeleton joint used as prior and skeleton cue")
    p.add_argument("--half-size", type=int, default=None, metavar="PX", help="fixed ROI half-size (default: depth-scaled)")
    p.add_argument("--extent-mm", type=float, default=250.0, metavar="MM", help="ROI half-size in mm at the prior's depth")
    p.add_argument("--colour-thresholds", type=_pair(int), default=(16, 66), metavar="LO,HI",
                   help="colour: lower,upper grayscale-difference thresholds (I_C4A, I_C4B)")
    p.add_argument("--depth-range", type=_pair(int), default=(0, 2550), metavar="LO,HI",
                   help="depth: difference range in mm quantised to 0-255 (I_d3)")
    p.add_argument("--depth-thresholds", type=_pair(int), default=(15, 255), metavar="LO,HI",
                   help="depth: lower,upper thresholds on I_d3 (I_d4A, I_d4B)")
    p.add_argument("--nearest-mm", type=int, default=50, metavar="MM",
                   help="depth: keep the slab this deep behind the nearest surface; 0 = the paper's band only")
    p.add_argument("--min-area", type=int, default=40, metavar="PX", help="smallest region kept (all cues)")
    p.add_argument("--skin-model", type=Path, default=None, metavar="MODEL.npz",
                   help="CIE-Lab GMM skin model saved by LabGmmSkin.save (adds the skin_lab cue)")
    p.add_argument("--json", action="store_true", help="print one JSON document")


def _background(args: argparse.Namespace, src, n: int):
    from drivers.mcap_replay import McapReplay
    from fusion_pf.cues import BackgroundModel
    from fusion_pf.errors import InputError

    if args.background is not None:
        with McapReplay(args.background) as empty:
            return BackgroundModel.from_frames(empty.frames()), f"{args.background} ({len(empty)} frames)"
    k = src.info().background_frames
    if k:
        return BackgroundModel.from_frames(src.frames(0, k)), f"{k} empty-scene frames of the recording"
    if not 1 <= args.background_frames <= n:
        raise InputError(f"--background-frames must be in [1, {n}], got {args.background_frames}")
    model = BackgroundModel.running(args.background_frames)
    for frame in src.frames(0, args.background_frames):
        model.update(frame)
    return model, f"median of the first {args.background_frames} frames"


def _roi(args: argparse.Namespace, frame):
    from fusion_pf.cues import make_roi

    if args.prior == "full" and args.at is None:
        return None
    joint = frame.joint(args.joint)
    depth = joint.depth_mm if joint is not None else None
    if args.at is not None:
        u, v = args.at
    elif args.prior == "truth" and frame.ground_truth is not None:
        u, v = frame.ground_truth.u, frame.ground_truth.v
    elif joint is not None:
        u, v = joint.u, joint.v
    else:
        return None
    return make_roi(u, v, frame.size, depth_mm=depth, fx=frame.intrinsics.fx,
                    half_size=args.half_size, extent_mm=args.extent_mm)


def run(args: argparse.Namespace) -> int:
    """Run the cues on one frame; print the measurements; write contact sheets."""
    import json
    import math

    import cv2

    from drivers.mcap_replay import McapReplay
    from fusion_pf.cues import (
        ColourCue,
        DepthCue,
        LabGmmSkin,
        RgbRuleSkin,
        RgChromaSkin,
        SkinCue,
        contact_sheet,
        skeleton_cue,
    )
    from fusion_pf.errors import InputError

    lo, hi = args.colour_thresholds
    colour = ColourCue(lower=lo, upper=hi, min_area=args.min_area)
    dlo, dhi = args.depth_thresholds
    depth = DepthCue(range_mm=args.depth_range, lower=dlo, upper=dhi, min_area=args.min_area,
                     nearest_mm=args.nearest_mm or None)
    skins = [SkinCue(RgChromaSkin(), min_area=args.min_area), SkinCue(RgbRuleSkin(), min_area=args.min_area)]
    if args.skin_model is not None:
        skins.append(SkinCue(LabGmmSkin.load(args.skin_model), min_area=args.min_area))
    if args.stages is not None:
        if args.stages.exists() and not args.stages.is_dir():
            raise InputError(f"--stages {args.stages} is not a directory")
        args.stages.mkdir(parents=True, exist_ok=True)

    with McapReplay(args.file) as src:
        n = len(src)
        if n == 0:
            raise InputError(f"{args.file} holds no frame")
        k = args.frame if args.frame is not None else min(src.info().background_frames, n - 1)
        if not 0 <= k < n:
            raise InputError(f"--frame must be in [0, {n - 1}], got {k}")
        background, bg_note = _background(args, src, n)
        frame = src.frame(k)
        if background.color is None or background.color.shape != frame.color.shape:
            raise InputError(f"background size does not match the recording's {frame.size[0]}x{frame.size[1]}")
        roi = _roi(args, frame)
        results = {"colour": colour(frame.color, background.color, roi=roi, stages=True)}
        if frame.depth is not None:
            if k > 0:
                prev = src.frame(k - 1)
                if prev.depth is not None:
                    depth(prev.depth, background.depth, roi=_roi(args, prev))
            results["depth"] = depth(frame.depth, background.depth, roi=roi, stages=True)
        for cue in skins:
            results[cue.source] = cue(frame.color, roi=roi, stages=True)
        results["skeleton"] = skeleton_cue(frame, args.joint)

    truth = frame.ground_truth
    rows = {}
    for name, res in results.items():
        m = res.measurement
        row = {"u": None, "v": None, "quality": None, "area": None, "error_px": None,
               "latency_ms": res.latency_ns / 1e6}
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
            title = (f"{args.file.name} frame {k} - {name}: " +
                     (f"u={m.u:.1f} v={m.v:.1f} q={m.quality:.2f}" if m else "no measurement"))
            sheet = contact_sheet(res.stages, title=title, point=point, equalize=("I_d1", "I_d2", "I_d3"))
            out = args.stages / f"frame{k:06d}_{name}.png"
            if not cv2.imwrite(str(out), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
                raise InputError(f"cannot write {out}")
            row["sheet"] = str(out)

    doc = {"file": str(args.file), "frame": k, "timestamp_ns": frame.timestamp_ns, "background": bg_note,
           "roi": roi.as_list() if roi is not None else None,
           "truth": None if truth is None else {"u": truth.u, "v": truth.v, "occluded": truth.occluded},
           "cues": rows}
    if args.json:
        print(json.dumps(doc, indent=2))
        return 0
    print(f"frame {k} of {args.file} ({frame.size[0]}x{frame.size[1]}), background: {bg_note}")
    print(f"roi {doc['roi'] if roi is not None else 'full frame'}"
          + ("" if truth is None else f"; truth u={truth.u:.1f} v={truth.v:.1f}{' (occluded)' if truth.occluded else ''}"))
    for name, row in rows.items():
        if row["u"] is None:
            text = "none"
        else:
            text = f"u={row['u']:7.1f} v={row['v']:7.1f} quality={row['quality']:.2f}"
            text += f" area={row['area']}" if row["area"] is not None else ""
            text += f" error={row['error_px']:.1f}px" if row["error_px"] is not None else ""
        print(f"{name:9s} {text}  ({row['latency_ms']:.2f} ms)" + (f"  -> {row['sheet']}" if "sheet" in row else ""))
    return 0
