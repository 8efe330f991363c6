"""Issue 24 item 1: an output that is an input by any route (hard link, symlink, same path) is refused.

Every command that writes is run in-process with ``--force`` and an output that
reaches one of its inputs; the run must exit 2 with one line naming the file and
leave every input byte-identical. Two outputs of one command that are one file
are refused too.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from fusion_pf.annotate.db import AnnotationDB
from fusion_pf.cli import main

LINKS = ("hard", "symlink")
CLI = [sys.executable, "-m", "fusion_pf"]


def _link(kind: str, target: Path, name: Path) -> Path:
    if kind == "hard":
        os.link(target, name)
    else:
        name.symlink_to(target.resolve())
    return name


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A recording, its tracked output (MCAP, CSV), an annotation database, an image folder, an intrinsics file."""
    root = tmp_path_factory.mktemp("inputs")
    rec = root / "rec.mcap"
    assert (
        main(["synth", str(rec), "--frames", "6", "--background-frames", "2", "--size", "96x64", "--no-progress"]) == 0
    )
    tracked, table = root / "tracked.mcap", root / "tracked.csv"
    assert main(["track", str(rec), "-o", str(tracked), "--csv", str(table), "--no-progress"]) == 0
    db = AnnotationDB(root / "clicks.sqlite", recording="rec.mcap", n_frames=6, width=96, height=64)
    db.set_click("A", 2, 100, 10.0, 10.0)
    db.close()
    images = root / "images"
    images.mkdir()
    rng = np.random.default_rng(0)
    for i in range(2):
        assert cv2.imwrite(str(images / f"img{i}.png"), rng.integers(0, 255, (48, 64, 3), dtype=np.uint8))
    intrinsics = root / "k.json"
    intrinsics.write_text('{"width": 64, "height": 48, "fx": 60, "fy": 60, "cx": 32, "cy": 24}')
    return {
        "rec": rec,
        "tracked": tracked,
        "csv": table,
        "db": root / "clicks.sqlite",
        "image": images / "img0.png",
        "images": images,
        "k": intrinsics,
    }


#: (command, input it clobbers, argv builder: (files, out, tmp) -> argv; ``out`` reaches the input).
CASES = {
    "track -o": ("rec", lambda f, out, tmp: ["track", f["rec"], "-o", out, "--force", "--no-progress"]),
    "track --csv": (
        "rec",
        lambda f, out, tmp: ["track", f["rec"], "-o", tmp / "t.mcap", "--csv", out, "--force", "--no-progress"],
    ),
    "track --background": (
        "tracked",
        lambda f, out, tmp: ["track", f["rec"], "-o", out, "--background", f["tracked"], "--force", "--no-progress"],
    ),
    "track --export-ply": (
        "rec",
        lambda f, out, tmp: ["track", f["rec"], "-o", tmp / "t.mcap", "--export-ply", out.parent, "--no-progress"],
    ),
    "record": ("rec", lambda f, out, tmp: ["record", f["rec"], out, "--force"]),
    "import (folder)": ("image", lambda f, out, tmp: ["import", f["images"], out, "--force", "--no-progress"]),
    "import --intrinsics": (
        "k",
        lambda f, out, tmp: ["import", f["images"], out, "--intrinsics", f["k"], "--force", "--no-progress"],
    ),
    "render -o": ("tracked", lambda f, out, tmp: ["render", f["tracked"], "-o", out, "--force"]),
    "render --sheet (source named in the metadata)": (
        "rec",
        lambda f, out, tmp: ["render", f["tracked"], "--sheet", out, "--force"],
    ),
    "annotations export --csv": ("db", lambda f, out, tmp: ["annotations", "export", f["db"], "--csv", out, "--force"]),
    "annotations export --operators-csv": (
        "db",
        lambda f, out, tmp: [
            "annotations",
            "export",
            f["db"],
            "--csv",
            tmp / "r.csv",
            "--operators-csv",
            out,
            "--force",
        ],
    ),
    "annotate --db": ("rec", lambda f, out, tmp: ["annotate", f["rec"], "--db", out]),
    "score --plots": (
        "rec",
        lambda f, out, tmp: ["score", f["csv"], "--ground-truth", f["rec"], "--plots", out.parent],
    ),
    "demo --out": ("rec", lambda f, out, tmp: ["demo", "--recording", f["rec"], "--out", out.parent, "--no-progress"]),
    "cues --stages": ("rec", lambda f, out, tmp: ["cues", f["rec"], "--stages", out.parent, "--cues", "colour"]),
}
#: The name the output must have where the command chooses it (folder outputs) or checks it (render).
NAMES = {
    "track --export-ply": "ply/frame_000002.ply",
    "render -o": "v.mp4",
    "render --sheet (source named in the metadata)": "s.png",
    "score --plots": "plots/score.json",
    "demo --out": "demo/tracked.csv",
    "cues --stages": "stages/frame000002_colour.png",
}


