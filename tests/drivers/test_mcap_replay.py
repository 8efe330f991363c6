"""McapReplay (drivers/mcap_replay.py): round trips, seeking, info, damaged and non-conforming files."""

import threading
import tracemalloc

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from drivers import mcap_format as fmt
from drivers import open_source
from drivers.mcap_replay import MAGIC, McapReplay
from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Intrinsics


def replay_all(path, **kwargs):
    with McapReplay(path, **kwargs) as replay:
        return list(replay), replay.stats, replay.info()


def test_roundtrip_is_exact(tmp_path, make_frames, record, same_frames):
    frames = make_frames(14, no_depth=(3, 9), no_skeleton=(5,), calibration_change=8)
    path = record(tmp_path / "r.mcap", frames, metadata={"seed": "0"})
    with open_source(str(path)) as replay:
        assert isinstance(replay, McapReplay) and len(replay) == 14
        out = list(replay)
        same_frames(frames, out)
        same_frames(frames, list(replay))  # re-iterable
        assert [f.seq for f in out] == list(range(14))
        assert replay.stats.frames == 28 and replay.stats.missing_depth == 4 and replay.stats.missing_skeleton == 2
        assert replay.stats.dropped == 0 and replay.stats.notes == []
        assert out[7].intrinsics.distortion_model == "none" and out[8].intrinsics.distortion_model == "plumb_bob"
        assert replay.metadata()["seed"] == "0"
        assert replay.describe() == "MCAP r.mcap (14 frames)"


@pytest.mark.parametrize("color_format, depth_format, exact", [("png", "png", True), ("jpeg", "raw", False)])
def test_compressed_roundtrip(tmp_path, make_frames, record, same_frames, color_format, depth_format, exact):
    frames = make_frames(5)
    # smooth images so that JPEG stays close
    ramp = np.linspace(0, 255, 64, dtype=np.uint8)[None, :, None]
    frames = [
        f.__class__(
            f.timestamp_ns,
            f.seq,
            np.broadcast_to(ramp, (48, 64, 3)).copy(),
            f.depth,
            f.intrinsics,
            f.joints,
            f.ground_truth,
            f.background,
        )
        for f in frames
    ]
    path = record(tmp_path / "c.mcap", frames, color_format=color_format, depth_format=depth_format)
    out, _, info = replay_all(path)
    same_frames(frames, out, exact_color=exact)
    assert (info.color_format, info.depth_format) == (color_format, "png" if depth_format == "png" else "16UC1")


def test_seeking_by_index_and_time(tmp_path, make_frames, record, same_frames):
    frames = make_frames(20)
    path = record(tmp_path / "s.mcap", frames, chunk_size=8_000)
    times = [f.timestamp_ns for f in frames]
    with McapReplay(path) as replay:
        assert replay.timestamps.tolist() == times
        for i in (19, 0, 7, 7, 13):
            same_frames([frames[i]], [replay.frame(i)])
        same_frames(frames[5:9], list(replay.frames(5, 9)))
        same_frames(frames[16:], list(replay.frames(16, 100)))
        same_frames(frames[4:9], list(replay.frames(start_ns=times[4], end_ns=times[9])))
        same_frames(frames[6:8], list(replay.frames(2, 8, start_ns=times[6] - 1)))
        assert list(replay.frames(9, 3)) == []
        assert replay.index_at(times[3] + 1) == 4 and replay.index_at(0) == 0 and replay.index_at(2**62) == 20
        with pytest.raises(InputError, match="frame index 20 is out of range; the recording has 20 frames"):
            replay.frame(20)
        with pytest.raises(InputError, match="frame index must be a non-negative int frame index, got -1"):
            replay.frame(-1)
        with pytest.raises(InputError, match="start must be a non-negative int"):
            list(replay.frames(1.5))
    with McapReplay(path, start_ns=times[10], end_ns=times[15]) as window:
        assert len(window) == 5 and window.timestamps.tolist() == times[10:15]
        same_frames(frames[10:15], list(window))
        same_frames([frames[12]], [window.frame(2)])
        same_frames(frames[11:13], list(window.frames(1, 3)))
        assert window.info().frames == 20  # info describes the whole file
    with pytest.raises(InputError, match="start_ns \\(5\\) must not be after end_ns \\(4\\)"):
        McapReplay(path, start_ns=5, end_ns=4)


