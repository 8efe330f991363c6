"""Real-footage benchmark: convert public hand data to fusion-pf recordings and track them.

Usage (from the repository root, data under ``/work/data`` by default)::

    python benchmarks/real_data.py prepare      # write the recordings under /work/data/real/
    python benchmarks/real_data.py run          # track each one with `fusion-pf track`, print the table

Data (never commit any of it; tests never depend on it)
--------------------------------------------------------
``hgc``: ``3d-hand-shape/hand-graph-cnn``, ``data/real_world_testset`` (Ge et al., CVPR 2019;
Snap Inc. non-commercial research licence). 583 real RGB frames of one hand, stored only as
256 x 256 crops of 1280 x 720 video frames; ``params.mat`` holds per frame the
bounding box of the crop in the video frame (``bbox``: x, y, w, h; square, 320-567 px on the
dev frames) and the video camera's intrinsics (``cam_param``: fx, fy, u0, v0; one camera,
fx = 923.6 px); ``pose_gt.mat`` the 21 3-D joints (cm, camera frame) in the order wrist,
thumb mcp/pip/dip/tip, index mcp..tip, middle, ring, little. The ground-truth palm is the
mean of the wrist and the four finger bases (joints 0, 5, 9, 13, 17), projected.
**Only source frames 477-582 (the development split) are read.** Frames 0-476 are the
held-out evaluation: their images are never loaded (only the dev images were extracted, see
below) and their rows of the ``.mat`` files are dropped right after reading.

``sr305``: ``LadaOndris/hand-recognition``, ``datasets/custom`` (MIT). RealSense SR305 depth
sequences, 640 x 480, 16-bit PNG in units of 0.125 mm, f = 476.007 px, principal point
(313.683, 242.755) (its readme.txt); the repository keeps every 20th frame of two
sequences (file name = capture index). No colour, no ground truth.

How the data was brought here (the ``fetch`` tool of the search library gives the git dirs)::

    G=/work/.mirror/3d-hand-shape+hand-graph-cnn/repo/.git
    D=/work/data/hand-graph-cnn/real_world_testset; mkdir -p $D/images
    for i in $(seq 477 582); do f=$(printf %05d $i).jpg
        git --git-dir=$G show HEAD:data/real_world_testset/images/$f > $D/images/$f; done
    for f in params.mat pose_gt.mat; do git --git-dir=$G show HEAD:data/real_world_testset/$f > $D/$f; done
    G=/work/.mirror/LadaOndris+hand-recognition/repo
    for p in $(git --git-dir=$G ls-tree -r --name-only HEAD datasets/custom); do
        mkdir -p /work/data/hand-recognition/$(dirname ${p#datasets/})
        git --git-dir=$G show HEAD:$p > /work/data/hand-recognition/${p#datasets/}; done

Recordings written by ``prepare`` (fusion-pf MCAP, docs/recording-format.md, no skeleton):

* ``hgc_dev_crop256.mcap``: the 106 dev crops as they are (PNG colour, lossless from the
  decoded JPEGs), with each crop's own intrinsics (a calibration message whenever the box
  changes, i.e. every frame) and ``/ground_truth/palm``.
* ``hgc_dev_canvas1280.mcap``: the same crops pasted back, resized, at their boxes into a
  1280 x 720 canvas of constant grey (128): the hand at its true position and size in the
  video frame, intrinsics of the video camera. The dataset ships no full frames, so outside
  the box there are no real pixels (said in the metadata ``canvas``).
* ``sr305_<sequence>.mcap``: one SR305 sequence, depth in mm (``round(raw / 8)``), a
  constant grey placeholder colour image (the format requires colour; the metadata
  ``placeholder_color`` says so), timestamps ``capture index * 100 ms`` (the capture loop
  pauses 0.1 s per frame, so this is an upper bound of the rate), ``seq`` = capture index.

Frame rate of the hand-graph-cnn video is not given; 30 fps is assumed.

``run`` calls ``python -m fusion_pf track REC -o OUT.mcap --csv OUT.csv --csv-latency``
(default tracking options; ``--csv-latency`` only fills the latency columns) in a
subprocess per recording and prints, against the ground truth: coverage (frames with an
estimate / frames), RMSE, median and 95th percentile of the error (px) of the fused estimate
and of every per-source ``<source>_u, <source>_v`` pair the CSV has; frames lost (the
``state`` column, when the tracker writes one) and frames without an estimate; estimates
outside the image; median per-frame latency (``latency_total_ms``) and wall time per frame
of the whole command; and two constant guesses (image centre, mean ground-truth palm of the
recording) for comparison. The per-source rows of the CSV are the cues as ``track`` ran them
(inside its window, fed its prediction); the ``<cue> (whole frame)`` rows are each cue alone:
run on every whole frame with no window, no prior and no memory of the previous frame (the
hand cue then detects the palm on the whole frame every frame), the "single cue" a fused
estimate must beat.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers.mcap_record import McapRecorder  # noqa: E402
from drivers.mcap_replay import McapReplay  # noqa: E402
from fusion_pf.errors import InputError  # noqa: E402
from fusion_pf.frame import Frame, Intrinsics, PalmPoint  # noqa: E402

#: The development split of the hand-graph-cnn real-world test set (inclusive).
DEV_FIRST, DEV_LAST = 477, 582
#: Joints averaged into the palm centre: wrist and the index, middle, ring, little mcp.
PALM_JOINTS = (0, 5, 9, 13, 17)
#: Assumed frame rate of the hand-graph-cnn video.
HGC_FPS = 30.0
#: SR305 depth unit (mm per raw count) and intrinsics, from datasets/custom/readme.txt.
SR305_UNIT_MM = 0.125
SR305_F, SR305_CX, SR305_CY = 476.007, 313.683, 242.755
#: Frame period given to the SR305 captures (the capture loop pauses 0.1 s per frame).
SR305_PERIOD_NS = 100_000_000
#: Grey level of the canvas outside the crop and of the SR305 placeholder colour.
GREY = 128
START_NS = 1_700_000_000_000_000_000

DATA = Path("/work/data")


# ---------------------------------------------------------------------- hand-graph-cnn


def load_hgc_dev(folder: Path) -> dict[str, np.ndarray]:
    """Camera, boxes and 3-D joints of the development frames only.

    Returns
    -------
    dict
        ``index`` (106,) source frame numbers, ``cam`` (106, 4) fx, fy, u0, v0 of the
        video camera, ``bbox`` (106, 4) x, y, w, h, ``joints`` (106, 21, 3) cm.
    """
    import scipy.io as sio

    params = sio.loadmat(folder / "params.mat")
    joints = sio.loadmat(folder / "pose_gt.mat")["pose_gt"]
    dev = np.arange(DEV_FIRST, DEV_LAST + 1)
    names = [str(p).strip() for p in params["image_path"][dev]]
    expected = [f"images/{i:05d}.jpg" for i in dev]
    if names != expected:
        raise InputError(
            f"{folder}/params.mat image_path rows {DEV_FIRST}-{DEV_LAST} are not {expected[0]}..; got {names[0]}.."
        )
    return {
        "index": dev,
        "cam": params["cam_param"][dev].astype(np.float64),
        "bbox": params["bbox"][dev].astype(np.int64),
        "joints": joints[dev].astype(np.float64),
    }


def palm_3d(joints: np.ndarray) -> np.ndarray:
    """Palm centres, shape (N, 3), of joints shaped (N, 21, 3)."""
    return joints[:, PALM_JOINTS].mean(axis=1)


def crop_intrinsics(cam: np.ndarray, bbox: np.ndarray, size: int) -> Intrinsics:
    """Intrinsics of the ``size`` x ``size`` crop of box ``bbox`` (the dataset's own formula)."""
    s = size / float(bbox[2])
    fx, fy, u0, v0 = cam
    return Intrinsics(size, size, fx * s, fy * s, (u0 - bbox[0]) * s, (v0 - bbox[1]) * s)


def project(k: Intrinsics, p: np.ndarray) -> PalmPoint:
    """Pixel of the camera-frame point ``p`` (any length unit)."""
    return PalmPoint(k.fx * p[0] / p[2] + k.cx, k.fy * p[1] / p[2] + k.cy)


def prepare_hgc(folder: Path, out: Path) -> list[Path]:
    """Write the crop and canvas recordings of the dev frames; returns their paths."""
    dev = load_hgc_dev(folder)
    palms = palm_3d(dev["joints"])
    crop_path, canvas_path = out / "hgc_dev_crop256.mcap", out / "hgc_dev_canvas1280.mcap"
    meta = {
        "generator": "benchmarks/real_data.py",
        "dataset": "3d-hand-shape/hand-graph-cnn data/real_world_testset (non-commercial licence)",
        "source_frames": f"{DEV_FIRST}-{DEV_LAST} (development split)",
        "fps": f"{HGC_FPS} (assumed)",
        "ground_truth": "mean of wrist and index/middle/ring/little mcp, projected",
    }
    video = Intrinsics(1280, 720, *dev["cam"][0])
    if not np.all(dev["cam"] == dev["cam"][0]):
        raise InputError(f"{folder}/params.mat: the dev frames have more than one camera; expected one")
    with (
        McapRecorder(crop_path, color_format="png", metadata={**meta, "view": "256x256 crops"}) as crop,
        McapRecorder(
            canvas_path,
            color_format="png",
            metadata={
                **meta,
                "view": "1280x720 canvas",
                "canvas": "crop resized into its box; outside the box constant grey 128, not real pixels",
            },
        ) as canvas,
    ):
        for k, i in enumerate(dev["index"]):
            path = folder / "images" / f"{i:05d}.jpg"
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if bgr is None:
                raise InputError(f"cannot read {path}; expected the dev JPEGs of the real-world test set")
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
            t = START_NS + round(k * 1e9 / HGC_FPS)
            k_crop = crop_intrinsics(dev["cam"][k], dev["bbox"][k], rgb.shape[0])
            crop.write(Frame(t, int(i), rgb, None, k_crop, ground_truth=project(k_crop, palms[k])))
            x, y, w, h = dev["bbox"][k]
            full = np.full((720, 1280, 3), GREY, np.uint8)
            full[y : y + h, x : x + w] = cv2.resize(rgb, (int(w), int(h)), interpolation=cv2.INTER_LINEAR)
            canvas.write(Frame(t, int(i), full, None, video, ground_truth=project(video, palms[k])))
    return [crop_path, canvas_path]


# ---------------------------------------------------------------------- SR305


def prepare_sr305(folder: Path, sequence: str, out: Path) -> Path:
    """Write one SR305 depth sequence as a recording; returns its path."""
    seq_dir = folder / sequence
    files = sorted(seq_dir.glob("*.png"), key=lambda p: int(p.stem))
    if not files:
        raise InputError(f"no PNG depth frames in {seq_dir}; expected datasets/custom/<sequence>/<index>.png")
    path = out / f"sr305_{sequence}.mcap"
    k = Intrinsics(640, 480, SR305_F, SR305_F, SR305_CX, SR305_CY)
    meta = {
        "generator": "benchmarks/real_data.py",
        "dataset": f"LadaOndris/hand-recognition datasets/custom/{sequence} (MIT), RealSense SR305",
        "depth": "raw * 0.125 mm, rounded to mm",
        "placeholder_color": f"constant grey {GREY}: the source has depth only",
        "timestamps": "capture index * 100 ms (the capture loop pauses 0.1 s per frame)",
    }
    grey = np.full((480, 640, 3), GREY, np.uint8)
    with McapRecorder(path, depth_format="png", color_format="png", metadata=meta) as rec:
        for f in files:
            raw = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            if raw is None or raw.dtype != np.uint16 or raw.shape != (480, 640):
                raise InputError(f"{f}: expected a 640x480 16-bit depth PNG")
            depth = np.rint(raw * SR305_UNIT_MM).astype(np.uint16)
            index = int(f.stem)
            rec.write(Frame(START_NS + index * SR305_PERIOD_NS, index, grey, depth, k))
    return path


# ---------------------------------------------------------------------- run


def _errors(est: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Euclidean error per frame, shape (N,); NaN where the estimate is missing."""
    return np.hypot(est[:, 0] - truth[:, 0], est[:, 1] - truth[:, 1])


def _stats(err: np.ndarray) -> dict[str, float]:
    ok = err[np.isfinite(err)]
    if ok.size == 0:
        return {"coverage": 0.0, "rmse": math.nan, "median": math.nan, "p95": math.nan}
    return {
        "coverage": ok.size / err.size,
        "rmse": float(np.sqrt(np.mean(ok**2))),
        "median": float(np.median(ok)),
        "p95": float(np.percentile(ok, 95)),
    }


def _read_csv(path: Path) -> tuple[list[str], list[dict[str, str]]]:
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        return list(reader.fieldnames or []), list(reader)


def _column(rows: list[dict[str, str]], name: str) -> np.ndarray:
    return np.array([float(r[name]) if r.get(name) not in (None, "") else math.nan for r in rows])


def track_one(rec: Path, work: Path) -> dict:
    """Run ``fusion-pf track`` on ``rec`` and measure it against the recording's ground truth."""
    out, table = work / f"{rec.stem}.tracked.mcap", work / f"{rec.stem}.csv"
    cmd = [
        sys.executable,
        "-m",
        "fusion_pf",
        "track",
        str(rec),
        "-o",
        str(out),
        "--csv",
        str(table),
        "--csv-latency",
        "--force",
        "--no-progress",
    ]
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise InputError(f"fusion-pf track {rec.name} exited {proc.returncode}: {proc.stderr.strip()[-300:]}")
    with McapReplay(rec) as replay:
        info = replay.info()
        truth = {}
        for i, f in enumerate(replay):
            if f.ground_truth is not None:
                truth[i] = (f.ground_truth.u, f.ground_truth.v)
    columns, rows = _read_csv(table)
    frames = [int(r["frame"]) for r in rows]
    sources = [c[:-2] for c in columns if c.endswith("_u") and c != "u" and f"{c[:-2]}_v" in columns]
    lines = (proc.stdout.strip() or proc.stderr.strip()).splitlines()
    res: dict = {
        "recording": rec.name,
        "size": (info.width, info.height),
        "frames": len(rows),
        "summary": lines[-1] if lines else "",
    }
    est = np.c_[_column(rows, "u"), _column(rows, "v")]
    w, h = info.width, info.height
    have = np.isfinite(est).all(axis=1)
    outside = have & ((est[:, 0] < -0.5) | (est[:, 0] > w - 0.5) | (est[:, 1] < -0.5) | (est[:, 1] > h - 0.5))
    res["no_estimate"] = int((~have).sum())
    res["outside"] = int(outside.sum())
    res["lost"] = sum(r.get("state") == "lost" for r in rows) if "state" in columns else None
    lat = _column(rows, "latency_total_ms") if "latency_total_ms" in columns else np.array([math.nan])
    res["latency_ms"] = float(np.nanmedian(lat)) if np.isfinite(lat).any() else math.nan
    res["wall_ms"] = 1000.0 * wall / max(len(rows), 1)
    if truth:
        gt = np.array([truth.get(f, (math.nan, math.nan)) for f in frames])
        scored = np.isfinite(gt).all(axis=1)
        gt = gt[scored]
        res["rows"] = {"fused": _stats(_errors(est[scored], gt))}
        for s in sources:
            pts = np.c_[_column(rows, f"{s}_u"), _column(rows, f"{s}_v")][scored]
            res["rows"][s] = _stats(_errors(pts, gt))
        centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0])
        res["rows"].update({f"{n} (whole frame)": st for n, st in whole_frame_cues(rec).items()})
        res["rows"]["const: centre"] = _stats(_errors(np.broadcast_to(centre, gt.shape), gt))
        res["rows"]["const: mean palm"] = _stats(_errors(np.broadcast_to(gt.mean(axis=0), gt.shape), gt))
    else:
        res["rows"] = {"fused": {"coverage": float(have.mean()), "rmse": math.nan, "median": math.nan, "p95": math.nan}}
        for s in sources:
            pts = np.c_[_column(rows, f"{s}_u"), _column(rows, f"{s}_v")]
            res["rows"][s] = {
                "coverage": float(np.isfinite(pts).all(axis=1).mean()),
                "rmse": math.nan,
                "median": math.nan,
                "p95": math.nan,
            }
    return res


