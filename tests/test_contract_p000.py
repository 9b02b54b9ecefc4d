"""The estimator contract for paper 000's estimators and multilateration.

:class:`Multilateration` (snapshot) and :class:`NetworkRLS` / :class:`NetworkEKF`
(recursive) on small generated problems: result types and shapes, (x, y) order against
the truth, batch equals one by one, a NaN measurement skipped, zero noise converging to
the truth, translation equivariance, and bad input raising the toolkit's errors.
"""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.geometry import distances, pairwise_distances
from radioloc.core.results import Estimate, Track
from radioloc.estimators.base import RecursiveEstimator, SnapshotEstimator
from radioloc.estimators.ekf import EKFState, NetworkEKF
from radioloc.estimators.multilateration import Multilateration
from radioloc.estimators.rls import NetworkRLS, RLSState

# an asymmetric anchor layout, so that swapping x and y changes the answer
ANCHORS = np.array([[0.0, 0.0], [120.0, 0.0], [100.0, 60.0], [10.0, 70.0], [60.0, 30.0]])


def _snapshot_problem(R=12, std=0.5, seed=0):
    rng = np.random.default_rng(seed)
    truth = np.column_stack([rng.uniform(60, 110, R), rng.uniform(5, 25, R)])   # x > y
    ranges = distances(truth[:, None], ANCHORS) + std * rng.normal(size=(R, len(ANCHORS)))
    return truth, np.abs(ranges)


def _network(R=3, K=5, N=6, std=1.0, seed=1, prior_std=(2.0, 20.0)):
    rng = np.random.default_rng(seed)
    truth = np.stack([rng.uniform(0, 800, (R, K)), rng.uniform(0, 200, (R, K))], axis=-1)
    pstd = np.where(np.arange(K) < 2, prior_std[0], prior_std[1])[None, :, None]
    var = np.broadcast_to(pstd**2, (R, K, 2)).astype(float)
    prior = truth + rng.normal(size=truth.shape) * pstd
    rho = pairwise_distances(truth)[:, None] + std * rng.normal(size=(R, N, K, K))
    return truth, prior, var, rho


NETWORK = {"rls": lambda: NetworkRLS(forgetting=0.8, std_m=1.0), "ekf": lambda: NetworkEKF(std_m=1.0)}


# ---------------------------------------------------------------- Multilateration

def test_multilateration_result_type_shapes_and_xy_order():
    truth, ranges = _snapshot_problem()
    est = Multilateration(std_m=0.5)
    assert isinstance(est, SnapshotEstimator)
    fit = est.locate(ranges, ANCHORS)
    assert isinstance(fit, Estimate)
    assert fit.position.shape == (12, 2) and fit.covariance.shape == (12, 2, 2)
    for k in ("converged", "stalled", "iterations", "residual_rms_m"):
        assert fit.diagnostics[k].shape == (12,)
    assert fit.diagnostics["converged"].all() and not fit.diagnostics["stalled"].any()
    err = np.linalg.norm(fit.position - truth, axis=-1)
    swapped = np.linalg.norm(fit.position[:, ::-1] - truth, axis=-1)
    assert err.max() < 3.0 and swapped.min() > 10.0


def test_multilateration_batch_equals_one_by_one_with_anchor_batches():
    truth, ranges = _snapshot_problem(R=6)
    anchors = ANCHORS + np.arange(6)[:, None, None] * np.array([3.0, -2.0])   # (R, M, 2)
    ranges = distances(truth[:, None], anchors) + 0.3
    est = Multilateration()
    batch = est.locate(ranges, anchors)
    for r in range(6):
        one = est.locate(ranges[r], anchors[r])
        np.testing.assert_allclose(batch.position[r], one.position, atol=1e-10)
        np.testing.assert_allclose(batch.covariance[r], one.covariance, rtol=1e-8)
        assert batch.diagnostics["iterations"][r] == one.diagnostics["iterations"]


def test_multilateration_nan_range_equals_dropping_it():
    truth, ranges = _snapshot_problem()
    with_nan = ranges.copy()
    with_nan[:, 2] = np.nan
    est = Multilateration(std_m=0.5)
    a = est.locate(with_nan, ANCHORS)
    b = est.locate(np.delete(ranges, 2, axis=1), np.delete(ANCHORS, 2, axis=0))
    np.testing.assert_allclose(a.position, b.position, atol=1e-9)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-8)
    assert np.all(np.isfinite(a.position))


