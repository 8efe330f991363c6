"""Tracking in world coordinates with several calibrated cameras (issue 26, paper 004 §6): frame sets -> per-camera cues -> one 3-D filter per target.

Per instant (a :class:`~fusion_pf.rig.FrameSet`):

1. every target's :class:`~fusion_pf.filter.world.WorldParticleFilter` moves to
   the instant; its predicted position is projected into every camera
   (:func:`~fusion_pf.filter.world.project`);
2. per camera, the single-camera cue stage (:class:`fusion_pf.pipeline.run._CueStage`:
   the configured cues, their windows and the association of their detections to the
   targets by label and distance, :func:`fusion_pf.association.associate`) runs
   with each target's projected prediction as its prior (the skeleton joint while
   confident, as with one camera, ``roi_prior``) and a window sized by the palm's
   apparent length at the projected depth (``fx x 95 mm / z``); a target without a
   prediction in that camera (lost, uninitialised, out of view) is looked for
   around its joint, else in the whole frame. Colour-only cameras run the cues
   that need no depth;
3. each measurement of a target becomes an observation: in a depth camera the
   pixel back-projected with the depth there (median of a window,
   :func:`fusion_pf.geometry.depth_at`) and moved to the world, a 3-D point with a
   robust Gaussian likelihood in mm (a skeleton joint with its own depth, never the
   depth image under it, :data:`PIXEL_ONLY`); in a colour-only camera (or without
   valid depth there) the pixel, with a robust reprojection likelihood in px (the source's ``--world-noise`` mm at the target:
   ``mm x fx / z`` px); a camera with depth learns its own noise per source online (:class:`_Noise`: the robust
   scale of its 3-D points' residuals against the posterior of targets far from every other, :func:`_alone`,
   measured in 3-D; at least the position process noise) and uses it for targets alone; near another target, and
   in a colour-only camera, the ``--world-noise``. With several targets, two closer than :data:`COMBINE_MM`
   (the one-camera pipeline's :data:`COMBINE_PALMS` palm lengths of 95 mm)
   are combined and share detections in every camera
   (paper 004 §5.2, as with one camera) until they are :data:`SEPARATE_MM` apart; a
   region detection both got in one camera measures the pair's midpoint
   (:func:`~fusion_pf.filter.world.measured_point`, the partner at its prediction) when
   its region holds both targets' projected predictions (one blob of the two), unless a
   depth camera splits it: its depth pixels near the two predictions, 2-means in 3-D started
   at them (paper 000), give each target its own part's centre (:meth:`_Camera.split`; the parts
   go to the hands whose elbows they fit, :func:`_swapped`); a region
   holding one of them is that target's alone (the nearer projected prediction keeps it:
   separating hands' two blobs, the partner took the other's). A combined pair closer than
   :data:`JOINED_MM` moves with :data:`JOINED_NOISE` of the process noise (step 1).
   Each combined target is kept :data:`HAND_THICKNESS_MM` from its partner's prediction
   (:class:`~fusion_pf.filter.world.Exclusion`, two hands are solid), and a joined pair's offset
   keeps the direction it had when the pair combined (:data:`JOINED_AXIS_MM`; paper 004's combined
   state: the shared blob measures the centre, the offset persists from the join);
   A tracked target's observations farther than :data:`GATE_SIGMAS` of their noise
   (at most their source's ``--world-noise``: a poor region's quality widens its likelihood, not the
   gate) plus the predicted spread are another object and dropped (validation gate),
   except its own skeleton joint (a certain label); so are those farther than
   :data:`GATE_SIGMAS` of the skeleton's and their own noise from the target's own
   joint in the world (:meth:`_WorldTarget._near_joint`: where the joint is, the
   prediction may trail a fast move);
   before the gate, a move faster than the process noise follows: the point the cameras
   agree on (:func:`_triangulate`, as acquisition's) farther than :data:`GATE_SIGMAS`
   of its spread plus the predicted spread re-seeds
   :data:`~fusion_pf.filter.world.RESEED_FRACTION` of the particles there (sensor
   resetting, :meth:`~fusion_pf.filter.world.WorldParticleFilter.reseed`, velocities
   up to the gap per step: the likelihood chooses), and the next step's process noise
   is learned from that innovation beyond the point's spread
   (:func:`~fusion_pf.filter.calibration.process_scale` within ``[1,``
   :data:`MAX_WORLD_NOISE_SCALE` ``]``; 1 without two cameras agreeing);
   a target measured along one camera's lines of sight only (no 3-D point: its depth
   cameras cannot see it, one colour-only camera can) is also held at its learned distance
   from its skeleton joint (:data:`REACH_JOINTS`: a hand from its elbow, the joint in the world
   from the depth cameras' joint depths or two cameras' lines of sight, :func:`_joint_world`; the
   distance's mean and spread learned online at the instants the target was measured in 3-D,
   :class:`_Reach`; before any, the population's, :data:`REACH_PRIOR_MM`), a
   :class:`~fusion_pf.filter.world.RangeObservation`: the line of sight
   leaves the depth along it unobserved, the range fixes it where the line crosses the shell;
   and at the depth its region's apparent size gives (the colour region's inscribed radius in px,
   the palm's half-width, times the depth over ``fx``: the size in mm learned online per camera at
   the instants the target was measured in 3-D, :class:`_Size`, a
   :class:`~fusion_pf.filter.world.SizeObservation`); its region pixels then weigh with
   :data:`ONE_LINE_PIXEL_SCALE` of their noise (nothing else measures it across the line), a region part's (a
   region the predictions split in 2-D: their guess) with its full noise (:func:`_across_line`);
4. acquisition (a target without a track): paper 004 §6.3's line-of-sight
   triangulation of the most trusted measurement of every camera that saw the
   target (:func:`~fusion_pf.filter.world.closest_point`; a line farther than
   :data:`ACQUIRE_GATE_MM` from the others' point is dropped while three or more
   remain), else one depth camera's 3-D point; the filter starts there;
5. supervision per target (:func:`fusion_pf.filter.states.step_state`, in mm): an
   observation *supports* the estimate within 3 sigma of its noise plus the
   posterior spread; the track is lost after ``silent_frames`` instants without
   support or when the posterior std stays above ``max_spread`` (of the reference
   image diagonal, converted to mm with :data:`MM_PER_REFERENCE_PX`). A target hidden from one camera is carried by the others'
   observations; one no camera measures keeps its (damped) motion until it is lost. The velocity a target keeps per
   step depends on how it was measured at the last instant (:data:`VELOCITY_DAMPING_3D` in 3-D, else
   :data:`~fusion_pf.filter.world.VELOCITY_DAMPING`).

Identity comes from the per-camera association (skeleton joint labels are
certain, handedness labels weigh, regions go to the nearest prediction).
"""

from __future__ import annotations

import dataclasses
import math
from collections import deque
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import cast

import numpy as np
from scipy.special import gammaincinv

from ..cues.background import AdaptiveBackground, BackgroundModel
from ..cues.regions import two_means
from ..cues.registry import CUES
from ..cues.roi import PALM_LENGTH_MM
from ..errors import InputError
from ..filter.calibration import process_scale
from ..filter.kernel import warm_up
from ..filter.likelihood import quality_sigma
from ..filter.states import Evidence, StateConfig, TrackStatus, step_state
from ..filter.world import (
    SURFACE_DEPTH_MM,
    VELOCITY_DAMPING,
    Exclusion,
    PixelObservation,
    PointObservation,
    RangeObservation,
    SizeObservation,
    WorldObservation,
    WorldParticleFilter,
    beyond,
    closest_point,
    in_view,
    measured_point,
    project,
    ray,
    surface_depth,
)
from ..frame import Frame, Intrinsics, Measurement
from ..geometry import backproject, depth_at
from ..rig import CameraPose, FrameSet
from .config import TrackConfig
from .events import Event, pair_within
from .run import (
    COMBINE_PALMS,
    DEGRADED_FRAMES,
    HOLDING,
    REFERENCE_PALM_PX,
    REFERENCE_SIZE,
    SEPARATE_PALMS,
    SUPPORT_SIGMAS,
    _CueStage,
    cue_names,
    targets_of,
)

__all__ = [
    "ACQUIRE_GATE_MM",
    "MAX_WORLD_NOISE_SCALE",
    "MM_PER_REFERENCE_PX",
    "ONE_LINE_PIXEL_SCALE",
    "REACH_JOINTS",
    "REACH_MIN_SAMPLES",
    "REACH_MIN_SIGMA_MM",
    "REACH_PRIOR_MM",
    "REACH_PRIOR_SIGMA_MM",
    "RESEED_AGREE_MM",
    "SIZE_MIN_SAMPLES",
    "SIZE_MIN_SIGMA_MM",
    "VELOCITY_DAMPING_3D",
    "WorldResult",
    "WorldTarget",
    "track_world",
]

