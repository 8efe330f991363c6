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
Registration (:class:`DepthRegistration`)
    Every depth pixel is back-projected with the depth camera's undistorted ray
    (precomputed once), moved into the colour camera (``p_c = R p_d + t``), projected with
    the colour intrinsics and distortion, and splatted over the colour pixels its footprint
    covers; where several land on one pixel the nearest wins (z-buffer). The result is
    uint16 millimetres (the colour camera's z) at colour resolution, 0 where no depth lands.
    This is what the SDK's ``k4a_transformation_depth_image_to_color_camera`` produces.

Timestamps are the Matroska block times (ns since the start of the recording); colour and
depth are paired by nearest time within half a colour frame period.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, Callable, Iterator

import cv2
import numpy as np

from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame, Intrinsics

from .base import ImportSource, frame_period_ns, merge_paired, pair_nearest
from .video import open_container

#: Depth modes by output size: (binned sensor size, crop offset), from the Azure Kinect SDK
#: (src/transformation/mode_specific_calibration.c).
DEPTH_MODES = {
    (640, 576): ((1024, 1024), (192, 180)),  # NFOV unbinned
    (320, 288): ((512, 512), (96, 90)),  # NFOV 2x2 binned
    (512, 512): ((512, 512), (0, 0)),  # WFOV 2x2 binned
    (1024, 1024): ((1024, 1024), (0, 0)),  # WFOV unbinned, passive IR
}
#: Neighbour spacing, relative to the nominal one, above which two depth pixels are across an edge.
_EDGE = 1.5


def _mode_intrinsics(params: list[float], binned: tuple[float, float], crop: tuple[float, float],
                     size: tuple[int, int]) -> Intrinsics:
    """Pixel intrinsics (OpenCV convention) of a mode from the normalised JSON parameters."""
    cx, cy, fx, fy, k1, k2, k3, k4, k5, k6, _codx, _cody, p2, p1 = params[:14]
    return Intrinsics(
        size[0], size[1], fx * binned[0], fy * binned[1], cx * binned[0] - crop[0] - 0.5,
        cy * binned[1] - crop[1] - 0.5, "rational_polynomial", (k1, k2, p1, p2, k3, k4, k5, k6),
    )


@dataclass(frozen=True)
class K4aCalibration:
    """Depth and colour camera calibration of one Azure Kinect recording mode.

    Attributes
    ----------
    depth, color : Intrinsics
        Of the recorded depth and colour modes, ``rational_polynomial`` distortion
        ``(k1, k2, p1, p2, k3, k4, k5, k6)``.
    rotation : ndarray, shape (3, 3)
        Depth camera to colour camera: ``p_c = rotation @ p_d + translation_mm``.
    translation_mm : ndarray, shape (3,)
    depth_metric_radius : float
        Largest undistorted normalised radius where the depth calibration is valid (0 = no limit).
    """

    depth: Intrinsics
    color: Intrinsics
    rotation: np.ndarray
    translation_mm: np.ndarray
    depth_metric_radius: float

    @classmethod
    def from_json(cls, text: str | bytes, depth_size: tuple[int, int], color_size: tuple[int, int],
                  where: str = "calibration.json") -> "K4aCalibration":
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
            raise RecordingError(f"depth track is {depth_size[0]}x{depth_size[1]}; expected an Azure Kinect depth "
                                 f"mode size ({', '.join(f'{w}x{h}' for w, h in DEPTH_MODES)})")
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


class DepthRegistration:
    """Map depth images of the depth camera into the colour camera (z-buffered splatting).

    Parameters
    ----------
    calibration : K4aCalibration
    """

    def __init__(self, calibration: K4aCalibration) -> None:
        self.calibration = c = calibration
        kd = c.depth
        u, v = np.meshgrid(np.arange(kd.width, dtype=np.float64), np.arange(kd.height, dtype=np.float64))
        pixels = np.stack([u.ravel(), v.ravel()], axis=1)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        rays = cv2.undistortPoints(pixels[:, None, :], kd.K, np.asarray(kd.distortion), criteria=criteria)[:, 0, :]
        # keep rays that project back onto their pixel (the iterative inverse converged) and lie within the
        # radius where the depth calibration is valid
        back = self._project(np.column_stack([rays, np.ones(len(rays))]), kd)
        ok = np.all(np.isfinite(back), axis=1) & (np.hypot(*(back - pixels).T) < 0.05)
        if c.depth_metric_radius > 0:
            ok &= np.hypot(rays[:, 0], rays[:, 1]) <= c.depth_metric_radius
        #: (H*W, 3) unit-depth rays of the depth pixels, NaN where invalid
        self.rays = np.where(ok[:, None], np.column_stack([rays, np.ones(len(rays))]), np.nan)
        kc = c.color
        # spacing, in colour pixels, of a depth pixel's neighbours on a fronto-parallel surface: the colour
        # focal length times the angle between neighbouring rays (both lenses' distortion included)
        grid = self.rays.reshape(kd.height, kd.width, 3)[:, :, :2]
        with np.errstate(invalid="ignore"):
            du = np.abs(np.diff(grid[:, :, 0], axis=1)) * kc.fx
            dv = np.abs(np.diff(grid[:, :, 1], axis=0)) * kc.fy
        #: (H*W, 2) nominal spacing in u and v of each depth pixel's projection, colour pixels
        self.nominal = np.stack([_neighbour_max(du, axis=1), _neighbour_max(dv, axis=0)], axis=-1).reshape(-1, 2)
        self.nominal = np.where(np.isfinite(self.nominal), self.nominal, max(kc.fx / kd.fx, kc.fy / kd.fy))

    @staticmethod
    def _project(points: np.ndarray, k: Intrinsics) -> np.ndarray:
        """(N, 3) camera points -> (N, 2) pixels with the camera's distortion (OpenCV rational model)."""
        k1, k2, p1, p2, k3, k4, k5, k6 = (tuple(k.distortion) + (0.0,) * 8)[:8]
        x, y = points[:, 0] / points[:, 2], points[:, 1] / points[:, 2]
        xx, yy, xy = x * x, y * y, x * y
        r2 = xx + yy
        radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
        xd = x * radial + 2 * p1 * xy + p2 * (r2 + 2 * xx)
        yd = y * radial + p1 * (r2 + 2 * yy) + 2 * p2 * xy
        return np.column_stack([k.fx * xd + k.cx, k.fy * yd + k.cy])

    def __call__(self, depth: np.ndarray) -> np.ndarray:
        """Register one depth image.

        Parameters
        ----------
        depth : ndarray, shape (Hd, Wd), uint16
            Millimetres in the depth camera, 0 = no depth.

        Returns
        -------
        ndarray, shape (Hc, Wc), uint16
            Millimetres (colour-camera z) at colour resolution, 0 where no depth lands.
        """
        c, kc = self.calibration, self.calibration.color
        hd, wd = depth.shape
        z = depth.ravel().astype(np.float64)
        valid = (z > 0) & np.isfinite(self.rays[:, 0])
        cam = self.rays[valid] * z[valid, None] @ c.rotation.T + c.translation_mm
        front = cam[:, 2] > 0
        idx = np.flatnonzero(valid)[front]
        cam = cam[front]
        uv = self._project(cam, kc)
        # each point covers the colour pixels up to half-way to its grid neighbours; a spacing beyond
        # _EDGE times the nominal one is a depth edge, where the nominal spacing is used
        grid = np.full((hd * wd, 2), np.nan)
        grid[idx] = uv
        grid = grid.reshape(hd, wd, 2)
        with np.errstate(invalid="ignore"):
            spacing = np.stack([_neighbour_max(np.abs(np.diff(grid[:, :, 0], axis=1)), axis=1),
                                _neighbour_max(np.abs(np.diff(grid[:, :, 1], axis=0)), axis=0)],
                               axis=-1).reshape(-1, 2)[idx]
            nominal = self.nominal[idx]
            half = np.where(np.isfinite(spacing) & (spacing <= _EDGE * nominal), spacing, nominal) / 2
        # the pixels p with lo <= p < uv + half, enumerated without a loop over points
        lo = np.ceil(uv - half).astype(np.int64)
        count = np.maximum(np.ceil(uv + half).astype(np.int64) - lo, 0)
        per_point = count[:, 0] * count[:, 1]
        owner = np.repeat(np.arange(len(uv)), per_point)
        k = np.arange(len(owner)) - np.repeat(np.cumsum(per_point) - per_point, per_point)
        pu = lo[owner, 0] + k % count[owner, 0]
        pv = lo[owner, 1] + k // count[owner, 0]
        inside = (pu >= 0) & (pu < kc.width) & (pv >= 0) & (pv < kc.height)
        flat = pv[inside] * kc.width + pu[inside]
        zmm = np.clip(np.rint(cam[owner[inside], 2]), 1, 65535).astype(np.uint16)
        out = np.full(kc.width * kc.height, 65535, np.uint16)
        np.minimum.at(out, flat, zmm)
        out[out == 65535] = 0
        return out.reshape(kc.height, kc.width)


def _neighbour_max(step: np.ndarray, axis: int) -> np.ndarray:
    """Per grid point, the larger of its two neighbour steps along ``axis`` (``step`` is one shorter)."""
    shape = list(step.shape)
    shape[axis] = 1
    pad = np.full(shape, np.nan)
    return np.fmax(np.concatenate([pad, step], axis=axis), np.concatenate([step, pad], axis=axis))


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
            self.calibration = K4aCalibration.from_json(attachment.data, depth_size, color_size,
                                                        f"{self.path}: calibration.json")
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
        self.report.extend([
            f"colour track {color.metadata.get('K4A_COLOR_MODE', color.codec_context.name)} "
            f"{color_size[0]}x{color_size[1]}, depth track {depth.metadata.get('K4A_DEPTH_MODE', '?')} "
            f"{depth_size[0]}x{depth_size[1]} registered to colour (z-buffered)",
            f"{paired} of {len(color_ns)} colour frames paired with depth within half a frame period, "
            f"{len(color_ns) - paired} without depth; {len(depth_ns) - paired} depth frames unpaired",
            f"intrinsics from calibration.json: fx={k.fx:.1f}, fy={k.fy:.1f}, cx={k.cx:.1f}, cy={k.cy:.1f}, "
            "rational_polynomial",
        ])

    def _scan(self, color: Any, depth: Any) -> tuple[np.ndarray, np.ndarray]:
        times: dict[int, list[int]] = {color.index: [], depth.index: []}
        for packet in self._container.demux(color, depth):
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
        for packet in container.demux(color, depth):
            if not packet.size or packet.pts is None:
                continue
            index = packet.stream.index
            rank = ranks[index]
            ranks[index] += 1
            kind = "color" if index == color.index else "depth"
            yield kind, rank, lambda packet=packet, kind=kind: self._decode(packet, kind)

    def _decode(self, packet: Any, kind: str) -> np.ndarray:
        frames = packet.decode()
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
