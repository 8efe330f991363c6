import math

import cv2
import numpy as np
import pytest

from fusion_pf.cues import DepthCue, make_roi
from fusion_pf.cues import depth as depth_module
from fusion_pf.cues.depth import depth_noise_mm
from fusion_pf.errors import InputError

STAGES = ["I_d1", "I_d2", "I_d3", "I_d4A", "I_d4B", "I_d5", "I_d6", "I_d7", "I_d8", "I_d9", "I_d10"]
# the paper's fixed band, 1.7 m+ in front of the wall: the hand only (no nearest-surface slab)
HAND_BAND = {"range_mm": (0, 2550), "lower": 170, "upper": 255, "nearest_mm": None}


def _err(m, truth):
    return math.hypot(m.u - truth[0], m.v - truth[1])


def test_finds_the_hand_centroid(scene):
    s = scene()
    res = DepthCue(**HAND_BAND)(s["depth"], s["bg_depth"])
    assert res.measurement is not None and res.measurement.source == "depth"
    assert _err(res.measurement, s["truth"]) < 1.0
    assert res.latency_ns > 0


def test_nearest_surface_slab_separates_the_hand_from_the_torso(scene):
    s = scene(hand=(100.0, 100.0))  # the hand in front of the torso
    roi = make_roi(100, 100, (240, 200), half_size=40)
    paper = DepthCue(lower=15, nearest_mm=None)(s["depth"], s["bg_depth"], roi=roi).measurement
    assert paper is None  # the torso fills the window and touches its border
    m = DepthCue(lower=15)(s["depth"], s["bg_depth"], roi=roi).measurement
    assert _err(m, s["truth"]) < 1.0
    assert m.extras["area"] == pytest.approx(np.count_nonzero(s["hand"]), rel=0.05)


def test_stage_names_shapes_and_dtypes(scene):
    s = scene()
    roi = make_roi(150, 90, (240, 200), half_size=30)
    st = DepthCue(**HAND_BAND)(s["depth"], s["bg_depth"], roi=roi, stages=True).stages
    assert list(st) == STAGES
    assert st["I_d1"].dtype == np.uint16 and st["I_d2"].dtype == np.uint16
    assert st["I_d3"].dtype == np.uint8
    for name in STAGES:
        assert st[name].shape == (61, 61)
    for name in STAGES[3:]:
        assert st[name].dtype == np.uint8 and set(np.unique(st[name])) <= {0, 255}
    assert int(st["I_d2"].max()) == 1800  # hand: 3000 - 1200 mm
    assert int(st["I_d3"].max()) == 180  # 1800 mm at 10 mm per level


def test_invalid_depth_never_counts_as_foreground(scene):
    """The paper's reading (invalid_far=False): no depth, in the frame or the background, is never foreground."""
    s = scene()
    depth = s["depth"].copy()
    depth[150:190, 150:230] = 0  # a band of invalid depth far bigger than the hand
    bg = s["bg_depth"].copy()
    bg[5:30, 5:60] = 0  # unknown background where the frame has (near) depth
    depth[5:30, 5:60] = 800
    m = DepthCue(**HAND_BAND, invalid_far=False)(depth, bg).measurement
    assert _err(m, s["truth"]) < 1.0
    zero = np.zeros_like(depth)
    assert DepthCue(**HAND_BAND)(zero, s["bg_depth"]).measurement is None
    assert DepthCue(lower=0)(zero, s["bg_depth"]).measurement is None
    assert DepthCue(**HAND_BAND, invalid_far=False)(s["depth"], zero).measurement is None


def test_invalid_background_counts_as_far_by_default(scene):
    """A hand in front of a background without depth (out of range) is foreground by default."""
    s = scene()
    u, v = int(round(s["truth"][0])), int(round(s["truth"][1]))
    bg = s["bg_depth"].copy()
    bg[max(v - 40, 0) : v + 40, max(u - 40, 0) : u + 40] = 0  # the wall behind the hand is out of range
    m = DepthCue(**HAND_BAND)(s["depth"], bg).measurement
    assert m is not None and _err(m, s["truth"]) < 3.0
    assert (
        DepthCue(**HAND_BAND, invalid_far=False)(s["depth"], bg).measurement is None
        or _err(DepthCue(**HAND_BAND, invalid_far=False)(s["depth"], bg).measurement, s["truth"]) > 3.0
    )


