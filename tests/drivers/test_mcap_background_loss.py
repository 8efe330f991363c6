"""Issue 24 item 4: frames lost in or before the background section are not silently taken for background.

A 24-frame recording (two frames per chunk) whose first ``K = 4`` frames are the
empty scene is damaged in its scanned form (no summary: the index is rebuilt
from the data section), where the lost frames leave no trace in any index.
Frames must keep their index in the recording (so the CSV shows the gap), the
background section must be decided by that index, and the lost background
frames must be counted and printed. An unreadable ``fusion_pf.recording``
record must be a warning (and exit 3) in ``track``, not a silent
``background_frames = 0``.
"""

from __future__ import annotations

import csv
import struct

import pytest
from mcap.reader import make_reader

from drivers import mcap_format as fmt
from drivers.mcap_replay import McapReplay
from fusion_pf import cli

N, K = 24, 4
#: Announced at open, as ``synth`` does; the recorder adds a corrected record when it is not.
METADATA = {fmt.BACKGROUND_FRAMES_KEY: str(K)}


@pytest.fixture
def recorded(tmp_path, make_frames, record):
    """``(frames, data, chunks)``: the recording's bytes and its chunk indexes (from the mcap reader)."""
    frames = make_frames(N, background=K)
    path = record(tmp_path / "full.mcap", frames, chunk_size=40_000, metadata=METADATA)
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    assert [len(frames_in(c, frames)) for c in chunks[:3]] == [2, 2, 2]
    return frames, path.read_bytes(), chunks, summary


def frames_in(chunk, frames):
    return [i for i, f in enumerate(frames) if chunk.message_start_time <= f.timestamp_ns <= chunk.message_end_time]


def data_section_only(data: bytes) -> bytes:
    """What a writer killed after its last chunk leaves: no summary, so replay scans the file."""
    summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
    return data[: summary_start - 13]


def flip(data: bytes, at: int) -> bytes:
    buf = bytearray(data)
    buf[at] ^= 0x40
    return bytes(buf)


