"""Host-side handling of the OAK driver on depthai's own host-only pipeline.

Real ``dai.ImgFrame`` (colour BGR888i / RGB888i, depth RAW16) and ``dai.NNData``
(MoveNet output tensor, FP16, as the device's NeuralNetwork node sends it)
messages go through a ThreadedHostNode or a ReplayMessage of an MCAP that
depthai's RecordMessage wrote, through a host-run Sync node, into the driver's
converter and queue loop. No device, no mocks.
"""

from __future__ import annotations

import datetime
import threading
import time
from pathlib import Path

import depthai as dai
import numpy as np
import pytest
from mcap.reader import make_reader

from drivers.base import SourceStats
from drivers.oak import (
    ClockMap,
    GroupConverter,
    colour_to_rgb,
    depth_to_mm,
    frames_from_queue,
    intrinsics_from_calibration,
    pose_tensor,
    timedelta_to_ns,
)
from drivers.oak_pose import MOVENET_KEYPOINTS, Letterbox, decode_movenet, joints_from_keypoints
from fusion_pf.errors import DeviceError, InputError
from fusion_pf.frame import Intrinsics

W, H = 64, 40
NN = 32
PERIOD = datetime.timedelta(milliseconds=33)
T0 = datetime.timedelta(seconds=1234, microseconds=567)
INTRINSICS = Intrinsics(W, H, 50.0, 51.0, 31.5, 19.5)
CLOCK = ClockMap(offset_ns=1_700_000_000_000_000_000)


def _colour(i: int) -> np.ndarray:
    """Deterministic RGB test image of frame ``i``."""
    rng = np.random.default_rng(i)
    return rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8)


def _depth(i: int) -> np.ndarray:
    depth = np.full((H, W), 800 + 10 * i, np.uint16)
    depth[::3, ::5] = 0  # invalid pixels
    return depth


def _pose(i: int) -> np.ndarray:
    """MoveNet output (1, 1, 17, 3) as FP16, y, x, score."""
    rng = np.random.default_rng(100 + i)
    yx = rng.uniform(0.2, 0.8, size=(17, 2))
    score = rng.uniform(0.0, 1.0, size=(17, 1))
    return np.concatenate([yx, score], axis=1).astype(np.float16).reshape(1, 1, 17, 3)


def _img(kind: dai.ImgFrame.Type, rgb: np.ndarray, seq: int, ts: datetime.timedelta) -> dai.ImgFrame:
    frame = dai.ImgFrame()
    frame.setCvFrame(np.ascontiguousarray(rgb[:, :, ::-1]), kind)  # setCvFrame takes BGR
    frame.setSequenceNum(seq)
    frame.setTimestamp(ts)
    return frame


def _depth_img(depth: np.ndarray, seq: int, ts: datetime.timedelta) -> dai.ImgFrame:
    frame = dai.ImgFrame()
    frame.setFrame(depth)
    frame.setWidth(depth.shape[1])
    frame.setHeight(depth.shape[0])
    frame.setType(dai.ImgFrame.Type.RAW16)
    frame.setSequenceNum(seq)
    frame.setTimestamp(ts)
    return frame


def _nn(i: int, seq: int, ts: datetime.timedelta) -> dai.NNData:
    nn = dai.NNData()
    nn.addTensor("Identity", _pose(i))
    nn.setSequenceNum(seq)
    nn.setTimestamp(ts)
    return nn


def _ts(seq: int) -> datetime.timedelta:
    return T0 + seq * PERIOD


class _HostStreams(dai.node.ThreadedHostNode):
    """Emits real colour, depth and pose messages shaped like the device pipeline's.

    ``seqs`` are the colour sequence numbers sent (gaps = frames the device
    lost); depth comes 1 ms after colour, like the stereo pipeline. After the
    last frame the node waits for ``release`` (set by the test once it has
    every frame), then stops the pipeline (``stop=True``, the host view of a
    pulled cable: the queues close), or idles (a device that went silent).
    """

    def __init__(self) -> None:
        super().__init__()
        self.colour = self.createOutput()
        self.depth = self.createOutput()
        self.skeleton = self.createOutput()
        self.seqs: list[int] = []
        self.colour_type = dai.ImgFrame.Type.BGR888i
        self.send_colour_depth = True
        self.stop = True
        self.release = threading.Event()
        self.linger_s = 0.0

    def run(self) -> None:
        for seq in self.seqs:
            ts = _ts(seq)
            if self.send_colour_depth:
                self.colour.send(_img(self.colour_type, _colour(seq), seq, ts))
                self.depth.send(_depth_img(_depth(seq), seq, ts + datetime.timedelta(milliseconds=1)))
            self.skeleton.send(_nn(seq, seq, ts))
            time.sleep(0.02)
        if self.stop:
            self.release.wait(timeout=10.0)
            time.sleep(self.linger_s)
            self.stopPipeline()
        else:
            while self.mainLoop():
                time.sleep(0.02)


