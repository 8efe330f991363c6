"""Interop: files written by foxglove-sdk replay identically; our files pass `rerun mcap check`
and the TypeScript @mcap readers (CRC-validated)."""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from drivers import mcap_format as fmt
from drivers.mcap_replay import McapReplay

INTEROP = Path(__file__).resolve().parents[1] / "interop"
VENV_BIN = Path(sys.executable).parent  # the test run's own environment (tools/setup.sh: .venv)


def replay(path):
    with McapReplay(path) as r:
        return list(r), r.info()


@pytest.mark.parametrize("color, depth", [("rgb8", "16UC1"), ("bgr8", "mono16"), ("png", "png"), ("jpeg", "16UC1")])
def test_foxglove_sdk_file_replays_to_identical_frames(
    tmp_path, make_frames, record, write_foxglove, same_frames, color, depth
):
    frames = make_frames(12, no_depth=(4,), no_skeleton=(7,), calibration_change=9)
    # both writers encode JPEG with OpenCV at quality 95, so even JPEG frames decode identically
    ours, our_info = replay(
        record(tmp_path / "ours.mcap", frames, jpeg_quality=95, color_format="jpeg" if color == "jpeg" else "raw")
    )
    theirs, info = replay(write_foxglove(tmp_path / "sdk.mcap", frames, color=color, depth=depth))
    assert info.library.startswith("foxglove-sdk") and info.indexed and not info.truncated
    same_frames(ours, theirs)
    if color != "jpeg":
        same_frames(frames, theirs)
    assert (info.frames, info.missing_depth, info.missing_skeleton, info.background_frames) == (
        our_info.frames,
        our_info.missing_depth,
        our_info.missing_skeleton,
        our_info.background_frames,
    )
    assert info.color_format == color and info.depth_format == depth


@pytest.mark.parametrize(
    "options, reason",
    [
        ({"use_chunks": False, "emit_chunk_indexes": False, "emit_message_indexes": False}, "no chunk index"),
        ({"emit_message_indexes": False}, "no message index"),
    ],
    ids=["unchunked", "no-message-index"],
)
def test_unindexed_foxglove_file_is_scanned(tmp_path, make_frames, write_foxglove, same_frames, options, reason):
    """A writer without chunks or message indexes: replay rebuilds the index by scanning."""
    import foxglove
    from foxglove import Context
    from foxglove.mcap import MCAPWriteOptions

    frames = make_frames(6)
    indexed, _ = replay(write_foxglove(tmp_path / "a.mcap", frames))
    original = foxglove.open_mcap

    def unchunked(path, *, context: Context, writer_options: MCAPWriteOptions):
        return original(path, context=context, writer_options=MCAPWriteOptions(chunk_size=20_000, **options))

    foxglove.open_mcap = unchunked
    try:
        path = write_foxglove(tmp_path / "flat.mcap", frames)
    finally:
        foxglove.open_mcap = original
    scanned, info = replay(path)
    assert not info.indexed and not info.truncated
    assert info.notes[0].startswith(f"file has no usable index ({reason})")
    same_frames(indexed, scanned)
    with McapReplay(path) as r:
        same_frames([indexed[4]], [r.frame(4)])


@pytest.fixture(scope="module")
def rerun_env(tmp_path_factory):
    rerun = VENV_BIN / "rerun"
    assert rerun.exists(), f"{rerun} missing: install rerun-sdk (tools/setup.sh --test)"
    home = tmp_path_factory.mktemp("rerun-home")
    env = {
        **os.environ,
        "HOME": str(home),
        "XDG_CONFIG_HOME": str(home / "config"),
        "XDG_DATA_HOME": str(home / "data"),
        "XDG_CACHE_HOME": str(home / "cache"),
        "RERUN_TELEMETRY_ENABLED": "false",
    }
    help_text = subprocess.run([str(rerun), "mcap", "--help"], env=env, capture_output=True, text=True, timeout=60)
    assert "check" in help_text.stdout, "this rerun version has no `rerun mcap check`"
    subprocess.run([str(rerun), "analytics", "disable"], env=env, capture_output=True, timeout=60, check=True)
    return str(rerun), env


