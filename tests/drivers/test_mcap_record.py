"""McapRecorder (drivers/mcap_record.py), checked with the independent mcap Python reader."""

import json
import os
import subprocess
import sys
from collections import Counter

import pytest
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from drivers import mcap_format as fmt
from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapReplay
from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame


def read_all(path):
    with open(path, "rb") as fh:
        reader = make_reader(fh, validate_crcs=True, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        messages = list(reader.iter_messages())
        metadata = [(m.name, m.metadata) for m in reader.iter_metadata()]
        header = reader.get_header()
    return header, summary, messages, metadata


def test_messages_follow_the_convention(tmp_path, make_frames, record):
    frames = make_frames(10, no_depth=(3,), no_skeleton=(4,), calibration_change=6)
    path = record(tmp_path / "a.mcap", frames, metadata={"generator": "test", "seed": "0"})
    header, summary, messages, metadata = read_all(path)
    assert header.library.startswith("fusion-pf ")
    topics = Counter(summary.channels[m.channel_id].topic for _, _, m in messages)
    n_cal = topics.pop(fmt.CALIBRATION_TOPIC)
    assert topics == {fmt.COLOR_TOPIC: 10, fmt.DEPTH_TOPIC: 9, fmt.SKELETON_TOPIC: 9, fmt.GROUND_TRUTH_TOPIC: 8}
    assert 2 <= n_cal <= len(summary.chunk_indexes) + 2  # the changes, and a copy in every chunk
    times = {f.timestamp_ns for f in frames}
    assert all(m.log_time == m.publish_time and m.log_time in times for _, _, m in messages)
    by_time = {f.timestamp_ns: f.intrinsics for f in frames}
    for _, c, m in messages:
        if c.topic == fmt.CALIBRATION_TOPIC:
            assert fmt.decode_calibration(m.data) == by_time[m.log_time]
    cal_meta = [m for name, m in metadata if name == fmt.CALIBRATION_METADATA]
    assert [fmt.decode_calibration_metadata(m) for m in cal_meta] == [
        (frames[0].timestamp_ns, frames[0].intrinsics),
        (frames[6].timestamp_ns, frames[6].intrinsics),
    ]
    schemas = {c.topic: (s.name, s.encoding, c.message_encoding) for s, c, _ in messages}
    assert schemas[fmt.COLOR_TOPIC] == (fmt.RAW_IMAGE, "protobuf", "protobuf")
    assert schemas[fmt.SKELETON_TOPIC] == (fmt.SKELETON_SCHEMA, "jsonschema", "json")
    assert schemas[fmt.GROUND_TRUTH_TOPIC] == (fmt.PALM_SCHEMA, "jsonschema", "json")
    assert {ci.compression for ci in summary.chunk_indexes} == {"zstd"} and len(summary.chunk_indexes) > 3
    assert all(ci.message_index_offsets for ci in summary.chunk_indexes)
    # the first metadata record announces 0, the correction arrives with the first foreground frame
    assert [m[fmt.BACKGROUND_FRAMES_KEY] for name, m in metadata if name == fmt.RECORDING_METADATA] == ["0", "2"]
    assert metadata[0][1]["generator"] == "test" and metadata[0][1][fmt.FORMAT_VERSION_KEY] == "1"
    skeleton = [json.loads(m.data) for _, c, m in messages if c.topic == fmt.SKELETON_TOPIC]
    assert [j["name"] for j in skeleton[0]["joints"]] == ["right_hand", "head", "left_hand"]
    assert skeleton[0]["joints"][0]["depth_mm"] is None


def test_every_chunk_starts_with_the_calibration(tmp_path, make_frames, record):
    """Issue 14 item 2: each chunk carries its own calibration copy as its first message."""
    from mcap.records import Channel, Chunk, Message
    from mcap.stream_reader import StreamReader, breakup_chunk

    frames = make_frames(30, calibration_change=17)
    path = record(tmp_path / "c.mcap", frames, chunk_size=40_000)
    channels, firsts = {}, []
    with open(path, "rb") as fh:
        for rec in StreamReader(fh, emit_chunks=True).records:
            if isinstance(rec, Chunk):
                inner = breakup_chunk(rec, validate_crc=True)
                channels.update({r.id: r.topic for r in inner if isinstance(r, Channel)})
                firsts.append(next(r for r in inner if isinstance(r, Message)))
    assert len(firsts) >= 5
    by_time = {f.timestamp_ns: f.intrinsics for f in frames}
    for m in firsts:
        assert channels[m.channel_id] == fmt.CALIBRATION_TOPIC
        assert fmt.decode_calibration(m.data) == by_time[m.log_time]


@pytest.mark.parametrize(
    "color_format, depth_format, compression", [("jpeg", "png", "zstd"), ("png", "raw", "lz4"), ("raw", "raw", "none")]
)
def test_formats_and_compressions(tmp_path, make_frames, record, color_format, depth_format, compression):
    frames = make_frames(4)
    path = record(
        tmp_path / "f.mcap", frames, color_format=color_format, depth_format=depth_format, compression=compression
    )
    _, summary, messages, _ = read_all(path)
    expected = {"zstd": "zstd", "lz4": "lz4", "none": ""}[compression]
    assert {ci.compression for ci in summary.chunk_indexes} == {expected}
    by_topic = {c.topic: s.name for s, c, _ in messages}
    assert by_topic[fmt.COLOR_TOPIC] == (fmt.RAW_IMAGE if color_format == "raw" else fmt.COMPRESSED_IMAGE)
    assert by_topic[fmt.DEPTH_TOPIC] == (fmt.RAW_IMAGE if depth_format == "raw" else fmt.COMPRESSED_IMAGE)


def test_tracker_topics(tmp_path, make_frames):
    frames = make_frames(3, background=0)
    path = tmp_path / "t.mcap"
    with McapRecorder(path) as rec:
        for f in frames:
            rec.write(f)
            rec.write_json(
                fmt.ESTIMATE_TOPIC,
                fmt.ESTIMATE_SCHEMA,
                {"frame": f.seq, "timestamp_ns": f.timestamp_ns, "u": 1.0, "v": 2.0, "xyz_mm": None},
                f.timestamp_ns,
            )
            rec.write_protobuf(fmt.PARTICLES_TOPIC, PointCloud(frame_id="camera", point_stride=12), f.timestamp_ns)
        rec.write_json("/custom", "my.Thing", {"k": [1, 2]}, 7, schema={"type": "object"})
        with pytest.raises(
            InputError, match="already carries fusion_pf.Estimate messages, cannot write fusion_pf.Cues"
        ):
            rec.write_json(fmt.ESTIMATE_TOPIC, fmt.CUES_SCHEMA, {}, 1)
        with pytest.raises(InputError, match="already carries foxglove.PointCloud"):
            rec.write_protobuf(fmt.PARTICLES_TOPIC, fmt.encode_calibration(frames[0].intrinsics, 0), 1)
    _, summary, messages, _ = read_all(path)
    counts = Counter(c.topic for _, c, _ in messages)
    assert counts[fmt.ESTIMATE_TOPIC] == 3 and counts[fmt.PARTICLES_TOPIC] == 3 and counts["/custom"] == 1
    schemas = {c.topic: s for s, c, _ in messages}
    assert json.loads(schemas[fmt.ESTIMATE_TOPIC].data)["title"] == fmt.ESTIMATE_SCHEMA
    assert schemas[fmt.PARTICLES_TOPIC].name == "foxglove.PointCloud"
    # tracker topics do not disturb replay
    with McapReplay(path) as replay:
        assert len(list(replay)) == 3


def test_bad_input_is_rejected_without_damaging_the_file(tmp_path, make_frames):
    frames = make_frames(4, background=1)
    path = tmp_path / "b.mcap"
    with McapRecorder(path) as rec:
        rec.write(frames[0])
        rec.write(frames[1])
        with pytest.raises(InputError, match="frame timestamps must increase: frame seq 1 has timestamp_ns="):
            rec.write(frames[1])
        with pytest.raises(InputError, match="background frames must be the first frames"):
            rec.write(Frame(frames[2].timestamp_ns, 2, frames[2].color, None, frames[2].intrinsics, background=True))
        with pytest.raises(InputError, match="takes a Frame, got ndarray"):
            rec.write(frames[2].color)
        with pytest.raises(InputError, match="topic '/camera/color' is written by write\\(frame\\)"):
            rec.write_json(fmt.COLOR_TOPIC, fmt.PALM_SCHEMA, {}, 1)
        with pytest.raises(InputError, match="not valid JSON"):
            rec.write_json(fmt.ESTIMATE_TOPIC, fmt.ESTIMATE_SCHEMA, {"u": float("inf")}, 1)
        with pytest.raises(InputError, match="timestamp_ns must be an integer number of nanoseconds, got 1.5"):
            rec.write_json(fmt.ESTIMATE_TOPIC, fmt.ESTIMATE_SCHEMA, {}, 1.5)
        rec.write(frames[2])
    with McapReplay(path) as replay:
        assert [f.seq for f in replay] == [0, 1, 2]
        assert replay.info().background_frames == 1


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"compression": "gzip"}, "compression must be one of"),
        ({"color_format": "webp"}, "color_format must be one of"),
        ({"depth_format": "jpeg"}, "depth_format must be one of"),
        ({"jpeg_quality": 0}, "jpeg_quality must be an int in 1..100, got 0"),
        ({"metadata": {"seed": 3}}, "metadata must map str to str"),
        ({"metadata": {"background_frames": "x"}}, "background_frames must be a non-negative integer, got 'x'"),
        ({"chunk_size": 0}, "chunk_size must be a positive int"),
    ],
)
def test_bad_options(tmp_path, kwargs, message):
    with pytest.raises(InputError, match=message):
        McapRecorder(tmp_path / "x.mcap", **kwargs)
    assert not (tmp_path / "x.mcap").exists()