def test_temporal_difference_follows_the_moving_hand_not_static_clutter(scene):
    prev, cur = scene(hand=(146.0, 90.0)), scene(hand=(150.0, 90.0))
    clutter = (slice(150, 195), slice(150, 235))  # a static object at hand depth, larger than the hand
    for s in (prev, cur):
        s["depth"][clutter] = 1150
    static = DepthCue(**HAND_BAND, temporal=False)
    assert _err(static(cur["depth"], cur["bg_depth"]).measurement, cur["truth"]) > 40
    cue = DepthCue(**HAND_BAND)
    first = cue(prev["depth"], prev["bg_depth"]).measurement
    assert first.extras["moved"] is False
    res = cue(cur["depth"], cur["bg_depth"], stages=True)
    assert res.measurement.extras["moved"] is True
    assert _err(res.measurement, cur["truth"]) < 3.0
    entered = cur["hand"] & ~prev["hand"]
    assert np.mean(res.stages["I_d6"][entered] == 255) > 0.95  # the pixels the hand entered
    cue.reset()
    assert cue(cur["depth"], cur["bg_depth"]).measurement.extras["moved"] is False


def test_previous_result_is_realigned_between_windows(scene):
    prev, cur = scene(hand=(146.0, 90.0)), scene(hand=(150.0, 90.0))
    cue = DepthCue(**HAND_BAND)
    cue(prev["depth"], prev["bg_depth"], roi=make_roi(140, 85, (240, 200), half_size=30))
    m = cue(cur["depth"], cur["bg_depth"], roi=make_roi(155, 95, (240, 200), half_size=30)).measurement
    assert m.extras["moved"] is True and _err(m, cur["truth"]) < 3.0


@pytest.mark.parametrize("du,dv", [(5, 0), (-17, 11), (30, -30)])
def test_shift_invariance(scene, du, dv):
    s0, s1 = scene(), scene(shift=(du, dv))
    m0 = DepthCue(**HAND_BAND)(s0["depth"], s0["bg_depth"]).measurement
    m1 = DepthCue(**HAND_BAND)(s1["depth"], s1["bg_depth"]).measurement
    assert (m1.u - m0.u, m1.v - m0.v) == pytest.approx((du, dv), abs=1e-6)


@pytest.mark.parametrize("shape", [(8, 8), (1, 1)])
def test_tiny_and_uniform_frames_give_none(shape):
    d = np.full(shape, 1000, np.uint16)
    assert DepthCue()(d, d.copy()).measurement is None
    assert DepthCue()(d, np.full(shape, 3000, np.uint16)).measurement is None


@pytest.mark.parametrize("u,v", [(0, 0), (239, 199), (-5, 100), (1000, 5)])
def test_roi_partly_or_fully_outside(scene, u, v):
    s = scene()
    cue = DepthCue(**HAND_BAND)
    for _ in range(2):
        m = cue(s["depth"], s["bg_depth"], roi=make_roi(u, v, (240, 200), half_size=50), stages=True).measurement
        assert m is None or (math.isfinite(m.u) and math.isfinite(m.v))


@pytest.mark.parametrize(
    "kwargs,needle",
    [
        ({"range_mm": (100, 100)}, "range_mm"),
        ({"range_mm": 5}, "range_mm"),
        ({"lower": 300}, "lower"),
        ({"upper": 10, "lower": 20}, "upper"),
        ({"dilate": -1}, "dilate"),
    ],
)
def test_bad_options(kwargs, needle):
    with pytest.raises(InputError, match=needle) as e:
        DepthCue(**kwargs)
    assert "\n" not in str(e.value)


def test_wrong_dtype_is_an_input_error(scene):
    s = scene()
    with pytest.raises(InputError, match="uint16"):
        DepthCue()(s["depth"].astype(np.float32), s["bg_depth"])


def test_the_slab_holds_the_palm_not_the_wrist_behind_it():
    """Realistic stereo depth (drivers.synth, 640 x 400), palms 15 cm in front of the body: the forearm
    recedes from the wrist by about 1 mm per mm, so a slab 50 mm deep keeps 3-4 cm of wrist above the
    palm and the region's centroid sits 3.7 px above the palm centre (RMSE 3.8 px). The default slab
    holds the palm (its own depth and the sensor noise, about 20 mm) and little of the wrist."""
    from drivers.synth import SynthSource
    from fusion_pf.cues.background import BackgroundModel

    with SynthSource(
        seed=3004, frames=40, size=(640, 400), hands=2, background_frames=10, joins=1, hand_front=0.15, clothing=3
    ) as src:
        frames = list(src)
    bg = BackgroundModel.from_frames([f for f in frames if f.background])
    err = []
    for f in frames[10:]:  # the hands apart, in front of the torso
        for g in (f.ground_truths or {})["right_hand"], (f.ground_truths or {})["left_hand"]:
            roi = make_roi(g.u, g.v, f.size, half_size=60)
            m = DepthCue(temporal=False)(f.depth, bg.depth, roi=roi).measurement
            err.append((m.u - g.u, m.v - g.v))
    e = np.array(err)
    assert len(e) == 60
    assert abs(e[:, 1].mean()) < 1.5 and np.sqrt((e**2).sum(axis=1).mean()) < 2.0, e.mean(axis=0)


