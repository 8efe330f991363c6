"""``fusion-pf merge`` across clocks: given, first-frame and motion-energy clock offsets.

Two single-camera recordings are cut from one synthetic two-camera scene (``synth --cameras 2``,
both cameras see the same instants; 8 frames of the empty room, then the person): the second
starts 3 frames later and its clock is moved by a known offset that is not a whole number of
frames; the merge must find the instants again.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest

from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapReplay
from drivers.rig import RigReplay, extrinsics_document, merge, motion_offset, write_extrinsics
from fusion_pf import cli
from fusion_pf.commands.merge import MergeOptions, parse_offsets
from fusion_pf.errors import InputError
from fusion_pf.rig import CameraPose

#: The second recording's clock runs this far ahead (37.04 frame periods at 30 fps).
SHIFT_NS = 1_234_567_891
#: The second recording starts this many frames after the first.
LATE = 3
FRAMES = 60
POSES = {"cam0": CameraPose.identity(), "cam1": CameraPose.from_rvec([0.0, -0.3, 0.0], [400.0, 0.0, 0.0])}


def _split(rig: Path, out: Path, shift_ns: int, late: int = 0) -> list[Path]:
    paths = []
    for k, camera in enumerate(("cam0", "cam1")):
        path = out / f"{camera}.mcap"
        with McapReplay(rig, camera=camera) as replay, McapRecorder(path) as rec:
            for frame in list(replay)[late if k else 0 :]:
                rec.write(dataclasses.replace(frame, timestamp_ns=frame.timestamp_ns + (shift_ns if k else 0)))
        paths.append(path)
    return paths


def _scene(tmp: Path, seed: int) -> list[Path]:
    rig = tmp / f"rig{seed}.mcap"
    args = ["synth", str(rig), "--cameras", "2", "--frames", str(FRAMES), "--size", "160x100", "--seed", str(seed)]
    assert cli.main([*args, "--background-frames", "8", "--lighting", "0", "--hands", "2", "--no-progress"]) == 0
    return _split(rig, tmp, SHIFT_NS, LATE)


@pytest.fixture(scope="module")
def shifted(tmp_path_factory) -> list[Path]:
    return _scene(tmp_path_factory.mktemp("clock"), 5)


def test_without_an_offset_the_clocks_do_not_meet(shifted, tmp_path: Path) -> None:
    report = merge(shifted, POSES, tmp_path / "m.mcap")
    cam = report["cameras"]["cam1"]
    assert cam["offset_ns"] == 0 and cam["offset_from"] == "none"
    # only where the two clocks' spans overlap do frames meet (wrongly: 1.23 s apart in the scene)
    assert cam["unmatched"] == 37 and report["sets"] == FRAMES + 37


def test_first_frame_alignment_assumes_the_recordings_started_together(shifted, tmp_path: Path) -> None:
    report = merge(shifted, POSES, tmp_path / "m.mcap", align="first")
    cam = report["cameras"]["cam1"]
    assert cam["offset_ns"] == -SHIFT_NS - 100_000_000 and cam["offset_from"] == "first frames"  # frame 3: 100 ms
    # every frame finds a partner, three frames off: matching counts cannot show a wrong offset
    assert cam["unmatched"] == 0 and report["sets"] == FRAMES


def test_motion_alignment_finds_the_offset_within_a_few_ms_and_every_frame_its_partner(shifted, tmp_path: Path) -> None:
    out = tmp_path / "m.mcap"
    report = merge(shifted, POSES, out, align="motion")
    cam = report["cameras"]["cam1"]
    assert abs(cam["offset_ns"] + SHIFT_NS) < 1_000_000, cam  # measured: 0.01 ms off (a frame is 33.3 ms)
    assert cam["correlation"] > 0.95 and cam["unmatched"] == 0 and report["sets"] == FRAMES
    with McapReplay(shifted[0]) as a, RigReplay(out) as rig:
        assert np.array_equal(rig.timestamps, a.timestamps)  # the reference clock's instants
        sets = list(rig)
    assert [len(s.views) for s in sets] == [1] * LATE + [2] * (FRAMES - LATE)
    # each instant holds one scene instant from both cameras: cam1's frame k - 3 with cam0's frame k
    with McapReplay(shifted[1]) as b:
        for k in (LATE, 30, FRAMES - 1):
            assert np.array_equal(sets[k].views["cam1"].frame.color, b.frame(k - LATE).color)


def test_motion_offset_on_a_known_series_with_a_fractional_shift() -> None:
    rng = np.random.default_rng(3)
    step = 33_333_333
    base = np.convolve(rng.exponential(1.0, 400), np.ones(5) / 5, mode="same")  # smooth, aperiodic
    t_ref = 10**18 + step * np.arange(300, dtype=np.int64)
    # the other camera's sample j saw the motion of reference sample j + 12.33, and its clock reads 5 s more
    other = np.interp(np.arange(300) + 12 + 1 / 3, np.arange(400), base)
    offset, corr = motion_offset(t_ref, base[:300], t_ref + 5 * 10**9, other, step)
    assert corr > 0.95
    expected = round((12 + 1 / 3) * step) - 5 * 10**9
    assert abs(offset - expected) < step / 10, (offset, expected)


def test_clock_offsets_given_on_the_command_line(shifted, tmp_path: Path, capsys) -> None:
    out = tmp_path / "m.mcap"
    cams = tmp_path / "cams.yaml"
    write_extrinsics(cams, extrinsics_document(POSES))
    argv = ["merge", *map(str, shifted), "--extrinsics", str(cams), "-o", str(out), "--clock-offset", "0,-1.234567891s"]
    assert cli.main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == f"wrote {FRAMES} instants of 2 cameras to {out}"
    assert lines[1].endswith("0 without a partner; clock offset +0.000 ms (reference)")
    assert lines[2].endswith("0 without a partner; clock offset -1234.568 ms (given)")
    assert cli.main([*argv[:-2], "--align", "motion", "--force"]) == 0
    out_text = capsys.readouterr().out
    assert re.search(r"clock offset -1234\.5\d\d ms \(motion, correlation (0\.9\d|1\.00)\)", out_text), out_text
    assert cli.main([*argv, "--align", "first", "--force"]) == 2
    assert capsys.readouterr().err.strip() == (
        "fusion-pf: error: --clock-offset and --align first are alternatives; give one"
    )
    assert cli.main([*argv[:-1], "1s", "--force"]) == 2
    assert "1 clock offset(s) given for 2 recording(s); give one each" in capsys.readouterr().err
    assert cli.main([*argv[:-1], "0,-2e9s", "--force"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("fusion-pf: error: clock offset -2000000000.000000000 s moves ") and "before 1970" in err


def test_parse_offsets_is_exact_and_refuses_missing_units() -> None:
    assert parse_offsets("0,-0") == (0, 0)  # zero needs no unit
    assert parse_offsets("0s,-1.25s,340ms,120000ns,7us") == (0, -1_250_000_000, 340_000_000, 120_000, 7_000)
    assert parse_offsets("0.000000001s") == (1,)
    for bad, message in [
        ("12", "must be a number with a unit ns, us, ms or s .* got '12'"),
        ("1.5ns", "must be a whole number of ns, got '1.5ns'"),
        ("fast", "got 'fast'"),
    ]:
        with pytest.raises(InputError, match=message):
            parse_offsets(bad)
    with pytest.raises(InputError, match="--clock-offset and --align motion are alternatives"):
        MergeOptions(clock_offset=(0, 1), align="motion")


def test_a_still_scene_gives_a_weak_motion_alignment_and_says_so(tmp_path: Path, capsys) -> None:
    rig = tmp_path / "board.mcap"
    assert cli.main(["synth", str(rig), "--cameras", "2", "--board", "--frames", "40", "--size", "160x100"]) == 0
    paths = _split(rig, tmp_path, SHIFT_NS, LATE)
    cams = tmp_path / "cams.yaml"
    write_extrinsics(cams, extrinsics_document(POSES))
    argv = ["merge", *map(str, paths), "--extrinsics", str(cams), "-o", str(tmp_path / "m.mcap"), "--align", "motion"]
    assert cli.main(argv) == 0
    (warning,) = [line for line in capsys.readouterr().err.splitlines() if "weak motion correlation" in line]
    assert warning.startswith("fusion-pf: warning: cam1's clock offset rests on a weak motion correlation (")
    assert warning.endswith(" < 0.5): check it, or give --clock-offset")


def test_identical_frames_or_a_short_recording_cannot_be_aligned_by_motion() -> None:
    t = 10**18 + 33_333_333 * np.arange(40, dtype=np.int64)
    with pytest.raises(InputError, match="^a recording shows no motion to align by .* give --clock-offset instead$"):
        motion_offset(t, np.arange(40.0), t, np.zeros(40), 33_333_333)
    with pytest.raises(InputError, match=r"^a recording is too short to align by motion \(12 frames; at least 30"):
        motion_offset(t, np.arange(40.0), t[:12], np.arange(12.0), 33_333_333)
