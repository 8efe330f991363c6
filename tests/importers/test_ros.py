"""ROS bag import: a realsense2_camera-style ROS 2 bag written by rosbags, read with mcap-ros2-support.

The bag carries the synthetic scene's frames, so every imported frame can be compared with
the frame it came from: colour exact (rgb8) or close (JPEG), depth exact (16UC1) or to the
millimetre (32FC1 metres), intrinsics from the camera info, timestamps from header.stamp.
"""

import numpy as np
import pytest

from drivers.importers import open_import
from drivers.importers.base import pair_nearest
from drivers.mcap_replay import McapReplay

from .conftest import QUANT_A, error_line, fusion_pf, write_ros2_bag


@pytest.fixture(scope="module")
def bag(tmp_path_factory, frames):
    return write_ros2_bag(tmp_path_factory.mktemp("ros") / "bag", frames, drop_depth=(3,))


def replay(path):
    with McapReplay(path) as r:
        return r.info(), list(r)


def test_auto_topics_pairing_and_contents(tmp_path, bag, frames):
    out = tmp_path / "out.mcap"
    proc = fusion_pf("import", bag, out, "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "colour: /camera/color/image_raw (sensor_msgs/msg/Image, 320x240)" in proc.stdout
    assert "depth: /camera/aligned_depth_to_color/image_raw" in proc.stdout
    assert (
        "7 of 8 colour frames paired with depth within half a frame period, 1 without depth; "
        "0 depth message(s) unpaired"
    ) in proc.stdout
    assert "intrinsics from /camera/color/camera_info" in proc.stdout
    assert "/camera/color/image_raw/compressed, /camera/depth/image_rect_raw" in proc.stdout
    info, got = replay(out)
    assert info.frames == 8 and info.missing_depth == 1 and info.missing_skeleton == 8
    assert "/skeleton/joints" not in {t.topic for t in info.topics}
    assert info.metadata["imported_from"] == "ros"
    for a, b in zip(frames, got, strict=True):
        assert b.timestamp_ns == a.timestamp_ns  # header.stamp, not the later log time
        assert np.array_equal(a.color, b.color) and b.intrinsics == a.intrinsics
    assert got[3].depth is None
    assert all(np.array_equal(a.depth, b.depth) for i, (a, b) in enumerate(zip(frames, got, strict=True)) if i != 3)
    track = fusion_pf("track", out, "-o", tmp_path / "tracked.mcap", "--no-progress")
    assert track.returncode == 0, track.stderr


def test_unaligned_depth_registered_with_tf_static(tmp_path, bag, frames):
    out = tmp_path / "out.mcap"
    proc = fusion_pf("import", bag, out, "--depth-topic", "/camera/depth/image_rect_raw", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert (
        "depth registered to colour (z-buffered): depth intrinsics from /camera/depth/camera_info, "
        "camera_depth_optical_frame to camera_color_optical_frame from /tf_static "
        "(translation 15.0, 0.0, 0.0 mm)"
    ) in proc.stdout
    _, got = replay(out)
    for a, b in zip(frames, got, strict=True):
        # the depth camera's view was made by backward warping (tests/importers/conftest.py): registering it
        # forward must give back the colour-aligned depth, except along depth edges
        both = (a.depth > 0) & (b.depth > 0)
        assert both.sum() > 0.9 * (a.depth > 0).sum()
        assert np.mean(np.abs(a.depth.astype(int) - b.depth)[both] <= 2) > 0.95


def test_compressed_colour_and_float_depth(tmp_path, frames):
    bag = write_ros2_bag(tmp_path / "bag", frames, depth="32FC1", unaligned=False)
    out = tmp_path / "out.mcap"
    proc = fusion_pf("import", bag, out, "--color-topic", "/camera/color/image_raw/compressed", "--no-progress")
    assert proc.returncode == 0, proc.stderr
    assert "sensor_msgs/msg/CompressedImage" in proc.stdout
    _, got = replay(out)
    for a, b in zip(frames, got, strict=True):
        assert np.abs(a.color.astype(int) - b.color).mean() < 3.0  # JPEG quality 95
        assert np.abs(a.depth.astype(int) - b.depth).max() <= 1  # metres in float32 back to mm
        assert np.array_equal(a.depth == 0, b.depth == 0)  # NaN = no depth


@pytest.mark.parametrize("encoding", ["16UC1", "32FC1"])
def test_compressed_depth_topic(tmp_path, frames, encoding):
    bag = write_ros2_bag(tmp_path / "bag", frames, depth=encoding, compressed_depth=True, unaligned=False)
    out = tmp_path / "out.mcap"
    proc = fusion_pf(
        "import", bag, out, "--no-progress", "--depth-topic", "/camera/aligned_depth_to_color/image_raw/compressedDepth"
    )
    assert proc.returncode == 0, proc.stderr
    assert "depth: /camera/aligned_depth_to_color/image_raw/compressedDepth" in proc.stdout
    _, got = replay(out)
    for a, b in zip(frames, got, strict=True):
        assert np.array_equal(a.depth == 0, b.depth == 0)
        if encoding == "16UC1":
            assert np.array_equal(a.depth, b.depth)
        else:  # one quantisation step of A / d is d^2 / A metres
            step_mm = (a.depth / 1000.0) ** 2 / QUANT_A * 1000.0
            assert np.all(np.abs(a.depth.astype(float) - b.depth) <= step_mm + 1.0)


def test_bag_folders_and_ros1_bag_read_with_rosbags(tmp_path, bag, frames):
    sqlite = write_ros2_bag(tmp_path / "sqlite", frames, sqlite=True, drop_depth=(3,))
    for source in (bag.parent, sqlite, write_ros2_bag(tmp_path / "ros1", frames, ros1=True, compressed=False)):
        out = tmp_path / f"{source.name}.mcap"
        proc = fusion_pf("import", source, out, "--no-progress")
        assert proc.returncode == 0, proc.stderr
        _, got = replay(out)
        assert len(got) == 8 and all(np.array_equal(a.color, b.color) for a, b in zip(frames, got, strict=True))
        assert sum(f.depth is not None for f in got) == (8 if source.suffix == ".bag" else 7)


def test_depth_topic_override_and_errors(tmp_path, bag, frames):
    no_tf = write_ros2_bag(tmp_path / "notf", frames[:2], tf=False)
    line = error_line(fusion_pf("import", no_tf, tmp_path / "x.mcap", "--depth-topic", "/camera/depth/image_rect_raw"))
    assert (
        "depth topic /camera/depth/image_rect_raw is 360x270 but colour topic /camera/color/image_raw "
        "is 320x240 and cannot be registered to it (/tf_static does not connect 'camera_depth_optical_frame' "
        "to 'camera_color_optical_frame')"
    ) in line
    line = error_line(fusion_pf("import", bag, tmp_path / "x.mcap", "--color-topic", "/camera/infra1/image_rect_raw"))
    assert "colour topic /camera/infra1/image_rect_raw is not in the bag" in line
    assert "/camera/color/image_raw (" in line
    proc = fusion_pf(
        "import",
        bag,
        tmp_path / "c.mcap",
        "--depth-topic",
        "none",
        "--no-progress",
        "--info-topic",
        "/camera/aligned_depth_to_color/camera_info",
    )
    assert proc.returncode == 0 and "depth: none (colour only)" in proc.stdout
    assert "intrinsics from /camera/aligned_depth_to_color/camera_info" in proc.stdout
    line = error_line(fusion_pf("import", bag, tmp_path / "x.mcap", "--info-topic", "/camera/color/image_raw"))
    assert "camera info topic /camera/color/image_raw has type sensor_msgs/msg/Image" in line
    empty = write_ros2_bag(tmp_path / "noimages", frames, images=False)
    line = error_line(fusion_pf("import", empty, tmp_path / "y.mcap"))
    assert "has no colour image topic (sensor_msgs Image or CompressedImage); found" in line
    assert "/camera/color/camera_info (sensor_msgs/msg/CameraInfo, 8)" in line
    assert "/tf_static (tf2_msgs/msg/TFMessage, 0)" in line
    line = error_line(fusion_pf("import", bag, tmp_path / "z.mcap", "--fps", "10"))
    assert "--fps does not apply to ROS bags" in line


def test_replaying_a_bag_points_to_import(tmp_path, bag):
    line = error_line(fusion_pf("info", bag))
    assert "has no /camera/color topic" in line and "(a ROS 2 bag: convert it with fusion-pf import)" in line


def test_fusion_pf_recording_is_not_a_ros_bag(tmp_path):
    rec = tmp_path / "synth.mcap"
    assert fusion_pf("record", "synth:frames=2,size=64x48", rec).returncode == 0
    line = error_line(fusion_pf("import", rec, tmp_path / "x.mcap"))
    assert "is not a ROS 2 bag" in line and "already a fusion-pf recording" in line


def test_pair_nearest_is_one_to_one_within_half_a_period():
    color = np.arange(10) * 100
    depth = np.array([3, 140, 310, 330, 900, 1000])
    pairs = pair_nearest(color, depth, 100)
    # depth 140 is nearest to colour 100 (40) and 200 (60): 100 keeps it, 200 gets none; 900 goes to 900, not 800
    assert pairs.tolist() == [0, 1, -1, 2, 3, -1, -1, -1, -1, 4]
    assert pair_nearest(color, np.empty(0, np.int64), 50).tolist() == [-1] * 10


def test_direct_replay_of_a_bag(bag, frames):
    with open_import(bag) as src:
        got = list(src)
    assert src.total == 8 and len(got) == 8 and got[3].depth is None


def _image_msg(array, encoding, *, pad=0, bigendian=False):
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    h, w = array.shape[:2]
    rows = np.ascontiguousarray(array).astype(array.dtype.newbyteorder(">" if bigendian else "<"))
    rows = rows.view(np.uint8).reshape(h, -1)
    data = np.hstack([rows, np.zeros((h, pad), np.uint8)]).ravel()
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    return ts.types["sensor_msgs/msg/Image"](
        header=Header(stamp=Time(sec=1, nanosec=0), frame_id="c"),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=int(bigendian),
        step=rows.shape[1] + pad,
        data=data,
    )


def test_image_encodings(frames):
    from drivers.importers.ros import decode_color, decode_depth
    from fusion_pf.errors import InputError

    rgb, depth = frames[0].color, frames[0].depth
    assert np.array_equal(decode_color(_image_msg(rgb[:, :, ::-1], "bgr8", pad=7), False, "t"), rgb)
    rgba = np.dstack([rgb, np.full(rgb.shape[:2], 9, np.uint8)])
    assert np.array_equal(decode_color(_image_msg(rgba, "rgba8"), False, "t"), rgb)
    grey = rgb[:, :, 1]
    assert np.array_equal(decode_color(_image_msg(grey, "mono8"), False, "t"), np.dstack([grey] * 3))
    yuyv = np.full((4, 8, 2), 128, np.uint8)  # BT.601 video range: Y = 16 black, Y = 235 white, U = V = 128
    yuyv[:2, :, 0], yuyv[2:, :, 0] = 16, 235
    out = decode_color(_image_msg(yuyv, "yuyv"), False, "t").astype(int)
    assert out[:2].max() <= 1 and out[2:].min() >= 254
    assert np.array_equal(decode_depth(_image_msg(depth, "16UC1", pad=4, bigendian=True), False, "t"), depth)
    metres = np.where(depth > 0, depth / 1000.0, np.nan).astype(np.float32)
    assert np.array_equal(decode_depth(_image_msg(metres, "32FC1"), False, "t"), depth)
    with pytest.raises(InputError, match="colour encoding 'bayer_rggb8' is not supported"):
        decode_color(_image_msg(grey, "bayer_rggb8"), False, "t")
    with pytest.raises(InputError, match="depth encoding '8UC1' is not supported"):
        decode_depth(_image_msg(grey, "8UC1"), False, "t")
