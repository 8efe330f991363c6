"""Experiments on top of the pipeline: particle-count sweeps and multi-execution (paper 003 §4.4-4.5)."""

from .sweep import PAPER_PARTICLE_COUNTS, PAPER_RUNS, SweepResult, job_config, job_seed, parse_counts, run_sweep

__all__ = ["PAPER_PARTICLE_COUNTS", "PAPER_RUNS", "SweepResult", "job_config", "job_seed", "parse_counts", "run_sweep"]
