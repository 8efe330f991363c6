"""Several targets through the one pipeline: accuracy per hand and the cost of a second target (issue 22).

For every seed, the two-hand synthetic scene (``synth --hands 2``: the hands join
twice and cross once per 300 frames, realistic stereo depth) is tracked by
:func:`fusion_pf.pipeline.track` with ``targets=("right_hand", "left_hand")``
and default options; printed per seed and hand: RMSE, RMSE while the hands are
joined (true palms closer than :data:`~fusion_pf.score.targets.JOINED_FRACTION`
of the diagonal), coverage, the share of frames with an estimate whose error is within
``2 sigma_px`` (the target's reported uncertainty; all, and joined), and the identity swaps between the hands
(:func:`~fusion_pf.score.targets.count_swaps`). Then the cost on the first
seed's (pre-rendered) frames: the process CPU time per tracked frame of a whole
:func:`~fusion_pf.pipeline.track` run of one target (``right_hand``) and of two,
given the background model (built once, not timed), the least of ``--repeats`` alternating runs (CPU time, not wall time: other
processes sharing the cores inflate the wall time unevenly), and their ratio.

Usage::

    PYTHONPATH=. python benchmarks/targets.py [--seeds 0,1,2] [--frames 330] [--size 640x400] [--filters pf,kf,sspf]
        [--scene hand_front=0.1,joins=3,crossings=2,timing=1]

Seed 0 is the one the pipeline was developed on; report the others as held out.
"""

from __future__ import annotations

import argparse
import math
import sys
import time

import numpy as np

from drivers.synth import VARIATIONS, SynthSource
from fusion_pf.cues.background import BackgroundModel
from fusion_pf.pipeline import TrackConfig, track
from fusion_pf.score.metrics import uncertainty_coverage
from fusion_pf.score.targets import JOINED_FRACTION, count_swaps

HANDS = ("right_hand", "left_hand")
BACKGROUND_FRAMES = 30


def _frames(
    seed: int, frames: int, size: tuple[int, int], scene: dict | None = None, background: int = BACKGROUND_FRAMES
) -> list:
    """The scene's frames, its first ``background`` ones empty (0: the person is in view from the first frame)."""
    with SynthSource(
        seed=seed, frames=frames, size=size, hands=2, background_frames=background, **(scene or {})
    ) as src:
        return list(src)


def _scene(text: str) -> dict:
    """``--scene`` ``K=V,...``: synth variations and layout options (``drivers.synth.VARIATIONS``)."""
    out = {}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        if key not in VARIATIONS:
            raise SystemExit(f"--scene: unknown synth option {key!r}; expected one of {', '.join(VARIATIONS)}")
        out[key] = value
    return out


