"""Peer benchmark: MediaPipe Hands vs fusion-pf's hand cue (HandLandmarker) on the same real frames.

Both see the same RGB arrays, frame by frame, as a video (MediaPipe: ``static_image_mode=False``,
one hand, full model; fusion-pf: ``HandLandmarker.track``). MediaPipe is the peer, not a
dependency: it runs in its own virtual environment (``mediapipe==0.10.14`` with numpy < 2), in
a worker process started by this script (``--worker``) and driven frame by frame, alternating
with fusion-pf on the same frame, so both see the same machine load.

Data: the hand-graph-cnn real-world test set (github:3d-hand-shape/hand-graph-cnn,
``data/real_world_testset``; non-commercial licence: never commit it). ONLY the development
frames 477-582 are read (frames 0-476 are the held-out evaluation). Two views:

* ``crop256``: the dataset's 256 x 256 crops as they are;
* ``canvas1280``: each crop resized back into its box in a 1280 x 720 frame of constant grey 128
  (the dataset ships no full frames; the hand is at its true position and size, the pixels
  outside the box are not real).

Ground truth (:func:`ground_truth`): the 3-D joints (cm, camera frame) projected with the
video camera's intrinsics (``cam_param`` fx, fy, u0, v0), mapped into the crop with the
dataset's own formula for ``crop256``. The dataset's joint order is MediaPipe's (wrist, then
thumb, index, middle, ring, little, each base to tip), so the palm is the mean of joints
0, 5, 9, 13, 17 for the ground truth (projected 3-D mean) and for both trackers (2-D mean).

Metrics per view and tracker: palm error RMSE, median, p95, max over the frames with an
output; coverage = frames with an output / frames; ms/frame (median, mean) on tracking frames
(the previous frame had a hand: one landmark call) and acquisition frames (whole-frame palm
detection) separately; the speed ratio fusion-pf / MediaPipe on tracking frames.

Run (from the repository root)::

    PYTHONPATH=. /work/main/.venv/bin/python benchmarks/mediapipe_peer.py \\
        --data /work/data/hand-graph-cnn/real_world_testset \\
        --mediapipe-python /work/venvs/mediapipe/bin/python
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

#: The development frames (source indices); frames 0-476 are held out and never read.
DEV_FRAMES = range(477, 583)
PALM_JOINTS = [0, 5, 9, 13, 17]
CANVAS = (1280, 720)
GREY = 128


def ground_truth(folder: Path, frames: range = DEV_FRAMES, crop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """2-D ground truth of the hand-graph-cnn real-world test set.

    Parameters
    ----------
    folder : Path
        The dataset's ``real_world_testset`` folder (``params.mat``, ``pose_gt.mat``).
    frames : range
        Source frame indices (must lie in 477-582: the development frames).
    crop : int or None
        None: pixels of the 1280 x 720 video frame; an int: pixels of the ``crop`` x ``crop``
        crop of each frame's box (the dataset's formula ``(u - x0) * crop / w``).

    Returns
    -------
    joints : ndarray, shape (n, 21, 2)
        Projected joints ``(u, v)``.
    palm : ndarray, shape (n, 2)
        Projected 3-D mean of joints 0, 5, 9, 13, 17 (wrist and the four finger bases).
    """
    from scipy.io import loadmat

    if frames.start < DEV_FRAMES.start or frames.stop > DEV_FRAMES.stop:
        raise ValueError(f"only the development frames 477-582 may be used, got {frames}")
    idx = np.asarray(frames)
    params, gt = loadmat(folder / "params.mat"), loadmat(folder / "pose_gt.mat")
    cam = params["cam_param"][idx].astype(np.float64)  # (n, 4) fx, fy, u0, v0
    box = params["bbox"][idx].astype(np.float64)  # (n, 4) x, y, w, h in the video frame
    xyz = gt["pose_gt"][idx].astype(np.float64)  # (n, 21, 3) cm
    pts = np.concatenate((xyz, xyz[:, PALM_JOINTS].mean(axis=1, keepdims=True)), axis=1)  # + the 3-D palm
    uv = pts[..., :2] / pts[..., 2:] * cam[:, None, :2] + cam[:, None, 2:]
    if crop is not None:
        uv = (uv - box[:, None, :2]) * (crop / box[:, None, 2:3])
    return uv[:, :21], uv[:, 21]


def load_frames(folder: Path, view: str) -> np.ndarray:
    """The development frames as RGB ``(n, H, W, 3)`` uint8 for ``view`` ``crop256`` or ``canvas1280``."""
    import cv2
    from scipy.io import loadmat

    box = loadmat(folder / "params.mat")["bbox"][np.asarray(DEV_FRAMES)]
    out = []
    for k, i in enumerate(DEV_FRAMES):
        rgb = cv2.cvtColor(cv2.imread(str(folder / "images" / f"{i:05d}.jpg")), cv2.COLOR_BGR2RGB)
        if view == "canvas1280":
            x, y, w, h = (int(a) for a in box[k])
            full = np.full((CANVAS[1], CANVAS[0], 3), GREY, np.uint8)
            full[y : y + h, x : x + w] = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_LINEAR)
            rgb = full
        out.append(rgb)
    return np.stack(out)


def mediapipe_worker(frames_path: str) -> None:
    """Worker side (MediaPipe's venv): Hands, one frame per request.

    Reads ``MODE INDEX`` per line on stdin (``video``: video mode, the tracker's state carries
    over; ``static``: static image mode, palm detection on every frame), processes that frame of
    the ``.npy`` file and answers one line: the wall time in ms, then 63 landmark values (x, y, z
    in fusion-pf pixels), or nothing more when MediaPipe reports no hand.
    """
    import mediapipe as mp

    frames = np.load(frames_path, mmap_mode="r")
    h, w = frames.shape[1:3]
    opts = dict(max_num_hands=1, model_complexity=1, min_detection_confidence=0.5, min_tracking_confidence=0.5)
    with (
        mp.solutions.hands.Hands(static_image_mode=False, **opts) as video,
        mp.solutions.hands.Hands(static_image_mode=True, **opts) as static,
    ):
        for hands in (video, static):
            hands.process(np.full((h, w, 3), GREY, np.uint8))  # warm-up: graph start, no hand
        for line in sys.stdin:
            mode, i = line.split()
            hands = video if mode == "video" else static
            rgb = np.ascontiguousarray(frames[int(i)])
            t0 = time.perf_counter()
            res = hands.process(rgb)
            ms = (time.perf_counter() - t0) * 1e3
            vals = []
            if res.multi_hand_landmarks:
                vals = [
                    v for q in res.multi_hand_landmarks[0].landmark for v in (q.x * w - 0.5, q.y * h - 0.5, q.z * w)
                ]
            print(" ".join(f"{v:.6f}" for v in [ms, *vals]), flush=True)


class MediaPipePeer:
    """MediaPipe Hands in its own interpreter (``python``), driven frame by frame."""

    def __init__(self, python: str, frames_path: Path) -> None:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        self.proc = subprocess.Popen(
            [python, __file__, "--worker", str(frames_path)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            env=env,
        )

    def __call__(self, mode: str, i: int) -> tuple[float, np.ndarray | None]:
        """Wall ms of frame ``i`` in ``mode`` (``video`` or ``static``) and its landmarks ``(21, 3)`` (None = no hand)."""
        self.proc.stdin.write(f"{mode} {i}\n")
        self.proc.stdin.flush()
        vals = [float(x) for x in self.proc.stdout.readline().split()]
        if not vals:
            raise RuntimeError("the MediaPipe worker stopped (is --mediapipe-python a venv with mediapipe?)")
        return vals[0], (np.array(vals[1:]).reshape(21, 3) if len(vals) > 1 else None)

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait()


def run_pass(frames: np.ndarray, frames_path: Path, python: str, num_threads: int) -> dict[str, dict[str, np.ndarray]]:
    """One pass over the frames, MediaPipe and fusion-pf alternating frame by frame (same load for both).

    Per frame: MediaPipe video mode, fusion-pf ``track`` with the previous observation (default
    options, and ``recentre=None``: MediaPipe's graph exactly), then the acquisition cost on the
    same frame: MediaPipe static image mode and fusion-pf ``track`` without a previous
    observation (palm detection + landmarks). Keys ``mediapipe``, ``fusion-pf``,
    ``fusion-pf-norecentre`` (tracking runs) and ``mediapipe-static``, ``fusion-pf-detect``
    (acquisition runs).
    """
    from fusion_pf.cues.hand import HandLandmarker

    hl = HandLandmarker(num_threads=num_threads)
    plain = HandLandmarker(num_threads=num_threads, recentre=None)
    for h in (hl, plain):
        h.detect(np.full(frames.shape[1:], GREY, np.uint8))  # warm-up: both models once
    peer = MediaPipePeer(python, frames_path)
    n = frames.shape[0]
    out = {
        name: {"landmarks": np.full((n, 21, 3), np.nan), "ms": np.zeros(n), "acquire": np.zeros(n, bool)}
        for name in ("mediapipe", "fusion-pf", "fusion-pf-norecentre", "mediapipe-static", "fusion-pf-detect")
    }

    def put(name: str, i: int, ms: float, lm: np.ndarray | None, acquire: bool) -> None:
        out[name]["ms"][i], out[name]["acquire"][i] = ms, acquire
        if lm is not None:
            out[name]["landmarks"][i] = lm

    prev, prev_plain, had_hand = None, None, False
    try:
        for i in range(n):
            ms, lm = peer("video", i)
            put("mediapipe", i, ms, lm, not had_hand)  # MediaPipe detects when it tracks no hand
            had_hand = lm is not None
            t0 = time.perf_counter()
            prev, mode = hl.track(frames[i], prev)
            put(
                "fusion-pf",
                i,
                (time.perf_counter() - t0) * 1e3,
                None if prev is None else prev.landmarks,
                mode == "detect",
            )
            t0 = time.perf_counter()
            prev_plain, mode = plain.track(frames[i], prev_plain)
            put(
                "fusion-pf-norecentre",
                i,
                (time.perf_counter() - t0) * 1e3,
                None if prev_plain is None else prev_plain.landmarks,
                mode == "detect",
            )
            ms, lm = peer("static", i)
            put("mediapipe-static", i, ms, lm, True)
            t0 = time.perf_counter()
            obs, _ = hl.track(frames[i], None)
            put("fusion-pf-detect", i, (time.perf_counter() - t0) * 1e3, None if obs is None else obs.landmarks, True)
    finally:
        peer.close()
    return out


def stats(palm: np.ndarray, gt: np.ndarray, ms: np.ndarray, acquire: np.ndarray) -> dict[str, float]:
    """Accuracy of palm estimates ``(n, 2)`` (NaN = no output) against ``gt`` ``(n, 2)``, and timing."""
    ok = np.isfinite(palm).all(axis=1)
    err = np.hypot(*(palm[ok] - gt[ok]).T)
    track = ~acquire
    return {
        "coverage": float(ok.mean()),
        "rmse": float(np.sqrt(np.mean(err**2))) if err.size else float("nan"),
        "median": float(np.median(err)) if err.size else float("nan"),
        "p95": float(np.percentile(err, 95)) if err.size else float("nan"),
        "max": float(err.max()) if err.size else float("nan"),
        "n_track": int(track.sum()),
        "n_acquire": int(acquire.sum()),
        "ms_track_median": float(np.median(ms[track])) if track.any() else float("nan"),
        "ms_track_mean": float(ms[track].mean()) if track.any() else float("nan"),
        "ms_acquire_median": float(np.median(ms[acquire])) if acquire.any() else float("nan"),
        "ms_all_mean": float(ms.mean()),
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=Path("/work/data/hand-graph-cnn/real_world_testset"))
    ap.add_argument("--mediapipe-python", default="/work/venvs/mediapipe/bin/python")
    ap.add_argument("--views", default="canvas1280,crop256")
    ap.add_argument("--passes", type=int, default=3, help="passes over the frames (timings: median over passes)")
    ap.add_argument("--threads", type=int, default=2, help="LiteRT threads of fusion-pf")
    ap.add_argument("--json", type=Path, help="also write the results here")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.worker:
        mediapipe_worker(args.worker)
        return 0

    results = {"load_before": os.getloadavg(), "views": {}}
    with tempfile.TemporaryDirectory() as tmp:
        for view in args.views.split(","):
            frames = load_frames(args.data, view)
            _, gt = ground_truth(args.data, crop=256 if view == "crop256" else None)
            np.save(Path(tmp) / "frames.npy", frames)
            passes_out = [
                run_pass(frames, Path(tmp) / "frames.npy", args.mediapipe_python, args.threads)
                for _ in range(args.passes)
            ]
            runs = {name: [p[name] for p in passes_out] for name in passes_out[0]}
            table = {}
            for name, passes in runs.items():
                first = passes[0]
                palm = first["landmarks"][:, PALM_JOINTS, :2].mean(axis=1)
                same = all(np.array_equal(p["landmarks"], first["landmarks"], equal_nan=True) for p in passes)
                per_pass = [stats(palm, gt, p["ms"], p["acquire"]) for p in passes]
                row = per_pass[0]
                for key in ("ms_track_median", "ms_track_mean", "ms_acquire_median", "ms_all_mean"):
                    row[key] = float(np.median([s[key] for s in per_pass]))  # median over passes
                row["identical_passes"] = same
                table[name] = row
            table["ratio_track_ms"] = table["fusion-pf"]["ms_track_median"] / table["mediapipe"]["ms_track_median"]
            table["ratio_acquire_ms"] = (
                table["fusion-pf-detect"]["ms_acquire_median"] / table["mediapipe-static"]["ms_acquire_median"]
            )
            results["views"][view] = {"frames": int(frames.shape[0]), "size": list(frames.shape[2:0:-1]), **table}
    results["load_after"] = os.getloadavg()

    print(
        f"frames {DEV_FRAMES.start}-{DEV_FRAMES.stop - 1} (dev), {args.passes} passes alternating per frame, "
        f"load {results['load_before'][0]:.2f} -> {results['load_after'][0]:.2f}"
    )
    head = (
        f"{'view':<11} {'tracker':<20} {'cover':>6} {'RMSE':>6} {'median':>6} {'p95':>6} {'max':>6} "
        f"{'track ms (n)':>13} {'acq ms (n)':>11}"
    )
    print(head)
    for view, r in results["views"].items():
        for name in ("mediapipe", "fusion-pf", "fusion-pf-norecentre", "mediapipe-static", "fusion-pf-detect"):
            s = r[name]
            print(
                f"{view:<11} {name:<20} {s['coverage']:6.1%} {s['rmse']:6.1f} {s['median']:6.1f} {s['p95']:6.1f} "
                f"{s['max']:6.1f} {s['ms_track_median']:6.2f} ({s['n_track']:3d}) {s['ms_acquire_median']:5.1f} "
                f"({s['n_acquire']:2d})"
            )
        print(
            f"{view:<11} ms ratio fusion-pf / MediaPipe: tracking frames {r['ratio_track_ms']:.2f}, "
            f"acquisition frames {r['ratio_acquire_ms']:.2f} (medians)"
        )
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
