"""MCAP recorder: a :class:`~drivers.base.Sink` writing frames per docs/recording-format.md.

Every frame becomes up to five messages (calibration when it changed or a new
chunk starts, colour, depth, skeleton, ground truth), all with ``log_time =
publish_time = frame.timestamp_ns``. Each calibration is also written once as a
``fusion_pf.calibration`` metadata record (outside the chunks, indexed by the
summary), so no single damaged chunk takes the calibration of the others with it;
each channel likewise gets a ``fusion_pf.channel`` metadata record, so a scan of
a file whose first chunk is damaged still knows the topics. Tracker outputs are added with :meth:`McapRecorder.write_json`
and :meth:`McapRecorder.write_protobuf`. The file is written in place (no temp
name): the header is flushed at once and every chunk reaches the OS as soon as it
is written, so a crash (even SIGKILL) leaves a readable partial file, and :meth:`McapRecorder.close` -- run by the context manager whatever
stopped the source -- writes the index and summary.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import IO, Any

import mcap
from google.protobuf.message import Message
from mcap.writer import CompressionType, Writer

from fusion_pf import __version__
from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame, Intrinsics
from fusion_pf.signals import sigint_deferred

from . import mcap_format as fmt
from .base import Sink
from .encoding import COMPRESSION_NAMES, EncodingOptions

#: Compression names accepted by :class:`McapRecorder`.
COMPRESSIONS = dict(
    zip(COMPRESSION_NAMES, (CompressionType.ZSTD, CompressionType.LZ4, CompressionType.NONE), strict=True)
)
#: Default uncompressed chunk size in bytes (about one raw 640x400 RGB-D frame).
CHUNK_SIZE = 1 << 20
#: Bytes a message adds to a chunk besides its data (record header 9, channel 2, sequence 4, two times 16).
_MESSAGE_OVERHEAD = 31
#: The mcap Writer's own chunk limit, never reached: this recorder ends chunks at frame boundaries.
_NEVER = 1 << 62


#: One message of a frame: ``(topic, protobuf message or None, JSON schema name or None, JSON object or None)``.
FrameMessage = tuple[str, Message | None, str | None, Any]


def camera_messages(messages: list[FrameMessage], camera: str) -> list[FrameMessage]:
    """One camera's frame messages in a multi-camera recording: topics under ``/<camera>``, Foxglove messages in the
    frame ``<camera>`` (the child frame of its pose on ``/tf``)."""
    out = [(fmt.camera_topic(camera, topic), proto, name, obj) for topic, proto, name, obj in messages]
    for _topic, proto, _name, _obj in out:
        if proto is not None:
            proto.frame_id = camera  # type: ignore[attr-defined]
    return out


def frame_messages(frame: Frame, color_format: str, jpeg_quality: int, depth_format: str) -> list[FrameMessage]:
    """The messages of one frame, calibration first: what :meth:`McapRecorder.write` writes (and the live view streams).

    Calibration, colour and depth are protobuf messages; skeleton, ground truth
    and hand landmarks JSON objects with their schema name.
    """
    t = frame.timestamp_ns
    messages: list[FrameMessage] = [
        (fmt.CALIBRATION_TOPIC, fmt.encode_calibration(frame.intrinsics, t), None, None),
        (fmt.COLOR_TOPIC, fmt.encode_color(frame.color, t, color_format, jpeg_quality), None, None),
    ]
    if frame.depth is not None:
        messages.append((fmt.DEPTH_TOPIC, fmt.encode_depth(frame.depth, t, depth_format), None, None))
    if frame.joints is not None:
        messages.append((fmt.SKELETON_TOPIC, None, fmt.SKELETON_SCHEMA, fmt.encode_skeleton(frame.joints)))
    if frame.ground_truths is not None:
        messages.extend(
            (fmt.GROUND_TRUTH_TOPIC, None, fmt.TARGET_PALM_SCHEMA, fmt.encode_target_palm(name, point))
            for name, point in frame.ground_truths.items()
        )
    elif frame.ground_truth is not None:
        messages.append((fmt.GROUND_TRUTH_TOPIC, None, fmt.PALM_SCHEMA, fmt.encode_palm(frame.ground_truth)))
    if frame.hands is not None:
        messages.append((fmt.HAND_TOPIC, None, fmt.HAND_SCHEMA, fmt.encode_hands(frame.hands)))
    return messages


class McapRecorder(Sink):
    """Write frames and tracker outputs into an MCAP file.

    Parameters
    ----------
    path : str or Path
        Output file; created or overwritten on :meth:`open` (refusing to
        overwrite is the command line's job).
    compression : {"zstd", "lz4", "none"}
        Chunk compression.
    color_format : {"raw", "jpeg", "png"}
        ``raw`` writes ``foxglove.RawImage`` rgb8, the others
        ``foxglove.CompressedImage``.
    depth_format : {"raw", "png"}
        ``raw`` writes ``foxglove.RawImage`` 16UC1, ``png`` a 16-bit PNG
        ``foxglove.CompressedImage``.
    jpeg_quality : int
        1-100, for ``color_format="jpeg"``.
    metadata : mapping of str to str, optional
        Written into the ``fusion_pf.recording`` metadata record (generator,
        seed, ...). ``background_frames`` is set from the frames' ``background``
        flags.
    chunk_size : int
        Uncompressed chunk size in bytes; a crash loses at most the chunk being
        filled. Chunks end at frame boundaries: a chunk is closed before a
        frame that would take it past ``chunk_size`` (a frame larger than that
        gets a chunk of its own), and every chunk starts with a copy of the
        calibration.

    Examples
    --------
    >>> with McapRecorder("out.mcap", color_format="jpeg") as rec:  # doctest: +SKIP
    ...     for frame in source:
    ...         rec.write(frame)
    """

    def __init__(
        self,
        path: str | Path,
        *,
        compression: str = EncodingOptions.compression,
        color_format: str = EncodingOptions.color_format,
        depth_format: str = EncodingOptions.depth_format,
        jpeg_quality: int = EncodingOptions.jpeg_quality,
        metadata: Mapping[str, str] | None = None,
        chunk_size: int = CHUNK_SIZE,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise InputError(f"compression must be one of {sorted(COMPRESSIONS)}, got {compression!r}")
        if color_format not in fmt.COLOR_FORMATS:
            raise InputError(f"color_format must be one of {fmt.COLOR_FORMATS}, got {color_format!r}")
        if depth_format not in fmt.DEPTH_FORMATS:
            raise InputError(f"depth_format must be one of {fmt.DEPTH_FORMATS}, got {depth_format!r}")
        if isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, int) or not 1 <= jpeg_quality <= 100:
            raise InputError(f"jpeg_quality must be an int in 1..100, got {jpeg_quality!r}")
        if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size < 1:
            raise InputError(f"chunk_size must be a positive int (bytes), got {chunk_size!r}")
        meta = dict(metadata or {})
        for key, value in meta.items():
            if not isinstance(key, str) or not isinstance(value, str):
                raise InputError(f"metadata must map str to str, got {key!r}: {value!r}")
        announced = meta.get(fmt.BACKGROUND_FRAMES_KEY, "0")
        if not announced.isdigit():
            raise InputError(f"metadata {fmt.BACKGROUND_FRAMES_KEY} must be a non-negative integer, got {announced!r}")
        self.path = Path(path)
        self.compression = compression
        self.color_format = color_format
        self.depth_format = depth_format
        self.jpeg_quality = jpeg_quality
        self.chunk_size = chunk_size
        self._metadata = {
            fmt.FORMAT_VERSION_KEY: fmt.FORMAT_VERSION,
            "writer": f"fusion-pf {__version__}",
            **meta,
            fmt.BACKGROUND_FRAMES_KEY: str(int(announced)),
        }
        self._announced = int(announced)
        self._fh: IO[bytes] | None = None
        self._writer: Writer | None = None
        self._schemas: dict[tuple[str, str], int] = {}
        self._channels: dict[str, tuple[int, str]] = {}
        self._intrinsics: dict[str | None, Intrinsics] = {}
        self._last_ns: dict[str | None, int] = {}
        self._chunk_cameras: set[str | None] = set()
        self._last_background_ns: int | None = None
        self._background = 0
        self._foreground = False
        self.frames_written = 0
        self.messages_written = 0
        self._bytes = 0
        self._chunk_bytes = 0
        #: The OSError that stopped writing (full disk, ...), or None.
        self.error: OSError | None = None

    # ------------------------------------------------------------------ lifecycle

    def open(self) -> None:
        """Create the file and write the header and the ``fusion_pf.recording`` metadata."""
        if self._writer is not None:
            raise RecordingError(f"recorder for {self.path} is already open")
        fh = open(self.path, "wb")
        try:
            writer = Writer(
                fh,
                chunk_size=_NEVER,
                compression=COMPRESSIONS[self.compression],
                enable_crcs=True,
                enable_data_crcs=True,
            )
            writer.start(profile="", library=f"fusion-pf {__version__}; mcap-python {mcap.__version__}")
            writer.add_metadata(fmt.RECORDING_METADATA, self._metadata)
            fh.flush()
        except BaseException:
            fh.close()
            raise
        self._fh, self._writer = fh, writer
        self._schemas.clear()
        self._channels.clear()
        self._intrinsics.clear()
        self._last_ns.clear()
        self._chunk_cameras.clear()
        self._last_background_ns = None
        self._background, self._foreground = 0, False
        self.frames_written = self.messages_written = 0
        self._chunk_bytes, self.error = 0, None

    def close(self) -> None:
        """Write the index and summary and close the file; safe to call twice.

        A Ctrl-C arriving meanwhile is held back until the file is complete,
        then re-raised.
        """
        writer, fh = self._writer, self._fh
        if writer is None or fh is None:
            return
        self._writer = self._fh = None
        with sigint_deferred():
            try:
                if self.error is None:
                    if not self._foreground:
                        self._announce_background(writer)
                    writer.finish()
            except OSError as exc:
                self.error = exc
            finally:
                try:
                    fh.close()
                except OSError as exc:
                    self.error = self.error or exc
                self._bytes = os.path.getsize(self.path)
        if self.error is not None:
            raise self._failure()

    def _failure(self) -> RecordingError:
        exc = self.error
        why = exc.strerror or str(exc) if exc is not None else "unknown error"
        return RecordingError(f"writing {self.path} failed ({why}); the file keeps the chunks that reached the disk")

    def __exit__(self, exc_type: object, *exc: object) -> None:
        try:
            self.close()
        except RecordingError:
            if exc_type is None:
                raise  # otherwise the exception in flight says what went wrong

    @property
    def bytes_written(self) -> int:
        """Size of the file so far (final size after :meth:`close`)."""
        if self._fh is not None:
            return self._fh.tell()
        return self._bytes

    def _require_writer(self) -> Writer:
        if self._writer is None:
            raise RecordingError(f"recorder for {self.path} is not open; use it inside a 'with' block")
        return self._writer

    # ------------------------------------------------------------------ channels

    def _channel(
        self, topic: str, schema_name: str, schema_encoding: str, schema_data: bytes, message_encoding: str
    ) -> int:
        writer = self._require_writer()
        known = self._channels.get(topic)
        if known is not None:
            if known[1] != schema_name:
                raise InputError(f"topic {topic!r} already carries {known[1]} messages, cannot write {schema_name}")
            return known[0]
        key = (schema_name, schema_encoding)
        schema_id = self._schemas.get(key)
        if schema_id is None:
            schema_id = writer.register_schema(name=schema_name, encoding=schema_encoding, data=schema_data)
            self._schemas[key] = schema_id
        channel_id = writer.register_channel(topic=topic, message_encoding=message_encoding, schema_id=schema_id)
        self._channels[topic] = (channel_id, schema_name)
        self._metadata_record(
            writer,
            fmt.CHANNEL_METADATA,
            {
                "id": str(channel_id),
                "topic": topic,
                "message_encoding": message_encoding,
                "schema_name": schema_name,
                "schema_encoding": schema_encoding,
            },
        )
        return channel_id

    def _proto_channel(self, topic: str, message: Message) -> int:
        name = message.DESCRIPTOR.full_name
        known = self._channels.get(topic)
        if known is not None and known[1] == name:
            return known[0]
        return self._channel(topic, name, "protobuf", fmt.protobuf_schema_data(type(message)), "protobuf")

    def _json_channel(self, topic: str, schema_name: str, schema: Mapping[str, Any] | None) -> int:
        known = self._channels.get(topic)
        if known is not None and known[1] == schema_name:
            return known[0]
        return self._channel(topic, schema_name, "jsonschema", fmt.json_schema_data(schema_name, schema), "json")

    def _add(self, channel_id: int, timestamp_ns: int, data: bytes, sequence: int = 0) -> None:
        # a Ctrl-C inside add_message could split a chunk from its message indexes
        writer = self._require_writer()
        if self.error is not None:
            raise self._failure()
        with sigint_deferred():
            try:
                writer.add_message(
                    channel_id=channel_id,
                    log_time=timestamp_ns,
                    publish_time=timestamp_ns,
                    data=data,
                    sequence=sequence & 0xFFFFFFFF,
                )
            except OSError as exc:
                self.error = exc
                raise self._failure() from None
            self.messages_written += 1
            self._chunk_bytes += _MESSAGE_OVERHEAD + len(data)

    def _end_chunk(self) -> None:
        """Write the chunk being filled (and its message indexes) and hand it to the OS."""
        if self._chunk_bytes:
            with sigint_deferred():
                try:
                    self._require_writer().flush()
                except OSError as exc:
                    self.error = exc
                    raise self._failure() from None
                self._chunk_bytes = 0
                self._chunk_cameras.clear()

    def _announce_background(self, writer: Writer) -> None:
        if self._background != self._announced:
            self._metadata[fmt.BACKGROUND_FRAMES_KEY] = str(self._background)
            self._metadata_record(writer, fmt.RECORDING_METADATA, dict(self._metadata))
            self._announced = self._background

    def _metadata_record(self, writer: Writer, name: str, data: dict[str, str]) -> None:
        if self.error is not None:
            raise self._failure()
        try:
            writer.add_metadata(name, data)
        except OSError as exc:
            self.error = exc
            raise self._failure() from None

    # ------------------------------------------------------------------ writing

    def write(self, frame: Frame, camera: str | None = None) -> None:
        """Write one frame: calibration (first frame and when it changes), colour, depth, skeleton, ground truth, hands.

        Parameters
        ----------
        frame : Frame
            Its timestamp must be later than the previous frame's (of the same
            camera); background frames must come before every other frame.
        camera : str, optional
            In a multi-camera recording, the camera: its topics get the prefix
            ``/<camera>`` and its Foxglove messages the ``frame_id`` ``<camera>``
            (the child frame of its pose on ``/tf``). The frames of one instant
            share a timestamp; background frames are counted per instant.
        """
        writer = self._require_writer()
        if not isinstance(frame, Frame):
            raise InputError(f"McapRecorder.write takes a Frame, got {type(frame).__name__}")
        t = frame.timestamp_ns
        last = self._last_ns.get(camera)
        if last is not None and t <= last:
            of = f" of camera {camera}" if camera is not None else ""
            raise InputError(
                f"frame timestamps{of} must increase: frame seq {frame.seq} has timestamp_ns={t} after {last}"
            )
        if frame.background and self._foreground:
            raise InputError(
                f"background frames must be the first frames of a recording: frame seq {frame.seq} "
                f"is a background frame after {self.frames_written - self._background} other frames"
            )
        changed = frame.intrinsics != self._intrinsics.get(camera)
        messages = frame_messages(frame, self.color_format, self.jpeg_quality, self.depth_format)
        if not frame.background and not self._foreground:
            self._foreground = True
            self._announce_background(writer)
        if camera is not None:
            messages = camera_messages(messages, camera)
        payloads = [
            (self._proto_channel(topic, proto), proto.SerializeToString())
            if proto is not None
            else (
                self._json_channel(topic, schema_name, None),
                fmt.encode_json(obj, f"{topic} of frame seq {frame.seq}"),
            )
            for topic, proto, schema_name, obj in messages
        ]
        size = sum(_MESSAGE_OVERHEAD + len(data) for _, data in payloads)
        with sigint_deferred():
            if self._chunk_bytes and self._chunk_bytes + size > self.chunk_size:
                self._end_chunk()
            if changed:
                record = fmt.calibration_metadata(frame.intrinsics, t)
                self._metadata_record(
                    writer, fmt.CALIBRATION_METADATA, record if camera is None else {**record, "camera": camera}
                )
            if not (changed or camera not in self._chunk_cameras):  # the chunk already holds this calibration
                payloads = payloads[1:]
            for channel_id, data in payloads:
                self._add(channel_id, t, data, frame.seq)
            self._chunk_cameras.add(camera)
            self._intrinsics[camera] = frame.intrinsics
            self._last_ns[camera] = t
            if frame.background and t != self._last_background_ns:
                self._background += 1
                self._last_background_ns = t
            self.frames_written += 1
            if self._chunk_bytes > self.chunk_size:
                self._end_chunk()

    def _check_extra_topic(self, topic: object) -> str:
        if not isinstance(topic, str) or not topic:
            raise InputError(f"topic must be a non-empty string, got {topic!r}")
        if topic in fmt.FRAME_TOPICS:
            raise InputError(f"topic {topic!r} is written by write(frame); choose another topic")
        return topic

    def write_json(
        self,
        topic: str,
        schema_name: str,
        obj: Any,
        timestamp_ns: int,
        *,
        schema: Mapping[str, Any] | None = None,
    ) -> None:
        """Write a JSON message (``log_time = publish_time = timestamp_ns``).

        Parameters
        ----------
        topic : str
            E.g. ``"/tracker/estimate"``; not one of the frame topics.
        schema_name : str
            A name from :data:`drivers.mcap_format.JSON_SCHEMAS` (e.g.
            ``"fusion_pf.Estimate"``), or any name when ``schema`` is given.
        obj : JSON-serialisable object
            NaN and infinity are rejected (use null).
        timestamp_ns : int
            Time of the frame the message belongs to.
        schema : mapping, optional
            JSON Schema of an unregistered ``schema_name``.
        """
        self._require_writer()
        topic = self._check_extra_topic(topic)
        t = fmt.check_timestamp(timestamp_ns)
        data = fmt.encode_json(obj, f"{topic} message")
        self._add(self._json_channel(topic, schema_name, schema), t, data)
        if self._chunk_bytes > self.chunk_size:
            self._end_chunk()

    def write_protobuf(self, topic: str, message: Message, timestamp_ns: int) -> None:
        """Write a protobuf message, e.g. a ``foxglove.ImageAnnotations`` overlay.

        Parameters
        ----------
        topic : str
            E.g. ``"/tracker/overlay"``; not one of the frame topics.
        message : google.protobuf.message.Message
            Its full name becomes the schema name; a topic keeps one type.
        timestamp_ns : int
            Time of the frame the message belongs to.
        """
        self._require_writer()
        topic = self._check_extra_topic(topic)
        if not isinstance(message, Message):
            raise InputError(f"write_protobuf takes a protobuf message, got {type(message).__name__}")
        t = fmt.check_timestamp(timestamp_ns)
        self._add(self._proto_channel(topic, message), t, message.SerializeToString())
        if self._chunk_bytes > self.chunk_size:
            self._end_chunk()
