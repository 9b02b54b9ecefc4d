"""Contract tests of paper 001's estimators: P2PParticleFilter, the peer EKF on RangeEKF,
LocalML and Ransac (types, shapes, (x, y) order, batch vs one-by-one, NaN skipped, models
as arguments, bad input)."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track
from radioloc.estimators.base import RecursiveEstimator, SnapshotEstimator
from radioloc.estimators.ekf_ranging import run_peer_ekf
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.estimators.p2p_particle import P2PParticleFilter, ParticleState
from radioloc.estimators.snapshot_baselines import LocalML, Ransac
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import ConstantVelocity, InputDriven, RandomWalk

ANCHORS = np.array([[0.0, 0.0], [40.0, 0.0], [0.0, 8.0], [40.0, 8.0], [20.0, 1.0], [20.0, 7.0]])
T = 30


def _one_vehicle(runs=2, seed=0, noise=0.02, ins_std=0.02):
    """One vehicle per run driving along x (x from 5 m, y about 2.5 m: far from symmetric),
    all-LOS ranges to the anchors; ranges (R, 1, T, 1 + M) with the self column NaN."""
    rng = np.random.default_rng(seed)
    t = np.arange(T + 1)
    x = 5.0 + 0.4 * t + rng.uniform(0, 1, (runs, 1))
    y = 2.5 + 0.3 * np.sin(t / 6.0) + rng.uniform(0, 0.5, (runs, 1))
    truth = np.stack([x, y], axis=-1)[:, None]                          # (R, 1, T + 1, 2)
    d = np.linalg.norm(truth[:, :, 1:, None, :] - ANCHORS, axis=-1)      # (R, 1, T, M)
    r = d + noise * rng.standard_normal(d.shape)
    ranges = np.concatenate([np.full(d.shape[:-1] + (1,), np.nan), r], axis=-1)
    ins = np.diff(truth, axis=2) + ins_std * rng.standard_normal(truth[:, :, 1:].shape)
    return truth, ranges, ins


MODEL = LosNlosRange(0.02, 5.0, 0.9)


def _pf(**kw):
    kw.setdefault("particles", 300)
    kw.setdefault("init_std", 0.3)
    kw.setdefault("reset_std_m", 0.1)
    return P2PParticleFilter(kw.pop("motion", InputDriven(0.02)), MODEL, **kw)


# ------------------------------------------------------------------ particle filter
def test_pf_types_shapes_and_xy_order():
    truth, ranges, ins = _one_vehicle()
    pf = _pf()
    assert isinstance(pf, RecursiveEstimator)
    rng = np.random.default_rng(1)
    state = pf.init(truth[:, :, 0], rng)
    assert isinstance(state, ParticleState) and state.particles.shape == (2, 1, 300, 2)
    nodes = np.concatenate([truth[:, :, 0], np.broadcast_to(ANCHORS, (2,) + ANCHORS.shape)], 1)
    state = pf.step(state, ranges[:, :, 0], nodes, rng, control=ins[:, :, 0])
    est = pf.estimate(state)
    assert isinstance(est, Estimate) and est.position.shape == (2, 1, 2)
    assert est.covariance.shape == (2, 1, 2, 2)
    assert est.diagnostics["ess"].shape == (2, 1) and est.diagnostics["los_detected"].shape == (2, 1, 7)
    track = pf.run(ranges, truth[:, :, 0], np.random.default_rng(1), anchors=ANCHORS, controls=ins)
    assert isinstance(track, Track)
    assert track.position.shape == (2, 1, T, 2) and track.covariance.shape == (2, 1, T, 2, 2)
    assert track.diagnostics["ess"].shape == (2, 1, T)
    assert track.diagnostics["los_detected"].shape == (2, 1, T, 7)
    assert track.diagnostics["resets"].shape == (2, 1, T)
    err = track.error(truth[:, :, 1:])
    # (x, y) order: x runs 5..18 m, y about 2.5 m; a swapped order would be metres off
    assert err[..., 5:].mean() < 0.1 and err.max() < 0.5
    assert np.all(np.isfinite(track.covariance))


def test_pf_nan_range_equals_masked_link():
    truth, ranges, ins = _one_vehicle()
    gone = ranges.copy()
    gone[..., 3] = np.nan                                              # anchor 2 never heard
    gone[:, :, 10:15, 5] = np.nan                                      # anchor 4 drops out
    pf = _pf()
    a = pf.run(gone, truth[:, :, 0], np.random.default_rng(5), anchors=ANCHORS, controls=ins)
    b = pf.run(np.delete(gone, 3, axis=-1), truth[:, :, 0], np.random.default_rng(5),
               anchors=np.delete(ANCHORS, 2, axis=0), controls=ins)
    np.testing.assert_array_equal(a.position, b.position)
    assert np.all(np.isfinite(a.position))
    assert not a.diagnostics["los_detected"][..., 3].any()


@pytest.mark.parametrize("motion", [ConstantVelocity(0.05), RandomWalk(0.05)])
def test_pf_without_ins(motion):
    truth, ranges, _ = _one_vehicle(noise=0.02)
    pf = _pf(motion=motion, particles=400, init_std=0.3)
    init = truth[:, :, 0]
    if motion.state_dim == 4:
        init = np.concatenate([init, np.broadcast_to([0.4, 0.0], init.shape)], axis=-1)
    track = pf.run(ranges, init, np.random.default_rng(2), anchors=ANCHORS, time=np.arange(T) * 1.0)
    err = track.error(truth[:, :, 1:])
    assert np.all(np.isfinite(err)) and err[..., 5:].mean() < 0.2
    assert track.diagnostics["state"].shape == (2, 1, T, motion.state_dim)
    if motion.state_dim == 4:
        vx = track.diagnostics["state"][..., 10:, 2]
        assert abs(vx.mean() - 0.4) < 0.1


def test_pf_bad_input():
    truth, ranges, ins = _one_vehicle()
    pf = _pf()
    rng = np.random.default_rng(0)
    with pytest.raises(InputError, match="control"):
        pf.run(ranges, truth[:, :, 0], rng, anchors=ANCHORS)
    with pytest.raises(InputError, match="ranges"):
        pf.run(ranges[..., :-1], truth[:, :, 0], rng, anchors=ANCHORS, controls=ins)
    bad = ranges.copy()
    bad[0, 0, 3, 2] = np.inf
    with pytest.raises(InputError, match="ranges"):
        pf.run(bad, truth[:, :, 0], rng, anchors=ANCHORS, controls=ins)
    with pytest.raises(InputError, match="initial"):
        pf.run(ranges, np.zeros((2, 1, 3)), rng, anchors=ANCHORS, controls=ins)
    with pytest.raises(InputError, match="initial"):
        pf.run(ranges, np.zeros((2, 3, 2)), rng, anchors=ANCHORS, controls=ins)
    with pytest.raises(ConfigError, match="init_std"):
        _pf(init_std=-1.0)
    with pytest.raises(ConfigError, match="motion"):
        P2PParticleFilter(InputDriven(0.1, dim=3), MODEL)


# ------------------------------------------------------------------ peer EKF
def test_peer_ekf_contract():
    truth, ranges, ins = _one_vehicle()
    ekf = RangeEKF(InputDriven(0.02), MODEL)
    tr = run_peer_ekf(ekf, ranges, truth[:, :, 0], init_std_m=0.3, anchors=ANCHORS, controls=ins)
    assert isinstance(tr, Track) and tr.position.shape == (2, 1, T, 2)
    assert tr.covariance.shape == (2, 1, T, 2, 2) and tr.diagnostics["nis"].shape == (2, 1, T)
    # moment-matched LOS/NLOS noise (bias 0.5 m at alpha = 0.9) on all-LOS ranges: biased,
    # but in (x, y) order and within a metre
    assert tr.error(truth[:, :, 1:]).max() < 1.0
    one = run_peer_ekf(ekf, ranges[1:], truth[1:, :, 0], init_std_m=0.3, anchors=ANCHORS,
                       controls=ins[1:])
    np.testing.assert_array_equal(one.position[0], tr.position[1])
    gone = ranges.copy()
    gone[..., 3] = np.nan
    a = run_peer_ekf(ekf, gone, truth[:, :, 0], init_std_m=0.3, anchors=ANCHORS, controls=ins)
    b = run_peer_ekf(ekf, np.delete(gone, 3, axis=-1), truth[:, :, 0], init_std_m=0.3,
                     anchors=np.delete(ANCHORS, 2, axis=0), controls=ins)
    np.testing.assert_array_equal(a.position, b.position)
    with pytest.raises(InputError, match="ranges"):
        run_peer_ekf(ekf, ranges[..., :-1], truth[:, :, 0], init_std_m=0.3, anchors=ANCHORS)
    # a range pushed below zero by noise is read as 0, not an error
    neg = ranges.copy()
    neg[0, 0, 4, 1] = -0.01
    np.testing.assert_array_equal(
        run_peer_ekf(ekf, neg, truth[:, :, 0], init_std_m=0.3, anchors=ANCHORS, controls=ins).position,
        run_peer_ekf(ekf, np.where(neg < 0, 0.0, neg), truth[:, :, 0], init_std_m=0.3,
                     anchors=ANCHORS, controls=ins).position)


# ------------------------------------------------------------------ snapshot baselines
def _snapshots(n=6, seed=4):
    rng = np.random.default_rng(seed)
    x = rng.uniform([5, 1], [35, 7], size=(n, 2))
    d = np.linalg.norm(x[:, None] - ANCHORS, axis=-1) + 0.01 * rng.standard_normal((n, 6))
    return x, d


@pytest.mark.parametrize("est", [LocalML(MODEL, 25.0), Ransac(0.06, 25.0)])
def test_snapshot_contract(est):
    assert isinstance(est, SnapshotEstimator)
    x, d = _snapshots()
    d[1, 4] += 6.0                                                      # one NLOS range
    d[2, 0] = np.nan                                                    # one absent link
    e = est.locate(d, ANCHORS)
    assert isinstance(e, Estimate) and e.position.shape == (6, 2)
    # (x, y) order against the truth
    np.testing.assert_allclose(e.position, x, atol=0.1)
    # batch equals one-by-one, exactly
    for i in range(6):
        np.testing.assert_array_equal(est.locate(d[i], ANCHORS).position, e.position[i])
    # a NaN range is the same as the link not being there
    np.testing.assert_array_equal(est.locate(np.delete(d[2], 0), ANCHORS[1:]).position,
                                  e.position[2])
    # batch axes lead: (2, 3) problems
    e2 = est.locate(d.reshape(2, 3, 6), ANCHORS)
    np.testing.assert_array_equal(e2.position.reshape(6, 2), e.position)
    with pytest.raises(InputError, match="centres"):
        est.locate(d, ANCHORS[:4])
    bad = d.copy()
    bad[0, 0] = np.inf
    with pytest.raises(InputError, match="ranges"):
        est.locate(bad, ANCHORS)


def test_ransac_refit_is_least_squares_on_the_inliers():
    x, d = _snapshots()
    d[:, 5] += 5.0                                                      # anchor 5 NLOS everywhere
    e = Ransac(0.06, 25.0).locate(d, ANCHORS)
    assert e.converged.all() and np.all(e.diagnostics["inliers"] == 5)
    # the gradient of the inlier least-squares cost vanishes at the estimate
    diff = e.position[:, None] - ANCHORS[:5]
    dist = np.linalg.norm(diff, axis=-1)
    grad = np.sum(((dist - d[:, :5]) / dist)[..., None] * diff, axis=1)
    np.testing.assert_allclose(grad, 0.0, atol=1e-8)


def test_snapshot_bad_settings():
    with pytest.raises(ConfigError, match="measurement"):
        LocalML(object(), 10.0)
    with pytest.raises(ConfigError, match="radius_m"):
        LocalML(MODEL, 0.0)
    with pytest.raises(ConfigError, match="threshold_m"):
        Ransac(-1.0, 10.0)
