"""Synthetic multi-camera scene: the synthetic person seen by N calibrated RGB-D cameras, or their calibration board.

Every camera renders the same 3-D scene with :mod:`drivers.synth`'s renderer
(person, colour pipeline, depth sensor model, skeleton), each from its own pose:

* **World** is the frame of the calibration board (:mod:`drivers.charuco`), a
  ChArUco board (7 x 5 squares of 160 mm, :class:`~drivers.charuco.BoardSpec`)
  standing where the person stands (x to the right, y down, z away from the
  cameras; its top-left corner at the origin). With ``board=True`` the recording
  is the rig's calibration sequence: every frame shows the board in the empty
  room (all frames are background frames); without it, the person in the same
  room, seen by the same cameras (the poses depend on the seed and the camera
  count only), so ``fusion-pf calibrate`` on the first recovers the poses of the
  second in the frame they were drawn in.
* **Static scene**, ray-cast per camera in world coordinates so all cameras see
  one geometry: the back wall 1.5 m behind the board, a wall on the left, the
  floor 1.65 m below the board's top edge and three boxes on it; colours are smooth textures of
  the world position (seeded). The board is the image of
  ``cv2.aruco.CharucoBoard.generateImage`` looked up (low-passed to the camera's
  pixel size) at the world point each pixel sees: the board warped into the
  camera by its pose and intrinsics.
* **Person**: the single-camera scene's person (``hands`` 1 or 2), placed with its
  nominal camera at world ``(0.45, 0.55, -1.5)`` m.
* **Cameras** ``cam0 .. cam{N-1}``: on an arc of radius 2 m around the point
  ``(0.55, 0.5, 0.2)`` m they look at, from 28 degrees left to 28 degrees right
  (``N = 1``: straight on), 0.4 m high, each jittered by the seed (yaw +-4
  degrees, radius +-0.2 m, height +-8 cm, aim +-10 cm, roll +-2 degrees); every
  camera has the single-camera scene's intrinsics. The poses are in the
  recording's metadata (``pose_<camera>``, written by :class:`drivers.rig.RigRecorder`) and on ``/tf``.
* **Colour-only cameras**: the last ``colour_only`` cameras have no depth.
* **Ground truth**: per camera the pixel truth of the single-camera scene (its
  ``/ground_truth/palm``), and per target the world position in mm (right hand; with
  ``hands=2`` also left hand and head), the palm's centre in the person model.
* **Scripted events** (``hands=2, script="events"``): the single-camera scene's
  script (the ball picked up and passed between the hands, the hand at the head,
  two joins) in the world, the ball drawn by every camera; its true events
  (:meth:`SynthRig.true_events`) are decided on 3-D distances, so they are the
  rig's.

The noise of each camera (colour, depth, skeleton) is its own (seeded by the
camera's number); motion and appearance are shared.
"""

from __future__ import annotations

import inspect
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, Intrinsics, Joint
from fusion_pf.rig import CameraPose

from . import synth_scene as sc
from .charuco import BoardSpec
from .synth import TARGETS, SynthSource, _int_option

_SCENE_FRAMES = inspect.signature(SynthSource).parameters["frames"].default

