"""Kalman-filter baseline (``--filter kf``): the particle filter's model, solved exactly.

Same state ``(u, v, du, dv)``, the same constant-velocity model (eq. 4 with
``Q = diag(pos^2, pos^2, vel^2, vel^2) dt``, see :mod:`fusion_pf.filter.motion`)
and the same initialisation as :class:`~fusion_pf.filter.pf.ParticleFilter`;
each available measurement of a frame is fused by a sequential update with
``H = [I2 0]`` and ``R = noise_px[source]^2 I2``. Because the Gaussian model is
linear, this is the optimal filter the particle filter approximates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement

from .base import Estimate, Tracker, check_prior, check_timestamp, fused_position
from .likelihood import DEFAULT_NOISE_PX, JointLikelihood
from .motion import DEFAULT_PROCESS_NOISE, FrameClock, check_process_noise, process_covariance, transition_matrix

__all__ = ["KalmanFilter"]

_H = np.hstack([np.eye(2), np.zeros((2, 2))])


class KalmanFilter(Tracker):
    """Constant-velocity Kalman filter fusing the cues sequentially.

    Parameters
    ----------
    process_noise : (float, float)
        ``(pos_px, vel_px)`` per frame step, as for the particle filter.
    noise_px : mapping of str to float
        Per-source measurement noise sigma in px; ``R = sigma^2 I2``.
    init_spread_px, init_velocity_px : float
        Initial position / velocity standard deviations (``P0`` diagonal).
    prior : (u, v) or (u, v, du, dv), optional
        State at the first step (which therefore does not predict); without it
        the filter waits for the first measurement.
    frame_period_ns : float, "auto" or None
        As for the particle filter: ``dt`` per step is 1 unless given.

    Attributes
    ----------
    x : ndarray, shape (4,)
        State mean after the last step.
    P : ndarray, shape (4, 4)
        State covariance after the last step.
    """

    def __init__(
        self,
        *,
        process_noise: tuple[float, float] = DEFAULT_PROCESS_NOISE,
        noise_px: Mapping[str, float] = DEFAULT_NOISE_PX,
        init_spread_px: float = 20.0,
        init_velocity_px: float = 2.0,
        prior=None,
        frame_period_ns: float | str | None = None,
    ) -> None:
        for name, value in (("init_spread_px", init_spread_px), ("init_velocity_px", init_velocity_px)):
            if not (math.isfinite(float(value)) and float(value) >= 0.0):
                raise InputError(f"{name} must be a finite number >= 0, got {value}")
        self.process_noise = check_process_noise(process_noise)
        self._like = JointLikelihood(noise_px)
        self.noise_px = self._like.noise_px
        self.init_spread_px = float(init_spread_px)
        self.init_velocity_px = float(init_velocity_px)
        start = check_prior(prior)
        self._clock = FrameClock(frame_period_ns)
        self.frame_period_ns = self._clock.frame_period_ns
        self.reset(start)

    def set_process_noise(self, process_noise: tuple[float, float]) -> None:
        """Change the process noise ``(pos px, vel px/frame)`` from the next step on."""
        self.process_noise = check_process_noise(process_noise)

    def reset(self, prior=None) -> None:
        """Forget the state and any earlier prior (the :meth:`~fusion_pf.filter.base.Tracker.reset` contract): start at
        ``prior`` (``(u, v)`` or ``(u, v, du, dv)``) when given, else from the next measurement. A prior kept across
        resets started the filter that re-acquires a lost palm at its last start, wherever the palm came back."""
        start = check_prior(prior)
        self._last_ns: int | None = None
        self.x = np.zeros(4)
        self.P = np.eye(4)
        self.initialised = False
        if start is not None:
            self._initialise(start)

    def _initialise(self, centre: np.ndarray) -> None:
        """``x0 = centre``, ``P0 = diag(spread^2, spread^2, vel^2, vel^2)``."""
        self.x = np.array(centre, dtype=np.float64)
        s, v = self.init_spread_px, self.init_velocity_px
        self.P = np.diag([s * s, s * s, v * v, v * v])
        self.initialised = True

    def predict(self, dt: float = 1.0) -> None:
        """Constant-velocity prediction (eq. 4 in expectation)."""
        f = transition_matrix(dt)
        # x = F x
        self.x = f @ self.x
        # P = F P F' + Q
        self.P = f @ self.P @ f.T + process_covariance(self.process_noise, dt)

    def update(self, measurement: Measurement) -> None:
        """One sequential measurement update with ``R = sigma_source^2 I2`` (Joseph form)."""
        sigma = self.noise_px[measurement.source]
        r = np.eye(2) * (sigma * sigma)
        # y = z - H x
        y = np.array([measurement.u, measurement.v]) - _H @ self.x
        # S = H P H' + R
        s = _H @ self.P @ _H.T + r
        # K = P H' S^-1
        k = np.linalg.solve(s, _H @ self.P).T
        # x = x + K y
        self.x = self.x + k @ y
        i_kh = np.eye(4) - k @ _H
        # P = (I - K H) P (I - K H)' + K R K'
        self.P = i_kh @ self.P @ i_kh.T + k @ r @ k.T

    def step(self, timestamp_ns: int, measurements: Sequence[Measurement]) -> Estimate | None:
        """Predict to ``timestamp_ns`` and fuse ``measurements`` one after another.

        Returns
        -------
        Estimate or None
            ``ess`` nan, ``n_particles`` 0, ``particles`` None, ``cov`` the
            position block of ``P``; None until initialised.
        """
        t = check_timestamp(timestamp_ns, self._last_ns)
        ms = self._like.check(measurements)
        if not self.initialised:
            if not ms:
                return None
            sigma = {m.source: self.noise_px[m.source] for m in ms}
            self._initialise(np.concatenate([fused_position(ms, sigma), [0.0, 0.0]]))
        elif self._last_ns is not None:
            self.predict(self._clock.steps(t, self._last_ns))
        self._last_ns = t
        for m in ms:
            self.update(m)
        return Estimate(
            timestamp_ns=t,
            u=float(self.x[0]),
            v=float(self.x[1]),
            ess=math.nan,
            resampled=False,
            n_particles=0,
            cov=self.P[:2, :2].copy(),
            particles=None,
        )
