"""The fusion-pf MCAP recording convention: topic names, schemas, encoders and decoders.

Everything that turns a :class:`~fusion_pf.frame.Frame` into MCAP messages and
back lives here, so the recorder (:mod:`drivers.mcap_record`) and the replay
driver (:mod:`drivers.mcap_replay`) cannot disagree. The convention itself is
described in ``docs/recording-format.md``.

Images use the Foxglove protobuf schemas (``foxglove.RawImage``,
``foxglove.CompressedImage``, ``foxglove.CameraCalibration``); skeleton, ground
truth and tracker outputs use JSON messages described by the JSON Schemas in
:data:`JSON_SCHEMAS`.

Decoders raise :class:`~fusion_pf.errors.RecordingError` naming the message
(``where``, e.g. ``"/camera/color at t=123 ns"``) and what was expected.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from typing import Any

import cv2
import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from google.protobuf.message import DecodeError, Message
from google.protobuf.timestamp_pb2 import Timestamp

from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import DISTORTION_MODELS, HandObservation, Intrinsics, Joint, PalmPoint
from fusion_pf.rig import WORLD_FRAME, CameraPose, check_camera_name

# --------------------------------------------------------------------------- topics

#: Colour frames: foxglove.RawImage (rgb8/bgr8) or foxglove.CompressedImage (jpeg/png).
COLOR_TOPIC = "/camera/color"
#: Depth aligned to colour: foxglove.RawImage 16UC1/mono16 (little-endian mm) or PNG.
DEPTH_TOPIC = "/camera/depth"
#: foxglove.CameraCalibration of the colour image (and the aligned depth).
CALIBRATION_TOPIC = "/camera/calibration"
#: JSON fusion_pf.Skeleton.
SKELETON_TOPIC = "/skeleton/joints"
#: JSON fusion_pf.PalmPoint (synthetic recordings only).
GROUND_TRUTH_TOPIC = "/ground_truth/palm"
#: JSON fusion_pf.HandLandmarks (hand-landmark network, e.g. on the OAK).
HAND_TOPIC = "/hand/landmarks"
#: JSON fusion_pf.Estimate, written by ``fusion-pf track -o``.
ESTIMATE_TOPIC = "/tracker/estimate"
#: JSON fusion_pf.Cues, written by ``fusion-pf track -o``.
CUES_TOPIC = "/tracker/cues"
#: JSON fusion_pf.WorldEstimate: the multi-camera (world) tracker's targets, one message per instant.
WORLD_ESTIMATE_TOPIC = "/tracker/world"
#: foxglove.ImageAnnotations, written by ``fusion-pf track -o``.
OVERLAY_TOPIC = "/tracker/overlay"
#: foxglove.PointCloud, written by ``fusion-pf track -o``.
PARTICLES_TOPIC = "/tracker/particles"
#: JSON fusion_pf.Event, one message per interaction event, written by ``fusion-pf track -o``.
EVENTS_TOPIC = "/tracker/events"
#: JSON fusion_pf.Event: the true events of a scripted synthetic recording (``synth --script events``).
GROUND_TRUTH_EVENTS_TOPIC = "/ground_truth/events"

#: Topics :meth:`McapRecorder.write` fills from a frame.
FRAME_TOPICS = (CALIBRATION_TOPIC, COLOR_TOPIC, DEPTH_TOPIC, SKELETON_TOPIC, GROUND_TRUTH_TOPIC, HAND_TOPIC)
#: Camera poses of a multi-camera recording: foxglove.FrameTransform from ``world`` to each camera.
TF_TOPIC = "/tf"
#: JSON fusion_pf.TargetWorldPoint: world ground truth of multi-camera synthetic recordings.
WORLD_TRUTH_TOPIC = "/ground_truth/world"
#: JSON fusion_pf.Visibility: which targets each camera of a synthetic multi-camera recording sees.
VISIBILITY_TOPIC = "/ground_truth/visibility"

#: Name of the MCAP metadata record describing the recording.
RECORDING_METADATA = "fusion_pf.recording"
#: Key of :data:`RECORDING_METADATA` giving the number K of leading background frames.
BACKGROUND_FRAMES_KEY = "background_frames"
#: Key of :data:`RECORDING_METADATA` giving the version of this convention.
FORMAT_VERSION_KEY = "format_version"
#: Name of the MCAP metadata records repeating each calibration outside the chunks (one per change).
CALIBRATION_METADATA = "fusion_pf.calibration"
#: Name of the MCAP metadata records repeating each channel outside the chunks (one per channel):
#: ``id``, ``topic``, ``message_encoding``, ``schema_name``, ``schema_encoding``. A scan of a file
#: whose first chunk is damaged still knows the channels.
CHANNEL_METADATA = "fusion_pf.channel"
#: Version of the convention written by this module.
FORMAT_VERSION = "1"
#: ``frame_id`` written into every Foxglove message.
FRAME_ID = "camera"

# --------------------------------------------------------------------------- schemas

RAW_IMAGE = "foxglove.RawImage"
COMPRESSED_IMAGE = "foxglove.CompressedImage"
CAMERA_CALIBRATION = "foxglove.CameraCalibration"
SKELETON_SCHEMA = "fusion_pf.Skeleton"
PALM_SCHEMA = "fusion_pf.PalmPoint"
#: Ground truth of one target of a multi-target recording (a PalmPoint plus ``target``).
TARGET_PALM_SCHEMA = "fusion_pf.TargetPalmPoint"
HAND_SCHEMA = "fusion_pf.HandLandmarks"
#: World ground truth of one target (mm) in a multi-camera recording.
WORLD_POINT_SCHEMA = "fusion_pf.TargetWorldPoint"
#: Per camera, the targets it sees at one instant (synthetic multi-camera recordings).
VISIBILITY_SCHEMA = "fusion_pf.Visibility"
FRAME_TRANSFORM = "foxglove.FrameTransform"
ESTIMATE_SCHEMA = "fusion_pf.Estimate"
#: The world tracker's estimate of one instant (every target: world position, state, cameras, pixels).
WORLD_ESTIMATE_SCHEMA = "fusion_pf.WorldEstimate"
CUES_SCHEMA = "fusion_pf.Cues"
EVENT_SCHEMA = "fusion_pf.Event"

#: Colour formats the recorder writes: raw rgb8, JPEG or PNG.
COLOR_FORMATS = ("raw", "jpeg", "png")
#: Depth formats the recorder writes: raw 16UC1 or 16-bit PNG.
DEPTH_FORMATS = ("raw", "png")
#: RawImage encodings accepted for colour.
COLOR_ENCODINGS = ("rgb8", "bgr8")
#: RawImage encodings accepted for depth (both mean little-endian uint16 mm).
DEPTH_ENCODINGS = ("16UC1", "mono16")

_JPEG_FORMATS = {"jpeg", "jpg", "image/jpeg"}
_PNG_FORMATS = {"png", "image/png"}

_NUMBER = {"type": "number"}
_NUMBER_OR_NULL = {"type": ["number", "null"]}
_UV_QUALITY = {
    "type": ["object", "null"],
    "required": ["u", "v", "quality"],
    "properties": {"u": _NUMBER, "v": _NUMBER, "quality": {"type": "number", "minimum": 0, "maximum": 1}},
}
_DRAFT = "https://json-schema.org/draft/2020-12/schema"

#: JSON Schemas of the JSON topics, by schema name (written into the MCAP Schema records).
JSON_SCHEMAS: dict[str, dict[str, Any]] = {
    SKELETON_SCHEMA: {
        "$schema": _DRAFT,
        "title": SKELETON_SCHEMA,
        "description": "Skeleton joints projected into the colour image; a joint may be absent.",
        "type": "object",
        "required": ["joints"],
        "properties": {
            "joints": {
                "type": "array",
                "items": {
                    "type": "object",
                    "required": ["name", "u", "v", "depth_mm", "confidence"],
                    "properties": {
                        "name": {"type": "string", "minLength": 1},
                        "u": {"type": "number", "description": "column, colour pixels"},
                        "v": {"type": "number", "description": "row, colour pixels"},
                        "depth_mm": {"type": ["number", "null"], "minimum": 0},
                        "confidence": {"type": "number", "minimum": 0, "maximum": 1},
                    },
                },
            }
        },
    },
    HAND_SCHEMA: {
        "$schema": _DRAFT,
        "title": HAND_SCHEMA,
        "description": "Hands found by a hand-landmark network; an empty list when it saw none.",
        "type": "object",
        "required": ["hands"],
        "properties": {
            "hands": {
                "type": "array",
                "items": {
                    "type": "object",
                    "required": ["landmarks", "palm", "score", "handedness"],
                    "properties": {
                        "landmarks": {
                            "description": "21 MediaPipe hand landmarks [u, v, z]: u, v full-frame colour "
                            "pixels, z relative depth in pixel units (MediaPipe) or null",
                            "type": "array",
                            "minItems": 21,
                            "maxItems": 21,
                            "items": {
                                "type": "array",
                                "prefixItems": [_NUMBER, _NUMBER, {"type": ["number", "null"]}],
                                "minItems": 3,
                                "maxItems": 3,
                            },
                        },
                        "palm": {
                            "description": "[u, v], mean of landmarks 0, 5, 9, 13, 17",
                            "type": "array",
                            "prefixItems": [_NUMBER, _NUMBER],
                            "minItems": 2,
                            "maxItems": 2,
                        },
                        "score": {"type": "number", "minimum": 0, "maximum": 1},
                        "handedness": {"enum": ["left", "right", None]},
                    },
                },
            }
        },
    },
    PALM_SCHEMA: {
        "$schema": _DRAFT,
        "title": PALM_SCHEMA,
        "description": "Ground-truth palm centre in colour pixels.",
        "type": "object",
        "required": ["u", "v"],
        "properties": {"u": _NUMBER, "v": _NUMBER, "occluded": {"type": "boolean"}},
    },
    TARGET_PALM_SCHEMA: {
        "$schema": _DRAFT,
        "title": TARGET_PALM_SCHEMA,
        "description": "Ground-truth centre of one target (e.g. right_hand, left_hand, head) in colour pixels.",
        "type": "object",
        "required": ["target", "u", "v"],
        "properties": {
            "target": {"type": "string", "minLength": 1},
            "u": _NUMBER,
            "v": _NUMBER,
            "occluded": {"type": "boolean"},
        },
    },
    WORLD_POINT_SCHEMA: {
        "$schema": _DRAFT,
        "title": WORLD_POINT_SCHEMA,
        "description": "Ground-truth centre of one target in the world frame of a multi-camera recording (mm).",
        "type": "object",
        "required": ["target", "xyz_mm"],
        "properties": {
            "target": {"type": "string", "minLength": 1},
            "xyz_mm": {"type": "array", "items": _NUMBER, "minItems": 3, "maxItems": 3},
        },
    },
    VISIBILITY_SCHEMA: {
        "$schema": _DRAFT,
        "title": VISIBILITY_SCHEMA,
        "description": "Ground truth of one instant of a multi-camera recording: per camera, the targets it sees "
        "(a target missing from a camera's list is hidden from it or outside its image).",
        "type": "object",
        "required": ["timestamp_ns", "visible"],
        "properties": {
            "timestamp_ns": {"type": "integer", "minimum": 0},
            "visible": {
                "type": "object",
                "additionalProperties": {"type": "array", "items": {"type": "string", "minLength": 1}},
            },
        },
    },
    WORLD_ESTIMATE_SCHEMA: {
        "$schema": _DRAFT,
        "title": WORLD_ESTIMATE_SCHEMA,
        "description": "World estimates (mm) of every target at one instant of a multi-camera recording: state, "
        "position (null without a track), posterior std, the cameras that measured it, and the position projected "
        "into every camera (null where out of view or without a track).",
        "type": "object",
        "required": ["timestamp_ns", "targets"],
        "properties": {
            "timestamp_ns": {"type": "integer", "minimum": 0},
            "targets": {
                "type": "array",
                "items": {
                    "type": "object",
                    "required": ["target", "state", "position_mm", "sigma_mm", "cameras", "pixels"],
                    "properties": {
                        "target": {"type": "string"},
                        "state": {"type": "string"},
                        "position_mm": {"type": ["array", "null"], "items": _NUMBER, "minItems": 3, "maxItems": 3},
                        "sigma_mm": _NUMBER_OR_NULL,
                        "cameras": {"type": "array", "items": {"type": "string"}},
                        "pixels": {
                            "type": "object",
                            "additionalProperties": {
                                "type": ["array", "null"],
                                "items": _NUMBER,
                                "minItems": 2,
                                "maxItems": 2,
                            },
                        },
                    },
                },
            },
        },
    },
    ESTIMATE_SCHEMA: {
        "$schema": _DRAFT,
        "title": ESTIMATE_SCHEMA,
        "description": "Tracker palm estimate of one frame: u, v (null without an estimate), or per target under "
        "`targets` when several targets are tracked.",
        "type": "object",
        "required": ["frame", "timestamp_ns"],
        "properties": {
            "frame": {"type": "integer", "minimum": 0},
            "timestamp_ns": {"type": "integer", "minimum": 0},
            "u": _NUMBER_OR_NULL,
            "v": _NUMBER_OR_NULL,
            "xyz_mm": {"type": ["array", "null"], "items": _NUMBER, "minItems": 3, "maxItems": 3},
            "sigma_px": _NUMBER_OR_NULL,
            "sigma_mm": _NUMBER_OR_NULL,
            "ess": _NUMBER_OR_NULL,
            "resampled": {"type": ["boolean", "null"]},
            "n_particles": {"type": "integer", "minimum": 0},
            "state": {"type": "string"},
            "likelihood_evaluations": {"type": "integer", "minimum": 0},
            "filter": {"type": "string"},
            "likelihood": {"type": "string"},
            "latency_ns": {"type": "object", "additionalProperties": {"type": "integer"}},
            "targets": {
                "type": "object",
                "additionalProperties": {
                    "type": "object",
                    "required": ["u", "v", "state"],
                    "properties": {
                        "u": _NUMBER_OR_NULL,
                        "v": _NUMBER_OR_NULL,
                        "state": {"type": "string"},
                        "xyz_mm": {"type": ["array", "null"], "items": _NUMBER, "minItems": 3, "maxItems": 3},
                        "sigma_px": _NUMBER_OR_NULL,
                        "sigma_mm": _NUMBER_OR_NULL,
                    },
                },
            },
        },
    },
    EVENT_SCHEMA: {
        "$schema": _DRAFT,
        "title": EVENT_SCHEMA,
        "description": "One interaction event (paper 004 §7): join, separate, contact, disappear, reappear, "
        "pick_up, put_down or exchange, with the targets involved.",
        "type": "object",
        "required": ["timestamp_ns", "frame", "event", "targets"],
        "properties": {
            "timestamp_ns": {"type": "integer", "minimum": 0},
            "frame": {"type": "integer", "minimum": 0},
            "event": {
                "enum": ["join", "separate", "contact", "disappear", "reappear", "pick_up", "put_down", "exchange"]
            },
            "targets": {"type": "array", "items": {"type": "string", "minLength": 1}, "minItems": 1, "maxItems": 2},
            "detail": {
                "type": "object",
                "properties": {"onset_frame": {"type": "integer", "minimum": 0}, "hue_deg": _NUMBER},
            },
        },
    },
    CUES_SCHEMA: {
        "$schema": _DRAFT,
        "title": CUES_SCHEMA,
        "description": "Per-source palm measurements of one frame (null = no measurement).",
        "type": "object",
        "required": ["frame", "timestamp_ns"],
        "properties": {
            "frame": {"type": "integer", "minimum": 0},
            "timestamp_ns": {"type": "integer", "minimum": 0},
            "colour": _UV_QUALITY,
            "depth": _UV_QUALITY,
            "skeleton": _UV_QUALITY,
            "roi": {"type": "array", "items": {"type": "integer"}, "minItems": 4, "maxItems": 4},
            "targets": {"type": "object", "additionalProperties": {"type": "object"}},
        },
    },
}


def protobuf_schema_data(message_class: type[Message]) -> bytes:
    """Serialized ``FileDescriptorSet`` of ``message_class`` and its dependencies.

    This is the ``data`` of an MCAP Schema record with encoding ``protobuf``.

    Parameters
    ----------
    message_class : type
        A generated protobuf message class.

    Returns
    -------
    bytes
    """
    fds = FileDescriptorSet()
    seen: set[str] = set()

    def add(file_descriptor: Any) -> None:
        for dep in file_descriptor.dependencies:
            if dep.name not in seen:
                seen.add(dep.name)
                add(dep)
        file_descriptor.CopyToProto(fds.file.add())

    add(message_class.DESCRIPTOR.file)
    return fds.SerializeToString()


def json_schema_data(schema_name: str, schema: Mapping[str, Any] | None = None) -> bytes:
    """The JSON Schema document of ``schema_name`` as UTF-8 bytes.

    Parameters
    ----------
    schema_name : str
        A name from :data:`JSON_SCHEMAS`, or any name when ``schema`` is given.
    schema : mapping, optional
        The JSON Schema of a schema name not in :data:`JSON_SCHEMAS`.

    Returns
    -------
    bytes

    Raises
    ------
    InputError
        When ``schema_name`` is unknown and no ``schema`` is given.
    """
    if schema is None:
        if schema_name not in JSON_SCHEMAS:
            raise InputError(
                f"unknown JSON schema name {schema_name!r}; expected one of {sorted(JSON_SCHEMAS)} "
                "or pass schema= with its JSON Schema"
            )
        schema = JSON_SCHEMAS[schema_name]
    return encode_json(dict(schema), f"JSON Schema of {schema_name}")


# --------------------------------------------------------------------------- helpers


def _timestamp(timestamp_ns: int) -> Timestamp:
    return Timestamp(seconds=timestamp_ns // 1_000_000_000, nanos=timestamp_ns % 1_000_000_000)


def _parse(message_class: type[Message], data: bytes | memoryview, where: str) -> Any:
    try:
        return message_class.FromString(data)
    except DecodeError as exc:
        raise RecordingError(f"{where}: not a valid {message_class.DESCRIPTOR.full_name} message ({exc})") from None


def _check_raw_size(msg: Any, bytes_per_pixel: int, where: str) -> None:
    if msg.width <= 0 or msg.height <= 0:
        raise RecordingError(f"{where}: image size must be positive, got {msg.width}x{msg.height}")
    if msg.step < msg.width * bytes_per_pixel:
        raise RecordingError(f"{where}: step {msg.step} is smaller than width {msg.width} x {bytes_per_pixel} bytes")
    if len(msg.data) < msg.step * msg.height:
        raise RecordingError(
            f"{where}: {msg.encoding} image {msg.width}x{msg.height} (step {msg.step}) needs "
            f"{msg.step * msg.height} bytes, got {len(msg.data)}"
        )


def _imdecode(data: bytes, flags: int, fmt: str, where: str) -> np.ndarray:
    image = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if image is None:
        raise RecordingError(f"{where}: the {fmt} data ({len(data)} bytes) cannot be decoded")
    return image


def _imencode(ext: str, image: np.ndarray, params: list[int]) -> bytes:
    ok, buf = cv2.imencode(ext, image, params)
    if not ok:
        raise InputError(f"OpenCV could not encode a {image.shape} {image.dtype} image as {ext}")
    return buf.tobytes()


# --------------------------------------------------------------------------- colour


def encode_color(
    rgb: np.ndarray, timestamp_ns: int, fmt: str = "raw", jpeg_quality: int = 90
) -> RawImage | CompressedImage:
    """Encode an RGB image as the protobuf message of :data:`COLOR_TOPIC`.

    Parameters
    ----------
    rgb : ndarray, shape (H, W, 3), uint8
        Colour image in R, G, B order.
    timestamp_ns : int
        Capture time, written into the message header.
    fmt : {"raw", "jpeg", "png"}
        ``raw`` gives a ``foxglove.RawImage`` with encoding ``rgb8``; the others a
        ``foxglove.CompressedImage``.
    jpeg_quality : int
        JPEG quality 1-100 (``fmt="jpeg"`` only).

    Returns
    -------
    RawImage or CompressedImage
    """
    h, w = rgb.shape[:2]
    if fmt == "raw":
        return RawImage(
            timestamp=_timestamp(timestamp_ns),
            frame_id=FRAME_ID,
            width=w,
            height=h,
            encoding="rgb8",
            step=w * 3,
            data=np.ascontiguousarray(rgb).tobytes(),
        )
    bgr = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2BGR)
    if fmt == "jpeg":
        data = _imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
    elif fmt == "png":
        data = _imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    else:
        raise InputError(f"colour format must be one of {COLOR_FORMATS}, got {fmt!r}")
    return CompressedImage(timestamp=_timestamp(timestamp_ns), frame_id=FRAME_ID, data=data, format=fmt)


def decode_color(schema_name: str, data: bytes | memoryview, where: str = COLOR_TOPIC) -> np.ndarray:
    """Decode a colour message into an RGB image.

    Parameters
    ----------
    schema_name : str
        ``foxglove.RawImage`` (encoding rgb8 or bgr8) or ``foxglove.CompressedImage``
        (format jpeg or png).
    data : bytes
        The serialized protobuf message.
    where : str
        Names the message in error messages.

    Returns
    -------
    ndarray, shape (H, W, 3), uint8
        The image in R, G, B order.
    """
    if schema_name == RAW_IMAGE:
        msg = _parse(RawImage, data, where)
        if msg.encoding not in COLOR_ENCODINGS:
            raise RecordingError(
                f"{where}: RawImage encoding {msg.encoding!r} is not supported; expected one of {COLOR_ENCODINGS}"
            )
        _check_raw_size(msg, 3, where)
        w, h, step = msg.width, msg.height, msg.step
        rows = np.frombuffer(msg.data, np.uint8, count=step * h).reshape(h, step)
        image = rows[:, : w * 3].reshape(h, w, 3)
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB) if msg.encoding == "bgr8" else image
    if schema_name == COMPRESSED_IMAGE:
        msg = _parse(CompressedImage, data, where)
        fmt = msg.format.lower()
        if fmt not in _JPEG_FORMATS | _PNG_FORMATS:
            raise RecordingError(
                f"{where}: CompressedImage format {msg.format!r} is not supported; expected jpeg or png"
            )
        bgr = _imdecode(msg.data, cv2.IMREAD_COLOR, fmt, where)
        return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    raise RecordingError(
        f"{where}: schema {schema_name!r} is not supported; expected {RAW_IMAGE} or {COMPRESSED_IMAGE}"
    )


# --------------------------------------------------------------------------- depth


def encode_depth(depth: np.ndarray, timestamp_ns: int, fmt: str = "raw") -> RawImage | CompressedImage:
    """Encode a depth image as the protobuf message of :data:`DEPTH_TOPIC`.

    Parameters
    ----------
    depth : ndarray, shape (H, W), uint16
        Depth in millimetres, 0 = no depth.
    timestamp_ns : int
        Capture time, written into the message header.
    fmt : {"raw", "png"}
        ``raw`` gives a ``foxglove.RawImage`` with encoding ``16UC1``
        (little-endian); ``png`` a ``foxglove.CompressedImage`` holding a
        16-bit greyscale PNG.

    Returns
    -------
    RawImage or CompressedImage
    """
    h, w = depth.shape
    if fmt == "raw":
        data = np.ascontiguousarray(depth, dtype="<u2").tobytes()
        return RawImage(
            timestamp=_timestamp(timestamp_ns),
            frame_id=FRAME_ID,
            width=w,
            height=h,
            encoding="16UC1",
            step=w * 2,
            data=data,
        )
    if fmt == "png":
        data = _imencode(".png", np.ascontiguousarray(depth), [cv2.IMWRITE_PNG_COMPRESSION, 1])
        return CompressedImage(timestamp=_timestamp(timestamp_ns), frame_id=FRAME_ID, data=data, format="png")
    raise InputError(f"depth format must be one of {DEPTH_FORMATS}, got {fmt!r}")


def decode_depth(schema_name: str, data: bytes | memoryview, where: str = DEPTH_TOPIC) -> np.ndarray:
    """Decode a depth message into uint16 millimetres.

    Parameters
    ----------
    schema_name : str
        ``foxglove.RawImage`` (encoding 16UC1 or mono16, little-endian) or
        ``foxglove.CompressedImage`` (format png, 16-bit greyscale).
    data : bytes
        The serialized protobuf message.
    where : str
        Names the message in error messages.

    Returns
    -------
    ndarray, shape (H, W), uint16
    """
    if schema_name == RAW_IMAGE:
        msg = _parse(RawImage, data, where)
        if msg.encoding not in DEPTH_ENCODINGS:
            raise RecordingError(
                f"{where}: RawImage encoding {msg.encoding!r} is not supported for depth; "
                f"expected one of {DEPTH_ENCODINGS}"
            )
        _check_raw_size(msg, 2, where)
        if msg.step % 2:
            raise RecordingError(f"{where}: step {msg.step} of a 16-bit image must be even")
        w, h, step = msg.width, msg.height, msg.step
        rows = np.frombuffer(msg.data, "<u2", count=step // 2 * h).reshape(h, step // 2)
        return rows[:, :w].astype(np.uint16, copy=False)
    if schema_name == COMPRESSED_IMAGE:
        msg = _parse(CompressedImage, data, where)
        if msg.format.lower() not in _PNG_FORMATS:
            raise RecordingError(
                f"{where}: CompressedImage format {msg.format!r} is not supported for depth; expected png"
            )
        depth = _imdecode(msg.data, cv2.IMREAD_UNCHANGED, "png", where)
        if depth.ndim != 2 or depth.dtype != np.uint16:
            channels = 1 if depth.ndim == 2 else depth.shape[2]
            raise RecordingError(
                f"{where}: depth PNG must be 16-bit single-channel, got {depth.dtype} with {channels} channel(s)"
            )
        return depth
    raise RecordingError(
        f"{where}: schema {schema_name!r} is not supported; expected {RAW_IMAGE} or {COMPRESSED_IMAGE}"
    )


# --------------------------------------------------------------------------- calibration


def encode_calibration(intrinsics: Intrinsics, timestamp_ns: int) -> CameraCalibration:
    """Encode intrinsics as a ``foxglove.CameraCalibration``.

    ``K`` is row-major 3x3, ``R`` the identity, ``P = [K | 0]``; the distortion
    model name and coefficients are written as they are (``"none"`` with no
    coefficients for a rectified image).

    Parameters
    ----------
    intrinsics : Intrinsics
    timestamp_ns : int

    Returns
    -------
    CameraCalibration
    """
    i = intrinsics
    return CameraCalibration(
        timestamp=_timestamp(timestamp_ns),
        frame_id=FRAME_ID,
        width=i.width,
        height=i.height,
        distortion_model=i.distortion_model,
        D=list(i.distortion),
        K=[i.fx, 0.0, i.cx, 0.0, i.fy, i.cy, 0.0, 0.0, 1.0],
        R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        P=[i.fx, 0.0, i.cx, 0.0, 0.0, i.fy, i.cy, 0.0, 0.0, 0.0, 1.0, 0.0],
    )


def decode_calibration(data: bytes | memoryview, where: str = CALIBRATION_TOPIC) -> Intrinsics:
    """Decode a ``foxglove.CameraCalibration`` into :class:`~fusion_pf.frame.Intrinsics`.

    An empty ``distortion_model`` means ``"none"``.

    Parameters
    ----------
    data : bytes
        The serialized protobuf message.
    where : str
        Names the message in error messages.

    Returns
    -------
    Intrinsics
    """
    msg = _parse(CameraCalibration, data, where)
    if len(msg.K) != 9:
        raise RecordingError(f"{where}: K must have 9 values (row-major 3x3), got {len(msg.K)}")
    model = msg.distortion_model or "none"
    if model not in DISTORTION_MODELS:
        raise RecordingError(
            f"{where}: distortion_model {model!r} is not supported; expected one of {sorted(DISTORTION_MODELS)}"
        )
    k = msg.K
    try:
        intrinsics = Intrinsics(msg.width, msg.height, k[0], k[4], k[2], k[5], model, tuple(msg.D))
    except InputError as exc:
        raise RecordingError(f"{where}: {exc}") from None
    check_plausible_intrinsics(intrinsics, where)
    return intrinsics


#: Largest focal length or principal-point offset accepted, in image sizes (a 0.06 degree field of view).
MAX_INTRINSICS_SCALE = 1e4


def check_plausible_intrinsics(intrinsics: Intrinsics, where: str) -> None:
    """Raise RecordingError unless fx, fy, |cx|, |cy| are at most :data:`MAX_INTRINSICS_SCALE` image sizes.

    Finite but absurd values (``fx = 1e308``) would overflow the geometry downstream.
    """
    i = intrinsics
    limit = MAX_INTRINSICS_SCALE * max(i.width, i.height)
    for name in ("fx", "fy", "cx", "cy"):
        value = getattr(i, name)
        if abs(value) > limit:
            raise RecordingError(
                f"{where}: {name} = {value:g} px is implausible for a {i.width}x{i.height} image; "
                f"expected |{name}| <= {limit:g}"
            )


_CALIBRATION_KEYS = ("timestamp_ns", "width", "height", "fx", "fy", "cx", "cy", "distortion_model", "distortion")


def calibration_metadata(intrinsics: Intrinsics, timestamp_ns: int) -> dict[str, str]:
    """The :data:`CALIBRATION_METADATA` record of a calibration in effect from ``timestamp_ns``.

    Floats are written with ``repr`` so they read back exactly; ``distortion``
    is a comma-separated list (empty for none).
    """
    i = intrinsics
    return {
        "timestamp_ns": str(int(timestamp_ns)),
        "width": str(i.width),
        "height": str(i.height),
        "fx": repr(float(i.fx)),
        "fy": repr(float(i.fy)),
        "cx": repr(float(i.cx)),
        "cy": repr(float(i.cy)),
        "distortion_model": i.distortion_model,
        "distortion": ",".join(repr(float(c)) for c in i.distortion),
    }


def decode_calibration_metadata(record: Mapping[str, str], where: str = CALIBRATION_METADATA) -> tuple[int, Intrinsics]:
    """``(timestamp_ns, intrinsics)`` of a :data:`CALIBRATION_METADATA` record.

    Raises
    ------
    RecordingError
        When a key is missing or a value is not a number of the expected kind.
    """
    missing = [key for key in _CALIBRATION_KEYS if key not in record]
    if missing:
        raise RecordingError(f"{where}: missing keys {missing}")
    try:
        t = int(record["timestamp_ns"])
        check_timestamp(t, f"{where} timestamp_ns")
        distortion = tuple(float(c) for c in record["distortion"].split(",") if c)
        intrinsics = Intrinsics(
            int(record["width"]),
            int(record["height"]),
            float(record["fx"]),
            float(record["fy"]),
            float(record["cx"]),
            float(record["cy"]),
            record["distortion_model"],
            distortion,
        )
    except (ValueError, InputError) as exc:
        raise RecordingError(f"{where}: {exc}") from None
    check_plausible_intrinsics(intrinsics, where)
    return t, intrinsics


# --------------------------------------------------------------------------- JSON


def encode_json(obj: Any, what: str = "message") -> bytes:
    """Serialize ``obj`` as compact UTF-8 JSON.

    Raises
    ------
    InputError
        When ``obj`` holds something JSON cannot represent (NaN, infinity, a
        non-string key, an object of unknown type).
    """
    try:
        return json.dumps(obj, separators=(",", ":"), allow_nan=False, ensure_ascii=False).encode()
    except (TypeError, ValueError) as exc:
        raise InputError(f"{what} is not valid JSON: {exc}") from None


def decode_json(data: bytes | memoryview, where: str) -> Any:
    """Parse a JSON message; a malformed one raises :class:`RecordingError`."""
    try:
        return json.loads(bytes(data))
    except (UnicodeDecodeError, ValueError) as exc:
        raise RecordingError(f"{where}: not valid JSON ({exc})") from None
    except RecursionError:
        raise RecordingError(f"{where}: JSON nested too deeply ({len(data)} bytes)") from None


def encode_skeleton(joints: Mapping[str, Joint]) -> dict[str, Any]:
    """The ``fusion_pf.Skeleton`` object of a frame's joints."""
    return {
        "joints": [
            {"name": name, "u": j.u, "v": j.v, "depth_mm": j.depth_mm, "confidence": j.confidence}
            for name, j in joints.items()
        ]
    }


