"""``fusion-pf track A.mcap B.mcap ... --out-dir DIR``: track a study, one Dask task per recording.

Each recording ``NAME.mcap`` gives ``DIR/NAME.mcap`` and ``DIR/NAME.csv``,
exactly what ``fusion-pf track NAME.mcap -o DIR/NAME.mcap --csv DIR/NAME.csv``
writes (the task runs that command's own :func:`~fusion_pf.commands.track.run`).
Outputs are written under temporary names in DIR (``.NAME.partial.*``) and
renamed when complete, then ``DIR/NAME.done.json`` records the input's SHA-256,
the tracker settings and the recording's summary row: a rerun skips a
recording whose record matches (same input bytes, same settings, outputs
present) and tracks the others. A recording that cannot be tracked is a row of
the summary (``failed``), not the end of the study. The study summary is
``DIR/study.csv`` and ``DIR/study.md``.

Distribution reuses the sweeps' Dask set-up
(:func:`fusion_pf.experiments.sweep.dask_client`): a local cluster of
``--workers`` processes, or an existing cluster with ``--scheduler``;
``--workers 1`` runs in this process.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import glob
import io
import json
import os
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fusion_pf.errors import FusionPFError, InputError
from fusion_pf.options import option, validate

from ._options import check_cluster, scheduler_option, workers_option

#: Columns of ``study.csv`` (and of ``study.md``).
SUMMARY_COLUMNS = (
    "recording",
    "status",
    "frames",
    "coverage",
    "tracking",
    "lost",
    "uninitialised",
    "reacquisitions",
    "losses",
    "skipped",
    "ms_per_frame",
    "task_s",
    "input_sha256",
)
#: Per-target columns of a study of several targets (``<target>_coverage``, ...), before ``input_sha256``.
TARGET_COLUMNS = ("coverage", "tracking", "lost", "uninitialised", "reacquisitions")
#: Suffix of the record a finished recording leaves in DIR.
DONE_SUFFIX = ".done.json"
#: Options of a single run that a study sets itself, per recording.
SINGLE_ONLY = ("output", "csv", "export_ply", "serve", "rerun", "realtime")


def _check_dir(label: str, value: Any) -> Path:
    path = Path(value)
    if path.exists() and not path.is_dir():
        raise InputError(f"{label} {path} is a file; expected a directory")
    if not path.parent.is_dir():
        raise InputError(f"{label}: parent directory {path.parent} does not exist")
    return path


@dataclass(frozen=True)
class StudyOptions:
    """The options of tracking several recordings (``--out-dir``), validated on construction."""

    out_dir: Path | None = option(
        None,
        kind="any",
        optional=True,
        parse=Path,
        check=_check_dir,
        metavar="DIR",
        show=lambda v: "one recording, -o",
        help="track every recording given (files, folders of .mcap files, globs) into DIR/NAME.mcap and "
        "DIR/NAME.csv, as Dask tasks, with a study summary DIR/study.csv and study.md; finished recordings "
        "are skipped on a rerun",
    )
    workers: int | None = workers_option(
        "study: worker processes of the local Dask cluster; 1: in this process (not with --scheduler)"
    )
    scheduler: str | None = scheduler_option("study: track on this existing Dask scheduler instead of a local cluster")

    def __post_init__(self) -> None:
        validate(self)
        check_cluster(self.workers, self.scheduler)


def recordings(items: list[str]) -> list[Path]:
    """The recordings named by ``items``: files, folders (their ``*.mcap``) and glob patterns, in order, once each."""
    out: list[Path] = []
    for item in items:
        path = Path(item)
        if path.is_dir():
            found = sorted(p for p in path.glob("*.mcap") if not p.name.startswith("."))
            if not found:
                raise InputError(f"folder {item} has no .mcap recordings")
        elif any(c in item for c in "*?["):
            found = [Path(p) for p in sorted(glob.glob(item))]
            if not found:
                raise InputError(f"pattern {item!r} matches no file")
        elif path.is_file():
            found = [path]
        else:
            raise InputError(f"{item} is not a recording file, a folder or a pattern; expected recordings to track")
        out.extend(p for p in found if p not in out)
    stems: dict[str, Path] = {}
    for p in out:
        if p.stem in stems:
            raise InputError(f"{stems[p.stem]} and {p} would both be tracked into {p.stem}.mcap; rename one")
        stems[p.stem] = p
    return out


def summary_columns(targets: tuple[str, ...] | None) -> tuple[str, ...]:
    """Columns of ``study.csv``: :data:`SUMMARY_COLUMNS`, with several targets also :data:`TARGET_COLUMNS` per target."""
    if targets is None or len(targets) < 2:
        return SUMMARY_COLUMNS
    per_target = tuple(f"{t}_{c}" for t in targets for c in TARGET_COLUMNS)
    return SUMMARY_COLUMNS[:-1] + per_target + SUMMARY_COLUMNS[-1:]


def _track_counts(states: list[str], covered: int) -> dict:
    """Coverage (frames with an estimate / frames), frames per state, re-acquisitions and losses of one track."""
    pairs = list(zip(states, states[1:]))
    return {
        "coverage": round(covered / len(states), 4) if states else 0.0,
        "tracking": states.count("tracking"),
        "lost": states.count("lost"),
        "uninitialised": states.count("uninitialised"),
        "reacquisitions": pairs.count(("lost", "tracking")),
        "losses": pairs.count(("tracking", "lost")),
    }


def _summary_row(name: str, outputs: tuple[Path, Path], seconds: float, skipped: str, sha: str, status: str) -> dict:
    """Frames, coverage, states, re-acquisitions, losses and time per frame of a tracked recording (from its outputs).

    ``ms_per_frame`` is the tracker's own time (decode, cues, filter: the
    estimates' ``latency_ns["total"]``), ``task_s`` the task's wall time.
    A several-target CSV (``<target>_state`` columns) gives each target's
    :data:`TARGET_COLUMNS` and pooled values: coverage over every target's
    frames, state frames and re-acquisitions summed over the targets.
    """
    from drivers.tracker_topics import read_json_topic

    with open(outputs[1], newline="", encoding="ascii") as fh:
        reader = csv.DictReader(fh)
        rows = list(reader)
        header = reader.fieldnames or []
    totals = [m["latency_ns"].get("total", 0) for _, m in read_json_topic(outputs[0], "/tracker/estimate")]
    targets = [c[: -len("_state")] for c in header if c.endswith("_state")]
    if not targets:
        pooled = _track_counts([r["state"] for r in rows], sum(r["u"] != "" for r in rows))
        per_target = {}
    else:
        each = {
            t: _track_counts([r[f"{t}_state"] for r in rows], sum(r[f"{t}_u"] != "" for r in rows)) for t in targets
        }
        pooled = {k: sum(c[k] for c in each.values()) for k in each[targets[0]] if k != "coverage"}
        pooled["coverage"] = round(sum(c["coverage"] for c in each.values()) / len(targets), 4)
        per_target = {f"{t}_{k}": c[k] for t, c in each.items() for k in TARGET_COLUMNS}
    frames = len(rows)
    return {
        "recording": name,
        "status": status,
        "frames": frames,
        **pooled,
        **per_target,
        "skipped": skipped,
        "ms_per_frame": round(sum(totals) / 1e6 / max(len(totals), 1), 2),
        "task_s": round(seconds, 2),
        "input_sha256": sha,
    }


def _warning(text: str) -> str:
    """The loss summary ``track`` printed (``fusion-pf: warning: skipped ...``), or ""."""
    prefix = "fusion-pf: warning: "
    return next((line[len(prefix) :] for line in text.splitlines() if line.startswith(prefix)), "")


def track_recording(args: argparse.Namespace, source: str, out_dir: str, sha: str, settings: str) -> dict:
    """One study task: track ``source`` into ``out_dir`` atomically and leave its done record; its summary row.

    Runs ``fusion-pf track`` (:func:`fusion_pf.commands.track.run`) with the
    study's options, writing ``.NAME.partial.mcap`` / ``.csv``; both are
    renamed when the run ended (complete or partial), then the done record is
    written (atomically too). A failure is the row's status.
    """
    from . import track

    name = Path(source).stem
    final = Path(out_dir)
    tmp_mcap, tmp_csv = final / f".{name}.partial.mcap", final / f".{name}.partial.csv"
    single = argparse.Namespace(**vars(args))
    single.source, single.output, single.csv, single.force, single.no_progress = source, tmp_mcap, tmp_csv, True, True
    single.more_sources, single.out_dir = [], None
    err = io.StringIO()
    t0 = time.perf_counter()
    try:
        with contextlib.redirect_stderr(err):
            code = track.run(single)
    except Exception as exc:  # one recording's failure is its row, not the end of the study
        for tmp in (tmp_mcap, tmp_csv):
            tmp.unlink(missing_ok=True)
        why = str(exc) if isinstance(exc, FusionPFError) else f"{type(exc).__name__}: {exc}"
        return {"recording": name, "status": f"failed: {why}".splitlines()[0], "input_sha256": sha}
    seconds = time.perf_counter() - t0
    skipped = _warning(err.getvalue())
    row = _summary_row(name, (tmp_mcap, tmp_csv), seconds, skipped, sha, "partial" if code else "done")
    os.replace(tmp_mcap, final / f"{name}.mcap")
    os.replace(tmp_csv, final / f"{name}.csv")
    record = final / f".{name}.partial.json"
    record.write_text(json.dumps({"input_sha256": sha, "tracker": settings, "row": row}, indent=1) + "\n")
    os.replace(record, final / f"{name}{DONE_SUFFIX}")
    return row


def finished(out_dir: Path, name: str, sha: str, settings: str) -> dict | None:
    """The summary row of a recording already tracked with the same input and settings, else None."""
    try:
        record = json.loads((out_dir / f"{name}{DONE_SUFFIX}").read_text())
    except (OSError, ValueError):
        return None
    complete = (out_dir / f"{name}.mcap").is_file() and (out_dir / f"{name}.csv").is_file()
    if not complete or record.get("input_sha256") != sha or record.get("tracker") != settings:
        return None
    return record.get("row")


def _study_markdown(rows: list[dict], wall: float, workers: int, columns: tuple[str, ...]) -> str:
    lines = [
        "# Study summary",
        "",
        f"{len(rows)} recordings, {sum(r.get('frames') or 0 for r in rows)} frames, "
        f"{wall:.1f} s on {workers} worker{'s' if workers != 1 else ''}.",
        "",
        "| " + " | ".join(columns[:-1]) + " |",
        "|" + "---|" * (len(columns) - 1),
    ]
    for r in rows:
        lines.append("| " + " | ".join(str(r.get(c, "")).replace("|", "/") for c in columns[:-1]) + " |")
    return "\n".join(lines) + "\n"


def _write_summary(out_dir: Path, rows: list[dict], wall: float, workers: int, columns: tuple[str, ...]) -> None:
    for name, text in (("study.csv", None), ("study.md", _study_markdown(rows, wall, workers, columns))):
        tmp = out_dir / f".{name}.partial"
        with open(tmp, "w", newline="", encoding="utf-8") as fh:
            if text is None:
                writer = csv.DictWriter(fh, columns, lineterminator="\n", extrasaction="ignore")
                writer.writeheader()
                writer.writerows(rows)
            else:
                fh.write(text)
        os.replace(tmp, out_dir / name)


def run_study(args: argparse.Namespace, config) -> int:
    """Track every recording of the command line into ``--out-dir``; the exit status (3 when one failed or was partial)."""
    from fusion_pf.annotate.db import recording_sha256
    from fusion_pf.errors import PARTIAL_EXIT_CODE
    from fusion_pf.options import from_args

    opts = from_args(StudyOptions, args)
    if opts.out_dir is None:
        raise InputError("several recordings need --out-dir DIR (one output per recording)")
    for name in SINGLE_ONLY:
        if getattr(args, name, None) not in (None, False):
            raise InputError(f"--{name.replace('_', '-')} is for one recording; a study writes DIR/NAME.mcap and .csv")
    sources = recordings([str(args.source), *args.more_sources])
    out_dir = opts.out_dir
    if opts.scheduler is not None:  # workers elsewhere: paths that do not depend on this process's directory
        sources, out_dir = [p.resolve() for p in sources], out_dir.resolve()
    settings = json.dumps(config.settings(), sort_keys=True)
    rows: dict[str, dict] = {}
    todo: list[tuple[str, str]] = []
    for path in sources:
        sha = recording_sha256(path)
        row = finished(out_dir, path.stem, sha, settings)
        if row is not None:
            rows[path.stem] = row
        else:
            todo.append((str(path), sha))
    plan = (
        f"fusion-pf: study of {len(sources)} recordings into {out_dir}: {len(rows)} already done, {len(todo)} to track"
    )
    t0 = time.perf_counter()
    with _executor(opts, len(todo)) as executor:
        workers = executor[2]
        out_dir.mkdir(exist_ok=True)
        print(plan + (f" on {workers} worker{'s' if workers != 1 else ''}" if todo else ""), file=sys.stderr)
        _run_tasks(args, executor, todo, str(out_dir), settings, rows)
    wall = time.perf_counter() - t0
    for leftover in out_dir.glob(".*.partial.*"):  # of tasks killed with their worker and done again since
        leftover.unlink(missing_ok=True)
    ordered = [rows[p.stem] for p in sources]
    _write_summary(out_dir, ordered, wall, workers, summary_columns(config.targets))
    bad = [r for r in ordered if r["status"] != "done"]
    frames = sum(r.get("frames") or 0 for r in ordered)
    print(
        f"fusion-pf: tracked {len(todo)} recordings in {wall:.1f} s ({frames} frames in the study); "
        f"{len(bad)} failed or partial; summary {out_dir / 'study.csv'}, {out_dir / 'study.md'}",
        file=sys.stderr,
    )
    for r in bad:
        print(f"fusion-pf: warning: {r['recording']}: {r['status']} {r.get('skipped', '')}".rstrip(), file=sys.stderr)
    return PARTIAL_EXIT_CODE if bad else 0


@contextlib.contextmanager
def _executor(opts: StudyOptions, n_tasks: int) -> Iterator[tuple[Callable[..., Any], Callable[[list], Any], int]]:
    """``(submit, as_completed, workers)``: ``submit(fn, *args)`` returns a future (``.result()``).

    No task, or ``--workers 1`` without a scheduler: in this process (a task
    runs when submitted). Otherwise the sweeps' Dask set-up
    (:func:`fusion_pf.experiments.sweep.dask_client`); an unreachable
    scheduler is an :class:`InputError` before anything is written.
    """
    if n_tasks == 0 or (opts.scheduler is None and opts.workers == 1):
        yield _InProcess, iter, (1 if n_tasks else 0)
        return
    from distributed import as_completed

    from fusion_pf.experiments.sweep import dask_client

    with dask_client(opts.workers, opts.scheduler, n_tasks) as (client, workers):
        yield (lambda fn, *a: client.submit(fn, *a, pure=False)), as_completed, workers


class _InProcess:
    """A task run at once in this process, with the interface of a Dask future."""

    def __init__(self, fn: Callable[..., Any], *args: Any) -> None:
        self.value = fn(*args)

    def result(self) -> Any:
        return self.value


def _run_tasks(args, executor, todo, out_dir: str, settings: str, rows: dict[str, dict]) -> None:
    """Submit one :func:`track_recording` task per recording of ``todo`` and collect the rows as they finish."""
    from tqdm import tqdm

    submit, completed, _ = executor
    task_args = argparse.Namespace(**{k: v for k, v in vars(args).items() if k != "_run"})
    bar = tqdm(
        total=len(todo), desc="study", unit="recording", disable=True if args.no_progress else None, file=sys.stderr
    )
    with bar:
        futures = {
            submit(track_recording, task_args, source, out_dir, sha, settings): Path(source).stem
            for source, sha in todo
        }
        for fut in completed(list(futures)):
            rows[futures[fut]] = _row(fut, futures[fut])
            bar.update(1)


def _row(fut: Any, name: str) -> dict:
    """The row of a finished task; a task that failed inside (not a recording error) is a failed row too."""
    try:
        return fut.result()
    except Exception as exc:
        return {"recording": name, "status": f"failed: {type(exc).__name__}: {exc}".splitlines()[0]}
