"""``fusion-pf render``: video and contact sheet of a tracked recording."""

import math
import re
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from drivers import mcap_format as fmt
from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapReplay
from drivers.render import (
    ESTIMATE_COLOUR,
    EXTRA_COLOURS,
    PARTICLE_COLOUR,
    SOURCE_COLOURS,
    TrackerFrame,
    contact_sheet,
    draw,
    read_tracker_topics,
)
from fusion_pf.cli import main
from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, Intrinsics

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "recordings" / "sample.mcap"


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """The shipped sample tracked with default options."""
    out = tmp_path_factory.mktemp("render") / "tracked.mcap"
    assert main(["track", str(SAMPLE), "-o", str(out), "--no-progress"]) == 0
    return out


def _decode(path):
    with av.open(str(path)) as c:
        stream = c.streams.video[0]
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
        return stream.codec_context.name, float(stream.average_rate), frames


def test_video_and_sheet_of_a_tracked_sample(tracked, tmp_path, capsys):
    video, sheet = tmp_path / "out.mp4", tmp_path / "sheet.png"
    assert main(["render", str(tracked), "-o", str(video), "--sheet", str(sheet), "--every", "30"]) == 0
    assert re.search(r"rendered 300 frames \(270 with tracker output\)", capsys.readouterr().out)
    codec, fps, frames = _decode(video)
    assert codec == "h264" and abs(fps - 30.0) < 0.01
    assert len(frames) == 300 and frames[0].shape == (400, 640, 3)  # 320x200 drawn at 2x
    outputs = read_tracker_topics(tracked)
    with McapReplay(SAMPLE) as rec:
        f = rec.frame(150)
        est = outputs[f.timestamp_ns].estimate
    # the estimate ring (radius 9 px at 2x) is red in the decoded video, the image elsewhere is not
    img = frames[150].astype(int)
    cu, cv = round((est["u"] + 0.5) * 2 - 0.5), round((est["v"] + 0.5) * 2 - 0.5)
    yy, xx = np.mgrid[: img.shape[0], : img.shape[1]]
    ring = np.abs(np.hypot(xx - cu, yy - cv) - 9) < 0.6
    red = (img[..., 0] > 170) & (img[..., 1] < 110) & (img[..., 2] < 110)
    assert red[ring].mean() > 0.5 and red[~(np.hypot(xx - cu, yy - cv) < 14)].mean() < 0.01
    grid = cv2.imread(str(sheet))
    # frames 0, 30, ..., 270: 10 tiles, 6 a row, 320x200 each with 2 px gaps
    assert grid.shape == (2 * 200 + 2, 6 * 320 + 5 * 2, 3)
    assert not grid[202:, 4 * 322 :].any()  # the two empty slots of the second row


def test_draw_any_sources_particles_state():
    k = Intrinsics(200, 120, 150.0, 150.0, 99.5, 59.5)
    frame = Frame(0, 7, np.full((120, 200, 3), 90, np.uint8), None, k)
    out = TrackerFrame(
        estimate={"u": 150.0, "v": 90.0, "state": "lost"},
        cues={"skin_rgb": (40.0, 30.0, 0.5), "zz_new_cue": (100.0, 60.0, 0.2), "depth": None},
        roi=(10.0, 10.0, 60.0, 50.0),
        particles=np.array([[20.0, 100.0], [180.0, 20.0], [-5.0, 3.0]]),
    )
    sources = ["depth", "skin_rgb", "zz_new_cue"]
    img = draw(frame, out, sources, scale=4)
    assert img.shape == (480, 800, 3)

    def at(u, v, dx=0, dy=0):
        return tuple(int(c) for c in img[round((v + 0.5) * 4 - 0.5) + dy, round((u + 0.5) * 4 - 0.5) + dx])

    assert at(40, 30, 3, 3) == SOURCE_COLOURS["skin_rgb"]
    assert at(100, 60, 3, 3) == EXTRA_COLOURS[0]  # an unknown source gets the first extra colour
    assert at(20, 100) == PARTICLE_COLOUR and at(180, 20) == PARTICLE_COLOUR
    assert at(150, 90, 9, 0) == ESTIMATE_COLOUR
    no_state = draw(
        frame,
        TrackerFrame(estimate={"u": 150.0, "v": 90.0}, cues=out.cues, roi=out.roi, particles=out.particles),
        sources,
        scale=4,
    )
    changed = np.any(img != no_state, axis=2)
    rows = np.nonzero(changed.any(axis=1))[0]
    assert changed.any() and rows.min() > 16 and rows.max() < 40  # only the state line differs
    bare = draw(frame, None, sources, scale=1)
    assert bare.shape == (120, 200, 3) and (bare[60:, :] == 90).all()  # untracked: header text only


