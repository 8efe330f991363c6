"""TrackConfig validation and defaults."""

from __future__ import annotations

import pytest

from fusion_pf.errors import InputError
from fusion_pf.pipeline import TrackConfig


def test_likelihood_default_follows_the_filter():
    assert TrackConfig().likelihood == "robust"
    assert TrackConfig(filter="kf").likelihood == "gaussian"
    assert TrackConfig(likelihood="gaussian").likelihood == "gaussian"


def test_partial_noise_keeps_the_other_defaults():
    default = TrackConfig().noise_px
    cfg = TrackConfig(noise_px={"depth": 3})
    assert cfg.noise_px == {**default, "depth": 3.0}


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"filter": "kf", "likelihood": "robust"}, "Gaussian only"),
        ({"filter": "ekf"}, "filter (--filter) must be one of pf, kf, sspf, got 'ekf'"),
        ({"particles": 0}, "particles (--particles) must be an integer in [1, 100000], got 0"),
        ({"particles": 2.5}, "particles (--particles) must be an integer in [1, 100000], got 2.5"),
        ({"joint": ""}, "joint (--joint) must be a non-empty string"),
        ({"noise_px": {"colour": -1}}, "noise_px (--noise): colour must be a number in [0.01, 10000] px, got -1"),
        ({"process_noise": (1.0,)}, "process_noise (--process-noise) must be a pair POS,VEL"),
        ({"sources": ("colour", "colour")}, "sources (--sources): cues must be distinct names"),
        ({"sources": ()}, "sources (--sources): cues must be distinct names"),
        ({"cue_noise_px": {"sonar": 1}}, "cue_noise_px (--cue-noise) has unknown source(s) sonar"),
        ({"roi_prior": "hand"}, "roi_prior (--roi-prior) must be one of auto, filter, skeleton, got 'hand'"),
        ({"prior_confidence": 1.5}, "prior_confidence (--prior-confidence) must be a number in [0, 1], got 1.5"),
        ({"roi_half_size": 0}, "roi_half_size (--roi-half-size) must be an integer in [1, 2000], got 0"),
        ({"background_k": 0}, "background_k (--background-k) must be an integer in [1, 10000], got 0"),
        ({"depth_radius": 51}, "depth_radius (--depth-radius) must be an integer in [0, 50], got 51"),
        ({"seed": -3}, "seed (--seed) must be an integer in [0,"),
    ],
)
def test_bad_values_name_the_value_and_the_range(kwargs, message):
    with pytest.raises(InputError) as info:
        TrackConfig(**kwargs)
    assert message in str(info.value) and "\n" not in str(info.value)
