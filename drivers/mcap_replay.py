"""MCAP replay: a seekable :class:`~drivers.base.ReplaySource` over recordings in the fusion-pf convention.

Reads any file that follows docs/recording-format.md, whichever library wrote
it. Frames are assembled by timestamp: every ``/camera/color`` message is a
frame; the depth, skeleton and ground-truth messages with the same
``log_time`` join it (a missing part is ``None`` and counted in
:attr:`~drivers.base.Source.stats`); the calibration in effect is the latest one
at or before the frame.

How the file is read
--------------------
Indexed (a finished file)
    The summary's chunk indexes and the message indexes after each chunk give
    every message's time without decompressing anything, so :meth:`McapReplay.open`
    is cheap, counts come from the summary, and :meth:`McapReplay.frame` reads
    only the chunk(s) holding one frame.
Scanned (a truncated or unfinished file, or one without index)
    One linear pass over the complete records rebuilds the same index in
    memory, one chunk at a time; the truncation is reported in
    ``stats.notes`` and :meth:`McapReplay.info` (``truncated=True``).

Replay streams: chunks are read one at a time with ``os.pread`` (so
concurrent :meth:`McapReplay.frame` calls from several threads are safe) and
chunk CRCs are checked. A corrupt chunk is skipped with a note; the frames it
held are counted as dropped.
"""

from __future__ import annotations

import json
import os
import struct
import threading
import zlib
from collections import OrderedDict
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import lz4.frame
import numpy as np
import zstandard
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame, Intrinsics, PalmPoint

from . import mcap_format as fmt
from .base import ReplaySource, SourceStats

MAGIC = b"\x89MCAP0\r\n"

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_METADATA, _OP_DATA_END = 0x06, 0x07, 0x0C, 0x0F
_FOOTER_LEN = 9 + 20
_MESSAGE_HEADER = struct.Struct("<HIQQ")
_RECORD_HEADER = struct.Struct("<BQ")

#: Parts of a frame, by topic.
_KINDS = {
    fmt.COLOR_TOPIC: "color",
    fmt.DEPTH_TOPIC: "depth",
    fmt.SKELETON_TOPIC: "skeleton",
    fmt.GROUND_TRUTH_TOPIC: "truth",
    fmt.HAND_TOPIC: "hands",
    fmt.CALIBRATION_TOPIC: "calibration",
}
_PROTO_SCHEMAS = {
    "color": (fmt.RAW_IMAGE, fmt.COMPRESSED_IMAGE),
    "depth": (fmt.RAW_IMAGE, fmt.COMPRESSED_IMAGE),
    "calibration": (fmt.CAMERA_CALIBRATION,),
}
_BLOCK_CACHE = 4
_CALIBRATION_CACHE = 4096



def _put(parts: dict, kind: str, record: tuple[int, memoryview, int]) -> None:
    """File a message of a frame: one per kind, except ground truth (one per target)."""
    if kind == "truth":
        parts.setdefault(kind, []).append(record)
    else:
        parts[kind] = record

class _Corrupt(Exception):
    """A record that cannot be parsed (internal; turned into notes or RecordingError)."""


class _Cursor:
    """Little-endian reader over a record body that raises _Corrupt on overrun."""

    def __init__(self, buf: bytes | memoryview, what: str) -> None:
        self.buf, self.pos, self.what = memoryview(buf), 0, what

    def take(self, n: int) -> memoryview:
        if n < 0 or self.pos + n > len(self.buf):
            raise _Corrupt(f"{self.what} record is shorter than its fields")
        out = self.buf[self.pos : self.pos + n]
        self.pos += n
        return out

    def uint(self, n: int) -> int:
        return int.from_bytes(self.take(n), "little")

    def string(self) -> str:
        try:
            return bytes(self.take(self.uint(4))).decode()
        except UnicodeDecodeError:
            raise _Corrupt(f"{self.what} record holds a string that is not UTF-8") from None

    def mapping(self) -> dict[str, str]:
        end = self.pos + self.uint(4)
        out: dict[str, str] = {}
        while self.pos < end:
            key = self.string()
            out[key] = self.string()
        return out


class _Channel(NamedTuple):
    id: int
    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str


class _Block(NamedTuple):
    """A chunk, or a message outside chunks: the unit the replay reads."""

    offset: int
    length: int
    is_chunk: bool
    start_ns: int
    end_ns: int
    channels: frozenset[int]


