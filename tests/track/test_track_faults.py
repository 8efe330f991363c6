"""No frame ends a run: cues that cannot measure, a prediction leaving the image, no palm at all (issue 23)."""

from __future__ import annotations

import csv
import dataclasses
import re

import numpy as np
import pytest

from drivers.mcap_record import McapRecorder
from drivers.synth import SynthSource
from fusion_pf.cli import main
from fusion_pf.cues import CueResult, LabGmmSkin
from fusion_pf.cues.hand import IDLE_AFTER
from fusion_pf.cues.registry import CUES, CueInfo, CueOptions, build_cue
from fusion_pf.frame import Frame, Intrinsics
from fusion_pf.pipeline import TrackConfig, TrackCsv, track

from .conftest import TRACK_TEST_SIZE

WALL_MM = 1800


def rows(path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def disc_frames(n: int, centres, *, size=(160, 120), radius=12) -> list[Frame]:
    """``n`` frames of a grey wall at 1.8 m with a skin-coloured disc at 0.6 m centred at ``centres[i]`` (None: no disc)."""
    w, h = size
    intr = Intrinsics(w, h, 120.0, 120.0, (w - 1) / 2, (h - 1) / 2)
    yy, xx = np.mgrid[0:h, 0:w]
    out = []
    for i in range(n):
        color = np.full((h, w, 3), 90, np.uint8)
        depth = np.full((h, w), WALL_MM, np.uint16)
        if centres[i] is not None:
            disc = (xx - centres[i][0]) ** 2 + (yy - centres[i][1]) ** 2 <= radius**2
            color[disc] = (200, 150, 120)
            depth[disc] = 600
        out.append(Frame(timestamp_ns=i * 33_333_333, seq=i, color=color, depth=depth, intrinsics=intr))
    return out


def write(path, frames: list[Frame]):
    with McapRecorder(path) as rec:
        for f in frames:
            rec.write(f)
    return path


def run_track(tmp_path, capsys, rec, *extra: str) -> tuple[int, list[dict[str, str]], str]:
    out, table = tmp_path / "out.mcap", tmp_path / "out.csv"
    capsys.readouterr()
    code = main(["track", str(rec), "-o", str(out), "--csv", str(table), "--no-progress", *extra])
    err = capsys.readouterr().err
    return code, rows(table), err


def test_prediction_leaving_the_image_is_clamped_and_the_run_goes_on(tmp_path, capsys):
    """A palm that leaves the bottom of the frame at 5 px/frame: the filter's prediction leaves the image.

    Before: the hand cue got a window of size 0 around the prediction and
    ``roi_hint must be finite (u, v, size) with size > 0`` ended the run.
    """
    n = 30
    centres = [(80.0, 30.0 + 5.0 * i) if 30.0 + 5.0 * i < 130 else None for i in range(n)]
    rec = write(tmp_path / "leave.mcap", disc_frames(n, centres))
    code, table, err = run_track(tmp_path, capsys, rec, "--cues", "hand,depth")
    assert code == 0, err
    assert [int(r["frame"]) for r in table] == list(range(n))
    tracked = [r for r in table if r["state"] == "tracking"]
    assert tracked and all(r["u"] and r["v"] for r in tracked)
    assert table[-1]["state"] == "lost" and table[-1]["u"] == ""  # the palm is gone: no estimate
    # lost at the end: the hand cue's idle search rests on every other whole-frame search (issue 25), counted; the
    # whole-frame search starts within two frames of the loss (the last prediction's window first)
    lost = sum(r["state"] == "lost" for r in table)
    rested = re.search(r"cues measured in: hand 0/30 \(rested on (\d+): idle search\), depth", err)
    assert rested and "states:" in err
    assert 1 <= (lost - 2) // 2 <= int(rested.group(1)) <= (lost + 1) // 2


class _Flaky:
    """The real depth cue, except that it raises in frame ``bad`` (a fault inside a cue)."""

    needs = frozenset({"depth", "background"})
    name = "flaky"

    def __init__(self, bad: int) -> None:
        self.inner = build_cue("depth")
        self.bad = bad

    def measure(self, frame, ctx) -> CueResult:
        if frame.seq == self.bad:
            raise RuntimeError("injected fault\nsecond line")
        r = self.inner.measure(frame, ctx)
        return CueResult(None if r.measurement is None else dataclasses.replace(r.measurement, source="flaky"))

    def reset(self) -> None:
        self.inner.reset()


def test_a_cue_that_raises_in_one_frame_gives_no_measurement_there(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(CUES, "flaky", CueInfo("flaky", _Flaky.needs, "test", lambda o: _Flaky(bad=7)))
    n = 15
    rec = write(tmp_path / "flaky.mcap", disc_frames(n, [(60.0 + 2 * i, 60.0) for i in range(n)]))
    code, table, err = run_track(tmp_path, capsys, rec, "--cues", "flaky", "--noise", "flaky=3")
    assert code == 0, err
    assert [int(r["frame"]) for r in table] == list(range(n))
    assert table[7]["flaky_u"] == "" and all(r["flaky_u"] for r in table[8:])
    assert "flaky 14/15 (failed on 1, first frame 7: injected fault)" in err
    assert table[-1]["state"] == "tracking"


def test_no_cue_ever_sees_the_palm(tmp_path, capsys):
    n = 12
    rec = write(tmp_path / "empty.mcap", disc_frames(n, [None] * n))
    code, table, err = run_track(tmp_path, capsys, rec)
    assert code == 0, err
    assert len(table) == n
    assert all(r["state"] == "uninitialised" and r["u"] == r["v"] == "" for r in table)
    assert f"0 tracking, 0 lost, {n} uninitialised" in err
    # every frame searches the whole frame: after IDLE_AFTER (3) misses the hand cue rests on every other one
    rests = len(range(IDLE_AFTER, n, 2))
    assert rests == 5 and f"cues measured in: hand 0/{n} (rested on {rests}: idle search), depth 0/{n}" in err


@pytest.fixture(scope="module")
def synth_frames():
    with SynthSource(frames=40, seed=5, size=TRACK_TEST_SIZE, background_frames=5) as src:
        return list(src)


@pytest.fixture(scope="module")
def skin_model(tmp_path_factory, synth_frames):
    with SynthSource(frames=1, seed=5, size=TRACK_TEST_SIZE) as src:
        frame, masks = src.render(0)
    path = tmp_path_factory.mktemp("skin") / "skin.npz"
    LabGmmSkin.fit(frame.color.reshape(-1, 3), masks["skin"].ravel(), rng=0).save(path)
    return path


@pytest.mark.parametrize("name", sorted(CUES))
def test_rows_without_tracking_have_no_position_for_every_cue(name, synth_frames, skin_model, tmp_path):
    """u, v are written exactly in ``tracking`` rows (docs/architecture.md, "CSV"), whatever the cue.

    Two scenes: the synthetic person, and a palm-coloured disc filling most of a
    160 x 120 frame (a low-quality blob: before, its first frame was written
    with u, v while ``uninitialised``, e.g. with skin_rgb and colour).
    """
    config = TrackConfig(cues=(name,), cue_options=CueOptions(skin_model=skin_model))
    near = disc_frames(20, [(80.0 + i, 60.0) for i in range(20)], radius=50)
    for scene, frames in (("synth", synth_frames), ("near", near)):
        with TrackCsv(tmp_path / f"{scene}.csv", sources=(name,)) as table:
            for result in track(frames, config):
                table.write(result)
        out = rows(tmp_path / f"{scene}.csv")
        assert len(out) == sum(not f.background for f in frames)
        assert {r["state"] for r in out} <= {"tracking", "lost", "uninitialised"}
        for r in out:
            assert (r["state"] == "tracking") == (r["u"] != "" and r["v"] != ""), (scene, r)
