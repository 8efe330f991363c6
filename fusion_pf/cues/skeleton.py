"""Skeleton "cue": the pose network's hand joint as a measurement (paper 003 §3.5, Kinect output).

The paper uses the Kinect skeleton output "directly as an observation cue
without further processing"; wrapping it in a :class:`CueResult` lets the
tracker treat all sources alike.
"""

from __future__ import annotations

import time

from ..frame import Frame
from .base import CueResult, Measurement


def skeleton_cue(frame: Frame, joint: str = "right_hand", *, source: str = "skeleton") -> CueResult:
    """The joint ``joint`` of ``frame`` as a measurement.

    Returns
    -------
    CueResult
        ``Measurement(source, u, v, quality=confidence, extras={"joint", "depth_mm"})``;
        measurement None when the frame has no skeleton, the joint is absent or
        its confidence is 0. No stage images.
    """
    t0 = time.perf_counter_ns()
    j = frame.joint(joint)
    m = None
    if j is not None and j.confidence > 0:
        m = Measurement(source, j.u, j.v, j.confidence, {"joint": joint, "depth_mm": j.depth_mm})
    return CueResult(m, {}, time.perf_counter_ns() - t0)
