"""End-to-end tracking on a synthetic scene: accuracy, occlusion, NaN-freedom, determinism, the cue/filter split."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from fusion_pf.cues import SOURCES
from fusion_pf.pipeline import TrackConfig, TrackCsv, extract_cues, run_filter, track

#: Paper 003 §4.2-4.3 protocol: Gaussian noise added to the colour and depth cue
#: positions. Without it the synthetic depth cue (1.5-2 px RMSE, unbiased) is
#: better than any fusion with the biased colour cue (the bare forearm pulls it
#: 5-7 px toward the elbow) and the skeleton; 2 px keeps the palm inside the
#: depth window for the 3-D tests, 4 px is the level at which the paper's claim
#: (fused below every single cue) is tested.
PAPER_CUE_NOISE = {"colour": 2.0, "depth": 2.0}
FUSION_CUE_NOISE = {"colour": 4.0, "depth": 4.0}


def errors(results) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Per-frame pixel error of each cue and of the estimate (``fused``), NaN where missing, and occlusion flags."""
    out: dict[str, list[float]] = {s: [] for s in (*SOURCES, "skin_rgb", "fused")}
    occluded = []
    for r in results:
        if r.background:
            continue
        g = r.ground_truth
        occluded.append(g.occluded)
        for s in (*SOURCES, "skin_rgb"):
            m = r.cues.get(s)
            out[s].append(np.nan if m is None else float(np.hypot(m.u - g.u, m.v - g.v)))
        e = r.estimate
        out["fused"].append(np.nan if e is None else float(np.hypot(e.u - g.u, e.v - g.v)))
    return {k: np.array(v) for k, v in out.items()}, np.array(occluded)


def rmse(e: np.ndarray) -> float:
    return float(np.sqrt(np.nanmean(e**2)))


@pytest.fixture(scope="module")
def robust_run(scene_frames):
    return list(track(scene_frames, TrackConfig(cue_noise_px=PAPER_CUE_NOISE, seed=1)))


def test_fused_rmse_is_below_every_single_cue(scene_frames):
    err, _ = errors(track(scene_frames, TrackConfig(cue_noise_px=FUSION_CUE_NOISE, seed=1)))
    fused = rmse(err["fused"])
    singles = {s: rmse(err[s]) for s in SOURCES}
    assert np.isfinite(err["fused"]).all()  # an estimate on every tracked frame
    assert all(fused < v for v in singles.values()), (fused, singles)


def test_occlusion_error_stays_bounded_while_the_skeleton_fails(robust_run):
    err, occluded = errors(robust_run)
    assert 20 <= occluded.sum() <= 120
    skeleton_p95 = np.nanpercentile(err["skeleton"][occluded], 95)
    fused_p95 = np.nanpercentile(err["fused"][occluded], 95)
    # at 320 px width the skeleton is biased 12-28 px toward the torso during occlusion
    assert skeleton_p95 > 15.0
    assert fused_p95 < 6.0 and np.nanmax(err["fused"][occluded]) < 10.0, (fused_p95, skeleton_p95)


@pytest.mark.parametrize("filt, likelihood", [("pf", "gaussian"), ("pf", "robust"), ("kf", None)])
def test_never_nan(scene_frames, filt, likelihood):
    results = list(track(scene_frames, TrackConfig(filter=filt, likelihood=likelihood, particles=50)))
    assert len(results) == len(scene_frames)
    assert [r.frame for r in results] == list(range(len(scene_frames)))
    for r, f in zip(results, scene_frames):
        assert r.background == f.background and r.timestamp_ns == f.timestamp_ns
        if r.background:
            assert r.estimate is None and all(m is None for m in r.cues.values())
            continue
        e = r.estimate
        assert np.isfinite([e.u, e.v]).all() and np.isfinite(e.cov).all()
        assert r.xyz_mm is None or np.isfinite(r.xyz_mm).all()
        assert all(v >= 0 for v in r.latency_ns.values())
        assert set(r.latency_ns) == {"decode", "colour", "depth", "skeleton", "filter", "total"}
        if filt == "pf":
            assert r.particles.shape == (50, 2) and np.isfinite(r.particles).all()
            assert r.weights.sum() == pytest.approx(1.0)
        else:
            assert r.particles is None and e.n_particles == 0
    tracked = [r for r in results if not r.background]
    assert sum(r.xyz_mm is not None for r in tracked) > 0.9 * len(tracked)


