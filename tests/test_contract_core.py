"""The contract's core: result types, the one Kalman update, the one NLLS driver, the
motion models, the range EKF and named random streams."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.rng import block_generator, experiment_seed, stream
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.estimators.kalman import kalman_predict, kalman_update
from radioloc.estimators.nlls import solve_nlls
from radioloc.models.motion import (
    ConstantAcceleration,
    ConstantVelocity,
    InputDriven,
    RandomWalk,
    UniformDisk,
    WhiteAccelerationCV,
    WhiteJerkCA,
)
from radioloc.models.ranging import GaussianRange, range_geometry

ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]])


def _spd(rng, n, batch=()):
    a = rng.standard_normal(batch + (n, n))
    return a @ np.swapaxes(a, -1, -2) + n * np.eye(n)


# ---- results ----------------------------------------------------------------------------
def test_track_from_steps_puts_time_after_batch():
    steps = [Estimate(np.full((3, 5, 2), float(t)), np.broadcast_to(np.eye(2), (3, 5, 2, 2)), t,
                      {"nis": np.full((3, 5), t)}) for t in range(4)]
    tr = track_from_steps(steps)
    assert tr.position.shape == (3, 5, 4, 2)
    assert tr.covariance.shape == (3, 5, 4, 2, 2)
    assert tr.diagnostics["nis"].shape == (3, 5, 4)
    np.testing.assert_array_equal(tr.time, np.arange(4.0))
    np.testing.assert_array_equal(tr.at(2).position, steps[2].position)
    assert tr.at(2).diagnostics["nis"].shape == (3, 5)


def test_result_types_reject_bad_shapes():
    with pytest.raises(InputError, match="covariance"):
        Estimate(np.zeros((4, 2)), np.zeros((4, 3, 3)))
    with pytest.raises(InputError, match="time"):
        Track(np.zeros((4, 5, 2)), time=np.arange(3.0))
    with pytest.raises(InputError, match="Track.position"):
        Track(np.zeros(2))


# ---- Kalman -----------------------------------------------------------------------------
def test_joseph_update_equals_textbook_form():
    rng = np.random.default_rng(1)
    n, m, B = 4, 3, 6
    P = _spd(rng, n, (B,))
    x = rng.standard_normal((B, n))
    H = rng.standard_normal((B, m, n))
    R = _spd(rng, m, (B,))
    nu = rng.standard_normal((B, m))
    x1, P1, S, used = kalman_update(x, P, nu, H, R)
    S_ref = H @ P @ np.swapaxes(H, -1, -2) + R
    K = P @ np.swapaxes(H, -1, -2) @ np.linalg.inv(S_ref)
    np.testing.assert_allclose(x1, x + np.einsum("bij,bj->bi", K, nu), rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(P1, P - K @ S_ref @ np.swapaxes(K, -1, -2), rtol=1e-9, atol=1e-10)
    np.testing.assert_array_equal(P1, np.swapaxes(P1, -1, -2))
    assert used.all()


def test_nan_measurement_row_is_an_exact_noop():
    rng = np.random.default_rng(2)
    n, B = 4, 5
    P = _spd(rng, n, (B,))
    x = rng.standard_normal((B, n))
    H = rng.standard_normal((B, 3, n))
    nu = rng.standard_normal((B, 3))
    full = kalman_update(x, P, nu[:, :2], H[:, :2], R_diag=np.ones((B, 2)))
    nu_nan = nu.copy()
    nu_nan[:, 2] = np.nan
    skip = kalman_update(x, P, nu_nan, H, R_diag=np.ones((B, 3)))
    np.testing.assert_allclose(skip[0], full[0], atol=1e-12)
    np.testing.assert_allclose(skip[1], full[1], atol=1e-12)
    assert not skip[3][:, 2].any()
    none = kalman_update(x, P, np.full((B, 3), np.nan), H, R_diag=np.ones((B, 3)))
    np.testing.assert_array_equal(none[0], x)


def test_kalman_update_rejects_ambiguous_noise():
    with pytest.raises(InputError, match="R and R_diag"):
        kalman_update(np.zeros(2), np.eye(2), np.zeros(1), np.ones((1, 2)))


def test_predict_matches_definition():
    rng = np.random.default_rng(3)
    cv = ConstantVelocity(0.7)
    x, P = rng.standard_normal((3, 4)), _spd(rng, 4, (3,))
    m, C = kalman_predict(x, P, cv.F(0.5), cv.Q(0.5))
    F = cv.F(0.5)
    np.testing.assert_allclose(m, x @ F.T)
    np.testing.assert_allclose(C, F @ P @ F.T + cv.Q(0.5), atol=1e-12)


# ---- motion models ----------------------------------------------------------------------
@pytest.mark.parametrize("model", [RandomWalk(0.3), ConstantVelocity(0.5), ConstantAcceleration(0.2),
                                   WhiteAccelerationCV(0.4),
                                   ConstantVelocity(0.5, dim=3), InputDriven(0.1)])
def test_motion_models_shapes_and_psd(model):
    dt = np.array([0.0, 0.1, 1.0, 2.5])
    F, Q = model.F(dt), model.Q(dt)
    n = model.state_dim
    assert F.shape == (4, n, n) and Q.shape == (4, n, n)
    assert np.all(np.linalg.eigvalsh(Q[1:]) > -1e-12)
    np.testing.assert_allclose(Q, np.swapaxes(Q, -1, -2))


@pytest.mark.parametrize("model", [ConstantVelocity(0.5), ConstantAcceleration(0.2), RandomWalk(1.0),
                                   WhiteAccelerationCV(0.3)])
@given(a=st.floats(0.0, 3.0), b=st.floats(0.0, 3.0))
@settings(max_examples=25, deadline=None)
def test_transition_composes(model, a, b):
    np.testing.assert_allclose(model.F(a) @ model.F(b), model.F(a + b), atol=1e-9)


def test_constant_velocity_sample_covariance_is_Q():
    cv = ConstantVelocity(2.0)
    rng = np.random.default_rng(4)
    x = np.zeros((200_000, 4))
    draws = cv.sample(x, 0.5, rng)
    np.testing.assert_allclose(np.cov(draws.T), cv.Q(0.5), atol=0.01)


def test_uniform_disk_stays_inside_and_logpdf():
    ud = UniformDisk(2.0)
    rng = np.random.default_rng(5)
    x = np.zeros((10_000, 2))
    nxt = ud.sample(x, 0.5, rng)
    assert np.all(np.linalg.norm(nxt, axis=-1) <= 1.0 + 1e-12)
    np.testing.assert_allclose(np.cov(nxt.T), ud.Q(0.5), atol=0.01)
    lp = ud.logpdf(np.array([[0.5, 0.0], [1.5, 0.0]]), np.zeros((2, 2)), 0.5)
    np.testing.assert_allclose(lp[0], -np.log(np.pi))
    assert lp[1] == -np.inf


@pytest.mark.parametrize("make", [RandomWalk, WhiteAccelerationCV, WhiteJerkCA])
def test_a_process_noise_per_batch_member_equals_each_members_own_model(make):
    """``q`` with one value per batch member (a run's steps along the last axis of ``dt``):
    each member's ``Q`` is that of a model with its own scalar ``q``; batch equals one by
    one."""
    q = np.array([0.0, 0.3, 2.0])
    dt = np.array([[0.1, 1.0], [0.5, 0.0], [2.5, 0.2]])
    Q = make(q[:, None]).Q(dt)
    for b in range(3):
        np.testing.assert_allclose(Q[b], make(float(q[b])).Q(dt[b]), rtol=1e-15)
    with pytest.raises(ConfigError, match="q"):
        make(np.array([0.1, -1.0]))


def test_motion_models_reject_bad_settings():
    with pytest.raises(ConfigError, match="dim"):
        RandomWalk(1.0, dim=4)
    with pytest.raises(InputError, match="dt"):
        ConstantVelocity(1.0).F(-1.0)
    with pytest.raises(ConfigError, match="accel_var"):
        ConstantVelocity(-1.0)


# ---- NLLS -------------------------------------------------------------------------------
def _range_problem(rng, batch=8, noise=0.0):
    truth = rng.uniform(2, 28, (batch, 2))
    z = np.linalg.norm(truth[:, None] - ANCHORS, axis=-1) + noise * rng.standard_normal((batch, 4))

    def residuals(x):
        h, J = range_geometry(x, ANCHORS)
        return z - h, J
    return truth, z, residuals


@pytest.mark.parametrize("method", ["gauss-newton", "levenberg-marquardt"])
def test_nlls_zero_noise_converges_to_truth(method):
    truth, _, res = _range_problem(np.random.default_rng(6))
    out = solve_nlls(res, np.full((8, 2), 15.0), method=method)
    np.testing.assert_allclose(out.x, truth, atol=1e-8)
    assert out.converged.all() and not out.stalled.any()


def test_nlls_newton_with_curvature():
    truth, _, res = _range_problem(np.random.default_rng(7), noise=0.01)

    def curvature(x):
        h, J = range_geometry(x, ANCHORS)
        eye = np.eye(2)
        return (eye - J[..., :, None] * J[..., None, :]) / h[..., None, None]
    gn = solve_nlls(res, truth + 0.5, method="gauss-newton")
    nt = solve_nlls(res, truth + 0.5, method="newton", curvature=curvature, step_control="none",
                    tol=1e-10)
    np.testing.assert_allclose(nt.x, gn.x, atol=1e-6)


def test_nlls_batch_equals_one_by_one():
    truth, z, res = _range_problem(np.random.default_rng(8), noise=0.3)
    batch = solve_nlls(res, np.full((8, 2), 15.0))
    for i in range(8):
        def r1(x, i=i):
            h, J = range_geometry(x, ANCHORS)
            return z[i] - h, J
        one = solve_nlls(r1, np.full(2, 15.0))
        np.testing.assert_allclose(one.x, batch.x[i], atol=1e-10)


def test_nlls_flags_singular_problem_as_stalled():
    def res(x):  # one range only: the normal matrix is rank one
        h, J = range_geometry(x, ANCHORS[:1])
        return 10.0 - h, J
    out = solve_nlls(res, np.array([[3.0, 4.0]]), ridge=0.0)
    assert out.stalled.all() and not out.converged.any()
    assert np.isfinite(out.x).all()


def test_nlls_rejects_unknown_method():
    with pytest.raises(ConfigError, match="method"):
        solve_nlls(lambda x: (x, x[..., None]), np.zeros(1), method="simplex")


# ---- range EKF --------------------------------------------------------------------------
def _walk(rng, batch=4, T=60, dt=0.5):
    t = np.arange(T) * dt
    truth = np.stack([5 + 0.8 * t, 8 + 0.3 * t], -1)
    truth = np.broadcast_to(truth, (batch, T, 2))
    r = np.linalg.norm(truth[..., None, :] - ANCHORS, axis=-1) + 0.1 * rng.standard_normal((batch, T, 4))
    return t, truth, r


def test_range_ekf_tracks_and_keeps_xy_order():
    rng = np.random.default_rng(9)
    t, truth, r = _walk(rng)
    ekf = RangeEKF(ConstantVelocity(0.05), GaussianRange(0.1), anchors=ANCHORS)
    tr = ekf.run(r, t, prior_mean=[5, 8, 0, 0], prior_cov=np.diag([4, 4, 1, 1]))
    assert isinstance(tr, Track) and tr.position.shape == (4, 60, 2)
    assert tr.error(truth)[:, 20:].mean() < 0.15
    assert tr.diagnostics["state"][:, -1, 2].mean() == pytest.approx(0.8, abs=0.1)  # vx
    nis = tr.diagnostics["nis"][:, 10:].mean()
    assert 2.0 < nis < 6.5                                   # 4 ranges: E[NIS] = 4


def test_range_ekf_nan_skipped_and_batch_equals_one_by_one():
    rng = np.random.default_rng(10)
    t, truth, r = _walk(rng)
    r[:, 7, :] = np.nan
    r[1, 8, 2] = np.nan
    ekf = RangeEKF(RandomWalk(1.0), GaussianRange(0.1), anchors=ANCHORS)
    kw = dict(prior_mean=[5, 8], prior_cov=np.eye(2) * 4)
    tr = ekf.run(r, t, **kw)
    assert np.isfinite(tr.position).all()
    assert tr.diagnostics["measurements_used"][1, 8] == 3
    np.testing.assert_array_equal(tr.diagnostics["measurements_used"][:, 7], 0)
    for i in range(4):
        np.testing.assert_allclose(ekf.run(r[i], t, **kw).position, tr.position[i], atol=1e-12)


def test_range_ekf_asynchronous_rows_and_translation():
    rng = np.random.default_rng(11)
    t, truth, r = _walk(rng, batch=1, T=80, dt=0.25)
    one_at_a_time = np.full_like(r, np.nan)
    idx = np.arange(80) % 4
    one_at_a_time[0, np.arange(80), idx] = r[0, np.arange(80), idx]
    ekf = RangeEKF(ConstantVelocity(0.05), GaussianRange(0.1), anchors=ANCHORS)
    kw = dict(prior_mean=[5, 8, 0, 0], prior_cov=np.diag([4, 4, 1, 1]))
    tr = ekf.run(one_at_a_time, t, **kw)
    assert tr.error(truth)[0, 40:].mean() < 0.3
    shift = np.array([100.0, -50.0])
    moved = RangeEKF(ConstantVelocity(0.05), GaussianRange(0.1), anchors=ANCHORS + shift)
    tr2 = moved.run(one_at_a_time, t, prior_mean=[105, -42, 0, 0], prior_cov=np.diag([4, 4, 1, 1]))
    np.testing.assert_allclose(tr2.position, tr.position + shift, atol=1e-7)


def test_rts_smoother_lowers_the_error():
    rng = np.random.default_rng(12)
    t, truth, r = _walk(rng, batch=20)
    ekf = RangeEKF(ConstantVelocity(0.05), GaussianRange(0.1), anchors=ANCHORS)
    kw = dict(prior_mean=[5, 8, 0, 0], prior_cov=np.diag([4, 4, 1, 1]))
    filt = ekf.run(r, t, **kw).error(truth).mean()
    smooth = ekf.run(r, t, smooth=True, **kw).error(truth).mean()
    assert smooth < 0.9 * filt


def test_range_ekf_known_height_with_3d_anchors():
    rng = np.random.default_rng(13)
    a3 = np.c_[ANCHORS, [3.0, 2.0, 3.0, 2.5]]
    t, truth, _ = _walk(rng, batch=2)
    h = 1.2
    d = np.sqrt(np.sum((truth[..., None, :] - ANCHORS) ** 2, -1) + (h - a3[:, 2]) ** 2)
    r = d + 0.05 * rng.standard_normal(d.shape)
    ekf = RangeEKF(ConstantVelocity(0.05), GaussianRange(0.05), anchors=a3, height_m=h)
    tr = ekf.run(r, t, prior_mean=[5, 8, 0, 0], prior_cov=np.diag([4, 4, 1, 1]))
    assert tr.error(truth)[:, 20:].mean() < 0.1


def test_range_ekf_bad_input():
    ekf = RangeEKF(RandomWalk(1.0), GaussianRange(0.1), anchors=ANCHORS)
    with pytest.raises(InputError, match="ranges"):
        ekf.run(np.full((5, 3), 1.0), prior_mean=[1, 1], prior_cov=np.eye(2))
    with pytest.raises(InputError, match="ranges"):
        ekf.run(np.full((5, 4), np.inf), prior_mean=[1, 1], prior_cov=np.eye(2))
    with pytest.raises(InputError, match="prior_cov"):
        ekf.run(np.full((5, 4), 1.0), prior_mean=[1, 1], prior_cov=-np.eye(2))
    with pytest.raises(InputError, match="time"):
        ekf.run(np.full((5, 4), 1.0), time=[0, 1, 2, 1, 3], prior_mean=[1, 1], prior_cov=np.eye(2))
    with pytest.raises(ConfigError, match="motion"):
        RangeEKF(UniformDisk(1.0).radius, GaussianRange(0.1))


# ---- random streams ---------------------------------------------------------------------
def test_named_streams_follow_the_experiment_seed():
    g = block_generator(17, 3)
    assert experiment_seed(g) == 17
    a = stream(g, "calibration").random(3)
    np.testing.assert_array_equal(a, stream(17, "calibration").random(3))
    np.testing.assert_array_equal(a, stream(block_generator(17, 0), "calibration").random(3))
    assert not np.array_equal(a, stream(18, "calibration").random(3))
    assert not np.array_equal(a, stream(17, "scene").random(3))
    with pytest.raises(ConfigError):
        experiment_seed(np.random.default_rng())


def test_rss_models_logpdf_and_sample_agree():
    from radioloc.models import LogDistanceGaussian, fit_trapezoid_model
    rng = np.random.default_rng(14)
    ld = LogDistanceGaussian(a=60.0, n=2.0, s=3.0)
    draws = ld.sample(np.full(200_000, 5.0), rng)
    assert draws.mean() == pytest.approx(float(ld.mean(5.0)), abs=0.05)
    assert draws.std() == pytest.approx(3.0, rel=0.01)
    grid = np.linspace(30, 70, 4001)
    assert np.trapezoid(np.exp(ld.logpdf(grid, 5.0)), grid) == pytest.approx(1.0, abs=1e-6)
    d = rng.uniform(0, 20, 6000)
    r = np.clip(np.rint(80 - 3.0 * d + rng.normal(0, 1.5, d.size)), 0, 100)
    trap = fit_trapezoid_model(r, d, tau_min=0.3, sigma_min=0.3, window=1)
    dist = trap.sample(np.full(200_000, 50), rng)
    assert np.all(np.isfinite(trap.logpdf(dist, 50)))
    hist, edges = np.histogram(dist, bins=60, density=True)
    mid = 0.5 * (edges[1:] + edges[:-1])
    np.testing.assert_allclose(hist, trap.density(np.maximum(mid, 0), 50), atol=0.05)
    assert trap.logpdf(trap.upper[50] + 1.0, 50) == -np.inf


@given(a=st.floats(0.01, 3.0), b=st.floats(0.01, 3.0))
@settings(max_examples=25, deadline=None)
def test_white_acceleration_noise_does_not_depend_on_the_split(a, b):
    """Two predictions over a and b equal one over a + b (Q composes), which the
    piecewise-constant acceleration of ConstantVelocity does not."""
    m = WhiteAccelerationCV(0.7)
    F_b = m.F(b)
    two = F_b @ m.Q(a) @ F_b.T + m.Q(b)
    np.testing.assert_allclose(two, m.Q(a + b), atol=1e-9)
