"""Counter-based standard normal draws for compiled particle-filter kernels.

The motion noise of the bootstrap particle filter is drawn inside the compiled step (one
pass per particle) instead of by ``numpy.random.Generator.standard_normal`` beforehand: in
a third of the CPU time (3.4-3.6 against 11 ns per draw, one thread, the shared 2-core
benchmark machine under load), with no pass over memory of its own, and any chunk of the draws can be made by
any thread, so the values depend only on the caller's generator and the sizes, never on the
number of threads or on the chunking.

Generator. Random bits come from Philox4x32-10 (Salmon, Moraes, Dror and Shaw, "Parallel
random numbers: as easy as 1, 2, 3", SC 2011; the generator of Random123, cuRAND and JAX;
it passes TestU01's BigCrush): a bijection of a 128-bit counter under a 64-bit key, ten
rounds of two 32 x 32 -> 64-bit multiplications. One call of :func:`draw_key` takes four
32-bit words from the caller's ``numpy.random.Generator`` (``rng.integers``): the key
``(k0, k1)`` and the two upper counter words ``(c2, c3)``, so each call's draws are a fresh
block of a 128-bit counter space under a fresh key (two calls collide only if all 128 drawn
bits agree). Draw ``e`` of a call (flat index, C order) uses the counter ``(n mod 2^32, n //
2^32, c2, c3)`` with ``n = e // 2``: one Philox block gives the two draws ``2n`` and ``2n +
1`` (its words ``(w0, w1)`` and ``(w2, w3)``), so up to 2^65 draws per call, and for
particles of two coordinates one block per particle. The implementation reproduces the
Random123 known-answer vectors (tests/test_pf_random.py).

Normals. A block's first 64-bit half ``(w0, w1)`` gives ``m1``, its top 52 bits, and the
uniform ``u1 = (2 m1 + 1) 2^-53`` in ``[2^-53, 1 - 2^-53]`` (never 0 or 1, exact); the second
half gives ``u2 = m2 2^-52`` in ``[0, 1)``. The Box-Muller transform turns them into the two
independent draws ``sqrt(-2 log u1) (cos 2 pi u2, sin 2 pi u2)`` (Box and Muller, 1958; exact
for exactly uniform inputs). The logarithm is written here (:func:`vlog`: exponent from the
bits, fdlibm's polynomial in ``s = f / (2 + f)``, within 1 ulp of ``numpy.log``), the sine
and cosine are Taylor polynomials to degree 17 and 18 on ``[-pi/4, pi/4]`` after reducing
``4 u2`` (exactly) to the nearest quarter turn, and every branch is a select, so LLVM
vectorises the loop (this numba has no SVML). Each draw is within 8 ulps of the radius of ``numpy.log``/``cos``/``sin``
on the same uniforms (in practice within 4). The largest radius is ``sqrt(-2 log 2^-53)`` =
8.57; beyond 6 sigma the tail is the exact ``P(R > r) = exp(-r^2 / 2)`` up to the grid's
2^-52. The tests compare the compiled draws with the NumPy reference of the same maths on
the same bits (:func:`standard_normal_numpy`, equal bit for bit: no fused multiply-add is
allowed in this module) and check Philox against Random123's known answers, and the draws'
moments, a Kolmogorov-Smirnov test, tail frequencies to 5 sigma in 5e7 draws, correlations
between draws, blocks, coordinates and calls, and that they do not depend on the thread
count (tests/test_pf_random.py).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from radioloc.core import fdlibm as fdl
from radioloc.estimators.pf_kernels import _f64_as_i64, _i64_as_f64

__all__ = ["draw_key", "standard_normal", "standard_normal_numpy", "philox4x32",
           "philox4x32_numpy", "vlog"]

_M0 = np.uint64(0xD2511F53)
_M1 = np.uint64(0xCD9E8D57)
_W0 = np.uint64(0x9E3779B9)
_W1 = np.uint64(0xBB67AE85)
_LO32 = np.uint64(0xFFFFFFFF)
_S32 = np.uint64(32)
_S20 = np.uint64(20)
_S12 = np.uint64(12)
_ONE_BITS = np.uint64(0x3FF0000000000000)
_HALF_ULP = 2.0 ** -53

# fdlibm e_log.c (radioloc.core.fdlibm)
_LN2_HI, _LN2_LO, _SQRT2 = fdl.LN2_HI, fdl.LN2_LO, fdl.SQRT2
_LG1, _LG2, _LG3, _LG4, _LG5, _LG6, _LG7 = (fdl.LG1, fdl.LG2, fdl.LG3, fdl.LG4, fdl.LG5,
                                            fdl.LG6, fdl.LG7)
_TWO52, _TWO52_BITS, _MANT, _ONE_I = fdl.TWO52, fdl.TWO52_BITS, fdl.MANT, fdl.ONE_I
_log_poly, _log_finish = fdl.log_poly, fdl.log_finish

_SHIFT = 6755399441055744.0             # 1.5 * 2^52: x + _SHIFT rounds x to an integer
_PIO2 = math.pi / 2.0
# Taylor coefficients of sin and cos on [-pi/4, pi/4] (the first omitted terms, x^19 / 19!
# and x^20 / 20!, are below 4e-18 there)
_S3, _S5, _S7, _S9, _S11, _S13, _S15, _S17 = (
    (-1.0) ** j / math.factorial(2 * j + 1) for j in range(1, 9))
_C4, _C6, _C8, _C10, _C12, _C14, _C16, _C18 = (
    (-1.0) ** j / math.factorial(2 * j) for j in range(2, 10))

#: Philox blocks (pairs of draws) per parallel task of :func:`standard_normal`.
BLOCK_CHUNK = 4096


def draw_key(rng: np.random.Generator) -> np.ndarray:
    """The key and upper counter words of one call's draws, from the caller's generator.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the four 32-bit words (one ``rng.integers`` call).

    Returns
    -------
    ndarray of uint64, shape (4,)
        ``(k0, k1, c2, c3)``, each below 2^32.
    """
    return rng.integers(0, 1 << 32, size=4, dtype=np.uint64)


# ---- compiled --------------------------------------------------------------------------

@njit(cache=True, inline="always", error_model="numpy")
def _philox(c0, c1, c2, c3, k0, k1):
    """Philox4x32-10 of the counter ``(c0, c1, c2, c3)`` under the key ``(k0, k1)`` (every
    word a uint64 below 2^32)."""
    for _ in range(10):
        p0 = _M0 * c0
        p1 = _M1 * c2
        c0 = (p1 >> _S32) ^ c1 ^ k0             # every operand below 2^32
        c1 = p1 & _LO32
        c2 = (p0 >> _S32) ^ c3 ^ k1
        c3 = p0 & _LO32
        k0 = (k0 + _W0) & _LO32
        k1 = (k1 + _W1) & _LO32
    return c0, c1, c2, c3


@njit(cache=True, inline="always", error_model="numpy")
def vlog(x: float) -> float:
    """``log(x)`` for a positive normal float, without a branch or a call (vectorises).

    Parameters
    ----------
    x : float
        Positive, normal (not subnormal, not inf or NaN).

    Returns
    -------
    float
        ``log(x)``, within 1 ulp of ``numpy.log`` (fdlibm's ``e_log.c`` reduction and
        polynomial).
    """
    k, f = _log_reduce(x)
    s = f / (2.0 + f)
    return _log_finish(k, f, s, _log_poly(s))


@njit(cache=True, inline="always", error_model="numpy")
def _log_reduce(x):
    """``(k, f)`` with ``x = 2^k (1 + f)``, ``1 + f`` in ``[sqrt(2) / 2, sqrt(2)]``."""
    bits = _f64_as_i64(x)
    k = _i64_as_f64((bits >> 52) | _TWO52_BITS) - (_TWO52 + 1023.0)
    m = _i64_as_f64((bits & _MANT) | _ONE_I)                 # [1, 2)
    big = m > _SQRT2
    m = m * 0.5 if big else m
    k = k + 1.0 if big else k
    return k, m - 1.0


@njit(cache=True, inline="always", error_model="numpy")
def _uniform_open(hi, lo):
    """``u = (2 m + 1) 2^-53`` in ``[2^-53, 1 - 2^-53]``, ``m`` the top 52 bits of ``hi 2^32 +
    lo`` (exact)."""
    mbits = (hi << _S20) | (lo >> _S12)
    return (_i64_as_f64(np.int64(mbits | _ONE_BITS)) - 1.0) + _HALF_ULP


@njit(cache=True, inline="always", error_model="numpy")
def _quarter_turns(hi, lo):
    """``4 u``, ``u = m 2^-52`` in ``[0, 1)``, ``m`` the top 52 bits of ``hi 2^32 + lo``
    (exact)."""
    mbits = (hi << _S20) | (lo >> _S12)
    return (_i64_as_f64(np.int64(mbits | _ONE_BITS)) - 1.0) * 4.0


@njit(cache=True, inline="always", error_model="numpy")
def _trig_head(v):
    """The quarter turn ``q`` nearest ``v`` (0..4), ``x = (v - q) pi / 2`` in ``[-pi/4, pi/4]``,
    ``z = x^2`` and the first five Horner steps of the sine and cosine polynomials."""
    q = (v + _SHIFT) - _SHIFT                    # nearest integer, 0..4
    x = (v - q) * _PIO2
    z = x * x
    ps = _S17
    ps = ps * z + _S15
    ps = ps * z + _S13
    ps = ps * z + _S11
    ps = ps * z + _S9
    pc = _C18
    pc = pc * z + _C16
    pc = pc * z + _C14
    pc = pc * z + _C12
    pc = pc * z + _C10
    return q, x, z, ps, pc


@njit(cache=True, inline="always", error_model="numpy")
def _trig_tail(x, z, ps, pc):
    """The last three Horner steps of :func:`_trig_head`'s polynomials: ``(sin x, cos x)``."""
    ps = ps * z + _S7
    ps = ps * z + _S5
    ps = ps * z + _S3
    pc = pc * z + _C8
    pc = pc * z + _C6
    pc = pc * z + _C4
    return x + x * z * ps, (1.0 - 0.5 * z) + z * z * pc


