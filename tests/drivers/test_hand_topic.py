"""The /hand/landmarks topic: HandObservation, Frame.hands, recording and replay."""

from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from mcap.reader import make_reader

import drivers.mcap_format as fmt
from drivers.mcap_record import McapRecorder
from drivers.mcap_replay import McapReplay
from fusion_pf.errors import InputError, RecordingError
from fusion_pf.frame import Frame, HandObservation, Intrinsics

INTR = Intrinsics(64, 40, 50.0, 50.0, 31.5, 19.5)


def _landmarks(seed: int, nan_z: bool = False) -> np.ndarray:
    rng = np.random.default_rng(seed)
    lm = np.column_stack([rng.uniform(0, 64, 21), rng.uniform(0, 40, 21), rng.normal(0, 5, 21)])
    if nan_z:
        lm[:, 2] = np.nan
    return lm


def _frame(i: int, hands) -> Frame:
    colour = np.full((40, 64, 3), i, np.uint8)
    return Frame(1_000_000_000 + i * 33_000_000, i, colour, None, INTR, hands=hands)


def test_hand_observation_palm_and_validation() -> None:
    lm = _landmarks(1)
    hand = HandObservation(lm, 0.9, "left")
    # the palm is the mean of the wrist and the four finger MCP joints (independent sum)
    expected = (lm[0, :2] + lm[5, :2] + lm[9, :2] + lm[13, :2] + lm[17, :2]) / 5
    np.testing.assert_allclose(hand.palm, expected, rtol=0, atol=1e-12)
    assert hand.landmarks.dtype == np.float64 and not hand.landmarks.flags.writeable
    lm[0, 0] = -1.0  # the observation holds its own copy
    assert hand.landmarks[0, 0] != -1.0
    with pytest.raises(InputError, match=r"shape \(21, 3\), got \(20, 3\)"):
        HandObservation(np.zeros((20, 3)), 0.5)
    with pytest.raises(InputError, match=r"score must be in \[0, 1\], got 1.5"):
        HandObservation(np.zeros((21, 3)), 1.5)
    with pytest.raises(InputError, match="handedness must be 'left', 'right' or None, got 'L'"):
        HandObservation(np.zeros((21, 3)), 0.5, "L")
    bad = np.zeros((21, 3))
    bad[3, 1] = np.nan
    with pytest.raises(InputError, match="u, v must be finite"):
        HandObservation(bad, 0.5)


def test_frame_hands_field() -> None:
    hand = HandObservation(_landmarks(2), 0.7, None)
    assert _frame(0, None).hands is None
    assert _frame(0, []).hands == ()
    assert _frame(0, [hand]).hands == (hand,)
    with pytest.raises(InputError, match=r"hands\[0\] must be a HandObservation, got dict"):
        _frame(0, [{"landmarks": []}])
    with pytest.raises(InputError, match="hands must be a sequence of HandObservation or None, got int"):
        _frame(0, 3)


def test_recorded_hands_replay_exactly_and_follow_the_schema(tmp_path: Path) -> None:
    hands = [
        None,
        (),
        (HandObservation(_landmarks(3), 0.95, "right"), HandObservation(_landmarks(4, nan_z=True), 0.6, None)),
    ]
    path = tmp_path / "hands.mcap"
    with McapRecorder(path) as rec:
        for i, h in enumerate(hands):
            rec.write(_frame(i, h))
    with McapReplay(path) as replay:
        back = list(replay)
    assert back[0].hands is None and back[1].hands == ()
    assert back[2].hands == hands[2]  # float64 through JSON: exact, NaN z as null
    assert np.isnan(back[2].hands[1].landmarks[:, 2]).all()
    schema = json.loads(fmt.json_schema_data(fmt.HAND_SCHEMA))
    with path.open("rb") as fh:
        messages = [(s, c, m) for s, c, m in make_reader(fh).iter_messages(topics=[fmt.HAND_TOPIC])]
    assert len(messages) == 2
    for s, c, m in messages:
        assert (s.name, s.encoding, c.message_encoding) == (fmt.HAND_SCHEMA, "jsonschema", "json")
        jsonschema.validate(json.loads(m.data), schema)
    payload = json.loads(messages[1][2].data)
    assert payload["hands"][0]["palm"] == hands[2][0].palm.tolist()
    assert payload["hands"][1]["landmarks"][0][2] is None and payload["hands"][1]["handedness"] is None


def test_bad_hand_messages_name_the_problem() -> None:
    good = fmt.encode_hands([HandObservation(_landmarks(5), 0.8, "left")])
    assert fmt.decode_hands(good)[0] == HandObservation(_landmarks(5), 0.8, "left")
    with pytest.raises(RecordingError, match="expected an object with a 'hands' list"):
        fmt.decode_hands({"hand": []})
    moved = json.loads(json.dumps(good))
    moved["hands"][0]["palm"][0] += 1.0
    with pytest.raises(RecordingError, match="hand 0 palm .* is not the mean of landmarks 0, 5, 9, 13, 17"):
        fmt.decode_hands(moved)
    short = json.loads(json.dumps(good))
    short["hands"][0]["landmarks"] = short["hands"][0]["landmarks"][:20]
    with pytest.raises(RecordingError, match="hand 0 landmarks must be 21"):
        fmt.decode_hands(short)
    no_score = json.loads(json.dumps(good))
    del no_score["hands"][0]["score"]
    with pytest.raises(RecordingError, match="hand 0 has no 'score'"):
        fmt.decode_hands(no_score)
    wrong = json.loads(json.dumps(good))
    wrong["hands"][0]["handedness"] = "both"
    with pytest.raises(RecordingError, match="hand 0: hand handedness must be"):
        fmt.decode_hands(wrong)
