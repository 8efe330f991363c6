"""Track states (paper 004 §5.2): single-target transitions, combination, identity re-assignment."""

import dataclasses
import math

import numpy as np
import pytest

from fusion_pf.errors import InputError
from fusion_pf.filter.states import (
    Evidence,
    StateConfig,
    TrackState,
    TrackStateMachine,
    TrackStatus,
    combine_states,
    reassign_identities,
    step_state,
)

CFG = StateConfig(
    max_spread_px=30.0,
    min_likelihood=0.05,
    silent_frames=3,
    degraded_frames=2,
    image_size=(320, 200),
    merge_px=20.0,
    split_px=35.0,
)
GOOD = Evidence((100.0, 100.0), spread_px=5.0, likelihood=0.8, cues=2)


def run(evidence):
    status, out = TrackStatus(), []
    for e in evidence:
        status = step_state(status, e, CFG)
        out.append(status.state)
    return out


def test_single_target_lifecycle_uninitialised_tracking_lost_reacquired():
    silent = Evidence((100.0, 100.0), spread_px=5.0, cues=0)
    states = run([Evidence(None, cues=0), GOOD, silent, silent, silent, silent, GOOD, GOOD])
    U, T, L = TrackState.UNINITIALISED, TrackState.TRACKING, TrackState.LOST
    # lost on the 3rd silent frame (silent_frames = 3), re-acquired by the next good frame
    assert states == [U, T, T, T, L, L, T, T]


def test_leaving_the_image_is_lost_at_once_and_degradation_after_degraded_frames():
    out = Evidence((-5.0, 100.0), spread_px=5.0, likelihood=0.8, cues=1)
    assert run([GOOD, out]) == [TrackState.TRACKING, TrackState.LOST]
    wide = Evidence((100.0, 100.0), spread_px=45.0, likelihood=0.8, cues=1)
    weak = Evidence((100.0, 100.0), spread_px=5.0, likelihood=0.01, cues=1)
    assert run([GOOD, wide, wide]) == [TrackState.TRACKING, TrackState.TRACKING, TrackState.LOST]
    assert run([GOOD, weak, GOOD, weak]) == [TrackState.TRACKING] * 4  # not consecutive: never lost
    # a degraded estimate does not (re)initialise a track
    assert run([wide, wide]) == [TrackState.UNINITIALISED] * 2
    # unknown spread / likelihood (nan) is not evidence of degradation
    assert run([Evidence((1.0, 1.0))]) == [TrackState.TRACKING]


def test_unlabelled_until_labelled():
    unl = Evidence((100.0, 100.0), spread_px=5.0, likelihood=0.8, cues=1, labelled=False)
    assert run([unl, unl, GOOD]) == [TrackState.UNLABELLED, TrackState.UNLABELLED, TrackState.TRACKING]


def test_combine_then_separate():
    t = TrackStatus(TrackState.TRACKING)
    s = combine_states([t, t, t], [(100.0, 100.0), (110.0, 100.0), (300.0, 50.0)], CFG)
    assert [x.state for x in s] == [TrackState.COMBINED, TrackState.COMBINED, TrackState.TRACKING]
    assert (s[0].partner, s[1].partner, s[2].partner) == (1, 0, None)
    # still within split_px: stays combined (hysteresis)
    s = combine_states(s, [(100.0, 100.0), (130.0, 100.0), (300.0, 50.0)], CFG)
    assert [x.state for x in s[:2]] == [TrackState.COMBINED] * 2
    s = combine_states(s, [(100.0, 100.0), (140.0, 100.0), (300.0, 50.0)], CFG)
    assert [x.state for x in s[:2]] == [TrackState.UNLABELLED] * 2 and s[0].partner is None
    # a combined target whose partner is lost is alone again
    lost = TrackStatus(TrackState.LOST)
    s = combine_states([TrackStatus(TrackState.COMBINED, partner=1), lost], [(1.0, 1.0), None], CFG)
    assert s[0].state == TrackState.TRACKING


