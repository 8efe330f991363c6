"""Tracking in world coordinates with several calibrated cameras (issue 26 item 3): 3-D accuracy per hand.

For every scene (camera count and colour-only cameras) and seed, the two-hand
synthetic rig (``fusion-pf synth --cameras N --colour-only K --hands 2 --occlude auto``, the
last K cameras without depth) is rendered and tracked by
:func:`fusion_pf.pipeline.world.track_world` with ``targets=(right_hand,
left_hand)`` and default options; printed per scene, seed and hand: the 3-D
RMSE (mm) against ``/ground_truth/world``, its median, the RMSE over the
instants at which one camera cannot see the hand (``--occlude auto``: a card
in front of one camera hides each hand once; ``/ground_truth/visibility``), the RMSE while the hands are joined
(true centres closer than the world tracker's combine distance, :data:`fusion_pf.pipeline.world.COMBINE_MM`: one
blob of the two) and while apart, at the instants one
camera alone sees the hand the error along and across that camera's line of sight (RMS; the depth
along a single line of sight is what one camera leaves unobserved), coverage and identity
swaps (:func:`fusion_pf.score.targets.score_world`); pooled per scene, the joined error split into the pair's
midpoint ``(r + l) / 2`` and half-offset ``(r - l) / 2`` (each hand's error is their sum or difference), and the
joined pair's estimated gap between the hands against the true one. Beside it, the
single-camera depth back-projection on the same scene: cam0's view alone
(``McapReplay(camera="cam0")``) tracked by the 2-D pipeline
(:func:`fusion_pf.pipeline.track`, same targets), each hand's ``xyz_mm``
moved to the world with cam0's pose.

Usage::

    PYTHONPATH=. python benchmarks/rig3d.py [--tuned 1,2] [--held-out 11,12] [--frames 160] [--size 640x400] [--recordings DIR] [--seed N]

``--recordings DIR`` keeps the rendered scenes there (``rig_CAMERAS_COLOUR-ONLY_SEED_SIZE_FRAMES.mcap``) and renders only those
missing, so that a second run (another version of the tracker) tracks the same recordings.

The seeds of ``--tuned`` are those the world tracker's constants were chosen on;
``--held-out`` seeds are reported separately. ``--seed`` is the trackers' seed (``fusion-pf track --seed``; default
the tracker's own), so that several filter seeds of the same scenes can be compared.
"""

from __future__ import annotations

import argparse
import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from drivers.mcap_replay import McapReplay
from drivers.rig import RigReplay
from fusion_pf.pipeline import TrackConfig, track
from fusion_pf.pipeline.world import COMBINE_MM, track_world
from fusion_pf.score.targets import score_world

HANDS = ("right_hand", "left_hand")
BACKGROUND_FRAMES = 10
#: (cameras, colour-only cameras) of the scenes.
SCENES = ((2, 0), (2, 1), (3, 1), (4, 2))


def render(out: Path, cameras: int, colour_only: int, seed: int, frames: int, size: str) -> None:
    """``fusion-pf synth`` of the two-hand rig into ``out``."""
    cmd = [sys.executable, "-m", "fusion_pf", "synth", str(out), "--cameras", str(cameras), "--colour-only"]
    cmd += [str(colour_only), "--hands", "2", "--frames", str(frames), "--background-frames", str(BACKGROUND_FRAMES)]
    cmd += ["--seed", str(seed), "--size", size, "--occlude", "auto", "--no-progress", "--force"]
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)


def world(path: Path, config: TrackConfig) -> tuple[dict, np.ndarray, float]:
    """World tracking of ``path``: per hand positions, truths, states; per hand 'a camera cannot see it' flags; ms per instant."""
    pos = {t: [] for t in HANDS}
    ref = {t: [] for t in HANDS}
    states = {t: [] for t in HANDS}
    silent = {t: [] for t in HANDS}
    alone = {t: [] for t in HANDS}
    t0 = time.process_time()
    with RigReplay(path) as rig:
        for r in track_world(rig, config):
            if r.background:
                continue
            for t in HANDS:
                w = r.targets[t]
                pos[t].append(np.full(3, math.nan) if w.position_mm is None else w.position_mm)
                ref[t].append(np.full(3, math.nan) if w.truth_mm is None else w.truth_mm)
                states[t].append(w.state)
                seen = (rig.visibility or {}).get(r.timestamp_ns, {})
                silent[t].append(any(t not in seen.get(c, ()) for c in rig.cameras))
                sees = [c for c in rig.cameras if t in seen.get(c, ())]
                alone[t].append(rig.poses[sees[0]].translation_mm if len(sees) == 1 else np.full(3, math.nan))
    ms = 1e3 * (time.process_time() - t0) / max(len(states[HANDS[0]]), 1)
    data = {
        "positions": {t: np.array(v) for t, v in pos.items()},
        "truths": {t: np.array(v) for t, v in ref.items()},
        "states": states,
        "alone": {t: np.array(v) for t, v in alone.items()},
    }
    return data, {t: np.array(v) for t, v in silent.items()}, ms


