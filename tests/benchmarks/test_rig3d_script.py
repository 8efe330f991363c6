"""benchmarks/rig3d.py: the joined / apart split, the joined pair's midpoint / half-offset errors and its gap."""

import dataclasses
import importlib.util
import math
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("rig3d_bench", ROOT / "benchmarks" / "rig3d.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def _data(right, left, right_truth, left_truth):
    """rig3d's per-hand positions and truths (instants x 3, mm)."""
    return {
        "positions": {"right_hand": np.array(right, dtype=np.float64), "left_hand": np.array(left, dtype=np.float64)},
        "truths": {
            "right_hand": np.array(right_truth, dtype=np.float64),
            "left_hand": np.array(left_truth, dtype=np.float64),
        },
    }


def test_joined_pair_error_splits_into_midpoint_and_half_offset():
    # instant 0: palms 30 mm apart (joined), both estimates 2 mm inward along x: the midpoint is exact, the
    # half-offset 2 mm short; instant 1: joined, both estimates 4 mm up: midpoint 4 mm off, half-offset exact;
    # instant 2: 300 mm apart (not joined); instant 3: joined but the left hand has no estimate
    nan = math.nan
    data = _data(
        right=[[2, 0, 0], [0, 4, 0], [0, 0, 0], [0, 0, 0]],
        left=[[28, 0, 0], [30, 4, 0], [300, 0, 0], [nan, nan, nan]],
        right_truth=[[0, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0]],
        left_truth=[[30, 0, 0], [30, 0, 0], [300, 0, 0], [30, 0, 0]],
    )
    assert bench.joined_mask(data).tolist() == [True, True, False, True]
    mid, half = bench.pair_errors(data)
    np.testing.assert_allclose(mid, [0.0, 4.0])
    np.testing.assert_allclose(half, [2.0, 0.0])
    np.testing.assert_allclose(bench.gap_errors(data), [-4.0, 0.0])  # 26 mm estimated where 30; 30 where 30
    assert math.isclose(bench.rms(np.array([3.0, 4.0])), math.sqrt(12.5))
    assert math.isnan(bench.rms(np.array([])))


def test_the_joined_distance_is_the_world_trackers_combine_distance():
    # just inside and just outside COMBINE_MM (1.07 palm lengths of 95 mm)
    d = bench.COMBINE_MM
    data = _data([[0, 0, 0]] * 2, [[d, 0, 0]] * 2, [[0, 0, 0]] * 2, [[d - 0.5, 0, 0], [d + 0.5, 0, 0]])
    assert bench.joined_mask(data).tolist() == [True, False]


def test_the_seed_option_reaches_both_trackers_config():
    # both the world tracker and the cam0 baseline run with this config: --seed changes their filters' seed only
    default = bench.tracker_config(None)
    assert default.seed == bench.TrackConfig().seed and default.targets == bench.HANDS
    seeded = bench.tracker_config(default.seed + 7)
    assert seeded.seed == default.seed + 7
    assert dataclasses.replace(seeded, seed=default.seed) == default
