"""The tracking pipeline: frames -> cues -> filter -> :class:`TrackResult` rows, and its outputs.

One frame goes through these stages (each timed with ``time.perf_counter_ns``;
the names are the keys of ``latency_ns``):

``decode``
    getting the frame from the source (MCAP decompression and image decoding,
    synthetic rendering, camera queue);
``skeleton``
    the joint ``config.joint`` as a measurement (:func:`fusion_pf.cues.skeleton_cue`);
``colour``, ``depth``
    paper 003 §3.5.1 / §3.5.2 on a region of interest (ROI) around a prior
    (:class:`~fusion_pf.cues.ColourCue`, :class:`~fusion_pf.cues.DepthCue`);
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
    :func:`track` uses ``"auto"`` unless told otherwise, :func:`extract_cues`
    ``"skeleton"``: its cue rows then do not depend on the filter or its seed,
    which is what particle-count sweeps and multi-execution need. With
    ``"filter"`` or ``"auto"``, :func:`extract_cues` runs the configured filter
    (seeded with ``config.seed``) to place the windows. The window is sized
    from the depth at the prior (``roi_extent_mm`` either side at the hand,
    see :func:`fusion_pf.cues.make_roi`) or fixed by ``roi_half_size``.

Background model (colour and depth cues)
    1. ``config.background``: a separate empty-scene recording; its frames
       flagged ``background`` if it has any, else all its frames (per-pixel
       median, :meth:`~fusion_pf.cues.BackgroundModel.from_frames`);
    2. else the source's own leading background frames (``Frame.background``,
       announced by the MCAP metadata ``fusion_pf.recording``
       ``background_frames``);
    3. else the running median of the first ``background_k`` frames of the
       stream (default :data:`DEFAULT_BACKGROUND_K`): those frames are read
       ahead, the median built, then they are tracked like every other frame.
    Background frames of the source are never tracked: they give a
    :class:`TrackResult` with ``background=True``, no cues and no estimate (the
    filter is not stepped), and the outputs skip them.

3-D palm
    ``xyz_mm`` is the estimate back-projected with the median of the non-zero
    depths in a ``(2 r + 1)^2`` window (``r = depth_radius``) around it
    (:mod:`fusion_pf.geometry`). The depth used is the frame's ROI grown by
    :data:`PATCH_MARGIN` px (kept with the cue row, so filter-only reruns give
    the same ``xyz_mm`` as :func:`track`); ``xyz_mm`` is None when the estimate
    is outside it or no valid depth lies in the window.

Outputs
    :class:`TrackerTopics` writes ``/tracker/estimate``, ``/tracker/cues``,
    ``/tracker/overlay`` and ``/tracker/particles`` (docs/recording-format.md,
    "Tracker outputs") through a :class:`~drivers.mcap_record.McapRecorder`;
    :class:`TrackCsv` writes the CSV of docs/architecture.md.
"""

from __future__ import annotations

import csv
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Iterable, Iterator, Mapping, Sequence

import numpy as np

from .cues import SOURCES, BackgroundModel, ColourCue, DepthCue, Measurement, Roi, make_roi, skeleton_cue
from .cues.regions import check_float, check_int
from .errors import InputError
from .filter import Estimate, KalmanFilter, ParticleFilter, Tracker
from .frame import Frame, Intrinsics, PalmPoint
from .geometry import DEFAULT_DEPTH_RADIUS, backproject, depth_at

__all__ = [
    "CSV_COLUMNS",
    "CueRow",
    "DEFAULT_BACKGROUND_K",
    "DEFAULT_PROCESS_NOISE",
    "DEFAULT_TRACK_NOISE_PX",
    "FILTERS",
    "PATCH_MARGIN",
    "ROI_PRIORS",
    "STAGES",
    "TrackConfig",
    "TrackCsv",
    "TrackResult",
    "TrackerTopics",
    "extract_cues",
    "load_background",
    "make_tracker",
    "run_filter",
    "track",
]

#: Latency stages of a frame, in pipeline order (the command line adds ``sinks``).
STAGES = ("decode", "colour", "depth", "skeleton", "filter", "total")
#: ``--filter`` values: the particle filter and the Kalman baseline.
FILTERS = ("pf", "kf")
#: ``--roi-prior`` values.
ROI_PRIORS = ("auto", "filter", "skeleton")
#: Frames of the running-median background when the source has no empty-scene frame.
DEFAULT_BACKGROUND_K = 30
#: Pixels the stored depth patch extends beyond the ROI on each side.
PATCH_MARGIN = 32

