"""Score a study: every tracker output of a folder against the recording of the same name in a reference folder.

``fusion-pf score OUT_DIR --ground-truth REF_DIR`` (``OUT_DIR`` as written by
``fusion-pf track ... --out-dir``): each ``OUT_DIR/NAME.csv`` (else
``NAME.mcap``) is scored against the ground truth of ``REF_DIR/NAME.mcap``
with :func:`~fusion_pf.score.evaluate.evaluate`; the pooled score concatenates
the frames of every recording (per source; a source missing from a recording
counts as missing there) and scores them with the same
:func:`~fusion_pf.score.metrics.score`.

A study of several targets (``track ... --out-dir DIR --targets ...``) is
scored per recording with :func:`~fusion_pf.score.targets.score_targets` and
pooled per target: the errors (and reported uncertainties, when every output has them) of every recording
concatenated, the frames per state and the identity swaps summed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fusion_pf.errors import InputError

from .evaluate import Evaluation, evaluate, read_reference
from .inputs import FrameSize, TopicReader
from .metrics import TIE_TOL_PX, Score, score
from .targets import read_targets, score_targets_recording, target_summary

__all__ = ["StudyScore", "TargetsStudyScore", "score_study", "study_markdown", "study_outputs"]

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


@dataclass(frozen=True)
class TargetsStudyScore:
    """Per recording (:func:`~fusion_pf.score.targets.score_targets` results) and pooled per target, several targets."""

    recordings: dict[str, dict]
    pooled: dict


def score_study(
    out_dir: str | Path,
    reference_dir: str | Path,
    *,
    read_topic: TopicReader,
    frame_size: FrameSize,
    tie_tol: float = TIE_TOL_PX,
) -> StudyScore | TargetsStudyScore:
    """Score every output of ``out_dir`` against ``reference_dir/NAME.mcap``; pooled over all frames.

    ``frame_size(recording)`` gives a recording's image size (several targets' swap distance).

    Raises
    ------
    InputError
        When a folder is missing or empty, an output has no reference recording, or
        outputs of one target and of several are mixed.
    """
    out_dir, reference_dir = Path(out_dir), Path(reference_dir)
    for what, d in (("tracker output folder", out_dir), ("reference folder", reference_dir)):
        if not d.is_dir():
            raise InputError(f"{what} {d} is not a folder")
    outputs = study_outputs(out_dir)
    for name, tracked in outputs.items():
        if not (reference_dir / f"{name}.mcap").is_file():
            raise InputError(f"{tracked} has no reference recording {reference_dir / f'{name}.mcap'}")
    tables = {name: read_targets(tracked, read_topic) for name, tracked in outputs.items()}
    several = [name for name, table in tables.items() if table is not None]
    if several and len(several) < len(tables):
        one = next(name for name, table in tables.items() if table is None)
        raise InputError(
            f"{outputs[several[0]]} holds several targets but {outputs[one]} one; expected the outputs of one study"
        )
    if several:
        return _score_targets_study(tables, reference_dir, read_topic, frame_size)
    evaluations = {}
    for name, tracked in outputs.items():
        ref = read_reference(ground_truth=reference_dir / f"{name}.mcap", read_topic=read_topic)
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
    sigma = (
        np.concatenate(
            [
                ev.table.sigma_px if ev.table.sigma_px is not None else np.full(len(ev.reference_uv), np.nan)
                for ev in evaluations.values()
            ]
        )
        if any(ev.table.sigma_px is not None for ev in evaluations.values())
        else None
    )
    return StudyScore(evaluations, score(pooled_points, reference_uv, tie_tol=tie_tol, sigma=sigma))


def _score_targets_study(
    tables: dict, reference_dir: Path, read_topic: TopicReader, frame_size: FrameSize
) -> TargetsStudyScore:
    """Each several-target output scored against its recording; pooled per target over every recording."""
    recordings = {
        name: score_targets_recording(table, reference_dir / f"{name}.mcap", read_topic, frame_size)
        for name, table in tables.items()
    }
    targets: list[str] = []
    for table in tables.values():
        targets += [t for t in table.uv if t not in targets]
    pooled: dict = {"targets": {}, "swaps": None}
    for t in targets:
        names = [name for name, r in recordings.items() if t in r["targets"]]
        sigmas = [tables[name].sigma_px for name in names]
        pooled["targets"][t] = target_summary(
            np.concatenate([recordings[name]["errors"][t] for name in names]),
            sum(recordings[name]["targets"][t]["n_reference"] for name in names),
            [s for name in names for s in tables[name].states[t]],
            None if any(x is None for x in sigmas) else np.concatenate([x[t] for x in sigmas if x is not None]),
        )
    swaps = [r["swaps"] for r in recordings.values() if r["swaps"] is not None]
    if swaps:
        pooled["swaps"] = sum(swaps)
    for r in recordings.values():
        r.pop("errors")
    return TargetsStudyScore(recordings, pooled)


def _targets_study_markdown(study: TargetsStudyScore, out_dir: str | Path, reference_dir: str | Path) -> str:
    """Markdown: per recording and target RMSE, p95, coverage, the share within ``2 sigma_px`` and identity swaps;
    then every target pooled."""
    lines = [
        f"# Study score: {out_dir} against {reference_dir}",
        "",
        "| recording | target | RMSE (px) | p95 (px) | coverage | within 2 sigma_px | identity swaps |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, r in study.recordings.items():
        swaps = "-" if r["swaps"] is None else str(r["swaps"])
        for t, m in r["targets"].items():
            lines.append(
                f"| {name} | {t} | {_cell(m['rmse_px'])} | {_cell(m['p95_px'])} | {_cell(m['coverage'], '.3f')} | "
                f"{_within_2(m['uncertainty'])} | {swaps} |"
            )
    swaps = "-" if study.pooled["swaps"] is None else str(study.pooled["swaps"])
    lines += [
        "",
        f"## Pooled ({len(study.recordings)} recordings; identity swaps {swaps})",
        "",
        "| target | RMSE (px) | median (px) | p95 (px) | coverage | with a reference | within 2 sigma_px | frames per state |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for t, m in study.pooled["targets"].items():
        states = ", ".join(f"{s} {n}" for s, n in sorted(m["states"].items()))
        lines.append(
            f"| {t} | {_cell(m['rmse_px'])} | {_cell(m['median_px'])} | {_cell(m['p95_px'])} | "
            f"{_cell(m['coverage'], '.3f')} | {m['n_reference']} | {_within_2(m['uncertainty'])} | {states} |"
        )
    return "\n".join(lines) + "\n"


def _within_2(u: dict | None) -> str:
    """The share within ``2 sigma_px`` of an ``uncertainty`` result (:func:`~fusion_pf.score.targets.target_summary`)."""
    return "-" if u is None else _cell(u["within_2_sigma"], ".3f")


def _cell(x: float, fmt: str = ".2f") -> str:
    return "-" if x is None or not np.isfinite(x) else format(x, fmt)


def study_markdown(study: StudyScore | TargetsStudyScore, out_dir: str | Path, reference_dir: str | Path) -> str:
    """Markdown: per recording the fused estimate's RMSE, p95, coverage, frames and the share within ``2 sigma_px``
    (:attr:`~fusion_pf.score.metrics.Score.uncertainty`); then every source pooled, and the pooled uncertainty coverage.

    Several targets: per recording and target, then per target pooled.
    """
    if isinstance(study, TargetsStudyScore):
        return _targets_study_markdown(study, out_dir, reference_dir)
    lines = [
        f"# Study score: {out_dir} against {reference_dir}",
        "",
        "| recording | frames | fused RMSE (px) | p95 (px) | coverage | within 2 sigma_px |",
        "|---|---|---|---|---|---|",
    ]
    for name, ev in study.recordings.items():
        fused = ev.score.summary.get("fused")
        u = ev.score.uncertainty
        within = "-" if u is None else _cell(u.within_2, ".3f")
        if fused is None:
            lines.append(f"| {name} | {ev.score.n_frames} | - | - | - | {within} |")
        else:
            lines.append(
                f"| {name} | {ev.score.n_frames} | {_cell(fused.rmse)} | {_cell(fused.p95)} | "
                f"{_cell(fused.coverage, '.3f')} | {within} |"
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
    u = p.uncertainty
    if u is not None:
        lines += [
            "",
            f"Reported uncertainty (`sigma_px`), pooled: the fused error is within `sigma_px` in "
            f"{_cell(100 * u.within_1, '.1f')} % and within `2 sigma_px` in {_cell(100 * u.within_2, '.1f')} % of the "
            f"{u.n} frames with an estimate, a reference and an uncertainty.",
        ]
    return "\n".join(lines) + "\n"