@njit(cache=True, inline="always", error_model="numpy")
def _quadrant(q, sn, cs):
    """``(cos, sin)(x + q pi / 2)`` from ``sin x``, ``cos x`` and the quarter turn ``q``."""
    swap = (q == 1.0) or (q == 3.0)
    c = sn if swap else cs
    s = cs if swap else sn
    c = -c if (q == 1.0) or (q == 2.0) else c
    s = -s if (q == 2.0) or (q == 3.0) else s
    return c, s


@njit(cache=True, inline="always", error_model="numpy")
def _box_muller(u1, v):
    """``sqrt(-2 log u1) (cos, sin)(v pi / 2)`` for ``u1`` in (0, 1], ``v`` in [0, 4)."""
    rad = math.sqrt(-2.0 * vlog(u1))
    q, x, z, ps, pc = _trig_head(v)
    sn, cs = _trig_tail(x, z, ps, pc)
    c, s = _quadrant(q, sn, cs)
    return rad * c, rad * s


@njit(cache=True, inline="always", error_model="numpy")
def normal_pair(n, k0, k1, c2, c3):
    """Draws ``2 n`` and ``2 n + 1`` of the call keyed by ``(k0, k1, c2, c3)`` (see the
    module; the four words of :func:`draw_key`, passed as scalars so that the loops calling
    this vectorise).

    Parameters
    ----------
    n : int
        Philox block (counter) index, ``0 <= n < 2^63``.
    k0, k1, c2, c3 : uint64
        The key words and the upper counter words.

    Returns
    -------
    (float, float)
    """
    c = np.uint64(n)
    w0, w1, w2, w3 = _philox(c & _LO32, c >> _S32, c2, c3, k0, k1)
    return _box_muller(_uniform_open(w0, w1), _quarter_turns(w2, w3))