def along_across(data: dict, t: str) -> tuple[np.ndarray, np.ndarray]:
    """The errors of hand ``t`` along and across the line of sight of the one camera that sees it (instants one
    camera alone sees it; mm): ``|e . d|`` and ``|e - (e . d) d|``, ``d`` the unit direction from that camera to the truth."""
    est, truth, centre = data["positions"][t], data["truths"][t], data["alone"][t]
    ok = np.isfinite(est).all(axis=1) & np.isfinite(truth).all(axis=1) & np.isfinite(centre).all(axis=1)
    d = truth[ok] - centre[ok]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    e = est[ok] - truth[ok]
    along = (e * d).sum(axis=1)
    return np.abs(along), np.linalg.norm(e - along[:, None] * d, axis=1)


def joined_mask(data: dict) -> np.ndarray:
    """Instants the two hands' true centres are closer than :data:`COMBINE_MM` (joined: one blob of the two)."""
    a, b = (data["truths"][t] for t in HANDS)
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(a - b, axis=1) < COMBINE_MM


def pair_errors(data: dict) -> tuple[np.ndarray, np.ndarray]:
    """While joined (:func:`joined_mask`), the error of the pair's midpoint ``(r + l) / 2`` and of its half-offset
    ``(r - l) / 2`` (mm, instants both hands have an estimate): each hand's error is their sum or difference."""
    er, el = (data["positions"][t] for t in HANDS)
    tr, tl = (data["truths"][t] for t in HANDS)
    ok = joined_mask(data) & np.isfinite(er).all(axis=1) & np.isfinite(el).all(axis=1)
    mid = np.linalg.norm((er + el)[ok] / 2 - (tr + tl)[ok] / 2, axis=1)
    half = np.linalg.norm((er - el)[ok] / 2 - (tr - tl)[ok] / 2, axis=1)
    return mid, half


def gap_errors(data: dict) -> np.ndarray:
    """While joined (:func:`joined_mask`), the estimated distance between the two hands minus the true one (mm, instants
    both hands have an estimate): whether the tracker holds the joined pair's gap, too wide (> 0) or too narrow."""
    er, el = (data["positions"][t] for t in HANDS)
    tr, tl = (data["truths"][t] for t in HANDS)
    ok = joined_mask(data) & np.isfinite(er).all(axis=1) & np.isfinite(el).all(axis=1)
    return np.linalg.norm((er - el)[ok], axis=1) - np.linalg.norm((tr - tl)[ok], axis=1)


def rms(values: np.ndarray) -> float:
    """Root mean square, NaN for none."""
    return float(np.sqrt(np.mean(values**2))) if values.size else math.nan


def single_camera(path: Path, config: TrackConfig, truths: dict[str, np.ndarray]) -> dict:
    """cam0 alone through the 2-D pipeline, its depth back-projection moved to the world: per hand positions."""
    with RigReplay(path) as rig:
        pose = rig.poses[rig.cameras[0]]
        camera = rig.cameras[0]
    pos = {t: [] for t in HANDS}
    states = {t: [] for t in HANDS}
    with McapReplay(path, camera=camera) as src:
        for r in track(src, config):
            if r.background:
                continue
            for t in HANDS:
                x = r.targets[t].xyz_mm
                pos[t].append(np.full(3, math.nan) if x is None else pose.to_world(x))
                states[t].append(r.targets[t].state)
    return {"positions": {t: np.array(v) for t, v in pos.items()}, "truths": truths, "states": states}


