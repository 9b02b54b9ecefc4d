"""The fingerprint models as measurement models.

- Paper 004's calibration mixtures (``MixtureRssModel``): its likelihood against the
  mixture's own densities, its sampler against its predicted mean, its refusals, and the
  mixture tracker fed through observations of it.
- The shared-place WiFi model (``FingerprintScanModel``): its rows against the fingerprint
  model's own scan likelihood, absent rows, its sampler, its refusals.

The generic contract loops run both through every estimator whose tags take them
(``rss-fingerprint`` and ``rss-scan`` in ``tests/model_cases.py``)."""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators import ExtendedKalmanFilter, GridFilter, MixtureTracker, ParticleFilter
from radioloc.models import (
    Context,
    DiagMixture,
    MixtureRssModel,
    Observation,
    RangeModel,
    UniformDisk,
)

STATIONS = np.array([[0.0, 0.0], [12.0, 0.0], [0.0, 6.0], [12.0, 6.0]])


def _mixtures(var=(0.4, 0.3), signal_var=0.5):
    gx, gy = np.meshgrid(np.arange(0.0, 12.1, 1.5), np.arange(0.0, 6.1, 1.5))
    grid = np.c_[gx.ravel(), gy.ravel()]
    d = np.linalg.norm(grid[None] - STATIONS[:, None], axis=-1)           # (S, K)
    nu = -40.0 - 20.0 * np.log10(np.maximum(d, 0.5))
    means = np.concatenate([np.broadcast_to(grid, d.shape + (2,)), nu[..., None]], -1)
    w = np.random.default_rng(0).uniform(0.5, 1.5, d.shape)
    return DiagMixture.create(w, means, np.broadcast_to(np.r_[var, signal_var], d.shape + (3,)))


MIX = _mixtures()
MODEL = MixtureRssModel(MIX)
CTX = Context(points=STATIONS[[2, 0, 3]], index=np.array([2, 0, 3]))
X = np.array([[3.3, 2.1], [8.0, 4.4], [11.0, 0.5]])


def test_logpdf_is_the_conditional_of_the_calibration_mixture():
    """``log p(m | x) = log D(x, m) - log D(x)``, with both densities from the mixture's own
    ``logpdf`` (row ``r`` is station ``index[r]``)."""
    z = np.array([[-52.0, -50.5, -61.0], [-60.0, -59.0, -55.0], [-63.0, -62.0, -50.0]])
    got = MODEL.logpdf(z, {"position": X}, CTX)
    for r, k in enumerate(CTX.index):
        st = MIX[k]
        joint = st.logpdf(np.c_[X, z[:, r]][:, None, :])[:, 0]
        marg = st.marginal([0, 1]).logpdf(X[:, None, :])[:, 0]
        np.testing.assert_allclose(got[:, r], joint - marg, rtol=0, atol=1e-10)


def test_the_density_integrates_to_one_and_nan_rows_give_zero():
    m = np.linspace(-110.0, 10.0, 6001)
    lp = MODEL.logpdf(np.broadcast_to(m[:, None], (m.size, 3)),
                      {"position": np.broadcast_to(X[1], (m.size, 2))}, CTX)
    np.testing.assert_allclose(np.trapezoid(np.exp(lp), m, axis=0), 1.0, atol=1e-9)
    z = np.array([[np.nan, -50.0, np.nan]])
    out = MODEL.logpdf(z, {"position": X[:1]}, CTX)
    assert out[0, 0] == 0.0 and out[0, 2] == 0.0 and np.isfinite(out[0, 1])


def test_sample_mean_is_the_predicted_conditional_mean():
    n = 10000
    pos = np.broadcast_to(X[0], (n, 2))
    draws = MODEL.sample({"position": pos}, CTX, np.random.default_rng(3))
    want = MODEL.predict({"position": X[:1]}, CTX)[0]
    se = draws.std(axis=0) / np.sqrt(n)
    assert np.all(np.abs(draws.mean(axis=0) - want) < 4 * se), (draws.mean(axis=0), want)


