"""The learned hand cue: MediaPipe's models on LiteRT, the decode path, tracking and failure.

Real images with reference landmarks from MediaPipe's own tests are in
``tests/cues/data/hand`` (Apache-2.0, see its README).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from fusion_pf.cues import hand
from fusion_pf.cues.base import Measurement
from fusion_pf.cues.hand import (
    PALM_JOINTS,
    HandLandmarker,
    HandObservation,
    HandRoi,
    PalmDetections,
    box_iou,
    decode_palms,
    hand_measurement,
    landmarks_roi,
    palm_roi,
    ssd_anchors,
    weighted_nms,
)
from fusion_pf.errors import InputError

DATA = Path(__file__).parent / "data" / "hand"
EXPECTED = json.loads((DATA / "expected.json").read_text())


def load(name: str) -> np.ndarray:
    return cv2.cvtColor(cv2.imread(str(DATA / name)), cv2.COLOR_BGR2RGB)


def expected(name: str) -> tuple[list[np.ndarray], float]:
    """MediaPipe's reference landmarks ``(21, 2)`` per hand in fusion-pf pixels, and the tolerance."""
    e = EXPECTED[name]
    return [np.array(h, dtype=np.float64) - 0.5 for h in e["hands"]], float(e["threshold_px"])


@pytest.fixture(scope="module")
def hl() -> HandLandmarker:
    """MediaPipe's own float models (the default landmark model is ``full_mixed``): the same graph as the reference."""
    return HandLandmarker(num_threads=2, landmark_model="full")


# ---------------------------------------------------------------- decode path


def test_anchors_follow_mediapipe_palm_detector_options():
    a = ssd_anchors()
    # palm_detection_cpu.pbtxt: num_boxes 2016 = 24*24*2 (stride 8) + 12*12*6 (strides 16, 16, 16)
    assert a.shape == (2016, 2)
    np.testing.assert_allclose(a[0], [0.5 / 24, 0.5 / 24])
    np.testing.assert_allclose(a[1], a[0])  # two anchors per cell of the stride-8 layer
    np.testing.assert_allclose(a[2], [1.5 / 24, 0.5 / 24])  # row-major: x moves first
    np.testing.assert_allclose(a[1151], [23.5 / 24, 23.5 / 24])
    np.testing.assert_allclose(a[1152:1158], np.tile([0.5 / 12, 0.5 / 12], (6, 1)))
    np.testing.assert_allclose(a[-1], [11.5 / 12, 11.5 / 12])


def test_anchors_equal_depthai_hand_trackers():
    old = np.geterr()
    try:
        mu = pytest.importorskip("depthai_hand_tracker.mediapipe_utils")  # sets np.seterr on import
    finally:
        np.seterr(**old)
    ref = mu.generate_handtracker_anchors(192, 192)
    assert ref.shape == (2016, 4)
    np.testing.assert_array_equal(ref[:, 2:], 1.0)  # fixed anchor size
    np.testing.assert_allclose(ssd_anchors(), ref[:, :2], atol=1e-12)


def test_decode_boxes_keypoints_scores():
    anchors = np.array([[0.25, 0.5], [0.75, 0.5], [0.5, 0.5], [0.1, 0.1]])
    raw = np.zeros((4, 18))
    raw[0, :4] = [19.2, -9.6, 38.4, 19.2]  # centre +0.1, -0.05; size 0.2 x 0.1 (input 192 px)
    raw[0, 4:] = np.arange(14) * 1.92  # keypoint offsets 0.00, 0.01, ..., 0.13 of the input
    raw[1, :4] = [0, 0, 19.2, 19.2]
    raw[2, :4] = [0, 0, -5.0, 10.0]  # negative width: dropped
    logits = np.array([2.0, 3.0, 5.0, -1.0])  # the last is below 0.5
    det = decode_palms(raw, logits[:, None], anchors, input_size=192, min_score=0.5)
    assert len(det) == 2
    np.testing.assert_allclose(det.scores, 1 / (1 + np.exp(-np.array([3.0, 2.0]))))  # best first
    np.testing.assert_allclose(det.boxes[1], [0.35 - 0.1, 0.45 - 0.05, 0.35 + 0.1, 0.45 + 0.05])
    np.testing.assert_allclose(det.boxes[0], [0.7, 0.45, 0.8, 0.55])
    np.testing.assert_allclose(det.keypoints[1], anchors[0] + 0.01 * np.arange(14).reshape(7, 2))
    # score clipping at +-100 keeps huge logits finite
    big = decode_palms(raw[:1], np.array([1e6]), anchors[:1], min_score=0.5)
    assert big.scores[0] == 1.0


