"""The tracking pipeline: frames -> cues -> detections -> association -> filter -> :class:`TrackResult` rows.

Targets
    One pipeline for the single palm (one target, named by ``config.joint``)
    and for several (``config.targets``, e.g. both hands and the head). Each
    target has its prior, cue window and filter; the cues' detections (every
    region of a window, each target's skeleton joint, up to one hand per hand
    target with its handedness) are assigned to the targets by
    :func:`fusion_pf.association.associate`; joined targets are ``combined``
    and share detections, and a separating pair gets its identities back
    (:class:`_Targets`). With several targets the first target's
    :class:`TrackResult` carries every target's in ``targets``.

One frame goes through these stages (each timed with ``time.perf_counter_ns``;
the names are the keys of ``latency_ns``):

``decode``
    getting the frame from the source (MCAP decompression and image decoding,
    synthetic rendering, camera queue);
one stage per cue (``config.cues``, built by :mod:`fusion_pf.cues.registry`)
    in the configured order, e.g. ``colour`` and ``depth`` (paper 003 §3.5.1 /
    §3.5.2 on a region of interest (ROI) around a prior) and ``skeleton`` (the
    joint ``config.joint``, or each target's); with several targets the sum
    over the targets' windows;
``filter``
    one :meth:`~fusion_pf.filter.base.Tracker.step` over the fused sources,
    then the palm in 3-D (:func:`fusion_pf.geometry.palm_xyz`);
``total``
    the whole frame, ``decode`` to the 3-D palm (the command line adds ``sinks``:
    writing the outputs of the frame).

ROI prior (``TrackConfig.roi_prior``)
    ``"skeleton"``: the skeleton joint of the frame (the paper's choice, §3.1;
    the previous frame's joint when it is missing). ``"filter"``: the filter's
    prediction for the frame, i.e. the last estimate extrapolated at the
    velocity of the last two (the joint until the filter has an estimate).
    ``"auto"``: the joint while its confidence is at least
    ``prior_confidence``, else the filter's prediction -- the skeleton is
    accurate when the palm is clear and biased when the palm is in front of
    the body, where its confidence drops; re-anchoring on a confident joint
    also stops a filter that lost the palm from dragging the window along.
    With ``"filter"`` or ``"auto"``, :func:`extract_cues` runs the configured
    filter (seeded with ``config.seed``) to place the windows, exactly as
    :func:`track` does; particle-count sweeps therefore re-run :func:`track`
    itself for every job. The prediction is clamped to the image (a palm
    leaving the frame is looked for at its border). The window is sized from the
    palm's apparent length (``roi_palms`` of it either side, at most half the
    image's shorter side, see :func:`fusion_pf.cues.make_roi`): the filter's
    smoothed palm length (hand landmarks, else depth at the best cue) once it
    has one and places the windows (not with ``"skeleton"``), else the depth at
    the prior; or fixed by ``roi_half_size``.

Cue faults
    A cue that raises while measuring a frame gives no measurement for that
    frame; the run goes on. :class:`TrackStats` counts per cue the frames
    without a measurement and those it failed on (with the first message).

Warm-start replay (``TrackConfig.replay_frames``, K)
    The filter starts at rest with every cue at its configured noise, and the
    per-cue noise (:mod:`fusion_pf.filter.calibration`) needs some 20-30
    frames to learn, e.g., that a sharp depth cue is 0.3 px: meanwhile the
    track trusts its own prediction and lags the moving palm (on the matrix
    scenes with one very precise cue, half or more of the squared error was
    in the first 20-30 frames). So the frames from the first one in which a
    target holds a track are held (their cue rows only: the cues ran once)
    until K of them are, and the filters then run again over them from the
    first, new filters (same seeds) with the noise, outlier probabilities
    and process noise the first pass learned from those frames, fixed during
    the replay (they taught them once), and its palm scale, which the replay
    goes on smoothing over those frames; they start at the most
    trusted cue within one apparent palm length of an anchor (a cue the
    learned noise trusts may be off the palm in the first frame): a backward
    pass (a filter with the same learned noise run over the held frames from
    the last to the first, started where the first pass had settled) gives
    each held frame's anchor, so the start is chosen by the agreement of all
    the held frames, not by the cues of the first one alone; a frame where no
    cue lies near its anchor (every cue off the palm) holds the track
    ``uninitialised`` (no estimate) and the next frame tries its own anchor.
    They go on online after the held frames. The held frames' rows
    come from the replay, in frame order, one per frame, K frames late, once
    (a live view receives them at once; a queue shorter than K drops the
    oldest, counted). A stream that ends before K tracked frames replays
    what it has; so does one stopped by a signal or a source's fault, whose
    held rows come out before the error. Only the first start of the stream is replayed: after a
    loss the learned noise persists, so a re-acquisition does not start
    from the configured noise, and is not delayed. Several targets are held
    and replayed together (from the first frame any of them holds a track),
    the supervision between them included.

Background model (colour and depth cues)
    1. the ``background`` argument: a model the caller built, e.g. the command
       line from the empty-scene recording ``config.background`` (the pipeline
       never opens files or devices itself);
    2. else the source's own leading background frames (``Frame.background``,
       announced by the MCAP metadata ``fusion_pf.recording``
       ``background_frames``);
    3. else a model learnt from the stream: the first ``background_k`` frames
       (default :data:`~fusion_pf.pipeline.config.DEFAULT_BACKGROUND_K`) are
       read ahead to warm it up, then tracked like every other frame;
       ``background_mode="adaptive"`` (default) keeps learning
       (:class:`~fusion_pf.cues.background.AdaptiveBackground`: MOG2 colour,
       farthest depth), ``"median"`` is their fixed per-pixel median.
    Background frames of the source are never tracked: they give a
    :class:`TrackResult` with ``background=True``, no cues and no estimate (the
    filter is not stepped), and the outputs skip them.

Uncertainty
    ``sigma_px`` of a tracking frame with two cues or more is
    ``sqrt(s_n^2 + d_n^2 + max(B_n, mean_i max(0, r_i^2 - s_i^2)))``: the error
    of the cue nearest the estimate (``n``: its noise ``s_n`` per axis and its
    distance ``d_n`` from the estimate) plus the larger of its slow error and
    the cues' disagreement that their noise does not explain (``r_i`` the
    distance of cue ``i`` from the estimate, ``s_i`` its noise per axis: the
    fused one, or a confident measurement's own white noise, quality at least
    :data:`~fusion_pf.filter.calibration.SELF_QUALITY`, where the calibration
    knows it and it is smaller). ``B_n`` is the nearest cue's slow error per
    axis (:meth:`~fusion_pf.filter.calibration.NoiseCalibration.slow`, from the
    offsets of confident pairs of cues, as the floors take it; 0 before
    :data:`~fusion_pf.filter.calibration.SLOW_MIN` frames of a pair): a cue's
    white noise does not see its bias, and where the other cues lie near the
    estimate by chance, or their own noise explains their distance, the
    disagreement term did not either. The larger, not the sum: a bias the
    cues' disagreement shows is the same bias. A frame with one cue or none has
    ``sqrt(lambda_max + max(0, r^2 - s^2) + B)``, the posterior position
    variance along its widest axis plus that cue's unexplained distance and its
    slow error as learned while other cues measured beside it (from every pair
    whatever its quality, and the whole of a pair's offset where only two cues
    were measured together: either may be the biased one; 0 for a cue that never
    had another beside it): a lone cue's noise is learned from its own
    differences, which do not see its slow error (with the nearest-cue form, the
    real development frames, where the learned hand cue measures alone, were
    covered at 2 sigma in 77.4 % (1280 x 720) and 64.2 % (256 x 256) of frames
    instead of 90.6 % and 91.5 %). The error is below ``2 sigma_px`` in ~95 % of
    frames (measured on synthetic scenes, docs/architecture.md).
    The two slow-error terms, measured (the estimates do not change; 2-sigma
    coverage, mean over scenes): the ray-cast scenes of
    ``benchmarks/raycast_scenes.py`` (another renderer), seeds 1-24, where
    ray-18-1280 and ray-23-320 were examined to choose the form, 88.2 -> 90.3 %
    (10 -> 8 scenes below 90 %; ray-23-320 54 -> 74 %, its skeleton alone
    5.5 px off for 72 frames); seeds 25-36, not examined, 88.7 -> 90.5 % (4 -> 3
    below 90 %); the own generator's held-out scenes (``--generate``
    24001-26030, 90 scenes) 94.9 -> 95.5 % (12 -> 11 below 90 %, 15 -> 24 above
    98 %; at 1 sigma 75.7 -> 77.8 %); the real development frames unchanged
    (90.6 and 91.5 %: one cue). With the sum of the two terms in place of the
    larger (and ``B_n`` from every pair, whatever its quality) the own scenes
    were covered in 97.3 % (24001-24030, 16 of 30 above 98 %) and the ray-cast
    ones in 97.9 % (18 of 24 above 98 %): the same bias counted twice.

    Why the nearest cue and not the posterior spread: the spread of a cue
    fused at its floor (a far palm's 0.2 px depth blob fused at 1-2 px) was
    several times its error (2-sigma coverage 100 % on far scenes), and it
    does not grow when the estimate lies between cues, where the error is.
    Why the white noise: a cue's fused noise is learned against the
    prediction, so while the track follows another cue it absorbs the two
    cues' offset. On the tune scene gen-40002-near-1024 the track followed a
    depth blob 10-25 px off the palm (white noise 0.2 px, fused at 3.5 px);
    the skeleton, 1-9 px off (white noise 1.1 px), was fused at 13.4 px, so its
    10-20 px from the estimate counted as noise and ``sigma_px`` said 2.5-3 px
    (2-sigma coverage 72 %). An offset beyond a cue's own white noise is no
    noise of that cue: one of the two cues, and the estimate with it, is that
    far off. The estimates do not depend on ``sigma_px``.
    A combined target's shared region copy (:func:`_offset_shared`) counts its
    guessed offset's error, :data:`SHARED_SPREAD_PALMS` of the apparent palm length per axis, in
    its white noise (:meth:`_FilterStage._explained`): fused at 0.1-0.2 px, the
    copies made ``sigma_px`` 0.3-1.5 px where the joined hands' error was 4-6 px.
    ``sigma_mm`` is the lateral counterpart of ``sigma_px`` at the palm's depth,
    ``sigma_px * z / fx`` (depth error not included).

3-D palm
    ``xyz_mm`` is the estimate back-projected with the median of the non-zero
    depths in a ``(2 r + 1)^2`` window (``r = depth_radius``) around it
    (:mod:`fusion_pf.geometry`). The depth used is the frame's ROI grown by
    :data:`PATCH_MARGIN` px (kept with the cue row, so filter-only reruns give
    the same ``xyz_mm`` as :func:`track`); ``xyz_mm`` is None when the estimate
    is outside it or no valid depth lies in the window.

Outputs are in :mod:`fusion_pf.pipeline.outputs` (CSV, JSON messages) and, for
MCAP, ``drivers.tracker_topics``.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Generic, TypeVar

import numpy as np

from ..association import HANDS, Detection, associate
from ..association.base import FRAGMENT_AREA, fragment, region_area
from ..cues.background import AdaptiveBackground, BackgroundModel
from ..cues.base import SOURCES, Cue, CueContext, opencv_threads
from ..cues.regions import DEFAULT_PALM_AREA
from ..cues.registry import CUES, build_cues
from ..cues.roi import PALM_LENGTH_MM, Roi, full_roi, make_roi
from ..errors import InputError
from ..filter import Estimate, KalmanFilter, ParticleFilter, Tracker
from ..filter.bursts import BURST_PALMS, BurstFilter
from ..filter.calibration import (
    MOTION_MIN,
    MOTION_WINDOW,
    SELF_QUALITY,
    NoiseCalibration,
    process_scale,
    starting_sigma,
)
from ..filter.estimate import largest_std
from ..filter.kernel import warm_up
from ..filter.likelihood import DEFAULT_OUTLIER_AREA_PX2, quality_sigma
from ..filter.sspf import ScatterSearchPF
from ..filter.states import (
    Evidence,
    StateConfig,
    TrackState,
    TrackStatus,
    combine_states,
    reassign_identities,
    step_state,
)
from ..frame import Frame, Intrinsics, Measurement, PalmPoint
from ..geometry import backproject, depth_at
from .config import TrackConfig
from .events import Event, EventDetector

__all__ = [
    "PATCH_MARGIN",
    "CueRow",
    "TrackResult",
    "STATES",
    "TrackStats",
    "cue_names",
    "cue_window",
    "pixel_scale",
    "extract_cues",
    "make_tracker",
    "run_filter",
    "stages",
    "track",
]

#: Pixels the stored depth patch extends beyond the ROI on each side.
PATCH_MARGIN = 32
#: The image size the pixel defaults (noise, window, palm area) were tuned at.
REFERENCE_SIZE = (320, 200)
#: Track states of the single target (paper 004 §5.2), as written to the outputs.
STATES = (TrackState.UNINITIALISED.value, TrackState.TRACKING.value, TrackState.LOST.value)
#: Apparent palm length in the reference scene, px: the synthetic person's palm at its median
#: distance in ``recordings/sample.mcap`` (1269 mm, fx 249.6 px at 320 x 200).
REFERENCE_PALM_PX = PALM_LENGTH_MM * 249.6 / 1269.0
#: Weight of one frame in the smoothed palm scale (a time constant of 5 frames).
PALM_RATE = 0.2
#: Relative change of the palm scale before the filter's noises are set again.
RESCALE_TOLERANCE = 0.02
#: Consecutive frames with a too-wide posterior before the track is lost.
DEGRADED_FRAMES = 3
#: States in which a target holds a track (an estimate): alone or joined (paper 004's ``combined``), or just separated.
HOLDING = (TrackState.TRACKING, TrackState.COMBINED, TrackState.UNLABELLED)
#: Detections of one source closer than this (px at the reference size) are one (two windows saw the same region).
MERGE_PX = 1.0
#: Two targets' estimates closer than this many of their apparent palm lengths are ``combined`` (paper 004) ...
COMBINE_PALMS = 1.07
#: ... combined ones farther apart than this separate ...
SEPARATE_PALMS = 1.87
#: ... and so do two targets whose own evidence (skeleton joints, two separate detections of one cue)
#: lies farther apart than this (two palms side by side are one palm width, about 0.45 lengths, apart;
#: at 1.1 a pair rubbing its hands separated and rejoined within 3-7 frames: false events on the scripted scene).
APART_PALMS = 1.5
#: A cue supports the estimate within this many of its noise plus the posterior spread
#: (a 2-D Gaussian lies farther in 1.1 % of frames).
SUPPORT_SIGMAS = 3.0
#: Several targets: a tracked target's association gate of a source is at least this many of
#: its apparent palm lengths (:meth:`_FilterStage.source_gates`).
GATE_FLOOR_PALMS = 1.0
#: A combined target's share of the region it shares with its partner is moved this many of its apparent
#: palm lengths toward the side it entered the combination from (:meth:`_Targets.offsets`): half the
#: distance between two palms side by side. A shared copy is uncertain by as much (:func:`_shared_widened`).
SHARED_OFFSET_PALMS = 0.225
#: The error of a combined target's guessed offset (:data:`SHARED_OFFSET_PALMS`) per axis, apparent palm lengths,
#: as ``sigma_px`` counts it in a shared copy's noise (module docstring, "Uncertainty").
SHARED_SPREAD_PALMS = SHARED_OFFSET_PALMS / 3.0
#: A pair combining again within this many frames of separating keeps the sides it first entered from
#: (:meth:`_Targets.offsets`): it was never apart, and its estimates right after a brief separation
#: are no evidence of where each hand is.
REJOIN_FRAMES = 5
#: A combined pair's region is split between them (:func:`fusion_pf.cues.regions.split_region`) while
#: their priors are at least this many apparent palm lengths apart (the hands side by side).
SPLIT_PALMS = 0.85
#: Smallest quality of a cue that may restart the filter at itself (``jump_sigmas``):
#: the hand cue's presence score is 0.9-1.0 on a visible hand.
JUMP_MIN_QUALITY = 0.8
#: Smallest quality of a lone measurement (no other cue within one apparent palm length) that may re-acquire a
#: lost track when more than one cue runs (:meth:`_FilterStage._startable`): below it the filter waits for a
#: confident cue or two that agree. With the person out of view the whole-frame search of the colour cue finds
#: scraps of the room (a pale book under flickering light, quality 0.03-0.38; on a lit scene 0.69), and a track
#: re-acquired there was 100-290 px off when the person came back (``synth --away``), its cue windows held around
#: the scrap while the person came in (gen-45413-lit-320: 23-87 px off for 11 frames). A confident cue, as for a
#: jump: 0.5 (session 29) still let the lit scene's scrap in. The first start is not held to it: a recording whose
#: one measuring cue is weak (a real RGB-D recording whose hand cue never fires, depth at 0.07-0.34) is tracked
#: from its first frame, as before. The cost: a person who comes back while the cues disagree and none is
#: confident waits until two agree (the default scene with ``--away 30``, seed 7: 11 frames, depth right at 0.36;
#: gen-45413: 11 frames, depth right at 0.25-0.31 beside a skeleton 40-60 px off).
START_MIN_QUALITY = JUMP_MIN_QUALITY


#: Without an empty scene (:attr:`BackgroundModel.learnt`), the auto cue that
#: replaces a background-subtraction cue of the paper's setting (:func:`cue_names`).
NO_SCENE_CUES = {"colour": "skin_rgb"}


def pixel_scale(size: tuple[int, int], config: TrackConfig) -> float:
    """Image diagonal over the :data:`REFERENCE_SIZE` diagonal (1 with ``config.scale_noise`` off)."""
    if not config.scale_noise:
        return 1.0
    return math.hypot(*size) / math.hypot(*REFERENCE_SIZE)


def cue_names(config: TrackConfig, frame: Frame | None = None, *, learnt: bool = False) -> tuple[str, ...]:
    """The cues ``config`` computes on a recording whose first tracked frame is ``frame``.

    ``config.cues`` when given. Otherwise (auto): on a recording with a
    skeleton and no camera hands, the paper's colour, depth and skeleton (paper
    003's setting, a body-tracking camera); else the learned ``hand`` cue plus
    ``depth`` and ``skeleton`` where the recording has them. Without a frame
    (nothing seen yet) the auto choice is the paper's.

    ``learnt``: the background is learnt from the recording itself (no
    empty-scene frame, :attr:`BackgroundModel.learnt`). The person is then part
    of it, so the colour cue's difference image shows motion since the warm-up
    rather than the hands (a palm in front of the learnt shirt differs from it
    by more than the colour band's upper bound; 30-50 px off on two-hand scenes
    with the hands near the body); the paper's setting then takes the skin rule
    ``skin_rgb`` (paper 002, no background) in its place.
    """
    if config.cues is not None:
        return config.cues
    if frame is None or (frame.joints is not None and frame.hands is None):
        return tuple(NO_SCENE_CUES.get(n, n) for n in SOURCES) if learnt else SOURCES
    return (
        "hand",
        *(("depth",) if frame.depth is not None else ()),
        *(("skeleton",) if frame.joints is not None else ()),
    )


def stages(cues: Sequence[str]) -> tuple[str, ...]:
    """Latency stages of a frame in pipeline order: decode, one per cue, filter, total."""
    return ("decode", *cues, "filter", "total")


@dataclass(frozen=True, eq=False)
class CueRow:
    """The cues of one frame, computed once and reusable by :func:`run_filter`.

    Attributes
    ----------
    frame : int
        Index of the frame in the source (background frames included).
    timestamp_ns : int
    background : bool
        An empty-scene frame: no cues, never tracked.
    cues : mapping of str to Measurement or None
        Per computed cue (:func:`cue_names`).
    latency_ns : mapping of str to int
        ``decode``, ``colour``, ``depth``, ``skeleton``.
    roi : Roi or None
        Window the colour and depth cues processed (None: no prior yet).
    depth_patch : ndarray (h, w) uint16 or None
        Depth of the ROI grown by :data:`PATCH_MARGIN` (for the 3-D palm).
    patch_origin : (int, int)
        Full-frame ``(x0, y0)`` of ``depth_patch``.
    intrinsics : Intrinsics
    ground_truth : PalmPoint or None
    """

    frame: int
    timestamp_ns: int
    background: bool
    cues: Mapping[str, Measurement | None]
    latency_ns: Mapping[str, int]
    roi: Roi | None
    depth_patch: np.ndarray | None
    patch_origin: tuple[int, int]
    intrinsics: Intrinsics
    ground_truth: PalmPoint | None = None

    def measurements(self, sources: Sequence[str]) -> list[Measurement]:
        """The present measurements of ``sources``, in that order."""
        return [m for s in sources if (m := self.cues.get(s)) is not None]


@dataclass(eq=False)
class TrackResult:
    """The tracker's output for one frame.

    Attributes
    ----------
    frame : int
        Index of the frame in the source.
    timestamp_ns : int
    background : bool
        An empty-scene frame (not tracked; estimate None, no cues).
    estimate : Estimate or None
        None for background frames and until the filter is initialised.
    cues : dict of str to Measurement or None
    xyz_mm : ndarray, shape (3,), or None
        Palm in camera coordinates (mm).
    latency_ns : dict of str to int
        Per stage of :func:`stages` (plus ``sinks`` once the command wrote the frame).
    roi : Roi or None
    particles : ndarray, shape (N, 2), or None
        Particle positions after the step (particle filter only).
    weights : ndarray, shape (N,), or None
        Their normalised weights.
    ground_truth : PalmPoint or None
    source_frame : Frame or None
        The frame itself (set by :func:`track`, None from :func:`run_filter`).
    state : str
        Track state after this frame, one of :data:`STATES` (``lost`` and
        ``uninitialised`` frames have no estimate).
    evaluations : int
        Likelihood evaluations the filter made in this frame (paper 002's cost measure).
    target : str
        The target this result is of (``config.targets[0]``, else ``config.joint``).
    targets : dict of str to TrackResult
        With several targets (``config.targets``): every target's result, this
        one's first; empty for one target.
    sigma_px : float or None
        Uncertainty of the estimate, px (module docstring, "Uncertainty"); None without an estimate.
    sigma_mm : float or None
        Its lateral counterpart at the palm's depth, mm; None without ``xyz_mm``.
    events : list of Event
        The interaction events this frame confirmed (:mod:`fusion_pf.pipeline.events`; set by :func:`track`).
    """

    frame: int
    timestamp_ns: int
    background: bool
    estimate: Estimate | None
    cues: dict[str, Measurement | None]
    xyz_mm: np.ndarray | None
    latency_ns: dict[str, int]
    roi: Roi | None = None
    particles: np.ndarray | None = None
    weights: np.ndarray | None = None
    ground_truth: PalmPoint | None = None
    source_frame: Frame | None = None
    state: str = TrackState.UNINITIALISED.value
    evaluations: int = 0
    target: str = "right_hand"
    targets: dict[str, "TrackResult"] = field(default_factory=dict)
    sigma_px: float | None = None
    sigma_mm: float | None = None
    events: list[Event] = field(default_factory=list)


# ---------------------------------------------------------------------- background


def _timed(source: Iterable[Frame]) -> Iterator[tuple[int, Frame, int]]:
    """``(index, frame, decode_ns)`` for every frame of ``source``.

    ``index`` is the frame's own index in its recording (``Frame.index``: lost
    frames leave gaps), else its position in the stream.
    """
    it = iter(source)
    count = 0
    while True:
        t0 = time.perf_counter_ns()
        try:
            frame = next(it)
        except StopIteration:
            return
        yield (count if frame.index is None else frame.index), frame, time.perf_counter_ns() - t0
        count += 1


def _needs_background(config: TrackConfig, frame: Frame) -> bool:
    """Whether a cue ``config`` runs on ``frame``'s recording subtracts a background (colour or depth)."""
    return any("background" in CUES[name].needs for name in cue_names(config, frame))