@pytest.mark.parametrize("link", LINKS)
@pytest.mark.parametrize("case", list(CASES))
def test_an_output_reaching_an_input_is_refused_and_the_input_kept(files, tmp_path, capsys, case, link):
    key, argv = CASES[case]
    out = tmp_path / NAMES.get(case, "out.mcap")
    out.parent.mkdir(exist_ok=True)
    _link(link, files[key], out)
    before = {name: _digest(p) for name, p in files.items() if p.is_file()}
    capsys.readouterr()
    assert main([str(a) for a in argv(files, out, tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("fusion-pf: error: "), err
    assert "is an input file" in err or "is the annotation database" in err, err
    assert {name: _digest(p) for name, p in files.items() if p.is_file()} == before
    assert not (tmp_path / "t.mcap").exists()  # nothing was opened for writing before the check


def test_the_same_path_is_refused_with_or_without_force(files, capsys):
    for extra in ([], ["--force"]):
        before = _digest(files["rec"])
        assert main(["track", str(files["rec"]), "-o", str(files["rec"]), "--no-progress", *extra]) == 2
        assert "is an input file" in capsys.readouterr().err and _digest(files["rec"]) == before


@pytest.mark.parametrize("link", LINKS)
def test_two_outputs_of_one_command_that_are_one_file_are_refused(files, tmp_path, capsys, link):
    first, sheet = tmp_path / "a.mcap", tmp_path / "s.png"
    first.write_bytes(b"keep")
    sheet.write_bytes(b"keep")
    cases = [
        ["track", files["rec"], "-o", first, "--csv", _link(link, first, tmp_path / "b.csv"), "--force"],
        ["render", files["tracked"], "-o", _link(link, sheet, tmp_path / "v.mp4"), "--sheet", sheet, "--force"],
        ["annotations", "export", files["db"], "--csv", first, "--operators-csv", _link(link, first, tmp_path / "o")],
    ]
    for argv in cases:
        capsys.readouterr()
        assert main([str(a) for a in argv] + (["--force"] if argv[0] == "annotations" else [])) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "are the same file" in err, err
        assert first.read_bytes() == b"keep" and sheet.read_bytes() == b"keep"
    new = tmp_path / "new"
    assert main(["track", str(files["rec"]), "-o", str(new), "--csv", str(tmp_path / "." / "new")]) == 2
    assert "are the same file" in capsys.readouterr().err and not new.exists()


def test_an_output_that_does_not_exist_yet_is_no_input(files, tmp_path):
    out = tmp_path / "fresh.mcap"
    assert main(["record", str(files["rec"]), str(out)]) == 0
    assert out.stat().st_ino != files["rec"].stat().st_ino


def test_an_output_reached_through_a_bind_mount_is_refused(files, tmp_path):
    """The input's folder bind-mounted elsewhere (a private mount namespace: needs root or user namespaces)."""
    if shutil.which("unshare") is None:
        pytest.skip("no unshare(1) to make a private mount namespace")
    mount = tmp_path / "mnt"
    mount.mkdir()
    rec = files["rec"]
    before = _digest(rec)
    script = 'mount --bind "$1" "$2" || exit 99; shift 2; exec "$@"'
    argv = [*CLI, "track", str(rec), "-o", str(mount / rec.name), "--force", "--no-progress"]
    proc = subprocess.run(
        ["unshare", "-m", "sh", "-c", script, "sh", str(rec.parent), str(mount), *argv],
        capture_output=True,
        text=True,
        timeout=300,
    )
    if proc.returncode == 99 or proc.stderr.startswith("unshare:"):
        pytest.skip(f"cannot bind-mount here: {proc.stderr.strip()}")
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.count("\n") == 1 and "is an input file" in proc.stderr
    assert _digest(rec) == before