def test_multilateration_zero_noise_converges_to_the_truth():
    truth, _ = _snapshot_problem()
    for method in ("gauss-newton", "levenberg-marquardt"):
        fit = Multilateration(method, std_m=1.0, max_iter=200).locate(
            distances(truth[:, None], ANCHORS), ANCHORS)
        np.testing.assert_allclose(fit.position, truth, atol=1e-6)
        assert fit.diagnostics["converged"].all()


def test_multilateration_translating_the_scene_translates_the_estimate():
    truth, ranges = _snapshot_problem()
    shift = np.array([1234.5, -678.9])
    est = Multilateration(std_m=0.5)
    a = est.locate(ranges, ANCHORS)
    b = est.locate(ranges, ANCHORS + shift)
    np.testing.assert_allclose(b.position, a.position + shift, atol=1e-6)
    np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-5)


def test_multilateration_bad_input():
    truth, ranges = _snapshot_problem(R=2)
    with pytest.raises(ConfigError, match="method"):
        Multilateration(method="simplex")
    with pytest.raises(InputError, match="ranges"):
        Multilateration().locate(ranges[:, :4], ANCHORS)
    with pytest.raises(InputError, match="ranges"):
        Multilateration().locate(np.where(ranges > 50, -1.0, ranges), ANCHORS)
    few = ranges.copy()
    few[1, :3] = np.nan
    with pytest.raises(GeometryError) as info:
        Multilateration().locate(few, ANCHORS)
    assert info.value.index == (1,) and "2 ranges" in info.value.detail


# ---------------------------------------------------------------- NetworkRLS / NetworkEKF

@pytest.mark.parametrize("name", sorted(NETWORK))
def test_network_track_type_shapes_and_xy_order(name):
    truth, prior, var, rho = _network()
    est = NETWORK[name]()
    assert isinstance(est, RecursiveEstimator)
    track = est.run(rho, prior, var)
    assert isinstance(track, Track)
    assert track.position.shape == (3, 5, 6, 2) and track.steps == 6
    np.testing.assert_array_equal(track.time, np.arange(1, 7))
    if name == "ekf":
        assert track.covariance.shape == (3, 5, 6, 2, 2)
        assert track.diagnostics["nis"].shape == (3, 5, 6)
    else:
        assert track.covariance is None
    assert track.diagnostics["measurements_used"].shape == (3, 5, 6)
    last = track.at(5)
    err = np.linalg.norm(last.position - truth, axis=-1)
    swapped = np.linalg.norm(last.position[..., ::-1] - truth, axis=-1)
    # the RLS frame drifts (its priors carry no weight, see its docstring): compare medians
    assert np.median(err) < 0.25 * np.median(swapped)
    if name == "ekf":
        assert np.median(err) < 10.0
    # locate = the last step of run
    np.testing.assert_allclose(est.locate(rho, prior, var).position, last.position)


@pytest.mark.parametrize("name", sorted(NETWORK))
def test_network_step_is_pure_and_estimate_matches_state(name):
    truth, prior, var, rho = _network()
    est = NETWORK[name]()
    s0 = est.init(prior, var)
    assert isinstance(s0, RLSState if name == "rls" else EKFState)
    before = est.estimate(s0).position.copy()
    s1 = est.step(s0, np.array([0, 1, 2]), rho[:, 0, [0, 1, 2][0]])
    np.testing.assert_array_equal(est.estimate(s0).position, before)
    assert isinstance(est.estimate(s1), Estimate)
    assert est.estimate(s1).position.shape == (3, 5, 2)


@pytest.mark.parametrize("name", sorted(NETWORK))
def test_network_batch_equals_one_by_one(name):
    truth, prior, var, rho = _network(R=4)
    rho[1, 2, 3, 0] = np.nan
    est = NETWORK[name]()
    batch = est.run(rho, prior, var)
    for r in range(4):
        one = est.run(rho[r:r + 1], prior[r:r + 1], var[r:r + 1])
        np.testing.assert_allclose(one.position[0], batch.position[r], rtol=1e-11, atol=1e-9)
        if name == "ekf":
            np.testing.assert_allclose(one.covariance[0], batch.covariance[r], rtol=1e-9,
                                       atol=1e-9)


