"""Smoke test of the benchmark machinery with tiny sizes: structure and sanity, not timings."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import pytest

from fusion_pf.errors import FusionPFError, InputError

# the benchmark script is not part of the package: load it from benchmarks/ by path
_spec = importlib.util.spec_from_file_location("bench", Path(__file__).resolve().parents[2] / "benchmarks" / "bench.py")
bench = importlib.util.module_from_spec(_spec)
sys.modules["bench"] = bench
_spec.loader.exec_module(bench)
robustness_bench, run_bench, to_markdown, main = bench.robustness_bench, bench.run_bench, bench.to_markdown, bench.main


def _check_timing(t: dict) -> None:
    assert t["repeats"] >= 1
    assert 0.0 < t["median_ms"] <= t["p95_ms"] < 60_000.0


def test_filter_sections_json_and_markdown(tmp_path):
    result = run_bench(tmp_path, quick=True, sizes=[40, 300], sections=("pf", "stonesoup", "resampling"))
    on_disk = json.loads((tmp_path / "bench.json").read_text())
    assert on_disk == json.loads(json.dumps(result))
    assert set(result) >= {"meta", "pf_step", "stonesoup_step", "resampling", "targets"}
    assert result["meta"]["quick"] is True and len(result["meta"]["loadavg_end"]) == 3
    assert [r["n"] for r in result["pf_step"]] == [40, 300] == [r["n"] for r in result["pf_step_robust"]]
    for r in result["pf_step"] + result["pf_step_robust"]:
        _check_timing(r)
        assert r["updates_per_s"] == pytest.approx(r["n"] / (r["median_ms"] / 1e3))
        assert r["resampled_fraction"] == 1.0  # forced resampling in every timed step
    assert [r["n"] for r in result["stonesoup_step"]] == [40, 300]
    for r in result["stonesoup_step"]:
        _check_timing(r["ours"])
        _check_timing(r["stonesoup"])
        assert r["speedup"] == pytest.approx(r["stonesoup"]["median_ms"] / r["ours"]["median_ms"])
        # both filters follow the path to within a few cue sigmas (the cues' noise is 6-15 px)
        assert set(r["rmse_px"]) == {"ours", "ours_robust_mean", "stonesoup"}
        assert all(0.5 < e < 15.0 for e in r["rmse_px"].values())
        assert r["rmse_gap_px"] == pytest.approx(r["rmse_px"]["ours"] - r["rmse_px"]["stonesoup"])
        assert r["rmse_gap_se_px"] > 0.0
    for r in result["resampling"]:
        for key in (
            "ours_residual",
            "ours_systematic",
            "ours_stratified",
            "ours_multinomial",
            "particles_residual",
            "filterpy_residual",
        ):
            _check_timing(r[key])
        assert r["ratio_vs_particles"] == pytest.approx(
            r["ours_residual"]["median_ms"] / r["particles_residual"]["median_ms"]
        )
    # only targets whose sizes were measured are reported: here the Stone Soup race
    assert [t["target"] for t in result["targets"]] == [
        ">= 10x faster than Stone Soup, interleaved (worst N)",
        "estimate RMSE <= Stone Soup's at equal N (worst N: (ours - theirs) / its s.e.)",
    ]
    md = (tmp_path / "bench.md").read_text()
    assert md == to_markdown(result)
    assert "## PF step" in md and "## PF step vs Stone Soup, interleaved" in md and "| 4e+01 |" in md
    assert "## Resampling" in md


def test_robustness_section_reports_both_likelihoods():
    rob = robustness_bench(n_particles=100, seeds=(0,), n_frames=110)
    for liar in ("skeleton", "colour"):
        assert set(rob["lying"][liar]) == {"pf_gaussian", "pf_robust", "kf"}
        for r in rob["lying"][liar].values():
            assert 0.0 < r["rmse_px"] < 100.0 and 0.0 < r["rmse_lying_px"] < 100.0
    # the tightest source lying: the robust mixture must beat the Gaussian in the window
    assert rob["lying"]["colour"]["pf_robust"]["rmse_lying_px"] < rob["lying"]["colour"]["pf_gaussian"]["rmse_lying_px"]
    assert set(rob["clean_rmse_px"]) >= {"pf_robust_mean", "pf_map", "pf_weighted_mean", "kf", "raw_colour"}


@pytest.mark.slow
def test_pipeline_and_replay_sections(tmp_path):
    result = run_bench(
        tmp_path, quick=True, sections=("pipeline", "replay"), sample=None, pipeline_frames=(3, 2), replay_frames=4
    )
    for size in ("640x400", "1280x800"):
        for mode in ("roi", "full_frame"):
            stages = result["pipeline"][size][mode]
            assert set(stages) == {
                "decode",
                "colour",
                "depth",
                "skeleton",
                "filter",
                "total",
                "sinks",
                "cues_plus_filter",
            }
            for t in stages.values():
                _check_timing(t)
            assert stages["total"]["median_ms"] >= stages["filter"]["median_ms"]
    rep = result["replay"]
    assert rep["short"]["frames"] == 14 and rep["long"]["frames"] == 26
    assert rep["short"]["fps"] > 0 and rep["long"]["max_rss_mib"] > 10
    assert rep["rss_ratio_long_over_short"] == pytest.approx(rep["long"]["max_rss_mib"] / rep["short"]["max_rss_mib"])
    names = [t["target"] for t in result["targets"]]
    assert any("cues + PF" in n for n in names) and any("peak RSS" in n for n in names)


def test_cli_bench_writes_outputs(tmp_path, capsys):
    out = tmp_path / "b"
    assert main(["--sections", "pf,resampling", "--sizes", "20,1e2", "--out", str(out)]) == 0
    assert "## PF step" in capsys.readouterr().out
    data = json.loads((out / "bench.json").read_text())
    assert [r["n"] for r in data["pf_step"]] == [20, 100] and "stonesoup_step" not in data


def test_bad_arguments():
    with pytest.raises(InputError, match="unknown bench section 'gpu'"):
        run_bench("unused", sections=("gpu",))
    with pytest.raises(SystemExit):
        main(["--sizes", "0"])


def test_missing_reference_libraries_are_named(monkeypatch, capsys, tmp_path):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "stonesoup" else real(name, *a))
    with pytest.raises(FusionPFError) as err:
        main(["--sections", "pf,stonesoup", "--out", str(tmp_path)])
    assert str(err.value) == (
        "the reference libraries stonesoup are not installed; install them with "
        "pip install 'fusion-pf[bench]', or choose --sections without stonesoup/resampling"
    )
    assert not (tmp_path / "bench.json").exists()
