"""Draw what the multi-camera (world) tracker did: every camera's view and a top view of the rig, per instant.

Reads a world tracker output: ``/tracker/world`` (JSON ``fusion_pf.WorldEstimate``, one
message per instant: every target's world position, state, uncertainty, the cameras that
measured it and its pixel in each camera) and the camera poses on ``/tf``; the images come
from the multi-camera recording that was tracked (:class:`drivers.rig.RigReplay`: the tracked
file itself, its metadata ``source`` or ``--input``), with its world ground truth
(``/ground_truth/world``) when it has one.

Each instant is one image: a grid of tiles (:func:`grid_shape`), one per camera in the rig's
order, then the top view, all of one size (the largest camera image at its integer drawing
scale, :func:`drivers.render.draw_scale`), 2 px black gaps.

* **Camera tiles**: the image, and per target its pixel in that camera (``pixels[camera]``)
  as a ring of radius 9 px in the target's colour (:func:`target_colour`), 3 px thick when the
  camera measured the target (it is in ``cameras``), 1 px when it did not, labelled with the
  target and its state. A camera without a frame at the instant is a black tile.
* **Top view** (world x to the right, world z up the tile: looking down the world y axis, which
  points down): the cameras (a white dot at the optical centre, the optical axis and the edges
  of the horizontal field of view), each target's position (a filled disc of radius 5 px in its
  colour, a thin circle of ``2 sigma_mm``) with its trail over the last :data:`TRAIL_INSTANTS`
  instants, and the ground truth (white tilted crosses, a thin grey trail); a legend at the top
  (:func:`legend_band` px: per target its state, ``2 sigma`` and the cameras that measured it).
  The view is fixed for the whole recording (:meth:`TopView.fit`): it spans every camera
  centre, every estimated position and every ground-truth point, grown by
  :data:`TOP_MARGIN_MM` on each side, at one scale on both axes, centred in the tile below the
  legend.
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame, Intrinsics
from fusion_pf.rig import CameraPose

from . import mcap_format as fmt
from .mcap_replay import McapTopics
from .render import Outputs, Rendered, draw_scale, frame_rate
from .rig import RigReplay, tf_poses

#: Colours (RGB) of the usual targets; others take :data:`EXTRA_TARGET_COLOURS` in order of appearance.
TARGET_COLOURS = {"right_hand": (255, 70, 70), "left_hand": (70, 160, 255), "head": (255, 210, 40)}
EXTRA_TARGET_COLOURS = ((200, 100, 255), (80, 230, 120), (255, 140, 200), (150, 150, 150))
#: Ground truth in the top view (crosses) and its trail.
TRUTH_COLOUR, TRUTH_TRAIL_COLOUR = (255, 255, 255), (150, 150, 150)
#: Cameras in the top view: the optical centre and the field of view's edges.
CAMERA_COLOUR, FOV_COLOUR = (255, 255, 255), (110, 110, 110)
#: Background of the top view and its 500 mm grid.
TOP_BACKGROUND, GRID_COLOUR, GRID_MM = (24, 24, 28), (48, 48, 56), 500.0
#: Instants of trail drawn behind each target (the current one included).
TRAIL_INSTANTS = 30
#: Room around the drawn points in the top view, mm.
TOP_MARGIN_MM = 250.0
#: Gap between tiles, px.
GAP = 2


@dataclass(frozen=True)
class WorldTarget:
    """One target of a ``/tracker/world`` message."""

    target: str
    state: str | None
    position_mm: np.ndarray | None
    sigma_mm: float | None
    cameras: tuple[str, ...]
    pixels: Mapping[str, tuple[float, float] | None]


def _finite(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def parse_world(msg: object, where: str) -> list[WorldTarget]:
    """The targets of one ``fusion_pf.WorldEstimate`` object.

    Raises
    ------
    InputError
        Naming the field, the target and what was expected.
    """
    targets = msg.get("targets") if isinstance(msg, dict) else None
    if not isinstance(targets, list):
        raise InputError(f"{where}: expected an object with a 'targets' list, got {str(msg)[:80]!r}")
    out = []
    for item in targets:
        name = item.get("target") if isinstance(item, dict) else None
        if not (isinstance(name, str) and name):
            raise InputError(f"{where}: every target needs a non-empty 'target' name, got {str(item)[:80]!r}")
        state, pos, sigma = item.get("state"), item.get("position_mm"), item.get("sigma_mm")
        cameras, pixels = item.get("cameras", []), item.get("pixels", {})
        if state is not None and not isinstance(state, str):
            raise InputError(f"{where}: {name} state must be a string or null, got {state!r}")
        if pos is not None and not (isinstance(pos, list) and len(pos) == 3 and all(map(_finite, pos))):
            raise InputError(f"{where}: {name} position_mm must be [x, y, z] (finite mm) or null, got {pos!r}")
        if sigma is not None and not (_finite(sigma) and sigma >= 0):
            raise InputError(f"{where}: {name} sigma_mm must be a number >= 0 or null, got {sigma!r}")
        if not (isinstance(cameras, list) and all(isinstance(c, str) for c in cameras)):
            raise InputError(f"{where}: {name} cameras must be a list of camera names, got {cameras!r}")
        if not isinstance(pixels, dict):
            raise InputError(f"{where}: {name} pixels must map cameras to [u, v] or null, got {pixels!r}")
        uv: dict[str, tuple[float, float] | None] = {}
        for camera, p in pixels.items():
            if p is not None and not (isinstance(p, list) and len(p) == 2 and all(map(_finite, p))):
                raise InputError(f"{where}: {name} pixels of {camera} must be [u, v] or null, got {p!r}")
            uv[camera] = None if p is None else (float(p[0]), float(p[1]))
        out.append(
            WorldTarget(
                name,
                state,
                None if pos is None else np.asarray(pos, np.float64),
                None if sigma is None else float(sigma),
                tuple(cameras),
                uv,
            )
        )
    return out


def has_world(path: Path) -> bool:
    """Whether ``path`` holds the world tracker's ``/tracker/world`` topic."""
    with McapTopics(path) as rec:
        return fmt.WORLD_ESTIMATE_TOPIC in rec.topics


