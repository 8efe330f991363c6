"""The shared types: the RGB-D :class:`Frame` every driver yields, the cues' :class:`Measurement`
and the filter's :class:`Estimate` (this module imports only numpy).

Data flows one way: driver -> :class:`Frame` -> cues -> filter -> estimate -> sinks.
A frame is immutable: its arrays are made read-only at construction and its
joints are a read-only mapping. Validation happens here, at the boundary; errors
are :class:`~fusion_pf.errors.InputError` naming the bad value and what was
expected.

Conventions
-----------
* Pixel coordinates ``(u, v)``: ``u`` is the column (x, rightwards), ``v`` the row
  (y, downwards), in full-frame pixels of the colour image, pixel centres at
  integer values.
* Timestamps are integer nanoseconds (``timestamp_ns``), the capture time.
* Depth is aligned to colour: same width, height and intrinsics, uint16
  millimetres, 0 = no depth.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from types import MappingProxyType

import numpy as np

from .errors import InputError

#: Distortion models accepted, with the number of coefficients each takes
#: (``None`` = any number). Names follow foxglove.CameraCalibration / ROS.
DISTORTION_MODELS: dict[str, int | None] = {
    "none": 0,
    "plumb_bob": 5,
    "rational_polynomial": 8,
    "kannala_brandt": 4,
    "opencv": None,
}

#: Joint names the skeleton stream uses (others are allowed and kept).
KNOWN_JOINTS = (
    "right_hand",
    "left_hand",
    "right_wrist",
    "left_wrist",
    "right_elbow",
    "left_elbow",
    "right_shoulder",
    "left_shoulder",
    "head",
    "torso",
)


#: The target whose ground truth is ``Frame.ground_truth`` when a frame has several.
PRIMARY_TARGET = "right_hand"


def _finite(name: str, value: object) -> float:
    try:
        f = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(f):
        raise InputError(f"{name} must be finite, got {value!r}")
    return f


@dataclass(frozen=True, slots=True)
class Intrinsics:
    """Pinhole camera intrinsics of the colour image (and of the aligned depth).

    Parameters
    ----------
    width, height : int
        Image size in pixels (> 0).
    fx, fy : float
        Focal lengths in pixels (> 0).
    cx, cy : float
        Principal point in pixels.
    distortion_model : str
        One of :data:`DISTORTION_MODELS` (``"none"`` for a rectified image).
    distortion : tuple of float
        Distortion coefficients, as many as the model takes.
    """

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    distortion_model: str = "none"
    distortion: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        for name in ("width", "height"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value <= 0:
                raise InputError(f"intrinsics {name} must be a positive int, got {value!r}")
            object.__setattr__(self, name, int(value))
        for name in ("fx", "fy"):
            f = _finite(f"intrinsics {name}", getattr(self, name))
            if f <= 0:
                raise InputError(f"intrinsics {name} must be > 0 pixels, got {f}")
            object.__setattr__(self, name, f)
        for name in ("cx", "cy"):
            object.__setattr__(self, name, _finite(f"intrinsics {name}", getattr(self, name)))
        if self.distortion_model not in DISTORTION_MODELS:
            raise InputError(
                f"distortion_model must be one of {sorted(DISTORTION_MODELS)}, got {self.distortion_model!r}"
            )
        coeffs = tuple(_finite("distortion coefficient", c) for c in self.distortion)
        expected = DISTORTION_MODELS[self.distortion_model]
        if expected is not None and len(coeffs) != expected and any(coeffs):
            raise InputError(
                f"distortion model {self.distortion_model!r} takes {expected} coefficients, got {len(coeffs)}"
            )
        object.__setattr__(self, "distortion", coeffs)

    @property
    def K(self) -> np.ndarray:
        """Camera matrix, shape (3, 3), float64: ``[[fx,0,cx],[0,fy,cy],[0,0,1]]``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width: int, height: int) -> "Intrinsics":
        """Intrinsics of the same camera resized to ``width`` x ``height`` pixels."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            width,
            height,
            self.fx * sx,
            self.fy * sy,
            (self.cx + 0.5) * sx - 0.5,
            (self.cy + 0.5) * sy - 0.5,
            self.distortion_model,
            self.distortion,
        )


@dataclass(frozen=True, slots=True)
class Joint:
    """One skeleton joint projected into the colour image.

    Parameters
    ----------
    u, v : float
        Pixel position in the colour frame.
    depth_mm : float or None
        Depth of the joint in millimetres, None when unknown.
    confidence : float
        The pose network's confidence in [0, 1].
    """

    u: float
    v: float
    depth_mm: float | None
    confidence: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "u", _finite("joint u", self.u))
        object.__setattr__(self, "v", _finite("joint v", self.v))
        if self.depth_mm is not None:
            d = _finite("joint depth_mm", self.depth_mm)
            if d < 0:
                raise InputError(f"joint depth_mm must be >= 0 or None, got {d}")
            object.__setattr__(self, "depth_mm", d)
        c = _finite("joint confidence", self.confidence)
        if not 0.0 <= c <= 1.0:
            raise InputError(f"joint confidence must be in [0, 1], got {c}")
        object.__setattr__(self, "confidence", c)


@dataclass(frozen=True, slots=True)
class PalmPoint:
    """A palm-centre position in colour pixels (ground truth or a reference).

    Parameters
    ----------
    u, v : float
        Palm centre in colour pixels.
    occluded : bool
        True while the palm is in front of / overlapping the body (a
        self-occlusion episode of the synthetic scene).
    """

    u: float
    v: float
    occluded: bool = False

    def __post_init__(self) -> None:
        object.__setattr__(self, "u", _finite("palm u", self.u))
        object.__setattr__(self, "v", _finite("palm v", self.v))


#: Landmarks whose mean is the palm centre (MediaPipe hand order: wrist and the
#: index, middle, ring and little finger MCP joints).
PALM_LANDMARKS = (0, 5, 9, 13, 17)

#: Number of MediaPipe hand landmarks.
HAND_LANDMARKS = 21


@dataclass(frozen=True, eq=False)
class HandObservation:
    """One hand seen by a hand-landmark network (topic ``/hand/landmarks``).

    Parameters
    ----------
    landmarks : ndarray, shape (21, 3), float64
        MediaPipe hand landmarks in MediaPipe order: ``u, v`` in full-frame
        colour pixels, ``z`` relative depth in pixel units (MediaPipe's
        convention: the wrist's depth as origin, smaller = closer to the
        camera), NaN when the network gives none. Stored read-only.
    score : float
        Palm / hand presence in [0, 1].
    handedness : str or None
        ``"left"``, ``"right"`` or None when unknown.
    """

    landmarks: np.ndarray
    score: float
    handedness: str | None = None

    def __post_init__(self) -> None:
        lm = np.array(self.landmarks, dtype=np.float64)
        if lm.shape != (HAND_LANDMARKS, 3):
            raise InputError(f"hand landmarks must have shape (21, 3), got {lm.shape}")
        if not np.all(np.isfinite(lm[:, :2])):
            raise InputError("hand landmark u, v must be finite")
        if np.any(np.isinf(lm[:, 2])):
            raise InputError("hand landmark z must be finite or NaN (unknown)")
        lm.flags.writeable = False
        object.__setattr__(self, "landmarks", lm)
        score = _finite("hand score", self.score)
        if not 0.0 <= score <= 1.0:
            raise InputError(f"hand score must be in [0, 1], got {score}")
        object.__setattr__(self, "score", score)
        if self.handedness not in (None, "left", "right"):
            raise InputError(f"hand handedness must be 'left', 'right' or None, got {self.handedness!r}")

    @property
    def palm(self) -> np.ndarray:
        """Palm centre ``(u, v)``, shape (2,): mean of landmarks 0, 5, 9, 13, 17."""
        return self.landmarks[list(PALM_LANDMARKS), :2].mean(axis=0)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, HandObservation):
            return NotImplemented
        return (
            np.array_equal(self.landmarks, other.landmarks, equal_nan=True)
            and self.score == other.score
            and self.handedness == other.handedness
        )

    __hash__ = None  # type: ignore[assignment]


def _readonly(a: np.ndarray) -> np.ndarray:
    if a.flags.writeable:
        a = a.view()
        a.flags.writeable = False
    return a


@dataclass(frozen=True, eq=False)
class Frame:
    """One synchronised RGB-D frame.

    Parameters
    ----------
    timestamp_ns : int
        Capture time in integer nanoseconds (>= 0).
    seq : int
        Sequence number from the source (>= 0); gaps mean dropped frames.
    color : ndarray, shape (H, W, 3), uint8
        RGB colour image (channel order R, G, B).
    depth : ndarray, shape (H, W), uint16, or None
        Depth in millimetres aligned to ``color``; 0 = invalid. None when the
        source gave no depth for this frame.
    intrinsics : Intrinsics
        Of ``color`` (and ``depth``); its size must equal (W, H).
    joints : mapping of str to Joint, or None
        Skeleton joints present in this frame (a joint may be absent); None when
        the source gave no skeleton message for this frame.
    ground_truth : PalmPoint or None
        True palm centre (synthetic recordings only).
    background : bool
        True for an empty-scene frame (no person), used by background models.
    ground_truths : mapping of str to PalmPoint, or None
        True centre per target (multi-target synthetic recordings, e.g.
        ``right_hand``, ``left_hand``, ``head``); None for single-target
        frames. When given and ``ground_truth`` is None, ``ground_truth``
        becomes the :data:`PRIMARY_TARGET`'s point (if present).
    hands : tuple of HandObservation, or None
        Hands a hand-landmark network found; None when the source has no hand
        stream (no ``/hand/landmarks`` topic), ``()`` when it ran and saw no hand.
    index : int or None
        Position of the frame in its recording (0-based; background frames and
        frames lost to damage counted, so the frames after a lost one keep
        their numbers and the gap shows), when the source knows it; None
        otherwise (the pipeline then numbers frames in arrival order).

    Notes
    -----
    The arrays are not copied: read-only views of the arrays passed in are
    stored, so the caller must not modify them afterwards.
    """

    timestamp_ns: int
    seq: int
    color: np.ndarray
    depth: np.ndarray | None
    intrinsics: Intrinsics
    joints: Mapping[str, Joint] | None = None
    ground_truth: PalmPoint | None = None
    background: bool = False
    ground_truths: Mapping[str, PalmPoint] | None = None
    hands: tuple[HandObservation, ...] | None = None
    index: int | None = None

    def __post_init__(self) -> None:
        for name in ("timestamp_ns", "seq", "index"):
            value = getattr(self, name)
            if value is None and name == "index":
                continue
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise InputError(f"frame {name} must be a non-negative int, got {value!r}")
            object.__setattr__(self, name, int(value))
        color = self.color
        if not isinstance(color, np.ndarray) or color.ndim != 3 or color.shape[2] != 3:
            shape = getattr(color, "shape", type(color).__name__)
            raise InputError(f"color must be an (H, W, 3) array, got shape {shape}")
        if color.dtype != np.uint8:
            raise InputError(f"color must be uint8 RGB, got {color.dtype}")
        h, w = color.shape[:2]
        if h == 0 or w == 0:
            raise InputError(f"color must not be empty, got shape {color.shape}")
        object.__setattr__(self, "color", _readonly(color))
        if self.depth is not None:
            depth = self.depth
            if not isinstance(depth, np.ndarray) or depth.ndim != 2:
                shape = getattr(depth, "shape", type(depth).__name__)
                raise InputError(f"depth must be an (H, W) array, got shape {shape}")
            if depth.dtype != np.uint16:
                raise InputError(f"depth must be uint16 millimetres, got {depth.dtype}")
            if depth.shape != (h, w):
                raise InputError(f"depth must be aligned to color: expected shape {(h, w)}, got {depth.shape}")
            object.__setattr__(self, "depth", _readonly(depth))
        if not isinstance(self.intrinsics, Intrinsics):
            raise InputError(f"intrinsics must be an Intrinsics, got {type(self.intrinsics).__name__}")
        if (self.intrinsics.width, self.intrinsics.height) != (w, h):
            raise InputError(
                f"intrinsics size {self.intrinsics.width}x{self.intrinsics.height} does not match color size {w}x{h}"
            )
        if self.joints is not None:
            joints = dict(self.joints)
            for name, joint in joints.items():
                if not isinstance(name, str) or not name:
                    raise InputError(f"joint names must be non-empty strings, got {name!r}")
                if not isinstance(joint, Joint):
                    raise InputError(f"joint {name!r} must be a Joint, got {type(joint).__name__}")
            object.__setattr__(self, "joints", MappingProxyType(joints))
        if self.hands is not None:
            if isinstance(self.hands, (str, bytes)) or not hasattr(self.hands, "__iter__"):
                raise InputError(
                    f"hands must be a sequence of HandObservation or None, got {type(self.hands).__name__}"
                )
            hands = tuple(self.hands)
            for k, hand in enumerate(hands):
                if not isinstance(hand, HandObservation):
                    raise InputError(f"hands[{k}] must be a HandObservation, got {type(hand).__name__}")
            object.__setattr__(self, "hands", hands)
        if self.ground_truth is not None and not isinstance(self.ground_truth, PalmPoint):
            raise InputError(f"ground_truth must be a PalmPoint or None, got {type(self.ground_truth).__name__}")
        if self.ground_truths is not None:
            truths = dict(self.ground_truths)
            for name, point in truths.items():
                if not isinstance(name, str) or not name:
                    raise InputError(f"ground_truths target names must be non-empty strings, got {name!r}")
                if not isinstance(point, PalmPoint):
                    raise InputError(f"ground_truths[{name!r}] must be a PalmPoint, got {type(point).__name__}")
            object.__setattr__(self, "ground_truths", MappingProxyType(truths))
            if self.ground_truth is None:
                object.__setattr__(self, "ground_truth", truths.get(PRIMARY_TARGET))

    def __reduce__(self):
        # a mappingproxy cannot be pickled: rebuild from the fields (process pools, Dask workers)
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values = {k: dict(v) if isinstance(v, MappingProxyType) else v for k, v in values.items()}
        return (_frame_from_fields, (values,))

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in pixels."""
        return self.intrinsics.width, self.intrinsics.height

    def joint(self, name: str) -> Joint | None:
        """The joint called ``name`` in this frame, or None when absent."""
        if self.joints is None:
            return None
        return self.joints.get(name)