def damaged_inside(recorded) -> tuple[bytes, list[int]]:
    """Chunk 1 (frames 2 and 3, inside the background section) corrupt, in a scanned file."""
    frames, data, chunks, _ = recorded
    c = chunks[1]
    return flip(data_section_only(data), c.chunk_start_offset + c.chunk_length // 2), frames_in(c, frames)


def damaged_before(recorded) -> tuple[bytes, list[int]]:
    """The bytes from the middle of chunk 0 to the middle of chunk 1 removed (the whole background), scanned."""
    frames, data, chunks, _ = recorded
    data = data_section_only(data)
    start = chunks[0].chunk_start_offset + chunks[0].chunk_length // 2
    end = chunks[1].chunk_start_offset + chunks[1].chunk_length // 2
    return data[:start] + data[end:], frames_in(chunks[0], frames) + frames_in(chunks[1], frames)


@pytest.mark.parametrize("damage", [damaged_inside, damaged_before])
def test_frames_keep_their_index_and_background_is_decided_by_it(recorded, tmp_path, damage):
    frames, *_ = recorded
    data, lost = damage(recorded)
    path = tmp_path / "bad.mcap"
    path.write_bytes(data)
    with McapReplay(path) as rec:
        out = list(rec)
        stats = rec.stats
    by_time = {f.timestamp_ns: i for i, f in enumerate(frames)}
    kept = [i for i in range(N) if i not in lost]
    assert [by_time[f.timestamp_ns] for f in out] == kept
    assert [f.index for f in out] == kept
    assert [f.background for f in out] == [i < K for i in kept]
    assert stats.dropped == len(lost)
    assert stats.lost_background == len([i for i in lost if i < K])


def test_track_csv_shows_the_gap_and_the_summary_counts_lost_background(recorded, tmp_path, capsys):
    data, lost = damaged_inside(recorded)
    path = tmp_path / "bad.mcap"
    path.write_bytes(data)
    out, table = tmp_path / "out.mcap", tmp_path / "out.csv"
    code = cli.main(["track", str(path), "-o", str(out), "--csv", str(table), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 3
    with open(table, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["frame"]) for r in rows] == list(range(K, N))  # every person frame, by its own number
    assert f"tracked {N - K} frames (2 background, 2 background lost)" in err
    assert "skipped 2 frames and an unknown number more: chunk at byte" in err


def _corrupt_recording_metadata(recorded, which: slice) -> bytes:
    """``which`` of the ``fusion_pf.recording`` records get a key-value map longer than the record."""
    _, data, _, summary = recorded
    records = [m for m in summary.metadata_indexes if m.name == fmt.RECORDING_METADATA]
    buf = bytearray(data)
    for index in records[which]:
        body = index.offset + 9
        name_len = struct.unpack_from("<I", data, body)[0]
        struct.pack_into("<I", buf, body + 4 + name_len, 1 << 20)
    return bytes(buf)


@pytest.mark.parametrize("scanned", [False, True])
@pytest.mark.parametrize(
    "which, expected",
    [(slice(None), "the number of background frames is unknown"), (slice(1, 2), "may be out of date")],
)
def test_unreadable_recording_metadata_is_a_warning_in_track(
    tmp_path, make_frames, record, capsys, scanned, which, expected
):
    frames = make_frames(N, background=K)
    path = record(tmp_path / "full.mcap", frames, chunk_size=40_000)  # K announced by a second record
    with open(path, "rb") as fh:
        summary = make_reader(fh).get_summary()
    assert [m.name for m in summary.metadata_indexes].count(fmt.RECORDING_METADATA) == 2
    data = _corrupt_recording_metadata((frames, path.read_bytes(), None, summary), which)
    path = tmp_path / "meta.mcap"
    path.write_bytes(data_section_only(data) if scanned else data)
    with McapReplay(path) as rec:
        assert rec.info().background_frames == 0
        assert len(rec.stats.warnings) == 1 and expected in rec.stats.warnings[0]
    code = cli.main(["track", str(path), "-o", str(tmp_path / "out.mcap"), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 3
    assert f"tracked {N} frames (0 background)" in err
    warning = [line for line in err.splitlines() if line.startswith("fusion-pf: warning:")]
    assert warning and fmt.RECORDING_METADATA in warning[-1] and expected in warning[-1]


def test_file_cut_inside_the_background_section_counts_its_lost_background(recorded, tmp_path):
    """A truncated tail of unknown length still says how many background frames it took (K - frames read)."""
    frames, data, chunks, _ = recorded
    path = tmp_path / "cut.mcap"
    path.write_bytes(data[: chunks[1].chunk_start_offset + 5])  # inside chunk 1's record header
    with McapReplay(path) as rec:
        out = list(rec)
        stats = rec.stats
    assert [f.index for f in out] == [0, 1] and all(f.background for f in out)
    assert stats.losses[-1].tail and stats.losses[-1].frames is None
    assert stats.lost_background == K - 2


def test_damaged_time_in_a_message_index_does_not_shift_the_frame_numbers(recorded, tmp_path):
    """A message index time outside its chunk would be a phantom frame before all others: the index is not trusted."""
    frames, data, chunks, summary = recorded
    (color,) = [cid for cid, ch in summary.channels.items() if ch.topic == fmt.COLOR_TOPIC]
    at = chunks[3].message_index_offsets[color] + 9 + 2 + 4  # the first (log_time, offset) pair
    buf = bytearray(data)
    struct.pack_into("<Q", buf, at, frames[0].timestamp_ns - 10**9)
    path = tmp_path / "index.mcap"
    path.write_bytes(bytes(buf))
    with McapReplay(path) as rec:
        out = list(rec)
        assert not rec.info().indexed
    by_time = {f.timestamp_ns: i for i, f in enumerate(frames)}
    assert [f.index for f in out] == [by_time[f.timestamp_ns] for f in out] == list(range(N))
    assert [f.background for f in out] == [i < K for i in range(N)]
