"""Click storage, the per-frame reference, per-operator agreement and the export command."""

from __future__ import annotations

import csv
import math
import sqlite3

import pytest

from fusion_pf.annotate.db import AnnotationDB, operator_table, reference_table, write_operators_csv
from fusion_pf.cli import main
from fusion_pf.errors import InputError, RecordingError


def _db(path, n_frames=10):
    return AnnotationDB(path, recording="r.mcap", n_frames=n_frames, width=320, height=200)


def test_reclick_replaces_and_rows_are_committed(tmp_path):
    db = _db(tmp_path / "a.sqlite")
    db.set_click("ann", 3, 1000, 10.0, 20.0)
    db.set_click("ann", 3, 1000, 11.5, 21.5)
    db.set_click("ann", 4, 2000, None, None)
    # another connection (another process would see the same) sees committed rows only
    rows = (
        sqlite3.connect(tmp_path / "a.sqlite")
        .execute("SELECT operator, frame, timestamp_ns, u, v, visible FROM clicks ORDER BY frame")
        .fetchall()
    )
    assert rows == [("ann", 3, 1000, 11.5, 21.5, 1), ("ann", 4, 2000, None, None, 0)]
    conn = sqlite3.connect(tmp_path / "a.sqlite")
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    clicks = db.operator_clicks("ann")
    assert [c.frame for c in clicks] == [3, 4]
    assert all(isinstance(c.clicked_ns, int) and c.clicked_ns > 1_600_000_000 * 10**9 for c in clicks)
    db.close()


@pytest.mark.parametrize(
    ("operator", "frame", "u", "v", "message"),
    [
        ("", 0, 1.0, 1.0, "empty"),
        ("x" * 65, 0, 1.0, 1.0, "at most 64"),
        ("a\nb", 0, 1.0, 1.0, "printable"),
        (7, 0, 1.0, 1.0, "string"),
        ("ann", 10, 1.0, 1.0, "out of range"),
        ("ann", -1, 1.0, 1.0, "out of range"),
        ("ann", True, 1.0, 1.0, "integer"),
        ("ann", 1.0, 1.0, 1.0, "integer"),
        ("ann", 0, 320.0, 1.0, "outside the image"),
        ("ann", 0, 1.0, -0.6, "outside the image"),
        ("ann", 0, math.nan, 1.0, "outside the image"),
        ("ann", 0, "1", 1.0, "number"),
        ("ann", 0, None, 1.0, "number"),
    ],
)
def test_bad_clicks_raise_and_write_nothing(tmp_path, operator, frame, u, v, message):
    db = _db(tmp_path / "a.sqlite")
    with pytest.raises(InputError, match=message):
        db.set_click(operator, frame, 5, u, v)
    assert sqlite3.connect(tmp_path / "a.sqlite").execute("SELECT count(*) FROM clicks").fetchone()[0] == 0
    db.close()


def test_image_border_is_inside(tmp_path):
    db = _db(tmp_path / "a.sqlite")
    db.set_click("ann", 0, 0, -0.5, 199.5)
    db.set_click("ann", 1, 0, 319.5, -0.5)
    assert len(db.operator_clicks("ann")) == 2
    db.close()


def test_database_of_another_recording_is_refused(tmp_path):
    _db(tmp_path / "a.sqlite", n_frames=10).close()
    with pytest.raises(RecordingError, match="n_frames = 10"):
        _db(tmp_path / "a.sqlite", n_frames=11)
    (tmp_path / "junk.sqlite").write_bytes(b"not a database at all" * 100)
    with pytest.raises(RecordingError, match="not an annotation database"):
        _db(tmp_path / "junk.sqlite")
    with pytest.raises(RecordingError, match="no such annotation database"):
        reference_table(tmp_path / "missing.sqlite")


@pytest.fixture
def three_operators(tmp_path):
    """Frame 0: A(0,0) B(6,0) C(0,8). Frame 1: A(10,10), B not visible. Frame 2: all not visible."""
    path = tmp_path / "three.sqlite"
    db = _db(path)
    db.set_click("A", 0, 100, 0.0, 0.0)
    db.set_click("B", 0, 100, 6.0, 0.0)
    db.set_click("C", 0, 100, 0.0, 8.0)
    db.set_click("A", 1, 200, 10.0, 10.0)
    db.set_click("B", 1, 200, None, None)
    db.set_click("A", 2, 300, None, None)
    db.set_click("C", 2, 300, None, None)
    db.close()
    return path


def test_reference_table_is_the_operator_mean_and_spread(three_operators):
    ref = reference_table(three_operators)
    assert [r["frame"] for r in ref] == [0, 1, 2]
    r0 = ref[0]
    assert r0["timestamp_ns"] == 100 and r0["n_operators"] == 3 and r0["n_not_visible"] == 0
    assert r0["mean_u"] == pytest.approx(2.0) and r0["mean_v"] == pytest.approx(8 / 3)
    expected = (math.hypot(2, 8 / 3) + math.hypot(4, 8 / 3) + math.hypot(2, 16 / 3)) / 3
    assert r0["spread_px"] == pytest.approx(expected)
    assert ref[1] == {
        "frame": 1,
        "timestamp_ns": 200,
        "n_operators": 2,
        "n_not_visible": 1,
        "mean_u": 10.0,
        "mean_v": 10.0,
        "spread_px": 0.0,
    }
    assert ref[2] == {
        "frame": 2,
        "timestamp_ns": 300,
        "n_operators": 2,
        "n_not_visible": 2,
        "mean_u": None,
        "mean_v": None,
        "spread_px": None,
    }


