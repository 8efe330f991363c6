"""The palm in 3-D: back-projection of colour pixels with aligned depth, and ROI point clouds.

Camera frame (millimetres): ``x`` rightwards, ``y`` downwards, ``z`` forwards
along the optical axis, origin at the colour camera's optical centre (the
OpenCV convention). A pixel ``(u, v)`` with depth ``z`` maps to::

    x = (u' - cx) / fx * z,    y = (v' - cy) / fy * z

where ``(u', v')`` is the undistorted pixel (the pixel itself when the
intrinsics have no distortion). Depth is the uint16 millimetre image aligned to
colour (0 = invalid), so the same intrinsics apply to both.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .errors import InputError
from .frame import Frame, Intrinsics

#: Half-size of the default depth window around the palm (a 7 x 7 window).
DEFAULT_DEPTH_RADIUS = 3


def _normalised(uv: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Normalised image coordinates ``(x/z, y/z)`` of pixels ``uv``, shape (N, 2)."""
    coeffs = np.asarray(intrinsics.distortion, dtype=np.float64)
    if intrinsics.distortion_model == "none" or not coeffs.any():
        xy = np.empty((uv.shape[0], 2))
        # x/z = (u - c_x) / f_x, y/z = (v - c_y) / f_y
        np.subtract(uv[:, 0], intrinsics.cx, out=xy[:, 0])
        np.subtract(uv[:, 1], intrinsics.cy, out=xy[:, 1])
        xy /= (intrinsics.fx, intrinsics.fy)
        return xy
    pts = uv.reshape(-1, 1, 2)
    if intrinsics.distortion_model == "kannala_brandt":
        out = cv2.fisheye.undistortPoints(pts, intrinsics.K, coeffs)
    else:
        out = cv2.undistortPoints(pts, intrinsics.K, coeffs)
    return out.reshape(-1, 2)


def backproject(uv: np.ndarray, z_mm: np.ndarray, intrinsics: Intrinsics) -> np.ndarray:
    """Back-project pixels with known depth to 3-D camera coordinates.

    Parameters
    ----------
    uv : array_like, shape (N, 2)
        Pixel positions ``(u, v)`` in colour pixels.
    z_mm : array_like, shape (N,)
        Depth of each pixel along the optical axis in millimetres (> 0).
    intrinsics : Intrinsics
        Colour-camera intrinsics (distortion is undone when present).

    Returns
    -------
    ndarray, shape (N, 3), float64
        ``[x, y, z]`` in millimetres, camera frame.

    Raises
    ------
    InputError
        When the shapes do not match or a depth is not a positive finite number.
    """
    uv = np.asarray(uv, dtype=np.float64)
    z = np.asarray(z_mm, dtype=np.float64)
    if uv.ndim != 2 or uv.shape[1] != 2:
        raise InputError(f"uv must have shape (N, 2), got {uv.shape}")
    if z.shape != (uv.shape[0],):
        raise InputError(f"z_mm must have shape ({uv.shape[0]},), got {z.shape}")
    if not np.all(np.isfinite(uv)):
        raise InputError("uv must be finite pixel positions, got NaN or inf")
    if z.size and not (np.all(np.isfinite(z)) and z.min() > 0):
        raise InputError(f"z_mm must be positive finite millimetres, got min {z.min()!r}")
    if uv.shape[0] == 0:
        return np.zeros((0, 3))
    xyz = np.empty((uv.shape[0], 3))
    # (x, y, z) = z (x/z, y/z, 1)
    np.multiply(_normalised(uv, intrinsics), z[:, None], out=xyz[:, :2])
    xyz[:, 2] = z
    return xyz


