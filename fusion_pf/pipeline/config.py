"""The tracking pipeline's options: :class:`TrackConfig`, one definition per default.

Every field is declared with :func:`fusion_pf.options.option`, which also makes
the ``fusion-pf track`` flags and their ``--help`` (with the real default). The
cue stage's own options are a nested :class:`~fusion_pf.cues.registry.CueOptions`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from ..cues.registry import CUES, CueOptions, check_cue_names
from ..errors import InputError
from ..filter.likelihood import DEFAULT_NOISE_PX, LIKELIHOODS
from ..filter.motion import DEFAULT_PROCESS_NOISE
from ..filter.proposal import PROPOSALS, check_manoeuvre
from ..filter.world import DEFAULT_WORLD_NOISE_MM, DEFAULT_WORLD_PROCESS_NOISE
from ..geometry import DEFAULT_DEPTH_RADIUS
from ..options import option, parse_pairs, parse_tuple, validate

__all__ = ["DEFAULT_BACKGROUND_K", "DEFAULT_REPLAY_FRAMES", "FILTERS", "ROI_PRIORS", "TARGETS", "TrackConfig"]

#: ``--filter`` values: the particle filter, the Kalman baseline and the scatter-search PF (paper 002).
FILTERS = ("pf", "kf", "sspf")
#: ``--roi-prior`` values.
ROI_PRIORS = ("auto", "filter", "skeleton")
#: Manoeuvre mixture of the particle filter's position noise: (probability per frame, std px at 320 x 200).
DEFAULT_MANOEUVRE = (0.1, 20.0)
#: Frames of the running-median background when the source has no empty-scene frame.
DEFAULT_BACKGROUND_K = 30
#: Frames of the warm-start replay (``replay_frames``, :class:`fusion_pf.pipeline.run` "Warm-start replay").
DEFAULT_REPLAY_FRAMES = 25


def _names(text: str) -> tuple[str, ...]:
    return tuple(s.strip() for s in text.split(",") if s.strip())


def _show_pairs(pairs: Mapping[str, float]) -> str:
    return ",".join(f"{k}={v:g}" for k, v in pairs.items()) or "none"


def _check_noise(
    label: str, value, defaults: Mapping[str, float] = DEFAULT_NOISE_PX, unit: str = "px"
) -> dict[str, float]:
    if not isinstance(value, Mapping):
        raise InputError(f"{label} must map source names to {unit}, e.g. colour=12,depth=4, got {value!r}")
    unknown = sorted(set(value) - set(CUES))
    if unknown:
        raise InputError(f"{label} has unknown source(s) {', '.join(unknown)}; expected among {', '.join(CUES)}")
    out = {}
    for s, sigma in {**defaults, **value}.items():
        try:
            x = float(sigma)
        except (TypeError, ValueError):
            x = float("nan")
        if not 0.01 <= x <= 10_000.0:
            raise InputError(f"{label}: {s} must be a number in [0.01, 10000] {unit}, got {sigma!r}")
        out[s] = x
    return out


def _check_world_noise(label: str, value) -> dict[str, float]:
    return _check_noise(label, value, DEFAULT_WORLD_NOISE_MM, "mm")


def _check_manoeuvre(label: str, value) -> tuple[float, float]:
    try:
        return check_manoeuvre(value)
    except InputError as exc:
        raise InputError(f"{label}: {exc}") from None


def _check_cue_noise(label: str, value) -> dict[str, float]:
    if not isinstance(value, Mapping):
        raise InputError(f"{label} must map source names to px, e.g. colour=4,depth=4, got {value!r}")
    unknown = sorted(set(value) - set(CUES))
    if unknown:
        raise InputError(f"{label} has unknown source(s) {', '.join(unknown)}; expected among {', '.join(CUES)}")
    out = {}
    for s in CUES:
        if s in value:
            x = float(value[s]) if isinstance(value[s], (int, float)) else float("nan")
            if not 0.0 <= x <= 1000.0:
                raise InputError(f"{label}: {s} must be a number in [0, 1000] px, got {value[s]!r}")
            out[s] = x
    return out


def _check_pair(label: str, value) -> tuple[float, float]:
    try:
        pos, vel = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"{label} must be a pair POS,VEL (px, px/frame), got {value!r}") from None
    for what, x in (("position", pos), ("velocity", vel)):
        if not 0.0 <= x <= 1000.0:
            raise InputError(f"{label}: {what} must be in [0, 1000], got {x:g}")
    return pos, vel


def _check_names(label: str, value) -> tuple[str, ...]:
    try:
        return check_cue_names(tuple(value))
    except InputError as exc:
        raise InputError(f"{label}: {exc}") from None


def _check_init(label: str, value) -> tuple[float, float]:
    try:
        u, v = (float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"{label} must be a pixel position U,V, got {value!r}") from None
    if not (abs(u) < 1e7 and abs(v) < 1e7):
        raise InputError(f"{label} must be finite pixels, got {value!r}")
    return u, v


#: Targets ``--targets`` can name (skeleton joint names; the two-hand synthetic scene's ground truth).
TARGETS = ("right_hand", "left_hand", "head")


def _check_targets(label: str, value) -> tuple[str, ...]:
    names = tuple(value)
    bad = [n for n in names if n not in TARGETS]
    if bad or not names or len(set(names)) != len(names):
        raise InputError(
            f"{label} must be distinct names among {', '.join(TARGETS)}, got {','.join(map(str, names))!r}"
        )
    return names


def _path(label: str, value) -> Path:
    return Path(value)


@dataclass(frozen=True)
class TrackConfig:
    """Every option of the tracking pipeline and its filter (validated on construction).

    The filter fields (``filter`` ... ``seed``) configure
    :func:`~fusion_pf.pipeline.run.make_tracker`; the cue fields choose and
    place the cues; ``cue_options`` configures them. See
    :mod:`fusion_pf.pipeline.run` for the ROI prior, background and 3-D palm.
    """

    filter: str = option(
        "pf",
        choices=FILTERS,
        help="the particle filter (paper 003), the Kalman baseline or the scatter-search PF (paper 002)",
    )
    particles: int = option(
        300, kind="int", lo=1, hi=100_000, metavar="N", help="particles of the particle filter (ignored by kf)"
    )
    likelihood: str | None = option(
        None,
        choices=LIKELIHOODS,
        optional=True,
        metavar="auto|gaussian|robust",
        show=lambda v: "auto",
        help="particle-filter likelihood: paper eq. 6 or Gaussian + outlier mixture; "
        "auto = robust for pf, gaussian for kf",
    )
    joint: str = option(
        "right_hand", kind="str", metavar="NAME", help="skeleton joint used as the skeleton cue and ROI prior"
    )
    targets: tuple[str, ...] | None = option(
        None,
        optional=True,
        parse=_names,
        check=_check_targets,
        metavar="TARGET,...",
        show=lambda v: "the palm only",
        help=f"track several targets, among {', '.join(TARGETS)}: every cue serves every target (a window and "
        "a filter per target, detections associated by label and distance, paper 004's states); "
        "CSV columns <target>_u, <target>_v, <target>_state",
    )
    cues: tuple[str, ...] | None = option(
        None,
        optional=True,
        parse=_names,
        check=_check_names,
        metavar="CUE,...",
        show=lambda v: (
            "auto: colour,depth,skeleton (paper 003) on a recording with a skeleton and no camera "
            "hands (skin_rgb in place of colour without an empty scene); else hand plus depth and "
            "skeleton where the recording has them"
        ),
        help=f"cues to compute, among {', '.join(CUES)}",
    )
    sources: tuple[str, ...] | None = option(
        None,
        optional=True,
        parse=_names,
        check=_check_names,
        metavar="SRC,...",
        show=lambda v: "all cues",
        help="cues the filter fuses (every cue is still computed and written)",
    )
    noise_px: Mapping[str, float] = option(
        factory=lambda: dict(DEFAULT_NOISE_PX),
        parse=parse_pairs,
        check=_check_noise,
        flag="--noise",
        metavar="SRC=PX,...",
        show=_show_pairs,
        unit="px, 1 sigma per axis",
        help="measurement noise per source (unnamed sources keep their default)",
    )
    world_noise_mm: Mapping[str, float] = option(
        factory=lambda: dict(DEFAULT_WORLD_NOISE_MM),
        parse=parse_pairs,
        check=_check_world_noise,
        flag="--world-noise",
        metavar="SRC=MM,...",
        show=_show_pairs,
        unit="mm, 1 sigma per axis",
        help="multi-camera recordings (tracked in world mm): measurement noise per source at the target, of a "
        "depth camera's back-projected detection and of a colour-only camera's pixel (px = mm x fx / depth)",
    )
    world_particles: int = option(
        300,
        kind="int",
        lo=1,
        hi=100_000,
        metavar="N",
        help="multi-camera recordings: particles of each target's world filter (3-D position and velocity)",
    )
    world_process_noise: tuple[float, float] = option(
        DEFAULT_WORLD_PROCESS_NOISE,
        parse=parse_tuple(2),
        check=_check_pair,
        metavar="POS,VEL",
        show=lambda v: f"{v[0]:g},{v[1]:g}",
        unit="mm, mm/frame",
        help="multi-camera recordings: process noise std per frame step of the world filter",
    )
    process_noise: tuple[float, float] = option(
        DEFAULT_PROCESS_NOISE,
        parse=parse_tuple(2),
        check=_check_pair,
        metavar="POS,VEL",
        show=lambda v: f"{v[0]:g},{v[1]:g}",
        unit="px, px/frame",
        help="process noise std per frame step of eq. 4",
    )
    proposal: str = option(
        "guided",
        choices=PROPOSALS,
        help="particle filter only: move particles with eq. 4 and let the cues weight them (prior, the "
        "paper's bootstrap filter), or draw them from the optimal proposal given the most precise cue "
        "(guided), which follows hands faster than the motion model without lag",
    )
    manoeuvre: tuple[float, float] = option(
        DEFAULT_MANOEUVRE,
        parse=parse_tuple(2),
        check=_check_manoeuvre,
        metavar="PROB,PX",
        show=lambda v: f"{v[0]:g},{v[1]:g}",
        unit="probability, px",
        help="particle filter only: with this probability per frame a particle's position noise has "
        "this std instead of --process-noise's (heavy-tailed motion: hands start, stop and turn); 0,0 is eq. 4",
    )
    cue_noise_px: Mapping[str, float] = option(
        factory=dict,
        parse=parse_pairs,
        check=_check_cue_noise,
        flag="--cue-noise",
        metavar="SRC=PX,...",
        show=_show_pairs,
        unit="px per axis",
        help="Gaussian noise added to cue positions before fusion, as paper 003 §4.2-4.3 does, e.g. colour=4,depth=4",
    )
    roi_prior: str = option(
        "auto",
        choices=ROI_PRIORS,
        help="centre of the cue window: the skeleton joint (paper), the filter prediction, "
        "or auto: the joint while confident, else the prediction (the whole frame while there is neither)",
    )
    prior_confidence: float = option(
        0.5,
        kind="float",
        lo=0.0,
        hi=1.0,
        help="auto ROI prior: smallest joint confidence for which the joint is the prior",
    )
    roi_half_size: int | None = option(
        None,
        kind="int",
        lo=1,
        hi=2000,
        optional=True,
        unit="px",
        show=lambda v: "from the palm",
        help="fixed ROI half-size",
    )
    roi_palms: float = option(
        2.6,
        kind="float",
        lo=0.5,
        hi=20.0,
        unit="palm lengths",
        help="ROI half-size in apparent palm lengths (the hand cue's wrist-to-middle-finger-base length, "
        "else fx x 95 mm over the depth at the prior), at most half the image's shorter side; 2.6 keeps "
        "a palm 24-56 px off a biased skeleton joint inside the window",
    )
    background: Path | None = option(
        None,
        optional=True,
        check=_path,
        metavar="FILE.mcap",
        help="empty-scene recording for the background model (read by the command)",
    )
    background_mode: str = option(
        "adaptive",
        choices=("adaptive", "median"),
        help="without empty-scene frames: learn the background from the stream "
        "(MOG2 colour, farthest depth; warmed up on the first --background-k "
        "frames) or the median of those frames",
    )
    background_k: int = option(
        DEFAULT_BACKGROUND_K,
        kind="int",
        lo=1,
        hi=10_000,
        metavar="K",
        help="frames of the running-median background when there is no empty scene",
    )
    depth_radius: int = option(
        DEFAULT_DEPTH_RADIUS, kind="int", lo=0, hi=50, unit="px", help="half-size of the 3-D palm's depth window"
    )
    seed: int = option(
        0, kind="int", lo=0, hi=2**63 - 1, metavar="S", help="seed of the particle filter and of --cue-noise"
    )
    init: tuple[float, float] | None = option(
        None,
        optional=True,
        parse=parse_tuple(2),
        check=_check_init,
        metavar="U,V",
        help="known palm position in the first tracked frame",
    )
    scale_noise: bool = option(
        True,
        kind="bool",
        help="scale --noise, --process-noise and the window without depth with the image "
        "diagonal: the values are px at 320x200",
    )
    palm_scale: bool = option(
        True,
        kind="bool",
        help="with --scale-noise, scale the noises with the palm's apparent size instead of the image "
        "diagonal wherever it is known: the hand cue's wrist-to-middle-finger-base length, else "
        "fx x 95 mm over the depth at the best cue (the values are px for a palm 18.7 px long, "
        "the sample's)",
    )
    adapt_noise: bool = option(
        True,
        kind="bool",
        help="learn each cue's noise and outlier probability per quality band (quarters of [0, 1]) in "
        "this recording, from its distance to the filter's prediction while tracking, else to the other "
        "cues of the same frame, never below a floor its own frame-to-frame white noise may lower "
        "(fusion_pf/filter/calibration.py), starting from --noise widened by "
        "1/sqrt(quality); off: --noise widened by 1/sqrt(quality)",
    )
    adapt_motion: bool = option(
        True,
        kind="bool",
        help="particle filter: learn the process noise from the filter's corrections (estimate minus "
        "prediction) in frames with two cues or more, between 0.3 and 1 x --process-noise "
        "(fusion_pf/filter/calibration.py, process_scale); off: --process-noise",
    )
    replay_frames: int = option(
        DEFAULT_REPLAY_FRAMES,
        kind="int",
        lo=0,
        hi=10_000,
        metavar="K",
        help="warm-start replay: once the track has held K frames from its first start, run the filter "
        "again over those K frames' cues (kept, not recomputed) from their first, with the noise and "
        "motion learned from them (--adapt-noise, --adapt-motion), and write those rows from the "
        "replay; they come K frames late, once. 0: off",
    )
    burst_gate: bool = option(
        True,
        kind="bool",
        help="set a cue aside in the frames it is in a burst (off the track in a run of frames while "
        "another cue of the frame agrees with the track and disagrees with it): a good / burst state "
        "per cue carried across frames, its transitions learned in this recording "
        "(fusion_pf/filter/bursts.py); off: every cue fused with its calibrated noise",
    )
    jump_sigmas: float = option(
        8.0,
        kind="float",
        lo=1.0,
        hi=1000.0,
        unit="sigmas",
        help="restart the filter at a confident cue (quality >= 0.8) that lies farther than "
        "this many of its noise plus the posterior spread from the prediction "
        "(a hand faster than the motion model)",
    )
    silent_frames: int = option(
        15,
        kind="int",
        lo=1,
        hi=100_000,
        metavar="K",
        help="the track is lost after K frames in which no fused cue supported the estimate (none "
        "within 3 sigma of its fused noise plus the posterior spread: the cues fell silent or disagree)",
    )
    max_spread: float = option(
        0.2,
        kind="float",
        lo=0.001,
        hi=10.0,
        unit="of the image diagonal",
        help="the track is lost when the posterior position std exceeds this",
    )
    cue_options: CueOptions = field(default_factory=CueOptions)

    def __post_init__(self) -> None:
        validate(self)
        if self.likelihood is None:
            object.__setattr__(self, "likelihood", "robust" if self.filter == "pf" else "gaussian")
        if self.filter != "pf" and self.likelihood != "gaussian":
            what = "the Kalman filter" if self.filter == "kf" else "the scatter-search PF"
            raise InputError(f"{what} (filter {self.filter}) is Gaussian only, got likelihood {self.likelihood!r}")
        if not isinstance(self.cue_options, CueOptions):
            raise InputError(f"cue_options must be a CueOptions, got {type(self.cue_options).__name__}")
        if self.cues is not None and self.sources is not None:
            extra = [s for s in self.sources if s not in self.cues]
            if extra:
                raise InputError(f"sources {', '.join(extra)} are not among the cues {', '.join(self.cues)}")

    def settings(self) -> dict:
        """The configuration as JSON-ready values (stored in the tracker's output metadata)."""
        from dataclasses import asdict

        out = asdict(self)
        out["background"] = None if self.background is None else str(self.background)
        opts = out["cue_options"]
        opts["skin_model"] = None if opts["skin_model"] is None else str(opts["skin_model"])
        return out

    @classmethod
    def from_settings(cls, settings: Mapping) -> "TrackConfig":
        """Rebuild a configuration from :meth:`settings` (unknown keys are ignored)."""
        import dataclasses

        names = {f.name for f in dataclasses.fields(cls)}
        kwargs = {k: v for k, v in settings.items() if k in names}
        for key in ("process_noise", "world_process_noise", "manoeuvre", "cues", "sources"):
            if isinstance(kwargs.get(key), list):
                kwargs[key] = tuple(kwargs[key])
        opts = kwargs.get("cue_options")
        if isinstance(opts, Mapping):
            cue_names = {f.name for f in dataclasses.fields(CueOptions)}
            opts = {k: v for k, v in opts.items() if k in cue_names}
            if isinstance(opts.get("depth_range_mm"), list):
                opts["depth_range_mm"] = tuple(opts["depth_range_mm"])
            kwargs["cue_options"] = CueOptions(**opts)
        return cls(**kwargs)
