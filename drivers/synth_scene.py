"""Geometry and rasterisation of the synthetic scene behind :class:`drivers.synth.SynthSource`.

The scene lives in camera coordinates (metres; X right, Y down, Z forward) and is
projected with a pinhole camera. Everything that does not move (the wall, the
shelving unit, the doorway, the painting, vignetting) is rendered once into
:class:`Background`; every frame then rasterises the person part by part inside
small regions of interest and composites the parts with a z-buffer.

The right forearm (pushed-up sleeve and bare skin) and the palm form a moving
layer that :func:`composite` can motion-blur with a line kernel
(:func:`motion_kernel`); :func:`illumination` gives the slow lighting drift
applied to the whole image.

This module holds no randomness of its own: the random scene parameters
(:class:`Motion`, :class:`Appearance`) and the static textures are drawn by
the caller from the seed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from fusion_pf.frame import Intrinsics

#: Pixel labels of the rendered label map.
LABEL_BACKGROUND, LABEL_CLOTH, LABEL_SKIN, LABEL_PALM = 0, 1, 2, 3

#: Base colours (RGB, 0-255, before shading, vignetting and flicker).
WALL_RGB = (148.0, 158.0, 174.0)
SHELF_RGB = (214.0, 214.0, 208.0)
SHELF_BACK_RGB = (184.0, 185.0, 182.0)
DOOR_FRAME_RGB = (222.0, 222.0, 216.0)
DOORWAY_RGB = (92.0, 96.0, 104.0)
SHIRT_RGB = (30.0, 38.0, 70.0)
TROUSERS_RGB = (46.0, 46.0, 52.0)
HAIR_RGB = (46.0, 34.0, 28.0)
SKIN_RGB = (218.0, 168.0, 142.0)
#: The darkest skin tone of the ``skin_tone`` scene option (1.0); 0.0 is :data:`SKIN_RGB`.
DARK_SKIN_RGB = (92.0, 60.0, 44.0)
#: Shirt colours of the ``clothing`` scene option (index 0, the default, is :data:`SHIRT_RGB`;
#: a fractional index blends the two neighbours): navy, a skin-like beige, a wood-like
#: brown, red, light grey, dark green. Beige and brown are the hard cases for skin cues.
CLOTHING_PALETTE = (
    SHIRT_RGB,
    (214.0, 170.0, 138.0),
    (150.0, 100.0, 62.0),
    (158.0, 36.0, 40.0),
    (196.0, 198.0, 200.0),
    (40.0, 84.0, 52.0),
)
#: Colours of the ``clutter`` objects that are not skin-coloured: wood, light wood, white,
#: red, blue, green, yellow, black.
CLUTTER_PALETTE = (
    (128.0, 84.0, 52.0),
    (196.0, 152.0, 106.0),
    (232.0, 232.0, 228.0),
    (176.0, 40.0, 36.0),
    (40.0, 70.0, 150.0),
    (60.0, 130.0, 70.0),
    (220.0, 190.0, 60.0),
    (30.0, 30.0, 32.0),
)
#: Pale box colours on the shelves (kept away from skin tones on purpose).
BOX_PALETTE = (
    (226.0, 226.0, 222.0),
    (172.0, 182.0, 194.0),
    (196.0, 210.0, 200.0),
    (206.0, 206.0, 218.0),
)

#: Body dimensions in metres.
SHOULDER_HALF_WIDTH = 0.18
CHEST_HALF_WIDTH = 0.19
SHOULDER_Y = -0.17
HIP_Y = 0.35
UPPER_ARM, FOREARM, HAND = 0.30, 0.27, 0.08
UPPER_ARM_RADIUS, FOREARM_RADIUS = 0.052, 0.042
PALM_HALF_WIDTH, PALM_HALF_LENGTH, PALM_THICKNESS = 0.05, 0.065, 0.02
#: Radius (metres) of the bare right forearm below the pushed-up sleeve.
BARE_FOREARM_RADIUS = 0.034
#: Half width and half height (metres) of the face, the skin ellipse of the head.
FACE_HALF_SIZE = (0.074, 0.1)
#: Colour of an occluding card (:func:`card_part`): a matte olive grey, neither skin nor clothing.
CARD_RGB = (104.0, 112.0, 88.0)


@dataclass(frozen=True)
class Background:
    """The static empty scene, rendered once.

    Attributes
    ----------
    color : ndarray, shape (H, W, 3), float32
        Noise-free RGB in grey levels, vignetting applied.
    depth_m : ndarray, shape (H, W), float32
        True depth in metres.
    vignette : ndarray, shape (H, W, 1), float32
        Multiplicative fall-off of the lens, applied to every rendered pixel.
    """

    color: np.ndarray
    depth_m: np.ndarray
    vignette: np.ndarray


@dataclass(frozen=True)
class Motion:
    """Random parameters of the person's motion, drawn once per seed.

    All periods are in frames; ``x0``, ``z0`` in metres; the palm amplitudes in
    normalised image units (pixels / fx).
    """

    x0: float
    z0: float
    sway_period: float
    sway_phase: float
    depth_sway_period: float
    depth_sway_phase: float
    palm_period: float
    palm_phase: float
    palm_mod_period: float
    palm_mod_phase: float
    palm_mod_depth: float
    palm_amp_x: float
    palm_offset: float
    palm_y_mid: float
    palm_amp_y: float
    palm_y_period: float
    palm_y_phase: float
    left_arm_period: float
    left_arm_phase: float
    bias_period: float
    bias_phase: float
    hand_front: float = 0.22


@dataclass(frozen=True)
class Appearance:
    """Random appearance and lighting parameters, drawn once per seed.

    Attributes
    ----------
    sleeve_fraction : float
        Where the pushed-up right sleeve ends, as a fraction of the forearm's
        length measured from the wrist (the forearm is bare up to there).
    drift_amps, drift_periods, drift_phases : tuple of float
        Global illumination drift ``sum amp * sin(2 pi i / period + phase)``
        over the frame index ``i`` (relative gain).
    gradient_amp, gradient_period, gradient_phase : float
        Drift of a horizontal illumination gradient (relative gain per
        normalised image unit ``x = (u - cx) / fx``).
    """

    sleeve_fraction: float
    drift_amps: tuple[float, ...]
    drift_periods: tuple[float, ...]
    drift_phases: tuple[float, ...]
    gradient_amp: float
    gradient_period: float
    gradient_phase: float


@dataclass(frozen=True)
class Pose:
    """3-D joint positions (metres, camera frame) of one person frame."""

    torso: np.ndarray
    head: np.ndarray
    right_shoulder: np.ndarray
    left_shoulder: np.ndarray
    right_elbow: np.ndarray
    left_elbow: np.ndarray
    right_wrist: np.ndarray
    left_wrist: np.ndarray
    right_hand: np.ndarray
    left_hand: np.ndarray


def default_intrinsics(width: int, height: int) -> Intrinsics:
    """The synthetic camera: an OAK-D-like pinhole, ``fx = fy = 0.78 * width``.

    ``0.78 * width`` gives a 65.3 degree horizontal field of view (the OAK-D colour
    camera at 16:10 is about 69 degrees); the principal point is the image centre
    and the image is rectified (distortion ``"none"``).
    """
    f = 0.78 * width
    return Intrinsics(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0, "none", ())


def _smooth_field(rng: np.random.Generator, shape: tuple[int, int], cells: tuple[int, int]) -> np.ndarray:
    """Zero-mean, unit-range smooth noise of ``shape`` from a ``cells`` grid (bicubic)."""
    coarse = rng.uniform(-1.0, 1.0, size=cells).astype(np.float32)
    return cv2.resize(coarse, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)


def _box(xn: np.ndarray, yn: np.ndarray, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    return (xn >= x0) & (xn < x1) & (yn >= y0) & (yn < y1)


def render_background(intr: Intrinsics, rng: np.random.Generator) -> Background:
    """Render the static scene: a slanted bluish-grey wall, a white shelving unit
    on the left (with pale boxes), an open doorway on the right (beyond the
    depth range) and a painting.

    Objects are placed in normalised image coordinates ``x = (u - cx) / fx``,
    ``y = (v - cy) / fy`` so the scene looks the same at every image size.
    """
    h, w = intr.height, intr.width
    xn = ((np.arange(w, dtype=np.float32) - intr.cx) / intr.fx)[None, :]
    yn = ((np.arange(h, dtype=np.float32) - intr.cy) / intr.fy)[:, None]
    xn, yn = np.broadcast_to(xn, (h, w)), np.broadcast_to(yn, (h, w))
    color = np.empty((h, w, 3), np.float32)
    color[:] = WALL_RGB
    texture = 7.0 * _smooth_field(rng, (h, w), (9, 14)) + 2.0 * _smooth_field(rng, (h, w), (60, 96))
    color += texture[..., None]
    depth = (3.0 + 0.3 * xn).astype(np.float32)

    # Painting on the wall, upper right of the person's head.
    painting = _box(xn, yn, 0.22, 0.36, -0.36, -0.20)
    canvas = np.stack([_smooth_field(rng, (h, w), (3, 4)) for _ in range(3)], axis=-1)
    color[painting] = 150.0 + 60.0 * canvas[painting]
    border = _box(xn, yn, 0.21, 0.37, -0.37, -0.19) & ~painting
    color[border] = DOOR_FRAME_RGB
    depth[painting | border] -= 0.02

    # Open doorway: the room behind is beyond the sensor's range.
    door_frame = _box(xn, yn, 0.415, 0.615, -0.36, 1.0)
    doorway = _box(xn, yn, 0.43, 0.60, -0.345, 1.0)
    color[door_frame] = DOOR_FRAME_RGB
    color[doorway] = np.asarray(DOORWAY_RGB, np.float32) * (0.85 + 0.15 * (yn[doorway] + 0.35))[:, None]
    depth[doorway] = 5.5

    # White shelving unit on the left: frame at 2.35 m, back panel at 2.65 m.
    unit = _box(xn, yn, -1.0, -0.34, -0.02, 1.0)
    color[unit] = SHELF_RGB
    depth[unit] = 2.35
    boards = (-0.02, 0.13, 0.28, 0.43)
    for top, bottom in zip(boards[:-1], boards[1:]):
        bay = _box(xn, yn, -1.0, -0.355, top + 0.014, bottom)
        color[bay] = SHELF_BACK_RGB
        depth[bay] = 2.65
        left = -0.355
        while left > xn[0, 0]:
            width = float(rng.uniform(0.04, 0.09))
            height = float(rng.uniform(0.05, 0.12))
            item = _box(xn, yn, left - width, left - 0.005, bottom - height, bottom)
            color[item] = BOX_PALETTE[int(rng.integers(len(BOX_PALETTE)))]
            depth[item] = 2.45
            left -= width + float(rng.uniform(0.01, 0.05))
    vignette = (1.0 - 0.12 * (xn**2 + yn**2) / 0.58).astype(np.float32)[..., None]
    return Background(color * vignette, depth, vignette)


def motion_parameters(rng: np.random.Generator) -> Motion:
    """Draw the person's motion parameters (smooth, periodic, seed-dependent)."""
    u = rng.uniform
    palm_period = float(u(80.0, 105.0))
    return Motion(
        x0=float(u(0.09, 0.15)),
        z0=float(u(1.45, 1.6)),
        sway_period=float(u(150.0, 220.0)),
        sway_phase=float(u(0, 2 * math.pi)),
        depth_sway_period=float(u(170.0, 260.0)),
        depth_sway_phase=float(u(0, 2 * math.pi)),
        palm_period=palm_period,
        palm_phase=float(u(0, 2 * math.pi)),
        palm_mod_period=palm_period * float(u(2.3, 3.1)),
        palm_mod_phase=float(u(0, 2 * math.pi)),
        palm_mod_depth=float(u(0.3, 0.6)),
        palm_amp_x=float(u(0.22, 0.26)),
        palm_offset=0.55,
        palm_y_mid=float(u(0.03, 0.07)),
        palm_amp_y=float(u(0.09, 0.12)),
        palm_y_period=palm_period * float(u(0.6, 0.8)),
        palm_y_phase=float(u(0, 2 * math.pi)),
        left_arm_period=float(u(90.0, 140.0)),
        left_arm_phase=float(u(0, 2 * math.pi)),
        bias_period=float(u(40.0, 70.0)),
        bias_phase=float(u(0, 2 * math.pi)),
    )


