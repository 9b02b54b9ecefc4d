"""The recursive grid step's explicit-vector kernels against plain references of the same
arithmetic, bit for bit: the Young-van Vliet recursions with their state in registers
(``_yvv_lanes``: the column pass's anti-causal half, the whole row pass) and the update's
block columns (``_post_column``: floor, likelihood by class, row sums).

The references compute each fused multiply-add the kernels form (``fma(g, x, a3 y3)``, then
``a2 y2`` and ``a1 y1`` added by FMA; the floor ``eps + c (x - eps)``) exactly, with
fractions, rounded once; every other operation is one IEEE operation in NumPy or Python. The
sizes cover a partial last block of rows (the lanes past the last row must be zero), a chunk
whose width is not a multiple of the 8-lane groups, float32 and float64 blocks, a scale
factor, and grids whose data do not start on a cache line (the column pass prefetches by
address)."""

from fractions import Fraction

import numpy as np
import pytest

from radioloc.estimators import grid_kernels as gk


def _fma(a, b, c):
    return float(Fraction(a) * Fraction(b) + Fraction(c))


def _line(seq, coef, tail, store, store_causal=float):
    """Causal, the zero border of ``tail`` cells, anti-causal: one line, as the kernels
    order it; ``store`` rounds a value as the blocks store it, ``store_causal`` a causal
    output as the anti-causal half reads it (the row pass stores it in the blocks; the
    states stay float64)."""
    g, a1, a2, a3 = (float(v) for v in coef)

    def yvv(x, y1, y2, y3):
        return _fma(a1, y1, _fma(a2, y2, _fma(g, x, a3 * y3)))

    y1 = y2 = y3 = 0.0
    causal = []
    for x in seq:
        y = yvv(x, y1, y2, y3)
        causal.append(store_causal(y))
        y1, y2, y3 = y, y1, y2
    border = []
    for _ in range(tail):
        y = yvv(0.0, y1, y2, y3)
        border.append(y)
        y1, y2, y3 = y, y1, y2
    y1 = y2 = y3 = 0.0
    for x in reversed(border):
        y = yvv(x, y1, y2, y3)
        y1, y2, y3 = y, y1, y2
    out = [0.0] * len(seq)
    for i in range(len(seq) - 1, -1, -1):
        y = yvv(causal[i], y1, y2, y3)
        out[i] = store(y)
        y1, y2, y3 = y, y1, y2
    return out


def _blur_reference(p, sigma, scale, eps, dtype):
    store = (lambda v: float(np.float32(v))) if dtype == np.float32 else float
    coef = gk.yvv_coefficients(sigma)
    tails = np.ceil(6.0 * sigma).astype(np.int64) + 3
    B, h, w = p.shape
    out = np.empty((B, h, w))
    excess = np.empty(B)
    for b in range(B):
        cols = np.empty((h, w))
        for c in range(w):
            cols[:, c] = _line([float(v) * scale[b] for v in p[b, :, c]], coef[b], tails[b],
                               store)
        rows = []
        for r in range(h):
            out[b, r] = _line([float(v) for v in cols[r]], coef[b], tails[b], store, store)
            acc = 0.0
            for v in out[b, r, ::-1]:                 # the row pass sums from the far end
                acc += max(v - eps, 0.0)
            rows.append(acc)
        excess[b] = np.array(rows).sum()
    return out, excess


def _unaligned(a):
    # the same values in memory starting 8 bytes past a cache line
    buf = np.empty(a.nbytes + 128, np.uint8)
    off = (-buf.ctypes.data) % 64 + 8
    v = buf[off:off + a.nbytes].view(a.dtype).reshape(a.shape)
    v[...] = a
    return v


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_blur_blocks_equal_the_exact_fma_reference(dtype):
    rng = np.random.default_rng(11)
    B, h, w = 2, gk.LANES + 5, 21                 # a partial block; 21 = 2 groups of 8 + 5
    p = _unaligned(rng.random((B, h, w)) ** 2)
    sigma = np.array([2.2, 3.1])
    scale = np.array([0.7, 1.3])
    eps = 1e-3
    blk, excess, bad = gk.gaussian_blocks(p, sigma, eps, dtype, np.inf, scale)
    ref, ref_excess = _blur_reference(p, sigma, scale, eps, dtype)
    assert bad == 0
    got = blk.transpose(0, 1, 3, 2).reshape(B, -1, w)
    np.testing.assert_array_equal(got[:, :h], ref)
    np.testing.assert_array_equal(got[:, h:], 0.0)       # the lanes past the last row
    np.testing.assert_array_equal(excess, ref_excess)