def decode_skeleton(obj: Any, where: str = SKELETON_TOPIC) -> dict[str, Joint]:
    """Joints of a ``fusion_pf.Skeleton`` object, by name.

    Raises
    ------
    RecordingError
        When the object does not follow the schema (the message names the bad
        joint and field).
    """
    if not isinstance(obj, dict) or not isinstance(obj.get("joints"), list):
        raise RecordingError(f"{where}: expected an object with a 'joints' list, got {str(obj)[:80]!r}")
    joints: dict[str, Joint] = {}
    for k, item in enumerate(obj["joints"]):
        if not isinstance(item, dict):
            raise RecordingError(f"{where}: joint {k} must be an object, got {item!r}")
        missing = [key for key in ("name", "u", "v", "confidence") if key not in item]
        if missing:
            raise RecordingError(f"{where}: joint {k} has no {', '.join(map(repr, missing))}")
        name = item["name"]
        if not isinstance(name, str) or not name:
            raise RecordingError(f"{where}: joint {k} name must be a non-empty string, got {name!r}")
        if name in joints:
            raise RecordingError(f"{where}: joint name {name!r} appears twice")
        try:
            joints[name] = Joint(item["u"], item["v"], item.get("depth_mm"), item["confidence"])
        except InputError as exc:
            raise RecordingError(f"{where}: joint {name!r}: {exc}") from None
    return joints


