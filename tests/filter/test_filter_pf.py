"""The data-fusion particle filter: equations, fusion accuracy, robustness, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import multivariate_normal

from fusion_pf.cues.base import Measurement
from fusion_pf.errors import InputError
from fusion_pf.filter import Estimate, KalmanFilter, ParticleFilter
from fusion_pf.filter.estimate import map_estimate, robust_mean, weighted_covariance, weighted_mean
from fusion_pf.filter.kernel import stream
from fusion_pf.filter.likelihood import JointLikelihood, robust_loglik
from fusion_pf.filter.scenario import SCENARIO_NOISE_PX, rmse, run_tracker, scripted_scenario
from fusion_pf.filter.sspf import ScatterSearchPF

NOISE = {"colour": 6.0, "depth": 10.0, "skeleton": 15.0}
MS = [Measurement("colour", 320.0, 200.0), Measurement("depth", 324.0, 197.0), Measurement("skeleton", 310.0, 210.0)]


def test_step_reproduces_equations_3_to_7_by_hand(stream_normals):
    """Predict (eq. 4) and weight update (eqs. 3, 5-7) recomputed independently, to 1e-12."""
    rng = np.random.default_rng(11)
    pf = ParticleFilter(
        noise_px=SCENARIO_NOISE_PX, n_particles=257, process_noise=(2.0, 0.5), ess_threshold=0.0, rng=rng
    )
    pf.step(0, MS)
    x0 = pf.particles.copy()
    logw0 = pf.log_weights.copy()
    # the first prediction seeds the kernels' normal stream from the filter's generator
    twin = np.random.Generator(np.random.PCG64())
    twin.bit_generator.state = rng.bit_generator.state
    noise = stream_normals(stream(twin), (4, 257)).T.astype(np.float64)
    frame = [MS[0], MS[2]]  # depth missing this frame: it must contribute nothing
    est = pf.step(1, frame)
    m = np.array([[1, 0, 1, 0], [0, 1, 0, 1], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    x1 = x0 @ m.T + noise * np.array([2.0, 2.0, 0.5, 0.5])
    np.testing.assert_allclose(pf.particles, x1, rtol=0, atol=1e-12)
    ll = sum(-((x1[:, 0] - z.u) ** 2 + (x1[:, 1] - z.v) ** 2) / (2 * NOISE[z.source] ** 2) for z in frame)
    logw = logw0 + ll
    logw -= np.logaddexp.reduce(logw)
    np.testing.assert_allclose(pf.log_weights, logw, rtol=0, atol=1e-9)
    w = np.exp(logw)
    assert est.ess == pytest.approx(1.0 / np.sum(w**2), rel=1e-9)
    assert not est.resampled
    assert np.exp(pf.log_weights).sum() == pytest.approx(1.0, abs=1e-12)


def test_frame_without_measurements_only_predicts():
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=300, rng=1)
    pf.step(0, MS)
    logw = pf.log_weights.copy()
    est = pf.step(5, [])
    np.testing.assert_array_equal(pf.log_weights, logw)
    assert isinstance(est, Estimate) and est.timestamp_ns == 5


def test_not_initialised_until_measurement_or_prior():
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=50, rng=0)
    assert pf.step(0, []) is None
    est = pf.step(1, MS)
    fused = np.array([[m.u, m.v] for m in MS]).T @ (w := np.array([1 / 36, 1 / 100, 1 / 225])) / w.sum()
    assert math.hypot(est.u - fused[0], est.v - fused[1]) < 10.0
    with_prior = ParticleFilter(
        noise_px=SCENARIO_NOISE_PX, n_particles=2000, prior=(100.0, 50.0), init_spread_px=5.0, rng=0
    )
    est = with_prior.step(0, [])
    assert est is not None and abs(est.u - 100) < 2 and abs(est.v - 50) < 2


@pytest.mark.parametrize(
    "make",
    [
        lambda **kw: ParticleFilter(n_particles=500, rng=0, **kw),
        lambda **kw: KalmanFilter(**kw),
        lambda **kw: ScatterSearchPF(n_particles=50, rng=0, **kw),
    ],
    ids=["pf", "kf", "sspf"],
)
def test_reset_without_a_prior_forgets_every_earlier_one(make):
    """The Tracker.reset contract: a reset without a prior waits for the next measurement, whatever prior the
    constructor or an earlier reset gave (a kept prior restarted a lost track where it had started before)."""
    f = make(noise_px=SCENARIO_NOISE_PX, prior=(100.0, 50.0), init_spread_px=2.0)
    assert f.initialised  # the constructor's prior
    f.reset(prior=(10.0, 20.0))
    est = f.step(0, [])
    assert f.initialised and math.hypot(est.u - 10.0, est.v - 20.0) < 2.0
    f.reset()
    assert not f.initialised and f.step(1, []) is None
    est = f.step(2, [Measurement("colour", 200.0, 150.0)])
    assert math.hypot(est.u - 200.0, est.v - 150.0) < 2.0  # started at the measurement


def test_shapes_and_estimate_fields():
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=123, rng=4)
    est = pf.step(0, MS)
    assert pf.particles.shape == (123, 4) and pf.log_weights.shape == (123,)
    assert est.particles.shape == (123, 2) and est.n_particles == 123
    assert est.cov.shape == (2, 2) and np.allclose(est.cov, est.cov.T) and np.all(np.linalg.eigvalsh(est.cov) > 0)
    assert 1.0 <= est.ess <= 123.0
    assert (
        ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=10, keep_particles=False, rng=0).step(0, MS).particles
        is None
    )


def test_resampling_happens_exactly_when_ess_below_two_thirds():
    sc = scripted_scenario(60, rng=5)
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=400, rng=5)
    seen = set()
    for k, ts in enumerate(sc.timestamps_ns):
        est = pf.step(int(ts), sc.frame(k))
        assert est.resampled == (est.ess < 2 / 3 * 400)
        if est.resampled:
            assert np.all(pf.log_weights == -math.log(400))
        seen.add(est.resampled)
    assert seen == {True, False}


def test_same_seed_same_output_different_seed_different():
    sc = scripted_scenario(40, rng=2)
    a = run_tracker(ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=200, rng=9), sc)
    b = run_tracker(ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=200, rng=9), sc)
    c = run_tracker(ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=200, rng=10), sc)
    assert np.array_equal(a, b) and not np.array_equal(a, c)


@pytest.mark.parametrize("resampler", ["residual", "multinomial", "stratified", "systematic"])
def test_fused_rmse_below_best_single_source(resampler):
    """Paper 003's claim on a scripted path with known noise (sigma 6 / 10 / 15 px)."""
    sc = scripted_scenario(200, noise_px=NOISE, rng=21)
    settle = slice(10, None)
    fused = rmse(
        run_tracker(ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=500, resampler=resampler, rng=1), sc),
        sc.truth,
        settle,
    )
    raw = {s: rmse(z, sc.truth, settle) for s, z in sc.measurements.items()}
    single = {
        s: rmse(
            run_tracker(
                ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=500, resampler=resampler, rng=1), sc, {s}
            ),
            sc.truth,
            settle,
        )
        for s in NOISE
    }
    best = min(min(raw.values()), min(single.values()))
    assert fused < 0.95 * best, (fused, raw, single)


