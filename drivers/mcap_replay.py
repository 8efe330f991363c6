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

Damage
------
Every frame that cannot be read is accounted for in ``stats.losses``
(:class:`~drivers.base.FrameLoss`: how many, where, why) and ``stats.dropped``;
``stats.loss_summary()`` says it in one line. A scan that meets a damaged
record (bad length, CRC, removed or duplicated bytes) searches forward for the
next plausible record instead of stopping, and estimates the frames lost in
the gap from the frame period. A malformed optional part (depth, skeleton,
ground truth) is left out of its frame and counted in ``stats.skipped_parts``.
The calibration is also read from the ``fusion_pf.calibration`` metadata and
from its copy at the start of every chunk, so a damaged chunk costs only its
own frames.
"""

from __future__ import annotations

import json
import os
import stat
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
from .base import FrameLoss, ReplaySource, SourceStats

MAGIC = b"\x89MCAP0\r\n"

_OP_HEADER, _OP_FOOTER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x01, 0x02, 0x03, 0x04, 0x05
_OP_CHUNK, _OP_MESSAGE_INDEX, _OP_ATTACHMENT, _OP_METADATA, _OP_DATA_END = 0x06, 0x07, 0x09, 0x0C, 0x0F
#: Records that may follow damage in the data section (where a scan may resynchronise).
_RESYNC_OPCODES = (_OP_SCHEMA, _OP_CHANNEL, _OP_CHUNK, _OP_MESSAGE_INDEX, _OP_METADATA, _OP_DATA_END, _OP_FOOTER)
_OP_STATISTICS = 0x0B
#: Summary-section records (chunk index ... summary offset): skipped by length when met in a scan.
_SUMMARY_OPCODES = (0x08, 0x0A, 0x0B, 0x0D, 0x0E)
#: Largest record or decompressed chunk accepted (as the mcap readers' record_size_limit).
_MAX_RECORD = 4 << 30
#: Bytes searched per read while resynchronising.
_RESYNC_WINDOW = 1 << 20
_TIME_LIMIT = 1 << 63
_FOOTER_LEN = 9 + 20
#: How a scan's reason starts when the summary failed its CRC (its schemas and channels then yield to the data section's).
_DAMAGED_SUMMARY = "damaged summary"
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


def _file_kind(mode: int) -> str:
    """What a file of ``st_mode`` ``mode`` that is not a regular file is: ``"a FIFO"``, ``"a character device"``, ..."""
    kinds = ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"))
    return next((name for test, name in kinds if test(mode)), "a socket" if stat.S_ISSOCK(mode) else "not a file")


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
    if size > _MAX_RECORD:
        raise _Corrupt(f"chunk claims {size} uncompressed bytes (more than {_MAX_RECORD})")
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


def _message_header(rec: memoryview | bytes) -> tuple[int, int, int]:
    """``(channel_id, sequence, log_time)`` of a message record body."""
    try:
        cid, seq, log_time, _pub = _MESSAGE_HEADER.unpack_from(rec)
    except struct.error as exc:
        raise _Corrupt(f"message record too short ({exc})") from None
    if log_time >= _TIME_LIMIT:
        raise _Corrupt(f"message log time {log_time} ns is beyond 2**63")
    return cid, seq, log_time


def _structure_ok(opcode: int, length: int, body: bytes, strict: bool = True) -> bool:
    """Whether the first bytes ``body`` of a record are consistent with its opcode and ``length``.

    Used to find the next record after damage; ``body`` holds at least the
    first 64 bytes of the record body (fewer when the record is shorter).
    Without ``strict`` (a record where one is expected) a chunk's message
    times are not checked, so parsing it can say what is wrong with them.
    """

    def u(at: int, n: int) -> int | None:
        return int.from_bytes(body[at : at + n], "little") if at + n <= len(body) else None

    if opcode == _OP_CHUNK:
        clen = u(28, 4)
        if clen is None or clen > 4:
            return False
        comp = body[32 : 32 + clen]
        rlen = u(32 + clen, 8)
        start, end = u(0, 8), u(8, 8)
        times_ok = start is not None and end is not None and (not strict or start <= end < _TIME_LIMIT)
        return comp in (b"", b"zstd", b"lz4") and rlen is not None and 40 + clen + rlen == length and times_ok
    if opcode == _OP_MESSAGE_INDEX:
        n = u(2, 4)
        return n is not None and n % 16 == 0 and 6 + n == length
    if opcode == _OP_DATA_END:
        return length == 4
    if opcode == _OP_FOOTER:
        return length == 20
    if opcode == _OP_METADATA:
        n = u(0, 4)
        if n is None or n > 256 or 4 + n + 4 > length:
            return False
        m = u(4 + n, 4)
        return m is not None and 4 + n + 4 + m == length
    if opcode == _OP_SCHEMA:
        n = u(2, 4)
        if n is None or n > 256:
            return False
        e = u(6 + n, 4)
        if e is None or e > 64:
            return False
        d = u(10 + n + e, 4)
        return d is not None and 14 + n + e + d == length
    if opcode == _OP_CHANNEL:
        n = u(4, 4)
        if n is None or n > 256:
            return False
        e = u(8 + n, 4)
        if e is None or e > 64:
            return False
        m = u(12 + n + e, 4)
        return m is not None and 16 + n + e + m == length
    return False


class _Damage(NamedTuple):
    """A damaged stretch of a scanned file."""

    offset: int
    reason: str
    before_ns: int | None  # latest colour time read before it (file order)
    hint: tuple[int, int] | None  # message start/end time from a chunk header that still parses


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
    trailing_bytes : int
        Bytes after the end of a complete MCAP file (after its footer and
        closing magic), ignored; 0 for a file that ends where MCAP ends.
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
    trailing_bytes: int = 0

    def to_dict(self) -> dict[str, Any]:
        """Plain-dict form (JSON-serialisable)."""
        out = asdict(self)
        out["topics"] = [asdict(t) for t in self.topics]
        out["notes"] = list(self.notes)
        return out

    def to_json(self, indent: int | None = 2) -> str:
        """The info as a JSON document."""
        return json.dumps(self.to_dict(), indent=indent)


@dataclass(frozen=True)
class TopicsInfo:
    """What :meth:`McapTopics.topics_info` reports: a file described by its topics, e.g. a tracker output.

    Attributes
    ----------
    path, size_bytes, library, profile, indexed, truncated, trailing_bytes, topics, metadata, notes
        As in :class:`RecordingInfo`.
    frames : int
        ``/tracker/estimate`` messages at distinct times (the tracked frames).
    start_ns, end_ns : int or None
        Time of the first and last of them.
    """

    path: str
    size_bytes: int
    library: str
    profile: str
    indexed: bool
    truncated: bool
    trailing_bytes: int
    topics: tuple[TopicInfo, ...]
    frames: int
    start_ns: int | None
    end_ns: int | None
    metadata: dict[str, str] = field(default_factory=dict)
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """Plain-dict form (JSON-serialisable)."""
        out = asdict(self)
        out["topics"] = [asdict(t) for t in self.topics]
        out["notes"] = list(self.notes)
        return out


class McapReplay(ReplaySource):
    """Replay a recording as frames.

    Parameters
    ----------
    path : str or Path
        The ``.mcap`` file.
    start_ns, end_ns : int, optional
        Select the frames with ``start_ns <= timestamp_ns < end_ns`` (absolute
        log times). ``len()``, ``frames()`` and ``frame()`` index this selection.
    camera : str, optional
        In a multi-camera recording, the camera to replay: its topics carry the
        prefix ``/<camera>`` (``/cam_left/camera/color``) and its calibration
        metadata records the key ``camera`` (:mod:`drivers.rig` reads all of them).

    Notes
    -----
    ``Frame.seq`` is the source's sequence number kept by our recorder (the
    colour message's MCAP ``sequence``, so a live source's dropped frames show
    as gaps) in recordings written by fusion-pf, and ``Frame.index`` for other
    writers. ``Frame.index`` is the frame's index in the whole recording,
    frames lost to damage counted (estimated from the frame period in a
    scanned file); the frames whose index is below ``background_frames`` have
    ``background=True``.
    """

    def __init__(
        self, path: str | Path, *, start_ns: int | None = None, end_ns: int | None = None, camera: str | None = None
    ) -> None:
        super().__init__()
        self.path = Path(path)
        self.camera = camera
        self._topic_kind = {fmt.camera_topic(camera, topic): kind for topic, kind in _KINDS.items()}
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
        self._trailing = 0
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
        self._corrupt: dict[int, str] = {}
        self._cal_meta: dict[int, Intrinsics] = {}
        self._cal_meta_times = np.zeros(0, np.int64)
        self._scan_losses: list[FrameLoss] = []
        #: Per scan loss: the readable frame (index in ``_all``) it precedes, len(_all) after the last, None unknown.
        self._scan_loss_at: list[int | None] = []
        #: Per frame of ``_all``: its index in the recording (frames lost in scanned gaps counted).
        self._source_index = np.zeros(0, np.int64)
        self._unplaced = 0
        self._stat_start: int | None = None
        self._stat_end: int | None = None
        #: Warnings for ``stats.warnings`` found while opening.
        self._warnings: list[str] = []
        self._meta_seen = {"recording": False, "fusion_pf": False}
        self._meta_problems: list[str] = []
        self._lost: dict[int, tuple[str, int | None]] = {}
        self._bad_parts: dict[str, set[int]] = {}
        self._part_times: dict[str, set[int]] = {}
        self._scan_damage: list[_Damage] = []
        self._stop: tuple[int, int | None, tuple[int, int] | None] | None = None
        self._stat_counts: dict[int, int] = {}

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
        fd = os.open(self.path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))  # a FIFO must not block the open
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):  # a FIFO or a device has no size to index and may never end
            os.close(fd)
            raise RecordingError(f"{self.path} is not a regular file ({_file_kind(mode)}); expected an .mcap file")
        self._fd = fd
        try:
            self._open()
        except BaseException:
            self.close()
            raise
        self.stats.notes[:0] = self._notes + self._warnings
        self.stats.warnings[:] = self._warnings
        self._publish()

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
        if offset < 0 or length < 0 or offset + length > self._size:
            raise _Corrupt(f"a record of {length} bytes at byte {offset} does not fit in the {self._size}-byte file")
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
        damaged = self._summary_crc_problem()
        if damaged is not None:
            return f"{_DAMAGED_SUMMARY}: {damaged}"
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
                _Channel(
                    ch.id,
                    ch.topic,
                    ch.message_encoding,
                    schema.name if schema else "",
                    schema.encoding if schema else "",
                )
            )
        times: dict[int, list[np.ndarray]] = {}
        try:
            for ci in summary.chunk_indexes:
                if not ci.message_start_time <= ci.message_end_time < _TIME_LIMIT:
                    raise _Corrupt(f"chunk index times {ci.message_start_time}..{ci.message_end_time} are impossible")
                opcode, length = _RECORD_HEADER.unpack(self._pread(ci.chunk_start_offset, 9))
                if opcode != _OP_CHUNK or 9 + length != ci.chunk_length:
                    raise _Corrupt(f"the chunk index points at byte {ci.chunk_start_offset}, where no such chunk is")
                self._blocks.append(
                    _Block(
                        ci.chunk_start_offset,
                        ci.chunk_length,
                        True,
                        ci.message_start_time,
                        ci.message_end_time,
                        frozenset(ci.message_index_offsets),
                    )
                )
                start = min(ci.message_index_offsets.values())
                buf = memoryview(self._pread(start, ci.message_index_length))
                for opcode, body in _records(buf, "message index"):
                    if opcode != _OP_MESSAGE_INDEX:
                        continue
                    cur = _Cursor(body, "message index")
                    cid = cur.uint(2)
                    pairs = cur.take(cur.uint(4))
                    log_times = np.frombuffer(pairs, "<u8", count=len(pairs) // 8)[0::2]
                    if log_times.size and int(log_times.max()) >= _TIME_LIMIT:
                        raise _Corrupt("a message index holds a log time beyond 2**63")
                    lo, hi = ci.message_start_time, ci.message_end_time
                    if log_times.size and (int(log_times.min()) < lo or int(log_times.max()) > hi):
                        # a damaged time would be taken for a frame of its own and shift the frame numbers
                        raise _Corrupt(
                            f"a message index of the chunk at byte {ci.chunk_start_offset} holds a log time "
                            f"outside the chunk's {lo}..{hi} ns"
                        )
                    times.setdefault(cid, []).append(log_times.astype(np.int64))
        except (_Corrupt, struct.error) as exc:
            return f"damaged index ({exc})"
        for mi in summary.metadata_indexes:
            try:
                self._add_metadata(self._pread(mi.offset, mi.length)[9:])
            except _Corrupt as exc:
                self._notes.append(f"skipped the metadata record at byte {mi.offset}: {exc}")
                if mi.name == fmt.RECORDING_METADATA:
                    self._meta_problems.append(
                        f"the {fmt.RECORDING_METADATA} metadata record at byte {mi.offset} cannot be read ({exc})"
                    )
        self._times = {cid: np.sort(np.concatenate(parts)) for cid, parts in times.items()}
        if summary.statistics is not None:
            self._counts = dict(summary.statistics.channel_message_counts)
        else:
            self._counts = {cid: len(t) for cid, t in self._times.items()}
        self._indexed = True
        return None

    def _summary_crc_problem(self) -> str | None:
        """Why the summary fails its CRC (the footer's ``summary_crc``), or None when it passes or has none.

        The CRC covers the summary section up to the footer's
        ``summary_offset_start`` field; zero means the writer did not compute one.
        """
        footer = self._size - 8 - _FOOTER_LEN
        opcode, length, start, _offsets, crc = struct.unpack("<BQQQI", os.pread(self._fd, _FOOTER_LEN, footer))  # type: ignore[arg-type]
        if opcode != _OP_FOOTER or length != _FOOTER_LEN - 9 or crc == 0 or start == 0:
            return None
        if not 8 <= start <= footer:
            return f"the footer puts the summary at byte {start}, outside the file"
        got = 0
        for at in range(start, footer + _FOOTER_LEN - 4, _RESYNC_WINDOW):
            got = zlib.crc32(os.pread(self._fd, min(_RESYNC_WINDOW, footer + _FOOTER_LEN - 4 - at), at), got)  # type: ignore[arg-type]
        return None if got == crc else f"summary CRC mismatch (expected {crc:#010x}, got {got:#010x})"

    def _add_channel(self, channel: _Channel) -> None:
        self._channels[channel.id] = channel
        kind = self._topic_kind.get(channel.topic)
        if kind is not None:
            self._kind[channel.id] = kind

    def _add_metadata(self, body: bytes | memoryview) -> dict[str, str] | None:
        """Take in a metadata record; return the fields of a ``fusion_pf.channel`` record (else None)."""
        cur = _Cursor(body, "metadata")
        name = cur.string()
        self._meta_seen["fusion_pf"] |= name in (fmt.CHANNEL_METADATA, fmt.CALIBRATION_METADATA)
        if name == fmt.CHANNEL_METADATA:
            return cur.mapping()
        if name == fmt.RECORDING_METADATA:
            self._metadata.update(cur.mapping())
            self._meta_seen["recording"] = True
        elif name == fmt.CALIBRATION_METADATA:
            record = cur.mapping()
            if record.get("camera") != self.camera:
                return None
            try:
                t, intrinsics = fmt.decode_calibration_metadata(record)
            except RecordingError as exc:
                raise _Corrupt(str(exc)) from None
            self._cal_meta[t] = intrinsics
        return None

    def _record_at(self, pos: int, strict: bool = True) -> tuple[int, int] | None:
        """``(opcode, length)`` of a plausible record starting at ``pos``, or None (see :func:`_structure_ok`)."""
        head = os.pread(self._fd, 9 + 64, pos)  # type: ignore[arg-type]
        if len(head) < 9:
            return None
        opcode, length = _RECORD_HEADER.unpack_from(head)
        if length > _MAX_RECORD or pos + 9 + length > self._size:
            return None
        if opcode in _SUMMARY_OPCODES or opcode in (_OP_HEADER, _OP_ATTACHMENT):
            return opcode, length
        if opcode == _OP_MESSAGE:
            if length < _MESSAGE_HEADER.size:
                return None
            return opcode, length
        if _structure_ok(opcode, length, head[9 : 9 + min(length, 64)], strict):
            return opcode, length
        return None

    def _resync(self, start: int) -> int | None:
        """Offset of the next plausible data-section record at or after ``start``, or None."""
        pos = start
        while pos + 9 <= self._size:
            buf = np.frombuffer(os.pread(self._fd, _RESYNC_WINDOW, pos), np.uint8)  # type: ignore[arg-type]
            for k in np.flatnonzero(np.isin(buf, _RESYNC_OPCODES)):
                at = pos + int(k)
                found = self._record_at(at)
                if found is not None and found[0] in _RESYNC_OPCODES:
                    return at
            pos += max(len(buf), 1)
        return None

    def _damaged_metadata(self, opcode: int, pos: int) -> None:
        """Note a damaged record at ``pos`` that still names itself a ``fusion_pf.recording`` metadata record."""
        name = fmt.RECORDING_METADATA.encode()
        head = os.pread(self._fd, 9 + 4 + len(name), pos)  # type: ignore[arg-type]
        if opcode == _OP_METADATA and head[9:] == len(name).to_bytes(4, "little") + name:
            self._meta_problems.append(f"the {fmt.RECORDING_METADATA} metadata record at byte {pos} is damaged")

    @staticmethod
    def _chunk_times(body: memoryview) -> tuple[int, int] | None:
        """Message start/end times from a (possibly corrupt) chunk header, when they are plausible."""
        if len(body) < 16:
            return None
        start, end = struct.unpack_from("<QQ", body)
        return (start, end) if start <= end < _TIME_LIMIT else None

    def _scan(self, reason: str) -> None:
        """Rebuild the index with one linear pass over the records, resynchronising after damage."""
        size = self._size
        self._reset()
        self._size = size
        schemas: dict[int, tuple[str, str]] = {}
        pending: dict[int, tuple[int, int, str, str]] = {}
        times: dict[int, list[int]] = {}
        damage: list[_Damage] = []
        spare: dict[int, dict[str, str]] = {}
        color_ids: set[int] = set()
        last_color: list[int] = []
        pos, end_seen, in_summary, stop, stop_at = 8, False, False, "", size
        metadata_read, metadata_count = 0, 0
        cut_hint: tuple[int, int] | None = None
        distrust_summary = reason.startswith(_DAMAGED_SUMMARY)  # its statistics still count frames: lost ones show

        def channel(cur: _Cursor) -> None:
            cid, sid = cur.uint(2), cur.uint(2)
            topic, encoding = cur.string(), cur.string()
            pending[cid] = (cid, sid, topic, encoding)
            if self._topic_kind.get(topic) == "color":
                color_ids.add(cid)

        def schema(cur: _Cursor) -> None:
            sid = cur.uint(2)
            schemas[sid] = (cur.string(), cur.string())

        def message(cid: int, log_time: int) -> None:
            times.setdefault(cid, []).append(log_time)
            if cid in color_ids:
                last_color.append(log_time)

        while pos + 9 <= size:
            found = self._record_at(pos, strict=False)
            if found is None or (
                in_summary and found[0] not in (_OP_SCHEMA, _OP_CHANNEL, _OP_FOOTER, *_SUMMARY_OPCODES)
            ):
                opcode, length = _RECORD_HEADER.unpack(os.pread(self._fd, 9, pos))  # type: ignore[arg-type]
                self._damaged_metadata(opcode, pos)
                why = (
                    f"a record (opcode 0x{opcode:02x}) of {length} bytes that does not fit"
                    if pos + 9 + length > size
                    else f"an unreadable record (opcode 0x{opcode:02x}, {length} bytes)"
                )
                nxt = self._resync(pos + 1)
                if nxt is None:
                    if not in_summary:
                        stop = f"the file ends at byte {size} after {why} at byte {pos}"
                        stop_at = pos
                        if opcode == _OP_CHUNK:
                            cut_hint = self._chunk_times(memoryview(os.pread(self._fd, 16, pos + 9)))  # type: ignore[arg-type]
                    break
                if not in_summary:
                    damage.append(
                        _Damage(
                            pos,
                            f"{nxt - pos} damaged bytes at byte {pos} ({why})",
                            max(last_color) if last_color else None,
                            None,
                        )
                    )
                pos = nxt
                continue
            opcode, length = found
            end = pos + 9 + length
            if opcode == _OP_FOOTER:
                end_seen = True
                if end + 8 < size and os.pread(self._fd, 8, end) == MAGIC:  # type: ignore[arg-type]
                    self._trailing = size - end - 8
                break
            if opcode == _OP_DATA_END:
                end_seen = in_summary = True
                pos = end
                continue
            if in_summary and distrust_summary and opcode in (_OP_SCHEMA, _OP_CHANNEL) and length >= 2:
                (known,) = struct.unpack("<H", os.pread(self._fd, 2, pos + 9))  # type: ignore[arg-type]
                if known in (schemas if opcode == _OP_SCHEMA else pending):  # the data section's own stands
                    pos = end
                    continue
            body = memoryview(os.pread(self._fd, length, pos + 9))  # type: ignore[arg-type]
            try:
                if opcode == _OP_HEADER:
                    cur = _Cursor(body, "header")
                    self._profile, self._library = cur.string(), cur.string()
                elif opcode == _OP_STATISTICS:
                    cur = _Cursor(body, "statistics")
                    cur.take(8 + 2 + 4 + 4)
                    metadata_count = cur.uint(4)
                    cur.take(4)
                    start_time = cur.uint(8)
                    end_time = cur.uint(8)
                    self._stat_start = start_time if start_time < _TIME_LIMIT else None
                    self._stat_end = end_time if start_time <= end_time < _TIME_LIMIT else None
                    end_map = cur.pos + cur.uint(4)
                    while cur.pos < end_map:
                        cid = cur.uint(2)
                        self._stat_counts[cid] = cur.uint(8)
                elif opcode == _OP_SCHEMA:
                    schema(_Cursor(body, "schema"))
                elif opcode == _OP_CHANNEL:
                    channel(_Cursor(body, "channel"))
                elif opcode == _OP_METADATA and not in_summary:
                    metadata_read += 1
                    fields = self._add_metadata(body)
                    if fields is not None and fields.get("id", "").isdigit():
                        spare[int(fields["id"])] = fields
                        if self._topic_kind.get(fields.get("topic", "")) == "color":
                            color_ids.add(int(fields["id"]))
                elif opcode == _OP_MESSAGE and not in_summary:
                    cid, _seq, t = _message_header(body)
                    message(cid, t)
                    self._blocks.append(_Block(pos, 9 + length, False, t, t, frozenset((cid,))))
                elif opcode == _OP_CHUNK and not in_summary:
                    records = list(_records(_decompress_chunk(body), "chunk"))
                    found_messages = [_message_header(rec) for op, rec in records if op == _OP_MESSAGE]
                    for op, rec in records:  # the whole chunk is sound: take it in
                        if op == _OP_SCHEMA:
                            schema(_Cursor(rec, "schema"))
                        elif op == _OP_CHANNEL:
                            channel(_Cursor(rec, "channel"))
                    for cid, _seq, log_time in found_messages:
                        message(cid, log_time)
                    if found_messages:
                        stamps = [log_time for _cid, _seq, log_time in found_messages]
                        self._blocks.append(
                            _Block(
                                pos,
                                9 + length,
                                True,
                                min(stamps),
                                max(stamps),
                                frozenset(cid for cid, _seq, _t in found_messages),
                            )
                        )
            except (_Corrupt, struct.error) as exc:
                kind = "chunk" if opcode == _OP_CHUNK else f"record (opcode 0x{opcode:02x})"
                self._damaged_metadata(opcode, pos)
                hint = self._chunk_times(body) if opcode == _OP_CHUNK else None
                damage.append(
                    _Damage(
                        pos, f"{kind} at byte {pos} is corrupt ({exc})", max(last_color) if last_color else None, hint
                    )
                )
                nxt = self._resync(pos + 1)
                if nxt is None:
                    break
                if nxt > end:  # the damage goes on past the corrupt record
                    damage.append(
                        _Damage(
                            end,
                            f"{nxt - end} unreadable bytes at byte {end}",
                            max(last_color) if last_color else None,
                            None,
                        )
                    )
                pos = nxt
                continue
            pos = end
        for cid, sid, topic, encoding in pending.values():
            name, schema_encoding = schemas.get(sid, ("", ""))
            self._add_channel(_Channel(cid, topic, encoding, name, schema_encoding))
        for cid, fields in spare.items():  # channels whose own record was in a damaged chunk
            if cid not in self._channels and cid <= 0xFFFF:
                self._add_channel(
                    _Channel(
                        cid,
                        fields.get("topic", ""),
                        fields.get("message_encoding", ""),
                        fields.get("schema_name", ""),
                        fields.get("schema_encoding", ""),
                    )
                )
                self._notes.append(
                    f"channel {cid} ({fields.get('topic', '')}) taken from its {fmt.CHANNEL_METADATA} metadata copy"
                )
        self._times = {cid: np.sort(np.asarray(t, np.int64)) for cid, t in times.items()}
        self._counts = {cid: len(t) for cid, t in times.items()}
        if metadata_count > metadata_read and not self._meta_problems:
            self._meta_problems.append(
                f"the summary counts {metadata_count} metadata records but {metadata_read} were read "
                f"(a {fmt.RECORDING_METADATA} record may be among the lost)"
            )
        self._truncated = not end_seen or (reason == "no footer" and not self._trailing)
        self._scan_damage = damage
        self._stop = (stop_at, max(last_color) if last_color else None, cut_hint) if not end_seen else None
        for d in damage:
            self._notes.append(f"{d.reason}; skipped it")
        if self._truncated:
            if end_seen:
                stop = f"the data section is complete but the file ends at byte {size} without a valid footer"
            where = stop or f"the file ends at byte {size} without a footer"
            self._notes.insert(
                0, f"file truncated (the writer did not finish it): {where}; replaying every complete message"
            )
        elif self._trailing:
            self._notes.insert(
                0,
                f"{self._trailing} bytes follow the end of the MCAP data (its footer and closing magic end at "
                f"byte {size - self._trailing}): they are not part of the recording and were ignored; scanned it",
            )
        else:
            self._notes.insert(0, f"file has no usable index ({reason}); scanned it")

    def _frame_period(self) -> float | None:
        """Typical interval between consecutive frames (ns): the median of the intervals near the shortest.

        Robust to lost frames (long intervals) as long as two consecutive frames were read. When
        no two were (every other frame lost, say) that median is a multiple of the period: the
        summary's span over its colour message count, when read, gives the period then.
        """
        gaps = np.diff(self._all)
        gaps = gaps[gaps > 0]
        if not len(gaps):
            return None
        observed = float(np.median(gaps[gaps <= 1.5 * gaps.min()]))
        count = sum(self._stat_counts.get(cid, 0) for cid, kind in self._kind.items() if kind == "color")
        if count >= 2 and self._stat_start is not None and self._stat_end is not None:
            span = (self._stat_end - self._stat_start) / (count - 1)
            ratio = observed / span if span > 0 else 0.0
            if ratio >= 1.5 and abs(ratio - round(ratio)) < 0.1:
                return span
        return observed

    def _estimate_scan_losses(self) -> None:
        """Turn the damage a scan met into frame losses, counting the frames each gap lacks.

        Damage met between the same two readable frames is one loss: the
        frames missing between them (from the frame period), described by the
        first damaged record and how many more followed.
        """
        damage, stop = self._scan_damage, self._stop
        times = self._all
        period = self._frame_period()

        def frames_in(lo: int, hi: int, inclusive: bool) -> int | None:
            """Frames strictly between ``lo`` and ``hi`` (and the two ends when ``inclusive``)."""
            if period is None:
                return None
            return max(int(round((hi - lo) / period)) + (1 if inclusive else -1), 0)

        # the first frame's time: our recorder's first calibration record, else the summary's first message
        first_ns = min(self._cal_meta) if self._cal_meta else self._stat_start
        groups: list[list[_Damage]] = []
        for d in damage:
            if groups and groups[-1][0].before_ns == d.before_ns:
                groups[-1].append(d)
            else:
                groups.append([d])
        for group in groups:
            before = group[0].before_ns
            k = int(np.searchsorted(times, before, "right")) if before is not None else 0
            after = int(times[k]) if k < len(times) else None
            hints = [d.hint for d in group if d.hint is not None]
            lo = min(h[0] for h in hints) if hints else None
            hi = max(h[1] for h in hints) if hints else None
            n: int | None
            if before is not None and after is not None:
                n = frames_in(before, after, False)
            elif after is not None:  # damage before the first readable frame
                lo = lo if lo is not None else first_ns
                n = None if lo is None or lo > after else frames_in(lo, after, True)
                n = None if n is None else n - 1  # ``after`` itself was read
            elif stop is not None or len(hints) < len(group):
                n = None  # after the last readable frame, with nothing to count to
            else:
                n = frames_in(before, hi, True) - 1 if before is not None and lo <= before else frames_in(lo, hi, True)
            reason = group[0].reason
            if len(group) > 1:
                reason += f", and {len(group) - 1} more damaged record(s) up to byte {group[-1].offset}"
            if n != 0:
                self._scan_losses.append(FrameLoss(n, reason, group[0].offset))
                self._scan_loss_at.append(k)
        self._check_statistics()
        if stop is not None:
            at, last, cut = stop
            if cut is not None and period is not None and (last is None or cut[0] > last):
                n = int(round((cut[1] - cut[0]) / period)) + 1
                self._scan_losses.append(FrameLoss(n, f"the chunk at byte {at} is cut off by the end of the file", at))
                self._scan_loss_at.append(len(times))
            after = f" after t={last} ns" if last is not None else ""
            self._scan_loss_at.append(None)
            self._scan_losses.append(
                FrameLoss(
                    None,
                    f"the file is truncated at byte {self._size}: any later frames recorded{after} are lost",
                    at,
                    tail=True,
                )
            )

    def _check_statistics(self) -> None:
        """Compare the frames read and counted lost with the colour message count of the summary, if read.

        The summary's Statistics record survives damage to the data section:
        frames it counts beyond those read or counted as lost were lost
        without a trace (e.g. a whole chunk removed); they fill an unknown count
        when there is exactly one, or are reported as a loss of their own.
        """
        colour = [cid for cid, kind in self._kind.items() if kind == "color"]
        if not self._stat_counts or not colour or self._stop is not None:
            return
        counted = sum(self._stat_counts.get(cid, 0) for cid in colour)
        known = sum(x.frames or 0 for x in self._scan_losses)
        missing = counted - len(self._all) - known
        unknown = [k for k, x in enumerate(self._scan_losses) if x.frames is None]
        if missing <= 0:
            return
        if len(unknown) == 1:
            x = self._scan_losses[unknown[0]]
            self._scan_losses[unknown[0]] = FrameLoss(missing, x.reason, x.offset, x.tail)
        elif not unknown:
            self._scan_loss_at.append(None)
            self._scan_losses.append(
                FrameLoss(
                    missing,
                    f"the summary counts {counted} {fmt.COLOR_TOPIC} messages, {missing} more than were read "
                    "or found in damaged records",
                )
            )

    def _place_frames(self) -> None:
        """Give every readable frame its index in the recording and decide the background section by it.

        A frame's index counts the frames lost in the scanned gaps before it, so
        the frames after a gap keep their numbers and the background section
        (the first ``background_frames`` of the recording) is not shifted onto
        person frames. After a gap of unknown size the indexes are lower bounds;
        if the background section may extend past such a gap it cannot be
        placed: the frames after the gap are not taken for background, and a
        warning says so. An unreadable ``fusion_pf.recording`` record (the
        number of background frames unknown) is a warning too.
        """
        n = len(self._all)
        shift = np.zeros(n + 1, np.int64)
        unknown_at: int | None = None
        for loss, at in zip(self._scan_losses, self._scan_loss_at, strict=True):
            if at is None:
                continue
            if loss.frames is None:
                unknown_at = at if unknown_at is None else min(unknown_at, at)
            else:
                shift[at] += loss.frames
        self._source_index = np.arange(n, dtype=np.int64) + np.cumsum(shift)[:n]
        k = self._background
        self._unplaced = n
        if (
            unknown_at is not None
            and unknown_at < n
            and (unknown_at == 0 or self._source_index[unknown_at - 1] < k - 1)
        ):
            self._unplaced = unknown_at
            self._warnings.append(
                f"frames were lost in a gap of unknown size before frame {unknown_at} read, so the "
                f"{k} background frames cannot be placed: the frames after the gap are tracked"
            )
        problems = list(self._meta_problems)
        own = self._library.startswith("fusion-pf") or self._meta_seen["fusion_pf"]
        if own and not problems and not self._meta_seen["recording"]:
            problems.append(f"no {fmt.RECORDING_METADATA} metadata record can be read")
        if problems:
            known = (
                f"background_frames={k} from another record may be out of date"
                if self._meta_seen["recording"]
                else "the number of background frames is unknown, so every frame is tracked"
            )
            self._warnings.append(f"{'; '.join(problems)}: {known}")

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
        required = (("color", fmt.camera_topic(self.camera, fmt.COLOR_TOPIC)),) + (
            () if self._cal_meta else (("calibration", fmt.camera_topic(self.camera, fmt.CALIBRATION_TOPIC)),)
        )
        for kind, topic in required:
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
        self._part_times = {kind: set(self._topic_times(kind).tolist()) for kind in ("depth", "skeleton", "truth")}
        if len(self._all) == 0:
            color_topic = fmt.camera_topic(self.camera, fmt.COLOR_TOPIC)
            raise RecordingError(
                f"{self.path} has no {color_topic} messages (no frames), although the topic is declared; "
                f"{self._topics_present()}"
            )
        self._cal_meta_times = np.array(sorted(self._cal_meta), np.int64)
        self._cal_times = np.union1d(self._topic_times("calibration"), self._cal_meta_times)
        if len(self._cal_times) == 0:
            raise RecordingError(
                f"{self.path} has no {fmt.CALIBRATION_TOPIC} message, which is required; {self._topics_present()}"
            )
        n_color = sum(self._counts.get(cid, 0) for cid, k in self._kind.items() if k == "color")
        if n_color > len(self._all):
            self._notes.append(
                f"{n_color - len(self._all)} {fmt.COLOR_TOPIC} messages share a timestamp; kept one each"
            )
        if self._cal_times[0] > self._all[0]:
            before = int(np.searchsorted(self._all, self._cal_times[0]))
            self._notes.append(f"{before} frames precede the first calibration; they use the first calibration")
        text = self._metadata.get(fmt.BACKGROUND_FRAMES_KEY, "0")
        if not text.isdigit():
            raise RecordingError(
                f"{self.path}: metadata {fmt.RECORDING_METADATA} {fmt.BACKGROUND_FRAMES_KEY} must be a "
                f"non-negative integer, got {text!r}"
            )
        self._background = int(text)  # as announced: frames lost from the section still count
        self._own_sequences = self._metadata.get("writer", "").startswith("fusion-pf")
        start_ns, end_ns = self._window
        lo = 0 if start_ns is None else int(np.searchsorted(self._all, start_ns, "left"))
        hi = len(self._all) if end_ns is None else int(np.searchsorted(self._all, end_ns, "left"))
        self._sel = (lo, max(lo, hi))
        self._estimate_scan_losses()
        self._place_frames()
        self._probe()

    def _probe(self) -> None:
        """Decode the first frame to check sizes and learn the formats."""
        try:
            parts = self._parts_at(int(self._all[0]))
            self._build(0, int(self._all[0]), parts, strict=True)
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
        raw = memoryview(self._pread(block.offset, block.length))
        opcode, length = _RECORD_HEADER.unpack_from(raw)
        if opcode != (_OP_CHUNK if block.is_chunk else _OP_MESSAGE) or 9 + length != block.length:
            raise _Corrupt(f"the record there changed (opcode 0x{opcode:02x}, {length} bytes)")
        body = raw[9:]
        out: list[tuple[int, int, memoryview, int]] = []
        if block.is_chunk:
            for opcode, rec in _records(_decompress_chunk(body), "chunk"):
                if opcode == _OP_MESSAGE:
                    cid, seq, log_time = _message_header(rec)
                    out.append((cid, log_time, rec[_MESSAGE_HEADER.size :], seq))
        else:
            cid, seq, log_time = _message_header(body)
            out.append((cid, log_time, body[_MESSAGE_HEADER.size :], seq))
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
                self._corrupt[block.offset] = str(exc)
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
        """The calibration in effect at ``t``: its message, else its ``fusion_pf.calibration`` metadata copy."""
        k = max(int(np.searchsorted(self._cal_times, t, "right")) - 1, 0)
        c = int(self._cal_times[k])
        with self._lock:
            cached = self._cal_cache.get(c)
        if cached is not None:
            return cached
        problems: list[str] = []
        intrinsics = None
        for block in self._blocks_between(c, c, ("calibration",)):
            try:
                records = self._block_records(block)
            except _Corrupt as exc:
                problems.append(str(self._corrupt_block(block, exc)))
                continue
            for cid, log_time, data, _seq in records:
                if log_time == c and self._kind.get(cid) == "calibration":
                    try:
                        intrinsics = fmt.decode_calibration(data, f"{fmt.CALIBRATION_TOPIC} at t={c} ns")
                        break
                    except RecordingError as exc:
                        problems.append(str(exc))
            if intrinsics is not None:
                break
        if intrinsics is None and len(self._cal_meta_times):
            m = max(int(np.searchsorted(self._cal_meta_times, t, "right")) - 1, 0)
            intrinsics = self._cal_meta[int(self._cal_meta_times[m])]
        if intrinsics is None:
            why = problems[0] if problems else "it cannot be found"
            raise _Corrupt(f"the {fmt.CALIBRATION_TOPIC} message at t={c} ns cannot be read: {why}")
        with self._lock:
            if len(self._cal_cache) >= _CALIBRATION_CACHE:
                self._cal_cache.clear()
            self._cal_cache[c] = intrinsics
        return intrinsics

    def _skip_part(self, part: str, index: int, exc: Exception) -> None:
        """Count a malformed optional ``part`` of frame ``index`` (noting the first of each part)."""
        with self._lock:
            seen = self._bad_parts.setdefault(part, set())
            if not seen:
                self.stats.notes.append(f"{exc}; frames are kept without an unreadable {part}")
            seen.add(index)
            self.stats.skipped_parts[part] = len(seen)

    def _build(
        self, index: int, t: int, parts: dict[str, tuple[int, memoryview, int]], *, strict: bool = False
    ) -> Frame:
        """Decode the parts of the frame with file index ``index`` at time ``t``.

        A malformed depth, skeleton or ground truth is left out and counted
        (:meth:`_skip_part`); with ``strict`` (the first frame, checked at open)
        it raises RecordingError instead. A frame whose colour or calibration
        cannot be used raises _Corrupt (RecordingError with ``strict``).
        """
        where = f"frame {index} (t={t} ns)"
        if "color" not in parts:
            raise _Corrupt(f"{where} has no {fmt.COLOR_TOPIC} message")
        cid, data, seq = parts["color"]
        try:
            color = fmt.decode_color(self._channels[cid].schema_name, data, f"{fmt.COLOR_TOPIC} of {where}")
            intrinsics = self._calibration_at(t)
            h, w = color.shape[:2]
            if (intrinsics.width, intrinsics.height) != (w, h):
                raise RecordingError(
                    f"{self.path}: {fmt.CALIBRATION_TOPIC} is for {intrinsics.width}x{intrinsics.height} images "
                    f"but {fmt.COLOR_TOPIC} is {w}x{h} in {where}"
                )
        except RecordingError as exc:
            if strict:
                raise
            raise _Corrupt(str(exc)) from None
        optional: dict[str, Any] = {"depth": None, "skeleton": None, "truth": None, "hands": None}
        truths: dict[str, PalmPoint] = {}
        topics = {
            "depth": fmt.DEPTH_TOPIC,
            "skeleton": fmt.SKELETON_TOPIC,
            "truth": fmt.GROUND_TRUTH_TOPIC,
            "hands": fmt.HAND_TOPIC,
        }
        names = {"depth": "depth", "skeleton": "skeleton", "truth": "ground truth", "hands": "hand landmarks"}
        for kind in ("depth", "skeleton", "truth", "hands"):
            if kind not in parts:
                continue
            records = parts[kind] if kind == "truth" else [parts[kind]]
            w_ = f"{topics[kind]} of {where}"
            for cid, data, _seq in records:
                try:
                    if kind == "depth":
                        value: Any = fmt.decode_depth(self._channels[cid].schema_name, data, w_)
                        if value.shape != (h, w):
                            raise RecordingError(
                                f"{self.path}: {fmt.DEPTH_TOPIC} is {value.shape[1]}x{value.shape[0]} but "
                                f"{fmt.COLOR_TOPIC} is {w}x{h} in {where}; depth must be aligned to colour (same size)"
                            )
                    elif kind == "skeleton":
                        value = fmt.decode_skeleton(fmt.decode_json(data, w_), w_)
                    elif kind == "hands":
                        value = fmt.decode_hands(fmt.decode_json(data, w_), w_)
                    else:
                        target, value = fmt.decode_truth(fmt.decode_json(data, w_), w_)
                        if target is not None:
                            truths[target] = value
                            continue
                except RecordingError as exc:
                    if strict:
                        raise
                    self._skip_part(names[kind], index, exc)
                    value = None
                optional[kind] = value
        source = int(self._source_index[index])
        return Frame(
            t,
            seq if self._own_sequences else source,
            color,
            optional["depth"],
            intrinsics,
            optional["skeleton"],
            optional["truth"],
            background=index < self._unplaced and source < self._background,
            ground_truths=truths or None,
            hands=optional["hands"],
            index=source,
        )

    def _lose(self, index: int, reason: str, offset: int | None) -> None:
        """Record that the frame with file index ``index`` could not be read, and why."""
        with self._lock:
            self._lost[index] = (reason, offset)
        self._publish()

    def _why_missing(self, t: int, kind: str = "color") -> tuple[str, int | None]:
        """Why the ``kind`` message at ``t`` was not read: the corrupt chunk that holds it, if any."""
        for block in self._blocks_between(t, t, (kind,)):
            reason = self._corrupt.get(block.offset)
            if reason is not None:
                what = "chunk" if block.is_chunk else "message"
                return f"{what} at byte {block.offset} is corrupt ({reason})", block.offset
        topic = {v: k for k, v in self._topic_kind.items()}[kind]
        return f"its {topic} message cannot be found", None

    def _publish(self) -> None:
        """Refresh ``stats.losses`` and ``stats.dropped`` from the losses found so far."""
        with self._lock:
            groups: dict[tuple[str, int | None], int] = {}
            for index in sorted(self._lost):
                key = self._lost[index]
                groups[key] = groups.get(key, 0) + 1
            losses = list(self._scan_losses) + [FrameLoss(n, reason, offset) for (reason, offset), n in groups.items()]
            self.stats.losses = losses
            self.stats.dropped = sum(loss.frames or 0 for loss in losses)
            self.stats.lost_background = self._lost_background()

    def _lost_background(self) -> int:
        """How many lost frames lie in the background section (by their index in the recording)."""
        k, src = self._background, self._source_index
        if not k or not len(src):
            return 0
        count = sum(1 for i in self._lost if i < self._unplaced and src[i] < k)
        end = int(src[-1]) + 1  # the first index after the frames read and counted
        for loss, at in zip(self._scan_losses, self._scan_loss_at, strict=True):
            if at is None or not loss.frames or at > self._unplaced:
                continue
            start = int(src[at]) - loss.frames if at < len(src) else int(src[-1]) + 1
            count += max(0, min(start + loss.frames, k) - start)
            end = max(end, start + loss.frames)
        if self._stop is not None and self._unplaced == len(src):  # a truncated tail: the rest of the section
            count += max(0, k - end)
        return count

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

        Frames whose colour message sits in a corrupt chunk, or whose colour or
        calibration cannot be decoded, are skipped and recorded in
        ``stats.losses`` and ``stats.dropped`` (with a note); a malformed depth,
        skeleton or ground truth is left out of its frame and counted in
        ``stats.skipped_parts``.
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
                self._lose(lo + k, *self._why_missing(t))
                continue
            for kind, part in (("depth", "depth"), ("skeleton", "skeleton"), ("truth", "ground truth")):
                if kind not in parts and t in self._part_times[kind]:  # indexed, but its chunk is unreadable
                    why, _offset = self._why_missing(t, kind)
                    self._skip_part(part, lo + k, f"the {part} of frame {lo + k} (t={t} ns) cannot be read: {why}")
            try:
                frame = self._build(lo + k, t, parts)
            except _Corrupt as exc:
                self._lose(lo + k, str(exc), None)
                continue
            yield frame

    def _topic_infos(self) -> tuple[TopicInfo, ...]:
        by_topic: dict[str, list[_Channel]] = {}
        for ch in self._channels.values():
            by_topic.setdefault(ch.topic, []).append(ch)
        return tuple(
            TopicInfo(
                topic,
                " | ".join(sorted({c.schema_name for c in chans})),
                " | ".join(sorted({c.schema_encoding for c in chans})),
                " | ".join(sorted({c.message_encoding for c in chans})),
                sum(self._counts.get(c.id, 0) for c in chans),
            )
            for topic, chans in sorted(by_topic.items())
        )

    def info(self) -> RecordingInfo:
        """Describe the whole recording (topics, counts, timing, calibration, truncation)."""
        self._require_open()
        topics = self._topic_infos()
        n = len(self._all)
        start, end = int(self._all[0]), int(self._all[-1])
        duration = end - start
        cal, problem = None, None
        for c in [start] + [int(c) for c in self._cal_times if c > start]:
            try:
                cal = self._calibration_at(c)
                break
            except _Corrupt as exc:
                problem = problem or exc
        if cal is None:
            raise RecordingError(f"{self.path}: no calibration can be read: {problem}")
        intrinsics = {
            "fx": cal.fx,
            "fy": cal.fy,
            "cx": cal.cx,
            "cy": cal.cy,
            "distortion_model": cal.distortion_model,
            "distortion": list(cal.distortion),
        }
        width, height = cal.width, cal.height

        def missing(kind: str) -> int:
            return int(n - np.count_nonzero(np.isin(self._all, self._topic_times(kind))))

        return RecordingInfo(
            path=str(self.path),
            size_bytes=self._size,
            library=self._library,
            profile=self._profile,
            indexed=self._indexed,
            truncated=self._truncated,
            topics=topics,
            frames=n,
            start_ns=start,
            end_ns=end,
            duration_ns=duration,
            fps=(n - 1) / (duration / 1e9) if n > 1 and duration > 0 else None,
            width=width,
            height=height,
            intrinsics=intrinsics,
            calibration_messages=len(self._cal_times),
            color_format=self._formats[0],
            depth_format=self._formats[1],
            background_frames=min(self._background, n),
            missing_depth=missing("depth"),
            missing_skeleton=missing("skeleton"),
            ground_truth_frames=n - missing("truth"),
            metadata=dict(self._metadata),
            notes=tuple(self._notes + [note for note in self.stats.notes if note not in self._notes]),
            trailing_bytes=self._trailing,
        )


class McapTopics(McapReplay):
    """Any topic of an MCAP file, read with the replay's own index, CRC checks and damage handling.

    The one MCAP reading path for what is not a frame: the tracker outputs
    (``/tracker/*``), ground truth and metadata, e.g. of a ``fusion-pf track``
    output that holds no ``/camera/color``. Open it like :class:`McapReplay`
    (a ``with`` block); no frame topic is required. A corrupt chunk is skipped
    with a note in ``stats.notes`` (its messages are missing).
    """

    def _finish_index(self) -> None:
        self._blocks.sort(key=lambda b: (b.start_ns, b.offset))
        self._block_start = np.array([b.start_ns for b in self._blocks], np.int64)
        self._block_end = np.array([b.end_ns for b in self._blocks], np.int64)

    def __len__(self) -> int:
        """No frames are read through this class."""
        return 0

    @property
    def topics(self) -> set[str]:
        """The topics of the file's channels."""
        self._require_open()
        return {c.topic for c in self._channels.values()}

    def topics_info(self) -> TopicsInfo:
        """Describe the file by its topics (a tracker output: its frames are its ``/tracker/estimate`` messages)."""
        self._require_open()
        times = np.unique(
            np.concatenate(
                [np.zeros(0, np.int64)]
                + [
                    self._times[c.id]
                    for c in self._channels.values()
                    if c.topic == fmt.ESTIMATE_TOPIC and c.id in self._times
                ]
            )
        )
        return TopicsInfo(
            path=str(self.path),
            size_bytes=self._size,
            library=self._library,
            profile=self._profile,
            indexed=self._indexed,
            truncated=self._truncated,
            trailing_bytes=self._trailing,
            topics=self._topic_infos(),
            frames=len(times),
            start_ns=int(times[0]) if len(times) else None,
            end_ns=int(times[-1]) if len(times) else None,
            metadata=dict(self._metadata),
            notes=tuple(self._notes + [note for note in self.stats.notes if note not in self._notes]),
        )

    def messages(self, topic: str) -> list[tuple[int, str, bytes]]:
        """``(log_time, message encoding, data)`` of every message on ``topic``, in time order."""
        self._require_open()
        cids = {cid for cid, c in self._channels.items() if c.topic == topic}
        out: list[tuple[int, str, bytes]] = []
        for block in self._blocks:
            if not block.channels & cids:
                continue
            try:
                records = self._block_records(block)
            except _Corrupt as exc:
                self._corrupt_block(block, exc)
                continue
            out += [
                (t, self._channels[cid].message_encoding, bytes(data)) for cid, t, data, _ in records if cid in cids
            ]
        out.sort(key=lambda m: m[0])
        return out