def test_xyz_reprojects_to_the_estimate_at_the_hand_depth(robust_run):
    checked = 0
    for r in robust_run:
        if r.background or r.xyz_mm is None:
            continue
        k = r.source_frame.intrinsics
        back, _ = cv2.projectPoints(r.xyz_mm.reshape(1, 3), np.zeros(3), np.zeros(3), k.K, np.zeros(5))
        np.testing.assert_allclose(back.reshape(2), [r.estimate.u, r.estimate.v], atol=1e-6)
        joint = r.source_frame.joint("right_hand")
        if not r.ground_truth.occluded and joint.confidence > 0.8:
            # the synthetic palm is 1.15-1.35 m away, the torso 0.22-0.32 m behind it; the clear
            # joint's depth has 15 mm noise (3 sigma 45 mm), the palm surface bulges up to 20 mm
            # toward the camera and the stereo depth moves in 1/8 px steps (11 mm at 1.3 m, 320 px)
            assert abs(r.xyz_mm[2] - joint.depth_mm) < 80.0
            checked += 1
    assert checked > 50


def test_csv_is_byte_identical_for_a_seed(scene_frames, tmp_path):
    config = TrackConfig(cue_noise_px=PAPER_CUE_NOISE, seed=7)
    paths = []
    for name, cfg in (("a", config), ("b", config), ("c", dataclasses.replace(config, seed=8))):
        path = tmp_path / f"{name}.csv"
        with TrackCsv(path) as table:
            for r in track(scene_frames, cfg):
                table.write(r)
        paths.append(path)
    a, b, c = (p.read_bytes() for p in paths)
    assert a == b
    assert a != c
    assert b"nan" not in a.lower()
    assert a.count(b"\n") == 1 + sum(not f.background for f in scene_frames)


def test_filter_only_reruns_reproduce_track(scene_frames):
    config = TrackConfig(roi_prior="skeleton", cue_noise_px=PAPER_CUE_NOISE, particles=80, seed=4)
    direct = list(track(scene_frames, config))
    rows = extract_cues(scene_frames, dataclasses.replace(config, particles=5))  # no filter runs here
    assert [r.frame for r in rows] == [r.frame for r in direct]
    rerun = run_filter(rows, dataclasses.replace(config, seed=99), rng=4)
    for d, r in zip(direct, rerun):
        assert d.background == r.background
        for s in SOURCES:
            assert (d.cues.get(s) is None) == (r.cues.get(s) is None)
            if d.cues.get(s) is not None:
                assert (d.cues[s].u, d.cues[s].v) == (r.cues[s].u, r.cues[s].v)
        if d.estimate is None:
            assert r.estimate is None
            continue
        assert (d.estimate.u, d.estimate.v, d.estimate.ess) == (r.estimate.u, r.estimate.v, r.estimate.ess)
        assert (d.xyz_mm is None and r.xyz_mm is None) or np.array_equal(d.xyz_mm, r.xyz_mm)
        assert r.latency_ns["total"] == sum(
            r.latency_ns[s] for s in ("decode", "colour", "depth", "skeleton", "filter")
        )
    other = run_filter(rows, config, rng=5)
    assert any(a.estimate.u != b.estimate.u for a, b in zip(rerun, other) if a.estimate is not None)


def test_running_median_background_when_there_is_no_empty_scene(scene_frames):
    people = [f for f in scene_frames if not f.background]
    results = list(track(people, TrackConfig(background_k=30)))
    assert len(results) == len(people) and not any(r.background for r in results)
    # the person is part of a background learnt from the stream: the skin rule replaces the colour cue
    assert all(tuple(r.cues) == ("skin_rgb", "depth", "skeleton") for r in results)
    err, _ = errors(results)
    assert np.mean(np.isfinite(err["skin_rgb"])) > 0.5
    assert np.mean(np.isfinite(err["depth"])) > 0.8
    assert rmse(err["fused"]) < 3.0  # measured 1.0 px (0.95 with the colour cue, itself 17.6 px off)