#: Millimetres per pixel of the reference scene at the reference palm's distance (95 mm palm over 18.7 px).
MM_PER_REFERENCE_PX = PALM_LENGTH_MM / REFERENCE_PALM_PX
#: Sources never back-projected with the depth image: the skeleton joint is biased off the hand during occlusion,
#: where the depth under it is the body's or the wall's (hundreds of mm off on the synthetic rig). A joint with its
#: own depth (a body tracker's 3-D joint, ``Joint.depth_mm``) seen by a depth camera is a 3-D point; else a pixel.
PIXEL_ONLY = frozenset({"skeleton"})
#: Two targets closer than this are combined (they share detections, paper 004 §5.2); farther than the second, apart (mm).
COMBINE_MM, SEPARATE_MM = COMBINE_PALMS * PALM_LENGTH_MM, SEPARATE_PALMS * PALM_LENGTH_MM
#: The 3-D split of a region two combined targets share in a depth camera (:meth:`_Camera.split`): at most
#: :data:`SPLIT_PIXELS` of its depth pixels, those within :data:`SPLIT_REACH_MM` of either target's predicted surface
#: (its palm and the fingers' roots, not the wrist: a palm is about 95 x 85 mm), at least :data:`SPLIT_MIN_POINTS` on
#: each side; each target's part measures its centre with :data:`SPLIT_NOISE_SCALE` of its source's world noise (a
#: part's centre was a median 11-14 mm across the line of sight and 0-2 mm along it from its hand's, where the shared
#: region's point was 13-45 mm from the pair's midpoint: 10-15 mm short along the line, the depth region's 20-35 mm
#: across). On the synthetic two-hand rig (640 x 400; tuned seeds 1, 2, 11, 12 x filter seeds 0, 1; mean per-hand RMSE,
#: mean worst hand): 2 cameras 14.4 / 15.3 mm without the split, 14.4 / 15.6 with it at the full noise and a 95 mm
#: reach (seeds 1, 12), 12.8 / 13.4 at 0.5 and 60 mm, 12.4 / 12.8 at 0.4 and 60 mm, 12.8 / 13.4 at 0.4 and 50 mm;
#: one RGB-D and one colour-only camera 14.2 / 15.0, 12.9 / 13.9, 13.1 / 13.9, 13.1 / 14.0. 0.3: worse on seeds 1, 12.
#: The source's noise is not widened by the shared region's quality (:meth:`_Camera.split`, session 35).
SPLIT_PIXELS, SPLIT_REACH_MM, SPLIT_MIN_POINTS, SPLIT_NOISE_SCALE = 4000, 60.0, 20, 0.4
#: A 3-D split's parts are given to the targets the other way round (:func:`_swapped`) when that fits their kinematic
#: ranges better by more than this (summed squared standard scores; 2 sigma; not tuned).
LABEL_MARGIN = 4.0
#: Fixed-point iterations of the 2-means cut's correction (:func:`_truncation`; within 0.01 mm of its fixed point
#: after 11 for a 45 mm disc at any gap).
TRUNCATION_ITERATIONS = 20
#: Combined targets whose estimates were closer than :data:`JOINED_MM` (both palms in one blob: the shared region
#: measures their midpoint only, their offset only each one's skeleton joint, 40-60 mm off while the hands touch) move
#: with :data:`JOINED_NOISE` of the process noise: the pair's offset, measured that noisily, diffused with the full
#: noise. On the synthetic two-hand rig (tuned seeds 1 and 2, 640 x 400; over 0.4-1.0 x noise, 45-100 mm) the pooled
#: RMSE of 2 cameras fell 16.8 -> 16.6 mm, 2 with one colour-only 28.6 -> 26.8, 3 (1) 15.4 -> 15.1, 4 (2) 14.4 -> 14.0;
#: lower noise, or up to the combined gap, lagged separating hands.
JOINED_MM, JOINED_NOISE = 60.0, 0.75
#: Two hands are solid: a combined target's centre stays at least a palm's thickness from its partner's prediction
#: (:class:`~fusion_pf.filter.world.Exclusion`; two palms pressed together have their centres half a thickness behind
#: each surface). Adult hand thickness at the metacarpals is about 30 mm (anthropometric surveys: 27-33 mm); the
#: boundary's softness in mm.
HAND_THICKNESS_MM, EXCLUSION_SOFTNESS_MM = 30.0, 5.0
#: A joined pair (estimates closer than :data:`JOINED_MM`) keeps the direction of its offset from the instant it
#: combined (paper 004's combined state): the offset's part across that direction has this std (mm). Without it (and
#: the exclusion) the offset, measured only by the skeleton joints, drifted toward zero and into depth: on the
#: synthetic two-hand rig (tuned seeds 1 and 2, 640 x 400, 2 cameras, 3 with one colour-only, 4 with two) the half
#: offset's RMSE while the hands were within 100 mm was 15-18 mm, 11-14 mm with 30-60 mm here (10-20 also moved the
#: pair's midpoint, 12 -> 14-19 mm).
JOINED_AXIS_MM = 40.0
#: Velocity a target measured in 3-D at the last instant (a depth camera's point, or two cameras' lines of sight) keeps
#: per frame step; one measured along one camera's lines of sight only, or not at all, keeps
#: :data:`~fusion_pf.filter.world.VELOCITY_DAMPING` (0.5: undamped, its velocity carried it along the unobserved line).
#: With 0.5 everywhere a moving hand trailed its truth by 1-1.4 frames; 0.9 everywhere was tried and lost on held-out
#: seeds of 2 cameras with one colour-only: the one-line hand it carried off. On the synthetic two-hand rig (seeds 1, 2
#: tuned and 11, 12, 640 x 400; over 0.7, 0.8, 0.9) 0.8 lowered the mean pooled RMSE in every scene, e.g. 2 cameras
#: 14.1 -> 13.2 mm (tuned), 15.7 -> 15.3 (11, 12), 2 with one colour-only 17.8 -> 16.7 and 16.0 -> 15.3.
VELOCITY_DAMPING_3D = 0.8
#: Validation gate of a tracked target's observations, in sigmas of their noise plus the predicted spread.
GATE_SIGMAS = 4.0
#: Largest factor of the process noise learned from a target's innovation (:meth:`_WorldTarget._reseed`): 30 mm and
#: 7.5 mm/frame at the default, about ``--world-process-noise 25,10``, which followed the scripted hand-to-head move.
MAX_WORLD_NOISE_SCALE = 3.0
#: Re-seeding and the learned process noise need the cameras' lines of sight within this of their point (mm): two
#: lines (two cameras) always have a nearest point, and during an occlusion one camera's joint is far off. The skeleton
#: joint's world noise (30 mm) and a margin; not tuned.
RESEED_AGREE_MM = 40.0
#: Acquisition: a line of sight farther than this from the triangulated point is not the same target (mm).
ACQUIRE_GATE_MM = 80.0
#: The skeleton joint a target's distance is learned from and held to while one camera alone measures it (the
#: kinematic range, :class:`_Reach`): a hand's elbow.
REACH_JOINTS = {"right_hand": "right_elbow", "left_hand": "left_elbow"}
#: The kinematic range is used once learned from this many instants with the target measured in 3-D; its noise is the
#: learned spread, at least :data:`REACH_MIN_SIGMA_MM` (mm). Not tuned.
REACH_MIN_SAMPLES, REACH_MIN_SIGMA_MM = 10, 10.0
#: Before that (a hand one camera alone sees from the start of a recording, never measured in 3-D yet) the range is the
#: population's: an adult's elbow to wrist is about 265 mm (anthropometric surveys, forearm length 250-280 mm), the
#: wrist to the palm's centre about 50 mm; the noise covers the population's spread and the wrist's bend (mm). Not
#: tuned. Without it such a hand random-walked along the line of sight with the process noise (held-out seed 41, two
#: cameras, one colour-only: the right hand hidden from the depth camera for the first 37 instants, 5 -> 71 mm).
REACH_PRIOR_MM, REACH_PRIOR_SIGMA_MM = 315.0, 30.0
#: A colour-only camera's apparent size of a target (:class:`_Size`) is used once learned from this many instants with
#: the target measured in 3-D; its noise is the learned spread, at least :data:`SIZE_MIN_SIGMA_MM` (mm). Not tuned.
SIZE_MIN_SAMPLES, SIZE_MIN_SIGMA_MM = 10, 1.0
#: While one camera alone measures a target along its lines of sight (:func:`_one_line`), its region pixels weigh
#: with this share of their source's world noise (``--world-noise``; 60 mm for colour), at least the position process
#: noise: that noise is a region point's 3-D offset from the palm's centre (the surface in front of it, depth noise,
#: forearm), mostly along the line of sight, while across it a region's centre is a few px off (0.1 x 60 mm: 2 px at
#: 1.5 m with fx 499 px); nothing else then measures the target across the line, and the kinematic range and the
#: apparent size pulled it off. The skeleton joint (biased off the hand during occlusion) keeps its noise. On the
#: synthetic two-hand rig (2 cameras, one colour-only, 640 x 400; tuned seeds 1, 2, 11, 12 x filter seeds 0, 1) the
#: RMSE while a camera could not see a hand: 18.9 mm at the full noise, 17.1 / 16.6 / 16.4 at 0.3 / 0.15 / 0.08,
#: 16.5 at 0.1 with the floor; with the skeleton joint's at 0.15 too 19.6; at every instant (several cameras
#: measuring the target), 0.15 made the pooled RMSE 26.1 mm (15.6 without), 3 cameras with one colour-only 25.5
#: (13.1), 4 with two 23.7 (12.3).
ONE_LINE_PIXEL_SCALE = 0.1
#: A camera's measurement noise per source (:class:`_Noise`) is learned online from the residuals of its gated
#: observations of a target far from every other (:func:`_alone`) and measured in 3-D, against the posterior estimate:
#: the median over the last :data:`NOISE_WINDOW` residuals, once :data:`NOISE_MIN_SAMPLES` were learned (before, the
#: source's ``--world-noise``). Not tuned.
NOISE_WINDOW, NOISE_MIN_SAMPLES = 200, 20


