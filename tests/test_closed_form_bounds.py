"""Paper 002: CRBs (Lemmas 1-2), Newton and EKF baselines, the p002 experiment smoke test."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radioloc.bounds.single_sensor import differenced_crb, raw_range_crb
from radioloc.core.errors import GeometryError, InputError
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.estimators.nlls_newton import NewtonTracker, range_residuals
from radioloc.models.motion import ConstantVelocity
from radioloc.models.ranging import GaussianRange

T = 0.1


def random_path(rng, n):
    return rng.uniform(-5, 5, (n, 2))


def noise_free_tracks(rng, n, runs):
    """A random sensor path, targets at constant velocity, and their exact ranges."""
    sensor = random_path(rng, n)
    x0 = np.c_[rng.uniform(-2, 2, (runs, 2)), rng.normal(0, 1, (runs, 2))]
    tracks = ConstantVelocity(0.0).simulate(x0, n, T, rng)
    return sensor, x0, tracks, np.linalg.norm(tracks[..., :2] - sensor, axis=-1)


def psd(m, tol=1e-9):
    return np.linalg.eigvalsh((m + m.T) / 2).min() >= -tol * max(1.0, np.abs(m).max())


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 100_000), n=st.integers(8, 25), noisy=st.booleans())
def test_lemma1_and_2_bound_does_not_grow_when_a_sample_is_added(seed, n, noisy):
    rng = np.random.default_rng(seed)
    k = int(rng.integers(0, n))
    state = np.r_[rng.uniform(-2, 2, 2), rng.normal(0, 1, 2)]
    sensor = random_path(rng, n + 1)
    kw = dict(sample_period_s=T, accel_var=0.15, std_m=np.sqrt(0.1) if noisy else 0.0,
              reference_index=k)
    small = differenced_crb(state, sensor[:n], **kw)
    large = differenced_crb(state, sensor, **kw)
    assert psd(small - large)                       # Cov(beta_1) <= Cov(beta_2), eq. (20)


def test_differenced_crb_equals_blue_covariance_at_truth():
    rng = np.random.default_rng(1)
    n = 20
    sensor = random_path(rng, n)
    state = np.array([0.5, -0.2, 0.3, 1.0])
    r = rng.uniform(3, 6, n)
    kw = dict(accel_var=0.15, std_m=np.sqrt(0.1), reference_index=7)
    est = ClosedFormTracker(**kw).locate(r, sensor, T, covariance_state=state)
    crb = differenced_crb(state, sensor, sample_period_s=T, **kw)
    np.testing.assert_allclose(est.diagnostics["state_covariance"], crb, rtol=1e-9)
    np.testing.assert_allclose(est.covariance, crb[:2, :2], rtol=1e-9)


def test_raw_range_crb_without_motion_noise_is_the_gaussian_range_crb():
    rng = np.random.default_rng(2)
    n, xi = 12, 0.04
    sensor = random_path(rng, n)
    state = np.array([0.5, -0.2, 0.3, 1.0])
    k = 5
    crb = raw_range_crb(state, sensor, sample_period_s=T, accel_var=0.0, std_m=np.sqrt(xi),
                        reference_index=k)

    def h(b):
        t = (np.arange(n) - k)[:, None] * T
        return np.linalg.norm(b[:2] + t * b[2:] - sensor, axis=-1)

    J = np.stack([(h(state + 1e-6 * e) - h(state - 1e-6 * e)) / 2e-6 for e in np.eye(4)], -1)
    np.testing.assert_allclose(crb, np.linalg.inv(J.T @ J / xi), rtol=1e-5)


def test_raw_range_bound_is_tighter_than_differenced_bound_on_average():
    rng = np.random.default_rng(3)
    n = 40
    sensor = random_path(rng, n)
    states = np.c_[rng.uniform(-2, 2, (50, 2)), rng.normal(0, 1, (50, 2))]
    kw = dict(sample_period_s=T, accel_var=0.15, std_m=np.sqrt(0.1))
    d = differenced_crb(states, sensor, **kw)
    r = raw_range_crb(states, sensor, **kw)
    assert np.mean(np.trace(r, axis1=1, axis2=2)) < np.mean(np.trace(d, axis1=1, axis2=2))


def test_bound_rejects_unidentifiable_geometry():
    n = 10
    sensor = np.zeros((n, 2))
    with pytest.raises(GeometryError):
        differenced_crb(np.ones(4), sensor, sample_period_s=T, accel_var=0.1, std_m=np.sqrt(0.1))


# ---- Newton ----------------------------------------------------------------------------
def test_newton_jacobian_and_curvature_match_finite_differences():
    rng = np.random.default_rng(4)
    n, k = 15, 6
    sensor = random_path(rng, n)
    r = rng.uniform(2, 6, n)
    beta = np.array([-0.3, 0.4, 0.2, 0.8])
    res, J, curv = range_residuals(beta, r, sensor, T, k, curvature=True)
    eps = 1e-6
    J_fd = np.stack([(range_residuals(beta - eps * e, r, sensor, T, k)[0]
                      - range_residuals(beta + eps * e, r, sensor, T, k)[0]) / (2 * eps)
                     for e in np.eye(4)], -1)
    C_fd = np.stack([(range_residuals(beta + eps * e, r, sensor, T, k)[1]
                      - range_residuals(beta - eps * e, r, sensor, T, k)[1]) / (2 * eps)
                     for e in np.eye(4)], -1)
    np.testing.assert_allclose(J, J_fd, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(curv, C_fd, rtol=1e-4, atol=1e-6)


def test_newton_converges_to_truth_on_noise_free_data_and_batches():
    rng = np.random.default_rng(5)
    n, runs = 20, 6
    sensor, x0, tracks, r = noise_free_tracks(rng, n, runs)
    truth = tracks[:, -1]
    start = truth + rng.normal(0, 0.2, truth.shape)
    newton = NewtonTracker(tol=1e-10, max_iter=50)
    est = newton.locate(r, sensor, T, initial_state=start)
    np.testing.assert_allclose(est.diagnostics["state"], truth, atol=1e-6)
    assert est.converged.all() and not est.diagnostics["stalled"].any()
    one = newton.locate(r[2], sensor, T, initial_state=start[2])
    np.testing.assert_allclose(one.diagnostics["state"], est.diagnostics["state"][2], atol=1e-10)


def test_newton_takes_the_step_that_meets_the_stopping_rule():
    """The paper's rule |step|^2 <= 0.1: the last (small) step is taken, then it stops."""
    rng = np.random.default_rng(8)
    n = 20
    sensor, x0, tracks, r = noise_free_tracks(rng, n, 1)
    start = tracks[0, -1] + np.array([0.05, -0.05, 0.1, 0.0])
    loose = NewtonTracker(tol=0.1**0.5).locate(r[0], sensor, T, initial_state=start)
    assert loose.converged and loose.diagnostics["iterations"] == 1
    # one full Newton step from a start this close is already far inside the tolerance
    assert np.linalg.norm(loose.diagnostics["state"] - tracks[0, -1]) < 1e-3


