"""The tracker's MCAP topics: writing them next to a recording, reading them back.

Writing: :class:`TrackerTopics` puts ``/tracker/estimate``, ``/tracker/cues``,
``/tracker/overlay``, ``/tracker/particles`` and ``/tracker/events`` (docs/recording-format.md,
"Tracker outputs") into a :class:`~drivers.mcap_record.McapRecorder`. The JSON
messages come from :mod:`fusion_pf.pipeline.outputs`; the Foxglove overlay and
point cloud are encoded here.

Reading: :func:`read_json_topic` returns the JSON messages of one topic
(``/tracker/*``, ``/ground_truth/palm``) and :func:`recording_metadata` the
``fusion_pf.recording`` metadata, for the scorer, ``render`` and sweeps. Every
MCAP read goes through the replay's own reader: frames through
:class:`~drivers.mcap_replay.McapReplay`, other topics through its
:class:`~drivers.mcap_replay.McapTopics`.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.filter.estimate import largest_std
from fusion_pf.pipeline import TrackConfig, TrackResult, cues_json, estimate_json
from fusion_pf.pipeline.outputs import targets_cues_json, targets_json
from fusion_pf.signals import sigint_deferred

from . import mcap_format as fmt
from .mcap_replay import McapTopics

__all__ = [
    "OVERLAY_COLOURS",
    "PARTICLES_FRAME_ID",
    "TrackerTopics",
    "overlay",
    "particle_cloud",
    "TOPICS",
    "read_json_topic",
    "read_topic",
    "recording_metadata",
    "find_source",
    "source_metadata",
]


def read_json_topic(path: str | Path, topic: str) -> list[tuple[int, dict]]:
    """``(log_time, message)`` of every JSON message on ``topic`` in the MCAP file ``path``.

    Read through :class:`~drivers.mcap_replay.McapTopics` (the replay's reader:
    damaged chunks are skipped, not fatal).

    Raises
    ------
    RecordingError
        When the file is not MCAP.
    InputError
        When the topic is not JSON or a message is not valid JSON.
    """
    with McapTopics(path) as rec:
        messages = rec.messages(topic)
    out = []
    for log_time, encoding, data in messages:
        if encoding != "json":
            raise InputError(f"{path}: topic {topic} must be JSON-encoded, got {encoding!r}")
        try:
            out.append((log_time, json.loads(data)))
        except (ValueError, RecursionError):
            raise InputError(
                f"{path}: topic {topic} has a message that is not valid JSON at log_time {log_time}"
            ) from None
    return out


#: Topic of each kind the scorer reads (:data:`fusion_pf.score.inputs.TopicReader`).
TOPICS = {
    "estimate": fmt.ESTIMATE_TOPIC,
    "cues": fmt.CUES_TOPIC,
    "ground_truth": fmt.GROUND_TRUTH_TOPIC,
    "events": fmt.EVENTS_TOPIC,
    "true_events": fmt.GROUND_TRUTH_EVENTS_TOPIC,
    "world": fmt.WORLD_ESTIMATE_TOPIC,
    "world_truth": fmt.WORLD_TRUTH_TOPIC,
}


def read_topic(path: str | Path, kind: str) -> list[tuple[int, dict]]:
    """The messages of the topic of ``kind`` (:data:`TOPICS`): the scorer's MCAP reader."""
    return read_json_topic(path, TOPICS[kind])


def frame_size(path: str | Path) -> tuple[int, int]:
    """Image size ``(width, height)`` of the recording at ``path`` (its first frame): the scorer's size reader."""
    from drivers.mcap_replay import McapReplay

    with McapReplay(Path(path)) as rec:
        return rec.frame(0).size


def recording_metadata(path: str | Path) -> dict[str, str]:
    """The ``fusion_pf.recording`` metadata of an MCAP file (later records override earlier keys; {} if none)."""
    with McapTopics(path) as rec:
        return rec.metadata()


def source_metadata(source: str | Path, output: str | Path) -> dict[str, str]:
    """The metadata naming the tracked input in the output ``output``: where :func:`find_source` looks.

    ``source`` is stored absolute when it is a file or folder, with
    ``source_relative``, its path from the output's folder, so the pair still
    resolves when both are moved together or opened from another directory;
    a spec that names no file (``synth:...``, ``oak``) is stored as given.
    """
    path = Path(source)
    if not path.exists():
        return {"source": str(source)}
    absolute = os.path.abspath(path)
    try:
        relative = os.path.relpath(absolute, os.path.abspath(Path(output).parent))
    except ValueError:  # another drive (Windows): no relative path
        return {"source": absolute}
    return {"source": absolute, "source_relative": relative}