@dataclass
class WorldTarget:
    """One target at one instant.

    Attributes
    ----------
    target : str
    state : str
        ``uninitialised``, ``tracking`` or ``lost`` (paper 004 §5.2).
    position_mm : ndarray (3,) or None
        World position (None without a track).
    sigma_mm : float or None
        Posterior std along its widest axis, mm.
    cameras : tuple of str
        The cameras that measured the target at this instant.
    pixels : dict of str to (u, v) or None
        The world estimate projected into every camera of the rig (None: no estimate, or out of that camera's view).
    truth_mm : ndarray (3,) or None
        The recording's world ground truth of the target.
    """

    target: str
    state: str
    position_mm: np.ndarray | None
    sigma_mm: float | None
    cameras: tuple[str, ...]
    pixels: dict[str, tuple[float, float] | None]
    truth_mm: np.ndarray | None = None


@dataclass
class WorldResult:
    """The world tracker's output for one instant (a frame set); ``events``: its interaction events, set by
    :mod:`fusion_pf.pipeline.world_events`."""

    index: int
    timestamp_ns: int
    background: bool
    targets: dict[str, WorldTarget] = field(default_factory=dict)
    frameset: FrameSet | None = None
    events: list[Event] = field(default_factory=list)


def _with_backgrounds(
    sets: Iterable[FrameSet], config: TrackConfig
) -> Iterator[tuple[FrameSet, dict[str, BackgroundModel] | None]]:
    """Frame sets with each camera's background model (None for background sets), as :func:`fusion_pf.pipeline.run.track` does per stream.

    The cameras' background frames when every camera has some, else an adaptive
    model learnt from the first ``background_k`` sets (read ahead, then tracked).
    """
    it = iter(sets)
    empties: dict[str, list[Frame]] = {}
    models: dict[str, BackgroundModel] | None = None
    for fs in it:
        if fs.background:
            for name, view in fs.views.items():
                empties.setdefault(name, []).append(view.frame)
            yield fs, None
            continue
        if models is None and not fs.views:  # no camera gave a frame: nothing to learn or track from
            yield fs, {}
            continue
        if models is None:
            first = next(iter(fs.views.values())).frame
            if not any("background" in CUES[c].needs for c in cue_names(config, first)):
                models = {name: BackgroundModel(None, None) for name in fs.views}
            elif empties and all(name in empties for name in fs.views):
                models = {name: BackgroundModel.from_frames(frames) for name, frames in empties.items()}
            else:
                ahead = [fs]
                for item in it:
                    if item.background:
                        raise InputError(
                            f"background frame set {item.index} comes after tracked ones; background frames must lead"
                        )
                    ahead.append(item)
                    if len(ahead) >= config.background_k:
                        break
                cameras = dict.fromkeys(name for s in ahead for name in s.views)
                adaptive = {
                    name: AdaptiveBackground(
                        [s.views[name].frame for s in ahead if name in s.views], history=10 * config.background_k
                    )
                    for name in cameras
                }
                for s in ahead:
                    yield s, dict(adaptive)
                    for name, view in s.views.items():
                        adaptive[name].adapt(view.frame)
                models = dict(adaptive)
                continue
        yield fs, models
        for name, view in fs.views.items():
            model = models.get(name)
            if isinstance(model, AdaptiveBackground):
                model.adapt(view.frame)