def test_box_iou():
    box = np.array([0.0, 0.0, 2.0, 2.0])
    boxes = np.array([[1.0, 1.0, 3.0, 3.0], [0.0, 0.0, 2.0, 2.0], [5.0, 5.0, 6.0, 6.0], [0.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(box_iou(box, boxes), [1 / 7, 1.0, 0.0, 0.0])


def test_weighted_nms_merges_overlaps_and_keeps_separate_boxes():
    boxes = np.array([[0.0, 0.0, 1.0, 1.0], [0.1, 0.0, 1.1, 1.0], [3.0, 3.0, 4.0, 4.0], [0.05, 0.0, 1.05, 1.0]])
    scores = np.array([0.9, 0.6, 0.8, 0.3])
    kps = np.stack([np.full((7, 2), i, dtype=float) for i in range(4)])
    order = np.argsort(-scores)
    det = PalmDetections(scores[order], boxes[order], kps[order])
    out = weighted_nms(det, 0.3)
    assert len(out) == 2
    np.testing.assert_allclose(out.scores, [0.9, 0.8])  # the best score of each group
    w = np.array([0.9, 0.6, 0.3])  # group of boxes 0, 1, 3 (IoU 0.82, 0.90 with box 0)
    np.testing.assert_allclose(out.boxes[0], w @ boxes[[0, 1, 3]] / w.sum())
    np.testing.assert_allclose(out.keypoints[0], np.full((7, 2), (w @ np.array([0.0, 1.0, 3.0])) / w.sum()))
    np.testing.assert_allclose(out.boxes[1], boxes[2])
    assert len(weighted_nms(det, 0.3, max_out=1)) == 1
    # a threshold above every overlap keeps every box
    assert len(weighted_nms(det, 0.95)) == 4
    assert len(weighted_nms(det.take(slice(0, 0)), 0.3)) == 0


def test_palm_roi_rotation_shift_and_size():
    box = np.array([100.0, 200.0, 140.0, 230.0])  # 40 x 30 px
    kps = np.zeros((7, 2))
    kps[0], kps[2] = [120, 230], [120, 200]  # wrist below the middle-finger base: upright
    roi = palm_roi(box, kps)
    assert roi.rotation == pytest.approx(0.0)
    assert roi.size == pytest.approx(40 * 2.6)  # square on the long side, x 2.6
    assert (roi.u, roi.v) == pytest.approx((120.0, 215.0 - 0.5 * 30))  # half a box towards the fingers
    kps[0], kps[2] = [100, 215], [140, 215]  # pointing right
    roi = palm_roi(box, kps)
    assert roi.rotation == pytest.approx(math.pi / 2)
    assert (roi.u, roi.v) == pytest.approx((120.0 + 0.5 * 30, 215.0))  # shifted to the right (fingers)
    top_centre = roi.to_image(np.array([[0.5, 0.0]]))[0]
    assert top_centre[0] > roi.u  # the crop's top is the fingers' side


def test_landmarks_roi_is_rotation_equivariant(hl):
    obs = hl.detect(load("hands.jpg"))[0]
    lm = obs.landmarks[:, :2]
    base = landmarks_roi(lm)
    centre = lm.mean(axis=0)
    for theta in (0.4, -1.2, 2.5):
        c, s = math.cos(theta), math.sin(theta)
        turned = (lm - centre) @ np.array([[c, s], [-s, c]]) + centre  # rotate the hand by theta
        roi = landmarks_roi(turned)
        assert math.remainder(roi.rotation - base.rotation - theta, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
        assert roi.size == pytest.approx(base.size)
        expect = np.array([[c, -s], [s, c]]) @ (np.array([base.u, base.v]) - centre) + centre
        np.testing.assert_allclose([roi.u, roi.v], expect, atol=1e-9)


def test_hand_roi_sample_is_the_rotated_square():
    img = np.zeros((100, 120, 3), np.uint8)
    img[20:40, 60:70] = 255  # a bright bar right of centre
    roi = HandRoi(64.5, 29.5, 40.0, math.pi / 2)  # turned so that image "right" is the crop's "up"
    crop = roi.sample(img, 40, zero_border=True)
    assert crop.shape == (40, 40, 3) and crop.dtype == np.uint8
    # MediaPipe's sampling: crop pixel (row i, column j) samples the frame at pixel-edge coordinates
    # (65, 30) + (20 - i, j - 20), i.e. pixel u = 85 - i, v = 10 + j: the bar's 10 columns
    # u = 60..69 become rows 25..16, its 20 rows v = 20..39 become columns 10..29
    expect = np.zeros((40, 40), np.uint8)
    expect[16:26, 10:30] = 255
    np.testing.assert_array_equal(crop[..., 0], expect)
    np.testing.assert_allclose(roi.corners()[0], roi.to_image(np.array([[0.0, 0.0]]))[0])


# ----------------------------------------------------------- real images


def match(observations: list[HandObservation], refs: list[np.ndarray]) -> list[float]:
    """Largest landmark error of each reference hand against its nearest observation."""
    return [min(float(np.abs(o.landmarks[:, :2] - r).max()) for o in observations) for r in refs]


def test_detect_two_hands_like_mediapipe(hl):
    rgb = load("hands.jpg")
    refs, tol = expected("hands.jpg")
    obs = hl.detect(rgb)
    assert len(obs) == 2
    errors = match(obs, refs)
    assert max(errors) < tol, errors
    for o in obs:
        assert o.landmarks.shape == (21, 3) and o.landmarks.dtype == np.float64
        assert 0.5 <= o.score <= 1.0
        assert o.handedness == "left"  # both are left hands seen from the back (checked by eye)
        np.testing.assert_allclose(o.palm, o.landmarks[list(PALM_JOINTS), :2].mean(axis=0))


def test_track_follows_video_like_mediapipe(hl):
    prev = None
    modes = []
    for i in range(3):
        name = f"asl_hand_{i:03d}.jpg"
        obs, mode = hl.track(load(name), prev)
        modes.append(mode)
        refs, tol = expected(name)
        assert obs is not None
        assert max(match([obs], refs)) < tol
        # the same models and graph as the reference: landmarks agree to a fraction of a pixel on average
        assert np.abs(obs.landmarks[:, :2] - refs[0]).mean() < 1.0
        ref_palm = refs[0][list(PALM_JOINTS)].mean(axis=0)
        assert np.hypot(*(obs.palm - ref_palm)) < 3.0  # palm centres agree to a few px
        prev = obs
    assert modes == ["detect", "track", "track"]


@pytest.mark.parametrize(
    ("model", "least_mean_px", "most_mean_px"),
    [("lite", 0.3, 6.0), ("full_int8", 0.3, 2.5), ("full_mixed", 0.1, 1.0)],
)
def test_cheaper_landmark_models_agree_with_mediapipe_and_the_full_model(hl, model, least_mean_px, most_mean_px):
    other = HandLandmarker(landmark_model=model)
    assert other._landmark.tensor.dtype == (np.float32 if model == "lite" else np.int8)
    for name in ("hands.jpg", "asl_hand_000.jpg", "asl_hand_002.jpg"):
        rgb = load(name)
        refs, tol = expected(name)
        obs = other.detect(rgb)
        # MediaPipe's own test applies its full-model threshold (20 px; 18 px for the ASL frames) here too
        assert len(obs) == len(refs) and max(match(obs, refs)) < tol
        for full in hl.detect(rgb):
            roi = landmarks_roi(full.landmarks)  # the same ROI for both models
            a, b = hl.landmarks(rgb, roi), other.landmarks(rgb, roi)
            assert a is not None and b is not None
            mean = float(np.hypot(*(a.landmarks[:, :2] - b.landmarks[:, :2]).T).mean())
            # another model (not the full one under another name), within a few px of it (full_mixed:
            # 0.30-0.73 px on these hands, full_int8 1.4-1.8 px)
            assert least_mean_px < mean < most_mean_px, (name, mean)
    # no hand: the presence head says so, as the full model's does (an int8 model calibrated on
    # hands alone read every crop of this photo as a hand)
    dino = load("dino_720.jpg")
    h, w = dino.shape[:2]
    for u in np.linspace(0.2, 0.8, 4) * w:
        for v in np.linspace(0.25, 0.75, 3) * h:
            roi = HandRoi(u, v, h / 2)
            assert hl.landmarks(dino, roi) is None and other.landmarks(dino, roi) is None, (u, v)


def test_lite_palm_detector_finds_the_hands_mediapipe_finds():
    lite = HandLandmarker(palm_model="lite")
    for name in ("hands.jpg", "asl_hand_001.jpg"):
        refs, tol = expected(name)
        obs = lite.detect(load(name))
        assert len(obs) == len(refs) and max(match(obs, refs)) < tol


def test_int8_palm_detector_finds_the_palms_the_float_detector_finds(hl):
    """The palm detector quantised to int8 (tools/quantise_hand_model.py --model palm): the same palms
    as the float model (the independent reference) on MediaPipe's test photos, boxes overlapping by
    IoU > 0.9 and keypoints within 8 px on average (5 % of these 165-175 px palm boxes; measured
    4.5-6.2 px), and the hands MediaPipe finds."""
    q = HandLandmarker(palm_model="full_int8")
    assert q._palm.tensor.dtype == np.int8
    for name in ("hands.jpg", "asl_hand_000.jpg", "asl_hand_001.jpg", "asl_hand_002.jpg"):
        rgb = load(name)
        a, b = hl.palms(rgb), q.palms(rgb)
        assert len(a) == len(b) == len(expected(name)[0]), name
        for i in range(len(a)):
            iou = box_iou(a.boxes[i], b.boxes)
            j = int(iou.argmax())
            assert iou[j] > 0.9, (name, iou)
            mean = float(np.hypot(*(a.keypoints[i] - b.keypoints[j]).T).mean())
            assert 0.5 < mean < 8.0, (name, mean)  # another model (not the float one under another name)
            assert b.scores[j] > 0.9
        refs, tol = expected(name)
        obs = q.detect(rgb)
        assert len(obs) == len(refs) and max(match(obs, refs)) < tol


def test_model_variants_are_checked_and_reach_the_landmarker():
    from fusion_pf.cues.registry import CueOptions, build_cues

    with pytest.raises(InputError, match="landmark_model must be one of full, full_mixed, full_int8, lite, got 'tiny'"):
        HandLandmarker(landmark_model="tiny")
    with pytest.raises(InputError, match="palm_model must be one of full, full_int8, lite, got 'tiny'"):
        HandLandmarker(palm_model="tiny")
    with pytest.raises(InputError, match="hand_landmark_model"):
        CueOptions(hand_landmark_model="tiny")
    lm = build_cues(["hand"], CueOptions(hand_landmark_model="lite", hand_palm_model="lite"))["hand"].landmarker
    assert (lm.landmark_model, lm.palm_model) == ("lite", "lite")
    default = build_cues(["hand"])["hand"].landmarker
    # MediaPipe Hands' palm detector; its full landmark model in mixed precision (issue 25)
    assert (default.landmark_model, default.palm_model) == ("full_mixed", "full")


def test_roi_hint_replaces_missing_track(hl):
    rgb = load("asl_hand_001.jpg")
    refs, tol = expected("asl_hand_001.jpg")
    palm = refs[0][list(PALM_JOINTS)].mean(axis=0)
    size = 2.0 * float(np.ptp(refs[0], axis=0).max())
    obs, mode = hl.track(rgb, None, roi_hint=(palm[0], palm[1], size))
    assert mode == "hint" and obs is not None
    assert max(match([obs], refs)) < tol
    # a hint on an empty part of the frame finds nothing there and falls back to detection
    obs, mode = hl.track(rgb, None, roi_hint=(60.0, 60.0, 100.0))
    assert mode == "detect" and obs is not None
    assert max(match([obs], refs)) < tol


def test_lost_track_falls_back_to_detection(hl):
    rgb = load("asl_hand_002.jpg")
    refs, _ = expected("asl_hand_002.jpg")
    good, _ = hl.track(load("asl_hand_001.jpg"), None)
    moved = good.landmarks.copy()
    moved[:, 0] -= moved[:, 0].min() - 5  # the same hand shape at the left edge of the frame, on background
    moved[:, 1] += 1080 - 5 - moved[:, 1].max()
    stale = HandObservation(moved, good.score, good.handedness)
    assert hl.landmarks(rgb, landmarks_roi(stale.landmarks)) is None  # no hand in the stale ROI
    obs, mode = hl.track(rgb, stale)
    assert mode == "detect" and obs is not None
    # re-detected from scratch, compared with MediaPipe's tracked result on this frame
    ref_palm = refs[0][list(PALM_JOINTS)].mean(axis=0)
    assert np.hypot(*(obs.palm - ref_palm)) < 5.0


@pytest.mark.parametrize("angle", [0.0, 1.5, 3.0, 4.5])
def test_recentring_recovers_an_off_centre_roi(hl, angle):
    rgb = load("asl_hand_001.jpg")
    refs, _ = expected("asl_hand_001.jpg")
    _, static_tol = expected("hands.jpg")  # MediaPipe's tolerance for a single image (20 px)
    good = landmarks_roi(refs[0])
    d = 0.25 * good.size  # the hand moved a quarter of the ROI since the last frame
    off = HandRoi(good.u + d * math.cos(angle), good.v + d * math.sin(angle), good.size, good.rotation)
    once = HandLandmarker(recentre=None).landmarks(rgb, off)  # MediaPipe: one call in the stale ROI
    twice = hl.landmarks(rgb, off)
    assert once is not None and twice is not None
    once_err = np.abs(once.landmarks[:, :2] - refs[0]).max()
    twice_err = np.abs(twice.landmarks[:, :2] - refs[0]).max()
    assert twice_err < static_tol
    assert once_err > 2 * twice_err  # the hand cut by the stale ROI is placed much worse


def _moving_hand(step: float, frames: int, *, widen: bool = False) -> list[np.ndarray]:
    """``asl_hand_001.jpg`` with the hand moving ``step`` x its tracking-ROI side to the right per frame
    (from 2 steps left of its place; ``widen``: from its place, the frame widened to keep the hand in it)."""
    rgb = load("asl_hand_001.jpg")
    refs, _ = expected("asl_hand_001.jpg")
    dx = step * landmarks_roi(refs[0]).size
    h, w = rgb.shape[:2]
    first = 0 if widen else 2
    size = (w + round((frames - 1) * dx), h) if widen else (w, h)
    shifts = [np.array([[1.0, 0.0, (k - first) * dx], [0.0, 1.0, 0.0]]) for k in range(frames)]
    return [cv2.warpAffine(rgb, m, size, borderMode=cv2.BORDER_REPLICATE) for m in shifts]


@pytest.mark.parametrize("step", [0.0, 0.15])
def test_one_landmark_call_per_tracked_frame(step):
    """Issue 25: a tracked frame costs exactly one landmark call and no palm detection, counted by the
    cue's landmarker, also when the hand moved 0.15 ROI since the last frame (re-centring at 0.1 used to
    call the model twice there)."""
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.hand import HandCue

    cue = HandCue()
    video = _moving_hand(step, 5)
    first = cue.measure(_frame(video[0]), CueContext()).measurement
    assert first is not None and first.extras["mode"] == "detect"
    before = dict(cue.landmarker.calls)
    for i, rgb in enumerate(video[1:], 1):
        m = cue.measure(_frame(rgb, i), CueContext()).measurement
        assert m is not None and m.extras["mode"] == "track"
        assert cue.landmarker.calls["landmark"] - before["landmark"] == i  # one call per frame
    assert cue.landmarker.calls["palm"] == before["palm"]  # tracked: no palm detection
    # the palm followed the motion
    assert abs(m.u - first.u - 4 * step * landmarks_roi(np.asarray(first.extras["landmarks"])).size) < 15.0


def test_only_a_large_jump_is_recentred():
    """A hand that jumped 0.3 ROI is re-centred in that frame (two calls); without re-centring (MediaPipe)
    every frame is one call."""
    video = _moving_hand(0.3, 2)
    for recentre, calls in ((hand.RECENTRE, 2), (None, 1)):
        lm = HandLandmarker(recentre=recentre)
        prev, _ = lm.track(video[0], None)
        n = lm.calls["landmark"]
        obs, mode = lm.track(video[1], prev)
        assert mode == "track" and lm.calls["landmark"] - n == calls


@pytest.mark.parametrize("lead", [hand.LEAD, 0.0])
def test_led_roi_keeps_a_steadily_moving_hand_to_one_call(lead):
    """Issue 25: a hand moving 0.25 ROI per frame (past ``recentre``) costs two landmark calls on the first
    tracked frame only: from then on the ROI is moved ahead with the last frame's motion and the model runs
    once per frame. MediaPipe's ROI (``lead`` 0) re-centres on every frame."""
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.hand import HandCue

    cue = HandCue(HandLandmarker(lead=lead))
    video = _moving_hand(0.25, 6, widen=True)
    assert cue.measure(_frame(video[0]), CueContext()).measurement.extras["mode"] == "detect"
    calls = []
    for i, rgb in enumerate(video[1:], 1):
        n = cue.landmarker.calls["landmark"]
        m = cue.measure(_frame(rgb, i), CueContext()).measurement
        assert m is not None and m.extras["mode"] == "track"
        calls.append(cue.landmarker.calls["landmark"] - n)
    assert calls == ([2, 1, 1, 1, 1] if lead else [2] * 5)
    refs, _ = expected("asl_hand_001.jpg")
    true_u = refs[0][list(hand.PALM_JOINTS), 0].mean() + 5 * 0.25 * landmarks_roi(refs[0]).size
    assert abs(m.u - true_u) < 10.0  # and the palm is where the hand is


def test_led_roi_moves_ahead_by_the_lead_share_of_a_fast_motion():
    refs, _ = expected("asl_hand_001.jpg")
    last = landmarks_roi(refs[0])
    fast = refs[0][:, :2] + [0.3 * last.size, -0.1 * last.size]
    roi = landmarks_roi(fast)
    led = hand.led_roi(fast, refs[0], 0.5)
    assert (led.u, led.v) == pytest.approx((roi.u + 0.15 * last.size, roi.v - 0.05 * last.size))
    assert (led.size, led.rotation) == pytest.approx((roi.size, roi.rotation)) and last.size == pytest.approx(roi.size)
    assert hand.led_roi(fast, None, 0.5) == roi == hand.led_roi(fast, refs[0], 0.0)
    slow = refs[0][:, :2] + [0.9 * hand.LEAD_FROM * last.size, 0.0]
    assert hand.led_roi(slow, refs[0], 0.5) == landmarks_roi(slow)  # a slow hand: MediaPipe's ROI


def test_hand_threads_option_reaches_the_landmarker():
    from fusion_pf.cues.registry import CueOptions, build_cues

    assert build_cues(["hand"])["hand"].landmarker.num_threads == 1  # default: never waits for a held core
    cue = build_cues(["hand"], CueOptions(hand_threads=2))["hand"]
    assert cue.landmarker.num_threads == 2 and cue.landmarker._landmark.twin is not None


# ------------------------------------------------------------------ failure


def test_no_hand_gives_no_observation(hl):
    dino = load("dino_720.jpg")
    assert hl.detect(dino) == []
    assert hl.track(dino, None) == (None, "detect")
    assert hl.detect(np.full((240, 320, 3), 255, np.uint8)) == []
    assert hl.detect(np.zeros((240, 320, 3), np.uint8)) == []


def test_presence_gate_rejects_false_palms():
    sensitive = HandLandmarker(min_detection=0.2)
    dino = load("dino_720.jpg")
    palms = sensitive.palms(dino)
    assert len(palms) >= 1  # the detector fires on the dinosaur at a low threshold ...
    assert sensitive.detect(dino) == []  # ... and the landmark model's presence score rejects it
    roi = palm_roi(palms.boxes[0], palms.keypoints[0])
    assert sensitive.landmarks(dino, roi) is None


# ----------------------------------------------------------- determinism, API


def test_deterministic_across_runs_and_instances(hl):
    rgb = load("hands.jpg")
    a = [o.landmarks.tobytes() for o in hl.detect(rgb)]
    b = [o.landmarks.tobytes() for o in hl.detect(rgb)]
    c = [o.landmarks.tobytes() for o in HandLandmarker(num_threads=2, landmark_model="full").detect(rgb)]
    assert a == b == c
    p, q = hl.palms(rgb), hl.palms(rgb)
    assert p.boxes.tobytes() == q.boxes.tobytes() and p.scores.tobytes() == q.scores.tobytes()


def test_thread_count_choice_never_changes_a_result(monkeypatch):
    # a 2-thread landmarker also builds 1-thread twins (in the background) and then sends each call to
    # the faster of the two while no other task is runnable
    monkeypatch.setattr(hand, "others_running", lambda: False)
    two, one = HandLandmarker(num_threads=2), HandLandmarker(num_threads=1)
    assert one._palm.twin is None and one._landmark.twin is None
    for m in (two._palm, two._landmark):
        assert m.twin is not None
        m.twin.join()
        assert len(m.interpreters) == 2
    rgb = load("hands.jpg")
    for _ in range(20):  # the twin's first call, then the faster one and exploration calls of the other
        assert [o.landmarks.tobytes() for o in two.detect(rgb)] == [o.landmarks.tobytes() for o in one.detect(rgb)]
    model = two._landmark
    assert min(model.calls) >= 2 and all(t > 0 for t in model.mean_ns)
    model.mean_ns = [5.0e6, 1.0e6]  # the 1-thread twin is faster now (e.g. another process holds a core)
    picks = []
    for _ in range(2 * hand._EXPLORE):
        picks.append(model._pick())
        model.calls[picks[-1]] += 1
    assert picks.count(1) == 2 * hand._EXPLORE - 2 and picks.count(0) == 2  # the slower one is only re-timed
    # another task runnable (or no way to tell): only the twin, the multi-threaded call could stall
    model.mean_ns = [1.0e6, 5.0e6]
    for running in (True, None):
        monkeypatch.setattr(hand, "others_running", lambda running=running: running)
        assert {model._pick() for _ in range(2 * hand._EXPLORE)} == {1}


@pytest.mark.parametrize(
    "text, running",
    [("0.10 0.20 0.30 1/180 4242\n", False), ("3.1 2.0 1.5 3/190 4243\n", True), ("garbage", None), (None, None)],
)
def test_others_running_reads_the_run_queue(tmp_path, text, running):
    path = tmp_path / "loadavg"
    if text is not None:
        path.write_text(text)
    assert hand.others_running(str(path)) is running


def test_measurement_from_observation(hl):
    obs, mode = hl.track(load("asl_hand_000.jpg"), None)
    m = hand_measurement(obs, mode)
    assert isinstance(m, Measurement)
    assert m.source == "hand"
    assert (m.u, m.v) == pytest.approx(tuple(obs.palm))
    assert m.quality == pytest.approx(obs.score)
    assert m.extras["mode"] == "detect" and m.extras["handedness"] in ("left", "right")
    np.testing.assert_allclose(m.extras["landmarks"], obs.landmarks, atol=1e-3)
    json.dumps(dict(m.extras))  # serialisable for the output
    with pytest.raises(InputError, match="mode"):
        hand_measurement(obs, "guess")


@pytest.mark.parametrize(
    "bad",
    [np.zeros((10, 10, 3), np.float32), np.zeros((10, 10), np.uint8), np.zeros((0, 10, 3), np.uint8), "img"],
)
def test_bad_image_is_an_input_error(hl, bad):
    with pytest.raises(InputError, match="uint8 RGB"):
        hl.detect(bad)


@pytest.mark.parametrize("hint", [(1.0, 2.0), (1.0, 2.0, 0.0), (np.nan, 1.0, 50.0), "abc"])
def test_bad_roi_hint(hl, hint):
    with pytest.raises(InputError, match="roi_hint"):
        hl.track(np.zeros((50, 50, 3), np.uint8), None, roi_hint=hint)


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"num_threads": 0}, "num_threads"),
        ({"min_detection": 1.5}, "min_detection"),
        ({"min_presence": -0.1}, "min_presence"),
        ({"max_hands": 0}, "max_hands"),
        ({"nms_iou": 0.0}, "nms_iou"),
        ({"recentre": 0.0}, "recentre"),
        ({"recentre": "yes"}, "recentre"),
        ({"lead": -0.5}, "lead"),
        ({"lead": True}, "lead"),
        ({"min_detection": "high"}, "min_detection"),
    ],
)
def test_bad_options(kwargs, word):
    with pytest.raises(InputError, match=word):
        HandLandmarker(**kwargs)


