"""Read what the scorer compares: tracker outputs and references, and align them.

Tracker outputs
    * the CSV of ``fusion-pf track --csv`` (columns in docs/architecture.md,
      "CSV"): ``frame, timestamp_ns, u, v, colour_u, colour_v, depth_u,
      depth_v, skeleton_u, skeleton_v`` are required, ``latency_<stage>_ms``
      columns are read when present and not empty (``fusion-pf track`` fills
      them only with ``--csv-latency``); an empty cell is a missing point;
    * the MCAP of ``fusion-pf track -o``: topics ``/tracker/estimate`` (``u``,
      ``v``, ``latency_ns``) and ``/tracker/cues`` (per source ``{u, v,
      quality}`` or null), keyed by their ``frame`` field.

    Both become a :class:`TrackTable` whose ``points`` are keyed by
    the sources the output has (the estimate is
    ``"fused"``).

References
    * ground truth: the ``/ground_truth/palm`` topic (JSON ``{"u", "v",
      "occluded"}``, ``log_time`` = the frame's ``timestamp_ns``) of a
      synthetic recording, or of a tracker MCAP (which copies its input
      topics);
    * annotations: the per-frame operator mean of an annotation database
      (:func:`fusion_pf.annotate.db.reference_table`, paper 003 §4.1).

Alignment (:func:`align`)
    Ground truth is matched to tracker rows by ``timestamp_ns``; annotations by
    ``frame`` index, and the two timestamps of a matched frame must agree.
    Every reference frame must match a tracker row (otherwise the files are
    from different recordings, or the tracker output is truncated: an
    :class:`~fusion_pf.errors.InputError` says so). Tracker rows without a
    reference (background frames, frames with no visible palm) are kept and
    skipped by the metrics.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fusion_pf.errors import InputError

#: What the scorer reads from MCAP files, by kind (``drivers.tracker_topics.TOPICS``
#: maps each kind to its topic of docs/recording-format.md).
ESTIMATE_TOPIC, CUES_TOPIC, GROUND_TRUTH_TOPIC = "estimate", "cues", "ground_truth"
#: Kinds of a multi-camera run: ``/tracker/world`` and ``/ground_truth/world``.
WORLD_TOPIC, WORLD_TRUTH_TOPIC = "world", "world_truth"

#: Keys of a ``/tracker/cues`` message that are not sources.
_CUES_FIELDS = ("frame", "timestamp_ns", "roi")

#: CSV columns the scorer needs; every ``<source>_u, <source>_v`` pair after them is a cue.
REQUIRED_CSV_COLUMNS = ("frame", "timestamp_ns", "u", "v")


def csv_sources(header: list[str]) -> tuple[str, ...]:
    """The cue sources of a tracker CSV header: every ``X`` with both ``X_u`` and ``X_v`` columns, in order."""
    return tuple(c[:-2] for c in header if c.endswith("_u") and c != "u" and c[:-2] + "_v" in header)


_MCAP_MAGIC = b"\x89MCAP0\r\n"
_SQLITE_MAGIC = b"SQLite format 3\x00"


def file_kind(path: str | Path) -> str:
    """``"mcap"``, ``"sqlite"`` or ``"csv"`` from the file's magic bytes (or suffix for CSV).

    Raises
    ------
    FileNotFoundError
        When ``path`` does not exist.
    InputError
        When the file is none of the three.
    """
    path = Path(path)
    with path.open("rb") as f:
        head = f.read(16)
    if head.startswith(_MCAP_MAGIC):
        return "mcap"
    if head.startswith(_SQLITE_MAGIC):
        return "sqlite"
    if path.suffix.lower() == ".csv":
        return "csv"
    raise InputError(
        f"{path}: unknown file type (first bytes {head[:8]!r}); expected an MCAP file, "
        "a tracker CSV (.csv) or an annotations SQLite database"
    )


@dataclass(frozen=True)
class TrackTable:
    """A tracker output as per-frame arrays.

    Attributes
    ----------
    path : str
        Where it was read from.
    frame : ndarray, shape (n,), int64
        Frame index of each row, strictly increasing.
    timestamp_ns : ndarray, shape (n,), int64
    points : dict of str to ndarray, shape (n, 2)
        Per scored source (the cues the tracker computed, e.g. ``colour``,
        ``depth``, ``skeleton``, then the estimate ``fused``), the ``(u, v)``
        pixels, NaN rows where the source gave nothing.
    latency_ms : dict of str to ndarray, shape (n,)
        Per latency stage with at least one value in the file, milliseconds
        (NaN when unknown).
    state : ndarray of str, shape (n,), or None
        Track state per row when the output has one (``tracking``, ``lost``, ``uninitialised``).
    sigma_px : ndarray, shape (n,), or None
        The estimate's reported uncertainty per row (``sigma_px``, NaN where none), when the output has it.
    """

    path: str
    frame: np.ndarray
    timestamp_ns: np.ndarray
    points: dict[str, np.ndarray]
    latency_ms: dict[str, np.ndarray]
    state: np.ndarray | None = None
    sigma_px: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.frame.size == 0:
            raise InputError(f"{self.path}: the tracker output has no frames")
        bad = np.flatnonzero(np.diff(self.frame) <= 0)
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"{self.path}: frame indices must be strictly increasing, got frame "
                f"{self.frame[i + 1]} after frame {self.frame[i]}"
            )


@dataclass(frozen=True)
class Reference:
    """Reference palm points per frame.

    Attributes
    ----------
    path : str
    kind : str
        ``"ground truth"`` or ``"annotations"``.
    frame : ndarray, shape (m,), int64, or None
        Frame index (annotations); None for ground truth (matched by time).
    timestamp_ns : ndarray, shape (m,), int64
    uv : ndarray, shape (m, 2)
        Reference ``(u, v)``, NaN rows where the palm is not visible.
    occluded : ndarray, shape (m,), bool, or None
        Ground-truth occlusion flags (None for annotations).
    spread_px : ndarray, shape (m,), or None
        Operator spread (annotations; NaN where unknown).
    """

    path: str
    kind: str
    frame: np.ndarray | None
    timestamp_ns: np.ndarray
    uv: np.ndarray
    occluded: np.ndarray | None
    spread_px: np.ndarray | None = None


def _column(path: str, name: str, cells: list[str], dtype: type) -> np.ndarray:
    arr = np.array(cells, dtype=str)
    if dtype is float:
        arr = np.where(arr == "", "nan", arr)
    try:
        out = arr.astype(np.float64 if dtype is float else np.int64)
    except (ValueError, OverflowError):
        # numpy's parser is stricter than Python's (e.g. about surrounding spaces):
        # convert cell by cell, naming the first cell neither accepts.
        values = []
        for row, cell in enumerate(cells, start=2):
            try:
                values.append(float(cell or "nan") if dtype is float else int(cell))
            except ValueError:
                kind = "a number or empty" if dtype is float else "an integer"
                raise InputError(f"{path}: line {row}, column {name!r} must be {kind}, got {cell!r}") from None
        try:
            out = np.array(values, dtype=np.float64 if dtype is float else np.int64)
        except OverflowError:
            raise InputError(f"{path}: column {name!r} has an integer out of the int64 range") from None
    if dtype is float and np.isinf(out).any():
        row = int(np.flatnonzero(np.isinf(out))[0]) + 2
        raise InputError(f"{path}: line {row}, column {name!r} must be finite, got {cells[row - 2]!r}")
    return out


def _pair(u: np.ndarray, v: np.ndarray, path: str, what: str) -> np.ndarray:
    uv = np.stack([u, v], axis=1)
    half = np.isnan(uv).sum(axis=1) == 1
    if half.any():
        raise InputError(f"{path}: {what} has u without v (or v without u) in row {int(np.flatnonzero(half)[0])}")
    return uv


def read_tracker_csv(path: str | Path) -> TrackTable:
    """Read the CSV written by ``fusion-pf track --csv``.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    TrackTable

    Raises
    ------
    InputError
        On missing columns, unparsable cells or non-increasing frames.
    """
    path = str(path)
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        raise InputError(f"{path}: empty file, expected a tracker CSV with a header row")
    header, body = rows[0], rows[1:]
    missing = [c for c in REQUIRED_CSV_COLUMNS if c not in header]
    if missing:
        raise InputError(
            f"{path}: missing column(s) {', '.join(missing)}; expected the tracker CSV of "
            "docs/architecture.md (fusion-pf track --csv)"
        )
    short = [i for i, r in enumerate(body, start=2) if len(r) != len(header)]
    if short:
        raise InputError(f"{path}: line {short[0]} has {len(body[short[0] - 2])} cells, expected {len(header)}")
    cols = {name: [r[i] for r in body] for i, name in enumerate(header)}
    sources = csv_sources(header)
    num = {c: _column(path, c, cols[c], float) for c in ("u", "v", *(f"{s}_{x}" for s in sources for x in "uv"))}
    points = {s: _pair(num[f"{s}_u"], num[f"{s}_v"], path, s) for s in sources}
    points["fused"] = _pair(num["u"], num["v"], path, "the estimate")
    latency = {
        c[len("latency_") : -len("_ms")]: _column(path, c, cols[c], float)
        for c in header
        if c.startswith("latency_") and c.endswith("_ms")
    }
    latency = {k: ms for k, ms in latency.items() if np.isfinite(ms).any()}
    return TrackTable(
        path=path,
        frame=_column(path, "frame", cols["frame"], int),
        timestamp_ns=_column(path, "timestamp_ns", cols["timestamp_ns"], int),
        points=points,
        latency_ms=latency,
        state=np.array(cols["state"], dtype=object) if "state" in cols else None,
        sigma_px=_sigmas(path, cols["sigma_px"]) if "sigma_px" in cols else None,
    )


def _sigmas(path: str, cells: list[str]) -> np.ndarray:
    """The ``sigma_px`` column: numbers >= 0 or empty (NaN)."""
    sigma = _column(path, "sigma_px", cells, float)
    bad = np.flatnonzero(sigma < 0)
    if bad.size:
        row = int(bad[0])
        raise InputError(
            f"{path}: line {row + 2}, column 'sigma_px' must be a number >= 0 or empty, got {cells[row]!r}"
        )
    return sigma


#: ``read_topic(path, kind) -> [(log_time_ns, message dict), ...]`` for a kind
#: ``"estimate"``, ``"cues"`` or ``"ground_truth"``: how MCAP topics are read
#: (``drivers.tracker_topics.read_topic``); the scorer never opens MCAP files.
TopicReader = Callable[[str, str], "list[tuple[int, dict]]"]
#: ``frame_size(recording) -> (width, height)``: the image size of a recording, read by the caller.
FrameSize = Callable[[Any], tuple[int, int]]


def _need_reader(path: str, read_topic: TopicReader | None) -> TopicReader:
    if read_topic is None:
        raise InputError(f"{path} is an MCAP file: pass read_topic (drivers.tracker_topics.read_topic) to read it")
    return read_topic


def _xy(path: str, topic: str, obj: object, where: str) -> tuple[float, float]:
    if obj is None:
        return (math.nan, math.nan)
    try:
        u, v = obj["u"], obj["v"]  # type: ignore[index]
    except (TypeError, KeyError):
        raise InputError(f"{path}: {topic} {where} must be an object with u and v, got {obj!r}") from None
    if u is None or v is None:
        return (math.nan, math.nan)
    try:
        fu, fv = float(u), float(v)
    except (TypeError, ValueError):
        raise InputError(f"{path}: {topic} {where} u, v must be numbers, got {u!r}, {v!r}") from None
    if not (math.isfinite(fu) and math.isfinite(fv)):
        raise InputError(f"{path}: {topic} {where} u, v must be finite, got {u!r}, {v!r}")
    return (fu, fv)


def sigma_field(path: str, topic: str, value: object, where: str) -> float:
    """An uncertainty field of a message: a number >= 0, or None (NaN)."""
    if value is None:
        return math.nan
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value >= 0:
        raise InputError(f"{path}: {topic} {where} sigma_px must be a number >= 0 or null, got {value!r}")
    return float(value)


def _frame_of(path: str, topic: str, msg: dict, log_time: int) -> int:
    frame = msg.get("frame") if isinstance(msg, dict) else None
    if isinstance(frame, bool) or not isinstance(frame, int) or frame < 0:
        raise InputError(
            f"{path}: {topic} message at log_time {log_time} must have a non-negative int 'frame', got {frame!r}"
        )
    return frame


def read_tracker_mcap(path: str | Path, read_topic: TopicReader | None = None) -> TrackTable:
    """Read the tracker topics of an MCAP written by ``fusion-pf track -o``.

    Rows are the union of the frames of ``/tracker/estimate`` and
    ``/tracker/cues``; a frame missing from one topic has NaN points there.

    Raises
    ------
    InputError
        When neither topic is present or a message is malformed.
    """
    path = str(path)
    read_topic = _need_reader(path, read_topic)
    estimates = read_topic(path, ESTIMATE_TOPIC)
    cues = read_topic(path, CUES_TOPIC)
    if not estimates and not cues:
        raise InputError(
            f"{path}: no tracker estimate or cue messages; expected the output of "
            "fusion-pf track -o (a recording must be tracked before it is scored)"
        )
    rows: dict[int, dict] = {}
    for log_time, msg in estimates:
        frame = _frame_of(path, ESTIMATE_TOPIC, msg, log_time)
        row = rows.setdefault(frame, {"timestamp_ns": msg.get("timestamp_ns", log_time)})
        row["fused"] = _xy(path, ESTIMATE_TOPIC, msg, f"frame {frame}")
        row["sigma_px"] = sigma_field(path, ESTIMATE_TOPIC, msg.get("sigma_px"), f"frame {frame}")
        lat = msg.get("latency_ns")
        lat = lat if isinstance(lat, dict) else {}
        row["latency"] = {k: float(v) / 1e6 for k, v in lat.items() if isinstance(v, (int, float))}
    for log_time, msg in cues:
        frame = _frame_of(path, CUES_TOPIC, msg, log_time)
        row = rows.setdefault(frame, {"timestamp_ns": msg.get("timestamp_ns", log_time)})
        for s, value in msg.items():
            if s not in _CUES_FIELDS:
                row.setdefault("sources", []).append(s)
                row[s] = _xy(path, CUES_TOPIC, value, f"frame {frame} {s}")
    frames = np.array(sorted(rows), dtype=np.int64)
    ordered = [rows[int(f)] for f in frames]
    nan2 = (math.nan, math.nan)
    sources = list(dict.fromkeys(s for r in ordered for s in r.get("sources", ())))
    points = {s: np.array([r.get(s, nan2) for r in ordered], dtype=np.float64) for s in (*sources, "fused")}
    stages = list(dict.fromkeys(s for r in ordered for s in r.get("latency", {})))
    latency = {s: np.array([r.get("latency", {}).get(s, math.nan) for r in ordered], dtype=np.float64) for s in stages}
    try:
        ts = np.array([int(r["timestamp_ns"]) for r in ordered], dtype=np.int64)
    except (TypeError, ValueError):
        raise InputError(f"{path}: tracker timestamp_ns values must be integers") from None
    has_sigma = any(isinstance(msg, dict) and "sigma_px" in msg for _, msg in estimates)
    sigma = np.array([r.get("sigma_px", math.nan) for r in ordered], dtype=np.float64) if has_sigma else None
    return TrackTable(path=path, frame=frames, timestamp_ns=ts, points=points, latency_ms=latency, sigma_px=sigma)


def read_tracker(path: str | Path, read_topic: TopicReader | None = None) -> TrackTable:
    """Read a tracker output, CSV or MCAP (by its content, see :func:`file_kind`; MCAP through ``read_topic``)."""
    kind = file_kind(path)
    if kind == "mcap":
        return read_tracker_mcap(path, read_topic)
    if kind == "csv":
        return read_tracker_csv(path)
    raise InputError(
        f"{path}: is an SQLite database, expected a tracker output (.csv or .mcap from fusion-pf track); "
        "pass annotations with --reference"
    )


def read_ground_truth(path: str | Path, read_topic: TopicReader | None = None) -> Reference:
    """Read ``/ground_truth/palm`` of a synthetic recording (or of a tracker MCAP).

    Raises
    ------
    InputError
        When the file is not an MCAP or has no ground truth.
    """
    path = str(path)
    if file_kind(path) != "mcap":
        raise InputError(f"{path}: ground truth must be an MCAP recording with ground-truth palm messages")
    msgs = _need_reader(path, read_topic)(path, GROUND_TRUTH_TOPIC)
    if not msgs:
        raise InputError(
            f"{path}: no ground-truth palm messages; only synthetic recordings carry ground "
            "truth (use --reference annotations.sqlite for real ones)"
        )
    msgs.sort(key=lambda m: m[0])
    ts = np.array([t for t, _ in msgs], dtype=np.int64)
    dup = np.flatnonzero(np.diff(ts) == 0)
    if dup.size:
        raise InputError(f"{path}: two {GROUND_TRUTH_TOPIC} messages at log_time {ts[dup[0]]}")
    uv = np.array([_xy(path, GROUND_TRUTH_TOPIC, m, f"at log_time {t}") for t, m in msgs])
    occluded = np.array([bool(m.get("occluded", False)) for _, m in msgs], dtype=bool)
    return Reference(path=path, kind="ground truth", frame=None, timestamp_ns=ts, uv=uv, occluded=occluded)


def _none_nan(x: object) -> float:
    return math.nan if x is None else float(x)  # type: ignore[arg-type]


def read_annotations(path: str | Path) -> Reference:
    """Read the per-frame operator mean of an annotation database (paper 003 §4.1).

    Raises
    ------
    InputError
        When the file is not an SQLite database or has no annotated frame.
    """
    path = str(path)
    kind = file_kind(path)
    if kind != "sqlite":
        hint = " (use --ground-truth for a recording)" if kind == "mcap" else ""
        raise InputError(f"{path}: unknown reference file, expected an annotations SQLite database{hint}")
    from fusion_pf.annotate.db import reference_table

    rows = reference_table(path)
    if not rows:
        raise InputError(f"{path}: the annotation database has no annotated frame")
    rows = sorted(rows, key=lambda r: r["frame"])
    return Reference(
        path=path,
        kind="annotations",
        frame=np.array([r["frame"] for r in rows], dtype=np.int64),
        timestamp_ns=np.array([r["timestamp_ns"] for r in rows], dtype=np.int64),
        uv=np.array([(_none_nan(r["mean_u"]), _none_nan(r["mean_v"])) for r in rows], dtype=np.float64),
        occluded=None,
        spread_px=np.array([_none_nan(r.get("spread_px")) for r in rows], dtype=np.float64),
    )


def align(
    frame: np.ndarray,
    timestamp_ns: np.ndarray,
    reference: Reference,
    name: str = "the tracker output",
) -> tuple[np.ndarray, np.ndarray | None]:
    """The reference point (and occlusion flag) of every tracker row.

    Parameters
    ----------
    frame, timestamp_ns : ndarray, shape (n,)
        Frame index and timestamp of each tracker row (e.g. of a
        :class:`TrackTable`, or of the cue rows of a sweep).
    reference : Reference
    name : str
        What the rows are, for error messages (e.g. the tracker file's path).

    Returns
    -------
    uv : ndarray, shape (n, 2)
        Reference per tracker row, NaN where the row has none.
    occluded : ndarray, shape (n,), bool, or None

    Raises
    ------
    InputError
        When a reference frame has no tracker row (frame count mismatch), or an
        annotated frame's timestamp differs from the tracker's.
    """
    frame = np.asarray(frame, dtype=np.int64)
    timestamp_ns = np.asarray(timestamp_ns, dtype=np.int64)
    n = frame.size
    if reference.frame is not None:
        key_ref, key_tab, what = reference.frame, frame, "frame"
    else:
        key_ref, key_tab, what = reference.timestamp_ns, timestamp_ns, "timestamp_ns"
    order = np.argsort(key_tab, kind="stable")
    pos = np.minimum(np.searchsorted(key_tab[order], key_ref), max(n - 1, 0))
    found = key_tab[order][pos] == key_ref if n else np.zeros(key_ref.size, dtype=bool)
    if not found.all():
        first = int(key_ref[np.flatnonzero(~found)[0]])
        raise InputError(
            f"frame count mismatch: {reference.path} has {key_ref.size} reference frames but "
            f"{int((~found).sum())} of them (first {what} {first}) have no row in {name} "
            f"({n} rows); score a tracker output of the whole recording the reference belongs to"
        )
    rows = order[pos]
    if reference.frame is not None:
        bad = np.flatnonzero(timestamp_ns[rows] != reference.timestamp_ns)
        if bad.size:
            i = int(bad[0])
            raise InputError(
                f"timestamp mismatch at frame {int(reference.frame[i])}: {name} has "
                f"timestamp_ns {int(timestamp_ns[rows[i]])}, {reference.path} has "
                f"{int(reference.timestamp_ns[i])}"
            )
    uv = np.full((n, 2), np.nan)
    uv[rows] = reference.uv
    occ = None
    if reference.occluded is not None:
        occ = np.zeros(n, dtype=bool)
        occ[rows] = reference.occluded
    return uv, occ
