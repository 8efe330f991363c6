"""Issue 24 item 5: damaged videos and image folders give a one-line error or skipped-and-counted frames.

Small videos are written here with PyAV (FFmpeg's mpeg4 encoder, 30 frames of
64 x 48) and damaged the way the fault campaign did: a byte flipped inside a
packet of an .mkv, a truncated .mkv, truncated .avi files. Folders get an image
that is not an image and a truncated PNG. ``fusion-pf import`` and ``track``
must never print a traceback: either exit 2 with one error line, or exit 3
with ``skipped N frames: why`` -- and the frames kept plus the frames counted
must be every frame of the input.
"""

from __future__ import annotations

import csv
import re

import av
import cv2
import numpy as np
import pytest

from drivers.mcap_replay import McapReplay
from fusion_pf import cli

N = 30


def write_video(path, n=N, size=(64, 48)):
    w, h = size
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=30)
        stream.width, stream.height, stream.pix_fmt = w, h, "yuv420p"
        for i in range(n):
            img = np.zeros((h, w, 3), np.uint8)
            img[:, :, 0] = i * 8
            img[10:20, 2 * i % w : 2 * i % w + 8] = 255
            for packet in stream.encode(av.VideoFrame.from_ndarray(img, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    return path


def packets(path):
    """``(byte position, size)`` of every video packet, from the demuxer."""
    with av.open(str(path)) as container:
        return [(p.pos, p.size) for p in container.demux(container.streams.video[0]) if p.size]


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def skipped(err):
    lines = [x for x in err.splitlines() if x.startswith("fusion-pf: warning: skipped")]
    assert len(lines) == 1, err
    return lines[0]


def imported_frames(path):
    with McapReplay(path) as rec:
        return [f.timestamp_ns for f in rec]


def test_flipped_byte_in_an_mkv_packet_costs_its_frame(tmp_path, capsys):
    video = write_video(tmp_path / "clip.mkv")
    pos, _size = packets(video)[10]
    data = bytearray(video.read_bytes())
    data[pos + 4] ^= 0xFF  # inside frame 10's packet: the decoder refuses it
    bad = tmp_path / "flipped.mkv"
    bad.write_bytes(bytes(data))
    code, _out, err = run(capsys, "import", bad, tmp_path / "out.mcap", "--no-progress")
    assert code == 3
    assert "skipped 1 frame: a damaged packet the decoder refuses" in skipped(err)
    assert len(imported_frames(tmp_path / "out.mcap")) == N - 1
    table = tmp_path / "t.csv"
    code, _out, err = run(capsys, "track", bad, "-o", tmp_path / "t.mcap", "--csv", table, "--no-progress")
    assert code == 3 and "a damaged packet the decoder refuses" in skipped(err)
    with open(table, newline="") as fh:
        assert [int(r["frame"]) for r in csv.DictReader(fh)] == [i for i in range(N) if i != 10]


def test_truncated_mkv_is_reported_as_truncated(tmp_path, capsys):
    video = write_video(tmp_path / "clip.mkv")
    data = video.read_bytes()
    cut = tmp_path / "cut.mkv"
    cut.write_bytes(data[: len(data) * 6 // 10])
    code, _out, err = run(capsys, "import", cut, tmp_path / "out.mcap", "--no-progress")
    assert code == 3
    line = skipped(err)
    kept = len(imported_frames(tmp_path / "out.mcap"))
    assert 0 < kept < N
    assert f"skipped {N - kept} frames: the video is truncated or damaged: it ends after {kept} frames" in line
    assert "header announces 1.000 s at 30 fps" in line
    code, _out, err = run(capsys, "track", cut, "-o", tmp_path / "t.mcap", "--no-progress")
    assert code == 3 and "truncated" in skipped(err) and f"tracked {kept} frames" in err


@pytest.mark.parametrize("fraction", [0.5, 0.7, 0.9])
def test_truncated_avi_is_one_line_or_counted(tmp_path, capsys, fraction):
    video = write_video(tmp_path / "clip.avi")
    data = video.read_bytes()
    cut = tmp_path / "cut.avi"
    cut.write_bytes(data[: int(len(data) * fraction)])
    for argv in (("import", cut, tmp_path / "out.mcap"), ("track", cut, "-o", tmp_path / "t.mcap")):
        code, out, err = run(capsys, *argv, "--force", "--no-progress")
        if code == 2:  # the container cannot be opened at all
            errors = [x for x in err.splitlines() if x.startswith("fusion-pf: error:")]
            assert len(errors) == 1 and "cannot be opened as a video" in errors[0]
            continue
        assert code == 3, err
        kept = int(re.search(r"^(?:imported|tracked) (\d+) frames", out + err, re.M).group(1))
        lost = int(re.match(r"fusion-pf: warning: skipped (\d+) frames?:", skipped(err)).group(1))
        assert kept + lost == N and lost > 0


def test_unreadable_images_are_skipped_and_counted(tmp_path, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(3)
    for i in range(8):
        cv2.imwrite(str(folder / f"{i:04d}.png"), rng.integers(0, 256, (48, 64, 3), dtype=np.uint8))
    (folder / "0002.png").write_bytes(b"\x00 not an image" * 20)
    png = (folder / "0005.png").read_bytes()
    (folder / "0005.png").write_bytes(png[: len(png) // 2])
    code, out, err = run(capsys, "import", folder, tmp_path / "out.mcap", "--no-progress")
    assert code == 3
    line = skipped(err)
    assert line.startswith("fusion-pf: warning: skipped 2 frames:")
    assert "0002.png" in line and "0005.png" in line and "cannot be decoded as an image" in line
    assert imported_frames(tmp_path / "out.mcap") == [round(i * 1e9 / 30) for i in range(8) if i not in (2, 5)]
    table = tmp_path / "t.csv"
    code, _out, err = run(capsys, "track", folder, "-o", tmp_path / "t.mcap", "--csv", table, "--no-progress")
    assert code == 3 and skipped(err).startswith("fusion-pf: warning: skipped 2 frames:")
    with open(table, newline="") as fh:
        assert [int(r["frame"]) for r in csv.DictReader(fh)] == [0, 1, 3, 4, 6, 7]


def test_unreadable_depth_image_keeps_its_frame(tmp_path, capsys):
    folder = tmp_path / "frames"
    folder.mkdir()
    rng = np.random.default_rng(4)
    for i in range(4):
        cv2.imwrite(str(folder / f"{i}_color.png"), rng.integers(0, 256, (48, 64, 3), dtype=np.uint8))
        cv2.imwrite(str(folder / f"{i}_depth.png"), rng.integers(1, 4000, (48, 64), dtype=np.uint16))
    (folder / "1_depth.png").write_bytes(b"broken")
    code, _out, err = run(capsys, "import", folder, tmp_path / "out.mcap", "--no-progress")
    assert code == 3
    assert "1 depth message unreadable (frames kept without depth)" in skipped(err)
    with McapReplay(tmp_path / "out.mcap") as rec:
        assert [f.depth is None for f in rec] == [False, True, False, False]


def test_packets_removed_inside_an_mkv_are_counted_and_leave_a_gap(tmp_path, capsys):
    """The demuxer skips the damage without a word: the frame timestamps show the gap (a constant-rate video)."""
    video = write_video(tmp_path / "clip.mkv")
    where = packets(video)
    data = video.read_bytes()
    bad = tmp_path / "holed.mkv"
    bad.write_bytes(data[: where[12][0]] + data[where[15][0] :])  # packets 12, 13 and 14 removed
    table = tmp_path / "t.csv"
    code, out, err = run(capsys, "track", bad, "-o", tmp_path / "t.mcap", "--csv", table, "--no-progress")
    assert code == 3
    lost = int(re.match(r"fusion-pf: warning: skipped (\d+) frames?:", skipped(err)).group(1))
    with open(table, newline="") as fh:
        numbers = [int(r["frame"]) for r in csv.DictReader(fh)]
    assert len(numbers) + lost == N
    assert numbers[:13] == [*range(12), 15]  # the frame after the hole keeps its number