def _sync(pipeline: dai.Pipeline) -> dai.node.Sync:
    sync = pipeline.create(dai.node.Sync)
    sync.setRunOnHost(True)
    sync.setSyncThreshold(PERIOD / 2)
    return sync


def _expected_joints(seq: int, depth: np.ndarray):
    kp = decode_movenet(_pose(seq).astype(np.float32), Letterbox((W, H), (NN, NN)))
    return joints_from_keypoints(kp, depth)


def _check_frame(frame, seq: int) -> None:
    assert frame.seq == seq
    assert frame.timestamp_ns == timedelta_to_ns(_ts(seq)) + CLOCK.offset_ns
    np.testing.assert_array_equal(frame.color, _colour(seq))
    np.testing.assert_array_equal(frame.depth, _depth(seq))
    assert frame.intrinsics == INTRINSICS
    assert dict(frame.joints) == _expected_joints(seq, _depth(seq))


def _run_live(seqs: list[int], *, stop: bool, timeout_s: float, colour_type=dai.ImgFrame.Type.BGR888i):
    """Run the host streams through a host Sync into frames_from_queue."""
    stats = SourceStats()
    converter = GroupConverter(INTRINSICS, CLOCK, (NN, NN), stats)
    frames = []
    with dai.Pipeline(False) as pipeline:
        src = pipeline.create(_HostStreams)
        src.seqs, src.stop, src.colour_type = seqs, stop, colour_type
        sync = _sync(pipeline)
        src.colour.link(sync.inputs["colour"])
        src.depth.link(sync.inputs["depth"])
        src.skeleton.link(sync.inputs["skeleton"])
        queue = sync.out.createOutputQueue(maxSize=8, blocking=False)
        pipeline.start()
        with pytest.raises(DeviceError) as info:
            for frame in frames_from_queue(queue, converter, timeout_s):
                frames.append(frame)
                if len(frames) == len(seqs):
                    src.release.set()
        pipeline.stop()
    return frames, stats, converter, str(info.value)


def test_pulled_cable_keeps_every_frame_counts_gaps_and_raises() -> None:
    seqs = [0, 1, 2, 5, 6, 9]
    frames, stats, converter, message = _run_live(seqs, stop=True, timeout_s=2.0)
    assert [f.seq for f in frames] == seqs
    for frame, seq in zip(frames, seqs):
        _check_frame(frame, seq)
    assert stats.dropped == 4 and converter.gaps == 2
    assert "stream closed" in message and "after 6 frames" in message
    assert "4 frames dropped before that, in 2 gaps" in message
    assert "\n" not in message


def test_silent_device_times_out_after_the_frames_it_sent() -> None:
    start = time.monotonic()
    frames, stats, _, message = _run_live([3, 4], stop=False, timeout_s=0.3)
    assert [f.seq for f in frames] == [3, 4]
    assert stats.dropped == 0
    assert "no frame from the OAK device for 0.3 s (device timeout) after 2 frames" in message
    assert time.monotonic() - start < 5.0


def test_device_that_never_sends_times_out_before_the_first_frame() -> None:
    with dai.Pipeline(False) as pipeline:
        src = pipeline.create(_HostStreams)
        src.stop = False
        sync = _sync(pipeline)
        src.colour.link(sync.inputs["colour"])
        queue = sync.out.createOutputQueue()
        pipeline.start()
        converter = GroupConverter(INTRINSICS, CLOCK, None, SourceStats())
        with pytest.raises(
            DeviceError, match=r"^no frame from the OAK device for 0.4 s \(device timeout\) before the first frame$"
        ):
            next(frames_from_queue(queue, converter, 0.2, start_timeout_s=0.4))
        pipeline.stop()


def test_rgb888i_colour_is_converted_exactly() -> None:
    frames, _, _, _ = _run_live([0, 1], stop=True, timeout_s=2.0, colour_type=dai.ImgFrame.Type.RGB888i)
    for frame in frames:
        _check_frame(frame, frame.seq)


