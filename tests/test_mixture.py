"""Gaussian-mixture models of paper 004: evaluation, conditioning, products, reduction,
calibration, localization and tracking."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radioloc.core.errors import InputError
from radioloc.estimators.mixture_localization import MixtureLocalizer, MixtureTracker
from radioloc.models.mixture import (DiagMixture, convolve, product, reduce, uniform_ball)
from radioloc.models.mixture_calibration import em_calibration, progressive_calibration
from radioloc.models.motion import UniformDisk
from radioloc.sim.corridor import Corridor


def random_mixture(rng, batch=(), k=4, d=2):
    w = rng.uniform(0.1, 1.0, batch + (k,))
    return DiagMixture.create(w, rng.normal(0, 3, batch + (k, d)),
                              rng.uniform(0.3, 2.0, batch + (k, d)))


def grid(lo=-15.0, hi=15.0, n=301):
    g = np.linspace(lo, hi, n)
    return g, g[1] - g[0]


def test_pdf_integrates_to_one_and_moments_match_grid():
    mix = random_mixture(np.random.default_rng(1), d=1, k=5)
    g, h = grid()
    p = mix.pdf(g[:, None])
    assert np.sum(p) * h == pytest.approx(1.0, abs=1e-6)
    mean, cov = mix.moments()
    assert np.sum(p * g) * h == pytest.approx(mean[0], abs=1e-6)
    assert np.sum(p * (g - mean[0]) ** 2) * h == pytest.approx(cov[0, 0], abs=1e-5)


def test_condition_matches_grid_section():
    rng = np.random.default_rng(2)
    mix = random_mixture(rng, d=2, k=5)
    g, h = grid()
    m0 = 0.7
    joint = mix.pdf(np.c_[g, np.full_like(g, m0)])
    expected = joint / (np.sum(joint) * h)
    got = mix.condition(1, m0).pdf(g[:, None])
    np.testing.assert_allclose(got, expected, atol=1e-6)


def test_product_matches_grid():
    rng = np.random.default_rng(3)
    a, b = random_mixture(rng, d=1, k=3), random_mixture(rng, d=1, k=4)
    g, h = grid()
    raw = a.pdf(g[:, None]) * b.pdf(g[:, None])
    p = product(a, b)
    assert p.n_components == 12
    np.testing.assert_allclose(p.pdf(g[:, None]), raw / (np.sum(raw) * h), atol=1e-6)


def test_convolve_moments_add():
    rng = np.random.default_rng(4)
    a, b = random_mixture(rng, d=2), random_mixture(rng, d=2, k=3)
    c = convolve(a, b)
    np.testing.assert_allclose(c.moments()[0], a.moments()[0] + b.moments()[0])
    np.testing.assert_allclose(c.moments()[1], a.moments()[1] + b.moments()[1])


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(3, 12), kmax=st.integers(1, 3))
def test_reduction_preserves_mass_mean_and_variances(seed, k, kmax):
    rng = np.random.default_rng(seed)
    mix = random_mixture(rng, batch=(3,), k=k, d=2)
    red = reduce(mix, kmax)
    assert red.n_components <= kmax
    np.testing.assert_allclose(red.weights.sum(-1), 1.0)
    m0, c0 = mix.moments()
    m1, c1 = red.moments()
    np.testing.assert_allclose(m1, m0, atol=1e-9)
    np.testing.assert_allclose(np.diagonal(c1, axis1=-2, axis2=-1),
                               np.diagonal(c0, axis1=-2, axis2=-1), rtol=1e-9)


def test_reduction_single_component_is_moment_match_and_batched_equals_one_by_one():
    rng = np.random.default_rng(5)
    mix = random_mixture(rng, batch=(4,), k=6, d=1)
    red = reduce(mix, 1)
    mean, cov = mix.moments()
    np.testing.assert_allclose(red.means[:, 0, 0], mean[:, 0])
    np.testing.assert_allclose(red.variances[:, 0, 0], cov[:, 0, 0])
    red3 = reduce(mix, 3)
    for i in range(4):
        one = reduce(mix[i], 3)
        np.testing.assert_allclose(one.moments()[0], red3[i].moments()[0])
        np.testing.assert_allclose(one.weights, red3[i].weights)


def test_uniform_ball_moments():
    for dim, var in ((1, 4.0 / 3.0), (2, 1.0)):
        mean, cov = uniform_ball(2.0, dim).moments()
        np.testing.assert_allclose(mean, 0.0, atol=1e-12)
        np.testing.assert_allclose(cov, var * np.eye(dim), atol=1e-12)


def test_em_recovers_known_mixture():
    rng = np.random.default_rng(6)
    means = np.array([[0.0, 0.0, -40.0], [10.0, 5.0, -70.0]])
    sd = np.array([[1.0, 0.5, 2.0], [0.7, 1.5, 3.0]])
    lab = rng.random(4000) < 0.3
    s = np.where(lab[:, None], means[0] + sd[0] * rng.standard_normal((4000, 3)),
                 means[1] + sd[1] * rng.standard_normal((4000, 3)))
    fit = em_calibration(s[:, :2], s[:, 2:], n_components=2, rng=np.random.default_rng(1))
    order = np.argsort(fit.means[0, :, 0])
    np.testing.assert_allclose(fit.weights[0, order], [0.3, 0.7], atol=0.03)
    np.testing.assert_allclose(fit.means[0, order], means, atol=0.2)
    np.testing.assert_allclose(np.sqrt(fit.variances[0, order]), sd, rtol=0.08)


def test_progressive_recovers_known_mixture_moments_and_ignores_missing():
    rng = np.random.default_rng(7)
    x = rng.uniform(0, 10, (3000, 1))
    m = np.c_[-40 - 2 * x[:, 0] + rng.normal(0, 1, 3000), -50 + x[:, 0]]
    m_missing = m.copy()
    m_missing[::3, 1] = np.nan
    mod = progressive_calibration(x, m_missing, [0.3, 0.5], max_components=10)
    assert mod.n_components <= 10
    mean, cov = mod.moments()
    np.testing.assert_allclose(mean[0], [x.mean(), m[:, 0].mean()], atol=1e-6)
    keep = np.isfinite(m_missing[:, 1])
    np.testing.assert_allclose(mean[1], [x[keep].mean(), m[keep, 1].mean()], atol=1e-6)
    # per-axis variances = data variance + kernel variance (moment-preserving insertion)
    np.testing.assert_allclose(np.diag(cov[0]), [x.var() + 0.09, m[:, 0].var() + 0.25],
                               rtol=1e-6)
    # the conditional mean of m given x follows the line of the data
    cm = mod[0].condition(0, 5.0).moments()[0][0]
    assert abs(cm - (-50.0)) < 1.0


def test_localization_zero_noise_corridor_finds_user():
    rng = np.random.default_rng(8)
    c = Corridor()
    x = rng.uniform(0, 60, (1500, 1))
    rss = c.sample_rss(x[:, 0], np.zeros(1500, bool), 0.5, rng)
    mod = progressive_calibration(x, rss, [0.5, 0.5], max_components=30)
    truth = np.array([12.0, 45.0])
    est = MixtureLocalizer(mod, max_components=8).locate(c.mean_rss(truth, False))
    assert est.batch_shape == (2,)
    np.testing.assert_allclose(est.position[:, 0], truth, atol=1.0)
    # one station missing: only the other one is used
    one = c.mean_rss(truth, False)
    one[:, 0] = np.nan
    only2 = MixtureLocalizer(mod[1:], 8).locate(one[:, 1:]).position
    np.testing.assert_allclose(MixtureLocalizer(mod, 8).locate(one).position, only2)


def test_tracking_batched_equals_one_by_one_and_static_concentrates():
    rng = np.random.default_rng(9)
    c = Corridor()
    x = rng.uniform(0, 60, (2, 600, 1))
    mod = progressive_calibration(x, c.sample_rss(x[..., 0], False, 1.0, rng), [1.0, 1.0], 16)
    rss = c.sample_rss(np.full((2, 6), 40.0), False, 1.0, rng)
    time = np.arange(6.0)
    res = MixtureTracker(mod, UniformDisk(1.5, dim=1), max_components=6).run(rss, time)
    assert res.position.shape == (2, 6, 1) and res.covariance.shape == (2, 6, 1, 1)
    for r in range(2):
        one = MixtureTracker(mod[r], UniformDisk(1.5, dim=1), 6).run(rss[r], time)
        np.testing.assert_allclose(one.position, res.position[r], rtol=1e-10)
    static = MixtureTracker(mod, UniformDisk(0.0, dim=1), 6).run(rss, time)
    assert np.all(static.covariance[:, -1, 0, 0] < static.covariance[:, 0, 0, 0])


def test_bad_input_raises():
    rng = np.random.default_rng(10)
    mod = random_mixture(rng, batch=(2,), k=3, d=2)
    with pytest.raises(InputError, match="rss"):
        MixtureLocalizer(mod).locate(np.zeros((4, 3)))
    with pytest.raises(InputError, match="no received"):
        MixtureLocalizer(mod).locate(np.full((1, 2), np.nan))
    with pytest.raises(InputError, match="variances"):
        DiagMixture.create([1.0], [[0.0]], [[-1.0]])
    with pytest.raises(InputError, match="max_components"):
        reduce(mod, 0)
    with pytest.raises(InputError, match="bandwidth"):
        progressive_calibration(np.zeros((3, 1)), np.zeros((3, 1)), [1.0, -1.0])


def test_reduce_ties_do_not_depend_on_rounding():
    """The disk cells tie exactly (equal weights, symmetric merge costs): a 1e-12 change of
    the radius must not flip a merge (it did for 81 of these 200 radii before)."""
    post = DiagMixture(np.ones(1), np.array([[1.3, -0.4]]), np.array([[0.2, 0.3]]))
    for r in np.linspace(0.1, 3.0, 200):
        a = reduce(convolve(post, uniform_ball(r, 2)), 4)
        b = reduce(convolve(post, uniform_ball(r * (1 + 1e-12), 2)), 4)
        np.testing.assert_allclose(a.means, b.means, atol=1e-9)
        np.testing.assert_allclose(a.variances, b.variances, rtol=1e-9)
