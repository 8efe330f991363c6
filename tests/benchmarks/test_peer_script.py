"""benchmarks/peer.py's summary and the acquisition cues it times (MediaPipe itself is not installed here)."""

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("peer", ROOT / "benchmarks" / "peer.py")
peer = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(peer)


def test_summary_compares_the_frames_both_sides_tracked_and_scores_against_ground_truth():
    n = 8
    r = {
        "size": (64, 48),
        "fp_ms": np.array([50.0, 2, 2, 2, 2, 2, 9, 2]),
        "fp_track": np.array([0.0, 0, 1, 1, 1, 1, 1, 1]),
        "mp_ms": np.array([40.0, 30, 4, 4, 4, 4, 4, 4]),
        "mp_track": np.array([0.0, 0, 1, 1, 1, 1, 1, 1]),
        "fp_acq_ms": np.full(n, 10.0),
        "mp_acq_ms": np.full(n, 20.0),
        "fp_acq_cpu": np.full(n, 9.0),
        "mp_acq_cpu": np.full(n, 12.0),
        "gt_u": np.full(n, 10.0),
        "gt_v": np.full(n, 10.0),
        "fp_u": np.array([13.0, 10, 10, 10, 10, 10, 10, math.nan]),
        "fp_v": np.full(n, 14.0),
        "mp_u": np.full(n, math.nan),
        "mp_v": np.full(n, math.nan),
        "fp_cpu": np.full(n, 3.0),
        "mp_cpu": np.full(n, 6.0),
        "fp_rq": np.array([0.0, 0, 0, 1, 0, 1, 7, 0]),
        "mp_rq": np.zeros(n),
        "fp_first": np.array([1.0, 0, 1, 0, 1, 0, 1, 0]),
        "start": np.array([1.0, 0, 0, 0, 0, 0, 0, 0]),
    }
    s = peer.summarise(r)
    assert s["tracking_frames"] == 6  # frames 2-7: both sides tracked
    assert s["fp"]["track_median_ms"] == 2.0 and s["mp"]["track_median_ms"] == 4.0
    assert s["ratio_track_median_ms"] == pytest.approx(0.5)
    assert s["ratio_acq_median_ms"] == pytest.approx(0.5) == s["ratio_track_cpu_median_ms"]
    assert s["ratio_acq_cpu_median_ms"] == pytest.approx(0.75) == s["ratio_acq_cpu_p99_ms"]
    # run-queue wait of the tracked frames 2-7 (MediaPipe's none: no ratio); the 9 ms frame 6 ran first
    assert s["fp"]["track_rq_median_ms"] == 0.5 and s["fp"]["track_rq_p95_ms"] == pytest.approx(
        np.percentile([0, 1, 0, 1, 7, 0], 95)
    )
    assert math.isnan(s["ratio_track_rq_median_ms"])
    assert (
        s["fp"]["track_p95_first_ms"] == pytest.approx(np.percentile([2, 2, 9], 95))
        and s["fp"]["track_p95_second_ms"] == 2.0
    )
    assert s["mp"]["track_p95_first_ms"] == 4.0 == s["mp"]["track_p95_second_ms"]
    # live acquisition: each side's own acquisition frames of the tracking run but its first (start-up): frame 1
    assert s["fp"]["own_acquisition_frames"] == 1 and s["mp"]["own_acquisition_frames"] == 1
    assert s["fp"]["live_acq_median_ms"] == 2.0 == s["fp"]["live_acq_p99_ms"]
    assert s["mp"]["live_acq_median_ms"] == 30.0 == s["mp"]["live_acq_p99_ms"]
    assert s["ratio_live_acq_median_ms"] == pytest.approx(2 / 30) and s["ratio_live_acq_cpu_p95_ms"] == 0.5
    assert s["fp"]["all_p99_ms"] == pytest.approx(np.percentile(r["fp_ms"][1:], 99))
    assert s["fp"]["all_p99_ms"] < 9.0  # frame 0's 50 ms start-up left out
    # errors 5 (frame 0) and 4 (frames 1-6), frame 7 has no estimate
    assert s["fp"]["rmse_px"] == pytest.approx(math.sqrt((25 + 6 * 16) / 7))
    assert s["fp"]["coverage"] == pytest.approx(7 / 8)
    assert s["mp"]["coverage"] == 0.0 and math.isnan(s["mp"]["rmse_px"])
    # MediaPipe never tracking: each side's own tracking frames
    r["mp_track"] = np.zeros(n)
    s = peer.summarise(r)
    assert s["tracking_frames"] == 0 and s["fp"]["tracking_frames"] == 6 and s["mp"]["tracking_frames"] == 0
    assert s["fp"]["track_median_ms"] == 2.0 and math.isnan(s["mp"]["track_median_ms"])


