"""Multi-camera recordings: poses, extrinsics files, merging single-camera recordings, reading frame sets."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from drivers import mcap_format as fmt
from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapReplay, McapTopics
from drivers.rig import RigReplay, load_extrinsics, match_times, merge
from drivers.synth import SynthSource
from fusion_pf.errors import InputError, RecordingError
from fusion_pf.rig import CameraPose

START = 1_700_000_000_000_000_000


def _random_pose(rng: np.random.Generator) -> CameraPose:
    return CameraPose.from_rvec(rng.uniform(-2.5, 2.5, 3), rng.uniform(-3000, 3000, 3))


def test_pose_quaternion_round_trip_and_algebra():
    rng = np.random.default_rng(0)
    for _ in range(50):
        pose = _random_pose(rng)
        back = CameraPose.from_quaternion(pose.quaternion(), pose.translation_mm)
        assert np.allclose(back.rotation, pose.rotation, atol=1e-12)
        p = rng.uniform(-1000, 1000, (7, 3))
        assert np.allclose(pose.to_camera(pose.to_world(p)), p)
        assert np.allclose(pose.compose(pose.inverse()).rotation, np.eye(3), atol=1e-12)
        other = _random_pose(rng)
        assert np.allclose(pose.compose(other).to_world(p), pose.to_world(other.to_world(p)))
    # rvec (Rodrigues) checked against OpenCV, an independent implementation
    import cv2

    rvec = np.array([0.3, -1.2, 0.7])
    assert np.allclose(CameraPose.from_rvec(rvec, np.zeros(3)).rotation, cv2.Rodrigues(rvec)[0], atol=1e-12)
    # 30 degrees about y: error_to measures it
    a = CameraPose.identity()
    b = CameraPose.from_rvec([0, math.radians(30), 0], [3, 4, 0])
    assert a.error_to(b) == pytest.approx((5.0, 30.0))
    with pytest.raises(InputError, match="proper rotation"):
        CameraPose(np.diag([1.0, 1.0, -1.0]), np.zeros(3))


def _write_extrinsics(path, entries):
    path.write_text(json.dumps({"cameras": entries}))
    return path


@pytest.mark.parametrize("angle", [1e-9, 1e-7, 1e-4, 0.5, 3.0])
def test_pose_rotation_error_is_the_relative_angle_at_every_scale(angle):
    # a rotation of `angle` rad about an oblique axis, applied after an arbitrary pose
    base = CameraPose.from_rvec([0.3, -1.1, 0.7], [10, 20, 30])
    axis = np.array([1.0, 2.0, -2.0]) / 3.0
    turned = base.compose(CameraPose.from_rvec(angle * axis, [0, 0, 0]))
    assert turned.error_to(base)[1] == pytest.approx(math.degrees(angle), rel=1e-6, abs=1e-12)
    assert base.error_to(base)[1] < 1e-12


def test_extrinsics_files_accept_quaternion_matrix_and_rvec(tmp_path):
    pose = CameraPose.from_rvec([0.1, 0.5, -0.2], [100, -20, 30])
    entries = [
        {"name": "a", "translation_mm": [100, -20, 30], "rotation_xyzw": pose.quaternion().tolist()},
        {"name": "b", "translation_mm": [100, -20, 30], "rotation_matrix": pose.rotation.tolist()},
        {"name": "c", "translation_mm": [100, -20, 30], "rotation_rvec": [0.1, 0.5, -0.2]},
    ]
    poses = load_extrinsics(_write_extrinsics(tmp_path / "e.json", entries))
    assert list(poses) == ["a", "b", "c"]
    for p in poses.values():
        assert p.error_to(pose)[0] < 1e-9 and p.error_to(pose)[1] < 1e-6
    yaml = tmp_path / "e.yaml"
    yaml.write_text("cameras:\n  left:\n    translation_mm: [1, 2, 3]\n    rotation_rvec: [0, 0, 0]\n")
    assert load_extrinsics(yaml)["left"] == CameraPose(np.eye(3), [1, 2, 3])


@pytest.mark.parametrize(
    "entry, message",
    [
        ({"name": "a", "translation_mm": [0, 0, 0]}, "needs exactly one of rotation_xyzw"),
        ({"name": "a", "rotation_rvec": [0, 0, 0]}, "has no translation_mm"),
        ({"name": "a/b", "translation_mm": [0, 0, 0], "rotation_rvec": [0, 0, 0]}, "name must be 1-64 letters"),
        ({"name": "a", "translation_mm": [0, 0], "rotation_rvec": [0, 0, 0]}, "translation must be 3 finite"),
        ({"name": "a", "translation_mm": [0, 0, 0], "rotation_xyzw": [0, 0, 0, 0.5]}, "norm 1"),
    ],
)
def test_bad_extrinsics_are_named(tmp_path, entry, message):
    with pytest.raises(InputError, match=message):
        load_extrinsics(_write_extrinsics(tmp_path / "e.json", [entry]))


def test_match_times_against_brute_force():
    rng = np.random.default_rng(3)
    for _ in range(30):
        ref = np.cumsum(rng.integers(20, 40, 30)).astype(np.int64)
        other = np.unique(rng.integers(0, int(ref[-1]) + 50, 25)).astype(np.int64)
        tol = int(rng.integers(0, 20))
        got, unmatched = match_times(ref, other, tol)
        # brute force: each frame's nearest reference time (ties to the earlier), kept by the nearest claimant
        want = other.copy()
        claims: dict[int, list[tuple[int, int]]] = {}
        for i, t in enumerate(other):
            d = np.abs(ref - t)
            j = int(np.argmin(d))
            if d[j] <= tol:
                claims.setdefault(int(ref[j]), []).append((int(d[j]), i))
        for r, cl in claims.items():
            want[min(cl)[1]] = r
        assert np.array_equal(got, want)
        assert unmatched == int(np.count_nonzero(got == other) - np.count_nonzero(np.isin(other, ref) & (got == other)))


def _single(path, *, seed, size, frames, start_ns=START, background=0):
    src = SynthSource(frames=frames, seed=seed, size=size, start_ns=start_ns, background_frames=background)
    with src, McapRecorder(path, metadata=src.metadata()) as rec:
        for frame in src:
            rec.write(frame)
    return path


@pytest.fixture
def rig_inputs(tmp_path):
    a = _single(tmp_path / "a.mcap", seed=1, size=(96, 64), frames=5, background=1)
    # camera b: another size, 4 ms later, one frame more, which has no partner
    b = _single(tmp_path / "b.mcap", seed=2, size=(80, 48), frames=6, start_ns=START + 4_000_000, background=1)
    poses = {
        "cam_a": CameraPose.from_rvec([0.0, 0.4, 0.0], [-500.0, 0.0, 100.0]),
        "cam_b": CameraPose.from_rvec([0.05, -0.4, 0.02], [500.0, -30.0, 100.0]),
    }
    return a, b, poses


def test_merge_and_read_back_frame_sets(tmp_path, rig_inputs):
    a, b, poses = rig_inputs
    out = tmp_path / "m.mcap"
    report = merge([a, b], poses, out)
    assert report["sets"] == 6
    assert report["cameras"]["cam_b"] == {
        "input": str(b),
        "frames": 6,
        "unmatched": 1,
        "offset_ns": 0,
        "offset_from": "none",
        "correlation": None,
    }
    with McapReplay(a) as ra, McapReplay(b) as rb:
        fa, fb = list(ra), list(rb)
    with RigReplay(out) as rig:
        assert rig.cameras == ("cam_a", "cam_b")
        for name, pose in poses.items():
            dt, dr = rig.poses[name].error_to(pose)
            assert dt < 1e-6 and dr < 1e-6
        sets = list(rig)
        assert [s.index for s in sets] == list(range(6))
        assert [sorted(s.views) for s in sets] == [["cam_a", "cam_b"]] * 5 + [["cam_b"]]
        assert [s.background for s in sets] == [True] + [False] * 5
        for k, s in enumerate(sets[:5]):
            assert s.timestamp_ns == fa[k].timestamp_ns  # camera b takes the reference camera's time
            assert np.array_equal(s.views["cam_a"].frame.color, fa[k].color)
            assert np.array_equal(s.views["cam_b"].frame.depth, fb[k].depth)
            assert s.views["cam_b"].frame.intrinsics == fb[k].intrinsics
            assert s.views["cam_b"].frame.ground_truth == fb[k].ground_truth
        assert sets[5].timestamp_ns == fb[5].timestamp_ns  # no partner: its own time
        again = rig.frameset(3)
        assert np.array_equal(again.views["cam_b"].frame.color, sets[3].views["cam_b"].frame.color)
        info = rig.info()
        assert [(c["name"], c["width"], c["height"], c["frames"]) for c in info["cameras"]] == [
            ("cam_a", 96, 64, 5),
            ("cam_b", 80, 48, 6),
        ]
        assert info["complete_sets"] == 5 and info["instants"] == 6
    # the convention's topics per camera, one static pose per camera on /tf, frame_id = camera
    with McapTopics(out) as topics:
        assert {"/cam_a/camera/color", "/cam_b/camera/depth", "/cam_b/camera/calibration", "/tf"} <= topics.topics
        tf = [fmt.decode_transform(d) for _t, _e, d in topics.messages(fmt.TF_TOPIC)]
        assert sorted((p, c) for p, c, _ in tf) == [("world", "cam_a"), ("world", "cam_b")]
        from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration

        (_, _, data), *_ = topics.messages("/cam_b/camera/calibration")
        assert CameraCalibration.FromString(data).frame_id == "cam_b"


def test_a_camera_without_a_pose_is_refused(tmp_path):
    src = SynthSource(frames=2, seed=0, size=(64, 48))
    path = tmp_path / "x.mcap"
    with src, McapRecorder(path) as rec:
        for frame in src:
            rec.write(frame, "cam_x")
    with pytest.raises(RecordingError, match=r"camera cam_x has no pose: expected a foxglove.FrameTransform world"):
        RigReplay(path).__enter__()
    # the single-camera reader says what it found instead
    with pytest.raises(RecordingError, match=r"has no /camera/color topic.*/cam_x/camera/color"):
        McapReplay(path).open()


def test_merge_and_info_command_line(tmp_path, rig_inputs, fusion_pf):
    a, b, poses = rig_inputs
    cams = _write_extrinsics(
        tmp_path / "cams.json",
        [
            {"name": n, "translation_mm": p.translation_mm.tolist(), "rotation_matrix": p.rotation.tolist()}
            for n, p in poses.items()
        ],
    )
    out = tmp_path / "m.mcap"
    proc = fusion_pf("merge", a, b, "--extrinsics", cams, "-o", out, "--tolerance-ms", "1")
    assert proc.returncode == 0, proc.stderr
    assert "cam_b             6 frames" in proc.stdout and "6 without a partner" in proc.stdout  # 4 ms > 1 ms
    proc = fusion_pf("info", out, "--verify")
    assert proc.returncode == 0, proc.stderr
    assert "rig           2 cameras, 11 instants (0 with every camera)" in proc.stdout
    assert "cam_a  96x64" in proc.stdout and "pose t_mm=[-500.0, 0.0, 100.0]" in proc.stdout
    proc = fusion_pf("merge", a, b, "--extrinsics", cams, "-o", out)
    assert proc.returncode != 0 and proc.stderr.strip().endswith("already exists; pass --force to overwrite it")
    proc = fusion_pf("merge", a, "--extrinsics", cams, "-o", tmp_path / "n.mcap")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "the extrinsics name 2 camera(s) (cam_a, cam_b) but 1 recording(s) were given" in proc.stderr


def test_a_damaged_chunk_costs_only_its_own_frames_in_every_camera(tmp_path, make_frames, record):
    """Chunks hold several instants of both cameras and start with the calibration of each: after a
    corrupt chunk the frames keep their own camera's intrinsics (camera a's changes at frame 5)."""
    a = record(tmp_path / "a.mcap", make_frames(12, seed=1, calibration_change=5))
    b = record(tmp_path / "b.mcap", make_frames(12, seed=2, size=(48, 32)))
    poses = {"a": CameraPose.identity(), "b": CameraPose.from_rvec([0, 0.3, 0], [500, 0, 0])}
    out = tmp_path / "m.mcap"
    merge([a, b], poses, out, recorder_kwargs={"chunk_size": 60_000})
    with McapReplay(a) as ra:
        want = {f.timestamp_ns: f.intrinsics for f in ra}
    with McapReplay(out, camera="a") as r:
        times = r.timestamps.copy()
        victim = next(blk for blk in r._blocks if blk.start_ns <= times[5] <= blk.end_ns)
        # every chunk starts with the calibration of each camera whose frames it holds
        for block in (blk for blk in r._blocks if blk.is_chunk):
            topics = [r._channels[cid].topic for cid, _t, _d, _s in r._block_records(block)]
            cameras = {t.split("/")[1] for t in topics if t.endswith("/camera/color")}
            assert cameras
            for c in cameras:
                first = topics.index(f"/{c}/camera/color")
                assert f"/{c}/camera/calibration" in topics[:first], (block.offset, c)
        # and the calibration metadata records are each camera's own
        assert {k.width for k in r._cal_meta.values()} == {64}
    with McapReplay(out, camera="b") as r:
        assert {k.width for k in r._cal_meta.values()} == {48}
    gone = [int(t) for t in times if victim.start_ns <= t <= victim.end_ns]
    assert 2 <= len(gone) < 6 and victim.end_ns < times[-1]
    data = bytearray(out.read_bytes())
    data[victim.offset + victim.length // 2] ^= 0x01
    out.write_bytes(bytes(data))
    with RigReplay(out) as rig:
        sets = list(rig)
        lost = {name: r.stats.dropped for name, r in rig.replays.items()}
    assert lost == {"a": len(gone), "b": len(gone)}
    assert [s.timestamp_ns for s in sets] == [int(t) for t in times if int(t) not in gone]
    for s in sets:
        assert sorted(s.views) == ["a", "b"]
        assert s.views["a"].frame.intrinsics == want[s.timestamp_ns]
        assert s.views["b"].frame.intrinsics.width == 48


def test_poses_survive_a_damaged_first_chunk(tmp_path, make_frames, record):
    """/tf is in the first chunk; the recording metadata repeats the poses outside the chunks."""
    a = record(tmp_path / "a.mcap", make_frames(8, seed=1))
    b = record(tmp_path / "b.mcap", make_frames(8, seed=2))
    poses = {
        "a": CameraPose.from_rvec([0.2, 0.1, 0.0], [1, 2, 3]),
        "b": CameraPose.from_rvec([0, -0.3, 0], [500, 0, 0]),
    }
    out = tmp_path / "m.mcap"
    merge([a, b], poses, out, recorder_kwargs={"chunk_size": 20_000})
    with McapTopics(out) as topics:
        first = min((blk for blk in topics._blocks if blk.is_chunk), key=lambda blk: blk.offset)
        assert first.start_ns == first.end_ns  # the poses and the first instant
    data = bytearray(out.read_bytes())
    data[first.offset + first.length // 2] ^= 0x01
    out.write_bytes(bytes(data))
    with RigReplay(out) as rig:
        sets = list(rig)
        assert any("pose taken from the recording metadata" in note for note in rig.notes)
        for name, pose in poses.items():
            assert rig.poses[name].error_to(pose)[0] < 1e-9 and rig.poses[name].error_to(pose)[1] < 1e-6
        assert rig.replays["a"].stats.dropped == 1 and rig.replays["b"].stats.dropped == 0
    assert [sorted(s.views) for s in sets] == [["b"]] + [["a", "b"]] * 7  # the damage took a's first frame
