"""The lane reduction's pass 1: its bound and its flat indexing.

- ``models.mixture._cost_bound`` (the logarithm-free bound of Runnalls' cost that pass 1 of
  ``_partner`` and ``_west_lanes`` computes for every candidate) never exceeds the exact
  cost (``log1p`` of the same ``y``), on random and adversarial inputs: weights over 300
  decades, near-degenerate covariances (``y`` near its floor ``-3/4``, ``y`` near 0,
  variances from ``1e-50`` to ``1e50``); and it is within 1e-3 of the cost's terms for
  ``-0.5 < y < 1`` (a bound that excludes nothing would make every merge cost exactly).
- ``_west_lanes`` indexes its lane array and lane state as flat arrays with constant
  strides in pass 1: the same results bit for bit as the NumPy reference on 2-D batches
  with weights over many decades and near-degenerate covariances.
"""

import numpy as np

from radioloc.models.mixture import (_LANES, DiagMixture, _cost_bound, reduce,
                                     reduce_reference)


def _pairs(rng, n):
    """Random (i, c) pairs with ``wi <= wc`` (i: the lowest weight) and the kernel's
    ``y`` (``_partner``'s arithmetic), ``log|P|`` of both."""
    wi = 10.0 ** rng.uniform(-300, 0, n)
    wc = np.minimum(wi * 10.0 ** rng.uniform(0, 12, n), 1.0)
    wc = np.maximum(wc, wi)
    scale = 10.0 ** rng.uniform(-50, 50, (n, 1))
    vi = scale * 10.0 ** rng.uniform(-3, 3, (n, 2))
    vc = scale * 10.0 ** rng.uniform(-3, 3, (n, 2))
    dm = np.sqrt(scale) * rng.normal(0, 1, (n, 2)) * 10.0 ** rng.uniform(-8, 2, (n, 1))
    return wi, wc, vi, vc, dm


def _adversarial(n):
    """Near-degenerate pairs: ``y`` near ``-3/4`` (equal weights, ``i`` far narrower, same
    mean), ``y`` near 0 (equal covariances, nearly equal means), ``y`` tiny and negative."""
    rng = np.random.default_rng(7)
    wi = np.full(n, 1.0 / 64)
    wc = wi * np.where(rng.uniform(size=n) < 0.5, 1.0, 1.0 + 10.0 ** rng.uniform(-12, 0, n))
    vc = 10.0 ** rng.uniform(-40, 40, (n, 1)) * np.ones((n, 2))
    kind = rng.integers(0, 3, n)
    shrink = np.where(kind[:, None] == 0, 10.0 ** rng.uniform(-15, -1, (n, 2)),
                      np.where(kind[:, None] == 1, 1.0, 1.0 - 10.0 ** rng.uniform(-15, -3, (n, 2))))
    vi = vc * shrink
    dm = np.where(kind[:, None] == 1, np.sqrt(vc) * 10.0 ** rng.uniform(-9, -1, (n, 2)), 0.0)
    return wi, wc, vi, vc, dm


def _costs(wi, wc, vi, vc, dm):
    """``y``, the exact cost with ``log1p`` and the bound, per pair."""
    ws = wi + wc
    inv = 1.0 / ws
    a1, a2 = wi * inv, wc * inv
    a12 = a1 * a2
    ivc = 1.0 / vc
    r = (a1[:, None] * (vi - vc) + a12[:, None] * dm * dm) * ivc
    y = r[:, 0] + r[:, 1] + r[:, 0] * r[:, 1]
    ldc = np.log(vc[:, 0] * vc[:, 1])
    ldi = np.log(vi[:, 0] * vi[:, 1])
    cost = 0.5 * (wi * (ldc - ldi) + ws * np.log1p(y))
    lb = np.array([_cost_bound(y[k], ldc[k], wi[k], ws[k], ldi[k], abs(ldi[k]))
                   for k in range(y.size)])
    terms = wi * (np.abs(ldc) + np.abs(ldi)) + ws * np.abs(np.log1p(y))
    return y, cost, lb, terms


def test_bound_never_exceeds_the_exact_cost_random():
    y, cost, lb, _ = _costs(*_pairs(np.random.default_rng(3), 6000))
    ok = np.isfinite(cost)
    assert ok.mean() > 0.99
    bad = ok & (lb > cost)
    assert not bad.any(), (y[bad], (lb - cost)[bad])


def test_bound_never_exceeds_the_exact_cost_near_degenerate():
    y, cost, lb, terms = _costs(*_adversarial(6000))
    assert y.min() < -0.74 and np.abs(y).min() < 1e-12       # both ends reached
    assert np.all(np.isfinite(cost))
    bad = lb > cost
    assert not bad.any(), (y[bad], (lb - cost)[bad] / terms[bad])


def test_bound_is_tight_where_merges_compete():
    # a bound that excluded nothing (-inf, or a series truncated too early) would pass the
    # tests above and cost every candidate exactly
    wi, wc, vi, vc, dm = _pairs(np.random.default_rng(5), 6000)
    y, cost, lb, terms = _costs(wi, wc, vi, vc, dm)
    mid = (y > -0.5) & (y < 1.0) & np.isfinite(cost)
    assert mid.sum() > 500
    assert np.all(cost[mid] - lb[mid] <= 1e-3 * terms[mid] + 1e-300)
    y2, cost2, lb2, terms2 = _costs(*_adversarial(3000))
    mid2 = (y2 > -0.5) & (y2 < 1.0)
    assert mid2.sum() > 500
    assert np.all(cost2[mid2] - lb2[mid2] <= 1e-3 * terms2[mid2] + 1e-300)


def _batch(rng, b, spread):
    k = 8
    a = DiagMixture.create(10.0 ** rng.uniform(-spread, 0, (b, k)), rng.normal(0, 3, (b, k, 2)),
                           10.0 ** rng.uniform(-2, 2, (b, k, 2)))
    c = DiagMixture.create(10.0 ** rng.uniform(-spread, 0, (b, k)), rng.normal(0, 3, (b, k, 2)),
                           10.0 ** rng.uniform(-2, 2, (b, k, 2)))
    w = (a.weights[:, :, None] * c.weights[:, None, :]).reshape(b, k * k)
    m = (0.5 * (a.means[:, :, None] + c.means[:, None, :])).reshape(b, k * k, 2)
    v = (a.variances[:, :, None] * c.variances[:, None, :]).reshape(b, k * k, 2)
    return DiagMixture.create(w, m, v)


def test_lanes_with_flat_pass1_equal_the_reference():
    rng = np.random.default_rng(11)
    for spread in (0.5, 30.0):                           # weights over 1 or 60 decades
        mix = _batch(rng, 2 * _LANES, spread)
        got, want = reduce(mix, 8), reduce_reference(mix, 8)
        np.testing.assert_array_equal(got.weights, want.weights)
        np.testing.assert_array_equal(got.means, want.means)
        np.testing.assert_array_equal(got.variances, want.variances)
