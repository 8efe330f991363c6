"""Accuracy metrics of paper 003 §4.4-4.5: per-frame error, RMSE, coverage, p95 and BestMax.

All metrics compare the palm points of several *sources* with a *reference*
(ground truth of a synthetic recording, or the mean of the human operators'
annotations, paper 003 §4.1), frame by frame. The scored sources are the three
cues and the filter's estimate, named as in :data:`SCORED_SOURCES`.

Definitions
-----------
Inputs are aligned arrays over the ``n`` frames of a tracker output: a source's
points ``(n, 2)`` with NaN rows where the source gave no point, and the
reference ``(n, 2)`` with NaN rows where the frame has no reference (a
background frame, a frame every operator marked "not visible").

Per-frame error
    ``e_t = sqrt((u_t - u*_t)^2 + (v_t - v*_t)^2)`` in pixels, the Euclidean
    distance between the source's point and the reference; NaN when either is
    missing.
RMSE
    ``sqrt(mean(e_t^2))`` over the frames where both the source and the
    reference exist; NaN when there is no such frame.
Coverage
    The fraction of reference frames (frames with a reference) where the
    source gave a point; NaN when no frame has a reference.
p95, mean, max
    Of ``e_t`` over the same frames as the RMSE. The 95th percentile uses
    linear interpolation between order statistics (``numpy.percentile``
    default): with the ``m`` errors sorted ascending ``e_(0) <= ... <=
    e_(m-1)``, ``p95 = e_(k) + f (e_(k+1) - e_(k))`` where ``k + f = 0.95 (m - 1)``.
Occlusion split
    When the reference says which frames are occluded (ground truth
    ``occluded`` flag), the RMSE is also reported over occluded frames only and
    over visible frames only, and the occlusion *episodes* (maximal runs of
    consecutive occluded frames) are counted.
BestMax (paper 003 §4.4)
    Per frame, among the sources present, the source with the smallest error
    gets one point; BestMax of a source is its number of points over the
    sequence. Decisions the paper leaves open are made as follows:

    * frames without a reference are skipped (nobody scores);
    * a source missing from a frame cannot score in that frame (the others
      still compete; a frame where every source is missing is skipped);
    * ties: every source whose error is within ``tie_tol`` pixels (default
      1e-6 px) of the frame's smallest error gets a point, so the points of a
      frame can exceed one and the BestMax column can sum to more than the
      number of scored frames. A tie happens in practice when the filter's
      estimate coincides with its only cue. The number of frames with a tie
      is reported.

Uncertainty coverage
    Where the tracker reports an uncertainty per frame with its estimate
    (``sigma_px``, ``sigma_mm`` of a world target), the shares of the frames
    with an error and a finite uncertainty ``s_t`` whose error is within
    ``s_t`` and within ``2 s_t``: whether the uncertainty a user filters frames
    by is honest on their recording (``docs/architecture.md``: the error is
    below ``2 sigma_px`` in about 95 % of the synthetic scenes' frames). NaN
    shares when no such frame exists.

Multi-execution (§4.5) averages BestMax over repeated filter runs with
different seeds; see :mod:`fusion_pf.score.sweep`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from fusion_pf.errors import InputError

#: Sources the scorer compares, in report order: the three cues and the filter estimate.
SCORED_SOURCES = ("colour", "depth", "skeleton", "fused")

#: Default tie tolerance of BestMax, in pixels.
TIE_TOL_PX = 1e-6


def _points(name: str, a: object, n: int | None = None) -> np.ndarray:
    arr = np.asarray(a, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 2:
        raise InputError(f"{name} must be an (n, 2) array of (u, v) pixels, got shape {arr.shape}")
    if n is not None and arr.shape[0] != n:
        raise InputError(f"{name} must have {n} rows (one per frame), got {arr.shape[0]}")
    if np.isinf(arr).any():
        raise InputError(f"{name} must be finite or NaN (missing), got an infinite value")
    return arr


def frame_errors(points: object, reference: object) -> np.ndarray:
    """Per-frame Euclidean error between a source's points and the reference.

    Parameters
    ----------
    points : array_like, shape (n, 2)
        The source's ``(u, v)`` per frame in pixels, NaN where it gave no point.
    reference : array_like, shape (n, 2)
        The reference ``(u, v)`` per frame, NaN where the frame has none.

    Returns
    -------
    ndarray, shape (n,)
        ``e_t`` in pixels; NaN where the source or the reference is missing.
    """
    ref = _points("reference", reference)
    pts = _points("points", points, ref.shape[0])
    d = pts - ref
    return np.hypot(d[:, 0], d[:, 1])


def rmse(errors: object) -> float:
    """Root mean square of the finite values of ``errors`` (NaN when there is none)."""
    e = np.asarray(errors, dtype=np.float64)
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e * e))) if e.size else math.nan


def bestmax_points(errors: Mapping[str, object], tie_tol: float = TIE_TOL_PX) -> dict[str, np.ndarray]:
    """BestMax points per frame (paper 003 §4.4), ties rewarded to every tied source.

    Parameters
    ----------
    errors : mapping of str to array_like, shape (n,)
        Per-frame errors of each competing source, NaN where the source (or the
        reference) is missing.
    tie_tol : float
        Errors within ``tie_tol`` pixels of the frame's smallest error tie.

    Returns
    -------
    dict of str to ndarray, shape (n,), int64
        1 where the source won (or tied for) the frame, else 0. Only frames
        where at least two sources compete give points: a source that is
        alone in a frame did not beat anybody (those frames are counted by
        :func:`uncontested_frames`).
    """
    if not errors:
        raise InputError("bestmax needs at least one source, got none")
    if not (isinstance(tie_tol, (int, float)) and math.isfinite(tie_tol) and tie_tol >= 0):
        raise InputError(f"tie_tol must be a finite number >= 0 pixels, got {tie_tol!r}")
    names = list(errors)
    arrays = [np.asarray(errors[k], dtype=np.float64) for k in names]
    shapes = sorted({a.shape for a in arrays})
    if len(shapes) != 1 or len(shapes[0]) != 1:
        raise InputError(f"errors must be 1-D arrays of one length, got shapes {shapes}")
    e = np.stack(arrays)
    present = np.isfinite(e)
    best = np.min(np.where(present, e, np.inf), axis=0)
    # a point needs a contest: at least two sources in the frame
    won = present & (e <= best + tie_tol) & (present.sum(axis=0) >= 2)
    return {k: won[i].astype(np.int64) for i, k in enumerate(names)}


def uncontested_frames(errors: Mapping[str, object]) -> dict[str, int]:
    """Frames where each source was the only one with an error (no BestMax point: nobody to beat)."""
    names = list(errors)
    present = np.isfinite(np.stack([np.asarray(errors[k], dtype=np.float64) for k in names]))
    alone = present & (present.sum(axis=0) == 1)
    return {k: int(alone[i].sum()) for i, k in enumerate(names)}


def bestmax(errors: Mapping[str, object], tie_tol: float = TIE_TOL_PX) -> dict[str, int]:
    """BestMax score of each source: its number of won (or tied) frames.

    See :func:`bestmax_points` for the parameters and the rules.
    """
    return {k: int(p.sum()) for k, p in bestmax_points(errors, tie_tol).items()}


def occlusion_episodes(occluded: object) -> np.ndarray:
    """Maximal runs of consecutive occluded frames.

    Parameters
    ----------
    occluded : array_like of bool, shape (n,)

    Returns
    -------
    ndarray, shape (k, 2), int64
        ``[start, stop)`` frame-row indices of each episode, in order.
    """
    occ = np.asarray(occluded, dtype=bool).astype(np.int8)
    edges = np.diff(np.concatenate([[0], occ, [0]]))
    return np.stack([np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)], axis=1).astype(np.int64)


@dataclass(frozen=True)
class SourceScore:
    """The summary metrics of one source (pixels unless stated).

    Attributes
    ----------
    rmse, mean, p95, max : float
        Over frames where both the source and the reference exist (NaN if none).
    coverage : float
        Fraction of reference frames where the source gave a point, in [0, 1].
    n_scored : int
        Frames where both the source and the reference exist.
    bestmax : int
        BestMax points (paper 003 §4.4; ties give each tied source a point;
        frames with one source give none).
    uncontested : int
        Frames where this source was the only one present (no BestMax point).
    rmse_occluded, rmse_visible : float
        RMSE over occluded / visible reference frames (NaN when unknown or empty).
    """

    rmse: float
    mean: float
    p95: float
    max: float
    coverage: float
    n_scored: int
    bestmax: int
    uncontested: int
    rmse_occluded: float
    rmse_visible: float


@dataclass(frozen=True)
class Coverage:
    """How often an estimate's reported uncertainty covers its error (module docstring, *Uncertainty coverage*).

    Attributes
    ----------
    n : int
        Frames with an error and a finite uncertainty.
    within_1, within_2 : float
        Shares of them whose error is at most one and two uncertainties (NaN when ``n`` is 0).
    """

    n: int
    within_1: float
    within_2: float


def uncertainty_coverage(errors: object, sigma: object) -> Coverage:
    """The :class:`Coverage` of per-frame ``errors`` ``(n,)`` by the per-frame uncertainties ``sigma`` ``(n,)``
    (same unit; NaN where missing)."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1)
    s = np.asarray(sigma, dtype=np.float64).reshape(-1)
    if e.shape != s.shape:
        raise InputError(f"sigma must have one value per frame ({e.size}), got {s.size}")
    if (s < 0).any():
        raise InputError(f"an uncertainty must be >= 0, got {float(s[s < 0][0])!r}")
    ok = np.isfinite(e) & np.isfinite(s)
    n = int(ok.sum())
    if n == 0:
        return Coverage(0, math.nan, math.nan)
    return Coverage(n, float((e[ok] <= s[ok]).mean()), float((e[ok] <= 2.0 * s[ok]).mean()))


