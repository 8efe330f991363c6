"""Data-fusion particle filter (paper 003 §3.2-3.6), resamplers and the Kalman baseline."""

from .base import Estimate, Tracker
from .estimate import ESTIMATORS
from .kf import KalmanFilter
from .likelihood import DEFAULT_NOISE_PX, LIKELIHOODS
from .pf import ParticleFilter
from .resample import RESAMPLERS, ess

__all__ = [
    "DEFAULT_NOISE_PX",
    "ESTIMATORS",
    "LIKELIHOODS",
    "RESAMPLERS",
    "Estimate",
    "KalmanFilter",
    "ParticleFilter",
    "Tracker",
    "ess",
]
