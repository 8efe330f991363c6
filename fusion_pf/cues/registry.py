"""The cue registry and the cue stage's options: one configuration for every command.

``fusion-pf track``, ``cues``, ``score --sweep`` and ``demo`` build their cues
here, from one :class:`CueOptions`, so a threshold tuned with ``fusion-pf cues``
is the threshold ``track`` uses. Each registered cue says what it needs from a
frame (:data:`~fusion_pf.cues.base.NEEDS`); the pipeline picks the cues a
recording can feed (:func:`fusion_pf.pipeline.cue_names`).

A new cue is a class with the :class:`~fusion_pf.cues.base.Cue` members plus a
:func:`register` call naming its builder.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..options import option, parse_tuple, validate
from .base import Cue
from .colour import ColourCue
from .depth import DepthCue
from .hand import LANDMARK_MODELS, PALM_MODELS, HandCue, HandLandmarker
from .handflow import LandmarkFlow
from .skeleton import SkeletonCue
from .skin import LabGmmSkin, RgbRuleSkin, RgChromaSkin, SkinCue

__all__ = ["CUES", "CueInfo", "CueOptions", "build_cue", "build_cues", "check_cue_names", "register"]


def _default(cls: type[Any], name: str):
    """The keyword default of ``cls.__init__`` (where each cue's default is defined)."""
    return inspect.signature(cls.__init__).parameters[name].default


def _range_mm(label: str, value) -> tuple[int, int]:
    try:
        lo, hi = (int(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"{label} must be two integers LO,HI in mm, got {value!r}") from None
    if not 0 <= lo < hi <= 65535:
        raise InputError(f"{label} must satisfy 0 <= LO < HI <= 65535 mm, got {lo},{hi}")
    return lo, hi


def _path_or_none(label: str, value) -> Path | None:
    return None if value is None else Path(value)


@dataclass(frozen=True)
class CueOptions:
    """Options of the cue stage (every command that runs cues takes these flags).

    Each default is the keyword default of the cue class it configures.
    """

    colour_lower: int = option(
        _default(ColourCue, "lower"),
        kind="int",
        lo=0,
        hi=254,
        unit="grey levels",
        help="colour cue: lower threshold of the grey difference (I_C4A)",
    )
    colour_upper: int = option(
        _default(ColourCue, "upper"),
        kind="int",
        lo=0,
        hi=255,
        unit="grey levels",
        help="colour cue: upper threshold of the grey difference (I_C4B)",
    )
    depth_range_mm: tuple[int, int] = option(
        _default(DepthCue, "range_mm"),
        parse=parse_tuple(2, int),
        check=_range_mm,
        metavar="LO,HI",
        show=lambda v: f"{v[0]},{v[1]}",
        unit="mm",
        help="depth cue: difference range quantised to grey levels 0-255 (I_d3)",
    )
    depth_lower: int = option(
        _default(DepthCue, "lower"),
        kind="int",
        lo=0,
        hi=254,
        unit="grey levels",
        help="depth cue: lower threshold on I_d3 (I_d4A)",
    )
    depth_upper: int = option(
        _default(DepthCue, "upper"),
        kind="int",
        lo=0,
        hi=255,
        unit="grey levels",
        help="depth cue: upper threshold on I_d3 (I_d4B)",
    )
    depth_nearest_mm: int = option(
        _default(DepthCue, "nearest_mm"),
        kind="int",
        lo=0,
        hi=65535,
        unit="mm",
        help="depth cue: keep the slab this deep behind the nearest surface; 0 = the paper's band only",
    )
    depth_invalid_far: bool = option(
        _default(DepthCue, "invalid_far"),
        kind="bool",
        help="depth cue: background pixels without depth count as far (a hand in "
        "front of an out-of-range wall is foreground)",
    )
    min_area: int = option(
        _default(ColourCue, "min_area"),
        kind="int",
        lo=0,
        hi=100_000,
        unit="px",
        help="smallest region the colour, depth and skin cues keep",
    )
    hand_threads: int = option(
        _default(HandLandmarker, "num_threads"),
        kind="int",
        lo=1,
        hi=64,
        unit="threads",
        help="hand cue: LiteRT threads per model call; 1 never waits for a core another process holds, "
        "more adds a single-threaded twin that runs every call while another task is runnable "
        "(otherwise the faster of the two runs)",
    )
    hand_landmark_model: str = option(
        _default(HandLandmarker, "landmark_model"),
        choices=LANDMARK_MODELS,
        help="hand cue: MediaPipe hand-landmark model variant (full: model_complexity=1, MediaPipe Hands' default; "
        "full_mixed: the full model in int8 but its input stage and last two blocks, 0.6x its CPU time per call, "
        "fused RMSE 10.5 / 5.92 px against 10.4 / 5.92 on the real development frames (canvas / crops); "
        "full_int8: the full model quantised to int8, 0.4x its CPU time per call, 4 per cent less accurate on the real "
        "development frames; lite: model_complexity=0, about half the CPU time per call)",
    )
    hand_palm_model: str = option(
        _default(HandLandmarker, "palm_model"),
        choices=PALM_MODELS,
        help="hand cue: MediaPipe palm-detection model variant (full, lite as --hand-landmark-model; full_int8: the "
        "full detector quantised to int8, 0.75x its CPU time per call, the same palms on MediaPipe's test photos "
        "but a slightly worse fused p95 on the real development frames)",
    )
    hand_search_palm_model: str | None = option(
        _default(HandLandmarker, "search_palm_model"),
        choices=PALM_MODELS,
        optional=True,
        help="hand cue: palm-detection model of an acquisition frame (the target lost, the whole frame searched; "
        "none: --hand-palm-model's); full_int8: 0.78x the full detector's CPU time per call, as good a whole-frame "
        "search on the real development frames, but 0.1 px worse tracked from there",
    )
    hand_flow_frames: int = option(
        _default(LandmarkFlow, "max_frames"),
        kind="int",
        lo=0,
        hi=1000,
        unit="frames",
        help="hand cue: most frames in a row whose landmarks optical flow carries from the last frame instead of "
        "a landmark-model call, and only while the palm joints track both ways and the hand moved rigidly "
        "(cues/handflow.py); 0 = the model on every tracked frame (MediaPipe; on the real development "
        "frames the flow's failed tries cost more than its carried frames save at the median and p95)",
    )
    cv_threads: int = option(
        1,
        kind="int",
        lo=1,
        hi=64,
        unit="threads",
        help="OpenCV threads while a frame is decoded and its cues run; 1 never waits for a core another process "
        "holds (the caller's setting is restored after each frame)",
    )
    skin_model: Path | None = option(
        None,
        optional=True,
        check=_path_or_none,
        metavar="MODEL.npz",
        help="CIE-Lab GMM skin model saved by LabGmmSkin.save (needed by the skin_lab cue)",
    )

    def __post_init__(self) -> None:
        validate(self)
        if self.colour_upper < self.colour_lower:
            raise InputError(
                f"colour_upper (--colour-upper) must be >= colour_lower {self.colour_lower}, got {self.colour_upper}"
            )
        if self.depth_upper < self.depth_lower:
            raise InputError(
                f"depth_upper (--depth-upper) must be >= depth_lower {self.depth_lower}, got {self.depth_upper}"
            )


@dataclass(frozen=True)
class CueInfo:
    """A registered cue: what it needs and how to build it from :class:`CueOptions`."""

    name: str
    needs: frozenset[str]
    help: str
    build: Callable[[CueOptions], Cue]


#: Every cue the pipeline can run, by source name.
CUES: dict[str, CueInfo] = {}


def register(
    name: str, needs: Iterable[str], help: str
) -> Callable[[Callable[[CueOptions], Cue]], Callable[[CueOptions], Cue]]:
    """Decorator registering a cue builder ``build(options) -> Cue`` under ``name``."""

    def decorate(build: Callable[[CueOptions], Cue]) -> Callable[[CueOptions], Cue]:
        CUES[name] = CueInfo(name, frozenset(needs), help, build)
        return build

    return decorate


@register("colour", ColourCue.needs, "paper 003 §3.5.1: background subtraction on colour")
def _colour(o: CueOptions) -> Cue:
    return ColourCue(lower=o.colour_lower, upper=o.colour_upper, min_area=o.min_area)


@register("depth", DepthCue.needs, "paper 003 §3.5.2: background subtraction on depth")
def _depth(o: CueOptions) -> Cue:
    return DepthCue(
        range_mm=o.depth_range_mm,
        lower=o.depth_lower,
        upper=o.depth_upper,
        min_area=o.min_area,
        nearest_mm=o.depth_nearest_mm or None,
        invalid_far=o.depth_invalid_far,
    )


@register("skeleton", SkeletonCue.needs, "the camera's skeleton joint (paper 003's K)")
def _skeleton(o: CueOptions) -> Cue:
    return SkeletonCue()


@register("hand", HandCue.needs, "learned palm detector + hand landmarks (MediaPipe models on LiteRT), or the camera's")
def _hand(o: CueOptions) -> Cue:
    return HandCue(
        num_threads=o.hand_threads,
        landmark_model=o.hand_landmark_model,
        palm_model=o.hand_palm_model,
        search_palm_model=o.hand_search_palm_model,
        flow=LandmarkFlow(o.hand_flow_frames) if o.hand_flow_frames else None,
    )


@register("skin_rgb", SkinCue.needs, "paper 002 eq. 4: explicit RGB skin rule")
def _skin_rgb(o: CueOptions) -> Cue:
    return SkinCue(RgbRuleSkin(), min_area=o.min_area)


@register("skin_rg", SkinCue.needs, "paper 000 eq. 5-6: rg-chromaticity skin model with grey world")
def _skin_rg(o: CueOptions) -> Cue:
    return SkinCue(RgChromaSkin(), min_area=o.min_area)


@register("skin_lab", SkinCue.needs, "paper 001: EM mixtures in CIE Lab, naive Bayes (needs --skin-model)")
def _skin_lab(o: CueOptions) -> Cue:
    if o.skin_model is None:
        raise InputError("the skin_lab cue needs a trained model: --skin-model MODEL.npz (LabGmmSkin.save)")
    return SkinCue(LabGmmSkin.load(o.skin_model), min_area=o.min_area)


def check_cue_names(names: Iterable[str]) -> tuple[str, ...]:
    """Validate cue names (known, distinct, at least one); returns them as a tuple."""
    out = tuple(names)
    unknown = [n for n in out if n not in CUES]
    if unknown or not out or len(set(out)) != len(out):
        raise InputError(f"cues must be distinct names among {', '.join(CUES)}, got {','.join(map(str, out))!r}")
    return out


def build_cue(name: str, options: CueOptions | None = None) -> Cue:
    """A new instance of the cue ``name``."""
    check_cue_names((name,))
    return CUES[name].build(options or CueOptions())


def build_cues(names: Iterable[str], options: CueOptions | None = None) -> dict[str, Cue]:
    """New instances of the cues ``names``, by name, in that order."""
    options = options or CueOptions()
    return {n: CUES[n].build(options) for n in check_cue_names(names)}