def _with_background(
    source: Iterable[Frame], config: TrackConfig, background: BackgroundModel | None
) -> Iterator[tuple[int, Frame, int, BackgroundModel | None]]:
    """Frames with the background model to use for them (None for background frames).

    Without a cue that needs a background (e.g. the hand cue alone), no model
    is learnt: tracked frames get an empty :class:`BackgroundModel` and cost
    no background subtractor update.
    """
    frames = _timed(source)
    model = background
    empties: list[Frame] = []
    for index, frame, dec in frames:
        if frame.background:
            if model is None:
                empties.append(frame)
            yield index, frame, dec, None
            continue
        if model is None and not _needs_background(config, frame):
            model = BackgroundModel(None, None)
        if model is None:
            if empties:
                model = BackgroundModel.from_frames(empties)
            else:
                ahead = [(index, frame, dec)]
                for item in frames:
                    if item[1].background:
                        raise InputError(
                            f"background frame {item[0]} comes after tracked frames; "
                            "background frames must lead the recording"
                        )
                    ahead.append(item)
                    if len(ahead) >= config.background_k:
                        break
                warm = [f for _, f, _ in ahead]
                if config.background_mode == "median":
                    model = BackgroundModel.from_frames(warm, learnt=True)
                else:
                    model = AdaptiveBackground(warm, history=10 * config.background_k)
                _check_size(model, index, frame)
                for i, f, d in ahead:
                    yield i, f, d, model
                    if isinstance(model, AdaptiveBackground):
                        model.adapt(f)
                continue
            empties.clear()
        if model.ready:
            _check_size(model, index, frame)
        yield index, frame, dec, model
        if isinstance(model, AdaptiveBackground):
            model.adapt(frame)


