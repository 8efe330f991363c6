"""Particle-count sweeps and multi-execution (paper 003 §4.4-4.5, Figures 8-9).

For every particle count ``N`` and run ``r`` the filter is re-run on the *same*
cue rows (cues are computed once, :func:`fusion_pf.track.extract_cues`) and
scored against the reference with :func:`fusion_pf.score.metrics.score`. Run 0
is the single execution of Figure 8; the mean over runs is the multi-execution
of Figure 9.

Determinism
    Job ``(N, r)`` draws from ``numpy.random.default_rng(SeedSequence([seed,
    N, r]))``, so its result depends only on ``(seed, N, r)``: not on the
    worker count, the order jobs finish in, or which other counts are swept.

Parallelism
    Jobs run in a :class:`concurrent.futures.ProcessPoolExecutor` with
    ``os.cpu_count()`` workers by default; each worker receives the cue rows
    and the configuration once, through the pool initializer (the ``fork``
    start method is used where available, so they are inherited rather than
    pickled). ``workers=1`` runs everything in the calling process.
"""

from __future__ import annotations

import dataclasses
import math
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fusion_pf.cues.base import SOURCES
from fusion_pf.errors import InputError

from .metrics import SCORED_SOURCES, TIE_TOL_PX, score

#: Particle counts of paper 003 §4.4.
PAPER_PARTICLE_COUNTS = (5, 10, 25, 50, 75, 100, 125, 150, 200, 250)

#: Runs per particle count of paper 003 §4.5.
PAPER_RUNS = 20


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