def appearance_parameters(rng: np.random.Generator) -> Appearance:
    """Draw the sleeve position and the illumination drift (seed-dependent)."""
    u = rng.uniform
    return Appearance(
        sleeve_fraction=float(u(0.3, 0.7)),
        drift_amps=(float(u(0.02, 0.035)), float(u(0.025, 0.045))),
        drift_periods=(float(u(50.0, 110.0)), float(u(160.0, 320.0))),
        drift_phases=(float(u(0, 2 * math.pi)), float(u(0, 2 * math.pi))),
        gradient_amp=float(u(0.01, 0.025)),
        gradient_period=float(u(120.0, 260.0)),
        gradient_phase=float(u(0, 2 * math.pi)),
    )


def illumination(a: Appearance, index: int, xn: np.ndarray) -> np.ndarray:
    """Relative illumination gain of frame ``index`` at normalised columns ``xn``.

    Parameters
    ----------
    a : Appearance
        Drift parameters.
    index : int
        Frame index (the drift runs through the background frames too).
    xn : ndarray, shape (1, W)
        Normalised image column coordinates ``(u - cx) / fx``.

    Returns
    -------
    ndarray, shape (1, W), float32
        ``1 + global drift + gradient drift * xn``.
    """
    two_pi = 2.0 * math.pi
    drift = sum(
        amp * math.sin(two_pi * index / period + phase)
        for amp, period, phase in zip(a.drift_amps, a.drift_periods, a.drift_phases)
    )
    slope = a.gradient_amp * math.sin(two_pi * index / a.gradient_period + a.gradient_phase)
    return (1.0 + drift + slope * xn).astype(np.float32)


def motion_kernel(du: float, dv: float) -> np.ndarray:
    """Normalised line kernel of a blur by ``(du, dv)`` pixels, centred on the kernel's middle.

    The segment from ``-(du, dv) / 2`` to ``+(du, dv) / 2`` is sampled every
    1/4 px and splatted bilinearly, so the kernel has no net shift.

    Returns
    -------
    ndarray, shape (k, k), float32
        Sums to 1; ``k`` odd.
    """
    length = math.hypot(du, dv)
    half = math.ceil(length / 2.0) + 1
    k = 2 * half + 1
    n = max(2, math.ceil(4.0 * length) + 1)
    t = np.linspace(-0.5, 0.5, n)
    x, y = half + t * du, half + t * dv
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = x - x0, y - y0
    kernel = np.zeros((k, k), np.float64)
    for dx, dy, wgt in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(kernel, (y0 + dy, x0 + dx), wgt)
    return (kernel / kernel.sum()).astype(np.float32)


def _elbow(shoulder: np.ndarray, wrist: np.ndarray, pole: np.ndarray) -> np.ndarray:
    """Two-link inverse kinematics: the elbow bends toward ``pole``."""
    d_vec = wrist - shoulder
    d = float(np.linalg.norm(d_vec))
    axis = d_vec / d
    a = min(max((UPPER_ARM**2 - FOREARM**2 + d * d) / (2.0 * d), 0.0), UPPER_ARM)
    bend = math.sqrt(max(UPPER_ARM**2 - a * a, 0.0))
    side = pole - np.dot(pole, axis) * axis
    side /= np.linalg.norm(side)
    return shoulder + a * axis + bend * side


