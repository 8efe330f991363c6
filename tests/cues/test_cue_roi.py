import math

import numpy as np
import pytest

from fusion_pf.cues.roi import PAPER_HALF_SIZE, make_roi, subsample
from fusion_pf.errors import InputError


def test_default_window_is_the_papers_141():
    r = make_roi(320, 200, (640, 400))
    assert r.shape == (141, 141) and r.offset == (320 - PAPER_HALF_SIZE, 200 - PAPER_HALF_SIZE)


def test_window_is_sized_in_palm_lengths_from_depth():
    near = make_roi(320, 200, (640, 400), depth_mm=950, fx=500, palms=2.0)  # palm 50 px long
    far = make_roi(320, 200, (640, 400), depth_mm=1900, fx=500, palms=2.0)  # 25 px
    assert near.shape == (201, 201) and far.shape == (101, 101)
    assert near.palm_area == pytest.approx(math.pi * (55 * 500 / 950) ** 2)
    assert far.palm_area == pytest.approx(near.palm_area / 4)


def test_a_measured_palm_length_wins_over_depth():
    r = make_roi(320, 200, (640, 400), palm_px=30.0, depth_mm=950, fx=500, palms=2.0)
    assert r.shape == (121, 121)


def test_a_close_palm_gets_at_most_half_the_shorter_side():
    """A palm 190 px long (350 mm, fx 700) in 960 x 540: 2.6 palms would be the whole frame."""
    r = make_roi(480, 270, (960, 540), depth_mm=350, fx=700)
    assert r.shape == (540, 541)  # half 270, clipped at the bottom edge
    assert make_roi(480, 270, (960, 540), palm_px=40.0).shape == (209, 209)


def test_window_is_clipped_at_the_frame_edge():
    r = make_roi(3, 395, (640, 400), half_size=20)
    assert (r.x0, r.y0, r.x1, r.y1) == (0, 375, 24, 400)
    img = np.zeros((400, 640))
    assert r.crop(img).shape == r.shape


@pytest.mark.parametrize("u,v", [(-50, 10), (700, 10), (10, 400), (math.nan, 5), (5, math.inf)])
def test_prior_outside_or_not_finite_gives_empty_window(u, v):
    assert make_roi(u, v, (640, 400)).empty


@pytest.mark.parametrize(
    "kwargs,needle",
    [({"half_size": 0}, "half_size"), ({"palms": 0.1}, "palms"), ({"min_half": -1}, "min_half")],
)
def test_bad_options_raise_one_line_input_error(kwargs, needle):
    with pytest.raises(InputError, match=needle) as e:
        make_roi(10, 10, (64, 40), **kwargs)
    assert "\n" not in str(e.value)


def test_search_step_keeps_a_whole_frame_search_near_500x280():
    from fusion_pf.cues.roi import full_roi, search_step

    assert [
        search_step(full_roi(w, h)) for w, h in ((320, 200), (640, 480), (960, 540), (1280, 720), (1920, 1080))
    ] == [1, 1, 2, 3, 4]


def test_reduced_search_finds_the_palm_the_full_resolution_search_finds(monkeypatch):
    # a 1280 x 720 synthetic scene: the whole-frame search on every 3rd row and column against
    # the same search on every pixel (SEARCH_PIXELS raised so the step is 1)
    from drivers.synth import SynthSource
    from fusion_pf.cues import roi as roi_module
    from fusion_pf.cues.background import BackgroundModel
    from fusion_pf.cues.colour import ColourCue
    from fusion_pf.cues.depth import DepthCue

    src = SynthSource(frames=12, size=(1280, 720), background_frames=2, seed=4)
    with src:
        frames = list(src)
    bg = BackgroundModel.from_frames(frames[:2])
    reduced = roi_module.SEARCH_PIXELS
    for k in (6, 11):
        f = frames[k]
        found = {}
        for pixels in (reduced, 10**9):
            monkeypatch.setattr(roi_module, "SEARCH_PIXELS", pixels)
            depth = DepthCue()(f.depth, bg.depth, keep_border=True).measurement
            colour = ColourCue()(f.color, bg.color, keep_border=True).measurement
            found[pixels] = (depth, colour)
        (d2, c2), (d1, c1) = found.values()
        assert d2.extras["search_step"] == 3 and d1.extras["search_step"] == 1
        assert math.hypot(d2.u - d1.u, d2.v - d1.v) < 3.0
        assert d2.extras["area"] == pytest.approx(d1.extras["area"], rel=0.1)
        assert abs(d2.quality - d1.quality) < 0.1
        assert math.hypot(c2.u - c1.u, c2.v - c1.v) < 6.0


def test_subsample_is_the_strided_copy_whatever_the_size_and_window():
    """OpenCV's nearest resize where it matches, numpy's strided copy (the reference) elsewhere:
    the same array for colour windows (views into a frame) and depth at every search step."""
    rng = np.random.default_rng(5)
    frame = rng.integers(0, 256, (731, 1283, 3), dtype=np.uint8)
    depth = rng.integers(0, 65535, frame.shape[:2], dtype=np.uint16)
    for y0, y1, x0, x1 in ((0, 720, 0, 1280), (3, 731, 1, 1283), (10, 550, 7, 968), (0, 2, 0, 1283), (5, 6, 9, 10)):
        for step in (1, 2, 3, 4, 5):
            for image in (frame[y0:y1, x0:x1], depth[y0:y1, x0:x1]):
                out = subsample(image, step)
                ref = image[::step, ::step]
                assert out.flags.c_contiguous and out.dtype == image.dtype
                np.testing.assert_array_equal(out, ref, err_msg=f"{(y0, y1, x0, x1)} step {step}")
