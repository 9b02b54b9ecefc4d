"""Gaussian-mixture reduction and eq. (2) localization (paper 004): the compiled backend
against the NumPy definition through the public API, and the invariants of the greedy
West/Runnalls rule (moment preservation, component count, order-free ties, bad input)."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators import MixtureLocalizer, MixtureTracker
from radioloc.models import DiagMixture, UniformDisk
from radioloc.models.mixture import (compact, convolve, merge_moments, pad_components, product,
                                     reduce, runnalls_cost, uniform_ball)

#: relative tolerance between the backends
RTOL = 1e-10


def _random(rng, b, k, d, wlo=0.1):
    return DiagMixture.create(rng.uniform(wlo, 1, (b, k)), rng.normal(0, 3, (b, k, d)),
                              rng.uniform(0.5, 2, (b, k, d)))


def _cases(rng):
    """Mixtures with and without exact ties: random products (D = 1, 2, 3), a mixture times
    itself ((i, j) and (j, i) tie), equal weights, a Gaussian convolved with the disk cells
    (60-degree symmetric: weights and costs tie in sixes), weights over 30 decades."""
    out = []
    for d in (1, 2, 3):
        a, b = _random(rng, 30, 8, d), _random(rng, 30, 8, d)
        out += [product(a, b), product(a, a)]
    out.append(DiagMixture.create(np.ones((20, 30)), rng.normal(0, 3, (20, 30, 2)),
                                  np.full((20, 30, 2), 0.7)))
    post = DiagMixture.create(rng.uniform(0.2, 1, (20, 5)), rng.normal(0, 2, (20, 5, 2)),
                              rng.uniform(0.2, 0.5, (20, 5, 2)))
    out.append(convolve(post, uniform_ball(np.full(20, 1.3), 2)))
    out.append(DiagMixture.create(10.0 ** rng.uniform(-30, 0, (20, 24)),
                                  rng.normal(0, 3, (20, 24, 2)),
                                  10.0 ** rng.uniform(-2, 2, (20, 24, 2))))
    return out


def _assert_close(a, b):
    assert a.weights.shape == b.weights.shape
    np.testing.assert_allclose(a.weights, b.weights, rtol=RTOL, atol=1e-300)
    np.testing.assert_allclose(a.means, b.means, rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(a.variances, b.variances, rtol=RTOL)


def _permuted(mix, p):
    return DiagMixture(mix.weights[..., p], mix.means[..., p, :], mix.variances[..., p, :])


def test_reduce_backends_agree():
    for mix in _cases(np.random.default_rng(21)):
        for kmax in (8, 3, 1):
            _assert_close(reduce(mix, kmax), reduce(mix, kmax, backend="numpy"))


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_reduce_preserves_mass_mean_variances_and_bounds_the_count(backend):
    rng = np.random.default_rng(22)
    for mix in _cases(rng):
        m0, c0 = mix.moments()
        for kmax in (5, 1):
            red = reduce(mix, kmax, backend=backend)
            assert red.n_components == kmax                     # every case has > 5
            assert np.all(np.sum(red.weights > 0, -1) == kmax)
            np.testing.assert_allclose(red.weights.sum(-1), 1.0, rtol=1e-12)
            m1, c1 = red.moments()
            np.testing.assert_allclose(m1, m0, rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(np.diagonal(c1, axis1=-2, axis2=-1),
                                       np.diagonal(c0, axis1=-2, axis2=-1), rtol=1e-9)


def test_merge_moments_preserves_the_pair():
    rng = np.random.default_rng(23)
    w1, w2 = rng.uniform(0.1, 1, 50), rng.uniform(0.1, 1, 50)
    m1, m2 = rng.normal(0, 3, (50, 2)), rng.normal(0, 3, (50, 2))
    v1, v2 = rng.uniform(0.5, 2, (50, 2)), rng.uniform(0.5, 2, (50, 2))
    w, m, v = merge_moments(w1, m1, v1, w2, m2, v2)
    tot = (w1 + w2)[:, None]
    pair = DiagMixture(np.c_[w1, w2] / tot, np.stack([m1, m2], 1), np.stack([v1, v2], 1))
    mean, cov = pair.moments()
    np.testing.assert_allclose(w, w1 + w2)
    np.testing.assert_allclose(m, mean)
    np.testing.assert_allclose(v, np.diagonal(cov, axis1=-2, axis2=-1))


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_one_merge_is_west_rule_with_runnalls_cost(backend):
    """Known answer: the lowest weight merged into the partner of lowest textbook
    Runnalls cost (:func:`runnalls_cost`), by moment matching."""
    rng = np.random.default_rng(28)
    mix = _random(rng, 200, 6, 2)
    i = np.argmin(mix.weights, -1)
    n = np.arange(200)
    cost = runnalls_cost(mix.weights[n, i][:, None], mix.means[n, i][:, None],
                         mix.variances[n, i][:, None], mix.weights, mix.means, mix.variances)
    cost[n, i] = np.inf
    j = np.argmin(cost, -1)
    w, m, v = merge_moments(mix.weights[n, i], mix.means[n, i], mix.variances[n, i],
                            mix.weights[n, j], mix.means[n, j], mix.variances[n, j])
    want = [mix.weights.copy(), mix.means.copy(), mix.variances.copy()]
    want[0][n, j], want[1][n, j], want[2][n, j] = w, m, v
    want[0][n, i] = 0.0
    _assert_close(reduce(mix, 5, backend=backend), compact(DiagMixture(*want)))


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_reduce_does_not_depend_on_component_order(backend):
    rng = np.random.default_rng(24)
    for mix in _cases(rng):
        base = reduce(mix, 6, backend=backend)
        other = reduce(_permuted(mix, rng.permutation(mix.n_components)), 6, backend=backend)
        np.testing.assert_array_equal(other.weights, base.weights)
        np.testing.assert_array_equal(other.means, base.means)
        np.testing.assert_array_equal(other.variances, base.variances)


def test_tie_rule_keeps_rotation_and_translation():
    """A half turn plus a shift of a tied mixture (disk cells, a mixture times itself)
    turns and shifts its reduction (to rounding: the rule reads no position)."""
    rng = np.random.default_rng(25)
    shift = np.array([1234.5, -987.25])
    cases = _cases(rng)
    for mix in cases[2:4] + cases[6:8]:
        turned = DiagMixture(mix.weights, shift - mix.means, mix.variances)
        a, b = reduce(mix, 5), reduce(turned, 5)
        ka = np.lexsort((a.means[..., 1], a.means[..., 0], -a.weights), axis=-1)
        mb = shift - b.means
        kb = np.lexsort((mb[..., 1], mb[..., 0], -b.weights), axis=-1)
        np.testing.assert_allclose(np.take_along_axis(mb, kb[..., None], -2),
                                   np.take_along_axis(a.means, ka[..., None], -2), atol=1e-9)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_negligible_component_goes_to_its_cheapest_partner(backend):
    """Weight 1e-12 next to B (cost about 1e-13), far from A which is nearer the mixture
    mean: merged into B (its cost decides, not the tie rule)."""
    mix = DiagMixture(np.array([[0.6, 0.4, 1e-12]]),
                      np.array([[[0.0, 0.0], [10.0, 0.0], [9.5, 0.0]]]), np.full((1, 3, 2), 4.0))
    out = reduce(mix, 2, backend=backend)
    assert out.weights[0, 0] == 0.6 and out.weights[0, 1] == 0.4 + 1e-12
    assert out.means[0, 1, 0] < 10.0
    np.testing.assert_array_equal(out.means[0, 0], [0.0, 0.0])


def test_bad_input():
    mix = _random(np.random.default_rng(26), 2, 4, 2)
    for bad in (0, -1, True):
        with pytest.raises(InputError, match="max_components"):
            reduce(mix, bad)
    with pytest.raises(InputError, match="reduction"):
        reduce(mix, 2, "west")
    with pytest.raises(ConfigError, match="backend"):
        reduce(mix, 2, backend="fortran")
    models = DiagMixture.create(np.ones((2, 3)), np.zeros((2, 3, 3)), np.ones((2, 3, 3)))
    with pytest.raises(ConfigError, match="backend"):
        MixtureLocalizer(models, backend="C")
    with pytest.raises(ConfigError, match="backend"):
        MixtureTracker(models, UniformDisk(1.0), backend=None)


@pytest.mark.parametrize("k,kmax,lead", [(16, 8, ()), (5, 8, ()), (6, 3, (2,))])
def test_localizer_backends_agree(k, kmax, lead):
    rng = np.random.default_rng(k + kmax)
    s = 5
    models = DiagMixture.create(rng.uniform(0.1, 1, lead + (s, k)),
                                rng.normal(0, 3, lead + (s, k, 3)),
                                rng.uniform(0.5, 4, lead + (s, k, 3)))
    rss = rng.normal(0, 3, (40,) + lead + (s,)) if lead else rng.normal(0, 3, (40, s))
    rss[rng.random(rss.shape) < 0.3] = np.nan
    rss[0] = np.nan                                            # a row with no station
    a, ha = MixtureLocalizer(models, kmax).density_and_mask(rss)
    b, hb = MixtureLocalizer(models, kmax, backend="numpy").density_and_mask(rss)
    np.testing.assert_array_equal(ha, hb)
    kk = max(a.n_components, b.n_components)
    a, b = pad_components(a, kk), pad_components(b, kk)
    got = np.broadcast_to(hb, a.batch_shape)
    _assert_close(a[got], b[got])
    rss = rss[1:]
    rss[..., 0] = 0.5                                          # a station in every row
    ea = MixtureLocalizer(models, kmax).locate(rss)
    eb = MixtureLocalizer(models, kmax, backend="numpy").locate(rss)
    np.testing.assert_allclose(ea.position, eb.position, rtol=RTOL, atol=1e-12)


def test_tracker_backends_agree():
    rng = np.random.default_rng(27)
    models = DiagMixture.create(rng.uniform(0.1, 1, (4, 12)), rng.normal(0, 3, (4, 12, 3)),
                                rng.uniform(0.5, 4, (4, 12, 3)))
    rss = rng.normal(0, 3, (3, 15, 4))
    rss[rng.random(rss.shape) < 0.2] = np.nan
    time = 0.5 * np.arange(15)
    for reduction in ("continuous", "runnalls"):
        a = MixtureTracker(models, UniformDisk(1.5), 6, reduction).run(rss, time)
        b = MixtureTracker(models, UniformDisk(1.5), 6, reduction, backend="numpy").run(rss, time)
        np.testing.assert_allclose(a.position, b.position, rtol=RTOL, atol=1e-10)
        np.testing.assert_allclose(a.covariance, b.covariance, rtol=RTOL, atol=1e-10)


def _grid_models():
    """Station models on a symmetric grid: every weight ties, and distances to a corner
    station tie in pairs."""
    stations = np.array([[0.0, 0.0], [12.0, 0.0], [0.0, 6.0], [12.0, 6.0]])
    gx, gy = np.meshgrid(np.arange(0.0, 12.1, 1.5), np.arange(0.0, 6.1, 1.5))
    grid = np.c_[gx.ravel(), gy.ravel()]
    m = -40.0 - 20.0 * np.log10(np.maximum(
        np.linalg.norm(grid[:, None, :] - stations, axis=-1), 0.5))
    k, s = m.shape
    means = np.concatenate([np.broadcast_to(grid, (s, k, 2)), m.T[..., None]], -1)
    return DiagMixture.create(np.ones((s, k)), means, np.broadcast_to([0.4, 0.3, 0.5], (s, k, 3)))


@pytest.mark.parametrize("reduction", ["continuous", "runnalls"])
def test_tracker_and_localizer_on_tied_grid_ignore_component_order(reduction):
    mod = _grid_models()
    rng = np.random.default_rng(3)
    path = np.c_[6 + 4 * np.sin(0.05 * np.arange(60)), 3 + 2 * np.sin(0.07 * np.arange(60))]
    stations = np.array([[0.0, 0.0], [12.0, 0.0], [0.0, 6.0], [12.0, 6.0]])
    rss = -40.0 - 20.0 * np.log10(np.maximum(
        np.linalg.norm(path[:, None, :] - stations, axis=-1), 0.5)) + rng.normal(0, 1, (60, 4))
    time = 0.333 * np.arange(60)
    p = np.random.default_rng(5).permutation(mod.n_components)
    ref = MixtureTracker(mod, UniformDisk(1.5), 8, reduction).run(rss, time).position
    got = MixtureTracker(_permuted(mod, p), UniformDisk(1.5), 8, reduction).run(rss, time)
    np.testing.assert_allclose(got.position, ref, atol=1e-9)
    a = MixtureLocalizer(mod, 8).locate(rss).position
    b = MixtureLocalizer(_permuted(mod, p), 8).locate(rss).position
    np.testing.assert_allclose(a, b, atol=1e-9)
