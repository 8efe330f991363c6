"""Scripted palm trajectories with known cue noise, for filter tests and measurements.

:func:`scripted_scenario` draws a smooth ground-truth palm path and, per source,
measurements with Gaussian noise of a known sigma, optional dropouts (frames
where a source gives nothing) and an optional *lying* window where one source is
offset by a fixed vector (e.g. the skeleton snapping to the wrong hand).
:func:`run_tracker` feeds it to any :class:`~fusion_pf.filter.base.Tracker`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement
from fusion_pf.rng import as_rng

from .base import Tracker

__all__ = ["Scenario", "rmse", "run_tracker", "scripted_scenario"]

FRAME_NS = 33_333_333
#: Noise of the simulated cues (px, 1 sigma per axis): colour tightest, skeleton loosest.
SCENARIO_NOISE_PX: Mapping[str, float] = {"colour": 6.0, "depth": 10.0, "skeleton": 15.0}


@dataclass(frozen=True)
class Scenario:
    """A scripted run.

    Attributes
    ----------
    truth : ndarray, shape (T, 2)
        Ground-truth palm centre per frame.
    measurements : dict of str to ndarray, shape (T, 2)
        Per-source cue positions; NaN rows are frames where that source is missing.
    timestamps_ns : ndarray, shape (T,)
        Frame times (30 fps).
    lie_frames : slice
        Frames in which the lying source is offset (empty slice if none).
    """

    truth: np.ndarray
    measurements: dict[str, np.ndarray]
    timestamps_ns: np.ndarray
    lie_frames: slice

    def frame(self, k: int, sources=None) -> list[Measurement]:
        """The measurements of frame ``k`` (only ``sources`` if given; missing ones left out)."""
        out = []
        for s, z in self.measurements.items():
            if (sources is None or s in sources) and np.isfinite(z[k]).all():
                out.append(Measurement(s, float(z[k, 0]), float(z[k, 1])))
        return out


def scripted_scenario(
    n_frames: int = 200,
    *,
    noise_px: Mapping[str, float] = SCENARIO_NOISE_PX,
    dropout: float = 0.0,
    lie_source: str | None = None,
    lie_offset_px: tuple[float, float] = (60.0, 0.0),
    lie_start: int = 80,
    lie_frames: int = 20,
    rng: np.random.Generator | int | None = None,
) -> Scenario:
    """Draw a scripted trajectory and its noisy cues.

    Parameters
    ----------
    n_frames : int
        Number of frames T (>= 2).
    noise_px : mapping of str to float
        Per-source measurement sigma (px per axis).
    dropout : float
        Probability in [0, 1) that a source is missing in a frame.
    lie_source : str, optional
        Source that lies during ``[lie_start, lie_start + lie_frames)``.
    lie_offset_px : (float, float)
        Offset added to the lying source.
    lie_start, lie_frames : int
        The lying window.
    rng : numpy.random.Generator, int or None
        Random source.

    Returns
    -------
    Scenario
    """
    if n_frames < 2:
        raise InputError(f"n_frames must be >= 2, got {n_frames}")
    if not (0.0 <= dropout < 1.0):
        raise InputError(f"dropout must be in [0, 1), got {dropout}")
    if lie_source is not None and lie_source not in noise_px:
        raise InputError(f"lie_source must be one of {', '.join(noise_px)}, got {lie_source!r}")
    rng = as_rng(rng)
    t = np.arange(n_frames, dtype=np.float64)
    # a Lissajous sweep over a 640 x 400 frame: up to ~6 px / frame
    truth = np.stack([320.0 + 150.0 * np.sin(t / 25.0), 200.0 + 100.0 * np.cos(t / 40.0)], axis=1)
    window = slice(lie_start, lie_start + lie_frames) if lie_source is not None else slice(0, 0)
    meas = {}
    for source, sigma in noise_px.items():
        z = truth + rng.normal(0.0, float(sigma), truth.shape)
        if dropout > 0.0:
            z[rng.random(n_frames) < dropout] = np.nan
        if source == lie_source:
            z[window] += np.asarray(lie_offset_px, dtype=np.float64)
        meas[source] = z
    return Scenario(truth, meas, np.arange(n_frames, dtype=np.int64) * FRAME_NS, window)


def run_tracker(tracker: Tracker, scenario: Scenario, sources=None) -> np.ndarray:
    """Run ``tracker`` over ``scenario``; returns (T, 2) estimates (NaN before initialisation)."""
    out = np.full((scenario.truth.shape[0], 2), np.nan)
    for k, ts in enumerate(scenario.timestamps_ns):
        est = tracker.step(int(ts), scenario.frame(k, sources))
        if est is not None:
            out[k] = est.u, est.v
    return out


def rmse(estimates: np.ndarray, truth: np.ndarray, frames: slice = slice(None)) -> float:
    """Root-mean-square Euclidean error over ``frames`` (rows with NaN are skipped)."""
    err = np.sum((estimates[frames] - truth[frames]) ** 2, axis=1)
    return float(np.sqrt(np.nanmean(err)))
