"""``fusion-pf track A.mcap B.mcap ... --out-dir DIR`` (a study on Dask) and ``fusion-pf score OUT_DIR --ground-truth REF_DIR``."""

import csv
import json
import math
import os
import signal
import subprocess
import time
from pathlib import Path

import psutil
import pytest

from drivers.tracker_topics import read_json_topic, recording_metadata

from ..conftest import CLI, run_cli


def _recordings(root: Path, seeds, frames: int = 20) -> list[Path]:
    root.mkdir(exist_ok=True)
    out = []
    for s in seeds:
        path = root / f"rec{s}.mcap"
        r = run_cli("synth", path, "--frames", frames, "--seed", s, "--size", "320x200", "--no-progress")
        assert r.returncode == 0, r.stderr
        out.append(path)
    return out


def _reference(recs: list[Path], ref_dir: Path) -> None:
    """Each recording tracked alone, as ``fusion-pf track REC -o ref/NAME.mcap --csv ref/NAME.csv``."""
    ref_dir.mkdir()
    for rec in recs:
        r = run_cli(
            "track", rec, "-o", ref_dir / f"{rec.stem}.mcap", "--csv", ref_dir / f"{rec.stem}.csv", "--no-progress"
        )
        assert r.returncode == 0, r.stderr


def _same_as_reference(out: Path, ref: Path, name: str) -> None:
    assert (out / f"{name}.csv").read_bytes() == (ref / f"{name}.csv").read_bytes()
    # the MCAP: the same messages but for the wall-clock latencies
    for topic in ("/tracker/estimate", "/tracker/cues"):
        a = read_json_topic(out / f"{name}.mcap", topic)
        b = read_json_topic(ref / f"{name}.mcap", topic)
        for (ta, ma), (tb, mb) in zip(a, b, strict=True):
            ma.pop("latency_ns", None), mb.pop("latency_ns", None)
            assert (ta, ma) == (tb, mb)
    assert recording_metadata(out / f"{name}.mcap") == recording_metadata(ref / f"{name}.mcap")


def _rows(path: Path) -> dict[str, dict]:
    with open(path, newline="") as fh:
        return {r["recording"]: r for r in csv.DictReader(fh)}


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """Three recordings tracked alone (the reference outputs) and as a study on a local 2-worker cluster."""
    root = tmp_path_factory.mktemp("study")
    os.chdir(root)  # relative paths: the outputs name their input as given
    recs = [p.relative_to(root) for p in _recordings(root / "recs", (1, 2, 3))]
    Path("recs/damaged.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\0" * 64)
    _reference(recs, Path("ref"))
    r = run_cli(
        "track",
        "recs/rec1.mcap",
        "recs/rec2.mcap",
        "recs/rec3.mcap",
        "recs/damaged.mcap",
        "--out-dir",
        "out",
        "--workers",
        2,
    )
    return root, recs, r


def test_a_study_on_two_workers_writes_what_each_track_writes_alone(study):
    root, recs, r = study
    assert r.returncode == 3, r.stderr  # one recording failed: partial study
    for rec in recs:
        _same_as_reference(root / "out", root / "ref", rec.stem)
    assert not list((root / "out").glob(".*"))  # no temporary file left


def test_the_summary_has_a_row_per_recording_and_the_failure_is_one_of_them(study):
    root, recs, r = study
    rows = _rows(root / "out" / "study.csv")
    assert list(rows) == ["rec1", "rec2", "rec3", "damaged"]
    assert rows["damaged"]["status"].startswith("failed: ") and "damaged.mcap" in rows["damaged"]["status"]
    assert "damaged: failed" in r.stderr
    for rec in recs:
        row = rows[rec.stem]
        with open(root / "ref" / f"{rec.stem}.csv", newline="") as fh:
            states = [x["state"] for x in csv.DictReader(fh)]
        assert row["status"] == "done" and int(row["frames"]) == len(states) == 20
        assert int(row["tracking"]) == states.count("tracking") and int(row["lost"]) == states.count("lost")
        assert float(row["ms_per_frame"]) > 0
    text = (root / "out" / "study.md").read_text()
    assert "| rec2 | done | 20 |" in text


