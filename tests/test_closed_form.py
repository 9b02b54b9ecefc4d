"""Paper 002: motion model, differenced linear model, closed-form BLUE tracker."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.models.motion import ConstantVelocity
from radioloc.models.track_noise import (
    accumulated_noise_covariance,
    accumulated_noise_variance,
    noise_coefficients,
    squared_noise_covariance,
)
from radioloc.models.single_sensor import SquaredRangeModel, third_difference
from radioloc.sim.single_sensor import circular_sensor_path

T = 0.1


def circle(n, step=1.3, radius=5.0):
    return circular_sensor_path(n, radius, step)


def closed_form(r, sensor, *, sample_period_s=T, accel_var, range_var=0.0, covariance_state=None,
                **settings):
    """The tracker's full-state output as (state, state_covariance, estimate)."""
    est = ClosedFormTracker(accel_var, std_m=np.sqrt(range_var), **settings).locate(
        r, sensor, sample_period_s, covariance_state=covariance_state)
    return est.diagnostics["state"], est.diagnostics["state_covariance"], est


def simulate(rng, runs, n, accel_var, range_var, dist="uniform", sensor=None):
    sensor = circle(n) if sensor is None else sensor
    x0 = np.concatenate([rng.uniform(-2, 2, (runs, 2)), rng.normal(0, 1, (runs, 2))], -1)
    tracks = ConstantVelocity(accel_var, distribution=dist).simulate(x0, n, T, rng)
    r = np.linalg.norm(tracks[..., :2] - sensor, axis=-1)
    h = np.sqrt(3 * range_var)
    noise = rng.uniform(-h, h, r.shape) if dist == "uniform" else rng.normal(0, np.sqrt(range_var), r.shape)
    return tracks, np.abs(r + noise), sensor


# ---- motion model --------------------------------------------------------------------
@pytest.mark.parametrize("k", [0, 4, 9])
def test_eq5_matches_covariance_diagonal_and_monte_carlo(k):
    n, q = 10, 0.15
    cov = accumulated_noise_covariance(n, k, T, q)
    np.testing.assert_allclose(np.diag(cov), accumulated_noise_variance(n, k, T, q), rtol=1e-12)
    rng = np.random.default_rng(1)
    model = ConstantVelocity(q, distribution="uniform")
    runs = 40_000
    g = model.sample_accelerations((runs, n - 1, 2), rng)
    tracks = model.propagate(np.array([1.0, 2.0, 0.5, -0.3]), g, T)
    t = (np.arange(n) - k)[:, None] * T
    eps = tracks[..., :2] - (tracks[:, k, None, :2] + t * tracks[:, k, None, 2:])
    emp = eps[..., 0].T @ eps[..., 0] / runs
    assert np.max(np.abs(emp - cov)) < 0.03 * cov.max()
    # eps on opposite sides of k are uncorrelated
    if 0 < k < n - 1:
        assert cov[0, n - 1] == 0.0
    emp_sq = np.cov(eps[..., 1].T ** 2)
    th_sq = squared_noise_covariance(n, k, T, q, excess_kurtosis=-1.2)
    assert np.max(np.abs(emp_sq - th_sq)) < 0.05 * th_sq.max()


def test_propagate_matches_recursion_eq1():
    rng = np.random.default_rng(2)
    g = rng.normal(size=(7, 2))
    s0 = np.array([0.3, -1.0, 2.0, 0.5])
    out = ConstantVelocity(1.0).propagate(s0, g, T)
    x = s0.copy()
    for m in range(7):
        x = np.r_[x[:2] + T * x[2:] + g[m] * T**2 / 2, x[2:] + T * g[m]]
        np.testing.assert_allclose(out[m + 1], x, atol=1e-12)


def test_noise_coefficients_eq4_printed_form():
    c = noise_coefficients(6, 2)
    np.testing.assert_allclose(c[5, 2:5], [2.5, 1.5, 0.5])    # n > k: (n-k)-1/2 ... 1/2
    np.testing.assert_allclose(c[0, 0:2], [0.5, 1.5])         # n < k: 1/2 ... (k-n)-1/2