def find_source(tracked: str | Path, metadata: dict[str, str]) -> Path | None:
    """The input a tracker output names (:func:`source_metadata`), or None when it cannot be found.

    Tried in order: ``source`` as stored (absolute, or relative to the current
    directory), ``source_relative`` from the output's folder, and ``source``
    from the output's folder (outputs written before ``source_relative``).
    """
    base = Path(tracked).parent
    source, relative = metadata.get("source"), metadata.get("source_relative")
    candidates = [Path(source)] if source else []
    if relative:
        candidates.append(base / relative)
    if source and not Path(source).is_absolute():
        candidates.append(base / source)
    return next((c for c in candidates if c.exists()), None)


def _timestamp(ns: int):
    from google.protobuf.timestamp_pb2 import Timestamp

    return Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)


#: Overlay colours (RGBA in [0, 1]) per source, the particles and the estimate.
OVERLAY_COLOURS = {
    "colour": (0.1, 0.9, 0.2, 1.0),
    "depth": (0.2, 0.5, 1.0, 1.0),
    "skeleton": (1.0, 0.3, 0.9, 1.0),
    "particles": (1.0, 0.85, 0.1, 0.6),
    "estimate": (1.0, 0.1, 0.1, 1.0),
    "roi": (1.0, 1.0, 1.0, 0.5),
    "other": (0.0, 0.9, 0.9, 1.0),
}
#: ``frame_id`` of ``/tracker/particles`` (coordinates are image pixels, not metres).
PARTICLES_FRAME_ID = "camera_pixels"


class TrackerTopics:
    """Writes the tracker output topics of each tracked frame into a recorder.

    Topics (docs/recording-format.md, "Tracker outputs"): ``/tracker/estimate``
    and ``/tracker/cues`` (JSON) and ``/tracker/overlay``
    (``foxglove.ImageAnnotations``) once per tracked frame;
    ``/tracker/particles`` (``foxglove.PointCloud``) once per tracked frame
    with a particle set; ``/tracker/events`` (JSON) once per interaction event
    (``result.events``). Background frames get none.

    Parameters
    ----------
    recorder : drivers.mcap_record.McapRecorder
        An open recorder.
    config : TrackConfig
        Written into the estimates (``filter``, ``likelihood``).
    """

    def __init__(self, recorder, config: TrackConfig) -> None:
        self.recorder = recorder
        self.config = config

    def write(self, result: TrackResult) -> None:
        """Write the topics of ``result`` (none for a background frame)."""
        if result.background:
            return
        t = result.timestamp_ns
        several = bool(result.targets)
        messages = [
            (
                fmt.ESTIMATE_TOPIC,
                fmt.ESTIMATE_SCHEMA,
                targets_json(result, self.config) if several else estimate_json(result, self.config),
            ),
            (fmt.CUES_TOPIC, fmt.CUES_SCHEMA, targets_cues_json(result) if several else cues_json(result)),
        ]
        cloud = particle_cloud(result)
        picture = overlay(result)
        for other in list(result.targets.values())[1:]:  # several targets: one picture of all
            picture.MergeFrom(overlay(other))
        # one Ctrl-C deferral for the frame's messages (a frame is written whole; per message it cost ~60 us each)
        with sigint_deferred():
            for topic, schema, doc in messages:
                self.recorder.write_json(topic, schema, doc, t)
            self.recorder.write_protobuf(fmt.OVERLAY_TOPIC, picture, t)
            if cloud is not None:
                self.recorder.write_protobuf(fmt.PARTICLES_TOPIC, cloud, t)
            for event in result.events:
                self.recorder.write_json(fmt.EVENTS_TOPIC, fmt.EVENT_SCHEMA, event.as_json(), t)


