"""benchmarks/fusion_matrix.py end to end on one small scene (synth, track, score as a user runs them)."""

import importlib.util
import math
import re
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("fusion_matrix", ROOT / "benchmarks" / "fusion_matrix.py")
fusion_matrix = importlib.util.module_from_spec(_spec)
sys.modules["fusion_matrix"] = fusion_matrix  # its dataclasses look their module up
_spec.loader.exec_module(fusion_matrix)


def test_one_scene_row_and_its_split_summary(tmp_path, capsys):
    assert fusion_matrix.main(["--out", str(tmp_path), "--only", "default-320", "--frames", "40", "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    row = next(line for line in out.splitlines() if line.startswith("default-320"))
    colour, depth, skeleton, fused, ratio, paired = (float(x) for x in re.findall(r"\d+\.\d+", row)[:6])
    assert abs(ratio - fused / min(colour, depth, skeleton)) < 0.01
    assert abs(paired - ratio) < 0.01  # the best cue (depth) measures in every tracked frame: paired = ratio
    assert "held: 1 scenes, ratio mean" in out and "tune:" not in out
    assert (tmp_path / "default-320.csv").is_file()


def test_scene_names_are_unique_and_splits_known():
    names = [s.name for s in fusion_matrix.SCENES]
    assert len(names) == len(set(names))
    assert {s.split for s in fusion_matrix.SCENES} == set(fusion_matrix.SPLITS)


def test_save_then_compare_prints_fused_new_over_old_and_the_geometric_mean(tmp_path, capsys):
    scenes = {s.name: s for s in fusion_matrix.SCENES}

    def row(name, fused, ratio):
        cues = {"colour": (fused / ratio, 1.0)}
        return {"scene": scenes[name], "cues": cues, "best": "colour", "fused": fused, "ratio": ratio, "paired": ratio,
                "bestmax": 0.5, "coverage": 1.0, "cover2sd": 0.95}  # fmt: skip

    old = tmp_path / "old.json"
    fusion_matrix.save([row("default-320", 2.0, 1.0), row("near-body-640", 4.0, 0.5)], old)
    fusion_matrix.compare([row("default-320", 1.0, 0.5), row("near-body-640", 8.0, 1.0)], old)
    out = capsys.readouterr().out
    assert "default-320" in out and "2.00 ->    1.00 ( 0.50x)" in out and "8.00 ( 2.00x)" in out
    # geometric mean of 0.5 and 2: 1; the held split's ratio means 0.75 -> 0.75
    assert "held: fused new / old geometric mean 1.000 (1 of 2 worse); ratio mean 0.75 -> 0.75" in out


def test_noise_split_finds_a_cues_white_noise_under_its_bias(tmp_path):
    # reference: the simulated noise. colour 2 px off to the right plus 0.3 px of white noise; depth 1 px of
    # white noise, missing every 7th frame (no difference spans the gap)
    import csv

    import numpy as np

    from drivers.synth import SynthSource

    scene = next(s for s in fusion_matrix.SCENES if s.name == "default-320")
    frames = 200
    src = SynthSource(frames=frames, seed=scene.seed, size=(320, 200), background_frames=10, **scene.options)
    gen = np.random.default_rng(0)
    table = tmp_path / "t.csv"
    with open(table, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["frame", "colour_u", "colour_v", "depth_u", "depth_v", "colour_quality", "depth_quality"])
        for k in range(10, frames):
            g = src.ground_truth(k)
            c = np.array([g.u + 2.0, g.v]) + gen.normal(0.0, 0.3, 2)
            d = np.array([g.u, g.v]) + gen.normal(0.0, 1.0, 2)
            out.writerow([k, *c, *(d if k % 7 else ("", "")), 0.9, 0.9 if k % 7 else ""])
    split = fusion_matrix.noise_split(table, scene, frames)
    assert set(split) == {"colour", "depth"}
    assert abs(split["colour"][1] - 0.3) < 0.3 * 0.25 and abs(split["depth"][1] - 1.0) < 0.25
    # colour's median error is its bias: sqrt((2^2 + 2 * 0.3^2) / 2 / ln 2) = 1.74 px per axis
    assert abs(split["colour"][0] - 1.74) < 0.15 and split["colour"][0] > 4 * split["colour"][1]
    # slow error from the truth: sqrt(1.74^2 - 0.3^2) = 1.71 px; online, two cues cannot split their
    # offset (2 px^2 per axis) from it: the calibration's prior splits it by their white noise, colour
    # sqrt(2 * 0.09 / 1.09) = 0.41 px, depth sqrt(2 * 1 / 1.09) = 1.35 px, the wrong way round here (a smooth
    # biased cue beside a noisy unbiased one: the prior's known failure)
    assert abs(split["colour"][2] - 1.71) < 0.15 and split["depth"][2] < 0.5
    assert abs(split["colour"][3] - 0.41) < 0.15 and abs(split["depth"][3] - 1.35) < 0.2


def test_startup_split_separates_the_first_tracked_frames(tmp_path):
    # reference: offsets written into the table. fused 3 px off over the first STARTUP_FRAMES tracked rows,
    # 0.5 px after; the best cue 1 px off throughout but missing every 5th row; an untracked row counts nowhere
    import csv

    from drivers.synth import SynthSource

    scene = next(s for s in fusion_matrix.SCENES if s.name == "default-320")
    frames = 60
    src = SynthSource(frames=frames, seed=scene.seed, size=(320, 200), background_frames=10, **scene.options)
    table = tmp_path / "t.csv"
    first = fusion_matrix.STARTUP_FRAMES
    with open(table, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["frame", "u", "v", "depth_u", "depth_v"])
        out.writerow([10, "", "", 0.0, 0.0])
        for i, k in enumerate(range(11, frames)):
            g = src.ground_truth(k)
            off = 3.0 if i < first else 0.5
            out.writerow([k, g.u + off, g.v, *((g.u, g.v + 1.0) if i % 5 else ("", ""))])
    ff, bf, fr, br = fusion_matrix.startup_split(table, scene, frames, "depth")
    assert abs(ff - 3.0) < 1e-6 and abs(fr - 0.5) < 1e-6
    assert abs(bf - 1.0) < 1e-6 and abs(br - 1.0) < 1e-6


def _table(tmp_path, frames, row_of):
    """A tracker table for default-320's truth: ``row_of(i, g, before, after)`` gives (u, v, colour_u, colour_v, depth_u, depth_v)."""
    import csv

    from drivers.synth import SynthSource

    scene = next(s for s in fusion_matrix.SCENES if s.name == "default-320")
    src = SynthSource(frames=frames, seed=scene.seed, size=(320, 200), background_frames=10, **scene.options)
    table = tmp_path / "t.csv"
    with open(table, "w", newline="") as f:
        out = csv.writer(f)
        out.writerow(["frame", "u", "v", "colour_u", "colour_v", "depth_u", "depth_v"])
        for i, k in enumerate(range(11, frames - 1)):  # each row's neighbours have a truth
            out.writerow([k, *row_of(i, src.ground_truth(k), src.ground_truth(k - 1), src.ground_truth(k + 1))])
    return table, scene


def test_bestmax_split_tells_a_fused_estimate_behind_the_best_cue_from_one_near_another(tmp_path):
    # reference: offsets written into the table, 10 rows of each kind. won: fused 0.1 px off, depth 1 px, no
    # colour; behind: depth 0.2 px, fused 0.5 px beside it (nearest to depth), colour 3 px; elsewhere: depth
    # 0.2 px, fused 2.5 px off and 0.5 px from colour (3 px off); uncontested: fused alone
    def row_of(i, g, before, after):
        u, v = g.u, g.v
        return [
            (u + 0.1, v, "", "", u + 1.0, v),
            (u + 0.5, v, u + 3.0, v, u + 0.2, v),
            (u, v + 2.5, u, v + 3.0, u + 0.2, v),
            (u, v, "", "", "", ""),
        ][i % 4]

    table, scene = _table(tmp_path, 52, row_of)
    b = fusion_matrix.bestmax_split(table, scene, 52)
    assert b["frames"] == 30
    assert abs(b["won"] - 1 / 3) < 1e-9 and abs(b["behind"] - 1 / 3) < 1e-9 and abs(b["elsewhere"] - 1 / 3) < 1e-9
    assert abs(b["behind_fused"] - 0.5) < 1e-6 and abs(b["behind_cue"] - 0.2) < 1e-6
    assert abs(b["elsewhere_fused"] - 2.5) < 1e-6 and abs(b["elsewhere_cue"] - 0.2) < 1e-6
    # squared errors: 10 x 0.01 won, 10 x 0.25 behind, 10 x 6.25 elsewhere
    assert abs(b["behind_sq"] - 2.5 / 65.1) < 1e-6 and abs(b["elsewhere_sq"] - 62.5 / 65.1) < 1e-6


def test_bestmax_split_measures_the_lag_along_the_palms_motion(tmp_path):
    # reference: the fused estimate written 1 px behind the truth along its central difference (the direction
    # computed here from the neighbouring frames' truth); depth 5 px off, so fused wins every frame
    import math

    def row_of(i, g, before, after):
        du, dv = after.u - before.u, after.v - before.v
        n = math.hypot(du, dv)
        return (g.u - du / n, g.v - dv / n, "", "", g.u + 5.0, g.v)

    table, scene = _table(tmp_path, 40, row_of)
    b = fusion_matrix.bestmax_split(table, scene, 40)
    assert b["won"] == 1.0 and b["behind"] == 0.0 and b["elsewhere"] == 0.0
    assert abs(b["lag"] + 1.0) < 1e-6 and b["speed"] > 0.0


def test_generated_scenes_are_a_pure_function_of_their_seeds_and_valid_synth_scenes():
    from drivers.synth import VARIATIONS, SynthSource

    a, b = fusion_matrix.generated_scenes(300, 12), fusion_matrix.generated_scenes(300, 12)
    assert a == b and len({s.name for s in a}) == 12
    assert fusion_matrix.generated_scenes(305, 1)[0] == a[5]  # a scene depends on its seed alone
    assert {s.name.split("-")[2] for s in a} == set(fusion_matrix.GENERATED_KINDS)
    assert {s.split for s in a} == {fusion_matrix.GENERATED}
    for s in a:
        for key, value in s.options.items():
            assert VARIATIONS[key][1] <= value <= VARIATIONS[key][2], (s.name, key, value)
        w, h = (int(x) for x in s.size.split("x"))
        SynthSource(frames=12, seed=s.seed, size=(w, h), background_frames=10, **s.options)
    near = [s for s in a if "-near-" in s.name]
    far = [s for s in a if "-far-" in s.name]
    assert max(s.options["hand_front"] for s in near) < min(s.options["hand_front"] for s in far)


def test_away_scenes_send_the_person_away_in_every_scene(capsys):
    from drivers.synth import SynthSource

    base = fusion_matrix.generated_scenes(500, 3)
    away = fusion_matrix.away_scenes(base, 30)
    assert [s.name for s in away] == [f"{s.name}-away30" for s in base]
    assert all(a.options == {**b.options, "away": 30} and a.seed == b.seed for a, b in zip(away, base))
    w, h = (int(x) for x in away[0].size.split("x"))
    src = SynthSource(frames=130, seed=away[0].seed, size=(w, h), background_frames=10, **away[0].options)
    gone = [src.away_at(i) for i in range(10, 130)]
    assert 0.2 <= sum(gone) / len(gone) <= 0.4  # 30 of every 100 person frames
    with pytest.raises(SystemExit) as exc:
        fusion_matrix.main(["--generate", "500:3", "--away", "100"])
    assert exc.value.code == 2 and "--away must be in 1..99" in capsys.readouterr().err


def test_generate_runs_a_fresh_set_and_reports_it_as_its_own_split(tmp_path, capsys):
    argv = ["--out", str(tmp_path), "--generate", "402:1", "--frames", "40", "--jobs", "1"]
    assert fusion_matrix.main(argv) == 0
    out = capsys.readouterr().out
    assert any(line.startswith("gen-402-") for line in out.splitlines())
    assert "generated: 1 scenes, ratio mean" in out and "held:" not in out


def test_paired_ratio_compares_fused_and_cue_on_the_cues_own_frames():
    """A cue measured in two easy frames is not 'best' over frames it never saw: the paired ratio uses its frames only."""
    fused = [1.0, 1.0, 30.0, 40.0]
    cue = [4.0, None, float("nan"), 4.0]  # frames 0 and 3
    plain = math.sqrt(sum(e * e for e in fused) / 4) / 4.0
    assert plain > 1.0
    # frames 0 and 3: sqrt((1 + 1600) / 2) / sqrt((16 + 16) / 2)
    assert abs(fusion_matrix.paired_ratio(fused, cue) - math.sqrt(1601 / 2) / 4.0) < 1e-12
    assert math.isnan(fusion_matrix.paired_ratio([1.0, None], [None, 2.0]))


def test_only_selects_among_the_generated_scenes_and_names_what_it_cannot_find(capsys):
    generated = fusion_matrix.generated_scenes(31, 6)
    name = generated[2].name
    assert [s.name for s in fusion_matrix.select(generated, {name})] == [name]
    assert fusion_matrix.select(generated, {fusion_matrix.GENERATED}) == generated
    try:
        fusion_matrix.main(["--generate", "31:6", "--only", f"{name},default-320"])
    except SystemExit as exc:
        assert exc.code == 2
    else:
        raise AssertionError("--only with a fixed scene's name under --generate must fail")
    err = capsys.readouterr().err
    assert "default-320" in err and name not in err.split("split of this matrix:")[1]
