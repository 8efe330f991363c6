"""Paper 000's multi-modal PF: association, k-means clustering and linking, elite estimate, supervision."""

import math

import numpy as np
import pytest

from fusion_pf.cues.base import Measurement
from fusion_pf.errors import InputError
from fusion_pf.filter.kf import KalmanFilter
from fusion_pf.filter.multi import (
    IndependentTrackers,
    KMeansParticleFilter,
    cluster_spread,
    elite_mean,
    kmeans_clusters,
    link_clusters,
    membership,
    overlap,
)
from fusion_pf.filter.pf import ParticleFilter
from fusion_pf.filter.states import TrackState

NOISE = {"colour": 6.0, "skeleton": 10.0}


def test_kmeans_labels_two_clouds_and_links_them_to_previous_estimates():
    rng = np.random.default_rng(0)
    a, b = np.array([100.0, 100.0]), np.array([160.0, 110.0])
    pts = np.concatenate([a + 6 * rng.standard_normal((150, 2)), b + 6 * rng.standard_normal((150, 2))])
    truth = np.repeat([0, 1], 150)
    labels, cent = kmeans_clusters(pts, np.array([[110.0, 100.0], [150.0, 100.0]]), rng=1)
    assert np.array_equal(labels, truth)
    # reference: the centroids are the clouds' means
    np.testing.assert_allclose(cent, [pts[:150].mean(0), pts[150:].mean(0)])
    # previous estimates listed in the other order: cluster 0 belongs to target 1
    assert link_clusters(cent, np.array([b, a])).tolist() == [1, 0]
    # deterministic: same input, same labels
    assert np.array_equal(kmeans_clusters(pts, cent, rng=2)[0], labels)


def test_elite_mean_spread_membership_overlap_reference_values():
    states = np.array([[0.0, 0, 1, 0], [2.0, 0, 1, 0], [10.0, 10, 0, 0], [20.0, 20, 0, 0]])
    m = np.array([1.0, 3.0, 0.1, 0.1])  # mean 1.05: elite = memberships > 0.84 -> the first two
    np.testing.assert_allclose(elite_mean(states, m), [1.5, 0.0, 1.0, 0.0])  # (1*0 + 3*2) / 4
    # eq. 9: mean of sqrt(squared distance) = mean Euclidean distance
    assert cluster_spread(np.array([[3.0, 0.0], [0.0, 5.0]]), np.zeros(2)) == pytest.approx(4.0)
    assert math.isnan(cluster_spread(np.zeros((0, 2)), np.zeros(2)))
    ms = [Measurement("colour", 6.0, 0.0), Measurement("skeleton", 0.0, 0.0)]
    assert membership(np.zeros(2), ms, NOISE) == pytest.approx(math.exp(-0.5 * (1.0 + 0.0) / 2))
    assert math.isnan(membership(np.zeros(2), [], NOISE))
    o = overlap(np.array([[0.0, 0.0], [20.0, 0.0], [100.0, 0.0], [np.nan, np.nan]]), 20.0)
    assert o[0, 1] == o[1, 0] == pytest.approx(0.5) and o[0, 2] == 0.0 and o[0, 3] == 0.0 and o[0, 0] == 0.0


def crossing(frames=90):
    """Two point targets crossing with a vertical offset of 30 px; one labelled cue each."""
    t = np.arange(frames, dtype=float)
    u_a = 100.0 + 100.0 * t / frames
    u_b = 200.0 - 100.0 * t / frames
    return np.stack([u_a, np.full(frames, 100.0)], 1), np.stack([u_b, np.full(frames, 130.0)], 1)


def run(f, a, b, rng, noise=3.0):
    out = []
    for k in range(len(a)):
        za, zb = a[k] + noise * rng.standard_normal(2), b[k] + noise * rng.standard_normal(2)
        e = f.step(k * 33_000_000, {"a": [Measurement("colour", *za)], "b": [Measurement("colour", *zb)]})
        out.append(e)
    return out


