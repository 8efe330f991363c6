"""``fusion-pf track``: track the palm through a recording or a live source (paper 003)."""

from __future__ import annotations

import argparse
from pathlib import Path

from drivers import SOURCE_SPECS
from drivers.live import LiveOptions
from fusion_pf.cues.registry import CueOptions
from fusion_pf.pipeline import TrackConfig
from fusion_pf.text import printable

from ._study import StudyOptions

NAME = "track"
HELP = "track the palm (data-fusion particle filter or Kalman baseline) and write MCAP/CSV outputs"
DESCRIPTION = (
    "Track the palm centre through SOURCE by fusing the cues (by default the colour cue, the depth "
    "cue -- paper 003 §3.5, background subtraction in a window around a prior -- and the skeleton "
    "joint) in a particle filter (or the Kalman baseline). OUT.mcap gets /tracker/estimate, "
    "/tracker/cues, /tracker/overlay and /tracker/particles (docs/recording-format.md, 'Tracker "
    "outputs') and /tracker/events (interaction events: joins, contacts, losses, carried objects) and names the input recording in its metadata (key 'source'); Foxglove and Rerun "
    "open the two files together. --copy-input also copies every input frame into OUT.mcap. "
    "--csv writes one row per tracked frame (docs/architecture.md, 'CSV'). The background model "
    "comes from --background, else the recording's own background frames, else the median of its "
    "first --background-k frames. Pixels are colour-image pixels, 3-D points camera-frame "
    "millimetres. The same --seed gives a byte-identical CSV (latency columns are left empty unless "
    "--csv-latency). Outputs are finalised on Ctrl-C (exit 130), SIGTERM (143), SIGHUP (129) and errors (exit 2). A damaged "
    "recording is tracked as far as it can be read: the frames skipped and why are printed and the "
    "exit status is 3 (partial). A multi-camera recording (fusion-pf synth --cameras, merge) is tracked in world "
    "millimetres (one 3-D particle filter per target fed by every camera's cues): the CSV has one row per instant "
    "and target (x_mm, y_mm, z_mm, sigma_mm, the cameras that measured it, u, v per camera) and OUT.mcap gets "
    "/tracker/world, /tracker/events (joins, contacts, losses, carried objects decided in world mm) and the camera "
    "poses on /tf; --serve and --rerun show every camera, the poses and the targets live."
)


#: The config classes whose flags the command registers.
CONFIGS = (TrackConfig, CueOptions, LiveOptions, StudyOptions)

#: File name of each ``--export-ply`` point cloud.
PLY_NAME = "frame_{frame}.ply"
#: ``--color-format`` values.
COLOR_FORMATS = ("auto", "raw", "jpeg", "png")


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf track``: the command's own, then the pipeline's and the cues'."""
    from fusion_pf.options import add_options

    p.add_argument("source", metavar="SOURCE", help=f"what to track: {SOURCE_SPECS}")
    p.add_argument("more_sources", nargs="*", metavar="SOURCE", help="more recordings to track (with --out-dir)")
    p.add_argument(
        "-o",
        "--output",
        type=Path,
        metavar="OUT.mcap",
        help="MCAP file to write (tracker topics; with --copy-input also the input frames)",
    )
    p.add_argument("--csv", type=Path, metavar="OUT.csv", help="also write the per-frame CSV")
    p.add_argument(
        "--csv-latency",
        action="store_true",
        help="fill the CSV's latency_*_ms columns (wall time: the CSV is then not byte-identical across runs)",
    )
    p.add_argument(
        "--copy-input",
        action="store_true",
        help="also copy every input frame (colour, depth, calibration, skeleton, ground truth) into OUT.mcap",
    )
    p.add_argument(
        "--export-ply",
        type=Path,
        metavar="DIR",
        help="write the ROI point cloud of every tracked frame (mm, camera frame) as DIR/frame_NNNNNN.ply",
    )
    p.add_argument(
        "--color-format",
        default="auto",
        metavar="auto|raw|jpeg|png",
        help="colour encoding of copied frames (auto: as the input recording, raw otherwise)",
    )
    p.add_argument("--force", action="store_true", help="overwrite OUT.mcap / OUT.csv if they exist")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    add_options(p, TrackConfig, title="tracker")
    add_options(p, CueOptions, title="cues")
    add_options(p, LiveOptions, title="live view (Foxglove, Rerun)")
    add_options(p, StudyOptions, title="study: several recordings as Dask tasks")


