"""The two-hand (hand-washing) synthetic scene: schedule, per-target ground truth, recording round trip."""

import cv2
import numpy as np
import pytest

from drivers import open_source
from drivers import synth_scene as sc
from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapReplay
from drivers.synth import OCCLUDED_OVERLAP, TARGETS, SynthSource
from fusion_pf.cli import main
from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, PalmPoint


def runs(flags):
    out, n = [], 0
    for f in list(flags) + [False]:
        if f:
            n += 1
        elif n:
            out.append(n)
            n = 0
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_hands_join_twice_for_over_a_second_and_cross_once_per_cycle(seed):
    src = SynthSource(frames=300, size=(320, 200), hands=2, seed=seed, fps=30.0)
    truths = [src.ground_truths(i) for i in range(len(src))]
    assert set(truths[0]) == set(TARGETS)
    joined = [t["right_hand"].occluded for t in truths]
    assert [t["left_hand"].occluded for t in truths] == joined
    assert not any(t["head"].occluded for t in truths)
    long_runs = [n for n in runs(joined) if n >= 30]  # >= 1 s at 30 fps
    assert len(long_runs) == 2
    side = np.sign([t["left_hand"].u - t["right_hand"].u for t in truths])
    assert np.count_nonzero(np.diff(side) != 0) == 1  # one crossing
    # the head stays well above the hands
    assert all(t["head"].v < min(t["right_hand"].v, t["left_hand"].v) - 40 for t in truths)
    # the overlap that defines "joined" is the rendered one
    assert [src.palm_overlap(i) >= OCCLUDED_OVERLAP for i in range(len(src))] == joined


def test_ground_truth_is_the_centre_of_each_rendered_palm():
    src = SynthSource(frames=40, size=(640, 400), hands=2, seed=0, background_frames=2)
    assert src.ground_truths(0) is None and src.render(0)[0].ground_truths is None
    frame, masks = src.render(10)  # hands apart
    n, labels, stats, centroids = cv2.connectedComponentsWithStats(masks["palm"].astype(np.uint8))
    assert n == 3  # background + two palms
    left_blob, right_blob = sorted(centroids[1:].tolist())  # image left = the person's right hand
    gt = frame.ground_truths
    assert np.hypot(left_blob[0] - gt["right_hand"].u, left_blob[1] - gt["right_hand"].v) < 1.0
    assert np.hypot(right_blob[0] - gt["left_hand"].u, right_blob[1] - gt["left_hand"].v) < 1.0
    assert frame.ground_truth == gt["right_hand"]
    # the skin the cues see includes the face at the head's ground truth
    assert masks["skin"][round(gt["head"].v), round(gt["head"].u)]
    # the skeleton names a joint per hand near its truth while the hands are apart
    for name in ("right_hand", "left_hand", "head"):
        j = frame.joints[name]
        assert np.hypot(j.u - gt[name].u, j.v - gt[name].v) < 10 or name == "head"


def test_joined_hands_degrade_the_skeleton():
    src = SynthSource(frames=300, size=(320, 200), hands=2, seed=0)
    conf = np.array([src.joints(i)["right_hand"].confidence for i in range(0, 300, 5)])
    joined = np.array([src.ground_truths(i)["right_hand"].occluded for i in range(0, 300, 5)])
    assert conf[joined].mean() < 0.6 < 0.85 < conf[~joined].mean()


def test_one_hand_scene_is_unchanged_and_options(tmp_path, capsys):
    one = SynthSource(frames=3, size=(64, 40), seed=3)
    assert "hands" not in one.metadata() and one.ground_truths(0) is None
    explicit = SynthSource(frames=3, size=(64, 40), seed=3, hands=1).render(2)[0]
    assert np.array_equal(explicit.color, one.render(2)[0].color) and explicit.ground_truth == one.ground_truth(2)
    two = open_source("synth:hands=2,frames=3,size=64x40")
    assert two.hands == 2 and two.metadata()["hands"] == "2" and "hands=2" in two.describe()
    with pytest.raises(InputError, match="hands must be an integer in \\[1, 2\\]"):
        SynthSource(hands=3)
    out = tmp_path / "two.mcap"
    assert (
        main(
            [
                "synth",
                str(out),
                "--frames",
                "4",
                "--size",
                "64x40",
                "--hands",
                "2",
                "--background-frames",
                "1",
                "--no-progress",
            ]
        )
        == 0
    )
    capsys.readouterr()
    src = SynthSource(frames=4, size=(64, 40), hands=2, background_frames=1)
    with McapReplay(out) as rec:
        assert rec.info().ground_truth_frames == 3
        for i, f in enumerate(rec):
            assert f.ground_truths == src.render(i)[0].ground_truths
            assert f.ground_truth == (None if i == 0 else f.ground_truths["right_hand"])