# ---- differenced model ----------------------------------------------------------------
@settings(max_examples=30, deadline=None)
@given(n=st.integers(4, 40), a=st.floats(-10, 10), b=st.floats(-10, 10), c=st.floats(-10, 10))
def test_third_difference_annihilates_quadratics(n, a, b, c):
    i = np.arange(n)
    assert np.allclose(third_difference(n) @ (a + b * i + c * i**2), 0.0, atol=1e-9 * (1 + abs(c) * n**2))
    assert np.any(third_difference(n) @ (i**3.0) != 0)


def test_squared_range_noise_moments_monte_carlo():
    rng = np.random.default_rng(3)
    n, k, q, xi, runs = 9, 4, 2.0, 0.1, 100_000
    sensor = circle(n)
    tracks, r, _ = simulate(rng, 1, n, q, xi)       # one trajectory for the state
    state = tracks[0, k]
    model = ConstantVelocity(q, distribution="uniform")
    init = np.broadcast_to(tracks[0, 0], (runs, 4))
    # rebuild trajectories with the same state at k: condition by shifting each run
    trk = model.simulate(init, n, T, rng)
    t = (np.arange(n) - k)[:, None] * T
    eps = trk[..., :2] - (trk[:, k, None, :2] + t * trk[:, k, None, 2:])
    pos = (state[:2] + t * state[2:]) + eps
    rtrue = np.linalg.norm(pos - sensor, axis=-1)
    h = np.sqrt(3 * xi)
    rhat = rtrue + rng.uniform(-h, h, rtrue.shape)
    y = rhat**2 - np.sum(sensor**2, -1)
    srm = SquaredRangeModel(n, k, T, q, std_m=np.sqrt(xi), accel_excess_kurtosis=-1.2,
                            range_excess_kurtosis=-1.2)
    d = (state[:2] + t * state[2:]) - sensor
    quad_plus_lin = np.sum(d**2, -1) - np.sum(sensor**2, -1)
    e = y - quad_plus_lin
    th = srm.noise_covariance(state, sensor)
    se = np.sqrt(np.diag(th) / runs)
    assert np.all(np.abs(e.mean(0) - srm.noise_mean()) < 5 * se)
    emp = np.cov(e.T)
    assert np.max(np.abs(emp - th)) < 0.05 * np.max(np.abs(th))


# ---- estimator ------------------------------------------------------------------------
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(0, 14))
def test_noise_free_ranges_give_the_exact_state(seed, k):
    rng = np.random.default_rng(seed)
    n = 15
    x0 = np.r_[rng.uniform(-3, 3, 2), rng.normal(0, 1, 2)]
    tracks = ConstantVelocity(0.0).simulate(x0, n, T, rng)
    sensor = circle(n, step=rng.uniform(0.7, 2.0))
    r = np.linalg.norm(tracks[:, :2] - sensor, axis=-1)
    state, _, est = closed_form(r, sensor, accel_var=0.0, range_var=1e-10, reference_index=k)
    np.testing.assert_allclose(state, tracks[k], atol=1e-5)
    np.testing.assert_allclose(est.position, tracks[k, :2], atol=1e-5)
    np.testing.assert_allclose(est.diagnostics["trajectory"], tracks[:, :2], atol=1e-5)


def test_oracle_blue_is_unbiased_and_matches_its_covariance():
    rng = np.random.default_rng(4)
    runs, n, q, xi = 3000, 30, 0.15, 0.1
    tracks, r, sensor = simulate(rng, 1, n, q, xi)
    # many noise draws around one fixed state at k = n-1
    k = n - 1
    truth = tracks[0, k]
    model = ConstantVelocity(q, distribution="uniform")
    trk = model.simulate(np.broadcast_to(tracks[0, 0], (runs, 4)), n, T, rng)
    t = (np.arange(n) - k)[:, None] * T
    eps = trk[..., :2] - (trk[:, k, None, :2] + t * trk[:, k, None, 2:])
    pos = truth[:2] + t * truth[2:] + eps
    h = np.sqrt(3 * xi)
    rhat = np.linalg.norm(pos - sensor, axis=-1) + rng.uniform(-h, h, (runs, n))
    state, cov, _ = closed_form(rhat, sensor, accel_var=q, range_var=xi,
                                accel_excess_kurtosis=-1.2, range_excess_kurtosis=-1.2,
                                covariance_state=truth)
    err = state - truth
    se = np.sqrt(np.diag(cov[0]) / runs)
    assert np.all(np.abs(err.mean(0)) < 4 * se)
    np.testing.assert_allclose(np.cov(err.T).diagonal(), np.diag(cov[0]), rtol=0.1)


