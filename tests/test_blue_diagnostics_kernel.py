"""Pieces of the compiled BLUE of paper 002 that have their own plain reference:

* the ``trajectory`` diagnostic written by the kernel (``_blue_tracks_range``) equals
  :func:`radioloc.models.single_sensor.trajectory` of the returned state bit for bit (the
  same two operations per entry, no contraction in that kernel);
* the width-4 structured Cholesky recursion with its sums in local scalars
  (``_factor_solve4``) against the general recursion over work arrays (``_factor_solve``)
  and against NumPy's dense Cholesky of the same ``W`` (band plus ``F U'`` beyond it);
* the one-pass 5 x 5 Gram (``_gram5``) against the 15 dot products.

Tolerances: the recursions and NumPy factorise the same well-conditioned W (diagonal
dominant, condition number below 10) in different operation orders, so they agree to a
few ulps times the condition number: 1e-12 relative is asserted."""

import numpy as np
import pytest

from radioloc.estimators import closed_form as cf
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.models.single_sensor import trajectory
from test_closed_form_kernels import T, _tracks


@pytest.mark.parametrize("B,k,gap", [(40, None, False), (5, None, False), (40, 7, True)])
def test_kernel_trajectory_equals_the_model_trajectory(B, k, gap):
    n = 20
    r, s = _tracks(np.random.default_rng(3), B, n)
    if gap:
        r = r.copy()
        r[1, 4] = np.nan
    est = ClosedFormTracker(0.15, 0.1, reference_index=k).locate(r, s, T)
    ref = trajectory(est.diagnostics["state"], n, T, n - 1 if k is None else k)
    assert est.diagnostics["trajectory"].shape == (B, n, 2)
    np.testing.assert_array_equal(est.diagnostics["trajectory"], ref)


def _structured_system(m, r, rng):
    """A random ``W`` of the structured form (band of half-width 3 in ``wb``, ``W_ij =
    F_j . U_i`` for ``i >= j + 4``), diagonal dominant, and its dense twin."""
    pad = cf._PAD
    F = rng.normal(0.0, 0.05, (r, m))
    U = rng.normal(0.0, 0.05, (r, m))
    wb = np.zeros((4, m + pad))
    wb[0, pad:] = 20.0 + rng.random(m)
    for lag in range(1, 4):
        wb[lag, pad:pad + m - lag] = rng.normal(0.0, 0.5, m - lag)
    W = np.zeros((m, m))
    for j in range(m):
        for lag in range(4):
            if j + lag < m:
                W[j, j + lag] = W[j + lag, j] = wb[lag, pad + j]
        for i in range(j + 4, m):
            W[i, j] = W[j, i] = F[:, j] @ U[:, i]
    Z = rng.normal(0.0, 1.0, (5, m))
    return wb, F, U, Z, W


def _factor(fn, m, r, wb, F, U, Z, *extra):
    pad = cf._PAD
    lb = np.zeros((m + pad, 4))
    lb[:pad, 0] = 1.0
    li = np.ones(m + pad)
    qv = np.zeros((m + pad, r))
    zz = np.zeros((m + pad, r))
    X = np.zeros((5, m + pad))
    ok = fn(m, *extra, wb, F, U, Z, lb, li, qv, zz, *(
        (np.empty((r, r)), np.empty((r, 5))) if extra else ()), X)
    return ok, X[:, pad:], lb[pad:]


def test_width4_recursion_matches_the_general_recursion_and_numpy():
    m, r = 40, 4
    wb, F, U, Z, W = _structured_system(m, r, np.random.default_rng(11))
    ok4, X4, lb4 = _factor(cf._factor_solve4, m, r, wb, F, U, Z)
    okg, Xg, lbg = _factor(cf._factor_solve, m, r, wb, F, U, Z, r)
    assert ok4 and okg
    L = np.linalg.cholesky(W)
    Xref = np.linalg.solve(L, Z.T).T
    assert np.linalg.cond(W) < 10.0
    np.testing.assert_allclose(X4, Xg, rtol=0, atol=1e-12 * np.abs(Xg).max())
    np.testing.assert_allclose(X4, Xref, rtol=0, atol=1e-12 * np.abs(Xref).max())
    np.testing.assert_allclose(lb4[:, 0], np.diag(L), rtol=1e-12)
    np.testing.assert_allclose(lb4[1:, 1], np.diag(L, -1), rtol=0, atol=1e-12)


def test_width4_recursion_reports_a_non_positive_pivot():
    m, r = 20, 4
    wb, F, U, Z, _ = _structured_system(m, r, np.random.default_rng(12))
    wb[0, cf._PAD + 9] = -1.0                       # W no longer positive definite
    ok4, *_ = _factor(cf._factor_solve4, m, r, wb, F, U, Z)
    okg, *_ = _factor(cf._factor_solve, m, r, wb, F, U, Z, r)
    assert not ok4 and not okg


def test_gram5_equals_the_dot_products():
    X = np.random.default_rng(13).normal(size=(5, 30))
    G = np.empty((5, 5))
    cf._gram5(X, 4, 27, G)
    Xs = X[:, 4:27]
    ref = np.array([[sum(Xs[p, j] * Xs[q, j] for j in range(Xs.shape[1])) for q in range(5)]
                    for p in range(5)])
    np.testing.assert_allclose(G, ref, rtol=1e-14)
    np.testing.assert_array_equal(G, G.T)
