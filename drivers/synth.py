"""Synthetic RGB-D scene source: a person waving a palm (or washing both hands) in front of a wall.

:class:`SynthSource` renders the kind of scene paper 003 tracks (§3.5, §4): an
empty-room background, a person in dark clothing (right sleeve pushed up)
whose right palm moves smoothly and repeatedly passes in front of the torso
(self-occlusion), a stereo-like depth map, a Kinect-like skeleton stream that
fails during self-occlusion, and the true palm centre as ground truth.

Camera
------
OAK-D-like pinhole, ``fx = fy = 0.78 * width`` (65.3 degrees horizontal field of
view), principal point at the image centre, rectified (distortion ``"none"``).
Depth is aligned to colour.

Scene
-----
* Static background: a slanted bluish-grey wall (2.81-3.19 m, RGB ~(148, 158,
  174) with smooth texture), a white shelving unit on the left (frame 2.35 m,
  back 2.65 m, pale boxes 2.45 m), a painting, and an open doorway on the right
  whose room (5.5 m) lies beyond the depth range (depth 0).
* Person: torso ~1.45-1.6 m, swaying +-2.5 cm sideways and +-2 cm in depth;
  navy long-sleeved shirt, charcoal trousers, dark hair. The right sleeve is
  pushed up: the right forearm is bare (skin, 3.4 cm radius) from the wrist to
  a per-seed 30-70 % of its length toward the elbow (seeds 0 / 1 / 2: 45 / 35 /
  39 %), so skin shows on the face, neck, both hands and that forearm. The
  right palm (an ellipse 10 x 13 cm, ~42 x 54 px at 1.2 m, at 640 px width) is
  0.22-0.32 m in front of the torso (1.13-1.38 m) and sweeps horizontally
  (period 80-105 frames, frequency modulated) from far out to the person's
  right (image left) to 55-70 px across the torso's outline, and vertically
  between shoulder and hip height. The arm follows by two-link inverse
  kinematics. A region-based cue that takes the whole skin blob (palm and bare
  forearm) therefore has its centroid pulled toward the elbow by an amount that
  changes with the arm's foreshortening.
* Colour: the noise-free image is blurred (3 x 3 Gaussian, mixed pixels at
  outlines); the moving layer (right forearm, sleeve and palm) is
  motion-blurred along the palm's image velocity over an exposure of half the
  frame period (:data:`EXPOSURE_FRACTION`; line kernel, blurred colour and
  coverage composited over the rest) whenever the palm moves faster than
  1 px/frame (:data:`MIN_BLUR_SPEED_PX`): 99 % of the person frames (seeds
  0-2); the palm's speed is median 5.8, max 9.9 px/frame at 640 px width, so
  the blur is up to 5 px long. The image is then scaled by a slow
  illumination drift (two sinusoids over the frame index, periods 50-110
  and 160-320 frames, amplitudes 2-3.5 % and 2.5-4.5 %,
  plus a horizontal gradient of 1-2.5 % per normalised image unit with period
  120-260 frames; measured gain range over 300 frames 0.93-1.07, seeds 0-2)
  and a per-frame flicker gain uniform in [0.98, 1.02], and gets Gaussian
  sensor noise of sigma 2.5 grey levels per channel. The drift runs through
  the empty-scene frames too, so a background model leaves residuals of up to
  ~10 % of the scene's brightness.
* Speed: 83 frames/s at 640 x 400 and 340 frames/s at 320 x 200 (one core of
  the shared development machine), i.e. 200 frames at 640 x 400 in 2.4 s.

Colour difference ranges
------------------------
Measured with paper 003's pipeline (``|frame - background|`` per channel, then
``cv2.cvtColor(RGB2GRAY)``) against the mean of 30 background frames, over 68
person frames each of seeds 0-2 at 640 x 400 (1st / 50th / 99th percentile,
masks eroded by 2 px to skip the blurred outlines):

* background: 1 / 5 / 20 (the illumination drift; 0 / 2 / 6 without it)
* skin (face, neck, both hands, bare forearm): 20 / 28 / 50; the right palm
  alone: 20 / 27 / 49
* clothing and hair: 99 / 113 / 129

so background and skin now overlap in the tails: with ``lower = 12`` the
brightest background residuals pass on strongly drifted frames. The colour cue
(:class:`fusion_pf.cues.ColourCue` defaults, window on the skeleton joint) on
the shipped 320 x 200 sample: median error 6.8 px on clear frames (95th
percentile 9.7 px, coverage 100 %), 3.4 px while occluded (coverage 82 %: the
misses are palm-and-forearm regions touching the window border, which the
border clearing drops); it was 0.3 px before the sleeve, blur and drift.

Depth
-----
Aligned to colour, uint16 millimetres, 0 = invalid. The model is a stereo pair
with baseline ``B = 75 mm`` (:data:`BASELINE_MM`, the OAK-D's) and this camera as
the left, reference one, matched at the scene's resolution and focal length;
disparity ``d = fx * B / z``. Two models (``depth_model``):

``realistic`` (the default) has the artefacts of a real stereo sensor, each with
its source in the constant's documentation:

* noise: ``d`` gets Gaussian noise of :data:`DISPARITY_NOISE_PX` = 0.1 px (Intel's
  D400 sub-pixel RMS), spatially correlated (white noise blurred by a Gaussian of
  sigma 2 px, :data:`DEPTH_NOISE_CORRELATION_PX`, renormalised), so
  ``sigma_z = z**2 / (fx * B) * sigma_d``: 3.8 mm at 1.2 m and 24 mm at 3 m at 640
  px width, twice that at 320 px;
* quantisation: ``d`` is rounded to 1/8 px (:data:`SUBPIXEL_STEPS`, the OAK-D's 3
  sub-pixel bits), i.e. depth steps of ``z**2 / (8 fx B)``: 4.8 mm at 1.2 m, 30 mm at
  3 m (640 px), then ``z`` is rounded to mm. Measured on flat planes 0.45-4.4 m:
  log-log slope of the std 1.9-2.1, within 10 % of
  ``z**2 / (fx B) * sqrt(sigma_d**2 + (1/8)**2 / 12)`` from 1 m;
* depth steps (a disparity range above :data:`EDGE_STEP_PX` = 1 px inside a 5 x 5
  window, :data:`EDGE_BAND_PX`): of the pixels within 2 px of a step,
  :data:`EDGE_INVALID_FRACTION` = 40 % are invalid (left-right check) and
  :data:`EDGE_FLYING_FRACTION` = 40 % become flying pixels, with a disparity mixed
  uniformly between the near and the far surface's; on the palm, 9 % of the pixels
  are invalid and 7 % flying at 640 px width (16 % and 12 % at 320 px; seed 0);
* stereo shadows as in ``basic``, plus the band on the left border where the right
  camera does not see the point (``x < d``: 12 px for the wall at 640 px width);
* speckle holes: blobs (a white field blurred by a Gaussian of
  :data:`SPECKLE_BLOB_PX` = 1.5 px, thresholded) covering :data:`SPECKLE_FRACTION`
  = 1.5 % of the pixels;
* 0 closer than ``fx * B / MAX_DISPARITY_PX`` (the OAK-D's 0-95 px search range:
  0.39 m at 640 px width) and beyond :data:`MAX_RANGE_MM` = 4.5 m (the doorway).

About 17 % of the pixels of an empty frame are invalid.

``basic`` (the model ``recordings/sample.mcap`` was made with):

* noise: ``d`` gets Gaussian noise of sigma ``c * fx * B`` px (0.19 px at 640 px
  width), correlated and quantised to 1/8 px as above, so ``sigma_z = c * z**2``
  with ``c = 5e-6 / mm`` (:data:`DEPTH_NOISE_C`) at any resolution: 7 mm at 1.2 m,
  20 mm (1 %) at 2 m, 45 mm at 3 m. Measured (temporal std of 16 background
  frames, 2.3-3.2 m): sigma / (c z**2) = 1.00-1.04, log-log slope 2.06;
* stereo shadows: points this camera sees but the right camera cannot are
  invalid, giving a band on the left (occluded) side of every near-to-far edge,
  ``fx * B * (1/z_near - 1/z_far)`` px wide: ~6 px left of the palm over the
  torso, ~12 px left of the person over the wall at 640 px width;
* invalid single-pixel speckles: 1.5 % of the pixels (:data:`SPECKLE_FRACTION`);
* 0 beyond :data:`MAX_RANGE_MM` = 4.5 m (the doorway).

About 14 % of the pixels of an empty frame are invalid (mostly the doorway); the
palm is 98.5 % valid and has no flying pixels.

Skeleton (Kinect failure model)
-------------------------------
``Frame.joints`` holds the 10 joints of :data:`fusion_pf.frame.KNOWN_JOINTS`,
projected from the true 3-D pose, with depth in mm. Pixel figures below are at
640 px width and scale with ``fx``.

* Every joint while clear: Gaussian noise sigma 2 px per axis, depth noise
  15 mm, confidence 0.85-0.95.
* ``right_hand`` during self-occlusion, weighted by ``w = clip(f / 0.4, 0, 1)``
  (:data:`FULL_FAILURE_OVERLAP`)
  where ``f`` is the fraction of the palm's area over the torso/head region:
  a bias of ``w * B`` px toward the torso joint, ``B`` varying smoothly in
  24-56 px (period 40-70 frames); jitter sigma ``2 + 10 w`` px; confidence
  ``0.9 - 0.6 w`` (+-0.05): 0.25-0.35 at full occlusion; depth pulled
  ``0.8 w`` of the way to the torso depth, noise ``15 (1 + 2 w)`` mm.
* ``right_wrist``: half the hand's bias and extra jitter, confidence
  ``0.9 - 0.3 w``.

Measured over seeds 0-2, 300 frames each, against the ground truth:
``right_hand`` error while clear (no overlap, 566 frames) mean 2.5 px, 95th
percentile 4.8 px, confidence 0.90; while occluded (297 frames) mean 42 px
(5th-95th percentile 15-70 px), confidence 0.31, and the error points at the
torso (mean cosine 0.93).

Ground truth and occlusion
--------------------------
``Frame.ground_truth`` is the projected palm centre (the palm is the front-most
object, so it is the centroid of the ``palm`` mask to rasterisation accuracy);
the bare forearm is in the ``skin`` mask, never in ``palm``. Masks, depth and
ground truth are the instantaneous (unblurred) scene.
``occluded`` is true when at least 25 % of the palm lies over the torso/head
region (``f >= 0.25``, so ``w >= 0.625``); about 30 % of the person frames.

Two hands (``hands=2``)
-----------------------
A hand-washing person (:func:`drivers.synth_scene.wash_pose_at`): both sleeves
pushed up, both palms 0.28 m in front of the lower chest. One 300-frame cycle
(10 s at 30 fps; :data:`drivers.synth_scene.WASH_KEYS`) has the hands apart
(about 0.30 m, 58 px at 320 px width), approaching and **joined** for 61 and 47
frames (palms 4 cm apart and rubbing, >= 25 % overlap: ``occluded``), and one
**crossing** in between (the right hand passes 13 cm above the left, the palms
touch); odd cycles are mirrored, so the motion is continuous (the hands cross
back in the next cycle). The centre drifts and bobs a few centimetres
(per-seed parameters from ``spawn_key=(4,)``, so the background, lighting and
sleeve draws are those of the one-hand scene). The skin cues see both hands
and forearms, the face and neck, and a skin-coloured painting on the wall.

* Ground truth per target: ``Frame.ground_truths`` = ``{"right_hand",
  "left_hand", "head"}`` (palm centres, face centre; :meth:`SynthSource.ground_truths`),
  ``Frame.ground_truth`` = the right hand.
* Skeleton: every joint sigma 2 px (at 640 px width), confidence 0.85-0.95;
  while the hands are joined (weight ``w = clip(f / 0.4, 0, 1)``, ``f`` the
  fraction of the right palm covered by the left) both hand joints are pulled
  ``w / 2`` of the way to the pair's middle, jitter ``2 + 10 w`` px,
  confidence ``0.9 - 0.6 w``.
* No motion blur (two layers moving differently are not modelled); the depth
  and colour noise are the one-hand scene's.
* Every scene variation applies: ``skin_tone`` to both hands, forearms, the
  face and neck, ``clothing`` to the shirt and both sleeves, ``hand_front`` puts
  both palms ``hand_front + 0.06`` m in front of the torso
  (:data:`drivers.synth_scene.WASH_EXTRA_FRONT`; 0.28 m by default),
  ``skeleton_bias`` scales ``w`` of both hands and wrists (jitter; the pull and
  the confidence drop saturate at ``w = 1``), ``clutter``, ``lighting`` and
  ``depth_noise`` as for one hand.
* ``hands=1`` (the default) renders exactly the one-hand scene, bit for bit.
* Layout (``hands=2`` only; :data:`LAYOUT`; :func:`drivers.synth_scene.wash_keys`):
  ``joins`` (0-4) and ``crossings`` (0-3) per cycle, interleaved;
  ``hand_distance`` (m apart, 0.14-0.5), ``cross_height`` (how far the right
  palm passes above the left, 0.05-0.25 m); ``timing=1`` draws the order of the
  events and every hold, approach and crossing length from
  ``spawn_key=(6,)``. The defaults (2, 1, 0.30, 0.13, fixed timing) are
  :data:`drivers.synth_scene.WASH_KEYS`; a cycle ending crossed is followed by
  its mirror image.

Scripted events (``hands=2, script="events"``)
----------------------------------------------
The two-hand person acts a script (:data:`drivers.synth_scene.SCRIPT_KEYS`,
:func:`drivers.synth_scene.script_pose_at`; 300 nominal person frames, every
interval stretched 0.85-1.15 and the places moved a few centimetres per seed,
``spawn_key=(6,)``): the right hand reaches a dark green ball (7 cm, resting
beside the person at hand depth, drawn in colour and depth) and picks it up,
brings it home, the hands join and the ball moves from the right hand to the
left, the hands separate, the right hand goes to the right cheek and back, and
the hands join and separate again (the left hand keeps the ball). The palms
cross no threshold slowly: every approach lasts 10-14 frames. The true events
(:meth:`SynthSource.true_events`, :func:`drivers.synth_scene.script_events`)
are written to ``/ground_truth/events`` by ``fusion-pf synth``; skeleton,
per-target ground truth and noise are the two-hand scene's.

Scene variations
----------------
Keyword arguments (:data:`VARIATIONS`) that change one property of the scene
each, for benchmarks over many scenes (``benchmarks/fusion_matrix.py``); their
defaults render the scene described above bit for bit, and only non-default
values are written to the metadata.

* ``depth_noise``: factor on the disparity noise of either depth model (0-50);
* ``hand_front``: the palm's smallest distance in front of the torso, m
  (0.03-0.6; it sweeps to ``hand_front + 0.10``): near the body the depth cue
  cannot tell palm from torso;
* ``lighting``: factor on the illumination drift, gradient and flicker (0-10);
* ``skin_tone``: 0 (:data:`drivers.synth_scene.SKIN_RGB`) to 1
  (:data:`drivers.synth_scene.DARK_SKIN_RGB`), blended linearly; a dark palm
  differs little from the navy shirt;
* ``skeleton_bias``: factor on the occlusion weight ``w`` of the skeleton's
  hand and wrist (bias and jitter; the confidence and depth pull saturate at
  ``w = 1``), 0-5: 0 is a skeleton that never fails;
* ``clothing``: the shirt's colour, an index into
  :data:`drivers.synth_scene.CLOTHING_PALETTE` (0 navy, 1 skin-like beige, 2
  wood-like brown, 3 red, 4 light grey, 5 dark green; a fraction blends the two
  neighbours): a beige or brown shirt is skin to a colour rule, and the palms
  over the torso lose their colour contrast;
* ``clutter``: that many static objects (boxes and round shapes, 0-30) in the
  room (:func:`drivers.synth_scene.add_clutter`): every third is skin-coloured
  (a random tone), every second stands at hand depth (1.0-1.4 m) beside the
  person at hand height, the others in front of the wall (2.0-2.8 m); they
  are part of the empty scene, so a background model learns them, but the
  colour and depth cues see them in every frame. ``clutter = N + k`` keeps the
  first ``N`` objects of ``clutter = N``. An object at hand depth may hide
  part of an arm that passes behind it (never a palm);
* ``away``: the person leaves the view for ``away`` frames of every
  :data:`AWAY_CYCLE` person frames (0-95; the cycle's phase from the seed):
  those frames show the empty room but are not background frames (no
  skeleton, no ground truth), so a tracker loses the hand there and must find
  it again when the person is back, mid-motion (re-acquisition; a recording
  where acquisition frames dominate). One palm, no script.

Determinism
-----------
The scene (background textures, motion parameters) comes from
``SeedSequence(seed, spawn_key=(0,))``, the sleeve and the illumination drift
from ``spawn_key=(3,)``, the two-hand motion from ``spawn_key=(4,)``, the clutter
from ``spawn_key=(5,)``, the phase of ``away`` from ``spawn_key=(7,)``; frame ``i``'s image noise,
flicker and depth artefacts from
``spawn_key=(1, i)`` and its skeleton noise from ``spawn_key=(2, i)``. So frame
``i`` depends only on ``(seed, i, size, background_frames)`` and random access
equals iteration. The motion (and so the motion blur) is a function of the
person-frame index ``i - background_frames``, so adding background frames
delays the same motion; the illumination drift is a function of ``i``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator, Mapping

import cv2
import numpy as np
from scipy.special import ndtri

from fusion_pf import __version__
from fusion_pf.errors import InputError
from fusion_pf.frame import KNOWN_JOINTS, Frame, Intrinsics, Joint, PalmPoint

from . import synth_scene as sc
from .base import ReplaySource

#: Depth models: ``realistic`` (the default: stereo artefacts of a real sensor, see
#: "Depth") and ``basic`` (the model ``recordings/sample.mcap`` was made with).
DEPTH_MODELS = ("realistic", "basic")
#: ``basic`` model: ``sigma_z = DEPTH_NOISE_C * z**2`` (z in mm).
DEPTH_NOISE_C = 5e-6
#: ``realistic`` model: disparity noise (px, 1 sigma) of the stereo matcher. Intel's D400
#: tuning white paper (Grunnet-Jepsen et al., "Tuning depth cameras for best performance",
#: 2019) models the depth RMS error as ``z**2 * s / (f * B)`` with a sub-pixel RMS ``s`` of
#: 0.05-0.1 px on textured targets; Luxonis quotes < 2 % absolute error below 4 m for an
#: OAK-D at 800P (f = 882.5 px, B = 75 mm), i.e. at most 0.33 px. Skin is poorly textured,
#: so the upper end of Intel's range.
DISPARITY_NOISE_PX = 0.1
#: ``realistic`` model: disparity search range (px). The OAK-D searches 0-95 px (96
#: levels; Luxonis, "Configuring stereo depth"), so anything closer than ``f * B / 95``
#: is invalid (0.39 m at 640 px width).
MAX_DISPARITY_PX = 95.0
#: ``realistic`` model: half-width (px) of the band around a depth step where block
#: matching mixes foreground and background: half of a 5 x 5 matching window.
EDGE_BAND_PX = 2
#: ``realistic`` model: a disparity range above this (px) inside the matching window is a
#: depth step (1 px: 1.2 m palm over a 1.45 m torso is 5.4 px at 640 px width).
EDGE_STEP_PX = 1.0
#: ``realistic`` model: fractions of the edge-band pixels that the left-right consistency
#: check invalidates (0) and that become flying pixels (disparity ``(1 - a) d_near + a
#: d_far``, ``a`` uniform in [0, 1]); the rest keep their own depth. Chosen by eye to
#: resemble OAK-D depth at hand outlines with LR-check on, not measured.
EDGE_INVALID_FRACTION = 0.4
EDGE_FLYING_FRACTION = 0.4
#: ``realistic`` model: speckle holes are blobs (a white field blurred by a Gaussian of
#: this sigma in px, thresholded) covering :data:`SPECKLE_FRACTION` of the image, as the
#: speckle filter and poorly textured patches leave them.
SPECKLE_BLOB_PX = 1.5
#: Stereo baseline (mm) of the shadow model.
BASELINE_MM = 75.0
#: Spatial correlation of the disparity noise: Gaussian blur sigma in pixels.
DEPTH_NOISE_CORRELATION_PX = 2.0
#: Disparity is quantised to 1 / SUBPIXEL_STEPS pixel (OAK-D: 3 fractional bits).
SUBPIXEL_STEPS = 8
#: Depth beyond this (mm) is invalid (0).
MAX_RANGE_MM = 4500.0
#: Fraction of pixels with invalid (0) depth speckles.
SPECKLE_FRACTION = 0.015
#: Colour sensor noise, grey levels per channel.
COLOR_NOISE_SIGMA = 2.5
#: Global illumination flicker: gain uniform in ``[1 - F, 1 + F]``.
FLICKER = 0.02
#: Exposure time as a fraction of the frame period (motion blur of the moving arm).
EXPOSURE_FRACTION = 0.5
#: Palm image speed (px per frame) above which the moving arm is motion-blurred.
MIN_BLUR_SPEED_PX = 1.0
#: Fraction of the palm's area over the body from which the frame counts as occluded.
OCCLUDED_OVERLAP = 0.25
#: Overlap fraction at which the skeleton's right hand fails completely (``w = 1``).
FULL_FAILURE_OVERLAP = 0.4

#: Standard-normal quantiles of the 65536 equiprobable bins: indexing it with uniform
#: uint16 draws gives Gaussian noise (tails cut at 4.3 sigma) five times faster
#: than ``Generator.standard_normal``.
_NORMAL_TABLE = ndtri((np.arange(65536) + 0.5) / 65536).astype(np.float32)

_CORR_KSIZE = 13
#: Threshold, in standard deviations of the blurred field, above which a pixel is a speckle hole.
_SPECKLE_THRESHOLD = float(ndtri(1.0 - SPECKLE_FRACTION))
#: Standard deviation of unit white noise after the correlation blur (sqrt of the sum of
#: the squared 2-D kernel weights), used to bring the blurred field back to unit variance.
_CORR_STD = float((cv2.getGaussianKernel(_CORR_KSIZE, DEPTH_NOISE_CORRELATION_PX) ** 2).sum())

#: fx of the 640-px-wide camera, to which the skeleton's pixel figures refer.
_REFERENCE_FX = 0.78 * 640.0
#: Scene variations (``SynthSource`` keyword arguments) with their default and range: the
#: default renders the documented scene bit for bit.
VARIATIONS = {
    "depth_noise": (1.0, 0.0, 50.0),
    "hand_front": (0.22, 0.03, 0.6),
    "lighting": (1.0, 0.0, 10.0),
    "skin_tone": (0.0, 0.0, 1.0),
    "skeleton_bias": (1.0, 0.0, 5.0),
    "clothing": (0.0, 0.0, float(len(sc.CLOTHING_PALETTE) - 1)),
    "clutter": (0, 0, 30),
    "away": (0, 0, 95),
    "hand_distance": (sc.WASH_LAYOUT[2], 0.14, 0.5),
    "joins": (sc.WASH_LAYOUT[0], 0, 4),
    "crossings": (sc.WASH_LAYOUT[1], 0, 3),
    "cross_height": (sc.WASH_LAYOUT[3], 0.05, 0.25),
    "timing": (0, 0, 1),
}
#: The variations of the two-hand motion (``hands=2`` only).
LAYOUT = ("hand_distance", "joins", "crossings", "cross_height", "timing")
_OPTIONS = (
    "seed",
    "frames",
    "size",
    "fps",
    "background_frames",
    "start_ns",
    "depth_model",
    "hands",
    "script",
    *VARIATIONS,
)
#: Person frames per cycle of the ``away`` variation (the person is away for ``away`` of them).
AWAY_CYCLE = 100
#: Scripted scenes (``script``): ``none`` (the motion of ``hands``) or ``events`` (two hands that
#: join twice, a hand at the head, a ball picked up and passed; see "Scripted events").
SCRIPTS = ("none", "events")
#: Ground-truth targets of the two-hand scene, the primary one first.
TARGETS = ("right_hand", "left_hand", "head")
#: Most frames a synthetic recording may have.
MAX_FRAMES = 10_000_000
#: Range of the image width and height in pixels.
MIN_SIZE, MAX_SIZE = 32, 4096


def _int_option(name: str, value: object, lo: int, hi: int) -> int:
    if isinstance(value, bool):
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")
    if isinstance(value, (int, np.integer)):
        number = int(value)
    else:
        try:
            number = int(str(value).strip())
        except ValueError:
            raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}") from None
    if not lo <= number <= hi:
        raise InputError(f"{name} must be an integer in [{lo}, {hi}], got {number}")
    return number


def _variation(name: str, value: object) -> float:
    _, lo, hi = VARIATIONS[name]
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"synth option {name} must be a number in [{lo}, {hi}], got {value!r}") from None
    if not lo <= number <= hi:
        raise InputError(f"synth option {name} must be a number in [{lo}, {hi}], got {value!r}")
    return number


def _int_variation(name: str, value: object) -> int:
    _, lo, hi = VARIATIONS[name]
    return _int_option(f"synth option {name}", value, int(lo), int(hi))


def _fps_option(value: object) -> float:
    try:
        fps = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"synth option fps must be a number in (0, 1000], got {value!r}") from None
    if not (math.isfinite(fps) and 0.0 < fps <= 1000.0):
        raise InputError(f"synth option fps must be a number in (0, 1000], got {value!r}")
    return fps


def _size_option(value: object) -> tuple[int, int]:
    expected = f"WxH with both in [{MIN_SIZE}, {MAX_SIZE}], e.g. 640x400"
    if isinstance(value, str):
        parts = value.lower().split("x")
    elif isinstance(value, (tuple, list)):
        parts = list(value)
    else:
        raise InputError(f"synth option size must be {expected}, got {value!r}")
    if len(parts) != 2:
        raise InputError(f"synth option size must be {expected}, got {value!r}")
    try:
        w, h = (int(str(p).strip()) for p in parts)
    except ValueError:
        raise InputError(f"synth option size must be {expected}, got {value!r}") from None
    if not (MIN_SIZE <= w <= MAX_SIZE and MIN_SIZE <= h <= MAX_SIZE):
        raise InputError(f"synth option size must be {expected}, got {value!r}")
    return w, h


class SynthSource(ReplaySource):
    """Seeded synthetic RGB-D scene with skeleton and ground truth (see module docstring).

    Parameters
    ----------
    frames : int
        Number of frames, background frames included (>= 1).
    seed : int
        Scene and noise seed (>= 0).
    size : tuple of int
        ``(width, height)`` in pixels, each in [32, 4096].
    fps : float
        Frame rate in (0, 1000]; frame ``i`` is at ``start_ns + round(i * 1e9 / fps)``.
    background_frames : int
        The first ``background_frames`` frames show the empty scene
        (``Frame.background = True``, ``joints = {}``, no ground truth); in
        ``[0, frames]``.
    start_ns : int
        Timestamp of frame 0 in integer nanoseconds (>= 0).
    depth_model : {"realistic", "basic"}
        The stereo sensor model of the depth image (module docstring, "Depth").
    hands : int
        1 (default): the single-palm scene; 2: the two-hand hand-washing scene
        (see "Two hands" in the module docstring).

    Raises
    ------
    InputError
        When a parameter is outside its range.
    """

    def __init__(
        self,
        *,
        frames: int = 200,
        seed: int = 0,
        size: tuple[int, int] = (640, 400),
        fps: float = 30.0,
        background_frames: int = 0,
        start_ns: int = 1_700_000_000_000_000_000,
        depth_model: str = "realistic",
        hands: int = 1,
        script: str = "none",
        depth_noise: float = VARIATIONS["depth_noise"][0],
        hand_front: float = VARIATIONS["hand_front"][0],
        lighting: float = VARIATIONS["lighting"][0],
        skin_tone: float = VARIATIONS["skin_tone"][0],
        skeleton_bias: float = VARIATIONS["skeleton_bias"][0],
        clothing: float = VARIATIONS["clothing"][0],
        clutter: int = int(VARIATIONS["clutter"][0]),
        away: int = int(VARIATIONS["away"][0]),
        hand_distance: float = VARIATIONS["hand_distance"][0],
        joins: int = int(VARIATIONS["joins"][0]),
        crossings: int = int(VARIATIONS["crossings"][0]),
        cross_height: float = VARIATIONS["cross_height"][0],
        timing: int = int(VARIATIONS["timing"][0]),
    ) -> None:
        super().__init__()
        self.depth_noise = _variation("depth_noise", depth_noise)
        self.hand_front = _variation("hand_front", hand_front)
        self.lighting = _variation("lighting", lighting)
        self.skin_tone = _variation("skin_tone", skin_tone)
        self.skeleton_bias = _variation("skeleton_bias", skeleton_bias)
        self.clothing = _variation("clothing", clothing)
        self.hand_distance = _variation("hand_distance", hand_distance)
        self.cross_height = _variation("cross_height", cross_height)
        self.clutter = _int_variation("clutter", clutter)
        self.away = _int_variation("away", away)
        self.joins = _int_variation("joins", joins)
        self.crossings = _int_variation("crossings", crossings)
        self.timing = _int_variation("timing", timing)
        self._skin = sc.skin_rgb(self.skin_tone)
        self._shirt = sc.clothing_rgb(self.clothing)
        self.hands = _int_option("synth option hands", hands, 1, 2)
        if script not in SCRIPTS:
            raise InputError(f"synth option script must be one of {', '.join(SCRIPTS)}, got {script!r}")
        if script != "none" and self.hands != 2:
            raise InputError(f"synth option script {script!r} needs hands 2 (both hands act in it), got {self.hands}")
        self.script = script
        if self.away and (self.hands != 1 or script != "none"):
            raise InputError(f"synth option away={self.away} needs the one-palm scene (hands 1, no script)")
        self._n = _int_option("synth option frames", frames, 1, MAX_FRAMES)
        layout = [k for k in LAYOUT if getattr(self, k) != VARIATIONS[k][0]]
        if layout and self.hands != 2:
            raise InputError(f"synth option {layout[0]} describes the two-hand motion; it needs hands=2")
        if layout and script != "none":
            raise InputError(f"synth option {layout[0]} changes the two-hand motion, which script {script!r} fixes")
        self.seed = _int_option("synth option seed", seed, 0, 2**63 - 1)
        self.size = _size_option(size)
        self.fps = _fps_option(fps)
        self.background_frames = _int_option("synth option background_frames", background_frames, 0, self._n)
        self.start_ns = _int_option("synth option start_ns", start_ns, 0, 2**63 - 1)
        if depth_model not in DEPTH_MODELS:
            raise InputError(f"synth option depth_model must be one of {', '.join(DEPTH_MODELS)}, got {depth_model!r}")
        self.depth_model = depth_model
        self.intrinsics: Intrinsics = sc.default_intrinsics(*self.size)
        scene_rng = self._rng(0)
        self._motion = dataclasses.replace(sc.motion_parameters(scene_rng), hand_front=self.hand_front)
        self._background = sc.render_background(self.intrinsics, scene_rng)
        if self.clutter:
            self._background = sc.add_clutter(self.intrinsics, self._background, self._rng(5), self.clutter)
        self._bg_depth_valid = self._stereo_valid(self._background.depth_m)
        a = sc.appearance_parameters(self._rng(3))
        self._appearance = dataclasses.replace(
            a,
            drift_amps=tuple(self.lighting * x for x in a.drift_amps),
            gradient_amp=self.lighting * a.gradient_amp,
        )
        self._wash = self._wash_motion() if self.hands == 2 else None
        self._script = sc.script_parameters(self._rng(6)) if script == "events" else None
        self._away_phase = int(self._rng(7).integers(AWAY_CYCLE)) if self.away else 0
        k = self.intrinsics
        self._xn = ((np.arange(k.width, dtype=np.float32) - k.cx) / k.fx)[None, :]

    def _wash_motion(self) -> sc.WashMotion:
        """The two-hand motion: its per-seed parameters and the cycle of the layout options."""
        keys = sc.wash_keys(
            self.joins,
            self.crossings,
            self.hand_distance,
            self.cross_height,
            self._rng(6) if self.timing else None,
        )
        return dataclasses.replace(sc.wash_parameters(self._rng(4)), keys=keys, cross_height=self.cross_height)

    @classmethod
    def from_options(cls, options: Mapping[str, object]) -> "SynthSource":
        """Build a source from ``open_source`` options (strings or typed values).

        Parameters
        ----------
        options : mapping of str to str or object
            Any of ``seed``, ``frames``, ``size`` (``"640x400"`` or ``(w, h)``),
            ``fps``, ``background_frames``, ``start_ns``, ``depth_model``, ``hands`` (1 or 2),
            and the scene variations of :data:`VARIATIONS`.

        Raises
        ------
        InputError
            For an unknown key or a value outside its range.
        """
        unknown = sorted(set(options) - set(_OPTIONS))
        if unknown:
            raise InputError(f"unknown synth option {unknown[0]!r}; expected one of {', '.join(_OPTIONS)}")
        return cls(**dict(options))  # type: ignore[arg-type]

    # -- ReplaySource -------------------------------------------------------------------------

    def open(self) -> None:
        """Nothing to acquire: the scene is rendered on demand."""

    def close(self) -> None:
        """Nothing to release."""

    def __len__(self) -> int:
        return self._n

    def describe(self) -> str:
        w, h = self.size
        hands = (" hands=2" if self.hands == 2 else "") + (f" script={self.script}" if self._script else "")
        varied = "".join(f" {k}={v:g}" for k, v in self.variations().items())
        return (
            f"synth seed={self.seed} frames={self._n} {w}x{h} background_frames={self.background_frames}{hands}"
            + ("" if self.depth_model == "realistic" else f" depth_model={self.depth_model}")
            + varied
        )

    def variations(self) -> dict[str, float]:
        """The scene variations that differ from their default (:data:`VARIATIONS`)."""
        return {k: getattr(self, k) for k, (default, _, _) in VARIATIONS.items() if getattr(self, k) != default}

    def timestamp_ns(self, index: int) -> int:
        """Capture time of frame ``index`` in integer nanoseconds."""
        return self.start_ns + round(index * 1_000_000_000 / self.fps)

    def frames(
        self,
        start: int = 0,
        stop: int | None = None,
        *,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[Frame]:
        """Yield frames with index in ``[start, stop)`` and time in ``[start_ns, end_ns)``.

        ``stop`` beyond the end is clipped to ``len(self)``.
        """
        start = _int_option("frames() start", start, 0, MAX_FRAMES)
        stop = self._n if stop is None else min(_int_option("frames() stop", stop, 0, MAX_FRAMES), self._n)
        for i in range(start, stop):
            t = self.timestamp_ns(i)
            if start_ns is not None and t < start_ns:
                continue
            if end_ns is not None and t >= end_ns:
                return
            yield self.render(i)[0]

    def metadata(self) -> dict[str, str]:
        """Key/values for the recording's ``fusion_pf.recording`` metadata record."""
        w, h = self.size
        extra = {"hands": "2", "targets": ",".join(TARGETS)} if self.hands == 2 else {}
        if self._script is not None:
            extra["script"] = self.script
        return {
            "generator": "fusion_pf.synth",
            "generator_version": __version__,
            "seed": str(self.seed),
            "frames": str(self._n),
            "background_frames": str(self.background_frames),
            "size": f"{w}x{h}",
            "fps": repr(self.fps),
            "depth_model": self.depth_model,
            **(
                {"depth_noise_c_per_mm": repr(DEPTH_NOISE_C)}
                if self.depth_model == "basic"
                else {
                    "disparity_noise_px": repr(DISPARITY_NOISE_PX),
                    "baseline_mm": repr(BASELINE_MM),
                    "subpixel_steps": str(SUBPIXEL_STEPS),
                    "max_disparity_px": repr(MAX_DISPARITY_PX),
                }
            ),
            "occluded_overlap": repr(OCCLUDED_OVERLAP),
            **{k: repr(v) for k, v in self.variations().items()},
            **extra,
        }

    # -- geometry without pixels ----------------------------------------------------------------

    def _rng(self, *key: int) -> np.random.Generator:
        return np.random.default_rng(np.random.SeedSequence(self.seed, spawn_key=key))

    def _check_index(self, index: int) -> int:
        return _int_option("frame index", index, 0, self._n - 1)

    def away_at(self, index: int) -> bool:
        """Whether the person is away (the empty room, not a background frame) at frame ``index``."""
        t = self._check_index(index) - self.background_frames
        return t >= 0 and (t + self._away_phase) % AWAY_CYCLE < self.away

    def pose(self, index: int) -> sc.Pose | None:
        """True 3-D pose (metres) at frame ``index``; None for a background frame or while the person is away."""
        index = self._check_index(index)
        if index < self.background_frames or self.away_at(index):
            return None
        if self._script is not None:
            return sc.script_pose_at(self._motion, self._script, float(index - self.background_frames))[0]
        if self._wash is not None:
            return sc.wash_pose_at(self._motion, self._wash, float(index - self.background_frames))
        return sc.pose_at(self._motion, float(index - self.background_frames))

    def palm_overlap(self, index: int) -> float:
        """Fraction of the palm's area over the torso/head region at ``index`` (0 when empty).

        Two hands: the fraction of the right palm covered by the left palm.
        """
        pose = self.pose(index)
        if pose is None:
            return 0.0
        if self._wash is not None:
            return sc.hands_overlap(self.intrinsics, pose)
        return sc.palm_overlap(self.intrinsics, pose)

    def ground_truth(self, index: int) -> PalmPoint | None:
        """The true palm centre of frame ``index`` without rendering it (two hands: the right palm)."""
        truths = self.ground_truths(index)
        if truths is not None:
            return truths[TARGETS[0]]
        pose = self.pose(index)
        if pose is None:
            return None
        u, v = sc.project(self.intrinsics, pose.right_hand)
        occluded = sc.palm_overlap(self.intrinsics, pose) >= OCCLUDED_OVERLAP
        return PalmPoint(u, v, occluded=occluded)

    def ground_truths(self, index: int) -> dict[str, PalmPoint] | None:
        """Two hands: the true centre per target (:data:`TARGETS`); None for one hand or a background frame.

        ``occluded`` is true for a palm while at least :data:`OCCLUDED_OVERLAP`
        of the right palm is covered by the left one (the hands are joined);
        the head (face centre) is never occluded.
        """
        pose = self.pose(index)
        if pose is None or self._wash is None:
            return None
        intr = self.intrinsics
        joined = sc.hands_overlap(intr, pose) >= OCCLUDED_OVERLAP
        points = (pose.right_hand, pose.left_hand, sc.face_centre(pose))
        return {
            name: PalmPoint(*sc.project(intr, p), occluded=joined and name != "head")
            for name, p in zip(TARGETS, points)
        }

    def object_centre(self, index: int) -> np.ndarray | None:
        """Scripted scene: the ball's 3-D centre (m) at frame ``index``; None otherwise or for a background frame."""
        index = self._check_index(index)
        if self._script is None or index < self.background_frames:
            return None
        return sc.script_pose_at(self._motion, self._script, float(index - self.background_frames))[1]

    def true_events(self) -> list[dict]:
        """Scripted scene: its true events (``/ground_truth/events`` messages), in frame order; [] otherwise.

        Each is ``{"frame", "timestamp_ns", "event", "targets"}`` with ``frame``
        the recording's frame index (background frames counted);
        :func:`drivers.synth_scene.script_events` defines them.
        """
        if self._script is None:
            return []
        k = self.background_frames
        return [
            {"frame": t + k, "timestamp_ns": self.timestamp_ns(t + k), "event": event, "targets": list(targets)}
            for t, event, targets in sc.script_events(self._motion, self._script, self._n - k)
        ]

    def joints(self, index: int) -> dict[str, Joint]:
        """The skeleton stream of frame ``index`` (``{}`` for a background frame)."""
        pose = self.pose(index)
        if pose is None:
            return {}
        intr = self.intrinsics
        if self._wash is not None:
            return self._wash_joints(index, pose)
        k = intr.fx / _REFERENCE_FX
        w = min(sc.palm_overlap(intr, pose) / FULL_FAILURE_OVERLAP, 1.0)
        rng = self._rng(2, index)
        noise = rng.standard_normal((len(KNOWN_JOINTS), 3))
        conf_noise = rng.uniform(-0.05, 0.05, size=len(KNOWN_JOINTS))
        m = self._motion
        t = float(index - self.background_frames)
        bias_px = 40.0 + 16.0 * math.sin(2.0 * math.pi * t / m.bias_period + m.bias_phase)
        tu, tv = sc.project(intr, pose.torso)
        hu, hv = sc.project(intr, pose.right_hand)
        toward = np.array([tu - hu, tv - hv])
        norm = float(np.hypot(*toward))
        toward = toward / norm if norm > 1e-6 else np.array([0.0, 1.0])
        out: dict[str, Joint] = {}
        for j, name in enumerate(KNOWN_JOINTS):
            p = getattr(pose, name)
            u, v = sc.project(intr, p)
            z_mm = p[2] * 1000.0
            ww = w if name == "right_hand" else 0.5 * w if name == "right_wrist" else 0.0
            ww *= self.skeleton_bias
            sigma_px = (2.0 + 10.0 * ww) * k
            u += (ww * bias_px * toward[0]) * k + sigma_px * noise[j, 0]
            v += (ww * bias_px * toward[1]) * k + sigma_px * noise[j, 1]
            pull = 0.8 * min(ww, 1.0) if name == "right_hand" else 0.0
            z_mm += pull * (pose.torso[2] * 1000.0 - z_mm) + 15.0 * (1.0 + 2.0 * ww) * noise[j, 2]
            drop = 0.6 if name == "right_hand" else 0.3 if name == "right_wrist" else 0.0
            conf = 0.9 - drop * min(ww, 1.0) + conf_noise[j]
            out[name] = Joint(u, v, max(z_mm, 0.0), min(max(conf, 0.0), 1.0))
        return out

    def _wash_joints(self, index: int, pose: sc.Pose) -> dict[str, Joint]:
        """Two-hand skeleton: both hands fail while joined (see "Two hands" in the module docstring)."""
        intr = self.intrinsics
        k = intr.fx / _REFERENCE_FX
        w = min(sc.hands_overlap(intr, pose) / FULL_FAILURE_OVERLAP, 1.0)
        rng = self._rng(2, index)
        noise = rng.standard_normal((len(KNOWN_JOINTS), 3))
        conf_noise = rng.uniform(-0.05, 0.05, size=len(KNOWN_JOINTS))
        ru, rv = sc.project(intr, pose.right_hand)
        lu, lv = sc.project(intr, pose.left_hand)
        mid = np.array([(ru + lu) / 2.0, (rv + lv) / 2.0])
        out: dict[str, Joint] = {}
        for j, name in enumerate(KNOWN_JOINTS):
            p = getattr(pose, name)
            u, v = sc.project(intr, p)
            ww = w if name in ("right_hand", "left_hand") else 0.5 * w if name.endswith("wrist") else 0.0
            ww *= self.skeleton_bias
            sigma_px = (2.0 + 10.0 * ww) * k
            # joined hands: each joint is pulled half-way to the pair's middle
            pull = 0.5 * min(ww, 1.0)
            u += pull * (mid[0] - u) + sigma_px * noise[j, 0]
            v += pull * (mid[1] - v) + sigma_px * noise[j, 1]
            z_mm = p[2] * 1000.0 + 15.0 * (1.0 + 2.0 * ww) * noise[j, 2]
            conf = 0.9 - 0.6 * min(ww, 1.0) + conf_noise[j]
            out[name] = Joint(u, v, max(z_mm, 0.0), min(max(conf, 0.0), 1.0))
        return out

    # -- pixels -------------------------------------------------------------------------------

    @staticmethod
    def _gaussian(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
        """Standard-normal float32 noise of ``shape`` (via :data:`_NORMAL_TABLE`)."""
        count = math.prod(shape)
        index = np.frombuffer(rng.bytes(2 * count), dtype="<u2")
        return np.take(_NORMAL_TABLE, index).reshape(shape)

    def _stereo_valid(self, depth_m: np.ndarray) -> np.ndarray:
        """False where the second camera (``BASELINE_MM`` to the right) cannot see the point:
        hidden behind a nearer surface (both models) or, in the realistic model, outside its
        image (a band on the left border as wide as the disparity)."""
        disparity = (self.intrinsics.fx * BASELINE_MM * 1e-3) / depth_m
        x_right = np.arange(depth_m.shape[1], dtype=np.float32)[None, :] - disparity
        ahead = np.minimum.accumulate(x_right[:, ::-1], axis=1)[:, ::-1]
        valid = np.ones(depth_m.shape, bool)
        valid[:, :-1] = ahead[:, 1:] >= x_right[:, :-1]
        if self.depth_model == "realistic":
            valid &= x_right >= -0.5
        return valid

    def depth_image(self, depth_m: np.ndarray, rng: np.random.Generator | int) -> np.ndarray:
        """The sensor's depth image of a true depth map, with this source's depth model.

        Parameters
        ----------
        depth_m : ndarray, shape (H, W), float32
            True depth in metres (> 0), of this source's size.
        rng : Generator or int
            Noise source (:func:`fusion_pf.rng.as_rng`).

        Returns
        -------
        ndarray, shape (H, W), uint16
            Millimetres, 0 = invalid.
        """
        from fusion_pf.rng import as_rng

        depth_m = np.asarray(depth_m, dtype=np.float32)
        if depth_m.shape != (self.size[1], self.size[0]) or not (depth_m > 0).all():
            raise InputError(
                f"depth_m must be a positive ({self.size[1]}, {self.size[0]}) array, got shape {depth_m.shape}"
            )
        return self._depth_image(depth_m, self._stereo_valid(depth_m), as_rng(rng))

    def _depth_image(self, depth_m: np.ndarray, valid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        if self.depth_model == "realistic":
            return self._realistic_depth(depth_m, valid, rng)
        return self._basic_depth(depth_m, valid, rng)

    def _realistic_depth(self, depth_m: np.ndarray, valid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Depth (mm, uint16) of a stereo sensor (module docstring, "Depth"): mixed disparities and
        LR-check holes at depth steps, correlated disparity noise, sub-pixel quantisation,
        stereo shadows and border band, search-range and range limits, speckle blobs."""
        fb = np.float32(self.intrinsics.fx * BASELINE_MM)
        disparity = np.float32(fb * 1e-3) / depth_m
        window = np.ones((2 * EDGE_BAND_PX + 1, 2 * EDGE_BAND_PX + 1), np.uint8)
        near, far = cv2.dilate(disparity, window), cv2.erode(disparity, window)
        band = np.flatnonzero(near - far > np.float32(EDGE_STEP_PX))
        draw = rng.random((2, band.size), dtype=np.float32)
        flat = disparity.reshape(-1)
        mixed = (draw[0] >= EDGE_INVALID_FRACTION) & (draw[0] < EDGE_INVALID_FRACTION + EDGE_FLYING_FRACTION)
        flying, a = band[mixed], draw[1][mixed]
        flat[flying] = (1.0 - a) * near.reshape(-1)[flying] + a * far.reshape(-1)[flying]
        noise = self._gaussian(rng, depth_m.shape)
        field = cv2.GaussianBlur(noise, (_CORR_KSIZE, _CORR_KSIZE), DEPTH_NOISE_CORRELATION_PX)
        disparity += np.float32(self.depth_noise * DISPARITY_NOISE_PX / _CORR_STD) * field
        disparity = np.rint(disparity * SUBPIXEL_STEPS) / np.float32(SUBPIXEL_STEPS)
        with np.errstate(divide="ignore"):
            z = np.rint(fb / disparity)
        blobs = cv2.GaussianBlur(self._gaussian(rng, depth_m.shape), (0, 0), SPECKLE_BLOB_PX)
        holes = blobs > np.float32(_SPECKLE_THRESHOLD * float(blobs.std()))
        bad = ~valid | holes | (depth_m > np.float32(MAX_RANGE_MM * 1e-3)) | ~(disparity > 0)
        bad |= (disparity > np.float32(MAX_DISPARITY_PX)) | (z > 65535)
        bad.reshape(-1)[band[draw[0] < EDGE_INVALID_FRACTION]] = True
        z[bad] = 0
        return z.astype(np.uint16)

    def _basic_depth(self, depth_m: np.ndarray, valid: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Stereo-like depth (mm, uint16) from the true depth: correlated disparity noise,
        sub-pixel quantisation, shadows, speckles, range limit."""
        fb = self.intrinsics.fx * BASELINE_MM
        disparity = np.float32(fb * 1e-3) / depth_m
        noise = self._gaussian(rng, depth_m.shape)
        field = cv2.GaussianBlur(noise, (_CORR_KSIZE, _CORR_KSIZE), DEPTH_NOISE_CORRELATION_PX)
        disparity += np.float32(self.depth_noise * DEPTH_NOISE_C * fb / _CORR_STD) * field
        disparity = np.rint(disparity * SUBPIXEL_STEPS) / np.float32(SUBPIXEL_STEPS)
        with np.errstate(divide="ignore"):
            z = np.rint(np.float32(fb) / disparity)
        z[~valid | (depth_m > np.float32(MAX_RANGE_MM * 1e-3)) | ~(disparity > 0) | (z > 65535)] = 0
        out = z.astype(np.uint16)
        n = int(rng.binomial(out.size, SPECKLE_FRACTION))
        out.reshape(-1)[rng.integers(0, out.size, size=n)] = 0
        return out

    def blur_kernel(self, index: int) -> np.ndarray | None:
        """Motion-blur kernel of the moving arm at frame ``index`` (None: background frame or slow palm).

        The palm's image displacement during the exposure (centred on the frame
        time, :data:`EXPOSURE_FRACTION` of the frame period) as a line kernel;
        None when the palm moves at most :data:`MIN_BLUR_SPEED_PX` per frame, and
        always in the two-hand scene.
        """
        index = self._check_index(index)
        if index < self.background_frames or self._wash is not None:
            return None
        t = float(index - self.background_frames)
        half = EXPOSURE_FRACTION / 2.0
        ua, va = sc.project(self.intrinsics, sc.pose_at(self._motion, t - half).right_hand)
        ub, vb = sc.project(self.intrinsics, sc.pose_at(self._motion, t + half).right_hand)
        if math.hypot(ub - ua, vb - va) <= MIN_BLUR_SPEED_PX * EXPOSURE_FRACTION:
            return None
        return sc.motion_kernel(ub - ua, vb - va)

    def illumination(self, index: int) -> np.ndarray:
        """Relative illumination gain of frame ``index`` per column, shape (1, W) (flicker excluded)."""
        return sc.illumination(self._appearance, self._check_index(index), self._xn)

    def _color_image(self, color: np.ndarray, index: int, rng: np.random.Generator) -> np.ndarray:
        gain = np.float32(1.0 + self.lighting * rng.uniform(-FLICKER, FLICKER))
        blurred = cv2.GaussianBlur(color, (3, 3), 0.0)
        blurred *= (gain * self.illumination(index))[..., None]
        noise = self._gaussian(rng, color.shape)
        return cv2.addWeighted(blurred, 1.0, noise, COLOR_NOISE_SIGMA, 0.0, dtype=cv2.CV_8U)

    def _composite(self, index: int, pose: sc.Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The noise-free colour, true depth (m) and labels of person frame ``index`` (:func:`sc.composite`)."""
        if self._wash is not None:
            parts = sc.wash_parts(self.intrinsics, pose, self._appearance.sleeve_fraction, self._skin, self._shirt)
            ball = self.object_centre(index)
            if ball is not None and (part := sc.object_part(self.intrinsics, ball)) is not None:
                parts.append(part)
            return sc.composite(self._background, parts)
        parts = sc.person_parts(self.intrinsics, pose, self._appearance.sleeve_fraction, self._skin, self._shirt)
        return sc.composite(self._background, parts, self.blur_kernel(index))

    def render(self, index: int) -> tuple[Frame, dict[str, np.ndarray]]:
        """Render frame ``index``.

        Parameters
        ----------
        index : int
            Frame index in ``[0, len(self))``.

        Returns
        -------
        frame : Frame
            Colour, depth, intrinsics, joints, ground truth, background flag.
        masks : dict of str to ndarray
            Boolean (H, W) masks of the noise-free, unblurred scene:
            ``"skin"`` (face, neck, both hands, bare right forearm), ``"palm"``
            (the tracked right palm only; two hands: both palms), ``"person"``.
        """
        index = self._check_index(index)
        pose = self.pose(index)
        rng = self._rng(1, index)
        bg = self._background
        if pose is None:
            color_f, depth_m = bg.color, bg.depth_m
            labels = np.zeros(depth_m.shape, np.uint8)
            valid = self._bg_depth_valid
        else:
            color_f, depth_m, labels = self._composite(index, pose)
            valid = self._stereo_valid(depth_m)
        color = self._color_image(color_f, index, rng)
        depth = self._depth_image(depth_m, valid, rng)
        frame = Frame(
            timestamp_ns=self.timestamp_ns(index),
            seq=index,
            color=color,
            depth=depth,
            intrinsics=self.intrinsics,
            joints=self.joints(index),
            ground_truth=self.ground_truth(index),
            background=index < self.background_frames,
            ground_truths=self.ground_truths(index),
        )
        masks = {
            "skin": labels >= sc.LABEL_SKIN,
            "palm": labels == sc.LABEL_PALM,
            "person": labels != sc.LABEL_BACKGROUND,
        }
        return frame, masks