def read_world(path: Path) -> tuple[dict[int, list[WorldTarget]], dict[str, CameraPose]]:
    """The ``/tracker/world`` messages of ``path`` by log time (ns), and the camera poses on its ``/tf``.

    Raises
    ------
    InputError
        When there is no ``/tracker/world`` message, a message is malformed, or a camera has
        several different poses.
    """
    out: dict[int, list[WorldTarget]] = {}
    with McapTopics(path) as rec:
        for t, _encoding, data in rec.messages(fmt.WORLD_ESTIMATE_TOPIC):
            where = f"{path}: {fmt.WORLD_ESTIMATE_TOPIC} at log_time {t}"
            try:
                msg = json.loads(data)
            except (ValueError, RecursionError):
                raise InputError(f"{where}: not valid JSON") from None
            out[t] = parse_world(msg, where)
        try:
            seen = tf_poses(rec)
        except RecordingError as exc:
            raise InputError(f"{path}: {exc}") from None
    if not out:
        raise InputError(f"{path} has no {fmt.WORLD_ESTIMATE_TOPIC} messages; expected a world tracker's output")
    poses = {}
    for camera, found in seen.items():
        if len(found) > 1:
            raise InputError(f"{path}: camera {camera} has {len(found)} different poses on {fmt.TF_TOPIC}")
        poses[camera] = next(iter(found))
    return out, poses


def target_colour(name: str, order: Sequence[str]) -> tuple[int, int, int]:
    """The colour of target ``name``: :data:`TARGET_COLOURS`, else the extras in the order of ``order``."""
    if name in TARGET_COLOURS:
        return TARGET_COLOURS[name]
    extras = [t for t in order if t not in TARGET_COLOURS]
    return EXTRA_TARGET_COLOURS[extras.index(name) % len(EXTRA_TARGET_COLOURS)]


def grid_shape(tiles: int) -> tuple[int, int]:
    """``(columns, rows)`` of an instant's grid of ``tiles`` tiles: ``ceil(sqrt(tiles))`` columns."""
    columns = math.ceil(math.sqrt(tiles))
    return columns, math.ceil(tiles / columns)


