"""The cue contract: a frame in, one palm measurement (or None) and its detections out.

Every cue the pipeline can run is a :class:`Cue` (``name``, ``needs``,
``measure(frame, ctx)``, ``reset()``) registered in :mod:`fusion_pf.cues.registry`.
The extractors underneath take arrays and keyword-only options, never a device
or a file, and return a :class:`CueResult`: the measurement (None when nothing qualifies, never NaN or
an exception on degenerate input) plus, on request, its stage images named as
in paper 003 Figures 3-4 (``I_C2`` ... ``I_C9``, ``I_d2`` ... ``I_d10``).
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import cv2
import numpy as np

from ..association.base import Detection
from ..frame import SOURCES, Measurement

if TYPE_CHECKING:
    from ..frame import Frame
    from .background import BackgroundModel
    from .roi import Roi

__all__ = ["NEEDS", "SOURCES", "Cue", "CueContext", "CueResult", "Measurement", "opencv_threads"]


@contextmanager
def opencv_threads(n: int) -> Iterator[None]:
    """OpenCV's worker-thread count ``n`` (>= 1) inside the block, the caller's restored after.

    The cues' OpenCV calls are small (a 224 x 224 warp, a search at about 500 x 280): split over
    two threads they gain little on an idle machine, and when another process holds a core each
    call waits for that core's time slice (a 0.3 ms warp took 7-11 ms at the 95th percentile
    with one core kept busy, 0.6 ms single-threaded). Setting the count costs well under a
    microsecond, except lowering it while OpenCV's pool has threads (a parallel call since the
    count was raised): that stops them and waits for each, milliseconds on a loaded machine, so a
    caller keeps one block around all of a frame's OpenCV work (:func:`fusion_pf.pipeline.track`).
    """
    old = cv2.getNumThreads()
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(old)


@dataclass(frozen=True, slots=True)
class CueResult:
    """What a cue extractor returns.

    Parameters
    ----------
    measurement : Measurement or None
        None when no region qualified.
    stages : mapping of str to ndarray
        Stage images keyed by the paper's names; empty unless requested.
    latency_ns : int
        Wall time the extraction took (``time.perf_counter_ns``).
    candidates : tuple of Detection
        Every candidate the cue saw, for several targets (the hand cue's hands
        with their handedness); empty: the measurement is the only one
        (:attr:`detections`).
    rested : bool
        The cue did not search this frame (an idle cue resting, e.g. the hand
        cue's palm detection every other frame after several frames without a
        hand): no measurement, and none expected; counted by ``track``.
    """

    measurement: Measurement | None
    stages: Mapping[str, np.ndarray] = field(default_factory=dict)
    latency_ns: int = 0
    candidates: tuple[Detection, ...] = ()
    rested: bool = False

    @property
    def detections(self) -> tuple[Detection, ...]:
        """The cue's detections: its candidates, else its measurement (none without one)."""
        if self.candidates:
            return self.candidates
        return () if self.measurement is None else (Detection(self.measurement),)


#: What a cue may need from a frame: the colour image, aligned depth, the
#: skeleton joints, and a background model (of colour, or of depth with "depth").
NEEDS = ("color", "depth", "skeleton", "background")


@dataclass(frozen=True, slots=True)
class CueContext:
    """What the pipeline gives a cue besides the frame, for one frame.

    Parameters
    ----------
    roi : Roi or None
        Window to search (None: the whole frame).
    background : BackgroundModel or None
        Empty-scene model for the background-subtraction cues.
    joint : str
        Skeleton joint the skeleton cue reads.
    stages : bool
        Return the stage images too.
    prior : (float, float) or None
        Where the palm is expected (full-frame px); blob cues that can see
        several candidates (skin) take the one nearest to it.
    search : bool
        A whole-frame search for a palm (acquisition): regions touching the
        frame border are kept (an arm enters from the border).
    hands : int
        Hands the pipeline tracks (the hand cue follows up to this many; 1:
        the one nearest ``prior``).
    candidates : bool
        Several targets share the frame: region cues also return every region
        of the window as a candidate (another target's region may lie in it;
        the association picks).
    parts : tuple of (float, float)
        With ``candidates``: the predictions (full-frame px) of two joined
        (``combined``) targets; a region holding both is given as two parts,
        its pixels split between them (:func:`fusion_pf.cues.regions.split_region`).
    """

    roi: Roi | None = None
    background: BackgroundModel | None = None
    joint: str = "right_hand"
    stages: bool = False
    prior: tuple[float, float] | None = None
    search: bool = False
    hands: int = 1
    candidates: bool = False
    parts: tuple[tuple[float, float], ...] = ()


@runtime_checkable
class Cue(Protocol):
    """A palm cue: one frame in, one measurement (or None) out.

    ``name`` is the source name (CSV columns, JSON keys, likelihood terms);
    ``needs`` the frame parts it reads (a subset of :data:`NEEDS`); ``measure``
    never raises on degenerate input (no region -> measurement None);
    ``reset`` forgets per-stream state (e.g. the depth cue's previous frame).
    """

    needs: frozenset[str]

    @property
    def name(self) -> str: ...

    def measure(self, frame: "Frame", ctx: CueContext) -> CueResult: ...

    def reset(self) -> None: ...
