"""Score a study: every tracker output of a folder against the recording of the same name in a reference folder.

``fusion-pf score OUT_DIR --ground-truth REF_DIR`` (``OUT_DIR`` as written by
``fusion-pf track ... --out-dir``): each ``OUT_DIR/NAME.csv`` (else
``NAME.mcap``) is scored against the ground truth of ``REF_DIR/NAME.mcap``
with :func:`~fusion_pf.score.evaluate.evaluate`; the pooled score concatenates
the frames of every recording (per source; a source missing from a recording
counts as missing there) and scores them with the same
:func:`~fusion_pf.score.metrics.score`.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fusion_pf.errors import InputError

from .evaluate import Evaluation, evaluate, read_reference
from .inputs import TopicReader
from .metrics import TIE_TOL_PX, Score, score

__all__ = ["StudyScore", "score_study", "study_markdown", "study_outputs"]

#: Files of an output folder that are not tracker outputs.
_NOT_OUTPUTS = ("study.csv",)


def study_outputs(out_dir: Path) -> dict[str, Path]:
    """Tracker output per recording name: ``NAME.csv``, else ``NAME.mcap`` (the study's own files left out)."""
    found: dict[str, Path] = {}
    for path in sorted(out_dir.iterdir()):
        if path.name.startswith(".") or path.name in _NOT_OUTPUTS or path.suffix not in (".csv", ".mcap"):
            continue
        if path.suffix == ".csv" or path.stem not in found:
            found[path.stem] = path
    if not found:
        raise InputError(f"{out_dir} holds no tracker output (NAME.csv or NAME.mcap); expected a --out-dir of track")
    return found


@dataclass(frozen=True)
class StudyScore:
    """Per recording and pooled scores of a study."""

    recordings: dict[str, Evaluation]
    pooled: Score


def score_study(
    out_dir: str | Path, reference_dir: str | Path, *, read_topic: TopicReader, tie_tol: float = TIE_TOL_PX
) -> StudyScore:
    """Score every output of ``out_dir`` against ``reference_dir/NAME.mcap``; pooled over all frames.

    Raises
    ------
    InputError
        When a folder is missing or empty, or an output has no reference recording.
    """
    out_dir, reference_dir = Path(out_dir), Path(reference_dir)
    for what, d in (("tracker output folder", out_dir), ("reference folder", reference_dir)):
        if not d.is_dir():
            raise InputError(f"{what} {d} is not a folder")
    evaluations = {}
    for name, tracked in study_outputs(out_dir).items():
        reference = reference_dir / f"{name}.mcap"
        if not reference.is_file():
            raise InputError(f"{tracked} has no reference recording {reference}")
        ref = read_reference(ground_truth=reference, read_topic=read_topic)
        evaluations[name] = evaluate(tracked, ref, tie_tol=tie_tol, read_topic=read_topic)
    sources: list[str] = []
    for ev in evaluations.values():
        sources += [s for s in ev.score.sources if s not in sources]
    pooled_points = {
        s: np.concatenate(
            [
                ev.table.points[s] if s in ev.table.points else np.full((len(ev.reference_uv), 2), np.nan)
                for ev in evaluations.values()
            ]
        )
        for s in sources
    }
    reference_uv = np.concatenate([ev.reference_uv for ev in evaluations.values()])
    return StudyScore(evaluations, score(pooled_points, reference_uv, tie_tol=tie_tol))


def _cell(x: float, fmt: str = ".2f") -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, fmt)


def study_markdown(study: StudyScore, out_dir: str | Path, reference_dir: str | Path) -> str:
    """Markdown: per recording the fused estimate's RMSE, p95, coverage and frames; then every source pooled."""
    lines = [
        f"# Study score: {out_dir} against {reference_dir}",
        "",
        "| recording | frames | fused RMSE (px) | p95 (px) | coverage |",
        "|---|---|---|---|---|",
    ]
    for name, ev in study.recordings.items():
        fused = ev.score.summary.get("fused")
        if fused is None:
            lines.append(f"| {name} | {ev.score.n_frames} | - | - | - |")
        else:
            lines.append(
                f"| {name} | {ev.score.n_frames} | {_cell(fused.rmse)} | {_cell(fused.p95)} | {_cell(fused.coverage, '.3f')} |"
            )
    p = study.pooled
    lines += [
        "",
        f"## Pooled ({len(study.recordings)} recordings, {p.n_frames} frames, {p.n_reference} with a reference)",
        "",
        "| source | RMSE (px) | mean (px) | p95 (px) | max (px) | coverage | BestMax |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in p.sources:
        m = p.summary[s]
        lines.append(
            f"| {s} | {_cell(m.rmse)} | {_cell(m.mean)} | {_cell(m.p95)} | {_cell(m.max)} | {_cell(m.coverage, '.3f')} | {m.bestmax} |"
        )
    return "\n".join(lines) + "\n"