def _record(tmp_path: Path, seqs: list[int]) -> dict[str, Path]:
    """Colour and depth recorded by depthai's RecordMessage (its MCAP format)."""
    paths = {name: tmp_path / f"dai_{name}.mcap" for name in ("colour", "depth")}
    with dai.Pipeline(False) as pipeline:
        src = pipeline.create(_HostStreams)
        src.seqs, src.colour_type = seqs, dai.ImgFrame.Type.RGB888i
        src.release.set()
        src.linger_s = 0.3  # lets RecordMessage write the last frame before the pipeline stops
        for name, path in paths.items():
            rec = pipeline.create(dai.node.RecordMessage)
            rec.setRecordFile(path)
            getattr(src, name).link(rec.input)
        pipeline.start()
        pipeline.wait()
    for path in paths.values():
        with path.open("rb") as fh:
            assert sum(1 for _ in make_reader(fh).iter_messages()) == len(seqs)
    return paths


class _PoseOnly(_HostStreams):
    def __init__(self) -> None:
        super().__init__()
        self.send_colour_depth = False
        self.stop = False


def test_replayed_depthai_recording_through_sync(tmp_path: Path) -> None:
    seqs = [10, 11, 12, 14]
    paths = _record(tmp_path, seqs)
    stats = SourceStats()
    converter = GroupConverter(INTRINSICS, CLOCK, (NN, NN), stats)
    frames = []
    with dai.Pipeline(False) as pipeline:
        sync = _sync(pipeline)
        for name, path in paths.items():
            replay = pipeline.create(dai.node.ReplayMessage)
            replay.setReplayFile(path)
            # looping: a non-looping replay stops the whole pipeline at the end
            # of its file, racing the last group out of Sync
            replay.setLoop(True)
            replay.out.link(sync.inputs[name])
        # depthai 3.12 RecordMessage stores ImgFrame / IMU only, so the pose
        # network's NNData comes from a host node, matched by timestamp
        pose = pipeline.create(_PoseOnly)
        pose.seqs = seqs
        pose.skeleton.link(sync.inputs["skeleton"])
        queue = sync.out.createOutputQueue(maxSize=8, blocking=False)
        pipeline.start()
        for frame in frames_from_queue(queue, converter, 2.0):
            frames.append(frame)
            if len(frames) == len(seqs):
                break
        pipeline.stop()
    assert [f.seq for f in frames] == seqs
    for frame, seq in zip(frames, seqs):
        _check_frame(frame, seq)
    assert stats.dropped == 1


def test_group_without_skeleton_or_depth() -> None:
    stats = SourceStats()
    group = dai.MessageGroup()
    group["colour"] = _img(dai.ImgFrame.Type.BGR888i, _colour(0), 0, T0)
    frame = GroupConverter(INTRINSICS, CLOCK, None, stats).convert(group)
    assert frame.depth is None and frame.joints is None
    group["depth"] = _depth_img(_depth(0), 0, T0)
    group["skeleton"] = _nn(0, 0, T0)
    assert GroupConverter(INTRINSICS, CLOCK, None, stats).convert(group).joints is None
    assert GroupConverter(INTRINSICS, CLOCK, (NN, NN), stats).convert(group).joints is not None


def test_group_errors_name_the_problem() -> None:
    stats = SourceStats()
    converter = GroupConverter(INTRINSICS, CLOCK, (NN, NN), stats)
    group = dai.MessageGroup()
    group["depth"] = _depth_img(_depth(0), 0, T0)
    with pytest.raises(InputError, match="must hold a 'colour' frame"):
        converter.convert(group)
    group["colour"] = _img(dai.ImgFrame.Type.BGR888i, np.zeros((20, W, 3), np.uint8), 0, T0)
    with pytest.raises(DeviceError, match="colour frame is 64x20, expected 64x40"):
        converter.convert(group)
    group["colour"] = _img(dai.ImgFrame.Type.BGR888i, _colour(0), 0, T0)
    group["depth"] = _depth_img(np.zeros((H, 32), np.uint16), 0, T0)
    with pytest.raises(DeviceError, match="depth frame is 32x40, not aligned to the 64x40"):
        converter.convert(group)


def test_sequence_going_back_is_noted_not_counted() -> None:
    stats = SourceStats()
    converter = GroupConverter(INTRINSICS, CLOCK, None, stats)
    for seq in (7, 8, 2):
        group = dai.MessageGroup()
        group["colour"] = _img(dai.ImgFrame.Type.BGR888i, _colour(seq), seq, _ts(seq))
        converter.convert(group)
    assert stats.dropped == 0
    assert stats.notes == ["colour sequence number went back from 8 to 2 (device restarted)"]


