import numpy as np
import pytest

from fusion_pf.cues import BackgroundModel, skeleton_cue
from fusion_pf.cues.background import median_valid_depth
from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, Intrinsics, Joint

INTR = Intrinsics(4, 3, 100.0, 100.0, 1.5, 1.0)


def _frame(value, depth, seq=0, joints=None):
    return Frame(seq * 1000, seq, np.full((3, 4, 3), value, np.uint8), np.asarray(depth, np.uint16), INTR, joints)


def test_median_of_valid_depth_ignores_zeros():
    stack = np.array([[[0, 5]], [[1000, 0]], [[1010, 0]], [[0, 0]], [[3000, 7]]], np.uint16)
    out = median_valid_depth(stack)
    assert out.tolist() == [[1010, 6]]
    assert median_valid_depth(np.zeros((3, 2, 2), np.uint16)).tolist() == [[0, 0], [0, 0]]


def test_from_frames_is_the_per_pixel_median():
    frames = [_frame(v, np.full((3, 4), d)) for v, d in [(10, 0), (200, 1500), (30, 1600), (20, 0)]]
    bg = BackgroundModel.from_frames(frames)
    assert bg.color.shape == (3, 4, 3) and bg.color.dtype == np.uint8
    assert (bg.color == 25).all()
    assert (bg.depth == 1550).all() and bg.depth.dtype == np.uint16


def test_running_model_freezes_after_k_frames():
    bg = BackgroundModel.running(3)
    assert not bg.ready
    for i, v in enumerate([10, 20, 30, 250, 250]):
        bg.update(_frame(v, np.full((3, 4), 1000 + i), seq=i))
        assert bg.ready
    assert (bg.color == 20).all() and (bg.depth == 1001).all()


def test_background_input_errors():
    with pytest.raises(InputError, match="at least one"):
        BackgroundModel.from_frames([])
    with pytest.raises(InputError, match="background frames"):
        BackgroundModel.running(0)
    with pytest.raises(InputError, match="does not match"):
        BackgroundModel(np.zeros((3, 4, 3), np.uint8), np.zeros((2, 2), np.uint16))


def test_skeleton_cue_uses_the_joint_and_its_confidence():
    f = _frame(0, np.zeros((3, 4)), joints={"right_hand": Joint(1.5, 2.0, 1200.0, 0.7)})
    m = skeleton_cue(f).measurement
    assert (m.source, m.u, m.v, m.quality) == ("skeleton", 1.5, 2.0, 0.7)
    assert m.extras["depth_mm"] == 1200.0
    assert skeleton_cue(f, "left_hand").measurement is None
    assert skeleton_cue(_frame(0, np.zeros((3, 4)))).measurement is None
    zero = _frame(0, np.zeros((3, 4)), joints={"right_hand": Joint(1.0, 1.0, None, 0.0)})
    assert skeleton_cue(zero).measurement is None