#: Default measurement noise per source (px, 1 sigma per axis), tuned for the
#: robust particle filter on synthetic scenes seeds 2 and 4 (320 x 200, 200
#: person frames, filter seed 1, ROI on the skeleton joint), over colour
#: {5, 8, 12} x depth {3, 4, 6} x skeleton {20, 40}, with and without the paper's
#: added 4 px cue noise; the sample recording (seed 0) was not used. The colour
#: cue is trusted least of the image cues because a bare forearm pulls its
#: centroid 5-7 px toward the elbow; the skeleton's joint is biased 15-70 px
#: during occlusion, which the robust likelihood absorbs.
DEFAULT_TRACK_NOISE_PX: Mapping[str, float] = {"colour": 12.0, "depth": 4.0, "skeleton": 20.0}
#: Default process noise (position px, velocity px/frame) per frame step, tuned with the above.
DEFAULT_PROCESS_NOISE = (3.0, 1.0)


@dataclass(frozen=True)
class TrackConfig:
    """Every option of ``fusion-pf track`` (validated on construction).

    Parameters
    ----------
    filter : {"pf", "kf"}
        Particle filter (paper 003) or the Kalman baseline.
    particles : int
        Particles of the particle filter, 1-100000 (ignored by ``kf``).
    likelihood : {"gaussian", "robust"} or None
        Particle-filter likelihood (paper eq. 6 or the Gaussian + outlier
        mixture); None = ``"robust"`` for ``pf``, ``"gaussian"`` for ``kf``
        (the Kalman filter is Gaussian only).
    joint : str
        Skeleton joint used as the skeleton cue (and skeleton ROI prior).
    noise_px : mapping of str to float
        Measurement noise sigma (px) per source ``colour``, ``depth``,
        ``skeleton``; missing sources keep :data:`DEFAULT_TRACK_NOISE_PX`.
    process_noise : (float, float)
        ``(position px, velocity px/frame)`` std per frame step
        (default :data:`DEFAULT_PROCESS_NOISE`).
    sources : tuple of str
        Sources fused by the filter (all cues are still computed and reported).
    cue_noise_px : mapping of str to float
        Gaussian noise (px, per axis) added to a source's measurements before
        fusion, as paper 003 §4.2-4.3 does to its colour and depth cues "to
        show the effectiveness of the filter"; empty = none. Drawn from
        ``SeedSequence(seed, spawn_key=(1,))``, two normals per source per
        tracked frame, so the noisy cues depend only on the seed.
    roi_prior : {"auto", "filter", "skeleton"} or None
        Where the cue window is centred (module docstring); None =
        ``"auto"`` in :func:`track`, ``"skeleton"`` in :func:`extract_cues`.
    prior_confidence : float
        ``"auto"`` prior: smallest joint confidence, in [0, 1], for which the
        joint is the prior.
    roi_half_size : int or None
        Fixed ROI half-size in px (1-2000); None sizes it from the depth at the prior.
    roi_extent_mm : float
        Physical ROI half-size at the hand when sized from depth, 10-2000 mm
        (250 mm: ~100 px at 1.2 m and 640 px width; tuned on synthetic scene
        seed 0 so a palm offset 24-56 px from a biased skeleton joint still
        lies inside the window -- 150 mm lost it in 29 % of the frames).
    background : Path or None
        Empty-scene recording for the background model.
    background_k : int
        Frames of the running-median background, 1-10000.
    depth_radius : int
        Half-size of the 3-D palm's depth window, 0-50 px.
    seed : int
        Seed of the particle filter's random numbers (>= 0).
    """

    filter: str = "pf"
    particles: int = 100
    likelihood: str | None = None
    joint: str = "right_hand"
    noise_px: Mapping[str, float] = field(default_factory=lambda: dict(DEFAULT_TRACK_NOISE_PX))
    process_noise: tuple[float, float] = DEFAULT_PROCESS_NOISE
    sources: tuple[str, ...] = SOURCES
    cue_noise_px: Mapping[str, float] = field(default_factory=dict)
    roi_prior: str | None = None
    prior_confidence: float = 0.5
    roi_half_size: int | None = None
    roi_extent_mm: float = 250.0
    background: Path | None = None
    background_k: int = DEFAULT_BACKGROUND_K
    depth_radius: int = DEFAULT_DEPTH_RADIUS
    seed: int = 0

    def __post_init__(self) -> None:
        if self.filter not in FILTERS:
            raise InputError(f"filter must be one of {', '.join(FILTERS)}, got {self.filter!r}")
        object.__setattr__(self, "particles", check_int("particles", self.particles, 1, 100_000))
        likelihood = self.likelihood
        if likelihood is None:
            likelihood = "robust" if self.filter == "pf" else "gaussian"
        if likelihood not in ("gaussian", "robust"):
            raise InputError(f"likelihood must be gaussian or robust, got {likelihood!r}")
        if self.filter == "kf" and likelihood != "gaussian":
            raise InputError(f"the Kalman filter (filter kf) is Gaussian only, got likelihood {likelihood!r}")
        object.__setattr__(self, "likelihood", likelihood)
        if not isinstance(self.joint, str) or not self.joint:
            raise InputError(f"joint must be a non-empty joint name, e.g. right_hand, got {self.joint!r}")
        if not isinstance(self.noise_px, Mapping):
            raise InputError(f"noise_px must map each of {', '.join(SOURCES)} to px, got {self.noise_px!r}")
        unknown = sorted(set(self.noise_px) - set(SOURCES))
        if unknown:
            raise InputError(f"noise_px has unknown source(s) {', '.join(unknown)}; expected {', '.join(SOURCES)}")
        noise = {s: check_float(f"{s} noise (px)", self.noise_px.get(s, DEFAULT_TRACK_NOISE_PX[s]), 0.01, 10_000.0)
                 for s in SOURCES}
        object.__setattr__(self, "noise_px", noise)
        try:
            pos, vel = self.process_noise
        except (TypeError, ValueError):
            raise InputError(f"process_noise must be a pair (pos px, vel px/frame), got {self.process_noise!r}") from None
        object.__setattr__(self, "process_noise", (
            check_float("process noise position (px)", pos, 0.0, 1000.0),
            check_float("process noise velocity (px/frame)", vel, 0.0, 1000.0),
        ))
        if not isinstance(self.cue_noise_px, Mapping):
            raise InputError(f"cue_noise_px must map sources to px, got {self.cue_noise_px!r}")
        unknown = sorted(set(self.cue_noise_px) - set(SOURCES))
        if unknown:
            raise InputError(f"cue_noise_px has unknown source(s) {', '.join(unknown)}; expected {', '.join(SOURCES)}")
        object.__setattr__(self, "cue_noise_px", {
            s: check_float(f"{s} cue noise (px)", self.cue_noise_px[s], 0.0, 1000.0) for s in SOURCES if s in self.cue_noise_px
        })
        sources = tuple(self.sources)
        bad = [s for s in sources if s not in SOURCES]
        if bad or not sources or len(set(sources)) != len(sources):
            raise InputError(f"sources must be distinct names among {', '.join(SOURCES)}, got {','.join(map(str, sources))!r}")
        object.__setattr__(self, "sources", sources)
        if self.roi_prior is not None and self.roi_prior not in ROI_PRIORS:
            raise InputError(f"roi_prior must be one of {', '.join(ROI_PRIORS)}, got {self.roi_prior!r}")
        object.__setattr__(self, "prior_confidence", check_float("prior confidence", self.prior_confidence, 0.0, 1.0))
        if self.roi_half_size is not None:
            object.__setattr__(self, "roi_half_size", check_int("ROI half-size (px)", self.roi_half_size, 1, 2000))
        object.__setattr__(self, "roi_extent_mm", check_float("ROI extent (mm)", self.roi_extent_mm, 10.0, 2000.0))
        if self.background is not None:
            object.__setattr__(self, "background", Path(self.background))
        object.__setattr__(self, "background_k", check_int("background frames K", self.background_k, 1, 10_000))
        object.__setattr__(self, "depth_radius", check_int("depth window radius (px)", self.depth_radius, 0, 50))
        object.__setattr__(self, "seed", check_int("seed", self.seed, 0, 2**63 - 1))


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
        Per source in :data:`~fusion_pf.cues.SOURCES`.
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
        Per stage of :data:`STAGES` (plus ``sinks`` once the command wrote the frame).
    roi : Roi or None
    particles : ndarray, shape (N, 2), or None
        Particle positions after the step (particle filter only).
    weights : ndarray, shape (N,), or None
        Their normalised weights.
    ground_truth : PalmPoint or None
    source_frame : Frame or None
        The frame itself (set by :func:`track`, None from :func:`run_filter`).
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


