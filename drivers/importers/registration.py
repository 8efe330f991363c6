"""Depth-to-colour registration: a depth camera's image seen from the colour camera.

Every depth pixel is back-projected with the depth camera's undistorted ray (computed once),
moved into the colour camera (``p_c = R p_d + t``), projected with the colour intrinsics and
distortion, and splatted over the colour pixels its footprint covers; where several land on
one pixel the nearest wins (z-buffer). The result is uint16 millimetres (the colour camera's
z) at colour resolution, 0 where no depth lands. Used for Azure Kinect recordings and for
ROS bags whose depth is not aligned to colour.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from fusion_pf.frame import Intrinsics

#: Neighbour spacing, relative to the nominal one, above which two depth pixels are across an edge.
_EDGE = 1.5


@dataclass(frozen=True)
class DepthToColor:
    """Geometry of a depth camera relative to a colour camera.

    Attributes
    ----------
    depth, color : Intrinsics
        Of the depth and colour images (any distortion model of :class:`Intrinsics`).
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
    depth_metric_radius: float = 0.0


class DepthRegistration:
    """Map depth images of the depth camera into the colour camera (z-buffered splatting).

    Parameters
    ----------
    calibration : DepthToColor
    """

    def __init__(self, calibration: DepthToColor) -> None:
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
        px, py, pz = (self.rays[valid] * z[valid, None]).T
        # p_c = R p_d + t written out per component: a (N, 3) @ (3, 3) product goes through BLAS
        # threads that cost more CPU than the arithmetic
        cam = np.column_stack(
            [r[0] * px + r[1] * py + r[2] * pz + t for r, t in zip(c.rotation, c.translation_mm, strict=True)]
        )
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
            spacing = np.stack(
                [
                    _neighbour_max(np.abs(np.diff(grid[:, :, 0], axis=1)), axis=1),
                    _neighbour_max(np.abs(np.diff(grid[:, :, 1], axis=0)), axis=0),
                ],
                axis=-1,
            ).reshape(-1, 2)[idx]
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
