"""End to end on a small synthetic recording: record, track, score (CSV and MCAP), sweep.

Expected values are computed independently of the scorer: the tracker CSV is
parsed with the csv module and the ground truth comes straight from the
synthetic scene (not from the recording the scorer reads).
"""

import csv
import json
import math

import numpy as np
import pytest

from drivers import open_source
from drivers.synth import SynthSource
from fusion_pf.cli import main
from fusion_pf.experiments import job_config, job_seed
from fusion_pf.pipeline import TrackConfig, TrackCsv, track

SEED, FRAMES, BACKGROUND, SIZE = 5, 30, 5, (320, 200)  # seed 5: palm occluded in the first frames
SPEC = f"synth:seed={SEED},frames={FRAMES},background_frames={BACKGROUND},size={SIZE[0]}x{SIZE[1]}"
SOURCES = ("colour", "depth", "skeleton")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("synthetic")
    rec, out, table = d / "rec.mcap", d / "tracked.mcap", d / "tracked.csv"
    assert main(["record", SPEC, str(rec)]) == 0
    assert main(["track", str(rec), "-o", str(out), "--csv", str(table), "--csv-latency", "--no-progress"]) == 0
    return {"dir": d, "rec": rec, "mcap": out, "csv": table}


def ground_truth():
    scene = SynthSource(frames=FRAMES, seed=SEED, size=SIZE, background_frames=BACKGROUND)
    return {i: scene.ground_truth(i) for i in range(FRAMES) if scene.ground_truth(i) is not None}


def score_json(capsys, *argv):
    code = main(["score", *map(str, argv), "--json"])
    out, err = capsys.readouterr()
    assert code == 0, err
    return json.loads(out)


def expected_from_csv(path):
    gt = ground_truth()
    errors = {s: {} for s in (*SOURCES, "fused")}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            g = gt[int(row["frame"])]
            for s, (cu, cv) in {**{s: (f"{s}_u", f"{s}_v") for s in SOURCES}, "fused": ("u", "v")}.items():
                if row[cu] != "":
                    errors[s][int(row["frame"])] = math.hypot(float(row[cu]) - g.u, float(row[cv]) - g.v)
    wins = {s: 0 for s in errors}
    for frame in gt:
        present = {s: e[frame] for s, e in errors.items() if frame in e}
        if len(present) < 2:  # nobody to beat: no point
            continue
        best = min(present.values())
        for s, e in present.items():
            wins[s] += e <= best + 1e-6
    rmse = {s: math.sqrt(sum(x * x for x in e.values()) / len(e)) for s, e in errors.items()}
    coverage = {s: len(e) / len(gt) for s, e in errors.items()}
    return rmse, coverage, wins


