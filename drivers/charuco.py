"""ChArUco calibration boards (OpenCV's aruco module): the board, its image, detection and camera poses.

The board defines the ``world`` frame of a calibrated rig, OpenCV's board
frame: origin at the board's top-left outer corner, x along its rows (to the
right as printed), y down the printed board, z into the board (away from a
camera that sees its face); millimetres.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Intrinsics
from fusion_pf.rig import CameraPose

#: Recording-metadata keys describing the board of a synthetic multi-camera scene.
BOARD_KEYS = ("board_squares", "board_square_mm", "board_marker_mm", "board_dictionary")


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: ``squares`` (columns, rows), square and marker side (mm), ArUco dictionary name."""

    squares: tuple[int, int] = (7, 5)
    square_mm: float = 160.0
    marker_mm: float = 120.0
    dictionary: str = "DICT_4X4_50"

    def __post_init__(self) -> None:
        cols, rows = self.squares
        if not (2 <= cols <= 64 and 2 <= rows <= 64):
            raise InputError(f"board squares must be CxR with both in [2, 64], got {cols}x{rows}")
        if not (0 < self.marker_mm < self.square_mm):
            raise InputError(
                f"board marker side must be positive and smaller than the square ({self.square_mm} mm), "
                f"got {self.marker_mm} mm"
            )
        if not isinstance(getattr(cv2.aruco, self.dictionary, None), int) or not self.dictionary.startswith("DICT_"):
            raise InputError(
                f"board dictionary must be an OpenCV ArUco dictionary such as DICT_4X4_50, got {self.dictionary!r}"
            )

    @property
    def size_mm(self) -> tuple[float, float]:
        """Board width and height (mm)."""
        return self.squares[0] * self.square_mm, self.squares[1] * self.square_mm

    def board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board (lengths in mm)."""
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard(self.squares, self.square_mm, self.marker_mm, dictionary)

    def image(self, px_per_mm: float) -> np.ndarray:
        """The printed board (uint8, 255 white), ``px_per_mm`` pixels per millimetre, no margin."""
        w, h = self.size_mm
        size = (max(int(round(w * px_per_mm)), 8), max(int(round(h * px_per_mm)), 8))
        return self.board().generateImage(size, marginSize=0, borderBits=1)

    def metadata(self) -> dict[str, str]:
        """The :data:`BOARD_KEYS` metadata of this board."""
        return dict(
            zip(
                BOARD_KEYS,
                (f"{self.squares[0]}x{self.squares[1]}", repr(self.square_mm), repr(self.marker_mm), self.dictionary),
                strict=True,
            )
        )

    @classmethod
    def from_metadata(cls, meta: Mapping[str, str]) -> BoardSpec | None:
        """The board a recording's metadata describes, or None when it names none."""
        if not all(key in meta for key in BOARD_KEYS):
            return None
        try:
            cols, rows = (int(v) for v in meta["board_squares"].lower().split("x"))
            return cls(
                (cols, rows), float(meta["board_square_mm"]), float(meta["board_marker_mm"]), meta["board_dictionary"]
            )
        except ValueError:
            raise InputError(
                f"recording metadata describes an unreadable board: {dict((k, meta[k]) for k in BOARD_KEYS)}"
            ) from None


def camera_matrix(k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's camera matrix and distortion coefficients of ``k``."""
    matrix = np.array([[k.fx, 0.0, k.cx], [0.0, k.fy, k.cy], [0.0, 0.0, 1.0]])
    return matrix, np.asarray(k.distortion, dtype=np.float64)


@dataclass(frozen=True)
class Detection:
    """Board corners found in one image: 3-D board points (mm) and their pixels."""

    object_mm: np.ndarray  # (n, 3)
    pixels: np.ndarray  # (n, 2)


def detect(
    spec: BoardSpec, color_rgb: np.ndarray, detector: cv2.aruco.CharucoDetector | None = None
) -> Detection | None:
    """The ChArUco corners visible in an RGB image (sub-pixel, by OpenCV), or None below 6 corners."""
    board = spec.board()
    detector = detector or cv2.aruco.CharucoDetector(board)
    grey = cv2.cvtColor(np.ascontiguousarray(color_rgb), cv2.COLOR_RGB2GRAY)
    corners, ids, _markers, _marker_ids = detector.detectBoard(grey)
    if ids is None or len(ids) < 6:
        return None
    obj, img = board.matchImagePoints(corners, ids)
    return Detection(obj.reshape(-1, 3).astype(np.float64), img.reshape(-1, 2).astype(np.float64))


@dataclass(frozen=True)
class BoardPose:
    """A camera's pose in the board (world) frame from its detections, and the fit's quality."""

    pose: CameraPose
    rms_px: float
    max_px: float
    corners: int
    views: int


def camera_pose(detections: Sequence[Detection], k: Intrinsics) -> BoardPose:
    """The pose of a static camera that saw a static board in ``detections`` (all views in one PnP fit).

    ``cv2.solvePnP`` (iterative Levenberg-Marquardt from the IPPE solution of
    the planar board) over every corner of every view; the reprojection error is
    the RMS and maximum pixel distance between the corners found and the board
    corners projected with the pose.
    """
    obj = np.concatenate([d.object_mm for d in detections])
    img = np.concatenate([d.pixels for d in detections])
    matrix, dist = camera_matrix(k)
    ok, rvec, tvec = cv2.solvePnP(obj, img, matrix, dist, flags=cv2.SOLVEPNP_IPPE)
    if not ok:
        raise InputError(f"the board pose cannot be solved from {len(obj)} corners")
    ok, rvec, tvec = cv2.solvePnP(
        obj, img, matrix, dist, rvec, tvec, useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE
    )
    pose = CameraPose.from_rvec(rvec.reshape(3), tvec.reshape(3)).inverse()
    rms, worst = reprojection_error(detections, k, pose)
    return BoardPose(pose, rms, worst, len(obj), len(detections))


def reprojection_error(detections: Sequence[Detection], k: Intrinsics, pose: CameraPose) -> tuple[float, float]:
    """RMS and largest distance (px) between the corners found and the board corners projected with ``pose``."""
    obj = np.concatenate([d.object_mm for d in detections])
    img = np.concatenate([d.pixels for d in detections])
    matrix, dist = camera_matrix(k)
    to_camera = pose.inverse()
    rvec = cv2.Rodrigues(to_camera.rotation)[0]
    projected, _ = cv2.projectPoints(obj, rvec, to_camera.translation_mm, matrix, dist)
    err = np.linalg.norm(projected.reshape(-1, 2) - img, axis=1)
    return float(math.sqrt(np.mean(err**2))), float(err.max())
