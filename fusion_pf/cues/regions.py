"""Binary-region operations shared by every image cue (paper 003 §3.5.1-3.5.2).

One implementation of each morphological step of Figures 3-4, used by the
colour, depth and skin cues alike. Masks are ``uint8`` arrays holding 0 and 255
(the paper's 1-bit images, in the form OpenCV works on fastest); connectivity
is 8 everywhere. Every function is vectorised (OpenCV connected components and
look-up tables), accepts empty or tiny masks and never returns NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError

#: Expected palm area in pixels when no depth-derived value is known
#: (a ~30 px-diameter palm: 90 mm at ~1.2 m with fx ~ 400 px).
DEFAULT_PALM_AREA = 700.0
#: Smallest region (px) the cues keep by default (colour, depth and skin).
MIN_AREA_PX = 40
#: A region's position is the centroid of its core: the pixels at least this fraction of the region's
#: largest distance to its outline inside it (:func:`core_centre`). The palm is the widest part of a
#: hand-and-forearm region (the synthetic palm 10 cm wide, the forearm 6.8 cm: 0.68 of it), so the
#: core lies on the palm whatever length of forearm the region holds.
CORE_FRACTION = 0.7


def check_int(name: str, value: object, lo: int, hi: int) -> int:
    """Return ``value`` as an int in ``[lo, hi]`` or raise a one-line InputError."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise InputError(f"{name} must be an int in [{lo}, {hi}], got {value!r}")
    return int(value)


def check_float(name: str, value: object, lo: float, hi: float) -> float:
    """Return ``value`` as a finite float in ``[lo, hi]`` or raise a one-line InputError."""
    try:
        f = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number in [{lo}, {hi}], got {value!r}") from None
    if isinstance(value, bool) or not math.isfinite(f) or not lo <= f <= hi:
        raise InputError(f"{name} must be a number in [{lo}, {hi}], got {value!r}")
    return f


def _labels(mask: np.ndarray) -> tuple[int, np.ndarray]:
    n, labels = cv2.connectedComponents(mask, connectivity=8, ltype=cv2.CV_32S)
    return n, labels


def _components(mask: np.ndarray) -> tuple[int, np.ndarray, np.ndarray, np.ndarray, tuple[int, int]]:
    """``connectedComponentsWithStats`` (8-connected) of ``mask``'s non-empty bounding box.

    Its statistics pass visits every pixel of the image it is given: a palm in a whole-frame
    search (427 x 240 at 1280 x 720) cost 0.56 ms, its bounding box 0.05 ms. Returns the number
    of labels, the box's labels, the stats and centroids in ``mask``'s coordinates (label 0's
    are the box's background) and the box's corner ``(x, y)``; the labels are numbered in the
    same raster order as on the whole mask.
    """
    x, y, w, h = cv2.boundingRect(mask)
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(
        mask[y : y + h, x : x + w], connectivity=8, ltype=cv2.CV_32S
    )
    stats[:, cv2.CC_STAT_LEFT] += x
    stats[:, cv2.CC_STAT_TOP] += y
    centroids += (x, y)
    return n, labels, stats, centroids, (x, y)


