"""``fusion-pf demo``: track and score the shipped sample recording, write figures and tables."""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass
from pathlib import Path

from fusion_pf.experiments.paper import PAPER_PARTICLE_COUNTS
from fusion_pf.options import add_options, from_args, validate
from fusion_pf.pipeline.config import TrackConfig

from ._options import counts_option, runs_option, workers_option

NAME = "demo"
HELP = "track + score the sample recording (recordings/sample.mcap): figures 8-10 and tables"
DESCRIPTION = (
    "Track the shipped synthetic sample recording, score it against its ground truth and sweep the "
    "particle count with multi-execution (paper 003 §4.4-4.6). The tracked output (OUT/tracked.csv) "
    "is what 'fusion-pf track' gives with the default settings (cue window on the filter's "
    "prediction). The sweep tracks the recording again with the same settings for every particle "
    "count and run (job (N, r) is exactly 'fusion-pf track --particles N --seed job_seed'), as Dask "
    "tasks over the machine's cores. Writes to OUT: tracked.csv, "
    "errors_per_frame.png, "
    "latency_per_frame.png (Fig. 10), bestmax_vs_n.png (Fig. 8), multiexec_bestmax.png (Fig. 9), "
    "score.md and score.json; prints the Markdown report and where the files are."
)

#: The tracked output in OUT.
TRACKED_CSV = "tracked.csv"
#: Where the sample recording lives, relative to the repository root.
SAMPLE = Path("recordings") / "sample.mcap"


@dataclass(frozen=True)
class DemoOptions:
    """The sweep options of ``fusion-pf demo`` (validated on construction)."""

    sweep: tuple[int, ...] = counts_option(PAPER_PARTICLE_COUNTS, help="particle counts of the sweep (paper 003 §4.4)")
    runs: int = runs_option()
    workers: int | None = workers_option("worker processes of the sweep's local Dask cluster; 1: in this process")

    def __post_init__(self) -> None:
        validate(self)


#: The tracker options of the tracked output (and of the sweep), as ``fusion-pf track`` has them.
TRACK_OPTIONS = ("particles", "seed", "cue_noise_px")
#: The config classes whose flags the command registers (of TrackConfig only TRACK_OPTIONS).
CONFIGS = (DemoOptions, TrackConfig)


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Register the options of ``fusion-pf demo``."""
    p.add_argument("--out", type=Path, default=Path("out") / "demo", metavar="DIR", help="output directory")
    p.add_argument(
        "--recording",
        type=Path,
        default=None,
        metavar="REC.mcap",
        help=f"recording with ground truth; not given: {SAMPLE} of the repository",
    )
    add_options(p, DemoOptions)
    add_options(
        p, TrackConfig, exclude=[f.name for f in dataclasses.fields(TrackConfig) if f.name not in TRACK_OPTIONS]
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bars on stderr")


def find_sample(recording: Path | None) -> Path:
    """The recording to use: ``recording``, else ``recordings/sample.mcap`` here or in the repository."""
    from fusion_pf.errors import InputError

    if recording is not None:
        if not recording.is_file():
            raise InputError(f"--recording {recording} does not exist; expected an MCAP recording with ground truth")
        return recording
    import fusion_pf

    for candidate in (SAMPLE, Path(fusion_pf.__file__).resolve().parents[1] / SAMPLE):
        if candidate.is_file():
            return candidate
    raise InputError(
        f"sample recording {SAMPLE} not found (run from the repository root); pass --recording REC.mcap "
        "(make one with: fusion-pf record synth:seed=1,frames=200,background_frames=10 REC.mcap)"
    )


def run(args: argparse.Namespace) -> int:
    """Run the demo; returns the exit status."""
    import sys
    import time

    import numpy as np
    from tqdm import tqdm

    from drivers import ReplaySource, open_source
    from drivers.tracker_topics import read_topic
    from fusion_pf.errors import InputError
    from fusion_pf.experiments import run_sweep
    from fusion_pf.frame import SOURCES
    from fusion_pf.pipeline import TrackCsv, track
    from fusion_pf.score.evaluate import REPORT_FILES, evaluate, markdown, write_report
    from fusion_pf.score.inputs import align, read_ground_truth

    from ._paths import check_folder_outputs

    t_start = time.perf_counter()
    opts = from_args(DemoOptions, args)
    config = from_args(TrackConfig, args, cues=SOURCES)
    counts = opts.sweep
    if args.out.exists() and not args.out.is_dir():
        raise InputError(f"--out {args.out} is a file; expected a directory")
    recording = find_sample(args.recording)
    check_folder_outputs(args.out, (TRACKED_CSV, *REPORT_FILES), (recording,), "--out")
    reference = read_ground_truth(recording, read_topic)
    args.out.mkdir(parents=True, exist_ok=True)

    log = sys.stderr
    bar = {"unit": "frame", "disable": True if args.no_progress else None, "file": log}
    tracked = args.out / TRACKED_CSV
    print(f"demo: tracking {recording} -> {tracked}", file=log)
    with open_source(str(recording)) as src:
        n_frames = len(src) if isinstance(src, ReplaySource) else None
        frames = list(tqdm(src, total=n_frames, desc="decode", **bar))
    with TrackCsv(tracked, latency=True, sources=SOURCES) as table:
        for result in track(tqdm(frames, desc="track", **bar), config):
            table.write(result)
    ev = evaluate(tracked, reference)
    t_track = time.perf_counter() - t_start

    print(f"demo: tracking again for N = {', '.join(map(str, counts))} with {opts.runs} runs each", file=log)
    person = [(i, f) for i, f in enumerate(frames) if not f.background]
    uv, _ = align(
        np.array([i for i, _ in person], dtype=np.int64),
        np.array([f.timestamp_ns for _, f in person], dtype=np.int64),
        reference,
        name=str(recording),
    )
    sweep = run_sweep(
        frames, config, uv, counts, opts.runs, seed=config.seed, workers=opts.workers, progress=not args.no_progress
    )
    files = write_report(ev, args.out, sweep)
    figures = [str(p) for name, p in files.items() if name.endswith(".png")]
    print(markdown(ev, sweep, figures))
    total = time.perf_counter() - t_start
    print(f"Wrote {tracked} and {', '.join(str(p) for p in files.values())}")
    print(
        f"Demo took {total:.1f} s (tracking {t_track:.1f} s, sweep {sweep.wall_seconds:.1f} s on "
        f"{sweep.workers} worker(s)); figures and tables are in {args.out}"
    )
    return 0