def _stereo_noise(z: np.ndarray, sigma_mm: float, at_mm: float, rng: np.random.Generator) -> np.ndarray:
    """``z`` (mm) with a stereo sensor's noise: uniform in inverse depth, ``sigma_mm`` at ``at_mm``
    (``sigma_z = z^2 sigma_w``), correlated as a matcher's (white noise blurred by a Gaussian of 2 px)."""
    noise = cv2.GaussianBlur(rng.standard_normal(z.shape).astype(np.float32), (13, 13), 2.0)
    w = 1.0 / z + (sigma_mm / at_mm**2 / noise.std()) * noise
    return np.rint(1.0 / w).astype(np.uint16)


def _noisy_palm_and_forearm(sigma_mm: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """160 x 120 depth of a palm disc (radius 22 px, centre (60, 50), 1.2 m) facing the camera and a
    forearm (21 px wide) receding 3 mm per px below it, 0.8 m in front of the wall, with stereo depth
    noise of ``sigma_mm`` at the palm (:func:`_stereo_noise`)."""
    yy, xx = np.mgrid[:160, :120]
    z = np.full((160, 120), 2000.0)
    arm = (abs(xx - 60) <= 10) & (yy >= 60)
    z[arm] = 1200.0 + 3.0 * (yy[arm] - 60)
    palm = (xx - 60) ** 2 + (yy - 50) ** 2 <= 22**2
    z[palm] = 1200.0
    noisy = _stereo_noise(z, sigma_mm, 1200.0, np.random.default_rng(seed))
    out = np.where(palm | arm, noisy, np.uint16(2000))
    return out.astype(np.uint16), np.full((160, 120), 2000, np.uint16)


def test_the_slab_widens_with_the_measured_depth_noise(monkeypatch):
    """Depth noise of 15 mm (a far hand, 3-6x the sensor model's): a fixed 30 mm slab behind the 2nd
    percentile (itself 2 sigma in front of the palm) keeps under half of the palm's pixels, the opening
    breaks them up and the centroid wanders 9.3 px RMSE over 10 noise draws (stereo noise, 15 mm at the
    palm). The slab widened by the measured noise (2 sigma, added in variance) keeps the palm: 3.0 px."""

    def rmse() -> float:
        err = []
        for seed in range(10):
            d, b = _noisy_palm_and_forearm(15.0, seed)
            m = DepthCue(temporal=False, clear_border=False, min_area=0)(d, b).measurement
            err.append(99.0 if m is None else _err(m, (60.0, 50.0)))
        return float(np.sqrt(np.mean(np.square(err))))

    adaptive = rmse()
    monkeypatch.setattr(depth_module, "NOISE_SLAB_SIGMAS", 0.0)  # the fixed slab
    fixed = rmse()
    assert adaptive < 3.5 and fixed > 1.8 * adaptive, (adaptive, fixed)


def test_depth_noise_is_measured_across_slopes_and_edges():
    """Stereo noise of 10 mm at 1.2 m (growing as z^2) on a palm disc and a forearm sloping 3 mm per
    px, against the wall: the second differences cancel the slope and the MAD ignores the region's
    edges."""
    rng = np.random.default_rng(1)
    yy, xx = np.mgrid[:160, :120]
    z = np.full((160, 120), 2000.0)
    fg = ((abs(xx - 60) <= 10) & (yy >= 60)) | ((xx - 60) ** 2 + (yy - 50) ** 2 <= 22**2)
    z[fg] = np.where(yy[fg] >= 60, 1200.0 + 3.0 * (yy[fg] - 60), 1200.0)
    near = _stereo_noise(z, 10.0, 1200.0, rng)
    assert depth_noise_mm(near, fg, 5, 1200.0) == pytest.approx(10.0, rel=0.1)
    assert depth_noise_mm(near, fg & (yy < 3), 5, 1200.0) == 0.0  # too few pixels to measure: the fixed slab


def _palm_on_the_body_beside_a_far_wall(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """160 x 160 depth: a palm disc (radius 18 px, centre (45, 80), 1.2 m) 50 mm in front of the torso
    (columns 5-79), and beside the body (columns 80-159) a wall 2.6 m away that the empty-scene depth
    (3 m there) puts in the coarse region; stereo noise of 10 mm at 1.2 m, 47 mm on the wall."""
    yy, xx = np.mgrid[:160, :160]
    z = np.full((160, 160), 2600.0)
    z[:, 5:80] = 1250.0
    z[(xx - 45) ** 2 + (yy - 80) ** 2 <= 18**2] = 1200.0
    bg = np.full((160, 160), 3000, np.uint16)
    return _stereo_noise(z, 10.0, 1200.0, np.random.default_rng(seed)), bg


def test_the_noise_is_the_palms_not_the_far_walls():
    """The coarse region of a window beside the body holds far wall pixels, 2.2x the palm's depth and
    so about 5x as noisy (stereo). Measured in mm over the whole region, that noise widened the slab
    into the torso 50 mm behind the palm (on the realistic scenes: a 640 x 400 palm 4 cm in front of
    the body measured 120 mm of noise beside it, 50 mm over the body, against the sensor's 50 mm, and
    the depth cue lost 40 % of its frames). Measured in inverse depth and read at the nearest surface,
    it is the palm's: the slab holds the palm alone."""
    for seed in range(3):
        d, b = _palm_on_the_body_beside_a_far_wall(seed)
        assert depth_noise_mm(d, (b - d) > 150, 5, 1200.0) == pytest.approx(10.0, rel=0.15)
        m = DepthCue(temporal=False, clear_border=False)(d, b).measurement
        assert m is not None
        assert _err(m, (45.0, 80.0)) < 1.5
        assert m.extras["area"] < 1.3 * math.pi * 18**2


def test_a_new_background_array_is_searched_against_not_the_kept_one(scene):
    # the whole-frame search keeps its reduced background between frames: a new background array
    # (a background model that changed) must replace it, a window of another size too
    s = scene()
    cue = DepthCue(**HAND_BAND)
    first = cue(s["depth"], s["bg_depth"], keep_border=True).measurement
    assert first is not None and _err(first, s["truth"]) < 2.0
    cue.reset()
    nearer = np.where(s["bg_depth"] > 0, s["depth"], 0).astype(np.uint16)  # the hand is now background
    assert cue(s["depth"], nearer, keep_border=True).measurement is None
    cue.reset()
    again = cue(s["depth"], s["bg_depth"], keep_border=True).measurement
    assert again is not None and (again.u, again.v) == (first.u, first.v)


@pytest.mark.parametrize("seed", range(6))
def test_noise_equals_whole_image_second_differences(seed):
    # the flat-index computation against the definition over whole-image shifted arrays
    rng = np.random.default_rng(seed)
    h, w = rng.integers(3, 60, size=2)
    lag = int(rng.integers(1, 4))
    depth = rng.integers(0, 5000, size=(h, w)).astype(np.uint16)
    mask = rng.random((h, w)) < rng.uniform(0.3, 1.0)
    valid = mask & (depth > 0)
    z = np.where(valid, 1.0 / np.maximum(depth, 1).astype(np.float64), 0.0)  # inverse depth
    dd = []
    for a, m in ((z, valid), (z.T, valid.T)):
        if a.shape[1] > 2 * lag:
            both = m[:, : -2 * lag] & m[:, lag:-lag] & m[:, 2 * lag :]
            dd.append((a[:, : -2 * lag] - 2 * a[:, lag:-lag] + a[:, 2 * lag :])[both])
    d = np.concatenate(dd) if dd else np.empty(0)
    at = float(rng.uniform(300, 4000))
    want = 0.0 if d.size < depth_module.MIN_NOISE_SAMPLES else 1.4826 * np.median(np.abs(d)) / np.sqrt(6.0) * at * at
    assert depth_noise_mm(depth, mask, lag, at) == pytest.approx(want, rel=1e-6)


def test_reduced_whole_frame_search_is_refined_to_the_full_resolution_region(monkeypatch):
    """Issue 25: a whole-frame search at 1280 x 720 reads every 3rd pixel (cheap acquisition), and its
    centroid was that of the subsampled region, 1.6 / 2.2 px from the full-resolution search's on these
    frames; measured again at full resolution in a window around the region only, it is the same."""
    from drivers.synth import SynthSource
    from fusion_pf.cues.background import BackgroundModel
    from fusion_pf.cues.roi import full_roi, search_step

    src = SynthSource(frames=31, seed=6201, size=(1280, 720), background_frames=3)
    background = BackgroundModel.from_frames(src.frames(0, 3)).depth
    for i in (5, 30):
        frame = src.render(i)[0]
        reduced = DepthCue()(frame.depth, background, keep_border=True).measurement
        with monkeypatch.context() as mp:
            mp.setattr(depth_module, "search_step", lambda roi: 1)  # the same search at full resolution
            full = DepthCue()(frame.depth, background, keep_border=True).measurement
        assert reduced.extras["search_step"] == 3 and full.extras["search_step"] == 1
        assert reduced.extras["refined"] and "refined" not in full.extras
        assert math.hypot(reduced.u - full.u, reduced.v - full.v) < 0.05
        assert reduced.extras["area"] == full.extras["area"] and reduced.extras["bbox"] == full.extras["bbox"]
        # the subsampled region's own centroid, as before the refinement: over a pixel off
        with monkeypatch.context() as mp:
            mp.setattr(DepthCue, "_refine", lambda self, depth, background, m, *rest: m)
            coarse = DepthCue()(frame.depth, background, keep_border=True).measurement
        assert math.hypot(coarse.u - full.u, coarse.v - full.v) > 1.0
        gt = frame.ground_truth
        assert math.hypot(reduced.u - gt.u, reduced.v - gt.v) < math.hypot(coarse.u - gt.u, coarse.v - gt.v)
    assert search_step(full_roi(1280, 720)) == 3


def test_noise_reads_an_even_spread_of_at_most_max_pixels_triples():
    """Issue 25: in a reduced whole-frame search (1280 x 720) the noise of a large region is the MAD of
    the second differences starting at every k-th of its pixels (at most MAX_NOISE_PIXELS): 1.0 -> 0.5 ms
    of the search's 2.5 ms; within a few per cent of all pixels' value, which it is without the cap."""
    rng = np.random.default_rng(7)
    h, w, lag, at = 300, 400, 2, 1500.0
    depth = (1500 + rng.normal(0, 4, size=(h, w))).astype(np.uint16)
    mask = rng.random((h, w)) < 0.9
    valid = mask & (depth > 0)
    first = np.flatnonzero(valid)
    k = -(-first.size // depth_module.MAX_NOISE_PIXELS)
    assert first.size > depth_module.MAX_NOISE_PIXELS and k > 1
    starts = np.zeros(h * w, bool)
    starts[first[::k]] = True
    starts = starts.reshape(h, w)
    z = np.where(valid, 1.0 / np.maximum(depth, 1).astype(np.float64), 0.0)
    sampled, every = [], []
    for a, m, s in ((z, valid, starts), (z.T, valid.T, starts.T)):  # whole-image shifts, rows then columns
        both = m[:, : -2 * lag] & m[:, lag:-lag] & m[:, 2 * lag :]
        d = a[:, : -2 * lag] - 2 * a[:, lag:-lag] + a[:, 2 * lag :]
        sampled.append(d[both & s[:, : -2 * lag]])
        every.append(d[both])
    mad = [1.4826 * np.median(np.abs(np.concatenate(x))) / np.sqrt(6.0) * at * at for x in (sampled, every)]
    got = depth_noise_mm(depth, mask, lag, at, depth_module.MAX_NOISE_PIXELS)
    assert got == pytest.approx(mad[0], rel=1e-9) and got != mad[1]
    assert got == pytest.approx(mad[1], rel=0.03)
    assert depth_noise_mm(depth, mask, lag, at) == pytest.approx(mad[1], rel=1e-9)  # tracking windows: every pixel


def test_a_background_learnt_with_the_person_in_view_keeps_a_palm_near_the_torso():
    # no empty scene: the learnt depth background is the torso (1000 mm); the palm is 130 mm in front of it
    bg = np.full((120, 160), 1000, np.uint16)
    depth = bg.copy()
    yy, xx = np.mgrid[:120, :160]
    depth[(xx - 80) ** 2 + (yy - 60) ** 2 <= 14**2] = 870
    assert DepthCue()(depth, bg).measurement is None  # 130 mm < the empty-scene band's 150 mm
    m = DepthCue()(depth, bg, learnt=True).measurement
    assert m is not None and _err(m, (80.0, 60.0)) < 1.0
    assert DepthCue(learnt_lower=15)(depth, bg, learnt=True).measurement is None
