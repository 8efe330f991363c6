"""``fusion-pf info`` of a multi-camera recording: the rig (cameras, resolutions, intrinsics, poses)."""

from __future__ import annotations

import argparse
from typing import Any


def _text(rig: dict[str, Any], verified: dict | None) -> str:
    from fusion_pf.text import printable as p

    state = "TRUNCATED (writer did not finish)" if rig["truncated"] else "complete"
    lines = [
        f"file          {p(rig['path'])} ({rig['size_bytes']} bytes, {state})",
        f"writer        {p(rig['library']) or 'unknown'}",
        f"rig           {len(rig['cameras'])} cameras, {rig['instants']} instants "
        f"({rig['complete_sets']} with every camera), world ground truth {'yes' if rig['world_truth'] else 'no'}",
    ]
    width = max(len(c["name"]) for c in rig["cameras"])
    for c in rig["cameras"]:
        k = c["intrinsics"]
        t = ", ".join(f"{v:.1f}" for v in c["translation_mm"])
        q = ", ".join(f"{v:.4f}" for v in c["rotation_xyzw"])
        lines.append(
            f"  {p(c['name']):<{width}}  {c['width']}x{c['height']}  colour {c['color_format']}  "
            f"depth {p(c['depth_format'] or 'none')}  {c['frames']} frames  "
            f"fx={k['fx']:.2f} fy={k['fy']:.2f} cx={k['cx']:.2f} cy={k['cy']:.2f}  pose t_mm=[{t}] q_xyzw=[{q}]"
        )
    if rig["metadata"]:
        lines.append("metadata      " + " ".join(f"{p(key)}={p(value)}" for key, value in rig["metadata"].items()))
    tw = max(len(p(t["topic"])) for t in rig["topics"])
    lines.append("topics")
    for t in rig["topics"]:
        lines.append(
            f"  {p(t['topic']):<{tw}}  {t['message_count']:>8}  {p(t['schema_name'])} ({p(t['message_encoding'])})"
        )
    if verified is not None:
        lines.append(
            f"verified      {verified['sets']} frame sets decoded, {verified['dropped']} frames lost"
            + "".join(f"; {p(s)}" for s in verified["summaries"])
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Describe the rig; with --verify decode every frame set (exit 2 when a camera lost frames)."""
    import json
    import sys

    from drivers.rig import RigReplay
    from fusion_pf.errors import RecordingError
    from fusion_pf.text import printable

    with RigReplay(args.file) as rig:
        info = rig.info()
        verified: dict[str, Any] | None = None
        if args.verify:
            sets = sum(1 for _ in rig)
            stats = {name: replay.stats for name, replay in rig.replays.items()}
            verified = {
                "sets": sets,
                "dropped": sum(s.dropped for s in stats.values()),
                "summaries": [f"{name}: {s.loss_summary()}" for name, s in stats.items() if s.loss_summary()],
            }
            info["verified"] = verified
        notes = rig.notes + [n for replay in rig.replays.values() for n in replay.stats.notes]
    print(json.dumps(info, indent=2) if args.json else _text(info, verified))
    for note in dict.fromkeys(notes):
        print(f"fusion-pf: warning: {printable(note)}", file=sys.stderr)
    if verified is not None and verified["dropped"]:
        raise RecordingError(
            f"{args.file} failed verification: {verified['dropped']} frames cannot be read; "
            + "; ".join(verified["summaries"])
        )
    return 0
