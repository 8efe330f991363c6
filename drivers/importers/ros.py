"""Import ROS bags: ROS 2 in MCAP (a ``.mcap`` file or a bag folder), ROS 1 ``.bag``.

Messages read: ``sensor_msgs/msg/Image``, ``sensor_msgs/msg/CompressedImage`` and
``sensor_msgs/msg/CameraInfo``. A ``.mcap`` file is decoded with ``mcap-ros2-support``
(CDR with the ``ros2msg`` schemas the bag carries); bag folders (``metadata.yaml``, MCAP
or sqlite3 storage) and ROS 1 bags with ``rosbags``.

Topics are chosen by type and name unless given:

* colour: an image topic whose name says colour (``color``, ``rgb``, ``image``) and not
  depth/infrared, raw ``Image`` preferred to ``CompressedImage``;
* depth: an image topic named ``depth`` (or ``stereo``), ``aligned_depth_to_color``
  preferred (realsense2_camera with ``align_depth.enable:=true``); ``16UC1`` millimetres,
  ``32FC1`` metres, ``compressedDepth`` PNG. A depth topic not named aligned is registered
  to colour (:mod:`.registration`) with the CameraInfo next to it and the depth-to-colour
  transform of ``/tf_static`` (realsense2_camera publishes both); without them it must
  already have the colour size and is imported with a warning;
* camera info: the ``CameraInfo`` topic sharing the longest name prefix with the colour
  topic (``/camera/color/camera_info`` for ``/camera/color/image_raw``).

Timestamps are the messages' ``header.stamp`` (capture time; the bag's log time when the
stamp is zero). Each colour frame takes the nearest depth frame within half a colour frame
period (one to one); colour frames without one are imported without depth and counted.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame, Intrinsics

from .base import ImportSource, IntrinsicsOption, frame_of, frame_period_ns, merge_paired, pair_nearest, to_millimetres
from .registration import DepthRegistration, DepthToColor

IMAGE = "sensor_msgs/msg/Image"
COMPRESSED = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
_IMAGE_TYPES = (IMAGE, COMPRESSED)
_NOT_COLOR = ("depth", "infra", "/ir", "_ir", "stereo", "disparity", "confidence", "mono", "left", "right")
_COLOR_CODES = {
    "rgb8": None,
    "bgr8": cv2.COLOR_BGR2RGB,
    "8UC3": cv2.COLOR_BGR2RGB,
    "rgba8": cv2.COLOR_RGBA2RGB,
    "bgra8": cv2.COLOR_BGRA2RGB,
    "mono8": cv2.COLOR_GRAY2RGB,
    "8UC1": cv2.COLOR_GRAY2RGB,
    "yuv422": cv2.COLOR_YUV2RGB_UYVY,
    "uyvy": cv2.COLOR_YUV2RGB_UYVY,
    "yuv422_yuy2": cv2.COLOR_YUV2RGB_YUY2,
    "yuyv": cv2.COLOR_YUV2RGB_YUY2,
}
_CHANNELS = {
    "rgb8": 3,
    "bgr8": 3,
    "8UC3": 3,
    "rgba8": 4,
    "bgra8": 4,
    "mono8": 1,
    "8UC1": 1,
    "yuv422": 2,
    "uyvy": 2,
    "yuv422_yuy2": 2,
    "yuyv": 2,
}
_DEPTH_SCALE = {"16UC1": 1.0, "mono16": 1.0, "32FC1": 1000.0}
_PNG_MAGIC = b"\x89PNG"


def _normal_type(name: str) -> str:
    """``sensor_msgs/Image`` (ROS 1) and ``sensor_msgs/msg/Image`` (ROS 2) alike."""
    parts = name.split("/")
    return f"{parts[0]}/msg/{parts[-1]}" if len(parts) in (2, 3) else name


def _stamp_ns(data: bytes | memoryview, ros1: bool) -> int:
    """``header.stamp`` of a serialized Image/CompressedImage/CameraInfo (bytes 4-11 in ROS 1 and CDR)."""
    little = ros1 or bytes(data[1:2]) == b"\x01"
    sec, nsec = struct.unpack_from("<iI" if little else ">iI", data, 4)
    return sec * 1_000_000_000 + nsec


class _McapBag:
    """A ROS 2 ``.mcap`` file read with mcap + mcap-ros2-support."""

    ros1 = False

    def __init__(self, path: Path) -> None:
        from mcap.exceptions import McapError
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        self.path = path
        self._fh = open(path, "rb")
        try:
            self._reader = make_reader(self._fh)
            summary = self._reader.get_summary()
        except (McapError, ValueError, struct.error) as exc:
            self._fh.close()
            raise InputError(f"{path} is not a readable MCAP file ({exc})") from None
        if summary is None:
            self._fh.close()
            raise InputError(f"{path} has no MCAP summary (unfinished recording); re-index it with `mcap recover`")
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        self.topics: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        encodings = set()
        for cid, channel in summary.channels.items():
            schema = summary.schemas.get(channel.schema_id)
            self.topics[channel.topic] = _normal_type(schema.name) if schema else "(no schema)"
            self.counts[channel.topic] = counts.get(cid, 0)
            encodings.add(channel.message_encoding)
        if "cdr" not in encodings:
            self._fh.close()
            hint = (
                " (it is already a fusion-pf recording: replay it directly)" if "/camera/color" in self.topics else ""
            )
            raise InputError(
                f"{path} is not a ROS 2 bag: its messages are {sorted(encodings) or 'none'}, not CDR{hint}"
            )
        self._factory = DecoderFactory()
        self._decoders: dict[str, Callable[[bytes], Any]] = {}
        self._channels = summary.channels
        self._schemas = summary.schemas

    def raw(self, topics: list[str]) -> Iterator[tuple[str, int, bytes]]:
        for _, channel, message in self._reader.iter_messages(topics=topics, log_time_order=False):
            yield channel.topic, message.log_time, message.data

    def decode(self, topic: str, data: bytes) -> Any:
        decoder = self._decoders.get(topic)
        if decoder is None:
            channel = next(c for c in self._channels.values() if c.topic == topic)
            decoder = self._factory.decoder_for(channel.message_encoding, self._schemas.get(channel.schema_id))
            if decoder is None:
                raise InputError(f"{self.path}: topic {topic} cannot be decoded (no ros2msg schema)")
            self._decoders[topic] = decoder
        return decoder(data)

    def close(self) -> None:
        self._fh.close()


class _RosbagsBag:
    """A ROS 1 ``.bag`` or a ROS 2 bag folder read with rosbags."""

    def __init__(self, path: Path) -> None:
        from rosbags.highlevel import AnyReader

        self.path = path
        try:
            self._reader = AnyReader([path])
            self._reader.open()
        except Exception as exc:  # rosbags raises several reader error types (AnyReaderError, ReaderError, ...)
            raise InputError(f"{path} is not a readable ROS bag ({' '.join(str(exc).split())})") from None
        self.ros1 = not self._reader.is2
        self.topics = {c.topic: _normal_type(c.msgtype) for c in self._reader.connections}
        self.counts = {t: 0 for t in self.topics}
        for c in self._reader.connections:
            self.counts[c.topic] += c.msgcount
        self._types = {c.topic: c.msgtype for c in self._reader.connections}

    def raw(self, topics: list[str]) -> Iterator[tuple[str, int, bytes]]:
        connections = [c for c in self._reader.connections if c.topic in topics]
        for connection, log_time, data in self._reader.messages(connections=connections):
            yield connection.topic, log_time, data

    def decode(self, topic: str, data: bytes) -> Any:
        return self._reader.deserialize(data, self._types[topic])

    def close(self) -> None:
        self._reader.close()


def _open_bag(path: Path) -> _McapBag | _RosbagsBag:
    if path.is_dir() or path.suffix.lower() == ".bag":
        return _RosbagsBag(path)
    if path.suffix.lower() == ".db3":
        raise InputError(f"{path} is one file of a sqlite3 ROS 2 bag; pass the bag folder {path.parent}")
    return _McapBag(path)


def _field(msg: Any, *names: str) -> Any:
    for name in names:
        if hasattr(msg, name):
            return getattr(msg, name)
    raise RecordingError(f"message {type(msg).__name__} has no field {' or '.join(names)}")


def _image_array(msg: Any, dtype: np.dtype, channels: int, where: str) -> np.ndarray:
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray) else msg.data.tobytes(), np.uint8)
    item = np.dtype(dtype).itemsize * channels
    if h <= 0 or w <= 0 or step < w * item or data.size < step * h:
        raise RecordingError(f"{where}: {msg.encoding} image {w}x{h} (step {step}) holds {data.size} bytes")
    rows = data[: step * h].reshape(h, step)[:, : w * item]
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    out = (
        np.ascontiguousarray(rows).view(dt).reshape(h, w, channels)
        if channels > 1
        else np.ascontiguousarray(rows).view(dt).reshape(h, w)
    )
    return out.astype(np.dtype(dtype).newbyteorder("="), copy=False)


def decode_color(msg: Any, compressed: bool, where: str) -> np.ndarray:
    """RGB uint8 image, shape (H, W, 3), of a colour Image or CompressedImage message."""
    if compressed:
        image = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_COLOR)
        if image is None:
            raise RecordingError(f"{where}: CompressedImage format {msg.format!r} cannot be decoded")
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    encoding = msg.encoding
    if encoding not in _COLOR_CODES:
        raise InputError(
            f"{where}: colour encoding {encoding!r} is not supported; expected one of {sorted(_COLOR_CODES)}"
        )
    image = _image_array(msg, np.uint8, _CHANNELS[encoding], where)
    code = _COLOR_CODES[encoding]
    return np.ascontiguousarray(image) if code is None else cv2.cvtColor(image, code)


def decode_depth(msg: Any, compressed: bool, where: str) -> np.ndarray:
    """Depth in uint16 millimetres, shape (H, W), of a depth Image or CompressedImage message."""
    if compressed:
        data = bytes(msg.data)
        fmt = msg.format
        start = data.find(_PNG_MAGIC) if "compresseddepth" in fmt.lower() else 0
        image = cv2.imdecode(np.frombuffer(data[max(start, 0) :], np.uint8), cv2.IMREAD_UNCHANGED)
        if image is None or image.ndim != 2 or image.dtype != np.uint16:
            raise RecordingError(f"{where}: CompressedImage format {fmt!r} is not a 16-bit single-channel PNG")
        if "32FC1" in fmt:
            _, a, b = struct.unpack_from("<iff", data, 0)
            with np.errstate(divide="ignore"):
                metres = np.where(image > 0, a / (image.astype(np.float64) - b), 0.0)
            return to_millimetres(metres, 1000.0)
        return image
    encoding = msg.encoding
    if encoding not in _DEPTH_SCALE:
        raise InputError(
            f"{where}: depth encoding {encoding!r} is not supported; expected 16UC1 (mm), mono16 (mm) or 32FC1 (m)"
        )
    image = _image_array(msg, np.float32 if encoding == "32FC1" else np.uint16, 1, where)
    return to_millimetres(image, _DEPTH_SCALE[encoding])


def intrinsics_from_camera_info(msg: Any, where: str) -> Intrinsics:
    """Intrinsics of a ROS 1 or ROS 2 ``sensor_msgs/CameraInfo`` message."""
    k = [float(x) for x in _field(msg, "k", "K")]
    d = tuple(float(x) for x in _field(msg, "d", "D"))
    model = str(msg.distortion_model or "")
    sizes = {"plumb_bob": 5, "rational_polynomial": 8, "equidistant": 4}
    if not any(d):
        model, d = "none", ()
    elif model in sizes:
        n = sizes[model]
        if any(d[n:]):
            model = "opencv"
        else:
            d = d[:n]
        model = {"equidistant": "kannala_brandt"}.get(model, model)
    else:
        raise InputError(f"{where}: distortion_model {model!r} is not supported; expected one of {sorted(sizes)}")
    if len(k) != 9 or k[0] <= 0:
        raise RecordingError(f"{where}: K must be 9 numbers with fx > 0, got {k}")
    try:
        return Intrinsics(int(msg.width), int(msg.height), k[0], k[4], k[2], k[5], model, d)
    except InputError as exc:
        raise RecordingError(f"{where}: {exc}") from None


def _common_prefix(a: str, b: str) -> int:
    n = 0
    for x, y in zip(a.split("/"), b.split("/"), strict=False):
        if x != y:
            break
        n += 1
    return n


def _transform(
    tree: dict[str, tuple[str, np.ndarray, np.ndarray]], target: str, source: str
) -> tuple[np.ndarray, np.ndarray] | None:
    """``(R, t)`` with ``p_target = R @ p_source + t`` from a tf tree ``{child: (parent, R, t)}``, or None."""

    def to_root(frame: str) -> tuple[str, np.ndarray, np.ndarray]:
        rotation, translation = np.eye(3), np.zeros(3)
        seen = {frame}
        while frame in tree:
            parent, r, t = tree[frame]
            rotation, translation = r @ rotation, r @ translation + t
            frame = parent
            if frame in seen:
                break
            seen.add(frame)
        return frame, rotation, translation

    root_s, r_s, t_s = to_root(source)
    root_t, r_t, t_t = to_root(target)
    if root_s != root_t:
        return None
    return r_t.T @ r_s, r_t.T @ (t_s - t_t)


class RosBagSource(ImportSource):
    """Colour + registered depth frames from a ROS bag.

    Parameters
    ----------
    path : str or Path
        ``.mcap`` file (ROS 2), bag folder (ROS 2, ``metadata.yaml``) or ``.bag`` (ROS 1).
    color_topic, depth_topic, info_topic : str, optional
        Override the automatic choice; ``depth_topic="none"`` imports colour only.
    intrinsics : IntrinsicsOption, optional
        Used when the bag has no CameraInfo topic.
    """

    kind = "ros"

    def __init__(
        self,
        path: str | Path,
        *,
        color_topic: str | None = None,
        depth_topic: str | None = None,
        info_topic: str | None = None,
        intrinsics: IntrinsicsOption | None = None,
    ) -> None:
        super().__init__(path)
        self.requested = {"colour": color_topic, "depth": depth_topic, "camera info": info_topic}
        self.intrinsics_option = intrinsics or IntrinsicsOption()
        self.color_topic: str | None = None
        self.depth_topic: str | None = None
        self.info_topic: str | None = None
        self._bag: _McapBag | _RosbagsBag | None = None
        self._intrinsics: Intrinsics | None = None
        self._color_ns = np.empty(0, np.int64)
        self._color_keep: dict[int, int] = {}
        self._depth_rank: dict[int, int] = {}
        self._pairing = np.empty(0, np.int64)
        self._registration: DepthRegistration | None = None

    # ------------------------------------------------------------------ topic choice

    def _found(self) -> str:
        bag = self._bag
        return ", ".join(f"{t} ({bag.topics[t]}, {bag.counts.get(t, 0)})" for t in sorted(bag.topics)) or "no topics"

    def _check_topic(self, what: str, topic: str, types: tuple[str, ...]) -> str:
        have = self._bag.topics.get(topic)
        if have not in types:
            state = f"has type {have}" if have else "is not in the bag"
            raise InputError(f"{what} topic {topic} {state}; expected {' or '.join(types)}; found {self._found()}")
        return topic

    def _choose(self) -> None:
        bag = self._bag
        images = [t for t, ty in bag.topics.items() if ty in _IMAGE_TYPES and bag.counts.get(t, 1) > 0]
        req = self.requested
        if req["colour"] is not None:
            self.color_topic = self._check_topic("colour", req["colour"], _IMAGE_TYPES)
        else:
            colors = [
                t
                for t in images
                if not any(w in t.lower() for w in _NOT_COLOR) and not t.lower().endswith("compresseddepth")
            ]
            if not colors:
                raise InputError(
                    f"{self.path} has no colour image topic (sensor_msgs Image or CompressedImage); "
                    f"found {self._found()}"
                )

            def colour_score(t: str) -> tuple:
                low = t.lower()
                return (
                    any(w in low for w in ("color", "colour", "rgb")),
                    bag.topics[t] == IMAGE,
                    "image_raw" in low,
                    -len(t),
                    t,
                )

            self.color_topic = max(colors, key=colour_score)
        if req["depth"] is not None:
            self.depth_topic = (
                None if req["depth"] == "none" else self._check_topic("depth", req["depth"], _IMAGE_TYPES)
            )
        else:
            depths = [t for t in images if t != self.color_topic and ("depth" in t.lower() or "stereo" in t.lower())]

            def depth_score(t: str) -> tuple:
                low = t.lower()
                return ("aligned" in low and "color" in low, "aligned" in low, bag.topics[t] == IMAGE, -len(t), t)

            self.depth_topic = max(depths, key=depth_score) if depths else None
        infos = [t for t, ty in bag.topics.items() if ty == CAMERA_INFO]
        if req["camera info"] is not None:
            self.info_topic = self._check_topic("camera info", req["camera info"], (CAMERA_INFO,))
        elif infos:
            best = max(infos, key=lambda t: (_common_prefix(t, self.color_topic), "color" in t.lower(), t))
            self.info_topic = best if _common_prefix(best, self.color_topic) > 1 or len(infos) == 1 else None

    # ------------------------------------------------------------------ Source

    def _decoded(self, topic: str, data: bytes) -> Any:
        try:
            return self._bag.decode(topic, data)
        except (InputError, RecordingError):
            raise
        except Exception as exc:  # the CDR/ROS 1 decoders raise their own error types on bad data
            raise RecordingError(f"{self.path}: a message of {topic} cannot be decoded ({exc})") from None

    def _color(self, data: bytes) -> np.ndarray:
        return decode_color(
            self._decoded(self.color_topic, data), self._bag.topics[self.color_topic] == COMPRESSED, self.color_topic
        )

    def _depth(self, data: bytes) -> np.ndarray:
        depth = decode_depth(
            self._decoded(self.depth_topic, data), self._bag.topics[self.depth_topic] == COMPRESSED, self.depth_topic
        )
        return depth if self._registration is None else self._registration(depth)

    def _scan(self) -> tuple[bytes, bytes | None, bytes | None]:
        """Pass 1: stamps of every colour and depth message; the first message of each topic."""
        bag = self._bag
        topics = [t for t in (self.color_topic, self.depth_topic, self.info_topic) if t]
        color_ns, depth_ns, firsts = [], [], {}
        for topic, log_time, data in bag.raw(topics):
            firsts.setdefault(topic, bytes(data))
            if topic == self.info_topic:
                continue
            stamp = _stamp_ns(data, bag.ros1)
            (color_ns if topic == self.color_topic else depth_ns).append(stamp if stamp > 0 else log_time)
        if not color_ns:
            raise InputError(f"colour topic {self.color_topic} of {self.path} holds no messages")
        c = np.asarray(color_ns, np.int64)
        keep = np.flatnonzero(np.concatenate(([True], c[1:] > np.maximum.accumulate(c)[:-1])))
        if len(keep) < len(c):
            self.stats.dropped += len(c) - len(keep)
            self.report.append(f"{len(c) - len(keep)} colour message(s) skipped: their stamp did not increase")
        self._color_keep = {int(k): r for r, k in enumerate(keep)}
        self._color_ns = c[keep]
        d = np.asarray(depth_ns, np.int64)
        order = np.argsort(d, kind="stable")
        self._depth_rank = {int(k): r for r, k in enumerate(order)}
        period = frame_period_ns(self._color_ns)
        self._pairing = pair_nearest(self._color_ns, d[order], period // 2)
        return firsts[self.color_topic], firsts.get(self.depth_topic), firsts.get(self.info_topic)

    def _color_intrinsics(self, first_info: bytes | None, w: int, h: int) -> str:
        if first_info is None:
            self._intrinsics, origin = self.intrinsics_option.resolve(w, h)
            return f"no CameraInfo topic; intrinsics {origin}"
        k = intrinsics_from_camera_info(self._decoded(self.info_topic, first_info), self.info_topic)
        if (k.width, k.height) != (w, h):
            if k.width == 0 or abs(k.width / k.height - w / h) > 1e-3:
                raise InputError(f"camera info {self.info_topic} is for {k.width}x{k.height}, colour is {w}x{h}")
            k = k.scaled(w, h)
        self._intrinsics = k
        return (
            f"intrinsics from {self.info_topic} (fx={k.fx:.1f}, fy={k.fy:.1f}, cx={k.cx:.1f}, cy={k.cy:.1f}, "
            f"{k.distortion_model})"
        )

    def _depth_geometry(self, color_frame: str, depth_frame: str) -> tuple[DepthToColor | None, str]:
        """Depth-to-colour geometry from the depth camera info and /tf_static, or None and why not."""
        bag = self._bag
        infos = [t for t, ty in bag.topics.items() if ty == CAMERA_INFO and t != self.info_topic]
        info = max(infos, key=lambda t: _common_prefix(t, self.depth_topic), default=None)
        if info is None or _common_prefix(info, self.depth_topic) <= _common_prefix(info, self.color_topic):
            return None, "no CameraInfo topic next to the depth topic"
        tf_topics = [t for t, ty in bag.topics.items() if ty == TF_MESSAGE and "static" in t]
        if not tf_topics:
            return None, "no /tf_static topic"
        tree: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
        first_info = None
        for topic, _, data in bag.raw([info, *tf_topics]):
            if topic == info:
                first_info = first_info or bytes(data)
                continue
            for tf in self._decoded(topic, bytes(data)).transforms:
                q, v = tf.transform.rotation, tf.transform.translation
                rotation = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
                tree[tf.child_frame_id.lstrip("/")] = (
                    tf.header.frame_id.lstrip("/"),
                    rotation,
                    1000.0 * np.array([v.x, v.y, v.z]),
                )
        if first_info is None:
            return None, f"{info} holds no messages"
        moved = _transform(tree, color_frame.lstrip("/"), depth_frame.lstrip("/"))
        if moved is None:
            return None, f"/tf_static does not connect {depth_frame!r} to {color_frame!r}"
        k_depth = intrinsics_from_camera_info(self._decoded(info, first_info), info)
        return DepthToColor(k_depth, self._intrinsics, *moved), f"depth intrinsics from {info}"

    def _setup_depth(self, first_color: bytes, first_depth: bytes | None, w: int, h: int) -> list[str]:
        bag = self._bag
        if first_depth is None:
            raise InputError(f"depth topic {self.depth_topic} of {self.path} holds no messages")
        depth = self._depth(first_depth)
        paired = int((self._pairing >= 0).sum())
        lines = [
            f"depth: {self.depth_topic} ({bag.topics[self.depth_topic]}); {paired} of "
            f"{len(self._pairing)} colour frames paired with depth within half a frame period, "
            f"{len(self._pairing) - paired} without depth; {len(self._depth_rank) - paired} depth "
            "message(s) unpaired (skipped)"
        ]
        if "aligned" in self.depth_topic.lower():
            if depth.shape != (h, w):
                raise InputError(
                    f"aligned depth topic {self.depth_topic} is {depth.shape[1]}x{depth.shape[0]} but "
                    f"colour topic {self.color_topic} is {w}x{h}"
                )
            return lines
        color_frame = self._decoded(self.color_topic, first_color).header.frame_id
        depth_frame = self._decoded(self.depth_topic, first_depth).header.frame_id
        geometry, why = self._depth_geometry(color_frame, depth_frame)
        if geometry is not None and (geometry.depth.width, geometry.depth.height) == depth.shape[::-1]:
            self._registration = DepthRegistration(geometry)
            t = geometry.translation_mm
            lines.append(
                f"depth registered to colour (z-buffered): {why}, {depth_frame} to {color_frame} from /tf_static "
                f"(translation {t[0]:.1f}, {t[1]:.1f}, {t[2]:.1f} mm)"
            )
        elif depth.shape == (h, w):
            lines.append(
                f"warning: depth topic {self.depth_topic} is not aligned and cannot be registered ({why}): "
                "its pixels are taken as registered to colour"
            )
        else:
            raise InputError(
                f"depth topic {self.depth_topic} is {depth.shape[1]}x{depth.shape[0]} but colour topic "
                f"{self.color_topic} is {w}x{h} and cannot be registered to it ({why}): record "
                "aligned_depth_to_color, pass --depth-topic with an aligned topic, or --depth-topic none"
            )
        return lines

    def open(self) -> None:
        self._bag = _open_bag(self.path)
        try:
            self._choose()
            first_color, first_depth, first_info = self._scan()
            h, w = self._color(first_color).shape[:2]
            bag = self._bag
            lines = [f"colour: {self.color_topic} ({bag.topics[self.color_topic]}, {w}x{h})"]
            intrinsics_line = self._color_intrinsics(first_info, w, h)
            if self.depth_topic is not None:
                lines += self._setup_depth(first_color, first_depth, w, h)
            else:
                lines.append("depth: none (colour only)")
            lines.append(intrinsics_line)
            others = sorted(
                t
                for t, ty in bag.topics.items()
                if ty in _IMAGE_TYPES and t not in (self.color_topic, self.depth_topic)
            )
            if others:
                lines.append(f"other image topics not imported: {', '.join(others)}")
            self.report.extend(lines)
            self.total = len(self._color_ns)
        except BaseException:
            self.close()
            raise

    def close(self) -> None:
        if self._bag is not None:
            self._bag.close()
            self._bag = None

    def metadata(self) -> dict[str, str]:
        meta = {**super().metadata(), "ros_color_topic": str(self.color_topic)}
        if self.depth_topic:
            meta["ros_depth_topic"] = self.depth_topic
        return meta

    def _items(self) -> Iterator[tuple[str, int, Callable[[], Any]]]:
        n_color = n_depth = 0
        for topic, _, data in self._bag.raw([t for t in (self.color_topic, self.depth_topic) if t]):
            if topic == self.color_topic:
                rank = self._color_keep.get(n_color)
                n_color += 1
                if rank is not None:
                    yield "color", rank, lambda data=data: self._color(data)
            else:
                yield "depth", self._depth_rank[n_depth], lambda data=data: self._depth(data)
                n_depth += 1

    def _frames(self) -> Iterator[Frame]:
        for i, color, depth in merge_paired(self._items(), self._pairing):
            yield frame_of(int(self._color_ns[i]), i, color, depth, self._intrinsics, f"{self.path} frame {i}")
