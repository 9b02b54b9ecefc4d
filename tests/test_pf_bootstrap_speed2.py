"""The restructured loops of the bootstrap kernel and of its draws give the same values.

- ``pf_random.pairs_into`` draws in seven short loops (Philox in two halves of five rounds,
  Box-Muller in five parts): the values of one Philox4x32-10 call and of ``normal_pair``,
  bit for bit, at counters that carry into the upper word;
- ``pf_bootstrap.bootstrap_step`` writes the ancestor marks from counts made non-decreasing
  across the quarters of a chunk (each quarter's cumulative weights start from its own sum,
  which can round below the previous quarter's last): the marks equal those of the loop
  that carried the running maximum, on counts that dip at every quarter start.
"""

import numpy as np
import pytest
from numba import njit

from radioloc.estimators import pf_bootstrap as bs
from radioloc.estimators import pf_random as R


@njit(cache=False)     # not cached: a cache keyed on this file would keep a stale pf_random
def _pairs_by_block(n0, m, key):
    """Draw pairs one block at a time through ``normal_pair`` (the unsplit arithmetic)."""
    out = np.empty((2, m))
    for i in range(m):
        z0, z1 = R.normal_pair(n0 + i, key[0], key[1], key[2], key[3])
        out[0, i] = z0
        out[1, i] = z1
    return out


def test_split_philox_rounds_are_the_ten_rounds():
    """Five rounds, then five more from round 6's key, are ``philox4x32`` (which Random123's
    known answers hold), on counters whose low word carries."""
    rng = np.random.default_rng(3)
    key = rng.integers(0, 1 << 32, size=2, dtype=np.uint64)
    ctr = rng.integers(0, 1 << 32, size=(500, 4), dtype=np.uint64)
    ctr[:3, 0] = [0xFFFFFFFF, 0, 0xFFFFFFFE]

    @njit
    def split(c, k):
        out = np.empty_like(c)
        k0h = (k[0] + R._W0_5) & R._LO32
        k1h = (k[1] + R._W1_5) & R._LO32
        for i in range(c.shape[0]):
            w = R._philox_rounds(c[i, 0], c[i, 1], c[i, 2], c[i, 3], k[0], k[1], 5)
            w = R._philox_rounds(w[0], w[1], w[2], w[3], k0h, k1h, 5)
            for j in range(4):
                out[i, j] = w[j]
        return out
    np.testing.assert_array_equal(split(ctr, key), R.philox4x32_numpy(ctr, key))


@pytest.mark.parametrize("n0, m", [(0, 2048), (2 ** 32 - 700, 1500), (12345, 3), (7, 1)])
def test_staged_draws_equal_the_unsplit_draws_and_the_reference(n0, m):
    key = R.draw_key(np.random.default_rng(n0 % 97))
    buf = np.full((3, m + 2), np.nan)
    R.pairs_block(buf, n0, m, key[0], key[1], key[2], key[3])
    np.testing.assert_array_equal(buf[:2, :m], _pairs_by_block(n0, m, key))
    assert np.all(np.isnan(buf[:, m:])) and np.all(np.isnan(buf[2]))   # nothing else written
    n = np.arange(n0, n0 + m, dtype=np.uint64)
    ctr = np.stack([n & R._LO32, n >> R._S32, np.full_like(n, key[2]), np.full_like(n, key[3])], -1)
    w = R.philox4x32_numpy(ctr, key[:2])
    ref = R._box_muller_numpy(R._uniform_numpy(w[:, 0], w[:, 1], 1.0, R._HALF_ULP),
                              R._uniform_numpy(w[:, 2], w[:, 3], 4.0, 0.0))
    np.testing.assert_array_equal(buf[:2, :m], np.stack(ref))
    if n0 == 0:
        np.testing.assert_array_equal(buf[:2, :m].T.ravel(),
                                      R.standard_normal_numpy(None, 2 * m, key=key))


def _marks_reference(vr, m, mk, i0, f0):
    """The loop the kernel had: the running maximum of the counts carried from one ancestor
    to the next."""
    prev = f0
    for i in range(m):
        mk[prev - f0] = i0 + i
        prev = max(int(vr[i]), prev)


@pytest.mark.parametrize("seed", range(6))
def test_marks_from_counts_that_dip_at_quarter_starts(seed):
    """Counts non-decreasing within each quarter, with the first counts of a quarter below
    the previous quarter's last (a rounding of the quarter's start): the marks equal the
    running-maximum loop's, and the raised counts are the running maximum."""
    rng = np.random.default_rng(seed)
    m = int(rng.integers(4, 400))
    q = m // 4
    f0 = int(rng.integers(0, 50))
    bounds = [0, q, 2 * q, 3 * q, m]
    vr = np.empty(m)
    level = f0
    for a, b in zip(bounds[:-1], bounds[1:]):
        start = max(f0, level - int(rng.integers(1, 3)))          # a dip of 1 or 2
        steps = rng.choice([0, 0, 0, 1, 2, 5], size=b - a)
        steps[-1] = 2                                             # the next quarter can dip
        vr[a:b] = start + np.cumsum(steps) - steps[0]               # vr[a] = start
        level = int(max(level, vr[b - 1])) if b > a else level
    assert np.sum(np.diff(vr) < 0) == 3             # every quarter start dips
    nf = int(np.maximum.accumulate(vr).max()) - f0 + 1
    ref = np.full(nf + 1, -1, dtype=np.int64)
    _marks_reference(vr, m, ref, 100, f0)
    got = np.full(nf + 1, -1, dtype=np.int64)
    raised = vr.copy()
    bs._mark_offspring_starts(raised, m, q, got, 100, f0)
    np.testing.assert_array_equal(got, ref)
    np.testing.assert_array_equal(raised, np.maximum.accumulate(np.maximum(vr, f0)))


@pytest.mark.parametrize("chunk", [1, 5, 64, 2048])
def test_distinct_ancestors_from_the_rises_of_the_counts(chunk):
    """``distinct`` (counted from the rises of the raised counts, not in the fill) is the
    number of different ancestors, with most weight on few particles (chunks without
    offspring, ancestors whose offspring fill the chunk's last slot) and spread out."""
    import radioloc.estimators.p2p_particle as pp
    rng = np.random.default_rng(chunk)
    b, k = 3, 3000
    particles = 15.0 + rng.normal(size=(b, k, 2))
    particles[0, 40:] += 50.0                    # filter 0: 40 particles carry the weight
    node = np.broadcast_to(np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]]),
                           (b, 4, 2)).copy()
    theta = np.linalg.norm(node - 15.0, axis=-1)
    out = np.empty((b, k, 2))
    idx = np.empty((b, k), dtype=np.int64)
    mean, cov, ess = np.empty((b, 2)), np.empty((b, 2, 2)), np.empty(b)
    distinct = np.empty(b, dtype=np.int64)
    pred, v = np.empty((b, k, 2)), np.empty((b, k))
    bs.bootstrap_step(particles, pp._NO_ANCESTORS, False, np.zeros((b, 2)), np.full(2, 0.1),
                      R.draw_key(rng), node, theta, np.ones((b, 4), dtype=bool),
                      np.array([1 / 0.3, 1 / 0.3, 1 / 30.0]), np.array([0.0, 0.3, 0.9]),
                      chunk, True, out, idx, mean, cov, ess, distinct, pred, v)
    np.testing.assert_array_equal(distinct, [len(np.unique(r)) for r in idx])
    assert distinct[0] <= 40 < distinct[2]