@dataclass(frozen=True)
class Score:
    """Everything the scorer computes for one tracker output.

    Attributes
    ----------
    sources : tuple of str
        Scored sources in report order.
    errors : dict of str to ndarray, shape (n,)
        Per-frame error of each source (NaN where not scored).
    bestmax_points : dict of str to ndarray, shape (n,)
        Per-frame BestMax points of each source.
    summary : dict of str to SourceScore
    n_frames : int
        Rows of the tracker output.
    n_reference : int
        Rows with a reference point.
    n_bestmax_frames : int
        Rows where at least one source competed for BestMax.
    n_ties : int
        Rows where two or more sources tied for BestMax.
    n_occluded : int or None
        Reference rows flagged occluded (None when the reference has no flag).
    occlusion_episodes : ndarray, shape (k, 2)
        ``[start, stop)`` row indices of the runs of consecutive occluded
        flags (empty when unknown).
    tie_tol : float
        The BestMax tie tolerance used, in pixels.
    uncertainty : Coverage or None
        The ``fused`` estimate's :func:`uncertainty_coverage` by its ``sigma_px`` (None when the output has none).
    """

    sources: tuple[str, ...]
    errors: dict[str, np.ndarray]
    bestmax_points: dict[str, np.ndarray]
    summary: dict[str, SourceScore]
    n_frames: int
    n_reference: int
    n_bestmax_frames: int
    n_ties: int
    n_occluded: int | None
    occlusion_episodes: np.ndarray
    tie_tol: float
    uncertainty: Coverage | None = None