class _Camera:
    """One camera's cue stage: the configured cues (those needing no depth on a colour-only camera)."""

    def __init__(self, name: str, config: TrackConfig, frame: Frame, pose: CameraPose) -> None:
        names = cue_names(config, frame)
        if frame.depth is None:
            names = tuple(n for n in names if "depth" not in CUES[n].needs)
        if not names:
            raise InputError(
                f"camera {name} has no depth and none of the cues {', '.join(cue_names(config, frame))} runs without it"
            )
        sources = None if config.sources is None else tuple(s for s in config.sources if s in names) or None
        self.name = name
        self.pose = pose
        self.config = dataclasses.replace(config, cues=names, sources=sources)
        self.stage = _CueStage(self.config)
        self.sources = sources or names
        self.noise = {source: _Noise() for source in self.sources if source not in PIXEL_ONLY}
        self.floor_mm = config.world_process_noise[0]

    def nominal(self, m: Measurement) -> float:
        """``m``'s source's ``--world-noise`` widened by its quality (:func:`~fusion_pf.filter.likelihood.quality_sigma`)."""
        return quality_sigma(self.config.world_noise_mm[m.source], m)

    def sigma(self, m: Measurement) -> float:
        """``m``'s noise (mm) for a target :func:`_alone`: its source's learned noise (:class:`_Noise`), at least the position
        process noise (a narrower likelihood holds only the few particles within one step of it); the :meth:`nominal`
        one before it is learned or for a :data:`PIXEL_ONLY` source."""
        noise = self.noise.get(m.source)
        if noise is None or not noise.learned:
            return self.nominal(m)
        return max(noise.sigma(), self.floor_mm)

    def learn(self, m: Measurement, ob: PointObservation | PixelObservation, estimate_mm: np.ndarray) -> None:
        """Learn ``m``'s source's noise (:class:`_Noise`) from its observation ``ob`` at its target's posterior estimate."""
        noise = self.noise.get(m.source)
        if noise is not None and isinstance(ob, PointObservation):
            noise.learn(ob, estimate_mm)

    def observations(
        self,
        frame: Frame,
        target: str,
        cues: Mapping[str, Measurement | None],
        partner: tuple[Mapping[str, Measurement | None], np.ndarray] | None = None,
        own_mm: np.ndarray | None = None,
        alone: bool = False,
        partner_surface_mm: float = SURFACE_DEPTH_MM,
        ranges: tuple[RangeObservation, RangeObservation] | None = None,
    ) -> list[tuple[Measurement, PointObservation | PixelObservation]]:
        """Each fused measurement of ``target`` with its observation (a world point with depth there, else the pixel).

        ``partner``: a combined partner's measurements in this camera and predicted position; a region measurement
        both have (the same detection) measures the pair's midpoint (``partner_mm``) when its region holds both
        targets' projected predictions (one blob of the two hands, :func:`_holds_both`); a region holding one of
        them only is that target's alone (the nearer prediction keeps it, the other drops it). ``own_mm``: the
        target's predicted position. ``partner_surface_mm``: the partner's :func:`~fusion_pf.filter.world.surface_depth`.
        ``ranges``: the target's and the partner's kinematic ranges (:class:`_Reach`), which label a split's parts.

        A target ``alone`` in a depth camera gets its source's learned noise (:meth:`sigma`), except a region part (the
        ``part`` extra: one region the two hands' projected predictions split in 2-D,
        :func:`~fusion_pf.cues.regions.split_region`, whose centre is their guess), which keeps the nominal one: on
        unseen seed 655 (2 RGB-D cameras, a hand approaching the other) such a part lay 58-108 mm off the hand at the
        learned 10 mm, the estimate followed it, 94 mm off at worst.
        """
        out: list[tuple[Measurement, PointObservation | PixelObservation]] = []
        for source in self.sources:
            m = cues.get(source)
            if m is None:
                continue
            shared = None
            if partner is not None and source not in PIXEL_ONLY:
                other = partner[0].get(source)
                if other is not None and (other.u, other.v) == (m.u, m.v):
                    held = _holds_both(m, own_mm, partner[1], self.pose, frame.intrinsics)
                    if held is None or held == "both":
                        shared = partner[1]
                    elif held == "partner":
                        continue
            learned = alone and frame.depth is not None and "part" not in m.extras  # a region part is a guess
            sigma = self.sigma(m) if learned else self.nominal(m)
            if shared is not None and own_mm is not None and frame.depth is not None:
                part = self.split(frame, m, own_mm, shared, surface_depth(target), partner_surface_mm, ranges)
                if part is not None:
                    out.append((m, PointObservation(part, SPLIT_NOISE_SCALE * self.config.world_noise_mm[m.source])))
                    continue
            z = None
            if frame.depth is not None and source not in PIXEL_ONLY:
                z = depth_at(frame.depth, m.u, m.v, radius=self.config.depth_radius)
            elif frame.depth is not None and source == "skeleton":
                joint = frame.joint(target)
                if joint is not None and joint.depth_mm and (joint.u, joint.v) == (m.u, m.v):
                    z = joint.depth_mm
            if z is None:
                out.append((m, PixelObservation(np.array([m.u, m.v]), sigma, self.pose, frame.intrinsics, shared)))
            else:
                xyz = self.pose.to_world(backproject(np.array([[m.u, m.v]]), np.array([z]), frame.intrinsics))[0]
                if source not in PIXEL_ONLY:  # the surface seen, not the centre behind it
                    xyz = beyond(xyz, self.pose.translation_mm, surface_depth(target))
                out.append((m, PointObservation(xyz, sigma, shared)))
        return out

    def split(
        self,
        frame: Frame,
        m: Measurement,
        own_mm: np.ndarray,
        partner_mm: np.ndarray,
        own_surface_mm: float = SURFACE_DEPTH_MM,
        partner_surface_mm: float = SURFACE_DEPTH_MM,
        ranges: tuple[RangeObservation, RangeObservation] | None = None,
    ) -> np.ndarray | None:
        """The target's own part of a region two combined targets share (one blob of the two): its 3-D centre, or
        None when the region cannot be split.

        The depth pixels of the region's box (every ``k``-th row and column, at most :data:`SPLIT_PIXELS`) are
        back-projected to the world; those within :data:`SPLIT_REACH_MM` of either target's predicted surface (its
        prediction its :func:`~fusion_pf.filter.world.surface_depth`, ``own_surface_mm`` or ``partner_surface_mm``,
        nearer the camera) are split between the two by 2-means started at those surfaces (paper 000's k-means,
        :func:`~fusion_pf.cues.regions.two_means`); the target's part's centroid (the nearer part's corrected for the
        2-means cut, :func:`_truncation`) moved ``own_surface_mm`` away from the camera is its centre. None without a
        box or with fewer than :data:`SPLIT_MIN_POINTS` points on either side (the target's observation then measures
        the pair's midpoint). With ``ranges`` (the target's and the partner's kinematic ranges, :class:`_Reach`: a hand
        lies a forearm from its own elbow) the parts go to the targets the other way round when that fits the ranges
        better (:func:`_swapped`).

        A part measures one palm: :meth:`observations` gives it :data:`SPLIT_NOISE_SCALE` of its source's
        ``--world-noise``, not widened by the shared region's quality (a blob of two palms is a poor palm, quality
        0.2-0.4: 37-56 mm where the part's centre lay a median 12 mm from its hand's in 3-D, and the parts weighed less
        than the skeleton joints, about 52 mm, 40-60 mm off while the hands touch; on lead seeds 61, 92, 252, 2 RGB-D
        cameras, the joined hands' filter RMSE was 14.3 mm at the instants the plain mean of their 4 parts was 10.4).
        Weighed as one palm, a part labelled by the predictions alone locks two hands circling each other into each
        other's places: started at predictions that lag a fast turn of the pair's offset through a gap under a hand's
        thickness, each part is the other hand, and the estimates follow (the offset turned 180 degrees, 50-60 mm per
        hand for about 50 instants). The elbows tell the hands apart: with the true hands' centres the ranges labelled
        every combined instant right (seeds 61, 92, 638, 646). ``benchmarks/rig3d.py`` (640 x 400, filter seed 0;
        mean per hand, mm): unwidened noise without the labels, seeds 630-639 2 RGB-D 11.05 -> 11.88 (seed 638's hands
        12.1 / 11.5 -> 26.7 / 24.9; at 0.5 x the noise seeds 640-649 11.54 -> 12.63, seed 646's 30.0 / 25.1); with the
        labels: seeds 650-658, not examined, 2 RGB-D 11.87 -> 10.96, one RGB-D and one colour-only 12.65 -> 11.69
        (filter seed 1: 12.34 -> 11.41); 630-639 11.05 -> 10.46 and 12.62 -> 12.13; 640-649 11.54 -> 10.93 and
        12.75 -> 12.30; lead seeds 61, 62, 71, 72, 91-99, 251, 252 11.50 -> 10.52 and 12.80 -> 12.20; seeds 630-634, 3
        cameras with one colour-only 9.89 -> 9.75, 4 with two 9.21 -> 8.66; 0 swaps everywhere. Hands over 15 mm with
        one colour-only camera 3 -> 1 of 30 (lead seeds), unchanged on the others; but its worst hand rose on three
        seed sets of four (lead 17.9 -> 20.9 mm, 630-639 17.1 -> 19.9, 640-649 16.2 -> 17.7; 650-658 17.5 -> 15.9).

        The parts are used whether or not they are separated in the data: two joined hands are two hands, and the
        halves of their one blob, started at the predictions, measure each hand better than the blob's point
        measures their midpoint. Until session 21 a split was used only when its parts' separation (Ashman's D along
        the line through their means) was at least 3.3 (above a disc's halves, 3.21), else the region measured the
        midpoint. Without that test (``benchmarks/rig3d.py``, 640 x 400, 15 held-out seeds 61, 62, 71, 72, 91-99,
        251, 252; mean per hand, hands over 15 mm of 30, worst hand while a camera cannot see it, 0 swaps either way):
        2 cameras with one colour-only 14.31 -> 13.52 mm, 11 -> 7, 39.6 -> 37.3 (filter seed 1: 14.40 -> 14.26,
        10 -> 10, 46.7 -> 46.4); 2 RGB-D cameras 12.86 -> 12.22, 3 -> 0, 20.7 -> 20.2 (seed 1: 13.66 -> 12.19,
        5 -> 1); seeds 61, 62, 71, 72, 91: 3 cameras with one colour-only 10.60 -> 10.53, 4 with two 10.27 -> 10.01.
        The test rejected a split about half of the time, and the shared region's point then measured the midpoint
        with the source's ``--world-noise`` widened by the blob's quality (a two-palm blob is a poor palm: quality
        0.2-0.3, 110-170 mm), where that point was 8 mm per axis from the true midpoint (colour, tuned seeds 1, 2):
        the joined pair moved with its skeleton joints, 35-37 mm per axis off while the hands are near. Giving the
        shared point the unwidened 60 mm instead changed little (tuned seeds 1-6: 2 RGB-D 11.54 -> 11.01, one
        colour-only 13.25 -> 13.32 mm); its learned noise (about 10 mm) made both 20-22 mm: a midpoint measured
        against the partner's prediction moves each hand by twice the point's error. Neither is done.
        """
        box = m.extras.get("bbox")
        if box is None or frame.depth is None:
            return None
        x, y, w, h = (int(v) for v in cast("Sequence[float]", box))  # a region cue's [x, y, w, h], full-frame px
        height, width = frame.depth.shape
        x0, y0, x1, y1 = max(x, 0), max(y, 0), min(x + w, width), min(y + h, height)
        if x0 >= x1 or y0 >= y1:
            return None
        k = max(1, math.ceil(math.sqrt((x1 - x0) * (y1 - y0) / SPLIT_PIXELS)))
        patch = frame.depth[y0:y1:k, x0:x1:k]
        rows, cols = np.nonzero(patch > 0)
        if rows.size < 2 * SPLIT_MIN_POINTS:
            return None
        uv = np.stack([x0 + k * cols, y0 + k * rows], axis=1).astype(np.float64)
        pts = self.pose.to_world(backproject(uv, patch[rows, cols].astype(np.float64), frame.intrinsics))
        centre = self.pose.translation_mm
        seeds = np.stack([beyond(own_mm, centre, -own_surface_mm), beyond(partner_mm, centre, -partner_surface_mm)])
        near = ((pts[:, None, :] - seeds[None]) ** 2).sum(axis=2).min(axis=1) <= SPLIT_REACH_MM**2
        pts = pts[near]
        if len(pts) < 2 * SPLIT_MIN_POINTS:
            return None
        first = two_means(pts, seeds)
        if first is None or min(int(first.sum()), int((~first).sum())) < SPLIT_MIN_POINTS:
            return None
        if ranges is not None and _swapped(
            beyond(pts[first].mean(axis=0), centre, own_surface_mm),
            beyond(pts[~first].mean(axis=0), centre, partner_surface_mm),
            ranges,
        ):
            first = ~first
        own = pts[first]
        mean = own.mean(axis=0) + _truncation(own, pts[~first].mean(axis=0), centre)
        return beyond(mean, centre, own_surface_mm)

    def line_of_sight(self, m: Measurement, intrinsics: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
        """The world line of sight through ``m``'s pixel: (optical centre, direction)."""
        xy = backproject(np.array([[m.u, m.v]]), np.ones(1), intrinsics)[0, :2]  # (x/z, y/z), distortion undone
        return ray(xy, self.pose)


def _swapped(own_mm: np.ndarray, other_mm: np.ndarray, ranges: tuple[RangeObservation, RangeObservation]) -> bool:
    """Whether a split's parts (centres ``own_mm``, started at the target's prediction, and ``other_mm``, at its
    partner's) fit the two targets' kinematic ranges (``ranges``: the target's and the partner's, :class:`_Reach`; a
    hand lies a forearm from its own elbow) swapped better than as started, by more than :data:`LABEL_MARGIN` in summed
    squared standard scores: the predictions of two hands circling each other took each other's side."""

    def misfit(at: np.ndarray, ob: RangeObservation) -> float:
        return ((float(np.linalg.norm(at - ob.centre_mm)) - ob.range_mm) / ob.sigma_mm) ** 2

    kept = misfit(own_mm, ranges[0]) + misfit(other_mm, ranges[1])
    return misfit(other_mm, ranges[0]) + misfit(own_mm, ranges[1]) + LABEL_MARGIN < kept


def _truncation(own: np.ndarray, other_mean: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """The correction of a 3-D split's nearer part (:meth:`_Camera.split`) for the 2-means cut: ``own`` its points,
    ``other_mean`` the other part's centre, ``centre`` the camera's (all world mm); zero for the farther part.

    2-means gives each point to the nearer mean, so where two palms overlap in the camera the cut between the parts
    is the plane half way between their means, and the nearer palm's pixels beyond it go to the other part: its centre
    lies too far from its partner. Taken as a disc of radius ``r`` facing the camera, cut by a chord at ``h`` from its
    centre, the centroid of what is left moves away from the cut by ``2 / 3 (r^2 - h^2)^(3/2) / (pi r^2 - A)``,
    ``A = r^2 acos(h / r) - h sqrt(r^2 - h^2)`` the segment cut off. ``r`` is twice the part's standard deviation
    across the parts' axis (a disc's is ``r / 2``; the cut leaves that direction whole), at most the reach of the
    part away from the other measured from the corrected centre (the mean's farthest point that way plus the move: a
    palm side by side with the other, narrower along the axis than across it, is not cut and not moved). The half-way
    plane of means ``d`` apart, ``g`` of it across the line of sight, meets the palm's plane ``|d|^2 / (2 g)`` from
    its mean (the farther palm's depth tilts the cut away from the nearer one); ``h`` is that less the move itself (a
    fixed point: the cut lies half way between the *measured* means). The farther palm's part is not moved: the nearer
    one hides its side toward it, so its pixels are what the camera shows, whatever the cut. A part without extent
    (``r`` 0: its points on one line along the axis) is not moved.

    Per split on the synthetic two-hand rig (2 RGB-D cameras, lead seeds 61 and 92, the instants the true centres are
    under :data:`COMBINE_MM` apart, about 200 splits per source): the nearer hand's part lay 11-12 mm too far from
    its partner on average, 19-20 mm RMS across the line of sight; corrected 1-2 mm too far, 13 mm RMS (without the
    bound by the part's reach 1 mm too near; with the cut taken across the line of sight only, ``h`` half the gap, 5
    mm too near, 13 mm RMS). The farther hand's part: 4-8 mm too far, 12-13 mm RMS.
    """
    mean = own.mean(axis=0)
    view = (mean - centre) / float(np.linalg.norm(mean - centre))
    between = other_mean - mean
    axis = between - float(between @ view) * view
    gap = float(np.linalg.norm(axis))
    if gap == 0.0 or np.linalg.norm(other_mean - centre) < np.linalg.norm(mean - centre):
        return np.zeros(3)
    axis /= gap
    across = 2.0 * float(np.std(own @ np.cross(view, axis)))  # a disc's radius from its spread across the axis
    away = float(((mean - own) @ axis).max())  # the part's reach from its mean away from the other
    cut = float(between @ between) / (2.0 * gap)  # the half-way plane meets the palm's plane this far from its mean
    move = 0.0
    for _ in range(TRUNCATION_ITERATIONS):
        r = min(across, away + move)  # the true centre lies ``move`` nearer the other than the mean
        if r <= 0.0:
            return np.zeros(3)
        h = min(max(cut - move, 0.0), r)
        segment = r * r * math.acos(h / r) - h * math.sqrt(r * r - h * h)
        move = (2.0 / 3.0) * (r * r - h * h) ** 1.5 / (math.pi * r * r - segment)
    return move * axis


def _holds_both(
    m: Measurement, own_mm: np.ndarray | None, partner_mm: np.ndarray, pose: CameraPose, intrinsics: Intrinsics
) -> str | None:
    """Whose detection a region measurement two combined targets both got is: ``both`` when its region (the
    ``bbox`` extra) holds both targets' predictions projected into the camera, else ``own`` or ``partner``
    (the nearer projected prediction to the measurement); None when that cannot be told (no region box, no
    prediction of the target, a prediction behind the camera).
    """
    box = m.extras.get("bbox")
    if box is None or own_mm is None:
        return None
    uv, _ = project(
        np.stack([np.asarray(own_mm, dtype=np.float64), np.asarray(partner_mm, dtype=np.float64)]), pose, intrinsics
    )
    if not np.isfinite(uv).all():
        return None
    x, y, w, h = (float(v) for v in cast("Sequence[float]", box))  # a region cue's [x, y, w, h], full-frame px
    if all(x <= u <= x + w and y <= v <= y + h for u, v in uv):
        return "both"
    d = np.hypot(uv[:, 0] - m.u, uv[:, 1] - m.v)
    return "own" if d[0] <= d[1] else "partner"


def _acquire(
    seen: list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]],
) -> tuple[np.ndarray, float] | None:
    """Where to start a target's filter from this instant's observations (module docstring, 4): the point and its spread.

    The lines of sight of the most trusted measurement of every camera, triangulated; else the most trusted 3-D point.
    """
    agreed = _triangulate(seen)
    if agreed is not None:
        return agreed
    points = [ob for *_, ob in seen if isinstance(ob, PointObservation)]
    if points:
        first = min(points, key=lambda ob: ob.sigma_mm)
        return first.xyz_mm, first.sigma_mm
    return None


