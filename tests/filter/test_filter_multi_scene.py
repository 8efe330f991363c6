"""End to end on the two-hand synthetic scene: skin blobs + skeleton joints, k-means PF with supervision."""

import numpy as np
import pytest

from drivers.synth import SynthSource
from fusion_pf.cues.skin import RgbRuleSkin, SkinCue
from fusion_pf.filter.kf import KalmanFilter
from fusion_pf.filter.multi import IndependentTrackers, KMeansParticleFilter
from fusion_pf.multitarget import frame_inputs, identity_swaps, label_blobs, rmse, run_tracker, state_counts

TARGETS = ("right_hand", "left_hand", "head")
NOISE = {"skin_rgb": 8.0, "skeleton": 6.0}


@pytest.fixture(scope="module")
def inputs():
    with SynthSource(frames=330, size=(320, 200), background_frames=30, hands=2, seed=0) as src:
        return frame_inputs(iter(src), TARGETS, SkinCue(RgbRuleSkin(), min_area=30))


def test_kmeans_pf_with_supervision_keeps_both_hands_through_joins_and_the_crossing(inputs):
    assert len(inputs) == 300 and all(len(fi.blobs) >= 2 for fi in inputs)
    run = run_tracker(KMeansParticleFilter(TARGETS, n_particles=300, noise_px=NOISE, rng=0), inputs)
    assert identity_swaps(run, inputs, ("right_hand", "left_hand"), 25.0) == 0
    for t in ("right_hand", "left_hand"):
        assert rmse(run, inputs, t) < 6.0
        counts = state_counts(run, t)
        assert counts["lost"] == counts["uninitialised"] == 0
        assert counts["combined"] > 90  # two joins of >= 40 frames, the crossing
        assert counts["tracking"] > 90
    assert (run.evaluations == 300).all()


def test_identity_swaps_metric_counts_a_forced_swap(inputs):
    run = run_tracker(IndependentTrackers(TARGETS, lambda: KalmanFilter(noise_px=NOISE)), inputs)
    assert identity_swaps(run, inputs, ("right_hand", "left_hand"), 25.0) == 0
    right, left = run.estimates["right_hand"], run.estimates["left_hand"]
    right[150:], left[150:] = left[150:].copy(), right[150:].copy()
    assert identity_swaps(run, inputs, ("right_hand", "left_hand"), 25.0) == 1
    assert rmse(run, inputs, "right_hand") > 20


def test_layout_labels():
    # the painting (top right), the face, two hands below
    blobs = np.array([[231.0, 31.0], [179.0, 50.0], [149.0, 131.0], [207.0, 131.0]])
    assert label_blobs(blobs, TARGETS) == {"right_hand": 2, "left_hand": 3, "head": 1}
    assert label_blobs(blobs[:1], TARGETS) == {}
