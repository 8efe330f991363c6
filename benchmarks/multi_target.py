"""Two hands and the head: paper 000's Table I shape for the multi-target trackers.

Runs on a two-hand synthetic recording (``fusion-pf synth OUT.mcap --hands 2``,
or a ``synth:hands=2,...`` spec rendered on the fly) with whole-frame skin blobs
(:class:`fusion_pf.cues.skin.SkinCue` with paper 002's RGB rule) associated to
the targets, plus, unless ``--skin-only``, the skeleton joint of each target.
Prints per method: RMSE per target (px), identity swaps between the hands,
restarts, likelihood evaluations per frame, and frames per track state
(paper 004); then PF vs SSPF evaluations per frame at equal RMSE, on the
recording's hands and on a scripted fast single-target trajectory.

Usage::

    PYTHONPATH=. python benchmarks/multi_target.py [SOURCE] [--skin-only] [--seed S]

SOURCE defaults to ``synth:hands=2,frames=330,size=320x200,background_frames=30``.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace

import numpy as np

from drivers import open_source
from fusion_pf.cues.base import Measurement
from fusion_pf.cues.skin import RgbRuleSkin, SkinCue
from fusion_pf.filter.kf import KalmanFilter
from fusion_pf.filter.multi import IndependentTrackers, KMeansParticleFilter
from fusion_pf.filter.pf import ParticleFilter
from fusion_pf.filter.sspf import JointScatterSearchPF, ScatterSearchPF
from fusion_pf.multitarget import frame_inputs, identity_swaps, rmse, run_tracker, state_counts

TARGETS = ("right_hand", "left_hand", "head")
HANDS = ("right_hand", "left_hand")
NOISE_PX = {"skin_rgb": 8.0, "skeleton": 6.0}
#: Hands closer than this (px, at 320 px width: about 8 cm) are joined; swaps are not counted there.
SWAP_SEPARATION_PX = 25.0


def methods(seed: int) -> dict[str, object]:
    """The compared trackers (fresh instances)."""
    rng = np.random.default_rng(seed)
    return {
        "k-means PF + supervision": KMeansParticleFilter(TARGETS, n_particles=300, noise_px=NOISE_PX, rng=seed),
        "k-means PF, no supervision": KMeansParticleFilter(
            TARGETS, n_particles=300, noise_px=NOISE_PX, supervision=False, rng=seed
        ),
        "independent PFs (N=100)": IndependentTrackers(
            TARGETS, lambda: ParticleFilter(n_particles=100, noise_px=NOISE_PX, rng=rng)
        ),
        "per-target KFs": IndependentTrackers(TARGETS, lambda: KalmanFilter(noise_px=NOISE_PX)),
        "SSPF per target (N=30)": IndependentTrackers(
            TARGETS, lambda: ScatterSearchPF(n_particles=30, noise_px=NOISE_PX, rng=rng)
        ),
        "joint SSPF (N=100, b=6)": JointScatterSearchPF(TARGETS, n_particles=100, noise_px=NOISE_PX, rng=seed),
    }


def table(inputs, seed: int) -> None:
    """Paper 000 Table I shape, plus swaps, evaluations and state timelines."""
    head = f"{'method':28s} {'RMSE R':>7s} {'RMSE L':>7s} {'RMSE H':>7s} {'swaps':>5s} {'restarts':>8s} {'evals/f':>8s} {'s':>5s}"
    print(head)
    states = {}
    for name, tracker in methods(seed).items():
        t0 = time.perf_counter()
        run = run_tracker(tracker, inputs)
        dt = time.perf_counter() - t0
        r = [rmse(run, inputs, t) for t in TARGETS]
        swaps = identity_swaps(run, inputs, HANDS, SWAP_SEPARATION_PX)
        print(
            f"{name:28s} {r[0]:7.2f} {r[1]:7.2f} {r[2]:7.2f} {swaps:5d} {sum(run.restarts.values()):8d} "
            f"{run.evaluations.mean():8.0f} {dt:5.1f}"
        )
        states[name] = {t: state_counts(run, t) for t in HANDS}
    print("\nframes per state (right hand / left hand):")
    for name, per in states.items():
        cells = ", ".join(
            f"{s} {per['right_hand'][s]}/{per['left_hand'][s]}"
            for s in per["right_hand"]
            if per["right_hand"][s] or per["left_hand"][s]
        )
        print(f"  {name:28s} {cells}")


def equal_rmse(inputs, seed: int) -> None:
    """Likelihood evaluations per frame of independent PFs and SSPFs and the hands' mean RMSE."""
    print(f"\n{'filter':16s} {'N':>5s} {'evals/f':>8s} {'RMSE hands':>10s}")
    rows = []
    for kind, ns in (("PF", (10, 25, 50, 100, 200, 400)), ("SSPF", (10, 20, 30))):
        for n in ns:
            rng = np.random.default_rng(seed)
            make = (
                (lambda n=n, rng=rng: ParticleFilter(n_particles=n, noise_px=NOISE_PX, rng=rng))
                if kind == "PF"
                else (lambda n=n, rng=rng: ScatterSearchPF(n_particles=n, noise_px=NOISE_PX, rng=rng))
            )
            run = run_tracker(IndependentTrackers(HANDS, make), inputs)
            e = run.evaluations.mean() / len(HANDS)
            r = float(np.mean([rmse(run, inputs, t) for t in HANDS]))
            rows.append((kind, n, e, r))
            print(f"{kind:16s} {n:5d} {e:8.0f} {r:10.2f}")
    for kind, n, e, r in rows:
        if kind != "SSPF":
            continue
        match = [(pe, pn) for pk, pn, pe, pr in rows if pk == "PF" and pr <= r]
        text = (
            f"PF needs N={min(match)[1]} ({min(match)[0]:.0f} evals/frame)"
            if match
            else "no PF N in the sweep reaches it"
        )
        print(f"SSPF N={n}: RMSE {r:.2f} px with {e:.0f} evals/frame per target; {text}")


