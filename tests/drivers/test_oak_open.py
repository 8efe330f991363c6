"""OakSource.open / iterate / close for RVC2 and RVC4, without a camera.

``dai.Device`` and ``dai.Pipeline(device)`` are replaced by the signature-checked
stand-ins of :mod:`dai_spec` (no device can be created here); everything the
host runs is real: the Sync node (a real host node of the stand-in's host
pipeline), its queue, the messages (``ImgFrame`` with a real
``ImgTransformation``, RAW16 depth, ``NNData``), the calibration
(``CalibrationHandler``), the clock, the recorder and the replay.

A lost device: with ``setMaxReconnectionAttempts(0)`` and
``setStopOnDeviceLoss(True)`` (both checked below), depthai stops the pipeline
when the device fails ("strict mode", quoted from the installed depthai in
:func:`test_depthai_documents_the_strict_disconnect_semantics`); stopping the
host pipeline is that event as the host sees it.
"""

from __future__ import annotations

import datetime
import threading
import time
from pathlib import Path

import depthai as dai
import numpy as np
import pytest

import drivers.oak as oak
from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapReplay
from drivers.oak import OakConfig, OakSource
from fusion_pf.errors import DeviceError, InputError

from .dai_spec import REAL_DEVICE, REAL_PIPELINE, SpecDevice, SpecPipeline, camera_features, check_call

W, H = 640, 400
SENSOR = (4056, 3040)
K_SENSOR = [[3000.0, 0.0, 2000.0], [0.0, 3010.0, 1500.0], [0.0, 0.0, 1.0]]


def _calibration() -> dai.CalibrationHandler:
    calib = dai.CalibrationHandler()
    socket = dai.CameraBoardSocket.CAM_A
    calib.setCameraIntrinsics(socket, K_SENSOR, *SENSOR)
    calib.setDistortionCoefficients(socket, [0.1, -0.2, 0.001, 0.002, 0.05] + [0.0] * 9)
    calib.setCameraType(socket, dai.CameraModel.Perspective)
    return calib


def _transformation(extra_crop_rows: int = 0) -> dai.ImgTransformation:
    """What the Camera node reports: sensor -> scale -> centred crop, undistorted output."""
    tr = dai.ImgTransformation(*SENSOR, K_SENSOR, dai.CameraModel.Perspective, [0.0] * 14)
    s = W / SENSOR[0]
    tr.addScale(s, s)
    top = int((SENSOR[1] * s - H) / 2) + extra_crop_rows
    tr.addCrop(0, top, W, H)
    return tr


def _answers(platform: str = "RVC2", usb: dai.UsbSpeed = dai.UsbSpeed.SUPER, ir: list | None = None) -> dict:
    return {
        "getPlatformAsString": platform,
        "getConnectedCameraFeatures": camera_features(60.0, 120.0),
        "getUsbSpeed": usb,
        "readCalibration": _calibration(),
        "getIrDrivers": [] if ir is None else ir,
        "getProductName": "OAK-D-PRO" if ir else "OAK-D",
        "setIrLaserDotProjectorIntensity": True,
    }


@pytest.fixture()
def connect(monkeypatch: pytest.MonkeyPatch):
    """Put the stand-ins on the depthai module; returns (make, pipelines)."""
    pipelines: list[SpecPipeline] = []
    info = dai.DeviceInfo("14442C10D13EABCE00")
    info.name = "1.3"

    def make(answers: dict, close_s: float = 0.0) -> SpecDevice:
        device = SpecDevice(answers, close_s)

        class Device:
            @staticmethod
            def getAllAvailableDevices() -> list:
                return [info]

            def __new__(cls, arg):
                check_call(REAL_DEVICE, "__init__", (arg,), {})
                return device

        def pipeline(arg=True):
            check_call(REAL_PIPELINE, "__init__", (arg,), {})
            assert arg is device, "the pipeline must be built on the opened device"
            built = SpecPipeline()
            pipelines.append(built)
            return built

        monkeypatch.setattr(dai, "Device", Device)
        monkeypatch.setattr(dai, "Pipeline", pipeline)
        return device

    return make, pipelines


