"""Stage contact sheets: every stage image of one cue as labelled tiles (paper 003 Figs. 6-7)."""

from __future__ import annotations

from collections.abc import Mapping

import cv2
import numpy as np

_LABEL_H = 22
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def to_display(image: np.ndarray, *, equalize: bool = False) -> np.ndarray:
    """An RGB uint8 rendering of a stage image.

    uint16 images (depth, mm) are scaled to their own 0-max range; with
    ``equalize`` single-channel images are histogram-equalised (as the paper
    shows its first four depth stages, Fig. 7); binary and colour images are
    shown as they are.
    """
    a = image
    if a.dtype == np.uint16:
        top = int(a.max())
        a = (a.astype(np.float32) * (255.0 / top)).astype(np.uint8) if top > 0 else np.zeros(a.shape, np.uint8)
    elif a.dtype == np.bool_:
        a = a.astype(np.uint8) * 255
    elif a.dtype != np.uint8:
        a = np.clip(a, 0, 255).astype(np.uint8)
    if a.ndim == 2:
        if equalize and a.size:
            a = cv2.equalizeHist(a)
        a = cv2.cvtColor(a, cv2.COLOR_GRAY2RGB)
    return a


def contact_sheet(
    stages: Mapping[str, np.ndarray],
    *,
    title: str = "",
    columns: int = 4,
    tile: int = 200,
    equalize: tuple[str, ...] = (),
    point: tuple[float, float] | None = None,
) -> np.ndarray:
    """Lay out stage images as labelled tiles; returns an RGB uint8 image.

    Parameters
    ----------
    stages : mapping of name to ndarray
        Stage images in display order (e.g. a :class:`CueResult`'s ``stages``).
    title : str
        Text on the top bar.
    columns : int
        Tiles per row.
    tile : int
        Tile edge in pixels; each image is scaled (nearest neighbour) to fit.
    equalize : tuple of str
        Stage names shown histogram-equalised.
    point : (float, float), optional
        Measurement in window pixels, drawn as a red cross on every tile.
    """
    names = list(stages)
    rows = max(1, -(-len(names) // columns))
    sheet = np.full((_LABEL_H + rows * (tile + _LABEL_H), columns * tile, 3), 255, np.uint8)
    cv2.putText(sheet, title, (4, _LABEL_H - 6), _FONT, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    for i, name in enumerate(names):
        img = to_display(stages[name], equalize=name in equalize)
        r, c = divmod(i, columns)
        y, x = _LABEL_H + r * (tile + _LABEL_H), c * tile
        h, w = img.shape[:2]
        if h and w:
            s = tile / max(h, w)
            img = cv2.resize(img, (max(1, int(w * s)), max(1, int(h * s))), interpolation=cv2.INTER_NEAREST)
            if point is not None:
                pu, pv = int(round((point[0] + 0.5) * s - 0.5)), int(round((point[1] + 0.5) * s - 0.5))
                cv2.drawMarker(img, (pu, pv), (255, 0, 0), cv2.MARKER_CROSS, max(6, tile // 12), 2)
            sheet[y + _LABEL_H : y + _LABEL_H + img.shape[0], x : x + img.shape[1]] = img
        label = f"{name} {stages[name].shape} {stages[name].dtype}"
        cv2.putText(sheet, label, (x + 3, y + _LABEL_H - 6), _FONT, 0.4, (0, 0, 120), 1, cv2.LINE_AA)
    return sheet
