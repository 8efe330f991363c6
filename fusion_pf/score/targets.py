"""Scoring a multi-target tracker output per target (papers 000, 004): RMSE, coverage, states, identity swaps.

The tracker output is the CSV of ``fusion-pf track --targets ... --csv`` (columns
``<target>_u, <target>_v, <target>_state`` and, when written, ``<target>_sigma_px``) or its ``/tracker/estimate``
messages (``{"targets": {target: {u, v, state, sigma_px}}}``); the reference is the
ground truth per target of a multi-target recording (``/ground_truth/palm``
messages with a ``target`` field), matched by timestamp.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fusion_pf.errors import InputError

from .inputs import (
    ESTIMATE_TOPIC,
    GROUND_TRUTH_TOPIC,
    WORLD_TOPIC,
    WORLD_TRUTH_TOPIC,
    FrameSize,
    TopicReader,
    file_kind,
    sigma_field,
)
from .metrics import rmse, uncertainty_coverage
from .report import coverage_json

__all__ = [
    "SINGLE_PALM_TARGET",
    "TargetsTable",
    "count_swaps",
    "read_world",
    "score_world",
    "score_world_recording",
    "world_markdown",
    "read_targets_csv",
    "read_targets_topic",
    "read_targets",
    "score_targets",
    "score_targets_recording",
    "target_summary",
    "targets_markdown",
    "truths_by_target",
]

#: Hands closer than this fraction of the image diagonal are joined: an identity is not defined there
#: (25 px at 320 x 200, about 8 cm at the hands).
JOINED_FRACTION = 25.0 / math.hypot(320, 200)
#: The same in the world (mm): 25 px of the 320 x 200 reference scene at its palm's scale (5.08 mm per px).
JOINED_MM = 127.0


@dataclass(frozen=True)
class TargetsTable:
    """A multi-target tracker output: per target ``(n, 2)`` positions (NaN: none), ``(n,)`` states and, when the
    output has them, ``(n,)`` reported uncertainties (``sigma_px``, NaN: none; None: an output without the field)."""

    path: str
    timestamp_ns: np.ndarray
    uv: dict[str, np.ndarray]
    states: dict[str, list[str]]
    sigma_px: dict[str, np.ndarray] | None = None


def read_targets_csv(path: str | Path) -> TargetsTable | None:
    """The multi-target CSV at ``path``, or None when it is not one (no ``<target>_state`` column)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows:
        return None
    header = rows[0]
    targets = [c[: -len("_state")] for c in header if c.endswith("_state") and c[: -len("_state")] + "_u" in header]
    if not targets:
        return None
    col = {name: i for i, name in enumerate(header)}
    body = [r for r in rows[1:] if len(r) == len(header)]
    if len(body) != len(rows) - 1:
        raise InputError(f"{path}: a row has not the {len(header)} cells of the header")

    def num(cell: str) -> float:
        try:
            return float(cell) if cell else math.nan
        except ValueError:
            raise InputError(f"{path}: {cell!r} is not a number") from None

    ts = np.array([int(r[col["timestamp_ns"]]) for r in body], dtype=np.int64)
    uv = {t: np.array([[num(r[col[f"{t}_u"]]), num(r[col[f"{t}_v"]])] for r in body]).reshape(-1, 2) for t in targets}
    states = {t: [r[col[f"{t}_state"]] for r in body] for t in targets}
    sigma = None
    if all(f"{t}_sigma_px" in col for t in targets):
        sigma = {}
        for t in targets:
            name = f"{t}_sigma_px"
            sigma[t] = np.array([num(r[col[name]]) for r in body], dtype=np.float64)
            bad = np.flatnonzero(sigma[t] < 0)
            if bad.size:
                raise InputError(
                    f"{path}: line {int(bad[0]) + 2}, column {name!r} must be a number >= 0 or empty, "
                    f"got {body[int(bad[0])][col[name]]!r}"
                )
    return TargetsTable(str(path), ts, uv, states, sigma)


