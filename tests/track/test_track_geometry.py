"""3-D palm back-projection and ROI point clouds (fusion_pf.geometry)."""

from __future__ import annotations

import cv2
import numpy as np
import open3d as o3d
import pytest

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, Intrinsics
from fusion_pf.geometry import backproject, depth_at, palm_xyz, roi_points, write_roi_ply


def test_hand_worked_pinhole_case():
    # fx=500, cx=320: pixel u=420 is 100 px right of centre -> x = 100/500 * 1000 mm = 200 mm.
    # fy=400, cy=200: pixel v=160 is 40 px above centre -> y = -40/400 * 1000 mm = -100 mm.
    k = Intrinsics(640, 400, 500.0, 400.0, 320.0, 200.0)
    xyz = backproject(np.array([[420.0, 160.0]]), np.array([1000.0]), k)
    np.testing.assert_allclose(xyz, [[200.0, -100.0, 1000.0]])


@pytest.mark.parametrize(
    "model, coeffs",
    [
        ("none", ()),
        ("plumb_bob", (-0.12, 0.05, 0.001, -0.0015, -0.01)),
        ("rational_polynomial", (0.1, -0.05, 0.001, 0.002, 0.01, 0.05, -0.02, 0.005)),
        ("kannala_brandt", (0.05, -0.01, 0.002, -0.0005)),
    ],
)
def test_backprojection_reprojects_with_opencv(model, coeffs):
    k = Intrinsics(640, 400, 455.5, 457.0, 318.2, 203.9, model, coeffs)
    rng = np.random.default_rng(5)
    uv = np.column_stack((rng.uniform(20, 620, 50), rng.uniform(20, 380, 50)))
    z = rng.uniform(400, 3000, 50)
    xyz = backproject(uv, z, k)
    np.testing.assert_allclose(xyz[:, 2], z)
    dist = np.asarray(coeffs, dtype=np.float64)
    if model == "kannala_brandt":
        back, _ = cv2.fisheye.projectPoints(xyz.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k.K, dist)
    else:
        back, _ = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), k.K, dist)
    np.testing.assert_allclose(back.reshape(-1, 2), uv, atol=0.05)


def test_depth_window_is_a_median_that_ignores_zeros():
    depth = np.zeros((20, 30), np.uint16)
    depth[8:13, 10:15] = 1000
    depth[10, 12] = 5000  # one outlier inside the window
    depth[9, 11] = 0  # one hole
    assert depth_at(depth, 12.2, 9.6, radius=2) == 1000.0
    assert depth_at(depth, 2.0, 2.0, radius=2) is None  # only zeros
    assert depth_at(depth, 500.0, 2.0, radius=2) is None  # outside the image
    assert depth_at(depth, 29.4, 12.0, radius=1) is None  # clipped window, still zeros
    with pytest.raises(InputError, match="radius"):
        depth_at(depth, 1, 1, radius=-1)


def test_palm_xyz_uses_the_window_depth():
    k = Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)
    depth = np.zeros((48, 64), np.uint16)
    depth[20:29, 37:46] = 800
    xyz = palm_xyz(41.0, 24.0, depth, k)
    np.testing.assert_allclose(xyz, [(41 - 32) / 50 * 800, 0.0, 800.0])
    assert palm_xyz(5.0, 5.0, depth, k) is None
    assert palm_xyz(41.0, 24.0, None, k) is None


def test_backproject_rejects_bad_input():
    k = Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)
    with pytest.raises(InputError, match="z_mm must be positive"):
        backproject(np.array([[1.0, 2.0]]), np.array([0.0]), k)
    with pytest.raises(InputError, match=r"shape \(N, 2\)"):
        backproject(np.array([1.0, 2.0]), np.array([1.0]), k)


def test_roi_point_cloud_ply_round_trip(tmp_path):
    k = Intrinsics(64, 48, 50.0, 50.0, 32.0, 24.0)
    depth = np.zeros((48, 64), np.uint16)
    depth[10:20, 30:40] = 1200
    depth[12, 33] = 0
    color = np.zeros((48, 64, 3), np.uint8)
    color[..., 1] = 200
    frame = Frame(0, 0, color, depth, k)
    pts, cols = roi_points(frame, (28, 8, 36, 16))
    # valid pixels: u in [30, 36), v in [10, 16) minus the hole -> 6*6 - 1
    assert pts.shape == (35, 3) and cols.shape == (35, 3)
    np.testing.assert_allclose(pts[:, 2], 1200.0)
    path = tmp_path / "roi.ply"
    palm = np.array([1.0, 2.0, 1200.0])
    n = write_roi_ply(path, frame, (28, 8, 36, 16), palm=palm)
    cloud = o3d.io.read_point_cloud(str(path))
    got = np.asarray(cloud.points)
    assert n == 36 and got.shape == (36, 3)
    np.testing.assert_allclose(got[:-1], pts, atol=1e-3)
    np.testing.assert_allclose(got[-1], palm, atol=1e-3)
    np.testing.assert_allclose(np.asarray(cloud.colors)[-1], [1, 0, 0])


@pytest.mark.parametrize("seed", range(20))
def test_depth_at_is_numpy_median_of_the_valid_window(seed):
    rng = np.random.default_rng(seed)
    depth = rng.integers(0, 4000, size=(30, 40)).astype(np.uint16)
    depth[rng.random(depth.shape) < 0.4] = 0  # holes
    u, v, radius = rng.uniform(-3, 42), rng.uniform(-3, 32), int(rng.integers(0, 5))
    cu, cv = int(round(u)), int(round(v))
    window = depth[max(cv - radius, 0) : max(cv + radius + 1, 0), max(cu - radius, 0) : max(cu + radius + 1, 0)]
    valid = window[window > 0]
    expected = float(np.median(valid)) if valid.size else None
    assert depth_at(depth, u, v, radius=radius) == expected
