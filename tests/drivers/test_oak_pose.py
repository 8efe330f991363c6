"""MoveNet decoding, letterbox geometry and joint derivation of the OAK driver.

The letterbox mapping is checked against depthai's own ImageManip, run on the
host-only pipeline, so the documented math equals what the device does.
"""

from __future__ import annotations

import datetime

import depthai as dai
import numpy as np
import pytest

from drivers.oak_pose import (
    DEPTH_WINDOW_RADIUS,
    HAND_EXTENSION,
    MOVENET_KEYPOINTS,
    Letterbox,
    decode_movenet,
    depth_at,
    joints_from_keypoints,
)
from fusion_pf.errors import InputError


class _OneFrame(dai.node.ThreadedHostNode):
    """Sends one BGR888i frame with a white square at rows/cols given."""

    def __init__(self) -> None:
        super().__init__()
        self.out = self.createOutput()
        self.image: np.ndarray | None = None

    def run(self) -> None:
        frame = dai.ImgFrame()
        frame.setCvFrame(self.image, dai.ImgFrame.Type.BGR888i)
        frame.setTimestamp(datetime.timedelta(seconds=1))
        self.out.send(frame)


def _manip_letterbox(width: int, height: int, nn: int) -> dai.ImgFrame:
    with dai.Pipeline(False) as pipeline:
        src = pipeline.create(_OneFrame)
        src.image = np.zeros((height, width, 3), np.uint8)
        manip = pipeline.create(dai.node.ImageManip)
        manip.setRunOnHost(True)
        manip.initialConfig.setOutputSize(nn, nn, dai.ImageManipConfig.ResizeMode.LETTERBOX)
        manip.initialConfig.setFrameType(dai.ImgFrame.Type.RGB888p)
        src.out.link(manip.inputImage)
        queue = manip.out.createOutputQueue()
        pipeline.start()
        out = queue.get(datetime.timedelta(seconds=5))
        pipeline.stop()
    assert out is not None, "host ImageManip produced no frame"
    return out


@pytest.mark.parametrize(("width", "height", "nn"), [(640, 400, 192), (656, 400, 192), (640, 480, 256)])
def test_letterbox_matches_depthai_imagemanip(width: int, height: int, nn: int) -> None:
    out = _manip_letterbox(width, height, nn)
    transform = out.getTransformation()
    box = Letterbox((width, height), (nn, nn))
    for x_nn, y_nn in [(0.0, 0.0), (nn / 2, nn / 2), (10.5, 150.25), (nn, nn)]:
        ref = transform.invTransformPoint(dai.Point2f(x_nn, y_nn))
        u, v = box.to_frame(np.array([x_nn / nn]), np.array([y_nn / nn]))
        # our (u, v) has pixel centres at integers; depthai's points are continuous
        assert u[0] + 0.5 == pytest.approx(ref.x, abs=1e-3)
        assert v[0] + 0.5 == pytest.approx(ref.y, abs=1e-3)


def test_letterbox_geometry_640x400() -> None:
    box = Letterbox((640, 400), (192, 192))
    assert box.scale == pytest.approx(0.3)
    assert (box.pad_x, box.pad_y) == (pytest.approx(0.0), pytest.approx(36.0))


def test_letterbox_rejects_bad_sizes() -> None:
    with pytest.raises(InputError, match="frame_size"):
        Letterbox((0, 400), (192, 192))
    with pytest.raises(InputError, match="input_size"):
        Letterbox((640, 400), (192.0, 192))  # type: ignore[arg-type]


def _movenet(points: dict[str, tuple[float, float, float]], default=(0.5, 0.5, 0.1)) -> np.ndarray:
    """A (1, 1, 17, 3) MoveNet tensor (y, x, score) with the given keypoints."""
    out = np.array([points.get(name, default) for name in MOVENET_KEYPOINTS], dtype=np.float32)
    return out.reshape(1, 1, 17, 3)


def test_decode_movenet_maps_to_colour_pixels() -> None:
    box = Letterbox((640, 400), (192, 192))
    # nose at the image centre, right wrist at the top-left corner of the picture area
    tensor = _movenet({"nose": (0.5, 0.5, 0.9), "right_wrist": (36 / 192, 0.0, 0.75)})
    kp = decode_movenet(tensor, box)
    assert kp.shape == (17, 3)
    nose = kp[MOVENET_KEYPOINTS.index("nose")]
    assert nose == pytest.approx([319.5, 199.5, 0.9], abs=1e-5)
    wrist = kp[MOVENET_KEYPOINTS.index("right_wrist")]
    assert wrist == pytest.approx([-0.5, -0.5, 0.75], abs=1e-5)