# ---------------------------------------------------------------------- background


def load_background(path: str | Path, size: tuple[int, int] | None = None) -> BackgroundModel:
    """The background model of an empty-scene recording.

    Parameters
    ----------
    path : str or Path
        An MCAP recording; its ``background`` frames are used if it has any,
        else all its frames.
    size : (int, int), optional
        Expected ``(width, height)``; a different size is an InputError.

    Returns
    -------
    BackgroundModel
    """
    from drivers.mcap_replay import McapReplay

    with McapReplay(Path(path)) as rec:
        frames = list(rec)
    if not frames:
        raise InputError(f"background recording {path} has no frames")
    flagged = [f for f in frames if f.background]
    chosen = flagged or frames
    if size is not None and chosen[0].size != tuple(size):
        w, h = chosen[0].size
        raise InputError(f"background recording {path} is {w}x{h} but the source is {size[0]}x{size[1]}")
    return BackgroundModel.from_frames(chosen)


def _timed(source: Iterable[Frame]) -> Iterator[tuple[int, Frame, int]]:
    """``(index, frame, decode_ns)`` for every frame of ``source``."""
    it = iter(source)
    index = 0
    while True:
        t0 = time.perf_counter_ns()
        try:
            frame = next(it)
        except StopIteration:
            return
        yield index, frame, time.perf_counter_ns() - t0
        index += 1