def _check_size(model: BackgroundModel, index: int, frame: Frame) -> None:
    assert model.color is not None, "the background model has no colour image yet"
    h, w = model.color.shape[:2]
    if (w, h) != frame.size:
        raise InputError(f"background is {w}x{h} but frame {index} is {frame.size[0]}x{frame.size[1]}")


# ---------------------------------------------------------------------- cues


def cue_window(
    frame: Frame, prior: tuple[float, float] | None, config: TrackConfig, palm_px: float | None = None
) -> Roi | None:
    """The cue window around ``prior`` in ``frame`` (None without a prior).

    Sized from the palm's apparent length ``palm_px`` when given, else from
    the depth at the prior, else fixed (:func:`~fusion_pf.cues.make_roi`).
    """
    if prior is None:
        return None
    z = None
    if palm_px is None and frame.depth is not None:
        z = depth_at(frame.depth, *prior, radius=config.depth_radius)
    return make_roi(
        prior[0],
        prior[1],
        frame.size,
        palm_px=palm_px,
        depth_mm=z,
        fx=frame.intrinsics.fx,
        half_size=config.roi_half_size,
        palms=config.roi_palms,
        pixel_scale=pixel_scale(frame.size, config),
    )


def targets_of(config: TrackConfig) -> tuple[str, ...]:
    """The targets ``config`` tracks: ``config.targets``, else the single palm named by ``config.joint``."""
    return config.targets if config.targets is not None else (config.joint,)


def window_groups(targets: Sequence[str], rois: Mapping[str, Roi | None]) -> list[tuple[str, Roi | None]]:
    """The windows the region cues process: overlapping target windows merged into one.

    A target's window joins a group when the bounding box of the group and the
    window is no larger than their areas together (two hands side by side,
    joined hands, two whole-frame searches), so no pixel is processed twice
    for little extra area. Returns ``(first target, window)`` per group: the
    first target's cue instance (and its per-stream state) processes the group.
    """
    groups: list[tuple[str, Roi | None, float]] = []
    for t in targets:
        roi = rois[t]
        area = 0.0 if roi is None else float(max(roi.x1 - roi.x0, 0) * max(roi.y1 - roi.y0, 0))
        for k, (first, g, g_area) in enumerate(groups):
            if roi is None or g is None or roi.empty or g.empty:
                continue
            x0, y0 = min(g.x0, roi.x0), min(g.y0, roi.y0)
            x1, y1 = max(g.x1, roi.x1), max(g.y1, roi.y1)
            if (x1 - x0) * (y1 - y0) <= g_area + area:
                groups[k] = (first, Roi(x0, y0, x1, y1, g.palm_area), g_area + area)
                break
        else:
            groups.append((t, roi, area))
    return [(t, roi) for t, roi, _ in groups]


class _CueStage:
    """Per-stream cue extraction: the configured cues, their state and the ROI prior of every target.

    Every target gets its own window (around its prior, the whole frame
    without one); the colour, depth and skin cues measure in each target's
    window, the skeleton cue reads each target's joint (a detection labelled
    with the target), the hand cue runs once and follows up to as many hands
    as there are hand targets. Their detections are then associated to the
    targets (:func:`fusion_pf.association.associate`); each target's row holds
    the detection each source gave it.
    """

    def __init__(self, config: TrackConfig) -> None:
        self.config = config
        self.targets = targets_of(config)
        self.names: tuple[str, ...] = config.cues or ()
        self.cues: dict[str, dict[str, Cue]] | None = None if config.cues is None else self._build()
        self.last_joint: dict[str, tuple[float, float]] = {}
        self.missing: dict[str, int] = {}
        self.rested: dict[str, int] = {}
        self.failed: dict[str, int] = {}
        self.first_error: dict[str, str] = {}
        self.noise_rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(1,)))

    def _build(self) -> dict[str, dict[str, Cue]]:
        """The cues of every target (each keeps its own per-stream state, e.g. the depth cue's previous frame)."""
        return {t: build_cues(self.names, self.config.cue_options) for t in self.targets}

    def prior(
        self, frame: Frame, mode: str, prediction: tuple[float, float] | None, target: str | None = None
    ) -> tuple[float, float] | None:
        """The ROI prior of ``target`` (default: the first) in ``frame`` under ``mode`` (module docstring)."""
        target = self.targets[0] if target is None else target
        joint = frame.joint(target)
        if joint is not None and joint.confidence > 0:
            self.last_joint[target] = (joint.u, joint.v)
        last = self.last_joint.get(target)
        confident = joint is not None and joint.confidence >= self.config.prior_confidence
        if mode == "auto" and prediction is None and not confident:
            return None  # acquisition without a confident joint: search the whole frame
        if mode == "skeleton" or prediction is None:
            return last
        if mode == "auto" and confident:
            assert joint is not None  # confident
            return joint.u, joint.v
        return prediction

    def roi(self, frame: Frame, prior: tuple[float, float] | None, palm_px: float | None) -> Roi | None:
        """Window around ``prior`` (:func:`cue_window`)."""
        return cue_window(frame, prior, self.config, palm_px)

    def detect(self, name: str, cue: Cue, index: int, frame: Frame, ctx: CueContext) -> tuple[Detection, ...]:
        """``cue``'s detections in ``frame``; none (the failure counted) when it fails on this frame; a rest counted."""
        try:
            result = cue.measure(frame, ctx)
            if result.rested:
                self.rested[name] = self.rested.get(name, 0) + 1
            found = result.detections
            for d in found:
                if not (math.isfinite(d.u) and math.isfinite(d.v)):
                    raise ValueError(f"non-finite position ({d.u}, {d.v})")
        except Exception as exc:  # one frame's fault never ends the run: no measurement, counted
            found = ()
            self.failed[name] = self.failed.get(name, 0) + 1
            self.first_error.setdefault(name, f"frame {index}: {exc}".splitlines()[0])
        return found

    def add_noise(self, cues: dict[str, Measurement | None]) -> dict[str, Measurement | None]:
        """``cues`` with ``config.cue_noise_px`` Gaussian noise added (paper 003 §4.2-4.3)."""
        draws = self.noise_rng.standard_normal((len(self.names), 2))
        out = dict(cues)
        for i, s in enumerate(self.names):
            sigma = self.config.cue_noise_px.get(s, 0.0)
            m = cues[s]
            if m is not None and sigma > 0:
                extras = {**m.extras, "added_noise_px": sigma}
                out[s] = Measurement(s, m.u + sigma * draws[i, 0], m.v + sigma * draws[i, 1], m.quality, extras)
        return out

    def __call__(
        self,
        index: int,
        frame: Frame,
        decode_ns: int,
        model: BackgroundModel | None,
        prior: tuple[float, float] | None,
        palm_px: float | None = None,
    ) -> CueRow:
        """All cues of one frame for the first target: in the window around ``prior`` (sized by ``palm_px``, :func:`cue_window`), or over the whole frame without one (acquisition)."""
        t = self.targets[0]
        return self.rows(index, frame, decode_ns, model, {t: prior}, {t: palm_px})[t]

    def rows(
        self,
        index: int,
        frame: Frame,
        decode_ns: int,
        model: BackgroundModel | None,
        priors: Mapping[str, tuple[float, float] | None],
        palms: Mapping[str, float | None] | None = None,
        partners: Mapping[str, str] | None = None,
        source_gates: Mapping[str, Mapping[str, float] | None] | None = None,
        offsets: Mapping[str, tuple[float, float]] | None = None,
        keep_slivers: bool = False,
    ) -> dict[str, CueRow]:
        """Every target's cue row of one frame: detections in the targets' windows (sized by ``palms``), associated to the targets.

        Several targets: a target's detection of a source lies within its
        window's gate (:meth:`_gate`) and its ``source_gates`` of that source
        (:meth:`_FilterStage.source_gates`). A combined target's copy of the
        region detection it shares with its partner is moved by its
        ``offsets`` (:meth:`_Targets.offsets`). A hand's region slivers are
        dropped (:func:`_without_fragments`) unless ``keep_slivers``: the world
        tracker keeps them, its other cameras outvote one camera's sliver (with
        them dropped, the synthetic 4-camera rig at 320 x 200 lost a hand's
        contact with the head, ``benchmarks/rig_events.py`` seed 5).
        """
        if self.cues is None:
            self.names = cue_names(self.config, frame, learnt=model is not None and model.learnt)
            self.cues = self._build()
        lat = {"decode": decode_ns}
        targets = tuple(priors)
        several = len(targets) > 1
        rois: dict[str, Roi | None] = {}
        for t, p in priors.items():
            if p is None:
                s = pixel_scale(frame.size, self.config)
                rois[t] = full_roi(*frame.size, palm_area=DEFAULT_PALM_AREA * s * s)
            else:
                rois[t] = self.roi(frame, p, (palms or {}).get(t))
        hands = max(1, sum(t in HANDS for t in targets)) if several else 1
        detections: list[Detection] = []
        groups = window_groups(targets, rois)
        with opencv_threads(self.config.cue_options.cv_threads):  # no cue waits for a core held elsewhere
            for name in self.names:
                t0 = time.perf_counter_ns()
                needs = self.cues[targets[0]][name].needs
                if name == "hand":
                    calls = [(targets[0], rois[targets[0]])]
                elif "skeleton" in needs:
                    calls = [(t, rois[t]) for t in targets]
                else:
                    calls = groups
                for t, roi in calls:
                    ctx = CueContext(
                        roi=roi,
                        background=model,
                        joint=t,
                        prior=priors[t],
                        search=priors[t] is None,
                        hands=hands,
                        candidates=several,
                        parts=_joined_priors(priors, partners or {}, roi, palms or {}),
                    )
                    found = self.detect(name, self.cues[t][name], index, frame, ctx)
                    if "skeleton" in needs:  # the joint of target t: a certain label
                        found = tuple(Detection(d.measurement, label=t) for d in found)
                    detections.extend(found)
                lat[name] = time.perf_counter_ns() - t0
        assigned = associate(
            targets,
            [priors[t] for t in targets],
            detections,
            gates=[self._gate(frame, rois[t] if several and priors[t] is not None else None) for t in targets],
            source_gates=[(source_gates or {}).get(t) if several else None for t in targets],
            partners=partners,
            merge_px=MERGE_PX * pixel_scale(frame.size, self.config),
        )
        if several and not keep_slivers:
            assigned = _without_fragments(assigned, rois)
        if several and partners and offsets:
            assigned = _offset_shared(assigned, partners, offsets)
        out = {}
        for t in targets:
            cues: dict[str, Measurement | None] = dict.fromkeys(self.names)
            for d in assigned[t]:
                cues[d.source] = d.measurement
            if t == targets[0]:
                for name in self.names:
                    self.missing[name] = self.missing.get(name, 0) + (cues[name] is None)
            if self.config.cue_noise_px:
                cues = self.add_noise(cues)
            out[t] = self._row(index, frame, cues, dict(lat), rois[t], t if several else None)
        return out

    @staticmethod
    def _gate(frame: Frame, roi: Roi | None) -> float:
        """Association gate of a target: half its window's diagonal; the image diagonal without a window (one target, acquisition)."""
        if roi is None or roi.empty:
            return math.hypot(*frame.size)
        return max(math.hypot(roi.x1 - roi.x0, roi.y1 - roi.y0) / 2.0, 1.0)

    @staticmethod
    def _row(
        index: int,
        frame: Frame,
        cues: dict[str, Measurement | None],
        lat: dict[str, int],
        roi: Roi | None,
        target: str | None,
    ) -> CueRow:
        """The cue row of one target (``target`` None: the single palm, whose ground truth is the frame's)."""
        patch, origin = None, (0, 0)
        if roi is not None and not roi.empty and frame.depth is not None:
            w, h = frame.size
            x0, y0 = max(roi.x0 - PATCH_MARGIN, 0), max(roi.y0 - PATCH_MARGIN, 0)
            x1, y1 = min(roi.x1 + PATCH_MARGIN, w), min(roi.y1 + PATCH_MARGIN, h)
            patch, origin = frame.depth[y0:y1, x0:x1].copy(), (x0, y0)
        return CueRow(
            frame=index,
            timestamp_ns=frame.timestamp_ns,
            background=False,
            cues=cues,
            latency_ns=lat,
            roi=roi,
            depth_patch=patch,
            patch_origin=origin,
            intrinsics=frame.intrinsics,
            ground_truth=frame.ground_truth if target is None else (frame.ground_truths or {}).get(target),
        )