def test_likelihood_only_estimators_take_it_and_jacobian_ones_refuse_it():
    assert GridFilter.tags.accepts(MODEL) and ParticleFilter.tags.accepts(MODEL)
    assert MixtureTracker.tags.accepts(MODEL)
    assert not ExtendedKalmanFilter.tags.accepts(MODEL)
    with pytest.raises(ConfigError, match="MixtureRssModel"):
        ExtendedKalmanFilter.tags.require(MODEL, "observations[0].model", "ExtendedKalmanFilter")
    with pytest.raises(ConfigError, match="MixtureRssModel.*logpdf"):
        MODEL.jacobian({"position": X}, CTX)
    with pytest.raises(ConfigError, match="MixtureRssModel"):
        MODEL.std(CTX)


def test_bad_input_is_named():
    with pytest.raises(InputError, match="context.index"):
        MODEL.logpdf(np.zeros((3, 3)), {"position": X}, Context(points=STATIONS[:3]))
    with pytest.raises(InputError, match="context.index.*row 1"):
        MODEL.predict({"position": X}, Context(points=STATIONS[:2], index=np.array([0, 7])))
    with pytest.raises(InputError, match="models"):
        MixtureRssModel(MIX[0])                          # no station axis
    with pytest.raises(InputError, match="z"):
        MODEL.logpdf(np.zeros((3, 2)), {"position": X}, CTX)


def _walk():
    time = 0.5 * np.arange(8)
    truth = np.array([[2.0, 1.0], [3.0, 4.5]])[:, None] + np.c_[1.0 * time, 0.3 * time]
    d = np.linalg.norm(truth[..., None, :] - STATIONS, axis=-1)
    rss = -40.0 - 20.0 * np.log10(np.maximum(d, 0.5)) \
        + 0.3 * np.sin(np.arange(d.size)).reshape(d.shape)
    rss[0, 3, 1] = np.nan                                 # a station not received
    return time, truth, rss


def test_mixture_tracker_through_observations_is_the_tracker_on_readings():
    """The tracker fed an observation of the model (rows in another order than the station
    columns) gives the track of its readings form, to rounding."""
    time, _, rss = _walk()
    trk = MixtureTracker(MIX, UniformDisk(1.5), max_components=8)
    want = trk.run(rss, time)
    rows = np.array([3, 1, 0, 2])
    obs = Observation(MODEL, rss[..., rows], Context(points=STATIONS[rows], index=rows))
    got = MixtureTracker(motion=UniformDisk(1.5), max_components=8).run(obs, time)
    np.testing.assert_allclose(got.position, want.position, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.covariance, want.covariance, rtol=0, atol=1e-12)


def test_mixture_tracker_with_a_gaussian_prior_tracks():
    time, truth, rss = _walk()
    obs = Observation(MODEL, rss, Context(points=STATIONS, index=np.arange(4)))
    prior = np.c_[truth[:, 0] + 0.4, np.broadcast_to([1.0, 0.3], (2, 2))]
    from radioloc.models import WhiteAccelerationCV
    track = MixtureTracker(motion=WhiteAccelerationCV(0.05), max_components=8).run(
        obs, time, prior_mean=prior, prior_cov=np.diag([1.0, 1.0, 0.04, 0.04]))
    err = np.linalg.norm(track.position[:, -1] - truth[:, -1], axis=-1)
    assert np.all(err < 1.0), err


def test_mixture_tracker_needs_a_prior_for_other_models_and_names_missing_station_models():
    """Another model has no calibration area to start from: the prior is named."""
    obs = Observation(RangeModel(std_m=0.1), np.ones((3, 4)), Context(points=STATIONS))
    with pytest.raises(InputError, match="RangeModel.*prior_mean"):
        MixtureTracker(motion=UniformDisk(1.5)).run(obs, np.arange(3.0))
    with pytest.raises(InputError, match="models"):
        MixtureTracker(motion=UniformDisk(1.5)).run(np.zeros((3, 4)), np.arange(3.0))
    bad = Observation(MODEL, np.zeros((3, 2)), Context(points=STATIONS[:2]))
    with pytest.raises(InputError, match="context.index"):
        MixtureTracker(motion=UniformDisk(1.5)).run(bad, np.arange(3.0))