def config_from_args(args: argparse.Namespace):
    """The :class:`~fusion_pf.pipeline.TrackConfig` of the command line (InputError on bad values)."""
    from fusion_pf.options import from_args

    return from_args(TrackConfig, args, cue_options=from_args(CueOptions, args))


def load_background(path: Path):
    """The background model of the empty-scene recording ``path`` (its background frames, else all)."""
    from drivers.mcap_replay import McapReplay
    from fusion_pf.cues.background import BackgroundModel
    from fusion_pf.errors import InputError

    with McapReplay(Path(path)) as rec:
        frames = list(rec)
    if not frames:
        raise InputError(f"background recording {path} has no frames")
    return BackgroundModel.from_frames([f for f in frames if f.background] or frames)


def _check_outputs(args: argparse.Namespace, config) -> None:
    from fusion_pf.errors import InputError

    from ._paths import check_distinct, check_folder_outputs, check_output

    inputs = (args.source, config.background)
    outputs = [("output", args.output)] + ([("--csv", args.csv)] if args.csv is not None else [])
    for what, out in outputs:
        check_output(out, force=args.force, what=what, inputs=inputs)
    check_distinct(outputs)
    if args.export_ply is not None:
        if args.export_ply.exists() and not args.export_ply.is_dir():
            raise InputError(f"--export-ply {args.export_ply} is a file; expected a directory")
        if not args.export_ply.parent.is_dir():
            raise InputError(f"--export-ply parent directory {args.export_ply.parent} does not exist")
        check_folder_outputs(
            args.export_ply, [PLY_NAME.format(frame="*")], inputs + (args.output, args.csv), "--export-ply"
        )
    if config.background is not None and not config.background.is_file():
        raise InputError(f"--background {config.background} does not exist; expected an empty-scene .mcap recording")


def _recorder_options(src, args: argparse.Namespace) -> dict:
    """Colour/depth encodings and metadata of the output, following the input recording."""
    from drivers.tracker_topics import source_metadata
    from fusion_pf.errors import InputError

    options: dict = {
        "color_format": "raw",
        "depth_format": "raw",
        "metadata": source_metadata(args.source, args.output),
    }
    info = src.info() if callable(getattr(src, "info", None)) else None
    if info is not None:
        options["color_format"] = {"jpeg": "jpeg", "png": "png"}.get(info.color_format or "", "raw")
        options["depth_format"] = "png" if info.depth_format == "png" else "raw"
        mine = ("background_frames", "format_version", "writer", "source", "source_relative")
        keep = {k: v for k, v in info.metadata.items() if k not in mine}
        options["metadata"] = {**keep, **options["metadata"]}
    elif callable(getattr(src, "metadata", None)):
        options["metadata"] = {**src.metadata(), **options["metadata"]}
    if args.color_format != "auto":
        options["color_format"] = args.color_format
    for key, value in options["metadata"].items():
        if not isinstance(value, str):
            raise InputError(f"source metadata {key!r} must be a string, got {value!r}")
    return options


def _tracked_line(tracked: int, n_background: int, src, args: argparse.Namespace) -> str:
    """The summary line: frames tracked, background frames read and (when any) background frames lost."""
    stats = getattr(src, "stats", None)
    lost = getattr(stats, "lost_background", 0)
    background = f"{n_background} background" + (f", {lost} background lost" if lost else "")
    return f"tracked {tracked} frames ({background}) of {printable(args.source)} -> {printable(args.output)}" + (
        f", {printable(args.csv)}" if args.csv is not None else ""
    )


