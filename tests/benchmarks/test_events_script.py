"""benchmarks/events.py: the per-run table of the scripted events scene, on a short small scene."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("events_bench", ROOT / "benchmarks" / "events.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_a_short_scene_reports_its_first_five_events(capsys):
    # 200 frames (30 empty): pick-up, join, separation, exchange and the hand at the head
    assert bench.main(["--seeds", "2", "--sizes", "160x100", "--frames", "200"]) == 0
    lines = capsys.readouterr().out.splitlines()
    row = next(line for line in lines if line.startswith("| 160x100 | 2 |"))
    assert row.split(" | ")[2:6] == ["held out", "5", "0", "0"], row
    assert lines[-1] == "1/1 runs perfect; 5 matched, 0 missed, 0 false"
