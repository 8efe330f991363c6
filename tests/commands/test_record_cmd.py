"""``fusion-pf record``: synthetic and replayed sources, limits, overwrite protection, source failure, Ctrl-C."""

import json
import signal
import subprocess
import sys
import time

import numpy as np
from mcap.writer import Writer

from drivers import mcap_format as fmt
from drivers import open_source
from drivers.mcap_replay import McapReplay
from fusion_pf.frame import Intrinsics

CLI = [sys.executable, "-m", "fusion_pf"]
SYNTH = "synth:frames=6,seed=2,size=160x100,background_frames=2"


def error_line(proc):
    lines = proc.stderr.splitlines()
    assert "Traceback" not in proc.stderr and len([x for x in lines if x.startswith("fusion-pf: error:")]) == 1
    return next(x for x in lines if x.startswith("fusion-pf: error:"))


def test_record_synth_matches_the_source(tmp_path, fusion_pf):
    out = tmp_path / "synth.mcap"
    proc = fusion_pf("record", SYNTH, out)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"recorded 6 frames to {out}")
    assert "0 dropped, 0 without depth" in proc.stdout and f"{out.stat().st_size} bytes" in proc.stdout
    with open_source(SYNTH) as src, McapReplay(out) as replay:
        info = replay.info()
        for a, b in zip(src, replay, strict=True):
            assert a.timestamp_ns == b.timestamp_ns and np.array_equal(a.color, b.color)
            assert np.array_equal(a.depth, b.depth) and a.intrinsics == b.intrinsics
            assert a.ground_truth == b.ground_truth and a.background == b.background
    assert info.indexed and info.background_frames == 2
    assert info.metadata["source"] == SYNTH and info.metadata["generator"] == "fusion_pf.synth"


def test_limits_formats_and_overwrite(tmp_path, fusion_pf):
    out = tmp_path / "x.mcap"
    assert (
        fusion_pf(
            "record",
            SYNTH,
            out,
            "--frames",
            3,
            "--color-format",
            "jpeg",
            "--depth-format",
            "png",
            "--meta",
            "operator=ann",
        ).returncode
        == 0
    )
    before = out.read_bytes()
    proc = fusion_pf("record", SYNTH, out)
    assert proc.returncode == 2 and "already exists; pass --force to overwrite it" in error_line(proc)
    assert out.read_bytes() == before
    with McapReplay(out) as replay:
        info = replay.info()
    assert info.frames == 3 and (info.color_format, info.depth_format) == ("jpeg", "png")
    assert info.metadata["operator"] == "ann"
    # 30 fps synthetic capture time: 0.05 s holds frames at 0 and 33 ms
    proc = fusion_pf("record", SYNTH, out, "--duration", 0.05, "--force")
    assert proc.returncode == 0, proc.stderr
    with McapReplay(out) as replay:
        assert len(replay) == 2


def test_rerecording_a_recording(tmp_path, fusion_pf):
    first, second = tmp_path / "a.mcap", tmp_path / "b.mcap"
    assert fusion_pf("record", SYNTH, first).returncode == 0
    assert fusion_pf("record", first, second, "--color-format", "png").returncode == 0
    with McapReplay(first) as a, McapReplay(second) as b:
        assert b.info().metadata["seed"] == "2" and b.info().background_frames == 2
        for fa, fb in zip(a, b, strict=True):
            assert np.array_equal(fa.color, fb.color) and fa.background == fb.background
    proc = fusion_pf("record", first, first, "--force")
    assert proc.returncode == 2 and "is an input file; choose another output file" in error_line(proc)


def _source_that_fails_at_frame(path, n_good):
    """A recording whose frame ``n_good`` has a skeleton message that is not JSON."""
    k = Intrinsics(64, 48, 50, 50, 32, 24)
    with open(path, "wb") as fh:
        writer = Writer(fh, chunk_size=4_000)
        writer.start()
        cal = writer.register_channel(
            fmt.CALIBRATION_TOPIC, "protobuf", writer.register_schema(fmt.CAMERA_CALIBRATION, "protobuf", b"")
        )
        color = writer.register_channel(
            fmt.COLOR_TOPIC, "protobuf", writer.register_schema(fmt.RAW_IMAGE, "protobuf", b"")
        )
        skel = writer.register_channel(
            fmt.SKELETON_TOPIC,
            "json",
            writer.register_schema(fmt.SKELETON_SCHEMA, "jsonschema", fmt.json_schema_data(fmt.SKELETON_SCHEMA)),
        )
        writer.add_message(cal, 0, fmt.encode_calibration(k, 0).SerializeToString(), 0)
        for i in range(n_good + 3):
            t = i * 1000
            image = np.full((48, 64, 3), i, np.uint8)
            writer.add_message(color, t, fmt.encode_color(image, t).SerializeToString(), t)
            body = b"{not json" if i == n_good else fmt.encode_json({"joints": []})
            writer.add_message(skel, t, body, t)
        writer.finish()
    return path


