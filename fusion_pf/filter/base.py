"""The filter contract: measurements in, a palm estimate out, one frame at a time.

State convention: ``x = (u, v, du, dv)`` in pixels and pixels per frame step;
particle sets are ``(N, 4)`` arrays, positions ``(N, 2)``, log-weights ``(N,)``.
Fusing sources is a sum of ``(N,)`` log-likelihood arrays (paper 003 eq. 7 in
log space). A source missing from a frame contributes nothing.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Mapping, Sequence

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Estimate, Measurement

__all__ = ["Estimate", "Measurement", "Tracker", "check_prior", "check_timestamp", "fused_position"]


class Tracker(abc.ABC):
    """A recursive palm filter (particle filter or Kalman baseline)."""

    #: Whether the filter holds a state (a prior or a first measurement was given).
    initialised: bool

    @abc.abstractmethod
    def step(self, timestamp_ns: int, measurements: Sequence[Measurement]) -> Estimate | None:
        """Predict to ``timestamp_ns`` and update with ``measurements``.

        Returns None while the filter is not initialised (no measurement and no
        prior yet).
        """

    noise_px: dict[str, float]
    process_noise: tuple[float, float]

    @abc.abstractmethod
    def set_process_noise(self, process_noise: tuple[float, float]) -> None:
        """Change the process noise ``(pos px, vel px/frame)`` from the next step on."""

    def set_noise(self, source: str, sigma_px: float) -> None:
        """Change the measurement noise of ``source`` from the next step on (sigma in px, > 0)."""
        if source not in self.noise_px:
            raise InputError(f"unknown source {source!r}; the filter fuses {', '.join(self.noise_px)}")
        s = float(sigma_px)
        if not (math.isfinite(s) and s > 0.0):
            raise InputError(f"noise of {source} must be a finite number > 0 px, got {sigma_px!r}")
        self.noise_px[source] = s

    @abc.abstractmethod
    def reset(self, prior=None) -> None:
        """Forget the state; re-initialise at ``prior`` ``(u, v)`` if given, else from the next measurement."""


def check_prior(prior) -> np.ndarray | None:
    """Validate ``prior``: None, ``(u, v)`` or ``(u, v, du, dv)``; returns a (4,) array or None."""
    if prior is None:
        return None
    p = np.asarray(prior, dtype=np.float64).ravel()
    if p.shape not in ((2,), (4,)) or not np.isfinite(p).all():
        raise InputError(f"prior must be finite (u, v) or (u, v, du, dv), got {prior!r}")
    return np.concatenate([p, np.zeros(4 - p.shape[0])])


def fused_position(measurements: Sequence[Measurement], sigma: Mapping[str, float]) -> np.ndarray:
    """Precision-weighted mean of measurements, ``sum z_s / sigma_s^2 / sum 1 / sigma_s^2``.

    Returns
    -------
    ndarray, shape (2,)
    """
    prec = np.array([1.0 / sigma[m.source] ** 2 for m in measurements])
    z = np.array([[m.u, m.v] for m in measurements])
    # z_bar = sum_s z_s / sigma_s^2 / sum_s 1 / sigma_s^2
    return prec @ z / prec.sum()


def check_timestamp(timestamp_ns, last_ns: int | None) -> int:
    """Validate a step's timestamp: an int, later than the previous step's."""
    if isinstance(timestamp_ns, bool) or not isinstance(timestamp_ns, (int, np.integer)):
        raise InputError(f"timestamp_ns must be an int (nanoseconds), got {timestamp_ns!r}")
    t = int(timestamp_ns)
    if last_ns is not None and t <= last_ns:
        raise InputError(f"timestamp_ns must increase, got {t} after {last_ns}")
    return t
