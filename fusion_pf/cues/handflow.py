"""Hand landmarks carried by sparse optical flow between landmark-model calls.

The landmark model (:class:`~fusion_pf.cues.hand.HandLandmarker`) is the hand
cue's cost on a tracked frame. When the hand only moved since the last frame,
the previous landmarks carried by optical flow are as good as a new call; when
it changed pose, the flow cannot say where the fingers went and the model has
to look again. :class:`LandmarkFlow` does the carrying, one frame at a time:

1. both frames are resampled to the same small grey crop (:data:`FLOW_SIDE`
   px square, axis-aligned, centred and sized as the next tracking ROI,
   :func:`~fusion_pf.cues.hand.landmarks_roi`), so the flow costs the same at
   any image size and a hand of any size spans the same crop pixels;
2. pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``) moves the 21 previous
   landmarks into the new frame and back again: a point's forward-backward
   error (Kalal, Mikolajczyk and Matas, "Forward-backward error: automatic
   detection of tracking failures", ICPR 2010) bounds how far off it is;
3. one similarity transform (rotation, scale, shift; least squares) is fitted
   to the joints that set the palm centre and the next ROI (wrist, thumb base,
   finger bases and middle joints, :data:`~fusion_pf.cues.hand.ROI_JOINTS`)
   that came back; its residual is the part of their motion that is not rigid:
   fingers that bent or spread, a palm turning out of the image plane;
4. :func:`landmark_call_needed` decides: the model runs unless every palm
   joint came back (forward-backward error within :data:`FB_MAX` palm
   lengths), the motion is rigid (residual within :data:`RESIDUAL_MAX` palm
   lengths) and fewer than ``max_frames`` frames in a row were carried.

Both bounds are in palm lengths (wrist to middle-finger base), so they hold at
any distance and image size. They are a twentieth of the palm, the landmark
model's own palm error on real footage (10 px RMSE on palms of about 200 px on
the hand-graph-cnn development frames): a carried palm joint may not be
further off than the model is. Landmarks that did not come back follow the
similarity; the palm centre is the mean of the five carried palm joints, as on
a model frame.

Measured on those development frames (1280 x 720; the hand moves up to 158 px
and re-poses between most frames): with ``max_frames`` = 1 the flow is tried
on 34 of the 105 tracked frames and carries 11 (8 of 105 on the 256 x 256
crops). Hand cue alone, with and without the flow interleaved frame by frame
in one process (3 passes, load average 7-8 on 2 cores): a carried frame costs
0.95 ms CPU, a model frame 5.4-5.6 ms, and a failed try adds 0.45 ms to its
model frame; per tracked frame the mean CPU falls 4.5 %, but the median rises
3 % and the 95th percentile 12 % (the failed tries lengthen the model frames'
tail). So the default is off (:data:`MAX_FRAMES` = 0). Fused palm RMSE
(``track``): 10.34 px with ``max_frames`` = 1, 10.42 px with 2, 10.37 px
without the flow; crops 5.90 / 5.92 / 5.92 px. The flow pays off where the
hand moves rigidly for stretches of frames (held, or moving without
re-posing): ``max_frames`` = k lets up to k of every k + 1 frames skip the
model.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError
from ..frame import HandObservation
from .hand import PALM_JOINTS, ROI_JOINTS, Backoff, HandRoi, landmarks_roi

#: Side of the grey crop the flow runs on, px.
FLOW_SIDE = 128
#: Lucas-Kanade window (crop px) and pyramid levels above the crop: a point may move about
#: 2^3 x 7 = 56 crop px, i.e. 0.44 of the ROI side (0.9 of the hand) between frames.
FLOW_WINDOW = 15
FLOW_LEVELS = 3
#: Largest forward-backward error of a palm joint, palm lengths (:func:`landmark_call_needed`).
FB_MAX = 0.05
#: Largest RMS residual of the ROI joints' flow about one similarity, palm lengths.
RESIDUAL_MAX = 0.05
#: Default of ``max_frames`` (:class:`LandmarkFlow`, ``--hand-flow-frames``): off (module doc).
MAX_FRAMES = 0
_CRITERIA = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)


@dataclass(frozen=True, slots=True)
class FlowStep:
    """The previous landmarks carried into the new frame.

    Parameters
    ----------
    landmarks : ndarray, shape (21, 3)
        Carried landmarks, frame pixels (``z`` scaled with the similarity).
    fb_error : ndarray, shape (21,)
        Forward-backward error per landmark, frame pixels; inf where the flow lost it.
    residual : float
        RMS distance from the fitted similarity of the carried ROI joints that came back, frame pixels.
    palm_length : float
        Wrist to middle-finger base of the previous landmarks, frame pixels.
    """

    landmarks: np.ndarray
    fb_error: np.ndarray
    residual: float
    palm_length: float


def palm_length(landmarks: np.ndarray) -> float:
    """Wrist (0) to middle-finger base (9), pixels, at least 1."""
    lm = np.asarray(landmarks, dtype=np.float64)
    return max(float(np.hypot(*(lm[9, :2] - lm[0, :2]))), 1.0)


def grey_crop(rgb: np.ndarray, roi: HandRoi, side: int = FLOW_SIDE) -> np.ndarray:
    """``roi`` of ``rgb`` resampled to a ``(side, side)`` uint8 grey image (bilinear, replicated border)."""
    crop = cv2.warpAffine(
        rgb,
        roi.matrix(side),
        (side, side),
        flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
        borderMode=cv2.BORDER_REPLICATE,
    )
    return cv2.cvtColor(crop, cv2.COLOR_RGB2GRAY)


def fit_similarity(src: np.ndarray, dst: np.ndarray) -> tuple[complex, complex, float]:
    """Least-squares similarity ``dst ~ a * src + b`` of points ``(n, 2)`` (n >= 2) as complex numbers.

    Returns ``a`` (scale and rotation), ``b`` (shift) and the RMS residual.
    """
    z = src[:, 0] + 1j * src[:, 1]
    w = dst[:, 0] + 1j * dst[:, 1]
    zc, wc = z - z.mean(), w - w.mean()
    den = float(np.sum(np.abs(zc) ** 2))
    a = complex(np.sum(wc * np.conj(zc)) / den) if den > 0 else 1.0 + 0j
    b = complex(w.mean() - a * z.mean())
    residual = float(np.sqrt(np.mean(np.abs(w - (a * z + b)) ** 2)))
    return a, b, residual


def _lucas_kanade(template: np.ndarray, grey: np.ndarray, p0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points ``(n, 2)`` float32 (crop px) moved from ``template`` to ``grey``, and their forward-backward
    errors (crop px; inf where either pass lost the point)."""
    win = (FLOW_WINDOW, FLOW_WINDOW)
    pts = np.ascontiguousarray(p0, dtype=np.float32).reshape(-1, 1, 2)
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(
        template, grey, pts, np.empty_like(pts), winSize=win, maxLevel=FLOW_LEVELS, criteria=_CRITERIA
    )
    back, st2, _ = cv2.calcOpticalFlowPyrLK(
        grey, template, p1, np.empty_like(pts), winSize=win, maxLevel=FLOW_LEVELS, criteria=_CRITERIA
    )
    ok = (st1.reshape(-1) == 1) & (st2.reshape(-1) == 1)
    return p1.reshape(-1, 2), np.where(ok, np.hypot(*(back - pts).reshape(-1, 2).T), np.inf)