def test_score_csv_against_ground_truth_end_to_end(files, capsys):
    rep = score_json(capsys, files["csv"], "--ground-truth", files["rec"], "--plots", files["dir"] / "plots")
    rmse, coverage, wins = expected_from_csv(files["csv"])
    gt = ground_truth()
    assert rep["n_frames"] == FRAMES - BACKGROUND and rep["n_reference"] == len(gt)
    n_occluded = sum(p.occluded for p in gt.values())
    assert n_occluded > 0 and rep["n_occluded"] == n_occluded
    for s in (*SOURCES, "fused"):
        assert rep["sources"][s]["rmse_px"] == pytest.approx(rmse[s], rel=1e-9), s
        assert rep["sources"][s]["coverage"] == pytest.approx(coverage[s]), s
        assert rep["sources"][s]["bestmax"] == wins[s], s
    lat = rep["latency_ms"]
    assert {"colour", "depth", "skeleton", "filter", "total"} <= set(lat) and lat["total"]["mean"] > 0
    for name in ("errors_per_frame.png", "latency_per_frame.png"):
        assert (files["dir"] / "plots" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_score_reports_how_often_the_uncertainty_covers_the_error(files, capsys):
    gt = ground_truth()
    within = []
    with open(files["csv"], newline="") as f:
        for row in csv.DictReader(f):
            if row["u"] and row["sigma_px"] and int(row["frame"]) in gt:
                g = gt[int(row["frame"])]
                e = math.hypot(float(row["u"]) - g.u, float(row["v"]) - g.v)
                within.append((e <= float(row["sigma_px"]), e <= 2 * float(row["sigma_px"])))
    assert within
    expected = {
        "n": len(within),
        "within_1_sigma": pytest.approx(sum(a for a, _ in within) / len(within)),
        "within_2_sigma": pytest.approx(sum(b for _, b in within) / len(within)),
    }
    assert score_json(capsys, files["csv"], "--ground-truth", files["rec"])["uncertainty"] == expected
    from_mcap = score_json(capsys, files["mcap"], "--ground-truth", files["rec"])["uncertainty"]
    # the CSV rounds to 3 decimals, the MCAP keeps full precision: at most a frame on the boundary moves
    assert from_mcap["n"] == len(within)
    for k in ("within_1_sigma", "within_2_sigma"):
        assert from_mcap[k] == pytest.approx(expected[k], abs=1.01 / len(within)), k


def test_score_mcap_matches_csv(files, capsys):
    from_csv = score_json(capsys, files["csv"], "--ground-truth", files["rec"])
    from_mcap = score_json(capsys, files["mcap"], "--ground-truth", files["rec"])
    for s in (*SOURCES, "fused"):
        # The CSV rounds pixels to 3 decimals, the MCAP keeps full precision.
        assert from_mcap["sources"][s]["rmse_px"] == pytest.approx(from_csv["sources"][s]["rmse_px"], abs=2e-3)
        assert from_mcap["sources"][s]["coverage"] == from_csv["sources"][s]["coverage"]
    assert from_mcap["per_frame"]["frame"] == from_csv["per_frame"]["frame"]


def test_tiny_sweep_writes_figures_and_tables_and_is_deterministic(files, capsys):
    plots = files["dir"] / "sweep"
    argv = [files["mcap"], "--ground-truth", files["rec"], "--sweep", "5,50", "--runs", "2", "--no-progress"]
    rep = score_json(capsys, *argv, "--plots", plots, "--workers", "2")
    sweep = rep["sweep"]
    assert sweep["particle_counts"] == [5, 50] and sweep["runs"] == 2 and sweep["workers"] == 2
    bm = np.array(sweep["bestmax"])
    assert bm.shape == (2, 2, 4)
    n_ref = rep["n_reference"]
    assert (bm.sum(axis=2) >= n_ref).all()  # every reference frame awards at least one point
    for name in ("errors_per_frame.png", "latency_per_frame.png", "bestmax_vs_n.png", "multiexec_bestmax.png"):
        data = (plots / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000, name
    md = (plots / "score.md").read_text()
    assert "## Particle-count sweep (2 runs per N, seed 0)" in md
    assert md.count("\n| 5 |") == 1 and md.count("\n| 50 |") == 1
    assert json.loads((plots / "score.json").read_text())["sweep"]["bestmax"] == sweep["bestmax"]

    # One worker gives the same numbers (job seeds do not depend on scheduling).
    again = score_json(capsys, *argv, "--workers", "1")["sweep"]
    assert again["bestmax"] == sweep["bestmax"] and again["rmse_px"] == sweep["rmse_px"]

    # Job (N=50, run 1) is `fusion-pf track --particles 50 --seed job_seed(0, 50, 1)`: the CLI's CSV,
    # the same job tracked in this process and the sweep's RMSE (from the scene's own ground truth) agree.
    seed = job_seed(0, 50, 1)
    cli_csv = files["dir"] / "job.csv"
    assert (
        main(
            [
                "track",
                str(files["rec"]),
                "-o",
                str(files["dir"] / "job.mcap"),
                "--csv",
                str(cli_csv),
                "--particles",
                "50",
                "--seed",
                str(seed),
                "--no-progress",
            ]
        )
        == 0
    )
    with open_source(str(files["rec"])) as src:
        frames = list(src)
    here_csv = files["dir"] / "job_here.csv"
    with TrackCsv(here_csv) as table:
        for result in track(frames, job_config(TrackConfig(), 0, 50, 1)):
            table.write(result)
    assert here_csv.read_bytes() == cli_csv.read_bytes()
    gt = ground_truth()
    with open(cli_csv, newline="") as f:
        e = [
            math.hypot(float(r["u"]) - gt[int(r["frame"])].u, float(r["v"]) - gt[int(r["frame"])].v)
            for r in csv.DictReader(f)
            if r["u"] != "" and int(r["frame"]) in gt
        ]
    assert sweep["rmse_px"][1][1][3] == pytest.approx(math.sqrt(np.mean(np.square(e))), abs=2e-3)


def test_sweep_on_an_existing_dask_scheduler_matches_in_process(files, capsys):
    from distributed import LocalCluster

    argv = [files["mcap"], "--ground-truth", files["rec"], "--sweep", "5,25", "--runs", "2", "--no-progress"]
    inline = score_json(capsys, *argv, "--workers", "1")["sweep"]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        remote = score_json(capsys, *argv, "--scheduler", cluster.scheduler_address)["sweep"]
    assert remote["workers"] == 2 and inline["workers"] == 1
    assert remote["bestmax"] == inline["bestmax"] and remote["rmse_px"] == inline["rmse_px"]
    assert (
        main(
            [
                "score",
                str(files["mcap"]),
                "--ground-truth",
                str(files["rec"]),
                "--sweep",
                "5",
                "--scheduler",
                "tcp://127.0.0.1:9",
                "--no-progress",
            ]
        )
        == 2
    )
    assert "cannot reach the Dask scheduler 'tcp://127.0.0.1:9'" in capsys.readouterr().err


def test_sweep_rejects_a_bad_particle_count_before_tracking(files, capsys):
    assert main(["score", str(files["mcap"]), "--ground-truth", str(files["rec"]), "--sweep", "5,200000"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "particles (--particles) must be an integer in [1, 100000], got 200000" in err


def test_demo_on_a_small_recording(files, capsys):
    out = files["dir"] / "demo"
    code = main(
        [
            "demo",
            "--recording",
            str(files["rec"]),
            "--out",
            str(out),
            "--sweep",
            "5,50",
            "--runs",
            "2",
            "--workers",
            "1",
            "--no-progress",
        ]
    )
    stdout, err = capsys.readouterr()
    assert code == 0, err
    for name in (
        "tracked.csv",
        "errors_per_frame.png",
        "latency_per_frame.png",
        "bestmax_vs_n.png",
        "multiexec_bestmax.png",
        "score.md",
        "score.json",
    ):
        assert (out / name).stat().st_size > 0, name
        assert str(out / name) in stdout, name
    assert "## Particle-count sweep (2 runs per N, seed 0)" in stdout and "Demo took" in stdout
    rep = json.loads((out / "score.json").read_text())
    assert rep["n_reference"] == len(ground_truth()) and len(rep["sweep"]["bestmax"]) == 2
    # the demo's tracked.csv is `fusion-pf track --csv` with the latency columns filled in
    plain = files["dir"] / "plain.csv"
    assert (
        main(["track", str(files["rec"]), "-o", str(files["dir"] / "plain.mcap"), "--csv", str(plain), "--no-progress"])
        == 0
    )
    with open(out / "tracked.csv", newline="") as a, open(plain, newline="") as b:
        demo_rows, plain_rows = list(csv.reader(a)), list(csv.reader(b))
    latency = [i for i, c in enumerate(plain_rows[0]) if c.startswith("latency_")]
    assert any(demo_rows[1][i] for i in latency) and not any(plain_rows[1][i] for i in latency)
    blank = demo_rows[:1] + [[("" if i in latency else c) for i, c in enumerate(row)] for row in demo_rows[1:]]
    assert blank == plain_rows


def test_demo_without_recording_is_a_one_line_error(tmp_path, capsys):
    code = main(["demo", "--recording", str(tmp_path / "none.mcap"), "--out", str(tmp_path / "o")])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    assert (
        err.strip() == f"fusion-pf: error: --recording {tmp_path / 'none.mcap'} does not exist; "
        "expected an MCAP recording with ground truth"
    )
