"""The batched linear solve inside the NLLS driver, through solve_nlls on linear models:
the Gauss-Newton step equals LAPACK's solve of the normal equations; singular systems stall, unsolved."""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.estimators.nlls import solve_nlls


def _linear(J, z):
    def residuals(x):
        return z - np.einsum("bmi,bi->bm", J, x), J
    return residuals


@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_equals_lapack_on_well_conditioned_systems(n):
    rng = np.random.default_rng(n)
    J = rng.normal(size=(300, 2 * n + 2, n))
    z = rng.normal(size=(300, 2 * n + 2))
    fit = solve_nlls(_linear(J, z), np.zeros((300, n)), method="gauss-newton", max_iter=5)
    JT = np.swapaxes(J, -1, -2)
    ref = np.linalg.solve(JT @ J, (JT @ z[..., None]))[..., 0]        # the normal equations
    assert fit.converged.all() and not fit.stalled.any()
    np.testing.assert_allclose(fit.x, ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("n", [2, 3, 4])
def test_singular_systems_stall_without_a_step(n):
    rng = np.random.default_rng(10 + n)
    u = rng.normal(size=n)
    good = np.eye(n)[None].repeat(2, 0).reshape(2 * n, n)        # J'J = 2 I
    rank_one = np.outer(rng.normal(size=2 * n), u)               # J'J exactly singular
    near = good.copy()
    near[:, -1] *= 1e-8                                          # J'J condition number 1e16
    J = np.stack([good, rank_one, near])
    fit = solve_nlls(_linear(J, np.ones((3, 2 * n))), np.zeros((3, n)),
                     method="gauss-newton", max_iter=5, ridge=0.0)
    assert fit.stalled.tolist() == [False, True, True]
    np.testing.assert_allclose(fit.x[0], 1.0)
    assert np.all(fit.x[1:] == 0.0)