def _label(img: np.ndarray, text: str, org: tuple[int, int], colour: tuple[int, int, int]) -> None:
    """``text`` at ``org`` (its baseline's left end) in ``colour`` on a black box."""
    font, fs = cv2.FONT_HERSHEY_SIMPLEX, 0.45
    (w, h), base = cv2.getTextSize(text, font, fs, 1)
    cv2.rectangle(img, (org[0] - 2, org[1] - h - 2), (org[0] + w + 1, org[1] + base - 1), (0, 0, 0), -1)
    cv2.putText(img, text, org, font, fs, colour, 1, cv2.LINE_AA)


def draw_camera(
    camera: str,
    frame: Frame | None,
    targets: Sequence[WorldTarget],
    order: Sequence[str],
    scale: int,
    size: tuple[int, int],
    header: str,
) -> np.ndarray:
    """One camera's tile (``size`` = (width, height)): its image at ``scale`` and each target's pixel in it."""
    tile = np.zeros((size[1], size[0], 3), np.uint8)
    if frame is None:
        _label(tile, f"{camera}  {header}  no frame", (6, 16), (255, 255, 255))
        return tile
    img = frame.color
    if scale > 1:
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    h, w = min(img.shape[0], size[1]), min(img.shape[1], size[0])  # a camera whose size changed: clipped
    tile[:h, :w] = img[:h, :w]
    for item in targets:
        uv = item.pixels.get(camera)
        if uv is None:
            continue
        colour = target_colour(item.target, order)
        c = (int(round((uv[0] + 0.5) * scale - 0.5)), int(round((uv[1] + 0.5) * scale - 0.5)))
        measured = camera in item.cameras
        cv2.circle(tile, c, 9, (0, 0, 0), 5 if measured else 3, cv2.LINE_AA)
        cv2.circle(tile, c, 9, colour, 3 if measured else 1, cv2.LINE_AA if measured else cv2.LINE_8)
        _label(tile, f"{item.target.replace('_hand', '')}: {item.state or '-'}", (c[0] + 12, c[1] - 12), colour)
    _label(tile, f"{camera}  {header}", (6, 16), (255, 255, 255))
    return tile


@dataclass(frozen=True)
class TopView:
    """The top view's map from world x-z (mm) to tile pixels: x to the right, z up the tile.

    The map area is the tile below a ``band`` px high header (the legend):
    ``u = (width - 1) / 2 + (x - centre_x) / mm_per_px``,
    ``v = band + (height - band - 1) / 2 - (z - centre_z) / mm_per_px``.
    """

    centre_x: float
    centre_z: float
    mm_per_px: float
    width: int
    height: int
    band: int = 0

    @classmethod
    def fit(cls, points_mm: np.ndarray, size: tuple[int, int], band: int = 0) -> TopView:
        """The view of ``points_mm`` (N, 3 world mm; x and z used) with :data:`TOP_MARGIN_MM` around
        them, filling the tile of ``size`` (width, height) below a ``band`` px header at one scale."""
        xz = np.asarray(points_mm, np.float64).reshape(-1, 3)[:, [0, 2]]
        lo, hi = xz.min(axis=0) - TOP_MARGIN_MM, xz.max(axis=0) + TOP_MARGIN_MM
        w, h = size
        scale = max((hi[0] - lo[0]) / w, (hi[1] - lo[1]) / max(h - band, 1))
        return cls(float(lo[0] + hi[0]) / 2.0, float(lo[1] + hi[1]) / 2.0, float(scale), w, h, band)

    def px(self, xyz_mm: np.ndarray) -> tuple[int, int]:
        """Tile pixel of the world point ``xyz_mm`` (its y ignored)."""
        u = (self.width - 1) / 2.0 + (float(xyz_mm[0]) - self.centre_x) / self.mm_per_px
        v = self.band + (self.height - self.band - 1) / 2.0 - (float(xyz_mm[2]) - self.centre_z) / self.mm_per_px
        return int(round(u)), int(round(v))


