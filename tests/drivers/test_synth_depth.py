"""The realistic stereo depth model of the synthetic scene (drivers/synth.py, "Depth").

Every figure is measured on depth images rendered here, against the noise-free depth
of the same scene and the stereo geometry (``d = f B / z``); none is copied from a run.
"""

import math

import cv2
import numpy as np
import pytest

from drivers import synth_scene as sc
from drivers.synth import (
    BASELINE_MM,
    DISPARITY_NOISE_PX,
    EDGE_BAND_PX,
    EDGE_FLYING_FRACTION,
    EDGE_INVALID_FRACTION,
    EDGE_STEP_PX,
    MAX_DISPARITY_PX,
    MAX_RANGE_MM,
    SUBPIXEL_STEPS,
    SynthSource,
)
from fusion_pf.errors import InputError


def model_sigma_mm(z_mm, fb):
    """Disparity noise and the uniform error of the 1/8 px and 1 mm roundings, as depth."""
    disparity_var = DISPARITY_NOISE_PX**2 + (1.0 / SUBPIXEL_STEPS) ** 2 / 12.0
    return np.sqrt((z_mm**2 / fb) ** 2 * disparity_var + 1.0 / 12.0)


def plane(src, z_m):
    w, h = src.size
    return np.full((h, w), z_m, np.float32)


@pytest.mark.parametrize("size", [(640, 400), (320, 200)])
def test_noise_std_grows_with_z_squared(size):
    src = SynthSource(size=size)
    fb = src.intrinsics.fx * BASELINE_MM
    border = math.ceil(fb / 450.0) + 1  # the right camera's border band at the nearest plane
    zs = np.array([450.0, 700.0, 1000.0, 1500.0, 2200.0, 3200.0, 4400.0])
    sigmas = []
    for k, z in enumerate(zs):
        d = src.depth_image(plane(src, z / 1000.0), k)[:, border:].astype(np.float64)
        valid = d[d > 0]
        assert valid.size > 0.9 * d.size and abs(valid.mean() - z) < 0.01 * z
        sigmas.append(valid.std())
    slope = np.polyfit(np.log(zs), np.log(sigmas), 1)[0]
    assert 1.9 < slope < 2.1, slope
    # where the disparity noise dominates the roundings (from 1 m) the model holds to 10 %
    far = zs >= 1000.0
    ratio = np.array(sigmas)[far] / model_sigma_mm(zs[far], fb)
    assert np.all((ratio > 0.9) & (ratio < 1.1)), ratio


def test_disparity_is_quantised_to_subpixel_steps():
    src = SynthSource(size=(640, 400))
    fb = src.intrinsics.fx * BASELINE_MM
    for z in (1.2, 2.5):
        d = src.depth_image(plane(src, z), 3)
        values = np.unique(d[d > 0]).astype(np.float64)
        steps = SUBPIXEL_STEPS * fb / values  # disparity in 1/8 px units
        # off the 1/8 px grid only by the rounding to whole mm: 0.5 mm = 0.5 * 8 f B / z^2 steps
        assert np.all(np.abs(steps - np.rint(steps)) <= 0.5 * SUBPIXEL_STEPS * fb / values**2 + 1e-9)
        # consecutive levels are one 1/8 px step apart: z^2 / (8 f B) mm
        levels = np.rint(steps)
        assert np.all(np.diff(levels) == -1)
        gaps = np.diff(values)
        expected = (z * 1000.0) ** 2 / (SUBPIXEL_STEPS * fb)
        assert np.all(np.abs(np.median(gaps) - expected) < 0.15 * expected + 1)
        assert 5 <= values.size <= 12


def test_range_limits():
    src = SynthSource(size=(640, 400))
    fb = src.intrinsics.fx * BASELINE_MM
    too_close = fb / (MAX_DISPARITY_PX + 1.0) / 1000.0  # disparity beyond the search range
    assert not src.depth_image(plane(src, too_close), 1).any()
    assert not src.depth_image(plane(src, MAX_RANGE_MM / 1000.0 + 0.05), 1).any()
    near_ok = src.depth_image(plane(src, fb / (MAX_DISPARITY_PX - 3.0) / 1000.0), 1)
    # valid right of the right camera's border band (as wide as the disparity, 92 px)
    assert not near_ok[:, :91].any() and (near_ok[:, 95:] > 0).mean() > 0.95


