"""McapTopics: the replay's reader for non-frame topics (tracker outputs, metadata), damage included."""

from __future__ import annotations

import pytest

from drivers import mcap_format as fmt
from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapTopics
from drivers.tracker_topics import read_json_topic, recording_metadata
from fusion_pf.errors import InputError, RecordingError


def write_outputs(path, n=400):
    with McapRecorder(path, metadata={"source": "in.mcap"}) as rec:
        for k in range(n):
            rec.write_json(fmt.ESTIMATE_TOPIC, fmt.ESTIMATE_SCHEMA, {"frame": k, "u": float(k), "v": 2.0 * k}, 1000 + k)
    return path


def test_reads_a_tracker_output_without_frames(tmp_path):
    path = write_outputs(tmp_path / "out.mcap")
    with McapTopics(path) as rec:
        assert fmt.ESTIMATE_TOPIC in rec.topics and fmt.COLOR_TOPIC not in rec.topics
        msgs = rec.messages(fmt.ESTIMATE_TOPIC)
        assert rec.messages(fmt.CUES_TOPIC) == []
    assert [t for t, _, _ in msgs] == list(range(1000, 1400)) and {e for _, e, _ in msgs} == {"json"}
    assert read_json_topic(path, fmt.ESTIMATE_TOPIC)[7] == (1007, {"frame": 7, "u": 7.0, "v": 14.0})
    assert recording_metadata(path)["source"] == "in.mcap"


def test_a_corrupt_chunk_costs_only_its_messages(tmp_path):
    path = write_outputs(tmp_path / "out.mcap", n=60_000)  # several chunks
    with McapTopics(path) as rec:
        chunks = [b for b in rec._blocks if b.is_chunk]
    assert len(chunks) >= 2
    data = bytearray(path.read_bytes())
    data[chunks[1].offset + chunks[1].length // 2] ^= 0xFF  # inside the second chunk's compressed body
    path.write_bytes(bytes(data))
    with McapTopics(path) as rec:
        msgs = rec.messages(fmt.ESTIMATE_TOPIC)
        notes = list(rec.stats.notes)
    assert 0 < len(msgs) < 60_000
    assert any("is corrupt" in n and "skipped it" in n for n in notes)


def test_not_mcap_and_not_json_are_one_line_errors(tmp_path):
    bad = tmp_path / "x.mcap"
    bad.write_text("hello")
    with pytest.raises(RecordingError, match="not an MCAP file"):
        read_json_topic(bad, fmt.ESTIMATE_TOPIC)
    path = tmp_path / "proto.mcap"
    import numpy as np

    from fusion_pf.frame import Frame, Intrinsics

    intr = Intrinsics(fx=100.0, fy=100.0, cx=15.5, cy=11.5, width=32, height=24)
    with McapRecorder(path) as rec:
        rec.write(Frame(0, 0, np.zeros((24, 32, 3), np.uint8), None, intr))
    with pytest.raises(InputError, match="must be JSON-encoded"):
        read_json_topic(path, fmt.COLOR_TOPIC)