def _paint(labels: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """The mask of the labels where the boolean table ``keep`` is True (255) as one look-up-table gather."""
    lut = np.where(keep, np.uint8(255), np.uint8(0))
    return lut.take(labels)


def _touching_border(labels: np.ndarray, n: int) -> np.ndarray:
    """Boolean table over labels: True for labels with a pixel on the image border."""
    touch = np.zeros(n, dtype=bool)
    touch[labels[0, :]] = True
    touch[labels[-1, :]] = True
    touch[labels[:, 0]] = True
    touch[labels[:, -1]] = True
    return touch


def remove_small(mask: np.ndarray, min_area: int) -> np.ndarray:
    """Remove the connected regions smaller than ``min_area`` pixels (``bwareaopen``).

    Paper 003 Fig. 3 I_C5 -> I_C6 ("the unwanted small regions are eliminated").
    """
    if mask.size == 0 or min_area <= 1 or not cv2.countNonZero(mask):
        return mask.copy()
    n, labels = _labels(mask)  # (connectedComponentsWithStats costs 3x more; only the areas are needed)
    keep = np.bincount(labels.ravel(), minlength=n) >= min_area  # region kept when its area reaches min_area
    keep[0] = False  # label 0 is the background
    return _paint(labels, keep)


def open_thin(mask: np.ndarray, radius: int) -> np.ndarray:
    """Morphological opening with a ``(2 radius + 1)`` square: removes structures thinner than that.

    Part of our reading of paper 003 Fig. 3 I_C6: the blurred outlines of the
    subject's clothing survive both thresholds as 1-2 px lines that can join the
    hand to the window border; the opening removes them. 0 = no-op.
    """
    if mask.size == 0 or radius <= 0:
        return mask.copy()
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.morphologyEx(mask, cv2.MORPH_OPEN, kernel)


def keep_marked(mask: np.ndarray, marker: np.ndarray) -> np.ndarray:
    """The regions of ``mask`` that share at least one pixel with ``marker`` (reconstruction)."""
    if mask.size == 0 or not cv2.countNonZero(mask):
        return mask.copy()
    n, labels = _labels(mask)
    keep = np.zeros(n, dtype=bool)
    keep[labels[marker > 0]] = True  # every region the marker touches
    keep[0] = False
    return _paint(labels, keep)


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """Fill the holes of every region (``imfill(..., 'holes')``).

    Paper 003 Fig. 3 I_C7, Fig. 4 I_d7. A hole is a connected zero region that
    does not touch the image border.
    """
    if mask.size == 0 or not cv2.countNonZero(mask):
        return mask.copy()
    h, w = mask.shape
    outside = np.zeros((h + 2, w + 2), np.uint8)
    outside[1:-1, 1:-1] = mask
    cv2.floodFill(outside, None, (0, 0), 255)  # the zeros reachable from the border
    return cv2.bitwise_or(mask, cv2.bitwise_not(outside[1:-1, 1:-1]))  # mask OR the enclosed zeros


def dilate(mask: np.ndarray, radius: int) -> np.ndarray:
    """Dilate with a disc of ``radius`` pixels (Fig. 3 I_C8, Fig. 4 I_d8); 0 = no-op."""
    if mask.size == 0 or radius <= 0:
        return mask.copy()
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.dilate(mask, kernel)


def clear_border(mask: np.ndarray) -> np.ndarray:
    """Remove the regions touching the window border (``imclearborder``).

    Paper 003 Fig. 3 I_C9, Fig. 4 I_d10: the pixels "around the borders of the
    region of interest" left by the morphological steps are eliminated.
    """
    if mask.size == 0 or not cv2.countNonZero(mask):
        return mask.copy()
    n, labels = _labels(mask)
    drop = _touching_border(labels, n)  # regions with a pixel on the border
    drop[0] = True
    return _paint(labels, ~drop)


def core_centre(mask: np.ndarray) -> tuple[float, float, float]:
    """The centroid ``(u, v)`` of the core of the one region ``mask`` holds (non-zero pixels, mask coordinates), and
    the region's inscribed radius (px).

    The core is the pixels whose Euclidean distance to the nearest pixel
    outside the region (the mask's edge counts as outside) is at least
    :data:`CORE_FRACTION` of the largest such distance: the centre of the
    widest part. A palm with a length of forearm attached keeps its centre
    (the plain centroid moves toward the elbow by an amount that grows with
    the forearm's visible length, at every image size alike). The largest
    distance is the radius of the widest disc inside the region: the palm's
    half-width, whatever forearm is attached (its apparent size,
    :attr:`Region.radius`).
    """
    m = cv2.copyMakeBorder((mask > 0).astype(np.uint8), 1, 1, 1, 1, cv2.BORDER_CONSTANT, value=0)
    dist = cv2.distanceTransform(m, cv2.DIST_L2, 5)
    top = float(dist.max())
    weight = np.maximum(dist - CORE_FRACTION * top, 0.0)
    ys, xs = np.nonzero(weight)
    w = weight[ys, xs].astype(np.float64)
    total = float(w.sum())
    return float(xs @ w) / total - 1.0, float(ys @ w) / total - 1.0, top


@dataclass(frozen=True, slots=True)
class Region:
    """The largest connected region of a mask, in the mask's own pixels.

    Attributes
    ----------
    u, v : float
        Centroid (column, row).
    area : int
        Pixel count.
    bbox : tuple of int
        ``(x, y, w, h)`` bounding box.
    radius : float or None
        With a core centre (:func:`core_centre`): the largest distance of a region pixel from the outline, px.
    """

    u: float
    v: float
    area: int
    bbox: tuple[int, int, int, int]
    radius: float | None = None

    @property
    def roundness(self) -> float:
        """Area over the area of the disc spanning the longer bounding-box side, in (0, 1]."""
        side = max(self.bbox[2], self.bbox[3])
        return min(1.0, self.area / (math.pi * side * side / 4.0))


def largest_region(
    mask: np.ndarray, min_area: int = 1, near: tuple[float, float] | None = None, *, core: bool = False
) -> Region | None:
    """The largest 8-connected region and its centroid (paper 003 §3.5.1 steps i-iii).

    (i) find all regions in the window, (ii) compute their areas, (iii) take the
    centroid of the largest. Returns None when no region has ``min_area`` pixels.
    With ``near`` (a point in mask pixels), the region of at least ``min_area``
    pixels whose centroid is nearest to it is taken instead (so a face next to
    the tracked hand does not win for being larger). With ``core`` its
    position is :func:`core_centre` instead of the centroid.
    """
    if mask.size == 0 or not cv2.countNonZero(mask):
        return None
    n, labels, stats, centroids, (ox, oy) = _components(mask)
    if n <= 1:
        return None
    areas = stats[1:, cv2.CC_STAT_AREA]  # (ii) area of every region but the background
    if near is None:
        best = int(np.argmax(areas)) + 1  # (iii) the largest region is taken as the hand
    else:
        ok = areas >= max(1, min_area)
        if not ok.any():
            return None
        d2 = np.sum((centroids[1:] - np.asarray(near, dtype=np.float64)) ** 2, axis=1)  # squared distance to the prior
        best = int(np.argmin(np.where(ok, d2, np.inf))) + 1  # the qualifying region nearest the prior
    area = int(stats[best, cv2.CC_STAT_AREA])
    if area < max(1, min_area):
        return None
    x, y, w, h = (
        int(stats[best, k]) for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT)
    )
    if not core:
        return Region(float(centroids[best, 0]), float(centroids[best, 1]), area, (x, y, w, h))
    cu, cv_, radius = core_centre(labels[y - oy : y - oy + h, x - ox : x - ox + w] == best)
    return Region(cu + x, cv_ + y, area, (x, y, w, h), radius)


