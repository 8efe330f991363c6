"""Scoring of tracker outputs (paper 003 §4.4-4.6): RMSE, coverage, BestMax, sweeps, figures.

* :mod:`~fusion_pf.score.metrics` — per-frame error, RMSE, p95, coverage, BestMax (definitions);
* :mod:`~fusion_pf.score.inputs` — tracker CSV/MCAP, ground truth, annotations, alignment;
* :mod:`~fusion_pf.score.sweep` — particle-count sweeps and multi-execution in a process pool;
* :mod:`~fusion_pf.score.plots` — Figures 8-10 and the per-frame error figure;
* :mod:`~fusion_pf.score.report` — Markdown and JSON tables;
* :mod:`~fusion_pf.score.evaluate` — file in, report out (what ``fusion-pf score`` runs).
"""

from .evaluate import Evaluation, evaluate, read_reference, write_report
from .inputs import Reference, TrackTable, align, read_annotations, read_ground_truth, read_tracker
from .metrics import SCORED_SOURCES, Score, SourceScore, bestmax, bestmax_points, frame_errors, rmse, score
from .sweep import PAPER_PARTICLE_COUNTS, PAPER_RUNS, SweepResult, run_sweep, sweep_recording

__all__ = [
    "PAPER_PARTICLE_COUNTS",
    "PAPER_RUNS",
    "SCORED_SOURCES",
    "Evaluation",
    "Reference",
    "Score",
    "SourceScore",
    "SweepResult",
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
    "run_sweep",
    "score",
    "sweep_recording",
    "write_report",
]
