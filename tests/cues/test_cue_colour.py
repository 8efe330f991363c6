import math

import numpy as np
import pytest

from fusion_pf.cues import ColourCue, colour_cue, make_roi
from fusion_pf.errors import InputError

STAGES = ["I_C1", "I_C2", "I_C3", "I_C4A", "I_C4B", "I_C5", "I_C6", "I_C7", "I_C8", "I_C9"]


def test_finds_the_hand_centroid_full_frame(scene):
    s = scene()
    res = ColourCue()(s["color"], s["background"])
    m = res.measurement
    assert m is not None and m.source == "colour"
    assert math.hypot(m.u - s["truth"][0], m.v - s["truth"][1]) < 1.0
    assert 0.0 < m.quality <= 1.0
    assert res.latency_ns > 0


def test_roi_result_is_in_full_frame_pixels(scene):
    s = scene()
    roi = make_roi(140, 100, (240, 200), half_size=35)
    m = ColourCue()(s["color"], s["background"], roi=roi).measurement
    assert math.hypot(m.u - s["truth"][0], m.v - s["truth"][1]) < 1.0
    assert m.extras["roi"] == roi.as_list()


def test_stage_names_shapes_and_dtypes(scene):
    s = scene()
    roi = make_roi(150, 90, (240, 200), half_size=30)
    st_ = ColourCue()(s["color"], s["background"], roi=roi, stages=True).stages
    assert list(st_) == STAGES
    assert st_["I_C1"].shape == (61, 61, 3) and st_["I_C2"].shape == (61, 61, 3)
    for name in STAGES:
        assert st_[name].dtype == np.uint8
        if name not in ("I_C1", "I_C2"):
            assert st_[name].shape == (61, 61)
        if name not in ("I_C1", "I_C2", "I_C3"):
            assert set(np.unique(st_[name])) <= {0, 255}
    # I_C5 is the AND of the two thresholds; the dark clothing is removed by the upper one
    assert np.array_equal(st_["I_C5"], st_["I_C4A"] & st_["I_C4B"])
    assert ColourCue()(s["color"], s["background"], roi=roi).stages == {}


@pytest.mark.parametrize("du,dv", [(7, 0), (0, -9), (-23, 17), (31, 5)])
def test_shift_invariance(scene, du, dv):
    s0, s1 = scene(noise=0.0), scene(noise=0.0, shift=(du, dv))
    m0 = ColourCue()(s0["color"], s0["background"]).measurement
    m1 = ColourCue()(s1["color"], s1["background"]).measurement
    assert (m1.u - m0.u, m1.v - m0.v) == pytest.approx((du, dv), abs=1e-6)
    r0 = make_roi(150, 90, (240, 200), half_size=30)
    r1 = make_roi(150 + du, 90 + dv, (240, 200), half_size=30)
    w0 = ColourCue()(s0["color"], s0["background"], roi=r0).measurement
    w1 = ColourCue()(s1["color"], s1["background"], roi=r1).measurement
    assert (w1.u - w0.u, w1.v - w0.v) == pytest.approx((du, dv), abs=1e-6)


def test_uniform_image_gives_none():
    img = np.full((60, 80, 3), 128, np.uint8)
    assert ColourCue()(img, img.copy()).measurement is None
    assert ColourCue()(img, None).measurement is None


@pytest.mark.parametrize("u,v", [(2, 3), (237, 198), (-10, 50), (500, 500), (math.nan, 1.0)])
def test_roi_partly_or_fully_outside(scene, u, v):
    s = scene()
    res = ColourCue()(s["color"], s["background"], roi=make_roi(u, v, (240, 200), half_size=40), stages=True)
    m = res.measurement
    assert m is None or (math.isfinite(m.u) and math.isfinite(m.v))


def test_hand_half_outside_the_roi_is_not_taken_from_the_border(scene):
    s = scene()
    roi = make_roi(150 + 20, 90, (240, 200), half_size=20)  # the disc crosses the left window edge
    assert ColourCue()(s["color"], s["background"], roi=roi).measurement is None
    assert ColourCue(clear_border=False)(s["color"], s["background"], roi=roi).measurement is not None


def test_eight_by_eight_frames_give_none():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, (8, 8, 3), dtype=np.uint8)
    b = rng.integers(0, 256, (8, 8, 3), dtype=np.uint8)
    res = ColourCue()(a, b, stages=True)
    assert res.measurement is None
    assert res.stages["I_C9"].shape == (8, 8)


@pytest.mark.parametrize(
    "kwargs,needle",
    [
        ({"lower": -1}, "lower"),
        ({"lower": 50, "upper": 40}, "upper"),
        ({"min_area": 1.5}, "min_area"),
        ({"dilate": 99}, "dilate"),
    ],
)
def test_bad_options(kwargs, needle):
    with pytest.raises(InputError, match=needle) as e:
        ColourCue(**kwargs)
    assert "\n" not in str(e.value)


def test_mismatched_background_is_an_input_error(scene):
    s = scene()
    with pytest.raises(InputError, match="background"):
        colour_cue(s["color"], s["background"][:10])


def test_the_palm_centre_not_the_centroid_of_palm_and_forearm():
    # a palm disc (radius 25 at (80, 100)) with a bare forearm running 110 px to its right:
    # the cue's position is the palm's centre (the plain centroid lies ~25 px along the forearm)
    background = np.full((200, 240, 3), 100, np.uint8)
    color = background.copy()
    yy, xx = np.mgrid[:200, :240]
    skin = ((xx - 80) ** 2 + (yy - 100) ** 2 <= 25**2) | ((yy >= 92) & (yy <= 108) & (xx >= 80) & (xx < 215))
    color[skin] = 140
    m = ColourCue()(color, background).measurement
    assert m is not None
    assert math.hypot(m.u - 80.0, m.v - 100.0) < 1.0
