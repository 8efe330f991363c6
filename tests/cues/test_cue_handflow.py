"""Hand landmarks carried by optical flow between landmark-model calls (``fusion_pf.cues.handflow``).

Real OpenCV Lucas-Kanade on a real hand photo (``tests/cues/data/hand``) moved by known transforms;
the expected positions are the transforms applied to MediaPipe's reference landmarks.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from fusion_pf.cues.base import CueContext
from fusion_pf.cues.hand import PALM_JOINTS, HandCue, HandObservation, HandRoi, landmarks_roi
from fusion_pf.cues.handflow import (
    FB_MAX,
    MAX_FRAMES,
    RESIDUAL_MAX,
    FlowStep,
    LandmarkFlow,
    carry,
    fit_similarity,
    grey_crop,
    landmark_call_needed,
    palm_length,
)
from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, Intrinsics

DATA = Path(__file__).parent / "data" / "hand"
SCALE = 0.5  # the photo at half size: small frames, a hand still over 100 px long


@pytest.fixture(scope="module")
def photo() -> tuple[np.ndarray, np.ndarray]:
    """``asl_hand_001.jpg`` at :data:`SCALE` and MediaPipe's reference landmarks ``(21, 3)`` there (z = 0)."""
    bgr = cv2.imread(str(DATA / "asl_hand_001.jpg"))
    rgb = cv2.cvtColor(cv2.resize(bgr, None, fx=SCALE, fy=SCALE, interpolation=cv2.INTER_AREA), cv2.COLOR_BGR2RGB)
    ref = np.array(json.loads((DATA / "expected.json").read_text())["asl_hand_001.jpg"]["hands"][0], dtype=np.float64)
    uv = ref * SCALE - 0.5  # MediaPipe's pixel-edge coordinates -> pixel centres at the new size
    return rgb, np.column_stack((uv, np.zeros(21)))


