"""Markdown and JSON renderings of a :class:`~fusion_pf.score.metrics.Score` and a sweep.

Markdown is for people (stdout, ``score.md``); JSON is for programs
(``--json``, ``score.json``). In JSON, NaN (a metric with no frame to compute
it on, a missing per-frame error) is ``null``; distances are pixels, times
seconds or milliseconds as the key says.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from .metrics import Coverage, Score

if TYPE_CHECKING:
    from ..experiments.sweep import SweepResult

_LABELS = {"colour": "colour", "depth": "depth", "skeleton": "skeleton", "fused": "fused (DF-PF)"}


def _num(x: float, fmt: str = ".2f") -> str:
    return "–" if x is None or not math.isfinite(x) else format(x, fmt)


def json_number(x: float) -> float | None:
    """``x`` as a float for JSON, None when it is NaN or infinite."""
    x = float(x)
    return x if math.isfinite(x) else None


def coverage_json(c: Coverage) -> dict:
    """A :class:`~fusion_pf.score.metrics.Coverage` as JSON: ``n``, ``within_1_sigma``, ``within_2_sigma``."""
    return {"n": c.n, "within_1_sigma": json_number(c.within_1), "within_2_sigma": json_number(c.within_2)}


def _jlist(a: np.ndarray) -> list:
    a = np.asarray(a, dtype=np.float64)
    return [None if not math.isfinite(x) else round(x, 4) for x in a.tolist()]


def score_markdown(result: Score, tracker: str, reference: str, reference_kind: str) -> str:
    """Markdown section with the per-source table of a score.

    Parameters
    ----------
    result : Score
    tracker, reference : str
        Paths of the scored tracker output and the reference.
    reference_kind : str
        ``"ground truth"`` or ``"annotations"``.

    Returns
    -------
    str
    """
    occ = result.n_occluded is not None
    lines = [
        f"## Accuracy against {reference_kind}",
        "",
        f"Tracker output `{tracker}` ({result.n_frames} frames), reference `{reference}` "
        f"({result.n_reference} frames with a palm"
        + (f", {result.n_occluded} occluded in {len(result.occlusion_episodes)} episodes" if occ else "")
        + ").",
        "",
        "| source | RMSE (px) | mean (px) | p95 (px) | max (px) | coverage | BestMax | alone |"
        + (" RMSE occluded (px) | RMSE visible (px) |" if occ else ""),
        "|---|---:|---:|---:|---:|---:|---:|---:|" + ("---:|---:|" if occ else ""),
    ]
    for s in result.sources:
        m = result.summary[s]
        row = (
            f"| {_LABELS.get(s, s)} | {_num(m.rmse)} | {_num(m.mean)} | {_num(m.p95)} | {_num(m.max)} "
            f"| {_num(100 * m.coverage, '.1f')} % | {m.bestmax} | {m.uncontested} |"
        )
        if occ:
            row += f" {_num(m.rmse_occluded)} | {_num(m.rmse_visible)} |"
        lines.append(row)
    lines += [
        "",
        f"BestMax (paper 003 §4.4): in each of the {result.n_bestmax_frames} frames with a reference "
        f"and at least two sources, the source(s) with the smallest error score a point; sources within "
        f"{result.tie_tol:g} px of the best tie and each get a point ({result.n_ties} tied frames); "
        "a missing source cannot score, and a source alone in a frame scores nothing (column 'alone'). "
        "Coverage = share of reference frames where the source gave a point; frames without an estimate "
        "(lost, uninitialised) count as missing.",
    ]
    u = result.uncertainty
    if u is not None:
        lines += [
            "",
            f"Reported uncertainty (`sigma_px`): the fused error is within `sigma_px` in {_num(100 * u.within_1, '.1f')} % "
            f"and within `2 sigma_px` in {_num(100 * u.within_2, '.1f')} % of the {u.n} frames with an estimate, a "
            "reference and an uncertainty.",
        ]
    return "\n".join(lines) + "\n"


def sweep_markdown(sweep: SweepResult) -> str:
    """Markdown section with the sweep table: BestMax and fused RMSE per particle count.

    Cells are ``mean ± std`` over the runs (multi-execution, paper 003 §4.5);
    the run-0 values (single execution, Figure 8) follow in brackets.
    """
    mean, std = sweep.mean_bestmax(), sweep.std_bestmax()
    rmse = sweep.mean_rmse()
    fused = sweep.sources.index("fused")
    head = " | ".join(_LABELS.get(s, s) for s in sweep.sources)
    lines = [
        f"## Particle-count sweep ({sweep.runs} runs per N, seed {sweep.seed})",
        "",
        f"BestMax per source, mean ± std over runs [run 0]; {sweep.workers} worker(s), "
        f"{sweep.wall_seconds:.1f} s wall time.",
        "",
        f"| N | {head} | fused RMSE (px) | most BestMax |",
        "|---:|" + "---:|" * len(sweep.sources) + "---:|---|",
    ]
    for c, n in enumerate(sweep.particle_counts):
        cells = " | ".join(
            f"{mean[c, i]:.1f} ± {std[c, i]:.1f} [{sweep.bestmax[c, 0, i]}]" for i in range(len(sweep.sources))
        )
        top = np.flatnonzero(mean[c] == mean[c].max())
        best = ", ".join(_LABELS.get(sweep.sources[i], sweep.sources[i]) for i in top)
        lines.append(f"| {n} | {cells} | {_num(rmse[c, fused])} | {best} |")
    return "\n".join(lines) + "\n"


def score_json(
    result: Score,
    frame: np.ndarray,
    timestamp_ns: np.ndarray,
    *,
    tracker: str,
    reference: str,
    reference_kind: str,
    occluded: np.ndarray | None = None,
) -> dict:
    """JSON-serialisable dict of a score, with the per-frame series.

    Parameters
    ----------
    result : Score
    frame, timestamp_ns : ndarray, shape (n,)
        Of the tracker rows.
    tracker, reference, reference_kind : str
    occluded : ndarray of bool, shape (n,), optional

    Returns
    -------
    dict
    """
    return {
        "tracker": tracker,
        "reference": {"path": reference, "kind": reference_kind},
        "n_frames": result.n_frames,
        "n_reference": result.n_reference,
        "n_occluded": result.n_occluded,
        "occlusion_episodes": result.occlusion_episodes.tolist(),
        "bestmax": {
            "tie_tol_px": result.tie_tol,
            "n_frames": result.n_bestmax_frames,
            "n_ties": result.n_ties,
            "rules": "per frame with a reference, every present source within tie_tol_px of the "
            "smallest error gets one point; missing sources cannot score",
        },
        "sources": {
            s: {
                "rmse_px": json_number(m.rmse),
                "mean_px": json_number(m.mean),
                "p95_px": json_number(m.p95),
                "max_px": json_number(m.max),
                "coverage": json_number(m.coverage),
                "n_scored": m.n_scored,
                "bestmax": m.bestmax,
                "uncontested": m.uncontested,
                "rmse_occluded_px": json_number(m.rmse_occluded),
                "rmse_visible_px": json_number(m.rmse_visible),
            }
            for s, m in result.summary.items()
        },
        "uncertainty": None if result.uncertainty is None else coverage_json(result.uncertainty),
        "per_frame": {
            "frame": np.asarray(frame).tolist(),
            "timestamp_ns": np.asarray(timestamp_ns).tolist(),
            "occluded": None if occluded is None else np.asarray(occluded, dtype=bool).tolist(),
            "error_px": {s: _jlist(e) for s, e in result.errors.items()},
            "bestmax_point": {s: p.tolist() for s, p in result.bestmax_points.items()},
        },
    }


def sweep_json(sweep: SweepResult) -> dict:
    """JSON-serialisable dict of a sweep (per job BestMax and RMSE, and their means)."""
    return {
        "particle_counts": list(sweep.particle_counts),
        "runs": sweep.runs,
        "seed": sweep.seed,
        "seed_rule": "job (N, r) uses numpy.random.default_rng(SeedSequence([seed, N, r]))",
        "sources": list(sweep.sources),
        "workers": sweep.workers,
        "wall_seconds": round(sweep.wall_seconds, 3),
        "tie_tol_px": sweep.tie_tol,
        "bestmax": sweep.bestmax.tolist(),
        "bestmax_mean": np.round(sweep.mean_bestmax(), 4).tolist(),
        "bestmax_std": np.round(sweep.std_bestmax(), 4).tolist(),
        "rmse_px": [[_jlist(r) for r in c] for c in sweep.rmse],
        "rmse_mean_px": [_jlist(c) for c in sweep.mean_rmse()],
        "job_seconds": np.round(sweep.job_seconds, 4).tolist(),
        "axes": "bestmax and rmse_px are [count][run][source]; *_mean are [count][source]",
    }


def figure_list_markdown(paths: Sequence[str]) -> str:
    """Markdown section listing the written figures."""
    return "## Figures\n\n" + "".join(f"- `{p}`\n" for p in paths)
