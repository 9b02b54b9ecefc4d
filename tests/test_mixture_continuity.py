"""The continuous default of :class:`MixtureTracker` (``reduction="continuous"``, the
fixed-structure merge :func:`merge_groups`): a result depends continuously on its inputs.

The walk is the one of ``test_metamorphic`` (900 steps of about 0.333 s, uneven, four
stations, 8 position components). Bounds and why:

- every ``dt`` times ``1 + 1e-12``: < 1e-6 m (measured 1.5e-12 m; before, the greedy
  West/Runnalls merge moved it by up to 1 m on a BLE walk);
- time stamps rounded to 1 ms: < 2 cm. Rounding changes each ``dt`` by at most 1 ms, so
  each disk radius ``v_max dt`` by at most 1.5 mm; the filter step is a smooth function
  of the radius (Gaussian products and moment matching, no discrete choice) and forgets
  the past through the measurements, so the estimate moves by a fraction of that radius
  change (measured 0.75 mm, 1.5e-1 m with ``reduction="runnalls"``);
- stations permuted (models and columns together): exact (the measurement density takes
  the stations by decreasing reading);
- components of the models permuted: exact to 1e-9 (the West/Runnalls reduction of the
  measurement density breaks exact ties by the components' contents, never by position;
  a tied grid is in ``test_mixture_backends``);
- the scene rotated by a half turn (the disk mixture's 60-degree symmetry and the
  axis-aligned components map onto themselves) and translated: the estimate rotates and
  translates to 1e-8 m (measured 1.2e-9 m after 900 steps: the reductions return their
  components in a canonical order, which the half turn reverses for equal weights, so
  sums run in another order and rounding accumulates).
"""

import numpy as np
import pytest

from radioloc.core.errors import InputError
from radioloc.estimators import MixtureTracker
from radioloc.models import DiagMixture, UniformDisk
from radioloc.models.mixture import merge_groups, product

from test_metamorphic import I2, SHIFT, ZERO, mean_rss, mixture_models, rot

T = 900


@pytest.fixture(scope="module")
def walk():
    rng = np.random.default_rng(3)
    dt = 0.333 + 0.0005 * rng.standard_normal(T)
    time = np.concatenate([[0.0], np.cumsum(dt[1:])])
    heading = np.cumsum(0.2 * rng.standard_normal(T))
    path = np.c_[6 + 4 * np.sin(0.01 * np.arange(T)), 3 + 2 * np.sin(0.013 * np.arange(T))]
    path = path + 0.1 * np.c_[np.cos(heading), np.sin(heading)]
    rss = mean_rss(path) + rng.normal(0, 1.0, (T, 4))
    return time, path, rss


def _random_models(seed=4):
    """Station models on a jittered grid with distinct weights (no exact ties)."""
    rng = np.random.default_rng(seed)
    base = mixture_models(I2, ZERO, None)
    s, k = base.batch_shape[-1], base.n_components
    means = base.means.copy()
    means[..., :2] += rng.normal(0, 0.2, (k, 2))
    return DiagMixture.create(rng.uniform(0.5, 1.5, (s, k)), means,
                              base.variances * rng.uniform(0.8, 1.2, (s, k, 3)))


def _track(models, rss, time, **kw):
    return MixtureTracker(models, UniformDisk(1.5), max_components=8, **kw).run(rss, time)


def _moved(a, b):
    return float(np.max(np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1)))


@pytest.fixture(scope="module")
def base(walk):
    time, _, rss = walk
    return _track(mixture_models(I2, ZERO, None), rss, time).position


def test_default_is_continuous_and_tracks(walk, base):
    time, path, rss = walk
    assert MixtureTracker(mixture_models(I2, ZERO, None), UniformDisk(1.5)).reduction \
        == "continuous"
    # the greedy tracker's RMSE on this walk is 0.438 m, the continuous one 0.437 m
    rmse = float(np.sqrt(np.mean(np.sum((base - path) ** 2, -1))))
    assert rmse < 0.6


def test_infinitesimal_dt_change_is_infinitesimal(walk, base):
    time, _, rss = walk
    for eps in (1e-12, 1e-9):
        nudged = _track(mixture_models(I2, ZERO, None), rss, time * (1 + eps)).position
        assert _moved(nudged, base) < max(1e-6, 1e4 * eps), eps


def test_time_stamps_rounded_to_1ms_move_by_less_than_2cm(walk, base):
    time, _, rss = walk
    rounded = _track(mixture_models(I2, ZERO, None), rss, np.round(time, 3)).position
    assert _moved(rounded, base) < 0.02


