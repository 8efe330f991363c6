"""Import a folder of colour images and/or depth images (datasets, exported frames).

Layouts understood
------------------
* ``SRC/color/`` (or ``colour``, ``rgb``, ``image``, ``images``) and ``SRC/depth/`` sub-folders;
* one folder whose file names say what they hold (``0001_color.png`` / ``0001_depth.png``,
  ``frame-000000.color.png`` / ``frame-000000.depth.png``);
* one folder of unlabelled images: 16-bit single-channel images are depth, the others colour.

Colour and depth are paired by file name once the ``color``/``depth`` word is removed
(``0001_color.png`` with ``0001_depth.png``), otherwise, when both lists are equally long, by
their natural sort order (``2.png`` before ``10.png``). Depth images hold counts of
``depth_unit`` (``"1mm"`` by default; ``"0.125mm"`` for an Intel SR300/SR305, ``"0.2mm"``
for TUM RGB-D) and must be registered to colour already (same size). A folder with depth
images only gets a grey colour image rendered from the depth (near = bright, 32-255; 0 = no
depth), said so in
:attr:`ImportSource.report`. Frames are ``1 / fps`` apart.

An image that cannot be read (damaged, truncated, not an image) does not stop the folder:
a frame whose colour image is unreadable is skipped and counted in ``stats.losses`` (the
other frames keep their times and ``Frame.index``, so the gap shows), one whose depth image
is unreadable is kept without depth and counted in ``stats.skipped_parts``.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame

from ..base import FrameLoss
from .base import ImportSource, IntrinsicsOption, frame_of, parse_depth_unit, to_millimetres

#: File extensions read as images.
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm")
_COLOR_WORDS = ("color", "colour", "rgb", "image", "images", "img")
_DEPTH_WORDS = ("depth", "depths")
_WORD_RE = re.compile(r"(?:^|(?<=[^a-z]))(colou?r|rgb|images?|img|depths?)(?=[^a-z]|$)", re.IGNORECASE)


def natural_key(name: str) -> tuple:
    """Sort key ordering ``"2.png"`` before ``"10.png"``."""
    return tuple(int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", name))


def _kind_word(stem: str) -> str | None:
    words = {m.group(1).lower() for m in _WORD_RE.finditer(stem)}
    if words & set(_DEPTH_WORDS):
        return "depth"
    if words & set(_COLOR_WORDS):
        return "color"
    return None


def _pair_key(stem: str) -> str:
    return re.sub(r"^[._\- ]+|[._\- ]+$", "", _WORD_RE.sub("", stem)).lower()


def _images(folder: Path) -> list[Path]:
    return sorted(
        (p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS),
        key=lambda p: natural_key(p.name),
    )


def _image_size(path: Path) -> tuple[int, int]:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.size
    except (UnidentifiedImageError, OSError) as exc:
        raise InputError(f"{path} is not a readable image ({exc})") from None


def _is_depth_image(path: Path) -> bool | None:
    """Whether ``path`` holds a 16-bit or float single-channel image; None when it cannot be read."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return im.mode in ("I;16", "I;16B", "I;16L", "I", "F")
    except (UnidentifiedImageError, OSError):
        return None