def test_newton_output_is_finite_from_a_far_start():
    rng = np.random.default_rng(6)
    n = 15
    sensor = random_path(rng, n)
    r = rng.uniform(2, 6, (4, n))
    est = NewtonTracker().locate(r, sensor, T, initial_state=rng.normal(0, 100, (4, 4)))
    assert np.all(np.isfinite(est.position))


def test_newton_bad_input():
    with pytest.raises(InputError, match="initial_state"):
        NewtonTracker().locate(np.ones(10), np.random.default_rng(0).normal(size=(10, 2)), T,
                               initial_state=np.ones(3))


# ---- EKF (RangeEKF with the paper's motion model) ----------------------------------------
def test_ekf_tracks_noise_free_target_and_batches():
    rng = np.random.default_rng(7)
    n, runs = 60, 5
    sensor, x0, tracks, r = noise_free_tracks(rng, n, runs)
    prior = x0 + rng.normal(0, 0.3, x0.shape)
    ekf = RangeEKF(ConstantVelocity(1e-4), GaussianRange(1e-2))
    kw = dict(time=np.arange(n) * T, prior_cov=0.09 * np.eye(4),
              anchor_path=sensor[:, None, :])
    track = ekf.run(r[..., None], prior_mean=prior, **kw)
    assert track.position.shape == (runs, n, 2)
    assert np.max(np.linalg.norm(track.position[:, -1] - tracks[:, -1, :2], axis=-1)) < 0.05
    one = ekf.run(r[1, :, None], prior_mean=prior[1], **kw)
    np.testing.assert_allclose(one.position, track.position[1], atol=1e-10)


# ---- experiment ------------------------------------------------------------------------
def test_experiment_smoke(tmp_path, monkeypatch):
    import dataclasses
    import json

    import pandas as pd

    from radioloc.experiments.runner import run_experiment
    from radioloc.experiments import single_sensor

    monkeypatch.setenv("RADIOLOC_DATA", str(tmp_path / "no-data"))
    small = dataclasses.replace(single_sensor.SingleSensorConfig(), runs=4, block_size=2,
                                n_values=(10, 20), fig2_samples=15)
    monkeypatch.setattr(single_sensor.SingleSensorExperiment, "config",
                        lambda self, full: small)
    run_experiment("p002-single-sensor", out=tmp_path, progress=False)
    folder = tmp_path / "p002-single-sensor"
    assert (folder / "results.csv").is_file()
    assert (folder / "fig1_rmse_vs_n_synthetic.png").is_file()
    text = (folder / "summary.json").read_text()
    assert "rmse_blue_n20" in text and "skipped" in text
    assert "cpu" not in " ".join(c["claim"] for c in json.loads(text)["claims"]).lower()
    table = pd.read_csv(folder / "results.csv")
    assert set(table["table"]) == {"runs", "causal", "fig2", "sensitivity", "sensitivity_runs"}
    assert "causal_rmse_blue" in text
    assert "traj_rmse_blue_n20" in text and "newton_diverged_frac_n20" in text
    assert (table["table"] == "fig2").sum() == 3 * (15 - 9)