def test_missing_sources_and_dropouts_do_not_break_fusion():
    sc = scripted_scenario(200, dropout=0.3, rng=8)
    est = run_tracker(ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=500, rng=3), sc)
    assert np.isfinite(est).all()
    assert rmse(est, sc.truth, slice(10, None)) < rmse(sc.measurements["colour"], sc.truth)


@pytest.mark.parametrize("liar", ["colour", "skeleton"])
def test_robust_likelihood_resists_a_lying_source(liar):
    """One source offset by 60 px for 20 frames: the robust mixture stays closer to the truth."""
    sc = scripted_scenario(160, lie_source=liar, lie_start=80, lie_frames=20, rng=3)
    err = {
        lik: rmse(
            run_tracker(ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=1000, likelihood=lik, rng=0), sc),
            sc.truth,
            sc.lie_frames,
        )
        for lik in ("gaussian", "robust")
    }
    assert err["robust"] < err["gaussian"], err
    if liar == "colour":  # the tightest source lying drags the Gaussian filter most of the 60 px
        assert err["gaussian"] > 25.0 and err["robust"] < 12.0, err


def test_low_quality_widens_robust_likelihood():
    """A cue 8 px off pulls by its precision: sigma 10 at quality 1, ~31.6 at quality 0.1."""
    est = {}
    for q in (1.0, 0.1):
        pf = ParticleFilter(
            noise_px=SCENARIO_NOISE_PX,
            n_particles=4000,
            likelihood="robust",
            estimator="weighted_mean",
            ess_threshold=0.0,
            rng=0,
        )
        pf.step(0, [Measurement("colour", 300.0, 200.0)])
        est[q] = pf.step(1, [Measurement("depth", 308.0, 200.0, quality=q)]).u
    assert est[1.0] > est[0.1] + 1.0, est


def test_robust_loglik_matches_scipy_mixture():
    rng = np.random.default_rng(0)
    pts = rng.normal(300.0, 40.0, (50, 2))
    z, sigma, eps, area = np.array([310.0, 290.0]), 7.0, 0.2, 640.0 * 400.0
    d2 = np.sum((pts - z) ** 2, axis=1)
    expected = np.log((1 - eps) * multivariate_normal(z, sigma**2 * np.eye(2)).pdf(pts) + eps / area)
    np.testing.assert_allclose(robust_loglik(d2, sigma, eps, area), expected, rtol=1e-12)


