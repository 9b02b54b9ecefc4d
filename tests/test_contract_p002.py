"""Contract tests of the paper-002 estimators: ClosedFormTracker and NewtonTracker.

Types and shapes, (x, y) order against the truth, batch equals one by one, translation
equivariance, bad input raises the toolkit's errors, NaN ranges skipped (the closed form
drops the differences that involve the missing sample; Newton drops its residual).
"""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.results import Estimate
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.estimators.nlls_newton import NewtonTracker
from radioloc.sim.single_sensor import circular_sensor_path, noisy_ranges, random_tracks

T = 0.1
N = 15


def straight_scene(velocity=(1.5, 0.0), start=(0.5, -0.7), n=N):
    """A target on a straight line (no motion noise) and exact ranges to a circling sensor."""
    sensor = circular_sensor_path(n, 5.0, 1.3)
    t = np.arange(n)[:, None] * T
    pos = np.asarray(start) + t * np.asarray(velocity)
    state_last = np.r_[pos[-1], velocity]
    return sensor, np.linalg.norm(pos - sensor, axis=-1), state_last


def noisy_batch(runs=6, n=N, seed=3):
    rng = np.random.default_rng(seed)
    tracks = random_tracks(runs, n, T, 0.15, rng, box_m=2.0, speed_std=1.0)
    sensor = circular_sensor_path(n, 5.0, 1.3)
    return sensor, noisy_ranges(tracks[..., :2], sensor, std_m=np.sqrt(0.1), rng=rng), tracks


def blue(**kw):
    return ClosedFormTracker(accel_var=0.15, std_m=np.sqrt(0.1), **kw)


def exact_blue(**kw):
    return ClosedFormTracker(accel_var=0.0, std_m=1e-5, **kw)


# ---- types and shapes -------------------------------------------------------------------
@pytest.mark.parametrize("batch", [(), (4,), (2, 3)])
def test_types_and_shapes(batch):
    sensor, r, tracks = noisy_batch(int(np.prod(batch)) or 1)
    r = r.reshape(batch + (N,)) if batch else r[0]
    truth = tracks[..., -1, :].reshape(batch + (4,)) if batch else tracks[0, -1]
    for est in (blue().locate(r, sensor, T),
                NewtonTracker().locate(r, sensor, T, initial_state=truth)):
        assert isinstance(est, Estimate)
        assert est.position.shape == batch + (2,)
        assert est.diagnostics["state"].shape == batch + (4,)
        assert est.diagnostics["trajectory"].shape == batch + (N, 2)
        assert est.converged.shape == batch
        assert est.diagnostics["stalled"].dtype == bool
        assert np.all(np.isfinite(est.position))
        assert np.allclose(est.time, (N - 1) * T)
    est = blue().locate(r, sensor, T)
    assert est.covariance.shape == batch + (2, 2)
    assert est.diagnostics["state_covariance"].shape == batch + (4, 4)
    np.testing.assert_allclose(est.covariance, est.diagnostics["state_covariance"][..., :2, :2])


def test_time_argument_equals_sample_period():
    sensor, r, _ = noisy_batch(3)
    time = 12.0 + np.arange(N) * T
    a = blue().locate(r, sensor, T)
    b = blue().locate(r, sensor, time=time)
    np.testing.assert_allclose(a.position, b.position)
    assert np.isclose(b.time, time[-1])


# ---- (x, y) order against the truth -----------------------------------------------------
def test_zero_noise_recovers_the_truth_in_x_y_order():
    sensor, r, state = straight_scene(velocity=(1.5, -0.4), start=(0.5, -0.7))
    cf = exact_blue().locate(r, sensor, T)
    np.testing.assert_allclose(cf.position, state[:2], atol=1e-5)
    np.testing.assert_allclose(cf.diagnostics["state"], state, atol=1e-5)
    nt = NewtonTracker(tol=1e-10).locate(r, sensor, T, initial_state=state + [0.2, -0.1, 0.3, 0.1])
    np.testing.assert_allclose(nt.position, state[:2], atol=1e-6)
    np.testing.assert_allclose(nt.diagnostics["state"], state, atol=1e-6)
    assert nt.converged


