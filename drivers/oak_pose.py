"""Body-pose decoding for the OAK driver: MoveNet keypoints -> colour-frame joints.

Pure numpy, no depthai: the driver hands in the network's output tensor, this
module turns it into :class:`~fusion_pf.frame.Joint` objects.

Decoding (MoveNet single-pose, Lightning 192x192 or Thunder 256x256)
--------------------------------------------------------------------
The network outputs 17 keypoints x (y, x, score), i.e. 51 values (tensor
``Identity``, shape ``(1, 1, 17, 3)``). ``y`` and ``x`` are normalised to the
network input image (0 = top / left edge, 1 = bottom / right edge), ``score``
is in [0, 1]. The network input is made from the colour frame by a centred
letterbox (:class:`Letterbox`: uniform scale to fit, equal padding on both
sides), so a keypoint maps back to colour pixels by undoing the padding and
the scale. Pixel centres are at integer coordinates (``fusion_pf.frame``), so
half a pixel is subtracted from the continuous image coordinate.

Joint names
-----------
MoveNet's 17 names are kept (``left_eye``, ``right_knee``, ...; left/right are
the person's own sides), plus:

* ``head`` = the ``nose`` keypoint;
* ``torso`` = the mean of both shoulders and both hips, confidence = the
  smallest of their four scores;
* ``right_hand`` / ``left_hand``: MoveNet has no palm keypoint, so the palm
  centre is estimated by extending the elbow -> wrist segment beyond the wrist
  by :data:`HAND_EXTENSION` of its length, confidence = min(elbow, wrist).

Every joint keeps the network's score as its confidence (no threshold is
applied; consumers decide). ``depth_mm`` is the median of the non-zero depth
pixels in a (2r+1) x (2r+1) window around the joint (r =
:data:`DEPTH_WINDOW_RADIUS`), None when the window holds no valid depth or the
joint lies outside the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fusion_pf import geometry
from fusion_pf.errors import InputError
from fusion_pf.frame import Joint

#: MoveNet's keypoints, in output order.
MOVENET_KEYPOINTS = (
    "nose",
    "left_eye",
    "right_eye",
    "left_ear",
    "right_ear",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
    "left_hip",
    "right_hip",
    "left_knee",
    "right_knee",
    "left_ankle",
    "right_ankle",
)

#: Fraction of the elbow -> wrist length by which the segment is extended past
#: the wrist to estimate the palm centre. Adult averages: forearm (elbow to
#: wrist joint centres) about 26 cm; palm centre about 6.5 cm past the wrist
#: joint centre (half of an about 11 cm palm plus about 1 cm from the joint
#: centre to the wrist crease); 6.5 / 26 = 0.25. Exact only for a straight
#: wrist and an average hand; the filter's skeleton noise covers the rest.
HAND_EXTENSION = 0.25

#: Half-size of the depth window around a joint: 2 -> a 5 x 5 pixel window.
DEPTH_WINDOW_RADIUS = 2


@dataclass(frozen=True)
class Letterbox:
    """The centred letterbox that maps a colour frame onto the network input.

    Parameters
    ----------
    frame_size : (int, int)
        Colour frame ``(width, height)`` in pixels.
    input_size : (int, int)
        Network input ``(width, height)`` in pixels.

    Attributes
    ----------
    scale : float
        Uniform scale colour -> network input, ``min(in_w / w, in_h / h)``.
    pad_x, pad_y : float
        Padding (network-input pixels) left of and above the scaled image.
    """

    frame_size: tuple[int, int]
    input_size: tuple[int, int]

    def __post_init__(self) -> None:
        for name in ("frame_size", "input_size"):
            size = getattr(self, name)
            if len(size) != 2 or any(
                isinstance(s, bool) or not isinstance(s, (int, np.integer)) or s <= 0 for s in size
            ):
                raise InputError(f"letterbox {name} must be two positive ints (width, height), got {size!r}")

    @property
    def scale(self) -> float:
        (w, h), (iw, ih) = self.frame_size, self.input_size
        return min(iw / w, ih / h)

    @property
    def pad_x(self) -> float:
        return (self.input_size[0] - self.scale * self.frame_size[0]) / 2.0

    @property
    def pad_y(self) -> float:
        return (self.input_size[1] - self.scale * self.frame_size[1]) / 2.0

    def to_frame(self, x_norm: np.ndarray, y_norm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Map normalised network-input coordinates to colour pixels ``(u, v)``.

        Parameters
        ----------
        x_norm, y_norm : ndarray
            Coordinates in [0, 1] of the network input (values outside are
            allowed and map outside the frame).

        Returns
        -------
        u, v : ndarray of float64
            Colour-frame pixel coordinates, pixel centres at integers.
        """
        s = self.scale
        u = (np.asarray(x_norm, dtype=np.float64) * self.input_size[0] - self.pad_x) / s - 0.5
        v = (np.asarray(y_norm, dtype=np.float64) * self.input_size[1] - self.pad_y) / s - 0.5
        return u, v


