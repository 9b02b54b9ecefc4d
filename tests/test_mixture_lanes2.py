"""The lane reduction's exact costing in the lane, its vectorised logarithm, and the lanes in
the compiled eq. (2) of :class:`MixtureLocalizer`.

- ``models.mixture._best_above``: the cost of the lowest bound that pass 2's skip test of
  ``_west_lanes`` compares with, from a vectorised logarithm plus a margin: never below the
  cost with libm's ``log1p`` (the kernel's exact cost), its logarithm within a few ulps;
  ``inf`` where ``1 + y`` is not a positive normal float.
- ``_west_lanes`` with candidates the bound cannot exclude (costed in the lane,
  ``_lane_pass2``) and with ties among the exact costs (a step of ``_west_soa`` on a copy):
  the same results bit for bit as the NumPy reference and as the one-mixture kernel.
- ``MixtureLocalizer``: rows located in groups of ``_LANES`` (the products of one step
  reduced on lanes) equal the same rows located one at a time (no lanes), bit for bit, with
  stations not received in some rows (those steps row by row), and the NumPy composition
  of the same maths to rounding.
"""

import numpy as np
import pytest

from radioloc.estimators.mixture_localization import MixtureLocalizer
from radioloc.models.mixture import (_LANES, _LOG_MARGIN, DiagMixture, _best_above, product,
                                     reduce, reduce_reference)


def _assert_same(a, b):
    np.testing.assert_array_equal(a.weights, b.weights)
    np.testing.assert_array_equal(a.means, b.means)
    np.testing.assert_array_equal(a.variances, b.variances)


def _best(y, wc, ldc, wi, ldi):
    """``_best_above`` on one lane state per value (rows as in ``_west_lanes``)."""
    n = y.size
    S = np.zeros((41, n))
    S[35], S[36], S[37] = y, wc, ldc
    S[6], S[11], S[12] = wi, ldi, np.abs(ldi)
    _best_above(S, S.view(np.int64), 35, 36, 37, 6, 11, 12, 18)
    return S[18]


def test_best_above_bounds_the_libm_cost_within_its_margin():
    rng = np.random.default_rng(7)
    n = 20000
    mag = 10.0 ** rng.uniform(-18, 6, n)
    y = np.concatenate([mag, -np.minimum(mag, 1 - 1e-16), rng.uniform(-1, 3, n),
                        [0.0, 1e-300, -1e-300, 5e-324, 1e300, -1 + 2.0 ** -53]])
    wi = rng.uniform(1e-4, 0.5, y.size)
    wc = rng.uniform(1e-4, 0.9, y.size)
    ldc = rng.normal(0, 3, y.size)
    ldi = rng.normal(0, 3, y.size)
    got = _best(y, wc, ldc, wi, ldi)
    ws = wi + wc
    lp = np.log1p(y)
    exact = 0.5 * (wi * (ldc - ldi) + ws * lp)
    assert np.all(got >= exact)
    terms = wi * (np.abs(ldc) + np.abs(ldi)) + ws * np.abs(lp)
    assert np.all(got - exact <= 1.01 * _LOG_MARGIN * terms + 4e-16 * terms)
    # the logarithm itself: with wi = 0 and ldc = 0 the bound is ws (lp + 2 margin |lp|) / 2
    one = _best(y, np.full(y.size, 2.0), np.zeros(y.size), np.zeros(y.size), np.zeros(y.size))
    approx = one / (1.0 + 2.0 * _LOG_MARGIN * np.sign(lp))
    assert np.all(np.abs(approx - lp) <= 8 * np.finfo(float).eps * np.abs(lp) + 1e-320)


def test_best_above_is_inf_where_u_is_not_a_positive_normal_float():
    y = np.array([-1.0, np.inf, np.nan, -2.0])
    got = _best(y, np.full(4, 0.5), np.zeros(4), np.full(4, 0.5), np.zeros(4))
    assert np.all(got == np.inf)


def _grid_batch(rng, n, eps):
    """``n`` 2-D mixtures of 25 components on a 5 x 5 unit grid, weight ``1 + r^2 / 10``
    (``r``: distance to the centre) times ``1 + eps * noise``, each mixture translated by a
    multiple of 1/8. The centre has the lowest weight; its four neighbours are its equal
    best partners: with ``eps = 0`` they tie exactly (the merge takes a step of
    ``_west_soa`` on a copy, then the lane finishes alone: its lowest weights tie), with
    ``eps = 1e-7`` their costs differ by about 1e-7, beyond the tie tolerance and within the
    bound's slack (costed in the lane)."""
    g = np.stack(np.meshgrid(np.arange(5.0), np.arange(5.0)), -1).reshape(25, 2)
    r2 = np.sum((g - 2.0) ** 2, -1)
    m = g + np.round(8 * rng.uniform(0, 10, (n, 1, 2))) / 8
    w = (1.0 + 0.1 * r2) * (1.0 + eps * rng.normal(size=(n, 25)))
    return DiagMixture.create(w, m, np.full((n, 25, 2), 0.3))


@pytest.mark.parametrize("eps", [0.0, 1e-7])
def test_lanes_with_near_ties_equal_reference(eps):
    rng = np.random.default_rng(11)
    mix = _grid_batch(rng, 2 * _LANES, eps)
    fast = reduce(mix, 8)
    _assert_same(fast, reduce_reference(mix, 8))
    one = [reduce(mix[i:i + 1], 8) for i in range(0, 2 * _LANES, 9)]
    for r, i in zip(one, range(0, 2 * _LANES, 9)):
        _assert_same(r, fast[i:i + 1])


def _models(rng, s=6, k=16):
    return DiagMixture.create(rng.uniform(0.1, 1, (s, k)), rng.normal(0, 3, (s, k, 3)),
                              rng.uniform(0.5, 4, (s, k, 3)))


def test_localizer_groups_equal_rows_one_at_a_time():
    rng = np.random.default_rng(12)
    models = _models(rng)
    rss = rng.normal(0, 3, (_LANES + 13, 6))          # a full group, a part group
    rss[3, 2] = np.nan                                  # first group: one step row by row
    rss[_LANES + 2, :4] = np.nan
    loc = MixtureLocalizer(models, 8)
    batch = loc.density(rss)
    for i in range(rss.shape[0]):
        one = loc.density(rss[i:i + 1])
        kk = one.n_components
        np.testing.assert_array_equal(batch.weights[i, :kk], one.weights[0])
        np.testing.assert_array_equal(batch.means[i, :kk], one.means[0])
        np.testing.assert_array_equal(batch.variances[i, :kk], one.variances[0])
        assert np.all(batch.weights[i, kk:] == 0.0)
    ref, have = loc.density_reference(rss)
    assert np.all(have)
    kk = min(ref.n_components, batch.n_components)
    np.testing.assert_allclose(batch.weights[:, :kk], ref.weights[:, :kk], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(batch.means[:, :kk], ref.means[:, :kk], rtol=1e-9, atol=1e-9)
