"""Small hand-built frames and recordings for the MCAP driver tests.

Fixtures return factories so each test chooses sizes and gaps:

* ``make_frames(n, size=(64, 48), seed=0, background=2, no_depth=(), no_skeleton=(),
  calibration_change=None)`` -> list of Frame: random colour/depth from an rng, two or three
  joints (``left_hand`` absent in odd frames, ``right_hand`` depth null every third frame),
  ground truth (occluded in frames 4-5), 30 fps timestamps.
* ``record(path, frames, **recorder_kwargs)`` -> Path, written by McapRecorder.
* ``write_foxglove(path, frames, color="rgb8", depth="16UC1")`` -> Path, the same content
  written by foxglove-sdk (the Rust MCAP writer), with bgr8 / mono16 / jpeg / png variants.
* ``write_messages(path, messages)`` -> Path: arbitrary (topic, schema, payload, t) messages
  through the mcap Python writer, for files that break the convention.
* ``same_frames(a, b, exact_color=True)`` -> None, asserting two frame lists are equal.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from drivers import mcap_format as fmt
from fusion_pf.frame import Frame, Intrinsics, Joint, PalmPoint
from fusion_pf.rng import as_rng

T0 = 1_700_000_000_000_000_000
PERIOD = 33_333_333


def _make_frames(
    n: int = 12,
    *,
    size: tuple[int, int] = (64, 48),
    seed: int = 0,
    background: int = 2,
    no_depth: tuple[int, ...] = (),
    no_skeleton: tuple[int, ...] = (),
    calibration_change: int | None = None,
) -> list[Frame]:
    rng = as_rng(seed)
    w, h = size
    base = Intrinsics(w, h, 0.78 * w, 0.78 * w, (w - 1) / 2, (h - 1) / 2)
    changed = Intrinsics(w, h, 0.8 * w, 0.81 * w, w / 2, h / 2, "plumb_bob", (0.1, -0.02, 0.001, 0.0, 0.003))
    frames = []
    for i in range(n):
        color = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        depth = None if i in no_depth else rng.integers(0, 6000, (h, w), dtype=np.uint16)
        joints = None
        if i not in no_skeleton:
            u, v = rng.uniform(0, w, 3), rng.uniform(0, h, 3)
            joints = {
                "right_hand": Joint(
                    u[0], v[0], None if i % 3 == 0 else float(rng.uniform(500, 3000)), 0.25 + i / (2 * n)
                ),
                "head": Joint(u[1], v[1], 1500.0, 1.0),
            }
            if i % 2 == 0:
                joints["left_hand"] = Joint(u[2], v[2], 1234.5, 0.0)
        intrinsics = changed if calibration_change is not None and i >= calibration_change else base
        truth = None if i < background else PalmPoint(rng.uniform(0, w), rng.uniform(0, h), occluded=i in (4, 5))
        frames.append(Frame(T0 + i * PERIOD, i, color, depth, intrinsics, joints, truth, background=i < background))
    return frames


def _same_frames(a: list[Frame], b: list[Frame], exact_color: bool = True) -> None:
    assert len(a) == len(b), (len(a), len(b))
    for fa, fb in zip(a, b):
        assert fa.timestamp_ns == fb.timestamp_ns
        assert fa.color.shape == fb.color.shape and fb.color.dtype == np.uint8
        if exact_color:
            assert np.array_equal(fa.color, fb.color), fa.seq
        else:
            assert np.abs(fa.color.astype(int) - fb.color.astype(int)).mean() < 25, fa.seq
        assert (fa.depth is None) == (fb.depth is None)
        if fa.depth is not None:
            assert fb.depth.dtype == np.uint16 and np.array_equal(fa.depth, fb.depth), fa.seq
        assert fa.intrinsics == fb.intrinsics
        assert (None if fa.joints is None else dict(fa.joints)) == (None if fb.joints is None else dict(fb.joints))
        assert fa.ground_truth == fb.ground_truth
        assert fa.background == fb.background


@pytest.fixture
def make_frames():
    return _make_frames


@pytest.fixture
def same_frames():
    return _same_frames


@pytest.fixture
def record():
    from drivers.mcap_record import McapRecorder

    def write(path: Path, frames: list[Frame], **kwargs) -> Path:
        kwargs.setdefault("chunk_size", 16_000)
        with McapRecorder(path, **kwargs) as rec:
            for frame in frames:
                rec.write(frame)
        return Path(path)

    return write


@pytest.fixture
def write_foxglove():
    """Write frames with foxglove-sdk (Rust MCAP writer), in a private logging context."""
    import foxglove
    from foxglove import Channel, Context, Schema
    from foxglove.channels import CameraCalibrationChannel, CompressedImageChannel, RawImageChannel
    from foxglove.mcap import MCAPWriteOptions
    from foxglove.messages import CameraCalibration, CompressedImage, RawImage, Timestamp

    def stamp(t: int) -> Timestamp:
        return Timestamp(t // 1_000_000_000, t % 1_000_000_000)

    def write(
        path: Path,
        frames: list[Frame],
        color: str = "rgb8",
        depth: str = "16UC1",
        chunk_size: int = 50_000,
        background: int = 2,
    ) -> Path:
        ctx = Context()
        options = MCAPWriteOptions(chunk_size=chunk_size, compression_threads=0)
        writer = foxglove.open_mcap(path, context=ctx, writer_options=options)
        cal_ch = CameraCalibrationChannel(fmt.CALIBRATION_TOPIC, context=ctx)
        color_ch = (RawImageChannel if color in ("rgb8", "bgr8") else CompressedImageChannel)(
            fmt.COLOR_TOPIC, context=ctx
        )
        depth_ch = (RawImageChannel if depth in ("16UC1", "mono16") else CompressedImageChannel)(
            fmt.DEPTH_TOPIC, context=ctx
        )

        def json_channel(topic: str, name: str) -> Channel:
            schema = Schema(name=name, encoding="jsonschema", data=fmt.json_schema_data(name))
            return Channel(topic, schema=schema, message_encoding="json", context=ctx)

        skel_ch = json_channel(fmt.SKELETON_TOPIC, fmt.SKELETON_SCHEMA)
        truth_ch = json_channel(fmt.GROUND_TRUTH_TOPIC, fmt.PALM_SCHEMA)
        writer.write_metadata(fmt.RECORDING_METADATA, {fmt.BACKGROUND_FRAMES_KEY: str(background)})
        last = None
        for f in frames:
            t = f.timestamp_ns
            h, w = f.color.shape[:2]
            if f.intrinsics != last:
                k = f.intrinsics
                cal_ch.log(
                    CameraCalibration(
                        timestamp=stamp(t),
                        frame_id="cam",
                        width=w,
                        height=h,
                        distortion_model=k.distortion_model,
                        D=list(k.distortion),
                        K=[k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1],
                    ),
                    log_time=t,
                )
                last = f.intrinsics
            if color in ("rgb8", "bgr8"):
                img = f.color if color == "rgb8" else f.color[..., ::-1]
                # pad each row by 4 bytes to exercise `step`
                padded = np.zeros((h, w * 3 + 4), np.uint8)
                padded[:, : w * 3] = np.ascontiguousarray(img).reshape(h, w * 3)
                color_ch.log(
                    RawImage(
                        timestamp=stamp(t), width=w, height=h, encoding=color, step=w * 3 + 4, data=padded.tobytes()
                    ),
                    log_time=t,
                )
            else:
                ext = ".jpg" if color == "jpeg" else ".png"
                ok, buf = cv2.imencode(
                    ext,
                    cv2.cvtColor(np.ascontiguousarray(f.color), cv2.COLOR_RGB2BGR),
                    [cv2.IMWRITE_JPEG_QUALITY, 95] if ext == ".jpg" else [],
                )
                color_ch.log(CompressedImage(timestamp=stamp(t), format=color, data=buf.tobytes()), log_time=t)
            if f.depth is not None:
                if depth in ("16UC1", "mono16"):
                    depth_ch.log(
                        RawImage(
                            timestamp=stamp(t),
                            width=w,
                            height=h,
                            encoding=depth,
                            step=w * 2,
                            data=f.depth.astype("<u2").tobytes(),
                        ),
                        log_time=t,
                    )
                else:
                    ok, buf = cv2.imencode(".png", np.ascontiguousarray(f.depth))
                    depth_ch.log(CompressedImage(timestamp=stamp(t), format="png", data=buf.tobytes()), log_time=t)
            if f.joints is not None:
                skel_ch.log(fmt.encode_skeleton(f.joints), log_time=t)
            if f.ground_truth is not None:
                truth_ch.log(fmt.encode_palm(f.ground_truth), log_time=t)
        writer.close()
        return Path(path)

    return write


@pytest.fixture
def write_messages():
    """Write ``(topic, schema_name, payload, t)`` messages with the mcap Python writer.

    ``payload`` is a protobuf message (schema = its full name) or a JSON-able object
    (``schema_name`` used with the JSON schema encoding).
    """
    from google.protobuf.message import Message
    from mcap.writer import Writer

    def write(path: Path, messages: list[tuple[str, str, object, int]], metadata: dict | None = None) -> Path:
        with open(path, "wb") as fh:
            writer = Writer(fh, chunk_size=30_000)
            writer.start()
            if metadata is not None:
                writer.add_metadata(fmt.RECORDING_METADATA, metadata)
            channels: dict[str, int] = {}
            for topic, schema_name, payload, t in messages:
                if topic not in channels:
                    if isinstance(payload, Message):
                        sid = writer.register_schema(schema_name, "protobuf", fmt.protobuf_schema_data(type(payload)))
                        channels[topic] = writer.register_channel(topic, "protobuf", sid)
                    else:
                        sid = writer.register_schema(schema_name, "jsonschema", b"{}")
                        channels[topic] = writer.register_channel(topic, "json", sid)
                data = payload.SerializeToString() if isinstance(payload, Message) else fmt.encode_json(payload)
                writer.add_message(channels[topic], log_time=t, data=data, publish_time=t)
            writer.finish()
        return Path(path)

    return write