def test_passes_pool_their_frames_and_leave_out_each_start_up():
    rng = np.random.default_rng(4)
    cols = ("fp_ms", "fp_cpu", "fp_rq", "fp_acq_ms", "fp_acq_cpu", "mp_ms", "mp_cpu", "mp_rq", "mp_acq_ms")
    cols += ("mp_acq_cpu", "gt_u", "gt_v", "fp_u", "fp_v", "mp_u", "mp_v", "fp_first")

    def one_pass(n):
        r = {"size": (64, 48), **{c: rng.uniform(1, 9, n) for c in cols}}
        r["fp_first"] = np.arange(n) % 2.0
        r["fp_track"] = r["mp_track"] = (np.arange(n) > 1).astype(float)
        r["fp_ms"][0] = r["mp_ms"][0] = 500.0  # each pass's start-up
        r["start"] = (np.arange(n) == 0).astype(float)
        return r

    a, b = one_pass(12), one_pass(9)
    s = peer.summarise(peer.pool([a, b]))
    assert s["frames"] == 21 and s["tracking_frames"] == 10 + 7
    fp = np.concatenate([a["fp_ms"][2:], b["fp_ms"][2:]])
    assert s["fp"]["track_p95_ms"] == pytest.approx(np.percentile(fp, 95))
    # live: every frame but the two start-ups; the second pass's frame 1 (no hand before it) is its own acquisition
    every = np.concatenate([a["fp_ms"][1:], b["fp_ms"][1:]])
    assert s["fp"]["all_p99_ms"] == pytest.approx(np.percentile(every, 99)) and s["fp"]["all_p99_ms"] < 500
    assert s["fp"]["own_acquisition_frames"] == 2
    err = np.hypot(*(np.concatenate([p[f"fp_{x}"] - p[f"gt_{x}"] for p in (a, b)]) for x in "uv"))
    assert s["fp"]["rmse_px"] == pytest.approx(math.sqrt(np.mean(err**2)))


def test_passes_must_be_at_least_one(capsys):
    with pytest.raises(SystemExit) as exc:
        peer.main(["x.mcap", "--passes", "0"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.endswith("--passes must be a whole number >= 1, got 0")


def test_acquisition_cues_search_the_whole_frame_of_a_recording(tmp_path):
    from drivers import open_source
    from fusion_pf.cli import main as cli
    from fusion_pf.pipeline import TrackConfig

    rec = tmp_path / "s.mcap"
    assert cli(["synth", str(rec), "--frames", "6", "--size", "160x100", "--seed", "3"]) == 0
    cues, context = peer._acquisition_cues(rec, TrackConfig())
    assert set(cues) >= {"colour", "depth", "skeleton"}
    with open_source(rec) as src:
        frame = src.frame(src.info().background_frames + 2)
    ctx = context(frame)
    assert ctx.search and ctx.prior is None and (ctx.roi.x0, ctx.roi.y0, ctx.roi.x1, ctx.roi.y1) == (0, 0, 160, 100)
    found = [cue.measure(frame, ctx).measurement for cue in cues.values()]
    assert any(m is not None for m in found)


def test_run_queue_wait_grows_while_this_process_waits_for_a_core():
    """Linux schedstat: spinning while more spinning processes than cores run, this process waits for a core."""
    import os
    import subprocess
    import sys
    import time

    if not sys.platform.startswith("linux"):
        pytest.skip("schedstat is Linux's")
    assert not math.isnan(peer.run_queue_ns()), "Linux without /proc/<pid>/task/*/schedstat"
    spinners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2 * (os.cpu_count() or 1))]
    try:
        time.sleep(0.1)
        before = peer.run_queue_ns()
        end = time.perf_counter() + 0.3
        while time.perf_counter() < end:
            pass
        waited = peer.run_queue_ns() - before
    finally:
        for p in spinners:
            p.kill()
            p.wait()
    assert waited > 10e6  # of 300 ms runnable with 3 runnable tasks per core, far more than 10 ms waiting


def test_setups_pair_fusion_pf_landmark_models_with_mediapipe_complexity(capsys):
    assert peer.parse_setups("full:1,full_int8:1, lite:0,full:1:full_int8") == [
        ("full", 1, "full"),
        ("full_int8", 1, "full"),
        ("lite", 0, "full"),
        ("full", 1, "full_int8"),
    ]
    for bad in ("full", "full:2", "tiny:1", "full:1,", "full:1:tiny"):
        assert peer.parse_setups(bad) is None, bad
    with pytest.raises(SystemExit):
        peer.main(["x.mcap", "--setups", "full:2"])
    assert "--setups must be LANDMARK:COMPLEXITY[:PALM]" in capsys.readouterr().err
    stats = {k: 1.0 for k in ("track_median_ms", "track_p95_ms", "track_cpu_median_ms", "track_cpu_p95_ms")}
    stats |= {k: 1.0 for k in ("track_rq_median_ms", "track_rq_p95_ms", "track_p95_first_ms", "track_p95_second_ms")}
    stats |= {k: 1.0 for k in ("acq_median_ms", "acq_p95_ms", "acq_p99_ms")}
    stats |= {k: 1.0 for k in ("acq_cpu_median_ms", "acq_cpu_p95_ms", "acq_cpu_p99_ms")}
    stats |= {f"live_{k}": 1.0 for k in stats if k.startswith("acq")} | {"all_p99_ms": 1.0}
    side = {**stats, "own_acquisition_frames": 0, "tracking_frames": 3}
    s = {"size": (64, 48), "frames": 3, "tracking_frames": 3, "fp": side, "mp": side}
    s |= {f"ratio_{k}": 1.0 for k in stats}
    peer.print_summary(Path("r.mcap"), "quiet", ("full_int8", 0, "full_int8"), (1.0, 1.0), s, ("hand", "depth"))
    out = capsys.readouterr().out
    assert "fusion-pf cues hand,depth" in out and "live acquisition, p99" in out
    assert "run-queue wait, p95" in out and "p95 right after the other side" in out
    assert "0 ms before each side's turn" in out
    with pytest.raises(SystemExit):
        peer.main(["x.mcap", "--gap-ms", "-1"])
    assert "--gap-ms must be a number of ms >= 0, got -1.0" in capsys.readouterr().err
    assert "fusion-pf hand landmarks full_int8, palm detector full_int8" in out
    assert "MediaPipe model_complexity 0 (lite" in out