def test_station_permutation_is_exact(walk, base):
    time, _, rss = walk
    for perm in ([2, 0, 3, 1], [3, 2, 1, 0]):
        perm = np.array(perm)
        other = _track(mixture_models(I2, ZERO, perm), rss[:, perm], time).position
        assert _moved(other, base) < 1e-9


def test_component_permutation_is_exact_without_ties(walk):
    time, _, rss = walk
    mod = _random_models()
    ref = _track(mod, rss[:300], time[:300]).position
    p = np.random.default_rng(5).permutation(mod.n_components)
    other = DiagMixture(mod.weights[..., p], mod.means[..., p, :], mod.variances[..., p, :])
    assert _moved(_track(other, rss[:300], time[:300]).position, ref) < 1e-9


def test_prior_component_permutation_is_exact(walk):
    time, _, rss = walk
    rng = np.random.default_rng(6)
    prior = DiagMixture.create(rng.uniform(0.2, 1, 5), rng.uniform(0, 10, (5, 2)),
                               rng.uniform(0.5, 2, (5, 2)))
    p = np.array([3, 0, 4, 2, 1])
    other = DiagMixture(prior.weights[p], prior.means[p], prior.variances[p])
    mod = mixture_models(I2, ZERO, None)
    a = MixtureTracker(mod, UniformDisk(1.5), 8).run(rss[:100], time[:100], prior=prior).position
    b = MixtureTracker(mod, UniformDisk(1.5), 8).run(rss[:100], time[:100], prior=other).position
    assert _moved(a, b) < 1e-9


def test_half_turn_and_translation_move_the_estimate_with_the_scene(walk, base):
    time, _, rss = walk
    R = rot(np.pi)
    turned = _track(mixture_models(R, SHIFT, None), rss, time).position
    assert _moved((turned - SHIFT) @ R, base) < 1e-8


def test_greedy_option_is_kept_and_validated(walk):
    time, _, rss = walk
    mod = mixture_models(I2, ZERO, None)
    greedy = _track(mod, rss[:40], time[:40], reduction="runnalls").position
    cont = _track(mod, rss[:40], time[:40]).position
    assert np.all(np.isfinite(greedy)) and _moved(greedy, cont) > 0   # another re-approximation
    with pytest.raises(InputError, match="reduction"):
        MixtureTracker(mod, UniformDisk(1.5), 8, reduction="greedy")


def test_merge_groups_preserves_moments_and_is_continuous():
    rng = np.random.default_rng(7)
    a = DiagMixture.create(rng.uniform(0.1, 1, (3, 4)), rng.normal(0, 3, (3, 4, 2)),
                           rng.uniform(0.5, 2, (3, 4, 2)))
    b = DiagMixture.create(rng.uniform(0.1, 1, (3, 5)), rng.normal(0, 3, (3, 5, 2)),
                           rng.uniform(0.5, 2, (3, 5, 2)))
    p = product(a, b)
    mean, cov = p.moments()
    for keep, k in (("outer", 4), ("inner", 5)):
        g = merge_groups(p, 4, keep)
        assert g.n_components == k
        gm, gc = g.moments()
        np.testing.assert_allclose(gm, mean, atol=1e-12)
        np.testing.assert_allclose(np.diagonal(gc, axis1=-2, axis2=-1),
                                   np.diagonal(cov, axis1=-2, axis2=-1), rtol=1e-12)
        np.testing.assert_allclose(g.weights.sum(-1), 1.0, rtol=1e-12)
    # continuity: a 1e-9 change of a mean moves the merged means by about as much
    b2 = DiagMixture(b.weights, b.means + 1e-9, b.variances)
    d = merge_groups(product(a, b2), 4, "inner").means - merge_groups(p, 4, "inner").means
    assert np.max(np.abs(d)) < 1e-8
    # an empty group is an empty slot; bad structure raises
    w = p.weights.copy()
    w[:, 0::5] = 0.0                                     # every pair with b's first component
    g = merge_groups(DiagMixture(w, p.means, p.variances), 4, "inner")
    assert np.all(g.weights[:, 0] == 0) and np.all(g.variances[:, 0] == 1)
    with pytest.raises(InputError, match="n_outer"):
        merge_groups(p, 3, "inner")
    with pytest.raises(InputError, match="keep"):
        merge_groups(p, 4, "both")