def carry(
    template: np.ndarray, grey: np.ndarray, roi: HandRoi, landmarks: np.ndarray, *, fb_max: float = FB_MAX
) -> FlowStep:
    """Carry ``landmarks`` ``(21, 3)`` (frame px) from ``template`` to ``grey``, both crops of ``roi``.

    Lucas-Kanade forward and back in the crops (:data:`FLOW_WINDOW`,
    :data:`FLOW_LEVELS`), the palm joints first: when one of them is lost or
    its forward-backward error exceeds ``fb_max`` palm lengths, the other
    landmarks are not tracked (their error is inf and the residual inf: the
    model must run). Otherwise the similarity is fitted to the ROI joints that
    came back and moves the landmarks that did not.
    """
    side = template.shape[0]
    m = roi.matrix(side)  # crop px -> frame px
    inv = cv2.invertAffineTransform(m)
    lm = np.asarray(landmarks, dtype=np.float64)
    palm = palm_length(lm)
    p0 = (lm[:, :2] @ inv[:, :2].T + inv[:, 2]).astype(np.float32)
    k = roi.size / side  # frame px per crop px
    moved = lm[:, :2].copy()
    fb = np.full(lm.shape[0], np.inf)
    first = list(PALM_JOINTS)
    rest = [i for i in range(lm.shape[0]) if i not in PALM_JOINTS]
    for stage in (first, rest):
        p1, err = _lucas_kanade(template, grey, p0[stage])
        moved[stage] = p1.astype(np.float64) @ m[:, :2].T + m[:, 2]
        fb[stage] = err * k
        if not np.all(fb[first] <= fb_max * palm):
            return FlowStep(np.column_stack((moved, lm[:, 2])), fb, np.inf, palm)
    good = np.isfinite(fb)
    fit = good.copy()
    fit[np.setdiff1d(np.arange(lm.shape[0]), ROI_JOINTS)] = False
    a, b, residual = fit_similarity(lm[fit, :2], moved[fit])  # the 5 palm joints at least
    z = lm[:, 0] + 1j * lm[:, 1]
    rigid = a * z + b
    uv = np.where(good[:, None], moved, np.column_stack((rigid.real, rigid.imag)))
    return FlowStep(np.column_stack((uv, lm[:, 2] * abs(a))), fb, residual, palm)


