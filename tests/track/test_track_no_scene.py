"""Issue 22: a recording without empty-scene frames (the person in view from the first frame).

The background is then learnt from the stream and holds the person, so the
paper's colour cue (background subtraction) is replaced by the skin rule in the
automatic cue choice, for one target and for several; an empty scene keeps the
paper's cues.
"""

from __future__ import annotations

import pytest

from drivers.synth import SynthSource
from fusion_pf.cues.background import BackgroundModel
from fusion_pf.experiments.sweep import sweep_sources
from fusion_pf.pipeline import TrackConfig, track

HANDS = ("right_hand", "left_hand")
PAPER = ("colour", "depth", "skeleton")
NO_SCENE = ("skin_rgb", "depth", "skeleton")


def _frames(background_frames: int) -> list:
    with SynthSource(
        frames=background_frames + 6, seed=4, size=(160, 100), hands=2, background_frames=background_frames
    ) as src:
        return list(src)


def _sources(results) -> set[tuple[str, ...]]:
    """The cue sources of every tracked target row."""
    out = set()
    for r in results:
        if not r.background:
            out.update(tuple(t.cues) for t in (r.targets or {"": r}).values())
    return out


@pytest.mark.parametrize("targets", [None, HANDS])
def test_without_an_empty_scene_the_skin_rule_replaces_the_colour_cue(targets):
    frames = _frames(0)
    config = TrackConfig(targets=targets, background_k=3)
    assert _sources(track(frames, config)) == {NO_SCENE}
    assert sweep_sources(frames, config) == NO_SCENE


@pytest.mark.parametrize("targets", [None, HANDS])
def test_an_empty_scene_keeps_the_papers_cues(targets):
    config = TrackConfig(targets=targets)
    frames = _frames(2)
    assert _sources(track(frames, config)) == {PAPER}
    assert sweep_sources(frames, config) == PAPER
    # the caller's empty-scene model (``--background``) counts as one too
    people = frames[2:]
    model = BackgroundModel.from_frames(frames[:2])
    assert _sources(track(people, config, background=model)) == {PAPER}
    assert sweep_sources(people, config, model) == PAPER


def test_cues_given_by_the_user_are_kept_without_an_empty_scene():
    config = TrackConfig(targets=HANDS, cues=PAPER, background_k=3)
    assert _sources(track(_frames(0), config)) == {PAPER}