@njit(cache=True, inline="always", error_model="numpy")
def _philox_rounds(c0, c1, c2, c3, k0, k1, n):
    """``n`` rounds of Philox4x32 from the counter state ``(c0, c1, c2, c3)`` under the round
    key ``(k0, k1)`` (the rounds of :func:`_philox`, which are ``n = 10`` from the first)."""
    for _ in range(n):
        p0 = _M0 * c0
        p1 = _M1 * c2
        c0 = (p1 >> _S32) ^ c1 ^ k0
        c1 = p1 & _LO32
        c2 = (p0 >> _S32) ^ c3 ^ k1
        c3 = p0 & _LO32
        k0 = (k0 + _W0) & _LO32
        k1 = (k1 + _W1) & _LO32
    return c0, c1, c2, c3


# the round key of round 6 (after five increments of the Weyl sequence), modulo 2^32 later
_W0_5 = np.uint64(5 * 0x9E3779B9)
_W1_5 = np.uint64(5 * 0xBB67AE85)


@njit(cache=True, inline="always", error_model="numpy")
def pairs_into(buf, n0, m, k0, k1, c2, c3):
    """Rows 0 and 1 of ``buf[:, :m]``: the draw pairs of blocks ``n0 .. n0 + m - 1``.

    Seven loops over the blocks, each vectorised by LLVM: Philox rounds 1-5 into a work
    array, rounds 6-10 into the two uniforms (rows 0 and 1), the logarithm's reduction and
    division, its polynomial, the radius, the first five and the last three terms of the
    sine and cosine polynomials, then the quadrant's signs and the product with the radius.
    The same operations in the same order as :func:`normal_pair` (the values are stored
    between the loops, exactly): a loop whose body is one long chain of dependent
    operations (ten Philox rounds, a Horner polynomial of eight terms after a division)
    keeps the floating-point scheduler full of operations that wait, and the shorter
    loops run 1.2x faster (one thread, 2048 blocks: 8.3 -> 6.9 ns per pair). Inlined into
    the caller, so it takes the caller's floating-point flags: a caller compiled with
    contraction (``fastmath={"contract"}``) would fuse the polynomials' multiply-adds and
    draw other values than :func:`standard_normal_numpy`; such a caller calls
    :func:`pairs_block` instead.

    Parameters
    ----------
    buf : ndarray, shape (R, >= m), R >= 2
        Output rows 0 (draws ``2 n``) and 1 (draws ``2 n + 1``).
    n0, m : int
        First block and number of blocks.
    k0, k1, c2, c3 : uint64
        The words of :func:`draw_key`.

    Returns
    -------
    None
    """
    # every word is below 2^32; saying so lets LLVM use one 32 x 32-bit multiply per product
    # in the first round too
    k0 = k0 & _LO32
    k1 = k1 & _LO32
    c2 = c2 & _LO32
    c3 = c3 & _LO32
    k0h = (k0 + _W0_5) & _LO32
    k1h = (k1 + _W1_5) & _LO32
    wk = np.empty((4, m), dtype=np.uint64)
    t = np.empty((5, m))
    o0 = buf[0, :m]
    o1 = buf[1, :m]
    w0r = wk[0]
    w1r = wk[1]
    w2r = wk[2]
    w3r = wk[3]
    for i in range(m):
        c = np.uint64(n0 + i)
        w0, w1, w2, w3 = _philox_rounds(c & _LO32, c >> _S32, c2, c3, k0, k1, 5)
        w0r[i] = w0
        w1r[i] = w1
        w2r[i] = w2
        w3r[i] = w3
    for i in range(m):
        w0, w1, w2, w3 = _philox_rounds(w0r[i], w1r[i], w2r[i], w3r[i], k0h, k1h, 5)
        o0[i] = _uniform_open(w0, w1)
        o1[i] = _quarter_turns(w2, w3)
    # the radius sqrt(-2 log u1): vlog in three loops
    tk = t[0]
    tf = t[1]
    ts = t[2]
    tr = t[3]
    for i in range(m):
        k, f = _log_reduce(o0[i])
        tk[i] = k
        tf[i] = f
        ts[i] = f / (2.0 + f)
    for i in range(m):
        tr[i] = _log_poly(ts[i])
    for i in range(m):
        o0[i] = math.sqrt(-2.0 * _log_finish(tk[i], tf[i], ts[i], tr[i]))
    # cos and sin of the quarter turns v: the polynomials in two loops, then the quadrant
    tx = t[0]
    tz = t[1]
    tps = t[2]
    tpc = t[3]
    tq = t[4]
    for i in range(m):
        q, x, z, ps, pc = _trig_head(o1[i])
        tq[i] = q
        tx[i] = x
        tz[i] = z
        tps[i] = ps
        tpc[i] = pc
    for i in range(m):
        sn, cs = _trig_tail(tx[i], tz[i], tps[i], tpc[i])
        tps[i] = sn
        tpc[i] = cs
    for i in range(m):
        c, s = _quadrant(tq[i], tps[i], tpc[i])
        rad = o0[i]
        o0[i] = rad * c
        o1[i] = rad * s


