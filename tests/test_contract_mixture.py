"""Contract tests of the paper-004 estimators: MixtureLocalizer and MixtureTracker.

A synthetic calibration with a known answer: every station's model has one axis-aligned
component per grid point, at the noise-free log-distance signal strength of that point, so
that the exact signal strengths of a grid point localize it.
"""

import numpy as np
import pytest

from radioloc.core.errors import InputError
from radioloc.core.results import Estimate, Track
from radioloc.estimators.mixture_localization import (MixtureLocalizer, MixtureState,
                                                      MixtureTracker, posterior_mixture)
from radioloc.models.mixture import DiagMixture
from radioloc.models.motion import RandomWalk, UniformDisk

STATIONS = np.array([[0.0, 0.0], [12.0, 0.0], [0.0, 6.0], [12.0, 6.0]])


def mean_rss(p):
    d = np.linalg.norm(np.asarray(p, float)[..., None, :] - STATIONS, axis=-1)
    return -40.0 - 20.0 * np.log10(np.maximum(d, 0.5))


@pytest.fixture(scope="module")
def models():
    gx, gy = np.meshgrid(np.arange(0.0, 12.1, 1.0), np.arange(0.0, 6.1, 1.0))
    grid = np.c_[gx.ravel(), gy.ravel()]                             # (K, 2)
    m = mean_rss(grid)                                               # (K, S)
    k, s = m.shape
    means = np.concatenate([np.broadcast_to(grid, (s, k, 2)), m.T[..., None]], axis=-1)
    var = np.broadcast_to([0.3, 0.3, 0.5], (s, k, 3)).copy()
    return DiagMixture.create(np.ones((s, k)), means, var)


TRUTH = np.array([8.0, 2.0])                                         # x != y: catches swaps


def test_localizer_types_shapes_and_truth(models):
    loc = MixtureLocalizer(models, max_components=8)
    est = loc.locate(mean_rss(np.array([TRUTH, [3.0, 5.0]])))
    assert isinstance(est, Estimate)
    assert est.position.shape == (2, 2) and est.covariance.shape == (2, 2, 2)
    np.testing.assert_allclose(est.position, [TRUTH, [3.0, 5.0]], atol=0.3)
    np.testing.assert_array_equal(est.diagnostics["measurements_used"], [4, 4])
    post = posterior_mixture(est)
    assert post.batch_shape == (2,) and post.dim == 2
    mean, cov = post.moments()
    np.testing.assert_allclose(mean, est.position)
    np.testing.assert_allclose(cov, est.covariance)


