"""Particle-count sweeps and multi-execution (paper 003 §4.4-4.5, Figures 8-9) on Dask.

Every job ``(N, r)`` runs the tracking pipeline :func:`fusion_pf.pipeline.track`
itself -- cues and filter, with exactly the configuration of ``fusion-pf
track`` except ``particles = N`` and ``seed = job_seed(seed, N, r)`` -- and is
scored against the reference. So job ``(N, r)`` writes the same CSV as
``fusion-pf track --particles N --seed job_seed(seed, N, r)``. Run 0 is the
single execution of Figure 8; the mean over runs is the multi-execution of
Figure 9.

Determinism
    Job ``(N, r)`` depends only on ``(seed, N, r)`` (:func:`job_seed`): not on
    the worker count, the order jobs finish in, or which other counts are swept.

Distribution
    Jobs are Dask tasks (``distributed``). By default a local cluster of
    worker processes (Dask starts them with ``spawn``), one per core;
    ``scheduler="tcp://HOST:PORT"`` submits to an existing Dask cluster
    instead; ``workers=1`` without a scheduler runs every job in the calling
    process. The frames are decoded once and scattered to the workers.
"""

from __future__ import annotations

import dataclasses
import math
import os
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..cues.background import BackgroundModel
from ..errors import InputError
from ..frame import Frame
from ..pipeline import TrackConfig, TrackResult, cue_names, track
from ..score.metrics import TIE_TOL_PX, score
from ..signals import sigint_deferred

__all__ = [
    "PAPER_PARTICLE_COUNTS",
    "dask_client",
    "PAPER_RUNS",
    "SweepResult",
    "job_config",
    "job_seed",
    "parse_counts",
    "result_points",
    "run_sweep",
]

from .paper import PAPER_PARTICLE_COUNTS, PAPER_RUNS


def parse_counts(text: str) -> tuple[int, ...]:
    """Parse a comma-separated list of particle counts, e.g. ``"5,10,25"``.

    Raises
    ------
    InputError
        When an item is not an integer >= 1 or a count repeats.
    """
    items = [t.strip() for t in str(text).split(",")]
    counts = []
    for t in items:
        try:
            n = int(t)
        except ValueError:
            raise InputError(f"particle counts must be comma-separated integers >= 1, got {t!r} in {text!r}") from None
        if n < 1:
            raise InputError(f"particle counts must be >= 1, got {n} in {text!r}")
        counts.append(n)
    if len(set(counts)) != len(counts):
        raise InputError(f"particle counts must not repeat, got {text!r}")
    return tuple(counts)


def job_seed(seed: int, n_particles: int, run: int) -> int:
    """The tracker seed of sweep job ``(n_particles, run)``: 63 bits of ``SeedSequence([seed, N, run])``."""
    state = np.random.SeedSequence([int(seed), int(n_particles), int(run)]).generate_state(1, np.uint64)[0]
    return int(state >> np.uint64(1))


def job_config(config: TrackConfig, seed: int, n_particles: int, run: int) -> TrackConfig:
    """The configuration of sweep job ``(n_particles, run)``: ``config`` with that N and :func:`job_seed`."""
    return dataclasses.replace(config, particles=int(n_particles), seed=job_seed(seed, n_particles, run))


def result_points(results: Sequence[TrackResult], sources: Sequence[str]) -> np.ndarray:
    """Points of every scored source from tracker results.

    Parameters
    ----------
    results : sequence of TrackResult
        Tracked (not background) frames.
    sources : sequence of str
        The computed cues, in order.

    Returns
    -------
    ndarray, shape (len(sources) + 1, n, 2)
        The cues in ``sources`` order, then the estimate (``fused``); NaN where
        a source gave nothing.
    """
    out = np.full((len(sources) + 1, len(results), 2), np.nan)
    for t, r in enumerate(results):
        for i, s in enumerate(sources):
            m = r.cues.get(s)
            if m is not None:
                out[i, t] = (m.u, m.v)
        if r.estimate is not None:
            out[len(sources), t] = (r.estimate.u, r.estimate.v)
    return out


def _run_job(
    frames: Sequence[Frame], config: TrackConfig, background: BackgroundModel | None
) -> tuple[np.ndarray, float]:
    """Track ``frames`` with ``config``; the points of the tracked frames and the wall time."""
    t0 = time.perf_counter()
    results = [r for r in track(frames, config, background=background) if not r.background]
    return result_points(results, sweep_sources(frames, config, background)), time.perf_counter() - t0


def sweep_sources(
    frames: Sequence[Frame], config: TrackConfig, background: BackgroundModel | None = None
) -> tuple[str, ...]:
    """The cues every job computes (those of the first tracked frame; the background is learnt from the
    stream without ``background`` and empty-scene frames)."""
    first = next((f for f in frames if not f.background), None)
    learnt = background is None and not any(f.background for f in frames)
    return cue_names(config, first, learnt=learnt)