def _with_background(
    source: Iterable[Frame], config: TrackConfig
) -> Iterator[tuple[int, Frame, int, BackgroundModel | None]]:
    """Frames with the background model to use for them (None for background frames)."""
    frames = _timed(source)
    model = None if config.background is None else load_background(config.background)
    empties: list[Frame] = []
    for index, frame, dec in frames:
        if frame.background:
            if model is None:
                empties.append(frame)
            yield index, frame, dec, None
            continue
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
                model = BackgroundModel.from_frames(f for _, f, _ in ahead)
                _check_size(model, index, frame)
                for i, f, d in ahead:
                    yield i, f, d, model
                continue
            empties.clear()
        _check_size(model, index, frame)
        yield index, frame, dec, model


def _check_size(model: BackgroundModel, index: int, frame: Frame) -> None:
    h, w = model.color.shape[:2]
    if (w, h) != frame.size:
        raise InputError(f"background is {w}x{h} but frame {index} is {frame.size[0]}x{frame.size[1]}")


# ---------------------------------------------------------------------- cues


class _CueStage:
    """Per-stream cue extraction: the colour and depth cues and their state."""

    def __init__(self, config: TrackConfig) -> None:
        self.config = config
        self.colour = ColourCue()
        self.depth = DepthCue()
        self.last_joint: tuple[float, float] | None = None
        self.noise_rng = np.random.default_rng(np.random.SeedSequence(config.seed, spawn_key=(1,)))

    def prior(self, frame: Frame, mode: str, prediction: tuple[float, float] | None) -> tuple[float, float] | None:
        """The ROI prior of ``frame`` under ``mode`` (module docstring)."""
        joint = frame.joint(self.config.joint)
        if joint is not None and joint.confidence > 0:
            self.last_joint = (joint.u, joint.v)
        if mode == "skeleton" or prediction is None:
            return self.last_joint
        if mode == "auto" and joint is not None and joint.confidence >= self.config.prior_confidence:
            return joint.u, joint.v
        return prediction

    def roi(self, frame: Frame, prior: tuple[float, float] | None) -> Roi | None:
        """Window around ``prior``, sized from the depth there (or fixed)."""
        if prior is None:
            return None
        z = depth_at(frame.depth, *prior, radius=self.config.depth_radius) if frame.depth is not None else None
        return make_roi(
            prior[0], prior[1], frame.size, depth_mm=z, fx=frame.intrinsics.fx,
            half_size=self.config.roi_half_size, extent_mm=self.config.roi_extent_mm,
        )

    def add_noise(self, cues: dict[str, Measurement | None]) -> dict[str, Measurement | None]:
        """``cues`` with ``config.cue_noise_px`` Gaussian noise added (paper 003 §4.2-4.3)."""
        draws = self.noise_rng.standard_normal((len(SOURCES), 2))
        out = dict(cues)
        for i, s in enumerate(SOURCES):
            sigma = self.config.cue_noise_px.get(s, 0.0)
            m = cues[s]
            if m is not None and sigma > 0:
                extras = {**m.extras, "added_noise_px": sigma}
                out[s] = Measurement(s, m.u + sigma * draws[i, 0], m.v + sigma * draws[i, 1], m.quality, extras)
        return out

    def __call__(
        self, index: int, frame: Frame, decode_ns: int, model: BackgroundModel | None, prior: tuple[float, float] | None
    ) -> CueRow:
        """All cues of one frame in the window around ``prior`` (None: no window, no image cues)."""
        lat = {"decode": decode_ns}
        t0 = time.perf_counter_ns()
        skeleton = skeleton_cue(frame, self.config.joint).measurement
        lat["skeleton"] = time.perf_counter_ns() - t0
        roi = self.roi(frame, prior)
        colour = depth = None
        t0 = time.perf_counter_ns()
        if roi is not None and model is not None:
            colour = self.colour(frame.color, model.color, roi=roi).measurement
        lat["colour"] = time.perf_counter_ns() - t0
        t0 = time.perf_counter_ns()
        if roi is not None and model is not None and frame.depth is not None and model.depth is not None:
            depth = self.depth(frame.depth, model.depth, roi=roi).measurement
        lat["depth"] = time.perf_counter_ns() - t0
        cues = {"colour": colour, "depth": depth, "skeleton": skeleton}
        if self.config.cue_noise_px:
            cues = self.add_noise(cues)
        patch, origin = None, (0, 0)
        if roi is not None and not roi.empty and frame.depth is not None:
            w, h = frame.size
            x0, y0 = max(roi.x0 - PATCH_MARGIN, 0), max(roi.y0 - PATCH_MARGIN, 0)
            x1, y1 = min(roi.x1 + PATCH_MARGIN, w), min(roi.y1 + PATCH_MARGIN, h)
            patch, origin = frame.depth[y0:y1, x0:x1].copy(), (x0, y0)
        return CueRow(
            frame=index, timestamp_ns=frame.timestamp_ns, background=False,
            cues=cues, latency_ns=lat,
            roi=roi, depth_patch=patch, patch_origin=origin, intrinsics=frame.intrinsics,
            ground_truth=frame.ground_truth,
        )