def job_rng(seed: int, n_particles: int, run: int) -> np.random.Generator:
    """The generator of sweep job ``(n_particles, run)`` (independent of scheduling)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), int(n_particles), int(run)]))


def result_points(results: Sequence) -> np.ndarray:
    """Points of every scored source from ``TrackResult`` rows.

    Parameters
    ----------
    results : sequence of TrackResult
        As returned by :func:`fusion_pf.track.run_filter` / :func:`fusion_pf.track.track`.

    Returns
    -------
    ndarray, shape (len(SCORED_SOURCES), n, 2)
        In :data:`SCORED_SOURCES` order (cues, then the estimate as ``fused``);
        NaN where a source gave nothing.
    """
    out = np.full((len(SCORED_SOURCES), len(results), 2), np.nan)
    for t, r in enumerate(results):
        for i, s in enumerate(SOURCES):
            m = r.cues.get(s)
            if m is not None:
                out[i, t] = (m.u, m.v)
        if r.estimate is not None:
            out[len(SOURCES), t] = (r.estimate.u, r.estimate.v)
    return out


_WORKER: dict = {}


def _init_worker(cue_rows: Sequence, config: object) -> None:
    _WORKER["cue_rows"] = cue_rows
    _WORKER["config"] = config


def _run_job(n_particles: int, run: int, seed: int) -> tuple[np.ndarray, float]:
    from fusion_pf.track import run_filter

    config = dataclasses.replace(_WORKER["config"], particles=int(n_particles))
    t0 = time.perf_counter()
    results = run_filter(_WORKER["cue_rows"], config, job_rng(seed, n_particles, run))
    return result_points(results), time.perf_counter() - t0


@dataclass(frozen=True)
class SweepResult:
    """Scores of every ``(particle count, run)`` job.

    Attributes
    ----------
    particle_counts : tuple of int
    runs : int
    seed : int
    sources : tuple of str
        :data:`SCORED_SOURCES`.
    bestmax : ndarray, shape (n_counts, runs, n_sources), int64
        BestMax of each source in each job (cues compete with that job's estimate).
    rmse : ndarray, shape (n_counts, runs, n_sources)
        RMSE in pixels of each source in each job (NaN when never scored).
    errors : ndarray, shape (n_counts, runs, n_sources, n_frames)
        Per-frame errors in pixels (NaN where not scored).
    job_seconds : ndarray, shape (n_counts, runs)
        Wall time of each filter run.
    wall_seconds : float
        Wall time of the whole sweep.
    workers : int
        Worker processes used (1 = in process).
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


def run_sweep(
    cue_rows: Sequence,
    config: object,
    reference: np.ndarray,
    particle_counts: Sequence[int] = PAPER_PARTICLE_COUNTS,
    runs: int = PAPER_RUNS,
    *,
    seed: int = 0,
    workers: int | None = None,
    progress: bool = True,
    tie_tol: float = TIE_TOL_PX,
) -> SweepResult:
    """Re-run the filter for every particle count and run, and score each run.

    Parameters
    ----------
    cue_rows : sequence of CueRow
        From :func:`fusion_pf.track.extract_cues`, one per frame.
    config : TrackConfig
        The filter configuration; its ``particles`` is replaced per job.
    reference : ndarray, shape (n, 2)
        Reference ``(u, v)`` per cue row, NaN where missing (see
        :func:`fusion_pf.score.inputs.align`).
    particle_counts : sequence of int
        Particle counts ``N`` (>= 1).
    runs : int
        Runs per count (>= 1); run ``r`` uses seed ``(seed, N, r)``.
    seed : int
        Base seed (>= 0).
    workers : int, optional
        Worker processes (default ``os.cpu_count()``, capped at the job count).
    progress : bool
        Show a tqdm progress bar on stderr.
    tie_tol : float
        BestMax tie tolerance in pixels.

    Returns
    -------
    SweepResult
    """
    counts = tuple(int(n) for n in particle_counts)
    if not counts or min(counts) < 1:
        raise InputError(f"particle counts must be a non-empty list of integers >= 1, got {list(counts)}")
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or runs < 1:
        raise InputError(f"runs must be an integer >= 1, got {runs!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    n = len(cue_rows)
    reference = np.asarray(reference, dtype=np.float64)
    if reference.shape != (n, 2):
        raise InputError(f"reference must have shape ({n}, 2) (one row per cue row), got {reference.shape}")
    jobs = [(c, r) for c in range(len(counts)) for r in range(runs)]
    n_workers = min(len(jobs), os.cpu_count() or 1) if workers is None else int(workers)
    if n_workers < 1:
        raise InputError(f"workers must be >= 1, got {workers!r}")
    n_workers = min(n_workers, len(jobs))
    points = np.full((len(counts), runs, len(SCORED_SOURCES), n, 2), np.nan)
    seconds = np.zeros((len(counts), runs))
    from tqdm import tqdm

    t0 = time.perf_counter()
    # Largest counts first: the slowest jobs start early, so the pool stays busy.
    order = sorted(jobs, key=lambda j: -counts[j[0]])
    if n_workers == 1:
        _init_worker(cue_rows, config)
        try:
            for c, r in tqdm(order, desc="sweep", unit="run", disable=not progress, file=sys.stderr):
                points[c, r], seconds[c, r] = _run_job(counts[c], r, seed)
        finally:
            _WORKER.clear()
    else:
        methods = multiprocessing.get_all_start_methods()
        ctx = multiprocessing.get_context("fork" if "fork" in methods else None)
        pool = ProcessPoolExecutor(n_workers, mp_context=ctx, initializer=_init_worker, initargs=(cue_rows, config))
        try:
            futures = {pool.submit(_run_job, counts[c], r, seed): (c, r) for c, r in order}
            with tqdm(total=len(futures), desc="sweep", unit="run", disable=not progress, file=sys.stderr) as bar:
                for fut in as_completed(futures):
                    c, r = futures[fut]
                    points[c, r], seconds[c, r] = fut.result()
                    bar.update(1)
        finally:
            # On an error or Ctrl-C, drop the jobs not started yet instead of finishing the sweep.
            pool.shutdown(wait=True, cancel_futures=True)
    wall = time.perf_counter() - t0
    bestmax = np.zeros((len(counts), runs, len(SCORED_SOURCES)), dtype=np.int64)
    rmse = np.full((len(counts), runs, len(SCORED_SOURCES)), math.nan)
    errors = np.full((len(counts), runs, len(SCORED_SOURCES), n), math.nan)
    for c, r in jobs:
        s = score(dict(zip(SCORED_SOURCES, points[c, r])), reference, tie_tol=tie_tol)
        bestmax[c, r] = [s.summary[k].bestmax for k in SCORED_SOURCES]
        rmse[c, r] = [s.summary[k].rmse for k in SCORED_SOURCES]
        errors[c, r] = [s.errors[k] for k in SCORED_SOURCES]
    return SweepResult(
        particle_counts=counts,
        runs=int(runs),
        seed=int(seed),
        sources=SCORED_SOURCES,
        bestmax=bestmax,
        rmse=rmse,
        errors=errors,
        job_seconds=seconds,
        wall_seconds=wall,
        workers=n_workers,
        tie_tol=float(tie_tol),
    )


def tracker_settings(path: str) -> dict | None:
    """The tracker settings ``fusion-pf track`` stored in its output MCAP, or None.

    ``fusion-pf track -o OUT.mcap`` writes its :class:`~fusion_pf.track.TrackConfig`
    as JSON under the key ``tracker`` of the ``fusion_pf.recording`` metadata
    record. Returns that dict (None when the file has no such key).
    """
    import json

    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            for meta in make_reader(f).iter_metadata():
                if meta.name == "fusion_pf.recording" and "tracker" in meta.metadata:
                    settings = json.loads(meta.metadata["tracker"])
                    return settings if isinstance(settings, dict) else None
    except (McapError, ValueError):
        return None
    return None


def sweep_config(settings: dict | None = None) -> object:
    """The :class:`~fusion_pf.track.TrackConfig` a sweep uses.

    Parameters
    ----------
    settings : dict, optional
        Tracker settings (:func:`tracker_settings`); unknown keys are ignored,
        missing ones take the defaults.

    Returns
    -------
    TrackConfig
        With ``roi_prior="skeleton"``: the cue windows follow the skeleton
        joint (paper 003 §3.1), so the cue rows do not depend on the filter
        and every ``(N, run)`` job fuses the same cues.
    """
    from fusion_pf.track import TrackConfig

    names = {f.name for f in dataclasses.fields(TrackConfig)}
    kwargs = {k: v for k, v in (settings or {}).items() if k in names and k != "roi_prior"}
    for key in ("process_noise", "sources"):
        if isinstance(kwargs.get(key), list):
            kwargs[key] = tuple(kwargs[key])
    return TrackConfig(**kwargs, roi_prior="skeleton")


def sweep_recording(
    recording: str,
    reference,
    config: object,
    particle_counts: Sequence[int] = PAPER_PARTICLE_COUNTS,
    runs: int = PAPER_RUNS,
    *,
    seed: int = 0,
    workers: int | None = None,
    progress: bool = True,
    tie_tol: float = TIE_TOL_PX,
) -> SweepResult:
    """Extract the cues of a recording once, then :func:`run_sweep` against a reference.

    Parameters
    ----------
    recording : str
        Source spec of the recording to re-track (an MCAP path or ``synth:...``).
    reference : Reference
        From :mod:`fusion_pf.score.inputs`; aligned to the cue rows by frame or time.
    config : TrackConfig
    particle_counts, runs, seed, workers, progress, tie_tol
        As in :func:`run_sweep`.

    Returns
    -------
    SweepResult
    """
    from drivers import open_source
    from fusion_pf.track import extract_cues

    from .inputs import align

    with open_source(str(recording)) as src:
        cue_rows = extract_cues(src, config)
    frame = np.array([r.frame for r in cue_rows], dtype=np.int64)
    ts = np.array([r.timestamp_ns for r in cue_rows], dtype=np.int64)
    uv, _ = align(frame, ts, reference, name=f"{recording} (re-tracked for the sweep)")
    return run_sweep(
        cue_rows, config, uv, particle_counts, runs,
        seed=seed, workers=workers, progress=progress, tie_tol=tie_tol,
    )