def test_a_rerun_skips_finished_recordings_and_retracks_a_changed_one(study):
    root, recs, _ = study
    os.chdir(root)
    before = (root / "out" / "rec1.mcap").stat().st_mtime_ns
    r = run_cli("track", "recs", "--out-dir", "out", "--workers", 1)
    assert "3 already done, 1 to track" in r.stderr, r.stderr  # the damaged one is tried again
    assert (root / "out" / "rec1.mcap").stat().st_mtime_ns == before
    # other tracker settings: nothing is done any more
    r = run_cli("track", "recs/rec1.mcap", "recs/rec2.mcap", "--out-dir", "out", "--workers", 1, "--particles", 50)
    assert "0 already done, 2 to track" in r.stderr and r.returncode == 0, r.stderr


def test_score_a_study_per_recording_and_pooled(study):
    root, recs, _ = study
    os.chdir(root)
    r = run_cli("score", "ref", "--ground-truth", "recs")
    assert r.returncode == 0, r.stderr
    per, covered = {}, {}
    for rec in recs:
        one = run_cli("score", f"ref/{rec.stem}.csv", "--ground-truth", rec, "--json")
        report = json.loads(one.stdout)
        per[rec.stem] = fused = report["sources"]["fused"]
        covered[rec.stem] = report["uncertainty"]
        line = next(x for x in r.stdout.splitlines() if x.startswith(f"| {rec.stem} |"))
        assert f"| {fused['rmse_px']:.2f} |" in line
        assert line.rstrip().endswith(f"| {covered[rec.stem]['within_2_sigma']:.3f} |")
    # pooled RMSE: the frame-weighted root mean square of the recordings' RMSEs (a second computation)
    n = {k: v["n_scored"] for k, v in per.items()}
    pooled = math.sqrt(sum(n[k] * per[k]["rmse_px"] ** 2 for k in per) / sum(n.values()))
    line = next(x for x in r.stdout.splitlines() if x.startswith("| fused |"))
    assert line.split("|")[2].strip() == f"{pooled:.2f}"
    # pooled uncertainty coverage: the frame-weighted mean of the recordings' shares (a second computation)
    m = sum(c["n"] for c in covered.values())
    within_2 = sum(c["n"] * c["within_2_sigma"] for c in covered.values()) / m
    assert f"within `2 sigma_px` in {100 * within_2:.1f} % of the {m} frames" in r.stdout


def test_an_unreachable_scheduler_is_a_one_line_error(tmp_path):
    recs = _recordings(tmp_path / "recs", (1,), frames=3)
    with psutil_free_port() as port:
        r = run_cli("track", *recs, "--out-dir", tmp_path / "out", "--scheduler", f"tcp://127.0.0.1:{port}")
    assert r.returncode == 2
    assert r.stderr.count("\n") == 1 and "cannot reach the Dask scheduler" in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


class psutil_free_port:
    """A port nobody listens on (bound and released)."""

    def __enter__(self) -> int:
        import socket

        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            return s.getsockname()[1]

    def __exit__(self, *exc) -> None:
        return None


def _wait_for(predicate, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not predicate():
        assert time.monotonic() < end, "timed out"
        time.sleep(0.02)


def test_a_study_killed_mid_task_leaves_no_half_written_output_and_the_rerun_tracks_only_the_rest(tmp_path):
    os.chdir(tmp_path)
    recs = [p.relative_to(tmp_path) for p in _recordings(tmp_path / "recs", (4, 5, 6, 7), frames=40)]
    _reference(recs, Path("ref"))
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [*CLI, "track", "recs", "--out-dir", "out", "--workers", "1"], stderr=subprocess.PIPE, text=True
    )
    # killed while the second recording is being written (the first one is finished)
    _wait_for(lambda: (out / "rec4.done.json").exists() and (out / ".rec5.partial.mcap").exists())
    proc.send_signal(signal.SIGKILL)
    proc.communicate()
    finished = sorted(p.name for p in out.glob("*.mcap") if not p.name.startswith("."))
    assert finished == ["rec4.mcap"]  # rec5 is only under its temporary name
    _same_as_reference(out, Path("ref"), "rec4")
    r = run_cli("track", "recs", "--out-dir", "out", "--workers", 2)
    assert r.returncode == 0, r.stderr
    assert "1 already done, 3 to track" in r.stderr
    for rec in recs:
        _same_as_reference(out, Path("ref"), rec.stem)
    assert not list(out.glob(".*"))