def decode_movenet(values: np.ndarray, letterbox: Letterbox) -> np.ndarray:
    """Decode a MoveNet output into colour-frame keypoints.

    Parameters
    ----------
    values : ndarray
        The output tensor, any shape holding 51 values in (y, x, score) order
        per keypoint.
    letterbox : Letterbox
        How the network input was made from the colour frame.

    Returns
    -------
    ndarray, shape (17, 3), float64
        Rows in :data:`MOVENET_KEYPOINTS` order, columns ``u, v, score``.

    Raises
    ------
    InputError
        When the tensor does not hold 51 finite values, or a score is outside [0, 1].
    """
    flat = np.asarray(values, dtype=np.float64).reshape(-1)
    if flat.size != 3 * len(MOVENET_KEYPOINTS):
        raise InputError(
            f"pose network output has {flat.size} values; expected 51 (MoveNet: 17 keypoints x (y, x, score))"
        )
    if not np.all(np.isfinite(flat)):
        raise InputError("pose network output must be finite, got NaN or inf")
    kp = flat.reshape(len(MOVENET_KEYPOINTS), 3)
    score = kp[:, 2]
    if score.min() < 0.0 or score.max() > 1.0:
        raise InputError(f"pose keypoint scores must be in [0, 1], got range [{score.min()}, {score.max()}]")
    u, v = letterbox.to_frame(kp[:, 1], kp[:, 0])
    return np.column_stack([u, v, score])


def depth_at(depth: np.ndarray | None, u: float, v: float, radius: int = DEPTH_WINDOW_RADIUS) -> float | None:
    """Median of the non-zero depth pixels around ``(u, v)``.

    Parameters
    ----------
    depth : ndarray, shape (H, W), uint16, or None
        Depth in millimetres, 0 = invalid.
    u, v : float
        Pixel position (centres at integers).
    radius : int
        Window half-size (>= 0); the window is clipped at the image border.

    Returns
    -------
    float or None
        Median depth in millimetres; None when ``depth`` is None, the point is
        outside the image, or no pixel in the window is valid.
    """
    if isinstance(radius, bool) or not isinstance(radius, (int, np.integer)) or radius < 0:
        raise InputError(f"depth window radius must be an int >= 0, got {radius!r}")
    if depth is None:
        return None
    h, w = depth.shape
    if not (0 <= round(u) < w and 0 <= round(v) < h):
        return None
    return geometry.depth_at(depth, u, v, radius=radius)


def joints_from_keypoints(keypoints: np.ndarray, depth: np.ndarray | None) -> dict[str, Joint]:
    """Turn decoded MoveNet keypoints into named joints with depth.

    Parameters
    ----------
    keypoints : ndarray, shape (17, 3)
        ``u, v, score`` rows from :func:`decode_movenet`.
    depth : ndarray, shape (H, W), uint16, or None
        Aligned depth of the same frame.

    Returns
    -------
    dict of str to Joint
        The 17 MoveNet joints plus ``head``, ``torso``, ``right_hand`` and
        ``left_hand`` (see the module docstring).
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    if kp.shape != (len(MOVENET_KEYPOINTS), 3):
        raise InputError(f"keypoints must have shape (17, 3), got {kp.shape}")
    index = {name: i for i, name in enumerate(MOVENET_KEYPOINTS)}

    def make(u: float, v: float, score: float) -> Joint:
        return Joint(u, v, depth_at(depth, u, v), score)

    joints = {name: make(*kp[i]) for name, i in index.items()}
    joints["head"] = joints["nose"]
    trunk = kp[[index[n] for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip")]]
    joints["torso"] = make(trunk[:, 0].mean(), trunk[:, 1].mean(), trunk[:, 2].min())
    for side in ("right", "left"):
        elbow, wrist = kp[index[f"{side}_elbow"]], kp[index[f"{side}_wrist"]]
        palm = wrist[:2] + HAND_EXTENSION * (wrist[:2] - elbow[:2])
        joints[f"{side}_hand"] = make(palm[0], palm[1], min(elbow[2], wrist[2]))
    return joints
