"""``fusion-pf info`` on good, truncated, corrupt and non-conforming files (subprocess, with timeouts)."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.writer import Writer

from drivers import mcap_format as fmt
from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapReplay
from fusion_pf.frame import Frame, Intrinsics, Joint, PalmPoint
from fusion_pf.rng import as_rng

CLI = [sys.executable, "-m", "fusion_pf"]


def frames(n, size=(64, 48), seed=0):
    rng = as_rng(seed)
    w, h = size
    k = Intrinsics(w, h, 50.0, 50.0, w / 2, h / 2)
    return [
        Frame(
            10_000 + i * 40_000_000,
            i,
            rng.integers(0, 256, (h, w, 3), dtype=np.uint8),
            None if i == 3 else rng.integers(0, 4000, (h, w), dtype=np.uint16),
            k,
            None if i in (3, 4) else {"right_hand": Joint(3.0, 4.0, None, 0.5)},
            PalmPoint(5.0, 6.0),
            background=i == 0,
        )
        for i in range(n)
    ]


def recording(path, n=10, **kwargs):
    with McapRecorder(path, chunk_size=12_000, metadata={"generator": "test"}, **kwargs) as rec:
        for f in frames(n):
            rec.write(f)
    return Path(path)


def raw_messages(path, color_size, depth_size, calibration=True):
    (cw, ch), (dw, dh) = color_size, depth_size
    msgs = [
        (fmt.COLOR_TOPIC, fmt.encode_color(np.zeros((ch, cw, 3), np.uint8), 5)),
        (fmt.DEPTH_TOPIC, fmt.encode_depth(np.zeros((dh, dw), np.uint16), 5)),
    ]
    if calibration:
        msgs.insert(0, (fmt.CALIBRATION_TOPIC, fmt.encode_calibration(Intrinsics(cw, ch, 500, 500, cw / 2, ch / 2), 5)))
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        for topic, msg in msgs:
            sid = writer.register_schema(msg.DESCRIPTOR.full_name, "protobuf", fmt.protobuf_schema_data(type(msg)))
            cid = writer.register_channel(topic, "protobuf", sid)
            writer.add_message(cid, log_time=5, data=msg.SerializeToString(), publish_time=5)
        writer.finish()
    return Path(path)


def one_error_line(proc):
    lines = [line for line in proc.stderr.splitlines() if line.startswith("fusion-pf: error:")]
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    return lines[0]


def test_info_text_and_json(tmp_path, fusion_pf):
    path = recording(tmp_path / "rec.mcap", color_format="jpeg")
    proc = fusion_pf("info", path)
    assert proc.returncode == 0 and proc.stderr == ""
    text = proc.stdout
    assert "complete, indexed" in text and "frames        10 over 0.360 s (25.00 fps)" in text
    assert "resolution    64x48  colour jpeg  depth 16UC1" in text
    assert "fx=50.000 fy=50.000 cx=32.000 cy=24.000 distortion none" in text
    assert "background    1 frames" in text and "depth in 1 frames, skeleton in 2 frames" in text
    assert "/camera/color              10  foxglove.CompressedImage (protobuf, schema protobuf)" in text
    proc = fusion_pf("info", path, "--json")
    assert proc.returncode == 0
    info = json.loads(proc.stdout)
    with McapReplay(path) as replay:
        assert info == replay.info().to_dict()
    assert info["frames"] == 10 and info["fps"] == pytest.approx(25.0) and info["metadata"]["generator"] == "test"


def test_truncated_file_is_described_with_a_warning(tmp_path, fusion_pf):
    data = recording(tmp_path / "rec.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) * 2 // 3])
    proc = fusion_pf("info", cut, "--json")
    assert proc.returncode == 0, proc.stderr
    info = json.loads(proc.stdout)
    assert info["truncated"] and not info["indexed"] and 3 <= info["frames"] < 10
    warnings = proc.stderr.splitlines()
    assert len(warnings) == 1 and warnings[0].startswith("fusion-pf: warning: file truncated")


def test_verify_reports_a_corrupt_chunk(tmp_path, fusion_pf):
    path = recording(tmp_path / "rec.mcap")
    with McapReplay(path) as replay:
        victim = replay._blocks[1]
    data = bytearray(path.read_bytes())
    data[victim.offset + victim.length // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    assert fusion_pf("info", path).returncode == 0  # the index alone is intact
    proc = fusion_pf("info", path, "--verify")
    assert proc.returncode == 2
    assert f"chunk at byte {victim.offset} is corrupt" in proc.stderr
    assert "failed verification" in one_error_line(proc)
    assert "lost; skipped" in proc.stdout and "is corrupt" in proc.stdout


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p: p.write_bytes(b"GIF89a not a recording"), "is not an MCAP file: it starts with b'GIF89a n'"),
        (lambda p: p.write_bytes(b""), "is empty \\(0 bytes\\)"),
        (
            lambda p: raw_messages(p, (640, 400), (320, 200)),
            "/camera/depth is 320x200 but /camera/color is 640x400 in frame 0 \\(t=5 ns\\); depth must be aligned",
        ),
        (
            lambda p: raw_messages(p, (64, 48), (64, 48), calibration=False),
            "has no /camera/calibration topic, which is required; topics present: /camera/color, /camera/depth",
        ),
        (
            lambda p: p.write_bytes(recording(p.with_suffix(".full.mcap")).read_bytes()[:3000]),
            "has no /camera/color messages|has no /camera/color topic",
        ),
        (lambda p: None, "recording not found"),
    ],
    ids=["not-mcap", "empty", "depth-320x200", "no-calibration", "truncated-early", "missing"],
)
def test_unusable_files_exit_2_with_one_line(tmp_path, make, message, fusion_pf):
    import re

    path = tmp_path / "bad.mcap"
    make(path)
    proc = fusion_pf("info", path)
    assert proc.returncode == 2 and proc.stdout == ""
    assert re.search(message, one_error_line(proc))


def test_ten_cut_points_never_traceback_or_hang(tmp_path, fusion_pf):
    data = recording(tmp_path / "rec.mcap", n=12).read_bytes()
    results = []
    for cut in np.linspace(1, len(data) - 1, 10).astype(int):
        path = tmp_path / f"cut{cut}.mcap"
        path.write_bytes(data[:cut])
        proc = fusion_pf("info", path, "--json")
        assert "Traceback" not in proc.stderr and len(proc.stderr.splitlines()) == 1, proc.stderr
        if proc.returncode == 0:
            assert proc.stderr.startswith("fusion-pf: warning: file truncated")
            results.append(json.loads(proc.stdout)["frames"])
        else:
            assert proc.returncode == 2 and proc.stderr.startswith("fusion-pf: error:") and str(path) in proc.stderr
            results.append(0)
    assert results[0] == 0 and results[-1] == 12 and results == sorted(results)