def _body_at(m: Motion, t: float) -> tuple[float, float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The swaying body at time ``t`` (frames): torso x and z (m), torso centre, head and both shoulders (m)."""
    two_pi = 2.0 * math.pi
    tx = m.x0 + 0.025 * math.sin(two_pi * t / m.sway_period + m.sway_phase)
    tz = m.z0 + 0.02 * math.sin(two_pi * t / m.depth_sway_period + m.depth_sway_phase)
    torso = np.array([tx, (SHOULDER_Y + HIP_Y) / 2.0, tz])
    head = np.array([tx, -0.37, tz - 0.02])
    r_sh = np.array([tx - SHOULDER_HALF_WIDTH, SHOULDER_Y + 0.045, tz])
    l_sh = np.array([tx + SHOULDER_HALF_WIDTH, SHOULDER_Y + 0.045, tz])
    return tx, tz, torso, head, r_sh, l_sh


def pose_at(m: Motion, t: float) -> Pose:
    """The person's pose at person-frame ``t`` (frames since the first non-empty frame).

    The right palm follows ``x = x_edge + amp_x (sin theta - offset)`` in
    normalised image units, ``x_edge`` being the image position of the torso's
    outline at chest height (the person's right side, image left), with a
    frequency-modulated phase ``theta``; its vertical position is a second
    sinusoid between shoulder and hip height and its depth is ``hand_front``
    to ``hand_front + 0.10`` m (0.22-0.32 by default) in front of the torso
    (closest when furthest across the body). The arm follows
    by two-link inverse kinematics; the left arm hangs and swings slightly.
    """
    two_pi = 2.0 * math.pi
    tx, tz, torso, head, r_sh, l_sh = _body_at(m, t)

    theta = (
        two_pi * t / m.palm_period
        + m.palm_phase
        + m.palm_mod_depth * math.sin(two_pi * t / m.palm_mod_period + m.palm_mod_phase)
    )
    s = math.sin(theta)
    pz = tz - m.hand_front - 0.10 * (s + 1.0) / 2.0
    x_edge = (tx - CHEST_HALF_WIDTH) / tz
    px = x_edge + m.palm_amp_x * (s - m.palm_offset) + 0.02 * math.sin(2.0 * theta)
    py = m.palm_y_mid + m.palm_amp_y * math.sin(two_pi * t / m.palm_y_period + m.palm_y_phase)
    palm = np.array([px * pz, py * pz, pz])
    to_palm = palm - r_sh
    r_wr = palm - HAND * to_palm / np.linalg.norm(to_palm)
    r_el = _elbow(r_sh, r_wr, np.array([-0.5, 1.0, 0.3]))

    swing = 0.12 * math.sin(two_pi * t / m.left_arm_period + m.left_arm_phase)
    c, sn = math.cos(swing), math.sin(swing)
    upper = np.array([0.17 * c - 0.985 * sn, 0.17 * sn + 0.985 * c, 0.03]) * UPPER_ARM
    l_el = l_sh + upper
    lower_dir = np.array([-0.05 * c - 0.99 * sn, -0.05 * sn + 0.99 * c, -0.12])
    lower_dir /= np.linalg.norm(lower_dir)
    l_wr = l_el + FOREARM * lower_dir
    l_hand = l_wr + HAND * lower_dir
    return Pose(torso, head, r_sh, l_sh, r_el, l_el, r_wr, l_wr, palm, l_hand)


def project(intr: Intrinsics, p: np.ndarray) -> tuple[float, float]:
    """Pixel ``(u, v)`` of the 3-D point ``p`` (metres)."""
    return intr.fx * p[0] / p[2] + intr.cx, intr.fy * p[1] / p[2] + intr.cy


@dataclass
class Part:
    """One rasterised body part inside its region of interest.

    ``rows``/``cols`` slice the image; ``mask``, ``depth`` (metres) and ``shade``
    (a brightness factor) have the shape of that slice. ``moving`` parts (the
    right forearm and palm) form the layer that :func:`composite` motion-blurs.
    """

    rows: slice
    cols: slice
    mask: np.ndarray
    depth: np.ndarray
    shade: np.ndarray
    rgb: tuple[float, float, float]
    label: int
    on_top: bool = False
    moving: bool = False


def _grid(intr: Intrinsics, u0: float, u1: float, v0: float, v1: float, clip: bool = True):
    """Pixel-centre grids (broadcastable (1, w) and (h, 1)) over a bounding box."""
    c0, c1 = int(math.floor(u0)), int(math.ceil(u1)) + 1
    r0, r1 = int(math.floor(v0)), int(math.ceil(v1)) + 1
    if clip:
        c0, c1 = max(c0, 0), min(c1, intr.width)
        r0, r1 = max(r0, 0), min(r1, intr.height)
    if c1 <= c0 or r1 <= r0:
        return None
    uu = np.arange(c0, c1, dtype=np.float32)[None, :]
    vv = np.arange(r0, r1, dtype=np.float32)[:, None]
    return slice(r0, r1), slice(c0, c1), uu, vv


def ellipse_mask(intr: Intrinsics, centre: np.ndarray, half_w: float, half_h: float, angle: float, clip: bool = True):
    """Rasterise an image-plane ellipse of a disc at 3-D ``centre``.

    ``half_w``/``half_h`` are semi-axes in metres (scaled by ``f / z``), ``angle``
    the direction of the ``half_h`` axis in the image (radians). Returns
    ``(rows, cols, mask, q, du, dv)`` with ``q`` the normalised squared radius, or
    None when the ellipse is outside the image.
    """
    cu, cv = project(intr, centre)
    a = half_w * intr.fx / centre[2]
    b = half_h * intr.fy / centre[2]
    r = max(a, b)
    g = _grid(intr, cu - r, cu + r, cv - r, cv + r, clip)
    if g is None:
        return None
    rows, cols, uu, vv = g
    du, dv = uu - np.float32(cu), vv - np.float32(cv)
    ca, sa = math.cos(angle), math.sin(angle)
    along = du * ca + dv * sa
    across = -du * sa + dv * ca
    q = (across / a) ** 2 + (along / b) ** 2
    return rows, cols, q <= 1.0, q, du, dv


def _ellipse_part(intr, centre, half_w, half_h, angle, thickness, rgb, label, on_top=False):
    """A disc-like part (head, face, hand) bulging by ``thickness`` metres, lit from the upper left."""
    e = ellipse_mask(intr, centre, half_w, half_h, angle)
    if e is None:
        return None
    rows, cols, mask, q, du, dv = e
    height = np.sqrt(np.maximum(1.0 - q, 0.0))
    r = max(half_w, half_h) * intr.fx / centre[2]
    shade = 0.80 + 0.20 * height - 0.07 * (du + dv) / r
    depth = np.float32(centre[2]) - np.float32(thickness) * height
    return Part(rows, cols, mask, depth, shade, rgb, label, on_top)


def _capsule_part(intr, a3, b3, radius, rgb, label, round_start=True):
    """A cylinder with round ends (a sleeve) from ``a3`` to ``b3``, ``radius`` metres thick.

    With ``round_start`` False the end at ``a3`` is cut flat (where a bare
    forearm leaves its sleeve).
    """
    ua, va = project(intr, a3)
    ub, vb = project(intr, b3)
    ra, rb = radius * intr.fx / a3[2], radius * intr.fx / b3[2]
    r = max(ra, rb)
    g = _grid(intr, min(ua, ub) - r, max(ua, ub) + r, min(va, vb) - r, max(va, vb) + r)
    if g is None:
        return None
    rows, cols, uu, vv = g
    eu, ev = ub - ua, vb - va
    length2 = max(eu * eu + ev * ev, 1e-9)
    along = ((uu - ua) * eu + (vv - va) * ev) / length2
    t = np.clip(along, 0.0, 1.0)
    dist = np.hypot(uu - (ua + t * eu), vv - (va + t * ev))
    rad = ra + t * (rb - ra)
    mask = dist <= rad
    if not round_start:
        mask &= along >= 0.0
    height = np.sqrt(np.maximum(1.0 - (dist / rad) ** 2, 0.0))
    depth = (a3[2] + t * (b3[2] - a3[2]) - radius * height).astype(np.float32)
    shade = 0.70 + 0.35 * height
    return Part(rows, cols, mask, depth, shade, rgb, label)


def _polygon_part(intr, points3, centre_x, half_width, bulge, rgb, label):
    """A flat-ish polygon (torso, legs) bulging by ``bulge`` metres at ``centre_x``."""
    uv = np.array([project(intr, p) for p in points3])
    u0, v0 = uv.min(axis=0)
    u1, v1 = uv.max(axis=0)
    g = _grid(intr, u0, u1, v0, v1)
    if g is None:
        return None
    rows, cols, uu, _ = g
    z = float(points3[0][2])
    mask = _fill_polygon(intr, points3, rows, cols)
    cu = intr.fx * centre_x / z + intr.cx
    half = half_width * intr.fx / z
    height = np.sqrt(np.maximum(1.0 - ((uu - cu) / half) ** 2, 0.0))
    depth = np.broadcast_to((z - bulge * height).astype(np.float32), mask.shape)
    shade = np.broadcast_to(0.74 + 0.30 * height, mask.shape)
    return Part(rows, cols, mask, depth, shade, rgb, label)


def _drop(pose: Pose) -> float:
    """How far (metres, down) the torso is from its place in the single-camera scene (0 there).

    The outlines of torso, neck and legs follow the torso by it, so a camera
    that sees the person from another height (:mod:`drivers.synth_rig`) draws them
    around the body.
    """
    return float(pose.torso[1]) - (SHOULDER_Y + HIP_Y) / 2.0


def torso_outline(pose: Pose) -> list[np.ndarray]:
    """3-D outline of the torso (a shirt from shoulders to hips)."""
    x, z = pose.torso[0], pose.torso[2]
    ys = SHOULDER_Y
    dy = _drop(pose)
    pts = [
        (-0.20, ys + 0.03),
        (-0.07, ys - 0.01),
        (0.07, ys - 0.01),
        (0.20, ys + 0.03),
        (CHEST_HALF_WIDTH, ys + 0.16),
        (0.16, 0.22),
        (0.17, HIP_Y),
        (-0.17, HIP_Y),
        (-0.16, 0.22),
        (-CHEST_HALF_WIDTH, ys + 0.16),
    ]
    return [np.array([x + dx, y + dy, z]) for dx, y in pts]


def _hand_angle(intr: Intrinsics, wrist: np.ndarray, hand: np.ndarray) -> float:
    wu, wv = project(intr, wrist)
    hu, hv = project(intr, hand)
    return math.atan2(hv - wv, hu - wu)


def palm_mask(intr: Intrinsics, pose: Pose, clip: bool = True):
    """The right palm ellipse: ``(rows, cols, mask, q, du, dv)`` as :func:`ellipse_mask`."""
    angle = _hand_angle(intr, pose.right_wrist, pose.right_hand)
    return ellipse_mask(intr, pose.right_hand, PALM_HALF_WIDTH, PALM_HALF_LENGTH, angle, clip)


def _fill_polygon(intr: Intrinsics, points3: list[np.ndarray], rows: slice, cols: slice) -> np.ndarray:
    """Boolean mask over ``rows`` x ``cols`` of the projected polygon (1/16 px precision)."""
    mask = np.zeros((rows.stop - rows.start, cols.stop - cols.start), np.uint8)
    shift = 4
    uv = np.array([project(intr, p) for p in points3])
    local = np.round((uv - [cols.start, rows.start]) * (1 << shift)).astype(np.int32)
    cv2.fillPoly(mask, [local], 1, lineType=cv2.LINE_8, shift=shift)
    return mask.astype(bool)


def _neck_outline(pose: Pose) -> list[np.ndarray]:
    x, z, dy = pose.torso[0], pose.torso[2] - 0.04, _drop(pose)
    return [
        np.array([x + dx, y + dy, z])
        for dx, y in ((-0.055, -0.29), (0.055, -0.29), (0.055, SHOULDER_Y), (-0.055, SHOULDER_Y))
    ]


def body_region(intr: Intrinsics, pose: Pose, rows: slice, cols: slice) -> np.ndarray:
    """Boolean mask, over ``rows`` x ``cols`` (may exceed the image), of the
    torso, neck and head silhouettes, whatever is in front of them."""
    out = _fill_polygon(intr, torso_outline(pose), rows, cols)
    out |= _fill_polygon(intr, _neck_outline(pose), rows, cols)
    uu = np.arange(cols.start, cols.stop, dtype=np.float32)[None, :]
    vv = np.arange(rows.start, rows.stop, dtype=np.float32)[:, None]
    hu, hv = project(intr, pose.head)
    a, b = 0.088 * intr.fx / pose.head[2], 0.115 * intr.fy / pose.head[2]
    out |= ((uu - hu) / a) ** 2 + ((vv - hv) / b) ** 2 <= 1.0
    return out


def palm_overlap(intr: Intrinsics, pose: Pose) -> float:
    """Fraction of the right palm's area that lies over the torso/head region."""
    rows, cols, mask, *_ = palm_mask(intr, pose, clip=False)
    area = int(mask.sum())
    if area == 0:
        return 0.0
    return float((mask & body_region(intr, pose, rows, cols)).sum()) / area


def skin_rgb(tone: float) -> tuple[float, float, float]:
    """Skin colour of ``tone`` in [0, 1]: :data:`SKIN_RGB` (0) blended linearly into :data:`DARK_SKIN_RGB` (1)."""
    return tuple(float(a + tone * (b - a)) for a, b in zip(SKIN_RGB, DARK_SKIN_RGB))  # type: ignore[return-value]


def clothing_rgb(index: float) -> tuple[float, float, float]:
    """Shirt colour of ``index`` in ``[0, len(CLOTHING_PALETTE) - 1]``: a palette entry, fractions blend linearly."""
    i = min(int(index), len(CLOTHING_PALETTE) - 2)
    t = index - i
    if t == 0.0:
        return CLOTHING_PALETTE[i]
    return tuple(float(a + t * (b - a)) for a, b in zip(CLOTHING_PALETTE[i], CLOTHING_PALETTE[i + 1]))  # type: ignore[return-value]


def add_clutter(intr: Intrinsics, bg: Background, rng: np.random.Generator, count: int) -> Background:
    """``bg`` with ``count`` static objects (boxes and round shapes) standing in the room.

    Every third object (the first included) is skin-coloured (a tone drawn from
    :func:`skin_rgb`), the others from :data:`CLUTTER_PALETTE`. Even-numbered
    objects stand at hand depth (1.0-1.4 m) beside the person (normalised
    ``x`` 0.33-0.5 either side of the person's centre, at hand height); the others
    are anywhere in front of the wall (2.0-2.8 m). Each has a smooth shading
    texture; all are drawn nearest last, behind the person.
    """
    h, w = intr.height, intr.width
    xn = ((np.arange(w, dtype=np.float32) - intr.cx) / intr.fx)[None, :]
    yn = ((np.arange(h, dtype=np.float32) - intr.cy) / intr.fy)[:, None]
    xn, yn = np.broadcast_to(xn, (h, w)), np.broadcast_to(yn, (h, w))
    objects = []
    for k in range(count):
        u = rng.uniform
        if k % 3 == 0:
            rgb = skin_rgb(float(u(0.0, 1.0)))
        else:
            rgb = CLUTTER_PALETTE[int(rng.integers(len(CLUTTER_PALETTE)))]
        if k % 2 == 0:
            z = float(u(1.0, 1.4))
            cx = 0.08 + float(rng.choice((-1.0, 1.0))) * float(u(0.33, 0.5))
            cy = float(u(0.0, 0.3))
        else:
            z = float(u(2.0, 2.8))
            cx, cy = float(u(-0.8, 0.8)), float(u(-0.4, 0.5))
        half_w, half_h = (float(u(0.04, 0.12)) / z * 1.2 for _ in range(2))
        round_shape = bool(rng.random() < 0.4)
        shade = 1.0 + 0.08 * _smooth_field(rng, (h, w), (3, 3))
        objects.append((z, cx, cy, half_w, half_h, round_shape, np.asarray(rgb, np.float32), shade))
    color, depth = bg.color.copy(), bg.depth_m.copy()
    for z, cx, cy, half_w, half_h, round_shape, rgb, shade in sorted(objects, key=lambda o: -o[0]):
        if round_shape:
            mask = ((xn - cx) / half_w) ** 2 + ((yn - cy) / half_h) ** 2 <= 1.0
        else:
            mask = _box(xn, yn, cx - half_w, cx + half_w, cy - half_h, cy + half_h)
        color[mask] = rgb * (shade[mask] * bg.vignette[mask, 0])[:, None]
        depth[mask] = z
    return Background(color, depth, bg.vignette)


def card_part(intr: Intrinsics, target: np.ndarray, radius_m: float, distance: float, margin: float) -> Part | None:
    """A square card between the camera and the 3-D point ``target`` (metres) that hides a disc of ``radius_m`` there.

    The card is fronto-parallel at ``distance`` times the target's depth, centred on
    the target's line of sight, ``margin`` times as wide as the disc's image (plus 2 px),
    matte (shade 0.9-1.0 from its top-left to its bottom-right) and drawn over
    everything (``on_top``); its label is :data:`LABEL_BACKGROUND` (not the person).
    None when the target is behind the camera or the card outside the image.
    """
    if target[2] <= 0:
        return None
    cu, cv = project(intr, target)
    half = margin * radius_m * intr.fx / float(target[2]) + 2.0
    g = _grid(intr, cu - half, cu + half, cv - half, cv + half)
    if g is None:
        return None
    rows, cols, uu, vv = g
    mask = (np.abs(uu - np.float32(cu)) <= half) & (np.abs(vv - np.float32(cv)) <= half)
    shade = (0.95 - 0.025 * ((uu - np.float32(cu)) + (vv - np.float32(cv))) / np.float32(half)) * np.ones_like(mask)
    depth = np.full(mask.shape, np.float32(distance * target[2]), np.float32)
    return Part(rows, cols, mask, depth, shade.astype(np.float32), CARD_RGB, LABEL_BACKGROUND, on_top=True)


def person_parts(
    intr: Intrinsics,
    pose: Pose,
    sleeve_fraction: float,
    skin: tuple[float, float, float] = SKIN_RGB,
    shirt: tuple[float, float, float] = SHIRT_RGB,
) -> list[Part]:
    """Every body part of ``pose``, rasterised (parts outside the image omitted).

    The right sleeve is pushed up: the forearm is bare skin from the wrist to
    ``sleeve_fraction`` of its length toward the elbow. The right forearm
    (sleeve and skin) and palm are the ``moving`` parts, last in the list.
    Skin (face, neck, hands, bare forearm) has colour ``skin``, the shirt ``shirt``.
    """
    x, z, dy = pose.torso[0], pose.torso[2], _drop(pose)
    parts = []
    for side in (-1.0, 1.0):
        leg = [
            np.array([x + side * dx, y + dy, z + 0.02])
            for dx, y in ((0.02, HIP_Y - 0.02), (0.175, HIP_Y - 0.02), (0.15, 1.2), (0.03, 1.2))
        ]
        parts.append(_polygon_part(intr, leg, x + side * 0.095, 0.08, 0.06, TROUSERS_RGB, LABEL_CLOTH))
    parts.append(_polygon_part(intr, torso_outline(pose), x, 0.21, 0.10, shirt, LABEL_CLOTH))
    parts.append(_polygon_part(intr, _neck_outline(pose), x, 0.06, 0.02, skin, LABEL_SKIN))
    parts.append(
        _ellipse_part(intr, pose.head + [0.0, -0.012, 0.0], 0.088, 0.112, math.pi / 2, 0.08, HAIR_RGB, LABEL_CLOTH)
    )
    parts.append(_ellipse_part(intr, face_centre(pose), *FACE_HALF_SIZE, math.pi / 2, 0.07, skin, LABEL_SKIN))
    parts.append(_capsule_part(intr, pose.left_shoulder, pose.left_elbow, UPPER_ARM_RADIUS, shirt, LABEL_CLOTH))
    parts.append(_capsule_part(intr, pose.left_elbow, pose.left_wrist, FOREARM_RADIUS, shirt, LABEL_CLOTH))
    parts.append(
        _ellipse_part(
            intr,
            pose.left_hand,
            0.045,
            0.06,
            _hand_angle(intr, pose.left_wrist, pose.left_hand),
            PALM_THICKNESS,
            skin,
            LABEL_SKIN,
        )
    )
    parts.append(_capsule_part(intr, pose.right_shoulder, pose.right_elbow, UPPER_ARM_RADIUS, shirt, LABEL_CLOTH))
    sleeve_edge = pose.right_wrist + sleeve_fraction * (pose.right_elbow - pose.right_wrist)
    arm = [
        _capsule_part(intr, pose.right_elbow, sleeve_edge, FOREARM_RADIUS, shirt, LABEL_CLOTH),
        _capsule_part(intr, sleeve_edge, pose.right_wrist, BARE_FOREARM_RADIUS, skin, LABEL_SKIN, round_start=False),
        _ellipse_part(
            intr,
            pose.right_hand,
            PALM_HALF_WIDTH,
            PALM_HALF_LENGTH,
            _hand_angle(intr, pose.right_wrist, pose.right_hand),
            PALM_THICKNESS,
            skin,
            LABEL_PALM,
            on_top=True,
        ),
    ]
    for p in arm:
        if p is not None:
            p.moving = True
    return [p for p in parts + arm if p is not None]


def draw_parts(
    color: np.ndarray,
    depth: np.ndarray,
    labels: np.ndarray,
    vignette: np.ndarray,
    parts: list[Part],
    r0: int = 0,
    c0: int = 0,
) -> np.ndarray:
    """Z-buffer ``parts`` into the arrays (whose pixel ``(0, 0)`` is image pixel ``(r0, c0)``).

    Returns the boolean coverage of the drawn parts.
    """
    drawn = np.zeros(depth.shape, bool)
    for p in parts:
        rows = slice(p.rows.start - r0, p.rows.stop - r0)
        cols = slice(p.cols.start - c0, p.cols.stop - c0)
        zroi = depth[rows, cols]
        sel = p.mask if p.on_top else p.mask & (p.depth < zroi)
        zroi[sel] = p.depth[sel]
        rgb = np.asarray(p.rgb, np.float32)
        croi = color[rows, cols]
        croi[sel] = rgb * (p.shade[sel] * vignette[rows, cols][sel, 0])[:, None]
        labels[rows, cols][sel] = p.label
        drawn[rows, cols] |= sel
    return drawn


def composite(
    bg: Background, parts: list[Part], blur: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Z-buffer the parts over the background, motion-blurring the moving layer.

    Parameters
    ----------
    bg : Background
        The static scene.
    parts : list of Part
        Static parts first, then the ``moving`` ones.
    blur : ndarray (k, k) float32, optional
        Line kernel (:func:`motion_kernel`) of the moving layer's blur during
        the exposure; None = no blur. The layer's colour (premultiplied by its
        coverage) and its coverage are blurred and composited over the rest;
        depth and labels stay sharp (they are the true, instantaneous scene).

    Returns
    -------
    color : ndarray, (H, W, 3) float32
    depth_m : ndarray, (H, W) float32
    labels : ndarray, (H, W) uint8 (``LABEL_*``)
    """
    color = bg.color.copy()
    depth = bg.depth_m.copy()
    labels = np.zeros(depth.shape, np.uint8)
    moving = [p for p in parts if p.moving]
    draw_parts(color, depth, labels, bg.vignette, [p for p in parts if not p.moving])
    if blur is None or not moving:
        draw_parts(color, depth, labels, bg.vignette, moving)
        return color, depth, labels
    pad = blur.shape[0] // 2 + 1
    h, w = depth.shape
    r0 = max(min(p.rows.start for p in moving) - pad, 0)
    r1 = min(max(p.rows.stop for p in moving) + pad, h)
    c0 = max(min(p.cols.start for p in moving) - pad, 0)
    c1 = min(max(p.cols.stop for p in moving) + pad, w)
    base = color[r0:r1, c0:c1].copy()
    layer = np.zeros_like(base)
    alpha = draw_parts(
        layer, depth[r0:r1, c0:c1], labels[r0:r1, c0:c1], bg.vignette[r0:r1, c0:c1], moving, r0, c0
    ).astype(np.float32)
    layer = cv2.filter2D(layer, -1, blur, borderType=cv2.BORDER_REPLICATE)
    alpha = cv2.filter2D(alpha, -1, blur, borderType=cv2.BORDER_REPLICATE)
    color[r0:r1, c0:c1] = layer + (1.0 - alpha)[..., None] * base
    return color, depth, labels


# -- two hands (``hands=2``): hand washing ---------------------------------------------------------

#: Key frames of one hand-washing cycle (person frames): ``(frame, d, dy)`` with
#: ``d`` the horizontal distance (metres) from the right to the left palm centre
#: (> 0: each hand on its own side; < 0: crossed) and ``dy`` how far the right palm
#: is above the left one (metres). Joined twice for >= 40 frames, crossed once.
WASH_KEYS: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.30, 0.0),
    (25.0, 0.30, 0.0),
    (50.0, 0.04, 0.0),
    (100.0, 0.04, 0.0),
    (125.0, 0.30, 0.0),
    (150.0, 0.30, 0.0),
    (165.0, 0.15, 0.11),
    (180.0, 0.0, 0.13),
    (195.0, -0.15, 0.11),
    (210.0, -0.30, 0.0),
    (225.0, -0.30, 0.0),
    (245.0, -0.04, 0.0),
    (285.0, -0.04, 0.0),
    (300.0, -0.30, 0.0),
)
#: How much farther in front of the torso than the one-hand scene's ``hand_front`` the
#: washing palms are (m): 0.22 + 0.06 = 0.28 m by default.
WASH_EXTRA_FRONT = 0.06
#: Length of one cycle (frames); odd cycles are mirrored (``d -> -d``), so the motion is continuous.
WASH_PERIOD = WASH_KEYS[-1][0]
#: Distance of the joined palm centres (m).
JOINED_D = 0.04
#: The layout of :data:`WASH_KEYS`: joins, crossings per cycle, hands' distance apart and
#: crossing height (m).
WASH_LAYOUT = (2, 1, 0.30, 0.13)
#: Phase lengths (frames) of a generated cycle (:func:`wash_keys`) with fixed timing:
#: hold apart, approach (and part), hold joined, a quarter of a crossing ...
WASH_PHASES = (25.0, 25.0, 50.0, 15.0)
#: ... and their ranges when drawn per seed (``timing``).
WASH_PHASE_RANGES = ((5.0, 40.0), (12.0, 35.0), (15.0, 90.0), (8.0, 20.0))


@dataclass(frozen=True)
class WashMotion:
    """Random parameters of the two-hand (hand-washing) motion, drawn once per seed.

    Periods in frames, amplitudes in metres; ``keys`` is the cycle
    (:func:`wash_keys`) and ``cross_height`` its crossing height, m.
    """

    rub_period: float
    rub_amp: float
    bob_period: float
    bob_phase: float
    bob_amp: float
    centre_period: float
    centre_phase: float
    centre_amp: float
    height: float
    keys: tuple[tuple[float, float, float], ...] = WASH_KEYS
    cross_height: float = WASH_LAYOUT[3]


def wash_parameters(rng: np.random.Generator) -> WashMotion:
    """Draw the hand-washing parameters (seed-dependent)."""
    u = rng.uniform
    return WashMotion(
        rub_period=float(u(10.0, 16.0)),
        rub_amp=float(u(0.008, 0.014)),
        bob_period=float(u(50.0, 80.0)),
        bob_phase=float(u(0, 2 * math.pi)),
        bob_amp=float(u(0.02, 0.04)),
        centre_period=float(u(90.0, 150.0)),
        centre_phase=float(u(0, 2 * math.pi)),
        centre_amp=float(u(0.02, 0.04)),
        height=float(u(0.16, 0.22)),
    )


def wash_keys(
    joins: int, crossings: int, distance: float, cross_height: float, rng: np.random.Generator | None = None
) -> tuple[tuple[float, float, float], ...]:
    """Key frames (as :data:`WASH_KEYS`) of a cycle with ``joins`` joins and ``crossings`` crossings.

    The hands start ``distance`` m apart on their own sides; the events follow
    in an interleaved order (joins spread between the crossings), each after
    a hold apart. A join approaches to :data:`JOINED_D`, holds and parts again;
    a crossing passes the right palm ``cross_height`` m above the left to the
    other side (``d`` changes sign). Phase lengths are :data:`WASH_PHASES`, or
    drawn from :data:`WASH_PHASE_RANGES` with ``rng`` (which also shuffles the
    order of the events). :data:`WASH_LAYOUT` with fixed timing is
    :data:`WASH_KEYS` itself.
    """
    if rng is None and (joins, crossings, distance, cross_height) == WASH_LAYOUT:
        return WASH_KEYS
    events = ["cross"] * crossings
    for k in range(joins):  # spread the joins over the gaps between the crossings
        events.insert(round(k * (crossings + 1) / max(joins, 1)) + k, "join")
    if rng is not None:
        events = [events[i] for i in rng.permutation(len(events))]

    def phase(i: int) -> float:
        if rng is None:
            return WASH_PHASES[i]
        lo, hi = WASH_PHASE_RANGES[i]
        return float(round(rng.uniform(lo, hi)))

    side, t = 1.0, 0.0
    keys = [(0.0, distance, 0.0)]
    for event in events:
        t += phase(0)
        keys.append((t, side * distance, 0.0))
        if event == "join":
            t += phase(1)
            keys.append((t, side * JOINED_D, 0.0))
            t += phase(2)
            keys.append((t, side * JOINED_D, 0.0))
            t += phase(1)
            keys.append((t, side * distance, 0.0))
        else:
            for d, dy in ((0.5, 0.85), (0.0, 1.0), (-0.5, 0.85), (-1.0, 0.0)):
                t += phase(3)
                keys.append((t, side * d * distance, dy * cross_height))
            side = -side
    t += phase(0)
    keys.append((t, side * distance, 0.0))
    return tuple(keys)


def wash_schedule(t: float, keys: Sequence[tuple[float, float, float]] = WASH_KEYS) -> tuple[float, float]:
    """``(d, dy)`` of the cycle ``keys`` (:data:`WASH_KEYS`) at person-frame ``t`` (cosine-eased between key frames).

    A cycle that ends crossed (an odd number of crossings) is followed by its
    mirror image (``d -> -d``), so the motion is continuous.
    """
    period = keys[-1][0]
    cycle, local = divmod(t, period)
    sign = -1.0 if keys[-1][1] < 0 and int(cycle) % 2 else 1.0
    times = [k[0] for k in keys]
    i = min(max(int(np.searchsorted(times, local, side="right")) - 1, 0), len(keys) - 2)
    (t0, d0, y0), (t1, d1, y1) = keys[i], keys[i + 1]
    s = (1.0 - math.cos(math.pi * (local - t0) / (t1 - t0))) / 2.0
    return sign * (d0 + s * (d1 - d0)), y0 + s * (y1 - y0)


def _two_arm_pose(
    torso: np.ndarray, head: np.ndarray, r_sh: np.ndarray, l_sh: np.ndarray, r_palm: np.ndarray, l_palm: np.ndarray
) -> Pose:
    """The pose with both palms placed: each wrist :data:`HAND` back from its palm toward the shoulder, elbows by IK."""
    hands = []
    for sh, palm, pole in ((r_sh, r_palm, np.array([-0.5, 1.0, 0.3])), (l_sh, l_palm, np.array([0.5, 1.0, 0.3]))):
        to_palm = palm - sh
        wr = palm - HAND * to_palm / np.linalg.norm(to_palm)
        hands.append((wr, _elbow(sh, wr, pole)))
    (r_wr, r_el), (l_wr, l_el) = hands
    return Pose(torso, head, r_sh, l_sh, r_el, l_el, r_wr, l_wr, r_palm, l_palm)


def wash_pose_at(m: Motion, w: WashMotion, t: float) -> Pose:
    """The two-hand pose at person-frame ``t``: both palms in front of the lower chest.

    The torso sways as in :func:`pose_at`; the palms are ``d`` apart
    horizontally and ``dy`` vertically (:func:`wash_schedule`) around a centre
    that drifts slowly, ``hand_front + 0.06`` m (:data:`WASH_EXTRA_FRONT`; 0.28 by
    default) in front of the torso, the right palm 0.03 m more while crossing; while joined they rub
    (anti-phase oscillation of ``rub_amp``). Both arms follow by two-link
    inverse kinematics.
    """
    two_pi = 2.0 * math.pi
    tx, tz, torso, head, r_sh, l_sh = _body_at(m, t)
    d, dy = wash_schedule(t, w.keys)
    crossing = dy / w.cross_height
    # 1 while joined (|d| = 0.04 m), fading out by |d| = 0.14 m; no rubbing while crossing
    joined = min(max(1.0 - (abs(d) - 0.04) / 0.10, 0.0), 1.0) * (1.0 - crossing)
    rub = joined * w.rub_amp * math.sin(two_pi * t / w.rub_period)
    cx = tx + w.centre_amp * math.sin(two_pi * t / w.centre_period + w.centre_phase)
    cy = w.height + w.bob_amp * math.sin(two_pi * t / w.bob_period + w.bob_phase)
    front = m.hand_front + WASH_EXTRA_FRONT
    r_palm = np.array([cx - d / 2.0 + rub, cy - dy / 2.0 - rub, tz - front - 0.03 * crossing])
    l_palm = np.array([cx + d / 2.0 - rub, cy + dy / 2.0 + rub, tz - front])
    return _two_arm_pose(torso, head, r_sh, l_sh, r_palm, l_palm)


def left_palm_mask(intr: Intrinsics, pose: Pose, clip: bool = True):
    """The left palm ellipse (two-hand scene): ``(rows, cols, mask, q, du, dv)`` as :func:`ellipse_mask`."""
    angle = _hand_angle(intr, pose.left_wrist, pose.left_hand)
    return ellipse_mask(intr, pose.left_hand, PALM_HALF_WIDTH, PALM_HALF_LENGTH, angle, clip)


def hands_overlap(intr: Intrinsics, pose: Pose) -> float:
    """Fraction of the right palm's area covered by the left palm's ellipse (two-hand scene)."""
    rows, cols, mask, *_ = palm_mask(intr, pose, clip=False)
    area = int(mask.sum())
    if area == 0:
        return 0.0
    angle = _hand_angle(intr, pose.left_wrist, pose.left_hand)
    cu, cv = project(intr, pose.left_hand)
    a = PALM_HALF_WIDTH * intr.fx / pose.left_hand[2]
    b = PALM_HALF_LENGTH * intr.fy / pose.left_hand[2]
    uu = np.arange(cols.start, cols.stop, dtype=np.float32)[None, :] - np.float32(cu)
    vv = np.arange(rows.start, rows.stop, dtype=np.float32)[:, None] - np.float32(cv)
    ca, sa = math.cos(angle), math.sin(angle)
    q = ((-uu * sa + vv * ca) / a) ** 2 + ((uu * ca + vv * sa) / b) ** 2
    return float((mask & (q <= 1.0)).sum()) / area


def face_centre(pose: Pose) -> np.ndarray:
    """3-D centre of the face (the skin ellipse of the head), metres."""
    return pose.head + np.array([0.0, 0.012, -0.02])


def face_mask(intr: Intrinsics, pose: Pose, clip: bool = True):
    """The face ellipse (the head's skin): ``(rows, cols, mask, q, du, dv)`` as :func:`ellipse_mask`."""
    return ellipse_mask(intr, face_centre(pose), *FACE_HALF_SIZE, math.pi / 2, clip)


def wash_parts(
    intr: Intrinsics,
    pose: Pose,
    sleeve_fraction: float,
    skin: tuple[float, float, float] = SKIN_RGB,
    shirt: tuple[float, float, float] = SHIRT_RGB,
) -> list[Part]:
    """Every body part of a two-hand ``pose``, rasterised.

    Both sleeves are pushed up to ``sleeve_fraction`` of the forearm, both
    palms are ``LABEL_PALM``; the nearer arm is drawn last (on top). Nothing is
    ``moving`` (the two-hand scene has no motion blur). Skin has colour ``skin``,
    the shirt ``shirt``.
    """
    x, z, dy = pose.torso[0], pose.torso[2], _drop(pose)
    parts = []
    for side in (-1.0, 1.0):
        leg = [
            np.array([x + side * dx, y + dy, z + 0.02])
            for dx, y in ((0.02, HIP_Y - 0.02), (0.175, HIP_Y - 0.02), (0.15, 1.2), (0.03, 1.2))
        ]
        parts.append(_polygon_part(intr, leg, x + side * 0.095, 0.08, 0.06, TROUSERS_RGB, LABEL_CLOTH))
    parts.append(_polygon_part(intr, torso_outline(pose), x, 0.21, 0.10, shirt, LABEL_CLOTH))
    parts.append(_polygon_part(intr, _neck_outline(pose), x, 0.06, 0.02, skin, LABEL_SKIN))
    parts.append(
        _ellipse_part(intr, pose.head + [0.0, -0.012, 0.0], 0.088, 0.112, math.pi / 2, 0.08, HAIR_RGB, LABEL_CLOTH)
    )
    parts.append(_ellipse_part(intr, face_centre(pose), *FACE_HALF_SIZE, math.pi / 2, 0.07, skin, LABEL_SKIN))
    arms = []
    for sh, el, wr, hand in (
        (pose.right_shoulder, pose.right_elbow, pose.right_wrist, pose.right_hand),
        (pose.left_shoulder, pose.left_elbow, pose.left_wrist, pose.left_hand),
    ):
        edge = wr + sleeve_fraction * (el - wr)
        arms.append(
            (
                float(hand[2]),
                [
                    _capsule_part(intr, sh, el, UPPER_ARM_RADIUS, shirt, LABEL_CLOTH),
                    _capsule_part(intr, el, edge, FOREARM_RADIUS, shirt, LABEL_CLOTH),
                    _capsule_part(intr, edge, wr, BARE_FOREARM_RADIUS, skin, LABEL_SKIN, round_start=False),
                    _ellipse_part(
                        intr,
                        hand,
                        PALM_HALF_WIDTH,
                        PALM_HALF_LENGTH,
                        _hand_angle(intr, wr, hand),
                        PALM_THICKNESS,
                        skin,
                        LABEL_PALM,
                        on_top=True,
                    ),
                ],
            )
        )
    for _, arm in sorted(arms, key=lambda a: -a[0]):
        parts.extend(arm)
    return [p for p in parts if p is not None]


# -- scripted interactions (``script="events"``): joins, a hand at the head, an object passed ------

#: Colour of the carried ball (RGB): a dark saturated green, far in hue from skin (~20 deg) and the
#: navy shirt (~230 deg), and far in brightness from the wall so the skin cues do not take it.
OBJECT_RGB = (30.0, 120.0, 40.0)
#: Radius of the carried ball (m).
OBJECT_RADIUS = 0.035
#: Where a held ball is relative to the holding palm's centre (m): below it and slightly in front.
GRIP_OFFSET = (0.0, 0.075, -0.01)
#: Truth thresholds (3-D distances between centres, m): palms closer than this are joined ...
JOIN_M = 0.10
#: ... and a palm closer than this to the face centre touches the head.
CONTACT_M = 0.15

#: Key frames of the script (nominal person frames, stretched per seed): ``(frame, right, left, holder)``
#: with ``right``/``left`` the palm's place (``"home"``, ``"object"``: at the ball's resting place,
#: ``"meet"``: 2 cm right/left of the pair's meeting point, ``"head"``: at the right cheek) and
#: ``holder`` the hand holding the ball from that key frame on (None: the ball rests).
SCRIPT_KEYS: tuple[tuple[float, str, str, str | None], ...] = (
    (0.0, "home", "home", None),
    (20.0, "home", "home", None),
    (32.0, "object", "home", "right_hand"),
    (40.0, "object", "home", "right_hand"),
    (54.0, "home", "home", "right_hand"),
    (70.0, "home", "home", "right_hand"),
    (82.0, "meet", "meet", "right_hand"),
    (100.0, "meet", "meet", "left_hand"),
    (116.0, "meet", "meet", "left_hand"),
    (126.0, "home", "home", "left_hand"),
    (150.0, "home", "home", "left_hand"),
    (162.0, "head", "home", "left_hand"),
    (186.0, "head", "home", "left_hand"),
    (198.0, "home", "home", "left_hand"),
    (220.0, "home", "home", "left_hand"),
    (232.0, "meet", "meet", "left_hand"),
    (262.0, "meet", "meet", "left_hand"),
    (272.0, "home", "home", "left_hand"),
    (300.0, "home", "home", "left_hand"),
)


@dataclass(frozen=True)
class ScriptMotion:
    """Random parameters of the scripted scene, drawn once per seed.

    ``times`` are the key frames of :data:`SCRIPT_KEYS` after a per-seed
    stretch of each interval (0.85-1.15); positions in metres relative to the
    torso centre (x) and absolute (y); ``object_rest`` is the ball's resting
    place ``(x, y)`` beside the person's right (image left).
    """

    times: tuple[float, ...]
    home_right: tuple[float, float]
    home_left: tuple[float, float]
    meet: tuple[float, float]
    object_rest: tuple[float, float]


def script_parameters(rng: np.random.Generator) -> ScriptMotion:
    """Draw the scripted scene's timing and places (seed-dependent)."""
    u = rng.uniform
    gaps = np.diff([k[0] for k in SCRIPT_KEYS]) * rng.uniform(0.85, 1.15, size=len(SCRIPT_KEYS) - 1)
    times = tuple(float(t) for t in np.concatenate([[0.0], np.cumsum(gaps)]))
    return ScriptMotion(
        times=times,
        home_right=(float(u(-0.19, -0.15)), float(u(0.16, 0.22))),
        home_left=(float(u(0.15, 0.19)), float(u(0.16, 0.22))),
        meet=(float(u(-0.03, 0.03)), float(u(0.12, 0.18))),
        object_rest=(float(u(-0.36, -0.32)), float(u(0.02, 0.08))),
    )


def _script_places(m: Motion, s: ScriptMotion, tx: float, tz: float, head: np.ndarray) -> dict[str, np.ndarray]:
    """The 3-D places of :data:`SCRIPT_KEYS` for each hand at the torso's current position."""
    front = tz - m.hand_front - WASH_EXTRA_FRONT
    grip = np.asarray(GRIP_OFFSET)
    rest = np.array([tx + s.object_rest[0], s.object_rest[1], front + grip[2]])
    face = head + np.array([0.0, 0.012, -0.02])
    return {
        "right_hand:home": np.array([tx + s.home_right[0], s.home_right[1], front]),
        "left_hand:home": np.array([tx + s.home_left[0], s.home_left[1], front]),
        "right_hand:meet": np.array([tx + s.meet[0] - 0.02, s.meet[1], front]),
        "left_hand:meet": np.array([tx + s.meet[0] + 0.02, s.meet[1], front]),
        "right_hand:object": rest - grip,
        "right_hand:head": face + np.array([-0.10, 0.02, -0.03]),
        "object:rest": rest,
    }


def script_pose_at(m: Motion, s: ScriptMotion, t: float) -> tuple[Pose, np.ndarray]:
    """The pose at person-frame ``t`` of the scripted scene and the ball's 3-D centre.

    The torso sways as in :func:`pose_at`; each palm moves between the places
    of :data:`SCRIPT_KEYS` (cosine-eased between key frames, still after the
    last); the ball rests until its first holder reaches it, then follows the
    holder's palm at :data:`GRIP_OFFSET`, moving smoothly to the new holder's
    grip over the key interval in which the holder changes. Both arms follow by
    two-link inverse kinematics.
    """
    tx, tz, torso, head, r_sh, l_sh = _body_at(m, t)
    places = _script_places(m, s, tx, tz, head)
    i = min(max(int(np.searchsorted(s.times, t, side="right")) - 1, 0), len(s.times) - 2)
    t0, t1 = s.times[i], s.times[i + 1]
    e = (1.0 - math.cos(math.pi * min(max((t - t0) / (t1 - t0), 0.0), 1.0))) / 2.0
    (_, r0, l0, h0), (_, r1, l1, h1) = SCRIPT_KEYS[i], SCRIPT_KEYS[i + 1]
    r_palm = places[f"right_hand:{r0}"] + e * (places[f"right_hand:{r1}"] - places[f"right_hand:{r0}"])
    l_palm = places[f"left_hand:{l0}"] + e * (places[f"left_hand:{l1}"] - places[f"left_hand:{l0}"])
    grip = np.asarray(GRIP_OFFSET)
    palms = {"right_hand": r_palm, "left_hand": l_palm}
    if h0 is None:
        ball = places["object:rest"]
    else:
        ball = palms[h0] + grip if h1 == h0 else palms[h0] + grip + e * (palms[str(h1)] - palms[h0])
    return _two_arm_pose(torso, head, r_sh, l_sh, r_palm, l_palm), ball


def object_part(intr: Intrinsics, centre: np.ndarray) -> Part | None:
    """The ball at ``centre`` (a disc bulging by its radius, :data:`OBJECT_RGB`), None outside the image."""
    return _ellipse_part(intr, centre, OBJECT_RADIUS, OBJECT_RADIUS, 0.0, OBJECT_RADIUS, OBJECT_RGB, LABEL_CLOTH)


def script_events(m: Motion, s: ScriptMotion, frames: int) -> list[tuple[int, str, tuple[str, ...]]]:
    """The true events of the scripted scene over person frames ``[0, frames)``: ``(frame, event, targets)``.

    ``join`` / ``separate``: the palm centres come closer than :data:`JOIN_M`
    / move farther apart again; ``contact``: a palm comes closer than
    :data:`CONTACT_M` to the face centre; ``pick_up``: the frame the ball's
    first holder reaches it (the key frame); ``exchange``: the separation
    after which another hand holds the ball (targets: giver, taker).
    """
    out: list[tuple[int, str, tuple[str, ...]]] = []
    joined = False
    touching = {"right_hand": False, "left_hand": False}
    holder_at_join: str | None = None
    pick = next(k for k, key in enumerate(SCRIPT_KEYS) if key[3] is not None)
    pick_frame = math.ceil(s.times[pick])
    for t in range(frames):
        pose, _ = script_pose_at(m, s, float(t))
        i = min(max(int(np.searchsorted(s.times, t, side="right")) - 1, 0), len(s.times) - 1)
        holder = SCRIPT_KEYS[i][3]
        if t == pick_frame:
            out.append((t, "pick_up", (str(SCRIPT_KEYS[pick][3]),)))
        d = float(np.linalg.norm(pose.right_hand - pose.left_hand))
        if not joined and d < JOIN_M:
            joined, holder_at_join = True, holder
            out.append((t, "join", ("right_hand", "left_hand")))
        elif joined and d >= JOIN_M:
            joined = False
            out.append((t, "separate", ("right_hand", "left_hand")))
            if holder_at_join is not None and holder is not None and holder != holder_at_join:
                out.append((t, "exchange", (holder_at_join, holder)))
        face = face_centre(pose)
        for name, palm in (("right_hand", pose.right_hand), ("left_hand", pose.left_hand)):
            near = float(np.linalg.norm(palm - face)) < CONTACT_M
            if near and not touching[name]:
                out.append((t, "contact", (name, "head")))
            touching[name] = near
    return out