@pytest.mark.parametrize("kind", ["BGR888i", "RGB888i", "BGR888p", "RGB888p"])
def test_colour_types_convert_exactly(kind: str) -> None:
    rgb = _colour(5)
    out = colour_to_rgb(_img(getattr(dai.ImgFrame.Type, kind), rgb, 0, T0))
    assert out.dtype == np.uint8 and out.flags.c_contiguous
    np.testing.assert_array_equal(out, rgb)


def test_nv12_colour_is_converted_to_rgb() -> None:
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[:] = (200, 60, 30)
    out = colour_to_rgb(_img(dai.ImgFrame.Type.NV12, rgb, 0, T0))
    assert out.shape == (H, W, 3)
    assert np.abs(out.astype(int) - rgb).max() <= 4  # NV12 is lossy (chroma subsampled)


def test_frame_type_errors() -> None:
    depth = _depth_img(_depth(0), 0, T0)
    with pytest.raises(InputError, match="colour frame type must be one of .* got RAW16"):
        colour_to_rgb(depth)
    with pytest.raises(InputError, match="depth frame type must be RAW16 .* got BGR888i"):
        depth_to_mm(_img(dai.ImgFrame.Type.BGR888i, _colour(0), 0, T0))


def test_pose_tensor_selection() -> None:
    nn = dai.NNData()
    nn.addTensor("7022.0", np.zeros((17, 1, 1), np.float16))
    nn.addTensor("Identity", _pose(1))
    np.testing.assert_array_equal(pose_tensor(nn), _pose(1).astype(np.float32))
    other = dai.NNData()
    other.addTensor("keypoints", _pose(2).reshape(17, 3))
    other.addTensor("score", np.zeros((1,), np.float16))
    assert pose_tensor(other).size == 51
    two = dai.NNData()
    two.addTensor("a", _pose(1))
    two.addTensor("b", _pose(2))
    with pytest.raises(InputError, match="one 51-value tensor, got layers"):
        pose_tensor(two)


def test_timedelta_to_ns_is_exact() -> None:
    td = datetime.timedelta(days=3, seconds=7, microseconds=123_456)
    assert timedelta_to_ns(td) == ((3 * 86_400 + 7) * 10**6 + 123_456) * 1_000
    assert timedelta_to_ns(datetime.timedelta(0)) == 0


def test_clock_map_gives_wall_clock_ns() -> None:
    clock = ClockMap.capture()
    mapped = clock.to_ns(dai.Clock.now())
    assert isinstance(mapped, int)
    assert abs(mapped - time.time_ns()) < 5_000_000  # 5 ms
    with pytest.raises(InputError, match="samples must be an int >= 1"):
        ClockMap.capture(0)


def _calibration(model: dai.CameraModel, coeffs: list[float]) -> dai.CalibrationHandler:
    calib = dai.CalibrationHandler()
    socket = dai.CameraBoardSocket.CAM_A
    calib.setCameraIntrinsics(socket, [[3000.0, 0.0, 2000.0], [0.0, 3010.0, 1500.0], [0.0, 0.0, 1.0]], 4056, 3040)
    calib.setDistortionCoefficients(socket, coeffs)
    calib.setCameraType(socket, model)
    return calib


def test_intrinsics_from_calibration_at_output_size() -> None:
    coeffs = [0.1, -0.2, 0.001, 0.002, 0.05, 0.01, 0.0, 0.0] + [0.0] * 6
    intr = intrinsics_from_calibration(_calibration(dai.CameraModel.Perspective, coeffs), 640, 400)
    # 4056x3040 (4:3) -> 640x400 (16:10): scale by 640/4056, crop rows centred
    s = 640 / 4056
    crop = (3040 * s - 400) / 2
    assert (intr.width, intr.height) == (640, 400)
    assert intr.fx == pytest.approx(3000 * s, rel=1e-6)
    assert intr.fy == pytest.approx(3010 * s, rel=1e-6)
    assert intr.cx == pytest.approx(2000 * s, rel=1e-6)
    assert intr.cy == pytest.approx(1500 * s - crop, rel=1e-6)
    assert intr.distortion_model == "rational_polynomial"
    assert intr.distortion == pytest.approx(coeffs[:8], abs=1e-7)


