"""Pieces every importer shares: the source base class, intrinsics, depth units, pairing, the writer loop.

An importer is a :class:`~drivers.base.Source` over a file or folder made by
another tool. It yields ordinary :class:`~fusion_pf.frame.Frame` objects
(colour RGB uint8, depth uint16 millimetres aligned to colour, colour
intrinsics, integer-ns timestamps, no skeleton), so the tracker can replay it
directly and :func:`write_recording` can turn it into a fusion-pf MCAP
recording (docs/recording-format.md).
"""

from __future__ import annotations

import json
import math
import re
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fusion_pf.errors import FusionPFError, InputError
from fusion_pf.frame import DISTORTION_MODELS, Frame, Intrinsics

from ..base import Source

#: Horizontal field of view (degrees) assumed when a source carries no intrinsics.
DEFAULT_HFOV_DEG = 60.0
#: Valid horizontal fields of view in degrees (inclusive).
HFOV_RANGE_DEG = (1.0, 179.0)

_UNIT_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0, "um": 1e-3}
_UNIT_RE = re.compile(r"^\s*(\d+(?:\.\d*)?|\.\d+)?\s*(mm|cm|m|um)\s*$")

#: Examples of ``--depth-unit`` values, for help texts and errors.
DEPTH_UNIT_EXAMPLES = "1mm, 0.1mm, 0.125mm, 0.2mm, 0.25mm, 1cm, m, 0.001m"


def parse_depth_unit(text: str) -> float:
    """Millimetres per depth count of a unit such as ``"0.125mm"``, ``"1mm"`` or ``"m"``.

    Parameters
    ----------
    text : str
        An optional positive number followed by ``um``, ``mm``, ``cm`` or ``m``.

    Returns
    -------
    float
        Millimetres per stored count (> 0).
    """
    match = _UNIT_RE.match(str(text).lower())
    if match is None:
        raise InputError(f"unknown depth unit {text!r}; expected a length such as {DEPTH_UNIT_EXAMPLES}")
    scale = float(match.group(1)) if match.group(1) else 1.0
    if not scale > 0:
        raise InputError(f"depth unit {text!r} must be a positive length")
    return scale * _UNIT_MM[match.group(2)]


def to_millimetres(depth: np.ndarray, mm_per_count: float) -> np.ndarray:
    """Convert a depth image to uint16 millimetres (0 = no depth).

    Parameters
    ----------
    depth : ndarray, shape (H, W), integer or float
        Depth in counts of ``mm_per_count`` millimetres; NaN, infinite and
        non-positive values mean no depth.
    mm_per_count : float

    Returns
    -------
    ndarray, shape (H, W), uint16
        Rounded to the millimetre; values beyond 65535 mm become 0 (no depth).
    """
    if depth.dtype == np.uint16 and mm_per_count == 1.0:
        return depth
    mm = np.rint(depth.astype(np.float64) * mm_per_count)
    valid = np.isfinite(mm) & (mm > 0) & (mm <= 65535)
    return np.where(valid, mm, 0).astype(np.uint16)


def fov_intrinsics(width: int, height: int, hfov_deg: float = DEFAULT_HFOV_DEG) -> Intrinsics:
    """Pinhole intrinsics of an undistorted ``width`` x ``height`` camera with a horizontal field of view.

    ``fx = fy = (width / 2) / tan(hfov / 2)``, principal point at the image centre
    (``((width - 1) / 2, (height - 1) / 2)``, pixel centres at integers).
    """
    lo, hi = HFOV_RANGE_DEG
    if not lo <= hfov_deg <= hi:
        raise InputError(f"field of view must be in [{lo:g}, {hi:g}] degrees, got {hfov_deg}")
    f = width / 2 / math.tan(math.radians(hfov_deg) / 2)
    return Intrinsics(width, height, f, f, (width - 1) / 2, (height - 1) / 2)


def _matrix(value: Any, where: str) -> list[float]:
    data = value.get("data") if isinstance(value, Mapping) else value
    flat = np.asarray(data, dtype=np.float64).ravel() if data is not None else np.empty(0)
    if flat.size != 9:
        raise InputError(f"{where} must hold 9 numbers (a 3x3 camera matrix), got {flat.size}")
    return flat.tolist()


