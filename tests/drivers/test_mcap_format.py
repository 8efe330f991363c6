"""Encoders and decoders of the recording convention (drivers/mcap_format.py)."""

import json

import cv2
import numpy as np
import pytest
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
from google.protobuf.descriptor_pb2 import FileDescriptorSet

from drivers import mcap_format as fmt
from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Intrinsics, Joint, PalmPoint
from fusion_pf.rng import as_rng


@pytest.fixture
def rgb():
    return as_rng(1).integers(0, 256, (30, 40, 3), dtype=np.uint8)


@pytest.fixture
def depth():
    return as_rng(2).integers(0, 65535, (30, 40), dtype=np.uint16)


@pytest.mark.parametrize("form", ["raw", "png"])
def test_lossless_color_roundtrip(rgb, form):
    msg = fmt.encode_color(rgb, 1_500_000_000_123, form)
    assert msg.timestamp.seconds == 1500 and msg.timestamp.nanos == 123 and msg.frame_id == fmt.FRAME_ID
    schema = fmt.RAW_IMAGE if form == "raw" else fmt.COMPRESSED_IMAGE
    out = fmt.decode_color(schema, msg.SerializeToString())
    assert out.dtype == np.uint8 and np.array_equal(out, rgb)


def test_jpeg_color_is_close(rgb):
    smooth = cv2.GaussianBlur(rgb, (9, 9), 3)
    msg = fmt.encode_color(smooth, 0, "jpeg", jpeg_quality=95)
    assert msg.format == "jpeg" and msg.data[:2] == b"\xff\xd8"
    out = fmt.decode_color(fmt.COMPRESSED_IMAGE, msg.SerializeToString())
    assert out.shape == smooth.shape
    assert np.abs(out.astype(int) - smooth.astype(int)).mean() < 3
    low = fmt.encode_color(smooth, 0, "jpeg", jpeg_quality=5)
    assert len(low.data) < len(msg.data)


def test_bgr8_with_row_padding_decodes_to_rgb(rgb):
    h, w = rgb.shape[:2]
    rows = np.full((h, w * 3 + 8), 77, np.uint8)
    rows[:, : w * 3] = rgb[..., ::-1].reshape(h, w * 3)
    msg = RawImage(width=w, height=h, encoding="bgr8", step=w * 3 + 8, data=rows.tobytes())
    assert np.array_equal(fmt.decode_color(fmt.RAW_IMAGE, msg.SerializeToString()), rgb)


@pytest.mark.parametrize("form", ["raw", "png"])
def test_depth_roundtrip(depth, form):
    msg = fmt.encode_depth(depth, 5, form)
    schema = fmt.RAW_IMAGE if form == "raw" else fmt.COMPRESSED_IMAGE
    if form == "raw":
        assert msg.encoding == "16UC1" and msg.step == 80
        assert msg.data[:2] == int(depth[0, 0]).to_bytes(2, "little")
    out = fmt.decode_depth(schema, msg.SerializeToString())
    assert out.dtype == np.uint16 and np.array_equal(out, depth)


def test_mono16_is_read_as_16uc1(depth):
    msg = RawImage(width=40, height=30, encoding="mono16", step=80, data=depth.astype("<u2").tobytes())
    assert np.array_equal(fmt.decode_depth(fmt.RAW_IMAGE, msg.SerializeToString()), depth)


@pytest.mark.parametrize(
    "intrinsics",
    [
        Intrinsics(640, 400, 499.2, 500.1, 319.5, 199.5),
        Intrinsics(64, 48, 50, 51, 32, 24, "plumb_bob", (0.1, -0.2, 0.001, 0.002, 0.05)),
        Intrinsics(64, 48, 50, 51, 32, 24, "rational_polynomial", tuple(np.linspace(-0.1, 0.1, 8))),
    ],
)
def test_calibration_roundtrip(intrinsics):
    msg = fmt.encode_calibration(intrinsics, 9)
    assert list(msg.K) == pytest.approx(intrinsics.K.ravel().tolist())
    assert list(msg.P)[:3] == [intrinsics.fx, 0.0, intrinsics.cx]
    assert fmt.decode_calibration(msg.SerializeToString()) == intrinsics


def test_empty_distortion_model_means_none():
    msg = fmt.encode_calibration(Intrinsics(8, 6, 5, 5, 4, 3), 0)
    msg.distortion_model = ""
    assert fmt.decode_calibration(msg.SerializeToString()).distortion_model == "none"


def test_skeleton_and_palm_roundtrip():
    joints = {"right_hand": Joint(1.5, 2.25, None, 0.3), "head": Joint(10, 20, 1500.0, 1.0)}
    obj = json.loads(fmt.encode_json(fmt.encode_skeleton(joints)))
    assert obj == {
        "joints": [
            {"name": "right_hand", "u": 1.5, "v": 2.25, "depth_mm": None, "confidence": 0.3},
            {"name": "head", "u": 10.0, "v": 20.0, "depth_mm": 1500.0, "confidence": 1.0},
        ]
    }
    assert fmt.decode_skeleton(obj) == joints
    palm = PalmPoint(3.0, 4.5, occluded=True)
    assert fmt.decode_palm(json.loads(fmt.encode_json(fmt.encode_palm(palm)))) == palm
    assert fmt.decode_palm({"u": 1, "v": 2}) == PalmPoint(1, 2, False)