def _background_row(index: int, frame: Frame, decode_ns: int) -> CueRow:
    return CueRow(
        frame=index, timestamp_ns=frame.timestamp_ns, background=True,
        cues={s: None for s in SOURCES}, latency_ns={"decode": decode_ns, "colour": 0, "depth": 0, "skeleton": 0},
        roi=None, depth_patch=None, patch_origin=(0, 0), intrinsics=frame.intrinsics,
        ground_truth=frame.ground_truth,
    )


# ---------------------------------------------------------------------- filter


def make_tracker(config: TrackConfig, rng: np.random.Generator | int | None = None) -> Tracker:
    """The filter ``config`` describes: the particle filter (seeded by ``rng``, else ``config.seed``) or Kalman.

    Both learn the frame period from the timestamps (``frame_period_ns="auto"``):
    a steady source steps by one frame as in the paper, and a gap left by
    dropped frames is bridged by as many motion steps.
    """
    if config.filter == "kf":
        return KalmanFilter(process_noise=config.process_noise, noise_px=config.noise_px, frame_period_ns="auto")
    return ParticleFilter(
        n_particles=config.particles, process_noise=config.process_noise, noise_px=config.noise_px,
        likelihood=config.likelihood, resampler="residual", estimator="robust_mean", frame_period_ns="auto",
        rng=config.seed if rng is None else rng,
    )


class _FilterStage:
    """The filter over a stream of cue rows, with the prediction used as ROI prior."""

    def __init__(self, config: TrackConfig, rng: np.random.Generator | int | None) -> None:
        self.config = config
        self.tracker = make_tracker(config, rng)
        self._history: list[tuple[int, float, float]] = []

    def prediction(self, timestamp_ns: int) -> tuple[float, float] | None:
        """Constant-velocity extrapolation of the last two estimates to ``timestamp_ns``."""
        if not self._history:
            return None
        t1, u1, v1 = self._history[-1]
        if len(self._history) == 1:
            return u1, v1
        t0, u0, v0 = self._history[-2]
        k = (timestamp_ns - t1) / (t1 - t0)
        return u1 + k * (u1 - u0), v1 + k * (v1 - v0)

    def __call__(self, row: CueRow) -> TrackResult:
        """Step the filter with ``row`` (not for background rows) and build the result."""
        t0 = time.perf_counter_ns()
        estimate = self.tracker.step(row.timestamp_ns, row.measurements(self.config.sources))
        particles = weights = xyz = None
        if estimate is not None:
            self._history = [*self._history[-1:], (row.timestamp_ns, estimate.u, estimate.v)]
            xyz = _xyz(row, estimate.u, estimate.v, self.config.depth_radius)
            if isinstance(self.tracker, ParticleFilter):
                particles = self.tracker.particles[:, :2].copy()
                weights = np.exp(self.tracker.log_weights)
        lat = dict(row.latency_ns)
        lat["filter"] = time.perf_counter_ns() - t0
        return TrackResult(
            frame=row.frame, timestamp_ns=row.timestamp_ns, background=False, estimate=estimate,
            cues=dict(row.cues), xyz_mm=xyz, latency_ns=lat, roi=row.roi,
            particles=particles, weights=weights, ground_truth=row.ground_truth,
        )


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
        frame=row.frame, timestamp_ns=row.timestamp_ns, background=True, estimate=None,
        cues=dict(row.cues), xyz_mm=None, latency_ns=lat, ground_truth=row.ground_truth,
    )