def intrinsics_from_mapping(doc: Mapping[str, Any], where: str) -> Intrinsics:
    """Intrinsics from a parsed JSON/YAML document in one of the common layouts.

    Layouts
    -------
    * flat: ``width, height, fx, fy, cx, cy`` [``distortion_model``, ``distortion``];
    * ROS ``camera_info`` YAML (camera_calibration): ``image_width``, ``image_height``,
      ``camera_matrix: {data: [9]}``, ``distortion_model``, ``distortion_coefficients: {data}``;
    * Open3D ``PinholeCameraIntrinsic`` JSON: ``width``, ``height``, ``intrinsic_matrix``
      (9 numbers, column-major).
    """
    if not isinstance(doc, Mapping):
        raise InputError(f"{where} must hold a mapping of intrinsics, got {type(doc).__name__}")
    model, coeffs = str(doc.get("distortion_model", "none") or "none"), ()
    if "camera_matrix" in doc:
        k = _matrix(doc["camera_matrix"], f"{where}: camera_matrix")
        fx, fy, cx, cy = k[0], k[4], k[2], k[5]
        width, height = doc.get("image_width"), doc.get("image_height")
        dist = doc.get("distortion_coefficients")
        coeffs = tuple((dist.get("data") if isinstance(dist, Mapping) else dist) or ())
    elif "intrinsic_matrix" in doc:
        k = _matrix(doc["intrinsic_matrix"], f"{where}: intrinsic_matrix")
        fx, fy, cx, cy = k[0], k[4], k[6], k[7]
        width, height = doc.get("width"), doc.get("height")
    else:
        missing = [key for key in ("width", "height", "fx", "fy", "cx", "cy") if key not in doc]
        if missing:
            raise InputError(
                f"{where} has no {', '.join(missing)}; expected width, height, fx, fy, cx, cy "
                f"(or a ROS camera_info / Open3D intrinsic layout), found keys {sorted(doc)}"
            )
        fx, fy, cx, cy = doc["fx"], doc["fy"], doc["cx"], doc["cy"]
        width, height = doc["width"], doc["height"]
        coeffs = tuple(doc.get("distortion", doc.get("D", ())) or ())
    if model == "plumb_bob" and not any(coeffs):
        model, coeffs = "none", ()
    if model not in DISTORTION_MODELS:
        raise InputError(
            f"{where}: distortion_model {model!r} is not supported; expected one of {sorted(DISTORTION_MODELS)}"
        )
    try:
        return Intrinsics(width, height, fx, fy, cx, cy, model, coeffs)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def load_document(path: str | Path, what: str) -> Any:
    """The document of a YAML (``.yaml``/``.yml``) or JSON file; ``what`` names it in errors."""
    path = Path(path)
    text = path.read_text()
    if path.suffix.lower() in (".yaml", ".yml"):
        from ruamel.yaml import YAML, YAMLError

        try:
            return YAML(typ="safe").load(text)
        except YAMLError as exc:
            raise InputError(f"{what} {path} is not valid YAML ({' '.join(str(exc).split())})") from None
    try:
        return json.loads(text)
    except ValueError as exc:
        raise InputError(f"{what} {path} is not valid JSON ({exc})") from None


def load_intrinsics(path: str | Path) -> Intrinsics:
    """Intrinsics from a JSON or YAML file (layouts of :func:`intrinsics_from_mapping`)."""
    return intrinsics_from_mapping(load_document(path, "intrinsics file"), f"intrinsics file {path}")