def read_targets_topic(path: str, read_topic: TopicReader) -> TargetsTable | None:
    """The multi-target ``/tracker/estimate`` messages of a ``track --targets -o`` output, or None when it has none."""
    msgs = [
        (ts, m)
        for ts, m in read_topic(path, ESTIMATE_TOPIC)
        if isinstance(m, dict) and isinstance(m.get("targets"), dict)
    ]
    if not msgs:
        return None
    targets = list(msgs[0][1]["targets"])

    def xy(value: object) -> float:
        return float(value) if isinstance(value, (int, float)) else math.nan

    uv = {
        t: np.array([[xy(m["targets"].get(t, {}).get("u")), xy(m["targets"].get(t, {}).get("v"))] for _, m in msgs])
        for t in targets
    }
    states = {t: [str(m["targets"].get(t, {}).get("state", "")) for _, m in msgs] for t in targets}
    sigma = None
    if any("sigma_px" in (m["targets"].get(t) or {}) for _, m in msgs for t in targets):
        sigma = {
            t: np.array(
                [
                    sigma_field(
                        path, ESTIMATE_TOPIC, (m["targets"].get(t) or {}).get("sigma_px"), f"at {ts} ns, target {t}"
                    )
                    for ts, m in msgs
                ],
                dtype=np.float64,
            )
            for t in targets
        }
    return TargetsTable(path, np.array([int(ts) for ts, _ in msgs], dtype=np.int64), uv, states, sigma)


#: The target a single-palm reference (ground truth without target names) scores by default.
SINGLE_PALM_TARGET = "right_hand"


def read_truths(
    path: str, read_topic: TopicReader
) -> tuple[dict[str, dict[int, tuple[float, float]]], dict[int, tuple[float, float]]]:
    """The ground truth of ``path``: per target (messages with a ``target`` field) and of a single palm (without)."""
    out: dict[str, dict[int, tuple[float, float]]] = {}
    palm: dict[int, tuple[float, float]] = {}
    for t, msg in read_topic(path, GROUND_TRUTH_TOPIC):
        if not isinstance(msg, dict) or "u" not in msg or "v" not in msg:
            continue
        target = msg.get("target")
        if isinstance(target, str):
            out.setdefault(target, {})[int(t)] = (float(msg["u"]), float(msg["v"]))
        else:
            palm[int(t)] = (float(msg["u"]), float(msg["v"]))
    return out, palm


def truths_by_target(path: str, read_topic: TopicReader) -> dict[str, dict[int, tuple[float, float]]]:
    """Ground truth per target of a multi-target recording: ``{target: {timestamp_ns: (u, v)}}``."""
    out, _ = read_truths(path, read_topic)
    if not out:
        raise InputError(
            f"{path}: no ground truth with a target field; expected a multi-target recording (synth --hands 2)"
        )
    return out


