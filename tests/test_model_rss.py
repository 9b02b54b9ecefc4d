"""RSS as a measurement model: log-distance Gaussian (h, Jacobian) and the trapezoids of
paper 003 as a likelihood on positions."""

import numpy as np
import pytest

from radioloc.bounds.anchors import range_fisher_information
from radioloc.bounds.fisher import crb, fisher_information
from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.base import Tags
from radioloc.models.measurement import Context, StateLayout, numerical_jacobian
from radioloc.models.rss_model import RssModel, TrapezoidRssModel
from radioloc.models.rssi_logdistance import LogDistanceGaussian
from radioloc.models.rssi_trapezoid import TrapezoidModel

CHANNEL = LogDistanceGaussian(a=-40.0, n=2.5, s=4.0, d_ref_m=0.5)
ANCHORS = np.array([[0.0, 0.0, 2.0], [15.0, 0.0, 2.5], [0.0, 15.0, 3.0], [15.0, 15.0, 2.0]])


def trapezoids():
    levels = np.arange(101.0)
    mu = np.clip(30.0 - 0.3 * levels, 0.5, None)
    return TrapezoidModel(mu=mu, tau=np.full(101, 1.0), sigma=np.full(101, 2.0),
                          count=np.ones(101))


@pytest.mark.parametrize("dim, height", [(2, None), (3, None), (2, 1.0)])
def test_jacobian_equals_finite_differences(dim, height):
    model = RssModel(CHANNEL)
    anchors = ANCHORS if dim == 3 or height is not None else ANCHORS[:, :2]
    ctx = Context(points=anchors, height_m=height)
    layout = StateLayout(dim=dim, order=1)
    rng = np.random.default_rng(6)
    x = layout.join({"position": rng.uniform(1, 14, (8, dim)), "velocity": rng.normal(size=(8, dim))})
    _, H = layout.measure(model, x, ctx)
    numeric = numerical_jacobian(model, layout.split(x), ctx)
    np.testing.assert_allclose(H[..., :dim], numeric["position"], atol=1e-6, rtol=1e-6)
    assert np.all(H[..., dim:] == 0.0)


def test_prediction_and_density_are_the_channel_models():
    model = RssModel(CHANNEL)
    ctx = Context(points=ANCHORS[:, :2])
    pos = np.array([[3.0, 4.0], [0.1, 0.2]])
    d = np.linalg.norm(pos[:, None, :] - ANCHORS[:, :2], axis=-1)
    np.testing.assert_allclose(model.predict({"position": pos}, ctx), CHANNEL.mean(d))
    z = CHANNEL.mean(d) + np.array([1.0, -2.0, 0.5, 3.0])
    np.testing.assert_allclose(model.logpdf(z, {"position": pos}, ctx), CHANNEL.logpdf(z, d))
    np.testing.assert_allclose(model.std(ctx), 4.0)
    # inside d_ref the mean is flat, so is the Jacobian
    assert np.all(model.jacobian({"position": pos}, ctx)["position"][1, 0] == 0.0)


def test_rss_bound_grows_with_the_shadowing():
    layout = StateLayout(dim=2)
    x = np.array([5.0, 6.0])
    ctx = Context(points=ANCHORS[:, :2])
    tight = crb(RssModel(CHANNEL), x, ctx, layout).rmse_m
    loose = crb(RssModel(LogDistanceGaussian(a=-40.0, n=2.5, s=8.0, d_ref_m=0.5)), x, ctx, layout).rmse_m
    assert loose == pytest.approx(2.0 * tight, rel=1e-9)


def test_rss_information_is_that_of_ranges_with_distance_scaled_noise():
    # d RSS / d d = -10 n / (ln 10 d): RSS is a range of std s ln 10 d / (10 n)
    x = np.array([[5.0, 6.0], [11.0, 3.0]])
    anchors = ANCHORS[:, :2]
    d = np.linalg.norm(x[:, None, :] - anchors, axis=-1)
    range_std = CHANNEL.s * np.log(10.0) * d / (10.0 * CHANNEL.n)
    np.testing.assert_allclose(
        fisher_information(RssModel(CHANNEL), x, Context(points=anchors), StateLayout(dim=2)),
        range_fisher_information(x, anchors, std_m=range_std), rtol=1e-10)


def test_trapezoid_likelihood_on_positions():
    traps = trapezoids()
    model = TrapezoidRssModel(traps)
    ctx = Context(points=ANCHORS[:, :2])
    pos = np.array([[3.0, 4.0], [10.0, 10.0]])
    d = np.linalg.norm(pos[:, None, :] - ANCHORS[:, :2], axis=-1)
    z = np.array([[60.0, 40.0, 45.0, np.nan], [50.0, 70.0, 20.0, 55.0]])
    lp = model.logpdf(z, {"position": pos}, ctx)
    assert lp[0, 3] == 0.0
    ok = np.isfinite(z)
    np.testing.assert_allclose(lp[ok], traps.logpdf(d[ok], z[ok].astype(int)))
    # a position whose distances sit on the plateaus scores higher than one far from them
    ctx1 = Context(points=np.array([[0.0, 0.0]]))
    near = model.logpdf(np.array([60.0]), {"position": np.array([traps.mu[60], 0.0])}, ctx1)
    far = model.logpdf(np.array([60.0]), {"position": np.array([traps.mu[60] + 2.5, 0.0])}, ctx1)
    assert near[0] > far[0]


def test_likelihood_only_model_refuses_gaussian_use_and_bad_input_names_the_argument():
    model = TrapezoidRssModel(trapezoids())
    ctx = Context(points=ANCHORS[:, :2])
    state = {"position": np.zeros(2)}
    for call in (lambda: model.predict(state, ctx), lambda: model.jacobian(state, ctx),
                 lambda: model.noise_cov(ctx), lambda: model.sample(state, ctx, np.random.default_rng(0))):
        with pytest.raises(ConfigError, match="logpdf"):
            call()
    with pytest.raises(ConfigError, match="models"):
        crb(model, np.zeros(2), ctx, StateLayout(dim=2))
    assert not Tags(kinds=None, uses="jacobian").accepts(model)
    assert Tags(kinds=None, uses="logpdf").accepts(model)
    assert Tags(kinds=("rss",), uses="jacobian").accepts(RssModel(CHANNEL))
    with pytest.raises(InputError, match="model"):
        RssModel(trapezoids())
    with pytest.raises(InputError, match="model"):
        TrapezoidRssModel(CHANNEL)
    with pytest.raises(InputError, match="rssi"):
        model.logpdf(np.array([3.5, 1.0, 2.0, 4.0]), state, ctx)
