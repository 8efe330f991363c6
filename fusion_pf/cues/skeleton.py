"""Skeleton "cue": the pose network's hand joint as a measurement (paper 003 §3.5, Kinect output).

The paper uses the Kinect skeleton output "directly as an observation cue
without further processing"; wrapping it in a :class:`CueResult` lets the
tracker treat all sources alike.
"""

from __future__ import annotations

import time

from ..frame import Frame
from .base import CueContext, CueResult, Measurement


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


class SkeletonCue:
    """The camera's skeleton joint as a :class:`~fusion_pf.cues.base.Cue` (paper 003's K source).

    Parameters
    ----------
    source : str
        Source name of the measurements.
    """

    #: Frame parts the cue reads (:data:`~fusion_pf.cues.base.NEEDS`).
    needs = frozenset({"skeleton"})

    def __init__(self, *, source: str = "skeleton") -> None:
        self.name = str(source)

    def reset(self) -> None:
        """Nothing to forget: the joint is read as given."""

    def measure(self, frame: Frame, ctx: CueContext) -> CueResult:
        """The joint ``ctx.joint`` of ``frame`` (:func:`skeleton_cue`)."""
        return skeleton_cue(frame, ctx.joint, source=self.name)