@njit(cache=True, error_model="numpy", fastmath=False)
def pairs_block(buf, n0, m, k0, k1, c2, c3):
    """:func:`pairs_into` compiled as a function of its own, without contraction whatever the
    caller's flags (the draws of :func:`standard_normal_numpy`, bit for bit). ``fastmath=False``
    is explicit because numba passes a caller's ``fastmath`` on to a callee that does not
    set its own (and caches the callee compiled so: the draws then depended on which kernel
    compiled first).

    Parameters
    ----------
    buf : ndarray, shape (R, >= m), R >= 2
        Output rows 0 (draws ``2 n``) and 1 (draws ``2 n + 1``).
    n0, m : int
        First block and number of blocks.
    k0, k1, c2, c3 : uint64
        The words of :func:`draw_key`.

    Returns
    -------
    None
    """
    pairs_into(buf, n0, m, k0, k1, c2, c3)


@njit(cache=True, parallel=True, error_model="numpy", fastmath=False)
def _fill_normal(key, out, chunk):
    """``out[e]`` = draw ``e`` of the call keyed by ``key``; parallel over chunks of
    blocks."""
    size = out.shape[0]
    nblocks = (size + 1) // 2
    ntasks = max(1, -(-nblocks // chunk))
    k0, k1, c2, c3 = key[0], key[1], key[2], key[3]
    for task in prange(ntasks):
        b0 = task * chunk
        b1 = min(nblocks, b0 + chunk)
        buf = np.empty((2, b1 - b0))
        pairs_into(buf, b0, b1 - b0, k0, k1, c2, c3)
        for n in range(b0, b1):
            out[2 * n] = buf[0, n - b0]
            if 2 * n + 1 < size:
                out[2 * n + 1] = buf[1, n - b0]


@njit(cache=True)
def philox4x32(counter, key):
    """Philox4x32-10 of counters (compiled; for the known-answer tests).

    Parameters
    ----------
    counter : ndarray of uint64, shape (M, 4)
        Counter words, each below 2^32.
    key : ndarray of uint64, shape (2,)
        Key words, each below 2^32.

    Returns
    -------
    ndarray of uint64, shape (M, 4)
    """
    out = np.empty_like(counter)
    for i in range(counter.shape[0]):
        w0, w1, w2, w3 = _philox(counter[i, 0], counter[i, 1], counter[i, 2], counter[i, 3],
                                 key[0], key[1])
        out[i, 0] = w0
        out[i, 1] = w1
        out[i, 2] = w2
        out[i, 3] = w3
    return out


def standard_normal(rng: np.random.Generator, shape, key=None) -> np.ndarray:
    """Standard normal draws made by the compiled counter-based generator.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the call's key (:func:`draw_key`); unused if ``key`` is given.
    shape : int or tuple of int
        Shape of the result.
    key : ndarray of uint64, shape (4,), optional
        A key from :func:`draw_key` (the draws of a compiled kernel that used it).

    Returns
    -------
    ndarray of float64
        Independent N(0, 1) draws; the values depend only on the key and the flat index,
        not on the number of threads.
    """
    if key is None:
        key = draw_key(rng)
    shape = (shape,) if np.isscalar(shape) else tuple(shape)
    out = np.empty(int(np.prod(shape, dtype=np.int64)))
    if out.size:
        _fill_normal(np.ascontiguousarray(key, dtype=np.uint64), out, BLOCK_CHUNK)
    return out.reshape(shape)


# ---- NumPy reference -------------------------------------------------------------------

def philox4x32_numpy(counter: np.ndarray, key: np.ndarray) -> np.ndarray:
    """Philox4x32-10 in NumPy (the reference of the compiled generator).

    Parameters
    ----------
    counter : ndarray of uint64, shape (M, 4)
        Counter words, each below 2^32.
    key : ndarray of uint64, shape (2,)
        Key words, each below 2^32.

    Returns
    -------
    ndarray of uint64, shape (M, 4)
    """
    c = [np.asarray(counter[:, i], dtype=np.uint64) for i in range(4)]
    k0, k1 = np.uint64(key[0]), np.uint64(key[1])
    for _ in range(10):
        p0 = _M0 * c[0]
        p1 = _M1 * c[2]
        c = [((p1 >> _S32) ^ c[1] ^ k0) & _LO32, p1 & _LO32,
             ((p0 >> _S32) ^ c[3] ^ k1) & _LO32, p0 & _LO32]
        k0 = (k0 + _W0) & _LO32
        k1 = (k1 + _W1) & _LO32
    return np.stack(c, axis=-1)


def _vlog_numpy(x):
    bits = x.view(np.int64)
    k = ((bits >> 52) | _TWO52_BITS).view(np.float64) - (_TWO52 + 1023.0)
    m = ((bits & _MANT) | _ONE_I).view(np.float64)
    big = m > _SQRT2
    m = np.where(big, m * 0.5, m)
    k = np.where(big, k + 1.0, k)
    f = m - 1.0
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    t1 = w * (_LG2 + w * (_LG4 + w * _LG6))
    t2 = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7)))
    r = t2 + t1
    hfsq = 0.5 * f * f
    return k * _LN2_HI - ((hfsq - (s * (hfsq + r) + k * _LN2_LO)) - f)