def test_recorder_and_replay_keep_single_and_multi_target_truth(tmp_path):
    base = SynthSource(frames=2, size=(64, 40), seed=1).render(1)[0]
    truths = {"right_hand": PalmPoint(1.0, 2.0, True), "left_hand": PalmPoint(3.0, 4.0), "head": PalmPoint(5.0, 6.0)}
    multi = Frame(base.timestamp_ns + 1, 2, base.color, base.depth, base.intrinsics, base.joints, ground_truths=truths)
    assert multi.ground_truth == truths["right_hand"]
    for frame in (base, multi):
        path = tmp_path / f"r{frame.seq}.mcap"
        with McapRecorder(path) as rec:
            rec.write(frame)
        with McapReplay(path) as rep:
            (back,) = list(rep)
        assert back.ground_truth == frame.ground_truth
        assert back.ground_truths == frame.ground_truths
    assert dict(back.ground_truths) == truths and back.ground_truth == truths["right_hand"]
    # one recording carries one kind of ground truth
    with McapRecorder(tmp_path / "mixed.mcap") as rec:
        rec.write(base)
        with pytest.raises(InputError, match="already carries fusion_pf.PalmPoint"):
            rec.write(multi)
    with pytest.raises(InputError, match="ground_truths\\['x'\\] must be a PalmPoint"):
        Frame(0, 0, base.color, None, base.intrinsics, ground_truths={"x": (1, 2)})
    with pytest.raises(InputError, match="target names"):
        Frame(0, 0, base.color, None, base.intrinsics, ground_truths={"": PalmPoint(1, 2)})


def test_wash_schedule_is_continuous_across_cycles():
    d = np.array([sc.wash_schedule(t)[0] for t in np.arange(0.0, 600.0, 0.5)])
    assert np.abs(np.diff(d)).max() < 0.02
    assert sc.wash_schedule(0.0) == (0.30, 0.0) and sc.wash_schedule(300.0)[0] == pytest.approx(-0.30)


def _layout(src):
    """(joins of >= 10 frames, crossings, largest apart distance px) over the source's frames."""
    truths = [src.ground_truths(i) for i in range(len(src))]
    joined = [t["right_hand"].occluded for t in truths]
    dx = np.array([t["left_hand"].u - t["right_hand"].u for t in truths])
    return len([n for n in runs(joined) if n >= 10]), int(np.count_nonzero(np.diff(np.sign(dx)) != 0)), np.abs(dx).max()


def test_layout_options_set_joins_crossings_distance_and_timing():
    base = SynthSource(frames=300, size=(320, 200), hands=2, seed=5)
    assert base._wash.keys is sc.WASH_KEYS  # the documented cycle, bit for bit
    joins, crossings, far = _layout(base)
    assert (joins, crossings) == (2, 1)
    kw = dict(size=(320, 200), hands=2, seed=5, joins=3, crossings=2, hand_distance=0.4)
    period = sc.wash_keys(3, 2, 0.4, 0.13)[-1][0]
    other = SynthSource(frames=int(period), **kw)
    assert "hand_distance=0.4 joins=3 crossings=2" in other.describe()
    j, c, wide = _layout(other)
    assert (j, c) == (3, 2) and wide > 1.2 * far
    # timing drawn from the seed: same seed same motion, another seed another
    drawn = [SynthSource(frames=300, size=(320, 200), hands=2, seed=s, timing=1)._wash.keys for s in (5, 5, 6)]
    assert drawn[0] == drawn[1] != drawn[2]
    d = np.array([sc.wash_schedule(t, drawn[2])[0] for t in np.arange(0.0, 3 * drawn[2][-1][0], 0.5)])
    assert np.abs(np.diff(d)).max() < 0.02  # continuous across cycles
    with pytest.raises(InputError, match="synth option crossings describes the two-hand motion; it needs hands=2"):
        SynthSource(frames=3, crossings=2)
    with pytest.raises(
        InputError, match="synth option timing changes the two-hand motion, which script 'events' fixes"
    ):
        SynthSource(frames=3, hands=2, script="events", timing=1)
    with pytest.raises(InputError, match=r"synth option joins must be an integer in \[0, 4\], got 5"):
        SynthSource(frames=3, hands=2, joins=5)
