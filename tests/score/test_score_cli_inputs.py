"""``fusion-pf score`` on hand-written files: the report's numbers and bad inputs (exit 2, one line)."""

import csv
import json
import math

import pytest
from mcap.writer import Writer

from fusion_pf.cli import main

HEADER = [
    "frame",
    "timestamp_ns",
    "u",
    "v",
    "colour_u",
    "colour_v",
    "depth_u",
    "depth_v",
    "skeleton_u",
    "skeleton_v",
    "x_mm",
    "y_mm",
    "z_mm",
    "ess",
    "resampled",
    "n_particles",
    "latency_decode_ms",
    "latency_colour_ms",
    "latency_depth_ms",
    "latency_skeleton_ms",
    "latency_filter_ms",
    "latency_total_ms",
]
T0, DT = 1_000_000_000, 33_333_333

# Ground truth: frame 0 is a background frame (no ground-truth message).
GT = {1: (100.0, 50.0, False), 2: (110.0, 50.0, True), 3: (120.0, 60.0, False)}
# Per frame: estimate, colour, depth, skeleton (None = missing).
ROWS = {
    0: (None, None, None, None),
    1: ((103.0, 54.0), (100.0, 50.0), (106.0, 58.0), None),  # e: 5, 0, 10, -
    2: ((110.0, 53.0), None, (110.0, 54.0), (116.0, 58.0)),  # e: 3, -, 4, 10
    3: ((120.0, 61.0), (123.0, 64.0), None, (120.0, 61.0)),  # e: 1, 5, -, 1 (tie fused/skeleton)
}


def write_csv(path, rows=ROWS, header=HEADER):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for frame, (est, col, dep, ske) in rows.items():
            cells = [frame, T0 + frame * DT]
            for p in (est, col, dep, ske):
                cells += ["", ""] if p is None else [f"{p[0]:.3f}", f"{p[1]:.3f}"]
            cells += ["", "", "", "", "0", "100", "0.5", "1.0", "9.0", "0.1", "0.2", "10.8"]
            w.writerow([str(c) for c in cells][: len(header)])
    return path


def write_gt(path, gt=GT, t0=T0):
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("fusion_pf.PalmPoint", "jsonschema", b"{}")
        cid = w.register_channel("/ground_truth/palm", "json", sid)
        for frame, (u, v, occ) in gt.items():
            t = t0 + frame * DT
            w.add_message(cid, t, json.dumps({"u": u, "v": v, "occluded": occ}).encode(), t)
        w.finish()
    return path


