"""Video import: files written by OpenCV's VideoWriter (an independent encoder path), read with PyAV."""

import cv2
import numpy as np
import pytest

from drivers import open_source
from drivers.importers import detect
from drivers.importers.video import VideoSource
from drivers.mcap_replay import McapReplay
from fusion_pf.frame import Intrinsics

from .conftest import error_line, fusion_pf


def write_video(path, frames, fourcc, fps):
    h, w = frames[0].color.shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert writer.isOpened()
    for f in frames:
        writer.write(cv2.cvtColor(f.color, cv2.COLOR_RGB2BGR))
    writer.release()
    return path


@pytest.mark.parametrize(("name", "fourcc", "fps"), [("clip.mp4", "mp4v", 25), ("clip.avi", "MJPG", 12)])
def test_import_video(tmp_path, frames, name, fourcc, fps):
    video = write_video(tmp_path / name, frames, fourcc, fps)
    assert detect(video) == "video"
    out = tmp_path / "out.mcap"
    proc = fusion_pf("import", video, out, "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "colour only, no depth; intrinsics assumed: 60 deg horizontal field of view" in proc.stdout
    with McapReplay(out) as replay:
        info = replay.info()
        got = list(replay)
    assert info.frames == len(frames) and info.missing_depth == len(frames) and (info.width, info.height) == (320, 240)
    assert [f.timestamp_ns for f in got] == [round(i * 1e9 / fps) for i in range(len(frames))]
    for a, b in zip(frames, got, strict=True):
        assert np.abs(a.color.astype(int) - b.color).mean() < 8.0  # lossy codecs, same picture
    track = fusion_pf("track", out, "-o", tmp_path / "tracked.mcap", "--no-progress")
    assert track.returncode == 0, track.stderr


def test_fps_and_intrinsics_flags(tmp_path, frames):
    video = write_video(tmp_path / "clip.mp4", frames[:4], "mp4v", 25)
    out = tmp_path / "out.mcap"
    proc = fusion_pf("import", video, out, "--fps", "10", "--fx", "300", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    with McapReplay(out) as replay:
        got = list(replay)
    assert [f.timestamp_ns for f in got] == [0, 100_000_000, 200_000_000, 300_000_000]
    assert got[0].intrinsics == Intrinsics(320, 240, 300.0, 300.0, 159.5, 119.5)
    line = error_line(fusion_pf("import", video, out, "--force", "--depth-unit", "1mm"))
    assert "--depth-unit applies to image folders" in line


def test_not_a_video(tmp_path):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"not a video at all")
    line = error_line(fusion_pf("import", bad, tmp_path / "x.mcap"))
    assert "cannot be opened as a video" in line


def test_open_source_replays_videos_and_folders_directly(tmp_path, frames):
    video = write_video(tmp_path / "clip.avi", frames[:3], "MJPG", 30)
    with open_source(video) as src:
        got = list(src)
    assert isinstance(src, VideoSource) and len(got) == 3 and got[0].depth is None