def test_underflow_reinitialises_instead_of_nan():
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=300, rng=0)
    pf.step(0, MS)
    far = [Measurement("colour", 1.0e5, -4.0e4), Measurement("skeleton", 1.0e5 + 5, -4.0e4)]
    est = pf.step(1, far)
    assert pf.reinitialisations == 1
    assert np.isfinite(pf.log_weights).all() and np.isfinite([est.u, est.v]).all()
    assert math.hypot(est.u - 1.0e5, est.v + 4.0e4) < 25.0


def test_robust_filter_reacquires_a_target_that_jumped_but_ignores_one_liar():
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=500, likelihood="robust", rng=0)
    for k in range(10):
        pf.step(k, MS)
    liar = [MS[0], MS[1], Measurement("skeleton", 600.0, 200.0)]
    est = pf.step(10, liar)
    assert pf.reinitialisations == 0 and math.hypot(est.u - 321, est.v - 199) < 8.0
    jumped = [Measurement(m.source, m.u + 300.0, m.v) for m in MS]
    est = pf.step(11, jumped)
    assert pf.reinitialisations == 1 and math.hypot(est.u - 621, est.v - 199) < 15.0


def test_fused_gaussian_equals_product_of_source_gaussians():
    """The one-pass joint (Gaussian around the precision-weighted mean) equals eq. 7 summed per source."""
    like = JointLikelihood(NOISE)
    rng = np.random.default_rng(1)
    pos = rng.normal(300.0, 30.0, (400, 2))
    joint, lost = like(pos, MS, np.empty(400))
    ll = sum(-np.sum((pos - [m.u, m.v]) ** 2, axis=1) / (2 * NOISE[m.source] ** 2) for m in MS)
    np.testing.assert_allclose(joint, ll - ll.max(), rtol=0, atol=1e-9)
    assert not lost and joint.max() == 0.0
    far = [Measurement("colour", 300.0 + 500.0, 300.0)]
    assert like(pos, far, np.empty(400))[1]  # -(> 350 px)^2 / 72 < log(tiny): lost


def test_estimators_by_hand():
    pos = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [4.0, 4.0]])
    w = np.array([0.1, 0.2, 0.3, 0.4])
    np.testing.assert_allclose(weighted_mean(pos, w), [2.0 + 1.6, 3.0 + 1.6])
    np.testing.assert_allclose(map_estimate(pos, w), [4.0, 4.0])
    # top half: particles 2 and 3, weights 0.3 / 0.4 renormalised
    np.testing.assert_allclose(robust_mean(pos, w, 0.5), [(0.4 * 4) / 0.7, (0.3 * 10 + 0.4 * 4) / 0.7])
    np.testing.assert_allclose(robust_mean(pos, w, 1.0), weighted_mean(pos, w))
    m = weighted_mean(pos, w)
    d = pos - m
    np.testing.assert_allclose(weighted_covariance(pos, w), (w[:, None] * d).T @ d)
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=500, estimator="map", ess_threshold=0.0, rng=1)
    est = pf.step(0, MS)
    best = pf.particles[np.argmax(pf.log_weights)]
    assert (est.u, est.v) == (best[0], best[1])


@pytest.mark.parametrize(("pos", "vel"), [(2.0, 0.0), (0.0, 0.5), (0.0, 0.0)])
def test_zero_process_noise_components_stay_deterministic(pos, vel):
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=300, process_noise=(pos, vel), ess_threshold=0.0, rng=3)
    pf.step(0, MS)
    x0 = pf.particles.copy()
    pf.step(1, [])
    x1 = pf.particles
    moved = x0[:, :2] + x0[:, 2:]
    assert np.array_equal(x1[:, 2:], x0[:, 2:]) == (vel == 0.0)
    assert np.allclose(x1[:, :2], moved, rtol=0, atol=1e-12) == (pos == 0.0)


def test_frame_period_bridges_dropped_frames():
    period = 33_333_333
    pf = ParticleFilter(
        noise_px=SCENARIO_NOISE_PX,
        n_particles=2000,
        process_noise=(0.0, 0.0),
        prior=(100, 100, 3, -2),
        init_spread_px=0.0,
        init_velocity_px=0.0,
        frame_period_ns=period,
        rng=0,
    )
    pf.step(0, [])
    est = pf.step(3 * period, [])
    assert (est.u, est.v) == pytest.approx((109.0, 94.0))


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_particles": 0}, "n_particles"),
        ({"likelihood": "cauchy"}, "likelihood must be one of gaussian, robust"),
        ({"resampler": "best"}, "resampler must be one of"),
        ({"estimator": "median"}, "estimator must be one of"),
        ({"ess_threshold": 1.5}, r"ess_threshold must be in \[0, 1\]"),
        ({"top_fraction": 0.0}, "top_fraction"),
        ({"process_noise": (1.0, -1.0)}, "velocity std"),
        ({"noise_px": {"colour": 0.0}}, "noise_px"),
        ({"outlier_prob": 1.0}, "outlier_prob"),
        ({"prior": (1.0, np.nan)}, "prior"),
        ({"rng": -1}, "seed"),
    ],
)
def test_bad_options_raise_input_error(kwargs, message):
    with pytest.raises(InputError, match=message):
        ParticleFilter(**kwargs)


