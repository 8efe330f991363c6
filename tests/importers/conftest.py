"""Shared pieces of the importer tests: source frames, a ROS 2 bag writer, the CLI.

* ``synth_frames(n, size)`` -> list of Frame from the synthetic scene (the content every
  written-here test file carries, so imports can be compared with it).
* ``write_ros2_bag(folder, frames, ...)`` -> Path of the ``.mcap`` file: a ROS 2 bag written
  by ``rosbags`` (its MCAP storage plugin, the ROS 2 Humble message definitions), topics
  as realsense2_camera publishes them with ``align_depth.enable:=true``.
* ``fusion_pf(*args)`` runs the CLI in a subprocess; ``error_line(proc)`` its one error line.
"""

from __future__ import annotations

import struct
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers import open_source
from fusion_pf.frame import Intrinsics

CLI = [sys.executable, "-m", "fusion_pf"]
FIXTURES = Path(__file__).resolve().parents[1] / "fixtures"


def fusion_pf(*args, timeout=300):
    return subprocess.run([*CLI, *map(str, args)], capture_output=True, text=True, timeout=timeout)


def error_line(proc):
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    lines = [x for x in proc.stderr.splitlines() if x.startswith("fusion-pf: error:")]
    assert len(lines) == 1, proc.stderr
    return lines[0]


def synth_frames(n, size=(320, 240), seed=5):
    w, h = size
    with open_source(f"synth:frames={n},seed={seed},size={w}x{h},background_frames=0") as src:
        return list(src)


def _header(typestore, stamp_ns, frame_id):
    Header = typestore.types["std_msgs/msg/Header"]
    Time = typestore.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=stamp_ns // 1_000_000_000, nanosec=stamp_ns % 1_000_000_000)
    if "seq" in Header.__dataclass_fields__:  # ROS 1
        return Header(seq=0, stamp=stamp, frame_id=frame_id)
    return Header(stamp=stamp, frame_id=frame_id)


def _camera_info(typestore, stamp_ns, k, frame_id):
    CameraInfo = typestore.types["sensor_msgs/msg/CameraInfo"]
    RegionOfInterest = typestore.types["sensor_msgs/msg/RegionOfInterest"]
    arrays = {
        "d": np.zeros(5),
        "k": np.array([k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1], np.float64),
        "r": np.eye(3).ravel(),
        "p": np.array([k.fx, 0, k.cx, 0, 0, k.fy, k.cy, 0, 0, 0, 1, 0], np.float64),
    }
    if "K" in CameraInfo.__dataclass_fields__:  # ROS 1 names
        arrays = {name.upper(): value for name, value in arrays.items()}
    return CameraInfo(
        header=_header(typestore, stamp_ns, frame_id),
        height=k.height,
        width=k.width,
        distortion_model="plumb_bob",
        **arrays,
        binning_x=0,
        binning_y=0,
        roi=RegionOfInterest(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
    )


def _image(typestore, stamp_ns, frame_id, array, encoding):
    Image = typestore.types["sensor_msgs/msg/Image"]
    h, w = array.shape[:2]
    data = np.ascontiguousarray(array).view(np.uint8).ravel()
    return Image(
        header=_header(typestore, stamp_ns, frame_id),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=data.size // h,
        data=data,
    )


#: Colour camera origin in the depth camera's optical frame (mm): 15 mm to the left.
COLOR_IN_DEPTH_MM = np.array([-15.0, 0.0, 0.0])


def depth_intrinsics(color):
    """Intrinsics of the test bags' depth camera: 360x270, a slightly wider view than colour's."""
    return Intrinsics(360, 270, 0.95 * color.fx, 0.95 * color.fy, 179.5, 134.5)


def depth_camera_view(depth_c, kc, kd):
    """What a depth camera with intrinsics ``kd`` at :data:`COLOR_IN_DEPTH_MM` from the colour camera sees.

    Backward warping, independent of the importer's forward splatting: each depth pixel's ray
    is intersected with the colour-aligned depth map by fixed-point iteration (z -> the
    colour depth where the point at z projects); pixels that do not settle (depth edges,
    outside the colour view) get 0.
    """
    vd, ud = np.mgrid[0 : kd.height, 0 : kd.width].astype(np.float64)
    rx, ry = (ud - kd.cx) / kd.fx, (vd - kd.cy) / kd.fy
    t = -COLOR_IN_DEPTH_MM  # p_c = p_d + t

    def sample(z):
        uc = np.rint(kc.fx * (rx * z + t[0]) / (z + t[2]) + kc.cx).astype(int)
        vc = np.rint(kc.fy * (ry * z + t[1]) / (z + t[2]) + kc.cy).astype(int)
        inside = (uc >= 0) & (uc < kc.width) & (vc >= 0) & (vc < kc.height)
        return np.where(inside, depth_c[np.clip(vc, 0, kc.height - 1), np.clip(uc, 0, kc.width - 1)], 0).astype(float)

    z = np.full(rx.shape, 1000.0)
    for _ in range(6):
        s = sample(z)
        z = np.where(s > 0, s, z)
    settled = (sample(z) > 0) & (np.abs(sample(z) - z) < 0.5)
    return np.where(settled, z, 0).astype(np.uint16)


def _tf_static(typestore, stamp_ns):
    """realsense2_camera's static transforms: camera_link -> {depth, color}_frame -> *_optical_frame."""
    T = typestore.types
    optical = T["geometry_msgs/msg/Quaternion"](x=-0.5, y=0.5, z=-0.5, w=0.5)
    identity = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)

    def stamped(parent, child, xyz, q):
        return T["geometry_msgs/msg/TransformStamped"](
            header=_header(typestore, stamp_ns, parent),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=xyz[0], y=xyz[1], z=xyz[2]), rotation=q
            ),
        )

    # the colour camera 15 mm to the left (+y of camera_link, -x of the optical frames)
    return T["tf2_msgs/msg/TFMessage"](
        transforms=[
            stamped("camera_link", "camera_depth_frame", (0.0, 0.0, 0.0), identity),
            stamped("camera_depth_frame", "camera_depth_optical_frame", (0.0, 0.0, 0.0), optical),
            stamped("camera_link", "camera_color_frame", (0.0, 0.015, 0.0), identity),
            stamped("camera_color_frame", "camera_color_optical_frame", (0.0, 0.0, 0.0), optical),
        ]
    )


