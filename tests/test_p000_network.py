"""Tests of the distributed RLS and sequential EKF network estimators (paper 000)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radioloc.core.alignment import rigid_aligned_error
from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.rng import block_generator
from radioloc.core.geometry import pairwise_distances
from radioloc.estimators.ekf import NetworkEKF, range_jacobian
from radioloc.estimators.rls import NetworkRLS, pair_rows

RLS = NetworkRLS()


def _network(R=5, K=6, seed=0, prior_std=(1.0, 30.0)):
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0.0, 1000.0, size=(R, K, 2))
    std = np.where(np.arange(K) < K // 2, prior_std[0], prior_std[1])[None, :, None]
    var = np.broadcast_to(std**2, (R, K, 2)).astype(float)
    prior = truth + rng.normal(size=truth.shape) * std
    return rng, truth, prior, var


def _align_error(est, truth):
    """Largest error after the best rigid motion (Procrustes) per run."""
    return rigid_aligned_error(est, truth).max()


# ---------------------------------------------------------------- RLS

def test_rls_pair_rows_are_linear_in_the_master_position():
    """eq. (3): with true positions and exact ranges, z = A x_k exactly."""
    _, truth, _, _ = _network(R=3)
    D = pairwise_distances(truth)
    k = np.array([0, 2, 5])
    valid = np.ones((3, 6), bool)
    valid[np.arange(3), k] = False
    A, z, w = pair_rows(truth, D[np.arange(3), k], valid)
    pred = np.einsum("rpa,ra->rp", A, truth[np.arange(3), k])
    np.testing.assert_allclose(w * z, w * pred, rtol=1e-9, atol=1e-6)
    assert np.all(w.sum(1) == 10)      # (K-1)(K-2)/2 pairs of the other nodes


def test_rls_zero_noise_recovers_the_network_shape():
    _, truth, prior, var = _network(R=4, prior_std=(0.5, 20.0))
    D = pairwise_distances(truth)
    rls = NetworkRLS(forgetting=0.7)   # lambda = 1 remembers the early linearisations
    s = rls.init(prior, var)
    for _ in range(400):
        s = rls.iterate(s, D)
    assert _align_error(s.position, truth) < 1e-3 * _align_error(prior, truth)


def test_rls_exact_start_stays_put():
    _, truth, _, var = _network(R=3)
    s = RLS.init(truth, var)
    s = RLS.iterate(s, pairwise_distances(truth))
    np.testing.assert_allclose(s.position, truth, atol=1e-7)


def test_rls_update_changes_only_the_master():
    rng, truth, prior, var = _network(R=4)
    s = RLS.init(prior, var)
    master = np.array([0, 1, 2, 3])
    D = pairwise_distances(truth) + rng.normal(size=(4, 6, 6))
    new = RLS.step(s, master, D[np.arange(4), master])
    changed = np.any(new.position != s.position, axis=-1)
    assert np.array_equal(changed, np.eye(4, 6, dtype=bool))


def test_rls_batched_equals_one_by_one():
    rng, truth, prior, var = _network(R=4)
    D = pairwise_distances(truth)
    rho = D + 10 * rng.normal(size=D.shape)
    mask = rng.uniform(size=D.shape) > 0.2
    batch = RLS.iterate(RLS.init(prior, var), rho, mask)
    for r in range(4):
        one = RLS.iterate(RLS.init(prior[r:r + 1], var[r:r + 1]), rho[r:r + 1], mask[r:r + 1])
        np.testing.assert_allclose(one.position[0], batch.position[r], rtol=1e-12)
        np.testing.assert_allclose(one.information[0], batch.information[r], rtol=1e-12)


def test_rls_missing_link_equals_dropping_its_pairs():
    """A masked range removes exactly the pairs that use it (NaN there is allowed)."""
    rng, truth, prior, var = _network(R=2)
    rho = pairwise_distances(truth)[:, 0] + rng.normal(size=(2, 6))
    mask = np.ones((2, 6), bool)
    mask[:, 3] = False
    rho_nan = rho.copy()
    rho_nan[:, 3] = np.nan
    a = RLS.step(RLS.init(prior, var), 0, rho_nan, mask)
    np.testing.assert_array_equal(RLS.step(RLS.init(prior, var), 0, rho_nan).position,
                                  a.position)          # NaN alone = the same missing link
    # same thing by hand: the node-3 pairs carry weight 0
    s = RLS.init(prior, var)
    valid = mask.copy()
    valid[:, 0] = False
    A, z, w = pair_rows(prior, np.where(mask, rho, 0.0), valid)
    info = s.information[:, 0] + np.einsum("rp,rpa,rpb->rab", w, A, A)
    step = np.linalg.solve(info, np.einsum("rpa,rp->ra", A, w * (z - np.einsum(
        "rpa,ra->rp", A, prior[:, 0])))[..., None])[..., 0]
    np.testing.assert_allclose(a.position[:, 0], prior[:, 0] + step, rtol=1e-10)
    assert np.all(w.sum(1) == 6)       # 4 remaining others -> 6 pairs


def test_rls_singular_geometry_raises():
    K = 4
    pos = np.zeros((1, K, 2))
    pos[0, :, 0] = [0.0, 100.0, 200.0, 300.0]        # all on a line
    s = RLS.init(pos, np.full((1, K, 2), 1e12))       # the prior carries no weight
    with pytest.raises(GeometryError, match="singular"):
        RLS.step(s, 0, pairwise_distances(pos)[:, 0])


def test_rls_bad_input():
    _, truth, prior, var = _network(R=2)
    s = RLS.init(prior, var)
    with pytest.raises(InputError, match="master_idx"):
        RLS.step(s, np.array([0, 7]), np.zeros((2, 6)))
    with pytest.raises(InputError, match="ranges"):
        RLS.step(s, 0, np.zeros((2, 5)))
    bad = pairwise_distances(truth)[:, 0]
    bad[1, 2] = np.inf
    with pytest.raises(InputError, match="ranges"):
        RLS.step(s, 0, bad)
    with pytest.raises(InputError, match="prior_var"):
        RLS.init(prior, np.zeros_like(var))
    with pytest.raises(ConfigError, match="forgetting"):
        NetworkRLS(forgetting=1.5)
    with pytest.raises(ConfigError, match="std_m"):
        NetworkRLS(prior_scale="transformed-noise")


# ---------------------------------------------------------------- EKF

def test_jacobian_matches_finite_differences():
    rng, truth, _, _ = _network(R=3)
    master = np.array([0, 3, 5])
    h, H = range_jacobian(truth, master)
    eps = 1e-4
    flat = truth.reshape(3, -1)
    for c in range(12):
        dp = flat.copy()
        dm = flat.copy()
        dp[:, c] += eps
        dm[:, c] -= eps
        hp, _ = range_jacobian(dp.reshape(truth.shape), master)
        hm, _ = range_jacobian(dm.reshape(truth.shape), master)
        fd = (hp - hm) / (2 * eps)
        fd[np.arange(3), master] = 0.0
        np.testing.assert_allclose(H[:, :, c], fd, atol=1e-7)


def test_jacobian_master_block_has_opposite_sign():
    """The corrected eq. (17): d|x_p - x_k|/dx_k = -d|x_p - x_k|/dx_p."""
    pos = np.array([[[0.0, 0.0], [3.0, 4.0], [10.0, 0.0]]])
    _, H = range_jacobian(pos, np.array([0]))
    np.testing.assert_allclose(H[0, 1, 2:4], [0.6, 0.8])
    np.testing.assert_allclose(H[0, 1, 0:2], [-0.6, -0.8])
    np.testing.assert_allclose(H[0, 2, 0:2], [-1.0, 0.0])
    assert np.all(H[0, 0] == 0)


def test_one_ekf_update_equals_hand_computation():
    pos = np.array([[0.0, 0.0], [3.0, 4.0], [10.0, 0.0]])
    var = np.array([[4.0, 4.0], [1.0, 1.0], [9.0, 9.0]])
    ekf = NetworkEKF(std_m=np.sqrt(2.0))
    s = ekf.init(pos[None], var[None])
    z = np.array([[0.0, 5.5, 9.0]])
    out = ekf.step(s, 0, z)
    # by hand: rows p = 1, 2 of H (2 x 6), Sigma = diag, textbook EKF update
    H = np.array([[-0.6, -0.8, 0.6, 0.8, 0.0, 0.0],
                  [-1.0, 0.0, 0.0, 0.0, 1.0, 0.0]])
    P = np.diag(var.ravel())
    S = H @ P @ H.T + 2.0 * np.eye(2)
    L = P @ H.T @ np.linalg.inv(S)
    x = pos.ravel() + L @ (np.array([5.5, 9.0]) - np.array([5.0, 10.0]))
    Pn = P - P @ H.T @ np.linalg.inv(S) @ H @ P                        # eq. (21)
    np.testing.assert_allclose(out.mean[0], x, rtol=1e-12)
    np.testing.assert_allclose(out.covariance[0], Pn, rtol=1e-10, atol=1e-12)


def test_ekf_zero_noise_converges_to_truth():
    _, truth, prior, var = _network(R=4, prior_std=(1e-3, 20.0))
    D = pairwise_distances(truth)
    ekf = NetworkEKF(std_m=0.1)
    s = ekf.init(prior, var)
    start = np.max(np.abs(prior - truth))
    for _ in range(50):
        s = ekf.iterate(s, D)
    assert np.max(np.abs(s.position - truth)) < 1e-3 * start


def test_ekf_batched_equals_one_by_one_with_missing_links():
    rng, truth, prior, var = _network(R=4)
    D = pairwise_distances(truth)
    rho = D + 10 * rng.normal(size=D.shape)
    mask = rng.uniform(size=D.shape) > 0.3
    ekf = NetworkEKF(std_m=10.0)
    batch = ekf.iterate(ekf.init(prior, var), rho, mask)
    for r in range(4):
        one = ekf.iterate(ekf.init(prior[r:r + 1], var[r:r + 1]), rho[r:r + 1], mask[r:r + 1])
        np.testing.assert_allclose(one.mean[0], batch.mean[r], rtol=1e-12)
        np.testing.assert_allclose(one.covariance[0], batch.covariance[r], rtol=1e-9, atol=1e-9)


def test_ekf_fully_masked_packet_is_a_no_op():
    _, truth, prior, var = _network(R=2)
    ekf = NetworkEKF(std_m=3.0)
    s = ekf.init(prior, var)
    out = ekf.step(s, np.array([1, 4]), np.full((2, 6), np.nan), np.zeros((2, 6), bool))
    np.testing.assert_allclose(out.mean, s.mean)
    np.testing.assert_allclose(out.covariance, s.covariance)


def test_ekf_coincident_nodes_raise():
    pos = np.zeros((1, 3, 2))
    pos[0, 2] = [5.0, 5.0]
    ekf = NetworkEKF(std_m=1.0)
    s = ekf.init(pos, np.ones((1, 3, 2)))
    with pytest.raises(GeometryError, match="coincident"):
        ekf.step(s, 0, np.array([[0.0, 1.0, 7.0]]))


def test_ekf_bad_input():
    _, truth, prior, var = _network(R=2)
    ekf = NetworkEKF(std_m=1.0)
    s = ekf.init(prior, var)
    rho = pairwise_distances(truth)[:, 0]
    with pytest.raises(ConfigError, match="std_m"):
        NetworkEKF(std_m=0.0)
    with pytest.raises(InputError, match="master_idx"):
        ekf.step(s, -1, rho)
    with pytest.raises(InputError, match="prior_mean"):
        ekf.init(prior[..., :1], var)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(0, 5))
def test_ekf_update_shrinks_covariance_and_keeps_it_symmetric(seed, k):
    rng, truth, prior, var = _network(R=3, seed=seed)
    ekf = NetworkEKF(std_m=2.0)
    s = ekf.init(prior, var)
    rho = pairwise_distances(truth)[:, k] + rng.normal(size=(3, 6))
    out = ekf.step(s, k, rho)
    np.testing.assert_allclose(out.covariance, out.covariance.transpose(0, 2, 1))
    diff = s.covariance - out.covariance            # prior - posterior is PSD
    assert np.all(np.linalg.eigvalsh(diff) > -1e-8 * np.abs(s.covariance).max())
    assert np.all(np.linalg.eigvalsh(out.covariance) > 0)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), shift=st.floats(-1e4, 1e4), angle=st.floats(0, 6.283))
def test_rls_is_equivariant_to_rigid_motions(seed, shift, angle):
    """Ranges are invariant to rigid motions: moving the priors moves the estimates."""
    rng, truth, prior, _ = _network(R=2, seed=seed)
    var = np.full_like(prior, 50.0)                  # isotropic prior so rotation commutes
    rho = pairwise_distances(truth) + rng.normal(size=(2, 6, 6))
    c, s_ = np.cos(angle), np.sin(angle)
    Q = np.array([[c, -s_], [s_, c]])
    a = RLS.iterate(RLS.init(prior, var), rho)
    b = RLS.iterate(RLS.init(prior @ Q.T + shift, var), rho)
    np.testing.assert_allclose(b.position, a.position @ Q.T + shift, atol=1e-6 * (1 + abs(shift)))


# ---------------------------------------------------------------- bound

def test_network_information_matches_jacobian_and_has_the_rigid_null_space():
    from radioloc.bounds.cooperative import network_crb, network_range_information, node_crb_trace
    _, truth, _, var = _network(R=2)
    info = network_range_information(truth, std_m=2.0)
    # the same information from the EKF Jacobians of the K masters
    ref = np.zeros_like(info)
    for k in range(6):
        _, H = range_jacobian(truth, np.full(2, k))
        ref += np.einsum("rpi,rpj->rij", H, H) / 4.0
    np.testing.assert_allclose(info, ref, atol=1e-12)
    # translations and the rotation are unobservable from ranges: rank 2K - 3
    assert np.all(np.linalg.matrix_rank(info, tol=1e-9) == 9)
    crb = network_crb(truth, std_m=2.0, prior_var=var, counts=10.0)
    assert np.all(node_crb_trace(crb) > 0)
    more = network_crb(truth, std_m=2.0, prior_var=var, counts=20.0)
    assert np.all(node_crb_trace(more) < node_crb_trace(crb))
    from radioloc.bounds.cooperative import network_crb_node_traces
    seq = network_crb_node_traces(truth, std_m=2.0, prior_var=var,
                                  counts=np.array([0.0, 10.0, 20.0]))
    np.testing.assert_allclose(seq[0], (var[..., 0] + var[..., 1]), rtol=1e-9)
    np.testing.assert_allclose(seq[1], node_crb_trace(crb), rtol=1e-8)
    np.testing.assert_allclose(seq[2], node_crb_trace(more), rtol=1e-8)


def test_network_crb_coincident_nodes_raise():
    from radioloc.bounds.cooperative import network_crb
    pos = np.zeros((1, 3, 2))
    with pytest.raises(GeometryError, match="coincide"):
        network_crb(pos, std_m=1.0, prior_var=np.ones((1, 3, 2)))


# ---------------------------------------------------------------- experiment

def test_p000_experiment_smoke(tmp_path):
    from dataclasses import replace

    from radioloc.experiments.p000_montecarlo import P000MonteCarlo
    exp = P000MonteCarlo()
    cfg = replace(exp.config(False), runs=6, block_size=6, iterations=4)
    frame = exp.run_block(cfg, np.arange(6), block_generator(0, 0))
    assert len(frame) == 6 * 5 * len(cfg.range_var_m2)
    assert np.all(np.isfinite(frame.to_numpy(dtype=float)))
    summary = exp.summarize(cfg, frame, tmp_path)
    names = {m.name for m in summary.metrics}
    for need in ("rls_final_error_m_var900", "ekf_final_error_m_var900",
                 "rls_final_error_m_var10000", "ekf_final_error_m_var10000",
                 "rls_steps_to_converge_var900", "ekf_steps_to_converge_var900",
                 "crb_rmse_m_var900", "crb_rmse_m_var10000"):
        assert need in names
    assert (tmp_path / "fig1_error_vs_iteration_var900.png").is_file()
    # iteration 0 is the prior: all methods start from the same error
    first = frame[frame.iteration == 0]
    np.testing.assert_allclose(first["rls_err_assisted_m"], first["ekf_err_assisted_m"])


# ---------------------------------------------------------------- locate

def _write_log(tmp_path, missing_prior=False):
    import pandas as pd
    rng, truth, prior, var = _network(R=1, prior_std=(10.0, 100.0))
    ids = list("ABCDEF")
    pri = pd.DataFrame({"node": ids, "x": prior[0, :, 0], "y": prior[0, :, 1],
                        "var_x": var[0, :, 0], "var_y": var[0, :, 1]})
    if missing_prior:
        pri = pri[pri.node != "F"]
    pri.to_csv(tmp_path / "priors.csv", index=False)
    D = pairwise_distances(truth)[0]
    rows = [(10 * n + k, ids[k], ids[p], "range", abs(D[k, p] + rng.normal()))
            for n in range(40) for k in range(6) for p in range(6) if p != k and (k, p) != (2, 4)]
    pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"]).to_csv(
        tmp_path / "meas.csv", index=False)
    return truth[0], ids


def test_locate_ekf_and_rls_from_csv(tmp_path):
    from radioloc.io.logs import read_measurements
    from radioloc.locate.base import LocateRequest, run_method
    truth, ids = _write_log(tmp_path)
    req = LocateRequest(read_measurements(tmp_path / "meas.csv"), priors=tmp_path / "priors.csv",
                        options={"range_std_m": "1"})
    ekf = run_method("ekf", req)
    last = ekf[ekf.time == ekf.time.max()].set_index("node").loc[ids]
    assert np.all(np.isfinite(last["uncertainty_m"]))
    err = np.linalg.norm(last[["x", "y"]].to_numpy() - truth, axis=1)
    assert np.all(err < 4 * last["uncertainty_m"].to_numpy() + 1.0)
    req.options = {"forgetting": "0.7"}  # lambda = 1 keeps the early linearisation errors
    rls = run_method("rls", req)
    assert len(rls) == len(ekf) and "uncertainty_m" not in rls.columns
    final = rls[rls.time == rls.time.max()].set_index("node").loc[ids][["x", "y"]].to_numpy()
    assert _align_error(final[None], truth[None]) < 20.0     # the shape, up to the frame


def test_locate_network_bad_priors(tmp_path):
    from radioloc.io.logs import read_measurements
    from radioloc.locate.base import LocateRequest, run_method
    _write_log(tmp_path, missing_prior=True)
    meas = read_measurements(tmp_path / "meas.csv")
    with pytest.raises(InputError, match="'F'"):
        run_method("ekf", LocateRequest(meas, priors=tmp_path / "priors.csv"))
    with pytest.raises(InputError, match="priors"):
        run_method("rls", LocateRequest(meas))
    (tmp_path / "bad.csv").write_text("node,x,y,var_x,var_y\nA,0,0,0,1\n")
    with pytest.raises(InputError, match="var_x"):
        run_method("rls", LocateRequest(meas, priors=tmp_path / "bad.csv"))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), shift=st.floats(-1e4, 1e4), angle=st.floats(0, 6.283))
def test_rigid_aligned_error_ignores_rigid_motions(seed, shift, angle):
    _, truth, prior, _ = _network(R=2, seed=seed)
    c, s_ = np.cos(angle), np.sin(angle)
    moved = truth @ np.array([[c, -s_], [s_, c]]).T + shift
    assert rigid_aligned_error(moved, truth).max() < 1e-6 * (1 + abs(shift))
    assert rigid_aligned_error(prior, truth).max() > 0.1


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), shift=st.floats(-1e4, 1e4))
def test_ekf_is_equivariant_to_translations(seed, shift):
    rng, truth, prior, var = _network(R=2, seed=seed)
    rho = pairwise_distances(truth) + rng.normal(size=(2, 6, 6))
    ekf = NetworkEKF(std_m=2.0)
    a = ekf.iterate(ekf.init(prior, var), rho)
    b = ekf.iterate(ekf.init(prior + shift, var), rho)
    np.testing.assert_allclose(b.position, a.position + shift, atol=1e-6 * (1 + abs(shift)))
    np.testing.assert_allclose(b.covariance, a.covariance, rtol=1e-6, atol=1e-6)


def test_p000_planted_diverged_run_is_counted_and_does_not_decide(tmp_path):
    from dataclasses import replace

    from radioloc.experiments.p000_montecarlo import P000MonteCarlo
    exp = P000MonteCarlo()
    cfg = replace(exp.config(False), runs=8, block_size=8, iterations=6)
    frame = exp.run_block(cfg, np.arange(8), block_generator(0, 0))
    clean = exp.summarize(cfg, frame[frame.run != 3], tmp_path / "clean")
    planted = frame.copy()
    # run 3 at 10,000 m^2 blows up exponentially in the RLS (as run 4707 of the full run)
    hit = (planted.run == 3) & (planted.range_var_m2 == 10_000.0)
    for c in ("assisted", "unassisted"):
        planted.loc[hit, f"rls_err_{c}_m"] = 10.0 ** (planted.loc[hit, "iteration"] * 8.0)
        planted.loc[hit, f"rls_sqerr_{c}_m2"] = 10.0 ** (planted.loc[hit, "iteration"] * 16.0)
    planted.loc[hit & (planted.iteration == 6), "rls_err_unassisted_m"] = np.inf
    s = exp.summarize(cfg, planted, tmp_path / "planted")
    m = {x.name: x.value for x in s.metrics}
    mc = {x.name: x.value for x in clean.metrics}
    assert m["rls_diverged_runs_var10000"] == 1 and m["ekf_diverged_runs_var10000"] == 0
    assert m["rls_diverged_runs_var900"] == 0
    assert not np.isfinite(m["rls_final_error_m_all_runs_var10000"])
    # the mean over the runs that did not diverge is the mean without the planted run
    assert m["rls_final_error_m_var10000"] == pytest.approx(mc["rls_final_error_m_var10000"])
    assert m["rls_steps_to_converge_var10000"] == mc["rls_steps_to_converge_var10000"]
    assert np.isfinite(m["rls_final_median_error_m_var10000"])
    # the EKF's numbers do not move (its own runs are all kept)
    full = exp.summarize(cfg, frame, tmp_path / "full")
    mf = {x.name: x.value for x in full.metrics}
    assert m["ekf_final_error_m_var10000"] == pytest.approx(mf["ekf_final_error_m_var10000"])
    assert m["rls_final_median_error_m_var900"] == pytest.approx(mf["rls_final_median_error_m_var900"])


def test_p000_robust_curves_median_and_kept_runs():
    import pandas as pd

    from radioloc.experiments.p000_montecarlo import METHODS, robust_curves
    it = np.arange(3)
    rows = []
    for r, scale in enumerate([1.0, 2.0, 3.0, np.nan]):
        for i in it:
            row = {"run": r, "iteration": i, "crb_assisted_m2": 1.0, "crb_unassisted_m2": 1.0}
            for m in METHODS:
                v = (scale if np.isfinite(scale) or i < 2 else np.nan) * (i + 1)
                if not np.isfinite(scale) and i < 2:
                    v = 1e9 * (i + 1)
                for c in ("assisted", "unassisted"):
                    row[f"{m}_err_{c}_m"] = v
                    row[f"{m}_sqerr_{c}_m2"] = v * v
                row[f"{m}_aligned_err_m"] = v
            rows.append(row)
    rob = robust_curves(pd.DataFrame(rows), {"assisted": 0.5, "unassisted": 0.5}, 1e4)
    assert rob["kept"]["rls"].tolist() == [True, True, True, False]
    np.testing.assert_allclose(rob["curves"]["rls_err_assisted_m"], [2.0, 4.0, 6.0])
    assert rob["per_run"]["ekf"].shape == (4, 3)


# full-size (5000 runs, seed 0) reproduction, docs/p000.md
P000_FULL = {("ekf", 900.0, "mean"): 11.2033, ("ekf", 10_000.0, "mean"): 13.758,
             ("rls", 900.0, "median"): 175.3689, ("rls", 10_000.0, "median"): 282.3243}
P000_FULL_VERDICTS = [False, False, False, True, False, False, True]   # settling time per run


def test_p000_reproduction_at_reduced_size_holds_the_full_numbers_and_verdicts(tmp_path):
    """100 runs: the headline numbers lie within 3 Monte Carlo standard errors of the full
    run's, and every claim has the full run's verdict."""
    from dataclasses import replace

    from radioloc.experiments.p000_montecarlo import P000MonteCarlo, robust_curves
    exp = P000MonteCarlo()
    cfg = replace(exp.config(False), runs=100, block_size=100)
    frame = exp.run_block(cfg, np.arange(100), block_generator(0, 0))
    s = exp.summarize(cfg, frame, tmp_path)
    m = {x.name: x.value for x in s.metrics}
    wt = {"assisted": 0.5, "unassisted": 0.5}
    for (meth, rv, stat), full in P000_FULL.items():
        rob = robust_curves(frame[frame.range_var_m2 == rv], wt, cfg.diverged_m)
        fin = rob["per_run"][meth][rob["kept"][meth], -1]
        se = fin.std(ddof=1) / np.sqrt(fin.size) * (1.2533 if stat == "median" else 1.0)
        tag = f"var{rv:g}"
        value = m[f"{meth}_final_error_m_{tag}" if stat == "mean" else f"{meth}_final_median_error_m_{tag}"]
        assert abs(value - full) <= 3 * se, (meth, rv, stat, value, full, se)
    assert [c.holds for c in s.claims] == P000_FULL_VERDICTS