def test_missing_model_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="palm_detection_full.tflite not found"):
        HandLandmarker(model_dir=tmp_path)


def test_previous_must_be_an_observation(hl):
    with pytest.raises(InputError, match="HandObservation"):
        hl.track(np.zeros((50, 50, 3), np.uint8), np.zeros((21, 3)))
    with pytest.raises(InputError, match="before must be a HandObservation"):
        hl.track(np.zeros((50, 50, 3), np.uint8), None, before=np.zeros((21, 3)))


def test_observation_needs_21_landmarks():
    with pytest.raises(InputError, match=r"\(21, 3\)"):
        HandObservation(np.zeros((20, 3)), 0.9, "left")


# ---------------------------------------------------------------- several hands


def _two_hands() -> np.ndarray:
    """One real hand and its mirror image side by side: a left and a right hand."""
    rgb = load("asl_hand_000.jpg")
    return np.ascontiguousarray(np.concatenate([rgb, rgb[:, ::-1]], axis=1))


def _frame(rgb: np.ndarray, i: int = 0):
    from fusion_pf.frame import Frame, Intrinsics

    h, w = rgb.shape[:2]
    return Frame(i * 33_000_000, i, rgb, None, Intrinsics(w, h, 500.0, 500.0, w / 2, h / 2))