# ---------------------------------------------------------------------- public API


def track(
    source: Iterable[Frame], config: TrackConfig, *, rng: np.random.Generator | int | None = None
) -> Iterator[TrackResult]:
    """Track the palm through ``source``, one :class:`TrackResult` per frame.

    Parameters
    ----------
    source : iterable of Frame
        An opened :class:`~drivers.base.Source` (or any iterable of frames).
    config : TrackConfig
    rng : numpy.random.Generator, int or None
        The particle filter's random source; None uses ``config.seed``.

    Yields
    ------
    TrackResult
        In frame order, background frames included (``background=True``),
        with ``source_frame`` set. ``latency_ns["total"]`` is the wall time of
        the frame from ``decode`` to the 3-D palm.
    """
    cues = _CueStage(config)
    filt = _FilterStage(config, rng)
    mode = config.roi_prior or "auto"
    for index, frame, dec, model in _with_background(source, config):
        t0 = time.perf_counter_ns() - dec
        if model is None:
            result = _background_result(_background_row(index, frame, dec))
        else:
            prior = cues.prior(frame, mode, filt.prediction(frame.timestamp_ns))
            result = filt(cues(index, frame, dec, model, prior))
            result.latency_ns["total"] = time.perf_counter_ns() - t0
        result.source_frame = frame
        yield result


def extract_cues(frames: Iterable[Frame], config: TrackConfig) -> list[CueRow]:
    """Compute the cues of every frame once, for filter-only reruns (:func:`run_filter`).

    Parameters
    ----------
    frames : iterable of Frame
        An opened source or any iterable of frames.
    config : TrackConfig
        Cue options (joint, ROI, background, cue noise). With ``roi_prior``
        None or ``"skeleton"`` (the choice for sweeps) the rows do not depend
        on the filter; with ``"filter"`` or ``"auto"`` the configured filter,
        seeded with ``config.seed``, places the ROIs.

    Returns
    -------
    list of CueRow
        One per frame, background frames included.
    """
    cues = _CueStage(config)
    mode = config.roi_prior or "skeleton"
    filt = None if mode == "skeleton" else _FilterStage(config, None)
    rows = []
    for index, frame, dec, model in _with_background(frames, config):
        if model is None:
            rows.append(_background_row(index, frame, dec))
            continue
        prediction = None if filt is None else filt.prediction(frame.timestamp_ns)
        row = cues(index, frame, dec, model, cues.prior(frame, mode, prediction))
        if filt is not None:
            filt(row)
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
    filt = _FilterStage(config, rng)
    out = []
    for row in cue_rows:
        if row.background:
            out.append(_background_result(row))
            continue
        result = filt(row)
        result.latency_ns["total"] = sum(result.latency_ns[s] for s in STAGES[:-1])
        out.append(result)
    return out


# ---------------------------------------------------------------------- CSV


#: CSV columns, in order (docs/architecture.md "CSV").
CSV_COLUMNS = (
    "frame", "timestamp_ns", "u", "v",
    "colour_u", "colour_v", "depth_u", "depth_v", "skeleton_u", "skeleton_v",
    "x_mm", "y_mm", "z_mm", "ess", "resampled", "n_particles",
    "latency_decode_ms", "latency_colour_ms", "latency_depth_ms",
    "latency_skeleton_ms", "latency_filter_ms", "latency_total_ms",
    "latency_sinks_ms", "colour_quality", "depth_quality", "skeleton_quality",
)


def _f(value: float | None, digits: int) -> str:
    """Fixed-format float; empty for None or NaN (so a file never holds 'nan')."""
    if value is None or not math.isfinite(value):
        return ""
    return f"{value:.{digits}f}"


