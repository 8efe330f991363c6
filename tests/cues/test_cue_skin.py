import json
import math

import numpy as np
import pytest

from fusion_pf.cues import LabGmmSkin, RgbRuleSkin, RgChromaSkin, SkinCue, grey_world_gains, make_roi, skin_cue
from fusion_pf.cues.skin import fit_gmm_1d
from fusion_pf.errors import InputError

SKIN_NAMES = ["I_S1", "I_S2", "I_S3", "I_S4", "I_S5", "I_S6", "I_S7"]


def _labelled(scene):
    s = scene()
    return s["color"].reshape(-1, 3), s["hand"].ravel(), s


def test_explicit_rgb_rule_matches_eq4_on_hand_picked_pixels():
    px = np.array(
        [[[200, 150, 120], [46, 41, 21], [45, 100, 30], [120, 110, 100], [100, 80, 100], [90, 60, 70]]], np.uint8
    )
    # skin; just above every bound; R<=45; |R-G|<=15; R not > B; skin-like
    assert (RgbRuleSkin().mask(px)[0] > 0).tolist() == [True, False, False, False, False, True]
    assert (RgbRuleSkin().mask(np.array([[[61, 45, 21]]], np.uint8)) > 0).all()


def test_grey_world_gains_make_the_mean_grey():
    img = np.zeros((4, 4, 3), np.uint8)
    img[...] = (100, 150, 200)
    g = grey_world_gains(img)
    assert g * np.array([100, 150, 200]) == pytest.approx([150, 150, 150])
    assert grey_world_gains(np.zeros((3, 3, 3), np.uint8)).tolist() == [1.0, 1.0, 1.0]


def test_rg_chroma_is_eq6_normalised_and_zero_outside_the_rectangle():
    model = RgChromaSkin(r_range=(0.4, 0.6), g_range=(0.25, 0.35), sigma=0.6, grey_world=False)
    centre = np.array([[[125, 75, 50]]], np.uint8)  # r = 0.5, g = 0.3
    p = model.probability(centre)
    assert p[0, 0] == pytest.approx(1.0, abs=1e-3)
    off = np.array([[[110, 75, 65]]], np.uint8)  # r = 0.44, g = 0.3
    expected = math.exp(-((0.44 - 0.5) ** 2) / (2 * 0.06**2))
    assert model.probability(off)[0, 0] == pytest.approx(expected, abs=0.01)
    grey = np.full((2, 2, 3), 120, np.uint8)
    assert model.probability(grey).max() == 0.0
    assert model.score(centre)[0, 0] == 255


def test_grey_world_recovers_skin_under_a_colour_cast(scene):
    s = scene()
    cast = np.clip(s["color"].astype(np.float32) * np.array([0.75, 0.9, 1.25]), 0, 255).astype(np.uint8)
    plain = RgChromaSkin(grey_world=False).mask(cast)
    compensated = RgChromaSkin(grey_world=True).mask(cast)
    recall = lambda m: np.count_nonzero((m > 0) & s["hand"]) / np.count_nonzero(s["hand"])
    assert recall(compensated) > 0.95 > recall(plain)


@pytest.mark.parametrize("model", [RgChromaSkin(), RgbRuleSkin()], ids=["rg", "rgb"])
def test_fixed_models_precision_recall_on_the_handbuilt_scene(scene, model):
    s = scene()
    pred = model.mask(s["color"], s["color"]) > 0
    tp = np.count_nonzero(pred & s["hand"])
    assert tp / np.count_nonzero(pred) > 0.95
    assert tp / np.count_nonzero(s["hand"]) > 0.95


def test_em_recovers_a_two_component_mixture():
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.normal(60, 4, 3000), rng.normal(140, 8, 1000)])
    mean, var, w = fit_gmm_1d(x, 2, rng=np.random.default_rng(0))
    order = np.argsort(mean)
    assert mean[order] == pytest.approx([60, 140], abs=1.0)
    assert np.sqrt(var[order]) == pytest.approx([4, 8], rel=0.1)
    assert w[order] == pytest.approx([0.75, 0.25], abs=0.02)


def test_lab_gmm_fit_predict_save_load_roundtrip(scene, tmp_path):
    px, labels, s = _labelled(scene)
    model = LabGmmSkin.fit(px, labels, components=2, rng=5)
    pred = model.mask(s["color"]) > 0
    tp = np.count_nonzero(pred & s["hand"])
    assert tp / np.count_nonzero(pred) > 0.95 and tp / np.count_nonzero(s["hand"]) > 0.95
    again = LabGmmSkin.fit(px, labels, components=2, rng=5)
    assert np.array_equal(again.means, model.means)  # same seed, same model
    path = tmp_path / "skin.npz"
    model.save(path)
    assert path.stat().st_size < 5000
    loaded = LabGmmSkin.load(path)
    assert np.array_equal(loaded.mask(s["color"]), model.mask(s["color"]))
    with np.load(path, allow_pickle=False) as z:  # plain arrays, no pickle
        assert sorted(z.files) == ["kind", "log_prior", "means", "variances", "version", "weights"]