def _triangulate(
    seen: list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]],
) -> tuple[np.ndarray, float] | None:
    """The point at least two cameras agree on: the lines of sight of every camera's most trusted measurement
    triangulated, the farthest dropped while three or more remain, until all are within :data:`ACQUIRE_GATE_MM`;
    with its spread (the farthest line's distance, at least the best measurement's noise). None without agreement."""
    best: dict[str, tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]] = {}
    for item in seen:
        name = item[0].name
        if name not in best or item[3].sigma_mm < best[name][3].sigma_mm:
            best[name] = item
    chosen = list(best.values())
    lines = [cam.line_of_sight(m, intr) for cam, intr, m, _ in chosen]
    keep = list(range(len(lines)))
    while len(keep) >= 2:
        try:
            point, dist = closest_point(np.array([lines[k][0] for k in keep]), np.array([lines[k][1] for k in keep]))
        except InputError:
            return None
        if dist.max() <= ACQUIRE_GATE_MM:
            return point, max(float(dist.max()), min(chosen[k][3].sigma_mm for k in keep))
        if len(keep) < 3:
            return None
        keep.pop(int(np.argmax(dist)))
    return None


def _joint_world(fs: FrameSet, name: str) -> np.ndarray | None:
    """Skeleton joint ``name`` in the world: the mean of the depth cameras' joints with their own depth, back-projected;
    else the lines of sight of two or more cameras' joints triangulated (within :data:`ACQUIRE_GATE_MM`); else None."""
    points, lines = [], []
    for view in fs.views.values():
        joint = view.frame.joint(name)
        if joint is None:
            continue
        uv = np.array([[joint.u, joint.v]])
        if view.frame.depth is not None and joint.depth_mm:
            points.append(view.pose.to_world(backproject(uv, np.array([joint.depth_mm]), view.frame.intrinsics))[0])
        lines.append(ray(backproject(uv, np.ones(1), view.frame.intrinsics)[0, :2], view.pose))
    if points:
        return np.mean(points, axis=0)
    if len(lines) < 2:
        return None
    try:
        point, dist = closest_point(np.array([o for o, _ in lines]), np.array([d for _, d in lines]))
    except InputError:
        return None
    return point if float(dist.max()) <= ACQUIRE_GATE_MM else None


