"""Figures of the scorer (paper 003 Figures 8-10), written as PNG with matplotlib's Agg backend.

* :func:`plot_bestmax_vs_n` — BestMax of each source against the particle
  count, single execution (Figure 8);
* :func:`plot_multiexec` — mean BestMax over runs per particle count, with
  ±1 standard deviation (Figure 9);
* :func:`plot_errors` — per-frame error of each source, occlusion episodes
  shaded;
* :func:`plot_latency` — per-stage latency per frame (Figure 10).

Every function takes the data and an output path, writes one PNG and returns
the path. Colours are fixed per source (:data:`SOURCE_STYLE`) across figures.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

#: Colour, marker and label of every scored source, shared by all figures.
SOURCE_STYLE = {
    "colour": {"color": "tab:orange", "marker": "s", "label": "colour cue"},
    "depth": {"color": "tab:blue", "marker": "^", "label": "depth cue"},
    "skeleton": {"color": "tab:green", "marker": "v", "label": "skeleton (camera joint)"},
    "fused": {"color": "black", "marker": "o", "label": "fused (DF-PF estimate)"},
}

#: Colours of scored sources and latency stages without their own style.
_OTHER_COLOURS = ("tab:red", "tab:cyan", "tab:olive", "tab:pink", "tab:brown", "darkgoldenrod")


def _style(table: dict, name: str, marker: bool = True) -> dict:
    """The style of ``name``: its own, else a colour of :data:`_OTHER_COLOURS` chosen by the name."""
    if name in table:
        return table[name]
    colour = _OTHER_COLOURS[sum(map(ord, name)) % len(_OTHER_COLOURS)]
    return {"color": colour, "label": name.replace("_", " "), **({"marker": "D"} if marker else {})}


#: Colour and label of every latency stage.
STAGE_STYLE = {
    "decode": {"color": "tab:gray", "label": "decode"},
    "colour": {"color": "tab:orange", "label": "colour cue"},
    "depth": {"color": "tab:blue", "label": "depth cue"},
    "skeleton": {"color": "tab:green", "label": "skeleton cue"},
    "filter": {"color": "tab:purple", "label": "particle filter"},
    "total": {"color": "black", "label": "total (decode to estimate)"},
    "sinks": {"color": "tab:brown", "label": "writing outputs"},
}


def _figure(width: float = 8.0, height: float = 4.5):
    """A figure and its axes from matplotlib's object API (no pyplot, no global backend)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=110)
    return fig, fig.subplots()


def _legend(ax, ncol: int) -> None:
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=ncol, fontsize=9, frameon=False)


def _save(fig, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, bbox_inches="tight")
    return path


def _contested(sweep) -> int:
    """Frames where at least one source was scored (the frames BestMax awards), most over jobs."""
    return int(np.isfinite(sweep.errors).any(axis=2).sum(axis=-1).max())


def plot_bestmax_vs_n(sweep, path: str | Path, run: int = 0) -> Path:
    """Figure 8: BestMax of each source against the particle count, one execution.

    Parameters
    ----------
    sweep : SweepResult
    path : str or Path
        PNG to write.
    run : int
        Which run is the single execution (default the first).

    Returns
    -------
    Path
    """
    fig, ax = _figure()
    x = np.arange(len(sweep.particle_counts))
    for i, s in enumerate(sweep.sources):
        st = _style(SOURCE_STYLE, s)
        ax.plot(
            x,
            sweep.bestmax[:, run, i],
            marker=st["marker"],
            color=st["color"],
            label=st["label"],
            linewidth=2.2 if s == "fused" else 1.4,
        )
    ax.set_xticks(x, [str(n) for n in sweep.particle_counts])
    ax.set_xlabel("number of particles N")
    ax.set_ylabel(f"BestMax (frames won of {_contested(sweep)}; ties to each)")
    ax.set_title(f"BestMax vs particle count, single execution (run {run}, seed {sweep.seed})")
    ax.grid(alpha=0.3)
    ax.set_ylim(bottom=0)
    _legend(ax, 4)
    return _save(fig, path)


def plot_multiexec(sweep, path: str | Path) -> Path:
    """Figure 9: multi-execution mean BestMax per particle count, bars ±1 std over runs.

    Parameters
    ----------
    sweep : SweepResult
    path : str or Path

    Returns
    -------
    Path
    """
    fig, ax = _figure(9.0, 4.8)
    mean, std = sweep.mean_bestmax(), sweep.std_bestmax()
    k = len(sweep.sources)
    width = 0.8 / k
    x = np.arange(len(sweep.particle_counts))
    for i, s in enumerate(sweep.sources):
        st = _style(SOURCE_STYLE, s)
        ax.bar(
            x + (i - (k - 1) / 2) * width,
            mean[:, i],
            width,
            yerr=std[:, i],
            capsize=2,
            color=st["color"],
            label=st["label"],
            error_kw={"elinewidth": 0.8},
        )
    ax.set_xticks(x, [str(n) for n in sweep.particle_counts])
    ax.set_xlabel("number of particles N")
    ax.set_ylabel(f"mean BestMax over {sweep.runs} runs (frames of {_contested(sweep)})")
    ax.set_title(f"Multi-execution BestMax ({sweep.runs} runs per N, error bars ±1 std)")
    ax.grid(axis="y", alpha=0.3)
    ax.set_ylim(bottom=0)
    _legend(ax, 4)
    return _save(fig, path)