def _read(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise InputError(f"{path} cannot be decoded as an image")
    return image


class ImageFolderSource(ImportSource):
    """Frames from a folder of colour and/or depth images.

    Parameters
    ----------
    path : str or Path
        The folder.
    depth_unit : str
        Length of one depth count (:func:`~drivers.importers.base.parse_depth_unit`).
    fps : float
        Frame rate giving the timestamps (frame ``i`` at ``i / fps`` s).
    intrinsics : IntrinsicsOption, optional
        Where the colour intrinsics come from (default: a 60 deg field of view).
    """

    kind = "folder"

    def __init__(
        self,
        path: str | Path,
        *,
        depth_unit: str = "1mm",
        fps: float = 30.0,
        intrinsics: IntrinsicsOption | None = None,
    ) -> None:
        super().__init__(path)
        self.mm_per_count = parse_depth_unit(depth_unit)
        self.depth_unit = depth_unit
        if not fps > 0:
            raise InputError(f"fps must be > 0, got {fps}")
        self.fps = float(fps)
        self.intrinsics_option = intrinsics or IntrinsicsOption()
        self.pairs: list[tuple[Path | None, Path | None]] = []
        self._intrinsics = None
        self._grey_range: tuple[float, float] | None = None

    # ------------------------------------------------------------------ layout

    def _find(self) -> tuple[list[Path], list[Path]]:
        folder = self.path
        if not folder.is_dir():
            raise InputError(f"{folder} is not a folder")
        subdirs = {p.name.lower(): p for p in folder.iterdir() if p.is_dir()}
        color_dir = next((subdirs[w] for w in _COLOR_WORDS if w in subdirs), None)
        depth_dir = next((subdirs[w] for w in _DEPTH_WORDS if w in subdirs), None)
        if color_dir is not None or depth_dir is not None:
            colors = _images(color_dir) if color_dir is not None else []
            depths = _images(depth_dir) if depth_dir is not None else []
            self.report.append(
                f"folder layout: colour from {color_dir.name + '/' if color_dir else '(none)'}, "
                f"depth from {depth_dir.name + '/' if depth_dir else '(none)'}"
            )
            return colors, depths
        files = _images(folder)
        if not files:
            found = sorted(p.name for p in folder.iterdir())[:8]
            raise InputError(
                f"{folder} holds no images ({', '.join(IMAGE_EXTENSIONS)}) and no color/ or depth/ sub-folder; "
                f"found {found or 'nothing'}"
            )
        colors, depths, unknown = [], [], []
        for p in files:
            {"color": colors, "depth": depths, None: unknown}[_kind_word(p.stem)].append(p)
        by_ext: dict[str, bool] = {}
        for p in unknown:  # the first readable image of each extension decides (a damaged one is skipped later)
            ext = p.suffix.lower()
            if ext not in by_ext:
                probe = _is_depth_image(p)
                if probe is not None:
                    by_ext[ext] = probe
        for p in unknown:
            (depths if by_ext.get(p.suffix.lower(), False) else colors).append(p)
        colors.sort(key=lambda p: natural_key(p.name))
        depths.sort(key=lambda p: natural_key(p.name))
        return colors, depths

    def _pair(self, colors: list[Path], depths: list[Path]) -> list[tuple[Path | None, Path | None]]:
        if not colors or not depths:
            return [(c, None) for c in colors] or [(None, d) for d in depths]
        dkeys = {_pair_key(p.stem): p for p in depths}
        matched = sum(_pair_key(c.stem) in dkeys for c in colors)
        if matched >= max(1, len(colors) // 2):
            pairs = [(c, dkeys.get(_pair_key(c.stem))) for c in colors]
            unpaired_depth = len(depths) - matched
            self.report.append(
                f"paired colour and depth by file name: {matched} pairs, {len(colors) - matched} colour "
                f"image(s) without depth, {unpaired_depth} depth image(s) without colour (skipped)"
            )
            return pairs
        if len(colors) == len(depths):
            self.report.append(f"paired {len(colors)} colour and depth images by sorted file name")
            return list(zip(colors, depths, strict=True))
        raise InputError(
            f"{self.path}: cannot pair {len(colors)} colour images (e.g. {colors[0].name}) with "
            f"{len(depths)} depth images (e.g. {depths[0].name}): names do not match and the counts differ"
        )

    def _check_sizes(self) -> tuple[int, int]:
        sizes: dict[tuple[int, int], list[str]] = {}
        for c, d in self.pairs:
            for p in (c, d):
                if p is not None:
                    try:
                        sizes.setdefault(_image_size(p), []).append(p.name)
                    except InputError:
                        continue  # unreadable: skipped and counted when its frame is read
        if not sizes:
            raise InputError(f"no image in {self.path} can be read (e.g. {self.pairs[0][0] or self.pairs[0][1]})")
        if len(sizes) > 1:
            found = "; ".join(f"{w}x{h}: {len(names)} (e.g. {names[0]})" for (w, h), names in sizes.items())
            raise InputError(f"images in {self.path} differ in size ({found}); expected one size for all")
        return next(iter(sizes))

    # ------------------------------------------------------------------ Source

    def open(self) -> None:
        colors, depths = self._find()
        self.pairs = self._pair(colors, depths)
        if not self.pairs:
            raise InputError(f"{self.path} holds no colour or depth images")
        width, height = self._check_sizes()
        self._intrinsics, origin = self.intrinsics_option.resolve(width, height)
        self.total = len(self.pairs)
        n_depth = sum(d is not None for _, d in self.pairs)
        self.report.append(
            f"{self.total} frames of {width}x{height} at {self.fps:g} fps, {n_depth} with depth "
            f"({self.depth_unit} per count); intrinsics {origin}"
        )
        if not colors:
            self.report.append("no colour images: colour is a grey rendering of depth (near = bright)")

    def close(self) -> None:
        self._grey_range = None

    def _grey(self, depth_mm: np.ndarray) -> np.ndarray:
        if self._grey_range is None:
            valid = depth_mm[depth_mm > 0]
            lo, hi = np.percentile(valid, [1, 99]) if valid.size else (0.0, 1.0)
            self._grey_range = (float(lo), float(max(hi, lo + 1.0)))
        lo, hi = self._grey_range
        grey = np.clip(32.0 + 223.0 * (hi - depth_mm.astype(np.float32)) / (hi - lo), 32, 255).astype(np.uint8)
        grey[depth_mm == 0] = 0
        return np.repeat(grey[:, :, None], 3, axis=2)

    def _unreadable(self, path: Path, exc: InputError, frames: int) -> None:
        """Count an image that cannot be read: its frame lost (``frames=1``) or kept without depth (0)."""
        if frames:
            self.stats.losses.append(FrameLoss(frames, str(exc)))
            self.stats.dropped += frames
            return
        if not self.stats.skipped_parts.get("depth"):
            self.stats.notes.append(f"{exc}; frames are kept without an unreadable depth")
        self.stats.skipped_parts["depth"] = self.stats.skipped_parts.get("depth", 0) + 1

    def _frames(self) -> Iterator[Frame]:
        period = 1e9 / self.fps
        for i, (c, d) in enumerate(self.pairs):
            depth = None
            if d is not None:
                try:
                    raw = _read(d, cv2.IMREAD_UNCHANGED)
                except InputError as exc:
                    self._unreadable(d, exc, 0 if c is not None else 1)
                    if c is None:
                        continue
                else:
                    if raw.ndim != 2:
                        raise InputError(f"depth image {d} has {raw.shape[2]} channels; expected one channel")
                    depth = to_millimetres(raw, self.mm_per_count)
            if c is not None:
                try:
                    color = cv2.cvtColor(_read(c, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
                except InputError as exc:
                    self._unreadable(c, exc, 1)
                    continue
            else:
                assert depth is not None  # a depth-only pair whose depth could not be read was skipped
                color = self._grey(depth)
            yield frame_of(int(round(i * period)), i, color, depth, self._intrinsics, str(c or d), index=i)