def test_malformed_skeleton_midway_is_skipped_and_reported(tmp_path, fusion_pf):
    """Issue 14 item 6: one malformed optional message costs only that message, and says so."""
    src = _source_that_fails_at_frame(tmp_path / "in.mcap", 4)
    out = tmp_path / "out.mcap"
    proc = fusion_pf("record", src, out)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr
    assert any(
        "not valid JSON" in line and "kept without an unreadable skeleton" in line for line in proc.stderr.splitlines()
    )
    assert proc.stdout.startswith("recorded 7 frames")
    with McapReplay(out) as replay:
        frames = list(replay)
        assert [int(f.color[0, 0, 0]) for f in frames] == list(range(7))
        assert [f.joints is None for f in frames] == [i == 4 for i in range(7)]


def test_corrupt_chunk_in_the_source_is_a_warning(tmp_path, fusion_pf):
    src, out = tmp_path / "in.mcap", tmp_path / "out.mcap"
    assert fusion_pf("record", "synth:frames=12,size=320x200", src).returncode == 0
    with McapReplay(src) as replay:
        victim = replay._blocks[len(replay._blocks) // 2]
    data = bytearray(src.read_bytes())
    data[victim.offset + victim.length // 2] ^= 0x10
    src.write_bytes(bytes(data))
    proc = fusion_pf("record", src, out)
    assert proc.returncode == 0 and "Traceback" not in proc.stderr
    warnings = proc.stderr.splitlines()
    assert len(warnings) == 1 and f"chunk at byte {victim.offset} is corrupt" in warnings[0]
    assert warnings[0].startswith("fusion-pf: warning:")
    with McapReplay(out) as replay:
        n = len(replay)
    assert 0 < n < 12 and f"recorded {n} frames" in proc.stdout and f"{12 - n} dropped" in proc.stdout


def test_bad_arguments(tmp_path, fusion_pf):
    proc = fusion_pf("record", "webcam:0", tmp_path / "w.mcap")
    assert proc.returncode == 2 and "unknown source 'webcam:0'" in error_line(proc)
    proc = fusion_pf("record", SYNTH, tmp_path / "missing-dir" / "w.mcap")
    assert proc.returncode == 2 and "output directory" in error_line(proc)
    proc = fusion_pf("record", SYNTH, tmp_path / "w.mcap", "--frames", 0)
    assert proc.returncode == 2 and "frames (--frames) must be an integer in [1, inf], got 0" in error_line(proc)
    assert not (tmp_path / "w.mcap").exists()


def test_ctrl_c_finalises_the_file(tmp_path, fusion_pf):
    out = tmp_path / "live.mcap"
    proc = subprocess.Popen(
        [*CLI, "record", "synth:frames=100000,size=640x400", str(out)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and (not out.exists() or out.stat().st_size < 3_000_000):
            time.sleep(0.05)
        assert out.exists() and out.stat().st_size >= 3_000_000, "recording did not start"
        proc.send_signal(signal.SIGINT)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        proc.kill()
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and "fusion-pf: interrupted" in stderr
    assert "(interrupted)" in stdout
    info = json.loads(fusion_pf("info", out, "--json").stdout)
    assert info["indexed"] and not info["truncated"] and info["frames"] >= 3
    assert f"recorded {info['frames']} frames (interrupted)" in stdout


def test_size_and_fps_reach_the_source(tmp_path, fusion_pf):
    out = tmp_path / "small.mcap"
    proc = fusion_pf("record", "synth:frames=4", out, "--size", "160x100", "--fps", "10")
    assert proc.returncode == 0, proc.stderr
    with McapReplay(out) as rec:
        frames = list(rec)
    assert frames[0].color.shape == (100, 160, 3)
    assert frames[1].timestamp_ns - frames[0].timestamp_ns == 100_000_000
    proc = fusion_pf("record", out, tmp_path / "again.mcap", "--size", "64x48")
    assert proc.returncode == 2
    assert error_line(proc) == (
        f"fusion-pf: error: --size/--fps apply to a camera or synthetic source, not to the recording {out}"
    )
