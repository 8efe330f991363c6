"""What the pipeline writes, independent of the file format: CSV rows and JSON messages.

* :class:`TrackCsv` writes the CSV of docs/architecture.md ("CSV"): one row per
  tracked frame, columns :func:`csv_columns` of the computed cues;
* :func:`estimate_json` and :func:`cues_json` are the ``/tracker/estimate`` and
  ``/tracker/cues`` messages (docs/recording-format.md); the MCAP writer of
  those and of the Foxglove overlay is ``drivers.tracker_topics``.
"""

from __future__ import annotations

import csv
import math
from collections.abc import Sequence
from pathlib import Path
from typing import IO

from ..cues.base import SOURCES
from ..errors import InputError
from .config import TrackConfig
from .events import events_cell
from .run import TrackResult, stages
from .world import WorldResult

__all__ = [
    "CSV_COLUMNS",
    "TARGET_CSV_FIELDS",
    "TrackCsv",
    "csv_columns",
    "csv_row",
    "cues_json",
    "estimate_json",
    "targets_csv_columns",
    "targets_csv_row",
    "targets_cues_json",
    "targets_json",
    "world_csv_columns",
    "world_csv_row",
    "world_json",
]


def csv_columns(sources: Sequence[str] = SOURCES) -> tuple[str, ...]:
    """CSV columns, in order, for the computed cues ``sources`` (docs/architecture.md "CSV")."""
    return (
        "frame",
        "timestamp_ns",
        "u",
        "v",
        *(f"{s}_{c}" for s in sources for c in ("u", "v")),
        "x_mm",
        "y_mm",
        "z_mm",
        "sigma_px",
        "sigma_mm",
        "ess",
        "resampled",
        "n_particles",
        *(f"latency_{stage}_ms" for stage in (*stages(sources), "sinks")),
        *(f"{s}_quality" for s in sources),
        "state",
        "events",
    )


#: CSV columns of the paper's three cues (colour, depth, skeleton).
CSV_COLUMNS = csv_columns(SOURCES)


def _f(value: float | None, digits: int) -> str:
    """Fixed-format float; empty for None or NaN (so a file never holds 'nan')."""
    if value is None or not math.isfinite(value):
        return ""
    return f"{value:.{digits}f}"


class TrackCsv:
    """Writes tracked frames as CSV rows (:func:`csv_columns`), flushed row by row.

    Background frames are skipped. Floats use fixed formats (pixels 3 decimals,
    mm 1, ESS 3, latency ms 3), so the same seed gives a byte-identical file as
    long as ``latency`` is False: wall-clock latency differs from run to run,
    so its columns are left empty unless asked for.

    Parameters
    ----------
    path : str or Path
    latency : bool
        Fill the ``latency_*_ms`` columns.
    sources : sequence of str or None
        The computed cues (:func:`~fusion_pf.pipeline.run.cue_names`); None:
        those of the first tracked frame (the header is written then).
    """

    def __init__(self, path: str | Path, *, latency: bool = False, sources: Sequence[str] | None = SOURCES) -> None:
        self.path = Path(path)
        self.latency = bool(latency)
        self.sources = None if sources is None else tuple(sources)
        self._fh: IO[str] | None = None
        self.rows = 0

    def __enter__(self) -> "TrackCsv":
        self._fh = open(self.path, "w", newline="", encoding="ascii")
        self._writer = csv.writer(self._fh, lineterminator="\n")
        if self.sources is not None:
            self._writer.writerow(csv_columns(self.sources))
        return self

    def __exit__(self, *exc: object) -> None:
        if self._fh is not None:
            self._fh.close()
            self._fh = None

    def write(self, result: TrackResult) -> None:
        """Append the row of ``result`` (nothing for a background frame)."""
        if result.background:
            return
        if self._fh is None:
            raise InputError(f"CSV {self.path} is not open; use TrackCsv inside a 'with' block")
        if self.sources is None:
            self.sources = tuple(result.cues)
            self._writer.writerow(csv_columns(self.sources))
        self._writer.writerow(csv_row(result, latency=self.latency, sources=self.sources))
        self._fh.flush()
        self.rows += 1


