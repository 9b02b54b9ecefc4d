"""The batched linear solve inside the NLLS driver: equal to LAPACK, singular systems flagged."""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.estimators.nlls import _solve


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_equals_lapack_on_well_conditioned_systems(n):
    rng = np.random.default_rng(n)
    J = rng.normal(size=(300, 2 * n + 2, n))
    A = np.einsum("bmi,bmj->bij", J, J)          # normal matrices, as the driver builds
    b = rng.normal(size=(300, n))
    s, ok = _solve(A, b)
    ref = np.linalg.solve(A, b[..., None])[..., 0]
    assert ok.all()
    np.testing.assert_allclose(s, ref, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_singular_and_non_finite_systems_are_flagged_not_solved(n):
    rng = np.random.default_rng(10 + n)
    good = np.eye(n) * 2.0
    u = rng.normal(size=n)
    rank_one = np.outer(u, u)                    # exactly singular (n >= 2)
    near = np.eye(n)
    near[-1, -1] = 1e-16                         # condition number 1e16
    bad = np.eye(n)
    bad[0, 0] = np.nan
    A = np.stack([good, rank_one, near, bad])
    s, ok = _solve(A, np.ones((4, n)))
    assert ok.tolist() == [True, False, False, False]
    np.testing.assert_allclose(s[0], 0.5)
    assert np.all(s[1:] == 0.0) and np.all(np.isfinite(s))
