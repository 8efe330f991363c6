"""Scoring of tracker outputs (paper 003 §4.4-4.6): RMSE, coverage, BestMax, figures.

* :mod:`~fusion_pf.score.metrics` — per-frame error, RMSE, p95, coverage, BestMax, uncertainty coverage (definitions);
* :mod:`~fusion_pf.score.inputs` — tracker CSV or topics, ground truth, annotations, alignment;
* :mod:`~fusion_pf.score.plots` — Figures 8-10 and the per-frame error figure;
* :mod:`~fusion_pf.score.report` — Markdown and JSON tables;
* :mod:`~fusion_pf.score.evaluate` — file in, report out (what ``fusion-pf score`` runs).

Sweeps and multi-execution are experiments: :mod:`fusion_pf.experiments`. MCAP files
are read by the caller (``drivers.tracker_topics.read_json_topic``, passed as ``read_topic``).
"""

from .evaluate import Evaluation, evaluate, read_reference, write_report
from .inputs import Reference, TrackTable, align, read_annotations, read_ground_truth, read_tracker
from .metrics import (
    SCORED_SOURCES,
    Coverage,
    Score,
    SourceScore,
    bestmax,
    bestmax_points,
    frame_errors,
    rmse,
    score,
    uncertainty_coverage,
)

__all__ = [
    "SCORED_SOURCES",
    "Coverage",
    "Evaluation",
    "Reference",
    "Score",
    "SourceScore",
    "TrackTable",
    "align",
    "bestmax",
    "bestmax_points",
    "evaluate",
    "frame_errors",
    "read_annotations",
    "read_ground_truth",
    "read_reference",
    "read_tracker",
    "rmse",
    "score",
    "uncertainty_coverage",
    "write_report",
]
