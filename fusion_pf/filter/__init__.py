"""Data-fusion particle filter (paper 003 §3.2-3.6), resamplers and the Kalman baseline."""

from .base import Estimate, Tracker

__all__ = ["Estimate", "Tracker"]