def landmark_call_needed(
    step: FlowStep | None,
    carried: int,
    max_frames: int,
    *,
    fb_max: float = FB_MAX,
    residual_max: float = RESIDUAL_MAX,
    size: tuple[int, int] | None = None,
) -> bool:
    """Whether this frame needs the landmark model rather than the carried landmarks ``step``.

    Parameters
    ----------
    step : FlowStep or None
        The flow's result (None: there was nothing to carry).
    carried : int
        Frames in a row already carried by the flow before this one.
    max_frames : int
        Most frames in a row the flow may carry (0: the model runs on every frame).
    fb_max, residual_max : float
        Bounds on each palm joint's forward-backward error and on the non-rigid
        residual, in palm lengths of the previous landmarks.
    size : (width, height) or None
        The frame size: a palm joint carried off the frame needs the model.

    Returns
    -------
    bool
        True unless every palm joint came back within ``fb_max``, the motion
        is rigid within ``residual_max`` and ``carried < max_frames``.
    """
    if step is None or carried >= max_frames:
        return True
    palm = step.palm_length
    if not np.all(step.fb_error[list(PALM_JOINTS)] <= fb_max * palm):
        return True
    if not step.residual <= residual_max * palm:
        return True
    if size is not None:
        uv = step.landmarks[list(PALM_JOINTS), :2]
        if np.any(uv < -0.5) or np.any(uv[:, 0] > size[0] - 0.5) or np.any(uv[:, 1] > size[1] - 0.5):
            return True
    return False


class LandmarkFlow:
    """Carries one tracked hand's landmarks between landmark-model calls (module doc).

    Parameters
    ----------
    max_frames : int
        Most consecutive frames carried by the flow (>= 0); 0 = the model on
        every frame (MediaPipe's video mode).

    Use: :meth:`follow` before the model (a carried observation, or None when
    the model must run), then :meth:`remember` with the frame's observation.

    A hand that is changing pose keeps changing it for a while, and a flow that
    failed costs its crop and palm-joint flow on top of the model call: after a
    failure the flow waits 1, 2, 4, ... frames (at most
    :data:`~fusion_pf.cues.hand.BACKOFF_MAX`, :class:`~fusion_pf.cues.hand.Backoff`)
    before it tries again, back to every frame after a success.
    """

    def __init__(self, max_frames: int = MAX_FRAMES) -> None:
        if isinstance(max_frames, bool) or not isinstance(max_frames, (int, np.integer)) or max_frames < 0:
            raise InputError(f"max_frames must be an int >= 0, got {max_frames!r}")
        self.max_frames = int(max_frames)
        self.reset()
        #: Frames carried by the flow, and frames where it was tried, so far.
        self.frames = 0
        self.tries = 0

    def reset(self) -> None:
        """Forget the crop and the back-off (a new track starts with the model)."""
        self.carried = 0
        self._template: np.ndarray | None = None
        self._roi: HandRoi | None = None
        self.backoff = Backoff()

    def follow(self, rgb: np.ndarray, previous: HandObservation | None) -> HandObservation | None:
        """``previous`` carried into ``rgb`` when :func:`landmark_call_needed` says the flow is enough, else None."""
        if not self.backoff.ready():
            return None
        if previous is None or self._template is None or self._roi is None:
            return None
        self.tries += 1
        step = carry(self._template, grey_crop(rgb, self._roi), self._roi, previous.landmarks)
        h, w = rgb.shape[:2]
        if landmark_call_needed(step, self.carried, self.max_frames, size=(w, h)):
            self.backoff.failed()
            return None
        self.backoff.succeeded()
        self.frames += 1
        return HandObservation(step.landmarks, previous.score, previous.handedness)

    def remember(self, rgb: np.ndarray, obs: HandObservation | None, carried: bool) -> None:
        """Keep ``rgb``'s crop around ``obs`` (this frame's hand; ``carried``: by the flow) for the next frame."""
        self.carried = self.carried + 1 if carried else 0
        if obs is None or self.carried >= self.max_frames or self.backoff.wait > 0:
            self._template = self._roi = None  # the next frame runs the model: no crop needed
            return
        r = landmarks_roi(obs.landmarks)
        self._roi = HandRoi(r.u, r.v, r.size)
        self._template = grey_crop(rgb, self._roi)