def tracker_config(seed: int | None) -> TrackConfig:
    """Default options for both hands; the trackers' seed ``seed`` (None: the tracker's default)."""
    return TrackConfig(targets=HANDS) if seed is None else TrackConfig(targets=HANDS, seed=seed)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tuned", default="1,2", help="seeds the constants were tuned on (default 1,2)")
    p.add_argument("--held-out", default="11,12", help="seeds not tuned on, reported separately (default 11,12)")
    p.add_argument("--frames", type=int, default=160, help="instants per scene, 10 background ones included")
    p.add_argument("--size", default="640x400", help="image size WxH of every camera")
    p.add_argument(
        "--recordings", type=Path, default=None, help="keep the rendered scenes in this folder and reuse them"
    )
    p.add_argument("--scenes", default=",".join(f"{c}:{k}" for c, k in SCENES), help="CAMERAS:COLOUR_ONLY,...")
    p.add_argument("--seed", type=int, default=None, help="the trackers' seed (default: the tracker's own)")
    args = p.parse_args(argv)
    scenes = [tuple(int(v) for v in s.split(":")) for s in args.scenes.split(",")]
    groups = [("tuned", args.tuned), ("held-out", args.held_out)]
    config = tracker_config(args.seed)
    print(
        "| seeds | cameras | colour-only | seed | hand | 3-D RMSE (mm) | median (mm) | RMSE while a camera cannot see it (mm, instants) "
        "| along / across the one seeing camera's line of sight (RMS mm, instants) | joined / apart RMSE (mm, instants joined) "
        "| coverage | swaps | ms/instant | cam0 back-projection RMSE (mm) | its median (mm) | its coverage | its swaps |"
    )
    print("|---|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    pooled: dict[tuple[str, int, int], list[float]] = {}
    ray_errors: dict[tuple[str, int, int], tuple[list[float], list[float]]] = {}
    pairs: dict[tuple[str, int, int], tuple[list[float], list[float]]] = {}
    gaps: dict[tuple[str, int, int], list[float]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.recordings or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for group, seeds in groups:
            for seed in (int(s) for s in seeds.split(",") if s):
                for cameras, colour_only in scenes:
                    path = folder / f"rig_{cameras}_{colour_only}_{seed}_{args.size}_{args.frames}.mcap"
                    if args.recordings is None or not path.exists():
                        render(path, cameras, colour_only, seed, args.frames, args.size)
                    data, silent, ms = world(path, config)
                    res = score_world(**{k: v for k, v in data.items() if k != "alone"})
                    base = score_world(**single_camera(path, config, data["truths"]))
                    joined = joined_mask(data)
                    mid, half = pair_errors(data)
                    pairs.setdefault((group, cameras, colour_only), ([], []))[0].extend(mid.tolist())
                    pairs[(group, cameras, colour_only)][1].extend(half.tolist())
                    gaps.setdefault((group, cameras, colour_only), []).extend(gap_errors(data).tolist())
                    for t in HANDS:
                        r, b = res["targets"][t], base["targets"][t]
                        err = res["errors"][t]
                        hidden = err[silent[t] & np.isfinite(err)]
                        hidden_rmse = float(np.sqrt(np.mean(hidden**2))) if hidden.size else math.nan
                        pooled.setdefault((group, cameras, colour_only), []).extend(err[np.isfinite(err)].tolist())
                        along, across = along_across(data, t)
                        ray_errors.setdefault((group, cameras, colour_only), ([], []))[0].extend(along.tolist())
                        ray_errors[(group, cameras, colour_only)][1].extend(across.tolist())
                        rms_along, rms_across = rms(along), rms(across)
                        ok = np.isfinite(err)
                        print(
                            f"| {group} | {cameras} | {colour_only} | {seed} | {t} | {r['rmse_mm']:.1f} | "
                            f"{r['median_mm']:.1f} | {hidden_rmse:.1f} ({hidden.size}) | {rms_along:.1f} / {rms_across:.1f} ({along.size}) | "
                            f"{rms(err[ok & joined]):.1f} / {rms(err[ok & ~joined]):.1f} ({int((ok & joined).sum())}) | {100 * r['coverage']:.1f} % | "
                            f"{res['swaps']} | {ms:.0f} | {b['rmse_mm']:.1f} | {b['median_mm']:.1f} | "
                            f"{100 * b['coverage']:.1f} % | {base['swaps']} |",
                            flush=True,
                        )
                    if args.recordings is None:
                        path.unlink()
    print("\nPooled 3-D RMSE per seed group and scene (both hands):")
    for (group, cameras, colour_only), errs in pooled.items():
        e = np.array(errs)
        a, c = (np.array(v) for v in ray_errors[(group, cameras, colour_only)])
        ratio = f"{rms(a):.1f} / {rms(c):.1f} mm" if a.size else "-"
        mid, half = (np.array(v) for v in pairs[(group, cameras, colour_only)])
        gap = np.array(gaps[(group, cameras, colour_only)])
        bias = f"{gap.mean():+.1f}" if gap.size else "-"
        print(
            f"  {group:8s} {cameras} cameras, {colour_only} colour-only: {rms(e):.1f} mm; "
            f"one camera seeing it ({a.size} instants), along / across its line of sight: {ratio}; "
            f"joined ({mid.size} instants), the pair's midpoint / half-offset: {rms(mid):.1f} / {rms(half):.1f} mm, "
            f"estimated minus true gap between the hands RMS / mean: {rms(gap):.1f} / {bias} mm"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