def _without_fragments(
    assigned: Mapping[str, list[Detection]], rois: Mapping[str, Roi | None]
) -> dict[str, list[Detection]]:
    """Each hand's detections without the region detections smaller than :data:`~fusion_pf.association.FRAGMENT_AREA` of its window's expected palm area (other targets' as they are).

    Two hands overlapping a few cm in front of the body often leave the depth cue no region of the
    pair, only slivers of it and of the body around it (40-460 px^2 against the hand's 900-4000,
    20-60 px off the hands); a target measured by one drifts with it, and its skeleton joint, whose
    learned noise grew against that track, cannot pull it back.
    """
    out = {t: list(ds) for t, ds in assigned.items()}
    for t, roi in rois.items():
        if t in out and t in HANDS and roi is not None:
            least = FRAGMENT_AREA * roi.palm_area
            out[t] = [d for d in out[t] if (a := region_area(d.measurement)) is None or a >= least]
    return out


def _offset_shared(
    assigned: Mapping[str, list[Detection]], partners: Mapping[str, str], offsets: Mapping[str, tuple[float, float]]
) -> dict[str, list[Detection]]:
    """Each combined target's copy of a region detection it shares with its partner, moved by its offset.

    Labelled detections (skeleton joints, the hand model) and the parts of a
    split region are each target's own and stay.
    """
    out = {t: list(ds) for t, ds in assigned.items()}
    for t, q in partners.items():
        if t not in assigned or q not in assigned or t not in offsets:
            continue
        du, dv = offsets[t]
        for k, d in enumerate(assigned[t]):
            if d.label is not None or not any(d is e for e in assigned[q]):
                continue
            m = d.measurement
            moved = Measurement(m.source, m.u + du, m.v + dv, m.quality, {**m.extras, "shared": True})
            out[t][k] = Detection(moved, d.label, d.label_score, d.depth_mm)
    return out


def _shared_widened(ms: Sequence[Measurement], sigmas: Mapping[str, float], palm: float) -> dict[str, float]:
    """``sigmas`` (px per source) with each shared region copy's widened in quadrature by :data:`SHARED_OFFSET_PALMS` of ``palm`` (px), when every region measurement of ``ms`` is a shared copy.

    A combined target's copy of the region it shares with its partner is the region's centre moved
    by a guessed offset (:func:`_offset_shared`): where in the region each hand lies is uncertain by
    about that offset, whatever noise the cue learned on its own. Two hands overlapping in front of
    the body share the colour and the depth region; the colour cue's noise, learned at 2 px while
    tracking alone and kept there by a track that follows its copy, made the pair follow the colour
    region's centre, 10-15 px off both hands (depth's copy 5-9 px; issue 22).
    Widened, the shared copies weigh about alike and the targets' own skeleton joints count. A row
    holding a region of its own or a part of a split region keeps its noises: the shared copy is
    not made weaker than the target's own evidence.
    """
    out = dict(sigmas)
    regions = [m for m in ms if region_area(m) is not None]
    if not regions or not all(m.extras.get("shared") for m in regions):
        return out
    for m in regions:
        out[m.source] = math.hypot(out[m.source], SHARED_OFFSET_PALMS * palm)
    return out


def _joined_priors(
    priors: Mapping[str, tuple[float, float] | None],
    partners: Mapping[str, str],
    roi: Roi | None,
    palms: Mapping[str, float | None],
) -> tuple[tuple[float, float], ...]:
    """The priors of the first pair of hands (a combined pair first) whose priors both lie in ``roi`` at least :data:`SPLIT_PALMS` apparent palm lengths apart (the region cues split a region holding both).

    Closer (one hand over the other) the 2-means split cuts the front palm in
    two and the hidden hand's part is off its centre: the pair shares the region.
    Two hands apart whose one region holds both (crossed forearms) get a part each.
    """
    hands = [t for t in priors if t in HANDS]
    pairs = [*partners.items(), *((a, b) for n, a in enumerate(hands) for b in hands[n + 1 :])]
    for a, b in pairs:
        pa, pb, palm = priors.get(a), priors.get(b), palms.get(a)
        if pa is None or pb is None or palm is None:
            continue
        if math.hypot(pa[0] - pb[0], pa[1] - pb[1]) < SPLIT_PALMS * palm:
            continue
        if roi is None or all(roi.x0 <= p[0] <= roi.x1 and roi.y0 <= p[1] <= roi.y1 for p in (pa, pb)):
            return (pa, pb)
    return ()


def _background_row(index: int, frame: Frame, decode_ns: int, names: Sequence[str]) -> CueRow:
    return CueRow(
        frame=index,
        timestamp_ns=frame.timestamp_ns,
        background=True,
        cues={s: None for s in names},
        latency_ns={"decode": decode_ns, **{s: 0 for s in names}},
        roi=None,
        depth_patch=None,
        patch_origin=(0, 0),
        intrinsics=frame.intrinsics,
        ground_truth=frame.ground_truth,
    )


# ---------------------------------------------------------------------- filter


def make_tracker(
    config: TrackConfig, rng: np.random.Generator | int | None = None, size: tuple[int, int] | None = None
) -> Tracker:
    """The filter ``config`` describes: the particle filter (seeded by ``rng``, else ``config.seed``) or Kalman.

    Both learn the frame period from the timestamps (``frame_period_ns="auto"``):
    a steady source steps by one frame as in the paper, and a gap left by
    dropped frames is bridged by as many motion steps. For images of ``size``
    the measurement and process noise and the initial spread are scaled by
    :func:`pixel_scale`, and the robust likelihood's outlier area is the image.
    """
    s = 1.0 if size is None else pixel_scale(size, config)
    noise = {k: v * s for k, v in config.noise_px.items()}
    process = (config.process_noise[0] * s, config.process_noise[1] * s)
    if config.filter == "kf":
        return KalmanFilter(process_noise=process, noise_px=noise, frame_period_ns="auto", init_spread_px=20.0 * s)
    if config.filter == "sspf":
        return ScatterSearchPF(
            n_particles=config.particles,
            process_noise=process,
            noise_px=noise,
            frame_period_ns="auto",
            init_spread_px=20.0 * s,
            rng=config.seed if rng is None else rng,
        )
    return ParticleFilter(
        n_particles=config.particles,
        process_noise=process,
        noise_px=noise,
        likelihood=config.likelihood or "robust",
        use_quality=not config.adapt_noise,
        proposal=config.proposal,
        manoeuvre=(config.manoeuvre[0], config.manoeuvre[1] * s),
        resampler="residual",
        estimator="robust_mean",
        frame_period_ns="auto",
        init_spread_px=20.0 * s,
        init_velocity_px=2.0 * s,
        outlier_area_px2=DEFAULT_OUTLIER_AREA_PX2 if size is None else float(size[0] * size[1]),
        rng=config.seed if rng is None else rng,
    )