def test_write_outside_with_and_double_close(tmp_path, make_frames):
    rec = McapRecorder(tmp_path / "c.mcap")
    with pytest.raises(RecordingError, match="is not open"):
        rec.write(make_frames(1)[0])
    with rec:
        rec.write(make_frames(1)[0])
    rec.close()
    assert rec.bytes_written == os.path.getsize(tmp_path / "c.mcap") > 0


def test_keyboard_interrupt_finalises(tmp_path, make_frames):
    frames = make_frames(6)
    path = tmp_path / "k.mcap"

    def interrupted_source():
        yield from frames[:4]
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        with McapRecorder(path, chunk_size=16_000) as rec:
            for frame in interrupted_source():
                rec.write(frame)
    _, summary, messages, _ = read_all(path)
    assert summary is not None and summary.statistics.channel_message_counts
    with McapReplay(path) as replay:
        assert len(replay) == 4 and not replay.info().truncated


def test_hard_crash_leaves_a_readable_partial_file(tmp_path):
    """A writer killed without close() (os._exit) leaves every complete chunk readable."""
    path = tmp_path / "crash.mcap"
    script = f"""
import os, sys
sys.path.insert(0, {os.path.dirname(__file__)!r})
from conftest import _make_frames
from drivers.mcap_record import McapRecorder
rec = McapRecorder({str(path)!r}, chunk_size=40_000)
rec.open()
pending = rec._writer._Writer__chunk_builder
for n, f in enumerate(_make_frames(40, background=3), 1):
    rec.write(f)
    if n >= 30 and pending.num_messages >= 5:  # the unwritten chunk holds a colour image
        break
print(n, flush=True)
os._exit(9)
"""
    proc = subprocess.run([sys.executable, "-c", script], timeout=60, capture_output=True, text=True)
    assert proc.returncode == 9, proc.stderr
    written = int(proc.stdout)
    with McapReplay(path) as replay:
        info = replay.info()
        frames = list(replay)
    assert info.truncated and not info.indexed
    assert 20 <= len(frames) < written
    assert [f.seq for f in frames] == list(range(len(frames)))
    assert info.background_frames == 3 and [f.background for f in frames[:4]] == [True, True, True, False]
    assert any("truncated" in note for note in info.notes)


def test_ctrl_c_during_close_is_held_back_until_the_file_is_complete(tmp_path, make_frames, monkeypatch):
    import signal

    path = tmp_path / "late.mcap"
    rec = McapRecorder(path)
    rec.open()
    for frame in make_frames(3):
        rec.write(frame)
    writer = rec._writer
    real_finish = writer.finish

    def finish_after_ctrl_c():
        os.kill(os.getpid(), signal.SIGINT)  # Ctrl-C arrives while the summary is being written
        real_finish()

    monkeypatch.setattr(writer, "finish", finish_after_ctrl_c)
    with pytest.raises(KeyboardInterrupt):
        rec.close()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with McapReplay(path) as replay:
        assert len(replay) == 3 and replay.info().indexed
