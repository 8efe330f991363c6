"""Import speed (frames/s) of every importer of ``fusion-pf import``.

Builds one input per format in a work folder, from the synthetic scene (640x480) and from the
Azure Kinect fixture, then times :func:`drivers.importers.write_recording` on each (raw colour
and depth, zstd, as ``fusion-pf import`` does by default)::

    PYTHONPATH=. python benchmarks/import_speed.py [--frames 150] [--workdir DIR]

Inputs:

* ``ros2``: a ROS 2 bag (rosbags, MCAP storage) with rgb8 colour, aligned 16UC1 depth,
  camera info and a JPEG compressed colour topic, as realsense2_camera records it;
* ``folder``: colour PNGs and 16-bit depth PNGs in ``color/`` and ``depth/``;
* ``video``: an MPEG-4 ``.mp4`` written by OpenCV (colour only);
* ``k4a``: the fixture's one Azure Kinect capture (MJPG 1280x720 + NFOV depth) decoded,
  registered and written ``frames / 3`` times (the fixture has one capture; registration dominates).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from drivers import open_source  # noqa: E402
from drivers.importers import open_import, write_recording  # noqa: E402


def synth(n: int) -> list:
    with open_source(f"synth:frames={n},seed=1,size=640x480,background_frames=0") as src:
        return list(src)


def make_ros2(folder: Path, frames: list) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    Image, Info = ts.types["sensor_msgs/msg/Image"], ts.types["sensor_msgs/msg/CameraInfo"]
    Roi, Compressed = ts.types["sensor_msgs/msg/RegionOfInterest"], ts.types["sensor_msgs/msg/CompressedImage"]
    topics = {
        "/camera/color/image_raw": Image,
        "/camera/aligned_depth_to_color/image_raw": Image,
        "/camera/color/camera_info": Info,
        "/camera/color/image_raw/compressed": Compressed,
    }
    with Writer(folder, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {t: writer.add_connection(t, c.__msgtype__, typestore=ts) for t, c in topics.items()}
        for f in frames:
            t = f.timestamp_ns
            hdr = Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="camera_color_optical_frame")
            k = f.intrinsics
            msgs = {
                "/camera/color/image_raw": Image(
                    header=hdr, height=480, width=640, encoding="rgb8", is_bigendian=0, step=1920, data=f.color.ravel()
                ),
                "/camera/aligned_depth_to_color/image_raw": Image(
                    header=hdr,
                    height=480,
                    width=640,
                    encoding="16UC1",
                    is_bigendian=0,
                    step=1280,
                    data=f.depth.view(np.uint8).ravel(),
                ),
                "/camera/color/camera_info": Info(
                    header=hdr,
                    height=480,
                    width=640,
                    distortion_model="plumb_bob",
                    d=np.zeros(5),
                    k=k.K.ravel(),
                    r=np.eye(3).ravel(),
                    p=np.hstack([k.K, np.zeros((3, 1))]).ravel(),
                    binning_x=0,
                    binning_y=0,
                    roi=Roi(x_offset=0, y_offset=0, height=0, width=0, do_rectify=False),
                ),
                "/camera/color/image_raw/compressed": Compressed(
                    header=hdr, format="jpeg", data=cv2.imencode(".jpg", f.color[:, :, ::-1])[1].ravel()
                ),
            }
            for topic, msg in msgs.items():
                writer.write(conns[topic], t, ts.serialize_cdr(msg, msg.__msgtype__))
    return next(folder.glob("*.mcap"))


def make_folder(folder: Path, frames: list) -> Path:
    (folder / "color").mkdir(parents=True, exist_ok=True)
    (folder / "depth").mkdir(exist_ok=True)
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / "color" / f"{i:06d}.png"), f.color[:, :, ::-1])
        cv2.imwrite(str(folder / "depth" / f"{i:06d}.png"), f.depth)
    return folder


def make_video(path: Path, frames: list) -> Path:
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30, (640, 480))
    for f in frames:
        writer.write(np.ascontiguousarray(f.color[:, :, ::-1]))
    writer.release()
    return path


def time_k4a(out: Path, n: int, compression: str) -> tuple[int, int, float, float, float]:
    """Open the Azure Kinect fixture (calibration, ray table), then decode, register and write its capture n times.

    Returns (frames, with depth, setup seconds, seconds, CPU seconds) of the n frames.
    """
    from dataclasses import replace

    from drivers.importers.k4a import AzureKinectSource
    from drivers.mcap_record import McapRecorder

    started = time.perf_counter()
    fixture = ROOT / "tests/fixtures/k4a_recording.mkv"
    with AzureKinectSource(fixture) as src, McapRecorder(out, compression=compression) as rec:
        setup = time.perf_counter() - started
        started, cpu = time.perf_counter(), time.process_time()
        for k in range(n):
            for frame in src:
                rec.write(replace(frame, timestamp_ns=frame.timestamp_ns + k * 33_333_333))
        return (
            rec.frames_written,
            src.stats.frames - src.stats.missing_depth,
            setup,
            time.perf_counter() - started,
            time.process_time() - cpu,
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=150, help="frames per input (k4a: a third of them)")
    parser.add_argument(
        "--compression",
        choices=("zstd", "lz4", "none"),
        default="zstd",
        help="output chunk compression (zstd, the default of fusion-pf import, dominates)",
    )
    parser.add_argument("--workdir", type=Path, help="where inputs and outputs go (default: a temporary folder)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        work = args.workdir or Path(tmp)
        work.mkdir(parents=True, exist_ok=True)
        frames = synth(args.frames)
        inputs = {
            "ros2": (make_ros2(work / "ros2", frames), {}),
            "folder": (make_folder(work / "folder", frames), {}),
            "video": (make_video(work / "video.mp4", frames), {}),
        }
        print(
            f"load average {os.getloadavg()[0]:.2f} {os.getloadavg()[1]:.2f}; {os.cpu_count()} CPUs; "
            f"output compression {args.compression}"
        )
        for name, (path, options) in inputs.items():
            out = work / f"{name}.mcap"
            started, cpu = time.perf_counter(), time.process_time()
            summary = write_recording(open_import(path, **options), out, progress=False, compression=args.compression)
            seconds, cpu = time.perf_counter() - started, time.process_time() - cpu
            print(
                f"{name:7s} {summary.frames:4d} frames 640x480, {summary.with_depth:4d} with depth: "
                f"{summary.frames / seconds:6.1f} frames/s ({seconds:.1f} s; {summary.frames / cpu:6.1f} frames per "
                "CPU second)"
            )
        n, with_depth, setup, seconds, cpu = time_k4a(work / "k4a.mcap", max(1, args.frames // 3), args.compression)
        print(
            f"k4a     {n:4d} frames 1280x720, {with_depth:4d} with depth: {n / seconds:6.1f} frames/s "
            f"({seconds:.1f} s; {n / cpu:6.1f} frames per CPU second; after {setup:.1f} s of set-up: "
            "calibration and depth ray table)"
        )
        print(f"load average {os.getloadavg()[0]:.2f} after")


if __name__ == "__main__":
    main()