def test_uncertainty_covers_the_error_in_about_95_percent_of_frames(scene_frames):
    """``2 sigma_px`` bounds the error in ~95 % of frames (docs/architecture.md, "CSV"), without being wide enough to
    cover nearly every frame at ``1 sigma_px``; the posterior spread alone does not cover it."""
    from fusion_pf.filter.estimate import largest_std

    results = [r for r in track(scene_frames, TrackConfig(seed=1)) if not r.background]
    assert all((r.sigma_px is None) == (r.estimate is None) for r in results)
    assert all((r.sigma_mm is None) == (r.xyz_mm is None) for r in results)
    tracked = [r for r in results if r.estimate is not None]
    err = np.array([np.hypot(r.estimate.u - r.ground_truth.u, r.estimate.v - r.ground_truth.v) for r in tracked])
    sigma = np.array([r.sigma_px for r in tracked])
    spread = np.array([largest_std(r.estimate.cov) for r in tracked])
    assert 0.9 <= np.mean(err <= 2 * sigma) < 1.0
    # a Rayleigh error of scale a covered at 2 sigma in 95 % of frames has sigma^2 = 1.5 a^2; a sigma 1.6x that wide
    # covers 1 - exp(-sigma^2 / 2 a^2) = 85 % at 1 sigma (measured 76-78 %)
    assert np.mean(err <= sigma) < 0.85
    assert np.mean(err <= 2 * spread) < np.mean(err <= 2 * sigma)
    for r in tracked:
        if r.xyz_mm is not None:
            assert r.sigma_mm == pytest.approx(r.sigma_px * r.xyz_mm[2] / r.source_frame.intrinsics.fx)


@pytest.mark.parametrize("seed", [0, 1])
def test_an_offset_the_learned_noise_absorbed_still_counts_in_the_uncertainty(seed):
    """Two cues 12 px apart: a smooth depth blob off the palm (0.2 px of white noise, low quality) and an unbiased
    skeleton joint (1.1 px). The track follows depth and the skeleton's noise, learned against that prediction,
    absorbs their offset; its own white noise does not, so ``sigma_px`` still covers the 12 px error (module
    docstring of :mod:`fusion_pf.pipeline.run`, "Uncertainty"; with the fused noise alone: 22-34 % of frames)."""
    import math

    from fusion_pf.frame import Intrinsics, Measurement
    from fusion_pf.pipeline.run import CueRow

    intr = Intrinsics(640, 400, 500.0, 500.0, 320.0, 200.0)
    rng = np.random.default_rng(seed)
    rows, truth = [], []
    for k in range(150):
        u, v = 320.0 + 80.0 * math.sin(k / 25.0), 200.0 + 40.0 * math.cos(k / 30.0)
        bias = 12.0 * (1.0 + 0.3 * math.sin(k / 20.0))
        cues = {
            "depth": Measurement("depth", u + bias + rng.normal(0.0, 0.2), v + rng.normal(0.0, 0.2), 0.4),
            "skeleton": Measurement("skeleton", u + rng.normal(0.0, 1.1), v + rng.normal(0.0, 1.1), 0.9),
        }
        latency = {"decode": 0, "depth": 0, "skeleton": 0}
        rows.append(CueRow(k, 1_000_000_000 + k * 33_333_333, False, cues, latency, None, None, (0, 0), intr))
        truth.append((u, v))
    results = run_filter(rows, TrackConfig(seed=1))[30:]  # after the white noise is learned
    assert all(r.estimate is not None for r in results)
    err = np.array([math.hypot(r.estimate.u - g[0], r.estimate.v - g[1]) for r, g in zip(results, truth[30:])])
    sigma = np.array([r.sigma_px for r in results])
    assert np.mean(err <= 2.0 * sigma) >= 0.9
    # the disagreement widens it to about the offset, no further (measured: median 8.9-9.1 px, the error 12.3-12.6)
    assert np.median(sigma) < 12.0


