"""The fused pieces of ``P2PParticleFilter.run`` (``_run_carried``) equal the NumPy they
replace, bit for bit: the reset of degenerate filters (``pf_kernels.reset_filters``) and
the count of distinct ancestors taken in ``moments_resample`` (tested with the kernel in
tests/test_p2p_step_carried.py); ``run`` equal to the steps is tested there too."""

import numpy as np
import pytest

from radioloc.estimators import pf_kernels as K


def reset_numpy(reset, mean, rng, std, dim, parts, idx, q_rows, q):
    """The reset as ``_run_carried`` wrote it in NumPy (link-major posteriors)."""
    k = parts.shape[1]
    parts[reset, :, :dim] = mean[reset][:, None, :dim] + std * \
        rng.standard_normal((int(reset.sum()), k, dim))
    idx[reset] = np.arange(k)
    q[reset] = q_rows[reset][:, :, None]


@pytest.mark.parametrize("n", [2, 4])
def test_reset_filters_equals_the_numpy_reset(n):
    g = np.random.default_rng(40 + n)
    b, k, nl, dim = 7, 33, 5, 2
    reset = np.array([True, False, False, True, True, False, True])
    mean = g.normal(size=(b, n)) * 1e3
    parts = g.normal(size=(b, k, n)) * 50.0
    idx = np.sort(g.integers(0, k, (b, k)), axis=-1)
    q_rows = g.random((b, nl))
    q = g.random((b, nl, k))
    std = 0.37
    ref = [a.copy() for a in (parts, idx, q)]
    orig = parts.copy()
    reset_numpy(reset, mean, np.random.default_rng(5), std, dim, *ref[:2], q_rows, ref[2])
    # the same draws, taken into a work array as run does
    z = np.random.default_rng(5).standard_normal(out=np.empty(int(reset.sum()) * k * dim + 3))
    K.reset_filters(reset, mean, z, std, dim, parts, idx, q_rows, q)
    for a, r in zip((parts, idx, q), ref):
        assert np.array_equal(a, r)
    # filters not reset and the components past dim are untouched
    assert np.array_equal(parts[~reset], orig[~reset])
    assert np.array_equal(parts[..., dim:], orig[..., dim:])
    assert not np.array_equal(parts[reset], orig[reset])
    assert np.array_equal(idx[reset], np.broadcast_to(np.arange(k), (4, k)))


def test_reset_filters_nothing_to_reset():
    g = np.random.default_rng(3)
    parts, idx, q = g.normal(size=(3, 8, 2)), np.zeros((3, 8), dtype=np.int64), g.random((3, 2, 8))
    before = [a.copy() for a in (parts, idx, q)]
    K.reset_filters(np.zeros(3, dtype=bool), g.normal(size=(3, 2)), np.empty(0), 0.5, 2, parts,
                    idx, g.random((3, 2)), q)
    assert all(np.array_equal(a, r) for a, r in zip((parts, idx, q), before))
