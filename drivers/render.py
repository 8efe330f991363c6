"""Draw what the tracker did: images with cue points, particles, the estimate and the track state.

Reads a tracked recording (the output of ``fusion-pf track -o``): the frames through
:class:`drivers.mcap_replay.McapReplay` (from the tracked file, or, when it has no colour,
from the input recording), the tracker topics ``/tracker/estimate``, ``/tracker/cues`` and
``/tracker/particles`` with :class:`~drivers.mcap_replay.McapTopics`, matched to the frames by log time.

``/tracker/cues`` is read as a mapping ``source -> {"u", "v", "quality"} or null`` for
whatever sources it holds (besides ``frame``, ``timestamp_ns`` and the optional ``roi``
``[x0, y0, x1, y1]``); an estimate with a ``state`` field has the state written under it, one
with ``sigma_px`` a thin circle of radius ``2 sigma_px`` (its uncertainty) and the value in the header;
with several targets (``targets``) each has a ring in its state's colour and its own thin ``2 sigma_px`` circle.

Drawing is done on the image scaled by an integer factor (so small images stay legible),
with OpenCV; the particles are drawn in one vectorised assignment.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame

from . import mcap_format as fmt
from .mcap_replay import McapReplay, McapTopics
from .rig import colour_cameras
from .tracker_topics import find_source

#: Colours (RGB) of the known sources; other sources take :data:`EXTRA_COLOURS` in sorted order.
SOURCE_COLOURS = {
    "colour": (40, 230, 60),
    "depth": (60, 130, 255),
    "skeleton": (255, 80, 230),
    "skin_rgb": (255, 150, 40),
    "skin_rg": (0, 230, 230),
    "skin_lab": (170, 110, 255),
}
EXTRA_COLOURS = ((255, 255, 255), (150, 255, 150), (255, 200, 200), (200, 200, 120))
PARTICLE_COLOUR = (255, 220, 30)
ESTIMATE_COLOUR = (255, 30, 30)
ROI_COLOUR = (235, 235, 235)
#: Colours of the track states (paper 004 §5.2).
STATE_COLOURS = {
    "tracking": (40, 230, 60),
    "lost": (255, 40, 40),
    "uninitialised": (255, 200, 0),
    "unlabelled": (255, 140, 0),
    "combined": (60, 140, 255),
}
#: Keys of a ``/tracker/cues`` message that are not sources.
CUE_META_KEYS = ("frame", "timestamp_ns", "roi")
#: Images narrower than this are scaled up by an integer factor before drawing.
MIN_DRAW_WIDTH = 640


@dataclass
class TrackerFrame:
    """Tracker output of one frame (any part may be missing).

    Attributes
    ----------
    estimate : dict or None
        The ``/tracker/estimate`` message.
    cues : dict of str to (u, v, quality) or None
        Per source; None when the source gave nothing this frame.
    roi : tuple of float or None
        ``(x0, y0, x1, y1)``, x1 and y1 exclusive.
    particles : ndarray, shape (N, 2), or None
        Particle positions (u, v).
    """

    estimate: dict | None = None
    cues: dict[str, tuple[float, float, float] | None] = field(default_factory=dict)
    roi: tuple[float, float, float, float] | None = None
    particles: np.ndarray | None = None


def _number(value: object) -> float | None:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        return None
    return float(value)


def _parse_cues(msg: dict, where: str) -> tuple[dict, tuple | None]:
    cues: dict[str, tuple[float, float, float] | None] = {}
    for name, value in msg.items():
        if name in CUE_META_KEYS:
            continue
        if value is None:
            cues[name] = None
            continue
        if not isinstance(value, dict):
            raise InputError(f"{where}: source {name!r} must be an object with u, v or null, got {value!r}")
        u, v = _number(value.get("u")), _number(value.get("v"))
        q = _number(value.get("quality"))
        cues[name] = None if u is None or v is None else (u, v, math.nan if q is None else q)
    roi = msg.get("roi")
    box = None
    if roi is not None:
        if not (isinstance(roi, list) and len(roi) == 4 and all(_number(x) is not None for x in roi)):
            raise InputError(f"{where}: roi must be [x0, y0, x1, y1], got {roi!r}")
        box = tuple(float(x) for x in roi)
    return cues, box


def _particles(data: bytes, where: str) -> np.ndarray:
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud

    cloud = PointCloud()
    try:
        cloud.ParseFromString(data)
    except Exception:
        raise InputError(f"{where}: not a foxglove.PointCloud message") from None
    names = {f.name: f for f in cloud.fields}
    if "x" not in names or "y" not in names or cloud.point_stride <= 0:
        raise InputError(f"{where}: point cloud without x, y fields")
    stride = cloud.point_stride
    n = len(cloud.data) // stride
    raw = np.frombuffer(cloud.data, np.uint8, count=n * stride).reshape(n, stride)
    x = raw[:, names["x"].offset : names["x"].offset + 4].copy().view("<f4")[:, 0]
    y = raw[:, names["y"].offset : names["y"].offset + 4].copy().view("<f4")[:, 0]
    return np.stack([x, y], axis=1).astype(np.float64)


def read_tracker_topics(path: Path) -> dict[int, TrackerFrame]:
    """Tracker outputs of ``path`` by log time (ns).

    Raises
    ------
    InputError
        When the file has no tracker topic or a message is malformed.
    """
    out: dict[int, TrackerFrame] = {}
    with McapTopics(path) as rec:
        for topic in (fmt.ESTIMATE_TOPIC, fmt.CUES_TOPIC, fmt.PARTICLES_TOPIC):
            for t, _encoding, data in rec.messages(topic):
                where = f"{path}: {topic} at log_time {t}"
                item = out.setdefault(t, TrackerFrame())
                if topic == fmt.PARTICLES_TOPIC:
                    item.particles = _particles(data, where)
                    continue
                try:
                    msg = json.loads(data)
                except (ValueError, RecursionError):
                    raise InputError(f"{where}: not valid JSON") from None
                if not isinstance(msg, dict):
                    raise InputError(f"{where}: expected a JSON object, got {type(msg).__name__}")
                if topic == fmt.ESTIMATE_TOPIC:
                    item.estimate = msg
                else:
                    item.cues, item.roi = _parse_cues(msg, where)
    if not out:
        raise InputError(
            f"{path} has no {fmt.ESTIMATE_TOPIC}, {fmt.CUES_TOPIC} or {fmt.PARTICLES_TOPIC} messages; "
            "expected the output of fusion-pf track -o"
        )
    return out


def image_recording(tracked: Path, input_path: Path | None, *, rig: bool = False) -> Path:
    """The recording that holds the colour images: ``input_path``, else ``tracked`` when it
    has ``/camera/color`` messages (``rig``: ``/<camera>/camera/color``), else the recording named
    by its metadata ``source`` (:func:`~drivers.tracker_topics.find_source`: as stored, else from
    the output's folder).

    Raises
    ------
    InputError
        When no such recording exists.
    """
    if input_path is not None:
        if not input_path.is_file():
            raise InputError(f"--input {input_path} does not exist; expected the recording that was tracked")
        return input_path
    with McapTopics(tracked) as rec:
        if colour_cameras(rec.topics) if rig else fmt.COLOR_TOPIC in rec.topics:
            return tracked
        metadata = rec.metadata()
    source = find_source(tracked, metadata)
    if source is None or not source.is_file():
        images = "/<camera>" + fmt.COLOR_TOPIC if rig else fmt.COLOR_TOPIC
        raise InputError(
            f"{tracked} has no {images} images and its metadata source {metadata.get('source')!r} is "
            "not a file (nor next to it); pass --input REC.mcap (the recording that was tracked)"
        )
    return source


def _colour_of(name: str, order: list[str]) -> tuple[int, int, int]:
    if name in SOURCE_COLOURS:
        return SOURCE_COLOURS[name]
    extras = [s for s in order if s not in SOURCE_COLOURS]
    return EXTRA_COLOURS[extras.index(name) % len(EXTRA_COLOURS)]


def draw_scale(width: int) -> int:
    """Integer factor that brings an image of ``width`` px to at least :data:`MIN_DRAW_WIDTH`."""
    return max(1, math.ceil(MIN_DRAW_WIDTH / width))


def draw(frame: Frame, out: TrackerFrame | None, sources: list[str], scale: int) -> np.ndarray:
    """Draw one frame.

    Parameters
    ----------
    frame : Frame
        Gives the image (RGB) and the frame number.
    out : TrackerFrame or None
        The tracker outputs of the frame (None: a frame the tracker did not process).
    sources : list of str
        Every source of the recording, for stable colours and the legend order.
    scale : int
        Integer scale factor of the drawing.

    Returns
    -------
    ndarray, shape (H * scale, W * scale, 3), uint8
        RGB.
    """
    img = frame.color
    if scale > 1:
        img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    img = np.ascontiguousarray(img).copy()
    h, w = img.shape[:2]
    font, fs, th = cv2.FONT_HERSHEY_SIMPLEX, 0.45, 1

    def px(u: float, v: float) -> tuple[int, int]:
        return int(round((u + 0.5) * scale - 0.5)), int(round((v + 0.5) * scale - 0.5))

    def label(text: str, org: tuple[int, int], colour: tuple[int, int, int]) -> None:
        cv2.putText(img, text, org, font, fs, (0, 0, 0), th + 2, cv2.LINE_AA)
        cv2.putText(img, text, org, font, fs, colour, th, cv2.LINE_AA)

    header = f"frame {frame.seq}" + ("  background" if frame.background else "")
    if out is not None:
        if out.roi is not None:
            x0, y0, x1, y1 = out.roi
            cv2.rectangle(img, px(x0, y0), px(x1 - 1, y1 - 1), ROI_COLOUR, 1)
        if out.particles is not None and len(out.particles):
            p = np.rint((out.particles + 0.5) * scale - 0.5).astype(np.int64)
            for du, dv in ((0, 0), (1, 0), (0, 1), (1, 1)):
                u, v = p[:, 0] + du, p[:, 1] + dv
                inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
                img[v[inside], u[inside]] = PARTICLE_COLOUR
        for k, name in enumerate(sources):
            colour = _colour_of(name, sources)
            cue = out.cues.get(name)
            present = cue is not None
            label(f"{name}{'' if present else ': -'}", (w - 110, 16 + 16 * k), colour)
            if present:
                c = px(cue[0], cue[1])
                cv2.drawMarker(img, c, (0, 0, 0), cv2.MARKER_TILTED_CROSS, 15, 4)
                cv2.drawMarker(img, c, colour, cv2.MARKER_TILTED_CROSS, 14, 2)
        e = out.estimate or {}
        targets = e.get("targets")
        if isinstance(targets, dict):  # several targets (track --targets): a ring per target, coloured by state
            for k, (name, te) in enumerate(targets.items()):
                te = te if isinstance(te, dict) else {}
                tu, tv, ts = _number(te.get("u")), _number(te.get("v")), te.get("state")
                colour = STATE_COLOURS.get(ts, (255, 255, 255)) if isinstance(ts, str) else (255, 255, 255)
                label(f"{name}: {ts}", (6, 34 + 16 * k), colour)
                if tu is not None and tv is not None:
                    c = px(tu, tv)
                    cv2.circle(img, c, 9, (0, 0, 0), 4, cv2.LINE_AA)
                    cv2.circle(img, c, 9, colour, 2, cv2.LINE_AA)
                    label(name.replace("_hand", ""), (c[0] + 11, c[1] - 11), colour)
                    sigma = _number(te.get("sigma_px"))
                    if sigma is not None:  # the target's 2-sigma circle, as the single palm's
                        cv2.circle(img, c, max(1, int(round(2.0 * sigma * scale))), colour, 1, cv2.LINE_AA)
            label(header, (6, 16), (255, 255, 255))
            return img
        u, v = _number(e.get("u")), _number(e.get("v"))
        if u is not None and v is not None:
            c = px(u, v)
            cv2.circle(img, c, 9, (0, 0, 0), 4, cv2.LINE_AA)
            cv2.circle(img, c, 9, ESTIMATE_COLOUR, 2, cv2.LINE_AA)
            cv2.drawMarker(img, c, ESTIMATE_COLOUR, cv2.MARKER_CROSS, 6, 1)
            sigma = _number(e.get("sigma_px"))
            if sigma is not None:  # the 2-sigma circle of the estimate's uncertainty
                cv2.circle(img, c, max(1, int(round(2.0 * sigma * scale))), ESTIMATE_COLOUR, 1, cv2.LINE_AA)
                header += f"  2 sigma {2.0 * sigma:.1f} px"
        else:
            header += "  no estimate"
        state = e.get("state")
        if isinstance(state, str):
            label(f"state: {state}", (6, 34), STATE_COLOURS.get(state, (255, 255, 255)))
    label(header, (6, 16), (255, 255, 255))
    return img


@dataclass
class Rendered:
    """What :func:`render` produced."""

    frames: int = 0
    tracked: int = 0
    size: tuple[int, int] = (0, 0)
    sheet_tiles: int = 0


class VideoWriter:
    """H.264 (libx264, yuv420p) MP4 writer with PyAV; odd sizes are padded to even."""

    def __init__(self, path: Path, fps: float) -> None:
        import av

        self.path = path
        self.fps = fps
        self._container = av.open(str(path), mode="w")
        self._stream = None
        self.frames = 0

    def write(self, rgb: np.ndarray) -> None:
        from fractions import Fraction

        import av

        h, w = rgb.shape[:2]
        if self._stream is None:
            self._stream = self._container.add_stream("libx264", rate=Fraction(self.fps).limit_denominator(1000))
            self._stream.width, self._stream.height = w + w % 2, h + h % 2
            self._stream.pix_fmt = "yuv420p"
            self._stream.options = {"crf": "20", "preset": "veryfast"}
        if w % 2 or h % 2:
            rgb = cv2.copyMakeBorder(rgb, 0, h % 2, 0, w % 2, cv2.BORDER_CONSTANT, value=0)
        for packet in self._stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")):
            self._container.mux(packet)
        self.frames += 1

    def close(self) -> None:
        if self._stream is not None:
            for packet in self._stream.encode():
                self._container.mux(packet)
        self._container.close()


def contact_sheet(tiles: list[np.ndarray], columns: int, tile_width: int) -> np.ndarray:
    """Tiles (RGB, same size) resized to ``tile_width`` and laid out row by row; black gaps."""
    h, w = tiles[0].shape[:2]
    tw = min(tile_width, w)
    th = max(1, round(h * tw / w))
    cols = min(columns, len(tiles))
    rows = math.ceil(len(tiles) / cols)
    gap = 2
    sheet = np.zeros((rows * (th + gap) - gap, cols * (tw + gap) - gap, 3), np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, cols)
        small = cv2.resize(tile, (tw, th), interpolation=cv2.INTER_AREA)
        sheet[r * (th + gap) : r * (th + gap) + th, c * (tw + gap) : c * (tw + gap) + tw] = small
    return sheet


class Outputs:
    """Where a render's drawings go: the video (every drawing) and the contact sheet (every ``every``-th).

    Counts the drawings in ``result`` (``frames``, ``size``, ``sheet_tiles``); :meth:`close` ends the
    video and writes the sheet.
    """

    def __init__(
        self, video: Path | None, sheet: Path | None, every: int, columns: int, tile_width: int, fps: float
    ) -> None:
        self.video, self.sheet, self.every = video, sheet, every
        self.columns, self.tile_width, self.fps = columns, tile_width, fps
        self.result = Rendered()
        self._writer: VideoWriter | None = None
        self._tiles: list[np.ndarray] = []

    def add(self, img: np.ndarray, tracked: bool) -> None:
        """One drawing (RGB); ``tracked``: it has tracker output."""
        self.result.size = (img.shape[1], img.shape[0])
        if self.video is not None:
            if self._writer is None:
                self._writer = VideoWriter(self.video, self.fps)
            self._writer.write(img)
        if self.sheet is not None and self.result.frames % self.every == 0:
            self._tiles.append(img)
        self.result.frames += 1
        self.result.tracked += tracked

    def close(self) -> None:
        """End the video (safe after an error: what was written stays playable)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None

    def write_sheet(self) -> Rendered:
        """Write the contact sheet (when asked for and anything was drawn); returns the counts."""
        if self.sheet is not None and self._tiles:
            sheet_img = contact_sheet(self._tiles, self.columns, self.tile_width)
            if not cv2.imwrite(str(self.sheet), cv2.cvtColor(sheet_img, cv2.COLOR_RGB2BGR)):
                raise InputError(f"cannot write the contact sheet {self.sheet}")
            self.result.sheet_tiles = len(self._tiles)
        return self.result


def frame_rate(times: np.ndarray) -> float:
    """Video frame rate from frame times (ns): the median period's, 30 when unknown."""
    period = float(np.median(np.diff(times))) if times.size > 1 else 0.0
    return 1e9 / period if period > 0 else 30.0


def render(
    tracked: Path,
    *,
    video: Path | None = None,
    sheet: Path | None = None,
    every: int = 10,
    columns: int = 6,
    tile_width: int = 320,
    fps: float | None = None,
    input_path: Path | None = None,
) -> Rendered:
    """Render a tracked recording to an MP4 and/or a PNG contact sheet.

    Parameters
    ----------
    tracked : Path
        Output of ``fusion-pf track -o``.
    video : Path, optional
        MP4 (H.264) with every frame.
    sheet : Path, optional
        PNG with every ``every``-th frame, ``columns`` tiles a row, each ``tile_width`` px wide
        at most.
    fps : float, optional
        Video frame rate; default from the frame timestamps (median period), 30 when unknown.
    input_path : Path, optional
        The recording that was tracked, for the images when ``tracked`` has none.

    Returns
    -------
    Rendered
        Frame counts and the drawing size.
    """
    outputs = read_tracker_topics(tracked)
    sources: list[str] = []
    for item in outputs.values():
        sources += [s for s in item.cues if s not in sources]
    with McapReplay(image_recording(tracked, input_path)) as replay:
        times = np.asarray(replay.timestamps, dtype=np.int64)
        if not set(times.tolist()) & set(outputs):
            raise InputError(
                f"{tracked}: no tracker message has the time of a frame of {replay.path}; "
                "pass --input with the recording that was tracked"
            )
        sink = Outputs(video, sheet, every, columns, tile_width, frame_rate(times) if fps is None else fps)
        try:
            for frame in replay:
                out = outputs.get(frame.timestamp_ns)
                sink.add(draw(frame, out, sources, draw_scale(frame.color.shape[1])), out is not None)
        finally:
            sink.close()
    return sink.write_sheet()