def test_schemas_are_self_describing():
    fds = FileDescriptorSet.FromString(fmt.protobuf_schema_data(RawImage))
    names = [f.name for f in fds.file]
    assert names[-1] == "foxglove/RawImage.proto" and "google/protobuf/timestamp.proto" in names
    for name in fmt.JSON_SCHEMAS:
        doc = json.loads(fmt.json_schema_data(name))
        assert doc["title"] == name and doc["type"] == "object" and doc["required"]
    custom = json.loads(fmt.json_schema_data("my.Thing", {"type": "object"}))
    assert custom == {"type": "object"}


@pytest.mark.parametrize(
    "call, message",
    [
        (lambda: fmt.decode_color(fmt.RAW_IMAGE, b"\xff\xff\xff"), "not a valid foxglove.RawImage"),
        (
            lambda: fmt.decode_color(
                fmt.RAW_IMAGE,
                RawImage(width=4, height=2, encoding="rgba8", step=16, data=bytes(32)).SerializeToString(),
            ),
            "encoding 'rgba8' is not supported",
        ),
        (
            lambda: fmt.decode_color(
                fmt.RAW_IMAGE, RawImage(width=4, height=2, encoding="rgb8", step=12, data=bytes(20)).SerializeToString()
            ),
            "needs 24 bytes, got 20",
        ),
        (
            lambda: fmt.decode_color(
                fmt.RAW_IMAGE, RawImage(width=4, height=2, encoding="rgb8", step=6, data=bytes(24)).SerializeToString()
            ),
            "step 6 is smaller than width 4",
        ),
        (
            lambda: fmt.decode_color(
                fmt.COMPRESSED_IMAGE, CompressedImage(format="webp", data=b"x").SerializeToString()
            ),
            "format 'webp' is not supported",
        ),
        (
            lambda: fmt.decode_color(
                fmt.COMPRESSED_IMAGE, CompressedImage(format="jpeg", data=b"nope").SerializeToString()
            ),
            "jpeg data \\(4 bytes\\) cannot be decoded",
        ),
        (lambda: fmt.decode_color("sensor_msgs/Image", b""), "schema 'sensor_msgs/Image' is not supported"),
        (
            lambda: fmt.decode_depth(
                fmt.RAW_IMAGE, RawImage(width=2, height=2, encoding="32FC1", step=8, data=bytes(16)).SerializeToString()
            ),
            "encoding '32FC1' is not supported for depth",
        ),
        (
            lambda: fmt.decode_depth(
                fmt.COMPRESSED_IMAGE, fmt.encode_color(np.zeros((4, 4, 3), np.uint8), 0, "png").SerializeToString()
            ),
            "depth PNG must be 16-bit single-channel, got uint8 with 3 channel",
        ),
        (lambda: fmt.decode_skeleton({"joints": [{"name": "a", "u": 1, "v": 2}]}), "joint 0 has no 'confidence'"),
        (
            lambda: fmt.decode_skeleton({"joints": [{"name": "a", "u": 1, "v": 2, "confidence": 2}]}),
            "joint 'a': joint confidence must be in \\[0, 1\\], got 2.0",
        ),
        (lambda: fmt.decode_skeleton({"bones": []}), "expected an object with a 'joints' list"),
        (lambda: fmt.decode_palm({"u": 1, "v": 2, "occluded": "yes"}), "'occluded' must be true or false"),
        (lambda: fmt.decode_json(b"{nope", "/x at t=1 ns"), "/x at t=1 ns: not valid JSON"),
    ],
)
def test_bad_messages_name_the_problem(call, message):
    with pytest.raises(RecordingError, match=message):
        call()


def test_bad_calibration_is_rejected():
    msg = fmt.encode_calibration(Intrinsics(8, 6, 5, 5, 4, 3), 0)
    msg.distortion_model = "fisheye62"
    with pytest.raises(RecordingError, match="distortion_model 'fisheye62' is not supported"):
        fmt.decode_calibration(msg.SerializeToString())
    msg.distortion_model = "none"
    msg.K[0] = 0.0
    with pytest.raises(RecordingError, match="fx must be > 0"):
        fmt.decode_calibration(msg.SerializeToString())


def test_encoder_input_errors(rgb, depth):
    with pytest.raises(InputError, match="not valid JSON"):
        fmt.encode_json({"u": float("nan")})
    with pytest.raises(InputError, match="colour format must be one of"):
        fmt.encode_color(rgb, 0, "webp")
    with pytest.raises(InputError, match="depth format must be one of"):
        fmt.encode_depth(depth, 0, "jpeg")
    with pytest.raises(InputError, match="unknown JSON schema name 'fusion_pf.Nope'"):
        fmt.json_schema_data("fusion_pf.Nope")
    with pytest.raises(InputError, match="timestamp_ns must be an integer"):
        fmt.check_timestamp(1.5)
    with pytest.raises(InputError, match="must be in \\[0, 2\\*\\*63\\)"):
        fmt.check_timestamp(-1)