# ---- the shared-place fingerprint model (WiFi scans) --------------------------------------
def _scan_model():
    from radioloc.models import FingerprintMixture, FingerprintScanModel
    rng = np.random.default_rng(7)
    k, s = 12, 5
    fm = FingerprintMixture(rng.uniform(0, 10, (k, 2)), rng.uniform(0.5, 2.0, (k, 2)),
                            np.log(np.full(k, 1.0 / k)), rng.uniform(0.1, 0.9, (k, s)),
                            rng.uniform(-80, -40, (k, s)), rng.uniform(4, 25, (k, s)),
                            np.ones(s, bool), np.zeros((k, 0), np.int64))
    return fm, FingerprintScanModel(fm)


def test_scan_rows_sum_to_the_fingerprint_models_own_scan_likelihood():
    """Sum of the rows = ``log sum_j r_j(x) exp(log L_j(scan))`` with ``log L_j`` from the
    fingerprint model's own ``loglik`` (NaN there = not detected), for any row order."""
    fm, model = _scan_model()
    scan = np.array([-55.0, np.nan, -71.0, np.nan, -48.0])        # loglik's form
    z = np.where(np.isnan(scan), model.not_detected, scan)
    x = np.array([[2.0, 3.0], [7.5, 1.0], [5.0, 9.0]])
    d = x[:, None, :] - fm.positions
    lx = fm.log_prior - 0.5 * np.sum(d * d / fm.position_variances
                                     + np.log(2 * np.pi * fm.position_variances), axis=-1)
    lr = lx - np.log(np.exp(lx).sum(-1, keepdims=True))
    want = np.log(np.sum(np.exp(lr + fm.loglik(scan[None])), axis=-1))
    for rows in (np.arange(5), np.array([3, 0, 4, 1, 2])):
        ctx = Context(points=np.zeros((5, 2)), index=rows)
        got = model.logpdf(np.broadcast_to(z[rows], (3, 5)), {"position": x}, ctx).sum(-1)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)


def test_scan_absent_rows_are_left_out():
    _, model = _scan_model()
    x = np.array([[4.0, 4.0]])
    z = np.array([[-60.0, model.not_detected, np.nan, -50.0, np.nan]])
    full = model.logpdf(z, {"position": x}, Context(points=np.zeros((5, 2)), index=np.arange(5)))
    kept = np.array([0, 1, 3])
    part = model.logpdf(z[:, kept], {"position": x},
                        Context(points=np.zeros((3, 2)), index=kept))
    assert full[0, 2] == 0.0 and full[0, 4] == 0.0
    np.testing.assert_allclose(full.sum(-1), part.sum(-1), rtol=0, atol=1e-12)


def test_scan_sampler_detects_at_the_models_rate():
    fm, model = _scan_model()
    n = 20000
    x = np.array([3.0, 6.0])
    ctx = Context(points=np.zeros((5, 2)), index=np.arange(5))
    draws = model.sample({"position": np.broadcast_to(x, (n, 2))}, ctx, np.random.default_rng(1))
    lr = model.place_log_weights({"position": x}, ctx)
    rate = np.exp(lr) @ fm.detect
    seen = (draws != model.not_detected).mean(axis=0)
    assert np.all(np.abs(seen - rate) < 4 * np.sqrt(rate * (1 - rate) / n)), (seen, rate)


def test_scan_model_is_likelihood_only_and_names_bad_input():
    _, model = _scan_model()
    assert GridFilter.tags.accepts(model) and ParticleFilter.tags.accepts(model)
    assert not ExtendedKalmanFilter.tags.accepts(model)
    assert MixtureTracker.tags.accepts(model)          # through its Gaussian-sum step
    with pytest.raises(ConfigError, match="FingerprintScanModel"):
        model.predict({"position": X}, CTX)
    with pytest.raises(InputError, match="context.index"):
        model.logpdf(np.zeros((3, 3)), {"position": X}, Context(points=STATIONS[:3]))