def test_a_worker_killed_mid_task_is_retried_and_leaves_no_half_written_output(tmp_path):
    os.chdir(tmp_path)
    recs = [p.relative_to(tmp_path) for p in _recordings(tmp_path / "recs", (8, 9), frames=60)]
    _reference(recs, Path("ref"))
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [*CLI, "track", "recs", "--out-dir", "out", "--workers", "2"], stderr=subprocess.PIPE, text=True
    )
    _wait_for(lambda: any(out.glob(".*.partial.mcap")))
    workers = psutil.Process(proc.pid).children(recursive=True)
    busy = [w for w in workers if any(f.path.endswith(".partial.mcap") for f in w.open_files())]
    assert busy, "no worker was writing"
    busy[0].kill()
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err
    for rec in recs:
        _same_as_reference(out, Path("ref"), rec.stem)
    assert not list(out.glob(".*"))


def test_a_study_of_two_targets_writes_what_each_track_writes_alone_and_sums_up_each_target(tmp_path):
    os.chdir(tmp_path)
    Path("recs").mkdir()
    recs = []
    for s in (1, 2):
        rec = Path(f"recs/two{s}.mcap")
        r = run_cli("synth", rec, "--frames", 15, "--seed", s, "--size", "320x200", "--hands", 2, "--no-progress")
        assert r.returncode == 0, r.stderr
        recs.append(rec)
    targets = ("--targets", "right_hand,left_hand")
    Path("ref").mkdir()
    for rec in recs:
        ref = Path("ref", rec.stem)
        r = run_cli(
            "track", rec, "-o", ref.with_suffix(".mcap"), "--csv", ref.with_suffix(".csv"), *targets, "--no-progress"
        )
        assert r.returncode == 0, r.stderr
    r = run_cli("track", *recs, "--out-dir", "out", "--workers", 1, *targets)
    assert r.returncode == 0, r.stderr
    rows = _rows(Path("out/study.csv"))
    for rec in recs:
        _same_as_reference(Path("out"), Path("ref"), rec.stem)
        with open(f"ref/{rec.stem}.csv", newline="") as fh:
            table = list(csv.DictReader(fh))
        row = rows[rec.stem]
        assert row["status"] == "done" and int(row["frames"]) == len(table) == 15
        assert float(row["ms_per_frame"]) > 0
        covered = 0
        for t in ("right_hand", "left_hand"):
            states = [x[f"{t}_state"] for x in table]
            n = sum(x[f"{t}_u"] != "" for x in table)
            covered += n
            assert float(row[f"{t}_coverage"]) == round(n / 15, 4) > 0
            assert int(row[f"{t}_tracking"]) == states.count("tracking")
            assert int(row[f"{t}_lost"]) == states.count("lost")
        assert float(row["coverage"]) == pytest.approx(covered / 30, abs=1e-4)
        assert int(row["tracking"]) == int(row["right_hand_tracking"]) + int(row["left_hand_tracking"])
    header = Path("out/study.md").read_text().splitlines()[4]
    assert "| right_hand_coverage |" in header and "| left_hand_reacquisitions |" in header

    # scored per recording and target, and pooled per target
    r = run_cli("score", "out", "--ground-truth", "recs")
    assert r.returncode == 0, r.stderr
    per = {}
    for rec in recs:
        one = run_cli("score", f"ref/{rec.stem}.csv", "--ground-truth", rec, "--json")
        per[rec.stem] = json.loads(one.stdout)
        for t, m in per[rec.stem]["targets"].items():
            line = next(x for x in r.stdout.splitlines() if x.startswith(f"| {rec.stem} | {t} |"))
            assert f"| {m['rmse_px']:.2f} |" in line and f"| {m['coverage']:.3f} |" in line
            assert f"| {m['uncertainty']['within_2_sigma']:.3f} |" in line  # the share within 2 sigma_px
    swaps = sum(p["swaps"] for p in per.values())
    assert f"identity swaps {swaps})" in r.stdout
    for t in ("right_hand", "left_hand"):
        # pooled RMSE: the frame-weighted root mean square of the recordings' RMSEs (a second computation)
        n = {k: round(p["targets"][t]["n_reference"] * p["targets"][t]["coverage"]) for k, p in per.items()}
        pooled = math.sqrt(sum(n[k] * per[k]["targets"][t]["rmse_px"] ** 2 for k in per) / sum(n.values()))
        line = next(x for x in r.stdout.splitlines() if x.startswith(f"| {t} |"))
        assert line.split("|")[2].strip() == f"{pooled:.2f}"
        # pooled share within 2 sigma_px: the frame-weighted mean of the recordings' shares
        u = {k: p["targets"][t]["uncertainty"] for k, p in per.items()}
        within = sum(u[k]["n"] * u[k]["within_2_sigma"] for k in u) / sum(u[k]["n"] for k in u)
        assert line.split("|")[7].strip() == f"{within:.3f}"
