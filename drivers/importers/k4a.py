"""Import Azure Kinect recordings (``k4arecorder`` Matroska ``.mkv``), depth registered to colour.

The file holds a ``COLOR`` track (MJPG, or raw BGRA/NV12/YUY2), a ``DEPTH`` track (raw
16-bit ``b16g``, millimetres), usually ``IR`` and ``IMU`` tracks, and the factory
calibration as a ``calibration.json`` attachment. PyAV (FFmpeg) demuxes and decodes it; the
Azure Kinect SDK is not needed.

Calibration (:class:`K4aCalibration`)
    ``calibration.json`` stores, per camera, normalised intrinsics of the full sensor
    (``cx, cy, fx, fy, k1..k6, codx, cody, p2, p1``, Brown-Conrady, the OpenCV rational
    model) and the camera's pose ``Rt`` relative to the depth camera (rotation row-major,
    translation in metres). The intrinsics of the recorded mode are obtained as the SDK does
    (``transformation_get_mode_specific_camera_calibration``: scale by the binned sensor
    size, subtract the crop offset, move the origin to the centre of the top-left pixel).
Registration
    :class:`~drivers.importers.registration.DepthRegistration` maps every depth image into
    the colour camera (z-buffered), what the SDK's
    ``k4a_transformation_depth_image_to_color_camera`` produces.

Timestamps are the Matroska block times (ns since the start of the recording); colour and
depth are paired by nearest time within half a colour frame period.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from fractions import Fraction
from pathlib import Path
from typing import Any

import numpy as np

from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame, Intrinsics

from .base import ImportSource, frame_period_ns, merge_paired, pair_nearest
from .registration import DepthRegistration, DepthToColor
from .video import open_container

#: Depth modes by output size: (binned sensor size, crop offset), from the Azure Kinect SDK
#: (src/transformation/mode_specific_calibration.c).
DEPTH_MODES = {
    (640, 576): ((1024, 1024), (192, 180)),  # NFOV unbinned
    (320, 288): ((512, 512), (96, 90)),  # NFOV 2x2 binned
    (512, 512): ((512, 512), (0, 0)),  # WFOV 2x2 binned
    (1024, 1024): ((1024, 1024), (0, 0)),  # WFOV unbinned, passive IR
}


def _mode_intrinsics(
    params: list[float], binned: tuple[float, float], crop: tuple[float, float], size: tuple[int, int]
) -> Intrinsics:
    """Pixel intrinsics (OpenCV convention) of a mode from the normalised JSON parameters."""
    cx, cy, fx, fy, k1, k2, k3, k4, k5, k6, _codx, _cody, p2, p1 = params[:14]
    return Intrinsics(
        size[0],
        size[1],
        fx * binned[0],
        fy * binned[1],
        cx * binned[0] - crop[0] - 0.5,
        cy * binned[1] - crop[1] - 0.5,
        "rational_polynomial",
        (k1, k2, p1, p2, k3, k4, k5, k6),
    )


class K4aCalibration(DepthToColor):
    """Depth and colour camera calibration of one Azure Kinect recording mode.

    A :class:`~drivers.importers.registration.DepthToColor` whose ``depth`` and ``color``
    intrinsics use the ``rational_polynomial`` model ``(k1, k2, p1, p2, k3, k4, k5, k6)``.
    """

    @classmethod
    def from_json(
        cls,
        text: str | bytes,
        depth_size: tuple[int, int],
        color_size: tuple[int, int],
        where: str = "calibration.json",
    ) -> "K4aCalibration":
        """Parse ``calibration.json`` for a depth mode and colour resolution (both ``(width, height)``)."""
        try:
            cameras = json.loads(text)["CalibrationInformation"]["Cameras"]
            by_purpose = {c["Purpose"]: c for c in cameras}
            depth = by_purpose["CALIBRATION_CameraPurposeDepth"]
            color = by_purpose["CALIBRATION_CameraPurposePhotoVideo"]
        except (ValueError, KeyError, TypeError) as exc:
            raise RecordingError(f"{where} is not an Azure Kinect calibration ({type(exc).__name__}: {exc})") from None
        for cam in (depth, color):
            model = cam["Intrinsics"]["ModelType"]
            if model != "CALIBRATION_LensDistortionModelBrownConrady":
                raise RecordingError(f"{where}: lens model {model} is not supported; expected BrownConrady")
        if depth_size not in DEPTH_MODES:
            raise RecordingError(
                f"depth track is {depth_size[0]}x{depth_size[1]}; expected an Azure Kinect depth "
                f"mode size ({', '.join(f'{w}x{h}' for w, h in DEPTH_MODES)})"
            )
        binned, crop = DEPTH_MODES[depth_size]
        k_depth = _mode_intrinsics(depth["Intrinsics"]["ModelParameters"], binned, crop, depth_size)
        params = list(color["Intrinsics"]["ModelParameters"])
        sw, sh = color["SensorWidth"], color["SensorHeight"]
        if sw * 9 == sh * 16:
            # legacy 16:9 calibration: re-express it for the 4:3 sensor (still normalised), as the SDK does
            params[1] = (params[1] * 2304 + 384) / 3072
            params[3] = params[3] * 2304 / 3072
        elif sw * 3 != sh * 4:
            raise RecordingError(f"{where}: colour sensor {sw}x{sh} is neither 16:9 nor 4:3")
        w, h = color_size
        if (w * 3) % 4:
            raise RecordingError(f"colour track {w}x{h} is not an Azure Kinect colour resolution")
        binned_h = w * 3 // 4
        k_color = _mode_intrinsics(params, (w, binned_h), (0, (binned_h - h) / 2), color_size)
        rt_d, rt_c = depth["Rt"], color["Rt"]
        r_d, t_d = np.reshape(rt_d["Rotation"], (3, 3)), np.asarray(rt_d["Translation"]) * 1000.0
        r_c, t_c = np.reshape(rt_c["Rotation"], (3, 3)), np.asarray(rt_c["Translation"]) * 1000.0
        rotation = r_c @ r_d.T
        return cls(k_depth, k_color, rotation, t_c - rotation @ t_d, float(depth.get("MetricRadius", 0.0)))


def _track(container: Any, title: str) -> Any:
    return next((s for s in container.streams.video if s.metadata.get("title", "").upper() == title), None)


def _tracks_found(container: Any) -> str:
    parts = []
    for s in container.streams:
        name = s.metadata.get("title") or s.metadata.get("filename") or "?"
        ctx = getattr(s, "codec_context", None)
        size = f" {ctx.width}x{ctx.height}" if s.type == "video" and ctx is not None else ""
        parts.append(f"{name} ({s.type}{', ' + ctx.name if s.type == 'video' and ctx else ''}{size})")
    return ", ".join(parts) or "no tracks"


class AzureKinectSource(ImportSource):
    """Colour + registered depth frames of an Azure Kinect ``.mkv``.

    Parameters
    ----------
    path : str or Path
    """

    kind = "k4a"

    def __init__(self, path: str | Path) -> None:
        super().__init__(path)
        self._container = None
        self.calibration: K4aCalibration | None = None
        self.registration: DepthRegistration | None = None
        self._color_ns = np.empty(0, np.int64)
        self._pairing = np.empty(0, np.int64)
        self.coverage: list[float] = []

    def open(self) -> None:
        container = open_container(self.path)
        try:
            color, depth = _track(container, "COLOR"), _track(container, "DEPTH")
            missing = [name for name, s in (("COLOR", color), ("DEPTH", depth)) if s is None]
            if missing:
                raise InputError(f"{self.path} has no {' or '.join(missing)} track; found {_tracks_found(container)}")
            attachment = next((a for a in container.streams.attachments if a.name == "calibration.json"), None)
            if attachment is None:
                raise InputError(f"{self.path} has no calibration.json attachment; found {_tracks_found(container)}")
            color_size = (color.codec_context.width, color.codec_context.height)
            depth_size = (depth.codec_context.width, depth.codec_context.height)
            self.calibration = K4aCalibration.from_json(
                attachment.data, depth_size, color_size, f"{self.path}: calibration.json"
            )
            self.registration = DepthRegistration(self.calibration)
            self._container = container
            color_ns, depth_ns = self._scan(color, depth)
            self._color_ns = color_ns
            self._pairing = pair_nearest(color_ns, depth_ns, frame_period_ns(color_ns) // 2)
        except BaseException:
            container.close()
            self._container = None
            raise
        k = self.calibration.color
        paired = int((self._pairing >= 0).sum())
        self.total = len(color_ns)
        self.report.extend(
            [
                f"colour track {color.metadata.get('K4A_COLOR_MODE', color.codec_context.name)} "
                f"{color_size[0]}x{color_size[1]}, depth track {depth.metadata.get('K4A_DEPTH_MODE', '?')} "
                f"{depth_size[0]}x{depth_size[1]} registered to colour (z-buffered)",
                f"{paired} of {len(color_ns)} colour frames paired with depth within half a frame period, "
                f"{len(color_ns) - paired} without depth; {len(depth_ns) - paired} depth frames unpaired",
                f"intrinsics from calibration.json: fx={k.fx:.1f}, fy={k.fy:.1f}, cx={k.cx:.1f}, cy={k.cy:.1f}, "
                "rational_polynomial",
            ]
        )
        others = [
            s.metadata.get("title", f"stream {s.index}")
            for s in self._container.streams
            if s.type in ("video", "subtitle", "audio", "data") and s.index not in (color.index, depth.index)
        ]
        if others:
            self.report.append(f"tracks not imported: {', '.join(others)}")

    def _scan(self, color: Any, depth: Any) -> tuple[np.ndarray, np.ndarray]:
        times: dict[int, list[int]] = {color.index: [], depth.index: []}
        for packet in self._demux(color, depth):
            if packet.size and packet.pts is not None:
                times[packet.stream.index].append(round(packet.pts * Fraction(packet.time_base) * 1_000_000_000))
        c, d = (np.asarray(times[s.index], np.int64) for s in (color, depth))
        if not len(c):
            raise InputError(f"{self.path}: the COLOR track holds no frames")
        for name, t in (("COLOR", c), ("DEPTH", d)):
            if np.any(np.diff(t) <= 0):
                raise RecordingError(f"{self.path}: {name} track timestamps do not increase")
        return c, d

    def close(self) -> None:
        if self._container is not None:
            self._container.close()
            self._container = None
        if self.coverage:
            self.report.append(
                f"registered depth covers {100 * float(np.mean(self.coverage)):.1f} % of the colour pixels "
                f"(mean over {len(self.coverage)} frames)"
            )
            self.coverage = []

    def metadata(self) -> dict[str, str]:
        meta = super().metadata()
        if self._container is not None:
            for key in ("K4A_DEVICE_SERIAL_NUMBER", "K4A_COLOR_FIRMWARE_VERSION", "K4A_DEPTH_FIRMWARE_VERSION"):
                if key in self._container.metadata:
                    meta[key.lower()] = self._container.metadata[key]
        return meta

    def _items(self) -> Iterator[tuple[str, int, Callable[[], Any]]]:
        container = self._container
        container.seek(0)
        color, depth = _track(container, "COLOR"), _track(container, "DEPTH")
        ranks = {color.index: 0, depth.index: 0}
        for packet in self._demux(color, depth):
            if not packet.size or packet.pts is None:
                continue
            index = packet.stream.index
            rank = ranks[index]
            ranks[index] += 1
            kind = "color" if index == color.index else "depth"
            yield kind, rank, lambda packet=packet, kind=kind: self._decode(packet, kind)

    def _demux(self, *streams: Any) -> Iterator[Any]:
        """The packets of ``streams``; a container that cannot be read further is a RecordingError."""
        import av

        try:
            yield from self._container.demux(*streams)
        except av.FFmpegError as exc:
            raise RecordingError(f"{self.path} cannot be read further ({exc}); the file is damaged") from None

    def _decode(self, packet: Any, kind: str) -> np.ndarray:
        import av

        try:
            frames = packet.decode()
        except av.FFmpegError as exc:
            raise RecordingError(
                f"{self.path}: a {kind} packet at pts {packet.pts} cannot be decoded ({exc})"
            ) from None
        if not frames:
            raise RecordingError(f"{self.path}: a {kind} packet at pts {packet.pts} decodes to no frame")
        if kind == "color":
            return frames[0].to_ndarray(format="rgb24")
        raw = frames[0].to_ndarray().astype(np.uint16)
        registered = self.registration(raw)
        self.coverage.append(float(np.count_nonzero(registered)) / registered.size)
        return registered

    def _frames(self) -> Iterator[Frame]:
        k = self.calibration.color
        for i, color, depth in merge_paired(self._items(), self._pairing):
            yield Frame(int(self._color_ns[i]), i, color, depth, k)
