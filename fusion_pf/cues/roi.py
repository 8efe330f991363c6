"""Region of interest around a prior palm position (paper 003 §3.5.1, §4.2-4.3).

The paper processes 141 x 141 windows around the hand. Here the window is
centred on a prior (the skeleton hand joint or the filter's prediction) and,
when the depth of the prior is known, sized so it always covers the same
physical extent: ``half = extent_mm * fx / z`` pixels. Without depth a fixed
half-size is used (70 px = the paper's 141 x 141). The window is clipped to the
frame; a prior outside the frame or not finite gives an empty window, on which
every cue returns None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from .regions import DEFAULT_PALM_AREA, check_float, check_int

#: Half-size in pixels of the paper's 141 x 141 window.
PAPER_HALF_SIZE = 70
#: A whole-frame search (acquisition) runs the region cues on about this many pixels (640 x 360):
#: larger windows are searched on every k-th row and column (:func:`search_step`).
SEARCH_PIXELS = 640 * 360


def search_step(roi: "Roi") -> int:
    """Pixel step of a whole-frame search in ``roi``: ``round(sqrt(pixels / SEARCH_PIXELS))``, at least 1.

    1 up to about 900 x 500 (the paper's frames and the sample), 2 for 960 x 540 to 1280 x 720,
    3 for 1920 x 1080: the search then costs about the same whatever the camera.
    """
    h, w = roi.shape
    return max(1, round(math.sqrt(h * w / SEARCH_PIXELS)))


@dataclass(frozen=True, slots=True)
class Roi:
    """A rectangular window ``[x0, x1) x [y0, y1)`` of the frame, clipped to it.

    Attributes
    ----------
    x0, y0, x1, y1 : int
        Column and row bounds in full-frame pixels (``x1``, ``y1`` exclusive).
    palm_area : float
        Expected palm area in pixels at the prior's depth (used by the quality
        score).
    """

    x0: int
    y0: int
    x1: int
    y1: int
    palm_area: float = DEFAULT_PALM_AREA

    @property
    def empty(self) -> bool:
        """True when the window holds no pixel."""
        return self.x1 <= self.x0 or self.y1 <= self.y0

    @property
    def slices(self) -> tuple[slice, slice]:
        """``(rows, cols)`` slices that crop an image to the window."""
        return slice(self.y0, self.y1), slice(self.x0, self.x1)

    @property
    def offset(self) -> tuple[int, int]:
        """``(x0, y0)``: add to window pixels to get full-frame pixels."""
        return self.x0, self.y0

    @property
    def shape(self) -> tuple[int, int]:
        """``(height, width)`` of the window."""
        return max(0, self.y1 - self.y0), max(0, self.x1 - self.x0)

    def crop(self, image: np.ndarray) -> np.ndarray:
        """The window of ``image`` (a view)."""
        return image[self.slices]

    def as_list(self) -> list[int]:
        """``[x0, y0, x1, y1]`` (JSON-friendly)."""
        return [self.x0, self.y0, self.x1, self.y1]


def full_roi(width: int, height: int, *, palm_area: float = DEFAULT_PALM_AREA) -> Roi:
    """The window covering the whole ``width`` x ``height`` frame."""
    return Roi(0, 0, int(width), int(height), palm_area)


def make_roi(
    u: float,
    v: float,
    size: tuple[int, int],
    *,
    depth_mm: float | None = None,
    fx: float | None = None,
    half_size: int | None = None,
    extent_mm: float = 250.0,
    palm_radius_mm: float = 55.0,
    min_half: int = 8,
    pixel_scale: float = 1.0,
) -> Roi:
    """The window around the prior ``(u, v)`` in a frame of ``size = (width, height)``.

    Parameters
    ----------
    u, v : float
        Prior palm position, full-frame pixels.
    size : (int, int)
        Frame ``(width, height)``.
    depth_mm, fx : float, optional
        Depth of the prior and focal length (px); when both are given and
        ``half_size`` is None, ``half = extent_mm * fx / depth_mm`` so the window
        spans ``2 * extent_mm`` at the hand, and the expected palm area is
        ``pi * (palm_radius_mm * fx / depth_mm) ** 2``.
    half_size : int, optional
        Fixed half-size in pixels (window ``2 * half + 1``); overrides depth.
    extent_mm : float
        Physical half-size of the window (10-2000 mm). The default 250 mm
        (~100 px at 1.25 m with fx = 499) keeps the palm inside the window
        while the synthetic skeleton's occlusion bias (24-56 px) lasts.
    palm_radius_mm : float
        Radius of the disc with the area of a palm seen face-on (5-200 mm;
        55 mm ~ a 100 x 120 mm palm ellipse), for the expected palm area.
    min_half : int
        Smallest half-size in pixels (1-1000).
    pixel_scale : float
        Without depth: the fixed half-size and the expected palm area scale
        with it (``PAPER_HALF_SIZE * s``, ``DEFAULT_PALM_AREA * s^2``): the
        pipeline passes the image diagonal over that of 320 x 200, so a hand
        filling the same fraction of the frame gets the same window.

    Returns
    -------
    Roi
        Clipped to the frame; empty when the prior is outside the frame or not
        finite.
    """
    w = check_int("frame width", size[0], 1, 1 << 20)
    h = check_int("frame height", size[1], 1, 1 << 20)
    extent_mm = check_float("extent_mm", extent_mm, 10.0, 2000.0)
    palm_radius_mm = check_float("palm_radius_mm", palm_radius_mm, 5.0, 200.0)
    min_half = check_int("min_half", min_half, 1, 1000)
    if half_size is not None:
        half_size = check_int("half_size", half_size, 1, 1 << 20)
    try:
        uf, vf = float(u), float(v)
    except (TypeError, ValueError):
        raise InputError(f"ROI prior must be numbers, got ({u!r}, {v!r})") from None
    pixel_scale = check_float("pixel_scale", pixel_scale, 0.01, 100.0)
    palm_area = DEFAULT_PALM_AREA * pixel_scale**2
    scale = None
    if depth_mm is not None and fx is not None:
        z, f = float(depth_mm), float(fx)
        if math.isfinite(z) and math.isfinite(f) and z > 0 and f > 0:
            scale = f / z  # pixels per millimetre at the prior's depth
            palm_area = math.pi * (palm_radius_mm * scale) ** 2  # expected palm disc in px
    if half_size is not None:
        half = half_size
    elif scale is not None:
        half = max(min_half, int(round(extent_mm * scale)))  # fixed physical size: k * fx / z
    else:
        half = max(min_half, int(round(PAPER_HALF_SIZE * pixel_scale)))
    if not (math.isfinite(uf) and math.isfinite(vf)) or not (-0.5 <= uf < w - 0.5 and -0.5 <= vf < h - 0.5):
        return Roi(0, 0, 0, 0, palm_area)
    cu, cv_ = int(round(uf)), int(round(vf))
    x0, x1 = max(0, cu - half), min(w, cu + half + 1)
    y0, y1 = max(0, cv_ - half), min(h, cv_ + half + 1)
    return Roi(x0, y0, x1, y1, palm_area)