def score(
    points: Mapping[str, object],
    reference: object,
    occluded: object | None = None,
    *,
    tie_tol: float = TIE_TOL_PX,
    sigma: object | None = None,
) -> Score:
    """Score each source's points against the reference.

    Parameters
    ----------
    points : mapping of str to array_like, shape (n, 2)
        Per source, ``(u, v)`` per frame in pixels, NaN rows where missing.
        The mapping's order is the report order.
    reference : array_like, shape (n, 2)
        Reference ``(u, v)`` per frame, NaN rows where the frame has none.
    occluded : array_like of bool, shape (n,), or None
        Ground-truth occlusion flag per frame, None when unknown.
    tie_tol : float
        BestMax tie tolerance in pixels.
    sigma : array_like, shape (n,), or None
        The ``fused`` estimate's reported uncertainty per frame in pixels (``sigma_px``, NaN where none), for
        :attr:`Score.uncertainty`.

    Returns
    -------
    Score
    """
    if not points:
        raise InputError("score needs at least one source, got none")
    ref = _points("reference", reference)
    n = ref.shape[0]
    has_ref = np.isfinite(ref).all(axis=1)
    if np.isnan(ref[~has_ref]).sum() != 2 * int((~has_ref).sum()):
        raise InputError("reference rows must be both finite or both NaN (missing)")
    occ = episodes = None
    if occluded is not None:
        flags = np.asarray(occluded, dtype=bool)
        if flags.shape != (n,):
            raise InputError(f"occluded must have shape ({n},) (one flag per frame), got {flags.shape}")
        episodes = occlusion_episodes(flags)
        occ = flags & has_ref
    errors = {k: frame_errors(_points(f"{k} points", p, n), ref) for k, p in points.items()}
    won = bestmax_points(errors, tie_tol)
    alone = uncontested_frames(errors)
    stack = np.stack([won[k] for k in errors])
    n_ref = int(has_ref.sum())
    summary = {}
    for k, e in errors.items():
        ok = np.isfinite(e)
        sel = e[ok]
        summary[k] = SourceScore(
            rmse=rmse(sel),
            mean=float(sel.mean()) if sel.size else math.nan,
            p95=float(np.percentile(sel, 95)) if sel.size else math.nan,
            max=float(sel.max()) if sel.size else math.nan,
            coverage=float(ok.sum() / n_ref) if n_ref else math.nan,
            n_scored=int(ok.sum()),
            bestmax=int(won[k].sum()),
            uncontested=alone[k],
            rmse_occluded=rmse(e[occ]) if occ is not None else math.nan,
            rmse_visible=rmse(e[has_ref & ~occ]) if occ is not None else math.nan,
        )
    return Score(
        sources=tuple(errors),
        errors=errors,
        bestmax_points=won,
        summary=summary,
        n_frames=n,
        n_reference=n_ref,
        n_bestmax_frames=int((stack.sum(axis=0) > 0).sum()),
        n_ties=int((stack.sum(axis=0) > 1).sum()),
        n_occluded=int(occ.sum()) if occ is not None else None,
        occlusion_episodes=episodes if episodes is not None else np.zeros((0, 2), np.int64),
        tie_tol=float(tie_tol),
        uncertainty=None if sigma is None else uncertainty_coverage(errors.get("fused", np.full(n, math.nan)), sigma),
    )