def encode_hands(hands: Sequence[HandObservation]) -> dict[str, Any]:
    """The ``fusion_pf.HandLandmarks`` object of a frame's hands (NaN z -> null)."""
    out = []
    for hand in hands:
        rows = [[float(u), float(v), None if np.isnan(z) else float(z)] for u, v, z in hand.landmarks]
        palm = hand.palm
        out.append(
            {
                "landmarks": rows,
                "palm": [float(palm[0]), float(palm[1])],
                "score": hand.score,
                "handedness": hand.handedness,
            }
        )
    return {"hands": out}


def decode_hands(obj: Any, where: str = HAND_TOPIC) -> tuple[HandObservation, ...]:
    """Hands of a ``fusion_pf.HandLandmarks`` object.

    ``palm`` is checked against the mean of landmarks 0, 5, 9, 13, 17 (to
    1e-6 px + 1e-9 relative); the observation recomputes it.

    Raises
    ------
    RecordingError
        When the object does not follow the schema (the message names the bad
        hand and field).
    """
    if not isinstance(obj, dict) or not isinstance(obj.get("hands"), list):
        raise RecordingError(f"{where}: expected an object with a 'hands' list, got {str(obj)[:80]!r}")
    hands = []
    for k, item in enumerate(obj["hands"]):
        if not isinstance(item, dict):
            raise RecordingError(f"{where}: hand {k} must be an object, got {str(item)[:80]!r}")
        missing = [key for key in ("landmarks", "palm", "score") if key not in item]
        if missing:
            raise RecordingError(f"{where}: hand {k} has no {', '.join(map(repr, missing))}")
        rows = item["landmarks"]
        if not isinstance(rows, list) or len(rows) != 21 or any(not isinstance(r, list) or len(r) != 3 for r in rows):
            raise RecordingError(f"{where}: hand {k} landmarks must be 21 [u, v, z] triples")
        try:
            lm = np.array([[r[0], r[1], np.nan if r[2] is None else r[2]] for r in rows], dtype=np.float64)
            hand = HandObservation(lm, item["score"], item.get("handedness"))
        except (TypeError, ValueError, InputError) as exc:
            raise RecordingError(f"{where}: hand {k}: {exc}") from None
        palm = item["palm"]
        if (
            not isinstance(palm, list)
            or len(palm) != 2
            or not np.allclose(np.asarray(palm, dtype=np.float64), hand.palm, rtol=1e-9, atol=1e-6)
        ):
            raise RecordingError(
                f"{where}: hand {k} palm {palm!r} is not the mean of landmarks 0, 5, 9, 13, 17 ({hand.palm.tolist()})"
            )
        hands.append(hand)
    return tuple(hands)


