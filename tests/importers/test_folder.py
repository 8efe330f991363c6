"""Image-folder import: real SR305 depth PNGs, colour+depth folders in three layouts, intrinsics files, errors."""

import json

import cv2
import numpy as np
import pytest

from drivers.importers import open_import
from drivers.importers.base import fov_intrinsics, load_intrinsics, parse_depth_unit, to_millimetres
from drivers.mcap_replay import McapReplay
from fusion_pf.errors import InputError

from .conftest import FIXTURES, error_line, fusion_pf

SR305 = FIXTURES / "sr305"


def replay(path):
    with McapReplay(path) as r:
        return r.info(), list(r)


def write_png(path, image):
    assert cv2.imwrite(str(path), cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else image)


def test_sr305_depth_pngs(tmp_path):
    out = tmp_path / "sr305.mcap"
    proc = fusion_pf(
        "import", SR305, out, "--depth-unit", "0.125mm", "--intrinsics", SR305 / "intrinsics.json", "--no-progress"
    )
    assert proc.returncode == 0, proc.stderr
    assert "4 frames of 640x480 at 30 fps, 4 with depth (0.125mm per count)" in proc.stdout
    assert "no colour images: colour is a grey rendering of depth" in proc.stdout
    info, got = replay(out)
    assert info.frames == 4 and info.intrinsics["fx"] == 476.007 and info.intrinsics["cx"] == 313.683
    assert [f.timestamp_ns for f in got] == [0, 33_333_333, 66_666_667, 100_000_000]
    for name, frame in zip(("30", "50", "70", "90"), got, strict=True):  # natural order: 30 < 50 < 70 < 90
        counts = cv2.imread(str(SR305 / f"{name}.png"), cv2.IMREAD_UNCHANGED)
        assert np.all(np.abs(frame.depth - counts * 0.125) <= 0.5) and np.array_equal(frame.depth > 0, counts > 0)
        hand = frame.depth[frame.depth > 0]
        assert 300 < np.median(hand) < 1000  # the dataset's scene: a hand in front of the sensor, under 1.5 m
        assert np.array_equal(frame.color[..., 0] == 0, frame.depth == 0)
    track = fusion_pf("track", out, "-o", tmp_path / "tracked.mcap", "--no-progress")
    assert track.returncode == 0, track.stderr


