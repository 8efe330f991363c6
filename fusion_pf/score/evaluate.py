"""Score a tracker output file against a reference file and write the report.

This is what ``fusion-pf score`` and ``fusion-pf demo`` run:
:func:`evaluate` reads and aligns the files (:mod:`fusion_pf.score.inputs`)
and computes the metrics (:mod:`fusion_pf.score.metrics`);
:func:`write_report` writes the figures (:mod:`fusion_pf.score.plots`) and the
Markdown and JSON tables (:mod:`fusion_pf.score.report`) into a directory.

Files written by :func:`write_report`
-------------------------------------
``errors_per_frame.png``
    per-frame error of each source, occlusion episodes shaded;
``latency_per_frame.png``
    per-stage latency per frame (Figure 10), when the tracker output has
    latency columns;
``bestmax_vs_n.png``, ``multiexec_bestmax.png``
    Figures 8 and 9, when a sweep was run;
``score.md``, ``score.json``
    the tables (see :mod:`fusion_pf.score.report`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from fusion_pf.errors import InputError

from . import plots, report
from .inputs import Reference, TopicReader, TrackTable, align, read_annotations, read_ground_truth, read_tracker
from .metrics import TIE_TOL_PX, Score, score

if TYPE_CHECKING:
    from ..experiments.sweep import SweepResult


@dataclass(frozen=True)
class Evaluation:
    """A scored tracker output.

    Attributes
    ----------
    table : TrackTable
        The tracker output.
    reference : Reference
        The reference as read.
    reference_uv : ndarray, shape (n, 2)
        The reference aligned to the tracker rows (NaN where none).
    occluded : ndarray of bool, shape (n,), or None
        Ground-truth occlusion flags aligned to the tracker rows.
    score : Score
    """

    table: TrackTable
    reference: Reference
    reference_uv: np.ndarray
    occluded: np.ndarray | None
    score: Score


def read_reference(
    reference: str | Path | None = None, ground_truth: str | Path | None = None, read_topic: TopicReader | None = None
) -> Reference:
    """Read the reference: annotations (``reference``) or ground truth (``ground_truth``), exactly one.

    Raises
    ------
    InputError
        When neither or both are given, or the file is not what was expected.
    """
    if (reference is None) == (ground_truth is None):
        raise InputError("give exactly one reference: annotations (--reference) or ground truth (--ground-truth)")
    if reference is not None:
        return read_annotations(reference)
    assert ground_truth is not None, "exactly one is given (checked above)"
    return read_ground_truth(ground_truth, read_topic)


def evaluate(
    tracked: str | Path,
    reference: Reference,
    *,
    tie_tol: float = TIE_TOL_PX,
    read_topic: TopicReader | None = None,
) -> Evaluation:
    """Read a tracker output, align it to ``reference`` and score it.

    Parameters
    ----------
    tracked : str or Path
        Tracker CSV or MCAP.
    reference : Reference
        From :func:`read_reference`.
    tie_tol : float
        BestMax tie tolerance in pixels.
    read_topic : callable, optional
        MCAP topic reader (:data:`~fusion_pf.score.inputs.TopicReader`), needed for an MCAP ``tracked``.

    Returns
    -------
    Evaluation
    """
    table = read_tracker(tracked, read_topic)
    uv, occ = align(table.frame, table.timestamp_ns, reference, name=table.path)
    return Evaluation(table, reference, uv, occ, score(table.points, uv, occ, tie_tol=tie_tol, sigma=table.sigma_px))


def frame_period_ms(timestamp_ns: np.ndarray) -> float | None:
    """Median interval between consecutive timestamps in ms (None with < 2 frames)."""
    ts = np.asarray(timestamp_ns, dtype=np.int64)
    return float(np.median(np.diff(ts))) / 1e6 if ts.size >= 2 else None


def markdown(evaluation: Evaluation, sweep: SweepResult | None = None, figures: list[str] | None = None) -> str:
    """The full Markdown report: accuracy table, then the sweep table and the figure list."""
    ev = evaluation
    parts = [report.score_markdown(ev.score, ev.table.path, ev.reference.path, ev.reference.kind)]
    if sweep is not None:
        parts.append(report.sweep_markdown(sweep))
    if figures:
        parts.append(report.figure_list_markdown(figures))
    return "\n".join(parts)


def as_json(evaluation: Evaluation, sweep: SweepResult | None = None, figures: list[str] | None = None) -> dict:
    """The full JSON report: score (with per-frame series), latency summary, sweep, figures."""
    ev = evaluation
    out = report.score_json(
        ev.score,
        ev.table.frame,
        ev.table.timestamp_ns,
        tracker=ev.table.path,
        reference=ev.reference.path,
        reference_kind=ev.reference.kind,
        occluded=ev.occluded,
    )
    out["latency_ms"] = {
        stage: {
            "mean": report.json_number(np.nanmean(ms)) if np.isfinite(ms).any() else None,
            "p95": report.json_number(np.nanpercentile(ms, 95)) if np.isfinite(ms).any() else None,
            "max": report.json_number(np.nanmax(ms)) if np.isfinite(ms).any() else None,
        }
        for stage, ms in ev.table.latency_ms.items()
    }
    out["sweep"] = report.sweep_json(sweep) if sweep is not None else None
    out["figures"] = list(figures or [])
    return out


#: Every file :func:`write_report` may write into its folder.
REPORT_FILES = (
    "errors_per_frame.png",
    "latency_per_frame.png",
    "bestmax_vs_n.png",
    "multiexec_bestmax.png",
    "score.md",
    "score.json",
)


def write_report(evaluation: Evaluation, out_dir: str | Path, sweep: SweepResult | None = None) -> dict[str, Path]:
    """Write the figures, ``score.md`` and ``score.json`` into ``out_dir``.

    Parameters
    ----------
    evaluation : Evaluation
    out_dir : str or Path
        Created if needed.
    sweep : SweepResult, optional
        Adds Figures 8 and 9 and the sweep table.

    Returns
    -------
    dict of str to Path
        Every file written, by name.
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a directory; expected an output directory")
    out.mkdir(parents=True, exist_ok=True)
    ev = evaluation
    files: dict[str, Path] = {}
    files["errors_per_frame.png"] = plots.plot_errors(
        ev.table.frame,
        ev.score.errors,
        out / "errors_per_frame.png",
        ev.score.occlusion_episodes,
        title=f"Error per frame against {ev.reference.kind} ({Path(ev.table.path).name})",
    )
    if ev.table.latency_ms:
        files["latency_per_frame.png"] = plots.plot_latency(
            ev.table.frame,
            ev.table.latency_ms,
            out / "latency_per_frame.png",
            budget_ms=frame_period_ms(ev.table.timestamp_ns),
        )
    if sweep is not None:
        files["bestmax_vs_n.png"] = plots.plot_bestmax_vs_n(sweep, out / "bestmax_vs_n.png")
        files["multiexec_bestmax.png"] = plots.plot_multiexec(sweep, out / "multiexec_bestmax.png")
    figures = [str(p) for p in files.values()]
    files["score.md"] = out / "score.md"
    files["score.md"].write_text(markdown(ev, sweep, figures))
    files["score.json"] = out / "score.json"
    files["score.json"].write_text(json.dumps(as_json(ev, sweep, figures), indent=1) + "\n")
    return files
