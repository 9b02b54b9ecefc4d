"""The mixture tracker on any model with a log-likelihood of the position: the progressive
Gaussian update (known answers against the Kalman update, evidence weights, zero
likelihood) and the tracker's honesty (NEES) on ranges and bearings beside the EKF.

The contract and metamorphic loops (tests/test_contract_generic.py,
tests/test_metamorphic.py) run it on every 2-D model case through its tags."""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators import ExtendedKalmanFilter, MixtureTracker
from radioloc.estimators.progressive_update import hermite_nodes, progressive_update
from radioloc.models import (BearingModel, Context, DiagMixture, Observation, RangeModel,
                             UniformDisk, WhiteAccelerationCV)


def _direct(z, std):
    """Log-likelihood of observing the position itself with noise ``std`` per axis."""
    def loglik(x):
        return -0.5 * np.sum(((x - z[:, None, None, :]) / std) ** 2, axis=-1)
    return loglik


def _kalman(m, P, z, std):
    S = P + std**2 * np.eye(len(m))
    K = P @ np.linalg.inv(S)
    return m + K @ (z - m), P - K @ P


def test_hermite_nodes_integrate_the_moments_of_the_normal():
    xi, a = hermite_nodes(2, 5)
    assert xi.shape == (25, 2) and np.isclose(a.sum(), 1.0)
    np.testing.assert_allclose(a @ xi, 0.0, atol=1e-14)
    np.testing.assert_allclose((a[:, None, None] * xi[:, :, None] * xi[:, None, :]).sum(0),
                               np.eye(2), atol=1e-13)
    np.testing.assert_allclose(a @ xi[:, 0] ** 4, 3.0, rtol=1e-12)


@pytest.mark.parametrize("std", [3.0, 0.3, 0.01])
def test_a_linear_gaussian_likelihood_gives_the_kalman_update(std):
    """Flat, comparable or 100 times sharper than the prior: the progressive update lands
    on the Kalman posterior; the velocity follows through its correlation."""
    m = np.array([1.0, -2.0, 0.5, 0.2])
    P = np.array([[1.0, 0.3, 0.2, 0.0], [0.3, 2.0, 0.0, 0.1],
                  [0.2, 0.0, 0.5, 0.0], [0.0, 0.1, 0.0, 0.4]])
    z = np.array([1.7, -2.9])
    H = np.zeros((2, 4))
    H[:, :2] = np.eye(2)
    S = H @ P @ H.T + std**2 * np.eye(2)
    K = P @ H.T @ np.linalg.inv(S)
    mk, Pk = m + K @ (z - H @ m), P - K @ H @ P
    w, mu, C, ok = progressive_update(np.ones((1, 1)), m[None, None], P[None, None],
                                      _direct(z[None], std), 2)
    assert ok.all() and np.isclose(w.sum(), 1.0)
    np.testing.assert_allclose(mu[0, 0], mk, atol=2e-3 * np.sqrt(Pk.diagonal().max()) + 1e-9)
    np.testing.assert_allclose(C[0, 0], Pk, rtol=0.01, atol=2e-3 * Pk.diagonal().max())


def test_component_weights_follow_the_evidence():
    """Two components: the posterior weights are the prior weights times each component's
    Gaussian evidence N(z; m_k, P_k + R)."""
    std = 0.5
    m = np.array([[[0.0, 0.0], [3.0, 1.0]]])
    P = np.broadcast_to(np.diag([1.0, 0.5]), (1, 2, 2, 2)).copy()
    w0 = np.array([[0.3, 0.7]])
    z = np.array([[1.0, 0.2]])
    w, mu, C, _ = progressive_update(w0, m, P, _direct(z, std), 2)
    ev = []
    for k in range(2):
        S = P[0, k] + std**2 * np.eye(2)
        d = z[0] - m[0, k]
        ev.append(w0[0, k] * np.exp(-0.5 * d @ np.linalg.solve(S, d)) / np.sqrt(np.linalg.det(S)))
    np.testing.assert_allclose(w[0], np.array(ev) / sum(ev), rtol=0.01)
    for k in range(2):
        mk, Pk = _kalman(m[0, k], P[0, k], z[0], std)
        np.testing.assert_allclose(mu[0, k], mk, atol=5e-3)
        np.testing.assert_allclose(C[0, k], Pk, rtol=0.02, atol=1e-4)