def test_motion_along_plus_x_gives_positive_vx():
    sensor, r, state = straight_scene(velocity=(2.0, 0.0), start=(-1.0, 0.3))
    cf = exact_blue().locate(r, sensor, T)
    nt = NewtonTracker(tol=1e-10).locate(r, sensor, T, initial_state=[0.5, 0.0, 0.5, 0.5])
    for est in (cf, nt):
        st = est.diagnostics["state"]
        assert st[2] > 1.9 and abs(st[3]) < 0.1                   # vx > 0, vy ~ 0
        assert est.position[0] > 0.7                              # x moved on from -1
        traj = est.diagnostics["trajectory"]
        assert np.all(np.diff(traj[:, 0]) > 0)


def test_reference_index_estimates_that_sample():
    sensor, r, state = straight_scene(velocity=(1.0, 0.5), start=(0.2, 0.1))
    est = exact_blue(reference_index=0).locate(r, sensor, T)
    np.testing.assert_allclose(est.position, [0.2, 0.1], atol=1e-5)
    assert est.time == 0.0
    est_neg = exact_blue(reference_index=-N).locate(r, sensor, T)
    np.testing.assert_allclose(est_neg.position, est.position)


# ---- batch equals one by one ------------------------------------------------------------
def test_batch_equals_one_by_one():
    sensor, r, tracks = noisy_batch(5)
    start = tracks[:, -1] + 0.3
    cf_b = blue().locate(r, sensor, T)
    nt_b = NewtonTracker().locate(r, sensor, T, initial_state=start)
    for i in range(5):
        cf = blue().locate(r[i], sensor, T)
        nt = NewtonTracker().locate(r[i], sensor, T, initial_state=start[i])
        np.testing.assert_allclose(cf.position, cf_b.position[i], rtol=1e-9, atol=1e-10)
        np.testing.assert_allclose(cf.covariance, cf_b.covariance[i], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(nt.position, nt_b.position[i], rtol=1e-9, atol=1e-10)
        assert nt.diagnostics["iterations"] == nt_b.diagnostics["iterations"][i]
        assert cf.diagnostics["iterations"] == cf_b.diagnostics["iterations"][i]


def test_per_problem_sensor_paths_batch():
    sensor, r, tracks = noisy_batch(2)
    other = circular_sensor_path(N, 6.0, 1.1)
    paths = np.stack([sensor, other])
    r2 = np.stack([r[0], np.linalg.norm(tracks[1, :, :2] - other, axis=-1)])
    both = blue().locate(r2, paths, T)
    np.testing.assert_allclose(both.position[1], blue().locate(r2[1], other, T).position)


# ---- translation ------------------------------------------------------------------------
def test_translating_the_scene_translates_the_estimate():
    sensor, r, tracks = noisy_batch(4)
    shift = np.array([30.0, -12.0])
    start = tracks[:, -1] + 0.2
    cf = blue().locate(r, sensor, T)
    cf_s = blue().locate(r, sensor + shift, T)
    np.testing.assert_allclose(cf_s.position, cf.position + shift, atol=1e-6)
    np.testing.assert_allclose(cf_s.covariance, cf.covariance, rtol=1e-6, atol=1e-9)
    nt = NewtonTracker().locate(r, sensor, T, initial_state=start)
    nt_s = NewtonTracker().locate(r, sensor + shift, T,
                                  initial_state=start + np.r_[shift, 0.0, 0.0])
    np.testing.assert_allclose(nt_s.position, nt.position + shift, atol=1e-6)


# ---- missing samples --------------------------------------------------------------------
@pytest.mark.parametrize("stopping", ["change", "criterion"])
def test_nan_range_blue_is_skipped(stopping):
    """A NaN drops its difference rows: finite estimate, other problems of the batch
    unchanged, four fewer differences (three at the window's ends)."""
    sensor, r, tracks = noisy_batch(3)
    full = blue(stopping=stopping).locate(r, sensor, T)
    r = r.copy()
    r[1, 6] = np.nan
    est = blue(stopping=stopping).locate(r, sensor, T)
    assert np.all(np.isfinite(est.position)) and np.all(np.isfinite(est.covariance))
    np.testing.assert_allclose(est.position[[0, 2]], full.position[[0, 2]], rtol=1e-12)
    np.testing.assert_array_equal(est.diagnostics["used_differences"], [N - 3, N - 7, N - 3])
    assert np.linalg.norm(est.position[1] - tracks[1, -1, :2]) < 1.0


@pytest.mark.parametrize("weighting", ["blue", "ols"])
def test_nan_at_first_sample_equals_the_shorter_series(weighting):
    sensor, r, _ = noisy_batch(4)
    r_nan = r.copy()
    r_nan[:, 0] = np.nan
    est = blue(weighting=weighting).locate(r_nan, sensor, T)
    short = blue(weighting=weighting).locate(r[:, 1:], sensor[1:], T)
    np.testing.assert_allclose(est.diagnostics["state"], short.diagnostics["state"],
                               rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(est.covariance, short.covariance, rtol=1e-9, atol=1e-15)


def test_nan_at_last_sample_equals_the_shorter_series_for_a_fixed_k():
    sensor, r, _ = noisy_batch(4)
    r_nan = r.copy()
    r_nan[:, -1] = np.nan
    est = blue(reference_index=5).locate(r_nan, sensor, T)
    short = blue(reference_index=5).locate(r[:, :-1], sensor[:-1], T)
    np.testing.assert_allclose(est.diagnostics["state"], short.diagnostics["state"],
                               rtol=1e-9, atol=1e-12)


def test_too_many_nans_leave_the_state_unidentified():
    sensor, r, _ = noisy_batch(1)
    r = r.copy()
    r[0, 2:12] = np.nan
    with pytest.raises(GeometryError, match="rank deficient"):
        blue().locate(r, sensor, T)


def test_nan_range_is_skipped_by_newton():
    sensor, r, state = straight_scene(velocity=(1.0, -0.5))
    r = r.copy()
    r[[3, 8]] = np.nan
    est = NewtonTracker(tol=1e-10).locate(r, sensor, T, initial_state=state + 0.1)
    assert np.all(np.isfinite(est.position))
    np.testing.assert_allclose(est.diagnostics["state"], state, atol=1e-6)


# ---- bad input --------------------------------------------------------------------------
def test_bad_settings_raise_at_construction():
    with pytest.raises(ConfigError, match="accel_var"):
        ClosedFormTracker(accel_var=-1.0)
    with pytest.raises(InputError, match="std_m"):
        ClosedFormTracker(accel_var=0.1, std_m=-0.1)
    with pytest.raises(ConfigError, match="weighting"):
        ClosedFormTracker(accel_var=0.1, weighting="wls")
    with pytest.raises(ConfigError, match="stopping"):
        ClosedFormTracker(accel_var=0.1, stopping="gls")
    with pytest.raises(ConfigError, match="tol"):
        ClosedFormTracker(accel_var=0.1, tol=0.0)
    with pytest.raises(ConfigError, match="max_iter"):
        NewtonTracker(max_iter=-1)
    with pytest.raises(ConfigError, match="step_control"):
        NewtonTracker(step_control="dogleg")
    with pytest.raises(ConfigError, match="reference_index"):
        NewtonTracker(reference_index=1.5)


def test_bad_input_raises_input_error():
    sensor, r, state = straight_scene()
    with pytest.raises(InputError, match="ranges"):
        blue().locate(-r, sensor, T)
    with pytest.raises(InputError, match="sensor_path"):
        blue().locate(r, sensor[:, :1], T)
    with pytest.raises(InputError, match="sensor_path"):
        NewtonTracker().locate(r, sensor[:-1], T, initial_state=state)
    with pytest.raises(InputError, match="sample_period_s, time"):
        blue().locate(r, sensor)
    with pytest.raises(InputError, match="time"):
        blue().locate(r, sensor, time=np.r_[0.0, np.cumsum(np.full(N - 1, T)) ** 1.1])
    with pytest.raises(InputError, match="reference_index"):
        ClosedFormTracker(accel_var=0.1, reference_index=N).locate(r, sensor, T)
    with pytest.raises(InputError, match="initial_state"):
        NewtonTracker().locate(r, sensor, T, initial_state=[0.0, 0.0])

# the reduced-size reproduction (headline numbers within Monte Carlo bands, claim verdicts)
# is tests/test_repro_p002.py