def encode_palm(palm: PalmPoint) -> dict[str, Any]:
    """The ``fusion_pf.PalmPoint`` object of a ground-truth point."""
    return {"u": palm.u, "v": palm.v, "occluded": palm.occluded}


def decode_palm(obj: Any, where: str = GROUND_TRUTH_TOPIC) -> PalmPoint:
    """A :class:`~fusion_pf.frame.PalmPoint` from a ``fusion_pf.PalmPoint`` object."""
    if not isinstance(obj, dict) or "u" not in obj or "v" not in obj:
        raise RecordingError(f"{where}: expected an object with 'u' and 'v', got {str(obj)[:80]!r}")
    occluded = obj.get("occluded", False)
    if not isinstance(occluded, bool):
        raise RecordingError(f"{where}: 'occluded' must be true or false, got {occluded!r}")
    try:
        return PalmPoint(obj["u"], obj["v"], occluded)
    except InputError as exc:
        raise RecordingError(f"{where}: {exc}") from None


def encode_target_palm(target: str, palm: PalmPoint) -> dict[str, Any]:
    """The ``fusion_pf.TargetPalmPoint`` object of one target's ground truth."""
    return {"target": target, **encode_palm(palm)}


def decode_truth(obj: Any, where: str = GROUND_TRUTH_TOPIC) -> tuple[str | None, PalmPoint]:
    """``(target, point)`` of a ground-truth message; target None for a single-target ``PalmPoint``."""
    target = obj.get("target") if isinstance(obj, dict) else None
    if target is not None and not (isinstance(target, str) and target):
        raise RecordingError(f"{where}: 'target' must be a non-empty string, got {target!r}")
    return target, decode_palm(obj, where)


