"""``fusion-pf render`` of a multi-camera (world) tracker output: every camera's view and a top view of the rig.

The tracked files are written here with the real recorder: ``/tracker/world`` messages made
from the synthetic rig's ground truth moved by known offsets, the pixels projected in the
test from each camera's intrinsics and pose; the drawing is checked at those pixels.
"""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from drivers import mcap_format as fmt
from drivers.mcap_record import McapRecorder
from drivers.rig import RigReplay
from fusion_pf.cli import main

#: Where the fixture's estimate is, from the truth (mm), plus DRIFT_MM per instant in x.
OFFSETS_MM = {"right_hand": np.array([-220.0, 0.0, -60.0]), "left_hand": np.array([220.0, 0.0, -60.0])}
OFFSETS_MM["head"] = np.array([0.0, 0.0, 320.0])
DRIFT_MM = np.array([70.0, 0.0, 0.0])
COLOURS = {"right_hand": (255, 70, 70), "left_hand": (70, 160, 255), "head": (255, 210, 40)}
HIDDEN = (3, 4)  # instants at which a card hides the right hand from cam1
LOST = 7  # the left hand is lost at the last instant
TILE_W, TILE_H, GAP = 640, 400, 2  # 160x100 cameras drawn at 4x


def _project(frame, pose, xyz):
    c = pose.to_camera(np.asarray(xyz, float)[None])[0]
    k = frame.intrinsics
    return [k.fx * c[0] / c[2] + k.cx, k.fy * c[1] / c[2] + k.cy]


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A 2-camera rig recording and its world tracker output (source in the metadata)."""
    folder = tmp_path_factory.mktemp("render_rig")
    rec, tracked = folder / "rig.mcap", folder / "tracked.mcap"
    argv = ["synth", str(rec), "--cameras", "2", "--hands", "2", "--frames", "8", "--background-frames", "2"]
    argv += ["--size", "160x100", "--seed", "5", "--occlude", "cam1:right_hand:3-4", "--no-progress"]
    assert main(argv) == 0
    estimates = {}
    with RigReplay(rec) as rig, McapRecorder(tracked, metadata={"source": str(rec)}) as out:
        t0 = int(rig.timestamps[0])
        for name, pose in rig.poses.items():
            out.write_protobuf(fmt.TF_TOPIC, fmt.encode_transform(name, pose, t0), t0)
        for fs in rig:
            if fs.background:
                continue
            targets = []
            for target, xyz in fs.truth_mm.items():
                lost = target == "left_hand" and fs.index == LOST
                p = xyz + OFFSETS_MM[target] + fs.index * DRIFT_MM
                hidden = target == "right_hand" and fs.index in HIDDEN
                pixels = {
                    cam: None if lost or (hidden and cam == "cam1") else _project(v.frame, v.pose, p)
                    for cam, v in fs.views.items()
                }
                cameras = [] if lost else ["cam0"] if hidden or target == "head" else ["cam0", "cam1"]
                targets.append(
                    {
                        "target": target,
                        "state": "lost" if lost else "tracking",
                        "position_mm": None if lost else p.tolist(),
                        "sigma_mm": None if lost else 15.0,
                        "cameras": cameras,
                        "pixels": pixels,
                    }
                )
                estimates[fs.index, target] = None if lost else (p, pixels)
            msg = {"timestamp_ns": fs.timestamp_ns, "targets": targets}
            out.write_json(fmt.WORLD_ESTIMATE_TOPIC, fmt.WORLD_ESTIMATE_SCHEMA, msg, fs.timestamp_ns)
    return rec, tracked, estimates


def _frames(sheet_path, count):
    sheet = cv2.cvtColor(cv2.imread(str(sheet_path)), cv2.COLOR_BGR2RGB)
    h = (sheet.shape[0] + GAP) // count - GAP
    return [sheet[k * (h + GAP) : k * (h + GAP) + h] for k in range(count)]


def _tile(img, row, col):
    return img[
        row * (TILE_H + GAP) : row * (TILE_H + GAP) + TILE_H, col * (TILE_W + GAP) : col * (TILE_W + GAP) + TILE_W
    ]


def _ring_share(tile, centre, radii, colour):
    """Share of 72 directions around ``centre`` in which a pixel at one of ``radii`` has ``colour`` (+-40)."""
    angles = np.linspace(0.0, 2 * np.pi, 72, endpoint=False)
    found = np.zeros(len(angles), bool)
    for r in radii:
        u = np.rint(centre[0] + r * np.cos(angles)).astype(int)
        v = np.rint(centre[1] + r * np.sin(angles)).astype(int)
        inside = (u >= 0) & (u < tile.shape[1]) & (v >= 0) & (v < tile.shape[0])
        close = np.zeros(len(angles), bool)
        close[inside] = np.abs(tile[v[inside], u[inside]].astype(int) - colour).max(axis=1) <= 40
        found |= close
    return found.mean()


def test_every_camera_view_and_the_top_view(scene, tmp_path, capsys):
    rec, tracked, estimates = scene
    sheet, video = tmp_path / "sheet.png", tmp_path / "out.mp4"
    argv = ["render", str(tracked), "-o", str(video), "--sheet", str(sheet), "--every", "1", "--columns", "1"]
    assert main([*argv, "--tile-width", "4096"]) == 0
    assert "rendered 8 instants (6 with tracker output)" in capsys.readouterr().out
    frames = _frames(sheet, 8)
    assert frames[0].shape == (2 * TILE_H + GAP, 2 * TILE_W + GAP, 3)  # 2 cameras + top view: a 2 x 2 grid
    assert not frames[0][TILE_H + GAP :, TILE_W + GAP :].any()  # the fourth slot is empty

    with RigReplay(rec) as rig:
        poses = rig.poses
        truth = rig.world_truth
        times = [int(t) for t in rig.timestamps]
        views = [{cam: (v.frame, v.pose) for cam, v in rig.frameset(k).views.items()} for k in range(len(rig))]
    # the top view, computed independently: x right, z up, every camera, estimate and truth with 250 mm around,
    # one scale, centred below the legend (title + one line per target: 24 + 3 * 16 px)
    points = [p.translation_mm for p in poses.values()] + [e[0] for e in estimates.values() if e is not None]
    points += [p for per in truth.values() for p in per.values()]
    xz = np.array(points)[:, [0, 2]]
    lo, hi = xz.min(axis=0) - 250.0, xz.max(axis=0) + 250.0
    band = 24 + 16 * 3
    scale = max((hi[0] - lo[0]) / TILE_W, (hi[1] - lo[1]) / (TILE_H - band))
    centre = (lo + hi) / 2.0

    def top_px(p):
        u = (TILE_W - 1) / 2.0 + (p[0] - centre[0]) / scale
        v = band + (TILE_H - band - 1) / 2.0 - (p[2] - centre[1]) / scale
        return int(round(u)), int(round(v))

    for k in range(2, 8):
        img = frames[k]
        top = _tile(img, 1, 0)
        for name, pose in poses.items():
            assert tuple(top[top_px(pose.translation_mm)[::-1]]) == (255, 255, 255), (k, name)
        for target, colour in COLOURS.items():
            est = estimates[k, target]
            gt = top_px(truth[times[k]][target])
            assert tuple(top[gt[::-1]]) == (255, 255, 255), (k, target)  # ground truth: a white cross
            if est is None:  # lost: no ring in any camera near where the target is
                for col, cam in enumerate(poses):
                    u, v = (round((c + 0.5) * 4 - 0.5) for c in _project(*views[k][cam], truth[times[k]][target]))
                    window = _tile(img, 0, col)[max(v - 14, 0) : v + 15, max(u - 14, 0) : u + 15].astype(int)
                    assert not (np.abs(window - colour).max(axis=2) <= 40).any(), (k, cam)
                continue
            p, pixels = est
            c = top_px(p)
            # (the fixture keeps every estimate clear of every ground-truth cross)
            assert min(np.hypot(c[0] - q[0], c[1] - q[1]) for q in map(top_px, truth[times[k]].values())) > 8
            assert tuple(top[c[::-1]]) == colour, (k, target)  # the estimate: a disc in the target's colour
            if k >= 4:  # the trail passes through the estimate of two instants before
                before = top_px(estimates[k - 2, target][0])
                assert np.abs(top[before[::-1]].astype(int) - colour).max() <= 60, (k, target)
            for col, cam in enumerate(poses):
                tile = _tile(img, 0, col)
                if pixels[cam] is None:  # hidden from cam1: nothing drawn where the estimate projects
                    u, v = (round((x + 0.5) * 4 - 0.5) for x in _project(*views[k][cam], p))
                    window = tile[max(v - 14, 0) : v + 15, max(u - 14, 0) : u + 15].astype(int)
                    assert not (np.abs(window - colour).max(axis=2) <= 40).any(), (k, cam, target)
                    continue
                ring = tuple(round((x + 0.5) * 4 - 0.5) for x in pixels[cam])
                assert _ring_share(tile, ring, (8.0, 8.5, 9.0, 9.5, 10.0), colour) > 0.8, (k, cam, target)
                measured = not (target == "head" and cam == "cam1")  # thick where measured, thin where not
                assert (_ring_share(tile, ring, (10.4,), colour) > 0.6) == measured, (k, cam, target)
    # the video: every instant, the same grid
    import av

    with av.open(str(video)) as c:
        decoded = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert len(decoded) == 8 and decoded[0].shape == frames[0].shape


def _messages(path):
    from drivers.mcap_replay import McapTopics

    with McapTopics(path) as rec:
        return [(t, json.loads(data)) for t, _e, data in rec.messages(fmt.WORLD_ESTIMATE_TOPIC)]


def _write(path, messages, metadata):
    with McapRecorder(path, metadata=metadata) as out:
        for t, msg in messages:
            out.write_json(fmt.WORLD_ESTIMATE_TOPIC, fmt.WORLD_ESTIMATE_SCHEMA, msg, t)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda m: m["targets"][0].update(position_mm=[1.0, 2.0]), "position_mm must be [x, y, z]"),
        (lambda m: m["targets"][0]["pixels"].update(cam9=[1.0, 2.0]), "names camera 'cam9', which"),
        (lambda m: m["targets"][0].update(target=""), "needs a non-empty 'target' name"),
        (lambda m: m["targets"][0]["pixels"].update(cam0=[1.0]), "pixels of cam0 must be [u, v] or null"),
        (lambda m: m.update(targets={}), "expected an object with a 'targets' list"),
    ],
)
def test_bad_world_messages_are_one_line_errors(scene, tmp_path, capsys, change, message):
    rec, tracked, _ = scene
    messages = _messages(tracked)
    change(messages[-1][1])
    bad = tmp_path / "bad.mcap"
    _write(bad, messages, {"source": str(rec)})
    assert main(["render", str(bad), "--sheet", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1, err
    assert not (tmp_path / "x.png").exists()


def test_images_from_input_when_the_source_is_gone(scene, tmp_path, capsys):
    rec, tracked, _ = scene
    moved = tmp_path / "moved.mcap"
    _write(moved, _messages(tracked), {"source": str(tmp_path / "gone.mcap")})
    assert main(["render", str(moved), "--sheet", str(tmp_path / "a.png")]) == 2
    err = capsys.readouterr().err
    assert "has no /<camera>/camera/color images" in err and "--input" in err and err.count("\n") == 1
    assert main(["render", str(moved), "--sheet", str(tmp_path / "a.png"), "--input", str(rec)]) == 0
    assert "rendered 8 instants (6 with tracker output)" in capsys.readouterr().out
    # without /tf in the tracked file the poses come from the recording: the same top view
    first = cv2.imread(str(tmp_path / "a.png"))
    assert main(["render", str(tracked), "--sheet", str(tmp_path / "b.png")]) == 0
    assert np.array_equal(first, cv2.imread(str(tmp_path / "b.png")))


def test_every_json_message_matches_its_stored_schema(scene):
    """The recording's visibility and the fixture's world estimates, read with ``mcap``, checked with ``jsonschema``."""
    import jsonschema
    from mcap.reader import make_reader

    rec, tracked, _ = scene
    seen: dict[str, int] = {}
    for path in (rec, tracked):
        with open(path, "rb") as fh:
            for schema, channel, message in make_reader(fh).iter_messages():
                if channel.message_encoding == "json":
                    doc = json.loads(schema.data)
                    jsonschema.validators.validator_for(doc)(doc).validate(json.loads(message.data))
                    seen[channel.topic] = seen.get(channel.topic, 0) + 1
    assert seen[fmt.VISIBILITY_TOPIC] == seen[fmt.WORLD_ESTIMATE_TOPIC] == 6
    with pytest.raises(jsonschema.ValidationError):  # the schema does check the fields
        doc = fmt.JSON_SCHEMAS[fmt.WORLD_ESTIMATE_SCHEMA]
        bad = {"timestamp_ns": 1, "targets": [{"target": "head", "pixels": {"cam0": [1.0]}}]}
        jsonschema.validators.validator_for(doc)(doc).validate(bad)
