"""The guided (locally optimal) proposal and the manoeuvre mixture, against closed forms and Monte Carlo."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion_pf.errors import InputError
from fusion_pf.filter import ParticleFilter
from fusion_pf.filter.pf import QUALITY_FALL
from fusion_pf.filter.proposal import check_manoeuvre, guided_positions, prior_positions
from fusion_pf.frame import Measurement


def _log_n2(d2, var):
    return -d2 / (2 * var) - np.log(2 * np.pi * var)


def test_gaussian_guided_matches_the_kalman_update():
    # one Gaussian component: x | mu, z ~ N(mu + q^2/(q^2+s^2) (z - mu), q^2 s^2/(q^2+s^2))
    n, q, sigma = 200_000, 4.0, 3.0
    mu = np.zeros((2, n))
    mu[0] = 10.0
    vel = np.zeros((2, n))
    log_ev, expected, inlier = guided_positions(mu, vel, q, (0.0, 0.0), (20.0, -5.0), sigma, np.random.default_rng(1))
    assert inlier
    gain = q * q / (q * q + sigma * sigma)
    np.testing.assert_allclose(expected[:, 0], [10.0 + gain * 10.0, -5.0 * gain])
    np.testing.assert_allclose(mu.mean(axis=1), expected[:, 0], atol=0.02)
    np.testing.assert_allclose(mu.std(axis=1), math.sqrt(q * q * sigma * sigma / (q * q + sigma * sigma)), rtol=0.01)
    # evidence: N2(z; mu, (q^2 + s^2) I), the marginal computed independently
    np.testing.assert_allclose(log_ev, _log_n2(10.0**2 + 5.0**2, q * q + sigma * sigma))
    assert not vel.any()  # no manoeuvre component: velocities untouched


def test_robust_guided_draws_from_the_exact_posterior_mixture():
    # posterior of x under prior N(mu, q^2) (+ manoeuvre) and the robust cue, by importance sampling on a grid
    q, sigma, eps, area, prob, m = 3.0, 2.0, 0.1, 1e4, 0.2, 15.0
    z = (12.0, 0.0)
    n = 400_000
    mu = np.zeros((2, n))
    vel = np.zeros((2, n))
    log_ev, expected, _ = guided_positions(
        mu, vel, q, (prob, m), z, sigma, np.random.default_rng(2), outlier=(eps, area)
    )
    # reference: the posterior by 2-D quadrature on a grid, independent of the closed form
    g = np.linspace(-80, 80, 801)
    d = g[1] - g[0]
    xx, yy = np.meshgrid(g, g)
    r2 = xx**2 + yy**2
    p2 = (1 - prob) * np.exp(-r2 / (2 * q * q)) / (2 * math.pi * q * q) + prob * np.exp(-r2 / (2 * (q * q + m * m))) / (
        2 * math.pi * (q * q + m * m)
    )
    lik = (1 - eps) * np.exp(-((xx - z[0]) ** 2 + yy**2) / (2 * sigma * sigma)) / (
        2 * math.pi * sigma * sigma
    ) + eps / area
    post = p2 * lik
    evidence = post.sum() * d * d
    mean_u = (post * xx).sum() * d * d / evidence
    np.testing.assert_allclose(log_ev[0], math.log(evidence), rtol=2e-3)
    np.testing.assert_allclose(expected[0, 0], mean_u, rtol=2e-3)
    assert mu[0].mean() == pytest.approx(mean_u, rel=0.01)
    # particles that took a manoeuvre also changed velocity, in the direction of their innovation
    assert vel[0].mean() > 0.5


def test_outlier_cue_keeps_the_prediction():
    mu = np.zeros((2, 1000))
    vel = np.zeros((2, 1000))
    _, expected, inlier = guided_positions(
        mu, vel, 2.0, (0.0, 0.0), (500.0, 0.0), 1.0, np.random.default_rng(3), outlier=(0.1, 1e6)
    )
    assert not inlier
    np.testing.assert_allclose(expected, 0.0, atol=1e-6)
    assert np.abs(mu).max() < 10.0  # drawn from eq. 4's noise around the prediction


def test_prior_positions_manoeuvre_share_and_coupling():
    n = 100_000
    x = np.zeros((4, n))
    prior_positions(x, 1.0, (0.25, 30.0), np.random.default_rng(4))
    moved = np.abs(x[2]) > 0
    assert moved.mean() == pytest.approx(0.25, abs=0.01)
    # a manoeuvre moves position and velocity by the same a
    np.testing.assert_allclose(x[2, moved].std(), 30.0, rtol=0.02)
    assert np.corrcoef(x[0, moved], x[2, moved])[0, 1] > 0.99


@pytest.mark.parametrize("bad", [(1.0, 5.0), (-0.1, 5.0), (0.1, -1.0), (0.1, math.inf), "x", (0.1,)])
def test_bad_manoeuvre_is_named(bad):
    with pytest.raises(InputError, match="manoeuvre"):
        check_manoeuvre(bad)


def test_guided_pf_follows_a_jump_at_every_seed_the_prior_pf_not():
    # a palm moving 3 px/frame jumps 60 px (1.5 manoeuvre sigmas) and keeps going: the guided PF follows at
    # once whatever the seed; the prior PF only when some of its 100 particles happened to manoeuvre
    def run(proposal, seed):
        pf = ParticleFilter(
            n_particles=100,
            noise_px={"hand": 2.0},
            likelihood="robust",
            proposal=proposal,
            manoeuvre=(0.1, 40.0),
            outlier_area_px2=640 * 400,
            rng=seed,
        )
        errors = []
        for k in range(40):
            u = 100.0 + 3.0 * k + (60.0 if k >= 20 else 0.0)
            est = pf.step(k * 33_000_000, [Measurement("hand", u, 200.0, quality=0.99)])
            if k in (20, 21, 22):
                errors.append(abs(est.u - u))
        return max(errors)

    guided = [run("guided", seed) for seed in range(5)]
    prior = [run("prior", seed) for seed in range(5)]
    assert max(guided) < 2.0
    assert max(prior) > 10.0


def test_guided_pf_is_deterministic_and_rejects_unknown_proposal():
    def run():
        pf = ParticleFilter(n_particles=50, likelihood="robust", proposal="guided", manoeuvre=(0.1, 20.0), rng=7)
        return [pf.step(k, [Measurement("depth", 50.0 + k, 60.0, quality=0.5)]).u for k in range(10)]

    assert run() == run()
    with pytest.raises(InputError, match="proposal"):
        ParticleFilter(proposal="optimal")


def _guided(**kw) -> ParticleFilter:
    """A guided robust PF with manoeuvres, as ``track`` runs it, starting still and 2 px wide."""
    return ParticleFilter(
        likelihood="robust", proposal="guided", manoeuvre=(0.1, 20.0), init_spread_px=2.0, init_velocity_px=0.0, **kw
    )


def _held_at(x0: float, **kw) -> ParticleFilter:
    """A guided robust PF that has tracked a still palm at (x0, 100)."""
    pf = _guided(n_particles=500, noise_px={"depth": 3.0, "skeleton": 6.0}, rng=4, **kw)
    for k in range(5):
        pf.step(k * 33_000_000, [Measurement("skeleton", x0, 100.0, 1.0)])
    return pf


def test_the_anchor_is_a_cue_the_prediction_explains():
    # depth, the more precise cue, jumped 40 px to another blob; the skeleton is where the palm was.
    # Anchored on depth, the manoeuvre component drew the particles to it (estimate ~20 px off); the
    # gate makes the skeleton the anchor and depth only weighs the particles, as an outlier
    pf = _held_at(100.0)
    e = pf.step(5 * 33_000_000, [Measurement("depth", 140.0, 100.0, 1.0), Measurement("skeleton", 101.0, 100.0, 1.0)])
    assert abs(e.u - 100.5) < 3.0
    # when no cue is explained (the palm moved beyond the motion model), the most precise one anchors
    pf = _held_at(100.0)
    e = pf.step(5 * 33_000_000, [Measurement("depth", 160.0, 100.0, 1.0), Measurement("skeleton", 175.0, 100.0, 1.0)])
    assert e.u > 140.0


def _steady(seed: int) -> ParticleFilter:
    """A guided robust PF that followed a palm moving 3 px/frame along u, seen by a precise depth cue and the skeleton."""
    pf = _guided(n_particles=100, noise_px={"depth": 2.0, "skeleton": 2.0}, outlier_area_px2=320 * 200, rng=seed)
    for k in range(10):
        ms = [Measurement("skeleton", 100.0 + 3.0 * k, 100.0, 1.0), Measurement("depth", 100.0 + 3.0 * k, 100.0, 1.0)]
        pf.step(k * 33_000_000, ms)
    return pf


def test_a_cue_that_jumped_off_its_path_outside_the_gate_neither_anchors_nor_weighs():
    # issue 23, gen-31728-near-360 frame 59: the skeleton (broad) anchors, a precise depth cue jumped 42 px off its
    # path to a blob outside the gate; as a weight it drew the step to the particles that had manoeuvred towards
    # it, and the track flipped to that blob for 25 frames. Set aside while the blob stays outside the gate, it is an
    # outlier to every particle: the steps are those without it
    def step(ms, frames=1):
        pf = _steady(3)
        pf.set_noise("skeleton", 40.0)
        for k in range(10, 10 + frames):
            e = pf.step(k * 33_000_000, [m(k) for m in ms])
        return e.u, e.v, pf.particles.copy()

    def skeleton(k):
        return Measurement("skeleton", 100.0 + 3.0 * k + 10.0, 100.0, 1.0)

    def blob(k):
        return Measurement("depth", 100.0 + 3.0 * k + 45.0, 100.0, 1.0)

    alone = step([skeleton], frames=3)
    assert step([blob, skeleton], frames=3)[:2] == alone[:2]
    assert np.array_equal(step([blob, skeleton], frames=3)[2], alone[2])

    # a cue that leaves the track without a jump (its second difference 6 px: the track may be the one that is off)
    # still weighs the particles
    def palm(k):
        return Measurement("depth", 100.0 + 3.0 * k + 6.0 * (k - 9), 100.0, 1.0)

    assert step([palm, skeleton], frames=3)[0] > alone[0] + 5.0


def test_the_gate_holds_the_bulk_of_the_prediction_not_its_manoeuvres():
    # issue 23, gen-31728-near-360 frames 59-60: the skeleton turned broad (40 px) and 20 px off, a depth blob 40 px
    # off the palm. The broad anchor prunes none of the particles that drew a manoeuvre (10 %, 20 px/frame of
    # velocity), so their weighted spread of the next prediction was 5-8 times its bulk's and the blob entered the
    # gate at the next frame: anchored there, 30-70 px off at 6 of 10 seeds. It jumped there and the bulk of the
    # prediction cannot explain it: set aside, the estimate stays within 5 px
    def second_frame_error(seed):
        pf = _steady(seed)
        pf.set_noise("skeleton", 40.0)
        for k, u in ((10, 130.0), (11, 133.0)):
            e = pf.step(
                k * 33_000_000,
                [Measurement("depth", u + 40.0, 100.0, 1.0), Measurement("skeleton", u + 20.0, 100.0, 1.0)],
            )
        return abs(e.u - 133.0)

    assert max(second_frame_error(seed) for seed in range(10)) < 5.0


def test_two_cues_that_agree_outside_the_gate_move_the_track():
    # issue 23, gen-31615-far-560 frames 114-118: a colour blob on the forearm (broad, explained) had led the track
    # 15-25 px off, depth (0.7 px) and the skeleton (2.4 px) on the palm and agreeing; two cues agreeing where the
    # prediction cannot explain them say the track is what is off: they count (and the more precise anchors)
    def last_error(seed):
        pf = ParticleFilter(
            n_particles=100,
            likelihood="robust",
            proposal="guided",
            manoeuvre=(0.1, 20.0),
            noise_px={"colour": 40.0, "depth": 1.0, "skeleton": 2.0},
            init_spread_px=2.0,
            init_velocity_px=0.0,
            outlier_area_px2=320 * 200,
            rng=seed,
        )
        for k in range(12):
            palm = 100.0 + 3.0 * k + (25.0 if k >= 10 else 0.0)
            track = 100.0 + 3.0 * k
            ms = [Measurement("colour", track, 100.0, 1.0)]
            ms += [Measurement("depth", palm, 100.0, 1.0), Measurement("skeleton", palm + 1.0, 100.0, 1.0)]
            e = pf.step(k * 33_000_000, ms)
        return abs(e.u - palm)

    assert max(last_error(seed) for seed in range(5)) < 3.0


def test_predicted_is_the_weighted_mean_and_spread_of_p_plus_v():
    pf = _held_at(100.0)
    assert ParticleFilter(rng=1).predicted(0) is None  # nothing to predict from
    x, w = pf.particles.copy(), pf.weights.copy()
    u, v, var = pf.predicted(5 * 33_000_000)
    # independent: numpy's weighted average and covariance of p + v (one frame step)
    pos = x[:, :2] + x[:, 2:]
    mean = np.average(pos, axis=0, weights=w)
    cov = np.cov(pos.T, aweights=w, bias=True)
    np.testing.assert_allclose([u, v], mean, atol=1e-9)
    assert var == pytest.approx(np.trace(cov) / 2.0, rel=1e-9)


def _turning_far_hand(seed, white=None, flip_at=None):
    # issue 23, gen-30907-far-1280 (frames 35-52): the palm turns round, its velocity going from -18 to +11 px/frame
    # in 20 frames (up to 2 px/frame^2), seen by a 0.2 px depth cue fused at its 2.5 px floor, with eq. 4's noise at
    # the pipeline's learned scale there (1.36); the RMS error of the estimate from frame 20 on
    pf = ParticleFilter(
        n_particles=100,
        noise_px={"depth": 2.5},
        likelihood="robust",
        proposal="guided",
        process_noise=(1.36 * 3.0, 1.36 * 1.0),
        manoeuvre=(0.1, 74.0),
        outlier_area_px2=1280 * 720,
        rng=seed,
    )
    if white is not None:
        pf.set_white_noise("depth", white)
    rng = np.random.default_rng(seed)
    errors, estimates = [], []
    for k in range(120):
        u, v = 640.0 + 162.0 * math.sin(0.111 * k), 360.0 + 97.0 * math.cos(0.089 * k)
        jump = 150.0 if flip_at is not None and k in flip_at else 0.0
        m = Measurement("depth", u + jump + 0.2 * rng.standard_normal(), v + 0.2 * rng.standard_normal(), quality=0.9)
        est = pf.step(k * 33_333_333, [m])
        estimates.append((est.u, est.v))
        if k >= 20 and jump == 0.0:
            errors.append(math.hypot(est.u - u, est.v - v))
    return math.sqrt(float(np.mean(np.square(errors)))), estimates


def test_a_precise_anchor_measures_the_velocity_of_a_far_hand_turning_round():
    # the guided proposal moves the particles' positions to the cue, their velocities only by eq. 4's walk and
    # selection: they lagged 6-12 px/frame and the estimate, pulled towards that prediction, was 1.2-1.4 px RMS
    # off (seeds 0-4). The cue's displacement, with its 0.2 px white noise, measures the velocity: 0.52-0.57 px.
    assert min(_turning_far_hand(seed)[0] for seed in range(5)) > 1.1
    assert max(_turning_far_hand(seed, white=0.2)[0] for seed in range(5)) < 0.8


def test_the_velocity_measurement_needs_a_precise_consistent_anchor():
    # a white noise of 1 px (sqrt(2) px of displacement noise, above half the 1.36 px/frame walk): eq. 4 alone
    assert _turning_far_hand(3, white=1.0)[1] == _turning_far_hand(3)[1]
    # a cue that jumps 150 px to another blob for two frames is not explained by the prediction: no velocity is
    # measured across the jump, and the track is as good as without the jump
    clean = _turning_far_hand(3, white=0.2)[0]
    assert _turning_far_hand(3, white=0.2, flip_at={50, 51})[0] < 1.2 * clean


def test_a_falling_quality_stops_the_velocity_measurement():
    # a blob whose confidence falls by more than QUALITY_FALL in a step is changing shape (dragged onto the forearm
    # in issue 23's far scenes): its displacement measures nothing, the step is the one without a white noise
    def follow():
        pf = ParticleFilter(n_particles=100, noise_px={"depth": 2.5}, likelihood="robust", proposal="guided", rng=1)
        pf.set_white_noise("depth", 0.2)
        for k in range(10):
            pf.step(k * 33_333_333, [Measurement("depth", 100.0 + 4.0 * k, 100.0, quality=0.9)])
        return pf

    def last_step(pf, quality):
        e = pf.step(10 * 33_333_333, [Measurement("depth", 141.0, 100.0, quality=quality)])
        return e.u, e.v, pf.particles[:, 2:].copy()

    fall = 0.9 - QUALITY_FALL - 0.01
    unmeasured = follow()
    unmeasured.set_white_noise("depth", None)
    u, v, vel = last_step(follow(), fall)
    u0, v0, vel0 = last_step(unmeasured, fall)
    assert (u, v) == (u0, v0) and np.array_equal(vel, vel0)
    # a steady quality: the velocities are drawn given the 5 px/frame displacement
    assert abs(last_step(follow(), 0.9 - QUALITY_FALL + 0.01)[2][:, 0].mean() - 5.0) < 0.3


def test_white_noise_must_be_a_number():
    pf = ParticleFilter(n_particles=10, rng=0)
    with pytest.raises(InputError, match="white noise"):
        pf.set_white_noise("depth", -1.0)
