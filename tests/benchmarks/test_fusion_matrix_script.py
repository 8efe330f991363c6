"""benchmarks/fusion_matrix.py end to end on one small scene (synth, track, score as a user runs them)."""

import importlib.util
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("fusion_matrix", ROOT / "benchmarks" / "fusion_matrix.py")
fusion_matrix = importlib.util.module_from_spec(_spec)
sys.modules["fusion_matrix"] = fusion_matrix  # its dataclasses look their module up
_spec.loader.exec_module(fusion_matrix)


def test_one_scene_row_and_its_split_summary(tmp_path, capsys):
    assert fusion_matrix.main(["--out", str(tmp_path), "--only", "default-320", "--frames", "40", "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("default-320"))
    colour, depth, skeleton, fused, ratio = (float(x) for x in re.findall(r"\d+\.\d+", row)[:5])
    assert abs(ratio - fused / min(colour, depth, skeleton)) < 0.01
    assert "held: 1 scenes, ratio mean" in out and "tune:" not in out
    assert (tmp_path / "default-320.csv").is_file()


def test_scene_names_are_unique_and_splits_known():
    names = [s.name for s in fusion_matrix.SCENES]
    assert len(names) == len(set(names))
    assert {s.split for s in fusion_matrix.SCENES} == set(fusion_matrix.SPLITS)
