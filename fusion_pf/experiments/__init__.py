"""Experiments on top of the pipeline: particle-count sweeps and multi-execution (paper 003 §4.4-4.5).

The sweep machinery (:mod:`fusion_pf.experiments.sweep`, which loads the
pipeline and OpenCV) is imported on first use, so the command line can read
the paper's sizes (:mod:`fusion_pf.experiments.paper`) without it.
"""

from .paper import PAPER_PARTICLE_COUNTS, PAPER_RUNS

__all__ = ["PAPER_PARTICLE_COUNTS", "PAPER_RUNS", "SweepResult", "job_config", "job_seed", "parse_counts", "run_sweep"]

_LAZY = ("SweepResult", "job_config", "job_seed", "parse_counts", "run_sweep")


def __getattr__(name: str):
    if name in _LAZY:
        from . import sweep

        return getattr(sweep, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