@dataclass(frozen=True)
class IntrinsicsOption:
    """How the user asked for intrinsics (command-line flags or a file), None fields unset.

    Attributes
    ----------
    file : Path or None
        JSON/YAML file (:func:`load_intrinsics`).
    fx, fy, cx, cy : float or None
        Pixels; ``fy`` defaults to ``fx``, ``cx, cy`` to the image centre.
    hfov_deg : float
        Horizontal field of view used when nothing else is given.
    """

    file: Path | None = None
    fx: float | None = None
    fy: float | None = None
    cx: float | None = None
    cy: float | None = None
    hfov_deg: float = DEFAULT_HFOV_DEG

    @property
    def given(self) -> bool:
        """True when a file or a focal length was given."""
        return self.file is not None or self.fx is not None

    def resolve(self, width: int, height: int) -> tuple[Intrinsics, str]:
        """Intrinsics for a ``width`` x ``height`` image and a sentence saying where they came from."""
        if self.file is not None:
            k = load_intrinsics(self.file)
            origin = f"from {self.file}"
            if (k.width, k.height) != (width, height):
                if abs(k.width / k.height - width / height) > 1e-3:
                    raise InputError(
                        f"intrinsics file {self.file} is for {k.width}x{k.height} images, the images are "
                        f"{width}x{height} (another aspect ratio)"
                    )
                origin += f" (scaled from {k.width}x{k.height})"
                k = k.scaled(width, height)
            return k, origin
        if self.fx is not None:
            fy = self.fx if self.fy is None else self.fy
            cx = (width - 1) / 2 if self.cx is None else self.cx
            cy = (height - 1) / 2 if self.cy is None else self.cy
            return Intrinsics(width, height, self.fx, fy, cx, cy), "from --fx/--fy/--cx/--cy"
        k = fov_intrinsics(width, height, self.hfov_deg)
        return k, (
            f"assumed: {self.hfov_deg:g} deg horizontal field of view, fx = fy = {k.fx:.1f} px, "
            f"principal point at the centre (pass --intrinsics FILE or --fx/--fy/--cx/--cy for the real ones)"
        )


def pair_nearest(color_ns: np.ndarray, depth_ns: np.ndarray, tolerance_ns: int) -> np.ndarray:
    """Pair every colour time with the nearest depth time within a tolerance, one to one.

    Parameters
    ----------
    color_ns : ndarray, shape (N,), int64
        Colour timestamps, increasing.
    depth_ns : ndarray, shape (M,), int64
        Depth timestamps, increasing.
    tolerance_ns : int
        Largest accepted ``|t_color - t_depth|``.

    Returns
    -------
    ndarray, shape (N,), int64
        Index into ``depth_ns`` of the depth paired with each colour frame, -1 for
        none. A depth frame nearest to several colour frames goes to the closest.
    """
    color_ns, depth_ns = np.asarray(color_ns, np.int64), np.asarray(depth_ns, np.int64)
    out = np.full(len(color_ns), -1, np.int64)
    if not len(color_ns) or not len(depth_ns):
        return out
    right = np.clip(np.searchsorted(depth_ns, color_ns), 0, len(depth_ns) - 1)
    left = np.clip(right - 1, 0, len(depth_ns) - 1)
    take_left = np.abs(depth_ns[left] - color_ns) <= np.abs(depth_ns[right] - color_ns)
    nearest = np.where(take_left, left, right)
    gap = np.abs(depth_ns[nearest] - color_ns)
    ok = gap <= tolerance_ns
    # one to one: among colour frames claiming the same depth frame, the closest keeps it
    order = np.lexsort((gap, nearest))
    order = order[ok[order]]
    _, first = np.unique(nearest[order], return_index=True)
    keep = order[first]
    out[keep] = nearest[keep]
    return out


def frame_period_ns(timestamps_ns: np.ndarray, default_ns: int = 33_333_333) -> int:
    """Median spacing of increasing timestamps (``default_ns`` for fewer than two)."""
    t = np.asarray(timestamps_ns, np.int64)
    if len(t) < 2:
        return default_ns
    return max(int(np.median(np.diff(t))), 1)


def merge_paired(
    items: Iterable[tuple[str, int, Callable[[], Any]]], pairing: np.ndarray
) -> Iterator[tuple[int, Any, Any]]:
    """Join colour and depth items read in file order into pairs, decoding only what is used.

    Parameters
    ----------
    items : iterable of (kind, index, decode)
        ``kind`` is ``"color"`` or ``"depth"``, ``index`` the item's rank in its
        stream (the order its timestamps were given to :func:`pair_nearest`),
        ``decode()`` returns its image.
    pairing : ndarray, shape (N,), int64
        :func:`pair_nearest` output.

    Yields
    ------
    (color_index, color, depth or None)
        In colour order, as soon as both halves have been read.
    """
    wanted = {int(j): i for i, j in enumerate(pairing) if j >= 0}
    colors: dict[int, Any] = {}
    depths: dict[int, Any] = {}
    next_color = 0
    for kind, index, decode in items:
        if kind == "color":
            colors[index] = decode()
        elif index in wanted:
            depths[wanted[index]] = decode()
        while next_color in colors and (pairing[next_color] < 0 or next_color in depths):
            yield next_color, colors.pop(next_color), depths.pop(next_color, None)
            next_color += 1
    while next_color < len(pairing) and next_color in colors:
        yield next_color, colors.pop(next_color), depths.pop(next_color, None)
        next_color += 1