def csv_row(result: TrackResult, *, latency: bool = False, sources: Sequence[str] = SOURCES) -> list[str]:
    """The CSV cells of one result, in :func:`csv_columns` order."""
    e = result.estimate
    cells = [
        str(result.frame),
        str(result.timestamp_ns),
        _f(None if e is None else e.u, 3),
        _f(None if e is None else e.v, 3),
    ]
    for s in sources:
        m = result.cues.get(s)
        cells += [_f(None if m is None else m.u, 3), _f(None if m is None else m.v, 3)]
    xyz = result.xyz_mm
    cells += [_f(float(c), 1) for c in xyz] if xyz is not None else [_f(None, 1)] * 3
    cells += [_f(result.sigma_px, 3), _f(result.sigma_mm, 1)]
    cells += [
        _f(None if e is None else e.ess, 3),
        "" if e is None else str(int(e.resampled)),
        "" if e is None else str(e.n_particles),
    ]
    for stage in (*stages(sources), "sinks"):
        ns = result.latency_ns.get(stage)
        cells.append(_f(ns / 1e6, 3) if latency and ns is not None else "")
    for s in sources:
        m = result.cues.get(s)
        cells.append(_f(None if m is None else m.quality, 3))
    cells += [result.state, events_cell(result.events)]
    return cells


def _finite_or_none(value: float | None) -> float | None:
    return float(value) if value is not None and math.isfinite(value) else None


def estimate_json(result: TrackResult, config: TrackConfig) -> dict:
    """The ``/tracker/estimate`` message of ``result``."""
    e = result.estimate
    return {
        "frame": result.frame,
        "timestamp_ns": result.timestamp_ns,
        "u": None if e is None else e.u,
        "v": None if e is None else e.v,
        "xyz_mm": None if result.xyz_mm is None else [float(c) for c in result.xyz_mm],
        "sigma_px": result.sigma_px,
        "sigma_mm": result.sigma_mm,
        "ess": None if e is None else _finite_or_none(e.ess),
        "resampled": None if e is None else e.resampled,
        "n_particles": 0 if e is None else e.n_particles,
        "state": result.state,
        "likelihood_evaluations": result.evaluations,
        "filter": config.filter,
        "likelihood": config.likelihood,
        "latency_ns": {k: int(v) for k, v in result.latency_ns.items()},
    }


def cues_json(result: TrackResult) -> dict:
    """The ``/tracker/cues`` message of ``result``: per computed cue ``{u, v, quality}`` or null."""
    out: dict = {"frame": result.frame, "timestamp_ns": result.timestamp_ns}
    for s, m in result.cues.items():
        out[s] = None if m is None else {"u": m.u, "v": m.v, "quality": m.quality}
    if result.roi is not None:
        out["roi"] = result.roi.as_list()
    return out


#: The per-target columns of a multi-target CSV, each prefixed by ``<target>_`` (the single palm's of the same name).
TARGET_CSV_FIELDS = ("u", "v", "state", "x_mm", "y_mm", "z_mm", "sigma_px", "sigma_mm")


def targets_csv_columns(targets: Sequence[str]) -> tuple[str, ...]:
    """CSV columns of a multi-target run: ``frame, timestamp_ns``, per target :data:`TARGET_CSV_FIELDS`, evaluations, events."""
    return (
        "frame",
        "timestamp_ns",
        *(f"{t}_{c}" for t in targets for c in TARGET_CSV_FIELDS),
        "likelihood_evaluations",
        "events",
    )


def _uv(result: TrackResult) -> tuple[float | None, float | None]:
    e = result.estimate
    return (None, None) if e is None else (e.u, e.v)


