"""benchmarks/rig_events.py: the per-run table of the scripted scene seen by a rig, on a short scene."""

import importlib.util
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("rig_events_bench", ROOT / "benchmarks" / "rig_events.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_a_short_rig_scene_reports_its_first_four_events(capsys):
    # 170 instants (30 empty) seen by 2 cameras: pick-up, join, separation and exchange
    assert bench.main(["--seeds", "1", "--sizes", "320x200", "--cameras", "2", "--frames", "170"]) == 0
    lines = capsys.readouterr().out.splitlines()
    row = next(line for line in lines if line.startswith("| 320x200 | 2 | 1 |"))
    assert row.split(" | ")[3:7] == ["tuned", "4", "0", "0"], row
    assert lines[-1] == "1 of 1 runs perfect (every true event within 5 frames, nothing else)"
