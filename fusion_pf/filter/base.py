"""The filter contract: measurements in, a palm estimate out, one frame at a time.

State convention: ``x = (u, v, du, dv)`` in pixels and pixels per frame step;
particle sets are ``(N, 4)`` arrays, positions ``(N, 2)``, log-weights ``(N,)``.
Fusing sources is a sum of ``(N,)`` log-likelihood arrays (paper 003 eq. 7 in
log space). A source missing from a frame contributes nothing.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fusion_pf.cues.base import Measurement


@dataclass(frozen=True, slots=True, eq=False)
class Estimate:
    """The filter's palm estimate for one frame.

    Parameters
    ----------
    timestamp_ns : int
        Time of the frame the estimate is for.
    u, v : float
        Estimated palm centre in colour pixels.
    ess : float
        Effective sample size ``1 / sum(w^2)`` before resampling (N/A -> nan for KF).
    resampled : bool
        Whether the particles were resampled in this step.
    n_particles : int
        Particle count (0 for the Kalman filter).
    cov : ndarray, shape (2, 2)
        Position covariance of the posterior (px^2).
    particles : ndarray, shape (N, 2), or None
        Particle positions after the update (None for the Kalman filter).
    """

    timestamp_ns: int
    u: float
    v: float
    ess: float
    resampled: bool
    n_particles: int
    cov: np.ndarray
    particles: np.ndarray | None = None


class Tracker(abc.ABC):
    """A recursive palm filter (particle filter or Kalman baseline)."""

    @abc.abstractmethod
    def step(self, timestamp_ns: int, measurements: Sequence[Measurement]) -> Estimate | None:
        """Predict to ``timestamp_ns`` and update with ``measurements``.

        Returns None while the filter is not initialised (no measurement and no
        prior yet).
        """

    @abc.abstractmethod
    def reset(self) -> None:
        """Forget the state; the next measurement initialises again."""