def test_localizer_batch_equals_one_by_one(models):
    loc = MixtureLocalizer(models, 8)
    rss = mean_rss(np.array([[8.0, 2.0], [3.0, 5.0], [10.5, 1.5]]))
    rss = (rss + np.random.default_rng(1).normal(0, 1.0, rss.shape)).reshape(3, 1, 4)
    rss[1, 0, 2] = np.nan
    batch = loc.locate(rss)
    assert batch.position.shape == (3, 1, 2)
    for i in range(3):
        one = loc.locate(rss[i, 0])
        np.testing.assert_allclose(one.position, batch.position[i, 0], rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(one.covariance, batch.covariance[i, 0], rtol=1e-12,
                                   atol=1e-12)


def test_localizer_nan_station_is_skipped(models):
    rss = mean_rss(TRUTH)
    rss[2] = np.nan
    full = MixtureLocalizer(models, 8).locate(rss)
    without = MixtureLocalizer(models[[0, 1, 3]], 8).locate(rss[[0, 1, 3]])
    np.testing.assert_allclose(full.position, without.position, rtol=1e-12)
    assert int(full.diagnostics["measurements_used"]) == 3
    np.testing.assert_allclose(full.position, TRUTH, atol=0.3)


def _walk(n=8):
    time = 0.5 * np.arange(n)
    path = np.c_[2.0 + 1.0 * time, 1.0 + 0.5 * time]                 # 1.1 m/s
    return time, path


def test_tracker_types_shapes_and_truth(models):
    time, path = _walk()
    trk = MixtureTracker(models, UniformDisk(1.5), max_components=8)
    res = trk.run(mean_rss(path), time)
    assert isinstance(res, Track)
    assert res.position.shape == (8, 2) and res.covariance.shape == (8, 2, 2)
    np.testing.assert_array_equal(res.time, time)
    assert res.diagnostics["measurements_used"].shape == (8,)
    assert res.diagnostics["mixture_weights"].shape == (8, 8)
    np.testing.assert_allclose(res.position, path, atol=0.8)     # the zero-mean disk lags
    assert isinstance(trk.init(), MixtureState)


def test_tracker_batch_equals_one_by_one_and_step_equals_run(models):
    time, path = _walk()
    rng = np.random.default_rng(2)
    rss = mean_rss(np.stack([path, path[::-1]])) + rng.normal(0, 1.5, (2, 8, 4))
    rss[0, 3, 1] = np.nan
    trk = MixtureTracker(models, UniformDisk(1.5), 8)
    batch = trk.run(rss, time)
    assert batch.position.shape == (2, 8, 2)
    for r in range(2):
        one = trk.run(rss[r], time)
        np.testing.assert_allclose(one.position, batch.position[r], rtol=1e-10, atol=1e-10)
    state = trk.init(batch_shape=(2,))
    dts = np.diff(time, prepend=time[0])
    for t in range(8):
        state = trk.step(state, rss[:, t], dts[t])
        np.testing.assert_allclose(trk.estimate(state).position, batch.position[:, t],
                                   rtol=1e-10, atol=1e-10)


def test_tracker_all_nan_step_is_prediction_only(models):
    time, path = _walk()
    trk = MixtureTracker(models, UniformDisk(1.5), 8)
    s1 = trk.step(trk.init(), mean_rss(path[0]), 0.0)
    s2 = trk.step(s1, np.full(4, np.nan), 0.4)
    e1, e2 = trk.estimate(s1), trk.estimate(s2)
    assert np.all(np.isfinite(e2.position))
    # disk prediction: zero-mean displacement with per-axis variance r^2 / 4 (r = 0.6 m);
    # the reduction preserves the mean and the per-axis variances
    np.testing.assert_allclose(e2.position, e1.position, atol=1e-9)
    np.testing.assert_allclose(np.diag(e2.covariance), np.diag(e1.covariance) + 0.6**2 / 4,
                               rtol=1e-9)
    assert int(e2.diagnostics["measurements_used"]) == 0
    # in run(): the all-NaN step gives a finite estimate
    rss = mean_rss(path)
    rss[4] = np.nan
    res = trk.run(rss, time)
    assert np.all(np.isfinite(res.position))
    # a leading all-NaN step (nothing known yet) reports the calibration area, finite
    rss[0] = np.nan
    res = trk.run(rss, time)
    assert np.all(np.isfinite(res.position))


def test_tracker_continuous_in_time_steps(models):
    """Multiplying every dt by 1 + 1e-12 moves no estimate by more than 1e-6 m.

    A one-component prior predicted over steps with no station received makes the disk
    cells tie exactly in the reduction; rounding used to decide those ties (0.05-0.27 m
    jumps here, 1.3 m on the BLE robot run)."""
    time, path = _walk(12)
    prior = DiagMixture(np.ones(1), np.array([[2.0, 1.0]]), np.array([[0.2, 0.3]]))
    for seed in range(3):
        rss = mean_rss(path) + np.random.default_rng(seed).normal(0, 2.0, (12, 4))
        rss[:4] = np.nan
        trk = MixtureTracker(models, UniformDisk(1.5), 4)
        a = trk.run(rss, time, prior=prior)
        b = trk.run(rss, time * (1 + 1e-12), prior=prior)
        assert np.max(np.abs(a.position - b.position)) < 1e-6
        a = trk.run(rss[4:], time[4:])
        b = trk.run(rss[4:], time[4:] * (1 + 1e-12))
        assert np.max(np.abs(a.position - b.position)) < 1e-6


def test_bad_input_raises(models):
    with pytest.raises(InputError, match="models"):
        MixtureLocalizer(np.zeros((2, 3)))
    with pytest.raises(InputError, match="max_components"):
        MixtureLocalizer(models, max_components=0)
    bad = DiagMixture(models.weights, models.means.copy(), models.variances)
    bad.means[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="models"):
        MixtureLocalizer(bad)
    with pytest.raises(InputError, match="motion"):
        MixtureTracker(models, RandomWalk(1.0))
    with pytest.raises(InputError, match="motion"):
        MixtureTracker(models, UniformDisk(1.5, dim=1))
    loc = MixtureLocalizer(models)
    with pytest.raises(InputError, match="rss"):
        loc.locate(np.zeros(3))
    with pytest.raises(InputError, match="rss"):
        loc.locate(np.array([-50.0, np.inf, -60.0, -70.0]))
    with pytest.raises(InputError, match="no received"):
        loc.locate(np.full(4, np.nan))
    trk = MixtureTracker(models, UniformDisk(1.5))
    with pytest.raises(InputError, match="time"):
        trk.run(np.zeros((3, 4)), [0.0, 1.0])
    with pytest.raises(InputError, match="time"):
        trk.run(np.zeros((3, 4)), [0.0, 1.0, 0.5])
    with pytest.raises(InputError, match="dt"):
        trk.step(trk.init(), np.zeros(4), -1.0)