def check_timestamp(timestamp_ns: object, what: str = "timestamp_ns") -> int:
    """Return ``timestamp_ns`` as an int, or raise InputError unless it is a non-negative int < 2**63."""
    if isinstance(timestamp_ns, bool) or not isinstance(timestamp_ns, (int, np.integer)):
        raise InputError(f"{what} must be an integer number of nanoseconds, got {timestamp_ns!r}")
    value = int(timestamp_ns)
    if not 0 <= value < 2**63:
        raise InputError(f"{what} must be in [0, 2**63) ns, got {value}")
    return value


def format_ns(timestamp_ns: int) -> str:
    """``timestamp_ns`` as seconds with millisecond precision, e.g. ``"12.345 s"``."""
    return f"{timestamp_ns / 1e9:.3f} s"


# --------------------------------------------------------------------------- several cameras


def camera_topic(camera: str | None, topic: str) -> str:
    """The topic of ``camera`` in a multi-camera recording (``/cam_left/camera/color``); ``topic`` itself for None."""
    return topic if camera is None else f"/{check_camera_name(camera)}{topic}"


def encode_transform(camera: str, pose: CameraPose, timestamp_ns: int) -> FrameTransform:
    """The ``foxglove.FrameTransform`` from ``world`` (parent) to ``camera`` (child): metres and a quaternion."""
    msg = FrameTransform(
        timestamp=_timestamp(timestamp_ns), parent_frame_id=WORLD_FRAME, child_frame_id=check_camera_name(camera)
    )
    x, y, z = (float(v) / 1000.0 for v in pose.translation_mm)
    msg.translation.x, msg.translation.y, msg.translation.z = x, y, z
    qx, qy, qz, qw = (float(v) for v in pose.quaternion())
    msg.rotation.x, msg.rotation.y, msg.rotation.z, msg.rotation.w = qx, qy, qz, qw
    return msg


