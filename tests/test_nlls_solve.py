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


def test_a_fix_in_earth_centred_coordinates_ends_in_a_few_steps():
    """Pseudoranges from satellites 2.66e7 m from the Earth's centre, the receiver near
    6.4e6 m and 50 m from the start, a clock offset of -1.4e5 m: every fix ends (converged
    or stalled) within 6 Gauss-Newton steps; steps at the spacing of the numbers there
    (about 1e-9 m) are rounding, not progress."""
    rng = np.random.default_rng(7)
    n = 200
    start = np.array([3.785e6, 0.8998e6, 5.0375e6])
    sats = rng.normal(size=(n, 10, 3))
    sats = sats / np.linalg.norm(sats, axis=-1, keepdims=True) + 1.2 * start / np.linalg.norm(start)
    sats *= 2.66e7 / np.linalg.norm(sats, axis=-1, keepdims=True)     # all above the horizon
    truth = start + rng.uniform(-50, 50, (n, 3))
    z = np.linalg.norm(sats - truth[:, None], axis=-1) - 1.4e5 + 3.0 * rng.standard_normal((n, 10))

    def residuals(x):
        d = x[:, None, :3] - sats
        r = np.linalg.norm(d, axis=-1)
        return z - r - x[:, None, 3], np.concatenate([d / r[..., None], np.ones(r.shape + (1,))], -1)

    fit = solve_nlls(residuals, np.concatenate([np.tile(start, (n, 1)), np.zeros((n, 1))], 1))
    assert np.all(fit.converged | fit.stalled) and fit.iterations.max() <= 6, np.bincount(fit.iterations)
    assert fit.converged.mean() > 0.8
    assert np.max(np.linalg.norm(fit.x[:, :3] - truth, axis=-1)) < 30.0