class _FilterStage:
    """The filter over a stream of cue rows, its track state and the prediction used as ROI prior.

    Initialisation and re-acquisition start the filter at the most trusted
    measurement (smallest quality-widened noise) that another cue agrees with,
    when any does (:meth:`_consensus`; ``config.init`` in the first tracked
    frame when given); a lost track only at one another cue agrees with or of
    quality :data:`START_MIN_QUALITY` or more (:meth:`_startable`). A tracking filter restarts at a confident
    cue beyond its reach (``config.jump_sigmas``, :meth:`_jumped`), and at the cues when a confident one another
    agrees with lies away from the track while no confident cue is near it (:meth:`_deserted`: a track started on
    a scrap of the room before the person came in). Supervision (:func:`fusion_pf.filter.states.step_state`):
    a cue *supports* the estimate when it lies within :data:`SUPPORT_SIGMAS` of
    its fused noise plus the posterior spread of it; the track is lost when the
    estimate leaves the image, when no fused cue supported it for
    ``config.silent_frames`` frames (the cues fell silent or disagree with it),
    or when the posterior position std stays above ``config.max_spread`` of the
    image diagonal for :data:`DEGRADED_FRAMES` frames; the filter is then reset,
    and the next frames search the whole image until a cue finds the palm again
    (a re-acquisition). Only ``tracking`` frames have an estimate: an
    ``uninitialised`` filter that is not yet supported is reset like a lost one.
    """

    def __init__(self, config: TrackConfig, rng: np.random.Generator | int | None) -> None:
        if config.filter == "pf":
            # the tracker is made at the first measurement: its compiled kernels are ready before any frame
            warm_up(wait=True)
        self.config = config
        self.rng = rng
        self.tracker: Tracker | None = None
        self.sources = config.sources
        self._history: list[tuple[int, float, float]] = []
        self.status = TrackStatus()
        self.states: StateConfig | None = None
        self.init = config.init
        self.reacquisitions = 0
        self.losses = 0
        self.jumps = 0
        self._spread: float | None = None
        self._size: tuple[int, int] | None = None
        self._var: dict[str, float] = {}
        self._palm_k: float | None = None
        self._applied_k: float | None = None
        self._scale = 1.0
        self._calibration = NoiseCalibration(self._starting_sigma) if config.adapt_noise else None
        self._moves: deque[float] = deque(maxlen=MOTION_WINDOW)
        self._motion_scale = 1.0
        self.bursts = BurstFilter() if config.burst_gate else None
        self._learn = True
        self._anchors: deque[tuple[float, float] | None] = deque()

    def replaying(self, learnt: _FilterStage, anchors: Sequence[tuple[float, float] | None]) -> None:
        """Start this (new) stage as the replay of ``learnt``'s first frames (module docstring, "Warm-start replay").

        It takes the noise, outlier probabilities and process noise ``learnt`` learned and keeps
        them fixed until :meth:`online` (the replayed frames taught them once); its smoothed palm
        scale is the start of this stage's own, smoothed on over the replayed frames. ``anchors``:
        where the palm is in each frame this stage will step, in order, as far as known (None: not
        known); until the filter is initialised it starts only at the most trusted cue within one
        apparent palm length of that frame's anchor (a cue the learned noise trusts may be off the
        palm in one frame), and holds (``uninitialised``) in a frame where no cue is; a frame without an
        anchor starts as a first start (:meth:`_consensus`).
        """
        self._calibration = learnt._calibration
        self._moves = learnt._moves
        self._motion_scale = learnt._motion_scale
        self._palm_k = learnt._palm_k
        self._learn = False
        self.init = None
        self._anchors = deque(anchors)

    def restart_at(self, m: Measurement, timestamp_ns: int) -> None:
        """Start the filter again at ``m`` (the next frame's window and prediction there)."""
        assert self.tracker is not None  # stepped
        self._restart(self.tracker, m)
        self._history = [(timestamp_ns, m.u, m.v)]

    def online(self) -> None:
        """Learn again from every frame (the replay is over)."""
        self._learn = True

    def _start(self, size: tuple[int, int]) -> None:
        self.tracker = make_tracker(self.config, self.rng, size)
        self._size = size
        self._init_spread = 20.0 * pixel_scale(size, self.config)
        self._var = {s: v * v for s, v in self.tracker.noise_px.items()}
        self._scale = pixel_scale(size, self.config)
        if self._palm_k is not None and self.config.palm_scale and self.config.scale_noise:
            self._rescale()  # a replay: the palm scale it learned, and its process noise
        elif self._motion_scale != 1.0:
            r = self._motion_scale * self._scale
            self.tracker.set_process_noise((self.config.process_noise[0] * r, self.config.process_noise[1] * r))
        diag = math.hypot(*size)
        self.states = StateConfig(
            max_spread_px=self.config.max_spread * diag,
            min_likelihood=0.0,
            silent_frames=self.config.silent_frames,
            degraded_frames=DEGRADED_FRAMES,
            image_size=size,
            merge_px=1.0,
            split_px=1.0,
        )

    @property
    def tracking(self) -> bool:
        """Whether the track holds (:data:`HOLDING`: an estimate, and a prediction to place the window)."""
        return self.status.state in HOLDING

    def prediction(self, timestamp_ns: int) -> tuple[float, float] | None:
        """Constant-velocity extrapolation of the last two estimates to ``timestamp_ns``, clamped to the image (None when lost)."""
        if self.init is not None:
            return self.init
        if not self._history or not self.tracking:
            return None
        t1, u1, v1 = self._history[-1]
        if len(self._history) == 1:
            return u1, v1
        t0, u0, v0 = self._history[-2]
        k = (timestamp_ns - t1) / (t1 - t0)
        u, v = u1 + k * (u1 - u0), v1 + k * (v1 - v0)
        assert self._size is not None  # set by _start with the first estimate
        return min(max(u, 0.0), self._size[0] - 1.0), min(max(v, 0.0), self._size[1] - 1.0)

    def source_gates(self) -> dict[str, float] | None:
        """Association gate per source, px: :data:`SUPPORT_SIGMAS` standard deviations of the posterior spread and the cue's noise, at least :data:`GATE_FLOOR_PALMS` palm lengths (None without a track).

        A detection the track would not count as support (:meth:`_support`) is
        not its own, whatever the window's size; the floor leaves room for the
        motion between two frames and a cue's bias on the palm.
        """
        if not self.tracking or self._spread is None or not self._var:
            return None
        floor = self._reach
        spread2 = self._spread**2
        return {s: max(floor, SUPPORT_SIGMAS * math.sqrt(spread2 + v)) for s, v in self._var.items()}

    @property
    def _reach(self) -> float:
        """:data:`GATE_FLOOR_PALMS` apparent palm lengths, px."""
        return GATE_FLOOR_PALMS * self._palm

    @property
    def _palm(self) -> float:
        """The apparent palm length, px (the reference palm at this image's scale until one is measured)."""
        return self.palm_px or REFERENCE_PALM_PX * self._scale

    @property
    def palm_px(self) -> float | None:
        """The palm's smoothed apparent length, px (None until a frame measured it)."""
        return None if self._palm_k is None else self._palm_k * REFERENCE_PALM_PX

    def _prior(self, m: Measurement) -> float:
        """Configured noise of ``m`` at scale 1: its source's ``--noise``, quality-widened (not a probability-quality cue)."""
        return quality_sigma(self.config.noise_px[m.source], m)

    def _starting_sigma(self, m: Measurement) -> float:
        """The noise ``m``'s learned noise starts from at scale 1 (:func:`~fusion_pf.filter.calibration.starting_sigma` of its ``--noise``)."""
        return starting_sigma(self.config.noise_px[m.source], m)

    def _calibrate(
        self,
        ms: Sequence[Measurement],
        trust: Mapping[str, float],
        predicted: tuple[float, float, float] | None,
        timestamp_ns: int,
    ) -> None:
        """Fuse this frame's cues with their calibrated noise and outlier probability (:class:`~fusion_pf.filter.calibration.NoiseCalibration`), then learn from them.

        ``trust`` is each source's calibrated noise at scale 1 (:meth:`_trust`); a combined target's
        shared region copies are fused with it widened (:func:`_shared_widened`). The cues are
        learned from against ``predicted`` (:meth:`_predicted`) when there is one.
        """
        calibration, tracker = self._calibration, self.tracker
        assert calibration is not None and tracker is not None  # adapt_noise; created by _start
        sigmas = _shared_widened(ms, {source: sigma * self._scale for source, sigma in trust.items()}, self._palm)
        for source, sigma in sigmas.items():
            tracker.set_noise(source, sigma)
            self._var[source] = sigma * sigma
        if isinstance(tracker, ParticleFilter):
            for m in ms:
                tracker.set_outlier_prob(m.source, calibration.outlier(m))
                # the white noise measured from the cue alone (confident measurements): the noise of its displacement
                white = calibration.white(m.source, m.quality) if m.quality >= SELF_QUALITY else None
                tracker.set_white_noise(m.source, None if white is None else math.sqrt(white) * self._scale)
        if self._learn:
            calibration.update(ms, sigmas, self._scale, predicted, timestamp_ns)

    def _predicted(self, timestamp_ns: int) -> tuple[float, float, float] | None:
        """The filter's prediction of this frame and its per-axis variance (u, v px, px^2) while it tracks, else None.

        The particle filter's own (:meth:`~fusion_pf.filter.pf.ParticleFilter.predicted`); for the
        other filters the constant-velocity extrapolation of the last two estimates (:meth:`prediction`)
        with the last posterior spread.
        """
        tracker = self.tracker
        if not self.tracking or self.init is not None or tracker is None or not tracker.initialised:
            return None
        if isinstance(tracker, ParticleFilter):
            return tracker.predicted(timestamp_ns)
        spread, predicted = self._spread, self.prediction(timestamp_ns)
        return None if spread is None or predicted is None else (*predicted, spread**2)

    def _jumped(self, m: Measurement, timestamp_ns: int) -> bool:
        """Whether a confident cue lies beyond the prediction's reach (``config.jump_sigmas`` of its noise plus the spread)."""
        predicted = self.prediction(timestamp_ns)
        if predicted is None or m.quality < JUMP_MIN_QUALITY or self._spread is None:
            return False
        reach = self.config.jump_sigmas * (math.sqrt(self._var[m.source]) + self._spread)
        return math.hypot(m.u - predicted[0], m.v - predicted[1]) > reach

    @staticmethod
    def _evaluations(tracker: Tracker, ms: Sequence[Measurement]) -> int:
        """Likelihood evaluations of this step: SSPF counts its own, a PF weighs its N particles once per frame with cues."""
        if isinstance(tracker, ScatterSearchPF):
            return tracker.evaluations
        if isinstance(tracker, ParticleFilter):
            return tracker.n_particles if ms else 0
        return 0

    def _palm_px(self, row: CueRow, ms: Sequence[Measurement], trust: Mapping[str, float]) -> float | None:
        """Apparent palm length in this frame: from the hand landmarks, else depth at the best cue (None without either)."""
        hand = row.cues.get("hand")
        landmarks = None if hand is None else hand.extras.get("landmarks")
        if landmarks is not None:
            lm = np.asarray(landmarks, dtype=np.float64)
            # wrist (0) to middle-finger base (9)
            return float(math.hypot(lm[9, 0] - lm[0, 0], lm[9, 1] - lm[0, 1]))
        if row.depth_patch is None or not ms:
            return None
        best = min(ms, key=lambda m: trust[m.source])
        x0, y0 = row.patch_origin
        h, w = row.depth_patch.shape
        if not (x0 - 0.5 <= best.u < x0 + w - 0.5 and y0 - 0.5 <= best.v < y0 + h - 0.5):
            return None
        z = depth_at(row.depth_patch, best.u - x0, best.v - y0, radius=self.config.depth_radius)
        # l_px = fx L_mm / z
        return None if z is None else row.intrinsics.fx * PALM_LENGTH_MM / z

    def _observe_palm(self, row: CueRow, ms: Sequence[Measurement], trust: Mapping[str, float]) -> bool:
        """Update the smoothed palm scale with this frame's palm length; whether there was one.

        The scale is an exponential average (rate :data:`PALM_RATE`) of
        ``palm_px / REFERENCE_PALM_PX`` and keeps its value in frames without a
        palm size.
        """
        palm = self._palm_px(row, ms, trust)
        if palm is None or not palm > 0.0:
            return False
        k = palm / REFERENCE_PALM_PX
        # k_bar <- k the first time, then (1 - a) k_bar + a k
        self._palm_k = k if self._palm_k is None else (1.0 - PALM_RATE) * self._palm_k + PALM_RATE * k
        return True

    def _rescale(self) -> None:
        """Scale the noises with the palm's apparent size (``config.palm_scale``).

        The defaults are px in the reference scene, where the palm is
        :data:`REFERENCE_PALM_PX` long; a palm ``k`` times longer (the smoothed
        scale of :meth:`_observe_palm`) gets ``k`` times the measurement,
        process and manoeuvre noise (a cue's error and a hand's motion in
        pixels both grow with its image size); the filter's noises are reset
        when ``k`` moved by more than :data:`RESCALE_TOLERANCE`.
        """
        k = self._palm_k
        assert k is not None  # _observe_palm saw a palm
        if self._applied_k is not None and abs(k - self._applied_k) <= RESCALE_TOLERANCE * self._applied_k:
            return
        self._applied_k = self._scale = k
        tracker = self.tracker
        assert tracker is not None  # created by _start
        for source in tracker.noise_px:
            sigma = self.config.noise_px[source] * k
            tracker.set_noise(source, sigma)
            self._var[source] = sigma * sigma
        r = self._motion_scale
        tracker.set_process_noise((self.config.process_noise[0] * k * r, self.config.process_noise[1] * k * r))
        if isinstance(tracker, ParticleFilter):
            tracker.manoeuvre = (self.config.manoeuvre[0], self.config.manoeuvre[1] * k)

    def _support(self, ms: Sequence[Measurement], estimate: Estimate | None) -> int:
        """How many of ``ms`` lie within :data:`SUPPORT_SIGMAS` of their fused noise plus the posterior spread of ``estimate``."""
        if estimate is None:
            return 0
        spread2 = (self._spread or 0.0) ** 2
        return sum(
            (m.u - estimate.u) ** 2 + (m.v - estimate.v) ** 2 <= SUPPORT_SIGMAS**2 * (self._var[m.source] + spread2)
            for m in ms
        )

    def _uncertainty(
        self, ms: Sequence[Measurement], estimate: Estimate, spread: float, weights: Mapping[str, float]
    ) -> float:
        """``sigma_px`` (module docstring): the nearest cue's error plus the larger of its slow error and the cues'
        unexplained disagreement; with one cue or none, the posterior spread plus its unexplained distance and its slow
        error. px."""
        d2 = [(m.u - estimate.u) ** 2 + (m.v - estimate.v) ** 2 for m in ms]
        explained = [self._explained(m, weights) for m in ms]
        excess = sum(max(0.0, r2 - s2) for r2, s2 in zip(d2, explained))
        if len(ms) < 2:
            # lambda_max + max(0, r^2 - s^2) + B: the lone cue's slow error, learned while other cues measured beside it
            bias = self._slow(ms[0].source, confident=False) if ms else 0.0
            return math.sqrt((spread if math.isfinite(spread) else 0.0) ** 2 + excess + bias)
        n = int(np.argmin(d2))
        # s_n^2 + d_n^2 + max(B_n, mean_i max(0, r_i^2 - s_i^2))
        return math.sqrt(explained[n] + d2[n] + max(self._slow(ms[n].source), excess / len(ms)))

    def _slow(self, source: str, confident: bool = True) -> float:
        """``source``'s slow error per axis at this frame's palm scale (:meth:`NoiseCalibration.slow`; 0 while
        unknown), px^2."""
        slow = None if self._calibration is None else self._calibration.slow(source, confident)
        return 0.0 if slow is None else slow * self._scale * self._scale

    def _explained(self, m: Measurement, weights: Mapping[str, float]) -> float:
        """The share of ``m``'s squared distance from the estimate its noise explains (module docstring,
        "Uncertainty"): its fused noise, or its own white noise where that is known and smaller, px^2.

        A combined target's shared region copy (:func:`_offset_shared`) is the region's centre moved by a guessed
        offset: its white noise is widened by that guess's error, :data:`SHARED_SPREAD_PALMS`.
        """
        fused = self._var[m.source] / weights[m.source]
        calibration = self._calibration
        if calibration is None or m.quality < SELF_QUALITY:
            return fused
        white = calibration.white(m.source, m.quality)
        if white is None:
            return fused
        offset = SHARED_SPREAD_PALMS * self._palm if m.extras.get("shared") else 0.0
        return min(fused, white * self._scale * self._scale + offset * offset)

    def _restart(self, tracker: Tracker, m: Measurement) -> None:
        """Start the filter at measurement ``m``; the PF and KF spread it by the cue's own noise (what one measurement
        tells; calibrated, :meth:`~fusion_pf.filter.calibration.NoiseCalibration.start_sigma`)."""
        if isinstance(tracker, (ParticleFilter, KalmanFilter)):
            spread = tracker.noise_px[m.source]
            calibration = self._calibration
            if calibration is not None:
                # the fused noise (widenings included) narrowed as the start noise is below the calibrated one
                spread *= calibration.start_sigma(m) / calibration.sigma(m)
            tracker.init_spread_px = spread
        tracker.reset(prior=(m.u, m.v))

    def _learn_motion(self, estimate: Estimate, predicted: tuple[float, float, float]) -> None:
        """Learn the position process noise from this frame's correction (:func:`~fusion_pf.filter.calibration.process_scale`).

        The correction ``estimate - prediction`` is kept at palm scale 1; from
        :data:`~fusion_pf.filter.calibration.MOTION_MIN` of them on, the process
        noise (position and velocity) is the configured one times the learned factor.
        """
        k = self._scale
        self._moves.append(0.5 * ((estimate.u - predicted[0]) ** 2 + (estimate.v - predicted[1]) ** 2) / (k * k))
        if len(self._moves) < MOTION_MIN:
            return
        self._motion_scale = process_scale(np.fromiter(self._moves, float), self.config.process_noise[0])
        tracker = self.tracker
        assert tracker is not None  # stepped
        r = self._motion_scale
        tracker.set_process_noise((self.config.process_noise[0] * k * r, self.config.process_noise[1] * k * r))

    def _weights(self, ms: Sequence[Measurement], predicted: tuple[float, float, float] | None) -> dict[str, float]:
        """Each cue's weight this frame (:class:`~fusion_pf.filter.bursts.BurstFilter`); a cue in a burst is fused with its noise over ``sqrt(w)``.

        1 for every cue with ``--no-burst-gate``. The burst scale is one apparent palm length.
        """
        if self.bursts is None:
            return {m.source: 1.0 for m in ms}
        palm = self._palm
        weights = self.bursts.weights(ms, self._var, predicted if self.tracking else None, BURST_PALMS * palm)
        tracker = self.tracker
        assert tracker is not None  # created by _start
        for source, w in weights.items():
            if w < 1.0:
                tracker.set_noise(source, math.sqrt(self._var[source] / w))
        return weights

    def _backed(self, ms: Sequence[Measurement]) -> list[Measurement]:
        """Those of ``ms`` another cue agrees with (within one apparent palm length)."""
        reach = self._reach
        return [m for m in ms if any(math.hypot(m.u - o.u, m.v - o.v) <= reach for o in ms if o is not m)]

    def _startable(self, ms: Sequence[Measurement], cues: int) -> list[Measurement]:
        """The measurements a (re)start may begin at: all of them, but for a lost track with more than one cue
        running (``cues``: how many run) only those another cue agrees with (:meth:`_backed`) or of quality
        :data:`START_MIN_QUALITY` or more."""
        if cues <= 1 or self.status.state != TrackState.LOST:
            return list(ms)
        backed = {id(m) for m in self._backed(ms)}
        return [m for m in ms if m.quality >= START_MIN_QUALITY or id(m) in backed]

    def _consensus(
        self, ms: Sequence[Measurement], trust: Mapping[str, float], share: Mapping[str, float]
    ) -> Measurement | None:
        """The cue a (re)start begins at, among :meth:`_startable`'s ``ms``: the most trusted of those another cue
        agrees with (:meth:`_backed`), when any does; so one trusted cue off the palm is not started at while two
        others agree. None: none of ``ms``."""
        if not ms:
            return None
        return min(self._backed(ms) or ms, key=lambda m: trust[m.source] / math.sqrt(share[m.source]))

    def _deserted(
        self, ms: Sequence[Measurement], trust: Mapping[str, float], share: Mapping[str, float], timestamp_ns: int
    ) -> Measurement | None:
        """The cue to restart at when a confident cue (:data:`JUMP_MIN_QUALITY`) another agrees with (:meth:`_backed`)
        and every cue of quality :data:`START_MIN_QUALITY` or more lie away from the prediction (beyond one apparent
        palm length and :data:`SUPPORT_SIGMAS` of their noise): the track holds on nothing or on unconfident cues.
        None otherwise."""
        predicted = self.prediction(timestamp_ns)
        if predicted is None:
            return None
        backed = self._backed(ms)
        if not any(m.quality >= JUMP_MIN_QUALITY for m in backed):
            return None
        reach2 = self._reach**2
        for m in ms:
            d2 = (m.u - predicted[0]) ** 2 + (m.v - predicted[1]) ** 2
            if m.quality >= START_MIN_QUALITY and (d2 <= reach2 or d2 <= SUPPORT_SIGMAS**2 * self._var[m.source]):
                return None
        return self._consensus(backed, trust, share)

    def _trust(self, m: Measurement) -> float:
        """The noise ``m`` is fused with at scale 1 (calibrated, else configured): smaller is more trusted."""
        return self._prior(m) if self._calibration is None else self._calibration.sigma(m)

    def __call__(self, row: CueRow) -> TrackResult:
        """Step the filter with ``row`` (not for background rows), supervise it and build the result."""
        t0 = time.perf_counter_ns()
        size = (row.intrinsics.width, row.intrinsics.height)
        if self.tracker is None:
            self._start(size)
        tracker, states = self.tracker, self.states
        assert tracker is not None and states is not None  # created by _start
        running = self.sources if self.sources is not None else tuple(row.cues)
        ms = row.measurements(running)
        trust = {m.source: self._trust(m) for m in ms}
        if self._observe_palm(row, ms, trust) and self.config.palm_scale and self.config.scale_noise:
            self._rescale()
        # the prediction of this frame, what the cues and the motion are learned against (two cues or more)
        predicted = self._predicted(row.timestamp_ns) if len(ms) >= 2 else None
        if self._calibration is not None and ms:
            self._calibrate(ms, trust, predicted, row.timestamp_ns)
        share = self._weights(ms, predicted)
        best = min(ms, key=lambda m: trust[m.source] / math.sqrt(share[m.source])) if ms else None
        if tracker.initialised and best is not None and self._jumped(best, row.timestamp_ns):
            self._restart(tracker, best)  # the palm moved beyond the motion model: restart at the cue
            self.jumps += 1
            predicted = None  # a restart is no correction of the motion model
        elif tracker.initialised and (moved := self._deserted(ms, trust, share, row.timestamp_ns)) is not None:
            self._restart(tracker, moved)  # the cues agree elsewhere, none with the track: restart at them
            self.jumps += 1
            predicted = None
        anchor = self._anchors.popleft() if self._anchors else None
        hold = False  # no cue near the anchor: the filter waits for one (module docstring, "Warm-start replay")
        if anchor is not None and not tracker.initialised:
            reach = self._reach
            near = [
                m for m in self._startable(ms, len(running)) if math.hypot(m.u - anchor[0], m.v - anchor[1]) <= reach
            ]
            if near:
                self._restart(tracker, min(near, key=lambda m: trust[m.source]))
            hold = not near
        elif not tracker.initialised and (ms or self.init is not None):
            if self.init is None:
                start = self._consensus(self._startable(ms, len(running)), trust, share)
                if start is not None:
                    self._restart(tracker, start)
                hold = start is None  # one unconfident cue alone: the filter waits for better evidence
            else:
                if isinstance(tracker, (ParticleFilter, KalmanFilter)):
                    tracker.init_spread_px = self._init_spread
                tracker.reset(prior=self.init)
        self.init = None
        if isinstance(tracker, ParticleFilter):
            # several cues: the posterior mean averages their noise; one cue: the paper's robust mean
            # stays on it (the weighted mean of a cloud one cue spread lags it, re-entering hands 3.5 px)
            tracker.set_estimator("weighted_mean" if len(ms) >= 2 else "robust_mean")
        estimate = None if hold else tracker.step(row.timestamp_ns, ms)
        for m in ms:
            if share[m.source] < 1.0:
                tracker.set_noise(m.source, math.sqrt(self._var[m.source]))  # the burst's weight was this frame's
        if (
            predicted is not None
            and estimate is not None
            and self.config.adapt_motion
            and self._learn
            and isinstance(tracker, ParticleFilter)
        ):
            self._learn_motion(estimate, predicted)
        cov = None if estimate is None else estimate.cov
        spread = math.nan if cov is None else largest_std(cov)
        self._spread = None if cov is None else spread
        position = None if estimate is None else (estimate.u, estimate.v)
        before = self.status.state
        evidence = Evidence(position, spread_px=spread, cues=self._support(ms, estimate))
        self.status = step_state(self.status, evidence, states)
        if not self.tracking and estimate is not None:
            self.losses += before in HOLDING
            tracker.reset()
            if self.bursts is not None:
                self.bursts.reset()
            self._history = []
            estimate = None
        elif self.tracking and before == TrackState.LOST:
            self.reacquisitions += 1
        particles = weights = xyz = sigma = sigma_mm = None
        if estimate is not None:
            self._history = [*self._history[-1:], (row.timestamp_ns, estimate.u, estimate.v)]
            xyz = _xyz(row, estimate.u, estimate.v, self.config.depth_radius)
            sigma = self._uncertainty(ms, estimate, spread, share)
            sigma_mm = None if xyz is None else sigma * float(xyz[2]) / row.intrinsics.fx
            if isinstance(tracker, ParticleFilter):
                particles = tracker.particles[:, :2].copy()
                weights = np.exp(tracker.log_weights)
            elif isinstance(tracker, ScatterSearchPF):
                particles = tracker.particles[:, :2].copy()
                weights = np.full(len(particles), 1.0 / len(particles))
        lat = dict(row.latency_ns)
        lat["filter"] = time.perf_counter_ns() - t0
        return TrackResult(
            frame=row.frame,
            timestamp_ns=row.timestamp_ns,
            background=False,
            estimate=estimate,
            cues=dict(row.cues),
            xyz_mm=xyz,
            latency_ns=lat,
            roi=row.roi,
            particles=particles,
            weights=weights,
            ground_truth=row.ground_truth,
            state=self.status.state.value,
            evaluations=self._evaluations(tracker, ms),
            sigma_px=sigma,
            sigma_mm=sigma_mm,
        )