def _events_line(events: dict[str, int]) -> str:
    """The summary line of the interaction events (``/tracker/events``), counted per event."""
    if not events:
        return "events: none"
    return "events: " + ", ".join(f"{n} {e}" for e, n in sorted(events.items()))


def _track_targets(src, frames, config, args: argparse.Namespace, recorder, table, background, bar, live) -> int:
    """Several targets (``--targets``): the same pipeline, its per-target CSV rows and ``/tracker/estimate`` messages.

    ``frames`` are those of ``src`` (paced with ``--realtime``); with a live view (``live``) the frame and
    every tracker message go to it as in a one-target run.
    """
    import csv
    import sys

    from drivers.tracker_topics import TrackerTopics
    from fusion_pf.errors import PARTIAL_EXIT_CODE
    from fusion_pf.pipeline import track
    from fusion_pf.pipeline.outputs import targets_csv_columns, targets_csv_row
    from fusion_pf.signals import sigint_deferred

    writer = None if table is None else csv.writer(table, lineterminator="\n")
    if writer is not None:
        writer.writerow(targets_csv_columns(config.targets))
    topics = TrackerTopics(recorder if live is None else live.tee(recorder), config)
    counts: dict[str, dict[str, int]] = {t: {} for t in config.targets}
    events: dict[str, int] = {}
    tracked = n_background = 0
    for result in track(frames, config, background=background):
        with sigint_deferred():
            assert result.source_frame is not None
            if args.copy_input:
                recorder.write(result.source_frame)
            topics.write(result)
            if live is not None:
                live.publish(result, result.source_frame)
            if not result.background:
                if writer is not None:
                    writer.writerow(targets_csv_row(result))
                    table.flush()
                for t, r in result.targets.items():
                    counts[t][r.state] = counts[t].get(r.state, 0) + 1
                for e in result.events:
                    events[e.event] = events.get(e.event, 0) + 1
        result.source_frame = None
        n_background += result.background
        tracked += not result.background
        bar.update(1)
    print(_tracked_line(tracked, n_background, src, args), file=sys.stderr)
    for t, c in counts.items():
        print(f"{t}: " + ", ".join(f"{n} {s}" for s, n in sorted(c.items())), file=sys.stderr)
    print(_events_line(events), file=sys.stderr)
    stats = getattr(src, "stats", None)
    if stats is not None and stats.partial:
        print(f"fusion-pf: warning: {stats.loss_summary()}", file=sys.stderr)
        return PARTIAL_EXIT_CODE
    return 0