def test_a_lone_cue_does_not_narrow_the_uncertainty_below_the_posterior_spread():
    """With one cue, ``sigma_px`` is the posterior spread plus that cue's unexplained distance, never its own noise
    alone: a lone cue's noise is learned from its own differences, which do not see its slow error (module docstring
    of :mod:`fusion_pf.pipeline.run`, "Uncertainty"; with its own noise, the real development frames' 2-sigma coverage
    fell 90.6 -> 77.4 % and 91.5 -> 64.2 %)."""
    import math

    from fusion_pf.filter.estimate import largest_std
    from fusion_pf.frame import Intrinsics, Measurement
    from fusion_pf.pipeline.run import CueRow

    intr = Intrinsics(640, 400, 500.0, 500.0, 320.0, 200.0)
    rng = np.random.default_rng(0)
    rows = []
    for k in range(80):
        u, v = 320.0 + 80.0 * math.sin(k / 25.0), 200.0 + 40.0 * math.cos(k / 30.0)
        m = Measurement("depth", u + 6.0 * math.sin(k / 15.0) + rng.normal(0.0, 0.3), v + rng.normal(0.0, 0.3), 0.9)
        rows.append(
            CueRow(
                k,
                1_000_000_000 + k * 33_333_333,
                False,
                {"depth": m},
                {"decode": 0, "depth": 0},
                None,
                None,
                (0, 0),
                intr,
            )
        )
    results = [r for r in run_filter(rows, TrackConfig(seed=1)) if r.estimate is not None]
    assert len(results) == 80
    assert all(r.sigma_px >= largest_std(r.estimate.cov) for r in results)


@pytest.mark.parametrize("seed", [0, 1])
def test_a_cue_left_alone_keeps_in_its_uncertainty_the_offset_it_showed_beside_another(seed):
    """A skeleton joint 10 px off the palm (1 px of white noise, confident) beside an unbiased, noisy, unconfident
    depth blob for 70 frames, then alone. Its own differences do not see its offset, and the posterior spread of a
    lone cue does not either: ``sigma_px`` was 1.6-4.6 px against a 10 px error (2-sigma coverage 0-15 %). The slow
    offset of the two cues, learned while both measured, is the lone cue's slow error (the whole of it: of two cues
    either may be the biased one; module docstring of :mod:`fusion_pf.pipeline.run`, "Uncertainty")."""
    import math

    from fusion_pf.frame import Intrinsics, Measurement
    from fusion_pf.pipeline.run import CueRow

    intr = Intrinsics(640, 400, 500.0, 500.0, 320.0, 200.0)
    rng = np.random.default_rng(seed)
    rows, truth = [], []
    for k in range(140):
        u, v = 320.0 + 80.0 * math.sin(k / 25.0), 200.0 + 40.0 * math.cos(k / 30.0)
        skeleton = Measurement("skeleton", u + 8.0 + rng.normal(0.0, 1.0), v - 6.0 + rng.normal(0.0, 1.0), 0.9)
        cues = {"skeleton": skeleton}
        if k < 70:
            cues["depth"] = Measurement("depth", u + rng.normal(0.0, 3.0), v + rng.normal(0.0, 3.0), 0.3)
        latency = {"decode": 0, **{c: 0 for c in cues}}
        rows.append(CueRow(k, 1_000_000_000 + k * 33_333_333, False, cues, latency, None, None, (0, 0), intr))
        truth.append((u, v))
    results = run_filter(rows, TrackConfig(seed=1))[80:]  # the skeleton alone
    assert all(r.estimate is not None for r in results)
    err = np.array([math.hypot(r.estimate.u - g[0], r.estimate.v - g[1]) for r, g in zip(results, truth[80:])])
    sigma = np.array([r.sigma_px for r in results])
    assert np.median(err) > 8.0  # the track follows the joint's offset
    assert np.mean(err <= 2.0 * sigma) >= 0.9
    # the offset, not more: measured median 9.0 / 7.3 px against errors of 10.3 / 9.7
    assert np.mean(err <= sigma) < 0.5