#: Most cameras a synthetic rig may have.
MAX_CAMERAS = 8
#: The nominal (single-camera scene) camera's centre in the world (metres): person and wall are placed from it.
NOMINAL_CENTRE_M = np.array([0.45, 0.55, -1.5])
#: The point the cameras look at (metres, world), their distance from it and their height (world y).
LOOK_AT_M = np.array([0.55, 0.5, 0.2])
ARC_RADIUS_M = 2.0
CAMERA_Y_M = 0.4
#: Yaw of the outermost cameras (degrees).
ARC_HALF_ANGLE_DEG = 28.0
#: The back wall's depth (metres, world z) and the floor's height (world y).
WALL_Z_M, FLOOR_Y_M = 1.5, 1.65
#: The wall on the left (metres, world x).
SIDE_WALL_X_M = -1.4
#: Boxes on the floor: min and max corners (metres, world).
BOXES_M = (
    (np.array([-0.65, 1.1, 0.5]), np.array([-0.1, 1.65, 1.05])),
    (np.array([1.7, 1.2, 0.2]), np.array([2.2, 1.65, 0.6])),
    (np.array([-1.4, 0.9, -0.6]), np.array([-1.05, 1.65, 0.1])),
)
#: Board ink and paper grey levels.
BOARD_BLACK, BOARD_WHITE = 28.0, 232.0
#: Radius (metres) of the disc a card hides per target: the palm's half length, the head's half height.
TARGET_RADIUS_M = {
    "right_hand": sc.PALM_HALF_LENGTH,
    "left_hand": sc.PALM_HALF_LENGTH,
    "head": sc.FACE_HALF_SIZE[1] + 0.015,
}
#: The skeleton joints a camera loses while a card hides the target from it.
TARGET_JOINTS = {
    "right_hand": ("right_hand", "right_wrist"),
    "left_hand": ("left_hand", "left_wrist"),
    "head": ("head",),
}
#: A card's distance from the camera (fraction of the target's depth) and its size (times the target's disc).
CARD_DEPTH_FRACTION, CARD_MARGIN = 0.5, 1.6
#: A target is visible in a camera when at least this fraction of its disc (inside the image or not) shows it.
VISIBLE_FRACTION = 0.25
#: ``occlude="auto"``: each hand's period is this fraction of its share of the person frames, at most
#: :data:`AUTO_MAX_FRAMES` frames.
AUTO_FRACTION, AUTO_MAX_FRAMES = 0.5, 60
_OCCLUSION = re.compile(r"^([^:]+):([^:]+):(\d+)-(\d+)$")


@dataclass(frozen=True)
class Occlusion:
    """A card hides ``target`` from ``camera`` during frames ``start`` to ``end`` (inclusive)."""

    camera: str
    target: str
    start: int
    end: int

    def covers(self, index: int) -> bool:
        return self.start <= index <= self.end

    def __str__(self) -> str:
        return f"{self.camera}:{self.target}:{self.start}-{self.end}"


def parse_occlusions(text: str) -> tuple[Occlusion, ...] | str:
    """``"none"``, ``"auto"`` or the periods of ``"CAM:TARGET:START-END[,...]"`` (frames, inclusive).

    Raises
    ------
    InputError
        Naming the malformed period and the expected form.
    """
    text = text.strip()
    if text in ("none", "auto"):
        return text
    out = []
    for item in text.split(","):
        m = _OCCLUSION.match(item.strip())
        if m is None:
            raise InputError(
                f"occlusion {item.strip()!r} must be CAMERA:TARGET:START-END (e.g. cam1:right_hand:40-80), "
                "or the whole value none or auto"
            )
        start, end = int(m.group(3)), int(m.group(4))
        if end < start:
            raise InputError(f"occlusion {item.strip()!r}: END {end} is before START {start}")
        out.append(Occlusion(m.group(1), m.group(2), start, end))
    return tuple(out)


