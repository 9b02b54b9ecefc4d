"""The counter-based normal generator of the compiled particle-filter kernels
(radioloc.estimators.pf_random): known answers of Philox4x32-10, the compiled draws against
the NumPy reference of the same maths on the same bits, the accuracy of the transform, the
distribution (moments, Kolmogorov-Smirnov, tails), independence and reproducibility."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy import stats

from radioloc.estimators import pf_random as R

# Random123's kat_vectors: counter (4 words), key (2 words), Philox4x32-10 output
KAT = [((0, 0, 0, 0), (0, 0), (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
       ((0xFFFFFFFF,) * 4, (0xFFFFFFFF,) * 2, (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
       ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
        (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1))]


def _draws(seed, n):
    return R.standard_normal(np.random.default_rng(seed), n)


def test_philox_known_answers():
    ctr = np.array([c for c, _, _ in KAT], dtype=np.uint64)
    for i, (_, key, want) in enumerate(KAT):
        k = np.array(key, dtype=np.uint64)
        assert R.philox4x32(ctr[i:i + 1], k)[0].tolist() == list(want)
        assert R.philox4x32_numpy(ctr[i:i + 1], k)[0].tolist() == list(want)


@pytest.mark.parametrize("size", [1, 2, 7, 200_001])
def test_compiled_draws_equal_numpy_reference_bit_for_bit(size):
    key = R.draw_key(np.random.default_rng(size))
    a = R.standard_normal(None, (size,), key=key)
    b = R.standard_normal_numpy(None, (size,), key=key)
    np.testing.assert_array_equal(a, b)
    # draws do not depend on the chunking of the parallel fill
    out = np.empty(size)
    R._fill_normal(key, out, 3)
    np.testing.assert_array_equal(out, a)


def test_vlog_within_one_ulp_of_numpy():
    x = np.concatenate([np.random.default_rng(1).random(200_000),
                        np.exp(np.random.default_rng(2).uniform(-700, 700, 200_000)),
                        2.0 ** -np.arange(1, 1022), [1.0, np.nextafter(1.0, 0), 2.0 ** -53]])
    ours = R._vlog_numpy(x)
    ref = np.log(x)
    ulp = np.spacing(np.maximum(np.abs(ref), np.finfo(float).tiny))
    assert np.max(np.abs(ours - ref) / ulp) <= 1.0
    # the compiled vlog is the same arithmetic (checked through the draws above); spot check
    from numba import njit

    @njit
    def vl(v):
        out = np.empty_like(v)
        for i in range(v.size):
            out[i] = R.vlog(v[i])
        return out
    np.testing.assert_array_equal(vl(x[:1000]), ours[:1000])


def test_box_muller_matches_libm_on_the_same_bits():
    """Each draw is sqrt(-2 log u1) (cos, sin)(2 pi u2) of its block's uniforms, within 8
    ulps of the radius (numpy.log, numpy.cos and numpy.sin as the reference; the reference
    itself rounds the angle)."""
    key = R.draw_key(np.random.default_rng(3))
    n = 400_000
    z = R.standard_normal(None, (n,), key=key)
    blk = np.arange(n // 2, dtype=np.uint64)
    ctr = np.stack([blk & R._LO32, blk >> R._S32, np.full_like(blk, key[2]),
                    np.full_like(blk, key[3])], -1)
    w = R.philox4x32_numpy(ctr, key[:2])
    u1 = R._uniform_numpy(w[:, 0], w[:, 1], 1.0, R._HALF_ULP)
    turn = R._uniform_numpy(w[:, 2], w[:, 3], 4.0, 0.0) / 4.0
    assert u1.min() > 0 and u1.max() < 1 and turn.min() >= 0 and turn.max() < 1
    rad = np.sqrt(-2.0 * np.log(u1))
    ref = np.stack([rad * np.cos(2 * np.pi * turn), rad * np.sin(2 * np.pi * turn)], -1).ravel()
    assert np.all(np.abs(z - ref) <= 8 * np.finfo(float).eps * np.repeat(rad, 2))


def test_the_uniforms_reach_the_grid_ends():
    """u1 = (2 m + 1) 2^-53: never 0 or 1; the extreme radius is sqrt(-2 log 2^-53) = 8.57."""
    hi = np.array([0, 0xFFFFFFFF], dtype=np.uint64)
    lo = np.array([0, 0xFFFFFFFF], dtype=np.uint64)
    u = R._uniform_numpy(hi, lo, 1.0, R._HALF_ULP)
    assert u[0] == 2.0 ** -53 and u[1] == 1.0 - 2.0 ** -53
    z0, _ = R._box_muller_numpy(u[:1], np.zeros(1))
    np.testing.assert_allclose(z0, np.sqrt(106 * np.log(2.0)), rtol=1e-15)


def test_moments_and_kolmogorov_smirnov():
    z = _draws(11, 2_000_000)
    n = z.size
    assert abs(z.mean()) < 5 / np.sqrt(n)
    assert abs(z.var() - 1.0) < 5 * np.sqrt(2.0 / n)
    assert abs(stats.skew(z)) < 5 * np.sqrt(6.0 / n)
    assert abs(stats.kurtosis(z)) < 5 * np.sqrt(24.0 / n)
    assert stats.kstest(z, "norm").pvalue > 1e-3
    # each coordinate of a block (cos and sin parts) on its own
    assert stats.kstest(z[0::2], "norm").pvalue > 1e-3
    assert stats.kstest(z[1::2], "norm").pvalue > 1e-3


def test_tail_frequencies():
    """Counts beyond 1..5 sigma in 5e7 draws within 5 Poisson standard deviations (plus 3)
    of the normal's; beyond that the tail is exact by construction: the radius is sqrt(-2
    log u1) to a few ulps for every u1 of the grid (tests above), so P(R > r) = exp(-r^2 /
    2) up to the grid's 2^-52."""
    rng = np.random.default_rng(12)
    levels = np.arange(1.0, 6.0)
    counts = np.zeros(levels.size)
    n = 0
    for _ in range(10):
        a = np.abs(R.standard_normal(rng, 5_000_000))
        counts += (a[:, None] > levels).sum(0)
        n += a.size
    expected = n * 2 * stats.norm.sf(levels)
    assert np.all(np.abs(counts - expected) < 5 * np.sqrt(expected) + 3), (counts, expected)


