"""The parallel weights/moments, systematic resampling and gather kernels of the particle
filter against plain NumPy on random inputs, with chunks smaller than the particle sets so
that every chunk boundary is exercised."""

import numpy as np
import pytest

from radioloc.estimators import pf_kernels as K
from radioloc.estimators.p2p_particle import _moments


@pytest.mark.parametrize("n", [2, 4])
@pytest.mark.parametrize("chunk", [7, 64, 4096])
def test_weights_moments_equal_numpy(n, chunk):
    rng = np.random.default_rng(n + chunk)
    b, k = 5, 1000
    log_w = rng.normal(size=(b, k)) * 5
    # positions far from the origin: the moments must not lose the digits of the offset
    particles = 1e4 + rng.normal(size=(b, k, n))
    w, mean, cov, ess = np.empty((b, k)), np.empty((b, n)), np.empty((b, n, n)), np.empty(b)
    K.weights_moments(log_w, particles, chunk, w, mean, cov, ess)
    rw, rmean, rcov, ress = _moments(log_w, particles, "numpy")
    np.testing.assert_allclose(w, rw, rtol=1e-12)
    np.testing.assert_allclose(mean, rmean, rtol=1e-14, atol=1e-12)
    np.testing.assert_allclose(cov, rcov, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ess, ress, rtol=1e-12)


@pytest.mark.parametrize("chunk", [1, 13, 100, 4096])
def test_systematic_indices_chunked_against_searchsorted(chunk):
    rng = np.random.default_rng(chunk)
    w = rng.random((6, 1000)) ** 6
    w[2, 100:400] = 0.0                       # chunks with no weight
    w /= w.sum(-1, keepdims=True)
    u = rng.random(6)
    u[0] = 0.0
    idx = np.empty(w.shape, dtype=np.int64)
    K.systematic_indices(w, u, idx, chunk)
    cdf = np.cumsum(w, -1)
    cdf[:, -1] = 1.0 + 1e-12
    ref = np.stack([np.minimum(np.searchsorted(c, (uu + np.arange(1000)) / 1000, side="right"), 999)
                    for c, uu in zip(cdf, u)])
    np.testing.assert_array_equal(idx, ref)
    assert np.all(np.diff(idx, axis=-1) >= 0)


@pytest.mark.parametrize("chunk", [3, 50, 4096])
def test_gather_resampled_chunked_equals_numpy(chunk):
    rng = np.random.default_rng(chunk)
    particles, q = rng.normal(size=(4, 200, 2)), rng.random((4, 200, 5))
    idx = rng.integers(0, 200, (4, 200))
    idx[1] = 7                                 # one ancestor
    op, oq = np.empty_like(particles), np.empty_like(q)
    distinct = np.empty(4, dtype=np.int64)
    K.gather_resampled(particles, q, idx, op, oq, distinct, np.empty((4, 200), dtype=bool), chunk)
    np.testing.assert_array_equal(op, np.take_along_axis(particles, idx[..., None], axis=1))
    np.testing.assert_array_equal(oq, np.take_along_axis(q, idx[..., None], axis=1))
    np.testing.assert_array_equal(distinct, [len(np.unique(r)) for r in idx])


def test_large_normal_draws_are_reproducible_and_standard():
    from radioloc.estimators import p2p_particle as pp
    shape = (3, 70_000)                                    # above the parallel threshold
    a = pp._standard_normal(np.random.default_rng(4), shape)
    b = pp._standard_normal(np.random.default_rng(4), shape)
    np.testing.assert_array_equal(a, b)
    assert a.shape == shape
    # parts from independent children: mean 0, variance 1 within 5 standard errors
    n = a.size
    assert abs(a.mean()) < 5 / np.sqrt(n)
    assert abs(a.var() - 1.0) < 5 * np.sqrt(2.0 / n)
    # parts do not repeat each other
    part = pp._DRAW_PART
    flat = a.ravel()
    assert not np.array_equal(flat[:100], flat[part:part + 100])
    # small draws: the generator's own stream
    np.testing.assert_array_equal(pp._standard_normal(np.random.default_rng(4), (5, 2)),
                                  np.random.default_rng(4).standard_normal((5, 2)))
