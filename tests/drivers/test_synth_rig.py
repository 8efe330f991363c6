"""The synthetic multi-camera scene and rig calibration (synth --cameras N [--board], calibrate)."""

from __future__ import annotations

import hashlib
import re

import numpy as np
import pytest

from drivers.charuco import BoardSpec
from drivers.rig import RigReplay, load_extrinsics
from drivers.rig_calibration import ICP_BOARD_TOLERANCE_PX, calibrate
from drivers.synth_rig import SynthRig
from fusion_pf.geometry import backproject


def _project(k, points_cam):
    return np.c_[k.fx * points_cam[:, 0] / points_cam[:, 2] + k.cx, k.fy * points_cam[:, 1] / points_cam[:, 2] + k.cy]


def test_world_truth_is_where_every_camera_sees_the_targets():
    rig = SynthRig(3, frames=4, seed=21, size=(320, 200), background_frames=1, hands=2, depth_model="basic")
    assert rig.truth_mm(0) == {}
    frames, truth = rig.frames(3), rig.truth_mm(3)
    assert sorted(truth) == ["head", "left_hand", "right_hand"]
    for name, frame in frames.items():
        pose = rig.poses[name]
        for target, xyz in truth.items():
            cam = pose.to_camera(xyz[None])
            u, v = _project(frame.intrinsics, cam)[0]
            gt = frame.ground_truths[target]
            # the head's pixel truth is the face centre each camera sees (1-2 cm in front of the head)
            assert (gt.u, gt.v) == pytest.approx((u, v), abs=2.0 if target == "head" else 1e-6), (name, target)
        # the depth image agrees: the right palm's surface is at most its thickness nearer than its centre
        u, v = (int(round(c)) for c in _project(frame.intrinsics, pose.to_camera(truth["right_hand"][None]))[0])
        if 0 <= u < 320 and 0 <= v < 200 and frame.depth[v, u]:
            z = pose.to_camera(truth["right_hand"][None])[0, 2]
            assert -60.0 < frame.depth[v, u] - z < 25.0, name


def test_the_cameras_see_one_static_scene():
    """Depth of camera A, moved into camera B by the two poses, meets B's own depth (one geometry)."""
    rig = SynthRig(2, board=True, frames=1, seed=22, size=(320, 200), depth_model="basic")
    (a, fa), (b, fb) = rig.frames(0).items()
    vs, us = np.nonzero(fa.depth)
    world = rig.poses[a].to_world(backproject(np.c_[us, vs], fa.depth[vs, us].astype(float), fa.intrinsics))
    cam_b = rig.poses[b].to_camera(world)
    uv = np.rint(_project(fb.intrinsics, cam_b)).astype(int)
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < 320) & (uv[:, 1] >= 0) & (uv[:, 1] < 200)
    seen = fb.depth[uv[inside, 1], uv[inside, 0]].astype(float)
    diff = seen - cam_b[inside, 2]
    valid = seen > 0
    assert inside.mean() > 0.5 and valid.mean() > 0.6
    # on the board (nearer than 2.5 m, nothing in front of it) unbiased and within the sensor noise (basic
    # model: sigma = 0.5 % of z per metre); farther, one camera sees wall the other sees behind the board
    near = valid & (cam_b[inside, 2] < 2500.0)
    relative = diff[near] / cam_b[inside][near, 2]
    assert near.sum() > 5000
    assert abs(np.median(relative)) < 0.003
    assert np.median(np.abs(relative)) < 0.02


def test_same_seed_same_frames_other_seed_other_poses():
    def digest(seed):
        rig = SynthRig(2, frames=2, seed=seed, size=(96, 64), background_frames=1)
        h = hashlib.sha1()
        for i in range(2):
            for frame in rig.frames(i).values():
                h.update(frame.color.tobytes() + frame.depth.tobytes())
        return h.hexdigest(), rig.poses

    (d1, p1), (d2, p2), (d3, p3) = digest(5), digest(5), digest(6)
    assert d1 == d2 and p1 == p2
    assert d1 != d3 and p1["cam0"].error_to(p3["cam0"])[0] > 1.0