def test_kmeans_pf_keeps_identities_through_a_crossing_and_both_clusters_populated():
    a, b = crossing()
    f = KMeansParticleFilter(["a", "b"], n_particles=200, noise_px=NOISE, rng=0)
    out = run(f, a, b, np.random.default_rng(3))
    ea = np.array([[e.targets["a"].u, e.targets["a"].v] for e in out])
    eb = np.array([[e.targets["b"].u, e.targets["b"].v] for e in out])
    assert np.hypot(*(ea - a).T).max() < 12 and np.hypot(*(eb - b).T).max() < 12
    assert np.bincount(f.labels, minlength=2).min() > 40  # no cluster absorbed the other
    assert all(e.evaluations == 200 for e in out)
    assert {e.targets["a"].state for e in out} <= {TrackState.TRACKING, TrackState.COMBINED, TrackState.UNLABELLED}
    assert f.n_particles == 200 and f.share == 100


def test_supervision_restarts_a_degraded_target_and_adapts_the_noise():
    a, b = crossing(60)
    b = b.copy()
    b[30:] += (0.0, 150.0)  # target b's cue jumps 150 px away (a wrong association, a re-appearance)
    rng = np.random.default_rng(4)
    sup = KMeansParticleFilter(["a", "b"], n_particles=200, noise_px=NOISE, patience=3, rng=0)
    out = run(sup, a, b, rng)
    assert sup.restarts == {"a": 0, "b": 1}
    restart = [k for k, e in enumerate(out) if e.targets["b"].restarted]
    assert restart == [32]  # third consecutive degraded frame

    def error(e, k):
        return np.hypot(e.targets["b"].u - b[k, 0], e.targets["b"].v - b[k, 1])

    assert error(out[33], 33) < 10
    # without supervision the cluster only creeps towards the far cue (random-walk noise of 3 px / frame)
    plain = KMeansParticleFilter(["a", "b"], n_particles=200, noise_px=NOISE, supervision=False, rng=0)
    out_plain = run(plain, a, b, np.random.default_rng(4))
    assert plain.restarts == {"a": 0, "b": 0}
    assert error(out_plain[33], 33) > 50


def test_supervision_noise_far_and_fast_vs_joined():
    """§III-E: separated and fast -> extra noise; great overlap -> conservative; else nominal."""
    f = KMeansParticleFilter(["a", "b"], n_particles=200, noise_px=NOISE, fast_px=4.0, rng=0)
    gains = []
    for k in range(40):
        ua = 50.0 + 8.0 * k if k < 20 else 210.0  # a moves 8 px / frame, then stops
        ub = 400.0 if k < 20 else 212.0  # b waits far away, then joins a
        e = f.step(k, {"a": [Measurement("colour", ua, 100.0)], "b": [Measurement("colour", ub, 100.0)]})
        gains.append(e.targets["a"].noise_gain)
    assert gains[15] == f.fast_gain and gains[-1] == f.conservative_gain
    assert 1.0 in gains[:3]  # the velocity estimate has not built up yet


def test_kmeans_pf_input_errors_and_late_targets():
    with pytest.raises(InputError, match="n_particles"):
        KMeansParticleFilter(["a", "b"], n_particles=3)
    with pytest.raises(InputError, match="distinct"):
        KMeansParticleFilter(["a", "a"])
    f = KMeansParticleFilter(["a", "b"], n_particles=20, noise_px=NOISE, rng=0)
    with pytest.raises(InputError, match="unknown target 'c'"):
        f.step(0, {"c": []})
    e = f.step(1, {"a": [Measurement("colour", 10.0, 10.0)]})
    assert e.targets["a"].state == TrackState.TRACKING and math.isnan(e.targets["b"].u)
    assert e.targets["b"].state == TrackState.UNINITIALISED and e.evaluations == 10
    e = f.step(2, {"b": [Measurement("colour", 90.0, 10.0)]})  # b starts late, a coasts
    assert abs(e.targets["b"].u - 90.0) < 15 and e.evaluations == 10


def test_independent_baselines_pf_and_kf():
    a, b = crossing()
    rng = np.random.default_rng(1)
    for factory, evals in (
        (lambda: ParticleFilter(n_particles=50, noise_px=NOISE, rng=rng), 100),
        (lambda: KalmanFilter(noise_px=NOISE), 0),
    ):
        f = IndependentTrackers(["a", "b"], factory)
        out = run(f, a, b, np.random.default_rng(2))
        ea = np.array([[e.targets["a"].u, e.targets["a"].v] for e in out])
        assert np.hypot(*(ea - a).T)[5:].max() < 12
        assert out[-1].evaluations == evals
        assert np.isfinite(f.predictions()).all()