def _look_at(centre: np.ndarray, target: np.ndarray, roll_deg: float) -> np.ndarray:
    """Camera-to-world rotation of a camera at ``centre`` looking at ``target`` (world y down), rolled."""
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross(z, [0.0, -1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    r = np.stack([x, y, z], axis=1)
    c, s = math.cos(math.radians(roll_deg)), math.sin(math.radians(roll_deg))
    return r @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def rig_poses(cameras: int, rng: np.random.Generator) -> dict[str, CameraPose]:
    """The poses (mm) of the synthetic rig's cameras (module docstring), jittered by ``rng``."""
    out = {}
    for k in range(cameras):
        yaw = 0.0 if cameras == 1 else -ARC_HALF_ANGLE_DEG + 2 * ARC_HALF_ANGLE_DEG * k / (cameras - 1)
        yaw = math.radians(yaw + rng.uniform(-4.0, 4.0))
        radius = ARC_RADIUS_M + rng.uniform(-0.2, 0.2)
        centre = LOOK_AT_M + radius * np.array([math.sin(yaw), 0.0, -math.cos(yaw)])
        centre[1] = CAMERA_Y_M + rng.uniform(-0.08, 0.08)
        target = LOOK_AT_M + rng.uniform(-0.1, 0.1, 3)
        out[f"cam{k}"] = CameraPose(_look_at(centre, target, rng.uniform(-2.0, 2.0)), centre * 1000.0)
    return out


class _Textures:
    """Seeded smooth colour textures of world positions (the same for every camera)."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.freq = rng.uniform(3.0, 11.0, (3, 4, 2))
        self.phase = rng.uniform(0.0, 2 * math.pi, (3, 4))

    def field(self, which: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """A smooth field in [-1, 1] of two world coordinates (metres)."""
        f, p = self.freq[which], self.phase[which]
        out = np.zeros(a.shape, np.float32)
        for j in range(4):
            out += np.sin(f[j, 0] * a + f[j, 1] * b + p[j]).astype(np.float32)
        return out / 4.0


def render_static(
    intr: Intrinsics, pose: CameraPose, board: BoardSpec, board_pyramid: list[np.ndarray] | None, tex: _Textures
) -> sc.Background:
    """Ray-cast the static scene (walls, floor, boxes and, given its image pyramid, the board) for one camera."""
    h, w = intr.height, intr.width
    xn = (np.arange(w, dtype=np.float64) - intr.cx) / intr.fx
    yn = (np.arange(h, dtype=np.float64) - intr.cy) / intr.fy
    rays_cam = np.stack(np.broadcast_arrays(xn[None, :], yn[:, None], np.ones((h, w))), axis=-1)  # z = 1
    d = rays_cam @ pose.rotation.T  # world direction per unit of depth
    o = pose.translation_mm / 1000.0
    inf = np.float64(np.inf)

    def plane(axis: int, value: float) -> np.ndarray:
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (value - o[axis]) / d[..., axis]
        return np.where(t > 1e-6, t, inf)

    t_boxes = []
    for lo, hi in BOXES_M:
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - o) / d, (hi - o) / d
        t_near = np.nanmax(np.minimum(t1, t2), axis=-1)
        t_far = np.nanmin(np.maximum(t1, t2), axis=-1)
        t_boxes.append(np.where((t_near <= t_far) & (t_near > 1e-6), t_near, inf))
    t_board = plane(2, 0.0)
    pb = o + t_board[..., None] * d
    bw, bh = (v / 1000.0 for v in board.size_mm)
    on_board = (pb[..., 0] >= 0) & (pb[..., 0] <= bw) & (pb[..., 1] >= 0) & (pb[..., 1] <= bh)
    on_board &= board_pyramid is not None
    t_board = np.where(on_board, t_board, inf)
    ts = np.stack([plane(2, WALL_Z_M), plane(1, FLOOR_Y_M), plane(0, SIDE_WALL_X_M), t_board, *t_boxes])
    which = np.argmin(ts, axis=0)
    depth = np.min(ts, axis=0)
    if not np.isfinite(depth).all():
        raise InputError("a synthetic camera sees past the scene (no surface along some rays)")
    p = o + depth[..., None] * d
    color = np.empty((h, w, 3), np.float32)
    wall = which == 0
    color[wall] = np.asarray(sc.WALL_RGB, np.float32) + 14.0 * tex.field(0, p[wall, 0], p[wall, 1])[:, None]
    floor = which == 1
    grain = tex.field(1, p[floor, 0], p[floor, 2])
    color[floor] = np.array([150.0, 118.0, 86.0], np.float32) + 22.0 * grain[:, None]
    side = which == 2
    color[side] = np.asarray(sc.WALL_RGB, np.float32) * 0.9 + 14.0 * tex.field(0, p[side, 2], p[side, 1])[:, None]
    palette = np.asarray(sc.BOX_PALETTE, np.float32)[[1, 2, 3]]
    for k, (lo, hi) in enumerate(BOXES_M):
        box = which == 4 + k
        face = np.argmax(np.stack([np.abs(p[box] - lo), np.abs(p[box] - hi)]).min(axis=0) < 1e-6, axis=-1)
        shade = 1.0 + 0.08 * tex.field(2, p[box, 0] + p[box, 1], p[box, 2])[:, None]
        color[box] = palette[(face + k) % 3] * shade
    on = which == 3
    if board_pyramid is not None and on.any():
        # the coarsest board image at least 4 times finer than the camera's pixels, low-passed to them
        scale = intr.fx / float(np.median(depth[on])) / 1000.0  # camera pixels per board mm
        level = next(
            (img for img in board_pyramid[::-1] if img.shape[1] / board.size_mm[0] >= 4.0 * scale), board_pyramid[0]
        )
        ppm = level.shape[1] / board.size_mm[0]
        level = cv2.GaussianBlur(level, (0, 0), 0.5 * ppm / scale)
        mx = (pb[..., 0] * 1000.0 * ppm - 0.5).astype(np.float32)
        my = (pb[..., 1] * 1000.0 * ppm - 0.5).astype(np.float32)
        ink = cv2.remap(level, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE).astype(np.float32) / 255.0
        color[on] = (BOARD_BLACK + (BOARD_WHITE - BOARD_BLACK) * ink[on])[:, None]
    vignette = (1.0 - 0.12 * (xn[None, :] ** 2 + yn[:, None] ** 2) / 0.58).astype(np.float32)[..., None]
    return sc.Background(color * vignette, depth.astype(np.float32), vignette)


def _target_point(pose: sc.Pose, target: str) -> np.ndarray:
    """The 3-D centre of ``target`` in ``pose`` (the palm; the face for the head)."""
    return {"right_hand": pose.right_hand, "left_hand": pose.left_hand, "head": sc.face_centre(pose)}[target]


class _CameraView(SynthSource):
    """One camera of the rig: the single-camera scene's renderer over the rig's static scene, from its pose."""

    def __init__(
        self,
        number: int,
        pose: CameraPose,
        background: sc.Background,
        occlusions: tuple[Occlusion, ...] = (),
        **scene: Any,
    ) -> None:
        self.number = number
        super().__init__(**scene)
        self._camera_pose = pose
        self._background = background
        self._bg_depth_valid = self._stereo_valid(background.depth_m)
        self.occlusions = occlusions

    def hidden(self, index: int) -> tuple[str, ...]:
        """The targets a card hides from this camera at frame ``index``."""
        return tuple(dict.fromkeys(o.target for o in self.occlusions if o.covers(index)))

    def _composite(self, index: int, pose: sc.Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        color, depth, labels = super()._composite(index, pose)
        cards = [
            sc.card_part(self.intrinsics, _target_point(pose, t), TARGET_RADIUS_M[t], CARD_DEPTH_FRACTION, CARD_MARGIN)
            for t in self.hidden(index)
        ]
        sc.draw_parts(color, depth, labels, self._background.vignette, [c for c in cards if c is not None])
        return color, depth, labels

    def joints(self, index: int) -> dict[str, Joint]:
        """The skeleton of this camera: a hidden target's joints are missing (the camera cannot see them)."""
        lost = {j for t in self.hidden(index) for j in TARGET_JOINTS[t]}
        return {name: joint for name, joint in super().joints(index).items() if name not in lost}

    def visible(self, index: int, masks: Mapping[str, np.ndarray]) -> tuple[str, ...]:
        """The targets this camera sees at ``index`` (``masks``: its :meth:`render` masks of that frame).

        A target is visible when at least :data:`VISIBLE_FRACTION` of its disc (the
        palm ellipse; the face ellipse for the head), counted inside the image or
        not, shows it: palm pixels for a hand, skin that is not a palm for the head.
        """
        pose = self.pose(index)
        if pose is None:
            return ()
        intr = self.intrinsics
        discs = {
            "right_hand": (sc.palm_mask, masks["palm"]),
            "left_hand": (sc.left_palm_mask, masks["palm"]),
            "head": (sc.face_mask, masks["skin"] & ~masks["palm"]),
        }
        out = []
        for target in self.targets:
            disc, shows = discs[target]
            full = disc(intr, pose, clip=False)
            inside = disc(intr, pose, clip=True)
            area = 0 if full is None else int(full[2].sum())
            if area == 0 or inside is None:
                continue
            rows, cols, mask = inside[:3]
            if np.count_nonzero(mask & shows[rows, cols]) >= VISIBLE_FRACTION * area:
                out.append(target)
        return tuple(out)

    @property
    def targets(self) -> tuple[str, ...]:
        return TARGETS if self.hands == 2 else TARGETS[:1]

    def _rng(self, *key: int) -> np.random.Generator:
        # noise (1: images, 2: skeleton) is per camera; motion and appearance are shared
        return super()._rng(*key, 1000 + self.number) if key and key[0] in (1, 2) else super()._rng(*key)

    def world_pose(self, index: int) -> sc.Pose | None:
        """The person's pose in world metres at frame ``index`` (None: background frame)."""
        nominal = super().pose(index)
        if nominal is None:
            return None
        return sc.Pose(*(np.asarray(getattr(nominal, f)) + NOMINAL_CENTRE_M for f in sc.Pose.__dataclass_fields__))

    def pose(self, index: int) -> sc.Pose | None:
        """The person's pose in this camera's frame (metres), what the renderer draws."""
        world = self.world_pose(index)
        if world is None:
            return None
        return sc.Pose(*(self._to_camera(np.asarray(getattr(world, f))) for f in sc.Pose.__dataclass_fields__))

    def object_centre(self, index: int) -> np.ndarray | None:
        """Scripted scene: the ball's centre in this camera's frame (metres), what the renderer draws."""
        nominal = super().object_centre(index)
        return None if nominal is None else self._to_camera(np.asarray(nominal) + NOMINAL_CENTRE_M)

    def _to_camera(self, world_m: np.ndarray) -> np.ndarray:
        """World metres to this camera's frame (metres)."""
        return self._camera_pose.to_camera(world_m * 1000.0) / 1000.0


class SynthRig:
    """The synthetic multi-camera scene (module docstring); frame sets by index.

    Parameters
    ----------
    cameras : int
        1 to :data:`MAX_CAMERAS`.
    board : bool
        Render the rig's calibration sequence (the board in the empty room) instead of the person.
    colour_only : int
        The last ``colour_only`` cameras have no depth (``Frame.depth = None``), in ``[0, cameras]``.
    occlude : str or tuple of Occlusion
        Periods in which a card hides a target from one camera: ``"none"``,
        ``"auto"`` (with 2 or more cameras, each hand once, camera and period from the
        seed: :meth:`auto_occlusions`), ``"CAM:TARGET:START-END[,...]"`` (frames,
        inclusive) or :class:`Occlusion` objects.
    **scene
        :class:`~drivers.synth.SynthSource`'s options (frames, seed, size, fps,
        background_frames, start_ns, depth_model, hands).
    """

    def __init__(
        self,
        cameras: int,
        *,
        board: bool = False,
        colour_only: int = 0,
        occlude: str | tuple[Occlusion, ...] = "none",
        **scene: Any,
    ) -> None:
        self.cameras = _int_option("synth option cameras", cameras, 1, MAX_CAMERAS)
        self.colour_only = _int_option("synth option colour_only", colour_only, 0, self.cameras)
        self.board = BoardSpec() if board else None
        if board:  # the calibration sequence: the board in the empty room
            scene["background_frames"] = scene.get("frames", _SCENE_FRAMES)
        probe = SynthSource(**scene)
        if probe.clutter:
            raise InputError(
                f"synth option clutter must be 0 with cameras >= 2 (the rig renders its own room), got {probe.clutter}"
            )
        if probe.away:
            raise InputError(f"synth option away must be 0 with cameras >= 2, got {probe.away}")
        self.poses = rig_poses(self.cameras, probe._rng(11))
        tex = _Textures(probe._rng(10))
        pyramid = None
        if self.board is not None:
            pyramid = [self.board.image(4.0)]
            while pyramid[-1].shape[1] > 64:  # block means (pyrDown's samples sit a quarter pixel off the centres)
                pyramid.append(cv2.resize(pyramid[-1], None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA))
        spec = self.board or BoardSpec()
        self.source = probe
        self.occlusions = self._occlusions(parse_occlusions(occlude) if isinstance(occlude, str) else tuple(occlude))
        self.views = {
            name: _CameraView(
                k,
                pose,
                render_static(probe.intrinsics, pose, spec, pyramid, tex),
                tuple(o for o in self.occlusions if o.camera == name),
                **scene,
            )
            for k, (name, pose) in enumerate(self.poses.items())
        }

    @property
    def targets(self) -> tuple[str, ...]:
        """The scene's targets (:data:`drivers.synth.TARGETS`; one hand: the right hand only)."""
        return TARGETS if self.source.hands == 2 else TARGETS[:1]

    def _occlusions(self, spec: tuple[Occlusion, ...] | str) -> tuple[Occlusion, ...]:
        """The periods of ``spec`` checked against the rig and the scene (``"auto"`` drawn from the seed)."""
        if spec == "none" or (spec == "auto" and (self.board is not None or self.cameras < 2)):
            return ()
        if spec == "auto":
            return self.auto_occlusions()
        if self.board is not None and spec:
            raise InputError("synth option occlude hides a target of the person; the board sequence has none")
        frames = len(self.source)
        for o in spec:
            if o.camera not in self.poses:
                raise InputError(f"occlusion {o}: no camera {o.camera!r}; the rig has {', '.join(self.poses)}")
            if o.target not in self.targets:
                raise InputError(f"occlusion {o}: no target {o.target!r}; the scene has {', '.join(self.targets)}")
            if not 0 <= o.start <= o.end < frames:
                raise InputError(f"occlusion {o}: frames must lie in [0, {frames - 1}], got {o.start}-{o.end}")
        return tuple(spec)  # type: ignore[arg-type]

    def auto_occlusions(self) -> tuple[Occlusion, ...]:
        """One period per hand, in a camera drawn from the seed.

        The person frames are split into one share per hand (the right hand's
        first); each hand is hidden for :data:`AUTO_FRACTION` of its share (at most
        :data:`AUTO_MAX_FRAMES`, at least 1 frame) at a start drawn inside it.
        Nothing when the scene has fewer person frames than hands.
        """
        rng = self.source._rng(12)
        first = self.source.background_frames
        hands = [t for t in self.targets if t != "head"]
        share = (len(self.source) - first) // len(hands)
        if share < 1:
            return ()
        out = []
        for k, target in enumerate(hands):
            length = max(1, min(AUTO_MAX_FRAMES, int(round(AUTO_FRACTION * share))))
            start = first + k * share + int(rng.integers(0, share - length + 1))
            out.append(Occlusion(f"cam{int(rng.integers(0, self.cameras))}", target, start, start + length - 1))
        return tuple(out)

    def __len__(self) -> int:
        return len(self.source)

    def timestamp_ns(self, index: int) -> int:
        return self.source.timestamp_ns(index)

    def true_events(self) -> list[dict]:
        """Scripted scene: its true events (:meth:`drivers.synth.SynthSource.true_events`: 3-D distances, the same
        for every camera); [] otherwise."""
        return self.source.true_events()

    def truth_mm(self, index: int) -> dict[str, np.ndarray]:
        """World ground truth (mm) per target at ``index`` (empty for a background frame)."""
        view = next(iter(self.views.values()))
        world = view.world_pose(index)
        if world is None:
            return {}
        points = (world.right_hand, world.left_hand, sc.face_centre(world))  # the face as the nominal camera sees it
        targets = TARGETS if self.source.hands == 2 else TARGETS[:1]
        return {name: np.asarray(p) * 1000.0 for name, p in zip(targets, points, strict=False)}

    @property
    def colour_only_cameras(self) -> tuple[str, ...]:
        """The cameras without depth (the last ``colour_only``)."""
        return tuple(self.poses)[self.cameras - self.colour_only :]

    def frames(self, index: int) -> dict[str, Frame]:
        """Every camera's frame at ``index`` (no depth from the colour-only cameras)."""
        return self.render(index)[0]

    def render(self, index: int) -> tuple[dict[str, Frame], dict[str, tuple[str, ...]]]:
        """Every camera's frame at ``index`` and the targets each camera sees (:meth:`_CameraView.visible`)."""
        plain = self.colour_only_cameras
        frames, visible = {}, {}
        for name, view in self.views.items():
            frame, masks = view.render(index)
            frames[name] = replace(frame, seq=index, **({"depth": None} if name in plain else {}))
            visible[name] = view.visible(index, masks)
        return frames, visible

    def metadata(self) -> dict[str, str]:
        """The single-camera scene's metadata, the camera count, the board and the world frame's definition."""
        return {
            **self.source.metadata(),
            "generator": "fusion_pf.synth_rig",
            "cameras_count": str(self.cameras),
            "colour_only_cameras": ",".join(self.colour_only_cameras),
            "world": "calibration board frame (origin top-left outer corner, x right, y down, z into the board)",
            **(self.board.metadata() if self.board is not None else {}),
            **({"occlusions": ",".join(map(str, self.occlusions))} if self.occlusions else {}),
        }