@pytest.mark.parametrize("name", sorted(NETWORK))
def test_network_nan_link_equals_masked_link(name):
    truth, prior, var, rho = _network()
    mask = np.ones(rho.shape, bool)
    mask[:, :, 1, 3] = False
    mask[0, 2, 4, :] = False                               # a whole packet lost
    with_nan = np.where(mask, rho, np.nan)
    est = NETWORK[name]()
    a = est.run(with_nan, prior, var)
    b = est.run(rho, prior, var, mask=mask)
    np.testing.assert_array_equal(a.position, b.position)
    assert np.all(np.isfinite(a.position))
    if name == "ekf":
        np.testing.assert_array_equal(a.covariance, b.covariance)


def test_ekf_nan_packet_is_a_no_op():
    truth, prior, var, rho = _network()
    est = NetworkEKF(std_m=1.0)
    s = est.init(prior, var)
    out = est.step(s, 2, np.full((3, 5), np.nan))
    np.testing.assert_array_equal(out.mean, s.mean)
    np.testing.assert_allclose(out.covariance, s.covariance)


@pytest.mark.parametrize("name", sorted(NETWORK))
def test_network_zero_noise_converges_to_the_truth(name):
    """The EKF reaches the truth; the RLS its shape (its frame is not fixed by the priors)."""
    from radioloc.core.alignment import rigid_aligned_error
    truth, prior, var, _ = _network(R=2, K=6, prior_std=(1e-3, 15.0))
    var = np.where(np.arange(6)[None, :, None] < 3, 1e-6, var)
    prior = np.where(np.arange(6)[None, :, None] < 3, truth, prior)
    n = 60 if name == "ekf" else 400
    rho = np.broadcast_to(pairwise_distances(truth)[:, None], (2, n, 6, 6))
    est = NetworkEKF(std_m=0.1) if name == "ekf" else NetworkRLS(forgetting=0.7)
    final = est.run(rho, prior, var).position[:, :, -1]
    if name == "ekf":
        assert np.abs(final - truth).max() < 1e-3 * np.abs(prior - truth).max()
    else:
        assert rigid_aligned_error(final, truth).max() < 1e-3 * rigid_aligned_error(prior, truth).max()


@pytest.mark.parametrize("name", sorted(NETWORK))
def test_network_translating_the_scene_translates_the_estimate(name):
    truth, prior, var, rho = _network()
    shift = np.array([-4321.0, 987.0])
    est = NETWORK[name]()
    a = est.run(rho, prior, var)
    b = est.run(rho, prior + shift, var)
    np.testing.assert_allclose(b.position, a.position + shift, atol=1e-6)


@pytest.mark.parametrize("name", sorted(NETWORK))
def test_network_bad_input(name):
    truth, prior, var, rho = _network()
    est = NETWORK[name]()
    with pytest.raises(InputError, match="prior_mean"):
        est.init(prior[:, :2], var[:, :2])
    with pytest.raises(InputError, match="prior_var"):
        est.init(prior, -var)
    s = est.init(prior, var)
    with pytest.raises(InputError, match="master_idx"):
        est.step(s, 9, rho[:, 0, 0])
    with pytest.raises(InputError, match="ranges"):
        est.step(s, 0, rho[:, 0, 0, :3])
    bad = rho.copy()
    bad[0, 0, 0, 1] = np.inf
    with pytest.raises(InputError, match="ranges"):
        est.run(bad, prior, var)
    with pytest.raises(InputError, match="ranges"):
        est.run(rho[:, 0], prior, var)


def test_network_bad_settings():
    with pytest.raises(ConfigError, match="forgetting"):
        NetworkRLS(forgetting=0.0)
    with pytest.raises(ConfigError, match="prior_scale"):
        NetworkRLS(prior_scale=-1.0)
    with pytest.raises(ConfigError, match="std_m"):
        NetworkEKF(std_m=float("nan"))