@pytest.mark.parametrize("cameras, seed", [(3, 31), (2, 32)])
def test_calibrate_recovers_every_pose(tmp_path, fusion_pf, cameras, seed):
    rec = tmp_path / "board.mcap"
    proc = fusion_pf(
        "synth",
        rec,
        "--cameras",
        cameras,
        "--board",
        "--frames",
        2,
        "--size",
        "640x400",
        "--seed",
        seed,
        "--no-progress",
    )
    assert proc.returncode == 0, proc.stderr
    out = tmp_path / "cams.yaml"
    proc = fusion_pf("calibrate", rec, "-o", out)
    assert proc.returncode == 0, proc.stderr
    errors = re.findall(r"^(cam\d)  reprojection error (\d+\.\d+) px RMS", proc.stdout, re.M)
    assert [name for name, _ in errors] == [f"cam{k}" for k in range(cameras)]
    assert all(float(e) < 0.5 for _, e in errors)
    found = load_extrinsics(out)
    with RigReplay(rec) as rig:
        truth = rig.poses  # what the scene was rendered with, as the recording's /tf says
    for name, pose in SynthRig(cameras, frames=1, seed=seed, size=(640, 400)).poses.items():
        assert truth[name].error_to(pose)[0] < 1e-6 and truth[name].error_to(pose)[1] < 1e-6
    for name, pose in truth.items():
        dt, dr = found[name].error_to(pose)
        assert dt < 5.0 and dr < 0.5, (name, dt, dr)


def test_calibrate_without_a_board_says_which_cameras(tmp_path, fusion_pf):
    rec = tmp_path / "scene.mcap"
    assert fusion_pf("synth", rec, "--cameras", 2, "--frames", 2, "--size", "160x100", "--no-progress").returncode == 0
    proc = fusion_pf("calibrate", rec, "-o", tmp_path / "cams.json")
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1
    assert "was not found by camera cam0 (0 of 2 frames), cam1 (0 of 2 frames)" in proc.stderr
    assert not (tmp_path / "cams.json").exists()
    proc = fusion_pf("synth", tmp_path / "x.mcap", "--board")
    assert proc.returncode == 2 and "needs --cameras 2 or more" in proc.stderr


def test_icp_refinement_runs_and_keeps_only_what_agrees_with_the_board(tmp_path):
    rig_scene = SynthRig(2, board=True, frames=2, seed=33, size=(320, 200), depth_model="basic")
    from drivers.rig import RigRecorder

    path = tmp_path / "board.mcap"
    with RigRecorder(path, rig_scene.poses, metadata=rig_scene.metadata()) as rec:
        for i in range(2):
            rec.write(rig_scene.timestamp_ns(i), rig_scene.frames(i))
    with RigReplay(path) as rig:
        results = calibrate(rig, BoardSpec(), refine="icp")
    refined = [r for r in results.values() if r.icp is not None]
    assert len(refined) == 1 and sum(r.reference for r in results.values()) == 1
    (r,) = refined
    assert 0.0 < r.icp.fitness <= 1.0 and np.isfinite(r.icp.board_rms_px)
    if r.icp.accepted:
        assert r.icp.board_rms_px <= r.board.rms_px + ICP_BOARD_TOLERANCE_PX and r.pose != r.board.pose
    else:
        assert r.pose == r.board.pose


def test_colour_only_cameras_have_no_depth(tmp_path, fusion_pf):
    rec = tmp_path / "mixed.mcap"
    proc = fusion_pf(
        "synth", rec, "--cameras", 3, "--colour-only", 1, "--frames", 2, "--size", "96x64", "--no-progress"
    )
    assert proc.returncode == 0, proc.stderr
    with RigReplay(rec) as rig:
        depth = {
            name: [v.frame.depth is not None for s in rig for v in s.views.values() if v.camera == name]
            for name in rig.cameras
        }
        assert rig.replays["cam0"].metadata()["colour_only_cameras"] == "cam2"
    assert depth == {"cam0": [True, True], "cam1": [True, True], "cam2": [False, False]}
    proc = fusion_pf("synth", tmp_path / "x.mcap", "--colour-only", 1)
    assert proc.returncode == 2 and "needs --cameras 2 or more" in proc.stderr
    proc = fusion_pf("synth", tmp_path / "x.mcap", "--cameras", 2, "--colour-only", 3)
    assert proc.returncode == 2 and "must be in [0, cameras 2], got 3" in proc.stderr