def targets_csv_row(result: TrackResult) -> list[str]:
    """The CSV cells of a multi-target frame (``result.targets``), in :func:`targets_csv_columns` order.

    Per target as the single palm's row: u, v, sigma_px empty without an estimate, x, y, z, sigma_mm also without depth.
    """
    cells = [str(result.frame), str(result.timestamp_ns)]
    for r in result.targets.values():
        u, v = _uv(r)
        xyz = [None] * 3 if r.xyz_mm is None else [float(c) for c in r.xyz_mm]
        cells += [_f(u, 3), _f(v, 3), r.state, *(_f(c, 1) for c in xyz), _f(r.sigma_px, 3), _f(r.sigma_mm, 1)]
    cells.append(str(sum(r.evaluations for r in result.targets.values())))
    cells.append(events_cell(result.events))
    return cells


def targets_json(result: TrackResult, config: TrackConfig) -> dict:
    """The ``/tracker/estimate`` message of a multi-target frame: per target ``{u, v, state, xyz_mm, sigma_px, sigma_mm}``.

    Each field as the single palm's (:func:`estimate_json`; null when none). ``latency_ns`` is the frame's
    (``total``: decode to every target's estimate).
    """
    return {
        "frame": result.frame,
        "timestamp_ns": result.timestamp_ns,
        "targets": {
            t: {
                "u": _finite_or_none(_uv(r)[0]),
                "v": _finite_or_none(_uv(r)[1]),
                "state": r.state,
                "xyz_mm": None if r.xyz_mm is None else [float(c) for c in r.xyz_mm],
                "sigma_px": _finite_or_none(r.sigma_px),
                "sigma_mm": _finite_or_none(r.sigma_mm),
            }
            for t, r in result.targets.items()
        },
        "filter": config.filter,
        "likelihood_evaluations": sum(r.evaluations for r in result.targets.values()),
        "latency_ns": {k: int(v) for k, v in result.latency_ns.items()},
    }


def targets_cues_json(result: TrackResult) -> dict:
    """The ``/tracker/cues`` message of a multi-target frame: per target its :func:`cues_json` fields."""
    return {
        "frame": result.frame,
        "timestamp_ns": result.timestamp_ns,
        "targets": {
            t: {k: v for k, v in cues_json(r).items() if k not in ("frame", "timestamp_ns")}
            for t, r in result.targets.items()
        },
    }


def world_csv_columns(cameras: Sequence[str]) -> tuple[str, ...]:
    """CSV columns of a multi-camera run: one row per instant and target (docs/architecture.md, "Several cameras")."""
    return (
        "frame",
        "timestamp_ns",
        "target",
        "state",
        "x_mm",
        "y_mm",
        "z_mm",
        "sigma_mm",
        "cameras",
        *(f"{c}_{k}" for c in cameras for k in ("u", "v")),
        "events",
    )


def world_csv_row(result: WorldResult, target: str, cameras: Sequence[str]) -> list[str]:
    """The CSV cells of ``target`` at one instant, in :func:`world_csv_columns` order (empty cells without a value).

    The ``events`` cell holds the instant's events whose first target is ``target`` (each event in one row).
    """
    w = result.targets[target]
    xyz = (None, None, None) if w.position_mm is None else tuple(float(v) for v in w.position_mm)
    cells = [str(result.index), str(result.timestamp_ns), target, w.state]
    cells += [_f(v, 1) for v in xyz] + [_f(w.sigma_mm, 1), " ".join(w.cameras)]
    for c in cameras:
        uv = w.pixels.get(c)
        cells += ["", ""] if uv is None else [_f(uv[0], 3), _f(uv[1], 3)]
    cells.append(events_cell([e for e in result.events if e.targets[0] == target]))
    return cells


def world_json(result: WorldResult) -> dict:
    """The ``/tracker/world`` message of one instant (schema ``fusion_pf.WorldEstimate``, docs/recording-format.md)."""
    return {
        "timestamp_ns": int(result.timestamp_ns),
        "targets": [
            {
                "target": t,
                "state": w.state,
                "position_mm": None if w.position_mm is None else [float(v) for v in w.position_mm],
                "sigma_mm": _finite_or_none(w.sigma_mm),
                "cameras": list(w.cameras),
                "pixels": {c: None if uv is None else [float(uv[0]), float(uv[1])] for c, uv in w.pixels.items()},
            }
            for t, w in result.targets.items()
        ],
    }
