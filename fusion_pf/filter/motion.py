"""Constant-velocity motion model (paper 003 §3.4, eq. 4).

State ``x = (u, v, du, dv)``: palm centre in colour pixels and its velocity in
pixels per *frame step*. Eq. 4, ``x_k = M x_(k-1) + gamma (x) sigma_x``, uses
``M = [[I2, I2], [0, I2]]``, i.e. a unit time step. fusion-pf keeps that unit: by
default every :meth:`~fusion_pf.filter.pf.ParticleFilter.step` is one step
(``dt = 1``), whatever the timestamps. With a frame period the step becomes
``dt = (t_k - t_(k-1)) / period`` so dropped frames are bridged; ``M`` then has
``dt I2`` in its upper-right block and the noise standard deviations grow with
``sqrt(dt)`` (a random walk over ``dt`` unit steps). With ``"auto"`` the period is
learnt from the stream (:class:`FrameClock`): a steady source steps by exactly 1,
a gap of k periods by k.

The noise ``gamma (x) sigma_x`` of eq. 4 is an independent zero-mean Gaussian
per state component with standard deviations ``(pos, pos, vel, vel)`` px
(``process_noise = (pos, vel)``); the Kalman baseline uses the matching
``Q = diag(pos^2, pos^2, vel^2, vel^2) dt``, so both filters share one model.
"""

from __future__ import annotations

import math

import numpy as np

from fusion_pf.errors import InputError

__all__ = ["FrameClock", "check_process_noise", "noise_std", "predict", "process_covariance", "transition_matrix"]


#: Default process noise per frame step: (position px, velocity px/frame) std
#: of eq. 4, tuned with :data:`~fusion_pf.filter.likelihood.DEFAULT_NOISE_PX`.
DEFAULT_PROCESS_NOISE = (3.0, 1.0)


def check_process_noise(process_noise) -> tuple[float, float]:
    """Validate ``process_noise = (pos_px, vel_px)``; both finite and >= 0."""
    try:
        pos, vel = (float(s) for s in process_noise)
    except (TypeError, ValueError):
        raise InputError(
            f"process_noise must be a pair (pos_px, vel_px) of numbers >= 0, got {process_noise!r}"
        ) from None
    for name, s in (("position", pos), ("velocity", vel)):
        if not (math.isfinite(s) and s >= 0.0):
            raise InputError(f"process_noise {name} std must be a finite number >= 0 px, got {s}")
    return pos, vel


def transition_matrix(dt: float = 1.0) -> np.ndarray:
    """The constant-velocity coefficient matrix ``M`` of eq. 4.

    Parameters
    ----------
    dt : float
        Step length in frame steps (1 in the paper).

    Returns
    -------
    ndarray, shape (4, 4)
        ``[[I2, dt I2], [0, I2]]``.
    """
    m = np.eye(4)
    # M = [[I2, dt I2], [0_2, I2]]
    m[0, 2] = m[1, 3] = dt
    return m


def noise_std(process_noise, dt: float = 1.0) -> np.ndarray:
    """Per-component standard deviations of the eq. 4 noise over one step.

    Parameters
    ----------
    process_noise : (float, float)
        ``(pos_px, vel_px)`` per unit step.
    dt : float
        Step length in frame steps.

    Returns
    -------
    ndarray, shape (4,)
        ``(pos, pos, vel, vel) * sqrt(dt)``.
    """
    pos, vel = check_process_noise(process_noise)
    # gamma = (pos, pos, vel, vel) sqrt(dt)
    return np.array([pos, pos, vel, vel]) * math.sqrt(dt)


def process_covariance(process_noise, dt: float = 1.0) -> np.ndarray:
    """Covariance ``Q`` of the eq. 4 noise (the Kalman baseline's process noise).

    Returns
    -------
    ndarray, shape (4, 4)
        ``diag(pos^2, pos^2, vel^2, vel^2) dt``.
    """
    # Q = diag(gamma^2)
    return np.diag(noise_std(process_noise, dt) ** 2)


def predict(
    state_t: np.ndarray,
    std: np.ndarray,
    rng: np.random.Generator,
    *,
    dt: float = 1.0,
    scratch: np.ndarray | None = None,
) -> None:
    """Move particles one step with eq. 4, in place.

    Parameters
    ----------
    state_t : ndarray, shape (4, N)
        Particles stored *transposed* (one contiguous row per state component,
        so every column operation streams); ``particles = state_t.T`` is the
        usual ``(N, 4)`` view. Modified in place.
    std : ndarray, shape (4,)
        Noise standard deviations from :func:`noise_std`.
    rng : numpy.random.Generator
        Random source.
    dt : float
        Step length in frame steps.
    scratch : ndarray, shape (4, N), optional
        Preallocated buffer for the noise draw (avoids an allocation per step).
    """
    if scratch is None:
        scratch = np.empty_like(state_t)
    # x_pos <- x_pos + dt x_vel   (M x)
    if dt == 1.0:
        state_t[:2] += state_t[2:]
    else:
        state_t[:2] += dt * state_t[2:]
    # components without noise (std (pos, pos, vel, vel) of 0) draw nothing
    lo = 0 if std[0] > 0.0 else 2
    hi = 4 if std[2] > 0.0 else 2
    if lo >= hi:
        return
    noise = scratch[lo:hi]
    rng.standard_normal(out=noise)
    # x <- M x + gamma (x) sigma_x,  sigma_x ~ N(0, I)
    noise *= std[lo:hi, None]
    state_t[lo:hi] += noise


class FrameClock:
    """Turns frame timestamps into eq. 4 step lengths ``dt`` (in frame steps).

    Parameters
    ----------
    frame_period_ns : float, "auto" or None
        None: every step is one frame step, whatever the timestamps (paper
        003). A number: ``dt = (t_k - t_(k-1)) / frame_period_ns``. ``"auto"``:
        the period is the shortest interval seen so far and ``dt`` is the
        interval in whole periods, at least 1, so a steady source gives
        ``dt = 1`` exactly (timing jitter below half a period is ignored) and a
        gap of k frame periods (k - 1 dropped frames) gives ``dt = k``.
    """

    def __init__(self, frame_period_ns: float | str | None = None) -> None:
        if frame_period_ns is not None and frame_period_ns != "auto":
            if isinstance(frame_period_ns, (str, bool)) or not (
                isinstance(frame_period_ns, (int, float, np.integer, np.floating))
                and math.isfinite(frame_period_ns)
                and frame_period_ns > 0
            ):
                raise InputError(f"frame_period_ns must be a number > 0, 'auto' or None, got {frame_period_ns!r}")
            frame_period_ns = float(frame_period_ns)
        self.frame_period_ns = frame_period_ns
        self._shortest: int | None = None

    def steps(self, t: int, last_ns: int | None) -> float:
        """``dt`` from the previous step at ``last_ns`` to ``t`` (1 for the first step)."""
        if self.frame_period_ns is None or last_ns is None:
            return 1.0
        gap = t - last_ns
        if not isinstance(self.frame_period_ns, str):  # a number; the only str is "auto"
            # dt = (t_k - t_(k-1)) / period
            return gap / self.frame_period_ns
        self._shortest = gap if self._shortest is None else min(self._shortest, gap)
        # dt = round((t_k - t_(k-1)) / shortest interval), at least one step
        return float(max(1, round(gap / self._shortest)))