def test_blur_blocks_read_float32_grids_and_count_bad_cells():
    rng = np.random.default_rng(12)
    B, h, w = 2, 9, 70                              # a chunk of 64 and one of 6 columns
    p = (rng.random((B, h, w)) * 2.0).astype(np.float32)
    p[1, 4, 66] = np.nan
    p[0, 0, 3] = -1.0
    p[0, 8, 69] = 5.0                              # above the limit once scaled
    sigma = np.array([2.0, 2.5])
    scale = np.array([1.5, 1.0])
    blk, excess, bad = gk.gaussian_blocks(p, sigma, 0.0, np.float64, 4.0, scale)
    ref, ref_excess = _blur_reference(p[:1].astype(np.float64), sigma[:1], scale[:1], 0.0,
                                      np.float64)
    assert bad == 3
    got = blk.transpose(0, 1, 3, 2).reshape(B, -1, w)[:, :h]
    np.testing.assert_array_equal(got[0], ref[0])          # grid 0: finite
    assert np.isnan(got[1]).any()


def _update_reference(blk, shape, x, y, xy, mu, tau, sig, eps, excess):
    B, h, w = shape
    k = h * w
    prior = blk.transpose(0, 1, 3, 2).reshape(B, -1, w)[:, :h].astype(np.float64)
    out = np.empty(shape)
    rows = np.empty((B, h))
    for b in range(B):
        if excess[b] > 0.0:
            c = (1.0 - k * eps) / excess[b]
            fl = np.array([[_fma(c, v - eps, eps) if v - eps > 0.0 else eps for v in row]
                           for row in prior[b]])
        else:
            fl = np.full((h, w), 1.0 / k)
        dx = x - xy[b, 0]
        dy = y - xy[b, 1]
        d = np.sqrt(dx[None, :] * dx[None, :] + dy[:, None] * dy[:, None])
        e = np.maximum(np.abs(d - mu[b]) - tau[b], 0.0)
        lik = np.maximum(sig[b] - e, 0.0) / sig[b]
        out[b] = np.maximum(fl * lik, eps)
        for r in range(h):
            acc = 0.0
            for v in out[b, r]:
                acc += v
            rows[b, r] = acc
    return out, 1.0 / rows.sum(axis=1)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_update_blocks_equal_the_exact_fma_reference(dtype):
    rng = np.random.default_rng(13)
    B, h, w = 3, gk.LANES + 8, 150
    shape = (B, h, w)
    blk = (rng.random((B, 2, w, gk.LANES)) ** 3).astype(dtype)
    blk[:, -1, :, h - gk.LANES:] = 0.0
    x = np.arange(w) * 0.25 - 18.0
    y = np.arange(h) * 0.25 - 5.0
    xy = rng.uniform(-5, 5, (B, 2))
    # run 0: a ring (every class); run 1: the flat top reaches the reader (mu < tau);
    # run 2: no excess (the uniform prior)
    mu = np.array([9.0, 3.0, 8.0])
    tau = np.array([2.0, 5.0, 1.5])
    sig = np.array([3.0, 2.0, 4.0])
    excess = np.array([0.8, 1.7, 0.0])
    eps = 1e-6
    raw, scale = gk.trapezoid_posterior_blocks(blk, shape, x, y, xy, mu, tau, sig, eps, excess)
    ref, ref_scale = _update_reference(blk, shape, x, y, xy, mu, tau, sig, eps, excess)
    np.testing.assert_array_equal(raw, ref)
    np.testing.assert_array_equal(scale, ref_scale)
    zones = gk._zones(mu, tau, sig)
    d2 = (x[None, :] - xy[0, 0]) ** 2 + (y[:, None] - xy[0, 1]) ** 2
    assert (d2 >= zones[0, 3]).any() and ((d2 >= zones[0, 1]) & (d2 <= zones[0, 2])).any()