def test_info(tmp_path, make_frames, record):
    frames = make_frames(11, background=3, no_depth=(4,), no_skeleton=(4, 6))
    path = record(tmp_path / "i.mcap", frames, metadata={"generator": "hand"})
    with McapReplay(path) as replay:
        info = replay.info()
        n_chunks = sum(b.is_chunk for b in replay._blocks)
    assert info.indexed and not info.truncated and info.notes == ()
    assert info.frames == 11 and info.duration_ns == 10 * 33_333_333
    assert info.fps == pytest.approx(30.0, rel=1e-6)
    assert (info.width, info.height) == (64, 48) and info.intrinsics["fx"] == pytest.approx(0.78 * 64)
    assert info.background_frames == 3 and info.missing_depth == 1 and info.missing_skeleton == 2
    assert info.ground_truth_frames == 8 and info.calibration_messages == n_chunks  # a copy per chunk
    assert info.metadata["generator"] == "hand"
    counts = {t.topic: t.message_count for t in info.topics}
    assert counts == {
        fmt.COLOR_TOPIC: 11,
        fmt.DEPTH_TOPIC: 10,
        fmt.SKELETON_TOPIC: 9,
        fmt.GROUND_TRUTH_TOPIC: 8,
        fmt.CALIBRATION_TOPIC: n_chunks,
    }
    as_json = __import__("json").loads(info.to_json())
    assert as_json["topics"][0]["topic"] == fmt.CALIBRATION_TOPIC and as_json["frames"] == 11


def test_truncated_at_ten_cut_points(tmp_path, make_frames, record, same_frames):
    frames = make_frames(16)
    data = record(tmp_path / "full.mcap", frames, chunk_size=12_000).read_bytes()
    cuts = np.linspace(4, len(data) - 1, 10).astype(int)
    outcomes = []
    for cut in cuts:
        path = tmp_path / f"cut{cut}.mcap"
        path.write_bytes(data[:cut])
        try:
            out, stats, info = replay_all(path)
        except RecordingError as exc:
            message = str(exc)
            assert "\n" not in message and str(path) in message
            assert ("truncated" in message) or ("no /camera/color" in message)
            outcomes.append(0)
            continue
        assert info.truncated and not info.indexed
        assert any(note.startswith("file truncated") for note in info.notes)
        assert stats.notes and stats.notes[0].startswith("file truncated")
        # every complete message replays, in order, unchanged (parts of the last frame may be missing)
        n = len(out)
        assert 0 < n <= 16 and info.frames == n
        same_frames(frames[: n - 1], out[: n - 1])
        assert np.array_equal(out[-1].color, frames[n - 1].color)
        outcomes.append(n)
    assert outcomes[0] == 0 and outcomes[-1] == 16
    assert outcomes == sorted(outcomes) and len(set(outcomes)) >= 6