@pytest.mark.parametrize("seed", [0, 2])
def test_the_nearest_cue_s_slow_error_bounds_the_uncertainty_from_below(seed):
    """Three confident cues: a smooth depth blob 5 px off the palm (0.3 px of white noise) and two unbiased ones
    (4 px). The track follows depth; the two others' distance from it is mostly their own noise, so their
    unexplained disagreement said too little in the frames they happened to fall near the estimate (2-sigma
    coverage 82 / 89 %). Depth's slow error, split from the three pairs' offsets (the three-cornered hat), is
    the nearest cue's error whatever this frame's disagreement says (module docstring of
    :mod:`fusion_pf.pipeline.run`, "Uncertainty")."""
    import math

    from fusion_pf.frame import Intrinsics, Measurement
    from fusion_pf.pipeline.run import CueRow

    intr = Intrinsics(640, 400, 500.0, 500.0, 320.0, 200.0)
    rng = np.random.default_rng(seed)
    rows, truth = [], []
    for k in range(150):
        u, v = 320.0 + 80.0 * math.sin(k / 25.0), 200.0 + 40.0 * math.cos(k / 30.0)
        cues = {
            "depth": Measurement("depth", u + 4.0 + rng.normal(0.0, 0.3), v - 3.0 + rng.normal(0.0, 0.3), 0.9),
            "skeleton": Measurement("skeleton", u + rng.normal(0.0, 4.0), v + rng.normal(0.0, 4.0), 0.9),
            "colour": Measurement("colour", u + rng.normal(0.0, 4.0), v + rng.normal(0.0, 4.0), 0.9),
        }
        latency = {"decode": 0, **{c: 0 for c in cues}}
        rows.append(CueRow(k, 1_000_000_000 + k * 33_333_333, False, cues, latency, None, None, (0, 0), intr))
        truth.append((u, v))
    results = run_filter(rows, TrackConfig(seed=1))[60:]  # once the pairs' offsets are known
    err = np.array([math.hypot(r.estimate.u - g[0], r.estimate.v - g[1]) for r, g in zip(results, truth[60:])])
    sigma = np.array([r.sigma_px for r in results])
    assert np.median(err) > 4.0  # the track follows depth's offset
    assert np.mean(err <= 2.0 * sigma) >= 0.95
    # a floor, not a widening: at 1 sigma as before (measured 42 / 43 %)
    assert np.mean(err <= sigma) < 0.6


def test_cues_run_with_the_configured_opencv_threads(monkeypatch):
    """Issue 25: the cues run single-threaded in OpenCV by default (a split call waits for a core another
    process holds), and so does the frame's decoding (lowering the count after a decode had started OpenCV's
    pool stopped its threads on every frame: a wait of milliseconds on a loaded machine); the caller's
    setting is restored after every frame."""
    from drivers.synth import SynthSource
    from fusion_pf.cues.colour import ColourCue
    from fusion_pf.cues.registry import CueOptions

    seen: list[int] = []
    measure = ColourCue.measure

    def spy(self, frame, ctx):
        seen.append(cv2.getNumThreads())
        return measure(self, frame, ctx)

    monkeypatch.setattr(ColourCue, "measure", spy)
    with SynthSource(frames=5, seed=1, size=(160, 100), background_frames=2) as src:
        frames = list(src)
    decoded: list[int] = []

    def source():
        for f in frames:
            decoded.append(cv2.getNumThreads())  # a source decodes the frame when it is asked for it
            yield f

    caller = cv2.getNumThreads()
    try:
        cv2.setNumThreads(2)
        for options, threads in ((CueOptions(), 1), (CueOptions(cv_threads=2), 2)):
            seen.clear()
            decoded.clear()
            for _ in track(source(), TrackConfig(cues=("colour",), cue_options=options)):
                assert cv2.getNumThreads() == 2  # restored between frames
            assert seen == [threads] * 3
            assert decoded == [threads] * 5
    finally:
        cv2.setNumThreads(caller)
