"""Every JSON message of a ``track`` output validates against the JSON Schema its MCAP schema record holds.

The messages are read with the ``mcap`` library and checked with ``jsonschema`` (validators
neither written here): one palm its cues never find (u, v null in every frame) and two targets
(per-target estimates under ``targets``).
"""

from __future__ import annotations

import json

import jsonschema
import pytest
from mcap.reader import make_reader


def _json_messages(path):
    with open(path, "rb") as fh:
        for schema, channel, message in make_reader(fh).iter_messages():
            if channel.message_encoding == "json":
                assert schema is not None and schema.encoding == "jsonschema", channel.topic
                yield channel.topic, json.loads(schema.data), json.loads(message.data)


@pytest.mark.parametrize(
    "source, extra",
    [
        ("synth:seed=3,frames=20,size=160x100", ["--cues", "hand,depth"]),
        ("synth:seed=1,frames=40,size=320x200,hands=2", ["--targets", "right_hand,left_hand"]),
    ],
)
def test_every_tracker_json_message_matches_its_schema(fusion_pf, tmp_path, source, extra):
    out = tmp_path / "o.mcap"
    r = fusion_pf("track", source, "-o", out, "--no-progress", *extra)
    assert r.returncode == 0, r.stderr
    seen: dict[str, int] = {}
    nulls = 0
    for topic, schema, doc in _json_messages(out):
        jsonschema.validators.validator_for(schema)(schema).validate(doc)
        seen[topic] = seen.get(topic, 0) + 1
        nulls += topic == "/tracker/estimate" and (doc.get("u", 0) is None or "targets" in doc)
    assert seen["/tracker/estimate"] == seen["/tracker/cues"] > 0
    assert nulls > 0  # the cases the schema once refused are among the checked messages