@dataclass(frozen=True)
class SweepResult:
    """Scores of every ``(particle count, run)`` job.

    Attributes
    ----------
    particle_counts : tuple of int
    runs : int
    seed : int
    sources : tuple of str
        The computed cues, then ``"fused"``.
    bestmax : ndarray, shape (n_counts, runs, n_sources), int64
        BestMax of each source in each job (cues compete with that job's estimate).
    rmse : ndarray, shape (n_counts, runs, n_sources)
        RMSE in pixels of each source in each job (NaN when never scored).
    errors : ndarray, shape (n_counts, runs, n_sources, n_frames)
        Per-frame errors in pixels (NaN where not scored).
    job_seconds : ndarray, shape (n_counts, runs)
        Wall time of each job (cues and filter).
    wall_seconds : float
        Wall time of the whole sweep.
    workers : int
        Dask workers used (1 = in process).
    tie_tol : float
        BestMax tie tolerance in pixels.
    """

    particle_counts: tuple[int, ...]
    runs: int
    seed: int
    sources: tuple[str, ...]
    bestmax: np.ndarray
    rmse: np.ndarray
    errors: np.ndarray
    job_seconds: np.ndarray
    wall_seconds: float
    workers: int
    tie_tol: float

    def mean_bestmax(self) -> np.ndarray:
        """Multi-execution mean BestMax, shape (n_counts, n_sources) (Figure 9)."""
        return self.bestmax.mean(axis=1)

    def std_bestmax(self) -> np.ndarray:
        """Standard deviation over runs of BestMax, shape (n_counts, n_sources) (ddof 0)."""
        return self.bestmax.std(axis=1)

    def mean_rmse(self) -> np.ndarray:
        """Mean over runs of the RMSE in pixels, shape (n_counts, n_sources)."""
        ok = np.isfinite(self.rmse)
        n = ok.sum(axis=1)
        total = np.where(ok, self.rmse, 0.0).sum(axis=1)
        return np.where(n > 0, total / np.maximum(n, 1), np.nan)


