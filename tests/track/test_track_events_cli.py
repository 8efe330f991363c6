"""The scripted events scene end to end: ``synth --script events``, ``track --targets``, ``score``.

Every true event (two joins and separations, a ball picked up and passed
between the hands, a hand at the head) is reported within 5 frames and
nothing else is; the ``/tracker/events`` and ``/ground_truth/events`` messages
validate against the JSON Schema of their MCAP schema records (``jsonschema``),
and the CSV's ``events`` column holds the same events.
"""

from __future__ import annotations

import csv
import json

import jsonschema
import pytest
from mcap.reader import make_reader

from drivers.synth import SynthSource
from fusion_pf.errors import InputError
from fusion_pf.score.events import match_events, parse_events_cell

SCENE = ("--hands", "2", "--script", "events", "--frames", "300", "--background-frames", "30", "--size", "160x100")


def _topic(path, topic):
    """``(schema, message)`` of every message on ``topic``, schema from its MCAP schema record."""
    out = []
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages(topics=[topic]):
            assert schema is not None and schema.encoding == "jsonschema" and channel.message_encoding == "json"
            out.append((json.loads(schema.data), json.loads(message.data)))
    return out


@pytest.fixture(scope="module")
def tracked(tmp_path_factory, fusion_pf):
    d = tmp_path_factory.mktemp("events")
    rec, out, table = d / "scene.mcap", d / "tracked.mcap", d / "tracked.csv"
    r = fusion_pf("synth", rec, *SCENE, "--seed", "0", "--no-progress")
    assert r.returncode == 0, r.stderr
    r = fusion_pf("track", rec, "-o", out, "--csv", table, "--targets", "right_hand,left_hand,head", "--no-progress")
    assert r.returncode == 0, r.stderr
    return rec, out, table, r.stderr


def test_every_scripted_event_is_reported_within_five_frames_and_nothing_else(tracked):
    rec, out, table, stderr = tracked
    truth = _topic(rec, "/ground_truth/events")
    reported = _topic(out, "/tracker/events")
    for schema, doc in truth + reported:
        jsonschema.validators.validator_for(schema)(schema).validate(doc)
    assert [m["event"] for _, m in truth] == [
        "pick_up",
        "join",
        "separate",
        "exchange",
        "contact",
        "join",
        "separate",
    ]
    score = match_events([m for _, m in truth], [m for _, m in reported])
    assert score.perfect, score.summary()
    assert all(abs(o) <= 5 for _, _, o in score.matched)
    assert "events: 1 contact, 1 exchange, 2 join, 1 pick_up, 2 separate" in stderr
    # the CSV column holds the same events, in the frames of the messages
    with open(table, newline="") as fh:
        rows = list(csv.DictReader(fh))
    from_csv = [e for row in rows for e in parse_events_cell(int(row["frame"]), row["events"])]
    assert [(e["frame"], e["event"], e["targets"]) for e in from_csv] == [
        (m["frame"], m["event"], m["targets"]) for _, m in reported
    ]
    assert sum(row["events"] == "" for row in rows) == len(rows) - len(reported)


def test_score_matches_the_tracked_events_to_the_truth(tracked, fusion_pf):
    rec, out, table, _ = tracked
    r = fusion_pf("score", table, "--ground-truth", rec)  # the CSV's events column
    assert r.returncode == 0, r.stderr
    assert "Events (within 5 frames of /ground_truth/events): 7 matched" in r.stdout
    assert "0 missed, 0 false" in r.stdout
    r = fusion_pf("score", out, "--ground-truth", rec, "--json")  # the /tracker/events topic
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["events"]["perfect"] is True and len(doc["events"]["matched"]) == 7


def test_true_events_follow_the_seed_and_the_script_needs_two_hands(fusion_pf, tmp_path):
    a = SynthSource(hands=2, script="events", seed=5, frames=360, size=(64, 40)).true_events()
    b = SynthSource(hands=2, script="events", seed=5, frames=360, size=(64, 40)).true_events()
    c = SynthSource(hands=2, script="events", seed=6, frames=360, size=(64, 40)).true_events()
    assert a == b and [e["frame"] for e in a] != [e["frame"] for e in c]
    assert SynthSource(hands=2, seed=5, frames=10, size=(64, 40)).true_events() == []
    with pytest.raises(InputError, match="needs hands 2"):
        SynthSource(script="events")
    with pytest.raises(InputError, match="script must be one of none, events"):
        SynthSource(hands=2, script="dance")
    r = fusion_pf("synth", tmp_path / "x.mcap", "--script", "events")
    assert r.returncode == 2 and "--script events is a two-hand scene; it needs --hands 2" in r.stderr
    assert "Traceback" not in r.stderr


def test_one_palm_leaving_and_coming_back_disappears_and_reappears_once(tmp_path, capsys):
    from .test_track_faults import disc_frames, run_track, write

    n = 70
    centres = [None if 20 <= i < 40 else (80.0, 60.0) for i in range(n)]  # gone in frames 20-39
    rec = write(tmp_path / "away.mcap", disc_frames(n, centres))
    code, table, err = run_track(tmp_path, capsys, rec, "--cues", "depth")
    assert code == 0, err
    events = [(int(r["frame"]), r["events"]) for r in table if r["events"]]
    assert [e for _, e in events] == ["disappear:right_hand", "reappear:right_hand"], events
    (lost, _), (back, _) = events
    # lost once the cue has been silent for the supervision's 10 frames (+1 to confirm); back within 5 frames
    assert 20 <= lost <= 20 + 10 + 1 and 40 <= back <= 45
    assert "events: 1 disappear, 1 reappear" in err