def count_swaps(ea: np.ndarray, eb: np.ndarray, ta: np.ndarray, tb: np.ndarray, min_separation_px: float) -> int:
    """Identity swaps between two targets: changes of "exchanging the estimates lowers the error".

    Parameters
    ----------
    ea, eb : ndarray, shape (n, d)
        Estimates of targets a and b (NaN: none): pixels (d = 2) or world mm (d = 3).
    ta, tb : ndarray, shape (n, d)
        Their true positions.
    min_separation_px : float
        Only frames where the truths are at least this far apart count (joined hands are ambiguous), in their unit.
    """

    def dist(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        return np.hypot(*(a - b).T) if a.shape[1] == 2 else np.sqrt(((a - b) ** 2).sum(axis=1))

    sep = dist(ta, tb)
    straight = dist(ea, ta) + dist(eb, tb)
    crossed = dist(ea, tb) + dist(eb, ta)
    ok = (sep >= min_separation_px) & np.isfinite(straight) & np.isfinite(crossed)
    flags = np.concatenate([[False], (crossed < straight)[ok]])
    return int(np.count_nonzero(flags[1:] != flags[:-1]))


def target_summary(err: np.ndarray, n_reference: int, states: list[str], sigma: np.ndarray | None = None) -> dict:
    """RMSE, median, p95 (px) of the finite errors ``err``, coverage (finite errors / ``n_reference``), frames per
    state, and ``uncertainty``: how often the reported ``sigma`` (same length as ``err``, NaN: none) covers the
    error (:func:`~fusion_pf.score.metrics.uncertainty_coverage` as ``n``, ``within_1_sigma``, ``within_2_sigma``;
    None without ``sigma``)."""
    e = err[np.isfinite(err)]
    counts: dict[str, int] = {}
    for s in states:
        counts[s] = counts.get(s, 0) + 1
    return {
        "rmse_px": rmse(e) if e.size else math.nan,
        "median_px": float(np.median(e)) if e.size else math.nan,
        "p95_px": float(np.percentile(e, 95)) if e.size else math.nan,
        "coverage": float(e.size / n_reference) if n_reference else math.nan,
        "n_reference": n_reference,
        "states": counts,
        "uncertainty": None if sigma is None else coverage_json(uncertainty_coverage(err, sigma)),
    }


def score_targets(table: TargetsTable, truths: dict[str, dict[int, tuple[float, float]]], diagonal_px: float) -> dict:
    """Per target: RMSE, median, p95 (px), coverage, frames per state, uncertainty coverage (with ``table.sigma_px``);
    identity swaps between the two hands."""
    out: dict = {"targets": {}, "swaps": None}
    aligned = {}
    for t, uv in table.uv.items():
        ref = np.array([truths.get(t, {}).get(int(ts), (math.nan, math.nan)) for ts in table.timestamp_ns]).reshape(
            -1, 2
        )
        aligned[t] = ref
        err = np.hypot(*(uv - ref).T)
        out.setdefault("errors", {})[t] = err
        sigma = None if table.sigma_px is None else table.sigma_px[t]
        out["targets"][t] = target_summary(err, int(np.isfinite(ref[:, 0]).sum()), table.states[t], sigma)
    if "right_hand" in table.uv and "left_hand" in table.uv:
        out["swaps"] = count_swaps(
            table.uv["right_hand"],
            table.uv["left_hand"],
            aligned["right_hand"],
            aligned["left_hand"],
            JOINED_FRACTION * diagonal_px,
        )
    return out


def score_targets_recording(
    table: TargetsTable,
    recording: str | Path,
    read_topic: TopicReader,
    frame_size: FrameSize,
    target: str | None = None,
) -> dict:
    """:func:`score_targets` of ``table`` against the ground truth of ``recording``.

    ``frame_size(recording)`` gives its image size (the caller's reader: this package opens no files).
    A single-palm ``recording`` (one palm, no target names) scores one target
    of ``table``: ``target``, else :data:`SINGLE_PALM_TARGET`; the result's
    ``single_palm`` names it (None for a multi-target reference).
    """
    truths, palm = read_truths(str(recording), read_topic)
    if truths and target is not None:
        raise InputError(
            f"--target names the target of a single-palm reference, but {recording} has ground truth per target "
            f"({', '.join(truths)})"
        )
    single = None
    if not truths and palm:
        single = SINGLE_PALM_TARGET if target is None else target
        if single not in table.uv:
            raise InputError(
                f"{recording} has the ground truth of one palm, scored as target {single}, but {table.path} tracks "
                f"{', '.join(table.uv)}; choose one with --target"
            )
        table = TargetsTable(
            table.path,
            table.timestamp_ns,
            {single: table.uv[single]},
            {single: table.states[single]},
            None if table.sigma_px is None else {single: table.sigma_px[single]},
        )
        truths = {single: palm}
    elif not truths:
        raise InputError(
            f"{recording}: no ground truth on /{GROUND_TRUTH_TOPIC}; expected a recording with ground truth"
        )
    w, h = frame_size(recording)
    result = score_targets(table, truths, math.hypot(w, h))
    result["single_palm"] = single
    return result


def read_targets(path: str | Path, read_topic: TopicReader) -> TargetsTable | None:
    """The multi-target output at ``path`` (CSV or MCAP, by its content), or None when it is of one target."""
    if file_kind(path) == "csv":
        return read_targets_csv(path)
    return read_targets_topic(str(path), read_topic)


def targets_markdown(result: dict, tracked: str, reference: str) -> str:
    """The per-target report as Markdown."""
    lines = [
        "## Accuracy per target against ground truth",
        "",
        f"Tracker output `{tracked}`, reference `{reference}`.",
        "",
        "| target | RMSE (px) | median (px) | p95 (px) | coverage | within sigma_px / 2 sigma_px | frames per state |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for t, r in result["targets"].items():
        states = ", ".join(f"{s} {n}" for s, n in sorted(r["states"].items()))
        cov = r["coverage"]
        lines.append(
            f"| {t} | {_fixed(r['rmse_px'], 2)} | {_fixed(r['median_px'], 2)} | {_fixed(r['p95_px'], 2)} | "
            f"{'–' if math.isnan(cov) else f'{100 * cov:.1f} %'} | {within_cell(r['uncertainty'])} | {states} |"
        )
    if result.get("single_palm") is not None:
        lines += [
            "",
            f"The reference holds one palm (no target names): scored as target {result['single_palm']}; "
            "the other targets have no ground truth.",
        ]
    if result["swaps"] is not None:
        lines += [
            "",
            f"Identity swaps between right_hand and left_hand (frames where they are apart): {result['swaps']}.",
        ]
    return "\n".join(lines) + "\n"


def _fixed(x: float, digits: int) -> str:
    """A report cell: ``x`` with ``digits`` decimals, "–" for NaN (a target without an estimate or a reference)."""
    return "–" if math.isnan(x) else f"{x:.{digits}f}"


def within_cell(u: dict | None) -> str:
    """A report cell of an ``uncertainty`` result: "within 1 sigma / within 2 sigma % (n)", "–" without one."""
    if u is None or u["within_2_sigma"] is None:
        return "–"
    return f"{100 * u['within_1_sigma']:.1f} / {100 * u['within_2_sigma']:.1f} % ({u['n']})"


def score_world(
    positions: dict[str, np.ndarray],
    truths: dict[str, np.ndarray],
    states: dict[str, list[str]],
    *,
    min_separation_mm: float = JOINED_MM,
    sigmas: dict[str, np.ndarray] | None = None,
) -> dict:
    """3-D accuracy per target of a multi-camera run against the world ground truth (``/ground_truth/world``).

    Parameters
    ----------
    positions, truths : dict of str to ndarray (n, 3)
        Per target the world estimates and truths of the same ``n`` instants, mm (NaN: none).
    states : dict of str to list of str
        Per target the track state of each instant.
    sigmas : dict of str to ndarray (n,), optional
        Per target the reported uncertainty of each instant (``sigma_mm``, NaN: none).

    Returns
    -------
    dict
        ``targets``: per target ``rmse_mm``, ``median_mm``, ``p95_mm``, ``coverage`` (instants with an estimate
        among those with a truth), ``states``, ``uncertainty`` (with ``sigmas``: ``n``, ``within_1_sigma``,
        ``within_2_sigma``, the shares of the instants with an error and an uncertainty whose 3-D error is within
        one and two ``sigma_mm``, :func:`~fusion_pf.score.metrics.uncertainty_coverage`; else None); ``errors``: per target ``(n,)`` mm (NaN: none); ``swaps`` between
        the hands (None unless both are scored).
    """
    out: dict = {"targets": {}, "errors": {}, "swaps": None}
    for t, p in positions.items():
        ref = truths[t]
        err = np.sqrt(((p - ref) ** 2).sum(axis=1))
        out["errors"][t] = err
        summary = target_summary(
            err, int(np.isfinite(ref[:, 0]).sum()), states[t], None if sigmas is None else sigmas.get(t)
        )
        out["targets"][t] = {
            "rmse_mm": summary["rmse_px"],
            "median_mm": summary["median_px"],
            "p95_mm": summary["p95_px"],
            **{k: summary[k] for k in ("coverage", "n_reference", "states", "uncertainty")},
        }
    if "right_hand" in positions and "left_hand" in positions:
        out["swaps"] = count_swaps(
            positions["right_hand"],
            positions["left_hand"],
            truths["right_hand"],
            truths["left_hand"],
            min_separation_mm,
        )
    return out


@dataclass(frozen=True)
class WorldTable:
    """A multi-camera tracker output: per target ``(n, 3)`` world positions (mm, NaN: none), ``(n,)`` states and
    ``(n,)`` reported uncertainties (``sigma_mm``, NaN: none)."""

    path: str
    timestamp_ns: np.ndarray
    xyz: dict[str, np.ndarray]
    states: dict[str, list[str]]
    sigma_mm: dict[str, np.ndarray]


def _number(value: object) -> float:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else math.nan


def read_world(path: str | Path, read_topic: TopicReader) -> WorldTable | None:
    """The world estimates of a ``track MULTI.mcap`` output (its CSV or ``/tracker/world``), None when it is not one."""
    rows: dict[int, dict[str, tuple[np.ndarray, str, float]]] = {}
    if file_kind(path) == "csv":
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            if not {"target", "x_mm", "cameras"} <= set(reader.fieldnames or ()):
                return None
            for row in reader:
                try:
                    t = int(row["timestamp_ns"])
                    xyz = np.array([float(row[k]) if row[k] else math.nan for k in ("x_mm", "y_mm", "z_mm")])
                    sigma = float(row["sigma_mm"]) if row.get("sigma_mm") else math.nan
                except (KeyError, ValueError, TypeError):
                    raise InputError(
                        f"{path}: a row is not a world estimate (timestamp_ns, x_mm, y_mm, z_mm, sigma_mm): {row}"
                    ) from None
                rows.setdefault(t, {})[row["target"]] = (xyz, row["state"], _uncertainty(path, sigma, row))
    else:
        for t, m in read_topic(str(path), WORLD_TOPIC):
            targets = m.get("targets") if isinstance(m, dict) else None
            if not isinstance(targets, list):
                raise InputError(f"{path}: /tracker/world message at {t} ns has no targets list")
            for item in targets:
                p = item.get("position_mm") if isinstance(item, dict) else None
                xyz = np.array([_number(v) for v in p]) if isinstance(p, list) and len(p) == 3 else np.full(3, math.nan)
                sigma = item.get("sigma_mm")
                if sigma is not None and (isinstance(sigma, bool) or not isinstance(sigma, (int, float))):
                    raise InputError(
                        f"{path}: /tracker/world at {t} ns: sigma_mm must be a number or null, got {sigma!r}"
                    )
                rows.setdefault(int(t), {})[str(item.get("target"))] = (
                    xyz,
                    str(item.get("state", "")),
                    _uncertainty(path, math.nan if sigma is None else float(sigma), item),
                )
    if not rows:
        return None
    ts = np.array(sorted(rows), dtype=np.int64)
    targets = list(dict.fromkeys(t for r in rows.values() for t in r))
    none = (np.full(3, math.nan), "", math.nan)
    positions = {t: np.array([rows[int(k)].get(t, none)[0] for k in ts]).reshape(-1, 3) for t in targets}
    states = {t: [rows[int(k)].get(t, none)[1] for k in ts] for t in targets}
    sigmas = {t: np.array([rows[int(k)].get(t, none)[2] for k in ts], dtype=np.float64) for t in targets}
    return WorldTable(str(path), ts, positions, states, sigmas)


def _uncertainty(path: str | Path, sigma: float, row: object) -> float:
    """A world target's ``sigma_mm``: NaN (none) or a finite number >= 0."""
    if not (math.isnan(sigma) or (math.isfinite(sigma) and sigma >= 0)):
        raise InputError(f"{path}: sigma_mm must be a number >= 0 (mm) or empty, got {sigma!r} in {row}")
    return sigma


def score_world_recording(table: WorldTable, recording: str | Path, read_topic: TopicReader) -> dict:
    """:func:`score_world` of ``table`` against the ``/ground_truth/world`` of the multi-camera ``recording``."""
    truth: dict[str, dict[int, np.ndarray]] = {}
    for t, m in read_topic(str(recording), WORLD_TRUTH_TOPIC):
        p = m.get("xyz_mm") if isinstance(m, dict) else None
        if isinstance(p, list) and len(p) == 3:
            truth.setdefault(str(m.get("target")), {})[int(t)] = np.array([_number(v) for v in p])
    if not truth:
        raise InputError(f"{recording} has no world ground truth (/ground_truth/world)")
    none = np.full(3, math.nan)
    truths = {t: np.array([truth.get(t, {}).get(int(k), none) for k in table.timestamp_ns]) for t in table.xyz}
    return score_world(table.xyz, truths, table.states, sigmas=table.sigma_mm)


def world_markdown(result: dict, tracked: str, reference: str) -> str:
    """The world report as Markdown."""
    lines = [
        "## 3-D accuracy per target against the world ground truth",
        "",
        f"Tracker output `{tracked}`, reference `{reference}` (`/ground_truth/world`).",
        "",
        "| target | RMSE (mm) | median (mm) | p95 (mm) | coverage | within sigma_mm / 2 sigma_mm | instants per state |",
        "|---|---:|---:|---:|---:|---:|---|",
    ]
    for t, r in result["targets"].items():
        states = ", ".join(f"{s} {n}" for s, n in sorted(r["states"].items()))
        cov = r["coverage"]
        lines.append(
            f"| {t} | {_fixed(r['rmse_mm'], 1)} | {_fixed(r['median_mm'], 1)} | {_fixed(r['p95_mm'], 1)} | "
            f"{'–' if math.isnan(cov) else f'{100 * cov:.1f} %'} | {within_cell(r['uncertainty'])} | {states} |"
        )
    if result["swaps"] is not None:
        lines += [
            "",
            f"Identity swaps between right_hand and left_hand (instants where they are apart): {result['swaps']}.",
        ]
    return "\n".join(lines) + "\n"