def _check(counts: tuple[int, ...], runs: int, seed: int, workers: int | None) -> None:
    if not counts or min(counts) < 1:
        raise InputError(f"particle counts must be a non-empty list of integers >= 1, got {list(counts)}")
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 1:
        raise InputError(f"runs must be an integer >= 1, got {runs!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
        raise InputError(f"workers must be an integer >= 1, got {workers!r}")


def run_sweep(
    frames: Sequence[Frame],
    config: TrackConfig,
    reference: np.ndarray,
    particle_counts: Sequence[int] = PAPER_PARTICLE_COUNTS,
    runs: int = PAPER_RUNS,
    *,
    seed: int = 0,
    background: BackgroundModel | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    tie_tol: float = TIE_TOL_PX,
) -> SweepResult:
    """Track the frames for every particle count and run, and score each run.

    Parameters
    ----------
    frames : sequence of Frame
        The recording, decoded (background frames included).
    config : TrackConfig
        The tracker configuration; ``particles`` and ``seed`` are set per job
        (:func:`job_config`).
    reference : ndarray, shape (n, 2)
        Reference ``(u, v)`` per tracked (non-background) frame, NaN where missing.
    particle_counts : sequence of int
        Particle counts ``N`` (>= 1).
    runs : int
        Runs per count (>= 1).
    seed : int
        Base seed (>= 0).
    background : BackgroundModel, optional
        Empty-scene model, as for :func:`~fusion_pf.pipeline.track`.
    workers : int, optional
        Worker processes of the local Dask cluster (default: one per core);
        1 without ``scheduler`` runs in the calling process.
    scheduler : str, optional
        Address of an existing Dask scheduler (``tcp://HOST:PORT``).
    progress : bool
        Show a tqdm progress bar on stderr.
    tie_tol : float
        BestMax tie tolerance in pixels.

    Returns
    -------
    SweepResult
    """
    from tqdm import tqdm

    counts = tuple(int(n) for n in particle_counts)
    _check(counts, runs, seed, workers)
    frames = list(frames)
    n = sum(not f.background for f in frames)
    reference = np.asarray(reference, dtype=np.float64)
    if reference.shape != (n, 2):
        raise InputError(f"reference must have shape ({n}, 2) (one row per tracked frame), got {reference.shape}")
    for c in counts:
        job_config(config, seed, c, 0)
    sources = (*sweep_sources(frames, config, background), "fused")
    jobs = [(c, r) for c in range(len(counts)) for r in range(runs)]
    points = np.full((len(counts), runs, len(sources), n, 2), np.nan)
    seconds = np.zeros((len(counts), runs))
    # Largest counts first: the slowest jobs start early, so the workers stay busy.
    order = sorted(jobs, key=lambda j: -counts[j[0]])
    bar = tqdm(total=len(jobs), desc="sweep", unit="run", disable=not progress, file=sys.stderr)
    t0 = time.perf_counter()
    if scheduler is None and workers == 1:
        n_workers = 1
        for c, r in order:
            points[c, r], seconds[c, r] = _run_job(frames, job_config(config, seed, counts[c], r), background)
            bar.update(1)
    else:
        n_workers = _run_dask(frames, config, background, counts, order, seed, workers, scheduler, points, seconds, bar)
    bar.close()
    wall = time.perf_counter() - t0
    bestmax = np.zeros((len(counts), runs, len(sources)), dtype=np.int64)
    rmse = np.full((len(counts), runs, len(sources)), math.nan)
    errors = np.full((len(counts), runs, len(sources), n), math.nan)
    for c, r in jobs:
        s = score(dict(zip(sources, points[c, r])), reference, tie_tol=tie_tol)
        bestmax[c, r] = [s.summary[k].bestmax for k in sources]
        rmse[c, r] = [s.summary[k].rmse for k in sources]
        errors[c, r] = [s.errors[k] for k in sources]
    return SweepResult(
        particle_counts=counts,
        runs=int(runs),
        seed=int(seed),
        sources=sources,
        bestmax=bestmax,
        rmse=rmse,
        errors=errors,
        job_seconds=seconds,
        wall_seconds=wall,
        workers=n_workers,
        tie_tol=float(tie_tol),
    )


#: glibc malloc settings of the local cluster's workers. Dask sets ``MALLOC_TRIM_THRESHOLD_=65536``, which
#: also fixes the mmap threshold at 128 KiB: every frame-sized array is then a fresh mmap, page-faulted in and
#: unmapped again (a 200-frame 320x200 recording: 61 000 page faults and 0.55 s CPU per task, against 5 000 and
#: 0.37 s with these values, the calling process's figures). Arrays up to 16 MiB come from the heap, which keeps
#: up to 64 MiB of free memory.
WORKER_MALLOC = {"MALLOC_MMAP_THRESHOLD_": str(16 << 20), "MALLOC_TRIM_THRESHOLD_": str(64 << 20)}


@contextmanager
def dask_client(workers: int | None, scheduler: str | None, n_tasks: int) -> Iterator[tuple[Any, int]]:
    """A Dask client and its worker count: a local cluster of ``workers`` processes (at most ``n_tasks``), or ``scheduler``.

    The local cluster's workers are processes (one thread each, started with
    ``spawn``); both are closed on exit.

    Raises
    ------
    InputError
        When ``scheduler`` cannot be reached (within 10 s).
    """
    import logging

    import dask
    from distributed import Client, LocalCluster

    log = logging.getLogger("distributed")
    log.setLevel(logging.ERROR)
    cluster = client = None
    stopped = False
    try:
        with sigint_deferred():  # a stop request waits until the cluster is up, so that it can be closed
            if scheduler is None:
                n_workers = min(n_tasks, workers or os.cpu_count() or 1)
                # glibc reads these when a process starts: they must be in the environment the workers are spawned with
                with dask.config.set({f"distributed.nanny.pre-spawn-environ.{k}": v for k, v in WORKER_MALLOC.items()}):
                    cluster = LocalCluster(
                        n_workers=n_workers,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=None,
                        # a worker's own log (e.g. a heartbeat cut by the cluster's closing on Ctrl-C) is not the
                        # user's business: a failed task reaches the caller as its exception
                        silence_logs=logging.CRITICAL,
                    )
                client = Client(cluster)
            else:
                try:
                    client = Client(scheduler, timeout="10s")
                except (OSError, TimeoutError, ValueError) as exc:
                    raise InputError(f"cannot reach the Dask scheduler {scheduler!r}: {exc}") from None
        yield client, len(client.scheduler_info(n_workers=-1)["workers"]) or 1
    except KeyboardInterrupt:
        # a signal or Ctrl-C (Terminated is one): the process ends. A request the in-process scheduler was serving
        # when its workers closed (a scatter: KeyError of the removed worker's address) fails in an asyncio task
        # nobody awaits, which asyncio reports with a traceback whenever the task is collected, up to the
        # interpreter's exit; the stop is reported by the caller
        logging.getLogger("asyncio").setLevel(logging.CRITICAL + 1)
        stopped = True
        raise
    except BaseException:
        stopped = True
        raise
    finally:
        # stopped mid-run (a signal, Ctrl-C, an error): the in-process scheduler's CRITICAL reports of results it
        # can no longer send to the closing client are not the user's business (the stop is reported by the caller)
        level = log.level
        if stopped:
            log.setLevel(logging.CRITICAL + 1)
        try:
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
        finally:
            log.setLevel(level)


def _run_dask(frames, config, background, counts, order, seed, workers, scheduler, points, seconds, bar) -> int:
    """Run the jobs as Dask tasks; fills ``points`` and ``seconds``; returns the worker count."""
    from distributed import as_completed

    with dask_client(workers, scheduler, len(order)) as (client, n_workers):
        shared = client.scatter([frames, background], broadcast=True)
        futures = {
            client.submit(_run_job, shared[0], job_config(config, seed, counts[c], r), shared[1], pure=False): (c, r)
            for c, r in order
        }
        for fut in as_completed(futures):
            c, r = futures[fut]
            points[c, r], seconds[c, r] = fut.result()
            bar.update(1)
    return n_workers
