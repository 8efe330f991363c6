"""Interaction events (paper 004 §7): the detector on hand-made state sequences and images, the matcher."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from fusion_pf.errors import InputError
from fusion_pf.frame import Frame, Intrinsics, Joint
from fusion_pf.pipeline.events import EventConfig, EventDetector, Persist, events_cell, object_modes
from fusion_pf.score.events import match_events, parse_events_cell

T, C, U, L, N = "tracking", "combined", "unlabelled", "lost", "uninitialised"
HANDS3 = ("right_hand", "left_hand", "head")
#: A small camera: the palm (95 mm) at 1000 mm is 12.5 px long.
INTR = Intrinsics(160, 100, 125.0, 125.0, 79.5, 49.5)
PALM_PX = 125.0 * 95.0 / 1000.0
SKIN = (218, 168, 142)
GREEN = (30, 120, 40)
NAVY = (30, 38, 70)


def _feed(det, sequence, positions=None, image=None, depths=None):
    """Run ``det`` over per-frame state dicts; ``[(frame, event, targets)]``."""
    out = []
    for k, states in enumerate(sequence):
        pos = positions[k] if positions is not None else {t: (10.0 * i, 10.0) for i, t in enumerate(states)}
        img = image(k) if callable(image) else image
        for e in det.update(states, pos, k, 1000 + k, image=img, depths_mm=depths):
            out.append((e.frame, e.event, e.targets))
    return out


def test_persist_takes_a_value_held_for_enough_frames_and_ignores_a_flicker():
    p = Persist(2, False)
    assert [p.update(x, k) for k, x in enumerate([True, False, True, True, True])] == [False] * 3 + [True, False]
    assert p.value is True and p.onset == 2
    q = Persist(1, None)
    assert q.update(False, 0) and q.value is False


def test_one_target_reports_only_disappear_and_reappear_and_a_one_frame_loss_is_none():
    det = EventDetector(["right_hand"])
    seq = [N] * 2 + [T] * 5 + [L] + [T] * 4 + [L] * 3 + [T] * 3
    events = _feed(det, [{"right_hand": s} for s in seq])
    # no 'reappear' for the first acquisition, nothing for the one-frame loss at 7;
    # lost from 12: confirmed at 13 (persist 2), back at 15: confirmed at 16
    assert events == [(13, "disappear", ("right_hand",)), (16, "reappear", ("right_hand",))]
    assert det.counts["disappear"] == det.counts["reappear"] == 1 and det.counts["join"] == 0


def test_two_hands_join_and_separate_and_a_one_frame_combination_is_none():
    det = EventDetector(HANDS3)
    pair = [T] * 3 + [C] + [T] * 3 + [C] * 5 + [U] + [T] * 3
    seq = [{"right_hand": s, "left_hand": s, "head": T} for s in pair]
    events = _feed(det, seq)
    assert events == [
        (8, "join", ("right_hand", "left_hand")),
        (13, "separate", ("right_hand", "left_hand")),
    ]
    # a hand combined with the head is no join of the hands but a contact (even without an image)
    det2 = EventDetector(HANDS3)
    assert _feed(det2, [{"right_hand": C, "left_hand": T, "head": C}] * 4) == [(1, "contact", ("right_hand", "head"))]


def _blank(k: int = 0, draw=()) -> Frame:
    colour = np.full((100, 160, 3), 150, np.uint8)
    for (u, v), r, rgb in draw:
        cv2.circle(colour, (int(u), int(v)), int(r), rgb, -1)
    return Frame(
        1000 + k,
        k,
        colour,
        np.full((100, 160), 1000, np.uint16),
        INTR,
        joints={"torso": Joint(150.0, 90.0, 1500.0, 0.9)},
    )


def test_contact_has_hysteresis_and_reports_each_touch_once():
    # contact below 1.3 palm lengths (16.25 px), ends beyond 1.8 (22.5 px)
    det = EventDetector(HANDS3)
    dist = [40, 15, 15, 20, 15, 20, 22, 22, 30, 30, 15, 30, 30, 15, 15]
    seq = [{t: T for t in HANDS3}] * len(dist)
    positions = [{"right_hand": (40.0 + d, 50.0), "left_hand": (140.0, 80.0), "head": (40.0, 50.0)} for d in dist]
    depths = {t: 1000.0 for t in HANDS3}
    events = _feed(det, seq, positions, _blank(), depths)
    # first touch 1-2 (confirmed at 2), kept through 20-22 px, ended by 8-9; the one-frame 15 at 10 is nothing;
    # the second touch from 13 is confirmed at 14
    assert events == [(2, "contact", ("right_hand", "head")), (14, "contact", ("right_hand", "head"))]


def test_object_modes_find_a_coloured_object_beside_the_hand_but_not_skin_or_clothing():
    hand = (80.0, 50.0)
    with_ball = _blank(draw=[(hand, 6, SKIN), ((80, 59), 4, GREEN)]).color
    modes = object_modes(with_ball, None, hand, PALM_PX, None, EventConfig())
    assert len(modes) == 1 and abs(modes[0][0] - 127.0) <= 6.0  # hue of (30, 120, 40): 126.9 degrees
    skin_only = _blank(draw=[(hand, 6, SKIN)]).color
    assert object_modes(skin_only, None, hand, PALM_PX, None, EventConfig()) == []
    sleeve = _blank(draw=[(hand, 6, SKIN), ((80, 59), 4, NAVY)]).color
    navy_hue = float(cv2.cvtColor(np.array([[NAVY]], np.uint8), cv2.COLOR_RGB2HSV_FULL)[0, 0, 0]) * 360 / 256
    assert object_modes(sleeve, None, hand, PALM_PX, None, EventConfig())  # a navy thing is an object ...
    assert object_modes(sleeve, None, hand, PALM_PX, None, EventConfig(), navy_hue) == []  # ... unless it is clothing
    tiny = _blank(draw=[(hand, 6, SKIN), ((80, 59), 1, GREEN)]).color
    assert object_modes(tiny, None, hand, PALM_PX, None, EventConfig()) == []  # below the smallest region
    far = np.full((100, 160), 1000, np.uint16)
    far[50:, :] = 1300  # the ball 30 cm behind the hand: the body, not held
    assert object_modes(with_ball, far, hand, PALM_PX, 1000.0, EventConfig()) == []
    assert object_modes(with_ball, far, hand, PALM_PX, 1300.0, EventConfig())  # at a hand 1300 mm away: held


def test_a_still_hand_picks_up_and_the_object_is_exchanged_across_a_join():
    depths = {t: 1000.0 for t in HANDS3}
    right, left, head = (40.0, 60.0), (120.0, 60.0), (80.0, 15.0)
    frames, seq, pos = [], [], []

    def add(states, r, lft, ball_at):
        k = len(seq)
        draw = [(r, 6, SKIN), (lft, 6, SKIN), (head, 7, SKIN)]
        if ball_at is not None:
            draw.append(((ball_at[0], ball_at[1] + 9), 4, GREEN))
        frames.append(_blank(k, draw))
        seq.append(dict(zip(HANDS3, states)))
        pos.append({"right_hand": r, "left_hand": lft, "head": head})

    for _ in range(4):
        add((T, T, T), right, left, None)
    for _ in range(4):  # the ball appears at the still right hand (4 frames): picked up, confirmed at frame 7
        add((T, T, T), right, left, right)
    mid = (80.0, 60.0)
    for _ in range(5):  # joined: the ball passes
        add((C, C, T), mid, mid, mid)
    for _ in range(6):  # apart again, the ball at the left hand
        add((T, T, T), right, left, left)
    events = _feed(EventDetector(HANDS3), seq, pos, lambda k: frames[k], depths)
    names = [(f, e, t) for f, e, t in events]
    assert names == [
        (7, "pick_up", ("right_hand",)),
        (9, "join", ("right_hand", "left_hand")),
        (14, "separate", ("right_hand", "left_hand")),
        (14, "exchange", ("right_hand", "left_hand")),  # the left hand's ball seen from the separation's onset, 13
    ]


def test_without_the_exchange_the_same_separation_keeps_the_carrier():
    depths = {t: 1000.0 for t in HANDS3}
    right, left, head, mid = (40.0, 60.0), (120.0, 60.0), (80.0, 15.0), (80.0, 60.0)
    frames, seq, pos = [], [], []
    plan = (
        [((T, T, T), right, left, right)] * 8 + [((C, C, T), mid, mid, mid)] * 5 + [((T, T, T), right, left, right)] * 6
    )
    for k, (states, r, lft, ball) in enumerate(plan):
        draw = [(r, 6, SKIN), (lft, 6, SKIN), (head, 7, SKIN), ((ball[0], ball[1] + 9), 4, GREEN)]
        frames.append(_blank(k, draw))
        seq.append(dict(zip(HANDS3, states)))
        pos.append({"right_hand": r, "left_hand": lft, "head": head})
    events = _feed(EventDetector(HANDS3), seq, pos, lambda k: frames[k], depths)
    assert [e for _, e, _ in events] == ["pick_up", "join", "separate"]


def test_event_config_and_targets_are_checked():
    with pytest.raises(InputError, match="persist"):
        EventConfig(persist=0)
    with pytest.raises(InputError, match="contact_on"):
        EventConfig(contact_on=2.0, contact_off=1.0)
    with pytest.raises(InputError, match="unknown target 'nose'"):
        EventDetector(["right_hand"]).update({"nose": T}, {}, 0, 0)


def test_csv_cell_round_trips_and_bad_cells_are_refused():
    det = EventDetector(HANDS3)
    seq = [{"right_hand": s, "left_hand": s, "head": T} for s in [T, C, C]]
    events = []
    for k, states in enumerate(seq):
        events = det.update(states, {t: (k, 0.0) for t in states}, k, k)
    assert events_cell(events) == "join:right_hand+left_hand" and events_cell([]) == ""
    assert parse_events_cell(2, "join:right_hand+left_hand;contact:right_hand+head") == [
        {"frame": 2, "event": "join", "targets": ["right_hand", "left_hand"]},
        {"frame": 2, "event": "contact", "targets": ["right_hand", "head"]},
    ]
    with pytest.raises(InputError, match="frame 3"):
        parse_events_cell(3, "join")


def test_match_events_within_the_tolerance_one_to_one():
    truth = [
        {"frame": 10, "event": "join", "targets": ["right_hand", "left_hand"]},
        {"frame": 40, "event": "exchange", "targets": ["right_hand", "left_hand"]},
        {"frame": 60, "event": "contact", "targets": ["right_hand", "head"]},
    ]
    reported = [
        {"frame": 15, "event": "join", "targets": ["left_hand", "right_hand"]},  # a pair: order free, +5 in
        {"frame": 16, "event": "join", "targets": ["right_hand", "left_hand"]},  # a second one: false
        {"frame": 41, "event": "exchange", "targets": ["left_hand", "right_hand"]},  # wrong direction: false
        {"frame": 66, "event": "contact", "targets": ["right_hand", "head"]},  # +6: too late
    ]
    score = match_events(truth, reported)
    assert [(t["frame"], o) for t, _, o in score.matched] == [(10, 5)]
    assert [m["frame"] for m in score.missed] == [40, 60]
    assert [f["frame"] for f in score.false] == [16, 41, 66]
    assert not score.perfect and "1 matched" in score.summary()
    assert match_events(truth, [dict(t) for t in truth]).perfect
    with pytest.raises(InputError, match="tolerance"):
        match_events(truth, reported, tolerance=-1)