def overlay(result: TrackResult):
    """``foxglove.ImageAnnotations`` of ``result``: particles, ROI, cue points, estimate circle."""
    from foxglove_schemas_protobuf.CircleAnnotation_pb2 import CircleAnnotation
    from foxglove_schemas_protobuf.Color_pb2 import Color
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.Point2_pb2 import Point2
    from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
    from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation

    ts = _timestamp(result.timestamp_ns)
    msg = ImageAnnotations()

    def colour(name: str) -> Color:
        r, g, b, a = OVERLAY_COLOURS.get(name, OVERLAY_COLOURS["other"])
        return Color(r=r, g=g, b=b, a=a)

    if result.particles is not None:
        cloud = PointsAnnotation(
            timestamp=ts, type=PointsAnnotation.POINTS, outline_color=colour("particles"), thickness=2.0
        )
        cloud.MergeFromString(_points_wire(PointsAnnotation, Point2, result.particles))
        msg.points.append(cloud)
    if result.roi is not None and not result.roi.empty:
        r = result.roi
        corners = [(r.x0, r.y0), (r.x1, r.y0), (r.x1, r.y1), (r.x0, r.y1)]
        msg.points.append(
            PointsAnnotation(
                timestamp=ts,
                type=PointsAnnotation.LINE_LOOP,
                outline_color=colour("roi"),
                thickness=1.0,
                points=[Point2(x=float(x) - 0.5, y=float(y) - 0.5) for x, y in corners],
            )
        )
    for s, m in result.cues.items():
        if m is None:
            continue
        msg.points.append(
            PointsAnnotation(
                timestamp=ts,
                type=PointsAnnotation.POINTS,
                outline_color=colour(s),
                thickness=8.0,
                points=[Point2(x=m.u, y=m.v)],
            )
        )
        msg.texts.append(
            TextAnnotation(
                timestamp=ts,
                position=Point2(x=m.u + 6.0, y=m.v - 6.0),
                text=s,
                font_size=12.0,
                text_color=colour(s),
                background_color=Color(r=0, g=0, b=0, a=0.4),
            )
        )
    e = result.estimate
    if e is not None:
        # diameter of the 2-sigma circle of the estimate's uncertainty, at least 10 px
        sigma = largest_std(e.cov) if result.sigma_px is None else result.sigma_px
        msg.circles.append(
            CircleAnnotation(
                timestamp=ts,
                position=Point2(x=e.u, y=e.v),
                diameter=max(10.0, 4.0 * sigma),
                thickness=2.0,
                outline_color=colour("estimate"),
            )
        )
    return msg


def _points_wire(annotation, point, uv: np.ndarray) -> bytes:
    """Protobuf wire bytes of ``annotation.points`` holding the ``point`` messages ``uv`` ``(N, 2)``, built as one array.

    Each element is ``points`` (length-delimited, 18 bytes) holding ``x`` and
    ``y`` as fixed64 doubles, the standard encoding of a repeated message, so
    parsing it equals appending ``point(x=u, y=v)`` per row (no per-particle
    message objects: 100 of those cost ~0.7 ms a frame).
    """
    tag = annotation.DESCRIPTOR.fields_by_name["points"].number << 3 | 2  # wire type 2: length-delimited
    x_tag = point.DESCRIPTOR.fields_by_name["x"].number << 3 | 1  # wire type 1: 64-bit
    y_tag = point.DESCRIPTOR.fields_by_name["y"].number << 3 | 1
    rec = np.empty(
        len(uv), dtype=[("tag", "u1"), ("len", "u1"), ("xt", "u1"), ("x", "<f8"), ("yt", "u1"), ("y", "<f8")]
    )
    rec["tag"], rec["len"], rec["xt"], rec["yt"] = tag, 18, x_tag, y_tag
    rec["x"], rec["y"] = uv[:, 0], uv[:, 1]
    return rec.tobytes()


def particle_cloud(result: TrackResult):
    """``foxglove.PointCloud`` of the particles: ``x = u``, ``y = v``, ``z = 0`` (px) and ``weight``.

    Several targets: every target's particles, each set's weights divided by the
    number of sets; None when no target holds particles.
    """
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

    sets = [r for r in (result.targets.values() or [result]) if r.particles is not None and r.weights is not None]
    if not sets:
        return None
    n = sum(r.particles.shape[0] for r in sets)
    data = np.zeros((n, 4), dtype="<f4")
    data[:, :2] = np.concatenate([r.particles for r in sets])
    data[:, 3] = np.concatenate([r.weights for r in sets]) / len(sets)
    f32 = PackedElementField.FLOAT32
    return PointCloud(
        timestamp=_timestamp(result.timestamp_ns),
        frame_id=PARTICLES_FRAME_ID,
        pose=Pose(position=Vector3(x=0, y=0, z=0), orientation=Quaternion(x=0, y=0, z=0, w=1)),
        point_stride=16,
        fields=[
            PackedElementField(name=name, offset=4 * i, type=f32) for i, name in enumerate(("x", "y", "z", "weight"))
        ],
        data=data.tobytes(),
    )