def accuracy(frames: list, targets: tuple[str, ...] = HANDS, filt: str = "pf") -> dict:
    """Per target RMSE, joined RMSE, coverage, shares within ``2 sigma_px`` (all, joined); swaps between the hands;
    with filter ``filt``."""
    est = {t: [] for t in targets}
    sigma: dict[str, list[float]] = {t: [] for t in targets}
    truth = {t: [] for t in HANDS}
    config = TrackConfig(targets=targets if len(targets) > 1 else None, joint=targets[0], filter=filt)
    for r in track(frames, config):
        if r.background:
            continue
        per = r.targets or {targets[0]: r}
        for t in targets:
            e = per[t].estimate
            est[t].append((math.nan, math.nan) if e is None else (e.u, e.v))
            sigma[t].append(math.nan if per[t].sigma_px is None else per[t].sigma_px)
        gts = r.source_frame.ground_truths or {}
        for t in HANDS:
            g = gts.get(t)
            truth[t].append((math.nan, math.nan) if g is None else (g.u, g.v))
    w, h = frames[0].size
    tr = {t: np.array(v) for t, v in truth.items()}
    joined = np.hypot(*(tr["right_hand"] - tr["left_hand"]).T) < JOINED_FRACTION * math.hypot(w, h)
    out: dict = {"targets": {}}
    uv = {t: np.array(v) for t, v in est.items()}
    for t in targets:
        err = np.hypot(*(uv[t] - tr[t]).T)
        ok = np.isfinite(err)
        j = ok & joined
        s = np.array(sigma[t])
        out["targets"][t] = {
            "rmse_px": float(np.sqrt(np.mean(err[ok] ** 2))) if ok.any() else math.nan,
            "joined_rmse_px": float(np.sqrt(np.mean(err[j] ** 2))) if j.any() else math.nan,
            "coverage": float(ok.mean()),
            "within_2_sigma": uncertainty_coverage(err, s).within_2,
            "joined_within_2_sigma": uncertainty_coverage(np.where(joined, err, np.nan), s).within_2,
        }
    if len(targets) == 2:
        out["swaps"] = count_swaps(
            uv["right_hand"], uv["left_hand"], tr["right_hand"], tr["left_hand"], JOINED_FRACTION * math.hypot(w, h)
        )
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", default="0,1,2", help="comma-separated scene seeds (default 0,1,2)")
    p.add_argument("--frames", type=int, default=330, help="frames per scene, background frames included")
    p.add_argument(
        "--background-frames",
        type=int,
        default=BACKGROUND_FRAMES,
        help=f"leading empty-scene frames per scene (default {BACKGROUND_FRAMES}; 0 = none: the background "
        "is learnt from the recording, the person in view)",
    )
    p.add_argument("--size", default="640x400", help="image size WxH")
    p.add_argument("--repeats", type=int, default=3, help="alternating timing runs (default 3; 0 = no timing)")
    p.add_argument("--filters", default="pf", help="comma-separated per-target filters among pf, kf, sspf (default pf)")
    p.add_argument(
        "--scene",
        default="",
        help="synth scene options K=V,... (e.g. hand_front=0.1,joins=3,crossings=2,timing=1; default none)",
    )
    args = p.parse_args(argv)
    size = tuple(int(x) for x in args.size.split("x"))
    seeds = [int(s) for s in args.seeds.split(",")]
    print("| seed | filter | hand | RMSE (px) | joined RMSE (px) | coverage | within 2 sigma_px | joined | swaps |")
    print("|---:|---|---|---:|---:|---:|---:|---:|---:|")
    first = None
    for seed in seeds:
        frames = _frames(seed, args.frames, size, _scene(args.scene), args.background_frames)
        first = first or frames
        for filt in args.filters.split(","):
            res = accuracy(frames, HANDS, filt)
            for t, r in res["targets"].items():
                print(
                    f"| {seed} | {filt} | {t} | {r['rmse_px']:.2f} | {r['joined_rmse_px']:.2f} | "
                    f"{100 * r['coverage']:.1f} % | {100 * r['within_2_sigma']:.1f} % | "
                    f"{100 * r['joined_within_2_sigma']:.1f} % | {res['swaps']} |"
                )
    assert first is not None
    if args.repeats < 1:
        return 0
    one, two = (min(c) for c in zip(*(cpu_per_frame(first) for _ in range(args.repeats))))
    print(
        f"\nCPU time per frame at {args.size} (least of {args.repeats}): one target {one:.2f} ms, "
        f"two {two:.2f} ms, ratio {two / one:.2f}"
    )
    return 0


def cpu_per_frame(frames: list) -> tuple[float, float]:
    """Process CPU ms per tracked frame of one target (``right_hand``) and of both hands, run back to back."""
    out = []
    tracked = sum(not f.background for f in frames)
    empty = [f for f in frames if f.background]
    background = BackgroundModel.from_frames(empty) if empty else None  # built once, not timed
    for config in (TrackConfig(), TrackConfig(targets=HANDS)):
        t0 = time.process_time()
        for _ in track(frames, config, background=background):
            pass
        out.append(1e3 * (time.process_time() - t0) / tracked)
    return out[0], out[1]


if __name__ == "__main__":
    sys.exit(main())