class TrackCsv:
    """Writes tracked frames as CSV rows (:data:`CSV_COLUMNS`), flushed row by row.

    Background frames are skipped. Floats use fixed formats (pixels 3 decimals,
    mm 1, ESS 3, latency ms 3), so the same seed gives a byte-identical file as
    long as ``latency`` is False: wall-clock latency differs from run to run,
    so its columns are left empty unless asked for.

    Parameters
    ----------
    path : str or Path
    latency : bool
        Fill the ``latency_*_ms`` columns.
    """

    def __init__(self, path: str | Path, *, latency: bool = False) -> None:
        self.path = Path(path)
        self.latency = bool(latency)
        self._fh: IO[str] | None = None
        self.rows = 0

    def __enter__(self) -> "TrackCsv":
        self._fh = open(self.path, "w", newline="", encoding="ascii")
        self._writer = csv.writer(self._fh, lineterminator="\n")
        self._writer.writerow(CSV_COLUMNS)
        return self

    def __exit__(self, *exc: object) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def write(self, result: TrackResult) -> None:
        """Append the row of ``result`` (nothing for a background frame)."""
        if result.background:
            return
        if self._fh is None:
            raise InputError(f"CSV {self.path} is not open; use TrackCsv inside a 'with' block")
        self._writer.writerow(csv_row(result, latency=self.latency))
        self._fh.flush()
        self.rows += 1


def csv_row(result: TrackResult, *, latency: bool = False) -> list[str]:
    """The CSV cells of one result, in :data:`CSV_COLUMNS` order."""
    e = result.estimate
    cells = [str(result.frame), str(result.timestamp_ns), _f(e and e.u, 3), _f(e and e.v, 3)]
    for s in SOURCES:
        m = result.cues.get(s)
        cells += [_f(m and m.u, 3), _f(m and m.v, 3)]
    xyz = result.xyz_mm
    cells += [_f(None if xyz is None else float(c), 1) for c in (xyz if xyz is not None else (None,) * 3)]
    cells += [_f(e and e.ess, 3), "" if e is None else str(int(e.resampled)), "" if e is None else str(e.n_particles)]
    for stage in (*STAGES, "sinks"):
        ns = result.latency_ns.get(stage)
        cells.append(_f(ns / 1e6, 3) if latency and ns is not None else "")
    for s in SOURCES:
        m = result.cues.get(s)
        cells.append(_f(m and m.quality, 3))
    return cells


# ---------------------------------------------------------------------- MCAP topics