def run(args: argparse.Namespace) -> int:
    """Track SOURCE, writing OUT.mcap (and the CSV / PLY files); returns the exit status."""
    import json
    import sys
    import time
    from contextlib import ExitStack

    from tqdm import tqdm

    from drivers import ReplaySource, open_source
    from drivers.live import Live, paced
    from drivers.mcap_record import McapRecorder
    from drivers.tracker_topics import TrackerTopics
    from fusion_pf.annotate.db import recording_sha256
    from fusion_pf.errors import PARTIAL_EXIT_CODE, InputError
    from fusion_pf.geometry import write_roi_ply
    from fusion_pf.options import from_args
    from fusion_pf.pipeline import STATES, TrackCsv, TrackStats, track
    from fusion_pf.signals import sigint_deferred

    config = config_from_args(args)
    live_options = from_args(LiveOptions, args)
    if args.more_sources or getattr(args, "out_dir", None) is not None:
        from ._study import run_study

        return run_study(args, config)
    if args.output is None:
        raise InputError("track needs -o OUT.mcap (or --out-dir DIR to track several recordings)")
    several = config.targets is not None and len(config.targets) > 1  # one target named is the single palm
    if config.filter == "pf":
        # the particle filter's compiled kernels load while the recording opens and the cues start
        from fusion_pf.filter.kernel import warm_up

        warm_up()
    if args.color_format not in COLOR_FORMATS:
        raise InputError(f"--color-format must be one of {', '.join(COLOR_FORMATS)}, got {args.color_format!r}")
    _check_outputs(args, config)
    if str(args.source).lower().endswith(".mcap") and Path(args.source).is_file():
        from drivers.rig import is_rig

        if is_rig(args.source):  # several cameras: tracked in world coordinates
            from ._rig_track import track_rig

            return track_rig(args, config, live_options)
    background = None if config.background is None else load_background(config.background)
    if args.export_ply is not None:
        args.export_ply.mkdir(exist_ok=True)
    tracked = n_background = 0
    states = {s: 0 for s in STATES}
    events: dict[str, int] = {}
    with open_source(args.source) as src, ExitStack() as stack:
        options = _recorder_options(src, args)
        options["metadata"]["tracker"] = json.dumps(config.settings(), sort_keys=True)
        if str(args.source).lower().endswith(".mcap") and Path(args.source).is_file():
            options["metadata"]["source_sha256"] = recording_sha256(args.source)
        table = targets_csv = None
        with sigint_deferred():  # each output is closed by the stack once it is open
            if args.csv is not None and several:  # opened first: a failing CSV leaves no MCAP
                targets_csv = stack.enter_context(open(args.csv, "w", newline="", encoding="ascii"))
            elif args.csv is not None:
                table = stack.enter_context(TrackCsv(args.csv, latency=args.csv_latency, sources=config.cues))
            recorder = stack.enter_context(McapRecorder(args.output, **options))
        total = len(src) if isinstance(src, ReplaySource) else None
        bar = stack.enter_context(
            tqdm(
                total=total,
                unit="frame",
                desc=src.describe(),
                disable=True if args.no_progress or live_options.enabled else None,
                file=sys.stderr,
            )
        )
        live = stack.enter_context(Live(live_options)) if live_options.enabled else None
        frames = paced(src) if live_options.realtime else src
        if several:
            return _track_targets(src, frames, config, args, recorder, targets_csv, background, bar, live)
        topics = TrackerTopics(recorder if live is None else live.tee(recorder), config)
        track_stats = TrackStats()
        for result in track(frames, config, background=background, stats=track_stats):
            with sigint_deferred():
                t0 = time.perf_counter_ns()
                assert result.source_frame is not None  # track() sets it on every result
                if args.copy_input:
                    recorder.write(result.source_frame)
                topics.write(result)
                if live is not None:
                    live.publish(result, result.source_frame)
                if (
                    args.export_ply is not None
                    and not result.background
                    and result.roi is not None
                    and result.source_frame.depth is not None
                ):
                    r = result.roi
                    write_roi_ply(
                        args.export_ply / PLY_NAME.format(frame=f"{result.frame:06d}"),
                        result.source_frame,
                        (r.x0, r.y0, r.x1, r.y1),
                        palm=result.xyz_mm,
                    )
                result.latency_ns["sinks"] = time.perf_counter_ns() - t0
                if table is not None:
                    table.write(result)
            result.source_frame = None
            n_background += result.background
            tracked += not result.background
            states[result.state] += not result.background
            for e in result.events:
                events[e.event] = events.get(e.event, 0) + 1
            bar.update(1)
    print(_tracked_line(tracked, n_background, src, args), file=sys.stderr)
    print(
        f"states: {states['tracking']} tracking, {states['lost']} lost, {states['uninitialised']} uninitialised; "
        f"{track_stats.reacquisitions} re-acquisitions after {track_stats.losses} losses; "
        + track_stats.cue_summary(tracked),
        file=sys.stderr,
    )
    print(_events_line(events), file=sys.stderr)
    stats = getattr(src, "stats", None)
    if stats is not None and stats.partial:
        print(f"fusion-pf: warning: {stats.loss_summary()}", file=sys.stderr)
        return PARTIAL_EXIT_CODE
    return 0