#: The paper's source names (colour cue, depth cue, skeleton joint): the default
#: cues, and CSV columns, JSON keys and likelihood terms of those sources.
SOURCES = ("colour", "depth", "skeleton")


def _frame_from_fields(values: dict) -> Frame:
    return Frame(**values)


@dataclass(frozen=True, slots=True)
class Measurement:
    """A palm-centre measurement from one source.

    Parameters
    ----------
    source : str
        Name of the source, e.g. ``"colour"``, ``"depth"``, ``"skeleton"``, ``"skin_rg"``.
    u, v : float
        Palm centre in full-frame colour pixels.
    quality : float
        How much the cue trusts itself, in [0, 1] (region compactness, joint
        confidence, ...); robust fusion may weight by it.
    extras : mapping
        Cue-specific values (area in px, ROI, ...), JSON-serialisable.
    """

    source: str
    u: float
    v: float
    quality: float = 1.0
    extras: Mapping[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "extras", MappingProxyType(dict(self.extras)))

    def __reduce__(self):
        # a mappingproxy cannot be pickled; rebuild from a plain dict (process pools)
        return (Measurement, (self.source, self.u, self.v, self.quality, dict(self.extras)))

    @property
    def z(self) -> np.ndarray:
        """The measurement as a ``(2,)`` float64 array ``[u, v]``."""
        return np.array([self.u, self.v])


@dataclass(frozen=True, slots=True, eq=False)
class Estimate:
    """The filter's palm estimate for one frame.

    Parameters
    ----------
    timestamp_ns : int
        Time of the frame the estimate is for.
    u, v : float
        Estimated palm centre in colour pixels.
    ess : float
        Effective sample size ``1 / sum(w^2)`` before resampling (N/A -> nan for KF).
    resampled : bool
        Whether the particles were resampled in this step.
    n_particles : int
        Particle count (0 for the Kalman filter).
    cov : ndarray, shape (2, 2)
        Position covariance of the posterior (px^2).
    particles : ndarray, shape (N, 2), or None
        Particle positions after the update (None for the Kalman filter).
    """

    timestamp_ns: int
    u: float
    v: float
    ess: float
    resampled: bool
    n_particles: int
    cov: np.ndarray
    particles: np.ndarray | None = None
