"""Detections to targets: labels first, then gated nearest prediction (Hungarian), sharing only when combined."""

from __future__ import annotations

import pytest

from fusion_pf.association import Detection, associate, compatible, handedness_label
from fusion_pf.errors import InputError
from fusion_pf.frame import Measurement

HANDS = ("right_hand", "left_hand")


def det(source: str, u: float, v: float, label: str | None = None, score: float = 1.0) -> Detection:
    return Detection(Measurement(source, u, v, 0.9), label=label, label_score=score)


def picked(out: dict[str, list[Detection]]) -> dict[str, list[tuple[str, float, float]]]:
    return {t: [(d.source, d.u, d.v) for d in ds] for t, ds in out.items()}


def test_nearest_prediction_one_to_one_over_all_targets():
    # closest pair first would give (9, 0) to the left target (1 px) and leave the right one 20 px away;
    # the joint assignment minimises the total distance (9 + 10 px) instead
    out = associate(HANDS, [(0.0, 0.0), (10.0, 0.0)], [det("colour", 9, 0), det("colour", 20, 0)], gates=[80, 80])
    assert picked(out) == {"right_hand": [("colour", 9, 0)], "left_hand": [("colour", 20, 0)]}


def test_a_certain_label_goes_to_its_target_whatever_the_distance():
    dets = [det("skeleton", 10, 0, "right_hand"), det("skeleton", 300, 0, "left_hand")]
    out = associate(HANDS, [(300.0, 0.0), (10.0, 0.0)], dets, gates=[5, 5])  # predictions crossed, tiny gates
    assert picked(out) == {"right_hand": [("skeleton", 10, 0)], "left_hand": [("skeleton", 300, 0)]}
    # a joint of a target that is not tracked goes to nobody
    out = associate(("right_hand",), [(10.0, 0.0)], [det("skeleton", 11, 0, "head")], gates=[50])
    assert out == {"right_hand": []}


def test_handedness_decides_between_targets_at_similar_distances():
    # both hands predicted at the same place (joined): handedness gives each its own
    dets = [det("hand", 100, 0, "left_hand", 0.8), det("hand", 104, 0, "right_hand", 0.8)]
    out = associate(HANDS, [(102.0, 0.0), (102.0, 0.0)], dets, gates=[60, 60])
    assert picked(out) == {"right_hand": [("hand", 104, 0)], "left_hand": [("hand", 100, 0)]}
    # without labels the same detections are assigned by distance alone (here: the first target takes the first)
    plain = [det("hand", 100, 0), det("hand", 104, 0)]
    out = associate(HANDS, [(101.0, 0.0), (103.0, 0.0)], plain, gates=[60, 60])
    assert picked(out) == {"right_hand": [("hand", 100, 0)], "left_hand": [("hand", 104, 0)]}


def test_an_uncertain_label_cannot_pull_a_tracked_target_across_the_image():
    # the right hand is tracked at (100, 0); the model calls its hand "left" with a weak score:
    # the left target (no prediction, acquisition) does not take it from the right one
    out = associate(HANDS, [(100.0, 0.0), None], [det("hand", 102, 0, "left_hand", 0.3)], gates=[60, 400])
    assert picked(out) == {"right_hand": [("hand", 102, 0)], "left_hand": []}
    # a confident opposite label does: the right hand's target was on the wrong hand
    out = associate(HANDS, [(100.0, 0.0), None], [det("hand", 102, 0, "left_hand", 0.9)], gates=[60, 100])
    assert picked(out) == {"right_hand": [], "left_hand": [("hand", 102, 0)]}


def test_gate_and_acquisition():
    # beyond the gate of the tracked target; the target without a prediction takes what nobody wants
    out = associate(HANDS, [(0.0, 0.0), None], [det("colour", 100, 0), det("colour", 5, 0)], gates=[20, 400])
    assert picked(out) == {"right_hand": [("colour", 5, 0)], "left_hand": [("colour", 100, 0)]}
    out = associate(HANDS, [(0.0, 0.0), (300.0, 0.0)], [det("colour", 100, 0)], gates=[20, 20])
    assert picked(out) == {"right_hand": [], "left_hand": []}


def test_one_detection_is_shared_only_by_combined_targets():
    dets = [det("colour", 100, 0), det("depth", 101, 0)]
    preds = [(98.0, 0.0), (103.0, 0.0)]
    apart = associate(HANDS, preds, dets, gates=[50, 50])
    assert sum(len(v) for v in apart.values()) == 2  # each detection to one target only
    joined = associate(
        HANDS, preds, dets, gates=[50, 50], partners={"right_hand": "left_hand", "left_hand": "right_hand"}
    )
    assert picked(joined)["right_hand"] == picked(joined)["left_hand"] == [("colour", 100, 0), ("depth", 101, 0)]


