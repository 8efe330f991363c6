"""Region of interest around a prior palm position (paper 003 §3.5.1, §4.2-4.3).

The paper processes 141 x 141 windows around the hand. Here the window is
centred on a prior (the skeleton hand joint or the filter's prediction) and,
when the palm's apparent length ``l`` is known (measured by the hand cue, or
``fx * 95 mm / z`` at the prior's depth), sized in palm lengths: ``half =
palms * l`` pixels, at most half the image's shorter side (a hand close to the
camera does not get the whole frame). Without either a fixed half-size is used
(70 px = the paper's 141 x 141). The window is clipped to the frame; a prior
outside the frame or not finite gives an empty window, on which every cue
returns None.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import InputError
from .regions import DEFAULT_PALM_AREA, check_float, check_int

#: Half-size in pixels of the paper's 141 x 141 window.
PAPER_HALF_SIZE = 70
#: Palm length (wrist to middle-finger base) of an adult hand, mm: turns depth into an apparent palm size.
PALM_LENGTH_MM = 95.0

#: A whole-frame search (acquisition) runs the region cues on about this many pixels (500 x 280):
#: larger windows are searched on every k-th row and column (:func:`search_step`).
SEARCH_PIXELS = 500 * 280


def search_step(roi: "Roi") -> int:
    """Pixel step of a whole-frame search in ``roi``: ``round(sqrt(pixels / SEARCH_PIXELS))``, at least 1.

    1 up to 640 x 480 (the sample, VGA cameras), 2 for 960 x 540,
    3 for 1280 x 720, 4 for 1920 x 1080: the search then costs about the same whatever the camera.
    At 1280 x 720 (a synthetic RGB-D scene, colour + depth cues) step 3 instead of 2 halves the
    search's CPU time (8.8 -> 4.6 ms median), the depth cue's whole-frame palm moving 1.2 -> 2.1 px
    (median over 80 frames; RMSE 9.3 -> 9.0 px).
    """
    h, w = roi.shape
    return max(1, round(math.sqrt(h * w / SEARCH_PIXELS)))


def subsample(image: np.ndarray, step: int) -> np.ndarray:
    """``image[::step, ::step]`` as a new contiguous array (a search at :func:`search_step`).

    A colour image ``(H, W, 3)`` goes through OpenCV's nearest-neighbour resize by ``1 / step``
    wherever that gives the same array (its size rounds, ``[::step]`` takes the ceiling: then the
    strided copy): numpy copies three interleaved channels pixel by pixel, 0.34 ms for a
    1280 x 720 frame at step 3 against 0.09 ms. A single-channel image is copied by numpy (faster
    there than OpenCV).
    """
    h, w = image.shape[:2]
    if image.ndim == 3 and step > 1 and min(h, w) >= step:
        out = cv2.resize(image, None, fx=1 / step, fy=1 / step, interpolation=cv2.INTER_NEAREST)
        if out.shape[:2] == (-(-h // step), -(-w // step)):
            return out
    return np.ascontiguousarray(image[::step, ::step])


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


def _positive(x: float | None) -> float | None:
    """``x`` as a float when it is a finite number > 0, else None."""
    return None if x is None or not (math.isfinite(float(x)) and float(x) > 0) else float(x)


def make_roi(
    u: float,
    v: float,
    size: tuple[int, int],
    *,
    palm_px: float | None = None,
    depth_mm: float | None = None,
    fx: float | None = None,
    half_size: int | None = None,
    palms: float = 2.6,
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
    palm_px : float, optional
        Apparent palm length (wrist to middle-finger base) in pixels, e.g.
        measured by the hand cue; else derived from ``depth_mm`` and ``fx``:
        ``fx * PALM_LENGTH_MM / depth_mm``.
    depth_mm, fx : float, optional
        Depth of the prior and focal length (px), for the palm length when
        ``palm_px`` is not given.
    half_size : int, optional
        Fixed half-size in pixels (window ``2 * half + 1``); overrides the palm.
    palms : float
        Half-size in palm lengths when the palm length is known (0.5-20):
        ``half = palms * palm_px``, at most half the image's shorter side. The
        default 2.6 (247 mm at the hand, ~100 px at 1.25 m with fx = 499) keeps
        the palm inside the window while the synthetic skeleton's occlusion
        bias (24-56 px) lasts.
    palm_radius_mm : float
        Radius of the disc with the area of a palm seen face-on (5-200 mm;
        55 mm ~ a 100 x 120 mm palm ellipse), for the expected palm area
        ``pi * (palm_radius_mm / PALM_LENGTH_MM * palm_px) ** 2``.
    min_half : int
        Smallest half-size in pixels (1-1000).
    pixel_scale : float
        Without a palm length: the fixed half-size and the expected palm area
        scale with it (``PAPER_HALF_SIZE * s``, ``DEFAULT_PALM_AREA * s^2``): the
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
    palms = check_float("palms", palms, 0.5, 20.0)
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
    length = _positive(palm_px)
    z, f = _positive(depth_mm), _positive(fx)
    if length is None and z is not None and f is not None:
        length = f * PALM_LENGTH_MM / z  # l_px = fx L_mm / z
    if length is not None:
        palm_area = math.pi * (palm_radius_mm / PALM_LENGTH_MM * length) ** 2  # expected palm disc in px
    if half_size is not None:
        half = half_size
    elif length is not None:
        half = max(min_half, min(int(round(palms * length)), min(w, h) // 2))  # palm lengths, inside the image
    else:
        half = max(min_half, int(round(PAPER_HALF_SIZE * pixel_scale)))
    if not (math.isfinite(uf) and math.isfinite(vf)) or not (-0.5 <= uf < w - 0.5 and -0.5 <= vf < h - 0.5):
        return Roi(0, 0, 0, 0, palm_area)
    cu, cv_ = int(round(uf)), int(round(vf))
    x0, x1 = max(0, cu - half), min(w, cu + half + 1)
    y0, y1 = max(0, cv_ - half), min(h, cv_ + half + 1)
    return Roi(x0, y0, x1, y1, palm_area)
