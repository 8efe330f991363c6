"""Frame, Intrinsics, Joint and PalmPoint: construction, immutability, validation messages."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, Intrinsics, Joint, PalmPoint


def intr(w=8, h=6):
    return Intrinsics(w, h, 5.0, 5.0, w / 2, h / 2)


def make(**kw):
    args = dict(
        timestamp_ns=10,
        seq=0,
        color=np.zeros((6, 8, 3), np.uint8),
        depth=np.zeros((6, 8), np.uint16),
        intrinsics=intr(),
    )
    args.update(kw)
    return Frame(**args)


def test_valid_frame_is_immutable():
    color = np.zeros((6, 8, 3), np.uint8)
    f = make(color=color, joints={"right_hand": Joint(1, 2, None, 0.5)})
    with pytest.raises(ValueError):
        f.color[0, 0, 0] = 1
    with pytest.raises(TypeError):
        f.joints["x"] = Joint(0, 0, None, 1)
    with pytest.raises(AttributeError):
        f.seq = 3
    assert f.size == (8, 6)
    assert f.joint("right_hand").confidence == 0.5
    assert f.joint("left_hand") is None
    assert make(joints=None).joint("right_hand") is None


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"timestamp_ns": -1}, "timestamp_ns must be a non-negative int, got -1"),
        ({"timestamp_ns": 1.5}, "timestamp_ns must be a non-negative int, got 1.5"),
        ({"seq": True}, "seq must be a non-negative int"),
        ({"color": np.zeros((6, 8), np.uint8)}, "color must be an (H, W, 3) array, got shape (6, 8)"),
        ({"color": np.zeros((6, 8, 3), np.float32)}, "color must be uint8 RGB, got float32"),
        ({"depth": np.zeros((6, 8), np.float32)}, "depth must be uint16 millimetres, got float32"),
        ({"depth": np.zeros((3, 4), np.uint16)}, "expected shape (6, 8), got (3, 4)"),
        ({"intrinsics": intr(16, 12)}, "intrinsics size 16x12 does not match color size 8x6"),
        ({"joints": {"right_hand": (1, 2)}}, "joint 'right_hand' must be a Joint, got tuple"),
        ({"ground_truth": (1, 2)}, "ground_truth must be a PalmPoint or None, got tuple"),
    ],
)
def test_frame_errors_name_value_and_expectation(kw, message):
    with pytest.raises(InputError) as info:
        make(**kw)
    assert message in str(info.value)


@pytest.mark.parametrize(
    "args, message",
    [
        ((0, 6, 5.0, 5.0, 4.0, 3.0), "width must be a positive int, got 0"),
        ((8, 6, -5.0, 5.0, 4.0, 3.0), "fx must be > 0 pixels, got -5.0"),
        ((8, 6, 5.0, float("nan"), 4.0, 3.0), "fy must be finite, got nan"),
        ((8, 6, 5.0, 5.0, 4.0, 3.0, "fisheye"), "distortion_model must be one of"),
        ((8, 6, 5.0, 5.0, 4.0, 3.0, "plumb_bob", (0.1, 0.2)), "takes 5 coefficients, got 2"),
    ],
)
def test_intrinsics_errors(args, message):
    with pytest.raises(InputError, match=message.replace("(", r"\(").replace(")", r"\)")):
        Intrinsics(*args)


@pytest.mark.parametrize(
    "args, message",
    [
        ((1, 2, None, 1.5), "confidence must be in [0, 1], got 1.5"),
        ((1, 2, -3, 0.5), "depth_mm must be >= 0 or None, got -3.0"),
        (("a", 2, None, 0.5), "joint u must be a number, got 'a'"),
    ],
)
def test_joint_errors(args, message):
    with pytest.raises(InputError) as info:
        Joint(*args)
    assert message in str(info.value)


def test_palm_point_occluded_default():
    assert PalmPoint(3, 4).occluded is False
    assert PalmPoint(3, 4, occluded=True).occluded is True


def test_camera_matrix():
    K = Intrinsics(640, 400, 500.0, 501.0, 320.5, 199.5).K
    np.testing.assert_array_equal(K, [[500.0, 0, 320.5], [0, 501.0, 199.5], [0, 0, 1]])


@given(
    w=st.integers(1, 4000),
    h=st.integers(1, 4000),
    f=st.floats(10, 5000),
    u=st.floats(0, 1),
    v=st.floats(0, 1),
    w2=st.integers(1, 4000),
    h2=st.integers(1, 4000),
)
def test_scaled_intrinsics_map_pixels_consistently(w, h, f, u, v, w2, h2):
    """A ray hitting pixel (u, v) at size WxH hits the resized pixel at the scaled size.

    Independent check: pixel edges scale by w2/w, so a pixel centre p maps to
    (p + 0.5) * s - 0.5; the ray through it must be the same before and after.
    """
    a = Intrinsics(w, h, f, f * 1.1, w * 0.45, h * 0.55)
    b = a.scaled(w2, h2)
    pu, pv = u * (w - 1), v * (h - 1)
    x, y = (pu - a.cx) / a.fx, (pv - a.cy) / a.fy
    qu, qv = (pu + 0.5) * w2 / w - 0.5, (pv + 0.5) * h2 / h - 0.5
    np.testing.assert_allclose([(qu - b.cx) / b.fx, (qv - b.cy) / b.fy], [x, y], rtol=1e-9, atol=1e-9)