#: Inverse-depth quantisation of 32FC1 compressedDepth messages: stored = A / depth_m + B.
QUANT_A, QUANT_B = 3000.0, -1.0


def _compressed_depth(depth_mm, encoding):
    """compressed_depth_image_transport payload: config header (format 0 = PNG, A, B) + 16-bit PNG."""
    if encoding == "16UC1":
        stored, a, b = depth_mm, 0.0, 0.0
    else:
        with np.errstate(divide="ignore"):
            stored = np.where(depth_mm > 0, np.rint(QUANT_A / (depth_mm / 1000.0) + QUANT_B), 0).astype(np.uint16)
        a, b = QUANT_A, QUANT_B
    png = cv2.imencode(".png", stored)[1].tobytes()
    return np.frombuffer(struct.pack("<iff", 0, a, b) + png, np.uint8)


def write_ros2_bag(
    folder,
    frames,
    *,
    depth="16UC1",
    drop_depth=(),
    depth_offset_ns=2_000_000,
    compressed=True,
    unaligned=True,
    images=True,
    ros1=False,
    compressed_depth=False,
    sqlite=False,
    tf=True,
):
    """Write frames as a realsense2_camera-style bag; return the .mcap (ROS 2), bag folder (sqlite) or .bag path.

    Colour ``rgb8`` on /camera/color/image_raw (stamp = frame time), aligned depth on
    /camera/aligned_depth_to_color/image_raw (``16UC1`` mm or ``32FC1`` m, NaN for no depth)
    ``depth_offset_ns`` later, camera info on both namespaces, a JPEG
    /camera/color/image_raw/compressed, and the unaligned /camera/depth/image_rect_raw
    (:func:`depth_camera_view`, 360x270, its /camera/depth/camera_info) with the camera's
    /tf_static (``tf=True``, realsense2_camera's frames: the colour camera 15 mm to the left
    of the depth camera). Frames listed in ``drop_depth`` get no aligned depth message. With
    ``compressed_depth``, the aligned depth also goes to .../image_raw/compressedDepth as
    compressed_depth_image_transport publishes it (12-byte config header, then a 16-bit PNG of
    millimetres for 16UC1 or of quantised inverse metres for 32FC1).
    """
    from rosbags.typesys import Stores, get_typestore

    folder = Path(folder)
    if ros1:
        from rosbags.rosbag1 import Writer

        typestore = get_typestore(Stores.ROS1_NOETIC)
        writer, serialize = Writer(folder.with_suffix(".bag")), typestore.serialize_ros1
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        typestore = get_typestore(Stores.ROS2_HUMBLE)
        writer = Writer(
            folder,
            version=Writer.VERSION_LATEST,
            storage_plugin=StoragePlugin.SQLITE3 if sqlite else StoragePlugin.MCAP,
        )
        serialize = typestore.serialize_cdr
    topics = {
        "/camera/color/camera_info": "sensor_msgs/msg/CameraInfo",
        "/camera/aligned_depth_to_color/camera_info": "sensor_msgs/msg/CameraInfo",
    }
    if not ros1:
        topics["/tf_static"] = "tf2_msgs/msg/TFMessage"
    if images:
        topics.update(
            {
                "/camera/color/image_raw": "sensor_msgs/msg/Image",
                "/camera/aligned_depth_to_color/image_raw": "sensor_msgs/msg/Image",
            }
        )
        if compressed:
            topics["/camera/color/image_raw/compressed"] = "sensor_msgs/msg/CompressedImage"
        if unaligned:
            topics["/camera/depth/image_rect_raw"] = "sensor_msgs/msg/Image"
            topics["/camera/depth/camera_info"] = "sensor_msgs/msg/CameraInfo"
        if compressed_depth:
            topics["/camera/aligned_depth_to_color/image_raw/compressedDepth"] = "sensor_msgs/msg/CompressedImage"
    with writer:
        conns = {t: writer.add_connection(t, ty, typestore=typestore) for t, ty in topics.items()}
        CompressedImage = typestore.types["sensor_msgs/msg/CompressedImage"]

        def put(topic, msg, log_ns):
            writer.write(conns[topic], log_ns, serialize(msg, topics[topic]))

        if images and unaligned and tf and not ros1:
            put("/tf_static", _tf_static(typestore, frames[0].timestamp_ns), frames[0].timestamp_ns)
        for i, f in enumerate(frames):
            t = f.timestamp_ns
            log = t + 5_000_000
            info = _camera_info(typestore, t, f.intrinsics, "camera_color_optical_frame")
            put("/camera/color/camera_info", info, log)
            put("/camera/aligned_depth_to_color/camera_info", info, log)
            if not images:
                continue
            put("/camera/color/image_raw", _image(typestore, t, "camera_color_optical_frame", f.color, "rgb8"), log)
            if compressed:
                ok, jpg = cv2.imencode(".jpg", cv2.cvtColor(f.color, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
                put(
                    "/camera/color/image_raw/compressed",
                    CompressedImage(
                        header=_header(typestore, t, "camera_color_optical_frame"),
                        format="rgb8; jpeg compressed bgr8",
                        data=jpg.ravel(),
                    ),
                    log,
                )
            if i not in drop_depth:
                td = t + depth_offset_ns
                if depth == "16UC1":
                    array = f.depth
                else:
                    array = np.where(f.depth > 0, f.depth.astype(np.float32) / 1000, np.nan).astype(np.float32)
                put(
                    "/camera/aligned_depth_to_color/image_raw",
                    _image(typestore, td, "camera_color_optical_frame", array, depth),
                    log + 1,
                )
                if compressed_depth:
                    put(
                        "/camera/aligned_depth_to_color/image_raw/compressedDepth",
                        CompressedImage(
                            header=_header(typestore, td, "camera_color_optical_frame"),
                            format=f"{depth}; compressedDepth png",
                            data=_compressed_depth(f.depth, depth),
                        ),
                        log + 1,
                    )
            if unaligned:
                kd = depth_intrinsics(f.intrinsics)
                other = depth_camera_view(f.depth, f.intrinsics, kd)
                put(
                    "/camera/depth/image_rect_raw",
                    _image(typestore, t, "camera_depth_optical_frame", other, "16UC1"),
                    log + 2,
                )
                put("/camera/depth/camera_info", _camera_info(typestore, t, kd, "camera_depth_optical_frame"), log + 2)
    if ros1:
        return folder.with_suffix(".bag")
    return folder if sqlite else next(folder.glob("*.mcap"))


@pytest.fixture(scope="module")
def frames():
    return synth_frames(8)
