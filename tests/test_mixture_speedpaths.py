"""The arithmetic of the compiled West/Runnalls kernel: Runnalls' cost computed without
cancellation equals the textbook formula, the logarithm-free bound that lets the kernel skip
candidates is below the cost it skips (also for negligible weights, shrinking merges and
subnormal-sized ratios), and a negligible component is merged into its cheapest partner
(its cost, not the tie rule, decides)."""

import numpy as np

from radioloc.models.mixture import (DiagMixture, _cost_bound, _logdet_np, _partners,
                                     reduce, reduce_reference, runnalls_cost)


def _pairs(rng, n=4000):
    """Random component pairs: weights over 30 decades, means up to far apart, variances
    over four decades (shrinking and widening merges)."""
    wi = 10.0 ** rng.uniform(-30, 0, n)
    wc = wi * 10.0 ** rng.uniform(0, 30, n)
    mi, mc = rng.normal(0, 3, (n, 2)), rng.normal(0, 3, (n, 2))
    mc[: n // 4] = mi[: n // 4] + 1e-9 * rng.normal(size=(n // 4, 2))
    vi, vc = 10.0 ** rng.uniform(-2, 2, (n, 2)), 10.0 ** rng.uniform(-2, 2, (n, 2))
    return wi, mi, vi, wc, mc, vc


def _kernel_costs(wi, mi, vi, wc, mc, vc):
    """cost, scale and y of the kernel's arithmetic through the NumPy reference
    (``_partners`` of two-component rows)."""
    w = np.c_[wi, wc]
    m = np.stack([mi, mc], 1)
    v = np.stack([vi, vc], 1)
    j, cost, scale = _partners(w, m, v, 1.0 / v, _logdet_np(v), np.ones(w.shape, bool),
                               np.zeros(w.shape[0], int))
    assert np.all(j == 1)
    return cost, scale


def test_cost_equals_runnalls_formula():
    rng = np.random.default_rng(31)
    wi, mi, vi, wc, mc, vc = _pairs(rng)
    cost, scale = _kernel_costs(wi, mi, vi, wc, mc, vc)
    ref = runnalls_cost(wi, mi, vi, wc, mc, vc)
    # the textbook form cancels: its rounding is eps times w_c |log|P_c||
    tol = 1e-13 * (scale + (wi + wc) * np.abs(np.log(vc).sum(-1)) + wi * np.abs(np.log(vi).sum(-1)))
    assert np.all(np.abs(cost - ref) <= tol)
    assert np.all(cost >= -1e-15 * scale)                     # Runnalls' cost is >= 0


def test_bound_is_below_the_cost_it_skips():
    rng = np.random.default_rng(32)
    wi, mi, vi, wc, mc, vc = _pairs(rng)
    cost, scale = _kernel_costs(wi, mi, vi, wc, mc, vc)
    ws = wi + wc
    a1, a2 = wi / ws, wc / ws
    dm = mi - mc
    r = (a1[:, None] * (vi - vc) + (a1 * a2)[:, None] * dm * dm) * (1.0 / vc)
    y = r[:, 0] + r[:, 1] + r[:, 0] * r[:, 1]
    ldi, ldc = _logdet_np(vi), _logdet_np(vc)
    lb = np.array([_cost_bound(y[k], ldc[k], wi[k], ws[k], ldi[k], abs(ldi[k]))
                   for k in range(y.size)])
    assert np.all(lb <= cost)
    close = (y > -0.5) & (y < 1.0)                            # the bound is tight there
    assert np.all(cost[close] - lb[close] <= 1e-3 * np.abs(cost[close]) + 1e-13 * scale[close])
    # tiny ratios (no subnormal powers): still below
    for yy in (1e-120, -1e-120, 1e-300, -1e-300, 0.0):
        assert _cost_bound(yy, 0.3, 1e-200, 1.0, 0.1, 0.1) <= 0.5 * (1e-200 * 0.2 + np.log1p(yy))


def test_negligible_component_goes_to_its_cheapest_partner():
    """A component of weight 1e-12 next to B (cost about 1e-13) and far from A, which is
    nearer the mixture mean: merged into B. (A tie window of 1e-9 of w |log|P|| had
    counted every partner of so light a component as tied, and the tie rule chose A.)"""
    w = np.array([[0.6, 0.4, 1e-12]])
    m = np.array([[[0.0, 0.0], [10.0, 0.0], [9.5, 0.0]]])
    v = np.full((1, 3, 2), 4.0)
    mix = DiagMixture(w, m, v)
    for out in (reduce(mix, 2), reduce_reference(mix, 2)):
        assert out.weights[0, 0] == 0.6
        assert out.weights[0, 1] == 0.4 + 1e-12
        assert out.means[0, 1, 0] < 10.0
        np.testing.assert_array_equal(out.means[0, 0], [0.0, 0.0])
