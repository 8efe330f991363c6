"""The guided (locally optimal) proposal and the manoeuvre mixture, against closed forms and Monte Carlo."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fusion_pf.errors import InputError
from fusion_pf.filter import ParticleFilter
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


def _held_at(x0: float, **kw) -> ParticleFilter:
    """A guided robust PF with manoeuvres (as ``track`` runs it) that has tracked a still palm at (x0, 100)."""
    pf = ParticleFilter(
        n_particles=500,
        likelihood="robust",
        proposal="guided",
        manoeuvre=(0.1, 20.0),
        noise_px={"depth": 3.0, "skeleton": 6.0},
        init_spread_px=2.0,
        init_velocity_px=0.0,
        rng=4,
        **kw,
    )
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
