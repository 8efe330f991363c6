"""Shared synthetic scene of the tracking tests (rendered once per session)."""

from __future__ import annotations

import pytest

from drivers.synth import SynthSource

#: Small frames keep the tests fast; the cues and the filter work at any size.
TRACK_TEST_SIZE = (320, 200)


@pytest.fixture(scope="session")
def scene_frames():
    """220 frames of synthetic scene seed 3 at 320 x 200 (20 background frames, ~30 % of the rest occluded)."""
    with SynthSource(frames=220, seed=3, size=TRACK_TEST_SIZE, background_frames=20) as src:
        return list(src)
