"""Colour cue: paper 003 §3.5.1, Figure 3 (background subtraction + morphology).

Stages (all cropped to the region of interest, ``h x w``):

=========  ======================  =============================================
name       shape, dtype            content
=========  ======================  =============================================
I_C1       (h, w, 3) uint8         input colour window (RGB)
I_C2       (h, w, 3) uint8         ``|I - B|`` per channel (difference image)
I_C3       (h, w) uint8            grayscale of I_C2
I_C4A      (h, w) uint8 {0, 255}   ``I_C3 > lower`` (removes the background)
I_C4B      (h, w) uint8 {0, 255}   ``I_C3 <= upper`` (removes the dark clothing /
                                   subject outline)
I_C5       (h, w) uint8 {0, 255}   I_C4A AND I_C4B (coarse hand region)
I_C6       (h, w) uint8 {0, 255}   small regions (< ``min_area`` px) and thin
                                   outlines (opening, radius ``open_radius``)
                                   removed
I_C7       (h, w) uint8 {0, 255}   holes filled
I_C8       (h, w) uint8 {0, 255}   dilated by a disc of radius ``dilate``
I_C9       (h, w) uint8 {0, 255}   regions touching the window border removed
=========  ======================  =============================================

The largest region of I_C9 gives the measurement (plus the window offset): not
its centroid, as in the paper, but the centre of its core
(:func:`~fusion_pf.cues.regions.core_centre`, the centroid of its pixels
farthest inside it, weighted by that distance). A palm with its bare forearm is
one skin region whose centroid lies toward the elbow by an amount that grows
with the forearm's visible length; its core is on the palm. Measured with the
default fused tracker: ``recordings/sample.mcap`` colour 5.80 -> 1.83 px RMSE
(fused 1.07 -> 1.02); two-hand scenes at 960 x 540 (seeds 1018, 1020) colour
13-15 -> 1-2 px RMSE while the hands are apart. Default thresholds come from the synthetic scene
(``drivers.synth``, seeds 0-2, 68 person frames each at 640 x 400, 1st / 50th /
99th percentile of the grayscale difference against the 30-frame mean
background, masks eroded by 2 px): background 1 / 5 / 20 (the scene's
illumination drift), skin 20 / 28 / 50 (palm 20 / 27 / 49), dark clothing and
hair 99 / 113 / 129; so ``lower = 16``, ``upper = 66``. With ``lower = 12``
the drifted background joins the hand region on some frames (coverage 0.72
instead of 0.88 on seed 0's frames 20-80 with a 5-frame background). The
blurred outline between clothing and wall passes both thresholds as 1-2 px
lines; the opening in I_C6 removes them.
Tune the thresholds on your own scene with ``fusion-pf cues --stages``. No band
helps where the clothing differs from the empty scene by as much as the skin
does: on the ray-cast scenes of ``benchmarks/raycast_scenes.py`` (palm 16-99
grey levels from the wall, median per scene) each scene's own band, taken from
the palm's true pixels, made the person one region and the cue measured in
0-3 % of the frames of six of eight scenes; the learned hand cue or ``skin_rgb``
are the cues for such a scene.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from ..errors import InputError
from ..frame import Frame
from .base import CueContext, CueResult
from .regions import (
    MIN_AREA_PX,
    check_int,
    clear_border,
    dilate,
    fill_holes,
    open_thin,
    remove_small,
    window_regions,
)
from .roi import Roi, full_roi, search_step, subsample


def _check_pair(color: np.ndarray, background: np.ndarray | None) -> bool:
    """Validate the colour inputs; False when there is no background to subtract."""
    if not isinstance(color, np.ndarray) or color.ndim != 3 or color.shape[2] != 3 or color.dtype != np.uint8:
        raise InputError(f"colour must be an (H, W, 3) uint8 array, got {getattr(color, 'shape', color)!r}")
    if background is None:
        return False
    if background.shape != color.shape or background.dtype != np.uint8:
        raise InputError(
            f"colour background must match the colour image {color.shape} uint8, "
            f"got {background.shape} {background.dtype}"
        )
    return True


class ColourCue:
    """The colour-based observation model of paper 003 (Fig. 3).

    Parameters
    ----------
    lower : int
        Lower grayscale-difference threshold, 0-254: I_C4A = I_C3 > lower.
    upper : int
        Upper threshold, ``lower``-255: I_C4B = I_C3 <= upper.
    min_area : int
        Regions smaller than this (px) are removed (I_C6), 0-100000.
    open_radius : int
        Opening radius (px) removing thin outlines before the area filter
        (I_C6), 0-20; 0 = the paper's area filter only.
    dilate : int
        Dilation disc radius in px (I_C8), 0-50.
    clear_border : bool
        Remove regions touching the window border (I_C9).
    source : str
        Measurement source name.
    """

    def __init__(
        self,
        *,
        lower: int = 16,
        upper: int = 66,
        min_area: int = MIN_AREA_PX,
        open_radius: int = 1,
        dilate: int = 2,
        clear_border: bool = True,
        source: str = "colour",
    ) -> None:
        self.lower = check_int("colour lower threshold", lower, 0, 254)
        self.upper = check_int("colour upper threshold", upper, self.lower, 255)
        self.min_area = check_int("colour min_area", min_area, 0, 100_000)
        self.open_radius = check_int("colour open_radius", open_radius, 0, 20)
        self.dilate = check_int("colour dilate radius", dilate, 0, 50)
        self.clear_border = bool(clear_border)
        self.source = str(source)

    #: Frame parts the cue reads (:data:`~fusion_pf.cues.base.NEEDS`).
    needs = frozenset({"color", "background"})

    @property
    def name(self) -> str:
        """Source name of the measurements."""
        return self.source

    def reset(self) -> None:
        """Nothing to forget: the colour cue has no state."""

    def measure(self, frame: Frame, ctx: CueContext) -> CueResult:
        """The :class:`~fusion_pf.cues.base.Cue` form: ``frame``'s colour against ``ctx.background``."""
        background = None if ctx.background is None else ctx.background.color
        return self(
            frame.color,
            background,
            roi=ctx.roi,
            stages=ctx.stages,
            keep_border=ctx.search,
            candidates=ctx.candidates,
            parts=ctx.parts,
        )

    def __call__(
        self,
        color: np.ndarray,
        background: np.ndarray | None,
        *,
        roi: Roi | None = None,
        stages: bool = False,
        keep_border: bool = False,
        candidates: bool = False,
        parts: tuple[tuple[float, float], ...] = (),
    ) -> CueResult:
        """Extract the palm centre from ``color`` against ``background``.

        Parameters
        ----------
        color, background : ndarray, shape (H, W, 3), uint8
            Current and reference (empty-scene) RGB images.
        roi : Roi, optional
            Window to process; the whole frame when None.
        keep_border : bool
            Keep regions touching the window border (a whole-frame search, where
            the arm enters from the image border). The search of a window larger
            than :data:`~fusion_pf.cues.roi.SEARCH_PIXELS` reads every k-th row and
            column (:func:`~fusion_pf.cues.roi.search_step`).
        candidates : bool
            Also return every region as a candidate (``CueResult.candidates``,
            several targets: the association picks).
        parts : tuple of (float, float)
            With ``candidates``: two joined targets' predictions; a region
            holding both is two candidates (:func:`~fusion_pf.cues.regions.split_region`).
        stages : bool
            Also return the stage images I_C1 ... I_C9 (at the search's reduced
            resolution when it had one).

        Returns
        -------
        CueResult
            Measurement in full-frame pixels (None when no region qualifies or
            there is no background), stages, latency.
        """
        t0 = time.perf_counter_ns()
        has_bg = _check_pair(color, background)
        h, w = color.shape[:2]
        roi = full_roi(w, h) if roi is None else roi
        out: dict[str, np.ndarray] = {}
        if not has_bg or roi.empty:
            return CueResult(None, out, time.perf_counter_ns() - t0)
        assert background is not None  # _check_pair is False without a background
        step = search_step(roi) if keep_border else 1
        c1, b1 = roi.crop(color), roi.crop(background)
        if step > 1:
            c1, b1 = subsample(c1, step), subsample(b1, step)
        c2 = cv2.absdiff(c1, b1)  # I_C2 = |I - B| per channel
        c3 = cv2.cvtColor(c2, cv2.COLOR_RGB2GRAY)  # I_C3 = grayscale difference
        c4a = cv2.threshold(c3, self.lower, 255, cv2.THRESH_BINARY)[1]  # I_C4A = I_C3 > lower
        c4b = cv2.threshold(c3, self.upper, 255, cv2.THRESH_BINARY_INV)[1]  # I_C4B = I_C3 <= upper
        c5 = cv2.bitwise_and(c4a, c4b)  # I_C5 = I_C4A AND I_C4B
        c6 = remove_small(open_thin(c5, self.open_radius), self.min_area // (step * step))  # I_C6 = thin, small removed
        c7 = fill_holes(c6)  # I_C7 = holes filled
        c8 = dilate(c7, self.dilate)  # I_C8 = dilation
        c9 = clear_border(c8) if self.clear_border and not keep_border else c8  # I_C9 = border cleared
        extras = {"roi": roi.as_list(), "search_step": step}
        m, found = window_regions(
            c9,
            roi,
            self.source,
            min_area=self.min_area,
            extras=extras,
            step=step,
            candidates=candidates,
            parts=parts,
            core=True,
        )
        if stages:
            out = {
                "I_C1": c1.copy(),
                "I_C2": c2,
                "I_C3": c3,
                "I_C4A": c4a,
                "I_C4B": c4b,
                "I_C5": c5,
                "I_C6": c6,
                "I_C7": c7,
                "I_C8": c8,
                "I_C9": c9,
            }
        return CueResult(m, out, time.perf_counter_ns() - t0, found)


def colour_cue(
    color: np.ndarray,
    background: np.ndarray | None,
    *,
    roi: Roi | None = None,
    stages: bool = False,
    **options: object,
) -> CueResult:
    """Functional form of :class:`ColourCue`: ``ColourCue(**options)(color, background, ...)``."""
    return ColourCue(**options)(color, background, roi=roi, stages=stages)  # type: ignore[arg-type]
