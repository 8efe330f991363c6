"""Issue 14: damaged recordings cost only the damaged frames, and every lost frame is reported.

Each test damages a recording written by McapRecorder in one precise way and
checks that the frames still readable are read (and equal to what was
written) and that ``stats.losses`` accounts for the rest. Chunk positions
come from the independent mcap Python reader, not from McapReplay.
"""

from __future__ import annotations

import struct

import numpy as np
import pytest
from mcap.reader import make_reader

from drivers import mcap_format as fmt
from drivers.mcap_replay import McapReplay
from fusion_pf.errors import RecordingError
from fusion_pf.frame import Intrinsics

N = 24


@pytest.fixture
def recorded(tmp_path, make_frames, record):
    """``(frames, path, chunk_indexes)`` of a 24-frame recording, two frames per chunk."""
    frames = make_frames(N, calibration_change=13)
    path = record(tmp_path / "full.mcap", frames, chunk_size=40_000)
    with open(path, "rb") as fh:
        chunks = sorted(make_reader(fh).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert len(chunks) >= 8
    return frames, path, chunks


def frames_in(chunk, frames):
    return [i for i, f in enumerate(frames) if chunk.message_start_time <= f.timestamp_ns <= chunk.message_end_time]


def data_section_only(data: bytes) -> bytes:
    """The file without DataEnd, summary and footer: what a writer killed after its last chunk leaves."""
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    return data[: summary_start - 13]


def replay(path):
    with McapReplay(path) as r:
        out = list(r)
        return out, r.stats, r.info()


def check_frames(out, frames):
    """Every yielded frame equals the written frame with its timestamp (colour, depth, calibration)."""
    by_time = {f.timestamp_ns: f for f in frames}
    for f in out:
        w = by_time[f.timestamp_ns]
        assert np.array_equal(f.color, w.color) and np.array_equal(f.depth, w.depth)
        assert f.intrinsics == w.intrinsics


def corrupt(data: bytes, chunk, where: float = 0.5) -> bytes:
    buf = bytearray(data)
    buf[chunk.chunk_start_offset + int(chunk.chunk_length * where)] ^= 0x40
    return bytes(buf)


def test_corrupt_chunk_is_reported_with_its_frames_offset_and_reason(recorded, tmp_path):
    frames, path, chunks = recorded
    victim = chunks[4]
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(corrupt(path.read_bytes(), victim))
    out, stats, _ = replay(bad)
    lost = frames_in(victim, frames)
    assert [f.timestamp_ns for f in out] == [f.timestamp_ns for i, f in enumerate(frames) if i not in lost]
    check_frames(out, frames)
    assert len(stats.losses) == 1
    loss = stats.losses[0]
    assert loss.frames == len(lost) == stats.dropped and loss.offset == victim.chunk_start_offset
    assert "CRC" in loss.reason or "decompression" in loss.reason
    summary = stats.loss_summary()
    assert summary.startswith(f"skipped {len(lost)} frames: chunk at byte {victim.chunk_start_offset} is corrupt (")
    assert summary.endswith(f"({len(lost)} frames)") and "\n" not in summary


def test_damaged_chunks_of_a_scanned_file_are_counted(recorded, tmp_path):
    frames, path, chunks = recorded
    data = data_section_only(path.read_bytes())
    for victim in (chunks[2], chunks[6]):
        data = corrupt(data, victim)
    bad = tmp_path / "scanned.mcap"
    bad.write_bytes(data)
    out, stats, info = replay(bad)
    assert info.truncated and not info.indexed
    check_frames(out, frames)
    known = [x for x in stats.losses if x.frames is not None]
    assert [x.offset for x in known] == [chunks[2].chunk_start_offset, chunks[6].chunk_start_offset]
    assert [x.frames for x in known] == [len(frames_in(chunks[2], frames)), len(frames_in(chunks[6], frames))]
    assert len(out) + stats.dropped == N  # every frame read or counted
    assert any(x.frames is None and "truncated" in x.reason for x in stats.losses)
    assert stats.loss_summary().startswith(f"skipped {stats.dropped} frames and an unknown number more: chunk at byte")


def test_truncation_counts_the_frames_of_the_cut_chunk(recorded, tmp_path):
    from drivers.base import FrameLoss

    frames, path, chunks = recorded
    cut = chunks[5].chunk_start_offset + chunks[5].chunk_length // 2
    bad = tmp_path / "cut.mcap"
    bad.write_bytes(path.read_bytes()[:cut])
    out, stats, _ = replay(bad)
    check_frames(out, frames)
    assert len(out) == len([i for i in range(N) if frames[i].timestamp_ns < chunks[5].message_start_time])
    assert stats.losses[0] == FrameLoss(
        len(frames_in(chunks[5], frames)),
        f"the chunk at byte {chunks[5].chunk_start_offset} is cut off by the end of the file",
        chunks[5].chunk_start_offset,
    )
    assert stats.losses[1].frames is None


@pytest.mark.parametrize("scanned", [False, True])
def test_damaged_first_chunk_costs_only_its_own_frames(recorded, tmp_path, scanned):
    """Issue 14 item 2: the calibration (and, scanned, the channels) survive the loss of chunk 0."""
    frames, path, chunks = recorded
    data = corrupt(path.read_bytes(), chunks[0], 0.3)
    if scanned:
        data = data_section_only(data)
    bad = tmp_path / "first.mcap"
    bad.write_bytes(data)
    out, stats, info = replay(bad)
    lost = frames_in(chunks[0], frames)
    assert [f.timestamp_ns for f in out] == [f.timestamp_ns for i, f in enumerate(frames) if i not in lost]
    check_frames(out, frames)
    assert stats.dropped == len(lost) and stats.losses[0].offset == chunks[0].chunk_start_offset
    assert info.intrinsics["fx"] == pytest.approx(frames[0].intrinsics.fx)


def test_calibration_metadata_stands_in_for_an_unreadable_copy(recorded, tmp_path):
    """A frame whose own calibration copy cannot be read takes the calibration from the metadata."""
    frames, path, _ = recorded
    with McapReplay(path) as r:
        r._cal_meta_times = np.array(sorted(r._cal_meta), np.int64)
        assert len(r._cal_meta) == 2  # one record per change (frames 0 and 13)
        r._blocks_between = lambda lo, hi, kinds: []  # no message copy can be found
        r._cal_cache.clear()
        assert r._calibration_at(frames[20].timestamp_ns) == frames[20].intrinsics
        assert r._calibration_at(frames[5].timestamp_ns) == frames[5].intrinsics


def test_old_files_with_one_calibration_still_replay(tmp_path, make_frames, write_foxglove):
    frames = make_frames(10)
    path = write_foxglove(tmp_path / "old.mcap", frames, chunk_size=20_000)
    out, stats, info = replay(path)
    assert len(out) == 10 and info.calibration_messages == 1 and not stats.losses
    check_frames(out, frames)


@pytest.mark.parametrize("kind", ["remove", "duplicate"])
def test_scan_resynchronises_after_a_removed_or_duplicated_range(recorded, tmp_path, kind):
    """Issue 14 item 3: bytes removed from (or repeated in) chunk 3 cost chunk 3 at most, not the rest."""
    frames, path, chunks = recorded
    data = path.read_bytes()
    victim = chunks[3]
    start = victim.chunk_start_offset + 500
    end = start + 3000
    data = data[:start] + data[end:] if kind == "remove" else data[:end] + data[start:]
    bad = tmp_path / f"{kind}.mcap"
    bad.write_bytes(data)
    out, stats, info = replay(bad)
    check_frames(out, frames)
    after = [f.timestamp_ns for f in frames if f.timestamp_ns > victim.message_end_time]
    assert set(after) <= {f.timestamp_ns for f in out}  # every later chunk is still read
    assert len(out) + stats.dropped == N
    if kind == "remove":
        assert stats.dropped == len(frames_in(victim, frames))
        assert any(str(victim.chunk_start_offset) in x.reason for x in stats.losses)


def test_damaged_summary_lengths_are_bounded(recorded, tmp_path):
    """Issue 14 item 5: a huge length in the summary is refused, not passed to os.pread (MemoryError)."""
    frames, path, chunks = recorded
    data = bytearray(path.read_bytes())
    pos = struct.unpack_from("<Q", data, len(data) - 28)[0]  # summary start
    while data[pos] != 0x08:  # skip schemas and channels to the first chunk index record
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    body = pos + 9
    map_len = struct.unpack_from("<I", data, body + 32)[0]
    struct.pack_into("<Q", data, body + 36 + map_len, 1 << 60)  # message_index_length
    bad = tmp_path / "summary.mcap"
    bad.write_bytes(bytes(data))
    out, stats, info = replay(bad)
    assert len(out) == N and not info.indexed and "summary CRC mismatch" in info.notes[0]
    struct.pack_into("<I", data, len(data) - 12, 0)  # summary_crc 0: not checked, the index is read
    bad.write_bytes(bytes(data))
    out, stats, info = replay(bad)
    assert len(out) == N and not info.indexed and "damaged index" in info.notes[0]


def test_log_time_beyond_int64_in_a_scan_is_a_loss_not_an_overflow(tmp_path, write_messages):
    messages = []
    for t in (10, 20, 30, 40, 50):
        messages += [
            (
                fmt.CALIBRATION_TOPIC,
                fmt.CAMERA_CALIBRATION,
                fmt.encode_calibration(Intrinsics(64, 48, 50, 50, 32, 24), t),
                t,
            ),
            (fmt.COLOR_TOPIC, fmt.RAW_IMAGE, fmt.encode_color(np.zeros((48, 64, 3), np.uint8), t), t),
        ]
    messages.append((fmt.COLOR_TOPIC, fmt.RAW_IMAGE, fmt.encode_color(np.zeros((48, 64, 3), np.uint8), 60), 2**63 + 5))
    path = write_messages(tmp_path / "big.mcap", messages)
    data = path.read_bytes()
    with open(path, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    assert len(chunks) == 2 and chunks[0].message_end_time < 60
    for name, content in (("indexed.mcap", data), ("scanned.mcap", data_section_only(data))):
        bad = tmp_path / name
        bad.write_bytes(content)
        out, stats, info = replay(bad)
        got = [f.timestamp_ns for f in out]  # the frames of the intact first chunk
        assert got == [10, 20, 30, 40, 50][: len(got)] and 3 <= len(got) < 5
        assert any("2**63" in loss.reason for loss in stats.losses)


def test_absurd_focal_length_is_a_one_line_error(tmp_path, write_messages):
    cal = fmt.encode_calibration(Intrinsics(64, 48, 50, 50, 32, 24), 0)
    cal.K[0] = cal.K[4] = 1e308
    cal.P[0] = cal.P[5] = 1e308
    messages = [
        (fmt.CALIBRATION_TOPIC, fmt.CAMERA_CALIBRATION, cal, 0),
        (fmt.COLOR_TOPIC, fmt.RAW_IMAGE, fmt.encode_color(np.zeros((48, 64, 3), np.uint8), 0), 0),
    ]
    path = write_messages(tmp_path / "fx.mcap", messages)
    with pytest.raises(RecordingError, match=r"fx = 1e\+308 px is implausible for a 64x48 image"):
        replay(path)


def test_deeply_nested_skeleton_json_is_skipped_and_counted(tmp_path):
    """Issue 14 items 5 and 6: a RecursionError-deep skeleton costs only that skeleton."""
    from mcap.writer import Writer

    path = tmp_path / "deep.mcap"
    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        cal = w.register_channel(
            fmt.CALIBRATION_TOPIC, "protobuf", w.register_schema(fmt.CAMERA_CALIBRATION, "protobuf", b"")
        )
        col = w.register_channel(fmt.COLOR_TOPIC, "protobuf", w.register_schema(fmt.RAW_IMAGE, "protobuf", b""))
        skel = w.register_channel(
            fmt.SKELETON_TOPIC, "json", w.register_schema(fmt.SKELETON_SCHEMA, "jsonschema", b"{}")
        )
        w.add_message(cal, 0, fmt.encode_calibration(Intrinsics(64, 48, 50, 50, 32, 24), 0).SerializeToString(), 0)
        for t in (0, 10, 20):
            w.add_message(col, t, fmt.encode_color(np.zeros((48, 64, 3), np.uint8), t).SerializeToString(), t)
            body = b"[" * 100_000 + b"]" * 100_000 if t == 10 else b'{"joints":[]}'
            w.add_message(skel, t, body, t)
        w.finish()
    out, stats, _ = replay(path)
    assert [f.joints is None for f in out] == [False, True, False]
    assert stats.skipped_parts == {"skeleton": 1} and stats.dropped == 0
    assert "nested too deeply" in " ".join(stats.notes)
    assert "1 skeleton message unreadable (frames kept without skeleton)" in stats.loss_summary()


def test_parts_in_a_corrupt_chunk_of_another_writer_are_counted(tmp_path, make_frames, write_foxglove):
    """Another writer splits frames across chunks: a frame kept without its depth says why."""
    frames = make_frames(16)
    path = write_foxglove(tmp_path / "fox.mcap", frames, chunk_size=20_000)
    with open(path, "rb") as fh:
        chunks = sorted(make_reader(fh).get_summary().chunk_indexes, key=lambda c: c.chunk_start_offset)
    bad = tmp_path / "fox_bad.mcap"
    bad.write_bytes(corrupt(path.read_bytes(), chunks[len(chunks) // 2]))
    out, stats, _ = replay(bad)
    by_time = {f.timestamp_ns: f for f in frames}
    without = {
        part: sum(1 for f in out if getattr(by_time[f.timestamp_ns], attr) is not None and getattr(f, attr) is None)
        for part, attr in (("depth", "depth"), ("skeleton", "joints"), ("ground truth", "ground_truth"))
    }
    assert len(out) + stats.dropped == 16 and stats.dropped >= 1
    assert {k: v for k, v in without.items() if v} == stats.skipped_parts