def run_cli(capsys, *argv):
    code = main(["score", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_score_csv_against_ground_truth(tmp_path, capsys):
    tracked, gt = write_csv(tmp_path / "t.csv"), write_gt(tmp_path / "gt.mcap")
    code, out, err = run_cli(capsys, tracked, "--ground-truth", gt, "--json", "--plots", tmp_path / "plots")
    assert code == 0, err
    rep = json.loads(out)
    src = rep["sources"]
    assert src["fused"]["rmse_px"] == pytest.approx(math.sqrt((25 + 9 + 1) / 3))
    assert src["depth"]["rmse_px"] == pytest.approx(math.sqrt((100 + 16) / 2))
    assert src["colour"]["coverage"] == pytest.approx(2 / 3)
    # BestMax: f1 colour (0); f2 fused (3); f3 fused & skeleton tie (1).
    assert {k: v["bestmax"] for k, v in src.items()} == {"colour": 1, "depth": 0, "skeleton": 1, "fused": 2}
    assert rep["bestmax"]["n_ties"] == 1
    assert rep["n_reference"] == 3 and rep["n_occluded"] == 1
    assert src["fused"]["rmse_occluded_px"] == pytest.approx(3.0)
    assert rep["per_frame"]["error_px"]["fused"] == [None, 5.0, 3.0, 1.0]
    assert rep["latency_ms"]["total"]["mean"] == pytest.approx(10.8)
    for name in ("errors_per_frame.png", "latency_per_frame.png", "score.md", "score.json"):
        assert (tmp_path / "plots" / name).stat().st_size > 0
    assert json.loads((tmp_path / "plots" / "score.json").read_text())["sources"] == src
    md = (tmp_path / "plots" / "score.md").read_text()
    assert "| fused (DF-PF) | 3.42 |" in md  # sqrt(35/3) = 3.4157


def test_markdown_is_default_output(tmp_path, capsys):
    code, out, _ = run_cli(capsys, write_csv(tmp_path / "t.csv"), "--ground-truth", write_gt(tmp_path / "g.mcap"))
    assert code == 0
    assert out.startswith("## Accuracy against ground truth")
    assert "| depth | 7.62 |" in out  # sqrt(116/2) = 7.6158


def one_line_error(code, out, err):
    assert code == 2
    assert out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("fusion-pf: error: "), err
    return lines[0]


def test_missing_columns(tmp_path, capsys):
    header = [h for h in HEADER if h not in ("u", "v")]
    path = tmp_path / "t.csv"
    with open(path, "w") as f:
        f.write(",".join(header) + "\n")
    msg = one_line_error(*run_cli(capsys, path, "--ground-truth", write_gt(tmp_path / "g.mcap")))
    assert "missing column(s) u, v" in msg and str(path) in msg


def test_frame_count_mismatch(tmp_path, capsys):
    tracked = write_csv(tmp_path / "t.csv", rows={k: ROWS[k] for k in (0, 1, 2)})
    msg = one_line_error(*run_cli(capsys, tracked, "--ground-truth", write_gt(tmp_path / "g.mcap")))
    assert "frame count mismatch" in msg and "3 reference frames but 1 of them" in msg
    assert f"timestamp_ns {T0 + 3 * DT}" in msg


def test_ground_truth_from_another_recording(tmp_path, capsys):
    gt = write_gt(tmp_path / "g.mcap", t0=T0 + 5)
    msg = one_line_error(*run_cli(capsys, write_csv(tmp_path / "t.csv"), "--ground-truth", gt))
    assert "frame count mismatch" in msg and "3 of them" in msg


@pytest.mark.parametrize("content", [b"hello\n", b"\x00\x01binary"])
def test_unknown_reference_file(tmp_path, capsys, content):
    ref = tmp_path / "ref.txt"
    ref.write_bytes(content)
    msg = one_line_error(*run_cli(capsys, write_csv(tmp_path / "t.csv"), "--reference", ref))
    assert str(ref) in msg and "unknown" in msg


def test_recording_given_as_annotation_reference(tmp_path, capsys):
    gt = write_gt(tmp_path / "g.mcap")
    msg = one_line_error(*run_cli(capsys, write_csv(tmp_path / "t.csv"), "--reference", gt))
    assert "--ground-truth" in msg


def test_ground_truth_without_topic(tmp_path, capsys):
    gt = write_gt(tmp_path / "g.mcap", gt={})
    msg = one_line_error(*run_cli(capsys, write_csv(tmp_path / "t.csv"), "--ground-truth", gt))
    assert "no ground-truth palm messages" in msg


def test_missing_tracked_file(tmp_path, capsys):
    msg = one_line_error(*run_cli(capsys, tmp_path / "nope.csv", "--ground-truth", write_gt(tmp_path / "g.mcap")))
    assert "nope.csv" in msg


def test_bad_cell(tmp_path, capsys):
    path = write_csv(tmp_path / "t.csv")
    text = path.read_text().splitlines()
    cells = text[2].split(",")
    cells[4] = "abc"
    text[2] = ",".join(cells)
    path.write_text("\n".join(text) + "\n")
    msg = one_line_error(*run_cli(capsys, path, "--ground-truth", write_gt(tmp_path / "g.mcap")))
    assert "line 3, column 'colour_u' must be a number or empty, got 'abc'" in msg


@pytest.mark.parametrize(
    "extra, expected",
    [
        (["--sweep", "5,x"], "'x'"),
        (["--sweep", "0,5"], "must be >= 1, got 0"),
        (["--sweep", "5", "--runs", "0"], "runs (--runs) must be an integer in [1, 100000], got 0"),
        (["--workers", "0"], "workers (--workers) must be an integer in [1, 1024], got 0"),
        (["--workers", "2", "--scheduler", "tcp://h:1"], "with --scheduler the cluster's own workers run"),
    ],
)
def test_bad_sweep_options(tmp_path, capsys, extra, expected):
    msg = one_line_error(
        *run_cli(capsys, write_csv(tmp_path / "t.csv"), "--ground-truth", write_gt(tmp_path / "g.mcap"), *extra)
    )
    assert expected in msg


def write_annotations(path, shift_ns=0):
    from fusion_pf.annotate.db import AnnotationDB

    db = AnnotationDB(path, recording="rec.mcap", n_frames=4, width=640, height=480)
    try:
        for op in ("ann", "bob"):
            db.set_click(op, 0, T0, None, None)  # background frame: nobody sees a palm
        for frame, (u, v, _occ) in GT.items():
            t = T0 + frame * DT + (shift_ns if frame == 2 else 0)
            # Two operators 4 px apart horizontally: their mean is the ground truth.
            db.set_click("ann", frame, t, u - 2.0, v)
            db.set_click("bob", frame, t, u + 2.0, v)
    finally:
        db.close()
    return path


def test_score_against_annotations(tmp_path, capsys):
    db = write_annotations(tmp_path / "ann.sqlite")
    code, out, err = run_cli(capsys, write_csv(tmp_path / "t.csv"), "--reference", db, "--json")
    assert code == 0, err
    rep = json.loads(out)
    assert rep["reference"]["kind"] == "annotations"
    assert rep["n_reference"] == 3 and rep["n_occluded"] is None
    assert rep["sources"]["fused"]["rmse_px"] == pytest.approx(math.sqrt((25 + 9 + 1) / 3))
    assert rep["sources"]["fused"]["rmse_occluded_px"] is None
    assert {k: v["bestmax"] for k, v in rep["sources"].items()} == {"colour": 1, "depth": 0, "skeleton": 1, "fused": 2}


def test_annotation_timestamp_mismatch(tmp_path, capsys):
    db = write_annotations(tmp_path / "ann.sqlite", shift_ns=7)
    msg = one_line_error(*run_cli(capsys, write_csv(tmp_path / "t.csv"), "--reference", db))
    assert f"timestamp mismatch at frame 2: {tmp_path / 't.csv'} has timestamp_ns {T0 + 2 * DT}" in msg
    assert f"{db} has {T0 + 2 * DT + 7}" in msg


def test_annotations_beyond_the_tracker_output(tmp_path, capsys):
    db = write_annotations(tmp_path / "ann.sqlite")
    tracked = write_csv(tmp_path / "t.csv", rows={k: ROWS[k] for k in (0, 1)})
    msg = one_line_error(*run_cli(capsys, tracked, "--reference", db))
    assert "frame count mismatch" in msg and "4 reference frames but 2 of them (first frame 2)" in msg


def test_bad_frame_column_and_repeated_frames(tmp_path, capsys):
    path = write_csv(tmp_path / "t.csv")
    lines = path.read_text().splitlines()
    path.write_text("\n".join([lines[0], lines[1].replace("0,", "0.5,", 1), *lines[2:]]) + "\n")
    msg = one_line_error(*run_cli(capsys, path, "--ground-truth", write_gt(tmp_path / "g.mcap")))
    assert "line 2, column 'frame' must be an integer, got '0.5'" in msg
    path.write_text("\n".join([lines[0], lines[1], lines[1], *lines[2:]]) + "\n")
    msg = one_line_error(*run_cli(capsys, path, "--ground-truth", write_gt(tmp_path / "g.mcap")))
    assert "frame indices must be strictly increasing, got frame 0 after frame 0" in msg


def test_sweep_of_a_csv_against_annotations_needs_the_recording(tmp_path, capsys):
    db = write_annotations(tmp_path / "ann.sqlite")
    msg = one_line_error(*run_cli(capsys, write_csv(tmp_path / "t.csv"), "--reference", db, "--sweep", "5"))
    assert "--recording" in msg


def test_untracked_recording_as_tracker_output(tmp_path, capsys):
    gt = write_gt(tmp_path / "g.mcap")
    msg = one_line_error(*run_cli(capsys, gt, "--ground-truth", gt))
    assert "no tracker estimate or cue messages" in msg and "fusion-pf track" in msg


def with_column(path, name, cells):
    """The CSV at ``path`` with one more column ``name`` (``cells`` per data row)."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    rows = [rows[0] + [name]] + [r + [c] for r, c in zip(rows[1:], cells, strict=True)]
    with open(path, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    return path


def test_the_reported_uncertainty_is_scored_by_how_often_it_covers_the_error(tmp_path, capsys):
    # fused errors 5, 3, 1 px (frames 1-3); sigma_px 2.6 (5 within 2 sigma only), 3.0 (3 within 1 sigma), none
    tracked = with_column(write_csv(tmp_path / "t.csv"), "sigma_px", ["", "2.6", "3.0", ""])
    gt = write_gt(tmp_path / "gt.mcap")
    code, out, err = run_cli(capsys, tracked, "--ground-truth", gt, "--json")
    assert code == 0, err
    assert json.loads(out)["uncertainty"] == {"n": 2, "within_1_sigma": 0.5, "within_2_sigma": 1.0}
    code, out, _ = run_cli(capsys, tracked, "--ground-truth", gt)
    assert code == 0
    assert "within `sigma_px` in 50.0 % and within `2 sigma_px` in 100.0 % of the 2 frames" in out
    # an output without the column has no uncertainty to score
    code, out, _ = run_cli(capsys, write_csv(tmp_path / "plain.csv"), "--ground-truth", gt, "--json")
    assert code == 0 and json.loads(out)["uncertainty"] is None


@pytest.mark.parametrize("cell", ["-1", "abc"])
def test_a_bad_uncertainty_cell_is_a_one_line_error(tmp_path, capsys, cell):
    tracked = with_column(write_csv(tmp_path / "t.csv"), "sigma_px", ["", cell, "3.0", ""])
    line = one_line_error(*run_cli(capsys, tracked, "--ground-truth", write_gt(tmp_path / "gt.mcap")))
    assert "line 3, column 'sigma_px'" in line and repr(cell) in line