def _moved(rgb: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``rgb`` moved by the affine map ``m`` (2 x 3, old px -> new px)."""
    h, w = rgb.shape[:2]
    return cv2.warpAffine(rgb, m, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _similarity(angle_deg: float, scale: float, centre: np.ndarray, shift: tuple[float, float]) -> np.ndarray:
    m = cv2.getRotationMatrix2D((float(centre[0]), float(centre[1])), angle_deg, scale)
    m[:, 2] += shift
    return m


def _step(rgb: np.ndarray, new: np.ndarray, lm: np.ndarray) -> FlowStep:
    r = landmarks_roi(lm)
    roi = HandRoi(r.u, r.v, r.size)
    return carry(grey_crop(rgb, roi), grey_crop(new, roi), roi, lm)


def test_similarity_fit_matches_opencv_and_measures_the_non_rigid_part():
    rng = np.random.default_rng(3)
    src = rng.uniform(0, 200, (12, 2))
    m = _similarity(17.0, 1.2, np.array([50.0, 80.0]), (6.0, -9.0))
    dst = src @ m[:, :2].T + m[:, 2]
    a, b, residual = fit_similarity(src, dst)
    ref, _ = cv2.estimateAffinePartial2D(src, dst, method=cv2.LMEDS)  # an independent estimate
    np.testing.assert_allclose([[a.real, -a.imag, b.real], [a.imag, a.real, b.imag]], ref, atol=1e-6)
    assert residual < 1e-9
    noise = rng.normal(0, 1, dst.shape)
    rms = np.sqrt(np.mean(np.sum(noise**2, axis=1)))
    _, _, r = fit_similarity(src, dst + noise)
    # least squares: never above the true transform's residual (the noise), and 4 parameters absorb little of it
    assert 0.5 * rms < r <= rms


@pytest.mark.parametrize(
    ("angle", "scale", "shift"), [(0.0, 1.0, (7.3, -4.6)), (6.0, 1.06, (-3.0, 5.0)), (0.0, 1.0, (-25.0, 18.0))]
)
def test_flow_carries_landmarks_through_a_rigid_motion(photo, angle, scale, shift):
    """The hand moved, turned and grew rigidly: the carried palm lands where the transform puts it, the
    forward-backward errors and the residual are small, and no model call is needed."""
    rgb, lm = photo
    m = _similarity(angle, scale, lm[9, :2], shift)
    step = _step(rgb, _moved(rgb, m), lm)
    truth = lm[:, :2] @ m[:, :2].T + m[:, 2]
    palm = list(PALM_JOINTS)
    assert np.hypot(*(step.landmarks[palm, :2].mean(axis=0) - truth[palm].mean(axis=0))) < 1.0
    assert np.median(np.hypot(*(step.landmarks[:, :2] - truth).T)) < 1.0
    assert np.all(step.fb_error[palm] < 0.5)
    assert step.residual < 0.5 * RESIDUAL_MAX * step.palm_length
    assert not landmark_call_needed(step, 0, 1, size=rgb.shape[1::-1])


def test_a_hand_changing_shape_needs_the_model(photo):
    """A palm foreshortened along the arm (turned out of the image plane) is no similarity: the residual
    exceeds its bound and the model runs; the same frame unmoved passes."""
    rgb, lm = photo
    c = lm[9, :2]
    squash = np.array([[1.0, 0.0, 0.0], [0.0, 0.7, 0.3 * c[1]]])  # 30 % shorter along y about the palm
    step = _step(rgb, _moved(rgb, squash), lm)
    assert step.residual > RESIDUAL_MAX * step.palm_length
    assert landmark_call_needed(step, 0, 1)
    assert not landmark_call_needed(_step(rgb, rgb, lm), 0, 1)


def test_a_hand_that_vanished_needs_the_model(photo):
    """The hand replaced by a flat grey frame: the palm joints do not come back (or come back far off)."""
    rgb, lm = photo
    step = _step(rgb, np.full_like(rgb, 128), lm)
    assert landmark_call_needed(step, 0, 5)


def _flow_step(fb: float = 0.0, residual: float = 0.0, palm: float = 100.0, shift: float = 0.0) -> FlowStep:
    lm = np.zeros((21, 3))
    lm[:, 0] = np.linspace(100, 200, 21) + shift
    lm[:, 1] = 150.0
    return FlowStep(lm, np.full(21, fb), residual, palm)


def test_call_decision():
    """Every rule of landmark_call_needed, each bound in palm lengths (so it scales with the hand)."""
    ok = _flow_step()
    assert not landmark_call_needed(ok, 0, 1)
    assert landmark_call_needed(None, 0, 1)  # nothing carried
    assert landmark_call_needed(ok, 1, 1) and landmark_call_needed(ok, 0, 0)  # at most max_frames in a row
    assert not landmark_call_needed(ok, 2, 3)
    for palm in (50.0, 400.0):  # the same relative errors decide the same way at any hand size
        assert not landmark_call_needed(_flow_step(fb=0.9 * FB_MAX * palm, palm=palm), 0, 1)
        assert landmark_call_needed(_flow_step(fb=1.1 * FB_MAX * palm, palm=palm), 0, 1)
        assert not landmark_call_needed(_flow_step(residual=0.9 * RESIDUAL_MAX * palm, palm=palm), 0, 1)
        assert landmark_call_needed(_flow_step(residual=1.1 * RESIDUAL_MAX * palm, palm=palm), 0, 1)
    fingertip_lost = _flow_step()
    fingertip_lost.fb_error[8] = np.inf  # a fingertip is not a palm joint: it follows the similarity
    assert not landmark_call_needed(fingertip_lost, 0, 1)
    palm_lost = _flow_step()
    palm_lost.fb_error[PALM_JOINTS[2]] = np.inf
    assert landmark_call_needed(palm_lost, 0, 1)
    assert landmark_call_needed(_flow_step(residual=math.nan), 0, 1)
    assert not landmark_call_needed(ok, 0, 1, size=(320, 200))
    assert landmark_call_needed(_flow_step(shift=150.0), 0, 1, size=(320, 200))  # palm carried off the frame


def test_palm_length():
    lm = np.zeros((21, 3))
    lm[9, :2] = (30.0, 40.0)
    assert palm_length(lm) == 50.0
    assert palm_length(np.zeros((21, 3))) == 1.0


def _frame(rgb: np.ndarray, i: int) -> Frame:
    h, w = rgb.shape[:2]
    return Frame(i * 33_000_000, i, rgb, None, Intrinsics(w, h, 500.0, 500.0, w / 2, h / 2))


@pytest.mark.parametrize("max_frames", [1, 3])
def test_hand_cue_skips_the_model_on_carried_frames(photo, max_frames):
    """A hand drifting 2 px per frame: after detection, ``max_frames`` frames carried by the flow (no
    landmark call, mode "flow", the palm following the drift), then one model frame, and so on."""
    rgb, _ = photo
    cue = HandCue(flow=LandmarkFlow(max_frames))
    modes, palms, calls = [], [], []
    for i in range(2 * (max_frames + 1) + 1):
        m = cue.measure(_frame(_moved(rgb, _similarity(0.0, 1.0, np.zeros(2), (2.0 * i, 0.0))), i), CueContext())
        assert m.measurement is not None
        modes.append(m.measurement.extras["mode"])
        palms.append(m.measurement.u)
        calls.append(cue.landmarker.calls["landmark"])
    cycle = ["flow"] * max_frames + ["track"]
    assert modes == ["detect", *cycle, *cycle]
    for i, mode in enumerate(modes[1:], 1):
        assert (calls[i] == calls[i - 1]) == (mode == "flow")
        if mode == "flow":
            assert abs(palms[i] - palms[i - 1] - 2.0) < 0.5
    assert cue.flow is not None and cue.flow.frames == 2 * max_frames
    cue.reset()  # a new track starts with the model
    m = cue.measure(_frame(rgb, 0), CueContext()).measurement
    assert m is not None and m.extras["mode"] == "detect"


def test_without_flow_every_tracked_frame_calls_the_model(photo):
    rgb, _ = photo
    for cue in (HandCue(), HandCue(flow=LandmarkFlow(0))):
        modes = [cue.measure(_frame(rgb, i), CueContext()).measurement.extras["mode"] for i in range(3)]
        assert modes == ["detect", "track", "track"]


def test_flow_option_reaches_the_cue():
    from fusion_pf.cues.registry import CueOptions, build_cues

    assert MAX_FRAMES == 0 and build_cues(["hand"])["hand"].flow is None  # off by default (module doc)
    assert build_cues(["hand"], CueOptions(hand_flow_frames=3))["hand"].flow.max_frames == 3
    assert build_cues(["hand"], CueOptions(hand_flow_frames=0))["hand"].flow is None


@pytest.mark.parametrize("bad", [-1, 1.5, True, "2"])
def test_bad_max_frames(bad):
    with pytest.raises(InputError, match="max_frames"):
        LandmarkFlow(bad)


def test_flow_follows_nothing_without_a_previous_hand(photo):
    rgb, lm = photo
    flow = LandmarkFlow(2)
    assert flow.follow(rgb, None) is None
    prev = HandObservation(lm, 0.9, "right")
    assert flow.follow(rgb, prev) is None  # no crop kept yet
    flow.remember(rgb, prev, carried=False)
    carried = flow.follow(rgb, prev)
    assert carried is not None and carried.score == 0.9 and carried.handedness == "right"
    np.testing.assert_allclose(carried.palm, prev.palm, atol=0.1)


def test_flow_backs_off_after_failing(photo):
    """After a failed flow the next 1, 2, 4, ... frames (at most BACKOFF_MAX) go straight to the model
    without trying the flow (no crop, no Lucas-Kanade); a success resets the wait to one frame."""
    from fusion_pf.cues.hand import BACKOFF_MAX

    rgb, lm = photo
    gone = np.full_like(rgb, 128)  # the hand vanished: the flow fails
    prev = HandObservation(lm, 0.9, "right")
    flow = LandmarkFlow(1)

    def waits_between_tries(n: int) -> list[int]:
        out, wait = [], 0
        while len(out) < n:
            flow.remember(rgb, prev, carried=False)  # the model's frame: the photo
            tries = flow.tries
            assert flow.follow(gone, prev) is None
            if flow.tries == tries:
                wait += 1
            else:
                out.append(wait)
                wait = 0
        return out

    assert waits_between_tries(5) == [0, 1, 2, 4, 4] and BACKOFF_MAX == 4
    flow.remember(rgb, prev, carried=False)
    while flow.follow(rgb, prev) is None:  # wait out the back-off; the photo onto itself is carried
        flow.remember(rgb, prev, carried=False)
    assert waits_between_tries(3) == [0, 1, 2]  # the success reset the wait
