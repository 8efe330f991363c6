"""``fusion-pf track MULTI.mcap``: a multi-camera recording tracked in world coordinates (fusion_pf.pipeline.world)."""

from __future__ import annotations

import argparse
import json
import sys
from contextlib import ExitStack


def track_rig(args: argparse.Namespace, config, live_options) -> int:
    """Track ``args.source`` (a multi-camera recording) in world mm: CSV rows, ``/tracker/world``, ``/tracker/events``
    and ``/tf`` in ``-o``; with ``live_options`` (``--serve``, ``--rerun``) the live view of every camera."""
    import csv

    from tqdm import tqdm

    from drivers import mcap_format as fmt
    from drivers.live import Live, paced
    from drivers.mcap_record import McapRecorder
    from drivers.rig import RigReplay
    from drivers.tracker_topics import source_metadata
    from fusion_pf.annotate.db import recording_sha256
    from fusion_pf.errors import PARTIAL_EXIT_CODE, InputError
    from fusion_pf.pipeline.outputs import world_csv_columns, world_csv_row, world_json
    from fusion_pf.pipeline.run import targets_of
    from fusion_pf.pipeline.world import track_world
    from fusion_pf.pipeline.world_events import with_events
    from fusion_pf.signals import sigint_deferred

    from .track import _events_line

    for flag, value in (("--copy-input", args.copy_input), ("--export-ply", args.export_ply)):
        if value:
            raise InputError(f"{flag} is for one camera; {args.source} is a multi-camera recording")
    counts: dict[str, dict[str, int]] = {}
    events: dict[str, int] = {}
    tracked = n_background = 0
    with RigReplay(args.source) as rig, ExitStack() as stack:
        cameras = list(rig.cameras)
        metadata = {
            **source_metadata(args.source, args.output),
            "tracker": json.dumps(config.settings(), sort_keys=True),
            "source_sha256": recording_sha256(args.source),
            "cameras": ",".join(cameras),
        }
        with sigint_deferred():
            writer = None
            if args.csv is not None:  # opened first: a failing CSV leaves no MCAP
                table = stack.enter_context(open(args.csv, "w", newline="", encoding="ascii"))
                writer = csv.writer(table, lineterminator="\n")
                writer.writerow(world_csv_columns(cameras))
            recorder = stack.enter_context(McapRecorder(args.output, metadata=metadata))
        bar = stack.enter_context(
            tqdm(
                total=len(rig),
                unit="instant",
                desc=str(args.source),
                disable=True if args.no_progress or live_options.enabled else None,
            )
        )
        live = stack.enter_context(Live(live_options)) if live_options.enabled else None
        out = recorder if live is None else live.tee(recorder)  # the live view gets the messages written
        sets = paced(rig) if live_options.realtime else rig
        posed = False
        for result in with_events(track_world(sets, config), targets_of(config)):
            with sigint_deferred():
                if not posed:
                    for name, pose in rig.poses.items():
                        transform = fmt.encode_transform(name, pose, result.timestamp_ns)
                        recorder.write_protobuf(fmt.TF_TOPIC, transform, result.timestamp_ns)
                    posed = True
                if not result.background:
                    out.write_json(
                        fmt.WORLD_ESTIMATE_TOPIC, fmt.WORLD_ESTIMATE_SCHEMA, world_json(result), result.timestamp_ns
                    )
                    for event in result.events:
                        out.write_json(fmt.EVENTS_TOPIC, fmt.EVENT_SCHEMA, event.as_json(), result.timestamp_ns)
                        events[event.event] = events.get(event.event, 0) + 1
                    if writer is not None:
                        for t in result.targets:
                            writer.writerow(world_csv_row(result, t, cameras))
                        table.flush()
                    for t, w in result.targets.items():
                        counts.setdefault(t, {})[w.state] = counts.get(t, {}).get(w.state, 0) + 1
                if live is not None:
                    live.publish_world(result)
            result.frameset = None
            n_background += result.background
            tracked += not result.background
            bar.update(1)
        partial = [f"{name}: {r.stats.loss_summary()}" for name, r in rig.replays.items() if r.stats.partial]
    outputs = str(args.output) + (f", {args.csv}" if args.csv is not None else "")
    print(
        f"tracked {tracked} instants ({n_background} background) of {len(cameras)} cameras "
        f"({', '.join(cameras)}) of {args.source} in world mm -> {outputs}",
        file=sys.stderr,
    )
    for t, c in counts.items():
        print(f"{t}: " + ", ".join(f"{n} {s}" for s, n in sorted(c.items())), file=sys.stderr)
    print(_events_line(events), file=sys.stderr)
    if partial:
        print("fusion-pf: warning: " + "; ".join(partial), file=sys.stderr)
        return PARTIAL_EXIT_CODE
    return 0
