"""Acquisition window (_CueStage.prior: the joint, the prediction or the whole frame) and the learned process noise (--adapt-motion)."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_pf.frame import Frame, Intrinsics, Joint
from fusion_pf.pipeline import TrackConfig
from fusion_pf.pipeline.run import _CueStage


def _frame(confidence: float) -> Frame:
    intr = Intrinsics(width=64, height=48, fx=60.0, fy=60.0, cx=32.0, cy=24.0)
    color = np.zeros((48, 64, 3), np.uint8)
    return Frame(0, 0, color, None, intr, joints={"right_hand": Joint(50.0, 30.0, None, confidence)})


@pytest.mark.parametrize(
    ("mode", "confidence", "prediction", "expected"),
    [
        # acquisition (no prediction) with an unconfident joint: the whole frame is searched (issue 23:
        # a joint 90 px off at confidence 0.3 kept the depth and colour windows off the palm)
        ("auto", 0.3, None, None),
        ("auto", 0.9, None, (50.0, 30.0)),
        ("auto", 0.3, (10.0, 12.0), (10.0, 12.0)),
        ("auto", 0.9, (10.0, 12.0), (50.0, 30.0)),
        # the paper's mode always follows the joint, the filter mode the prediction once there is one
        ("skeleton", 0.3, None, (50.0, 30.0)),
        ("filter", 0.3, None, (50.0, 30.0)),
        ("filter", 0.9, (10.0, 12.0), (10.0, 12.0)),
    ],
)
def test_window_prior(mode, confidence, prediction, expected):
    stage = _CueStage(TrackConfig(cues=("depth",)))
    assert stage.prior(_frame(confidence), mode, prediction) == expected


def test_process_noise_is_learned_from_the_corrections_with_two_cues_or_more():
    # a smoothly moving synthetic palm seen by three cues: the filter's corrections are far below the
    # configured position noise, so --adapt-motion lowers it (to at least 0.3 x); off, it stays as configured
    from drivers.synth import SynthSource
    from fusion_pf.filter.calibration import MIN_PROCESS_SCALE
    from fusion_pf.pipeline.run import _FilterStage, extract_cues

    with SynthSource(frames=45, seed=3, size=(320, 200), background_frames=5) as src:
        rows = extract_cues(src, TrackConfig(seed=1))
    noise = {}
    for adapt in (True, False):
        stage = _FilterStage(TrackConfig(seed=1, adapt_motion=adapt), None)
        for row in rows:
            if not row.background:
                stage(row)
        assert stage.tracker is not None
        noise[adapt] = stage.tracker.process_noise[0] / stage._scale  # at palm scale 1
    configured = TrackConfig().process_noise[0]
    assert noise[False] == pytest.approx(configured)
    assert MIN_PROCESS_SCALE * configured - 1e-9 <= noise[True] < 0.8 * configured
