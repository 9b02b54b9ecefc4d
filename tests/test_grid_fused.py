"""The recursive grid step's update kernel classes each block column by its cells' squared
distances (likelihood exactly 0, exactly 1, or the full trapezoid formula with its square
root) so that the flat parts of the trapezoid need no square root. The classes only skip
work: the kernel with them equals, bit for bit, the same kernel with every column on the
full formula, on random inputs and on cells placed exactly on the trapezoid's corners."""

import numpy as np
import pytest

from radioloc.estimators import grid_kernels as gk

ALL_FULL = np.array([-1.0, np.inf, -1.0, np.inf])      # no column classed 0 or 1


def _run(blk, shape, x, y, xy, mu, tau, sig, eps, excess, zones):
    B, h, w = shape
    mode, c = gk._floor_args(B, h * w, eps, excess)
    out = np.empty(shape)
    rows = np.empty((B, h))
    gk._trapezoid_blocks(blk, x, y, xy, mu, tau, sig, zones, eps, out, rows, mode, c, False)
    return out, rows


def _check(blk, shape, x, y, xy, mu, tau, sig, eps):
    excess = np.full(shape[0], 0.7)
    zones = gk._zones(mu, tau, sig)
    got, rows = _run(blk, shape, x, y, xy, mu, tau, sig, eps, excess, zones)
    ref, rref = _run(blk, shape, x, y, xy, mu, tau, sig, eps, excess,
                     np.tile(ALL_FULL, (shape[0], 1)))
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(rows, rref)
    return zones


@pytest.mark.parametrize("seed", [0, 1])
def test_classes_change_no_bit_on_random_rings(seed):
    rng = np.random.default_rng(seed)
    B, h, w = 3, 2 * gk.LANES + 7, 150                  # a partial last block
    blk = (rng.random((B, -(-h // gk.LANES), w, gk.LANES)) ** 3).astype(np.float32)
    x = np.arange(w) * 0.25 - 18.0
    y = np.arange(h) * 0.25 - 9.0
    xy = rng.uniform(-5, 5, (B, 2))
    mu = rng.uniform(0.5, 15, B)
    tau = rng.uniform(0.1, 6, B)
    sig = rng.uniform(0.2, 5, B)
    zones = _check(blk, (B, h, w), x, y, xy, mu, tau, sig, 1e-9)
    assert np.all(zones[:, 3] > zones[:, 2])


def test_classes_change_no_bit_on_the_corners():
    # integer cell coordinates and trapezoid corners at integer distances (realised exactly
    # along the axes and by Pythagorean triples such as 5, 10, 13), so cells lie on every
    # class border;
    # run 1: mu < tau (the flat top reaches the centre), run 2: mu - tau - sigma < 0
    h, w = gk.LANES, 64
    x = np.arange(w, dtype=float) - 30.0
    y = np.arange(h, dtype=float) - 2.0
    xy = np.array([[0.0, 0.0], [-1.0, 1.0], [2.0, -1.0]])
    mu = np.array([11.5, 4.0, 9.0])
    tau = np.array([1.5, 6.0, 4.0])
    sig = np.array([5.0, 7.0, 8.0])          # corners 5, 10, 13, 18 / -, 0, 10, 17 / -, 5, 13, 21
    blk = np.random.default_rng(4).random((3, 1, w, gk.LANES)).astype(np.float32) + 0.1
    zones = _check(blk, (3, h, w), x, y, xy, mu, tau, sig, 1e-9)
    assert zones[1, 1] < 0 and zones[2, 0] < 0 and zones[0, 0] > 0


def test_nontemporal_stores_write_the_same_posterior():
    # the posterior tiles written with non-temporal stores (large float64 grids) equal the
    # ordinary stores bit for bit: whole tiles, the columns past the last whole tile of 16,
    # and a partial last block of rows (ordinary stores there)
    rng = np.random.default_rng(2)
    B, h, w = 2, 2 * gk.LANES + 7, 140
    blk = (rng.random((B, -(-h // gk.LANES), w, gk.LANES)) ** 3).astype(np.float32)
    x = np.arange(w) * 0.25 - 18.0
    y = np.arange(h) * 0.25 - 9.0
    xy = rng.uniform(-5, 5, (B, 2))
    mu, tau, sig = rng.uniform(2, 15, B), rng.uniform(0.1, 6, B), rng.uniform(0.2, 5, B)
    zones = gk._zones(mu, tau, sig)
    mode, c = gk._floor_args(B, h * w, 1e-9, np.full(B, 0.7))
    outs = []
    for nt in (False, True):
        out = gk._aligned_empty((B, h, w), np.float64)
        assert out.ctypes.data % 64 == 0
        rows = np.empty((B, h))
        gk._trapezoid_blocks(blk, x, y, xy, mu, tau, sig, zones, 1e-9, out, rows, mode, c, nt)
        outs.append((out, rows))
    np.testing.assert_array_equal(outs[1][0], outs[0][0])
    np.testing.assert_array_equal(outs[1][1], outs[0][1])