def depth_at(depth: np.ndarray, u: float, v: float, *, radius: int = DEFAULT_DEPTH_RADIUS) -> float | None:
    """Robust depth of the pixel ``(u, v)``: the median of the valid depths around it.

    Parameters
    ----------
    depth : ndarray, shape (H, W), uint16
        Depth in millimetres aligned to colour, 0 = invalid.
    u, v : float
        Pixel position; the window is centred on the nearest pixel and clipped
        to the image.
    radius : int
        Half-size of the square window (``2 * radius + 1`` pixels a side, >= 0).

    Returns
    -------
    float or None
        The median of the non-zero depths in the window in millimetres, None
        when the window is outside the image or holds no valid depth.
    """
    if isinstance(radius, bool) or not isinstance(radius, (int, np.integer)) or radius < 0:
        raise InputError(f"depth window radius must be an int >= 0, got {radius!r}")
    if not (np.isfinite(u) and np.isfinite(v)):
        return None
    h, w = depth.shape
    cu, cv = int(round(u)), int(round(v))
    u0, u1 = max(cu - radius, 0), min(cu + radius + 1, w)
    v0, v1 = max(cv - radius, 0), min(cv + radius + 1, h)
    if u0 >= u1 or v0 >= v1:
        return None
    window = depth[v0:v1, u0:u1]
    valid = np.sort(window[window > 0], axis=None)
    n = valid.size
    if n == 0:
        return None
    # the median: the middle value, or the mean of the two middle values (as np.median)
    return (float(valid[(n - 1) // 2]) + float(valid[n // 2])) / 2.0


def palm_xyz(
    u: float, v: float, depth: np.ndarray | None, intrinsics: Intrinsics, *, radius: int = DEFAULT_DEPTH_RADIUS
) -> np.ndarray | None:
    """The palm centre in 3-D camera coordinates (mm) from its pixel and the depth image.

    Parameters
    ----------
    u, v : float
        Palm centre in colour pixels (e.g. the filter estimate).
    depth : ndarray, shape (H, W), uint16, or None
        Aligned depth in millimetres (0 = invalid); None gives None.
    intrinsics : Intrinsics
        Colour-camera intrinsics.
    radius : int
        Half-size of the depth window (see :func:`depth_at`).

    Returns
    -------
    ndarray, shape (3,), or None
        ``[x, y, z]`` in millimetres, None without a valid depth near the pixel.
    """
    if depth is None:
        return None
    z = depth_at(depth, u, v, radius=radius)
    if z is None:
        return None
    return backproject(np.array([[u, v]]), np.array([z]), intrinsics)[0]


def roi_points(frame: Frame, roi: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """3-D points and colours of every valid depth pixel inside an ROI.

    Parameters
    ----------
    frame : Frame
        A frame with depth.
    roi : tuple of int
        ``(u0, v0, u1, v1)``: the half-open pixel box ``u0 <= u < u1``,
        ``v0 <= v < v1``; clipped to the image.

    Returns
    -------
    points : ndarray, shape (M, 3), float64
        Camera-frame millimetres.
    colours : ndarray, shape (M, 3), float64
        RGB in [0, 1].
    """
    if frame.depth is None:
        raise InputError(f"frame {frame.seq} has no depth, a point cloud needs depth")
    u0, v0, u1, v1 = (int(c) for c in roi)
    w, h = frame.size
    u0, u1 = max(u0, 0), min(u1, w)
    v0, v1 = max(v0, 0), min(v1, h)
    if u0 >= u1 or v0 >= v1:
        return np.zeros((0, 3)), np.zeros((0, 3))
    window = frame.depth[v0:v1, u0:u1]
    vs, us = np.nonzero(window)
    z = window[vs, us].astype(np.float64)
    uv = np.column_stack((us + u0, vs + v0)).astype(np.float64)
    colours = frame.color[vs + v0, us + u0].astype(np.float64) / 255.0
    return backproject(uv, z, frame.intrinsics), colours


def write_roi_ply(
    path: str | Path, frame: Frame, roi: tuple[int, int, int, int], *, palm: np.ndarray | None = None
) -> int:
    """Write the ROI point cloud of a frame as a PLY file (open3d).

    Parameters
    ----------
    path : str or Path
        Output ``.ply`` file.
    frame : Frame
        A frame with depth.
    roi : tuple of int
        ``(u0, v0, u1, v1)`` pixel box, see :func:`roi_points`.
    palm : ndarray, shape (3,), optional
        Palm centre in mm, added as one pure-red point.

    Returns
    -------
    int
        Number of points written.
    """
    import open3d as o3d

    points, colours = roi_points(frame, roi)
    if palm is not None:
        points = np.vstack((points, np.asarray(palm, dtype=np.float64).reshape(1, 3)))
        colours = np.vstack((colours, [[1.0, 0.0, 0.0]]))
    cloud = o3d.geometry.PointCloud()
    cloud.points = o3d.utility.Vector3dVector(points)
    cloud.colors = o3d.utility.Vector3dVector(colours)
    # open3d >= 0.19 stubs say os.PathLike; every supported version (>= 0.18) takes a str
    if not o3d.io.write_point_cloud(str(path), cloud, write_ascii=False):  # type: ignore[arg-type]
        raise OSError(f"open3d could not write {path}")
    return len(points)