def draw_top(
    view: TopView,
    cameras: Mapping[str, tuple[CameraPose, Intrinsics | None]],
    targets: Sequence[WorldTarget],
    trails: Mapping[str, Sequence[np.ndarray | None]],
    truth: Mapping[str, np.ndarray],
    truth_trails: Mapping[str, Sequence[np.ndarray]],
    order: Sequence[str],
    header: str,
) -> np.ndarray:
    """The top view of the rig at one instant (module docstring)."""
    img = np.full((view.height, view.width, 3), TOP_BACKGROUND, np.uint8)
    s = view.mm_per_px
    x0 = view.centre_x - view.width * s / 2.0
    z0 = view.centre_z - (view.height - view.band) * s / 2.0
    for x in np.arange(math.ceil(x0 / GRID_MM) * GRID_MM, x0 + view.width * s, GRID_MM):
        u = view.px(np.array([x, 0.0, view.centre_z]))[0]
        cv2.line(img, (u, view.band), (u, view.height - 1), GRID_COLOUR, 1)
    for z in np.arange(math.ceil(z0 / GRID_MM) * GRID_MM, z0 + (view.height - view.band) * s, GRID_MM):
        v = view.px(np.array([view.centre_x, 0.0, z]))[1]
        cv2.line(img, (0, v), (view.width - 1, v), GRID_COLOUR, 1)
    reach = 0.25 * min(view.width, view.height) * s  # length of the drawn axis and field-of-view edges, mm
    for name, (pose, intr) in cameras.items():
        centre = pose.translation_mm
        half = math.atan2(intr.width / 2.0, intr.fx) if intr is not None else math.radians(30.0)
        for side in (-1.0, 1.0):
            ray = pose.rotation @ np.array([side * math.tan(half), 0.0, 1.0])
            ray[1] = 0.0
            if np.linalg.norm(ray) > 1e-9:
                cv2.line(img, view.px(centre), view.px(centre + reach * ray / np.linalg.norm(ray)), FOV_COLOUR, 1)
        axis = pose.rotation[:, 2].copy()
        axis[1] = 0.0
        if np.linalg.norm(axis) > 1e-9:
            end = view.px(centre + 0.6 * reach * axis / np.linalg.norm(axis))
            cv2.line(img, view.px(centre), end, CAMERA_COLOUR, 1, cv2.LINE_AA)
        c = view.px(centre)
        cv2.circle(img, c, 4, CAMERA_COLOUR, -1)
        _label(img, name, (c[0] + 7, c[1] + 16), CAMERA_COLOUR)
    for points in truth_trails.values():
        if len(points) > 1:
            cv2.polylines(img, [np.array([view.px(p) for p in points], np.int32)], False, TRUTH_TRAIL_COLOUR, 1)
    for name, points in trails.items():
        colour = target_colour(name, order)
        for a, b in zip(points[:-1], points[1:], strict=False):
            if a is not None and b is not None:
                cv2.line(img, view.px(a), view.px(b), colour, 2, cv2.LINE_AA)
    for k, item in enumerate(targets):
        colour = target_colour(item.target, order)
        line = f"{item.target}: {item.state or '-'}"
        if item.position_mm is not None:
            c = view.px(item.position_mm)
            if item.sigma_mm is not None:
                cv2.circle(img, c, max(1, int(round(2.0 * item.sigma_mm / s))), colour, 1, cv2.LINE_AA)
            cv2.circle(img, c, 6, (0, 0, 0), -1)
            cv2.circle(img, c, 5, colour, -1)
            line += f"  2 sigma {2.0 * item.sigma_mm:.0f} mm" if item.sigma_mm is not None else ""
        line += f"  [{','.join(item.cameras)}]"
        _label(img, line, (6, 34 + 16 * k), colour)
    for point in truth.values():
        c = view.px(point)
        cv2.drawMarker(img, c, (0, 0, 0), cv2.MARKER_TILTED_CROSS, 13, 4)
        cv2.drawMarker(img, c, TRUTH_COLOUR, cv2.MARKER_TILTED_CROSS, 12, 2)
    _label(img, f"top view (x right, z up)  {header}", (6, 16), (255, 255, 255))
    return img


def legend_band(targets: int) -> int:
    """Height (px) of the top view's header: its title and one line per target."""
    return 24 + 16 * targets