def whole_frame_cues(rec: Path) -> dict[str, dict[str, float]]:
    """Each cue the recording can feed, alone on every whole frame, against the ground truth.

    No window, no prior, no memory: every cue is reset before each frame, so the hand cue runs
    whole-frame palm detection then landmarks every frame. The background-subtraction cues get
    the model ``fusion-pf cues`` uses (the recording's empty-scene frames, else the median of
    its first ``background_k`` frames). Returns the :func:`_stats` of each cue.
    """
    from fusion_pf.cues.background import BackgroundModel
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.registry import CUES, build_cues
    from fusion_pf.pipeline.config import TrackConfig

    config = TrackConfig()
    with McapReplay(rec) as src:
        first = src.frame(0)
        parts = {"color", "background"} | ({"depth"} if first.depth is not None else set())
        names = [c for c, info in CUES.items() if info.needs <= parts and c != "skin_lab"]
        cues = build_cues(names)
        k = src.info().background_frames or min(config.background_k, len(src))
        ctx = CueContext(background=BackgroundModel.from_frames(src.frames(0, k)), search=True)
        err: dict[str, list[float]] = {n: [] for n in names}
        for f in src:
            if f.background or f.ground_truth is None:
                continue
            for name, cue in cues.items():
                cue.reset()
                m = cue.measure(f, ctx).measurement
                err[name].append(math.nan if m is None else math.hypot(m.u - f.ground_truth.u, m.v - f.ground_truth.v))
    return {n: _stats(np.array(e)) for n, e in err.items()}