def test_intrinsics_distortion_models_and_errors() -> None:
    tilted = [0.1] * 14
    assert (
        intrinsics_from_calibration(_calibration(dai.CameraModel.Perspective, tilted), 640, 400).distortion_model
        == "opencv"
    )
    fisheye = intrinsics_from_calibration(_calibration(dai.CameraModel.Fisheye, [0.1, 0.01, 0.0, 0.001]), 640, 400)
    assert fisheye.distortion_model == "kannala_brandt" and len(fisheye.distortion) == 4
    with pytest.raises(DeviceError, match="distortion model must be Perspective or Fisheye, got Equirectangular"):
        intrinsics_from_calibration(_calibration(dai.CameraModel.Equirectangular, [0.0] * 14), 640, 400)
    with pytest.raises(DeviceError, match="no calibration for its colour camera"):
        intrinsics_from_calibration(dai.CalibrationHandler(), 640, 400)


def test_movenet_keypoint_order_matches_blob_output() -> None:
    # the MoveNet blob's first output is (1, 1, 17, 3): 17 keypoints of (y, x, score)
    from drivers.oak_pipeline import builtin_model_path

    blob = dai.OpenVINO.Blob(str(builtin_model_path("lightning")))
    assert list(blob.networkOutputs["Identity"].dims) == [3, len(MOVENET_KEYPOINTS), 1, 1]


def test_pulled_cable_mid_recording_leaves_a_complete_mcap(tmp_path: Path) -> None:
    """Frames from the host pipeline -> our McapRecorder -> McapReplay, exactly.

    The queue closes mid-recording (the host view of a pulled cable): the
    DeviceError passes through the recorder's ``with`` block, which finalises
    the file with every frame received.
    """
    from drivers.mcap_record import McapRecorder
    from drivers.mcap_replay import McapReplay

    intrinsics = Intrinsics(
        W, H, 50.0, 51.0, 31.5, 19.5, "rational_polynomial", (0.1, -0.2, 1e-3, 2e-3, 0.05, 0.0, 0.0, 0.0)
    )
    seqs = [0, 1, 3, 4]
    stats = SourceStats()
    converter = GroupConverter(intrinsics, CLOCK, (NN, NN), stats)
    path = tmp_path / "oak.mcap"
    sent = []
    with dai.Pipeline(False) as pipeline:
        src = pipeline.create(_HostStreams)
        src.seqs = seqs
        sync = _sync(pipeline)
        src.colour.link(sync.inputs["colour"])
        src.depth.link(sync.inputs["depth"])
        src.skeleton.link(sync.inputs["skeleton"])
        queue = sync.out.createOutputQueue(maxSize=8, blocking=False)
        pipeline.start()
        with pytest.raises(DeviceError, match="stream closed .* after 4 frames"):
            with McapRecorder(path) as recorder:
                for frame in frames_from_queue(queue, converter, 2.0):
                    recorder.write(frame)
                    sent.append(frame)
                    if len(sent) == len(seqs):
                        src.release.set()
        pipeline.stop()
    assert stats.dropped == 1
    with McapReplay(path) as replay:
        back = list(replay)
    assert len(back) == len(sent) == 4
    assert [b.seq for b in back] == seqs  # the device's numbering, gap included, survives the file
    for a, b in zip(sent, back):
        assert b.timestamp_ns == a.timestamp_ns
        np.testing.assert_array_equal(b.color, a.color)
        np.testing.assert_array_equal(b.depth, a.depth)
        assert b.intrinsics == a.intrinsics
        assert dict(b.joints) == dict(a.joints)


def test_bad_pose_messages_are_skipped_counted_and_noted_once() -> None:
    stats = SourceStats()
    converter = GroupConverter(INTRINSICS, CLOCK, (NN, NN), stats)
    joints = []
    for seq, values in enumerate(
        [_pose(0), np.zeros((1, 1, 17, 2), np.float16), _pose(2), np.full((1, 1, 17, 3), 2.0, np.float16)]
    ):
        group = dai.MessageGroup()
        group["colour"] = _img(dai.ImgFrame.Type.BGR888i, _colour(seq), seq, _ts(seq))
        nn = dai.NNData()
        nn.addTensor("Identity", values)
        group["skeleton"] = nn
        joints.append(converter.convert(group).joints)
    assert [j is None for j in joints] == [False, True, False, True]
    assert converter.bad_messages == 2
    assert stats.notes == [
        "skipped 2 bad skeleton message(s) (those frames have no skeleton); first: pose network output has "
        "34 values; expected 51 (MoveNet: 17 keypoints x (y, x, score))"
    ]