@pytest.mark.parametrize(
    ("ts", "ms", "message"),
    [
        (1, [Measurement("sonar", 1.0, 1.0)], "known sources: colour, depth, skeleton"),
        (1, [Measurement("colour", float("nan"), 1.0)], "finite"),
        (1, [Measurement("colour", 3.0e7, 1.0)], r"within \+-1e\+07"),
        (1, [Measurement("colour", 1.0, 1.0, quality=1.5)], r"quality must be in \[0, 1\]"),
        (0, MS, "must increase"),
        (2.5, MS, "must be an int"),
    ],
)
def test_bad_steps_raise_input_error(ts, ms, message):
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=20, rng=0)
    pf.step(0, MS)
    with pytest.raises(InputError, match=message):
        pf.step(ts, ms)


@settings(max_examples=40, deadline=None)
@given(
    frames=st.lists(
        st.lists(
            st.tuples(st.sampled_from(sorted(NOISE)), st.floats(-1e6, 1e6), st.floats(-1e6, 1e6), st.floats(0, 1)),
            max_size=3,
        ),
        min_size=1,
        max_size=6,
    ),
    likelihood=st.sampled_from(["gaussian", "robust"]),
)
def test_weights_stay_finite_and_normalised_for_any_cues(frames, likelihood):
    """Wild, contradictory cues (sources 1e6 px apart) never give NaN: log-sum-exp and re-initialisation."""
    pf = ParticleFilter(noise_px=SCENARIO_NOISE_PX, n_particles=64, likelihood=likelihood, rng=0)
    for k, frame in enumerate(frames):
        est = pf.step(k, [Measurement(s, u, v, quality=q) for s, u, v, q in frame])
        if est is None:
            continue
        assert np.isfinite(pf.log_weights).all() and np.isfinite(pf.particles).all()
        assert np.exp(pf.log_weights).sum() == pytest.approx(1.0, abs=1e-9)
        assert 1.0 - 1e-9 <= est.ess <= 64.0 + 1e-9 and np.isfinite([est.u, est.v]).all()


@settings(max_examples=200, deadline=None)
@given(
    st.floats(0.0, 1e6),
    st.floats(0.0, 1e6),
    st.floats(-1.0, 1.0),
)
def test_largest_std_equals_the_largest_eigenvalue(var_u, var_v, corr):
    from fusion_pf.filter.estimate import largest_std

    cov = np.array([[var_u, corr * math.sqrt(var_u * var_v)], [corr * math.sqrt(var_u * var_v), var_v]])
    reference = math.sqrt(max(float(np.linalg.eigvalsh(cov).max()), 0.0))
    assert largest_std(cov) == pytest.approx(reference, rel=1e-9, abs=1e-9)


def test_a_source_outlier_probability_set_online_is_the_one_the_robust_likelihood_uses():
    like = JointLikelihood({"depth": 2.0, "skeleton": 5.0}, likelihood="robust", use_quality=False)
    pos = np.random.default_rng(3).normal(100.0, 10.0, (300, 2))
    m = Measurement("depth", 104.0, 97.0, 1.0)
    like.set_outlier("depth", 0.3)
    assert like.outlier(m) == 0.3 and like.outlier(Measurement("skeleton", 0, 0, 1.0)) == like.outlier_prob
    joint, _ = like(pos, [m], np.empty(300))
    # by hand: log((1 - eps) exp(-d^2 / 2 sigma^2) / (2 pi sigma^2) + eps / A), normalised by its maximum
    d2 = ((pos - [104.0, 97.0]) ** 2).sum(axis=1)
    ll = np.log(0.7 * np.exp(-d2 / 8.0) / (2 * np.pi * 4.0) + 0.3 / like.outlier_area_px2)
    np.testing.assert_allclose(joint, ll - ll.max(), atol=1e-9)
    for bad in (0.0, 1.0, math.nan):
        with pytest.raises(InputError, match="outlier probability of depth"):
            like.set_outlier("depth", bad)
    with pytest.raises(InputError, match="unknown source"):
        like.set_outlier("colour", 0.2)
