"""The compiled network EKF (paper 000, eq. (18)-eq. (23)) against the plain NumPy reference
of the same maths: range_jacobian + the toolkit's kalman_update, master by master, on random
networks with missing links; batch equals one-by-one; coincident estimates raise."""

import numpy as np
import pytest

from radioloc.core.errors import GeometryError
from radioloc.core.geometry import pairwise_distances
from radioloc.estimators.ekf import EKFState, NetworkEKF, range_jacobian
from radioloc.estimators.kalman import kalman_update, normalised_innovation_squared


def _reference_step(state, master, rho, valid, var):
    R, K = state.runs, state.nodes
    h, H = range_jacobian(state.position, master, valid)
    innov = np.where(valid, rho - h, np.nan)
    mean, cov, S, used = kalman_update(state.mean, state.covariance, innov, H,
                                       R_diag=np.full((R, K), var), valid=valid)
    rr = np.arange(R)
    nis = state.nis.copy()
    nis[rr, master] = normalised_innovation_squared(innov, S, used)
    n_used = state.used.copy()
    n_used[rr, master] = used.sum(axis=-1)
    return EKFState(mean, cov, nis, n_used)


def _draws(seed, R=7, K=6, N=4, missing=0.2):
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0, 1000, (R, K, 2))
    var = np.broadcast_to(np.where(np.arange(K) < 3, 100.0, 1e4)[None, :, None], truth.shape)
    prior = truth + rng.normal(size=truth.shape) * np.sqrt(var)
    rho = pairwise_distances(truth)[:, None] + 30.0 * rng.normal(size=(R, N, K, K))
    rho[rng.random(rho.shape) < missing] = np.nan
    return prior, np.array(var), rho


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_iterate_equals_kalman_update_master_by_master(seed):
    prior, var, rho = _draws(seed)
    ekf = NetworkEKF(range_var_m2=900.0)
    s = ekf.init(prior, var)
    ref = ekf.init(prior, var)
    R, N, K, _ = rho.shape
    for n in range(N):
        s = ekf.iterate(s, rho[:, n])
        for k in range(K):
            valid = np.isfinite(rho[:, n, k]) & (np.arange(K) != k)
            ref = _reference_step(ref, np.full(R, k), np.where(valid, rho[:, n, k], 0.0),
                                  valid, 900.0)
    np.testing.assert_allclose(s.mean, ref.mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.covariance, ref.covariance, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(s.nis, ref.nis, rtol=1e-9)
    np.testing.assert_array_equal(s.used, ref.used)


def test_step_with_per_run_masters_and_mask_equals_reference():
    prior, var, rho = _draws(5, R=5)
    ekf = NetworkEKF(range_var_m2=400.0)
    s = ekf.init(prior, var)
    master = np.array([0, 3, 5, 1, 1])
    ranges = rho[np.arange(5), 0, master]
    mask = np.random.default_rng(9).random((5, 6)) > 0.3
    got = ekf.step(s, master, ranges, mask)
    valid = mask & np.isfinite(ranges) & (np.arange(6)[None] != master[:, None])
    ref = _reference_step(s, master, np.where(valid, ranges, 0.0), valid, 400.0)
    np.testing.assert_allclose(got.mean, ref.mean, rtol=0, atol=1e-9)
    np.testing.assert_allclose(got.covariance, ref.covariance, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(got.used, ref.used)


def test_batch_equals_one_by_one_and_coincident_estimates_raise():
    prior, var, rho = _draws(3, R=4)
    ekf = NetworkEKF()
    batch = ekf.iterate(ekf.init(prior, var), rho[:, 0])
    for r in range(4):
        one = ekf.iterate(ekf.init(prior[r:r + 1], var[r:r + 1]), rho[r:r + 1, 0])
        np.testing.assert_array_equal(one.mean[0], batch.mean[r])
    prior[2, 1] = prior[2, 0]                   # master 0 goes first: link 0-1 undefined
    rho[2, 0, 0, 1] = 500.0
    with pytest.raises(GeometryError, match="run 2"):
        ekf.iterate(ekf.init(prior, var), rho[:, 0])


@pytest.mark.parametrize("seed,forgetting", [(0, 1.0), (1, 0.9), (2, 1.0)])
def test_compiled_rls_iteration_equals_the_numpy_steps(seed, forgetting):
    """NetworkRLS.iterate (compiled, all masters) against K calls of the NumPy step with the
    previous iteration's positions as reference, with missing links and a mask."""
    from radioloc.estimators.rls import NetworkRLS
    rng = np.random.default_rng(seed)
    R, K = 9, 6
    truth = rng.uniform(0, 1000, (R, K, 2))
    prior = truth + rng.normal(0, 30, truth.shape)
    est = NetworkRLS(forgetting=forgetting)
    state = ref = est.init(prior, np.full(truth.shape, 900.0))
    for _ in range(3):
        rho = pairwise_distances(truth) + rng.normal(0, 30, (R, K, K))
        rho[rng.random(rho.shape) < 0.15] = np.nan
        mask = rng.random(rho.shape) > 0.1
        state = est.iterate(state, rho, mask)
        start = ref.position
        for k in range(K):
            ref = est.step(ref, np.full(R, k), rho[:, k], mask[:, k], reference=start)
        np.testing.assert_allclose(state.position, ref.position, rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(state.information, ref.information, rtol=1e-12)
        np.testing.assert_array_equal(state.used, ref.used)


def test_compiled_rls_singular_information_names_run_and_node():
    from radioloc.estimators.rls import NetworkRLS
    R, K = 3, 4
    prior = np.zeros((R, K, 2))
    prior[:, :, 0] = np.arange(K)                    # collinear estimates, no prior weight
    est = NetworkRLS()
    state = est.init(prior, np.full(prior.shape, 1e12))
    rho = np.abs(pairwise_distances(prior) + 1.0)
    with pytest.raises(GeometryError, match="run 0, node 0"):
        est.iterate(state, rho)


@pytest.mark.parametrize("K", [6, 5])
def test_shared_master_kernels_equal_the_per_run_master_kernel(K):
    # iterate (the same master per packet in every run) runs the kernels without the
    # master's own row (K = 6: sizes fixed at compile time); they must give the numbers of
    # the per-run-master kernel exactly, missing links included
    from radioloc.estimators import ekf as E
    prior, var, rho = _draws(11 + K, R=37, K=K, N=3, missing=0.15)
    ekf = NetworkEKF(range_var_m2=900.0)
    s = ekf.init(prior, var)
    R = prior.shape[0]
    masters = np.broadcast_to(np.arange(K), (R, K))
    for n in range(3):
        valid = np.isfinite(rho[:, n]) & ~np.eye(K, dtype=bool)
        rr = np.where(valid, rho[:, n], 0.0)
        outs = []
        for kernel, ms in ((E._packets, np.ascontiguousarray(masters)),
                           (E._packets_shared, np.arange(K)),
                           (E._packets_shared6 if K == 6 else E._packets_shared, np.arange(K))):
            mean, cov = s.mean.copy(), s.covariance.copy()
            nis, used = s.nis.copy(), s.used.copy()
            err = np.full((R, 2), -1, np.int64)
            kernel(mean, cov, ms, rr, valid, 900.0, nis, used, err)
            outs.append((mean, cov, nis, used))
        for got in outs[1:]:
            for a, b in zip(got, outs[0]):
                np.testing.assert_array_equal(a, b)
        s = ekf.iterate(s, rho[:, n])
        np.testing.assert_array_equal(s.mean, outs[0][0])