def _fmt(x: float, digits: int = 1) -> str:
    return "-" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.{digits}f}"


def print_table(results: list[dict]) -> None:
    """Print one block per recording."""
    for r in results:
        w, h = r["size"]
        lost = "n/a (no state column)" if r["lost"] is None else str(r["lost"])
        print(
            f"\n{r['recording']}  {w}x{h}, {r['frames']} tracked frames; lost {lost}; "
            f"without estimate {r['no_estimate']}; estimates outside the image {r['outside']}; "
            f"latency median {_fmt(r['latency_ms'], 2)} ms/frame, whole command {_fmt(r['wall_ms'], 1)} ms/frame"
        )
        if r["summary"]:
            print(f"  track says: {r['summary']}")
        print(f"  {'':22s} {'coverage':>9s} {'RMSE':>8s} {'median':>8s} {'p95':>8s}")
        for name, s in r["rows"].items():
            print(
                f"  {name:22s} {100 * s['coverage']:8.1f}% {_fmt(s['rmse']):>8s} {_fmt(s['median']):>8s} {_fmt(s['p95']):>8s}"
            )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    pp = sub.add_parser("prepare", help="write the recordings")
    pp.add_argument(
        "--hgc",
        type=Path,
        default=DATA / "hand-graph-cnn" / "real_world_testset",
        help="folder with params.mat, pose_gt.mat and images/00477.jpg..00582.jpg",
    )
    pp.add_argument(
        "--sr305",
        type=Path,
        default=DATA / "hand-recognition" / "custom",
        help="LadaOndris/hand-recognition datasets/custom folder",
    )
    pp.add_argument("--sequence", default="20210326-231615", help="SR305 sequence to convert")
    pp.add_argument("--out", type=Path, default=DATA / "real")
    pr = sub.add_parser("run", help="track every recording and print the table")
    pr.add_argument("recordings", nargs="*", type=Path, help="default: every .mcap in --out except *.tracked.mcap")
    pr.add_argument("--out", type=Path, default=DATA / "real")
    args = p.parse_args(argv)
    try:
        if args.cmd == "prepare":
            args.out.mkdir(parents=True, exist_ok=True)
            for path in prepare_hgc(args.hgc, args.out) + [prepare_sr305(args.sr305, args.sequence, args.out)]:
                with McapReplay(path) as rec:
                    info = rec.info()
                print(
                    f"wrote {path}: {info.frames} frames {info.width}x{info.height}, "
                    f"{info.ground_truth_frames} with ground truth, {path.stat().st_size / 1e6:.1f} MB"
                )
            return 0
        recs = args.recordings or sorted(p for p in args.out.glob("*.mcap") if not p.name.endswith(".tracked.mcap"))
        if not recs:
            raise InputError(f"no recordings in {args.out}; run `python benchmarks/real_data.py prepare` first")
        work = args.out / "runs"
        work.mkdir(parents=True, exist_ok=True)
        print(f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f} {os.getloadavg()[2]:.2f}")
        print_table([track_one(r, work) for r in recs])
        return 0
    except InputError as exc:
        print(f"real_data: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
