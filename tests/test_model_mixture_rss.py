"""Paper 004's calibration mixtures as a measurement model (``MixtureRssModel``): its
likelihood against the mixture's own densities, its sampler against its predicted mean,
its refusals, and the mixture tracker fed through observations of it. The generic contract
loops run it through every estimator whose tags take it (``rss-fingerprint`` in
``tests/model_cases.py``)."""

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


def test_mixture_tracker_refuses_other_models_and_missing_station_models():
    obs = Observation(RangeModel(std_m=0.1), np.zeros((3, 4)), Context(points=STATIONS))
    with pytest.raises(ConfigError, match="RangeModel.*rss_fingerprint"):
        MixtureTracker(motion=UniformDisk(1.5)).run(obs, np.arange(3.0))
    with pytest.raises(InputError, match="models"):
        MixtureTracker(motion=UniformDisk(1.5)).run(np.zeros((3, 4)), np.arange(3.0))
    bad = Observation(MODEL, np.zeros((3, 2)), Context(points=STATIONS[:2]))
    with pytest.raises(InputError, match="context.index"):
        MixtureTracker(motion=UniformDisk(1.5)).run(bad, np.arange(3.0))
