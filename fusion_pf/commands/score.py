"""``fusion-pf score``: accuracy of a tracker output against a reference (paper 003 §4.4-4.6)."""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

from fusion_pf.errors import InputError
from fusion_pf.experiments.paper import PAPER_PARTICLE_COUNTS
from fusion_pf.options import add_options, from_args, option, validate
from fusion_pf.score.metrics import TIE_TOL_PX
from fusion_pf.score.targets import SINGLE_PALM_TARGET

from ._options import check_cluster, counts_option, runs_option, scheduler_option, workers_option

NAME = "score"
HELP = "RMSE, coverage, p95 and BestMax of a tracker output; particle-count sweeps and figures"
DESCRIPTION = (
    "Score a tracker output (the CSV of 'fusion-pf track --csv' or its MCAP) against a reference: "
    "operator annotations (--reference annotations.sqlite, mean of the operators per frame) or the "
    "ground truth of a synthetic recording (--ground-truth REC.mcap). Per source (colour, depth, "
    "skeleton, fused estimate): RMSE, mean, p95 and max error in pixels, coverage, and BestMax "
    "(paper 003 §4.4: per frame the source closest to the reference scores a point; tied sources "
    "each score; missing sources and frames without a reference cannot). With --sweep the recording "
    "is tracked again, with the tracker settings stored in TRACKED.mcap, for every particle count and "
    "--runs seeds (multi-execution, §4.5), as Dask tasks on a local cluster or on --scheduler. With --plots DIR the figures (errors per frame, latency per frame, BestMax "
    "vs N, multi-execution BestMax) and score.md / score.json are written to DIR. Prints the "
    "Markdown report (or JSON with --json) on stdout."
)


@dataclass(frozen=True)
class ScoreOptions:
    """The scoring and sweep options of ``fusion-pf score`` (validated on construction)."""

    tie_tol: float = option(
        TIE_TOL_PX,
        kind="float",
        lo=0.0,
        hi=1000.0,
        unit="px",
        metavar="PX",
        help="BestMax: errors within this many pixels of the best tie (each tied source scores)",
    )
    sweep: tuple[int, ...] | None = counts_option(
        None,
        const=PAPER_PARTICLE_COUNTS,
        help="re-run the filter for these particle counts (alone: the paper's "
        f"{','.join(map(str, PAPER_PARTICLE_COUNTS))})",
    )
    runs: int = runs_option()
    seed: int = option(
        0,
        kind="int",
        lo=0,
        hi=2**63 - 1,
        metavar="S",
        help="base seed; run r of count N uses SeedSequence([seed, N, r])",
    )
    workers: int | None = workers_option(
        "worker processes of the local Dask cluster; 1: in this process (not with --scheduler)"
    )
    scheduler: str | None = scheduler_option("run the sweep on this existing Dask scheduler instead of a local cluster")
    target: str | None = option(
        None,
        kind="str",
        optional=True,
        metavar="NAME",
        show=lambda v: SINGLE_PALM_TARGET,
        help="a several-target output against a single-palm --ground-truth (one palm, no target names): "
        "the target it scores",
    )

    def __post_init__(self) -> None:
        validate(self)
        check_cluster(self.workers, self.scheduler)