def _colour(seq: int, tr: dai.ImgTransformation) -> dai.ImgFrame:
    rng = np.random.default_rng(seq)
    frame = dai.ImgFrame()
    frame.setCvFrame(rng.integers(0, 256, (H, W, 3), dtype=np.uint8), dai.ImgFrame.Type.BGR888i)
    frame.setTransformation(tr)
    frame.setSequenceNum(seq)
    frame.setTimestamp(datetime.timedelta(seconds=100, milliseconds=33 * seq))
    return frame


def _depth(seq: int) -> dai.ImgFrame:
    frame = dai.ImgFrame()
    frame.setFrame(np.full((H, W), 900 + seq, np.uint16))
    frame.setWidth(W)
    frame.setHeight(H)
    frame.setType(dai.ImgFrame.Type.RAW16)
    frame.setSequenceNum(seq)
    frame.setTimestamp(datetime.timedelta(seconds=100, milliseconds=33 * seq))
    return frame


def _pose(seq: int, bad: bool = False) -> dai.NNData:
    nn = dai.NNData()
    values = np.random.default_rng(seq).uniform(0.2, 0.8, (1, 1, 17, 3)).astype(np.float16)
    nn.addTensor("Identity", values[..., :2] if bad else values)  # 34 values: not MoveNet
    nn.setSequenceNum(seq)
    nn.setTimestamp(datetime.timedelta(seconds=100, milliseconds=33 * seq))
    return nn


def test_rvc2_open_stream_disconnect_and_close(connect, tmp_path: Path) -> None:
    make, pipelines = connect
    device = make(_answers(usb=dai.UsbSpeed.HIGH, ir=[("LM3644", 2, 0x63)]))
    source = OakSource(OakConfig(fps=30.0, ir_laser=600.0))
    path = tmp_path / "oak.mcap"
    seqs = [0, 1, 2, 4, 5]
    written = []
    with pytest.raises(DeviceError) as info:
        with source:
            (pipe,) = pipelines
            names = [c.name for c in device.calls]
            assert names.index("setMaxReconnectionAttempts") < names.index("getConnectedCameraFeatures")
            by_name = {c.name: c for c in device.calls}
            assert by_name["setMaxReconnectionAttempts"].args == (0,)
            assert by_name["setIrLaserDotProjectorIntensity"].args == (0.5,)  # 600 of 1200 mA
            assert [c.args for c in pipe.calls if c.name == "setStopOnDeviceLoss"] == [(True,)]
            meta = source.metadata()
            assert meta["oak_platform"] == "RVC2" and meta["oak_usb_speed"] == "HIGH"
            assert meta["oak_pose_input_type"] == "RGB888p" and meta["oak_ir_laser_ma"] == "600"
            assert any("USB2" in n and "38.4 MB/s" in n for n in source.stats.notes)
            feeds = pipe.feeds
            assert sorted(feeds) == ["inputImage", "inputs['colour']", "inputs['depth']", "inputs['skeleton']"]
            for seq in seqs:
                feeds["inputs['colour']"].send(_colour(seq, _transformation(extra_crop_rows=2)))
                feeds["inputs['depth']"].send(_depth(seq))
                feeds["inputs['skeleton']"].send(_pose(seq, bad=seq == 2))
            with McapRecorder(path) as recorder:
                for frame in source:
                    recorder.write(frame)
                    written.append(frame)
                    if len(written) == len(seqs):
                        # the device fails for good: strict mode stops the pipeline
                        threading.Timer(0.1, pipe.host.stop).start()
    message = str(info.value)
    assert "stream closed" in message and "after 5 frames" in message and "\n" not in message
    assert "1 frames dropped before that, in 1 gaps" in message
    assert [f.seq for f in written] == seqs
    # intrinsics are the frame's own: its crop starts at row 41, the calibration's centred crop at 39.84
    s = W / SENSOR[0]
    top = int((SENSOR[1] * s - H) / 2) + 2
    calib = oak.intrinsics_from_calibration(_calibration(), W, H)
    intr = written[0].intrinsics
    assert intr.distortion_model == "none" and intr.distortion == ()
    assert intr.cy == pytest.approx(K_SENSOR[1][2] * s - top, abs=1e-3)
    assert intr.fx == pytest.approx(calib.fx, rel=1e-6) and intr.cx == pytest.approx(calib.cx, abs=1e-3)
    (note,) = [n for n in source.stats.notes if n.startswith("colour intrinsics")]
    assert f"dcy={intr.cy - calib.cy:+.2f} px" in note and "dcy=-1.16 px" in note
    assert "dfx=+0.00" in note and "distortion none vs rational_polynomial" in note
    # the bad pose message was skipped and counted, the session went on
    assert written[2].joints is None and all(f.joints is not None for i, f in enumerate(written) if i != 2)
    assert source.stats.missing_skeleton == 1
    assert any(n.startswith("skipped 1 bad skeleton message(s)") and "34 values" in n for n in source.stats.notes)
    # middle-of-exposure timestamps (host frames carry exposure 0, so equal to getTimestamp())
    assert written[1].timestamp_ns - written[0].timestamp_ns == 33_000_000
    # closed: pipeline stopped, device closed, once
    assert [c.name for c in pipe.calls].count("stop") == 1
    assert [c.name for c in device.calls].count("close") == 1
    with McapReplay(path) as replay:
        back = list(replay)
    assert [b.seq for b in back] == seqs
    assert back[0].intrinsics == intr


