"""Whole-frame skin blobs: every skin region of a frame as a measurement (multi-target tracking).

The single-target :class:`~fusion_pf.cues.skin.SkinCue` keeps the largest region
of a window; with several targets (both hands and the face, papers 000 and 002)
every region is a candidate that :func:`fusion_pf.filter.multi.associate` gives
to the nearest target prediction. The region steps are the skin cue's: the
model's mask, small regions removed, holes filled, dilation.
"""

from __future__ import annotations

import cv2
import numpy as np

from .base import Measurement
from .regions import dilate, fill_holes, remove_small
from .skin import SkinCue, _check_rgb

__all__ = ["skin_blobs"]


def skin_blobs(color: np.ndarray, cue: SkinCue, *, max_blobs: int = 8) -> list[Measurement]:
    """All skin regions of ``color`` of at least ``cue.min_area`` px, largest first.

    Parameters
    ----------
    color : ndarray, shape (H, W, 3), uint8
        RGB frame.
    cue : SkinCue
        Supplies the skin model, ``min_area``, ``dilate`` and the source name.
    max_blobs : int
        At most this many (the largest) regions are returned.

    Returns
    -------
    list of Measurement
        Centroid of each region (``source = cue.source``), ``quality`` the
        region's area over the largest region's, ``extras["area"]`` in px.
    """
    _check_rgb("colour", color)
    mask = dilate(fill_holes(remove_small(cue.model.mask(color, color), cue.min_area)), cue.dilate)
    n, _, stats, centroids = cv2.connectedComponentsWithStats(mask, connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:
        return []
    areas = stats[1:, cv2.CC_STAT_AREA]
    order = np.argsort(areas)[::-1][:max_blobs]
    top = float(areas[order[0]])
    return [
        Measurement(
            cue.source,
            float(centroids[i + 1, 0]),
            float(centroids[i + 1, 1]),
            quality=float(areas[i]) / top,
            extras={"area": int(areas[i])},
        )
        for i in order
        if areas[i] >= max(cue.min_area, 1)
    ]