@pytest.mark.parametrize("layout", ["subfolders", "suffixes", "mixed"])
def test_colour_and_depth_layouts(tmp_path, frames, layout):
    src = tmp_path / "src"
    src.mkdir()
    for i, f in enumerate(frames):
        if layout == "subfolders":
            (src / "rgb").mkdir(exist_ok=True)
            (src / "depth").mkdir(exist_ok=True)
            write_png(src / "rgb" / f"{i:05d}.png", f.color)
            if i != 2:
                write_png(src / "depth" / f"{i:05d}.png", f.depth)
        elif layout == "suffixes":
            write_png(src / f"frame-{i:06d}.color.png", f.color)
            if i != 2:
                write_png(src / f"frame-{i:06d}.depth.png", f.depth)
        else:  # unlabelled: colour as .png 8-bit, depth as .tif 16-bit, told apart by their content
            write_png(src / f"{i}.png", f.color)
            if i != 2:
                write_png(src / f"{i}.tif", f.depth)
    out = tmp_path / "out.mcap"
    k = frames[0].intrinsics
    proc = fusion_pf("import", src, out, "--fps", "15", "--fx", k.fx, "--cx", k.cx, "--cy", k.cy, "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "paired colour and depth by file name: 7 pairs, 1 colour image(s) without depth" in proc.stdout
    info, got = replay(out)
    assert info.frames == 8 and info.missing_depth == 1 and info.fps == pytest.approx(15.0)
    for i, (a, b) in enumerate(zip(frames, got, strict=True)):
        assert np.array_equal(a.color, b.color) and b.intrinsics == k
        assert b.depth is None if i == 2 else np.array_equal(a.depth, b.depth)


def test_unmatched_names_pair_by_sorted_order(tmp_path, frames):
    # TUM RGB-D layout: rgb/ and depth/ named by their own capture times, depth in 1/5000 m
    src = tmp_path / "tum"
    (src / "rgb").mkdir(parents=True)
    (src / "depth").mkdir()
    for i, f in enumerate(frames[:4]):
        write_png(src / "rgb" / f"1305031102.{175304 + 33333 * i}.png", f.color)
        counts = (f.depth.astype(np.uint32) * 5).astype(np.uint16)
        write_png(src / "depth" / f"1305031102.{160407 + 33333 * i}.png", counts)
    out = tmp_path / "out.mcap"
    proc = fusion_pf("import", src, out, "--depth-unit", "0.2mm", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "paired 4 colour and depth images by sorted file name" in proc.stdout
    _, got = replay(out)
    for a, b in zip(frames[:4], got, strict=True):
        assert np.array_equal(a.color, b.color) and np.array_equal(a.depth, b.depth)
    (src / "depth" / "1305031102.999999.png").write_bytes((src / "depth" / "1305031102.160407.png").read_bytes())
    line = error_line(fusion_pf("import", src, out, "--force"))
    assert "cannot pair 4 colour images (e.g. 1305031102.175304.png) with 5 depth images" in line


def test_colour_only_folder_states_the_assumed_intrinsics(tmp_path, frames):
    src = tmp_path / "jpegs"
    src.mkdir()
    for i, f in enumerate(frames[:3]):
        assert cv2.imwrite(str(src / f"img{i}.jpg"), cv2.cvtColor(f.color, cv2.COLOR_RGB2BGR))
    out = tmp_path / "out.mcap"
    proc = fusion_pf("import", src, out, "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "assumed: 60 deg horizontal field of view, fx = fy = 277.1 px" in proc.stdout
    info, got = replay(out)
    assert info.frames == 3 and info.missing_depth == 3
    assert got[0].intrinsics == fov_intrinsics(320, 240, 60.0)
    assert got[0].intrinsics.fx == pytest.approx(160 / np.tan(np.radians(30)))
    track = fusion_pf("track", out, "-o", tmp_path / "tracked.mcap", "--no-progress")
    assert track.returncode == 0, track.stderr


def test_errors(tmp_path, frames):
    src = tmp_path / "mixed"
    src.mkdir()
    write_png(src / "a.png", frames[0].color)
    write_png(src / "b.png", cv2.resize(frames[1].color, (160, 120)))
    line = error_line(fusion_pf("import", src, tmp_path / "x.mcap"))
    assert "differ in size (320x240: 1 (e.g. a.png); 160x120: 1 (e.g. b.png))" in line
    line = error_line(fusion_pf("import", SR305, tmp_path / "x.mcap", "--depth-unit", "furlong"))
    assert "unknown depth unit 'furlong'; expected a length such as 1mm, 0.1mm, 0.125mm" in line
    empty = tmp_path / "empty"
    empty.mkdir()
    (empty / "notes.txt").write_text("x")
    line = error_line(fusion_pf("import", empty, tmp_path / "x.mcap"))
    assert "holds no images" in line and "found ['notes.txt']" in line
    line = error_line(fusion_pf("import", SR305, tmp_path / "x.mcap", "--color-topic", "/x"))
    assert "--color-topic apply to ROS bags" in line
    line = error_line(fusion_pf("import", tmp_path / "nothing.xyz", tmp_path / "x.mcap"))
    assert "does not exist" in line


def test_failure_mid_import_keeps_the_frames_written(tmp_path, frames):
    src = tmp_path / "src"
    src.mkdir()
    for i, f in enumerate(frames):
        write_png(src / f"{i}_color.png", f.color)
        depth = np.dstack([f.depth] * 3) if i == 5 else f.depth  # a 16-bit RGB "depth" image
        write_png(src / f"{i}_depth.png", depth)
    out = tmp_path / "out.mcap"
    line = error_line(fusion_pf("import", src, out))
    assert f"5_depth.png has 3 channels; expected one channel (after 5 frames; {out} is finalised" in line
    info, got = replay(out)
    assert info.frames == 5 and not info.truncated


def test_depth_units():
    assert parse_depth_unit("0.125mm") == 0.125 and parse_depth_unit("1mm") == 1.0
    assert parse_depth_unit("m") == 1000.0 and parse_depth_unit("0.2 mm") == 0.2 and parse_depth_unit("1cm") == 10.0
    for bad in ("", "mm2", "-1mm", "0mm", "inch"):
        with pytest.raises(InputError):
            parse_depth_unit(bad)
    depth = np.array([[0, 1.2345, np.nan], [np.inf, -1.0, 70.0]])
    assert to_millimetres(depth, 1000.0).tolist() == [[0, 1234, 0], [0, 0, 0]]  # 70 m is beyond uint16 mm


def test_intrinsics_files(tmp_path):
    ros = tmp_path / "camera_info.yaml"
    ros.write_text(
        "image_width: 640\nimage_height: 480\ncamera_name: c\n"
        "camera_matrix: {rows: 3, cols: 3, data: [500.0, 0.0, 320.5, 0.0, 501.0, 240.5, 0.0, 0.0, 1.0]}\n"
        "distortion_model: plumb_bob\n"
        "distortion_coefficients: {rows: 1, cols: 5, data: [0.1, -0.2, 0.0, 0.0, 0.05]}\n"
    )
    k = load_intrinsics(ros)
    assert (k.width, k.fx, k.fy, k.cx, k.cy) == (640, 500.0, 501.0, 320.5, 240.5)
    assert k.distortion_model == "plumb_bob" and k.distortion == (0.1, -0.2, 0.0, 0.0, 0.05)
    o3d = tmp_path / "intrinsic.json"  # Open3D PinholeCameraIntrinsic: column-major
    o3d.write_text(
        json.dumps({"width": 640, "height": 480, "intrinsic_matrix": [525.0, 0, 0, 0, 526.0, 0, 319.5, 239.5, 1]})
    )
    k = load_intrinsics(o3d)
    assert (k.fx, k.fy, k.cx, k.cy) == (525.0, 526.0, 319.5, 239.5)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"fx": 1}))
    with pytest.raises(InputError, match="has no width, height, fy, cx, cy"):
        load_intrinsics(bad)


def test_folder_replays_directly():
    with open_import(SR305, depth_unit="0.125mm") as src:
        frames = list(src)
    assert src.total == 4 and len(frames) == 4 and frames[0].depth.dtype == np.uint16