def test_labels_apart_separate_a_pair_one_shared_blob_holds_together():
    c = [TrackStatus(TrackState.COMBINED, partner=1), TrackStatus(TrackState.COMBINED, partner=0)]
    together = [(100.0, 100.0), (102.0, 100.0)]  # both estimates on the blob shared by the combination
    s = combine_states(c, together, CFG, [(90.0, 100.0), (115.0, 100.0)])  # joints within split_px
    assert [x.state for x in s] == [TrackState.COMBINED] * 2
    s = combine_states(c, together, CFG, [(80.0, 100.0), (120.0, 100.0)])  # joints 40 px > split_px apart
    assert [x.state for x in s] == [TrackState.UNLABELLED] * 2  # separated, not combined again at once
    # a pair whose joints are apart does not combine, one without both joints does
    t = [TrackStatus(TrackState.TRACKING)] * 2
    assert combine_states(t, together, CFG, [(80.0, 100.0), (120.0, 100.0)]) == t
    s = combine_states(t, together, CFG, [(80.0, 100.0), None])
    assert [x.state for x in s] == [TrackState.COMBINED] * 2
    with pytest.raises(InputError, match="labels"):
        combine_states(t, together, CFG, [None])


def test_state_machine_for_three_targets():
    fsm = TrackStateMachine(["right_hand", "left_hand", "head"], CFG)
    ev = {
        "right_hand": Evidence((100.0, 150.0), 5.0, 0.9, 1),
        "left_hand": Evidence((105.0, 150.0), 5.0, 0.9, 1),
        "head": Evidence((100.0, 30.0), 5.0, 0.9, 1),
    }
    assert fsm.update(ev) == {
        "right_hand": TrackState.COMBINED,
        "left_hand": TrackState.COMBINED,
        "head": TrackState.TRACKING,
    }
    ev["left_hand"] = Evidence((160.0, 150.0), 5.0, 0.9, 1)
    assert fsm.update(ev)["left_hand"] == TrackState.UNLABELLED
    assert fsm.update(ev)["left_hand"] == TrackState.TRACKING
    # a target without evidence goes lost after silent_frames
    for _ in range(CFG.silent_frames):
        states = fsm.update({"right_hand": ev["right_hand"], "left_hand": ev["left_hand"]})
    assert states["head"] == TrackState.LOST
    with pytest.raises(InputError, match="unknown target 'foot'"):
        fsm.update({"foot": GOOD})


def test_reassign_identities_by_entry_side():
    entry = np.array([[-10.0, 0.0], [10.0, 0.0]])  # target 0 entered from the left
    assert reassign_identities(entry, np.array([[150.0, 80.0], [110.0, 80.0]])).tolist() == [1, 0]
    assert reassign_identities(entry, np.array([[110.0, 80.0], [150.0, 80.0]])).tolist() == [0, 1]
    with pytest.raises(InputError):
        reassign_identities(entry, np.zeros((3, 2)))


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"max_spread_px": 0}, "max_spread_px"),
        ({"min_likelihood": 2}, "min_likelihood"),
        ({"silent_frames": 0}, "silent_frames"),
        ({"merge_px": 30, "split_px": 20}, "split_px"),
        ({"merge_px": math.nan}, "merge_px"),
    ],
)
def test_bad_config(kwargs, match):
    with pytest.raises(InputError, match=match):
        StateConfig(**kwargs)


def test_own_evidence_apart_separates_below_the_estimates_split_distance():
    c = [TrackStatus(TrackState.COMBINED, partner=1), TrackStatus(TrackState.COMBINED, partner=0)]
    together = [(100.0, 100.0), (102.0, 100.0)]
    joints = [(88.0, 100.0), (112.0, 100.0)]  # 24 px apart: within split_px 35
    assert [x.state for x in combine_states(c, together, CFG, joints)] == [TrackState.COMBINED] * 2
    near = dataclasses.replace(CFG, label_split_px=20.0)  # e.g. 1.1 apparent palm lengths
    assert [x.state for x in combine_states(c, together, near, joints)] == [TrackState.UNLABELLED] * 2
    # two separate detections the caller saw: apart without labels
    s = combine_states(c, together, CFG, None, apart=[(1, 0)])
    assert [x.state for x in s] == [TrackState.UNLABELLED] * 2
    t = [TrackStatus(TrackState.TRACKING)] * 2
    assert combine_states(t, together, CFG, None, apart=[(0, 1)]) == t
    with pytest.raises(InputError, match="label_split_px must be a finite number > 0 px or None, got -1"):
        StateConfig(label_split_px=-1)