def decode_transform(data: bytes | memoryview, where: str = TF_TOPIC) -> tuple[str, str, CameraPose]:
    """``(parent, child, pose)`` of a ``foxglove.FrameTransform`` message (translation back in mm)."""
    msg = _parse(FrameTransform, data, where)
    t, q = msg.translation, msg.rotation
    try:
        pose = CameraPose.from_quaternion([q.x, q.y, q.z, q.w], [1000.0 * t.x, 1000.0 * t.y, 1000.0 * t.z])
    except InputError as exc:
        raise RecordingError(f"{where} ({msg.parent_frame_id} -> {msg.child_frame_id}): {exc}") from None
    return msg.parent_frame_id, msg.child_frame_id, pose


def encode_world_point(target: str, xyz_mm: np.ndarray | Sequence[float]) -> dict[str, Any]:
    """The ``fusion_pf.TargetWorldPoint`` object of one target's world ground truth."""
    return {"target": target, "xyz_mm": [float(v) for v in xyz_mm]}


def decode_world_point(obj: Any, where: str = WORLD_TRUTH_TOPIC) -> tuple[str, np.ndarray]:
    """``(target, xyz_mm)`` of a ``fusion_pf.TargetWorldPoint`` object."""
    target = obj.get("target") if isinstance(obj, dict) else None
    xyz = obj.get("xyz_mm") if isinstance(obj, dict) else None
    if not (isinstance(target, str) and target):
        raise RecordingError(f"{where}: 'target' must be a non-empty string, got {str(obj)[:80]!r}")
    try:
        point = np.asarray(xyz, dtype=np.float64)
    except (TypeError, ValueError):
        point = np.zeros(0)
    if point.shape != (3,) or not np.isfinite(point).all():
        raise RecordingError(f"{where}: 'xyz_mm' of {target!r} must be 3 finite numbers, got {xyz!r}")
    return target, point


def encode_visibility(timestamp_ns: int, visible: Mapping[str, Sequence[str]]) -> dict[str, Any]:
    """The ``fusion_pf.Visibility`` object of one instant: per camera, the targets it sees."""
    return {"timestamp_ns": int(timestamp_ns), "visible": {camera: list(t) for camera, t in visible.items()}}


def decode_visibility(obj: Any, where: str = VISIBILITY_TOPIC) -> dict[str, tuple[str, ...]]:
    """Per camera, the targets it sees, from a ``fusion_pf.Visibility`` object."""
    visible = obj.get("visible") if isinstance(obj, dict) else None
    if not isinstance(visible, dict) or not all(
        isinstance(v, list) and all(isinstance(t, str) and t for t in v) for v in visible.values()
    ):
        raise RecordingError(
            f"{where}: 'visible' must map each camera to a list of target names, got {str(obj)[:80]!r}"
        )
    return {str(camera): tuple(targets) for camera, targets in visible.items()}