def test_lab_gmm_rejects_bad_input(tmp_path):
    px = np.zeros((10, 3), np.uint8)
    with pytest.raises(InputError, match="skin and non-skin"):
        LabGmmSkin.fit(px, np.zeros(10, bool))
    with pytest.raises(InputError, match="components"):
        LabGmmSkin.fit(px, np.arange(10) % 2 == 0, components=0)
    bad = tmp_path / "bad.npz"
    bad.write_text(json.dumps({"not": "a model"}))
    with pytest.raises(InputError, match="LabGmmSkin"):
        LabGmmSkin.load(bad)


def test_single_colour_classes_fit_without_nan():
    px = np.array([[200, 150, 120]] * 20 + [[110, 120, 140]] * 20, np.uint8)
    model = LabGmmSkin.fit(px, np.arange(40) < 20, components=3, rng=0)
    assert np.isfinite(model.log_odds(px[None])).all()
    assert (model.mask(px[None])[0] > 0).tolist() == [True] * 20 + [False] * 20


@pytest.mark.parametrize("model", [RgChromaSkin(), RgbRuleSkin()], ids=["rg", "rgb"])
def test_skin_cue_measures_the_hand_in_full_frame_pixels(scene, model):
    s = scene()
    roi = make_roi(145, 95, (240, 200), half_size=30)
    res = SkinCue(model)(s["color"], roi=roi, stages=True)
    m = res.measurement
    assert m.source == model.name
    assert math.hypot(m.u - s["truth"][0], m.v - s["truth"][1]) < 1.0
    assert list(res.stages) == SKIN_NAMES
    assert res.stages["I_S1"].shape == (61, 61, 3)
    for name in SKIN_NAMES[1:]:
        assert res.stages[name].shape == (61, 61) and res.stages[name].dtype == np.uint8


@pytest.mark.parametrize("du,dv", [(9, -4), (-25, 30)])
def test_skin_cue_shift_invariance(scene, du, dv):
    s0, s1 = scene(noise=0.0), scene(noise=0.0, shift=(du, dv))
    m0 = skin_cue(s0["color"], RgbRuleSkin()).measurement
    m1 = skin_cue(s1["color"], RgbRuleSkin()).measurement
    assert (m1.u - m0.u, m1.v - m0.v) == pytest.approx((du, dv), abs=1e-6)


@pytest.mark.parametrize(
    "img",
    [
        np.zeros((8, 8, 3), np.uint8),
        np.full((50, 60, 3), 255, np.uint8),
        np.full((30, 30, 3), (200, 150, 120), np.uint8),
    ],
    ids=["black8", "white", "allskin"],
)
def test_degenerate_images_give_none_without_nan(img):
    for model in (RgChromaSkin(), RgbRuleSkin()):
        res = SkinCue(model, clear_border=True)(img, stages=True)
        assert res.measurement is None
        assert np.isfinite(res.stages["I_S2"].astype(float)).all()
    assert SkinCue(RgbRuleSkin())(img, roi=make_roi(-100, -100, (img.shape[1], img.shape[0]))).measurement is None


@pytest.mark.parametrize(
    "factory,needle",
    [
        (lambda: RgChromaSkin(r_range=(0.6, 0.4)), "r_range"),
        (lambda: RgChromaSkin(sigma=0), "sigma"),
        (lambda: RgChromaSkin(threshold=2), "threshold"),
        (lambda: SkinCue(RgbRuleSkin(), min_area=-3), "min_area"),
        (lambda: SkinCue(object()), "skin model"),
    ],
)
def test_bad_options(factory, needle):
    with pytest.raises(InputError, match=needle) as e:
        factory()
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("candidates", [False, True])
def test_the_palm_centre_not_the_centroid_of_palm_and_forearm(candidates):
    # as the colour cue: a skin palm disc (radius 25 at (80, 100)) with a bare forearm running 110 px to its
    # right; the cue's position is the palm's centre (the centroid lies ~25 px along the forearm), core=False
    # keeps the centroid
    color = np.full((200, 240, 3), (60, 80, 120), np.uint8)
    yy, xx = np.mgrid[:200, :240]
    skin = ((xx - 80) ** 2 + (yy - 100) ** 2 <= 25**2) | ((yy >= 92) & (yy <= 108) & (xx >= 80) & (xx < 215))
    color[skin] = (200, 140, 110)
    for core, near in ((True, 1.0), (False, None)):
        res = SkinCue(RgbRuleSkin(), core=core)(color, candidates=candidates)
        m = res.candidates[0].measurement if candidates else res.measurement
        assert m is not None
        d = math.hypot(m.u - 80.0, m.v - 100.0)
        assert d < near if near else d > 15.0, (core, d)