def test_iterated_blue_beats_ols_and_is_near_its_covariance():
    rng = np.random.default_rng(5)
    tracks, r, sensor = simulate(rng, 400, 40, 0.15, 0.1)
    state, cov, est = closed_form(r, sensor, accel_var=0.15, range_var=0.1)
    truth = tracks[:, -1]
    mse_blue = np.mean(np.sum((est.position - truth[:, :2]) ** 2, -1))
    ols, _, ols_est = closed_form(r, sensor, accel_var=0.15, range_var=0.1, weighting="ols")
    mse_ols = np.mean(np.sum((ols_est.position - truth[:, :2]) ** 2, -1))
    np.testing.assert_allclose(ols, est.diagnostics["ols_state"])
    assert mse_blue < mse_ols
    assert np.all(est.converged | est.diagnostics["stalled"])
    predicted = np.mean(cov[:, 0, 0] + cov[:, 1, 1])
    assert 0.7 < mse_blue / predicted < 1.4


def test_batched_equals_one_by_one():
    rng = np.random.default_rng(6)
    tracks, r, sensor = simulate(rng, 5, 20, 0.15, 0.1)
    kw = dict(accel_var=0.15, range_var=0.1, reference_index=10)
    b_state, b_cov, batch = closed_form(r, sensor, **kw)
    for i in range(5):
        state, cov, one = closed_form(r[i], sensor, **kw)
        np.testing.assert_allclose(state, b_state[i], rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(cov, b_cov[i], rtol=1e-9, atol=1e-12)
        assert one.diagnostics["iterations"] == batch.diagnostics["iterations"][i]


@pytest.mark.parametrize("path", ["fixed", "linear", "quadratic_x"])
def test_quadratic_sensor_path_is_rejected(path):
    n = 12
    i = np.arange(n, dtype=float)
    sensor = circle(n)
    if path == "fixed":
        sensor = np.zeros((n, 2)) + [3.0, 4.0]
    elif path == "linear":
        sensor = np.stack([1 + 0.5 * i, 2 - 0.1 * i], -1)
    else:
        sensor[:, 0] = 0.3 * i**2 - i + 2
    with pytest.raises(GeometryError, match="degree <= 2"):
        closed_form(np.ones(n) * 5, sensor, accel_var=0.1, range_var=0.1)


def test_bad_input_raises_toolkit_errors():
    n = 10
    s = circle(n)
    kw = dict(accel_var=0.1, range_var=0.1)
    r = np.full(n, 5.0)
    with pytest.raises(InputError, match="ranges"):
        closed_form(np.r_[r[:-1], np.inf], s, **kw)
    with pytest.raises(InputError, match="ranges"):
        closed_form(np.r_[r[:-1], -2.0], s, **kw)     # below -6 sigma (sigma 0.32 m)
    with pytest.raises(InputError, match="sensor_path"):
        closed_form(r, s[:-1], **kw)
    with pytest.raises(InputError, match="reference_index"):
        closed_form(r, s, reference_index=n, **kw)
    with pytest.raises(InputError, match="ranges"):
        closed_form(r[:5], s[:5], **kw)
    with pytest.raises(ConfigError, match="sample_period_s"):
        closed_form(r, s, sample_period_s=0.0, accel_var=0.1)
    with pytest.raises(GeometryError, match="positive definite"):
        closed_form(r, s, accel_var=0.0, range_var=0.0)


def test_printed_eq14_reading_changes_only_off_diagonal_channel_terms():
    n, k, q, xi = 10, 3, 0.15, 0.2
    sensor = circle(n)
    state = np.array([-0.4, 0.3, 0.2, 1.0])
    derived = SquaredRangeModel(n, k, T, q, std_m=np.sqrt(xi)).noise_covariance(state, sensor)
    printed = SquaredRangeModel(n, k, T, q, std_m=np.sqrt(xi),
                                printed_eq14=True).noise_covariance(state, sensor)
    var = accumulated_noise_variance(n, k, T, q)
    np.testing.assert_allclose(np.diag(printed), np.diag(derived))
    i, j = 1, 7
    np.testing.assert_allclose(derived[i, j] - printed[i, j], 2 * xi * var[i] + 2 * xi * var[j])