def test_decode_movenet_rejects_wrong_tensors() -> None:
    box = Letterbox((640, 400), (192, 192))
    with pytest.raises(InputError, match="has 48 values; expected 51"):
        decode_movenet(np.zeros((16, 3)), box)
    bad = _movenet({"nose": (0.5, 0.5, 1.5)})
    with pytest.raises(InputError, match=r"scores must be in \[0, 1\]"):
        decode_movenet(bad, box)
    with pytest.raises(InputError, match="finite"):
        decode_movenet(_movenet({"nose": (np.nan, 0.5, 0.5)}), box)


def test_depth_at_is_median_of_nonzero_window() -> None:
    depth = np.zeros((20, 30), np.uint16)
    depth[8:13, 10:15] = np.arange(25, dtype=np.uint16).reshape(5, 5) * 10  # one zero at [8, 10]
    depth[10, 12] = 5000  # outlier, the median ignores it
    value = depth_at(depth, 12.2, 9.8)
    window = depth[8:13, 10:15]
    assert value == float(np.median(window[window > 0]))
    assert DEPTH_WINDOW_RADIUS == 2


def test_depth_at_none_cases_and_border_clipping() -> None:
    depth = np.zeros((10, 10), np.uint16)
    assert depth_at(depth, 5, 5) is None  # all invalid
    assert depth_at(None, 5, 5) is None
    depth[0, 0] = 700
    assert depth_at(depth, 0.4, -0.4) == 700.0  # window clipped at the corner
    assert depth_at(depth, -1.0, 0.0) is None  # outside the image
    assert depth_at(depth, 10.0, 3.0) is None
    with pytest.raises(InputError, match="radius"):
        depth_at(depth, 1, 1, radius=-1)


def test_joints_derive_hands_head_and_torso() -> None:
    box = Letterbox((640, 400), (192, 192))
    tensor = _movenet(
        {
            "nose": (0.3, 0.5, 0.95),
            "right_elbow": (0.5, 0.25, 0.8),
            "right_wrist": (0.5, 0.35, 0.6),
            "left_elbow": (0.5, 0.7, 0.4),
            "left_wrist": (0.4, 0.7, 0.9),
            "left_shoulder": (0.4, 0.6, 0.7),
            "right_shoulder": (0.4, 0.4, 0.8),
            "left_hip": (0.7, 0.6, 0.5),
            "right_hip": (0.7, 0.4, 0.6),
        }
    )
    kp = decode_movenet(tensor, box)
    depth = np.full((400, 640), 1234, np.uint16)
    joints = joints_from_keypoints(kp, depth)
    assert set(MOVENET_KEYPOINTS) | {"head", "torso", "right_hand", "left_hand"} == set(joints)
    elbow, wrist = joints["right_elbow"], joints["right_wrist"]
    hand = joints["right_hand"]
    assert hand.u == pytest.approx(wrist.u + HAND_EXTENSION * (wrist.u - elbow.u))
    assert hand.v == pytest.approx(wrist.v + HAND_EXTENSION * (wrist.v - elbow.v))
    assert hand.confidence == pytest.approx(0.6)
    assert hand.depth_mm == 1234.0
    left = joints["left_hand"]
    assert left.u == pytest.approx(joints["left_wrist"].u)
    assert left.v < joints["left_wrist"].v  # elbow below the wrist -> hand above it
    assert left.confidence == pytest.approx(0.4)
    assert joints["head"] == joints["nose"]
    trunk = [joints[n] for n in ("left_shoulder", "right_shoulder", "left_hip", "right_hip")]
    assert joints["torso"].u == pytest.approx(np.mean([j.u for j in trunk]))
    assert joints["torso"].v == pytest.approx(np.mean([j.v for j in trunk]))
    assert joints["torso"].confidence == pytest.approx(0.5)


def test_joints_keep_confidence_and_skip_depth_outside() -> None:
    box = Letterbox((640, 400), (192, 192))
    kp = decode_movenet(_movenet({"left_ankle": (0.99, 0.5, 0.05)}), box)  # in the bottom padding
    joints = joints_from_keypoints(kp, np.full((400, 640), 900, np.uint16))
    ankle = joints["left_ankle"]
    assert ankle.v > 400 and ankle.depth_mm is None
    assert ankle.confidence == pytest.approx(0.05)
    with pytest.raises(InputError, match=r"shape \(17, 3\)"):
        joints_from_keypoints(kp[:5], None)
