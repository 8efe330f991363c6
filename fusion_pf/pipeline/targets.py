"""Several targets through the pipeline: both hands and the head (papers 000, 002, 004).

``fusion-pf track --targets right_hand,left_hand,head`` runs this instead of the
single-palm pipeline. Per person frame the measurements are the whole-frame
skin blobs (paper 002's explicit RGB rule), associated to the targets by
nearest prediction within a gate, plus each target's skeleton joint
(:mod:`fusion_pf.multitarget`). The filter follows ``config.filter``: ``pf`` is
paper 000's k-means multi-modal particle filter with supervision (one set of
``particles x targets`` particles), ``kf`` one Kalman filter per target (paper
000's baseline), ``sspf`` paper 002's scatter-search PF over all targets in one
particle. Every target has paper 004's track state (uninitialised, unlabelled,
tracking, combined, lost).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

from ..cues.skin import RgbRuleSkin, SkinCue
from ..filter.kf import KalmanFilter
from ..filter.multi import IndependentTrackers, KMeansParticleFilter
from ..filter.sspf import JointScatterSearchPF
from ..frame import Frame
from ..multitarget import Associator, frame_input
from .config import TrackConfig
from .run import pixel_scale

__all__ = ["TargetsResult", "make_targets_tracker", "track_targets"]


@dataclass(eq=False)
class TargetsResult:
    """The multi-target tracker's output for one frame.

    Attributes
    ----------
    frame : int
        Index of the frame in the source.
    timestamp_ns : int
    background : bool
        An empty-scene frame (not tracked).
    targets : dict of str to (float, float, str)
        Per target ``(u, v, state)``; u, v NaN while the target has no estimate.
    evaluations : int
        Likelihood evaluations of the step.
    source_frame : Frame or None
    """

    frame: int
    timestamp_ns: int
    background: bool
    targets: dict[str, tuple[float, float, str]] = field(default_factory=dict)
    evaluations: int = 0
    source_frame: Frame | None = None


def make_targets_tracker(config: TrackConfig, size: tuple[int, int]):
    """The multi-target filter ``config.filter`` names, for images of ``size`` (noise scaled like the single-palm filter)."""
    assert config.targets is not None
    s = pixel_scale(size, config)
    noise = {k: v * s for k, v in config.noise_px.items()}
    process = (config.process_noise[0] * s, config.process_noise[1] * s)
    if config.filter == "kf":
        return IndependentTrackers(config.targets, lambda: KalmanFilter(process_noise=process, noise_px=noise))
    if config.filter == "sspf":
        return JointScatterSearchPF(
            config.targets, n_particles=config.particles, process_noise=process, noise_px=noise, rng=config.seed
        )
    return KMeansParticleFilter(
        config.targets,
        n_particles=config.particles * len(config.targets),
        process_noise=process,
        noise_px=noise,
        rng=config.seed,
    )


def track_targets(source: Iterable[Frame], config: TrackConfig) -> Iterator[TargetsResult]:
    """Track every target of ``config.targets`` through ``source``, one :class:`TargetsResult` per frame."""
    assert config.targets is not None
    skin = SkinCue(RgbRuleSkin(), min_area=config.cue_options.min_area)
    step = None
    for count, frame in enumerate(source):
        index = count if frame.index is None else frame.index
        if frame.background:
            yield TargetsResult(index, frame.timestamp_ns, True, source_frame=frame)
            continue
        if step is None:
            step = Associator(make_targets_tracker(config, frame.size))
        out = step(frame_input(frame, config.targets, skin))
        targets = {}
        for t in config.targets:
            e = out.targets[t]
            ok = math.isfinite(e.u) and math.isfinite(e.v)
            targets[t] = (e.u if ok else math.nan, e.v if ok else math.nan, e.state.value)
        yield TargetsResult(index, frame.timestamp_ns, False, targets, int(out.evaluations), frame)
