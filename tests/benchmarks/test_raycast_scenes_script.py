"""benchmarks/raycast_scenes.py: the second renderer's geometry, depth model and recording."""

import dataclasses
import importlib.util
import sys
from pathlib import Path

import numpy as np

from drivers.mcap_replay import McapReplay
from fusion_pf.frame import Intrinsics

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("raycast_scenes", ROOT / "benchmarks" / "raycast_scenes.py")
bench = sys.modules["raycast_scenes"] = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def _small(seed: int, **changes) -> tuple:
    scene = dataclasses.replace(bench.draw_scene(seed), size=(320, 200), **changes)
    f = 0.78 * 320
    return scene, Intrinsics(320, 200, f, f, 160.0, 100.0)


def test_the_true_palm_pixel_sees_the_palm_at_its_depth():
    """The projected ground truth hits the palm ellipsoid: its depth is the palm centre's less its half-thickness
    (16 mm), within the stereo noise (0.03 px of disparity: a few mm at 1-2 m)."""
    scene, intr = _small(1, disparity_noise_px=0.03)
    rng = np.random.default_rng(0)
    for k in (0, 30, 60):
        p = bench.pose(scene, k)
        _, depth = bench.render_frame(scene, p, intr, rng, k)
        u, v = bench.project(intr, p["palm"])
        patch = depth[int(v) - 1 : int(v) + 2, int(u) - 1 : int(u) + 2].astype(float)
        patch = patch[patch > 0]
        assert patch.size >= 5
        z = p["palm"][2] - 16.0
        step = z * z / (intr.fx * bench.BASELINE_MM) / 8  # one 1/8 px disparity step, mm
        assert abs(float(np.median(patch)) - z) < 3 * step + 5, (np.median(patch), z)


def test_depth_noise_grows_with_the_square_of_the_distance():
    """Active stereo: the wall's depth error (against the noise-free ray cast) at the same disparity noise is
    (z_far / z_near)^2 times larger for a person and room moved back."""
    spreads = []
    for distance in (1200.0, 2400.0):
        scene, intr = _small(2, disparity_noise_px=0.3, distance_mm=distance, clutter=())
        depth = bench.render_frame(scene, None, intr, np.random.default_rng(1), 0)[1].astype(float)
        wall = depth[20:60, 40:280]
        wall_z = distance + 1300.0
        spreads.append(float(np.std(wall[wall > 0] - wall_z)))
    ratio = spreads[1] / spreads[0]
    expected = ((2400.0 + 1300.0) / (1200.0 + 1300.0)) ** 2
    assert abs(ratio - expected) < 0.2 * expected, (ratio, expected)


def test_the_projector_shadow_leaves_no_depth_beside_a_near_object():
    """Left of the torso's left edge (the projector is 75 mm to the right) the wall has no depth; right of the
    right edge it does."""
    scene, intr = _small(3, disparity_noise_px=0.03, clutter=())
    p = bench.pose(scene, 0)
    depth = bench.render_frame(scene, p, intr, np.random.default_rng(2), 0)[1]
    t = p["torso"]
    row = int(bench.project(intr, t + np.array([0.0, 250.0, 0.0]))[1])
    left = int(bench.project(intr, t + np.array([-200.0, 0.0, -110.0]))[0])
    right = int(bench.project(intr, t + np.array([200.0, 0.0, -110.0]))[0])
    assert (depth[row, left - 6 : left - 2] == 0).all(), depth[row, left - 8 : left + 2]
    assert (depth[row, right + 3 : right + 7] > 0).mean() >= 0.5, depth[row, right - 2 : right + 8]


def test_a_scene_renders_to_a_recording_with_its_background_and_truth_and_the_same_seed_gives_the_same_frames(
    tmp_path,
):
    scene, _ = _small(4)
    frames = []
    for name in ("a.mcap", "b.mcap"):
        bench.render(scene, tmp_path / name, 3)
        with McapReplay(tmp_path / name) as rec:
            frames.append(list(rec))
    a, b = frames
    assert len(a) == bench.BACKGROUND_FRAMES + 3
    assert [f.background for f in a] == [True] * bench.BACKGROUND_FRAMES + [False] * 3
    assert all(f.ground_truth is None and f.joints is None for f in a[: bench.BACKGROUND_FRAMES])
    assert all(f.ground_truth is not None and "right_hand" in f.joints for f in a[bench.BACKGROUND_FRAMES :])
    for fa, fb in zip(a, b):
        np.testing.assert_array_equal(fa.color, fb.color)
        np.testing.assert_array_equal(fa.depth, fb.depth)


def test_two_sigma_coverage_counts_tracked_rows_with_a_truth(tmp_path):
    """Rows 0-3 against the truth (10, 20): errors 3, 5, 8 and 4 px with sigma_px 2 (2 sigma = 4 px): 2 of 4 within;
    row 4 has no estimate and row 5 no truth: neither counts."""
    from fusion_pf.frame import PalmPoint

    table = tmp_path / "t.csv"
    rows = ["frame,u,v,sigma_px", "0,13,20,2", "1,10,25,2", "2,10,28,2", "3,10,16,2", "4,,,", "5,10,20,2"]
    table.write_text("\n".join(rows) + "\n")
    truth = {k: PalmPoint(10.0, 20.0) for k in range(5)}
    assert bench.fusion_matrix.within_2sd(table, truth.get) == 0.5