def _uniform_numpy(hi, lo, scale, offset):
    mbits = (hi << _S20) | (lo >> _S12)
    return (((mbits | _ONE_BITS).view(np.float64) - 1.0) + offset) * scale


def _box_muller_numpy(u1, v):
    rad = np.sqrt(-2.0 * _vlog_numpy(u1))
    k = (v + _SHIFT) - _SHIFT
    x = (v - k) * _PIO2
    z = x * x
    ps = np.full_like(z, _S17)
    for c in (_S15, _S13, _S11, _S9, _S7, _S5, _S3):
        ps = ps * z + c
    sn = x + x * z * ps
    pc = np.full_like(z, _C18)
    for c in (_C16, _C14, _C12, _C10, _C8, _C6, _C4):
        pc = pc * z + c
    cs = (1.0 - 0.5 * z) + z * z * pc
    swap = (k == 1.0) | (k == 3.0)
    c, s = np.where(swap, sn, cs), np.where(swap, cs, sn)
    c = np.where((k == 1.0) | (k == 2.0), -c, c)
    s = np.where((k == 2.0) | (k == 3.0), -s, s)
    return rad * c, rad * s


def standard_normal_numpy(rng: np.random.Generator, shape, key=None) -> np.ndarray:
    """The draws of :func:`standard_normal` computed with NumPy (the reference).

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the call's key; unused if ``key`` is given.
    shape : int or tuple of int
        Shape of the result.
    key : ndarray of uint64, shape (4,), optional
        A key from :func:`draw_key`.

    Returns
    -------
    ndarray of float64
        Equal, bit for bit, to :func:`standard_normal` with the same key.
    """
    if key is None:
        key = draw_key(rng)
    key = np.asarray(key, dtype=np.uint64)
    shape = (shape,) if np.isscalar(shape) else tuple(shape)
    size = int(np.prod(shape, dtype=np.int64))
    n = np.arange((size + 1) // 2, dtype=np.uint64)
    ctr = np.stack([n & _LO32, n >> _S32, np.full_like(n, key[2]), np.full_like(n, key[3])], -1)
    w = philox4x32_numpy(ctr, key[:2])
    z = np.stack(_box_muller_numpy(_uniform_numpy(w[:, 0], w[:, 1], 1.0, _HALF_ULP),
                                   _uniform_numpy(w[:, 2], w[:, 3], 4.0, 0.0)), -1)
    return z.ravel()[:size].reshape(shape)