class _Targets:
    """One :class:`_FilterStage` per target and the supervision between them (paper 004 §5.2).

    After every target's step, two tracked targets closer than
    :data:`COMBINE_PALMS` apparent palm lengths become ``combined`` (they share detections in the next
    frame's association); a combined pair farther apart than
    :data:`SEPARATE_PALMS`, or whose skeleton joints or two detections of one cue lie farther than
    :data:`APART_PALMS` apart, separates (``unlabelled`` for a frame) and its
    identities are given back: by the targets' own skeleton joints of this
    frame when both have one (handedness already decides in the association),
    else by the side each entered the combination from
    (:func:`~fusion_pf.filter.states.reassign_identities`). A target not
    combined whose skeleton joint lies farther than :data:`SEPARATE_PALMS` from its
    estimate is started again at the joint (:meth:`_astray`). A single target is
    the single palm: no supervision between targets, no ``targets`` in its result.
    """

    def __init__(self, config: TrackConfig, rng: np.random.Generator | int | None) -> None:
        self.config = config
        self.rng = rng
        self.names = targets_of(config)
        self.stages = self._stages()
        self.entry: dict[str, tuple[float, float]] = {}
        self.parted: dict[str, int] = {}
        self._held: list[tuple[Mapping[str, CueRow], tuple[int, int]]] | None = None  # the frames to replay
        self._seen: list[dict[str, tuple[float, float] | None]] = []  # per held frame, each target's estimate of it
        self._replayed = config.replay_frames == 0

    def _stages(self) -> dict[str, _FilterStage]:
        """A new filter stage per target (the first seeded by ``rng``, the others by their own streams of ``config.seed``)."""
        seed = self.config.seed
        return {
            t: _FilterStage(
                self.config,
                self.rng if k == 0 else np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(3, k))),
            )
            for k, t in enumerate(self.names)
        }

    def partners(self) -> dict[str, str]:
        """The combined targets, each to its partner."""
        out = {}
        for t, f in self.stages.items():
            p = f.status.partner
            if f.status.state == TrackState.COMBINED and p is not None:
                out[t] = self.names[p]
        return out

    def offsets(self) -> dict[str, tuple[float, float]]:
        """Per combined target, where it lies from the region it shares with its partner.

        :data:`SHARED_OFFSET_PALMS` of its apparent palm length from the pair's
        middle, toward the side it entered the combination from: joined palms
        lie side by side, so their shared region is centred between them.
        """
        out = {}
        for t in self.partners():
            e, palm = self.entry.get(t), self.stages[t].palm_px
            n = 0.0 if e is None else math.hypot(*e)
            if e is None or palm is None or n < 1e-6:
                continue
            out[t] = (SHARED_OFFSET_PALMS * palm * e[0] / n, SHARED_OFFSET_PALMS * palm * e[1] / n)
        return out

    def __call__(self, rows: Mapping[str, CueRow], size: tuple[int, int]) -> list[TrackResult]:
        """The results this frame completes, in frame order (module docstring, "Warm-start replay").

        One, the frame's own, except from the first frame a target holds a track on: those frames
        are held (none) until ``config.replay_frames`` of them are, then all of them come from the
        replay at once.
        """
        result = self._step(rows, size)
        if self._replayed:
            return [result]
        if self._held is None:
            if not any(f.tracking for f in self.stages.values()):
                return [result]
            self._held, self._seen = [], []
        results = result.targets or {self.names[0]: result}
        self._seen.append({t: _position(r) for t, r in results.items()})
        self._held.append((rows, size))
        return self._replay() if len(self._held) >= self.config.replay_frames else []

    def flush(self) -> list[TrackResult]:
        """The frames still held at the end of the stream, replayed with what they taught."""
        return self._replay() if self._held else []

    def _replay(self) -> list[TrackResult]:
        """Run new filters over the held frames with the noise and motion the first pass learned; they go on online."""
        held, self._held, self._replayed = self._held or [], None, True
        learnt, self.stages = self.stages, self._stages()
        self.entry, self.parted = {}, {}
        for k, (t, f) in enumerate(self.stages.items()):
            f.replaying(
                learnt[t], self._anchors(learnt[t], k, [rows[t] for rows, _ in held], [s[t] for s in self._seen])
            )
        out = [self._step(rows, size) for rows, size in held]
        for f in self.stages.values():
            f.online()
        return out

    def _anchors(
        self, learnt: _FilterStage, k: int, rows: Sequence[CueRow], seen: Sequence[tuple[float, float] | None]
    ) -> list[tuple[float, float] | None]:
        """Where target ``k``'s replay looks for the palm in each held frame: a backward pass's estimates.

        A new filter with what ``learnt`` (the first pass) learned runs over the held ``rows`` from
        the last to the first (time mirrored), anchored at the first pass's estimates ``seen``: it
        starts where the first pass had settled and reaches the first frames with a prediction
        from all the later ones (the palm moves smoothly; a cue off the palm in the first frames
        is an outlier to it), where the first pass had only those frames' cues to start from.
        Its estimate of each frame, else the first pass's (module docstring, "Warm-start replay").
        """
        back = _FilterStage(
            self.config, np.random.default_rng(np.random.SeedSequence(self.config.seed, spawn_key=(4, k)))
        )
        back.replaying(learnt, seen[::-1])
        mirror = rows[0].timestamp_ns + rows[-1].timestamp_ns
        behind = [_position(back(replace(row, timestamp_ns=mirror - row.timestamp_ns))) for row in reversed(rows)]
        return [b if b is not None else s for b, s in zip(reversed(behind), seen, strict=True)]

    def _step(self, rows: Mapping[str, CueRow], size: tuple[int, int]) -> TrackResult:
        """Every target's filter over its row of this frame and the supervision between them: the first target's result."""
        results = {t: f(rows[t]) for t, f in self.stages.items()}
        if len(self.names) == 1:
            first = results[self.names[0]]
            first.target = self.names[0]
            return first
        self._supervise(rows, results, size)
        for t, r in results.items():
            r.target = t
        first = results[self.names[0]]  # after _supervise: a separation may have swapped the results
        first.targets = results
        return first

    def _supervise(self, rows: Mapping[str, CueRow], results: dict[str, TrackResult], size: tuple[int, int]) -> None:
        stages = [self.stages[t] for t in self.names]
        palms = [f.palm_px for f in stages if f.tracking and f.palm_px is not None]
        palm = sum(palms) / len(palms) if palms else REFERENCE_PALM_PX * pixel_scale(size, stages[0].config)
        config = StateConfig(
            merge_px=COMBINE_PALMS * palm,
            split_px=SEPARATE_PALMS * palm,
            label_split_px=APART_PALMS * palm,
            image_size=size,
        )
        positions = [_position(results[t]) for t in self.names]
        before = [f.status for f in stages]
        labels = [_label_position(rows[t]) for t in self.names]
        apart = [
            (k, b.partner)
            for k, b in enumerate(before)
            if b.state == TrackState.COMBINED
            and b.partner is not None
            and _detected_apart(
                rows[self.names[k]],
                rows[self.names[b.partner]],
                APART_PALMS * palm,
                hands=self.names[k] in HANDS and self.names[b.partner] in HANDS,
            )
        ]
        after = combine_states(before, positions, config, labels, apart)
        for k, (b, a) in enumerate(zip(before, after)):
            t = self.names[k]
            rejoined = t in self.entry and self.parted.get(t, REJOIN_FRAMES + 1) <= REJOIN_FRAMES
            if (
                a.state == TrackState.COMBINED
                and b.state != TrackState.COMBINED
                and a.partner is not None
                and not rejoined
            ):
                p, q = positions[k], positions[a.partner]
                if p is not None and q is not None:
                    self.entry[t] = (p[0] - (p[0] + q[0]) / 2, p[1] - (p[1] + q[1]) / 2)
            self.parted[t] = 0 if a.state == TrackState.COMBINED else self.parted.get(t, REJOIN_FRAMES) + 1
        for k, (b, a) in enumerate(zip(before, after)):
            j = b.partner
            if b.state == TrackState.COMBINED and a.state == TrackState.UNLABELLED and j is not None and k < j:
                self._separate(self.names[k], self.names[j], rows, results)
        for t, a in zip(self.names, after):
            self.stages[t].status = a
            results[t].state = a.state.value
            self._astray(t, rows[t], results[t], config.split_px)

    def _astray(self, t: str, row: CueRow, result: TrackResult, reach: float) -> None:
        """Start target ``t`` again at its skeleton joint when it is not combined and the joint lies beyond ``reach`` of its estimate.

        ``reach`` is the pair's separation distance (:data:`SEPARATE_PALMS` palm lengths): two hands
        overlapping near the body separate because one estimate left the pair for a depth region off
        both hands, while its joint stays 5-20 px from its hand; alone, the region then slides on
        within the window around its own prediction. The joint's learned noise is no measure of
        that distance: it was learned against the wrong track and grows to 2-4 palm lengths.
        """
        f, joint, e = self.stages[t], row.cues.get("skeleton"), result.estimate
        if joint is None or e is None or f.status.state not in (TrackState.TRACKING, TrackState.UNLABELLED):
            return
        if math.hypot(joint.u - e.u, joint.v - e.v) > reach:
            f.restart_at(joint, row.timestamp_ns)

    def _separate(self, a: str, b: str, rows: Mapping[str, CueRow], results: dict[str, TrackResult]) -> None:
        """Give a separating pair its identities: swap the two filters when the evidence says they crossed."""
        ra, rb = results[a].estimate, results[b].estimate
        if ra is None or rb is None:
            return
        modes = np.array([[ra.u, ra.v], [rb.u, rb.v]])
        la, lb = _label_position(rows[a]), _label_position(rows[b])
        if la is not None and lb is not None:
            labels = np.array([la, lb])
            straight = np.hypot(*(modes - labels).T).sum()
            crossed = np.hypot(*(modes[::-1] - labels).T).sum()
            swap = crossed < straight
        elif a in self.entry and b in self.entry:
            swap = bool(reassign_identities(np.array([self.entry[a], self.entry[b]]), modes)[0] == 1)
        else:
            swap = False
        if swap:
            self.stages[a], self.stages[b] = self.stages[b], self.stages[a]
            results[a], results[b] = results[b], results[a]