def plot_errors(
    frame: np.ndarray,
    errors: Mapping[str, np.ndarray],
    path: str | Path,
    episodes: np.ndarray | None = None,
    title: str = "Error per frame",
) -> Path:
    """Per-frame error of each source against the reference, occlusion episodes shaded.

    Parameters
    ----------
    frame : ndarray, shape (n,)
        Frame index of each row (x axis).
    errors : mapping of str to ndarray, shape (n,)
        Per-frame error in pixels per source (NaN = not scored; drawn as a gap).
    path : str or Path
    episodes : ndarray, shape (k, 2), optional
        ``[start, stop)`` row indices of occlusion episodes.
    title : str

    Returns
    -------
    Path
    """
    fig, ax = _figure(10.0, 4.8)
    frame = np.asarray(frame)
    shaded = False
    for start, stop in episodes if episodes is not None else np.zeros((0, 2), int):
        ax.axvspan(
            frame[start] - 0.5,
            frame[stop - 1] + 0.5,
            color="0.85",
            zorder=0,
            label=None if shaded else "occlusion episode (ground truth)",
        )
        shaded = True
    for s, e in errors.items():
        st = SOURCE_STYLE.get(s, {"color": None, "label": s})
        ax.plot(
            frame,
            e,
            color=st["color"],
            label=st["label"],
            linewidth=1.8 if s == "fused" else 1.0,
            alpha=1.0 if s == "fused" else 0.85,
        )
    finite = np.concatenate([np.asarray(e)[np.isfinite(e)] for e in errors.values()])
    if finite.size and finite.min() > 0 and finite.max() / finite.min() > 100:
        ax.set_yscale("log")
        ax.set_ylabel("error to reference (px, log scale)")
    else:
        ax.set_ylim(bottom=0)
        ax.set_ylabel("error to reference (px)")
    ax.set_xlabel("frame")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    _legend(ax, 5 if shaded else 4)
    return _save(fig, path)


def plot_latency(
    frame: np.ndarray,
    latency_ms: Mapping[str, np.ndarray],
    path: str | Path,
    budget_ms: float | None = None,
) -> Path:
    """Figure 10: latency of each pipeline stage per frame.

    Parameters
    ----------
    frame : ndarray, shape (n,)
    latency_ms : mapping of str to ndarray, shape (n,)
        Per stage (``decode``, ``colour``, ``depth``, ``skeleton``, ``filter``,
        ``total``), milliseconds; NaN = unknown.
    path : str or Path
    budget_ms : float, optional
        The frame period (real-time budget), drawn as a dashed line.

    Returns
    -------
    Path
    """
    fig, ax = _figure(10.0, 4.8)
    for stage, ms in latency_ms.items():
        st = STAGE_STYLE.get(stage, {"color": None, "label": stage})
        ms = np.asarray(ms, dtype=np.float64)
        ax.plot(
            frame,
            np.where(ms > 0, ms, np.nan),
            color=st["color"],
            label=st["label"],
            linewidth=1.8 if stage == "total" else 1.0,
        )
    if budget_ms is not None:
        ax.axhline(
            budget_ms,
            color="tab:red",
            linestyle="--",
            linewidth=1.0,
            label=f"frame period {budget_ms:.1f} ms (real-time budget)",
        )
    ax.set_yscale("log")
    ax.set_xlabel("frame")
    ax.set_ylabel("latency (ms, log scale)")
    ax.set_title("Latency per frame and stage")
    ax.grid(alpha=0.3, which="both")
    _legend(ax, 4)
    return _save(fig, path)


#: Colours of the track states on the per-target timelines (paper 004 §5.2).
STATE_COLOURS = {
    "uninitialised": "lightgrey",
    "unlabelled": "tab:orange",
    "tracking": "tab:green",
    "combined": "tab:blue",
    "lost": "tab:red",
}


def plot_targets(errors: Mapping[str, np.ndarray], states: Mapping[str, list[str]], path: str | Path) -> Path:
    """Per-target error per frame (top) and each target's track-state timeline (bottom).

    Parameters
    ----------
    errors : mapping of str to ndarray, shape (n,)
        Per target, the error in px per frame (NaN: no estimate or no reference).
    states : mapping of str to list of str
        Per target, the track state per frame.
    path : str or Path
        PNG to write.
    """
    from matplotlib.figure import Figure
    from matplotlib.patches import Patch

    fig = Figure(figsize=(10.0, 6.0), dpi=110)
    top, bottom = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    for k, (t, e) in enumerate(errors.items()):
        top.plot(np.arange(len(e)), e, linewidth=1.2, color=_OTHER_COLOURS[k % len(_OTHER_COLOURS)], label=t)
        colours = [STATE_COLOURS.get(s, "black") for s in states[t]]
        bottom.bar(np.arange(len(colours)), 0.8, bottom=k - 0.4, width=1.0, color=colours, linewidth=0)
    top.set_ylabel("error (px)")
    top.set_title("Error per target and track states")
    top.grid(alpha=0.3)
    top.legend(fontsize=9)
    bottom.set_yticks(range(len(errors)), list(errors))
    bottom.set_xlabel("tracked frame")
    handles = [Patch(color=c, label=s) for s, c in STATE_COLOURS.items()]
    bottom.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.45), ncol=5, fontsize=8, frameon=False)
    return _save(fig, path)