def compose(tiles: Sequence[np.ndarray]) -> np.ndarray:
    """The tiles (one size) in a :func:`grid_shape` grid, row by row, :data:`GAP` px black gaps."""
    h, w = tiles[0].shape[:2]
    columns, rows = grid_shape(len(tiles))
    out = np.zeros((rows * (h + GAP) - GAP, columns * (w + GAP) - GAP, 3), np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        out[r * (h + GAP) : r * (h + GAP) + h, c * (w + GAP) : c * (w + GAP) + w] = tile
    return out


def render_rig(
    tracked: Path,
    images: Path,
    *,
    video: Path | None = None,
    sheet: Path | None = None,
    every: int = 10,
    columns: int = 6,
    tile_width: int = 320,
    fps: float | None = None,
) -> Rendered:
    """Render a world tracker's output over the multi-camera recording ``images`` (module docstring).

    Returns
    -------
    Rendered
        Instants drawn, those with a ``/tracker/world`` message, the size of one instant's image, sheet tiles.
    """
    world, tf = read_world(tracked)
    order: list[str] = []
    for items in world.values():
        order += [i.target for i in items if i.target not in order]
    with RigReplay(images) as rig:
        named = {c for items in world.values() for i in items for c in (*i.cameras, *i.pixels)}
        unknown = sorted(named - set(rig.cameras))
        if unknown:
            raise InputError(
                f"{tracked}: {fmt.WORLD_ESTIMATE_TOPIC} names camera {unknown[0]!r}, which {images} does not have "
                f"(its cameras: {', '.join(rig.cameras)}); pass --input with the recording that was tracked"
            )
        times = np.asarray(rig.timestamps, np.int64)
        if not set(times.tolist()) & set(world):
            raise InputError(
                f"{tracked}: no {fmt.WORLD_ESTIMATE_TOPIC} message has the time of an instant of {images}; "
                "pass --input with the recording that was tracked"
            )
        poses = {name: tf.get(name, rig.poses[name]) for name in rig.cameras}
        first = {name: replay.frame(0) for name, replay in rig.replays.items() if len(replay)}
        if not first:
            raise InputError(f"{images}: no camera has a readable frame")
        intrinsics = {name: first[name].intrinsics if name in first else None for name in rig.cameras}
        scales = {name: draw_scale(f.color.shape[1]) for name, f in first.items()}
        size = (
            max(f.color.shape[1] * scales[n] for n, f in first.items()),
            max(f.color.shape[0] * scales[n] for n, f in first.items()),
        )
        points = [p.translation_mm for p in poses.values()]
        points += [i.position_mm for items in world.values() for i in items if i.position_mm is not None]
        points += [p for per in (rig.world_truth or {}).values() for p in per.values()]
        view = TopView.fit(np.array(points), size, legend_band(len(order)))
        cameras = {n: (poses[n], intrinsics[n]) for n in rig.cameras}
        trails: dict[str, deque[np.ndarray | None]] = {}
        truth_trails: dict[str, deque[np.ndarray]] = {}
        sink = Outputs(video, sheet, every, columns, tile_width, frame_rate(times) if fps is None else fps)
        try:
            for fs in rig:
                targets = world.get(fs.timestamp_ns)
                tracked_now = targets is not None
                targets = targets or []
                for name in set(trails) | {i.target for i in targets}:
                    trail = trails.setdefault(name, deque(maxlen=TRAIL_INSTANTS))
                    trail.append(next((i.position_mm for i in targets if i.target == name), None))
                truth = dict(fs.truth_mm or {})
                for name, p in truth.items():
                    truth_trails.setdefault(name, deque(maxlen=TRAIL_INSTANTS)).append(p)
                header = f"instant {fs.index}" + ("  background" if fs.background else "")
                header += "" if tracked_now else "  not tracked"
                tiles = [
                    draw_camera(
                        name,
                        fs.views[name].frame if name in fs.views else None,
                        targets,
                        order,
                        scales.get(name, 1),
                        size,
                        header,
                    )
                    for name in rig.cameras
                ]
                top = draw_top(
                    view,
                    cameras,
                    targets,
                    {n: list(t) for n, t in trails.items()},
                    truth,
                    {n: list(t) for n, t in truth_trails.items()},
                    order,
                    header,
                )
                sink.add(compose([*tiles, top]), tracked_now)
        finally:
            sink.close()
    return sink.write_sheet()