def test_every_target_has_its_own_two_sigma_circle():
    """Several targets: each target's ``sigma_px`` draws a thin circle of radius ``2 sigma_px`` in its state's colour."""
    from drivers.render import STATE_COLOURS

    k = Intrinsics(200, 120, 150.0, 150.0, 99.5, 59.5)
    frame = Frame(0, 7, np.full((120, 200, 3), 90, np.uint8), None, k)
    targets = {"right_hand": {"u": 50.0, "v": 60.0, "state": "tracking"}, "left_hand": {"u": 140.0, "v": 60.0}}
    targets["left_hand"]["state"] = "combined"
    plain = draw(frame, TrackerFrame(estimate={"targets": targets}, cues={}), [], scale=2)
    targets["right_hand"]["sigma_px"], targets["left_hand"]["sigma_px"] = 7.0, None
    img = draw(frame, TrackerFrame(estimate={"targets": targets}, cues={}), [], scale=2)
    changed = np.any(img != plain, axis=2)
    yy, xx = np.mgrid[: img.shape[0], : img.shape[1]]
    cu, cv = round(50.5 * 2 - 0.5), round(60.5 * 2 - 0.5)
    ring = np.abs(np.hypot(xx - cu, yy - cv) - 2 * 7.0 * 2) < 1.5  # radius 2 sigma_px at scale 2
    assert changed[ring].mean() > 0.5 and not changed[~ring].any()  # the right hand's circle only
    colour = np.array(STATE_COLOURS["tracking"])  # anti-aliased: every changed pixel moves toward that colour
    assert (
        np.abs(img[changed].astype(int) - colour).sum(axis=1) < np.abs(plain[changed].astype(int) - colour).sum(axis=1)
    ).all()


def test_images_from_the_source_named_in_the_metadata(tracked, tmp_path, capsys):
    """A tracked file without colour: images from metadata 'source', or from --input."""
    outputs = read_tracker_topics(tracked)

    def write(path, source):
        with McapRecorder(path, metadata={"source": source}) as rec:
            for t, item in sorted(outputs.items()):
                rec.write_json(fmt.ESTIMATE_TOPIC, fmt.ESTIMATE_SCHEMA, item.estimate, t)

    good, bad = tmp_path / "good.mcap", tmp_path / "bad.mcap"
    write(good, str(SAMPLE))
    write(bad, str(tmp_path / "gone.mcap"))
    assert main(["render", str(good), "--sheet", str(tmp_path / "a.png"), "--every", "100"]) == 0
    assert "rendered 300 frames (270 with tracker output)" in capsys.readouterr().out
    assert main(["render", str(bad), "--sheet", str(tmp_path / "b.png")]) == 2
    err = capsys.readouterr().err
    assert "has no /camera/color images" in err and "--input" in err and err.count("\n") == 1
    assert main(["render", str(bad), "--sheet", str(tmp_path / "b.png"), "--input", str(SAMPLE)]) == 0
    a, b = cv2.imread(str(tmp_path / "a.png")), cv2.imread(str(tmp_path / "b.png"))
    assert a.shape == (200, 3 * 320 + 4, 3) and b.shape == (
        5 * 200 + 4 * 2,
        6 * 320 + 10,
        3,
    )  # default --every 10: 30 tiles


@pytest.mark.parametrize(
    "argv, message",
    [
        (["{sample}", "--sheet", "{tmp}/x.png"], "has no /tracker/estimate, /tracker/cues or /tracker/particles"),
        (["{tracked}"], "nothing to write"),
        (
            ["{tracked}", "--sheet", "{tmp}/x.png", "--every", "0"],
            "every (--every) must be an integer in [1, 1000000], got 0",
        ),
        (["{tracked}", "-o", "{tmp}/x.avi"], "must end in .mp4"),
        (
            ["{tracked}", "-o", "{tmp}/x.mp4", "--fps", "fast"],
            "fps (--fps) must be a number in [0.001, 1000], got 'fast'",
        ),
        (["{tmp}/none.mcap", "-o", "{tmp}/x.mp4"], "does not exist; expected the output of fusion-pf track"),
    ],
)
def test_errors_are_one_line(tracked, tmp_path, capsys, argv, message):
    argv = [a.format(sample=SAMPLE, tmp=tmp_path, tracked=tracked) for a in argv]
    assert main(["render", *argv]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert not (tmp_path / "x.png").exists() and not (tmp_path / "x.mp4").exists()


def test_refuses_to_overwrite_without_force(tracked, tmp_path, capsys):
    sheet = tmp_path / "s.png"
    sheet.write_bytes(b"keep")
    assert main(["render", str(tracked), "--sheet", str(sheet)]) == 2
    assert "already exists; pass --force" in capsys.readouterr().err and sheet.read_bytes() == b"keep"


def test_contact_sheet_layout():
    tiles = [np.full((100, 160, 3), k * 40, np.uint8) for k in range(5)]
    sheet = contact_sheet(tiles, columns=2, tile_width=80)
    assert sheet.shape == (3 * 50 + 2 * 2, 2 * 80 + 2, 3)
    assert (sheet[:50, :80] == 0).all() and (sheet[52:102, 82:] == 120).all() and (sheet[104:, 82:] == 0).all()


def test_cue_messages_with_unknown_sources_and_no_roi(tmp_path):
    good, bad = tmp_path / "good.mcap", tmp_path / "bad.mcap"
    with McapRecorder(good) as rec:
        rec.write_json(
            fmt.CUES_TOPIC, fmt.CUES_SCHEMA, {"frame": 0, "timestamp_ns": 5, "hands": {"u": 1, "v": 2}, "x": None}, 5
        )
    item = read_tracker_topics(good)[5]
    assert item.roi is None and item.estimate is None and item.particles is None
    assert item.cues["x"] is None and item.cues["hands"][:2] == (1.0, 2.0) and math.isnan(item.cues["hands"][2])
    with McapRecorder(bad) as rec:
        rec.write_json(fmt.CUES_TOPIC, fmt.CUES_SCHEMA, {"frame": 1, "timestamp_ns": 6, "hands": 3}, 6)
    with pytest.raises(InputError, match=re.escape("source 'hands' must be an object with u, v or null, got 3")):
        read_tracker_topics(bad)