def _rerun_check(rerun: str, env: dict, path) -> tuple[subprocess.CompletedProcess, dict[str, str]]:
    """``rerun mcap check PATH`` (must exit 0) and its verdict per topic (``ok``, ``warn``, ``error``, ``fail``)."""
    proc = subprocess.run([rerun, "mcap", "check", str(path)], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows = {
        line.split()[3]: line.split()[0]
        for line in proc.stdout.splitlines()
        if line.split()[:1] and line.split()[0] in ("ok", "warn", "error", "fail")
    }
    return proc, rows


@pytest.mark.parametrize("color_format, depth_format", [("raw", "raw"), ("jpeg", "png")])
def test_rerun_mcap_check_passes(tmp_path, make_frames, record, rerun_env, color_format, depth_format):
    rerun, env = rerun_env
    path = record(tmp_path / "ours.mcap", make_frames(10), color_format=color_format, depth_format=depth_format)
    proc, rows = _rerun_check(rerun, env, path)
    assert rows == {topic: "ok" for topic in fmt.FRAME_TOPICS if topic != fmt.HAND_TOPIC}, proc.stdout  # no hands here


def test_rerun_mcap_check_catches_corruption(tmp_path, make_frames, record, rerun_env):
    """The check used above is able to fail: a flipped byte in a chunk is reported."""
    rerun, env = rerun_env
    path = record(tmp_path / "ours.mcap", make_frames(10))
    with McapReplay(path) as r:
        victim = r._blocks[1]
    data = bytearray(path.read_bytes())
    data[victim.offset + victim.length // 2] ^= 0x01
    path.write_bytes(bytes(data))
    proc = subprocess.run([rerun, "mcap", "check", str(path)], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode != 0 and "CRC" in proc.stderr


def node_read(path):
    node = shutil.which("node")
    assert node, "node is not installed (tools/setup.sh --test installs it)"
    assert (INTEROP / "node_modules" / "@mcap" / "core").is_dir(), (
        "run `npm ci` in tests/interop (tools/setup.sh --test)"
    )
    return subprocess.run(
        [node, str(INTEROP / "read_mcap.mjs"), str(path)], capture_output=True, text=True, timeout=120, cwd=INTEROP
    )


def indexed_chunks(path):
    """The chunk indexes of a finished recording (read by the mcap Python reader)."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        return make_reader(fh).get_summary().chunk_indexes


def test_typescript_readers_agree(tmp_path, make_frames, record):
    frames = make_frames(9, no_depth=(2,), no_skeleton=(3, 4))
    path = record(tmp_path / "ours.mcap", frames, color_format="jpeg", metadata={"seed": "4"})
    proc = node_read(path)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    indexed, stream = out["indexed"], out["stream"]
    counts = {
        fmt.CALIBRATION_TOPIC: len(indexed_chunks(path)),
        fmt.COLOR_TOPIC: 9,
        fmt.DEPTH_TOPIC: 8,
        fmt.SKELETON_TOPIC: 7,
        fmt.GROUND_TRUTH_TOPIC: 7,
    }  # a calibration copy starts every chunk
    assert {topic: t["count"] for topic, t in indexed["topics"].items()} == counts
    assert stream["done"] and stream["counts"] == counts and stream["dataSectionCrc"] != 0
    assert indexed["ordered"] and indexed["compression"] == ["zstd"] and indexed["messages"] == sum(counts.values())
    assert indexed["statistics"]["messageCount"] == sum(counts.values())
    topics = indexed["topics"]
    assert (
        topics[fmt.COLOR_TOPIC]["schema"] == fmt.COMPRESSED_IMAGE
        and topics[fmt.COLOR_TOPIC]["first"]["format"] == "jpeg"
    )
    assert topics[fmt.DEPTH_TOPIC]["first"] == {
        "width": 64,
        "height": 48,
        "encoding": "16UC1",
        "frame_id": "camera",
        "dataBytes": 64 * 48 * 2,
    }
    k = frames[0].intrinsics
    assert topics[fmt.CALIBRATION_TOPIC]["first"]["K"] == pytest.approx([k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1])
    assert topics[fmt.SKELETON_TOPIC]["schemaEncoding"] == "jsonschema" and topics[fmt.SKELETON_TOPIC]["first"] == {
        "keys": ["joints"]
    }
    recording_meta = [m for m in indexed["metadata"] if m["name"] == fmt.RECORDING_METADATA]
    channel_meta = {m["metadata"]["topic"] for m in indexed["metadata"] if m["name"] == fmt.CHANNEL_METADATA}
    assert channel_meta == set(counts)
    assert recording_meta[-1] == {
        "name": fmt.RECORDING_METADATA,
        "metadata": {
            "format_version": "1",
            "writer": indexed["metadata"][0]["metadata"]["writer"],
            "seed": "4",
            "background_frames": "2",
        },
    }


def test_typescript_reader_validates_crcs(tmp_path, make_frames, record):
    path = record(tmp_path / "ours.mcap", make_frames(10))
    with McapReplay(path) as r:
        victim = r._blocks[1]
    data = bytearray(path.read_bytes())
    data[victim.offset + victim.length // 2] ^= 0x01
    path.write_bytes(bytes(data))
    proc = node_read(path)
    assert proc.returncode == 1 and "CRC" in proc.stderr and proc.stderr.count("\n") == 1


# --------------------------------------------------------------------------- several cameras

_RERUN_TF = re.compile(r"\[(\w+)\]\s+┆\s+\[world\]\s+┆\s+\[\[([^\]]+)\]\]\s+┆\s+\[\[([^\]]+)\]\]")


@pytest.fixture(params=["merged", "synth"])
def rig_file(request, tmp_path, make_frames, record):
    """A multi-camera recording: merged from two single-camera ones (calibration changing, depth missing,
    small chunks), or the synthetic rig with world ground truth."""
    from drivers.rig import RigRecorder, merge
    from drivers.synth_rig import SynthRig
    from fusion_pf.rig import CameraPose

    path = tmp_path / "rig.mcap"
    if request.param == "merged":
        a = record(tmp_path / "a.mcap", make_frames(8, seed=1, no_depth=(3,), calibration_change=5))
        b = record(tmp_path / "b.mcap", make_frames(8, seed=2, size=(48, 32)))
        poses = {
            "cam_left": CameraPose.from_rvec([0.0, 0.5, 0.0], [-600.0, 0.0, 0.0]),
            "cam_right": CameraPose.from_rvec([0.1, -0.5, 0.05], [600.0, 20.0, -30.0]),
        }
        merge([a, b], poses, path, recorder_kwargs={"chunk_size": 16_000, "color_format": "jpeg"})
    else:
        rig = SynthRig(3, frames=3, seed=3, size=(96, 64), background_frames=1, hands=2)
        with RigRecorder(path, rig.poses, metadata=rig.metadata()) as rec:
            for i in range(3):
                rec.write(rig.timestamp_ns(i), rig.frames(i), rig.truth_mm(i))
    return path


def test_rig_recording_opens_in_the_typescript_readers_with_its_poses(rig_file):
    from drivers.mcap_replay import McapTopics
    from drivers.rig import RigReplay

    proc = node_read(rig_file)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    indexed, stream = out["indexed"], out["stream"]
    with McapTopics(rig_file) as topics:
        counts = {topic: len(topics.messages(topic)) for topic in topics.topics}
    assert {topic: t["count"] for topic, t in indexed["topics"].items()} == counts
    assert stream["done"] and stream["counts"] == counts
    with RigReplay(rig_file) as rig:
        poses = rig.poses
        for name in rig.cameras:
            cal = indexed["topics"][f"/{name}/camera/calibration"]["first"]
            assert cal["frame_id"] == name  # placed in the tf tree by its pose
            assert indexed["topics"][f"/{name}/camera/color"]["first"]["frame_id"] == name
    tf = {t["child_frame_id"]: t for t in indexed["transforms"]}
    assert sorted(tf) == sorted(poses) and {t["topic"] for t in tf.values()} == {"/tf"}
    for name, pose in poses.items():
        assert tf[name]["parent_frame_id"] == "world"
        assert tf[name]["translation"] == pytest.approx(pose.translation_mm / 1000.0, abs=1e-12)
        assert tf[name]["rotation"] == pytest.approx(pose.quaternion(), abs=1e-12)


def test_rig_recording_passes_rerun_and_rerun_reads_its_poses(rig_file, rerun_env, tmp_path):
    from drivers.rig import RigReplay

    rerun, env = rerun_env
    proc, rows = _rerun_check(rerun, env, rig_file)
    with RigReplay(rig_file) as rig:
        poses = rig.poses
        assert {f"/{name}/camera/color" for name in rig.cameras} | {"/tf"} <= set(rows)
    assert set(rows.values()) == {"ok"}, proc.stdout
    rrd = tmp_path / "rig.rrd"
    proc = subprocess.run(
        [rerun, "mcap", "convert", str(rig_file), "-o", str(rrd)], env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    proc = subprocess.run(
        [rerun, "rrd", "print", "-vvv", str(rrd)], env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    found = {m.group(1): (m.group(2), m.group(3)) for m in _RERUN_TF.finditer(proc.stdout)}
    assert sorted(found) == sorted(poses), proc.stdout[-2000:]  # Rerun's Transform3D, world -> camera
    for name, (quaternion, translation) in found.items():
        q = [float(v) for v in quaternion.split(",")]
        t = [float(v) for v in translation.split(",")]
        assert q == pytest.approx(poses[name].quaternion(), abs=1e-6)  # float32
        assert t == pytest.approx(poses[name].translation_mm / 1000.0, abs=1e-6)


def test_a_world_tracker_output_passes_rerun_with_its_camera_poses(tmp_path, rerun_env, fusion_pf):
    """``track MULTI.mcap -o OUT.mcap``: ``/tracker/world`` and the copied ``/tf`` pass Rerun's check; Rerun places the cameras."""
    from drivers.rig import RigReplay

    rerun, env = rerun_env
    multi, out = tmp_path / "multi.mcap", tmp_path / "out.mcap"
    proc = fusion_pf(
        "synth", multi, "--cameras", 2, "--hands", 2, "--frames", 12, "--background-frames", 3, "--size", "160x100"
    )
    assert proc.returncode == 0, proc.stderr
    proc = fusion_pf("track", multi, "-o", out)
    assert proc.returncode == 0, proc.stderr
    proc, rows = _rerun_check(rerun, env, out)
    assert {"/tracker/world", "/tf"} <= set(rows) and set(rows.values()) == {"ok"}, proc.stdout
    rrd = tmp_path / "out.rrd"
    proc = subprocess.run([rerun, "mcap", "convert", str(out), "-o", str(rrd)], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    proc = subprocess.run([rerun, "rrd", "print", "-vvv", str(rrd)], env=env, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    found = {m.group(1): m.group(3) for m in _RERUN_TF.finditer(proc.stdout)}
    with RigReplay(multi) as rig:
        poses = rig.poses
    assert sorted(found) == sorted(poses), proc.stdout[-2000:]
    for name, translation in found.items():
        t = [float(v) for v in translation.split(",")]
        assert t == pytest.approx(poses[name].translation_mm / 1000.0, abs=1e-6)
