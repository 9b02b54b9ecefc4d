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
    valid = g.random((b, nl)) < 0.7
    q = g.random((b, nl, k))
    q0 = q.copy()
    std = 0.37
    ref = [a.copy() for a in (parts, idx, q)]
    orig = parts.copy()
    reset_numpy(reset, mean, np.random.default_rng(5), std, dim, *ref[:2], q_rows, ref[2])
    # the same draws, taken into a work array as run does, by the compiled generator
    z = np.empty(int(reset.sum()) * k * dim + 3)
    K.fill_standard_normal(np.random.default_rng(5), z)
    K.reset_filters(reset, mean, z, std, dim, parts, idx, q_rows, valid, q)
    assert np.array_equal(parts, ref[0]) and np.array_equal(idx, ref[1])
    # the rows of existing links as the NumPy reset, the padding rows untouched
    for bb in range(b):
        for j in range(nl):
            assert np.array_equal(q[bb, j], ref[2][bb, j] if valid[bb, j] else q0[bb, j])
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
                    idx, g.random((3, 2)), np.ones((3, 2), dtype=bool), q)
    assert all(np.array_equal(a, r) for a, r in zip((parts, idx, q), before))


def search(w, u):
    """The sequential search of ``systematic_indices`` (one chunk), in Python."""
    k = len(w)
    idx = np.empty(k, dtype=np.int64)
    i, cdf = 0, 0.0 + w[0]
    for j in range(k):
        pos = (u + j) / k
        while cdf <= pos and i < k - 1:
            i += 1
            cdf += w[i]
        idx[j] = i
    return idx


def test_moments_resample_counts_equal_the_search_at_ties():
    """The count-based systematic resampling of ``moments_resample`` gives the search's
    indices where positions and cumulative sums tie exactly (weights of 1/8 and 1/64:
    ``cdf_i = pos_j`` in binary), with zero weights, one weight, and a NaN row; and the
    distinct ancestors."""
    k = 64
    rows = [np.full(k, 1.0 / k), np.repeat([1.0 / 8, 0.0], [8, k - 8]),
            np.r_[np.zeros(k - 1), 1.0], np.r_[1.0, np.zeros(k - 1)],
            np.tile([0.0, 2.0 / k], k // 2), np.full(k, np.nan)]
    g = np.random.default_rng(9)
    r = g.random((4, k)) ** 8
    rows += list(r / r.sum(-1, keepdims=True))
    w_rows = np.array(rows)
    b = len(w_rows)
    for u0 in (0.0, 0.5, 0.25, 1.0 - 2.0 ** -53, 0.123):
        u = np.full(b, u0)
        # log weights whose normalised weights are w_rows (exact for powers of two)
        with np.errstate(divide="ignore", invalid="ignore"):
            log_w = np.log(w_rows)
        x = g.normal(size=(b, k, 2))
        out = (np.empty((b, k)), np.empty((b, 2)), np.empty((b, 2, 2)), np.empty(b),
               np.empty((b, k), dtype=np.int64), np.empty(b, dtype=np.int64))
        K.moments_resample(log_w, x, u, *out)
        w, idx, distinct = out[0], out[4], out[5]
        ref_chunked = np.empty((b, k), dtype=np.int64)
        K.systematic_indices(w, u, ref_chunked, 4096)
        for row in range(b):
            ref = search(w[row], u0)
            assert np.array_equal(idx[row], ref), (u0, row)
            assert distinct[row] == len(np.unique(ref))
        assert np.array_equal(idx, ref_chunked)
    # the exact ties happen: some cdf equals some position
    cdf = np.cumsum(np.full(k, 1.0 / k))
    assert np.intersect1d(cdf, (0.0 + np.arange(k)) / k).size > 0


def test_fill_standard_normal_is_numpys():
    """The compiled draws equal ``Generator.standard_normal`` and leave the generator in
    the same state (so the draws after it agree too)."""
    for bg in (np.random.PCG64,):
        a, b = np.random.Generator(bg(11)), np.random.Generator(bg(11))
        out = np.empty(200_001)                 # about 50 draws from the ziggurat's tail
        K.fill_standard_normal(a, out)
        assert np.array_equal(out, b.standard_normal(200_001))
        assert np.array_equal(a.random(5), b.random(5))


def test_run_equals_steps_with_pooled_draws_and_deferred_resets(monkeypatch):
    """With the motion draws in parts from spawned children (sizes lowered so the highway of
    64 particles takes that path), ``run`` draws each step's reset from ``rng`` while the
    pool fills the next step's parts, and writes it before the next prediction: the track
    and the generator's state afterwards equal the steps' bit for bit; a reset written one
    step late would not."""
    from radioloc.estimators import p2p_particle as pp
    from radioloc.estimators.p2p_particle import P2PParticleFilter
    from radioloc.models.motion import InputDriven
    from test_p2p_step_carried import by_steps, highway, same_track
    monkeypatch.setattr(pp, "_DRAW_PARALLEL", 256)
    monkeypatch.setattr(pp, "_DRAW_PART", 160)
    sc, model, data = highway()
    pf = P2PParticleFilter(InputDriven(sc.ins_std_m), model, particles=64)
    r1, r2 = np.random.default_rng(1), np.random.default_rng(1)
    fast = pf.run(data.ranges, data.truth[:, :, 0], r1, anchors=data.anchors, controls=data.ins)
    ref = by_steps(pf, data.ranges, data.truth[:, :, 0], r2, data.anchors, controls=data.ins)
    assert fast.diagnostics["resets"][..., -1].sum() > 0          # the reset branch ran
    assert same_track(fast, ref)
    assert np.array_equal(r1.random(3), r2.random(3))
    assert np.array_equal(r1.spawn(1)[0].random(3), r2.spawn(1)[0].random(3))


def test_fill_normal_falls_back_to_numpy(monkeypatch):
    """A generator numba cannot take is drawn by NumPy, the same numbers."""
    from numba.core.errors import TypingError
    from radioloc.estimators import p2p_particle as pp

    def refuse(rng, out):
        raise TypingError("no numba type")
    monkeypatch.setattr(pp._k, "fill_standard_normal", refuse)
    out = np.empty(50)
    pp._fill_normal(np.random.default_rng(4), out)
    assert np.array_equal(out, np.random.default_rng(4).standard_normal(50))