def test_rvc4_open_builds_image_align_and_closes(connect, monkeypatch: pytest.MonkeyPatch) -> None:
    make, pipelines = connect
    device = make(_answers(platform="RVC4"))
    monkeypatch.setattr(oak, "START_TIMEOUT_S", 0.3)
    with OakSource(OakConfig(pose="none", timeout_s=0.2)) as source:
        (pipe,) = pipelines
        assert len(pipe.of(dai.node.ImageAlign)) == 1
        assert source.metadata()["oak_platform"] == "RVC4"
        assert not any("USB" in n for n in source.stats.notes)
        with pytest.raises(
            DeviceError, match=r"^no frame from the OAK device for 0.3 s \(device timeout\) before the first frame$"
        ):
            next(iter(source))
    assert [c.name for c in device.calls].count("close") == 1


def test_ir_laser_without_projector_closes_the_device(connect) -> None:
    make, pipelines = connect
    device = make(_answers(ir=[]))
    with pytest.raises(
        DeviceError, match=r"^ir_laser=100 mA needs an OAK with an IR dot projector \(Pro models\); OAK-D has none$"
    ):
        OakSource(OakConfig(ir_laser=100.0)).open()
    assert device.calls[-1].name == "close"


def test_fps_above_the_sensor_closes_the_device(connect) -> None:
    make, _ = connect
    answers = _answers()
    answers["getConnectedCameraFeatures"] = camera_features(35.0, 99.0)
    device = make(answers)
    with pytest.raises(DeviceError, match="oak fps 60 is above the 35 fps maximum"):
        OakSource(OakConfig(fps=60.0)).open()
    assert device.calls[-1].name == "close"


def test_model_without_input_width_closes_the_device(connect, tmp_path: Path) -> None:
    from .test_oak_pipeline import make_archive

    make, _ = connect
    device = make(_answers(platform="RVC4"))
    archive = make_archive(tmp_path / "flat.tar.xz", "model.dlc", b"\0" * 64, "BGR888i", [1, 3], "NC")
    with pytest.raises(InputError, match="does not declare an image input width"):
        OakSource(OakConfig(pose=str(archive))).open()
    assert device.calls[-1].name == "close"


def test_close_is_bounded_in_time(connect, monkeypatch: pytest.MonkeyPatch) -> None:
    make, _ = connect
    make(_answers(), close_s=2.0)  # a device that hangs on close
    monkeypatch.setattr(oak, "CLOSE_TIMEOUT_S", 0.3)
    source = OakSource(OakConfig(pose="none"))
    source.open()
    start = time.monotonic()
    source.close()
    assert time.monotonic() - start < 1.0
    assert source.stats.notes[-1] == "closing the OAK device did not finish within 0.3 s; abandoned"
    source.close()  # twice is fine