def test_hand_cue_follows_two_hands_with_their_handedness(hl):
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.hand import HandCue

    rgb = _two_hands()
    w = rgb.shape[1] // 2
    cue = HandCue(hl)
    ctx = CueContext(hands=2)
    first = cue.measure(_frame(rgb), ctx).detections
    assert len(first) == 2
    by_side = sorted(first, key=lambda d: d.u)
    assert by_side[0].u < w <= by_side[1].u  # one on each half
    # mirrored hands have opposite handedness; a new hand's label is one frame's vote
    assert {d.label for d in first} == {"right_hand", "left_hand"}
    assert all(d.label_score == pytest.approx(0.9) for d in first)
    assert {d.measurement.extras["mode"] for d in first} == {"detect"}
    # the mirror image of each hand lies where its twin was
    np.testing.assert_allclose(by_side[0].u + by_side[1].u, 2 * w - 1, atol=3.0)
    second = cue.measure(_frame(rgb, 1), ctx).detections
    assert {d.measurement.extras["mode"] for d in second} == {"track"}  # followed, no new detection
    assert sorted(d.label for d in second) == sorted(d.label for d in first)
    # one hand left the frame: one detection, the other hand's label kept
    left_only = rgb.copy()
    left_only[:, w:] = 0
    third = cue.measure(_frame(left_only, 2), ctx).detections
    assert len(third) == 1 and third[0].u < w and third[0].label == by_side[0].label
    # one hand asked for: the single-hand cue, no labels
    assert len(HandCue(hl).measure(_frame(rgb), CueContext()).detections) == 1