def test_operator_table_uses_the_mean_of_the_others(three_operators):
    ops = {r["operator"]: r for r in operator_table(three_operators)}
    assert sorted(ops) == ["A", "B", "C"]
    # A on frame 0: others' mean (3, 4) -> distance 5; frame 1: nobody else clicked
    assert ops["A"]["n_frames"] == 3 and ops["A"]["n_compared"] == 1
    assert ops["A"]["mean_dist_to_others_px"] == pytest.approx(5.0)
    assert ops["A"]["n_not_visible"] == 1
    assert ops["A"]["n_visibility_disagreements"] == 1  # clicked frame 1 where B said not visible
    # B: others' mean (0, 4) -> distance hypot(6, 4)
    assert ops["B"]["mean_dist_to_others_px"] == pytest.approx(math.hypot(6, 4))
    assert ops["B"]["n_visibility_disagreements"] == 1
    # C: others' mean (3, 0) -> distance hypot(3, 8)
    assert ops["C"]["max_dist_to_others_px"] == pytest.approx(math.hypot(3, 8))
    assert ops["C"]["n_visibility_disagreements"] == 0


def test_export_command_writes_both_csvs(three_operators, tmp_path, capsys):
    out = tmp_path / "ref.csv"
    assert main(["annotations", "export", str(three_operators), "--csv", str(out)]) == 0
    rows = list(csv.DictReader(out.open()))
    assert [r["frame"] for r in rows] == ["0", "1", "2"]
    assert rows[0]["mean_u"] == "2.000" and rows[0]["mean_v"] == "2.667"
    assert rows[2]["mean_u"] == "" and rows[2]["spread_px"] == "" and rows[2]["n_not_visible"] == "2"
    ops = list(csv.DictReader((tmp_path / "ref_operators.csv").open()))
    assert [(r["operator"], r["mean_dist_to_others_px"]) for r in ops][0] == ("A", "5.000")
    assert "3 frames" in capsys.readouterr().out
    other = tmp_path / "ops.csv"
    assert (
        main(["annotations", "export", str(three_operators), "--csv", str(out), "--operators-csv", str(other)]) == 2
    )  # issue 14: ref.csv exists
    assert "already exists; pass --force" in capsys.readouterr().err and not other.exists()
    assert (
        main(
            ["annotations", "export", str(three_operators), "--csv", str(out), "--operators-csv", str(other), "--force"]
        )
        == 0
    )
    assert other.read_text() == (tmp_path / "ref_operators.csv").read_text()


def test_export_never_overwrites_an_input(three_operators, tmp_path, capsys):
    """Issue 14 item 7: the database, its WAL and any recording are never export outputs, even with --force."""
    before = three_operators.read_bytes()
    for target, message in (
        (three_operators, "is the annotation database"),
        (three_operators.with_name(three_operators.name + "-wal"), "is the annotation database"),
    ):
        assert main(["annotations", "export", str(three_operators), "--csv", str(target), "--force"]) == 2
        assert message in capsys.readouterr().err
    recording = tmp_path / "rec.mcap"
    recording.write_bytes(b"\x89MCAP0\r\n" + bytes(100))
    for flag in ("--csv", "--operators-csv"):
        extra = ["--csv", str(tmp_path / "x.csv")] if flag == "--operators-csv" else []
        assert main(["annotations", "export", str(three_operators), *extra, flag, str(recording), "--force"]) == 2
        assert "is an MCAP recording, not a CSV; it is never overwritten" in capsys.readouterr().err
    copy = tmp_path / "copy.sqlite"
    copy.write_bytes(before)
    assert main(["annotations", "export", str(three_operators), "--csv", str(copy), "--force"]) == 2
    assert "is an SQLite database" in capsys.readouterr().err
    assert three_operators.read_bytes() == before and recording.read_bytes().startswith(b"\x89MCAP")


def test_csv_formula_injection_is_neutralised(tmp_path):
    """Issue 14 item 7: an operator named like a formula is written as text."""
    db = AnnotationDB(tmp_path / "f.sqlite", recording="r.mcap", n_frames=2, width=10, height=10)
    for name in ('=HYPERLINK("http://evil.example","x")', "+1+1", "-2", "@SUM(A1)", "ok"):
        db.set_click(name, 0, 5, 1.0, 1.0)
    db.close()
    out = tmp_path / "ops.csv"
    write_operators_csv(tmp_path / "f.sqlite", out)
    names = [row["operator"] for row in csv.DictReader(out.open())]
    assert sorted(names) == sorted(["'+1+1", "'-2", '\'=HYPERLINK("http://evil.example","x")', "'@SUM(A1)", "ok"])


def test_export_command_errors_are_one_line(tmp_path, capsys):
    assert main(["annotations", "export", str(tmp_path / "none.sqlite"), "--csv", str(tmp_path / "o.csv")]) == 2
    assert "no such file" in capsys.readouterr().err
    assert not (tmp_path / "o.csv").exists()