def region_quality(region: Region, palm_area: float) -> float:
    """Quality in [0, 1] of a region as a palm: size agreement times compactness.

    ``size = min(A / A_palm, A_palm / A)`` (1 when the area equals the expected
    palm area, falling off as its ratio in either direction) and
    ``compact`` = :attr:`Region.roundness` (1 for a filled disc or square,
    low for thin, elongated or ragged regions). The product is
    the quality; it is not a paper equation but our choice, documented here.
    """
    ratio = region.area / max(palm_area, 1.0)
    size = min(ratio, 1.0 / ratio)  # symmetric size agreement with the expected palm
    compact = region.roundness  # area / disc over the longer box side
    return float(min(1.0, max(0.0, size * compact)))


def measure(
    final: np.ndarray,
    offset: tuple[int, int],
    source: str,
    *,
    palm_area: float,
    min_area: int = 1,
    extras: dict | None = None,
    near: tuple[float, float] | None = None,
    step: int = 1,
    core: bool = False,
):
    """Turn a cue's final mask into a full-frame :class:`Measurement` (or None).

    ``near`` (full-frame pixels) picks the region nearest to it instead of the
    largest (:func:`largest_region`). The centroid is shifted by the window ``offset``
    ``(x0, y0)`` into full-frame pixels; ``quality`` is :func:`region_quality`;
    ``extras`` gets ``area`` (px), ``bbox`` (full-frame ``[x, y, w, h]``) and with ``core`` ``radius`` (px, :attr:`Region.radius`).
    ``step`` > 1: ``final`` holds every ``step``-th row and column of the window
    (a reduced whole-frame search); ``min_area`` and ``palm_area`` are full-resolution
    pixels and everything returned is in full-resolution pixels. ``core``: the
    region's :func:`core_centre` instead of its centroid.
    """
    from .base import Measurement

    x0, y0 = offset
    k2 = step * step
    near_w = None if near is None else ((near[0] - x0) / step, (near[1] - y0) / step)
    region = largest_region(final, min_area // k2, near_w, core=core)
    if region is None:
        return None
    info = dict(extras or {})
    info["area"] = region.area * k2
    bx, by, bw, bh = region.bbox
    info["bbox"] = [bx * step + x0, by * step + y0, bw * step, bh * step]
    if region.radius is not None:
        info["radius"] = region.radius * step
    return Measurement(
        source,
        region.u * step + x0,  # window centroid + ROI offset = full-frame column
        region.v * step + y0,  # window centroid + ROI offset = full-frame row
        region_quality(region, palm_area / k2),
        info,
    )


#: Iterations of the 2-means split of a shared region (:func:`split_region`).
SPLIT_ITERATIONS = 10


def two_means(points: np.ndarray, seeds: np.ndarray) -> np.ndarray | None:
    """Split ``points`` (N x D) between two means started at ``seeds`` (2 x D): 2-means (paper 000).

    Every point goes to the nearer mean, each mean moves to its points' centroid,
    :data:`SPLIT_ITERATIONS` times or until no point changes side. Returns which
    points are the first mean's (N booleans), None when one side is empty.
    """
    pts = np.asarray(points, dtype=np.float64)
    total = pts.sum(axis=0)
    means = np.asarray(seeds, dtype=np.float64).copy()
    near = np.zeros(len(pts), dtype=bool)
    for k in range(SPLIT_ITERATIONS):
        # nearer the first mean: |p - m0|^2 <= |p - m1|^2, i.e. p . (m1 - m0) <= (|m1|^2 - |m0|^2) / 2
        new = pts @ (means[1] - means[0]) <= (means[1] @ means[1] - means[0] @ means[0]) / 2.0
        if new.all() or not new.any():
            return None
        if k and np.array_equal(new, near):
            break  # converged: the means would not move again
        near = new
        count = int(near.sum())
        first = near.astype(np.float64) @ pts
        means = np.array([first / count, (total - first) / (len(pts) - count)])
    return near


def split_region(mask: np.ndarray, seeds: np.ndarray, *, core: bool = False) -> list[Region] | None:
    """Split the pixels of ``mask`` between two targets: 2-means over their positions (paper 000, :func:`two_means`).

    ``seeds`` (2 x 2, mask pixels) start the two means (two joined palms seen as one region give one part each). Returns
    the two parts in seed order, None when one is empty. With ``core`` a part's
    position is its :func:`core_centre` (a part holds its hand's forearm too).
    """
    ys, xs = np.nonzero(mask)
    pts = np.stack([xs, ys], axis=1).astype(np.float64)
    near = two_means(pts, seeds)
    if near is None:
        return None
    out = []
    for part in (near, ~near):
        p = pts[part]
        lo, hi = p.min(axis=0), p.max(axis=0)
        box = (int(lo[0]), int(lo[1]), int(hi[0] - lo[0]) + 1, int(hi[1] - lo[1]) + 1)
        if core:
            m = np.zeros(mask.shape, np.uint8)
            m[ys[part], xs[part]] = 1
            u, v, _ = core_centre(m)
        else:
            u, v = float(p[:, 0].mean()), float(p[:, 1].mean())
        out.append(Region(u, v, int(part.sum()), box))
    return out


def region_detections(
    final: np.ndarray,
    offset: tuple[int, int],
    source: str,
    *,
    palm_area: float,
    min_area: int = 1,
    extras: dict | None = None,
    max_regions: int = 8,
    step: int = 1,
    parts: tuple[tuple[float, float], ...] = (),
    core: bool = False,
) -> tuple:
    """Every region of ``final`` of at least ``min_area`` px as a full-frame :class:`Detection`, largest first.

    The same centroid, quality and extras as :func:`measure` gives its one
    region (``step`` as there); at most ``max_regions`` (the largest) are returned.
    A region whose box holds both of the two points ``parts`` (full-frame px:
    two joined targets' predictions) is given as its two parts instead
    (:func:`split_region`; extras ``part`` 0 or 1, the point it began at).
    ``core`` as in :func:`measure`.
    """
    from ..association.base import Detection
    from .base import Measurement

    if final.size == 0 or not cv2.countNonZero(final):
        return ()
    n, labels, stats, centroids, (ox, oy) = _components(final)
    areas = stats[1:, cv2.CC_STAT_AREA]
    x0, y0 = offset
    k2 = step * step
    seeds = None if len(parts) != 2 else (np.asarray(parts, dtype=np.float64) - (x0, y0)) / step
    out = []
    for i in np.argsort(-areas, kind="stable")[:max_regions]:
        area = int(areas[i])
        if area < max(1, min_area // k2):
            break
        x, y, w, h = (
            int(stats[i + 1, k]) for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP, cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT)
        )
        if core:
            cu, cv_, radius = core_centre(labels[y - oy : y - oy + h, x - ox : x - ox + w] == i + 1)
            region = Region(cu + x, cv_ + y, area, (x, y, w, h), radius)
        else:
            region = Region(float(centroids[i + 1, 0]), float(centroids[i + 1, 1]), area, (x, y, w, h))
        pieces: list[tuple[Region, dict]] = [(region, {})]
        if seeds is not None and all(x <= a <= x + w and y <= b <= y + h for a, b in seeds):
            split = split_region(labels[y - oy : y - oy + h, x - ox : x - ox + w] == i + 1, seeds - (x, y), core=core)
            if split is not None:
                pieces = [
                    (
                        Region(r.u + x, r.v + y, r.area, (r.bbox[0] + x, r.bbox[1] + y, r.bbox[2], r.bbox[3])),
                        {"part": k},
                    )
                    for k, r in enumerate(split)
                ]
        for r, tag in pieces:
            bx, by, bw, bh = r.bbox
            info = {
                **(extras or {}),
                "area": r.area * k2,
                "bbox": [bx * step + x0, by * step + y0, bw * step, bh * step],
                **({} if r.radius is None else {"radius": r.radius * step}),
                **tag,
            }
            m = Measurement(source, r.u * step + x0, r.v * step + y0, region_quality(r, palm_area / k2), info)
            out.append(Detection(m))
    return tuple(out)


def window_regions(
    final: np.ndarray,
    roi,
    source: str,
    *,
    min_area: int,
    extras: dict,
    step: int,
    candidates: bool,
    parts: tuple[tuple[float, float], ...] = (),
    core: bool = False,
):
    """A region cue's answer in ``roi``: ``(measurement, candidates)``.

    The measurement is :func:`measure`'s (the largest region); with
    ``candidates`` every region is also a :class:`Detection` (:func:`region_detections`,
    several targets: the association picks; ``parts`` as there) and the
    measurement is the first of them. ``core`` as in :func:`measure`.
    """
    kw = {"palm_area": roi.palm_area, "min_area": min_area, "extras": extras, "step": step, "core": core}
    if not candidates:
        return measure(final, roi.offset, source, **kw), ()
    found = region_detections(final, roi.offset, source, parts=parts, **kw)
    return (found[0].measurement if found else None), found
