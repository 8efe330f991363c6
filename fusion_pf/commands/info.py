"""``fusion-pf info``: describe a recording."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

NAME = "info"
HELP = "describe a recording: topics, counts, duration, fps, calibration, truncation; the rig of a multi-camera one"
DESCRIPTION = (
    "Print the topics, schemas and message counts of FILE.mcap, its duration, frame rate, "
    "resolution and intrinsics, background frames, frames missing depth or skeleton, and "
    "whether it is truncated. Counts come from the summary when the file is indexed; a "
    "truncated file is scanned. --verify also decodes every frame (checking chunk CRCs), says "
    "which frames could not be read and why, and exits 2 when frames are lost (a truncated tail "
    "alone, as an unfinished recording has, is a warning). For a multi-camera recording it shows "
    "the rig: each camera's resolution, formats, frames, intrinsics and pose in the world. Strings from the "
    "file are printed with control characters escaped."
)


#: The config classes whose flags the command registers: none, its only flags are paths and switches.
CONFIGS: tuple[type, ...] = ()


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf info``."""
    p.add_argument("file", type=Path, metavar="FILE.mcap", help="recording to describe")
    p.add_argument("--json", action="store_true", help="print one JSON document instead of text")
    p.add_argument("--verify", action="store_true", help="decode every frame and check chunk CRCs")


def _text(info: dict, verified: dict | None) -> str:
    from drivers.mcap_format import format_ns
    from fusion_pf.text import printable as p

    k = info["intrinsics"]
    fps = f"{info['fps']:.2f} fps" if info["fps"] is not None else "fps n/a"
    dist = f"{k['distortion_model']} {k['distortion']}" if k["distortion"] else k["distortion_model"]
    lines = [
        f"file          {p(info['path'])} ({info['size_bytes']} bytes, {_state(info)})",
        f"writer        {p(info['library']) or 'unknown'}",
        f"frames        {info['frames']} over {format_ns(info['duration_ns'])} ({fps}), start {info['start_ns']} ns",
        f"resolution    {info['width']}x{info['height']}  colour {info['color_format']}  "
        f"depth {p(info['depth_format'] or 'none')}",
        f"intrinsics    fx={k['fx']:.3f} fy={k['fy']:.3f} cx={k['cx']:.3f} cy={k['cy']:.3f} "
        f"distortion {dist} ({info['calibration_messages']} calibration message(s))",
        f"background    {info['background_frames']} frames",
        f"missing       depth in {info['missing_depth']} frames, skeleton in {info['missing_skeleton']} frames; "
        f"ground truth in {info['ground_truth_frames']} frames",
    ]
    if info["metadata"]:
        lines.append("metadata      " + " ".join(f"{p(key)}={p(value)}" for key, value in info["metadata"].items()))
    lines += _topics_text(info)
    if verified is not None:
        lines.append(
            f"verified      {verified['frames']} frames decoded, {verified['dropped']} lost"
            + (f"; {p(verified['summary'])}" if verified["summary"] else "")
        )
    return "\n".join(lines)


def _topics_text(info: dict) -> list[str]:
    from fusion_pf.text import printable as p

    width = max(len(p(t["topic"])) for t in info["topics"])
    lines = ["topics"]
    for t in info["topics"]:
        lines.append(
            f"  {p(t['topic']):<{width}}  {t['message_count']:>8}  {p(t['schema_name'])} "
            f"({p(t['message_encoding'])}, schema {p(t['schema_encoding'])})"
        )
    return lines


def _state(info: dict) -> str:
    state = "TRUNCATED (writer did not finish)" if info["truncated"] else "complete"
    if info["trailing_bytes"]:
        state += f" + {info['trailing_bytes']} trailing bytes after the end, ignored"
    return f"{state}, {'indexed' if info['indexed'] else 'scanned'}"


def _tracker_output(path: Path) -> dict | None:
    """The description of a ``fusion-pf track`` output (tracker topics, no images), or None for any other file."""
    from drivers import mcap_format as fmt
    from drivers.mcap_replay import McapTopics
    from drivers.tracker_topics import find_source
    from fusion_pf.errors import RecordingError

    try:
        with McapTopics(path) as rec:
            if fmt.COLOR_TOPIC in rec.topics or not any(t.startswith("/tracker/") for t in rec.topics):
                return None
            out = rec.topics_info().to_dict()
    except RecordingError:
        return None
    found = find_source(path, out["metadata"])
    out["kind"] = "tracker output"
    out["source"] = out["metadata"].get("source")
    out["source_found"] = None if found is None else str(found)
    return out


def _tracker_text(info: dict) -> str:
    from drivers.mcap_format import format_ns
    from fusion_pf.text import printable as p

    span = (
        f" over {format_ns(info['end_ns'] - info['start_ns'])}, start {info['start_ns']} ns"
        if info["start_ns"] is not None
        else ""
    )
    found = info["source_found"]
    where = "not found" if found is None else ("found" if found == info["source"] else f"found as {p(found)}")
    lines = [
        f"file          {p(info['path'])} ({info['size_bytes']} bytes, {_state(info)})",
        "kind          tracker output (fusion-pf track -o): tracker topics, no images",
        f"writer        {p(info['library']) or 'unknown'}",
        f"frames        {info['frames']} tracked ({'/tracker/estimate'} messages){span}",
        f"source        {p(info['source'] or 'not named')}" + (f" ({where})" if info["source"] else ""),
    ]
    meta = {k: v for k, v in info["metadata"].items() if k not in ("source", "tracker")}
    if meta:
        lines.append("metadata      " + " ".join(f"{p(key)}={p(value)}" for key, value in meta.items()))
    return "\n".join(lines + _topics_text(info))


def run(args: argparse.Namespace) -> int:
    """Print the description; exit 2 when the file cannot be used or --verify finds lost frames."""
    import sys

    from drivers.mcap_replay import McapReplay
    from drivers.rig import is_rig
    from fusion_pf.errors import RecordingError
    from fusion_pf.text import printable

    if args.file.is_file() and is_rig(args.file):
        from ._rig_info import run as rig_info

        return rig_info(args)
    try:
        with McapReplay(args.file) as replay:
            info = replay.info()
            verified: dict[str, Any] | None = None
            if args.verify:
                decoded = sum(1 for _ in replay)
                stats = replay.stats
                verified = {
                    "frames": decoded,
                    "dropped": stats.dropped,
                    "losses": [
                        {"frames": x.frames, "reason": x.reason, "offset": x.offset, "tail": x.tail}
                        for x in stats.losses
                    ],
                    "skipped_parts": dict(stats.skipped_parts),
                    "summary": stats.loss_summary(),
                }
                info = replay.info()
    except RecordingError:  # not a recording of frames: maybe a tracker output
        tracker = _tracker_output(args.file)
        if tracker is None:
            raise
        print(json.dumps(tracker, indent=2) if args.json else _tracker_text(tracker))
        for note in tracker["notes"]:
            print(f"fusion-pf: warning: {printable(note)}", file=sys.stderr)
        return 0
    out = info.to_dict()
    if verified is not None:
        out["verified"] = verified
    if args.json:
        print(json.dumps(out, indent=2))
    else:
        print(_text(out, verified))
    for note in info.notes:
        print(f"fusion-pf: warning: {printable(note)}", file=sys.stderr)
    if verified is not None and (
        verified["dropped"] or any(x["frames"] is None and not x["tail"] for x in verified["losses"])
    ):
        raise RecordingError(
            f"{args.file} failed verification: {verified['dropped']} frames cannot be read "
            f"({verified['frames']} decoded); {verified['summary']}"
        )
    return 0
