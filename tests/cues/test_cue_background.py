import numpy as np
import pytest

from fusion_pf.cues import BackgroundModel, skeleton_cue
from fusion_pf.cues.background import AdaptiveBackground, median_valid_depth
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


def test_adaptive_background_teaches_one_band_per_frame_like_a_whole_frame_mog2():
    """Issue 25: MOG2 on the whole 1280x720 frame every 5th frame cost that frame ~20 ms; the learnt frame
    now teaches one band of rows per frame in turn. MOG2 models each pixel on its own, so once a cycle is
    complete each band equals a whole-frame MOG2 fed the same learnt frames (every 5th)."""
    import cv2

    from fusion_pf.cues.background import AdaptiveBackground

    rng = np.random.default_rng(5)
    h, w, every = 23, 16, 5
    intr = Intrinsics(w, h, 50.0, 50.0, w / 2, h / 2)

    def frame(i: int) -> Frame:
        color = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
        depth = rng.integers(500, 3000, (h, w), dtype=np.uint16)
        return Frame(i * 33_000_000, i, color, depth, intr)

    warm = [frame(i) for i in range(3)]
    stream = [frame(i) for i in range(3, 3 + 4 * every - 1)]  # three learnt frames, each fully taught
    model = AdaptiveBackground(warm, history=20, every=every)
    edges = np.linspace(0, h, every + 1).round().astype(int)
    for seen, f in enumerate(stream, 1):
        before = model.color.copy()
        model.adapt(f)
        rows = np.flatnonzero(np.any(model.color != before, axis=(1, 2)))
        if seen < every:  # nothing learnt before the first learnt frame
            assert rows.size == 0
        else:  # one band per frame, in turn
            b = seen % every
            assert rows.size and edges[b] <= rows.min() and rows.max() < edges[b + 1]
    learnt = warm + stream[every - 1 :: every]
    for b in range(every):
        ref = cv2.createBackgroundSubtractorMOG2(history=20, detectShadows=False)
        for f in learnt:
            ref.apply(np.ascontiguousarray(f.color[edges[b] : edges[b + 1]]))
        np.testing.assert_array_equal(model.color[edges[b] : edges[b + 1]], ref.getBackgroundImage())
        far = np.max([f.depth[edges[b] : edges[b + 1]] for f in learnt], axis=0)
        np.testing.assert_array_equal(model.depth[edges[b] : edges[b + 1]], far)


def test_only_models_learnt_from_the_stream_are_flagged_learnt():
    frame = _frame(20, [[900] * 4] * 3)
    assert not BackgroundModel.from_frames([frame]).learnt  # empty-scene frames
    assert BackgroundModel.from_frames([frame], learnt=True).learnt
    assert BackgroundModel.running(2).learnt
    assert AdaptiveBackground([frame]).learnt