#: The fields shown under the sweep heading of ``--help``.
SWEEP_OPTIONS = ("sweep", "runs", "seed", "workers", "scheduler")
SWEEP_TITLE = "particle-count sweep (paper 003 §4.4-4.5)"
#: The config classes whose flags the command registers.
CONFIGS = (ScoreOptions,)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf score``."""
    p.add_argument(
        "tracked",
        metavar="TRACKED",
        help="tracker output: TRACKED.csv or TRACKED.mcap, or the --out-dir folder of a study (with --ground-truth "
        "a folder of the recordings: per recording and pooled)",
    )
    ref = p.add_mutually_exclusive_group(required=True)
    ref.add_argument("--reference", metavar="DB", help="annotations SQLite database (fusion-pf annotate)")
    ref.add_argument(
        "--ground-truth",
        metavar="REC.mcap",
        help="recording with /ground_truth/palm (synthetic); for a study, the folder of its recordings",
    )
    p.add_argument("--plots", metavar="DIR", help="write the PNG figures, score.md and score.json to DIR")
    p.add_argument("--json", action="store_true", help="print the report as JSON instead of Markdown")
    add_options(p, ScoreOptions, exclude=SWEEP_OPTIONS)
    add_options(p, ScoreOptions, exclude=("tie_tol", "target"), title=SWEEP_TITLE)
    p.add_argument(
        "--recording",
        metavar="SOURCE",
        help="recording to re-track for the sweep; not given: the input named in TRACKED.mcap's "
        "metadata (key 'source'), else the --ground-truth recording. The sweep uses the tracker "
        "settings stored in TRACKED.mcap (defaults for a CSV)",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


#: The figure of a multi-target score in --plots DIR.
TARGETS_FIGURE = "targets.png"


def sweep_recording(recording: str, reference, config, counts, args, opts: ScoreOptions):
    """Decode ``recording``, align the reference to its tracked frames and run the sweep."""
    import numpy as np

    from drivers import open_source
    from fusion_pf.experiments import job_config, run_sweep
    from fusion_pf.score.inputs import align

    from .track import load_background

    for n in counts:
        job_config(config, opts.seed, n, 0)
    with open_source(str(recording)) as src:
        frames = list(src)
    person = [(i, f) for i, f in enumerate(frames) if not f.background]
    frame = np.array([i for i, _ in person], dtype=np.int64)
    ts = np.array([f.timestamp_ns for _, f in person], dtype=np.int64)
    uv, _ = align(frame, ts, reference, name=f"{recording} (re-tracked for the sweep)")
    background = None if config.background is None else load_background(config.background)
    return run_sweep(
        frames,
        config,
        uv,
        counts,
        opts.runs,
        seed=opts.seed,
        background=background,
        workers=opts.workers,
        scheduler=opts.scheduler,
        progress=not args.no_progress,
        tie_tol=opts.tie_tol,
    )


def _score_events(args: argparse.Namespace, result: dict, read_topic):
    """The tracked events against the recording's ``/ground_truth/events`` (None without them), added to ``result``."""
    from fusion_pf.score.events import DEFAULT_TOLERANCE, events_json, match_events, read_events

    truth = read_events(args.ground_truth, "true_events", read_topic)
    if truth is None:
        return None
    events = match_events(truth, read_events(args.tracked, "events", read_topic) or [])
    result["events"] = events_json(events, DEFAULT_TOLERANCE)
    return events


def _print_events(events) -> None:
    """The events line of the Markdown report."""
    from fusion_pf.score.events import DEFAULT_TOLERANCE

    if events is not None:
        print(f"\nEvents (within {DEFAULT_TOLERANCE} frames of /ground_truth/events): {events.summary()}")


def _score_targets(table, args: argparse.Namespace, target: str | None, read_topic) -> int:
    """A multi-target CSV (``track --targets``): per-target accuracy, states and identity swaps."""
    from drivers.tracker_topics import frame_size
    from fusion_pf.score.targets import score_targets_recording, targets_markdown

    result = score_targets_recording(table, args.ground_truth, read_topic, frame_size, target)
    if result["single_palm"] is not None:
        print(
            f"fusion-pf score: {args.ground_truth} holds one palm; scoring target {result['single_palm']} "
            f"of {', '.join(table.uv)}",
            file=sys.stderr,
        )
    errors = result.pop("errors")
    events = _score_events(args, result, read_topic)
    if args.plots is not None:
        from fusion_pf.score.plots import plot_targets

        figure = plot_targets(errors, table.states, Path(args.plots) / TARGETS_FIGURE)
        print(f"fusion-pf score: wrote {figure}", file=sys.stderr)
    if args.json:
        print(json.dumps(result, indent=1, default=lambda x: None))
    else:
        print(targets_markdown(result, args.tracked, args.ground_truth), end="")
        _print_events(events)
    return 0


def _score_world(table, args: argparse.Namespace, read_topic) -> int:
    """A multi-camera run (``track MULTI.mcap``): 3-D RMSE per target against ``/ground_truth/world``, and its events."""
    from fusion_pf.score.targets import score_world_recording, world_markdown

    if args.plots is not None or args.reference is not None or from_args(ScoreOptions, args).sweep is not None:
        raise InputError(f"{args.tracked} is a multi-camera run: score it with --ground-truth MULTI.mcap only")
    result = score_world_recording(table, args.ground_truth, read_topic)
    result.pop("errors")
    events = _score_events(args, result, read_topic)
    if args.json:
        print(json.dumps(result, indent=1, default=lambda x: None))
    else:
        print(world_markdown(result, args.tracked, args.ground_truth), end="")
        _print_events(events)
    return 0