def _one_line(seen: list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]]) -> bool:
    """Whether ``seen`` measures the target along lines of sight of one camera only: no 3-D point, one camera."""
    return not any(isinstance(ob, PointObservation) for *_, ob in seen) and len({cam.name for cam, *_ in seen}) == 1


class _Running:
    """A running mean and variance (Welford), learned online one value at a time."""

    def __init__(self) -> None:
        self.count = 0
        self.mean = 0.0
        self.m2 = 0.0

    def learn(self, value: float) -> None:
        """Add one value."""
        self.count += 1
        delta = value - self.mean
        self.mean += delta / self.count
        self.m2 += delta * (value - self.mean)

    def sigma(self, floor: float) -> float:
        """The sample standard deviation, at least ``floor`` (needs two values)."""
        return max(math.sqrt(self.m2 / (self.count - 1)), floor)


class _Reach(_Running):
    """A target's distance from a skeleton joint (:data:`REACH_JOINTS`; a hand from its elbow), learned online.

    Learned (running mean and variance, Welford) at the instants the target was measured in 3-D (a depth camera's
    point, or two cameras' lines of sight); used as a :class:`~fusion_pf.filter.world.RangeObservation` while one
    camera alone measures it: a single line of sight leaves the depth along it unobserved, and the filter drifted
    along it. Before :data:`REACH_MIN_SAMPLES` were learned, the population's range (:data:`REACH_PRIOR_MM`).
    """

    def observation(self, joint_mm: np.ndarray) -> RangeObservation:
        """The range from ``joint_mm``: the learned one, or before :data:`REACH_MIN_SAMPLES` distances were learned the
        population's (:data:`REACH_PRIOR_MM`)."""
        centre = np.asarray(joint_mm, dtype=np.float64)
        if self.count < REACH_MIN_SAMPLES:
            return RangeObservation(centre, REACH_PRIOR_MM, REACH_PRIOR_SIGMA_MM)
        return RangeObservation(centre, self.mean, self.sigma(REACH_MIN_SIGMA_MM))


class _Size(_Running):
    """A target's size (mm) as one colour-only camera's region measures it, learned online: the region's inscribed
    radius (the ``radius`` extra, px: the palm's half-width whatever forearm is attached) times the target's depth in
    the camera over ``fx``.

    Learned at the instants the target was measured in 3-D, from the camera's pixels whose region holds the estimate
    (its projection within the inscribed radius of the pixel); used as a
    :class:`~fusion_pf.filter.world.SizeObservation` while that camera alone measures the target: the apparent size
    measures the depth along the line of sight a pixel leaves unobserved.
    """

    def learn_at(self, estimate_mm: np.ndarray, m: Measurement, ob: PixelObservation) -> None:
        """Learn from ``m`` (``ob`` its pixel) at the target's estimate, when it has an apparent size and its region
        holds the estimate."""
        size = _apparent_size(m, ob)
        if size is None:
            return
        uv, z = project(np.asarray(estimate_mm, dtype=np.float64)[None], ob.pose, ob.intrinsics)
        if np.isfinite(uv[0, 0]) and math.hypot(float(uv[0, 0]) - m.u, float(uv[0, 1]) - m.v) <= size:
            self.learn(size * float(z[0]) / ob.intrinsics.fx)

    def observation(self, m: Measurement, ob: PointObservation | PixelObservation) -> SizeObservation | None:
        """``m``'s apparent size as an observation, None without one (a 3-D point has none) or before
        :data:`SIZE_MIN_SAMPLES` were learned."""
        if not isinstance(ob, PixelObservation) or self.count < SIZE_MIN_SAMPLES:
            return None
        size = _apparent_size(m, ob)
        if size is None:
            return None
        return SizeObservation(size, self.mean, self.sigma(SIZE_MIN_SIGMA_MM), ob.pose, ob.intrinsics)


class _Noise:
    """One camera's measurement noise of one source, learned online (mm, per axis).

    Each residual of a gated 3-D point of a target :func:`_alone` and measured in 3-D against its posterior estimate
    (the point's distance ``d`` from it) is a per-axis noise ``d / median(chi_3)`` (the median distance of a
    3-dimensional standard normal from 0; a colour-only camera's pixels keep ``--world-noise``, :meth:`_Camera.sigma`);
    the noise is the median of the last :data:`NOISE_WINDOW` of these (robust: a region on another object is one
    large residual; the robust likelihood's outlier term takes it), used once :data:`NOISE_MIN_SAMPLES` were learned.
    """

    def __init__(self) -> None:
        self.values: deque[float] = deque(maxlen=NOISE_WINDOW)

    @property
    def learned(self) -> bool:
        return len(self.values) >= NOISE_MIN_SAMPLES

    def sigma(self) -> float:
        """The learned noise per axis (mm): the median of the last :data:`NOISE_WINDOW` residuals' noises."""
        return float(np.median(self.values))

    def learn(self, ob: PointObservation, estimate_mm: np.ndarray) -> None:
        """Learn from the 3-D point ``ob`` at its target's posterior estimate ``estimate_mm``."""
        # the median of chi_3: sqrt of chi-squared_3's, 2 P^-1(3 / 2, 1 / 2) (the regularised gamma's inverse)
        self.values.append(
            float(np.linalg.norm(ob.xyz_mm - estimate_mm)) / math.sqrt(2.0 * float(gammaincinv(1.5, 0.5)))
        )


def _across_line(
    cam: _Camera, m: Measurement, ob: PointObservation | PixelObservation, alone: bool
) -> PointObservation | PixelObservation:
    """A region pixel of the one camera that alone measures a target (:func:`_one_line`) with :data:`ONE_LINE_PIXEL_SCALE`
    of its noise, at least the camera's floor (the filter's position noise per step: a narrower line holds only the
    few particles that stayed in it), while it has its nominal noise (:meth:`_Camera.sigma`: its source's noise not
    learned yet, or the target not ``alone``, :func:`_alone`; a learned one is across the line already); a skeleton
    joint's (:data:`PIXEL_ONLY`), a learned one, a region part's (the ``part`` extra: a region the targets' projected
    predictions split in 2-D, :func:`~fusion_pf.cues.regions.split_region`, whose centre is their guess, not a
    measurement) or a 3-D point as it is. On the synthetic two-hand rig (2 cameras, one colour-only, 640 x 400) the parts
    the colour-only camera gave separating hands the depth camera could not see lay 53-79 mm off the hand across the
    line; at 0.1 of their noise the estimate followed them (tune seeds 382-393 with the depth camera hidden x filter
    seeds 0, 1: mean per-hand RMSE while a camera could not see the hand 17.4 mm, worst 69.9; 15.0 and 24.7 at the full
    noise)."""
    noise = cam.noise.get(m.source)
    if not isinstance(ob, PixelObservation) or noise is None or (noise.learned and alone) or "part" in m.extras:
        return ob
    return dataclasses.replace(ob, sigma_mm=max(ONE_LINE_PIXEL_SCALE * ob.sigma_mm, cam.floor_mm))


def _gate_sigma(item: tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]) -> float:
    """The noise an observation is gated with (:meth:`_WorldTarget._gated`, :meth:`_WorldTarget._near_joint`): its own,
    at most its source's ``--world-noise`` (:meth:`_Camera.nominal` before the quality widens it): a region's quality
    says how well its centre measures a palm, not how far from the palm it may lie."""
    return min(item[3].sigma_mm, item[0].config.world_noise_mm[item[2].source])


def _apparent_size(m: Measurement, ob: PixelObservation) -> float | None:
    """The apparent size (px) of a pixel observation's region: its ``radius`` extra, None without one, for a region two
    combined targets share (``partner_mm``) or a part of one (``part``), or a reduced whole-frame search."""
    radius = m.extras.get("radius")
    if ob.partner_mm is not None or radius is None or "part" in m.extras or m.extras.get("search_step", 1) != 1:
        return None
    return float(cast("float", radius))


def _within(ob: PointObservation | PixelObservation, at: np.ndarray, reach2: float) -> bool:
    """Whether observation ``ob`` lies within ``sqrt(reach2)`` mm of the world point ``at`` (a pixel: within that
    many mm at ``at``'s depth)."""
    if isinstance(ob, PointObservation):
        return float(((ob.xyz_mm - at) ** 2).sum()) <= reach2
    uv, z = project(at[None], ob.pose, ob.intrinsics)
    return (
        bool(np.isfinite(uv[0, 0]))
        and float(((uv[0] - ob.uv) ** 2).sum()) <= reach2 * (ob.intrinsics.fx / float(z[0])) ** 2
    )


