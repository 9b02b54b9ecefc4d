"""The network EKF and RLS of paper 000: the compiled backend against the NumPy definition
(the generic EKF update of PairRangeModel rows per packet, eq. (13)-eq. (25);
NetworkRLS.step per master, eq. (8)-eq. (11)) through the public API, and the invariants
of both."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, GeometryError
from radioloc.core.geometry import pairwise_distances
from radioloc.estimators.ekf import NetworkEKF, range_jacobian
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter, FilterState
from radioloc.estimators.kalman import kalman_update
from radioloc.estimators.rls import NetworkRLS
from radioloc.models.measurement import Observation
from radioloc.models.motion import RandomWalk
from radioloc.models.pair_range import NetworkLayout, PairContext, PairRangeModel

TOL = 1e-10


def _draws(seed, R=7, K=6, N=4, missing=0.2):
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0, 1000, (R, K, 2))
    var = np.broadcast_to(np.where(np.arange(K) < 3, 100.0, 1e4)[None, :, None], truth.shape)
    prior = truth + rng.normal(size=truth.shape) * np.sqrt(var)
    rho = pairwise_distances(truth)[:, None] + 30.0 * rng.normal(size=(R, N, K, K))
    rho[rng.random(rho.shape) < missing] = np.nan
    return truth, prior, np.array(var), rho


def _close(a, b):
    np.testing.assert_allclose(a, b, rtol=0, atol=TOL * max(np.abs(b).max(), 1.0))


@pytest.mark.parametrize("K", [6, 4])
def test_ekf_backends_agree(K):
    _, prior, var, rho = _draws(K, R=9, K=K, N=5)
    got, ref = (NetworkEKF(std_m=30.0, backend=b).run(rho, prior, var) for b in ("numba", "numpy"))
    _close(got.position, ref.position)
    _close(got.covariance, ref.covariance)
    for name in ("nis", "measurements_used"):
        _close(got.diagnostics[name], ref.diagnostics[name])


def test_ekf_step_with_per_run_masters_and_mask_backends_agree():
    _, prior, var, rho = _draws(5, R=5)
    master = np.array([0, 3, 5, 1, 1])
    ranges = rho[np.arange(5), 0, master]
    mask = np.random.default_rng(9).random((5, 6)) > 0.3
    out = []
    for b in ("numba", "numpy"):
        ekf = NetworkEKF(std_m=20.0, backend=b)
        out.append(ekf.step(ekf.init(prior, var), master, ranges, mask))
    _close(out[0].mean, out[1].mean)
    _close(out[0].covariance, out[1].covariance)
    np.testing.assert_array_equal(out[0].used, out[1].used)


def test_ekf_numpy_backend_is_the_generic_ekf_update_of_pair_ranges():
    _, prior, var, rho = _draws(2, R=4)
    ekf = NetworkEKF(std_m=30.0, backend="numpy")
    s = ekf.init(prior, var)
    master = np.full(4, 2)
    got = ekf.step(s, master, rho[:, 0, 2])
    # the generic filter, one observation of the rows p -> master (p != master)
    others = np.array([0, 1, 3, 4, 5])
    ctx = PairContext(points=np.zeros((5, 2)), pairs=np.stack([others, np.full(5, 2)], -1))
    state = FilterState(s.mean, s.covariance, 0.0, NetworkLayout(dim=2, nodes=6))
    ref, _ = ExtendedKalmanFilter(RandomWalk(0.0), gate=None).update(
        state, Observation(PairRangeModel(std_m=30.0), rho[:, 0, 2, others], ctx))
    np.testing.assert_array_equal(got.mean, ref.mean)
    np.testing.assert_array_equal(got.covariance, ref.covariance)
    # and, to rounding, eq. (19)-eq. (23) with the Jacobian of eq. (16)-eq. (17)
    valid = np.isfinite(rho[:, 0, 2]) & (np.arange(6) != 2)
    h, H = range_jacobian(s.position, master, valid)
    mean, cov, _, _ = kalman_update(s.mean, s.covariance, np.where(valid, rho[:, 0, 2] - h, np.nan),
                                    H, R_diag=np.full((4, 6), 900.0), valid=valid)
    _close(got.mean, mean)
    _close(got.covariance, cov)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_ekf_batch_equals_one_by_one_and_coincident_estimates_raise(backend):
    _, prior, var, rho = _draws(3, R=4)
    ekf = NetworkEKF(backend=backend)
    batch = ekf.iterate(ekf.init(prior, var), rho[:, 0])
    for r in range(4):
        one = ekf.iterate(ekf.init(prior[r:r + 1], var[r:r + 1]), rho[r:r + 1, 0])
        np.testing.assert_allclose(one.mean[0], batch.mean[r], rtol=1e-13)
    prior[2, 1] = prior[2, 0]                   # master 0 goes first: link 0-1 undefined
    rho[2, 0, 0, 1] = 500.0
    with pytest.raises(GeometryError, match="run 2: nodes 0 and 1"):
        ekf.iterate(ekf.init(prior, var), rho[:, 0])


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_ekf_noise_free_ranges_converge_to_the_truth(backend):
    truth, _, _, _ = _draws(4, R=3, missing=0.0)
    prior = truth + np.random.default_rng(1).normal(0, 5.0, truth.shape)
    rho = np.broadcast_to(pairwise_distances(truth)[:, None], (3, 30, 6, 6))
    track = NetworkEKF(std_m=0.01, backend=backend).run(rho, prior, np.full(truth.shape, 25.0))
    # exact ranges fix the network up to a rigid motion: every inter-node distance converges
    np.testing.assert_allclose(pairwise_distances(track.position[:, :, -1]),
                               pairwise_distances(truth), atol=0.05)


def test_backend_setting_is_validated():
    for cls in (NetworkEKF, NetworkRLS):
        with pytest.raises(ConfigError, match="backend"):
            cls(backend="fortran")


@pytest.mark.parametrize("seed,forgetting", [(0, 1.0), (1, 0.9)])
def test_rls_backends_agree(seed, forgetting):
    rng = np.random.default_rng(seed)
    R, K = 9, 6
    truth = rng.uniform(0, 1000, (R, K, 2))
    prior = truth + rng.normal(0, 30, truth.shape)
    ests = [NetworkRLS(forgetting=forgetting, std_m=30.0, backend=b)
            for b in ("numba", "numpy")]
    states = [e.init(prior, np.full(truth.shape, 900.0)) for e in ests]
    for _ in range(3):
        rho = pairwise_distances(truth) + rng.normal(0, 30, (R, K, K))
        rho[rng.random(rho.shape) < 0.15] = np.nan
        mask = rng.random(rho.shape) > 0.1
        states = [e.iterate(s, rho, mask) for e, s in zip(ests, states)]
        _close(states[0].position, states[1].position)
        _close(states[0].information, states[1].information)
        np.testing.assert_array_equal(states[0].used, states[1].used)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_rls_singular_information_names_run_and_node(backend):
    R, K = 3, 4
    prior = np.zeros((R, K, 2))
    prior[:, :, 0] = np.arange(K)                    # collinear estimates, no prior weight
    est = NetworkRLS(backend=backend)
    state = est.init(prior, np.full(prior.shape, 1e12))
    rho = np.abs(pairwise_distances(prior) + 1.0)
    with pytest.raises(GeometryError, match="run 0, node 0"):
        est.iterate(state, rho)
