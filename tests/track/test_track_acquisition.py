"""Where the cue window goes (fusion_pf/pipeline/run.py, _CueStage.prior): the joint, the prediction or the whole frame."""

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