def _records(buf: memoryview, what: str) -> Iterator[tuple[int, memoryview]]:
    pos, n = 0, len(buf)
    while pos < n:
        if pos + 9 > n:
            raise _Corrupt(f"{what} ends inside a record header")
        opcode, length = _RECORD_HEADER.unpack_from(buf, pos)
        if pos + 9 + length > n:
            raise _Corrupt(f"{what} holds a record (opcode 0x{opcode:02x}) longer than the {what}")
        yield opcode, buf[pos + 9 : pos + 9 + length]
        pos += 9 + length


def _decompress_chunk(body: memoryview) -> memoryview:
    """The records of a chunk record body, decompressed and CRC-checked."""
    cur = _Cursor(body, "chunk")
    cur.uint(16)
    size, crc = cur.uint(8), cur.uint(4)
    compression = cur.string()
    data = cur.take(cur.uint(8))
    try:
        if compression == "zstd":
            out = zstandard.ZstdDecompressor().decompress(data, max_output_size=size)
        elif compression == "lz4":
            out = lz4.frame.decompress(bytes(data))
        elif compression == "":
            out = bytes(data)
        else:
            raise _Corrupt(f"chunk compression {compression!r} is not supported (expected zstd, lz4 or none)")
    except _Corrupt:
        raise
    except Exception as exc:  # the decompressors raise their own error types on corrupt data
        raise _Corrupt(f"{compression} decompression failed ({exc})") from None
    if len(out) != size:
        raise _Corrupt(f"chunk decompressed to {len(out)} bytes, expected {size}")
    if crc and zlib.crc32(out) != crc:
        raise _Corrupt(f"chunk CRC mismatch (expected {crc:#010x}, got {zlib.crc32(out):#010x})")
    return memoryview(out)


@dataclass(frozen=True)
class TopicInfo:
    """One topic of a recording.

    Attributes
    ----------
    topic, schema_name, schema_encoding, message_encoding : str
    message_count : int
    """

    topic: str
    schema_name: str
    schema_encoding: str
    message_encoding: str
    message_count: int


@dataclass(frozen=True)
class RecordingInfo:
    """What :meth:`McapReplay.info` reports about a recording (the whole file).

    Attributes
    ----------
    path : str
    size_bytes : int
    library, profile : str
        From the MCAP header.
    indexed : bool
        True when the summary index was used; False when the file was scanned.
    truncated : bool
        True when the file ends early (the writer did not finish it).
    topics : tuple of TopicInfo
    frames : int
        Colour frames in the file.
    start_ns, end_ns : int
        Time of the first and last frame.
    duration_ns : int
    fps : float or None
        ``(frames - 1) / duration``; None for fewer than two frames.
    width, height : int
        Colour (and depth) size.
    intrinsics : dict
        ``fx, fy, cx, cy, distortion_model, distortion`` of the first calibration.
    calibration_messages : int
    color_format, depth_format : str or None
        ``rgb8``/``bgr8``/``jpeg``/``png`` and ``16UC1``/``mono16``/``png`` of the first frame.
    background_frames : int
    missing_depth, missing_skeleton : int
        Frames without a depth / skeleton message.
    ground_truth_frames : int
    metadata : dict
        The merged ``fusion_pf.recording`` metadata record(s).
    notes : tuple of str
        Truncation, corruption and other remarks.
    """

    path: str
    size_bytes: int
    library: str
    profile: str
    indexed: bool
    truncated: bool
    topics: tuple[TopicInfo, ...]
    frames: int
    start_ns: int
    end_ns: int
    duration_ns: int
    fps: float | None
    width: int
    height: int
    intrinsics: dict[str, Any]
    calibration_messages: int
    color_format: str | None
    depth_format: str | None
    background_frames: int
    missing_depth: int
    missing_skeleton: int
    ground_truth_frames: int
    metadata: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """Plain-dict form (JSON-serialisable)."""
        out = asdict(self)
        out["topics"] = [asdict(t) for t in self.topics]
        out["notes"] = list(self.notes)
        return out

    def to_json(self, indent: int | None = 2) -> str:
        """The info as a JSON document."""
        return json.dumps(self.to_dict(), indent=indent)


