"""BatchSmoother: the MAP trajectory by sparse Gauss-Newton, with robust and max-mixture losses."""

from __future__ import annotations

import time
from typing import ClassVar

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.batch_smoother import BatchSmoother, block_tridiagonal_marginals
from radioloc.estimators.kalman import kalman_predict, kalman_update
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, MeasurementModel, Observation
from radioloc.models.motion import WhiteAccelerationCV
from radioloc.models.ranging import RangeModel

from model_cases import MinimalBearing

ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]])
RING = np.c_[30 * np.cos(np.arange(8) * np.pi / 4), 30 * np.sin(np.arange(8) * np.pi / 4)] + 15


class Position(MeasurementModel):
    """A position fix (linear): only ``predict`` and ``std``."""

    kind: ClassVar[str] = "position"

    def __init__(self, std_m: float) -> None:
        self.std_m = std_m

    def predict(self, state, context):
        # one row per coordinate; the context's two (unused) points give the row count
        return state["position"] + 0.0 * context.points[..., 0]

    def std(self, context):
        return self.row_std(self.std_m, context)



def simulate(runs, steps, dt=0.1, q=0.5, seed=0):
    """Constant-velocity trajectories ``(runs, steps, 4)`` from the motion model."""
    rng = np.random.default_rng(seed)
    motion = WhiteAccelerationCV(q)
    L = np.linalg.cholesky(motion.Q(dt))
    x = np.zeros((runs, steps, 4))
    x[:, 0] = [12.0, 14.0, 1.0, 0.5]
    for t in range(1, steps):
        x[:, t] = x[:, t - 1] @ motion.F(dt).T + rng.standard_normal((runs, 4)) @ L.T
    return motion, x, np.arange(steps) * dt, rng


def range_obs(x, std, rng, anchors=ANCHORS):
    d = np.linalg.norm(x[..., None, :2] - anchors, axis=-1)
    return Observation(RangeModel(std_m=std), d + std * rng.standard_normal(d.shape),
                       Context(points=anchors))


def rmse(track, x):
    return float(np.sqrt(np.mean(np.sum((track.position - x[..., :2]) ** 2, -1))))


def test_zero_noise_converges_to_the_truth():
    motion, x, t, rng = simulate(2, 100)
    obs = range_obs(x, 1e-6, rng)
    tr = BatchSmoother(motion).run(obs, t, prior_mean=x[:, 0], prior_cov=np.eye(4))
    assert rmse(tr, x) < 1e-4
    assert tr.diagnostics["converged"].all()


def test_batch_equals_one_by_one_and_translation():
    motion, x, t, rng = simulate(3, 60, seed=1)
    obs = range_obs(x, 0.1, rng)
    z = obs.z.copy()
    z[1, 10:20, :2] = np.nan
    obs = Observation(obs.model, z, obs.context)
    sm = BatchSmoother(motion, loss="huber", loss_scale=2.0)
    tr = sm.run(obs, t, prior_mean=x[:, 0], prior_cov=np.eye(4))
    for i in range(3):
        one = sm.run(Observation(obs.model, z[i], obs.context), t, prior_mean=x[i, 0],
                     prior_cov=np.eye(4))
        np.testing.assert_allclose(tr.position[i], one.position, atol=1e-7)
        np.testing.assert_allclose(tr.covariance[i], one.covariance, rtol=1e-6, atol=1e-12)
    shift = np.array([500.0, -300.0])
    moved = sm.run(Observation(obs.model, z, Context(points=ANCHORS + shift)), t,
                   prior_mean=x[:, 0] + np.r_[shift, 0, 0], prior_cov=np.eye(4))
    np.testing.assert_allclose(moved.position, tr.position + shift, atol=1e-6)


def test_marginal_covariances_are_consistent():
    motion, x, t, rng = simulate(40, 100, seed=2)
    tr = BatchSmoother(motion).run(range_obs(x, 0.3, rng), t, prior_mean=x[:, 0],
                                   prior_cov=np.eye(4))
    e = tr.position - x[..., :2]
    nees = np.einsum("...i,...ij,...j->...", e, np.linalg.inv(tr.covariance), e)
    assert 1.7 < nees.mean() < 2.3                     # measured 2.04
    inside = np.mean(nees < 5.991)                       # 95 % ellipses
    assert 0.9 < inside < 0.99                         # measured 0.945