def test_flipped_byte_inside_a_chunk(tmp_path, make_frames, record, same_frames):
    frames = make_frames(16)
    path = record(tmp_path / "ok.mcap", frames, chunk_size=12_000)
    with McapReplay(path) as replay:
        blocks = replay._blocks
        victim = blocks[2]
        in_victim = [i for i, t in enumerate(replay.timestamps.tolist()) if victim.start_ns <= t <= victim.end_ns]
    data = bytearray(path.read_bytes())
    data[victim.offset + victim.length // 2] ^= 0x5A
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(bytes(data))
    with McapReplay(bad) as replay:
        out = list(replay)
        assert len(replay.stats.notes) == 1
        note = replay.stats.notes[0]
        assert f"chunk at byte {victim.offset} is corrupt" in note and ("CRC" in note or "decompression" in note)
        colour_lost = [i for i in in_victim if i not in {f.seq for f in out}]
        assert replay.stats.dropped == len(colour_lost) >= 1
        kept = [frames[f.seq] for f in out]
        for a, b in zip(kept, out):
            assert np.array_equal(a.color, b.color)
        with pytest.raises(
            RecordingError,
            match=f"frame {colour_lost[0]} .* cannot be read: .*chunk at byte {victim.offset} is corrupt",
        ):
            replay.frame(colour_lost[0])
        assert note in replay.info().notes


def test_not_mcap_empty_missing_directory(tmp_path):
    cases = {
        "text.mcap": (b"hello, this is not a recording\n", "is not an MCAP file: it starts with b'hello, t'"),
        "empty.mcap": (b"", "is empty \\(0 bytes\\); expected an MCAP recording"),
        "short.mcap": (MAGIC[:5], "is truncated to 5 bytes, before the end of the MCAP magic"),
        "magic.mcap": (
            MAGIC,
            "has no /camera/color topic, which is required; topics present: none \\(the file is truncated\\)",
        ),
    }
    for name, (content, message) in cases.items():
        path = tmp_path / name
        path.write_bytes(content)
        with pytest.raises(RecordingError, match=message):
            McapReplay(path).open()
    with pytest.raises(RecordingError, match="recording not found"):
        McapReplay(tmp_path / "nope.mcap").open()
    with pytest.raises(RecordingError, match="is a directory"):
        McapReplay(tmp_path).open()


def _frame_messages(t, color_size=(64, 48), depth_size=(64, 48), calibration=True):
    cw, ch = color_size
    dw, dh = depth_size
    out = []
    if calibration:
        out.append(
            (
                fmt.CALIBRATION_TOPIC,
                fmt.CAMERA_CALIBRATION,
                fmt.encode_calibration(Intrinsics(cw, ch, 50, 50, cw / 2, ch / 2), t),
                t,
            )
        )
    out.append((fmt.COLOR_TOPIC, fmt.RAW_IMAGE, fmt.encode_color(np.zeros((ch, cw, 3), np.uint8), t), t))
    out.append((fmt.DEPTH_TOPIC, fmt.RAW_IMAGE, fmt.encode_depth(np.ones((dh, dw), np.uint16), t), t))
    return out


def test_a_declared_colour_topic_without_messages_is_named_as_such(tmp_path):
    """A file cut before its first colour message still declares the topic: the error says so, not only "no messages"."""
    from mcap.writer import Writer

    path = tmp_path / "no_colour_messages.mcap"
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start()
        schemas: dict[str, int] = {}
        channels: dict[str, int] = {}
        for topic, schema_name, payload, t in _frame_messages(10):
            if schema_name not in schemas:
                schemas[schema_name] = writer.register_schema(
                    schema_name, "protobuf", fmt.protobuf_schema_data(type(payload))
                )
            if topic not in channels:
                channels[topic] = writer.register_channel(topic, "protobuf", schemas[schema_name])
            if topic != fmt.COLOR_TOPIC:
                writer.add_message(channels[topic], log_time=t, data=payload.SerializeToString(), publish_time=t)
        writer.finish()
    with pytest.raises(
        RecordingError,
        match="has no /camera/color messages \\(no frames\\), although the topic is declared; "
        "topics present: /camera/calibration, /camera/color, /camera/depth$",
    ):
        McapReplay(path).open()


def test_depth_not_aligned_to_colour(tmp_path, write_messages):
    path = write_messages(tmp_path / "m.mcap", _frame_messages(10, (640, 400), (320, 200)))
    with pytest.raises(RecordingError, match="/camera/depth is 320x200 but /camera/color is 640x400 in frame 0"):
        McapReplay(path).open()
    # a mismatch later in the file (issue 14 item 6): that frame is yielded without depth, counted and reported
    messages = (
        _frame_messages(10)
        + _frame_messages(20, calibration=False)
        + _frame_messages(30, depth_size=(32, 24), calibration=False)
        + _frame_messages(40, calibration=False)
    )
    path = write_messages(tmp_path / "late.mcap", messages)
    with McapReplay(path) as replay:
        got = [(frame.timestamp_ns, frame.depth is not None) for frame in replay]
        assert got == [(10, True), (20, True), (30, False), (40, True)]
        assert replay.stats.skipped_parts == {"depth": 1} and replay.stats.dropped == 0
        assert any("/camera/depth is 32x24 but /camera/color is 64x48 in frame 2" in n for n in replay.stats.notes)
        assert replay.stats.loss_summary() == (
            "skipped 0 frames: 1 depth message unreadable (frames kept without depth)"
        )


def test_calibration_size_must_match(tmp_path, write_messages):
    messages = _frame_messages(10)
    messages[0] = (
        fmt.CALIBRATION_TOPIC,
        fmt.CAMERA_CALIBRATION,
        fmt.encode_calibration(Intrinsics(640, 480, 500, 500, 320, 240), 10),
        10,
    )
    path = write_messages(tmp_path / "cal.mcap", messages)
    with pytest.raises(RecordingError, match="calibration is for 640x480 images but /camera/color is 64x48"):
        McapReplay(path).open()


def test_missing_required_topics_list_what_is_there(tmp_path, write_messages):
    path = write_messages(tmp_path / "nocal.mcap", _frame_messages(10, calibration=False))
    with pytest.raises(
        RecordingError,
        match="has no /camera/calibration topic, which is required; topics present: /camera/color, /camera/depth$",
    ):
        McapReplay(path).open()
    no_color = [m for m in _frame_messages(10) if m[0] != fmt.COLOR_TOPIC]
    path = write_messages(tmp_path / "nocolor.mcap", no_color)
    with pytest.raises(
        RecordingError,
        match="has no /camera/color topic, which is required; topics present: /camera/calibration, /camera/depth$",
    ):
        McapReplay(path).open()


def test_wrong_encoding_and_bad_metadata(tmp_path, write_messages):
    messages = _frame_messages(10)
    messages[1] = (fmt.COLOR_TOPIC, "my.Image", {"pixels": []}, 10)
    path = write_messages(tmp_path / "json.mcap", messages)
    with pytest.raises(
        RecordingError,
        match="/camera/color carries json my.Image messages; expected protobuf "
        "foxglove.RawImage or foxglove.CompressedImage",
    ):
        McapReplay(path).open()
    path = write_messages(tmp_path / "meta.mcap", _frame_messages(10), metadata={"background_frames": "two"})
    with pytest.raises(RecordingError, match="background_frames must be a non-negative integer, got 'two'"):
        McapReplay(path).open()


def test_frames_assembled_by_timestamp(tmp_path, write_messages):
    """Orphan depth (no colour) is not a frame; a calibration before the first frame applies."""
    messages = [
        (
            fmt.CALIBRATION_TOPIC,
            fmt.CAMERA_CALIBRATION,
            fmt.encode_calibration(Intrinsics(64, 48, 50, 50, 32, 24), 5),
            5,
        )
    ]
    messages += [m for m in _frame_messages(10, calibration=False)]
    messages += [m for m in _frame_messages(15, calibration=False) if m[0] == fmt.DEPTH_TOPIC]
    messages += [m for m in _frame_messages(20, calibration=False) if m[0] == fmt.COLOR_TOPIC]
    path = write_messages(tmp_path / "orphan.mcap", messages, metadata={"background_frames": "5"})
    out, stats, info = replay_all(path)
    assert [f.timestamp_ns for f in out] == [10, 20]
    assert out[1].depth is None and stats.missing_depth == 1 and stats.missing_skeleton == 2
    assert info.background_frames == 2 and all(f.background for f in out)


def test_concurrent_random_access(tmp_path, make_frames, record, same_frames):
    frames = make_frames(24)
    path = record(tmp_path / "threads.mcap", frames, chunk_size=6_000)
    errors = []
    with McapReplay(path) as replay:

        def worker(offset):
            try:
                for k in range(48):
                    i = (offset * 7 + k * 5) % 24
                    same_frames([frames[i]], [replay.frame(i)])
            except Exception as exc:  # collected and re-raised in the main thread
                errors.append(exc)

        threads = [threading.Thread(target=worker, args=(n,)) for n in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(timeout=60)
    assert errors == []


def test_replay_streams(tmp_path, make_frames, record):
    """Peak memory while replaying does not grow with the length of the file."""

    def peak_while_replaying(n):
        frames = make_frames(n, size=(320, 200), no_skeleton=tuple(range(n)))
        path = record(tmp_path / f"big{n}.mcap", frames, chunk_size=1 << 20)
        with McapReplay(path) as replay:
            tracemalloc.start()
            try:
                count = sum(1 for _ in replay)
                _, peak = tracemalloc.get_traced_memory()
            finally:
                tracemalloc.stop()
        assert count == n
        return peak, path.stat().st_size

    short_peak, _ = peak_while_replaying(20)
    long_peak, long_size = peak_while_replaying(80)
    assert long_size > 24_000_000
    assert long_peak < 1.25 * short_peak + 1_000_000, (short_peak, long_peak)
    assert long_peak < long_size / 3


@pytest.mark.parametrize("compression", ["lz4", "none"])
def test_other_chunk_compressions(tmp_path, make_frames, record, same_frames, compression):
    frames = make_frames(6)
    out, _, info = replay_all(record(tmp_path / "c.mcap", frames, compression=compression))
    same_frames(frames, out)
    assert info.indexed


@settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    n=st.integers(1, 9),
    chunk_size=st.sampled_from([1, 2_000, 5_000, 100_000]),
    gaps=st.sets(st.integers(0, 8)),
    skeleton_gaps=st.sets(st.integers(0, 8)),
    background=st.integers(0, 3),
    data=st.data(),
)
def test_any_chunking_replays_exactly(
    tmp_path, make_frames, record, same_frames, n, chunk_size, gaps, skeleton_gaps, background, data
):
    frames = make_frames(
        n,
        size=(16, 12),
        no_depth=tuple(gaps),
        no_skeleton=tuple(skeleton_gaps),
        background=background,
        calibration_change=n // 2 if n > 2 else None,
    )
    path = record(tmp_path / f"h{n}_{chunk_size}.mcap", frames, chunk_size=chunk_size)
    with McapReplay(path) as replay:
        same_frames(frames, list(replay))
        i = data.draw(st.integers(0, n - 1))
        j = data.draw(st.integers(i, n))
        same_frames(frames[i:j], list(replay.frames(i, j)))
        same_frames([frames[i]], [replay.frame(i)])
        assert replay.info().missing_depth == len([k for k in gaps if k < n])


def test_source_sequence_numbers_survive_a_recording(tmp_path, make_frames, record):
    """A live source's gaps (dropped frames) stay visible after replay, by index and in a window."""
    import dataclasses

    seqs = [10, 11, 12, 15, 16, 20]
    frames = [dataclasses.replace(f, seq=s) for f, s in zip(make_frames(len(seqs)), seqs)]
    path = record(tmp_path / "gaps.mcap", frames)
    with McapReplay(path) as replay:
        assert [f.seq for f in replay] == seqs
        assert [f.seq for f in replay.frames(2, 5)] == seqs[2:5]
        assert replay.frame(3).seq == 15
