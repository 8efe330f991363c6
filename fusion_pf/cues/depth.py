"""Depth cue: paper 003 §3.5.2, Figure 4 (background subtraction in depth + temporal difference).

Stages (cropped to the region of interest, ``h x w``):

=========  ======================  =============================================
name       shape, dtype            content
=========  ======================  =============================================
I_d1       (h, w) uint16           input depth window (mm, 0 = invalid)
I_d2       (h, w) uint16           ``max(B - D, 0)`` (mm nearer than the
                                   background); 0 where D or B is invalid
I_d3       (h, w) uint8            I_d2 quantised to 8 bit over ``range_mm``
I_d4A      (h, w) uint8 {0, 255}   ``I_d3 > lower``
I_d4B      (h, w) uint8 {0, 255}   ``I_d3 <= upper``
I_d5       (h, w) uint8 {0, 255}   I_d4A AND I_d4B, restricted to the slab
                                   ``nearest_mm`` behind the nearest surface
                                   and opened (radius ``open_radius``)
I_d6       (h, w) uint8 {0, 255}   ``|I_d5(t) - I_d5(t-1)|`` (changed pixels),
                                   regions < ``min_area`` removed
I_d7       (h, w) uint8 {0, 255}   I_d6 with its holes filled
I_d8       (h, w) uint8 {0, 255}   I_d7 dilated by a disc of radius ``dilate``
I_d9       (h, w) uint8 {0, 255}   regions of I_d5 that meet I_d8, holes filled
I_d10      (h, w) uint8 {0, 255}   regions touching the window border removed
=========  ======================  =============================================

Our reading of the paper's ill-defined steps
--------------------------------------------
The paper says: "the previous time step image obtained by the same operations
is used as reference for a subtraction operation. A new difference image (I_d6)
is obtained by this subtraction. After this phase, morphological filling (I_d7)
and dilation (I_d8) operations are applied successively. A logical AND-NOT
operation is applied afterwards in order to get the holes as regions (I_d9)".
We implement it as follows:

* *subtraction of the previous step's result*: I_d6 is the absolute difference
  (XOR) of this frame's coarse region I_d5 and the previous call's I_d5 (the
  previous window is re-aligned to the current one by the two windows'
  offsets; outside the previous window it counts as empty). For a moving hand
  this is the ring of pixels it entered and left. Regions smaller than
  ``min_area`` (depth-noise speckle on the band edges) are dropped.
* filling closes that ring (I_d7) and dilation reconnects its pieces (I_d8):
  together they mark *where something moved*.
* *AND-NOT "to get the holes as regions"*: I_d9 keeps the regions of the
  current coarse region I_d5 that meet the moved area I_d8 (I_d5 AND NOT the
  regions lying wholly in NOT I_d8), with their holes filled. Whole regions are
  kept rather than single pixels because a hand that moves a few pixels
  changes only a thin rim, which would bias the centroid; static things in the
  band (furniture, a torso edge) are removed.
* When nothing moved (I_d6 empty: first frame, a still hand, or
  ``temporal=False``) I_d9 is the filled coarse region, so a still hand is
  still measured.
* *nearest-surface slab* (our addition, ``nearest_mm``): the paper's fixed
  band cannot separate the palm from the torso on our scenes (difference
  ranges overlap once the background behind the palm varies), so I_d5 keeps
  only the pixels within ``nearest_mm`` of the nearest surface in the window
  (the 2nd percentile of the band's depths). ``nearest_mm=None`` restores the
  paper's band. The slab is 30 mm deep: a palm facing the camera spans about
  20 mm of depth with the sensor noise at 1.3 m (realistic stereo model), while
  the forearm recedes from the wrist by about 1 mm per mm of its length, so a
  deeper slab keeps that much wrist above the palm and the centroid follows it.
  With 50 mm the depth cue sat 7-9 px above the palm at 1280 x 720 (two-hand
  seed 3004, palms 15 cm in front of the body: 13.7 px RMSE while the hands
  were apart, 5.8 px with 30 mm) and 1.75 px RMSE on ``recordings/sample.mcap``
  (1.05 px with 30 mm; fused 1.02 -> 0.80 px).
* *the slab follows the depth noise*: 30 mm is the noise-free width. Where the
  noise is several times the sensor model's (``synth --depth-noise`` 3-6, a far
  hand) a fixed 30 mm cuts noisy palm pixels off: the 2nd percentile sits about
  2 sigma in front of the palm, so about half of its pixels stay and the
  opening breaks them up. The cue measures the noise sigma of the coarse region
  itself (:func:`depth_noise_mm`: MAD of second differences 5 px apart, past
  the matcher's spatial correlation; a planar slope cancels) in inverse depth,
  where a stereo sensor's noise is the same at every depth, and reads it at the
  nearest surface z0 (``sigma_z = z0^2 sigma_w``); the slab is
  ``hypot(nearest_mm, 2 sigma)`` (the two widths add in variance; 2 sigma is
  z0's bias). Measured in mm over the region (before), the wall pixels 1-2 m
  behind a palm beside the body, in the coarse region whenever the depth noise
  is high, made sigma 2-3x the palm's (120 mm against 50 on a 640 x 400 palm
  4 cm in front of the body, ``depth_noise`` 10): the slab took in the torso,
  the region touched the window border and the cue lost 20-55 % of its frames
  (GT-centred windows, own single-palm seeds 5001-5008). Measured sigma: 1.8 mm (big-1280), 6.4 (default-640), 13.9
  (far-hand-noisy-640b), 23.6 (skeleton-best-960), i.e. slabs of 30, 33, 40 and
  56 mm. ``benchmarks/fusion_matrix.py``, fixed 30 mm -> adaptive: far-hand-
  noisy-640b depth 1.42 -> 0.63 px, fused 1.18 -> 0.95; skeleton-best-960
  depth 17.6 -> 11.0, fused 4.27 -> 3.52; default-640 and big-1280 unchanged
  (fused 1.16 -> 1.14, 2.40); ``recordings/sample.mcap`` depth 1.04, fused
  0.79; seed 3004 1280 x 720 per hand 7.2/7.2 px. Not better: adding 4 sigma
  (z0's bias and the pixels' own spread) or adding sigmas linearly widens the
  slab into the wrist and, 6 cm behind the palm on skeleton-best-960, the torso
  (30 + 4 sigma: far-hand-noisy-640b depth 4.5, skeleton-best-960 49.5 px;
  30 + 1 sigma: default-640 fused 1.39, big-1280 2.88). These are tuning scenes.
  Where it lost (held-out scenes, measured once): a palm 4 cm in front of the
  body with depth noise 9-10x the model's, fused 16.9 -> 29.3 and 8.1 -> 19.0
  px against the 50 mm slab. Sixteen such scenes of our own (seeds 5001-5016,
  320 x 200 to 1280 x 720, palm 3-8 cm in front of the body, depth noise 6-12,
  skeleton bias 1-2.5, skin-like clothing): fused RMSE with the noise in mm /
  in inverse depth, geometric mean 0.74 (13 of 16 better; 0.71 on seeds
  5009-5016, rendered after the change), 0.79 against the 50 mm slab (10 of 16
  better). Still lost: where palm and torso are within one noise sigma (5002:
  10.6 px with the 50 mm slab, 39.4 now), no slab separates them. Measured and
  not kept there: scaling the quality by the share of the palm's depth band a
  palm can fill (no better: geometric mean about 1.0) and dropping the
  measurement (2-10x worse: depth is the one good cue in these scenes). The
  tuned matrix split, fused new / old: 0.97 (skeleton-lit-400 1.67 -> 1.42,
  far-hand-noisy-640b 0.89 -> 1.04), held out 0.96, new 1.02 (skeleton-best-
  lit-320 1.21 -> 1.68), fresh 0.87; ``recordings/sample.mcap`` depth 1.04 ->
  0.96 px, fused 0.78 unchanged; the two-hand seeds unchanged.

A whole-frame search (acquisition, ``keep_border``) runs the stages on every
k-th row and column (:func:`~fusion_pf.cues.roi.search_step`: 3 at 1280 x 720)
and then measures the region it found again at full resolution in a window
around it only (:meth:`DepthCue._refine`; one measurement, not the several-target
candidates): the subsampled region's centroid was 1.1 px median, 2.6 px p95
from the full-resolution search's (synthetic 1280 x 720, seed 6201, 30 frames),
the refined one 0.0 / 0.3 px (against the true palm 1.7 -> 0.5 px median) for
0.2 ms more CPU.

Invalid depth (0, in the frame or in the background) gives 0 in I_d2, which
is never above ``lower >= 0``, so it never counts as foreground.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import cast

import cv2
import numpy as np

from ..errors import InputError
from ..frame import Frame
from .base import CueContext, CueResult, Measurement
from .regions import (
    MIN_AREA_PX,
    check_int,
    clear_border,
    dilate,
    fill_holes,
    keep_marked,
    measure,
    open_thin,
    remove_small,
    window_regions,
)
from .roi import Roi, full_roi, search_step

#: Lag (full-resolution px) of the second differences that measure the depth noise: beyond the
#: stereo matcher's spatial correlation (its 5-7 px block; ``drivers.synth`` blurs the disparity
#: noise by a Gaussian of sigma 2 px, correlation exp(-1.6) = 0.21 at 5 px).
NOISE_LAG_PX = 5
#: Width of the noise part of the slab in noise sigmas: the 2nd percentile ``z0`` sits 2.05 sigma
#: in front of the nearest surface. It adds to ``nearest_mm`` (the noise-free width) in variance.
NOISE_SLAB_SIGMAS = 2.0
#: Margin (search steps) around a reduced whole-frame search's region in which it is measured again at
#: full resolution (:meth:`DepthCue._refine`).
REFINE_PAD = 2
#: Second differences needed to measure the noise; fewer give sigma 0 (the fixed slab).
MIN_NOISE_SAMPLES = 50
#: Most first pixels of triples :func:`depth_noise_mm` reads in a reduced whole-frame search (every k-th of
#: the mask's, evenly spread).
MAX_NOISE_PIXELS = 4096


def depth_noise_mm(depth: np.ndarray, mask: np.ndarray, lag: int, at_mm: float, max_pixels: int | None = None) -> float:
    """Robust depth noise sigma (mm) at the depth ``at_mm`` of the pixels in ``mask``: MAD of the
    second differences ``w[i - lag] - 2 w[i] + w[i + lag]`` of the inverse depth ``w = 1 / z``
    along rows and columns, all three pixels in ``mask``, times ``at_mm ** 2``.

    A stereo sensor's noise is uniform in disparity, so in inverse depth: its depth noise grows
    as ``z ** 2`` (``dz = z ** 2 dw``). Measured in inverse depth, the pixels of the whole region
    (the palm, the torso behind it and noisy wall pixels 1-2 m farther, each as noisy in ``w``)
    measure one noise, read at the nearest surface; measured in mm, the far pixels made it 2-3x
    the palm's. The second difference cancels a planar slope (the forearm receding from the
    wrist), the MAD ignores the depth steps at the region's edges; for independent noise its
    sigma is ``sqrt(6) sigma``. 0 when fewer than :data:`MIN_NOISE_SAMPLES` differences exist.
    Only the mask's valid pixels are read, by flat index (a whole-frame search's coarse region is
    1-2 % of the frame, spread over all of it: 0.3 ms as whole-image differences, 0.09 ms so).
    With ``max_pixels`` the triples start at every k-th of the mask's pixels only, at most
    ``max_pixels`` (a reduced whole-frame search passes :data:`MAX_NOISE_PIXELS`: at 1280 x 720 with a
    person 1.0 -> 0.5 ms, sigma within 1.4 % of all pixels' on synthetic frames; not in tracking
    windows, where it moved one synthetic scene's fused RMSE by +21 %).
    """
    h, w = mask.shape
    m = np.ravel(mask.astype(bool, copy=False) & (depth > 0))
    z = np.ravel(depth)
    first = np.flatnonzero(m)  # the first pixel of each triple
    if max_pixels is not None and first.size > max_pixels:
        first = first[:: -(-first.size // max_pixels)]  # every k-th, evenly spread
    rows, cols = np.divmod(first, w)
    diffs = []
    for inside, stride in ((cols < w - 2 * lag, lag), (rows < h - 2 * lag, lag * w)):  # along rows, columns
        i = first[inside]
        i = i[m[i + stride] & m[i + 2 * stride]]
        a, b, c = (1.0 / z[i + k * stride].astype(np.float64) for k in range(3))  # inverse depth, 1/mm
        diffs.append(a - 2.0 * b + c)
    dd = np.concatenate(diffs) if diffs else np.empty(0)
    if dd.size < MIN_NOISE_SAMPLES:
        return 0.0
    return float(1.4826 * np.median(np.abs(dd)) / np.sqrt(6.0) * at_mm * at_mm)  # sigma_z = z^2 sigma_w


class DepthCue:
    """The depth-based observation model of paper 003 (Fig. 4); keeps the previous I_d5.

    Parameters
    ----------
    range_mm : (int, int)
        Difference range ``(lo, hi)`` in mm mapped to grey levels 0-255
        (``0 <= lo < hi <= 65535``); differences outside are clipped.
    lower : int
        Lower threshold on I_d3, 0-254: I_d4A = I_d3 > lower.
    upper : int
        Upper threshold, ``lower``-255: I_d4B = I_d3 <= upper.
    min_area : int
        Smallest region (px) kept in I_d6 and as the final region, 0-100000.
    dilate : int
        Dilation disc radius in px (I_d8), 0-50.
    nearest_mm : int or None
        Keep in I_d5 only the pixels within this many mm behind the nearest
        surface of the coarse region (its 2nd depth percentile) where the depth
        is noise-free, 1-65535; the slab widens with the region's measured
        depth noise (module docstring: why 30, how it widens);
        None = the paper's band only. Our addition: the depth difference of the
        palm overlaps that of the torso and of furniture (the palm is ~0.25 m
        in front of the torso but the background behind it varies), while the
        palm is the front-most surface near the hand.
    open_radius : int
        Opening radius (px) applied to the slab (with ``nearest_mm``) to drop
        its noisy fringe, 0-20.
    temporal : bool
        Use the previous frame's I_d5 (paper); False skips the subtraction.
    clear_border : bool
        Remove regions touching the window border (I_d10).
    invalid_far : bool
        A background pixel without depth (0: out of range, e.g. a wall beyond
        a ToF sensor's reach, 77-82 % of the pixels of a RealSense SR305 scene)
        counts as infinitely far, so a valid pixel in front of it is
        foreground; False: the paper's reading, invalid is never foreground.
    source : str
        Measurement source name.
    learnt_lower : int
        ``lower`` against a background learnt from the stream itself
        (:attr:`~fusion_pf.cues.background.BackgroundModel.learnt`: no empty
        scene, the person in view from the first frame), 0-254, the smaller of
        the two applies. That background's depth is the torso, not the wall,
        and 150 mm (``lower`` 15) cut a palm 12-22 cm in front of the body
        down to forearm remnants; 5 (50 mm, the nearest-surface slab then
        keeps the palm, not the torso) took two hands without background
        frames from 17.1 / 20.2 px to 5.0 / 5.3 (tuning scene: seed 7002,
        848x480, ``hand_front`` 0.12, dark skin).
    """

    def __init__(
        self,
        *,
        range_mm: tuple[int, int] = (0, 2550),
        lower: int = 15,
        upper: int = 255,
        min_area: int = MIN_AREA_PX,
        dilate: int = 4,
        nearest_mm: int | None = 30,
        open_radius: int = 2,
        temporal: bool = True,
        clear_border: bool = True,
        invalid_far: bool = True,
        source: str = "depth",
        learnt_lower: int = 5,
    ) -> None:
        try:
            lo, hi = range_mm
        except (TypeError, ValueError):
            raise InputError(f"depth range_mm must be a pair (lo, hi) of mm, got {range_mm!r}") from None
        lo = check_int("depth range_mm lo", lo, 0, 65534)
        hi = check_int("depth range_mm hi", hi, lo + 1, 65535)
        self.range_mm = (lo, hi)
        self.lower = check_int("depth lower threshold", lower, 0, 254)
        self.upper = check_int("depth upper threshold", upper, self.lower, 255)
        self.learnt_lower = check_int("depth learnt_lower threshold", learnt_lower, 0, 254)
        self.min_area = check_int("depth min_area", min_area, 0, 100_000)
        self.dilate = check_int("depth dilate radius", dilate, 0, 50)
        self.nearest_mm = None if nearest_mm is None else check_int("depth nearest_mm", nearest_mm, 1, 65535)
        self.open_radius = check_int("depth open_radius", open_radius, 0, 20)
        self.temporal = bool(temporal)
        self.clear_border = bool(clear_border)
        self.invalid_far = bool(invalid_far)
        self.source = str(source)
        self._prev: tuple[np.ndarray, Roi, tuple[int, int], int] | None = None
        self._background: tuple[np.ndarray, Roi, int, np.ndarray] | None = None

    def reset(self) -> None:
        """Forget the previous frame's I_d5 (call when the stream restarts)."""
        self._prev = None

    def _search_background(self, background: np.ndarray, roi: Roi, step: int) -> np.ndarray:
        """``background`` in ``roi``, every ``step``-th row and column, invalid as infinitely far with
        ``invalid_far``; kept while the background array, the window and the step stay (every lost
        frame of a whole-frame search: 0.1 ms of its 1 ms at 1280 x 720). A background model gives
        a new array when it changes, never the same one rewritten."""
        kept = self._background
        if kept is not None and kept[0] is background and kept[1] == roi and kept[2] == step:
            return kept[3]
        b1 = np.ascontiguousarray(roi.crop(background)[::step, ::step])
        if self.invalid_far:
            b1 = np.where(b1 > 0, b1, np.uint16(65535))  # no background depth: as far as can be
        self._background = (background, roi, step, b1)
        return b1

    def _previous(self, roi: Roi, frame_shape: tuple[int, int], step: int) -> np.ndarray | None:
        """The previous I_d5 re-aligned to ``roi`` (empty outside the previous window), read every
        ``step``-th row and column (as this frame's search)."""
        if self._prev is None:
            return None
        mask, proi, shape, pstep = self._prev
        if shape != frame_shape:
            return None
        if pstep == step and proi == roi:
            return mask  # the same search window at the same resolution: as it was kept
        if pstep > 1:  # kept at its search's resolution: back to full resolution (each pixel its block)
            mask = np.repeat(np.repeat(mask, pstep, axis=0), pstep, axis=1)[: proi.shape[0], : proi.shape[1]]
        out = np.zeros(roi.shape, np.uint8)
        x0, y0 = max(roi.x0, proi.x0), max(roi.y0, proi.y0)
        x1, y1 = min(roi.x1, proi.x1), min(roi.y1, proi.y1)
        if x1 > x0 and y1 > y0:
            out[y0 - roi.y0 : y1 - roi.y0, x0 - roi.x0 : x1 - roi.x0] = mask[
                y0 - proi.y0 : y1 - proi.y0, x0 - proi.x0 : x1 - proi.x0
            ]
        return out if step == 1 else np.ascontiguousarray(out[::step, ::step])

    def _band(self, d1: np.ndarray, b1: np.ndarray, lower: int) -> tuple[np.ndarray, ...]:
        """I_d2, I_d3, I_d4A (threshold ``lower``), I_d4B and I_d5 of depth ``d1`` against the background
        ``b1`` (invalid as infinitely far with ``invalid_far``)."""
        valid = d1 != 0  # invalid current depth never counts as foreground
        if not self.invalid_far:
            valid &= b1 != 0  # nor does unknown background
        d2 = cv2.subtract(b1, d1, mask=valid.view(np.uint8))  # I_d2 = max(B - D, 0) (saturating), 0 where invalid
        lo, hi = self.range_mm
        d3 = np.clip((d2.astype(np.float32) - lo) * (255.0 / (hi - lo)), 0, 255).astype(np.uint8)  # I_d3: 8-bit
        d4a = cv2.threshold(d3, lower, 255, cv2.THRESH_BINARY)[1]  # I_d4A = I_d3 > lower
        d4b = cv2.threshold(d3, self.upper, 255, cv2.THRESH_BINARY_INV)[1]  # I_d4B = I_d3 <= upper
        return d2, d3, d4a, d4b, cv2.bitwise_and(d4a, d4b)  # I_d5 = I_d4A AND I_d4B

    def _refine(
        self,
        depth: np.ndarray,
        background: np.ndarray,
        m: Measurement,
        coarse: np.ndarray,
        roi: Roi,
        step: int,
        far: int | None,
        lower: int,
    ) -> Measurement:
        """A reduced whole-frame search's measurement ``m`` measured again at full resolution, in a window
        around its region only: the region's box (``m.extras["bbox"]``) grown by :data:`REFINE_PAD` search
        steps. There the band (threshold ``lower``) and slab (the search's nearest surface, ``far``) are taken at full resolution
        and opened by ``open_radius`` full-resolution pixels (as a tracking window's), the regions meeting
        the search's final mask ``coarse`` (each of its pixels the ``step`` x ``step`` block it stands for)
        are kept, their holes filled, and the largest gives the measurement (``extras["refined"]``): the
        centroid of a full-resolution region, not of every ``step``-th pixel of it. ``m`` unchanged when
        nothing is left there."""
        bx, by, bw, bh = cast("Sequence[int]", m.extras["bbox"])  # the region's [x, y, w, h], full-frame px
        pad = REFINE_PAD * step
        win = Roi(
            max(roi.x0, bx - pad),
            max(roi.y0, by - pad),
            min(roi.x1, bx + bw + pad),
            min(roi.y1, by + bh + pad),
            roi.palm_area,
        )
        d1 = win.crop(depth)
        b1 = win.crop(background)
        if self.invalid_far:
            b1 = np.where(b1 > 0, b1, np.uint16(65535))
        d5 = self._band(d1, b1, lower)[4]
        if far is not None:
            d5 = open_thin(cv2.bitwise_and(d5, d5, mask=(d1 <= far).view(np.uint8)), self.open_radius)
        rows = (np.arange(win.y0, win.y1) - roi.y0) // step  # the coarse pixel each full-resolution pixel is in
        cols = (np.arange(win.x0, win.x1) - roi.x0) // step
        mark = coarse[np.ix_(np.minimum(rows, coarse.shape[0] - 1), np.minimum(cols, coarse.shape[1] - 1))]
        final = fill_holes(keep_marked(d5, mark))
        extras = {**m.extras, "refined": True}
        refined = measure(
            final, win.offset, self.source, palm_area=roi.palm_area, min_area=self.min_area, extras=extras
        )
        return m if refined is None else refined

    #: Frame parts the cue reads (:data:`~fusion_pf.cues.base.NEEDS`).
    needs = frozenset({"depth", "background"})

    @property
    def name(self) -> str:
        """Source name of the measurements."""
        return self.source

    def measure(self, frame: Frame, ctx: CueContext) -> CueResult:
        """The :class:`~fusion_pf.cues.base.Cue` form: ``frame``'s depth against ``ctx.background``."""
        background = None if ctx.background is None else ctx.background.depth
        if frame.depth is None:
            return CueResult(None)
        return self(
            frame.depth,
            background,
            roi=ctx.roi,
            stages=ctx.stages,
            keep_border=ctx.search,
            candidates=ctx.candidates,
            parts=ctx.parts,
            learnt=ctx.background is not None and ctx.background.learnt,
        )

    def __call__(
        self,
        depth: np.ndarray,
        background: np.ndarray | None,
        *,
        roi: Roi | None = None,
        stages: bool = False,
        keep_border: bool = False,
        candidates: bool = False,
        parts: tuple[tuple[float, float], ...] = (),
        learnt: bool = False,
    ) -> CueResult:
        """Extract the palm centroid from ``depth`` against the ``background`` depth.

        Parameters
        ----------
        depth, background : ndarray, shape (H, W), uint16
            Current and reference depth in mm (0 = invalid).
        roi : Roi, optional
            Window to process; the whole frame when None.
        keep_border : bool
            Keep regions touching the window border (a whole-frame search, where
            the arm enters from the image border). The search of a window larger
            than :data:`~fusion_pf.cues.roi.SEARCH_PIXELS` reads every k-th row and
            column (:func:`~fusion_pf.cues.roi.search_step`).
        learnt : bool
            ``background`` was learnt from the stream: threshold I_d4A with
            ``min(lower, learnt_lower)``.
        candidates : bool
            Also return every region as a candidate (``CueResult.candidates``,
            several targets: the association picks).
        parts : tuple of (float, float)
            With ``candidates``: two joined targets' predictions; a region
            holding both is two candidates (:func:`~fusion_pf.cues.regions.split_region`).
        stages : bool
            Also return the stage images I_d1 ... I_d10 (at the search's reduced
            resolution when it had one).

        Returns
        -------
        CueResult
            Measurement in full-frame pixels or None; stages; latency.
        """
        t0 = time.perf_counter_ns()
        if not isinstance(depth, np.ndarray) or depth.ndim != 2 or depth.dtype != np.uint16:
            raise InputError(f"depth must be an (H, W) uint16 array, got {getattr(depth, 'shape', depth)!r}")
        out: dict[str, np.ndarray] = {}
        if background is None:
            return CueResult(None, out, time.perf_counter_ns() - t0)
        if background.shape != depth.shape or background.dtype != np.uint16:
            raise InputError(
                f"depth background must match the depth image {depth.shape} uint16, "
                f"got {background.shape} {background.dtype}"
            )
        h, w = depth.shape
        roi = full_roi(w, h) if roi is None else roi
        if roi.empty:
            return CueResult(None, out, time.perf_counter_ns() - t0)
        step = search_step(roi) if keep_border else 1
        d1 = np.ascontiguousarray(roi.crop(depth)[::step, ::step])  # contiguous once, not at every OpenCV call
        b1 = self._search_background(background, roi, step)
        lower = min(self.lower, self.learnt_lower) if learnt else self.lower
        d2, d3, d4a, d4b, d5 = self._band(d1, b1, lower)
        far = None  # the slab's far limit (mm), with nearest_mm
        if self.nearest_mm is not None and d5.any():
            near = d1[d5 > 0]  # valid depths of the coarse region
            z0 = float(np.partition(near, near.size // 50)[near.size // 50])  # nearest surface: 2nd percentile
            lag = max(1, round(NOISE_LAG_PX / step))
            sigma = depth_noise_mm(d1, d5 > 0, lag, z0, MAX_NOISE_PIXELS if step > 1 else None)  # the noise at z0
            slab = float(np.hypot(self.nearest_mm, NOISE_SLAB_SIGMAS * sigma))  # widths add in variance
            # the nearest surface's slab: d1 <= z0 + slab, i.e. <= its floor (integer depths)
            far = math.floor(z0 + slab)
            d5 = cv2.bitwise_and(d5, d5, mask=(d1 <= far).view(np.uint8))
            d5 = open_thin(d5, self.open_radius)  # the slab's ragged noisy edge removed
        prev = self._previous(roi, (h, w), step) if self.temporal else None
        self._prev = (d5, roi, (h, w), step)  # at this search's resolution: expanded only if the next frame needs it
        if prev is None:
            d6 = np.zeros_like(d5)
        else:
            # I_d6 = |I_d5(t) - I_d5(t-1)|
            d6 = remove_small(cv2.bitwise_xor(d5, prev), self.min_area // (step * step))
        moved = bool(cv2.countNonZero(d6))
        # nothing moved: I_d7 and I_d8 are as empty as I_d6 (and I_d9 does not read them)
        d7 = fill_holes(d6) if moved else d6  # I_d7 = filling
        d8 = dilate(d7, self.dilate) if moved else d6  # I_d8 = dilation
        d9 = fill_holes(keep_marked(d5, d8) if moved else d5)  # I_d9: regions of I_d5 that moved, holes filled
        d10 = clear_border(d9) if self.clear_border and not keep_border else d9  # I_d10 = border cleared
        extras = {"roi": roi.as_list(), "moved": moved, "search_step": step}
        m, found = window_regions(
            d10,
            roi,
            self.source,
            min_area=self.min_area,
            extras=extras,
            step=step,
            candidates=candidates,
            parts=parts,
        )
        if m is not None and step > 1 and not candidates:
            m = self._refine(depth, background, m, d10, roi, step, far, lower)
        if stages:
            out = {
                "I_d1": d1 if step > 1 else d1.copy(),
                "I_d2": d2,
                "I_d3": d3,
                "I_d4A": d4a,
                "I_d4B": d4b,
                "I_d5": d5,
                "I_d6": d6,
                "I_d7": d7,
                "I_d8": d8,
                "I_d9": d9,
                "I_d10": d10,
            }
        return CueResult(m, out, time.perf_counter_ns() - t0, found)