def test_a_region_spanning_two_targets_measures_neither_unless_they_are_combined():
    # hands 100 px apart near the body: one colour region bridges them through the torso (its box holds
    # both predictions, its centroid lies between them); a wood-coloured object beside the right hand
    bridge = Detection(Measurement("colour", 150, 100, 0.1, {"bbox": [90, 80, 120, 40]}))
    clutter = Detection(Measurement("colour", 130, 60, 0.5, {"bbox": [120, 50, 20, 20]}))
    preds = [(100.0, 100.0), (200.0, 100.0)]
    out = associate(HANDS, preds, [bridge, clutter, det("depth", 101, 99)], gates=[120, 120])
    # neither takes the bridge nor, seen by the colour cue only inside it, the clutter; depth is its own
    assert picked(out) == {"right_hand": [("depth", 101, 99)], "left_hand": []}
    # a region holding one target's prediction only is that target's; the other keeps its own region
    hand = Detection(Measurement("colour", 260, 100, 0.5, {"bbox": [250, 90, 20, 20]}))
    out = associate(HANDS, [(100.0, 100.0), (262.0, 100.0)], [bridge, hand], gates=[120, 120])
    assert picked(out) == {"right_hand": [("colour", 150, 100)], "left_hand": [("colour", 260, 100)]}
    # joined hands are one region holding both: the combined pair shares it (paper 004)
    partners = {"right_hand": "left_hand", "left_hand": "right_hand"}
    out = associate(HANDS, [(140.0, 100.0), (160.0, 100.0)], [bridge], gates=[120, 120], partners=partners)
    assert picked(out) == {"right_hand": [("colour", 150, 100)], "left_hand": [("colour", 150, 100)]}


def test_a_combined_pair_shares_its_blob_rather_than_take_a_distractor():
    # joined hands: one blob between the two predictions, a wood-coloured object 90 px out; the
    # one-to-one assignment gives each of the pair one of them, the pair shares the nearer blob
    partners = {"right_hand": "left_hand", "left_hand": "right_hand"}
    dets = [det("colour", 363, 262), det("colour", 439, 220), det("depth", 350, 270), det("depth", 380, 268)]
    out = associate(HANDS, [(356.0, 268.0), (372.0, 268.0)], dets, gates=[120, 120], partners=partners)
    # separating hands keep their own detections (each nearer its own prediction)
    assert picked(out) == {
        "right_hand": [("colour", 363, 262), ("depth", 350, 270)],
        "left_hand": [("colour", 363, 262), ("depth", 380, 268)],
    }


def test_the_head_never_takes_a_hand_detection():
    hand = det("hand", 50, 50)
    labelled = det("colour", 50, 50, "left_hand", 0.9)
    assert not compatible("head", hand) and not compatible("head", labelled)
    assert compatible("right_hand", hand) and compatible("head", det("colour", 50, 50))
    # the head is predicted exactly on the hand, the hand target has no prediction: the hand target gets it
    out = associate(("head", "right_hand"), [(50.0, 50.0), None], [hand], gates=[30, 400])
    assert picked(out) == {"head": [], "right_hand": [("hand", 50, 50)]}
    # alone, the head takes nothing of a hand, even combined with a hand target
    out = associate(("head",), [(50.0, 50.0)], [hand, labelled], gates=[30])
    assert out == {"head": []}
    out = associate(
        ("head", "right_hand"),
        [(50.0, 50.0), (50.0, 50.0)],
        [hand],
        gates=[30, 30],
        partners={"head": "right_hand", "right_hand": "head"},
    )
    assert picked(out) == {"head": [], "right_hand": [("hand", 50, 50)]}
    # and a hand never takes the head's joint
    assert not compatible("right_hand", det("skeleton", 0, 0, "head"))


def test_duplicates_of_one_region_are_one_detection():
    # the windows of two nearby targets saw the same region
    dets = [det("colour", 100.0, 0.0), det("colour", 100.4, 0.0)]
    out = associate(HANDS, [(99.0, 0.0), (101.0, 0.0)], dets, gates=[50, 50], merge_px=1.0)
    assert sum(len(v) for v in out.values()) == 1