def scripted(seed: int) -> None:
    """PF vs SSPF on a fast manoeuvring single target (up to 24 px / frame), the same motion model."""
    t = np.arange(200)
    truth = np.stack([320 + 150 * np.sin(2 * np.pi * t / 40), 200 + 80 * np.sin(2 * np.pi * t / 27)], 1)
    z = truth + np.random.default_rng(seed + 1).normal(0.0, 6.0, truth.shape)
    model = {"process_noise": (8.0, 3.0), "noise_px": {"colour": 6.0}}
    print("\nscripted fast trajectory (200 frames, cue sigma 6 px, process noise (8, 3) for both):")
    print(f"{'filter':16s} {'N':>5s} {'evals/f':>8s} {'RMSE':>8s}")
    for kind, ns in (("PF", (100, 200, 400, 800, 1600)), ("SSPF", (10, 20, 30))):
        for n in ns:
            f = (
                ParticleFilter(n_particles=n, rng=seed, **model)
                if kind == "PF"
                else ScatterSearchPF(n_particles=n, rng=seed, **model)
            )
            est, evals = [], []
            for k in range(len(t)):
                e = f.step(k * 33_333_333, [Measurement("colour", *z[k])])
                est.append((e.u, e.v))
                evals.append(getattr(f, "evaluations", n))
            err = np.hypot(*(np.array(est) - truth).T)[5:]
            print(f"{kind:16s} {n:5d} {np.mean(evals):8.0f} {np.sqrt((err**2).mean()):8.2f}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("source", nargs="?", default="synth:hands=2,frames=330,size=320x200,background_frames=30")
    p.add_argument("--skin-only", action="store_true", help="no skeleton joints (paper 000: skin only)")
    p.add_argument("--seed", type=int, default=0, help="filter seed")
    args = p.parse_args(argv)
    skin = SkinCue(RgbRuleSkin(), min_area=30)
    with open_source(args.source) as src:
        t0 = time.perf_counter()
        inputs = frame_inputs(iter(src), TARGETS, skin, skeleton=not args.skin_only)
    print(
        f"{args.source}: {len(inputs)} person frames, measurements in {time.perf_counter() - t0:.1f} s, "
        f"{'skin blobs only' if args.skin_only else 'skin blobs + skeleton joints'}\n"
    )
    if not all(set(HANDS) <= set(fi.truths) for fi in inputs):
        print("the source has no per-hand ground truth (make it with --hands 2)", file=sys.stderr)
        return 2
    table(inputs, args.seed)
    equal_rmse([replace(fi, labelled={t: fi.labelled.get(t, []) for t in HANDS}) for fi in inputs], args.seed)
    scripted(args.seed)
    return 0


if __name__ == "__main__":
    sys.exit(main())