class _WorldTarget:
    """One target's filter, track state and supervision (module docstring, 5)."""

    def __init__(self, name: str, config: TrackConfig, rng: np.random.Generator) -> None:
        scale = MM_PER_REFERENCE_PX
        self.name = name
        self.filter = WorldParticleFilter(config.world_particles, config.world_process_noise, rng)
        self.status = TrackStatus()
        self.noise_scale = 1.0
        self.joint_reach_mm = GATE_SIGMAS * config.world_noise_mm["skeleton"]
        self.reach = _Reach()
        self.sizes: dict[str, _Size] = {}
        self.states = StateConfig(
            max_spread_px=config.max_spread * math.hypot(*REFERENCE_SIZE) * scale,
            min_likelihood=0.0,
            silent_frames=config.silent_frames,
            degraded_frames=DEGRADED_FRAMES,
            image_size=None,
            merge_px=1.0,
            split_px=1.0,
        )

    @property
    def tracking(self) -> bool:
        return self.status.state in HOLDING

    def predicted(self) -> np.ndarray | None:
        """The predicted position (weighted mean of the moved particles), None without a track."""
        if not (self.filter.initialised and self.tracking):
            return None
        return self.filter.moments()[0]

    def step(
        self,
        t: int,
        seen: list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]],
        joint_mm: np.ndarray | None = None,
        apart: Exclusion | None = None,
        alone: bool = False,
        own_joint_mm: np.ndarray | None = None,
    ) -> tuple[np.ndarray | None, float | None]:
        """Update with this instant's observations (``seen``: every camera's), supervise; the estimate and its spread.

        ``joint_mm``: the target's :data:`REACH_JOINTS` joint in the world (:func:`_joint_world`), for its kinematic
        range (:class:`_Reach`), learned while the target is measured in 3-D and used while one camera alone sees it.
        ``apart``: a combined partner's exclusion (:func:`_exclusion`), applied to a tracked target. ``own_joint_mm``:
        the target's own skeleton joint in the world (:func:`_joint_world`): observations far from it are dropped
        before the re-seed and the gate (:meth:`_near_joint`).
        """
        if self.filter.initialised:
            seen = self._near_joint(seen, own_joint_mm)
            self._reseed(seen)
            seen = self._gated(seen)
        observations = [ob for *_, ob in seen]
        if not self.filter.initialised:
            start = _acquire(seen)
            if start is not None:
                self.noise_scale = 1.0
                self.filter.reset(start[0], start[1])
                self.filter.predict(t)
        one = _one_line(seen)
        reach = None if joint_mm is None or not one else self.reach.observation(joint_mm)
        fused: list[WorldObservation] = list(observations)
        if one:
            fused = [_across_line(cam, m, ob, alone) for cam, _, m, ob in seen]
            sized = (self.sizes.setdefault(cam.name, _Size()).observation(m, ob) for cam, _, m, ob in seen)
            fused += [ob for ob in sized if ob is not None]
        if self.filter.initialised:
            self.filter.update(
                [*fused, reach] if reach is not None else fused,
                () if apart is None or not self.tracking else (apart,),
            )
        measured_3d = bool(seen) and not _one_line(seen)
        # the next step's velocity damping: observed in 3-D, the velocity is checked by the next instant's measurement
        self.filter.damping = VELOCITY_DAMPING_3D if measured_3d else VELOCITY_DAMPING
        estimate, spread = self.filter.estimate() if self.filter.initialised else (None, None)
        if estimate is not None and joint_mm is not None and measured_3d:
            self.reach.learn(float(np.linalg.norm(estimate - joint_mm)))
        if estimate is not None and seen and not one:
            for cam, _, m, ob in seen:
                if isinstance(ob, PixelObservation):
                    self.sizes.setdefault(cam.name, _Size()).learn_at(estimate, m, ob)
        if estimate is not None and measured_3d and alone and self.tracking:
            for cam, _, m, ob in seen:
                cam.learn(m, ob, estimate)
        support = 0 if estimate is None else self._support(estimate, spread or 0.0, observations)
        position = None if estimate is None else (float(estimate[0]), float(estimate[1]))
        self.status = step_state(
            self.status, Evidence(position, spread_px=math.nan if spread is None else spread, cues=support), self.states
        )
        if not self.tracking and estimate is not None:
            self.filter.reset(None)
            return None, None
        return estimate, spread

    def _near_joint(
        self,
        seen: list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]],
        own_joint_mm: np.ndarray | None,
    ) -> list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]]:
        """The observations near the target's own skeleton joint in the world (``own_joint_mm``, :func:`_joint_world`;
        all without one): within :data:`GATE_SIGMAS` of the skeleton's ``--world-noise`` and their gate noise
        (:func:`_gate_sigma`, not widened by a region's quality: about 130 mm for a depth camera's point at its learned
        noise, 270 mm at the colour's default 60 mm; not tuned). One farther is another object whatever the prediction says: a
        hand raised fast to the head, its prediction trailing 100 mm, had every depth camera's region on the forearm
        250-320 mm off, the cameras agreed on it and the target was re-seeded there (``benchmarks/rig_events.py``,
        320 x 200, seed 5). A combined pair's shared measurement (of their midpoint) is kept."""
        if own_joint_mm is None:
            return seen
        return [
            item
            for item in seen
            if item[2].source in PIXEL_ONLY
            or item[3].partner_mm is not None
            or _within(item[3], own_joint_mm, self.joint_reach_mm**2 + GATE_SIGMAS**2 * _gate_sigma(item) ** 2)
        ]

    def _reseed(self, seen: list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]]) -> None:
        """Re-draw :data:`~fusion_pf.filter.world.RESEED_FRACTION` of the particles around the point the cameras agree
        on (:func:`_triangulate`) when it lies beyond :data:`GATE_SIGMAS` of its spread plus the predicted spread of
        the prediction: a move faster than the process noise follows (module docstring, 3)."""
        agreed = _triangulate(seen)
        if agreed is None or agreed[1] > RESEED_AGREE_MM:
            self.noise_scale = 1.0
            return
        mean, spread = self.filter.moments()
        gap2 = float(((agreed[0] - mean) ** 2).sum())
        # the innovation beyond the agreed point's own noise, per axis: the next step's process noise
        # (fusion_pf.filter.calibration.process_scale within [1, MAX_WORLD_NOISE_SCALE])
        excess = np.array([max(gap2 / 3.0 - agreed[1] ** 2, 0.0)])
        self.noise_scale = process_scale(excess, self.filter.process_noise_mm[0], 1.0, MAX_WORLD_NOISE_SCALE)
        if gap2 > (GATE_SIGMAS * math.hypot(agreed[1], spread)) ** 2:
            # velocities up to the whole gap in one step: the move may go on (the likelihood picks the next instants)
            self.filter.reseed(agreed[0], agreed[1], agreed[0] - mean)

    def _gated(
        self, seen: list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]]
    ) -> list[tuple[_Camera, Intrinsics, Measurement, PointObservation | PixelObservation]]:
        """The observations within :data:`GATE_SIGMAS` of their noise plus the predicted spread of the prediction.

        An observation beyond is another object (the other hand, an occluder in front of one camera, a
        region of the body): fused, a few of them pull the target off, which the robust likelihood alone
        does not prevent once the particles spread between the two.

        The noise is at most the source's ``--world-noise`` (:meth:`_Camera.nominal` before the quality widens
        it): a region's quality says how well its centre measures a palm, not how far from the palm it may
        lie. With the widened noise, on the synthetic two-hand rig (2 cameras, one colour-only, lead seed 94)
        the card hiding both joined hands from the depth camera was a shared region of quality about 0.1 there,
        660-700 mm in front of them, at 170-190 mm of noise: inside the gate (4 x 190 mm), fused with little
        weight, but a 3-D point, so the hand was not measured along one line of sight and the kinematic range
        and the apparent size were not applied; the left hand drifted up to 81 mm along the colour-only
        camera's line (RMSE while hidden 43.1 mm, 28.0 with this gate). ``benchmarks/rig3d.py`` (640 x 400,
        filter seed 0; mean per hand, hands over 15 mm, worst hand, worst while a camera cannot see it, mm):
        lead seeds 61, 62, 71, 72, 91-99, 251, 252, one RGB-D and one colour-only 13.54 -> 13.27, 6 -> 6,
        24.7 -> 17.0, 43.1 -> 28.0; 2 RGB-D 12.17 -> 12.15, 1 -> 2 (15.1 -> 15.2); seeds 620-629, rendered
        this session and not examined, one colour-only 14.38 -> 14.29, 9 -> 8, 19.1 -> 19.1, 26.3 -> 26.3;
        2 RGB-D 12.65 -> 12.62, 2 -> 2; 0 swaps everywhere.
        """
        mean, spread = self.filter.moments()
        kept = []
        for item in seen:
            ob = item[3]
            if item[2].source in PIXEL_ONLY:
                kept.append(item)
                continue
            if _within(
                ob, measured_point(mean, ob.partner_mm)[0], GATE_SIGMAS**2 * (_gate_sigma(item) ** 2 + spread**2)
            ):
                kept.append(item)
        return kept

    @staticmethod
    def _support(estimate: np.ndarray, spread: float, observations: list[PointObservation | PixelObservation]) -> int:
        """Observations within :data:`SUPPORT_SIGMAS` of their noise plus the posterior spread of ``estimate``."""
        return sum(
            _within(ob, measured_point(estimate, ob.partner_mm)[0], SUPPORT_SIGMAS**2 * (ob.sigma_mm**2 + spread**2))
            for ob in observations
        )