def _timestamp(ns: int):
    from google.protobuf.timestamp_pb2 import Timestamp

    return Timestamp(seconds=ns // 1_000_000_000, nanos=ns % 1_000_000_000)


def _finite_or_none(value: float) -> float | None:
    return float(value) if math.isfinite(value) else None


#: Overlay colours (RGBA in [0, 1]) per source, the particles and the estimate.
OVERLAY_COLOURS = {
    "colour": (0.1, 0.9, 0.2, 1.0),
    "depth": (0.2, 0.5, 1.0, 1.0),
    "skeleton": (1.0, 0.3, 0.9, 1.0),
    "particles": (1.0, 0.85, 0.1, 0.6),
    "estimate": (1.0, 0.1, 0.1, 1.0),
    "roi": (1.0, 1.0, 1.0, 0.5),
}
#: ``frame_id`` of ``/tracker/particles`` (coordinates are image pixels, not metres).
PARTICLES_FRAME_ID = "camera_pixels"


class TrackerTopics:
    """Writes the tracker output topics of each tracked frame into a recorder.

    Topics (docs/recording-format.md, "Tracker outputs"): ``/tracker/estimate``
    and ``/tracker/cues`` (JSON) and ``/tracker/overlay``
    (``foxglove.ImageAnnotations``) once per tracked frame;
    ``/tracker/particles`` (``foxglove.PointCloud``) once per tracked frame
    with a particle set. Background frames get none.

    Parameters
    ----------
    recorder : drivers.mcap_record.McapRecorder
        An open recorder.
    config : TrackConfig
        Written into the estimates (``filter``, ``likelihood``).
    """

    def __init__(self, recorder, config: TrackConfig) -> None:
        self.recorder = recorder
        self.config = config

    def write(self, result: TrackResult) -> None:
        """Write the topics of ``result`` (none for a background frame)."""
        from drivers import mcap_format as fmt

        if result.background:
            return
        t = result.timestamp_ns
        self.recorder.write_json(fmt.ESTIMATE_TOPIC, fmt.ESTIMATE_SCHEMA, self.estimate_json(result), t)
        self.recorder.write_json(fmt.CUES_TOPIC, fmt.CUES_SCHEMA, cues_json(result), t)
        self.recorder.write_protobuf(fmt.OVERLAY_TOPIC, overlay(result), t)
        if result.particles is not None:
            self.recorder.write_protobuf(fmt.PARTICLES_TOPIC, particle_cloud(result), t)

    def estimate_json(self, result: TrackResult) -> dict:
        """The ``/tracker/estimate`` message of ``result``."""
        e = result.estimate
        return {
            "frame": result.frame,
            "timestamp_ns": result.timestamp_ns,
            "u": None if e is None else e.u,
            "v": None if e is None else e.v,
            "xyz_mm": None if result.xyz_mm is None else [float(c) for c in result.xyz_mm],
            "ess": None if e is None else _finite_or_none(e.ess),
            "resampled": None if e is None else e.resampled,
            "n_particles": 0 if e is None else e.n_particles,
            "filter": self.config.filter,
            "likelihood": self.config.likelihood,
            "latency_ns": {k: int(v) for k, v in result.latency_ns.items()},
        }


def cues_json(result: TrackResult) -> dict:
    """The ``/tracker/cues`` message of ``result``."""
    out: dict = {"frame": result.frame, "timestamp_ns": result.timestamp_ns}
    for s in SOURCES:
        m = result.cues.get(s)
        out[s] = None if m is None else {"u": m.u, "v": m.v, "quality": m.quality}
    if result.roi is not None:
        out["roi"] = result.roi.as_list()
    return out


def overlay(result: TrackResult):
    """``foxglove.ImageAnnotations`` of ``result``: particles, ROI, cue points, estimate circle."""
    from foxglove_schemas_protobuf.CircleAnnotation_pb2 import CircleAnnotation
    from foxglove_schemas_protobuf.Color_pb2 import Color
    from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
    from foxglove_schemas_protobuf.Point2_pb2 import Point2
    from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
    from foxglove_schemas_protobuf.TextAnnotation_pb2 import TextAnnotation

    ts = _timestamp(result.timestamp_ns)
    msg = ImageAnnotations()

    def colour(name: str) -> Color:
        r, g, b, a = OVERLAY_COLOURS[name]
        return Color(r=r, g=g, b=b, a=a)

    if result.particles is not None:
        msg.points.append(PointsAnnotation(
            timestamp=ts, type=PointsAnnotation.POINTS, outline_color=colour("particles"), thickness=2.0,
            points=[Point2(x=float(u), y=float(v)) for u, v in result.particles],
        ))
    if result.roi is not None and not result.roi.empty:
        r = result.roi
        corners = [(r.x0, r.y0), (r.x1, r.y0), (r.x1, r.y1), (r.x0, r.y1)]
        msg.points.append(PointsAnnotation(
            timestamp=ts, type=PointsAnnotation.LINE_LOOP, outline_color=colour("roi"), thickness=1.0,
            points=[Point2(x=float(x) - 0.5, y=float(y) - 0.5) for x, y in corners],
        ))
    for s in SOURCES:
        m = result.cues.get(s)
        if m is None:
            continue
        msg.points.append(PointsAnnotation(
            timestamp=ts, type=PointsAnnotation.POINTS, outline_color=colour(s), thickness=8.0,
            points=[Point2(x=m.u, y=m.v)],
        ))
        msg.texts.append(TextAnnotation(
            timestamp=ts, position=Point2(x=m.u + 6.0, y=m.v - 6.0), text=s, font_size=12.0,
            text_color=colour(s), background_color=Color(r=0, g=0, b=0, a=0.4),
        ))
    e = result.estimate
    if e is not None:
        # diameter of the 2-sigma circle of the posterior position, at least 10 px
        sigma = math.sqrt(max(float(np.max(np.linalg.eigvalsh(e.cov))), 0.0))
        msg.circles.append(CircleAnnotation(
            timestamp=ts, position=Point2(x=e.u, y=e.v), diameter=max(10.0, 4.0 * sigma),
            thickness=2.0, outline_color=colour("estimate"),
        ))
    return msg


def particle_cloud(result: TrackResult):
    """``foxglove.PointCloud`` of the particles: ``x = u``, ``y = v``, ``z = 0`` (px) and ``weight``."""
    from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
    from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
    from foxglove_schemas_protobuf.Pose_pb2 import Pose
    from foxglove_schemas_protobuf.Quaternion_pb2 import Quaternion
    from foxglove_schemas_protobuf.Vector3_pb2 import Vector3

    n = result.particles.shape[0]
    data = np.zeros((n, 4), dtype="<f4")
    data[:, :2] = result.particles
    data[:, 3] = result.weights
    f32 = PackedElementField.FLOAT32
    return PointCloud(
        timestamp=_timestamp(result.timestamp_ns), frame_id=PARTICLES_FRAME_ID,
        pose=Pose(position=Vector3(x=0, y=0, z=0), orientation=Quaternion(x=0, y=0, z=0, w=1)),
        point_stride=16,
        fields=[PackedElementField(name=name, offset=4 * i, type=f32) for i, name in enumerate(("x", "y", "z", "weight"))],
        data=data.tobytes(),
    )