def test_step_edge_gets_flying_pixels_and_holes_only_next_to_it():
    """Near (1.0 m) left half, far (2.0 m) right half: no stereo shadow, only the matcher's artefacts."""
    src = SynthSource(size=(640, 400))
    fb = src.intrinsics.fx * BASELINE_MM
    truth = plane(src, 2.0)
    truth[:, :320] = 1.0
    d = src.depth_image(truth, 5).astype(np.float64)
    cols = np.arange(640)[None, :].repeat(400, axis=0)
    near_edge = np.abs(cols - 319.5) <= EDGE_BAND_PX - 0.5  # pixels whose 5x5 window holds both surfaces
    interior = (cols > 60) & ~near_edge
    tol = 6.0 * model_sigma_mm(truth * 1000.0, fb)
    flying = (d > 0) & (np.abs(d - truth * 1000.0) > tol)
    assert not flying[interior].any()
    band_flying = flying[near_edge].mean()
    # flying pixels: mixed disparities, so depths between the two surfaces
    assert np.all((d[flying] > 1000.0 - tol.max()) & (d[flying] < 2000.0 + tol.max()))
    assert 0.5 * EDGE_FLYING_FRACTION < band_flying <= EDGE_FLYING_FRACTION + 0.05, band_flying
    band_invalid = (d[near_edge] == 0).mean()
    assert abs(band_invalid - EDGE_INVALID_FRACTION) < 0.1, band_invalid
    assert (d[interior] == 0).mean() < 0.05  # speckle holes only


def test_flying_pixels_only_at_the_silhouettes_of_a_rendered_scene():
    src = SynthSource(frames=60, seed=2, background_frames=5)
    fb = src.intrinsics.fx * BASELINE_MM
    window = np.ones((2 * EDGE_BAND_PX + 1,) * 2, np.uint8)
    counts = []
    for i in (20, 35, 50):
        frame, masks = src.render(i)
        parts = sc.person_parts(src.intrinsics, src.pose(i), src._appearance.sleeve_fraction)
        truth_mm = sc.composite(src._background, parts, src.blur_kernel(i))[1] * 1000.0
        disparity = (fb / truth_mm).astype(np.float32)
        step = cv2.dilate(disparity, window) - cv2.erode(disparity, window) > EDGE_STEP_PX
        d = frame.depth.astype(np.float64)
        flying = (d > 0) & (np.abs(d - truth_mm) > 6.0 * model_sigma_mm(truth_mm, fb) + 2.0)
        assert not (flying & ~step).any(), i
        counts.append(flying.sum())
        person_edge = step & cv2.dilate(masks["person"].astype(np.uint8), window).astype(bool)
        assert flying[person_edge].mean() > 0.1
    assert min(counts) > 100, counts


def test_depth_is_deterministic_and_differs_from_the_basic_model():
    a = SynthSource(frames=8, seed=11, size=(320, 200), background_frames=2)
    b = SynthSource(frames=8, seed=11, size=(320, 200), background_frames=2)
    basic = SynthSource(frames=8, seed=11, size=(320, 200), background_frames=2, depth_model="basic")
    for i in (1, 6):
        fa, fb_, fc = a.render(i)[0], b.render(i)[0], basic.render(i)[0]
        assert np.array_equal(fa.depth, fb_.depth) and np.array_equal(fa.color, fc.color)
        assert not np.array_equal(fa.depth, fc.depth)
    truth = plane(a, 1.5)
    assert np.array_equal(a.depth_image(truth, 4), b.depth_image(truth, np.random.default_rng(4)))
    assert not np.array_equal(a.depth_image(truth, 4), a.depth_image(truth, 5))
    assert a.metadata()["depth_model"] == "realistic" and basic.metadata()["depth_model"] == "basic"


def test_bad_depth_model_and_depth_map():
    with pytest.raises(InputError, match="depth_model must be one of realistic, basic, got 'tof'"):
        SynthSource.from_options({"depth_model": "tof"})
    src = SynthSource(size=(64, 48))
    with pytest.raises(InputError, match=r"depth_m must be a positive \(48, 64\) array"):
        src.depth_image(np.zeros((48, 64), np.float32), 0)


def test_synth_command_depth_model(tmp_path, capsys):
    from drivers.mcap_replay import McapReplay
    from fusion_pf.cli import main

    out = tmp_path / "b.mcap"
    argv = ["synth", str(out), "--frames", "3", "--size", "96x64", "--no-progress"]
    assert main([*argv, "--depth-model", "basic"]) == 0
    with McapReplay(out) as rec:
        assert rec.info().metadata["depth_model"] == "basic"
        depth = rec.frame(2).depth
    assert np.array_equal(depth, SynthSource(frames=3, size=(96, 64), depth_model="basic").render(2)[0].depth)
    capsys.readouterr()
    assert main([*argv, "--force", "--depth-model", "tof"]) == 2
    err = capsys.readouterr().err
    assert "depth_model (--depth-model) must be one of realistic, basic, got 'tof'" in err and err.count("\n") == 1