def test_prior_off_the_image_gives_no_hint_instead_of_ending_the_run(hl):
    """Issue 24 fuzz: an estimate drifted off a damaged video's frame made an empty window, and the hand
    cue raised 'roi_hint must be finite ... size > 0' (exit 2 mid-run); it now searches without a hint."""
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.hand import HandCue
    from fusion_pf.cues.roi import Roi
    from fusion_pf.frame import Frame, Intrinsics

    image = load("asl_hand_000.jpg")
    h, w = image.shape[:2]
    frame = Frame(0, 0, image, None, Intrinsics(w, h, 500.0, 500.0, w / 2, h / 2))
    ctx = CueContext(roi=Roi(w, h, w, h), background=None, joint="right_hand", prior=(w + 5.0, h + 5.0))
    result = HandCue(hl).measure(frame, ctx)
    assert result.measurement is not None  # found by detection over the frame


def test_prior_window_without_a_hand_is_tried_less_and_less_often(hl):
    """Issue 25: while another cue tracks and the hand cue finds no hand, the landmark model ran in the
    prior's window on every frame (a call per frame on top of palm detection); after each failure the
    window is now skipped for 1, 2, 4, 4 ... frames (hand.Backoff), and a hand that appears is still
    found by the whole-frame palm detection on every frame, and a track just lost still tries it."""
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.hand import BACKOFF_MAX, HandCue
    from fusion_pf.cues.roi import Roi

    image = load("asl_hand_000.jpg")
    h, w = image.shape[:2]
    empty = np.full_like(image, 128)  # no palm anywhere: only the prior's window costs a landmark call
    ctx = CueContext(roi=Roi(w // 4, h // 4, 3 * w // 4, 3 * h // 4), prior=(w / 2, h / 2))
    cue = HandCue(hl)
    tried = []
    for i in range(13):
        n = hl.calls["landmark"]
        assert cue.measure(_frame(empty, i), ctx).measurement is None
        tried.append(hl.calls["landmark"] - n)
    assert BACKOFF_MAX == 4
    assert tried == [1, 0, 1, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0]
    # the hand appears in a skipped frame: palm detection finds it there
    m = cue.measure(_frame(image, 13), ctx).measurement
    assert m is not None and m.extras["mode"] == "detect"
    # found, then lost: the window is tried at once (a track just lost), and the back-off starts again
    n = hl.calls["landmark"]
    assert cue.measure(_frame(empty, 14), ctx).measurement is None
    assert hl.calls["landmark"] - n == 2  # the previous landmarks' ROI, then the prior's window
    tried = []
    for i in range(15, 19):
        n = hl.calls["landmark"]
        cue.measure(_frame(empty, i), ctx)
        tried.append(hl.calls["landmark"] - n)
    assert tried == [0, 1, 0, 0]


def test_idle_search_runs_palm_detection_on_every_other_acquisition_frame(hl):
    """Issue 25: a lost hand cost the palm detector on every acquisition frame (the whole frame searched
    by every cue); after IDLE_AFTER frames without a hand the cue rests on every other one (no model call,
    counted as rested), a hand that appears is found by the next search, and a prior never rests."""
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.hand import IDLE_AFTER, HandCue
    from fusion_pf.cues.roi import Roi, full_roi

    image = load("asl_hand_000.jpg")
    h, w = image.shape[:2]
    empty = np.full_like(image, 128)
    search = CueContext(roi=full_roi(w, h), search=True)
    cue = HandCue(hl)
    ran, rested = [], []
    for i in range(IDLE_AFTER + 6):
        n = hl.calls["palm"]
        result = cue.measure(_frame(empty, i), search)
        ran.append(hl.calls["palm"] - n)
        rested.append(result.rested)
        assert result.measurement is None
    assert IDLE_AFTER == 3
    assert ran == [1, 1, 1, 0, 1, 0, 1, 0, 1]
    assert rested == [not r for r in ran]
    # the hand appears on a resting frame: found on the next one, then followed (never resting while found)
    assert cue.measure(_frame(image, 9), search).rested
    m = cue.measure(_frame(image, 10), search).measurement
    assert m is not None and m.extras["mode"] == "detect"
    assert cue.measure(_frame(image, 11), search).measurement is not None
    # lost again: IDLE_AFTER searches before the first rest
    assert [cue.measure(_frame(empty, 12 + i), search).rested for i in range(5)] == [False] * 3 + [True, False]
    # with a prior (another cue tracks): no rest, whatever the misses
    ctx = CueContext(roi=Roi(w // 4, h // 4, 3 * w // 4, 3 * h // 4), prior=(w / 2, h / 2))
    assert not any(cue.measure(_frame(empty, 17 + i), ctx).rested for i in range(4))
    # a reset (a new stream) searches at once
    cue.reset()
    assert not cue.measure(_frame(empty, 21), search).rested


def test_acquisition_frames_detect_palms_with_the_search_model():
    """Issue 25: with --hand-search-palm-model full_int8 an acquisition frame's whole-frame palm detection
    runs the int8 detector (3.8 instead of 4.9 ms CPU at 1280 x 720), loaded on the first such frame;
    tracked frames keep the float one. By default both are the palm model."""
    from fusion_pf.cues.base import CueContext
    from fusion_pf.cues.hand import HandCue
    from fusion_pf.cues.roi import Roi, full_roi

    hl = HandLandmarker(landmark_model="full", search_palm_model="full_int8")
    assert hl.palm_model == "full" and hl.search_palm_model == "full_int8"
    image = load("asl_hand_000.jpg")
    h, w = image.shape[:2]
    n = dict(hl.calls)
    tracked, searched = hl.palms(image), hl.palms(image, search=True)
    assert hl.calls["palm"] - n["palm"] == 2 and hl.calls["search_palm"] - n["search_palm"] == 1
    assert len(tracked) and len(searched)  # the same palm, by a different model
    assert np.abs(tracked.boxes[0] - searched.boxes[0]).max() < 0.05 * max(w, h)
    assert not np.array_equal(tracked.scores, searched.scores)
    # through the cue: a search frame uses it, a frame with a prior (whole-frame detection after the window) not
    cue = HandCue(hl)
    n = dict(hl.calls)
    assert cue.measure(_frame(image, 0), CueContext(roi=full_roi(w, h), search=True)).measurement is not None
    assert hl.calls["search_palm"] - n["search_palm"] == 1
    cue.reset()
    empty = np.full_like(image, 128)
    n = dict(hl.calls)
    ctx = CueContext(roi=Roi(w // 4, h // 4, 3 * w // 4, 3 * h // 4), prior=(w / 2, h / 2))
    assert cue.measure(_frame(empty, 1), ctx).measurement is None
    assert hl.calls["palm"] - n["palm"] == 1 and hl.calls["search_palm"] == n["search_palm"]
    assert HandLandmarker().search_palm_model == "full"
    assert HandLandmarker(palm_model="lite").search_palm_model == "lite"
    with pytest.raises(InputError, match="search_palm_model must be one of"):
        HandLandmarker(search_palm_model="huge")