def _score_study(args: argparse.Namespace, opts: ScoreOptions, read_topic) -> int:
    """A study's output folder against a folder of recordings with ground truth: per recording and pooled."""
    from fusion_pf.score.study import score_study, study_markdown

    if args.ground_truth is None or opts.sweep is not None or args.plots is not None or args.json:
        raise InputError(
            f"{args.tracked} is a folder: score a study with --ground-truth REF_DIR (no --reference, --sweep, "
            "--plots or --json)"
        )
    from drivers.tracker_topics import frame_size

    study = score_study(
        args.tracked, args.ground_truth, read_topic=read_topic, frame_size=frame_size, tie_tol=opts.tie_tol
    )
    print(study_markdown(study, args.tracked, args.ground_truth), end="")
    return 0


def run(args: argparse.Namespace) -> int:
    """Score, optionally sweep, write and print the report; returns the exit status."""
    from drivers.tracker_topics import find_source, read_topic, recording_metadata
    from fusion_pf.pipeline import TrackConfig
    from fusion_pf.score.evaluate import REPORT_FILES, as_json, evaluate, markdown, read_reference, write_report
    from fusion_pf.score.inputs import file_kind

    from ._paths import SQLITE_SIDECARS, check_folder_outputs

    opts = from_args(ScoreOptions, args)
    counts = opts.sweep
    if Path(args.tracked).is_dir():
        return _score_study(args, opts, read_topic)
    needs_meta = args.plots is not None or args.reference is not None or counts is not None
    meta = recording_metadata(args.tracked) if needs_meta and file_kind(args.tracked) == "mcap" else {}
    source = find_source(args.tracked, meta)
    if args.plots is not None:
        db_files = [] if args.reference is None else [args.reference + s for s in ("", *SQLITE_SIDECARS)]
        inputs = (args.tracked, args.ground_truth, args.recording, source, *db_files)
        check_folder_outputs(Path(args.plots), (*REPORT_FILES, TARGETS_FIGURE), inputs, "--plots")
    if args.ground_truth is not None:
        from fusion_pf.score.targets import read_targets, read_world

        world = read_world(args.tracked, read_topic)
        if world is not None:
            return _score_world(world, args, read_topic)

        table = read_targets(args.tracked, read_topic)
        if table is not None:
            if counts is not None:
                raise InputError(
                    f"--sweep scores one target, but {args.tracked} holds several ({', '.join(table.uv)}); "
                    "sweep a run of one target (track without --targets, or --targets NAME)"
                )
            return _score_targets(table, args, opts.target, read_topic)
    if opts.target is not None:
        raise InputError(
            f"--target chooses the target of a several-target output scored against a single-palm --ground-truth; "
            f"{args.tracked} is of one target"
            + ("" if args.ground_truth is not None else " or scored against --reference")
        )
    reference = read_reference(args.reference, args.ground_truth, read_topic)
    ev = evaluate(args.tracked, reference, tie_tol=opts.tie_tol, read_topic=read_topic)
    if args.reference is not None:
        from fusion_pf.annotate.db import check_reference_matches

        check_reference_matches(
            args.reference,
            ev.table.frame.tolist(),
            ev.table.timestamp_ns.tolist(),
            source_sha256=meta.get("source_sha256"),
            what=str(args.tracked),
        )
    sweep = None
    if counts is not None:
        recording = args.recording or (str(source) if source else meta.get("source")) or args.ground_truth
        if recording is None:
            raise InputError("--sweep with a tracker CSV and --reference needs --recording SOURCE to re-track")
        try:
            settings = json.loads(meta.get("tracker", "{}"))
        except ValueError:
            raise InputError(f"{args.tracked}: its tracker settings are not valid JSON") from None
        config = TrackConfig.from_settings(settings if isinstance(settings, dict) else {})
        sweep = sweep_recording(recording, reference, config, counts, args, opts)
    figures: list[str] = []
    if args.plots is not None:
        files = write_report(ev, args.plots, sweep)
        figures = [str(p) for name, p in files.items() if name.endswith(".png")]
        print(f"fusion-pf score: wrote {', '.join(str(p) for p in files.values())}", file=sys.stderr)
    if args.json:
        print(json.dumps(as_json(ev, sweep, figures), indent=1))
    else:
        print(markdown(ev, sweep, figures), end="")
    return 0
