"""The compiled West/Runnalls reduction: equal to its NumPy reference bit for bit, and
independent of the order of the components (the order-free tie rule of ``reduce``), down to
the mixture localizer and tracker on the symmetric grid of ``test_metamorphic`` whose
exact ties moved the track by 0.11 m under a component permutation before."""

import numpy as np
import pytest

from radioloc.estimators import MixtureLocalizer, MixtureTracker
from radioloc.models import DiagMixture, UniformDisk
from radioloc.models.mixture import convolve, product, reduce, reduce_reference, uniform_ball

from test_metamorphic import I2, ZERO, _mixture_models
from test_mixture_continuity import T, _moved


def _permuted(mix, p):
    return DiagMixture(mix.weights[..., p], mix.means[..., p, :], mix.variances[..., p, :])


def _cases(rng):
    """Mixtures with and without exact ties: random products (d = 1, 2, 3), a mixture times
    itself ((i, j) and (j, i) tie), equal weights, a Gaussian convolved with the disk cells
    (60-degree symmetric: weights and costs tie in sixes)."""
    out = []
    for d in (1, 2, 3):
        a = DiagMixture.create(rng.uniform(0.1, 1, (40, 8)), rng.normal(0, 3, (40, 8, d)),
                               rng.uniform(0.5, 2, (40, 8, d)))
        b = DiagMixture.create(rng.uniform(0.1, 1, (40, 8)), rng.normal(0, 3, (40, 8, d)),
                               rng.uniform(0.5, 2, (40, 8, d)))
        out += [product(a, b), product(a, a)]
    out.append(DiagMixture.create(np.ones((20, 30)), rng.normal(0, 3, (20, 30, 2)),
                                  np.full((20, 30, 2), 0.7)))
    post = DiagMixture.create(rng.uniform(0.2, 1, (20, 5)), rng.normal(0, 2, (20, 5, 2)),
                              rng.uniform(0.2, 0.5, (20, 5, 2)))
    out.append(convolve(post, uniform_ball(np.full(20, 1.3), 2)))
    return out


def test_kernel_equals_numpy_reference_bit_for_bit():
    for mix in _cases(np.random.default_rng(21)):
        for kmax in (8, 3):
            fast, ref = reduce(mix, kmax), reduce_reference(mix, kmax)
            np.testing.assert_array_equal(fast.weights, ref.weights)
            np.testing.assert_array_equal(fast.means, ref.means)
            np.testing.assert_array_equal(fast.variances, ref.variances)


def test_reduction_does_not_depend_on_component_order():
    rng = np.random.default_rng(22)
    for mix in _cases(rng):
        base = reduce(mix, 6)
        for _ in range(3):
            other = reduce(_permuted(mix, rng.permutation(mix.n_components)), 6)
            np.testing.assert_array_equal(other.weights, base.weights)
            np.testing.assert_array_equal(other.means, base.means)
            np.testing.assert_array_equal(other.variances, base.variances)


def test_tie_rule_keeps_rotation_and_translation():
    """A half turn plus a shift of a tied mixture (disk cells, a mixture times itself)
    turns and shifts its reduction (to rounding: the rule reads no position)."""
    rng = np.random.default_rng(23)
    shift = np.array([1234.5, -987.25])
    for mix in _cases(rng)[2:4] + _cases(rng)[-2:]:
        turned = DiagMixture(mix.weights, shift - mix.means, mix.variances)
        a, b = reduce(mix, 5), reduce(turned, 5)
        ka = np.lexsort((a.means[..., 1], a.means[..., 0], -a.weights), axis=-1)
        mb = shift - b.means
        kb = np.lexsort((mb[..., 1], mb[..., 0], -b.weights), axis=-1)
        np.testing.assert_allclose(np.take_along_axis(mb, kb[..., None], -2),
                                   np.take_along_axis(a.means, ka[..., None], -2), atol=1e-9)


@pytest.fixture(scope="module")
def walk():
    from test_mixture_continuity import _mean_rss
    rng = np.random.default_rng(3)
    dt = 0.333 + 0.0005 * rng.standard_normal(T)
    time = np.concatenate([[0.0], np.cumsum(dt[1:])])
    path = np.c_[6 + 4 * np.sin(0.01 * np.arange(T)), 3 + 2 * np.sin(0.013 * np.arange(T))]
    rss = _mean_rss(path) + rng.normal(0, 1.0, (T, 4))
    return time[:300], rss[:300]


@pytest.mark.parametrize("reduction", ["continuous", "runnalls"])
def test_tracker_on_tied_grid_model_ignores_component_order(walk, reduction):
    """The symmetric grid model: every weight ties, and distances to a corner station tie
    in pairs (its 0.11 m case)."""
    time, rss = walk
    mod = _mixture_models(I2, ZERO, None)
    ref = MixtureTracker(mod, UniformDisk(1.5), 8, reduction=reduction).run(rss, time).position
    for seed in (5, 6):
        p = np.random.default_rng(seed).permutation(mod.n_components)
        got = MixtureTracker(_permuted(mod, p), UniformDisk(1.5), 8,
                             reduction=reduction).run(rss, time).position
        assert _moved(got, ref) < 1e-9


def test_localizer_on_tied_grid_model_ignores_component_order(walk):
    _, rss = walk
    mod = _mixture_models(I2, ZERO, None)
    ref = MixtureLocalizer(mod, 8).locate(rss).position
    p = np.random.default_rng(7).permutation(mod.n_components)
    got = MixtureLocalizer(_permuted(mod, p), 8).locate(rss).position
    assert _moved(got, ref) < 1e-9