def _position(result: TrackResult) -> tuple[float, float] | None:
    """The estimate of ``result`` as ``(u, v)``, None without one."""
    e = result.estimate
    return None if e is None else (e.u, e.v)


def _detected_apart(a: CueRow, b: CueRow, distance: float, *, hands: bool) -> bool:
    """Whether a region cue gave the two targets' rows two detections farther than ``distance`` apart (the cue sees two hands, not one shared blob).

    Between two hands (``hands``), a fragment of the other's region (:func:`~fusion_pf.association.fragment`)
    is no second hand; a hand's region beside the head's is a hand, however small against it.
    """
    for source, m in a.cues.items():
        n = b.cues.get(source)
        if m is None or n is None or m is n or source in ("skeleton", "hand") or "part" in m.extras:
            continue  # labelled sources count as labels; parts are one region the cue split between the pair
        if hands and (fragment(m, n) or fragment(n, m)):
            continue
        if math.hypot(m.u - n.u, m.v - n.v) > distance:
            return True
    return False


def _label_position(row: CueRow) -> tuple[float, float] | None:
    """Where the target's own label puts it this frame: its skeleton joint (None without one)."""
    m = row.cues.get("skeleton")
    return None if m is None else (m.u, m.v)


def _xyz(row: CueRow, u: float, v: float, radius: int) -> np.ndarray | None:
    """The palm in 3-D from the row's depth patch (None outside it or without depth)."""
    if row.depth_patch is None:
        return None
    x0, y0 = row.patch_origin
    h, w = row.depth_patch.shape
    if not (x0 - 0.5 <= u < x0 + w - 0.5 and y0 - 0.5 <= v < y0 + h - 0.5):
        return None
    z = depth_at(row.depth_patch, u - x0, v - y0, radius=radius)
    if z is None:
        return None
    return backproject(np.array([[u, v]]), np.array([z]), row.intrinsics)[0]


