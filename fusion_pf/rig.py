"""Several cameras, one world: camera poses and the frames of one instant (docs/recording-format.md, "Several cameras").

A rig is a set of named cameras, each with a rigid pose in a common ``world``
frame. A pose maps camera coordinates (millimetres; x right, y down, z forward,
the optical frame of :class:`~fusion_pf.frame.Intrinsics`) to world
coordinates: ``p_world = R @ p_camera + t``. ``R`` is the camera's orientation
in the world and ``t`` its optical centre, the same convention as a
``foxglove.FrameTransform`` from ``world`` (parent) to the camera (child).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError
from .frame import Frame

#: Name of the common frame the camera poses refer to.
WORLD_FRAME = "world"
#: How ``fusion-pf merge`` estimates a recording's clock offset to the first: not, first frames, motion energy.
ALIGNMENTS = ("none", "first", "motion")
#: Camera names: a topic segment (letters, digits, ``_``, ``-``), starting with a letter.
CAMERA_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_-]{0,63}")


def check_camera_name(name: object, where: str = "camera name") -> str:
    """Return ``name`` if it is a valid camera name, else raise InputError."""
    if not isinstance(name, str) or CAMERA_NAME.fullmatch(name) is None or name == WORLD_FRAME:
        raise InputError(
            f"{where} must be 1-64 letters, digits, '_' or '-' starting with a letter (not {WORLD_FRAME!r}), "
            f"got {name!r}"
        )
    return name


@dataclass(frozen=True, eq=False)
class CameraPose:
    """Rigid pose of a camera in the world: ``p_world = rotation @ p_camera + translation_mm``.

    Attributes
    ----------
    rotation : ndarray (3, 3) float64
        A rotation matrix (orthonormal, determinant +1, checked to 1e-6).
    translation_mm : ndarray (3,) float64
        The camera's optical centre in world coordinates (mm).
    """

    rotation: np.ndarray
    translation_mm: np.ndarray

    def __post_init__(self) -> None:
        r = np.asarray(self.rotation, dtype=np.float64)
        t = np.asarray(self.translation_mm, dtype=np.float64).reshape(-1)
        if r.shape != (3, 3) or not np.isfinite(r).all():
            raise InputError(f"rotation must be a finite 3x3 matrix, got {np.asarray(self.rotation).tolist()!r}")
        if t.shape != (3,) or not np.isfinite(t).all():
            raise InputError(f"translation must be 3 finite numbers (mm), got {np.asarray(self.translation_mm)!r}")
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise InputError(f"rotation must be a proper rotation matrix (R R^T = I, det +1), got {r.tolist()}")
        r.flags.writeable = t.flags.writeable = False
        object.__setattr__(self, "rotation", r)
        object.__setattr__(self, "translation_mm", t)

    @classmethod
    def identity(cls) -> CameraPose:
        """The pose of a camera whose frame is the world frame."""
        return cls(np.eye(3), np.zeros(3))

    @classmethod
    def from_quaternion(cls, xyzw: object, translation_mm: object) -> CameraPose:
        """A pose from a unit quaternion ``[x, y, z, w]`` (normalised here; norm must be 0.9-1.1)."""
        q = np.asarray(xyzw, dtype=np.float64).reshape(-1)
        norm = float(np.linalg.norm(q)) if q.shape == (4,) else math.nan
        if not 0.9 <= norm <= 1.1:
            raise InputError(f"rotation quaternion must be 4 numbers [x, y, z, w] of norm 1, got {xyzw!r}")
        x, y, z, w = q / norm
        r = np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ]
        )
        return cls(r, np.asarray(translation_mm, dtype=np.float64))

    @classmethod
    def from_rvec(cls, rvec: object, translation_mm: object) -> CameraPose:
        """A pose from a rotation vector (axis times angle, radians; Rodrigues)."""
        v = np.asarray(rvec, dtype=np.float64).reshape(-1)
        if v.shape != (3,) or not np.isfinite(v).all():
            raise InputError(f"rotation vector must be 3 finite numbers (radians), got {rvec!r}")
        angle = float(np.linalg.norm(v))
        if angle < 1e-15:
            return cls(np.eye(3), np.asarray(translation_mm, dtype=np.float64))
        k = v / angle
        kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
        r = np.eye(3) + math.sin(angle) * kx + (1 - math.cos(angle)) * (kx @ kx)
        return cls(r, np.asarray(translation_mm, dtype=np.float64))

    def quaternion(self) -> np.ndarray:
        """The rotation as a unit quaternion ``[x, y, z, w]`` with ``w >= 0``."""
        r = self.rotation
        trace = float(np.trace(r))
        if trace > 0:
            s = 2.0 * math.sqrt(trace + 1.0)
            q = [(r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s, 0.25 * s]
        else:
            i = int(np.argmax(np.diag(r)))
            j, k = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * math.sqrt(max(1.0 + r[i, i] - r[j, j] - r[k, k], 1e-300))
            q = [0.0, 0.0, 0.0, (r[k, j] - r[j, k]) / s]
            q[i] = 0.25 * s
            q[j] = (r[j, i] + r[i, j]) / s
            q[k] = (r[k, i] + r[i, k]) / s
        out = np.asarray(q) / np.linalg.norm(q)
        return -out if out[3] < 0 else out

    def inverse(self) -> CameraPose:
        """The inverse transform (world to camera)."""
        return CameraPose(self.rotation.T, -self.rotation.T @ self.translation_mm)

    def compose(self, other: CameraPose) -> CameraPose:
        """``self ∘ other``: apply ``other`` first, then ``self``."""
        return CameraPose(self.rotation @ other.rotation, self.rotation @ other.translation_mm + self.translation_mm)

    def to_world(self, points_mm: np.ndarray) -> np.ndarray:
        """Camera points ``(..., 3)`` (mm) in world coordinates."""
        return np.asarray(points_mm, dtype=np.float64) @ self.rotation.T + self.translation_mm

    def to_camera(self, points_mm: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` (mm) in this camera's coordinates."""
        return (np.asarray(points_mm, dtype=np.float64) - self.translation_mm) @ self.rotation

    def error_to(self, other: CameraPose) -> tuple[float, float]:
        """``(translation error mm, rotation error degrees)`` between two poses.

        The angle of the relative rotation ``R`` is ``atan2(sin, cos)`` with ``2 sin`` the norm of ``R``'s
        skew part and ``2 cos = trace R - 1``: exact to rounding at every angle, where ``acos`` of the cosine
        alone turns one rounding step of a 1 into 1e-6 degrees.
        """
        dt = float(np.linalg.norm(self.translation_mm - other.translation_mm))
        r = self.rotation.T @ other.rotation
        sin = 0.5 * math.hypot(r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1])
        cos = 0.5 * (float(np.trace(r)) - 1.0)
        return dt, math.degrees(math.atan2(sin, cos))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, CameraPose):
            return NotImplemented
        return bool(
            np.array_equal(self.rotation, other.rotation) and np.array_equal(self.translation_mm, other.translation_mm)
        )

    def __hash__(self) -> int:
        return hash((self.rotation.tobytes(), self.translation_mm.tobytes()))

    def __repr__(self) -> str:
        t = ", ".join(f"{v:.1f}" for v in self.translation_mm)
        q = ", ".join(f"{v:.4f}" for v in self.quaternion())
        return f"CameraPose(t_mm=[{t}], q_xyzw=[{q}])"


@dataclass(frozen=True)
class CameraView:
    """One camera's frame of an instant, with the camera's pose (its intrinsics are ``frame.intrinsics``)."""

    camera: str
    frame: Frame
    pose: CameraPose


@dataclass(frozen=True)
class FrameSet:
    """The frames of one instant, one per camera that has a frame then.

    Attributes
    ----------
    index : int
        Position of the instant in the recording.
    timestamp_ns : int
        The instant (every view's ``frame.timestamp_ns``).
    views : mapping of camera name to CameraView
        In the rig's camera order; a camera without a frame at this instant is absent.
    truth_mm : mapping of target to ndarray (3,), or None
        World ground truth (mm) of synthetic recordings, by target; None when the recording has none.
    background : bool
        True when every view is a background frame (empty scene).
    """

    index: int
    timestamp_ns: int
    views: Mapping[str, CameraView]
    truth_mm: Mapping[str, np.ndarray] | None = None
    background: bool = field(default=False)
