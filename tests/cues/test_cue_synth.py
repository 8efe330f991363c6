"""Cues on the synthetic scene (drivers.synth) against its ground truth.

Stated accuracies (ROI centred on the skeleton's right-hand joint, depth-scaled):
colour and skin cues within 20 px of the true palm centre on clear frames (95th
percentile; their skin region includes the bare forearm, whose pull toward the
elbow measures up to ~16 px on these frames at 640 px width), the depth cue
within 12 px (its region includes the wrist end of the forearm).
"""

import math

import numpy as np
import pytest

from drivers.synth import SynthSource
from fusion_pf.cues import (
    BackgroundModel,
    ColourCue,
    DepthCue,
    LabGmmSkin,
    RgbRuleSkin,
    RgChromaSkin,
    SkinCue,
    make_roi,
)

BG = 5
FIRST, LAST = 20, 80  # consecutive person frames, covering a self-occlusion episode of seed 0


@pytest.fixture(scope="module")
def synth():
    src = SynthSource(frames=LAST, seed=0, background_frames=BG)
    with src:
        bg = BackgroundModel.from_frames(src.render(i)[0] for i in range(BG))
        rendered = [src.render(i) for i in range(FIRST, LAST)]
    return src, bg, rendered


@pytest.fixture(scope="module")
def lab_model():
    src = SynthSource(frames=40, seed=1)
    rng = np.random.default_rng(0)
    px, lab = [], []
    for i in range(0, 40, 8):
        f, m = src.render(i)
        sel = m["skin"] | (rng.random(m["skin"].shape) < 0.05)
        px.append(f.color[sel])
        lab.append(m["skin"][sel])
    return LabGmmSkin.fit(np.concatenate(px), np.concatenate(lab), rng=0)


def _roi(frame):
    j = frame.joint("right_hand")
    return make_roi(j.u, j.v, frame.size, depth_mm=j.depth_mm, fx=frame.intrinsics.fx)


def _errors(rendered, cue_fn):
    clear, occluded, found = [], [], []
    for frame, _ in rendered:
        m = cue_fn(frame, _roi(frame)).measurement
        found.append(m is not None)
        if m is None:
            continue
        assert math.isfinite(m.u) and math.isfinite(m.v) and 0.0 <= m.quality <= 1.0
        e = math.hypot(m.u - frame.ground_truth.u, m.v - frame.ground_truth.v)
        (occluded if frame.ground_truth.occluded else clear).append(e)
    return np.array(clear), np.array(occluded), np.mean(found)


def test_the_window_holds_clear_and_occluded_frames(synth):
    occ = [f.ground_truth.occluded for f, _ in synth[2]]
    assert 5 < sum(occ) < len(occ) - 5


def test_colour_cue_accuracy(synth):
    _, bg, rendered = synth
    cue = ColourCue()
    clear, occluded, coverage = _errors(rendered, lambda f, r: cue(f.color, bg.color, roi=r))
    assert coverage > 0.85
    # measured: clear p95 15.8 px (bare-forearm bias), occluded median 7.0 px
    assert np.percentile(clear, 95) < 20.0 and len(clear) > 20
    assert np.median(occluded) < 10.0


def test_depth_cue_accuracy(synth):
    _, bg, rendered = synth
    cue = DepthCue()
    clear, occluded, coverage = _errors(rendered, lambda f, r: cue(f.depth, bg.depth, roi=r))
    assert coverage > 0.85
    assert np.percentile(clear, 95) < 12.0
    assert np.median(occluded) < 8.0


@pytest.mark.parametrize("name", ["rg", "rgb", "lab"])
def test_skin_cue_accuracy(synth, lab_model, name):
    _, _, rendered = synth
    model = {"rg": RgChromaSkin(), "rgb": RgbRuleSkin(), "lab": lab_model}[name]
    cue = SkinCue(model)
    clear, occluded, coverage = _errors(rendered, lambda f, r: cue(f.color, roi=r))
    assert coverage > 0.85
    assert np.percentile(clear, 95) < 20.0  # measured 15.1-15.4 px (bare-forearm bias)


# measured on these frames: rg 0.84 / 0.96, rgb 0.56 / 1.00, lab 0.98 / 0.99 (precision / recall)
@pytest.mark.parametrize("name,precision,recall", [("rg", 0.75, 0.9), ("rgb", 0.45, 0.97), ("lab", 0.93, 0.95)])
def test_skin_pixel_precision_and_recall(synth, lab_model, name, precision, recall):
    _, _, rendered = synth
    model = {"rg": RgChromaSkin(), "rgb": RgbRuleSkin(), "lab": lab_model}[name]
    tp = fp = fn = 0
    for frame, masks in rendered[::6]:
        pred = model.mask(frame.color, frame.color) > 0
        truth = masks["skin"]
        tp += np.count_nonzero(pred & truth)
        fp += np.count_nonzero(pred & ~truth)
        fn += np.count_nonzero(~pred & truth)
    assert tp / (tp + fp) > precision
    assert tp / (tp + fn) > recall


def test_background_from_the_first_frames_of_the_stream(synth):
    src, bg, _ = synth
    running = BackgroundModel.running(BG)
    with src:
        for frame in src.frames(0, BG + 2):
            running.update(frame)
    assert np.array_equal(running.color, bg.color) and np.array_equal(running.depth, bg.depth)
