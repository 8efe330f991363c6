"""Issue 24 items 7 and 8: ``info`` on odd files and tracker outputs, ``render`` from elsewhere, quiet LiteRT.

FIFOs and devices are refused without blocking; bytes appended after a complete
file are named as such (not truncation); a summary failing its CRC is not
trusted as an index; file names in success lines are escaped; the loss summary
says "unknown" instead of "0+"; ``info`` describes a ``track`` output; ``render``
finds the tracked recording from another directory and after both moved; the
LiteRT runtime's INFO line stays off a ``track`` run's stderr.
"""

from __future__ import annotations

import json
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import pytest

from drivers.base import FrameLoss, SourceStats
from drivers.mcap_replay import McapReplay
from fusion_pf.cli import main

CLI = [sys.executable, "-m", "fusion_pf"]


@pytest.fixture(scope="module")
def rec(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "rec.mcap"
    argv = ["synth", str(path), "--frames", "6", "--background-frames", "2", "--size", "96x64", "--no-progress"]
    assert main(argv) == 0
    return path


def info_json(path: Path, capsys) -> tuple[dict, str]:
    capsys.readouterr()
    assert main(["info", "--json", str(path)]) == 0
    captured = capsys.readouterr()
    return json.loads(captured.out), captured.err


def test_info_refuses_a_fifo_and_a_device_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.mcap"
    os.mkfifo(fifo)
    for path, kind in ((fifo, "a FIFO"), (Path("/dev/zero"), "a character device")):
        proc = subprocess.run([*CLI, "info", str(path)], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 2 and proc.stdout == ""
        assert proc.stderr == f"fusion-pf: error: {path} is not a regular file ({kind}); expected an .mcap file\n"


def test_bytes_after_a_complete_file_are_not_called_truncation(rec, tmp_path, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(rec.read_bytes() + bytes(range(256)) * 4)
    info, err = info_json(junk, capsys)
    assert not info["truncated"] and info["trailing_bytes"] == 1024 and info["frames"] == 6
    assert (
        f"1024 bytes follow the end of the MCAP data (its footer and closing magic end at byte {rec.stat().st_size})"
        in err
    )
    assert "truncated" not in err
    assert main(["info", str(junk)]) == 0
    assert "bytes, complete + 1024 trailing bytes after the end, ignored, scanned)" in capsys.readouterr().out


def test_a_summary_failing_its_crc_is_not_trusted_as_an_index(rec, tmp_path, capsys):
    good, _ = info_json(rec, capsys)
    assert good["indexed"] and not good["truncated"]
    data = rec.read_bytes()
    summary_start = struct.unpack_from("<Q", data, len(data) - 28)[0]
    for where in (len(data) - 12, summary_start + 20):  # the CRC field itself; a byte of a summary schema
        bad = bytearray(data)
        bad[where] ^= 0x5A
        path = tmp_path / f"bad{where}.mcap"
        path.write_bytes(bytes(bad))
        info, err = info_json(path, capsys)
        assert not info["indexed"] and not info["truncated"] and info["frames"] == 6
        assert "file has no usable index (damaged summary: summary CRC mismatch (expected 0x" in err
        with McapReplay(rec) as a, McapReplay(path) as b:
            assert [f.timestamp_ns for f in a] == [f.timestamp_ns for f in b]


def test_success_lines_escape_file_names(rec, tmp_path, capsys):
    odd = tmp_path / "a\x1b]0;owned\x07.mcap"
    tracked = tmp_path / "t\x1b[31m.mcap"
    capsys.readouterr()
    assert main(["synth", str(odd), "--frames", "4", "--size", "96x64", "--no-progress"]) == 0
    assert main(["track", str(odd), "-o", str(tracked), "--csv", str(tmp_path / "t\r.csv"), "--no-progress"]) == 0
    assert main(["record", str(odd), str(tmp_path / "r\x1b.mcap")]) == 0
    assert main(["render", str(tracked), "--sheet", str(tmp_path / "s\x07.png")]) == 0
    assert main(["info", str(odd)]) == 0
    out = capsys.readouterr()
    text = out.out + out.err
    assert not any(c in text for c in "\x1b\x07\r"), text
    for escaped in ("a\\x1b]0;owned\\x07.mcap", "t\\x1b[31m.mcap", "t\\r.csv", "r\\x1b.mcap", "s\\x07.png"):
        assert escaped in text


def test_a_loss_of_unknown_size_is_worded_without_0_plus():
    tail = FrameLoss(None, "the file is truncated at byte 9", tail=True)
    assert SourceStats(losses=[tail]).loss_summary() == (
        "skipped an unknown number of frames: the file is truncated at byte 9 (number unknown)"
    )
    chunk = FrameLoss(3, "chunk at byte 5 is corrupt")
    assert (
        SourceStats(dropped=3, losses=[chunk, tail])
        .loss_summary()
        .startswith("skipped 3 frames and an unknown number more: chunk at byte 5 is corrupt (3 frames)")
    )


def test_info_describes_a_tracker_output(rec, tmp_path, capsys):
    out = tmp_path / "tracked.mcap"
    assert main(["track", str(rec), "-o", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "tracker output (fusion-pf track -o)" in text
    assert "frames        4 tracked (/tracker/estimate messages) over 0.100 s" in text
    assert f"source        {rec} (found)" in text
    assert all(t in text for t in ("/tracker/estimate", "/tracker/cues", "/tracker/overlay", "/tracker/particles"))
    info, _ = info_json(out, capsys)
    assert info["kind"] == "tracker output" and info["frames"] == 4 and info["source_found"] == str(rec)
    assert info["metadata"]["source_relative"] == os.path.relpath(rec, tmp_path)


def test_render_finds_the_source_from_another_directory_and_after_a_move(rec, tmp_path):
    work = tmp_path / "work"
    (work / "out").mkdir(parents=True)
    shutil.copy(rec, work / "rec.mcap")
    run = {"capture_output": True, "text": True, "timeout": 300}
    tracked = subprocess.run([*CLI, "track", "rec.mcap", "-o", "out/t.mcap", "--no-progress"], cwd=work, **run)
    assert tracked.returncode == 0, tracked.stderr
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    proc = subprocess.run([*CLI, "render", str(work / "out" / "t.mcap"), "--sheet", "a.png"], cwd=elsewhere, **run)
    assert proc.returncode == 0, proc.stderr
    assert "rendered 6 frames (4 with tracker output)" in proc.stdout and (elsewhere / "a.png").is_file()
    moved = tmp_path / "moved"
    work.rename(moved)  # the absolute path is gone; the path relative to the output still holds
    proc = subprocess.run([*CLI, "render", "moved/out/t.mcap", "--sheet", "b.png"], cwd=tmp_path, **run)
    assert proc.returncode == 0, proc.stderr
    assert "rendered 6 frames (4 with tracker output)" in proc.stdout


def test_a_track_run_with_the_hand_cue_prints_no_litert_info(rec, tmp_path):
    out = tmp_path / "hand.csv"
    proc = subprocess.run(
        [*CLI, "track", rec, "-o", tmp_path / "h.mcap", "--csv", out, "--cues", "colour,hand", "--no-progress"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "hand_u" in out.read_text().splitlines()[0]  # the hand cue (LiteRT) ran
    assert "XNNPACK" not in proc.stderr and "INFO:" not in proc.stderr, proc.stderr
    assert proc.stderr.startswith("tracked 4 frames")
