"""benchmarks/real_data.py on data made here (never on the licensed dataset)."""

import importlib.util
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers.mcap_replay import McapReplay
from fusion_pf.errors import InputError
from fusion_pf.frame import Intrinsics

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("real_data", ROOT / "benchmarks" / "real_data.py")
real_data = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(real_data)


def test_crop_projection_equals_the_video_projection_mapped_into_the_box():
    cam = np.array([923.648, 923.759, 640.047, 362.336])
    box = np.array([404, 227, 445, 445])
    video = Intrinsics(1280, 720, *cam)
    crop = real_data.crop_intrinsics(cam, box, 256)
    rng = np.random.default_rng(1)
    for p in rng.uniform([-8, -5, 30], [8, 12, 45], size=(20, 3)):
        full, small = real_data.project(video, p), real_data.project(crop, p)
        s = 256 / 445
        assert abs((full.u - box[0]) * s - small.u) < 1e-9 and abs((full.v - box[1]) * s - small.v) < 1e-9


def test_palm_is_the_mean_of_wrist_and_four_finger_bases():
    joints = np.zeros((1, 21, 3))
    joints[0, :, 0] = np.arange(21)
    assert real_data.palm_3d(joints)[0, 0] == pytest.approx((0 + 5 + 9 + 13 + 17) / 5)


def test_sr305_sequence_becomes_a_depth_recording(tmp_path):
    seq = tmp_path / "custom" / "s1"
    seq.mkdir(parents=True)
    raw = {i: np.random.default_rng(i).integers(0, 12000, size=(480, 640)).astype(np.uint16) for i in (0, 20, 40)}
    for i, img in raw.items():
        cv2.imwrite(str(seq / f"{i}.png"), img)
    path = real_data.prepare_sr305(tmp_path / "custom", "s1", tmp_path)
    with McapReplay(path) as rec:
        frames = list(rec)
        meta = rec.info().metadata
    assert [f.seq for f in frames] == [0, 20, 40]
    assert np.diff([f.timestamp_ns for f in frames]).tolist() == [2_000_000_000] * 2
    for f in frames:
        assert np.array_equal(f.depth, np.rint(raw[f.seq] * 0.125).astype(np.uint16))
        assert (f.color == real_data.GREY).all() and f.ground_truth is None and f.joints is None
        assert (f.intrinsics.fx, f.intrinsics.cx, f.intrinsics.cy) == (476.007, 313.683, 242.755)
    assert meta["placeholder_color"].startswith("constant grey 128")
    with pytest.raises(InputError, match="no PNG depth frames"):
        real_data.prepare_sr305(tmp_path / "custom", "missing", tmp_path)


def test_run_tracks_a_recording_and_scores_it_against_its_ground_truth(tmp_path):
    res = real_data.track_one(ROOT / "recordings" / "sample.mcap", tmp_path)
    rows = res["rows"]
    assert res["frames"] == 270 and res["no_estimate"] == 0 and res["outside"] == 0
    assert {"fused", "colour", "depth", "skeleton", "const: centre", "const: mean palm"} <= set(rows)
    assert rows["fused"]["coverage"] == 1.0 and rows["fused"]["rmse"] < 5.0
    assert rows["fused"]["rmse"] < rows["const: mean palm"]["rmse"] < rows["const: centre"]["rmse"]
    assert rows["fused"]["median"] <= rows["fused"]["p95"] and res["latency_ms"] > 0
