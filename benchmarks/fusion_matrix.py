"""Fusion over a matrix of synthetic scenes: is the fused estimate at least as good as its best cue on each?

Usage (from the repository root)::

    python benchmarks/fusion_matrix.py [--out DIR] [--jobs J] [--frames N] [--only NAME,...]
        [--recordings DIR] [--save FILE.json] [--compare FILE.json] [--noise-split] [--startup] [--bestmax]
        [--generate FIRST:COUNT] [--away N] [-- TRACK OPTIONS]

Every scene of :data:`SCENES` is rendered with ``fusion-pf synth`` (its size, seed and scene
variations: depth noise, the palm's distance in front of the body, lighting, skin tone, skeleton
failure; ``drivers/synth.py``, "Scene variations"), tracked with default ``fusion-pf track`` (plus
any TRACK OPTIONS after ``--``) and scored with ``fusion-pf score --ground-truth --json``. The
scenes are chosen so that, in turn, each cue is the best by a wide margin, or all are close.

Printed per scene: the RMSE (px) of each cue alone (its own coverage in brackets when below
100 %), of the fused estimate, ``ratio`` = fused / best cue, the fused estimate's BestMax share
(paper 003 §4.4: frames where it is the closest of all sources), its coverage, and ``2sd`` = the
share of tracked frames whose error is below twice the reported ``sigma_px``. Then, separately for
the ``tune`` scenes (used while changing the fusion), the ``held`` ones (never looked at while
tuning: other seeds and other combinations; seen once by the first round of issue 23 C) and the
``new`` ones (held out from the second round on) and the ``fresh`` ones (held out from the
third round on): the mean and worst ratio, the scenes where
fused is not above the best cue, and the mean BestMax share.

``paired`` = fused / best cue over the frames where both have an error (the best cue's own frames):
the plain ratio compares RMSEs over different frames, and a cue that measures in a few easy frames
can be "best". Main 9938aa1, default track, seed 0: ``--generate 22001:30``'s gen-22008-near-800,
colour 19.5 px over 5 % of the frames, fused 21.6 over all of them: ratio 1.11, paired 0.16;
``--generate 23001:30``'s gen-23014-colour-400: ratio 3.95, paired 0.24. Over those 60 scenes the
ratio is above 1 on 8, the paired ratio on 4 (far hands with a sub-pixel depth cue at full coverage,
and one first frame 81 px off). The split summary gives both means and both lists of scenes above 1.

The ratio alone can flatter a worse track: each cue is measured in the tracker's window, so a worse
track can make the best cue worse too. ``--save`` keeps a run's table as JSON and ``--compare``
prints every scene's fused RMSE against such an earlier run, and per split the geometric mean of
new / old. ``--recordings`` takes the rendered scenes from an earlier run's ``--out`` (same
``--frames``) instead of rendering them again. ``--noise-split`` also prints, per scene and cue, the
median error and the white noise the calibration measures from the cue alone (``filter/calibration.py``):
a cue whose median error is well above its white noise is off by a slow bias, which no floor set from the
white noise may trust. ``--startup`` also prints, per scene, the RMSE of the fused estimate and of the
scene's best cue over the first :data:`STARTUP_FRAMES` tracked frames and over the rest. On main 479f794
(default track, seed 0) the three tune scenes where fused is above its best cue lose most of it there,
while the calibration has no residuals yet: first / rest, fused against the best cue, far-hand-noisy-640b
1.74 / 0.64 px against depth's 0.38 / 0.72, skeleton-lit-320 3.02 / 1.10 against the skeleton's
1.50 / 1.32, far-hand-sharp-960 1.14 / 0.33 against depth's 0.26 / 0.28.

``--generate FIRST:COUNT`` replaces the fixed matrix by COUNT scenes drawn from the seeds FIRST..
(:func:`generated_scenes`: every variation drawn, the kind of scene, i.e. which cue should win, set by the
seed), reported as the split ``generated``: a fresh held-out matrix for any change, as long as nobody
tuned on those seeds. ``--generate 20001:30`` (session 11's lead set, never shown to a helper before it
was measured), main dc73706, default track, seed 0: ratio mean 0.68, fused above the best cue on 5 of
30 (1.01-1.73x, each where depth is the best cue at 0.4-1.9 px), BestMax mean 50 %, against
``498736c`` (before issue 22's one pipeline) fused new / old geometric mean 0.53, worse on 5 of 30.

``--away N`` sends the person out of view N of every 100 frames in every scene (:func:`away_scenes`, ``synth
--away``, names ``NAME-awayN``): the track is lost and re-acquired, which no other scene asks. Main 146bd06 against
``96c9a9c`` (a reset filter forgets its last start; a lost track is re-acquired only by a cue another one agrees
with or of quality 0.5 or more; 0.8 since session 30), default track, seed 0, ``--away 30``: ``--generate 45101:24`` (held out: never looked
at frame by frame) fused new / old geometric mean 0.736, ratio mean 1.52 -> 1.33 (gen-45103-far-560 8.75 -> 0.86 px,
gen-45115-far-800 14.04 -> 1.58; worse on 8, gen-45123-skel-560 2.43 -> 14.46); development sets 45201:12 0.431 and
the skel and near scenes of 45301:60 0.621 (gen-45321-skel-1024 4.30 -> 14.94: a track started on a scrap of the
room before the person first came in, then slow to leave it).

``--bestmax`` also prints, per scene, where the fused estimate loses BestMax (:func:`bestmax_split`):
*behind* the winning cue (fused sits nearest that cue, a smoothed or pulled copy of it) or *elsewhere*
(nearer a cue further from the truth), with the median errors and each part's share of the fused squared
error, and the mean fused error along the palm's motion. On main 36038c9 (tune split, seed 0) the lag is
under 0.6 px on every scene (the estimate does not trail the palm), and the large scenes lose most frames
behind a sub-pixel cue (big-1280: won 12 %, behind 62 %, fused 0.58 against depth's 0.15 px, 14 % of the
squared error; elsewhere 26 %, on depth's 4-6 px runs at quality 0.5-0.6 while colour is 0.6 px off, 86 %).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

CUES = ("colour", "depth", "skeleton")
#: Tracked frames ``--startup`` counts as the start of a scene (:func:`startup_split`).
STARTUP_FRAMES = 20


@dataclass(frozen=True)
class Scene:
    """One synthetic scene of the matrix."""

    name: str
    split: str  # "tune", "held", "new" or "fresh"
    seed: int
    size: str
    options: dict[str, float] = field(default_factory=dict)


#: The splits, in report order: ``tune`` (looked at while changing the fusion), then held-out sets in the
#: order they were added (``held``, ``new``, ``fresh``), each run only to report.
SPLITS = ("tune", "held", "new", "fresh")
#: The matrix. ``tune``: seeds 1-4, looked at while changing the fusion; ``held``: seeds 5-8 and
#: other combinations, only run to report (seen by the first round of issue 23 C); ``new``: seeds
#: 9-12, held out from the second round on; ``fresh``: seeds 13-16, held out from the third.
SCENES = (
    Scene("default-640", "tune", 1, "640x400"),
    Scene("skeleton-best", "tune", 2, "640x400", {"skeleton_bias": 0.0, "depth_noise": 8.0, "hand_front": 0.05}),
    Scene("colour-best", "tune", 1, "640x400", {"skeleton_bias": 2.5, "depth_noise": 8.0, "hand_front": 0.04}),
    Scene("dark-skin-320", "tune", 2, "320x200", {"skin_tone": 1.0}),
    Scene("all-close-960", "tune", 1, "960x540", {"depth_noise": 5.0, "skeleton_bias": 0.3, "hand_front": 0.1}),
    Scene("big-1280", "tune", 2, "1280x720"),
    Scene("lighting-320", "tune", 1, "320x200", {"lighting": 4.0}),
    Scene("default-320", "held", 5, "320x200"),
    Scene("skeleton-best-1280", "held", 6, "1280x720", {"skeleton_bias": 0.0, "depth_noise": 6.0, "hand_front": 0.06}),
    Scene("near-body-640", "held", 7, "640x400", {"hand_front": 0.05, "skin_tone": 0.5}),
    Scene("lighting-bias-960", "held", 8, "960x540", {"lighting": 3.0, "skeleton_bias": 2.0}),
    Scene("far-hand-noisy-640", "held", 5, "640x400", {"depth_noise": 3.0, "hand_front": 0.4}),
    Scene("colour-best-320", "held", 6, "320x200", {"skeleton_bias": 3.0, "depth_noise": 10.0, "hand_front": 0.04}),
    # second round (issue 23 C): more tuning seeds, and held-out scenes not seen by the first round
    Scene("skeleton-best-960", "tune", 3, "960x540", {"skeleton_bias": 0.0, "depth_noise": 6.0, "hand_front": 0.06}),
    Scene("far-hand-noisy-320", "tune", 3, "320x200", {"depth_noise": 3.0, "hand_front": 0.4}),
    Scene("lighting-bias-640", "tune", 4, "640x400", {"lighting": 3.0, "skeleton_bias": 2.0}),
    Scene("far-hand-noisy-640b", "tune", 4, "640x400", {"depth_noise": 3.0, "hand_front": 0.4}),
    # third round (issue 23 C): tune scenes reproducing the second round's held-out failures (an accurate
    # skeleton beside a colour cue biased by lighting drift; a far hand with very accurate depth)
    Scene(
        "skeleton-lit-320",
        "tune",
        3,
        "320x200",
        {"skeleton_bias": 0.0, "depth_noise": 7.0, "hand_front": 0.05, "lighting": 2.0},
    ),
    Scene(
        "skeleton-lit-400",
        "tune",
        4,
        "400x250",
        {"skeleton_bias": 0.0, "depth_noise": 6.0, "hand_front": 0.06, "lighting": 2.5},
    ),
    Scene(
        "skeleton-lit-320b",
        "tune",
        1,
        "320x200",
        {"skeleton_bias": 0.0, "depth_noise": 8.0, "hand_front": 0.05, "lighting": 2.0},
    ),
    Scene(
        "skeleton-lit-320c",
        "tune",
        2,
        "320x200",
        {"skeleton_bias": 0.0, "depth_noise": 7.0, "hand_front": 0.05, "lighting": 2.0},
    ),
    Scene("far-hand-sharp-960", "tune", 2, "960x540", {"depth_noise": 2.0, "hand_front": 0.4}),
    Scene("colour-best-960", "new", 9, "960x540", {"skeleton_bias": 2.0, "depth_noise": 9.0, "hand_front": 0.05}),
    Scene(
        "skeleton-best-lit-320",
        "new",
        10,
        "320x200",
        {"skeleton_bias": 0.0, "depth_noise": 7.0, "hand_front": 0.05, "lighting": 2.0},
    ),
    Scene("dark-far-1280", "new", 11, "1280x720", {"skin_tone": 0.8, "hand_front": 0.3, "depth_noise": 2.0}),
    Scene(
        "all-close-640",
        "new",
        12,
        "640x400",
        {"depth_noise": 4.0, "skeleton_bias": 0.5, "hand_front": 0.15, "skin_tone": 0.3},
    ),
    # held out from the third round on (never run before its final table)
    Scene(
        "lit-skeleton-800",
        "fresh",
        13,
        "800x450",
        {"skeleton_bias": 0.0, "depth_noise": 6.0, "hand_front": 0.05, "lighting": 2.5},
    ),
    Scene("far-sharp-1024", "fresh", 14, "1024x576", {"depth_noise": 2.5, "hand_front": 0.35, "skin_tone": 0.4}),
    Scene(
        "mixed-480",
        "fresh",
        15,
        "480x300",
        {"lighting": 3.0, "skeleton_bias": 1.0, "depth_noise": 4.0, "hand_front": 0.1},
    ),
    Scene(
        "dark-colour-best-360",
        "fresh",
        16,
        "360x240",
        {"skin_tone": 0.6, "skeleton_bias": 2.5, "depth_noise": 9.0, "hand_front": 0.04},
    ),
)


#: Split of the scenes :func:`generated_scenes` draws (``--generate``), reported after the fixed matrix's.
GENERATED = "generated"
#: Image sizes :func:`generated_scenes` draws from.
GENERATED_SIZES = (
    "320x200",
    "360x240",
    "400x250",
    "480x300",
    "560x350",
    "640x400",
    "800x450",
    "960x540",
    "1024x576",
    "1280x720",
)
#: Kinds of generated scene, in turn by seed: which cue should be best, or how far the palm is from the body.
GENERATED_KINDS = ("near", "far", "mid", "skel", "colour", "lit")


def generated_scenes(first: int, count: int) -> tuple[Scene, ...]:
    """``count`` scenes of seeds ``first, first + 1, ...``, each drawn from its own seed: a fresh held-out matrix.

    Every scene varies the size, depth noise, skin tone, clothing, clutter, lighting, skeleton bias and the
    palm's distance in front of the body; its kind (:data:`GENERATED_KINDS`, ``seed % 6``) then sets the
    variations that decide which cue is best: ``near`` a palm 3-7 cm before the body, ``far`` 30-50 cm with
    sharp depth, ``skel`` an unbiased skeleton beside noisy depth near the body, ``colour`` a biased
    skeleton and noisy depth near the body, ``lit`` a lighting drift, ``mid`` none. The same seed gives the
    same scene on any machine, so a set of seeds nobody tuned on is a matrix nobody tuned on.
    """
    return tuple(_generated_scene(seed) for seed in range(first, first + count))


def away_scenes(scenes: Sequence[Scene], away: int) -> tuple[Scene, ...]:
    """``scenes`` with the person away ``away`` of every 100 frames (``synth --away``), named ``NAME-awayN``: the
    track is lost while nobody is in view and re-acquired when the person is back, which the other scenes never ask."""
    return tuple(replace(s, name=f"{s.name}-away{away}", options={**s.options, "away": away}) for s in scenes)


def _generated_scene(seed: int) -> Scene:
    """One scene of :func:`generated_scenes`, drawn from ``np.random.default_rng(seed)``."""
    rng = np.random.default_rng(seed)
    size = GENERATED_SIZES[int(rng.integers(len(GENERATED_SIZES)))]
    kind = GENERATED_KINDS[seed % len(GENERATED_KINDS)]

    def draw(lo: float, hi: float, digits: int = 2) -> float:
        return round(float(rng.uniform(lo, hi)), digits)

    o: dict[str, float] = {
        "depth_noise": round(float(np.exp(rng.uniform(math.log(1.5), math.log(12.0)))), 2),
        "skin_tone": draw(0.0, 1.0),
        "clothing": float(rng.integers(0, 6)),
        "clutter": int(rng.integers(0, 12)),
        "lighting": draw(0.5, 2.0),
        "skeleton_bias": draw(0.5, 2.5),
        "hand_front": draw(0.1, 0.3),
    }
    if kind == "near":
        o["hand_front"] = draw(0.03, 0.07, 3)
    elif kind == "far":
        o["hand_front"], o["depth_noise"] = draw(0.3, 0.5), draw(1.5, 3.0)
    elif kind == "skel":
        o["skeleton_bias"], o["depth_noise"], o["hand_front"] = 0.0, draw(6.0, 10.0), draw(0.04, 0.08, 3)
    elif kind == "colour":
        o["skeleton_bias"], o["depth_noise"], o["hand_front"] = draw(2.0, 3.0), draw(8.0, 11.0), draw(0.03, 0.06, 3)
    elif kind == "lit":
        o["lighting"] = draw(2.0, 4.0)
    return Scene(f"gen-{seed}-{kind}-{size.split('x')[0]}", GENERATED, seed, size, o)


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "fusion_pf", *args]


def _run(cmd: list[str]) -> str:
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {done.returncode}: {done.stderr.strip()[-500:]}")
    return done.stdout


def coverage_2sd(table: Path, scene: Scene, frames: int) -> float:
    """Share of tracked rows whose error is below ``2 sigma_px`` (ground truth from the synthetic source itself)."""
    from drivers.synth import SynthSource

    w, h = (int(x) for x in scene.size.split("x"))
    src = SynthSource(frames=frames, seed=scene.seed, size=(w, h), background_frames=10, **scene.options)
    return within_2sd(table, src.ground_truth)


def within_2sd(table: Path, truth) -> float:
    """Share of ``table``'s tracked rows whose error against ``truth(frame)`` (a PalmPoint or None) is below
    ``2 sigma_px``."""
    hits = []
    with open(table, newline="") as f:
        for row in csv.DictReader(f):
            if not row["u"] or not row["sigma_px"]:
                continue
            g = truth(int(row["frame"]))
            if g is None:
                continue
            err = float(np.hypot(float(row["u"]) - g.u, float(row["v"]) - g.v))
            hits.append(err <= 2.0 * float(row["sigma_px"]))
    return float(np.mean(hits)) if hits else float("nan")


def noise_split(table: Path, scene: Scene, frames: int) -> dict[str, tuple[float, float, float, float]]:
    """Per cue of the tracked ``table``: its median error, white noise, slow error and online slow error per axis, px.

    The median error is ``sqrt(median(|z - g|^2 / 2) / ln 2)`` against the synthetic source's ground
    truth ``g``; the white noise is :func:`fusion_pf.filter.calibration.white_noise` of the cue's unit-norm
    third differences over 4 frames in a row, what the calibration sees without the ground truth. A cue
    whose median error is well above its white noise has an error that is mostly slow bias. The slow
    error is ``sqrt(median error^2 - white^2)`` (from the truth); the online one, what the calibration
    estimates without it, is the median over the frames of ``sqrt(B_s)`` of
    :func:`fusion_pf.filter.calibration.slow_errors` on the last ``SLOW_WINDOW`` frames each pair of
    cues measured with quality ``SELF_QUALITY`` or more, a lone pair split by the cues' white noise above (px
    here, at the palm scale of the scene).
    """
    from drivers.synth import SynthSource
    from fusion_pf.filter.calibration import (
        SELF_ORDER,
        SELF_QUALITY,
        SLOW_MIN,
        SLOW_WINDOW,
        difference_weights,
        slow_errors,
        slow_offset,
        white_noise,
    )

    w, h = (int(x) for x in scene.size.split("x"))
    src = SynthSource(frames=frames, seed=scene.seed, size=(w, h), background_frames=10, **scene.options)
    with open(table, newline="") as f:
        rows = list(csv.DictReader(f))
    frame = np.array([int(r["frame"]) for r in rows])
    truth = [src.ground_truth(int(k)) for k in frame]
    g = np.array([(t.u, t.v) if t is not None else (np.nan, np.nan) for t in truth])
    weights = difference_weights(np.arange(SELF_ORDER + 1.0))
    out = {}
    zs = {}
    for c in CUES:
        if f"{c}_u" not in rows[0]:
            continue
        z = np.array([[float(r[f"{c}_{a}"]) if r[f"{c}_{a}"] else np.nan for a in "uv"] for r in rows])
        q = np.array([float(r[f"{c}_quality"]) if r.get(f"{c}_quality") else np.nan for r in rows])
        zs[c] = np.where((q >= SELF_QUALITY)[:, None], z, np.nan)
        e2 = 0.5 * ((z - g) ** 2).sum(axis=1)
        if not np.isfinite(e2).any():
            continue
        # windows of SELF_ORDER + 1 rows in a row, frames consecutive, the cue in each
        zw = np.lib.stride_tricks.sliding_window_view(z, SELF_ORDER + 1, axis=0)  # (m, 2, SELF_ORDER + 1)
        fw = np.lib.stride_tricks.sliding_window_view(frame, SELF_ORDER + 1)
        ok = np.isfinite(zw).all(axis=(1, 2)) & (fw[:, -1] - fw[:, 0] == SELF_ORDER)
        d = 0.5 * ((zw[ok] @ weights) ** 2).sum(axis=1)
        white = math.sqrt(white_noise(d)) if d.size else float("nan")
        median = math.sqrt(float(np.nanmedian(e2)) / math.log(2.0))
        out[c] = (median, white, math.sqrt(max(median**2 - white**2, 0.0)), float("nan"))
    # per pair the frames both measured, and how many of them precede each frame
    pairs = {}
    for i, a in enumerate(sorted(zs)):
        for b in sorted(zs)[i + 1 :]:
            d = zs[a] - zs[b]
            ok = np.isfinite(d).all(axis=1)
            pairs[(a, b)] = (d[ok], np.cumsum(ok))
    online: dict[str, list[float]] = {c: [] for c in out}
    for end in range(len(rows)):
        offsets = {}
        for key, (d, count) in pairs.items():
            n = int(count[end])
            if n >= SLOW_MIN:
                offsets[key] = slow_offset(d[max(n - SLOW_WINDOW, 0) : n])
        for c, b in slow_errors(offsets, {c: v[1] ** 2 for c, v in out.items() if math.isfinite(v[1])}).items():
            online[c].append(math.sqrt(b))
    return {c: (*v[:3], float(np.median(online[c])) if online[c] else float("nan")) for c, v in out.items()}


def startup_split(table: Path, scene: Scene, frames: int, best: str, first: int = STARTUP_FRAMES) -> tuple[float, ...]:
    """RMSE (px) of the fused estimate and of cue ``best`` over the first ``first`` tracked rows of ``table`` and the rest.

    Rows with a fused estimate and a ground truth count; each RMSE over those where the source measured
    (nan without any). Ground truth from the synthetic source itself.

    Returns
    -------
    (fused first, best first, fused rest, best rest)
    """
    from drivers.synth import SynthSource

    w, h = (int(x) for x in scene.size.split("x"))
    src = SynthSource(frames=frames, seed=scene.seed, size=(w, h), background_frames=10, **scene.options)
    err: dict[str, list[float]] = {"fused": [], best: []}
    with open(table, newline="") as f:
        for row in csv.DictReader(f):
            g = src.ground_truth(int(row["frame"]))
            if not row["u"] or g is None:
                continue
            for name, (u, v) in (("fused", ("u", "v")), (best, (f"{best}_u", f"{best}_v"))):
                e2 = (float(row[u]) - g.u) ** 2 + (float(row[v]) - g.v) ** 2 if row.get(u) else math.nan
                err[name].append(e2)

    def rmse(e: list[float]) -> float:
        a = np.array(e)
        a = a[np.isfinite(a)]
        return math.sqrt(float(a.mean())) if a.size else math.nan

    return rmse(err["fused"][:first]), rmse(err[best][:first]), rmse(err["fused"][first:]), rmse(err[best][first:])


def print_startup_split(rows: list[dict]) -> None:
    """Per scene: fused and best-cue RMSE over the first :data:`STARTUP_FRAMES` tracked frames and the rest (:func:`startup_split`)."""
    print(f"RMSE px, fused / best cue, over the first {STARTUP_FRAMES} tracked frames and over the rest")
    for r in rows:
        ff, bf, fr, br = r["startup"]
        print(
            f"{r['scene'].name:<20} {r['scene'].split:<5} {r['best']:<8} first {ff:6.2f} / {bf:6.2f}  rest {fr:6.2f} / {br:6.2f}"
        )


def bestmax_split(table: Path, scene: Scene, frames: int) -> dict[str, float]:
    """Where the fused estimate loses BestMax in ``table`` (paper 003 §4.4; ground truth from the synthetic source).

    A contested frame has the truth, the fused estimate and at least one cue. The fused estimate loses it
    when a cue is nearer the truth (beyond :data:`~fusion_pf.score.metrics.TIE_TOL_PX`). A lost frame is
    *behind* when the cue nearest the fused estimate is that winning cue (fused is a smoothed or pulled
    copy of the best cue of the frame), else *elsewhere* (fused sits nearer a cue that is further from the
    truth: it follows a wrong cue, or lies between cues). ``lag`` is the mean of the fused error along the
    palm's motion (the truth's central difference; negative: behind the palm).

    Returns
    -------
    dict
        ``frames`` (contested), ``won``, ``behind``, ``elsewhere`` (shares of them); ``behind_fused``,
        ``behind_cue``, ``elsewhere_fused``, ``elsewhere_cue`` (median error of the fused estimate and of
        the winning cue in those frames, px); ``behind_sq``, ``elsewhere_sq`` (their share of the fused
        squared error over the contested frames); ``lag`` and ``speed`` (median palm speed), px and px/frame.
    """
    from drivers.synth import SynthSource
    from fusion_pf.score.metrics import TIE_TOL_PX

    w, h = (int(x) for x in scene.size.split("x"))
    src = SynthSource(frames=frames, seed=scene.seed, size=(w, h), background_frames=10, **scene.options)
    with open(table, newline="") as f:
        rows = list(csv.DictReader(f))

    def points(u: str, v: str) -> np.ndarray:
        return np.array([[float(r[u]), float(r[v])] if r.get(u) and r.get(v) else [np.nan, np.nan] for r in rows])

    truth = [src.ground_truth(int(r["frame"])) for r in rows]
    g = np.array([(t.u, t.v) if t is not None else (np.nan, np.nan) for t in truth])
    fused = points("u", "v")
    cues = np.stack([points(f"{c}_u", f"{c}_v") for c in CUES if f"{c}_u" in rows[0]])  # (cues, n, 2)
    err = np.hypot(*(cues - g).transpose(2, 0, 1))  # (cues, n)
    to_fused = np.hypot(*(cues - fused).transpose(2, 0, 1))
    fe = np.hypot(*(fused - g).T)
    ok = np.isfinite(fe) & np.isfinite(err).any(axis=0)
    winner = np.argmin(np.where(np.isfinite(err), err, np.inf), axis=0)
    best = np.take_along_axis(np.where(np.isfinite(err), err, np.inf), winner[None], axis=0)[0]
    nearest = np.argmin(np.where(np.isfinite(to_fused), to_fused, np.inf), axis=0)
    lost = ok & (fe > best + TIE_TOL_PX)
    behind, elsewhere = lost & (nearest == winner), lost & (nearest != winner)
    # the palm's motion per frame: central differences of the truth over consecutive frames
    frame = np.array([int(r["frame"]) for r in rows])
    vel = np.full_like(g, np.nan)
    inner = (frame[2:] - frame[:-2] == 2) if len(rows) > 2 else np.zeros(0, bool)
    vel[1:-1][inner] = 0.5 * (g[2:] - g[:-2])[inner]
    speed = np.hypot(*vel.T)
    moving = ok & np.isfinite(speed) & (speed > 0.0)
    along = ((fused - g) * vel).sum(axis=1)[moving] / speed[moving]
    total = float((fe[ok] ** 2).sum())
    n = int(ok.sum())

    def median(a: np.ndarray) -> float:
        return float(np.median(a)) if a.size else math.nan

    return {
        "frames": n,
        "won": float((ok & ~lost).sum() / n) if n else math.nan,
        "behind": float(behind.sum() / n) if n else math.nan,
        "elsewhere": float(elsewhere.sum() / n) if n else math.nan,
        "behind_fused": median(fe[behind]),
        "behind_cue": median(best[behind]),
        "elsewhere_fused": median(fe[elsewhere]),
        "elsewhere_cue": median(best[elsewhere]),
        "behind_sq": float((fe[behind] ** 2).sum() / total) if total > 0 else math.nan,
        "elsewhere_sq": float((fe[elsewhere] ** 2).sum() / total) if total > 0 else math.nan,
        "lag": float(along.mean()) if along.size else math.nan,
        "speed": median(speed[moving]),
    }


def print_bestmax_split(rows: list[dict]) -> None:
    """Per scene: the frames the fused estimate wins and where it loses them (:func:`bestmax_split`)."""
    print(
        "BestMax split: frames fused wins; loses behind the winning cue (fused nearest it) / elsewhere (nearer "
        "another cue): share of frames, median error fused / winning cue px, share of fused squared error; "
        "lag = mean fused error along the motion px (speed px/frame)"
    )
    for r in rows:
        b = r["bestmax_split"]
        print(
            f"{r['scene'].name:<20} {r['scene'].split:<5} {r['scene'].size:>9} won {b['won']:4.0%}  "
            f"behind {b['behind']:4.0%} {b['behind_fused']:5.2f} / {b['behind_cue']:5.2f} ({b['behind_sq']:4.0%})  "
            f"elsewhere {b['elsewhere']:4.0%} {b['elsewhere_fused']:5.2f} / {b['elsewhere_cue']:5.2f} "
            f"({b['elsewhere_sq']:4.0%})  lag {b['lag']:+5.2f} ({b['speed']:4.1f})"
        )


def print_noise_split(rows: list[dict]) -> None:
    """Per scene and cue: median error / white noise / slow error / online slow error per axis, px (:func:`noise_split`)."""
    print(
        "median error / white noise / slow error (truth) / slow error (online) per axis, px"
        " (a cue whose error is mostly slow bias: the first well above the second)"
    )
    for r in rows:
        cells = " ".join(f"{c} {m:5.2f}/{wn:5.2f}/{sl:5.2f}/{on:5.2f}" for c, (m, wn, sl, on) in r["noise"].items())
        print(f"{r['scene'].name:<20} {r['scene'].split:<5} {cells}")


def paired_ratio(fused: Sequence[float | None], cue: Sequence[float | None]) -> float:
    """Fused RMSE over cue RMSE, both over the frames where each has an error (per-frame px, None or NaN: none); NaN without such frames."""
    f = np.array(fused, dtype=float)
    c = np.array(cue, dtype=float)
    ok = np.isfinite(f) & np.isfinite(c)
    if not ok.any():
        return math.nan
    # sqrt(mean f^2) / sqrt(mean c^2) over the common frames
    return math.sqrt(float(np.mean(f[ok] ** 2)) / float(np.mean(c[ok] ** 2)))


def run_scene(scene: Scene, out: Path, frames: int, track_args: list[str], recordings: Path | None = None) -> dict:
    """Render (or take from ``recordings``), track and score ``scene``; its row of the table."""
    tracked, table = out / f"{scene.name}.tracked.mcap", out / f"{scene.name}.csv"
    rec = (recordings or out) / f"{scene.name}.mcap"
    if recordings is None:
        variations = [a for k, v in scene.options.items() for a in (f"--{k.replace('_', '-')}", repr(v))]
        synth = ["synth", str(rec), "--frames", str(frames), "--seed", str(scene.seed), "--size", scene.size]
        _run(_cli(*synth, "--background-frames", "10", "--force", "--no-progress", *variations))
    elif not rec.is_file():
        raise RuntimeError(f"--recordings {recordings} has no {rec.name}: render it first (a run without --recordings)")
    track = ["track", str(rec), "-o", str(tracked), "--csv", str(table), "--force", "--no-progress", *track_args]
    _run(_cli(*track))
    score = json.loads(_run(_cli("score", str(table), "--ground-truth", str(rec), "--json", "--no-progress")))
    src = score["sources"]
    fused_name = next(k for k in src if k not in CUES)
    cues = {c: (src[c]["rmse_px"], src[c]["coverage"]) for c in CUES if c in src and src[c]["rmse_px"] is not None}
    best = min(cues, key=lambda c: cues[c][0])
    fused = src[fused_name]
    # a run without a single estimate (its one cue never started a track) has no fused RMSE
    fused_rmse = math.nan if fused["rmse_px"] is None else fused["rmse_px"]
    return {
        "scene": scene,
        "cues": cues,
        "best": best,
        "fused": fused_rmse,
        "ratio": fused_rmse / cues[best][0],
        "paired": paired_ratio(score["per_frame"]["error_px"][fused_name], score["per_frame"]["error_px"][best]),
        "bestmax": fused["bestmax"] / score["bestmax"]["n_frames"] if score["bestmax"]["n_frames"] else math.nan,
        "coverage": fused["coverage"],
        "cover2sd": coverage_2sd(table, scene, frames),
        "noise": noise_split(table, scene, frames),
        "startup": startup_split(table, scene, frames, best),
        "bestmax_split": bestmax_split(table, scene, frames),
    }


def print_table(rows: list[dict]) -> None:
    print(
        f"{'scene':<20} {'split':<5} {'size':>9} "
        + " ".join(f"{c:>13}" for c in CUES)
        + f" {'fused':>7} {'ratio':>6} {'paired':>6} {'BestMax':>7} {'cover':>6} {'2sd':>6}"
    )
    for r in rows:
        s = r["scene"]
        cells = []
        for c in CUES:
            rmse, cov = r["cues"].get(c, (float("nan"), 0.0))
            mark = "*" if c == r["best"] else " "
            cells.append(f"{rmse:7.2f}{mark}" + (f"({cov:3.0%})" if cov < 0.995 else "     "))
        print(
            f"{s.name:<20} {s.split:<5} {s.size:>9} "
            + " ".join(f"{c:>13}" for c in cells)
            + f" {r['fused']:7.2f} {r['ratio']:6.2f} {r['paired']:6.2f} {r['bestmax']:7.0%} {r['coverage']:6.0%}"
            + f" {r['cover2sd']:6.1%}"
        )
    for split in (*SPLITS, GENERATED):
        part = [r for r in rows if r["scene"].split == split]
        if not part:
            continue
        ratios = np.array([r["ratio"] for r in part])
        losing = [r["scene"].name for r in part if r["ratio"] > 1.0]
        paired = np.array([r["paired"] for r in part])
        losing_paired = [r["scene"].name for r in part if r["paired"] > 1.0]
        print(
            f"{split}: {len(part)} scenes, ratio mean {ratios.mean():.2f} worst {ratios.max():.2f}; "
            f"fused above the best cue on {', '.join(losing) or 'none'}; "
            f"paired mean {np.nanmean(paired):.2f}, above on the best cue's frames on {', '.join(losing_paired) or 'none'}; "
            f"BestMax mean {np.mean([r['bestmax'] for r in part]):.0%}; "
            f"2sd coverage mean {np.nanmean([r['cover2sd'] for r in part]):.1%}"
        )


def save(rows: list[dict], path: Path) -> None:
    """Write the rows as JSON (per scene: split, each cue's RMSE and coverage, fused RMSE, ratio, BestMax, 2sd)."""
    out = {
        r["scene"].name: {
            "split": r["scene"].split,
            "cues": {c: list(v) for c, v in r["cues"].items()},
            **{k: r[k] for k in ("best", "fused", "ratio", "paired", "bestmax", "coverage", "cover2sd")},
        }
        for r in rows
    }
    path.write_text(json.dumps(out, indent=1) + "\n")


def compare(rows: list[dict], path: Path) -> None:
    """Print each scene's fused RMSE against an earlier run's (:func:`save`), and per split the geometric
    mean of new / old fused RMSE and the ratio means of both (scenes in both runs only)."""
    old = json.loads(path.read_text())
    both = [r for r in rows if r["scene"].name in old]
    print(f"fused RMSE against {path}: new / old per scene")
    for r in both:
        o = old[r["scene"].name]
        print(
            f"{r['scene'].name:<20} {r['scene'].split:<5} fused {o['fused']:7.2f} -> {r['fused']:7.2f} "
            f"({r['fused'] / o['fused']:5.2f}x); ratio {o['ratio']:5.2f} -> {r['ratio']:5.2f}"
        )
    for split in (*SPLITS, GENERATED):
        part = [r for r in both if r["scene"].split == split]
        if not part:
            continue
        gm = float(np.exp(np.mean([np.log(r["fused"] / old[r["scene"].name]["fused"]) for r in part])))
        worse = sum(r["fused"] > old[r["scene"].name]["fused"] for r in part)
        print(
            f"{split}: fused new / old geometric mean {gm:.3f} ({worse} of {len(part)} worse); ratio mean "
            f"{np.mean([old[r['scene'].name]['ratio'] for r in part]):.2f} -> {np.mean([r['ratio'] for r in part]):.2f}"
        )


def select(scenes: tuple[Scene, ...], wanted: set[str]) -> tuple[Scene, ...]:
    """The scenes of ``scenes`` (the fixed matrix or ``--generate``'s) named in ``wanted`` or in a split it names."""
    return tuple(s for s in scenes if s.name in wanted or s.split in wanted)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    track_args: list[str] = []
    if "--" in argv:
        cut = argv.index("--")
        argv, track_args = argv[:cut], argv[cut + 1 :]
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=Path("fusion_matrix_runs"), help="work directory")
    p.add_argument("--jobs", type=int, default=2, help="scenes run at the same time")
    p.add_argument("--frames", type=int, default=160, help="frames per scene (10 of them empty-scene)")
    p.add_argument("--only", default=None, help="comma-separated scene names or splits (tune, held, new, fresh)")
    p.add_argument(
        "--generate",
        default=None,
        metavar="FIRST:COUNT",
        help="instead of the fixed matrix, COUNT scenes drawn from seeds FIRST.. (generated_scenes): a fresh held-out set",
    )
    p.add_argument(
        "--away",
        type=int,
        default=0,
        metavar="N",
        help="the person away N of every 100 frames in every scene (synth --away): losses and re-acquisitions",
    )
    p.add_argument(
        "--recordings", type=Path, default=None, help="take the rendered scenes from this earlier --out instead"
    )
    p.add_argument("--save", type=Path, default=None, help="write the table as JSON (for a later --compare)")
    p.add_argument("--compare", type=Path, default=None, help="an earlier --save: print fused RMSE new / old")
    p.add_argument(
        "--noise-split",
        action="store_true",
        help="also print each cue's median error and its white noise (what the calibration measures) per scene",
    )
    p.add_argument(
        "--startup",
        action="store_true",
        help=f"also print fused and best-cue RMSE over the first {STARTUP_FRAMES} tracked frames and the rest per scene",
    )
    p.add_argument(
        "--bestmax",
        action="store_true",
        help="also print per scene where the fused estimate loses BestMax: behind the winning cue or near another",
    )
    args = p.parse_args(argv)
    scenes = SCENES
    if args.generate:
        try:
            first, count = (int(x) for x in args.generate.split(":"))
        except ValueError:
            p.error(f"--generate must be FIRST:COUNT (two integers), got {args.generate!r}")
        if count < 1:
            p.error(f"--generate COUNT must be >= 1, got {count}")
        scenes = generated_scenes(first, count)
    if args.away:
        if not 0 < args.away < 100:
            p.error(f"--away must be in 1..99 (frames of every 100), got {args.away}")
        scenes = away_scenes(scenes, args.away)
    if args.only:
        wanted = set(args.only.split(","))
        unknown = wanted - {s.name for s in scenes} - {s.split for s in scenes}
        if unknown:
            p.error(f"--only names no scene or split of this matrix: {', '.join(sorted(unknown))}")
        scenes = select(scenes, wanted)
    args.out.mkdir(parents=True, exist_ok=True)
    print(f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}; track options: {track_args or 'defaults'}")
    try:
        with ThreadPoolExecutor(max_workers=args.jobs) as pool:
            rows = list(pool.map(lambda s: run_scene(s, args.out, args.frames, track_args, args.recordings), scenes))
    except RuntimeError as exc:
        print(f"fusion_matrix: error: {exc}", file=sys.stderr)
        return 2
    print_table(rows)
    if args.noise_split:
        print_noise_split(rows)
    if args.startup:
        print_startup_split(rows)
    if args.bestmax:
        print_bestmax_split(rows)
    if args.save is not None:
        save(rows, args.save)
    if args.compare is not None:
        compare(rows, args.compare)
    return 0


if __name__ == "__main__":
    sys.exit(main())
