"""benchmarks/targets.py: the per-seed table and the cost line, on a tiny scene."""

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("targets_bench", ROOT / "benchmarks" / "targets.py")
bench = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(bench)


def test_table_per_seed_filter_and_hand_then_the_cost(capsys):
    assert (
        bench.main(["--seeds", "3", "--frames", "45", "--size", "160x100", "--repeats", "1", "--filters", "pf,kf"]) == 0
    )
    lines = capsys.readouterr().out.splitlines()
    rows = [line for line in lines if line.startswith("| 3 |")]
    assert [r.split(" | ")[1:3] for r in rows] == [
        ["pf", "right_hand"],
        ["pf", "left_hand"],
        ["kf", "right_hand"],
        ["kf", "left_hand"],
    ]
    assert all("100.0 %" in r for r in rows)  # both hands covered in every tracked frame
    assert lines[-1].startswith("CPU time per frame at 160x100 (least of 1): one target ")


def test_scene_options_reach_the_synthetic_scene():
    assert bench._scene("hand_front=0.1,joins=3,timing=1") == {"hand_front": "0.1", "joins": "3", "timing": "1"}
    frames = bench._frames(3, 33, (64, 40), bench._scene("crossings=2,hand_distance=0.4"))
    plain = bench._frames(3, 33, (64, 40))
    assert frames[-1].ground_truths != plain[-1].ground_truths
    with pytest.raises(SystemExit, match="--scene: unknown synth option 'joints'"):
        bench._scene("joints=3")


def test_the_share_within_two_sigma_is_the_scorers_on_the_same_scene(tmp_path, capsys):
    """The benchmark's per-hand share within ``2 sigma_px`` (in memory) equals ``fusion-pf score``'s of the same scene
    rendered, tracked and scored through the command line (MCAP output: full precision)."""
    import json

    from fusion_pf.cli import main

    rec, out = tmp_path / "two.mcap", tmp_path / "t.mcap"
    synth = ["synth", str(rec), "--hands", "2", "--frames", "60", "--size", "160x100", "--seed", "3"]
    assert main([*synth, "--background-frames", str(bench.BACKGROUND_FRAMES)]) == 0
    assert main(["track", str(rec), "-o", str(out), "--targets", ",".join(bench.HANDS), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["score", str(out), "--ground-truth", str(rec), "--json"]) == 0
    scored = json.loads(capsys.readouterr().out)["targets"]
    res = bench.accuracy(bench._frames(3, 60, (160, 100)))
    for t in bench.HANDS:
        assert scored[t]["uncertainty"]["n"] > 0
        assert res["targets"][t]["within_2_sigma"] == pytest.approx(scored[t]["uncertainty"]["within_2_sigma"]), t