def track_world(
    sets: Iterable[FrameSet], config: TrackConfig, *, rng: np.random.Generator | int | None = None
) -> Iterator[WorldResult]:
    """Track ``config``'s targets (``--targets``, else the single palm) in world mm through frame sets (module docstring).

    Parameters
    ----------
    sets : iterable of FrameSet
        E.g. a ``drivers.rig.RigReplay``; every view's frame has its intrinsics, every camera its pose.
    config : TrackConfig
        The cue options, sources, ``world_noise_mm``, ``world_particles``, ``world_process_noise``,
        supervision (``silent_frames``; ``max_spread`` converted to mm) and seed.
    rng : numpy.random.Generator, int or None
        Seed of the first target's filter (None: ``config.seed``); the others' are spawned from ``config.seed``.

    Yields
    ------
    WorldResult
        One per frame set, background sets included (no targets).
    """
    if config.filter != "pf":
        raise InputError(f"tracking in world coordinates runs the particle filter (--filter pf), got {config.filter!r}")
    if config.background is not None:
        raise InputError(
            "--background is one camera's empty scene; a multi-camera recording needs its own background frames"
        )
    warm_up()
    names = targets_of(config)
    targets = {
        t: _WorldTarget(
            t,
            config,
            np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(4, k)))
            if k or rng is None
            else np.random.default_rng(rng),
        )
        for k, t in enumerate(names)
    }
    cameras: dict[str, _Camera] = {}
    partners: dict[str, str] = {}
    axes: dict[tuple[str, str], np.ndarray] = {}
    intrinsics: dict[str, Intrinsics] = {}
    poses: dict[str, CameraPose] = {}
    for fs, models in _with_backgrounds(sets, config):
        for name, view in fs.views.items():
            intrinsics[name], poses[name] = view.frame.intrinsics, view.pose
        if models is None:
            yield WorldResult(fs.index, fs.timestamp_ns, True, {}, fs)
            continue
        predicted: dict[str, np.ndarray | None] = {}
        scales = _noise_scales({t: target.predicted() for t, target in targets.items()}, partners)
        for t, target in targets.items():
            if target.filter.initialised:
                target.filter.predict(fs.timestamp_ns, scales[t] * target.noise_scale)
            predicted[t] = target.predicted()
        partners = _partners(predicted, partners)
        alone = _alone(predicted)
        axes = _entry_axes(axes, predicted, partners)
        elbows = {t: _joint_world(fs, REACH_JOINTS[t]) if t in REACH_JOINTS else None for t in names}
        ranges = {t: None if (e := elbows[t]) is None else targets[t].reach.observation(e) for t in names}
        seen: dict[str, list] = {t: [] for t in names}
        for name, view in fs.views.items():
            frame = view.frame
            if name not in cameras:
                cameras[name] = _Camera(name, config, frame, view.pose)
            cam = cameras[name]
            priors: dict[str, tuple[float, float] | None] = {}
            palms: dict[str, float | None] = {}
            for t in names:
                p = predicted[t]
                projected = None
                palms[t] = None
                if p is not None:
                    uv, z = project(p[None], view.pose, frame.intrinsics)
                    if in_view(uv, frame.intrinsics)[0]:
                        projected = (float(uv[0, 0]), float(uv[0, 1]))
                        palms[t] = frame.intrinsics.fx * PALM_LENGTH_MM / float(z[0])
                priors[t] = cam.stage.prior(frame, config.roi_prior, projected, t)
            rows = cam.stage.rows(fs.index, frame, 0, models.get(name), priors, palms, partners, keep_slivers=True)
            for t in names:
                mate = partners.get(t)
                mate_at = None if mate is None else predicted[mate]
                shared = None if mate is None or mate_at is None else (rows[mate].cues, mate_at)
                mate_surface = SURFACE_DEPTH_MM if mate is None else surface_depth(mate)
                own_range, mate_range = ranges[t], None if mate is None else ranges[mate]
                pair = None if own_range is None or mate_range is None else (own_range, mate_range)
                for m, ob in cam.observations(
                    frame, t, rows[t].cues, shared, predicted[t], alone[t], mate_surface, pair
                ):
                    seen[t].append((cam, frame.intrinsics, m, ob))
        out: dict[str, WorldTarget] = {}
        for t, target in targets.items():
            estimate, spread = target.step(
                fs.timestamp_ns,
                seen[t],
                elbows[t],
                _exclusion(t, predicted, partners, axes, scales),
                alone[t],
                _joint_world(fs, t),
            )
            pixels: dict[str, tuple[float, float] | None] = dict.fromkeys(intrinsics)
            if estimate is not None:
                for name, intr in intrinsics.items():
                    uv, _ = project(estimate[None], poses[name], intr)
                    if in_view(uv, intr)[0]:
                        pixels[name] = (float(uv[0, 0]), float(uv[0, 1]))
            measured = tuple(dict.fromkeys(cam.name for cam, *_ in seen[t]))
            truth = None if fs.truth_mm is None else fs.truth_mm.get(t)
            out[t] = WorldTarget(t, target.status.state.value, estimate, spread, measured, pixels, truth)
        yield WorldResult(fs.index, fs.timestamp_ns, False, out, fs)


def _exclusion(
    t: str,
    predicted: Mapping[str, np.ndarray | None],
    partners: Mapping[str, str],
    axes: Mapping[tuple[str, str], np.ndarray],
    scales: Mapping[str, float],
) -> Exclusion | None:
    """Target ``t``'s exclusion from its combined partner's prediction (:data:`HAND_THICKNESS_MM`); a joined pair's
    (:func:`_noise_scales` below 1) also keeps its offset along the direction it combined with (``axes``,
    :data:`JOINED_AXIS_MM`). None without a partner or predictions."""
    mate = partners.get(t)
    own, at = predicted.get(t), None if mate is None else predicted.get(mate)
    if own is None or at is None:
        return None
    axis = axes.get((t, mate)) if mate is not None and scales.get(t, 1.0) < 1.0 else None
    return Exclusion(np.asarray(at, dtype=np.float64), HAND_THICKNESS_MM, EXCLUSION_SOFTNESS_MM, axis, JOINED_AXIS_MM)


def _entry_axes(
    axes: Mapping[tuple[str, str], np.ndarray],
    predicted: Mapping[str, np.ndarray | None],
    partners: Mapping[str, str],
) -> dict[tuple[str, str], np.ndarray]:
    """Per combined (target, partner) the unit direction from the partner to the target when the two combined: kept
    while they stay combined, taken from the predictions for a pair combining now (a target's new partner too)."""
    out: dict[tuple[str, str], np.ndarray] = {}
    for a, b in partners.items():
        if (a, b) in axes:
            out[a, b] = axes[a, b]
            continue
        pa, pb = predicted.get(a), predicted.get(b)
        if pa is None or pb is None:
            continue
        r = np.asarray(pa, dtype=np.float64) - np.asarray(pb, dtype=np.float64)
        n = float(np.linalg.norm(r))
        if n > 0.0:
            out[a, b] = r / n
    return out


def _alone(predicted: Mapping[str, np.ndarray | None]) -> dict[str, bool]:
    """Per target whether it has a prediction and every other target's is farther than :data:`SEPARATE_MM` (or none):
    its regions are its own hand's alone, the condition its cameras' noise is learned in and used (:class:`_Noise`)."""
    return {
        t: p is not None
        and all(q is None or float(np.linalg.norm(p - q)) > SEPARATE_MM for o, q in predicted.items() if o != t)
        for t, p in predicted.items()
    }


def _partners(predicted: Mapping[str, np.ndarray | None], before: Mapping[str, str]) -> dict[str, str]:
    """Combined targets (each to its partner): predictions closer than :data:`COMBINE_MM`, or combined before and closer than :data:`SEPARATE_MM`."""
    return pair_within(predicted, before, COMBINE_MM, SEPARATE_MM)


def _noise_scales(estimates: Mapping[str, np.ndarray | None], partners: Mapping[str, str]) -> dict[str, float]:
    """Per target the factor of its process noise: :data:`JOINED_NOISE` for a combined target whose estimate and its
    partner's were closer than :data:`JOINED_MM` (a joined pair), else 1."""
    out = dict.fromkeys(estimates, 1.0)
    for a, b in partners.items():
        pa, pb = estimates.get(a), estimates.get(b)
        if pa is not None and pb is not None and float(np.linalg.norm(pa - pb)) < JOINED_MM:
            out[a] = JOINED_NOISE
    return out