def test_depthai_documents_the_strict_disconnect_semantics() -> None:
    """The disconnect policy relies on these documented semantics of the installed depthai."""
    doc = " ".join(REAL_PIPELINE.setStopOnDeviceLoss.__doc__.split())
    assert (
        "A device is lost for good when its state becomes FAILED - after the reconnection attempts are exhausted" in doc
    )
    assert (
        "To stop as soon as a device disconnects, disable reconnection on the devices (Device::setMaxReconnectionAttempts(0))"
        in doc
    )
    check_call(REAL_DEVICE, "setMaxReconnectionAttempts", (0,), {})


def test_connection_refused_is_one_line(connect, monkeypatch: pytest.MonkeyPatch) -> None:
    make, _ = connect
    make(_answers())

    class Busy:
        getAllAvailableDevices = dai.Device.getAllAvailableDevices

        def __new__(cls, arg):
            raise RuntimeError('Cannot connect to device with name "1.3",\n X_LINK_DEVICE_ALREADY_IN_USE')

    monkeypatch.setattr(dai, "Device", Busy)
    with pytest.raises(
        DeviceError,
        match=r'^cannot connect to OAK device 14442C10D13EABCE00: Cannot connect .* "1.3", X_LINK_DEVICE_ALREADY_IN_USE$',
    ):
        OakSource().open()


def test_depthai_error_while_starting_closes_the_device(connect) -> None:
    make, _ = connect
    answers = _answers()
    answers["readCalibration"] = RuntimeError("EEPROM\nempty")
    device = make(answers)
    with pytest.raises(
        DeviceError, match=r"^OAK device 14442C10D13EABCE00 failed to start the pipeline: EEPROM empty$"
    ):
        OakSource(OakConfig(pose="none")).open()
    assert device.calls[-1].name == "close"


def test_ir_projector_refusal(connect) -> None:
    make, _ = connect
    answers = _answers(ir=[("LM3644", 2, 0x63)])
    answers["setIrLaserDotProjectorIntensity"] = False
    device = make(answers)
    with pytest.raises(DeviceError, match="^OAK-D-PRO refused IR dot-projector current 100 mA$"):
        OakSource(OakConfig(ir_laser=100.0, pose="none")).open()
    assert device.calls[-1].name == "close"


def test_hands_wire_the_landmark_queues_on_rvc2_and_are_refused_on_rvc4(connect) -> None:
    make, pipelines = connect
    make(_answers())
    with OakSource(OakConfig(pose="none", hands="lite")) as source:
        assert source.metadata()["oak_hands"] == "lite"
        tracker = source._converter.hands
        assert tracker.landmark_in.type == "depthai.InputQueue" and tracker.landmark_out.type == "depthai.MessageQueue"
        assert "inputs['palm']" in pipelines[0].feeds
    device = make(_answers(platform="RVC4"))
    with pytest.raises(
        DeviceError,
        match=r"run on RVC2, but the connected OAK is RVC4; use hands=zoo or hands=PALM.tar.xz\+LANDMARKS.tar.xz "
        r"\(NN archives for RVC4\), or hands=none$",
    ):
        OakSource(OakConfig(pose="none", hands="lite")).open()
    assert device.calls[-1].name == "close"


def test_close_reports_depthai_errors(connect) -> None:
    make, pipelines = connect
    answers = _answers()
    answers["close"] = RuntimeError("XLink\nerror")
    make(answers)
    source = OakSource(OakConfig(pose="none"))
    source.open()
    pipelines[0].stop_error = RuntimeError("already stopped")
    source.close()
    assert source.stats.notes[-2:] == [
        "stopping the OAK pipeline failed: already stopped",
        "closing the OAK device failed: XLink error",
    ]


def test_frame_without_a_valid_transformation_is_refused() -> None:
    frame = dai.ImgFrame()
    frame.setCvFrame(np.zeros((H, W, 3), np.uint8), dai.ImgFrame.Type.BGR888i)
    with pytest.raises(DeviceError, match=r"transformation is invalid or not its size \(0x0 for a 640x400 frame\)"):
        oak.intrinsics_from_transformation(frame)