def test_zero_likelihood_everywhere_keeps_the_prediction():
    m = np.zeros((2, 1, 2))
    P = np.broadcast_to(np.eye(2), (2, 1, 2, 2)).copy()

    def loglik(x):                       # run 0: nothing explains it; run 1: a flat one
        out = np.zeros(x.shape[:-1])
        out[0] = -np.inf
        return out
    w, mu, C, ok = progressive_update(np.ones((2, 1)), m, P, loglik, 2)
    assert ok.tolist() == [False, True]
    np.testing.assert_array_equal(mu[0], m[0])          # run 0 untouched
    np.testing.assert_array_equal(C[0], P[0])
    np.testing.assert_allclose(mu[1], m[1], atol=1e-12)  # a flat likelihood changes nothing
    np.testing.assert_allclose(C[1], P[1], rtol=1e-5, atol=1e-12)


def _scene(model, std, B=60, T=25, seed=0):
    rng = np.random.default_rng(seed)
    dt = 0.5
    anchors = np.array([[0.0, 0], [30, 0], [0, 20], [30, 20]])
    motion = WhiteAccelerationCV(0.05, dim=2)
    F, Q = motion.F(dt), motion.Q(dt)
    x = np.c_[rng.uniform(5, 25, (B, 2)), rng.normal(0, 0.5, (B, 2))]
    P0 = np.diag([1.0, 1, 0.25, 0.25])
    m0 = x + rng.multivariate_normal(np.zeros(4), P0, B)
    traj = []
    for k in range(T):
        if k:
            x = x @ F.T + rng.multivariate_normal(np.zeros(4), Q, B)
        traj.append(x.copy())
    traj = np.stack(traj, 1)
    ctx = Context(points=anchors)
    h = model.predict({"position": traj[..., :2]}, ctx)
    z = h + std * rng.standard_normal(h.shape)
    return Observation(model, z, ctx), np.arange(T) * dt, m0, P0, traj[..., :2], motion


@pytest.mark.parametrize("model,std", [(RangeModel(std_m=0.3), 0.3),
                                       (BearingModel(std_rad=0.02), 0.02)])
def test_tracker_is_as_accurate_and_honest_as_the_ekf(model, std):
    """60 runs of 25 steps: RMSE within 10 % of the EKF's, mean NEES of the 2-D position
    within the band of 60 x 25 chi-square(2) values (and not far from the EKF's)."""
    obs, t, m0, P0, truth, motion = _scene(model, std)
    out = {}
    for cls in (MixtureTracker, ExtendedKalmanFilter):
        res = cls(motion=motion).run(obs, t, prior_mean=m0, prior_cov=P0)
        e = res.position - truth
        nees = np.einsum("...i,...ij,...j", e, np.linalg.inv(res.covariance), e)
        out[cls] = (np.sqrt(np.mean(np.sum(e**2, -1))), nees.mean())
    rmse, nees = out[MixtureTracker]
    assert rmse <= 1.1 * out[ExtendedKalmanFilter][0], out
    assert 1.5 < nees < 2.6, out


def test_a_two_component_prior_picks_the_mode_the_ranges_support():
    """A bimodal prior (the node at one of two places): ranges from the true place move
    the weight onto its component, and the estimate follows."""
    anchors = np.array([[0.0, 0.0], [20.0, 0.0], [10.0, 15.0]])
    truth = np.array([12.0, 5.0])
    ctx = Context(points=anchors)
    model = RangeModel(std_m=0.2)
    z = model.predict({"position": np.broadcast_to(truth, (4, 2))}, ctx)[None]
    prior = DiagMixture.create([0.5, 0.5], [[12.5, 5.5], [4.0, 9.0]], [[1.0, 1.0], [1.0, 1.0]])
    res = MixtureTracker(motion=UniformDisk(0.5, dim=2)).run(Observation(model, z, ctx),
                                                             np.arange(4.0), prior=prior)
    w = res.diagnostics["mixture_weights"][0, -1]
    means = res.diagnostics["mixture_means"][0, -1]
    near = int(np.argmin(np.linalg.norm(means[:2] - truth, axis=-1)))
    assert w[near] > 0.999
    np.testing.assert_allclose(res.position[0, -1], truth, atol=0.1)


def test_bad_input_is_named():
    obs, t, m0, P0, _, motion = _scene(RangeModel(std_m=0.3), 0.3, B=2, T=3)
    tracker = MixtureTracker(motion=motion)
    with pytest.raises(InputError, match="prior_mean"):
        tracker.run(obs, t)
    with pytest.raises(InputError, match="prior_cov"):
        tracker.run(obs, t, prior_mean=m0, prior_cov=-P0)
    with pytest.raises(InputError, match="time"):
        tracker.run(obs, t[::-1], prior_mean=m0, prior_cov=P0)
    flat3 = Observation(obs.model, obs.z, Context(points=np.c_[obs.context.points, np.ones(4)]))
    with pytest.raises(ConfigError, match="3-D points"):
        tracker.run(flat3, t, prior_mean=m0, prior_cov=P0)