class McapReplay(ReplaySource):
    """Replay a recording as frames.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.
    start_ns, end_ns : int, optional
        Select the frames with ``start_ns <= timestamp_ns < end_ns`` (absolute
        log times). ``len()``, ``frames()`` and ``frame()`` index this selection.

    Notes
    -----
    ``Frame.seq`` is the source's sequence number kept by our recorder (the
    colour message's MCAP ``sequence``, so a live source's dropped frames show
    as gaps) in recordings written by fusion-pf, and the frame's index in the
    whole file for other writers; the first ``background_frames`` frames of
    the file have ``background=True``.
    """

    def __init__(self, path: str | Path, *, start_ns: int | None = None, end_ns: int | None = None) -> None:
        super().__init__()
        self.path = Path(path)
        self._window = (
            None if start_ns is None else fmt.check_timestamp(start_ns, "start_ns"),
            None if end_ns is None else fmt.check_timestamp(end_ns, "end_ns"),
        )
        if None not in self._window and self._window[0] > self._window[1]:  # type: ignore[operator]
            raise InputError(f"start_ns ({start_ns}) must not be after end_ns ({end_ns})")
        self._fd: int | None = None
        self._lock = threading.Lock()
        self._reset()

    def _reset(self) -> None:
        self._size = 0
        self._indexed = False
        self._truncated = False
        self._library = self._profile = ""
        self._channels: dict[int, _Channel] = {}
        self._kind: dict[int, str] = {}
        self._blocks: list[_Block] = []
        self._block_start = np.zeros(0, np.int64)
        self._block_end = np.zeros(0, np.int64)
        self._times: dict[int, np.ndarray] = {}
        self._counts: dict[int, int] = {}
        self._metadata: dict[str, str] = {}
        self._notes: list[str] = []
        self._all = np.zeros(0, np.int64)
        self._cal_times = np.zeros(0, np.int64)
        self._cal_cache: dict[int, Intrinsics] = {}
        self._block_cache: OrderedDict[int, list[tuple[int, int, memoryview, int]]] = OrderedDict()
        self._sel = (0, 0)
        self._background = 0
        self._own_sequences = False
        self._formats: tuple[str | None, str | None] = (None, None)
        self._corrupt: set[int] = set()

    # ------------------------------------------------------------------ lifecycle

    def describe(self) -> str:
        """``"MCAP <name>"``, with the frame count once open."""
        if self._fd is None:
            return f"MCAP {self.path.name}"
        return f"MCAP {self.path.name} ({len(self)} frames)"

    def open(self) -> None:
        """Open the file, read (or rebuild) its index and check it follows the convention.

        Raises
        ------
        RecordingError
            When the file is missing, empty, not MCAP, has no ``/camera/color``
            frames or no calibration (listing the topics present), or its first
            frame is inconsistent (e.g. depth not the size of colour).
        """
        self.close()
        if not self.path.exists():
            raise RecordingError(f"recording not found: {self.path}")
        if self.path.is_dir():
            raise RecordingError(f"{self.path} is a directory; expected an .mcap file")
        self.stats = SourceStats()
        self._fd = os.open(self.path, os.O_RDONLY)
        try:
            self._open()
        except BaseException:
            self.close()
            raise
        self.stats.notes[:0] = self._notes

    def close(self) -> None:
        """Close the file; safe to call twice."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)
        self._reset()

    def _require_open(self) -> None:
        if self._fd is None:
            raise RuntimeError(f"{type(self).__name__} must be used inside a 'with' block")

    def _pread(self, offset: int, length: int) -> bytes:
        if self._fd is None:
            raise RuntimeError(f"{type(self).__name__} is closed")
        data = os.pread(self._fd, length, offset)
        if len(data) != length:
            raise _Corrupt(f"the file ends at byte {offset + len(data)}, inside a record ending at {offset + length}")
        return data

    # ------------------------------------------------------------------ index

    def _open(self) -> None:
        self._size = size = os.fstat(self._fd).st_size  # type: ignore[arg-type]
        if size == 0:
            raise RecordingError(f"{self.path} is empty (0 bytes); expected an MCAP recording")
        head = os.pread(self._fd, 8, 0)  # type: ignore[arg-type]
        if head != MAGIC:
            if MAGIC.startswith(head):
                raise RecordingError(f"{self.path} is truncated to {size} bytes, before the end of the MCAP magic")
            raise RecordingError(
                f"{self.path} is not an MCAP file: it starts with {head!r}, expected the MCAP magic {MAGIC!r}"
            )
        reason = self._read_summary()
        if reason is not None:
            self._scan(reason)
        self._finish_index()

    def _read_summary(self) -> str | None:
        """Load the index from the summary; return why the file must be scanned instead, or None."""
        size = self._size
        if size < 8 + _FOOTER_LEN + 8 or os.pread(self._fd, 8, size - 8) != MAGIC:  # type: ignore[arg-type]
            return "no footer"
        from mcap.reader import SeekingReader

        try:
            with open(self.path, "rb") as fh:
                reader = SeekingReader(fh)
                header = reader.get_header()
                summary = reader.get_summary()
        except Exception as exc:  # the mcap reader raises assorted errors on damaged summaries
            return f"unreadable summary ({type(exc).__name__}: {exc})"
        self._library, self._profile = header.library, header.profile
        if summary is None or not summary.chunk_indexes:
            return "no chunk index"
        for ci in summary.chunk_indexes:
            if not ci.message_index_offsets:
                return "no message index"
            if any(cid not in summary.channels for cid in ci.message_index_offsets):
                return "channels missing from the summary"
        for ch in summary.channels.values():
            schema = summary.schemas.get(ch.schema_id)
            self._add_channel(
                _Channel(ch.id, ch.topic, ch.message_encoding, schema.name if schema else "", schema.encoding if schema else "")
            )
        times: dict[int, list[np.ndarray]] = {}
        try:
            for ci in summary.chunk_indexes:
                self._blocks.append(
                    _Block(ci.chunk_start_offset, ci.chunk_length, True, ci.message_start_time,
                           ci.message_end_time, frozenset(ci.message_index_offsets))
                )
                start = min(ci.message_index_offsets.values())
                buf = memoryview(self._pread(start, ci.message_index_length))
                for opcode, body in _records(buf, "message index"):
                    if opcode != _OP_MESSAGE_INDEX:
                        continue
                    cur = _Cursor(body, "message index")
                    cid = cur.uint(2)
                    pairs = cur.take(cur.uint(4))
                    times.setdefault(cid, []).append(np.frombuffer(pairs, "<u8")[0::2].astype(np.int64))
            for mi in summary.metadata_indexes:
                self._add_metadata(self._pread(mi.offset, mi.length)[9:])
        except _Corrupt as exc:
            return f"damaged index ({exc})"
        self._times = {cid: np.sort(np.concatenate(parts)) for cid, parts in times.items()}
        if summary.statistics is not None:
            self._counts = dict(summary.statistics.channel_message_counts)
        else:
            self._counts = {cid: len(t) for cid, t in self._times.items()}
        self._indexed = True
        return None

    def _add_channel(self, channel: _Channel) -> None:
        self._channels[channel.id] = channel
        kind = _KINDS.get(channel.topic)
        if kind is not None:
            self._kind[channel.id] = kind

    def _add_metadata(self, body: bytes | memoryview) -> None:
        cur = _Cursor(body, "metadata")
        if cur.string() == fmt.RECORDING_METADATA:
            self._metadata.update(cur.mapping())

    def _scan(self, reason: str) -> None:
        """Rebuild the index with one linear pass over the complete records."""
        size = self._size
        self._reset()
        self._size = size
        schemas: dict[int, tuple[str, str]] = {}
        pending: dict[int, tuple[int, int, str, str]] = {}
        times: dict[int, list[int]] = {}
        pos, end_seen, stop = 8, False, ""

        def channel(cur: _Cursor) -> None:
            cid, sid = cur.uint(2), cur.uint(2)
            topic, encoding = cur.string(), cur.string()
            pending[cid] = (cid, sid, topic, encoding)

        def schema(cur: _Cursor) -> None:
            sid = cur.uint(2)
            schemas[sid] = (cur.string(), cur.string())

        while True:
            if pos + 9 > size:
                if pos < size:
                    stop = f"the file ends at byte {size} inside a record header at byte {pos}"
                break
            opcode, length = _RECORD_HEADER.unpack(os.pread(self._fd, 9, pos))  # type: ignore[arg-type]
            end = pos + 9 + length
            if opcode == 0 or end > size:
                stop = f"the file ends at byte {size} inside a record (opcode 0x{opcode:02x}) starting at byte {pos}"
                break
            if opcode in (_OP_DATA_END, _OP_FOOTER):
                end_seen = True
                break
            body = memoryview(os.pread(self._fd, length, pos + 9))  # type: ignore[arg-type]
            try:
                if opcode == _OP_HEADER:
                    cur = _Cursor(body, "header")
                    self._profile, self._library = cur.string(), cur.string()
                elif opcode == _OP_SCHEMA:
                    schema(_Cursor(body, "schema"))
                elif opcode == _OP_CHANNEL:
                    channel(_Cursor(body, "channel"))
                elif opcode == _OP_METADATA:
                    self._add_metadata(body)
                elif opcode == _OP_MESSAGE:
                    cid, _seq, log_time, _pub = _MESSAGE_HEADER.unpack_from(body)
                    times.setdefault(cid, []).append(log_time)
                    self._blocks.append(_Block(pos, 9 + length, False, log_time, log_time, frozenset((cid,))))
                elif opcode == _OP_CHUNK:
                    seen: set[int] = set()
                    lo, hi = None, None
                    for op, rec in _records(_decompress_chunk(body), "chunk"):
                        if op == _OP_SCHEMA:
                            schema(_Cursor(rec, "schema"))
                        elif op == _OP_CHANNEL:
                            channel(_Cursor(rec, "channel"))
                        elif op == _OP_MESSAGE:
                            cid, _seq, log_time, _pub = _MESSAGE_HEADER.unpack_from(rec)
                            times.setdefault(cid, []).append(log_time)
                            seen.add(cid)
                            lo = log_time if lo is None else min(lo, log_time)
                            hi = log_time if hi is None else max(hi, log_time)
                    if lo is not None:
                        self._blocks.append(_Block(pos, 9 + length, True, lo, hi, frozenset(seen)))
            except (_Corrupt, struct.error) as exc:
                self._notes.append(f"skipped a corrupt record (opcode 0x{opcode:02x}) at byte {pos}: {exc}")
            pos = end
        for cid, sid, topic, encoding in pending.values():
            name, schema_encoding = schemas.get(sid, ("", ""))
            self._add_channel(_Channel(cid, topic, encoding, name, schema_encoding))
        self._times = {cid: np.sort(np.asarray(t, np.int64)) for cid, t in times.items()}
        self._counts = {cid: len(t) for cid, t in times.items()}
        self._truncated = not end_seen or reason == "no footer"
        if self._truncated:
            if end_seen:
                stop = f"the data section is complete but the file ends at byte {size} without a valid footer"
            where = stop or f"the file ends at byte {size} without a footer"
            self._notes.insert(0, f"file truncated (the writer did not finish it): {where}; replaying every complete message")
        else:
            self._notes.insert(0, f"file has no usable index ({reason}); scanned it")

    def _topic_times(self, kind: str) -> np.ndarray:
        parts = [self._times[cid] for cid, k in self._kind.items() if k == kind and cid in self._times]
        return np.unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)

    def _topics_present(self) -> str:
        topics = sorted({c.topic for c in self._channels.values()})
        listed = ", ".join(topics) if topics else "none"
        extra = " (the file is truncated)" if self._truncated else ""
        if any(c.message_encoding == "cdr" for c in self._channels.values()):
            extra += " (a ROS 2 bag: convert it with fusion-pf import)"
        return f"topics present: {listed}{extra}"

    def _finish_index(self) -> None:
        self._blocks.sort(key=lambda b: (b.start_ns, b.offset))
        self._block_start = np.array([b.start_ns for b in self._blocks], np.int64)
        self._block_end = np.array([b.end_ns for b in self._blocks], np.int64)
        kinds = set(self._kind.values())
        for kind, topic in (("color", fmt.COLOR_TOPIC), ("calibration", fmt.CALIBRATION_TOPIC)):
            if kind not in kinds:
                raise RecordingError(f"{self.path} has no {topic} topic, which is required; {self._topics_present()}")
        for cid, kind in self._kind.items():
            ch = self._channels[cid]
            if kind in _PROTO_SCHEMAS:
                ok = ch.message_encoding == "protobuf" and ch.schema_name in _PROTO_SCHEMAS[kind]
                expected = " or ".join(_PROTO_SCHEMAS[kind])
                enc = "protobuf"
            else:
                ok = ch.message_encoding == "json"
                expected, enc = "a JSON schema", "json"
            if not ok:
                raise RecordingError(
                    f"{self.path}: {ch.topic} carries {ch.message_encoding or 'unencoded'} {ch.schema_name or '(no schema)'} "
                    f"messages; expected {enc} {expected}"
                )
        self._all = self._topic_times("color")
        if len(self._all) == 0:
            raise RecordingError(f"{self.path} has no {fmt.COLOR_TOPIC} messages (no frames); {self._topics_present()}")
        self._cal_times = self._topic_times("calibration")
        if len(self._cal_times) == 0:
            raise RecordingError(
                f"{self.path} has no {fmt.CALIBRATION_TOPIC} message, which is required; {self._topics_present()}"
            )
        n_color = sum(self._counts.get(cid, 0) for cid, k in self._kind.items() if k == "color")
        if n_color > len(self._all):
            self._notes.append(f"{n_color - len(self._all)} {fmt.COLOR_TOPIC} messages share a timestamp; kept one each")
        if self._cal_times[0] > self._all[0]:
            before = int(np.searchsorted(self._all, self._cal_times[0]))
            self._notes.append(f"{before} frames precede the first calibration; they use the first calibration")
        text = self._metadata.get(fmt.BACKGROUND_FRAMES_KEY, "0")
        if not text.isdigit():
            raise RecordingError(
                f"{self.path}: metadata {fmt.RECORDING_METADATA} {fmt.BACKGROUND_FRAMES_KEY} must be a "
                f"non-negative integer, got {text!r}"
            )
        self._background = min(int(text), len(self._all))
        self._own_sequences = self._metadata.get("writer", "").startswith("fusion-pf")
        start_ns, end_ns = self._window
        lo = 0 if start_ns is None else int(np.searchsorted(self._all, start_ns, "left"))
        hi = len(self._all) if end_ns is None else int(np.searchsorted(self._all, end_ns, "left"))
        self._sel = (lo, max(lo, hi))
        self._probe()

    def _probe(self) -> None:
        """Decode the first frame to check sizes and learn the formats."""
        try:
            parts = self._parts_at(int(self._all[0]))
            self._build(0, int(self._all[0]), parts)
        except _Corrupt:
            return  # noted by _corrupt_block; replay skips the block
        self._formats = tuple(  # type: ignore[assignment]
            self._format_of(*parts[kind][:2]) if kind in parts else None for kind in ("color", "depth")
        )

    def _format_of(self, cid: int, data: memoryview) -> str:
        if self._channels[cid].schema_name == fmt.COMPRESSED_IMAGE:
            return CompressedImage.FromString(data).format.lower()
        return RawImage.FromString(data).encoding

    # ------------------------------------------------------------------ reading

    def _block_records(self, block: _Block) -> list[tuple[int, int, memoryview, int]]:
        """``(channel_id, log_time, data, sequence)`` of the messages of a block (cached, CRC-checked)."""
        with self._lock:
            cached = self._block_cache.get(block.offset)
            if cached is not None:
                self._block_cache.move_to_end(block.offset)
                return cached
        body = memoryview(self._pread(block.offset, block.length))[9:]
        out: list[tuple[int, int, memoryview, int]] = []
        try:
            if block.is_chunk:
                for opcode, rec in _records(_decompress_chunk(body), "chunk"):
                    if opcode == _OP_MESSAGE:
                        cid, seq, log_time, _pub = _MESSAGE_HEADER.unpack_from(rec)
                        out.append((cid, log_time, rec[_MESSAGE_HEADER.size :], seq))
            else:
                cid, seq, log_time, _pub = _MESSAGE_HEADER.unpack_from(body)
                out.append((cid, log_time, body[_MESSAGE_HEADER.size :], seq))
        except struct.error as exc:
            raise _Corrupt(f"message record too short ({exc})") from None
        with self._lock:
            self._block_cache[block.offset] = out
            while len(self._block_cache) > _BLOCK_CACHE:
                self._block_cache.popitem(last=False)
        return out

    def _blocks_between(self, lo: int, hi: int, kinds: tuple[str, ...]) -> list[_Block]:
        """Blocks (in start order) that may hold messages of ``kinds`` timed in ``[lo, hi]``."""
        cids = {cid for cid, k in self._kind.items() if k in kinds}
        hits = np.flatnonzero((self._block_end >= lo) & (self._block_start <= hi))
        return [b for b in (self._blocks[i] for i in hits) if b.channels & cids]

    def _corrupt_block(self, block: _Block, exc: _Corrupt) -> _Corrupt:
        """Note (once per block) that ``block`` is corrupt; return the error to raise."""
        kind = "chunk" if block.is_chunk else "message"
        text = f"{self.path.name}: {kind} at byte {block.offset} is corrupt: {exc}"
        with self._lock:
            if block.offset not in self._corrupt:
                self._corrupt.add(block.offset)
                self.stats.notes.append(text + "; skipped it")
        return _Corrupt(text)

    def _parts_at(self, t: int) -> dict[str, tuple[int, memoryview, int]]:
        parts: dict[str, tuple[int, memoryview, int]] = {}
        for block in self._blocks_between(t, t, ("color", "depth", "skeleton", "truth", "hands")):
            try:
                records = self._block_records(block)
            except _Corrupt as exc:
                raise self._corrupt_block(block, exc) from None
            for cid, log_time, data, seq in records:
                kind = self._kind.get(cid)
                if log_time == t and kind is not None and kind != "calibration":
                    _put(parts, kind, (cid, data, seq))
        return parts

    def _calibration_at(self, t: int) -> Intrinsics:
        k = max(int(np.searchsorted(self._cal_times, t, "right")) - 1, 0)
        c = int(self._cal_times[k])
        with self._lock:
            cached = self._cal_cache.get(c)
        if cached is not None:
            return cached
        for block in self._blocks_between(c, c, ("calibration",)):
            try:
                records = self._block_records(block)
            except _Corrupt as exc:
                raise self._corrupt_block(block, exc) from None
            for cid, log_time, data, _seq in records:
                if log_time == c and self._kind.get(cid) == "calibration":
                    intrinsics = fmt.decode_calibration(data, f"{fmt.CALIBRATION_TOPIC} at t={c} ns")
                    with self._lock:
                        if len(self._cal_cache) >= _CALIBRATION_CACHE:
                            self._cal_cache.clear()
                        self._cal_cache[c] = intrinsics
                    return intrinsics
        raise _Corrupt(f"the {fmt.CALIBRATION_TOPIC} message at t={c} ns cannot be found")

    def _build(self, index: int, t: int, parts: dict[str, tuple[int, memoryview, int]]) -> Frame:
        """Decode the parts of the frame with file index ``index`` at time ``t``."""
        where = f"frame {index} (t={t} ns)"
        if "color" not in parts:
            raise _Corrupt(f"{where} has no {fmt.COLOR_TOPIC} message")
        cid, data, seq = parts["color"]
        color = fmt.decode_color(self._channels[cid].schema_name, data, f"{fmt.COLOR_TOPIC} of {where}")
        depth = None
        if "depth" in parts:
            cid, data, _seq = parts["depth"]
            depth = fmt.decode_depth(self._channels[cid].schema_name, data, f"{fmt.DEPTH_TOPIC} of {where}")
        joints = None
        if "skeleton" in parts:
            w = f"{fmt.SKELETON_TOPIC} of {where}"
            joints = fmt.decode_skeleton(fmt.decode_json(parts["skeleton"][1], w), w)
        truth = None
        truths: dict[str, PalmPoint] = {}
        w = f"{fmt.GROUND_TRUTH_TOPIC} of {where}"
        for _cid, data, _seq in parts.get("truth", ()):
            target, point = fmt.decode_truth(fmt.decode_json(data, w), w)
            if target is None:
                truth = point
            else:
                truths[target] = point
        hands = None
        if "hands" in parts:
            w = f"{fmt.HAND_TOPIC} of {where}"
            hands = fmt.decode_hands(fmt.decode_json(parts["hands"][1], w), w)
        intrinsics = self._calibration_at(t)
        h, w = color.shape[:2]
        if depth is not None and depth.shape != (h, w):
            raise RecordingError(
                f"{self.path}: {fmt.DEPTH_TOPIC} is {depth.shape[1]}x{depth.shape[0]} but {fmt.COLOR_TOPIC} is "
                f"{w}x{h} in {where}; depth must be aligned to colour (same size)"
            )
        if (intrinsics.width, intrinsics.height) != (w, h):
            raise RecordingError(
                f"{self.path}: {fmt.CALIBRATION_TOPIC} is for {intrinsics.width}x{intrinsics.height} images but "
                f"{fmt.COLOR_TOPIC} is {w}x{h} in {where}"
            )
        seq = seq if self._own_sequences else index
        return Frame(t, seq, color, depth, intrinsics, joints, truth, background=index < self._background,
                     ground_truths=truths or None, hands=hands)

    # ------------------------------------------------------------------ public API

    def __len__(self) -> int:
        """Number of selected frames."""
        self._require_open()
        return self._sel[1] - self._sel[0]

    @property
    def timestamps(self) -> np.ndarray:
        """Capture times of the selected frames, shape ``(len(self),)``, int64 ns, read-only."""
        self._require_open()
        out = self._all[self._sel[0] : self._sel[1]]
        out.flags.writeable = False
        return out

    def index_at(self, timestamp_ns: int) -> int:
        """Index (in the selection) of the first frame at or after ``timestamp_ns``; ``len(self)`` if none."""
        self._require_open()
        t = fmt.check_timestamp(timestamp_ns)
        a, b = self._sel
        return int(np.clip(np.searchsorted(self._all, t, "left"), a, b)) - a

    def metadata(self) -> dict[str, str]:
        """The recording's ``fusion_pf.recording`` metadata (later records override earlier keys)."""
        self._require_open()
        return dict(self._metadata)

    def _check_index(self, value: object, name: str) -> int:
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
            raise InputError(f"{name} must be a non-negative int frame index, got {value!r}")
        return int(value)

    def frame(self, index: int) -> Frame:
        """The frame at ``index`` in the selection (random access through the index).

        Raises
        ------
        InputError
            When ``index`` is not in ``[0, len(self))``.
        RecordingError
            When the chunk holding the frame is corrupt.
        """
        self._require_open()
        i = self._check_index(index, "frame index")
        if i >= len(self):
            raise InputError(f"frame index {i} is out of range; the recording has {len(self)} frames")
        absolute = self._sel[0] + i
        t = int(self._all[absolute])
        try:
            return self._build(absolute, t, self._parts_at(t))
        except _Corrupt as exc:
            raise RecordingError(f"frame {i} (t={t} ns) cannot be read: {exc}") from None

    def frames(
        self,
        start: int = 0,
        stop: int | None = None,
        *,
        start_ns: int | None = None,
        end_ns: int | None = None,
    ) -> Iterator[Frame]:
        """Yield the selected frames with index in ``[start, stop)`` and time in ``[start_ns, end_ns)``.

        Frames whose colour message sits in a corrupt chunk are skipped and
        counted in ``stats.dropped``, with a note.
        """
        self._require_open()
        start = self._check_index(start, "start")
        stop = None if stop is None else self._check_index(stop, "stop")
        a, b = self._sel
        lo, hi = a + start, b if stop is None else min(b, a + stop)
        if start_ns is not None:
            lo = max(lo, int(np.searchsorted(self._all, fmt.check_timestamp(start_ns, "start_ns"), "left")))
        if end_ns is not None:
            hi = min(hi, int(np.searchsorted(self._all, fmt.check_timestamp(end_ns, "end_ns"), "left")))
        if lo >= hi:
            return
        yield from self._stream(lo, hi)

    def _stream(self, lo: int, hi: int) -> Iterator[Frame]:
        times = self._all[lo:hi]
        n = len(times)

        def wanted(log_time: int) -> bool:
            i = int(np.searchsorted(times, log_time))
            return i < n and times[i] == log_time

        blocks = self._blocks_between(int(times[0]), int(times[-1]), ("color", "depth", "skeleton", "truth", "hands"))
        pending: dict[int, dict[str, tuple[int, memoryview, int]]] = {}
        next_block = 0
        for k in range(n):
            t = int(times[k])
            while next_block < len(blocks) and blocks[next_block].start_ns <= t:
                block = blocks[next_block]
                next_block += 1
                try:
                    records = self._block_records(block)
                except _Corrupt as exc:
                    self._corrupt_block(block, exc)
                    continue
                for cid, log_time, data, seq in records:
                    kind = self._kind.get(cid)
                    if kind is not None and kind != "calibration" and wanted(log_time):
                        _put(pending.setdefault(log_time, {}), kind, (cid, data, seq))
            parts = pending.pop(t, {})
            if "color" not in parts:
                self.stats.dropped += 1
                continue
            try:
                yield self._build(lo + k, t, parts)
            except _Corrupt as exc:
                raise RecordingError(f"frame {lo + k - self._sel[0]} (t={t} ns) cannot be read: {exc}") from None

    def info(self) -> RecordingInfo:
        """Describe the whole recording (topics, counts, timing, calibration, truncation)."""
        self._require_open()
        by_topic: dict[str, list[_Channel]] = {}
        for ch in self._channels.values():
            by_topic.setdefault(ch.topic, []).append(ch)
        topics = tuple(
            TopicInfo(
                topic,
                " | ".join(sorted({c.schema_name for c in chans})),
                " | ".join(sorted({c.schema_encoding for c in chans})),
                " | ".join(sorted({c.message_encoding for c in chans})),
                sum(self._counts.get(c.id, 0) for c in chans),
            )
            for topic, chans in sorted(by_topic.items())
        )
        n = len(self._all)
        start, end = int(self._all[0]), int(self._all[-1])
        duration = end - start
        try:
            cal = self._calibration_at(start)
            intrinsics = {
                "fx": cal.fx, "fy": cal.fy, "cx": cal.cx, "cy": cal.cy,
                "distortion_model": cal.distortion_model, "distortion": list(cal.distortion),
            }
            width, height = cal.width, cal.height
        except _Corrupt as exc:
            raise RecordingError(f"{self.path}: the first calibration cannot be read: {exc}") from None

        def missing(kind: str) -> int:
            return int(n - np.count_nonzero(np.isin(self._all, self._topic_times(kind))))

        return RecordingInfo(
            path=str(self.path), size_bytes=self._size, library=self._library, profile=self._profile,
            indexed=self._indexed, truncated=self._truncated, topics=topics, frames=n,
            start_ns=start, end_ns=end, duration_ns=duration,
            fps=(n - 1) / (duration / 1e9) if n > 1 and duration > 0 else None,
            width=width, height=height, intrinsics=intrinsics,
            calibration_messages=len(self._cal_times),
            color_format=self._formats[0], depth_format=self._formats[1],
            background_frames=self._background,
            missing_depth=missing("depth"), missing_skeleton=missing("skeleton"),
            ground_truth_frames=n - missing("truth"),
            metadata=dict(self._metadata), notes=tuple(self._notes + [
                note for note in self.stats.notes if note not in self._notes
            ]),
        )