def _background_result(row: CueRow) -> TrackResult:
    lat = dict(row.latency_ns)
    lat["filter"] = 0
    lat["total"] = lat["decode"]
    return TrackResult(
        frame=row.frame,
        timestamp_ns=row.timestamp_ns,
        background=True,
        estimate=None,
        cues=dict(row.cues),
        xyz_mm=None,
        latency_ns=lat,
        ground_truth=row.ground_truth,
    )


# ---------------------------------------------------------------------- public API


@dataclass
class TrackStats:
    """Counters of a :func:`track` run, kept up to date frame by frame.

    Attributes
    ----------
    losses : int
        Times the track was lost (supervision, see ``_FilterStage``).
    reacquisitions : int
        Times a lost track was found again by the whole-frame search.
    missing : dict of str to int
        Per computed cue, tracked frames in which it gave no measurement.
    failed : dict of str to int
        Per cue, the frames among those in which it raised (its fault, not the run's).
    first_error : dict of str to str
        Per failed cue, the first failure: ``"frame K: message"``.
    bursts : dict of str to int
        Per cue, the frames (summed over targets) it was set aside as a burst (``--burst-gate``).
    rested : dict of str to int
        Per cue, the frames it did not search (``CueResult.rested``: the hand cue's idle search).
    """

    losses: int = 0
    reacquisitions: int = 0
    missing: dict[str, int] = field(default_factory=dict)
    failed: dict[str, int] = field(default_factory=dict)
    first_error: dict[str, str] = field(default_factory=dict)
    bursts: dict[str, int] = field(default_factory=dict)
    rested: dict[str, int] = field(default_factory=dict)

    def cue_summary(self, tracked: int) -> str:
        """One line: per cue the frames it measured of ``tracked``, its failures (first message), bursts set aside and rests."""
        parts = []
        for name, missing in self.missing.items():
            part = f"{name} {tracked - missing}/{tracked}"
            if self.failed.get(name):
                part += f" (failed on {self.failed[name]}, first {self.first_error[name]})"
            if self.bursts.get(name):
                part += f" ({self.bursts[name]} set aside as bursts)"
            if self.rested.get(name):
                part += f" (rested on {self.rested[name]}: idle search)"
            parts.append(part)
        return "cues measured in: " + ", ".join(parts)


def track(
    source: Iterable[Frame],
    config: TrackConfig,
    *,
    background: BackgroundModel | None = None,
    rng: np.random.Generator | int | None = None,
    stats: TrackStats | None = None,
) -> Iterator[TrackResult]:
    """Track the palm through ``source``, one :class:`TrackResult` per frame.

    Parameters
    ----------
    source : iterable of Frame
        An opened :class:`~drivers.base.Source` (or any iterable of frames).
    config : TrackConfig
    background : BackgroundModel, optional
        Empty-scene model (e.g. of ``config.background``, loaded by the
        caller); None: the source's background frames, else the running median.
    rng : numpy.random.Generator, int or None
        The particle filter's random source; None uses ``config.seed``.
    stats : TrackStats, optional
        Filled with the run's losses and re-acquisitions.

    Yields
    ------
    TrackResult
        In frame order, background frames included (``background=True``),
        with ``source_frame`` set. ``latency_ns["total"]`` is the wall time of
        the frame from ``decode`` to the 3-D palm.
    """
    cues = _CueStage(config)
    targets = _Targets(config, rng)
    events = EventDetector(targets.names)
    frames = _with_background(source, config, background)
    order: _InOrder[tuple[Frame, int]] = _InOrder()
    while True:
        # the whole frame on the cues' OpenCV threads, its decoding too: lowering the count while OpenCV's
        # pool has threads (the decode's colour conversion starts them) stops them, ~3 ms of waiting a frame
        # on a loaded machine; the caller's count is back for its own code between frames
        stop: BaseException | None = None
        with opencv_threads(config.cue_options.cv_threads):
            try:
                item = next(frames, None)
                if item is not None:
                    _track_frame(item, cues, targets, order, config, stats)
            except BaseException as exc:  # a stop (signal, source fault): the held frames go out first, then it
                item, stop = None, exc
            if item is None:
                order.fill(targets.flush())
        yield from _finish(order.ready(), events)  # outside: the caller's own OpenCV threads
        if stop is not None:
            raise stop
        if item is None:
            return


def _track_frame(
    item: tuple[int, Frame, int, BackgroundModel | None],
    cues: _CueStage,
    targets: _Targets,
    order: _InOrder[tuple[Frame, int]],
    config: TrackConfig,
    stats: TrackStats | None,
) -> None:
    """One frame of :func:`track`: its cues and filters; the results it completes to ``order``."""
    index, frame, dec, model = item
    t0 = time.perf_counter_ns() - dec
    if model is None:
        result = _background_result(_background_row(index, frame, dec, cues.names))
        result.target = cues.targets[0]
        order.add((frame, result.latency_ns["total"]), result)
        return
    priors, palms = {}, {}
    for t, f in targets.stages.items():
        priors[t] = cues.prior(frame, config.roi_prior, f.prediction(frame.timestamp_ns), t)
        palms[t] = None if config.roi_prior == "skeleton" else f.palm_px  # as extract_cues: no filter there
    gates = {t: f.source_gates() for t, f in targets.stages.items()}
    rows = cues.rows(index, frame, dec, model, priors, palms, targets.partners(), gates, targets.offsets())
    results = targets(rows, frame.size)
    order.add((frame, time.perf_counter_ns() - t0))
    order.fill(results)
    if stats is not None:
        stats.losses = sum(f.losses for f in targets.stages.values())
        stats.reacquisitions = sum(f.reacquisitions for f in targets.stages.values())
        stats.missing, stats.failed, stats.first_error = cues.missing, cues.failed, cues.first_error
        stats.rested = cues.rested
        stats.bursts = {}
        for f in targets.stages.values():
            for name, n in ({} if f.bursts is None else f.bursts.bursts).items():
                stats.bursts[name] = stats.bursts.get(name, 0) + n


T = TypeVar("T")


class _InOrder(Generic[T]):
    """Per frame a tag and its result, given out in frame order once the results are there.

    A frame's result may come later than the frame (the warm-start replay's
    held frames): :meth:`fill` gives the oldest frames without one theirs.
    """

    def __init__(self) -> None:
        self._slots: deque[list] = deque()  # [tag, result or None], oldest first

    def add(self, tag: T, result: TrackResult | None = None) -> None:
        """A frame, with its result when it has one already."""
        self._slots.append([tag, result])

    def fill(self, results: Sequence[TrackResult]) -> None:
        """``results`` to the oldest frames without one, in order."""
        open_slots = (slot for slot in self._slots if slot[1] is None)
        for slot, result in zip(open_slots, results):
            slot[1] = result

    def ready(self) -> list[tuple[T, TrackResult]]:
        """The leading frames that have their results (removed)."""
        out = []
        while self._slots and self._slots[0][1] is not None:
            tag, result = self._slots.popleft()
            out.append((tag, result))
        return out


def _finish(ready: Sequence[tuple[tuple[Frame, int], TrackResult]], events: EventDetector) -> Iterator[TrackResult]:
    """Complete the results :func:`track` gives out: each frame's total time (its own processing), the frame, its events."""
    for (frame, total), result in ready:
        if not result.background:
            result.latency_ns["total"] = total
            for r in result.targets.values():
                r.latency_ns["total"] = total
        result.source_frame = frame
        result.events = events.feed(result)
        yield result


def extract_cues(
    frames: Iterable[Frame], config: TrackConfig, *, background: BackgroundModel | None = None
) -> list[CueRow]:
    """Compute the cues of every frame once, for filter-only reruns (:func:`run_filter`).

    Parameters
    ----------
    frames : iterable of Frame
        An opened source or any iterable of frames.
    config : TrackConfig
        Cue options (joint, ROI, cue noise). With ``roi_prior="skeleton"``
        the rows do not depend on the filter; with ``"filter"`` or ``"auto"``
        the configured filter, seeded with ``config.seed``, places the ROIs.
    background : BackgroundModel, optional
        As in :func:`track`.

    Returns
    -------
    list of CueRow
        One per frame, background frames included.
    """
    cues = _CueStage(config)
    mode = config.roi_prior
    targets = None if mode == "skeleton" else _Targets(config, None)
    rows = []
    for index, frame, dec, model in _with_background(frames, config, background):
        if model is None:
            rows.append(_background_row(index, frame, dec, cues.names))
            continue
        filt = None if targets is None else targets.stages[targets.names[0]]
        prediction = None if filt is None else filt.prediction(frame.timestamp_ns)
        palm = None if filt is None else filt.palm_px
        row = cues(index, frame, dec, model, cues.prior(frame, mode, prediction), palm)
        if targets is not None:
            targets({targets.names[0]: row}, frame.size)
        rows.append(row)
    return rows


def run_filter(
    cue_rows: Sequence[CueRow], config: TrackConfig, rng: np.random.Generator | int | None = None
) -> list[TrackResult]:
    """Run only the filter over precomputed cue rows.

    Parameters
    ----------
    cue_rows : sequence of CueRow
        From :func:`extract_cues`.
    config : TrackConfig
        Filter options (filter, particles, likelihood, noises, sources).
    rng : numpy.random.Generator, int or None
        The particle filter's random source; None uses ``config.seed``.

    Returns
    -------
    list of TrackResult
        ``latency_ns`` holds the cue stages as measured by :func:`extract_cues`,
        this run's ``filter`` time and ``total`` = their sum.
    """
    targets = _Targets(config, rng)
    order: _InOrder[None] = _InOrder()
    for row in cue_rows:
        if row.background:
            order.add(None, _background_result(row))
            continue
        order.add(None)
        order.fill(targets({targets.names[0]: row}, (row.intrinsics.width, row.intrinsics.height)))
    order.fill(targets.flush())
    out = [result for _, result in order.ready()]
    for result in out:
        if not result.background:
            result.latency_ns["total"] = sum(result.latency_ns[s] for s in stages(tuple(result.cues))[:-1])
    return out