def test_block_recursion_equals_the_dense_inverse():
    rng = np.random.default_rng(3)
    n, T = 3, 6
    A = rng.standard_normal((T * n, T * n))
    band = np.abs(np.subtract.outer(np.arange(T * n) // n, np.arange(T * n) // n)) <= 1
    H = (A @ A.T + T * n * np.eye(T * n)) * band
    D = np.stack([H[t * n:(t + 1) * n, t * n:(t + 1) * n] for t in range(T)])
    O = np.stack([H[t * n:(t + 1) * n, (t + 1) * n:(t + 2) * n] for t in range(T - 1)])
    inv = np.linalg.inv(H)
    dense = np.stack([inv[t * n:(t + 1) * n, t * n:(t + 1) * n] for t in range(T)])
    np.testing.assert_allclose(block_tridiagonal_marginals(D, O), dense, rtol=1e-10, atol=1e-14)


def rts(z, t, motion, std, m0, P0):
    """Kalman filter and Rauch-Tung-Striebel smoother of position fixes (the reference)."""
    T = z.shape[-2]
    H = np.eye(2, 4)
    means, covs, preds = [], [], []
    m, P = m0, P0
    for k in range(T):
        if k:
            m, P = kalman_predict(m, P, motion.F(t[k] - t[k - 1]), motion.Q(t[k] - t[k - 1]))
        preds.append((m, P))
        m, P, _, _ = kalman_update(m, P, z[..., k, :] - m[..., :2], H,
                                   R_diag=np.full(2, std ** 2))
        means.append(m)
        covs.append(P)
    ms, Ps = [means[-1]], [covs[-1]]
    for k in range(T - 2, -1, -1):
        F = motion.F(t[k + 1] - t[k])
        mp, Pp = preds[k + 1]
        G = covs[k] @ F.T @ np.linalg.inv(Pp)
        ms.insert(0, means[k] + np.einsum("...ij,...j->...i", G, ms[0] - mp))
        Ps.insert(0, covs[k] + G @ (Ps[0] - Pp) @ np.swapaxes(G, -1, -2))
    return np.stack(ms, -2), np.stack(Ps, -3)


def test_equals_the_rts_smoother_on_a_linear_gaussian_model():
    motion, x, t, rng = simulate(5, 80, seed=4)
    z = x[..., :2] + 0.5 * rng.standard_normal(x[..., :2].shape)
    z[:, 30:40] = np.nan                                # a gap: the motion model bridges it
    ctx = Context(points=np.zeros((2, 2)))
    m0 = x[:, 0] + rng.standard_normal((5, 4))
    P0 = np.eye(4)
    tr = BatchSmoother(motion).run(Observation(Position(0.5), z, ctx), t, prior_mean=m0,
                                   prior_cov=P0)
    ms, Ps = rts(z, t, motion, 0.5, m0, P0)
    np.testing.assert_allclose(tr.diagnostics["state"], ms, atol=1e-6)
    np.testing.assert_allclose(tr.diagnostics["state_covariance"], Ps, rtol=1e-5, atol=1e-9)
    assert rmse(tr, x) <= 1.01 * float(np.sqrt(np.mean(np.sum((ms[..., :2] - x[..., :2]) ** 2, -1))))


def test_max_mixture_beats_the_gaussian_on_los_nlos_ranges():
    motion, x, t, rng = simulate(4, 200, seed=5)
    noise = LosNlosRange(los_std_m=0.1, nlos_mean_m=4.0, alpha=0.6)
    model = RangeModel(noise=noise)
    ctx = Context(points=RING)
    z = model.sample({"position": x[..., :2]}, ctx, rng)
    obs = Observation(model, z, ctx)
    plain = BatchSmoother(motion).run(obs, t, prior_mean=x[:, 0], prior_cov=np.eye(4))
    mm = BatchSmoother(motion, los_nlos=noise).run(obs, t, prior_mean=x[:, 0],
                                                  prior_cov=np.eye(4))
    # measured: 0.47 m (the Gaussian of the mixture's moments) against 0.050 m
    assert rmse(mm, x) < 0.25 * rmse(plain, x)
    los = mm.diagnostics["los_detected"]
    assert los.shape == z.shape and 0.5 < los.mean() < 0.7


def test_robust_loss_beats_linear_with_outliers():
    motion, x, t, rng = simulate(4, 200, seed=6)
    obs = range_obs(x, 0.1, rng, RING)
    z = obs.z.copy()
    out = rng.random(z.shape) < 0.2
    z[out] += rng.uniform(10, 30, out.sum())
    obs = Observation(obs.model, z, obs.context)
    err = {loss: rmse(BatchSmoother(motion, loss=loss, loss_scale=3.0).run(
        obs, t, prior_mean=x[:, 0], prior_cov=np.eye(4)), x) for loss in ("linear", "huber",
                                                                         "cauchy")}
    # measured: linear 4.9 m, huber 0.10 m, cauchy 0.043 m
    assert err["huber"] < 0.1 * err["linear"] and err["cauchy"] < 0.1 * err["linear"]


def test_runs_a_bearing_model_with_a_numerical_jacobian():
    motion, x, t, rng = simulate(2, 50, seed=7)
    pts = np.array([[-20.0, 0.0], [0.0, -20.0], [40.0, 40.0]])
    model = MinimalBearing(0.01)
    ctx = Context(points=pts)
    z = model.sample({"position": x[..., :2]}, ctx, rng)
    tr = BatchSmoother(motion).run(Observation(model, z, ctx), t, prior_mean=x[:, 0],
                                   prior_cov=np.eye(4))
    assert rmse(tr, x) < 0.3 and tr.diagnostics["converged"].all()


def test_ten_thousand_steps_in_seconds():
    # a circle of 10 m radius at 1 m/s inside the ring (a simulated random walk in
    # velocity leaves the anchors far behind over 1000 s)
    rng = np.random.default_rng(8)
    t = np.arange(10_000) * 0.1
    x = 15 + 10 * np.stack([np.cos(t / 10), np.sin(t / 10)], -1)[None]
    motion = WhiteAccelerationCV(0.5)
    obs = range_obs(x, 0.1, rng, RING)
    x = np.concatenate([x, np.stack([-np.sin(t / 10), np.cos(t / 10)], -1)[None]], -1)
    cpu = time.process_time()
    tr = BatchSmoother(motion).run(obs, t, prior_mean=x[:, 0], prior_cov=np.eye(4))
    cpu = time.process_time() - cpu
    assert tr.diagnostics["converged"].all() and rmse(tr, x) < 0.1
    print(f"10^4 steps: {cpu:.1f} s of CPU")
    assert cpu < 30.0


def test_bad_input_names_the_argument():
    motion, x, t, rng = simulate(1, 10)
    obs = range_obs(x, 0.1, rng)
    sm = BatchSmoother(motion)
    with pytest.raises(ConfigError, match="motion"):
        BatchSmoother("cv")
    with pytest.raises(ConfigError, match="loss"):
        BatchSmoother(motion, loss="l1")
    with pytest.raises(ConfigError, match="null_hypothesis"):
        BatchSmoother(motion, null_hypothesis=(0.1, 5.0))
    with pytest.raises(InputError, match="time"):
        sm.run(obs, t[:5], prior_mean=x[:, 0], prior_cov=np.eye(4))
    with pytest.raises(InputError, match="time"):
        sm.run(obs, t[::-1], prior_mean=x[:, 0], prior_cov=np.eye(4))
    with pytest.raises(InputError, match="prior_cov"):
        sm.run(obs, t, prior_mean=x[:, 0], prior_cov=-np.eye(4))
    lopsided = np.eye(4)
    lopsided[1, 3] = -0.3                 # was symmetrised without a word
    with pytest.raises(InputError, match=r"prior_cov: not symmetric \(entry \(.*1, 3\)\)"):
        sm.run(obs, t, prior_mean=x[:, 0], prior_cov=lopsided)
    with pytest.raises(InputError, match="prior_mean"):
        sm.run(obs, t, prior_mean=np.zeros(3), prior_cov=np.eye(3))
    with pytest.raises(InputError, match="initial"):
        sm.run(obs, t, prior_mean=x[:, 0], prior_cov=np.eye(4), initial=np.zeros((3, 2)))
    with pytest.raises(InputError, match="observations"):
        sm.run([obs, 3], t, prior_mean=x[:, 0], prior_cov=np.eye(4))


def test_smooth_log_tracks_every_node_of_a_range_log():
    import pandas as pd

    from radioloc.locate.base import LocateRequest
    from radioloc.locate.batch_smooth import smooth_log

    motion, x, t, rng = simulate(2, 120, seed=9)
    rows = []
    for k, node in enumerate(("tag1", "tag2")):
        for i in range(len(t)):
            a = i % 4                                        # one anchor per time stamp
            d = np.linalg.norm(x[k, i, :2] - ANCHORS[a]) + 0.05 * rng.standard_normal()
            rows.append((t[i], node, f"A{a}", "range", d))
    meas = pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"])
    anchors = pd.DataFrame({"id": [f"A{a}" for a in range(4)], "x": ANCHORS[:, 0],
                            "y": ANCHORS[:, 1]})
    opts = {"los_std_m": "0.05", "nlos_mean_m": "2", "alpha": "0.9"}
    out = smooth_log(LocateRequest(meas, anchors, options=opts))
    assert list(out.columns[:4]) == ["time", "node", "x", "y"] and len(out) == 240
    for k, node in enumerate(("tag1", "tag2")):
        got = out[out.node == node][["x", "y"]].to_numpy()
        assert np.sqrt(np.mean(np.sum((got - x[k, :, :2]) ** 2, -1))) < 0.3
    with pytest.raises(ConfigError, match="loss"):
        smooth_log(LocateRequest(meas, anchors, options={"loss": "l1", **opts}))