def test_independence_between_draws_blocks_coordinates_and_calls():
    rng = np.random.default_rng(13)
    n = 1_000_000
    z = R.standard_normal(rng, (n // 2, 2))            # one block per row, like (x, y)
    z2 = R.standard_normal(rng, (n // 2, 2))           # the next call (the next step)
    bound = 5 / np.sqrt(n // 2)

    def corr(a, b):
        return np.corrcoef(a, b)[0, 1]
    assert abs(corr(z[:, 0], z[:, 1])) < bound                   # coordinates
    assert abs(corr(z[:, 0] ** 2, z[:, 1] ** 2)) < 2 * bound     # (the radius is shared)
    assert abs(corr(z[:-1, 0], z[1:, 0])) < bound                # neighbouring particles
    assert abs(corr(z[:-1, 1], z[1:, 0])) < bound
    assert abs(corr(z[:, 0], z2[:, 0])) < bound                  # successive calls
    assert abs(corr(z[:, 1], z2[:, 1])) < bound
    flat = z.ravel()
    for lag in (1, 2, 3, 64, 4096):
        assert abs(corr(flat[:-lag], flat[lag:])) < 5 / np.sqrt(flat.size)


def test_reproducible_from_the_generator_state():
    a = R.standard_normal(np.random.default_rng(7), (3, 1001, 2))
    b = R.standard_normal(np.random.default_rng(7), (3, 1001, 2))
    np.testing.assert_array_equal(a, b)
    rng = np.random.default_rng(7)
    c, d = R.standard_normal(rng, 100), R.standard_normal(rng, 100)
    assert not np.array_equal(c, d)
    # the draws are a prefix-stable function of the key and the flat index
    key = R.draw_key(np.random.default_rng(8))
    np.testing.assert_array_equal(R.standard_normal(None, 10, key=key),
                                  R.standard_normal(None, 11, key=key)[:10])


_SCRIPT = """
import hashlib, numpy as np
from radioloc.estimators import pf_random as R
from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import RandomWalk
z = R.standard_normal(np.random.default_rng(21), 300_001)
anchors = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]])
r = np.linalg.norm(np.array([15.0, 12.0]) - anchors, axis=-1)
ranges = np.concatenate([[np.nan], r])[None, None, None].repeat(4, 2)
pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.3, 1.0, 1.0), particles=9000)
tr = pf.run(ranges, np.array([[[14.0, 13.0]]]), np.random.default_rng(22), anchors=anchors)
print(hashlib.sha256(z.tobytes() + tr.position.tobytes()).hexdigest())
"""


def test_draws_and_filter_do_not_depend_on_the_thread_count():
    root = Path(__file__).resolve().parents[1]
    out = []
    for threads in ("1", "2"):
        env = dict(os.environ, NUMBA_NUM_THREADS=threads, PYTHONPATH=str(root / "src"))
        res = subprocess.run([sys.executable, "-c", _SCRIPT], env=env, capture_output=True,
                             text=True, timeout=600)
        assert res.returncode == 0, res.stderr
        out.append(res.stdout.strip())
    assert out[0] == out[1]