def _window(img, u, v, r=3):
    u, v = int(round(u)), int(round(v))
    return img[v - r : v + r + 1, u - r : u + r + 1]


def test_a_card_hides_a_hand_from_one_camera_during_its_period_only():
    scene = dict(frames=9, seed=41, size=(320, 200), background_frames=1, hands=2, depth_model="basic")
    hidden = SynthRig(3, occlude="cam1:right_hand:3-5", **scene)
    plain = SynthRig(3, **scene)
    for i in range(1, 9):
        (frames, visible), base = hidden.render(i), plain.frames(i)
        xyz = hidden.truth_mm(i)["right_hand"]
        during = 3 <= i <= 5
        for name, frame in frames.items():
            cam = hidden.poses[name].to_camera(xyz[None])
            u, v = _project(frame.intrinsics, cam)[0]
            assert 10 <= u < 310 and 10 <= v < 190, (name, i)  # the palm is inside every image
            skin = _window(base[name].color, u, v).reshape(-1, 3).mean(axis=0)
            assert skin[0] - skin[2] > 40, (name, i)  # without a card every camera shows the palm's skin
            if name == "cam1" and during:
                seen = _window(frame.color, u, v).reshape(-1, 3).mean(axis=0)
                assert abs(seen[0] - seen[2]) < 25 and np.abs(seen - skin).max() > 60, i  # the card, not skin
                depth = _window(frame.depth, u, v).astype(float)
                assert np.median(depth[depth > 0]) < 0.6 * cam[0, 2], i  # the card is nearer than the palm
                assert "right_hand" not in frame.joints and "right_wrist" not in frame.joints
                assert "right_hand" not in visible[name] and "left_hand" in visible[name]
            else:
                assert np.array_equal(frame.color, base[name].color) and np.array_equal(frame.depth, base[name].depth)
                assert frame.joints == base[name].joints
                assert "right_hand" in visible[name], (name, i)


def test_occlusions_are_recorded_with_the_visibility_and_auto_follows_the_seed(tmp_path, fusion_pf):
    rec = tmp_path / "occluded.mcap"
    args = ("--cameras", 2, "--frames", 8, "--background-frames", 2, "--size", "160x100", "--no-progress")
    proc = fusion_pf("synth", rec, *args, "--occlude", "cam0:right_hand:4-5", "--seed", 3)
    assert proc.returncode == 0, proc.stderr
    with RigReplay(rec) as rig:
        assert rig.replays["cam0"].metadata()["occlusions"] == "cam0:right_hand:4-5"
        assert rig.visibility is not None
        times = [int(t) for t in rig.timestamps]
        assert sorted(rig.visibility) == times[2:]  # the person's instants
        for k, t in enumerate(times[2:], start=2):
            assert rig.visibility[t]["cam1"] == ("right_hand",)
            assert rig.visibility[t]["cam0"] == (() if k in (4, 5) else ("right_hand",)), k
    auto = [
        SynthRig(3, occlude="auto", frames=200, background_frames=20, hands=2, seed=s).occlusions for s in (7, 7, 8)
    ]
    assert auto[0] == auto[1] and auto[0] != auto[2]
    for periods in auto:
        assert [o.target for o in periods] == ["right_hand", "left_hand"]
        assert all(20 <= o.start <= o.end < 200 and o.end - o.start + 1 == 45 for o in periods)
        assert periods[0].end < 110 <= periods[1].start  # each hand in its own half of the person frames
    for bad, message in (
        ("cam0:right_hand:5", "must be CAMERA:TARGET:START-END"),
        ("cam0:right_hand:5-2", "END 2 is before START 5"),
        ("cam7:right_hand:2-3", "no camera 'cam7'; the rig has cam0, cam1"),
        ("cam0:left_hand:2-3", "no target 'left_hand'; the scene has right_hand"),
        ("cam0:right_hand:2-8", "frames must lie in [0, 7], got 2-8"),
    ):
        proc = fusion_pf("synth", tmp_path / "x.mcap", *args, "--occlude", bad)
        assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1, (bad, proc.stderr)
        assert message in proc.stderr, (bad, proc.stderr)
        assert not (tmp_path / "x.mcap").exists()
    proc = fusion_pf("synth", tmp_path / "x.mcap", "--occlude", "auto")
    assert proc.returncode == 2 and "needs --cameras 2 or more" in proc.stderr