def test_handedness_names_the_hand_target():
    assert handedness_label("right") == "right_hand" and handedness_label(None) is None


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"gates": [10]}, "same length"),
        ({"gates": [10, -1]}, "gates"),
        ({"gates": [10, float("nan")]}, "gates"),
    ],
)
def test_bad_arguments_are_input_errors(kwargs, word):
    with pytest.raises(InputError, match=word):
        associate(HANDS, [None, None], [], **kwargs)


def test_label_score_must_be_a_probability():
    with pytest.raises(InputError, match="label_score"):
        det("hand", 0, 0, "right_hand", 1.5)


def test_a_source_gate_keeps_a_detection_beyond_the_targets_uncertainty_out():
    # a colour region 50 px from the right hand's prediction (clutter), inside its window's gate of 120 px
    dets = [det("colour", 150, 0), det("depth", 104, 0)]
    out = associate(HANDS, [(100.0, 0.0), None], dets, gates=[120, 300])
    assert picked(out)["right_hand"] == [("colour", 150, 0), ("depth", 104, 0)]
    # its uncertainty gates colour at 30 px: the clutter is nobody's but the acquiring target's
    out = associate(HANDS, [(100.0, 0.0), None], dets, gates=[120, 300], source_gates=[{"colour": 30.0}, None])
    assert picked(out) == {"right_hand": [("depth", 104, 0)], "left_hand": [("colour", 150, 0)]}
    with pytest.raises(InputError, match="source_gates must hold one mapping of px > 0"):
        associate(HANDS, [(100.0, 0.0), None], dets, gates=[120, 300], source_gates=[{"colour": 0.0}, None])
    with pytest.raises(InputError, match="source_gates must hold one mapping"):
        associate(HANDS, [(100.0, 0.0), None], dets, gates=[120, 300], source_gates=[None])


def test_a_combined_pair_keeps_the_parts_a_cue_split_their_region_into():
    partners = {"right_hand": "left_hand", "left_hand": "right_hand"}
    part = [Detection(Measurement("depth", u, 270.0, 0.9, {"part": k})) for k, u in enumerate((352.0, 376.0))]
    # the right hand's prediction lies nearer the left's part than its own (the estimates drifted together):
    # the parts are still each its own, not shared like a blob
    out = associate(HANDS, [(366.0, 270.0), (372.0, 270.0)], part, gates=[120, 120], partners=partners)
    assert picked(out) == {"right_hand": [("depth", 352, 270)], "left_hand": [("depth", 376, 270)]}


def test_a_combined_target_shares_its_partners_region_rather_than_keep_a_fragment():
    # two hands overlapping near the body: the depth cue sees the pair as one region (2400 px^2) and a sliver
    # of 500 px^2 beside it, nearer the left hand's prediction; the left hand takes the pair's region
    partners = {"right_hand": "left_hand", "left_hand": "right_hand"}
    region = Detection(Measurement("depth", 360, 271, 0.9, {"area": 2400}))
    sliver = Detection(Measurement("depth", 392, 300, 0.1, {"area": 500}))
    preds = [(358.0, 283.0), (381.0, 294.0)]
    out = associate(HANDS, preds, [region, sliver], gates=[120, 120], partners=partners)
    assert picked(out) == {"right_hand": [("depth", 360, 271)], "left_hand": [("depth", 360, 271)]}
    # a region of a quarter of the other's area or more is a hand's own
    half = Detection(Measurement("depth", 392, 300, 0.5, {"area": 1200}))
    out = associate(HANDS, preds, [region, half], gates=[120, 120], partners=partners)
    assert picked(out) == {"right_hand": [("depth", 360, 271)], "left_hand": [("depth", 392, 300)]}
    # not combined, the sliver is the left hand's (no sharing)
    out = associate(HANDS, preds, [region, sliver], gates=[120, 120])
    assert picked(out) == {"right_hand": [("depth", 360, 271)], "left_hand": [("depth", 392, 300)]}


def test_a_hand_in_contact_with_the_head_keeps_its_region_however_small_against_the_heads():
    # a hand touching the head: the head's region (6000 px^2) dwarfs the hand's (900 px^2); the hand's is no
    # fragment of the head's, so the hand keeps its own region
    targets = ("right_hand", "head")
    partners = {"right_hand": "head", "head": "right_hand"}
    head = Detection(Measurement("depth", 300, 120, 0.9, {"area": 6000}))
    hand = Detection(Measurement("depth", 340, 150, 0.8, {"area": 900}))
    out = associate(targets, [(338.0, 148.0), (302.0, 122.0)], [head, hand], gates=[120, 120], partners=partners)
    assert picked(out) == {"right_hand": [("depth", 340, 150)], "head": [("depth", 300, 120)]}