class ImportSource(Source):
    """A source over another tool's recording (a file or folder).

    Subclasses set :attr:`total` (frames to expect, or None) in :meth:`open`
    and add what the user should know to :attr:`report` (one line each:
    streams chosen, intrinsics origin, unpaired frames).
    """

    live = False
    #: Short format name (``"ros"``, ``"k4a"``, ``"folder"``, ``"video"``).
    kind = "import"

    def __init__(self, path: str | Path) -> None:
        super().__init__()
        self.path = Path(path)
        self.total: int | None = None
        self.report: list[str] = []

    def describe(self) -> str:
        return f"{self.kind} {self.path.name}"

    def metadata(self) -> dict[str, str]:
        """Free-form keys for the ``fusion_pf.recording`` metadata record."""
        return {"source": str(self.path), "imported_from": self.kind}


@dataclass
class ImportSummary:
    """What :func:`write_recording` wrote.

    Attributes
    ----------
    frames : int
    with_depth : int
        Frames written with a depth image.
    seconds : float
        Wall time of the import.
    bytes : int
        Size of the output file.
    report : list of str
        The source's remarks (streams chosen, intrinsics origin, unpaired frames).
    """

    frames: int = 0
    with_depth: int = 0
    seconds: float = 0.0
    bytes: int = 0
    report: list[str] = field(default_factory=list)

    @property
    def fps(self) -> float:
        """Frames imported per wall-clock second."""
        return self.frames / self.seconds if self.seconds > 0 else float("inf")


def write_recording(
    source: ImportSource,
    output: str | Path,
    *,
    max_frames: int | None = None,
    progress: bool | None = None,
    metadata: Mapping[str, str] | None = None,
    **recorder_options: Any,
) -> ImportSummary:
    """Import ``source`` into the fusion-pf MCAP recording ``output``.

    Parameters
    ----------
    source : ImportSource
        Unopened; opened and closed here.
    output : str or Path
        MCAP file to write (overwritten).
    max_frames : int, optional
        Stop after this many frames.
    progress : bool or None
        tqdm progress bar on stderr; None shows it only on a terminal.
    metadata : mapping, optional
        Extra keys for the ``fusion_pf.recording`` record.
    **recorder_options
        ``color_format``, ``depth_format``, ``compression``, ... of
        :class:`~drivers.mcap_record.McapRecorder`.

    Returns
    -------
    ImportSummary
    """
    from tqdm import tqdm

    from ..mcap_record import McapRecorder

    started = time.perf_counter()
    summary = ImportSummary()
    with source as src:
        meta = {**src.metadata(), **dict(metadata or {})}
        total = src.total if max_frames is None or src.total is None else min(src.total, max_frames)
        recorder = McapRecorder(output, metadata=meta, **recorder_options)
        frames = iter(src)
        try:
            with (
                recorder,
                tqdm(
                    total=total,
                    unit="frame",
                    desc=src.describe(),
                    disable=None if progress is None else not progress,
                    file=sys.stderr,
                ) as bar,
            ):
                for frame in frames:
                    recorder.write(frame)
                    summary.with_depth += frame.depth is not None
                    bar.update()
                    if max_frames is not None and recorder.frames_written >= max_frames:
                        break
        except FusionPFError as exc:
            raise type(exc)(
                f"{exc} (after {recorder.frames_written} frames; {output} is finalised and keeps them)"
            ) from None
        finally:
            frames.close()
        summary.frames = recorder.frames_written
        summary.bytes = recorder.bytes_written
    summary.report = list(source.report) + list(source.stats.notes)
    summary.seconds = time.perf_counter() - started
    return summary


def frame_of(
    timestamp_ns: int,
    seq: int,
    color: np.ndarray,
    depth: np.ndarray | None,
    intrinsics: Intrinsics,
    where: str,
    index: int | None = None,
) -> Frame:
    """A Frame (``index``: its place in the source), with a colour/depth size mismatch an InputError naming ``where``."""
    if depth is not None and depth.shape != color.shape[:2]:
        raise InputError(
            f"{where}: depth is {depth.shape[1]}x{depth.shape[0]} but colour is {color.shape[1]}x{color.shape[0]}; "
            "depth must be registered to colour (same size)"
        )
    return Frame(timestamp_ns, seq, color, depth, intrinsics, index=index)
