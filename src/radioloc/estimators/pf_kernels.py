"""Compiled kernels of the peer-to-peer particle filter (one pass over the particles per task).

:func:`link_weights` is the particle-link update of
:meth:`radioloc.estimators.p2p_particle.P2PParticleFilter.step` (Algorithm 2, lines 6, 8
and 11); :func:`weights_moments`, :func:`systematic_indices` and :func:`gather_resampled`
finish the step (weights, moments, line 12's resampling, the carried link posteriors).
The plain NumPy form of the same maths is ``P2PParticleFilter(kernel="numpy")``; the tests
compare the two on random inputs.

How the link update avoids logarithms. The link posterior carried per particle and link is
the LOS probability ``q = p(z = 1 | .)`` (one number, not two log values). For the new
range the prior is linear in ``q`` (``pi_1 = q P(1|1) + (1 - q) P(1|0)``), and both
likelihoods are evaluated relative to the constant ``c_e = log lam + (lam s)^2 / 2`` of the
exponentially modified Gaussian. With ``z = e / s``, ``u = z - lam s``, ``E_1 =
exp(-z^2 / 2)`` and ``G = exp(-(lam s)^2 / 2) erfcx(|u| / sqrt 2) E_1 / 2`` (``G =
exp(-lam e) Phi(-|u|)``, the identity ``-lam e - u^2 / 2 = -z^2 / 2 - (lam s)^2 / 2``):

    E_0 = exp(l_0 - c_e) = exp(-lam e) Phi(u) = G                 (u < 0)
                                               = exp(-lam e) - G   (u >= 0)
    E_1 = exp(l_1 - c_e) = exp(c_g - c_e) exp(-z^2 / 2)

so a particle-link update is a square root, two exponentials, one ``erfcx`` (no
cancellation: ``G <= exp(-lam e) / 2`` where it is subtracted), one division for the new
posterior ``q' = pi_1 E_1 / (pi_0 E_0 + pi_1 E_1)``, and a product accumulated per particle
whose exponent is moved into an integer counter after every link (exact: a power of two),
whose logarithm is taken once per particle. Where ``pi_0 E_0 + pi_1 E_1 <= 1e-150`` (a
particle metres from a range) that link is evaluated again in the log domain, so weights
stay exact.

Vector maths. ``exp`` and ``erfcx`` are written here (:func:`vexp`, :func:`verfcx`) as
branch-free range reduction and polynomial, so that LLVM vectorises the loop over the
particles of one link (AVX2, four lanes): the C library's scalar ``exp``/``erfc`` cost about
5.5 ns a call here (this numba build has no SVML). ``vexp``: ``x = k ln 2 + r``,
``|r| <= ln 2 / 2``, Taylor polynomial of degree 13, ``2^k`` built from its bits in two
factors (so subnormal results are right); ``verfcx``: the Chebyshev series of ``(1 + 2x)
erfcx(x)`` in ``y = (x - 3.75) / (x + 3.75)`` (Shepherd and Laframboise, 1981), 24 terms,
for ``x >= 0``. The errors against NumPy/SciPy are in tests/test_pf_fast_math.py.

Shortcuts per link (exact). Within a chunk, one pass computes every particle's residuals
``e``, ``z`` and ``u`` of a link and counts two conditions; the link then takes one of
three loops, each giving the full loop's values bit for bit (tests/test_pf_link_fast.py):

* every particle has ``u >= 8.5``: no ``erfcx``. There ``E_0 = exp(-lam e) - G`` with
  ``G / exp(-lam e) = Phi(-u) <= Phi(-8.5) = 9.5e-18 < 2^-56`` (the identity above). The
  computed ratio carries the rounding of the exponents (``|z^2 / 2| <= 745`` wherever
  ``E_1 > 0``, so below 1e-12 relative) and of ``vexp`` / ``verfcx`` (below 1e-14), so
  the computed ``G`` is below half an ulp of the computed ``exp(-lam e)`` whenever that is
  a normal number, and ``exp(-lam e) - G`` rounds to ``exp(-lam e)``: the loop uses ``G =
  0``. (Where ``exp(-lam e)`` is subnormal, the true ``G`` is below 1e-17 of it, so
  below half the smallest subnormal, and the computed product ``(half_c erfcx) E_1``
  rounds to 0 as well: its factors carry relative errors below 1e-12, or ``E_1`` is
  itself subnormal and the product smaller still.)
* and every particle has ``-z^2 / 2 < -745.2``: ``vexp`` clamps its argument to -745.2
  and returns exactly 0 there (tested), so ``E_1 = 0``, ``a_1 = 0``, the new posterior is
  ``0 / tot = 0``: a loop with one exponential and no division.
* otherwise the full loop, with ``erfcx`` evaluated beforehand in a loop of its own (a
  short body the core overlaps better than the long one).

On the paper 001 highway (s = 5 cm) most particle-link residuals are tens of ``s``: in
the benchmark's last step 58 % of the links take the first loop, 40 % the second.

Data layout. The carried LOS posteriors arrive as ``(K, L')`` per filter (the state's
layout); each chunk transposes those of its old links into one scratch row per link slot
(four particles at a time, whose rows stay in the L1 cache), every loop over the particles
of a link then reads and writes contiguous memory, and the new posteriors go back to
``(K, L)`` in tiles of 8 particles. These moves are about 3 ns of the kernel's 15-16 ns
per particle-link update on the benchmark (16 padded slots for 9.4 links per vehicle:
256 bytes in and out per particle). ``P2PParticleFilter.run`` carries them link-major
instead (``link_major``: ``(L, K)`` per filter, read through the resampling's ancestors):
one contiguous row per existing link is copied in and out, the padding slots untouched.

Gaussian case. A filter whose LOS fraction is exactly 1 and whose carried link posteriors
are all exactly 1 (the invariant of such a filter: ``pi_0 = 0`` for every link) has
``E_0 = 0``, so its link update is the Gaussian range log-likelihood summed over the links
per particle: a square root and a multiply-add per particle-link, no exponential (its new
posteriors are 1 and its pooled link posterior is LOS with probability exactly 1, so
neither is computed). The kernel checks the condition per filter and takes that path by
itself; ``P2PParticleFilter`` then carries the posteriors as one broadcast row.

Parallelism: ``prange`` over (batch entry, chunk of particles) tasks, so one filter of
10^5 particles uses every core as well as 20 vehicles of 900. All arithmetic is float64.
"""

from __future__ import annotations

import math
import os

# numba's OpenMP threads spin (busy-wait) after each parallel region unless told otherwise;
# a filter step calls a parallel kernel hundreds of times per second, and on a machine with
# more runnable threads than cores the spinning costs CPU the working threads need
# (measured on the paper 001 highway filter, 2 cores shared: 4.8 -> 3.1 CPU-s for 300 steps,
# same results). Read by libgomp when numba first starts its threads; a value the user set
# is kept.
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

import numpy as np  # noqa: E402
from llvmlite import ir  # noqa: E402
from numba import njit, prange, types  # noqa: E402
from numba.extending import intrinsic  # noqa: E402

from radioloc.models.los_nlos import log_ndtr_fast as _log_ndtr

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
_SQRT1_2 = math.sqrt(0.5)
_LN2 = math.log(2.0)
_LN2_HI = 6.93147180369123816490e-01     # ln 2 = _LN2_HI + _LN2_LO, _LN2_HI with 32 bits
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.0 / math.log(2.0)
_EXP_LO, _EXP_HI = -745.2, 710.0         # exp(x) is 0 below, inf above
_ERFCX_K = 3.75
_SHIFT = 6755399441055744.0             # 1.5 * 2^52: x + _SHIFT rounds x to an integer
_SHIFT_BITS = 0x4338000000000000         # bits of _SHIFT
_TWO52 = 4503599627370496.0              # 2^52
_TWO52_BITS = 0x4330000000000000         # bits of 2^52
_MANT = (1 << 52) - 1
_ONE_BITS = 1023 << 52
_TINY = 1e-150        # below: evaluate the link in the log domain
_SUM_OK = 1e-200      # a detection sum above this is resolved in the linear domain
_U_SKIP = 8.5        # u = z - lam s at or above this: the NLOS term needs no erfcx
_ROWS = 8            # scratch rows of a chunk before the link posteriors


@intrinsic
def _i64_as_f64(typingctx, x):
    """Reinterpret the bits of an int64 as a float64 (a register move)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())
    return types.float64(types.int64), codegen


@intrinsic
def _f64_as_i64(typingctx, x):
    """Reinterpret the bits of a float64 as an int64 (a register move)."""
    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))
    return types.int64(types.float64), codegen


@njit(cache=True, inline="always")
def vexp(x: float) -> float:
    """``exp(x)`` without a branch or a call, so that loops over it vectorise.

    Parameters
    ----------
    x : float
        Argument; results below the smallest subnormal are 0, above the largest float inf
        (not NaN-safe: the kernels never pass NaN).

    Returns
    -------
    float
        ``exp(x)``, within 2 ulps of ``numpy.exp`` for normal results (tests).
    """
    x = min(max(x, _EXP_LO), _EXP_HI)
    kf = (x * _INV_LN2 + _SHIFT) - _SHIFT          # round to nearest integer
    r = (x - kf * _LN2_HI) - kf * _LN2_LO
    p = 1.0 / 6227020800.0
    p = p * r + 1.0 / 479001600.0
    p = p * r + 1.0 / 39916800.0
    p = p * r + 1.0 / 3628800.0
    p = p * r + 1.0 / 362880.0
    p = p * r + 1.0 / 40320.0
    p = p * r + 1.0 / 5040.0
    p = p * r + 1.0 / 720.0
    p = p * r + 1.0 / 120.0
    p = p * r + 1.0 / 24.0
    p = p * r + 1.0 / 6.0
    p = p * r + 0.5
    p = p * r + 1.0
    p = p * r + 1.0
    # 2^k in two factors 2^k1 2^(k - k1) (subnormal results); the integers are read from
    # the bits of k + 1.5 2^52 (AVX2 has no float -> int64 conversion)
    k1f = math.floor(0.5 * kf)
    k1 = _f64_as_i64(k1f + _SHIFT) - _SHIFT_BITS
    k2 = _f64_as_i64((kf - k1f) + _SHIFT) - _SHIFT_BITS
    return p * _i64_as_f64((k1 + 1023) << 52) * _i64_as_f64((k2 + 1023) << 52)


@njit(cache=True, inline="always")
def verfcx(x: float) -> float:
    """Scaled complementary error function ``exp(x^2) erfc(x)`` for ``x >= 0``, branch-free.

    Parameters
    ----------
    x : float
        Argument, ``x >= 0`` (finite).

    Returns
    -------
    float
        ``erfcx(x)``, relative error below 7e-15 against ``scipy.special.erfcx`` (tests;
        at most 20 ulps measured, median 3).
    """
    t = 1.0 + 2.0 * x
    r = 1.0 / ((x + _ERFCX_K) * t)          # one division for y and the final quotient
    y = (x - _ERFCX_K) * t * r
    return _erfcx_cheb(y, y + y) * (x + _ERFCX_K) * r


@njit(cache=True, inline="always")
def _erfcx_cheb(y, y2):
    b2 = 0.0
    b1 = 2.2898349882893854e-16
    b2 = y2 * b1 - b2 + -1.470178145890344e-15
    b1 = y2 * b2 - b1 + -1.7208456881689926e-15
    b2 = y2 * b1 - b2 + 3.369179935042155e-14
    b1 = y2 * b2 - b1 + 3.2737701438634303e-14
    b2 = y2 * b1 - b2 + -9.652487142908228e-13
    b1 = y2 * b2 - b1 + 1.9456658506555868e-13
    b2 = y2 * b1 - b2 + 2.8687385800196807e-11
    b1 = y2 * b2 - b1 + -6.318079392997333e-11
    b2 = y2 * b1 - b2 + -7.754402571447105e-10
    b1 = y2 * b2 - b1 + 4.521959418024579e-09
    b2 = y2 * b1 - b2 + 1.0764999544554676e-08
    b1 = y2 * b2 - b1 + -2.1886401023463176e-07
    b2 = y2 * b1 - b2 + 7.740383065057976e-07
    b1 = y2 * b2 - b1 + 4.139027985738952e-06
    b2 = y2 * b1 - b2 + -6.916973302501222e-05
    b1 = y2 * b2 - b1 + 0.0004907758365258058
    b2 = y2 * b1 - b2 + -0.002413163540417663
    b1 = y2 * b2 - b1 + 0.009074997670705229
    b2 = y2 * b1 - b2 + -0.026658668435305934
    b1 = y2 * b2 - b1 + 0.05920993999819197
    b2 = y2 * b1 - b2 + -0.08424913336651804
    b1 = y2 * b2 - b1 + -0.00459005458064643
    return y * b1 - b2 + 1.177578934567402

@njit(cache=True, inline="always")
def _logaddexp(a: float, b: float) -> float:
    if a == -np.inf:
        return b
    if b == -np.inf:
        return a
    if a > b:
        return a + math.log1p(math.exp(b - a))
    return b + math.log1p(math.exp(a - b))


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _vsum(x, m):
    """Sum of ``x[:m]`` (reassociated, so it vectorises)."""
    s = 0.0
    for i in range(m):
        s += x[i]
    return s


def n_chunks(particles: int, chunk: int) -> int:
    """Number of particle chunks of :func:`link_weights`.

    Parameters
    ----------
    particles : int
        Particles per filter K.
    chunk : int
        Particles per task.

    Returns
    -------
    int
        ``ceil(K / chunk)``.
    """
    return max(1, -(-particles // chunk))


@njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _gauss_link(buf, m, nx, ny, th, inv_s):
    """Gaussian link (pi_0 = 0): ``-z^2 / 2`` added to row 7."""
    for i in range(m):
        dx = buf[0, i] - nx
        dy = buf[1, i] - ny
        z = (th - math.sqrt(dx * dx + dy * dy)) * inv_s
        buf[7, i] -= 0.5 * z * z


@njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _residuals(buf, m, nx, ny, th, s, ls2):
    """Range residual ``e`` into row 4, ``z = e / s`` into row 5 and the ``erfcx``
    argument ``|u| / sqrt 2`` into row 6 of every particle of a chunk. Returns how many
    particles have ``u = z - lam s < 8.5`` (the ones whose NLOS term needs ``erfcx``) and
    how many have ``-z^2 / 2 >= -745.2`` (the ones whose ``E_1`` is not exactly 0)."""
    need = 0
    los = 0
    for i in range(m):
        dx = buf[0, i] - nx
        dy = buf[1, i] - ny
        e = th - math.sqrt(dx * dx + dy * dy)
        z = e / s
        u = z - ls2
        buf[4, i] = e
        buf[5, i] = z
        buf[6, i] = abs(u) * _SQRT1_2
        need += 1 if u < _U_SKIP else 0
        los += 1 if -0.5 * z * z >= _EXP_LO else 0
    return need, los


@njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _erfcx_row(buf, m):
    """``erfcx`` of row 6 in place (a loop of its own: a short body that the core overlaps)."""
    for i in range(m):
        buf[6, i] = verfcx(buf[6, i])


@njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _mixture_link(buf, m, r, lam, ls2, hc, big_d1, c11, c10, c01, c00):
    """LOS/NLOS link of every particle of a chunk, vectorised over the particles, from the
    residuals of :func:`_residuals` (rows 4, 5) and ``erfcx`` values (row 6; ``hc = 0``
    where none is needed): prior ``pi_1 = c11 q + c10 (1 - q)``, ``pi_0 = c01 q + c00 (1 -
    q)`` from the carried posterior in row ``r``; new posterior into row ``r`` (-1 where
    ``tot <= 1e-150``: log domain), ``E_0``, ``E_1`` terms into rows 4, 5, running product
    rows 2, 3. Returns the number of log-domain particles."""
    nbad = 0
    for i in range(m):
        e = buf[4, i]
        z = buf[5, i]
        q = buf[r, i]
        pi1 = q * c11 + (1.0 - q) * c10
        pi0 = q * c01 + (1.0 - q) * c00
        e1 = vexp(-0.5 * z * z)
        g = hc * buf[6, i] * e1
        e0 = vexp(min(-lam * e, 0.0))
        a0 = pi0 * (g if z - ls2 < 0.0 else e0 - g)
        a1 = pi1 * big_d1 * e1
        tot = a0 + a1
        ok = tot > _TINY
        f = buf[2, i] * (tot if ok else 1.0)
        bits = _f64_as_i64(f)
        # biased exponent as a float: its bits under those of 2^52 (no int64 -> float
        # conversion in AVX2)
        buf[3, i] += _i64_as_f64((bits >> 52) | _TWO52_BITS) - (_TWO52 + 1023.0)
        buf[2, i] = _i64_as_f64((bits & _MANT) | _ONE_BITS)
        buf[r, i] = a1 / tot if ok else -1.0
        buf[4, i] = a0 if ok else 0.0
        buf[5, i] = a1 if ok else 0.0
        nbad += 0 if ok else 1
    return nbad


@njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _nlos_link(buf, m, r, lam, c01, c00):
    """:func:`_mixture_link` of a link where every particle has ``E_1 = 0`` exactly
    (``-z^2 / 2 < -745.2``: ``vexp`` returns 0) and ``u >= 8.5`` (``E_0 = exp(-lam e)``):
    the same values with ``a1 = 0``, so no ``E_1`` exponential and no division."""
    nbad = 0
    for i in range(m):
        e = buf[4, i]
        q = buf[r, i]
        pi0 = q * c01 + (1.0 - q) * c00
        a0 = pi0 * vexp(min(-lam * e, 0.0))
        ok = a0 > _TINY
        f = buf[2, i] * (a0 if ok else 1.0)
        bits = _f64_as_i64(f)
        buf[3, i] += _i64_as_f64((bits >> 52) | _TWO52_BITS) - (_TWO52 + 1023.0)
        buf[2, i] = _i64_as_f64((bits & _MANT) | _ONE_BITS)
        buf[r, i] = 0.0 if ok else -1.0
        buf[4, i] = a0 if ok else 0.0
        buf[5, i] = 0.0
        nbad += 0 if ok else 1
    return nbad


@njit(cache=True, parallel=True, error_model="numpy", fastmath={"contract"})
def link_weights(particles, node_xy, theta, valid, where_prev, prev_q, anc, carried,
                 link_major, los_std, nlos_mean, alpha, chunk, em, log_w, q_new, part_s, part_l,
                 em_pp, gauss):
    """Particle-link update of Algorithm 2 (lines 6, 8, 11) for every filter of a batch.

    Parameters
    ----------
    particles : ndarray, shape (B, K, n)
        Predicted particle states, position (x, y) first.
    node_xy : ndarray, shape (B, L, 2)
        Positions of the linked nodes.
    theta : ndarray, shape (B, L)
        Measured ranges.
    valid : ndarray of bool, shape (B, L)
        Which link slots exist.
    where_prev : ndarray of int64, shape (B, L)
        Slot of the link in ``prev_q``, or -1 for a new neighbour (line 8).
    prev_q : ndarray, shape (B, K, L') or (B, 1, L')
        Carried LOS posteriors ``p(z_{t-1} = 1 | .)`` of the previous step's links (one row
        shared by every particle in the second form).
    anc : ndarray of int64, shape (B, K) (or any 2-D shape when not ``carried``)
        With ``carried``: particle ``i`` carries the posteriors of row ``anc[b, i]`` of
        ``prev_q`` (the resampling's ancestors, read here instead of a gather beforehand:
        the same values as ``prev_q[b, anc[b]]`` passed without them).
    carried : bool
        Read ``prev_q`` through ``anc``.
    link_major : bool
        ``prev_q`` is ``(B, L', K)`` (or ``(B, L', 1)``) and ``q_new`` is ``(B, L, K)``:
        one contiguous row of particles per link slot, so the posteriors are copied in
        and out of the chunk's rows instead of transposed, and only the rows of existing
        links are touched (``q_new``'s rows of padding slots are left unwritten).
    los_std, nlos_mean, alpha : ndarray, shape (B,)
        ``s_LOS``, ``s_NLOS`` and alpha of each filter (the sticky chain follows alpha).
    chunk : int
        Particles per parallel task.
    em : bool
        Also fill ``em_pp``.
    log_w : ndarray, shape (B, K)
        Output: log weights ``sum_m log sum_z phi^i(km, z)`` (line 11).
    q_new : ndarray, shape (B, K, L)
        Output: normalised LOS posterior ``phi^i(z=1) / sum_z phi^i(z)`` (0 at padding).
    part_s : ndarray, shape (B, C, L, 2)
        Output: per chunk, ``sum_i exp(log phi^i(z) - c_e)`` over the linear-domain
        particle-links (terms below about 1e-300 are lost to underflow).
    part_l : ndarray, shape (B, C, L, 2)
        Output: per chunk, ``log sum_i phi^i(z)`` over the log-domain particle-links
        (-inf if none); a link whose two linear sums are both below 1e-200 is summed
        entirely here. ``log sum_i phi^i(z)`` is ``logaddexp(log part_s + c_e, part_l)``
        summed over chunks: exact to rounding wherever it is within about 690 of the
        other state's (so the detection rule and the normalised posterior are exact).
    em_pp : ndarray, shape (B, K, 3)
        Output if ``em``: per particle ``sum_m q'``, ``sum_m q' e^2`` and
        ``sum_m (1 - q') e`` (e: range minus particle distance).
    gauss : ndarray of bool, shape (B,)
        Output: the filters that took the Gaussian case (alpha = 1 and every carried
        posterior of a linked slot 1). For those ``q_new`` is not written (it is 1 on
        every link), ``part_s`` is 0 and ``part_l`` is ``(-inf, 0)`` per chunk (the NLOS
        sum is exactly 0; the LOS sum is left unnormalised: its exponentials are skipped).

    Returns
    -------
    None
        The results are written into the output arrays.
    """
    nb = q_new.shape[0]
    if link_major:
        nl, nk = q_new.shape[1], q_new.shape[2]
        qs = 1 if prev_q.shape[2] == nk else 0  # 0: one row shared by every particle
    else:
        nk, nl = q_new.shape[1], q_new.shape[2]
        qs = 1 if prev_q.shape[1] == nk else 0
    nc = part_s.shape[1]
    # Gaussian case: alpha = 1 and every carried LOS posterior of a link exactly 1
    ok = np.ones((nb, nc), dtype=np.bool_)
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        if alpha[b] != 1.0:
            ok[b, c] = False
            continue
        i1 = min(nk, (c + 1) * chunk) if qs else 1
        for j in range(nl):
            jp = where_prev[b, j]
            if valid[b, j] and jp >= 0:
                for i in range(c * chunk * qs, i1):
                    pi = anc[b, i] * qs if carried else i
                    v = prev_q[b, jp, pi] if link_major else prev_q[b, pi, jp]
                    if v != 1.0:
                        ok[b, c] = False
    for b in range(nb):
        gauss[b] = True
        for c in range(nc):
            gauss[b] = gauss[b] and ok[b, c]
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        s = los_std[b]
        lam = 1.0 / nlos_mean[b]
        a = alpha[b]
        ce = math.log(lam) + 0.5 * (lam * s) ** 2
        cg = -math.log(s) - _HALF_LOG_2PI
        d1 = cg - ce
        ls2 = lam * s
        big_d1 = math.exp(d1)
        half_c = 0.5 * math.exp(-0.5 * ls2 * ls2)
        # sticky chain: P[z_prev, z]
        t00, t01 = 1.0 - 0.5 * a, 0.5 * a
        t10, t11 = 0.5 * (1.0 - a), 0.5 * (1.0 + a)
        i0 = c * chunk
        i1 = min(nk, i0 + chunk)
        m = i1 - i0
        # scratch rows: 0 x, 1 y, 2 running product, 3 its binary exponent, 4 / 5 the
        # link's residual e / z, then its E_0 / E_1 terms, 6 erfcx, 7 log-domain sum,
        # _ROWS + j the LOS posterior of link slot j (carried in, new out; -1 marks a
        # log-domain link). One array, so the vector loops below need no runtime alias
        # checks; the posteriors are transposed in and out once per chunk, so every loop
        # over the particles of a link reads and writes contiguous memory.
        buf = np.empty((_ROWS + nl, m))
        for i in range(m):
            buf[0, i] = particles[b, i0 + i, 0]
            buf[1, i] = particles[b, i0 + i, 1]
            buf[2, i] = 1.0
            buf[3, i] = 0.0
            buf[7, i] = 0.0
        gs = gauss[b]
        if not gs:
            # carried posteriors of the links that existed at t - 1, in tiles of 4
            # particles (four loads, then four stores: their rows of prev_q stay in the L1
            # cache)
            rows = np.empty(nl, dtype=np.int64)
            cols = np.empty(nl, dtype=np.int64)
            n_old = 0
            for j in range(nl):
                if valid[b, j] and where_prev[b, j] >= 0:
                    rows[n_old] = _ROWS + j
                    cols[n_old] = where_prev[b, j]
                    n_old += 1
            m4 = m - m % 4 if not link_major else 0
            if link_major:
                # one row per link: copy (through the ancestors) instead of transposing
                for t in range(n_old):
                    r = rows[t]
                    jp = cols[t]
                    if carried and qs:
                        for i in range(m):
                            buf[r, i] = prev_q[b, jp, anc[b, i0 + i]]
                    else:
                        for i in range(m):
                            buf[r, i] = prev_q[b, jp, (i0 + i) * qs]
            for t0 in range(0, m4, 4):
                p0 = (i0 + t0) * qs
                p1 = p0 + qs
                p2 = p0 + 2 * qs
                p3 = p0 + 3 * qs
                if carried:
                    p0 = anc[b, i0 + t0] * qs
                    p1 = anc[b, i0 + t0 + 1] * qs
                    p2 = anc[b, i0 + t0 + 2] * qs
                    p3 = anc[b, i0 + t0 + 3] * qs
                for t in range(n_old):
                    r = rows[t]
                    jp = cols[t]
                    v0 = prev_q[b, p0, jp]
                    v1 = prev_q[b, p1, jp]
                    v2 = prev_q[b, p2, jp]
                    v3 = prev_q[b, p3, jp]
                    buf[r, t0] = v0
                    buf[r, t0 + 1] = v1
                    buf[r, t0 + 2] = v2
                    buf[r, t0 + 3] = v3
            for t in range(n_old if not link_major else 0):
                for i in range(m4, m):
                    pi = anc[b, i0 + i] if carried else i0 + i
                    buf[rows[t], i] = prev_q[b, pi * qs, cols[t]]
        if em:
            for i in range(i0, i1):
                em_pp[b, i, 0] = 0.0
                em_pp[b, i, 1] = 0.0
                em_pp[b, i, 2] = 0.0
        nvalid = 0
        for j in range(nl):
            part_s[b, c, j, 0] = 0.0
            part_s[b, c, j, 1] = 0.0
            part_l[b, c, j, 0] = -np.inf
            part_l[b, c, j, 1] = -np.inf
            r = _ROWS + j
            if not valid[b, j]:
                if not link_major:              # copied out (0 at padding); else never read
                    for i in range(m):
                        buf[r, i] = 0.0
                continue
            nvalid += 1
            nx = node_xy[b, j, 0]
            ny = node_xy[b, j, 1]
            th = theta[b, j]
            jp = where_prev[b, j]
            if gs:
                _gauss_link(buf, m, nx, ny, th, 1.0 / s)
                part_l[b, c, j, 1] = 0.0
            else:
                if jp >= 0:
                    c11, c10, c01, c00 = t11, t01, t10, t00
                else:
                    c11, c10, c01, c00 = a, 0.0, 1.0 - a, 0.0
                    for i in range(m):
                        buf[r, i] = 1.0
                # erfcx only for a link with a particle at u < 8.5 (see _residuals)
                need, los = _residuals(buf, m, nx, ny, th, s, ls2)
                if need == 0 and los == 0:
                    nbad = _nlos_link(buf, m, r, lam, c01, c00)
                else:
                    hc = 0.0
                    if need > 0:
                        _erfcx_row(buf, m)
                        hc = half_c
                    nbad = _mixture_link(buf, m, r, lam, ls2, hc, big_d1, c11, c10, c01,
                                         c00)
                part_s[b, c, j, 0] = _vsum(buf[4], m)
                part_s[b, c, j, 1] = _vsum(buf[5], m)
                if nbad > 0:                                # log domain
                    for i in range(m):
                        if buf[r, i] >= 0.0:
                            continue
                        dx = buf[0, i] - nx
                        dy = buf[1, i] - ny
                        e = th - math.sqrt(dx * dx + dy * dy)
                        z = e / s
                        if jp >= 0:
                            pi = (anc[b, i0 + i] if carried else i0 + i) * qs
                            q = prev_q[b, jp, pi] if link_major else prev_q[b, pi, jp]
                            pi1 = q * t11 + (1.0 - q) * t01
                            pi0 = q * t10 + (1.0 - q) * t00
                        else:
                            pi1 = a
                            pi0 = 1.0 - a
                        l0 = -lam * e + _log_ndtr(z - ls2)          # minus c_e
                        l1 = d1 - 0.5 * z * z
                        A0 = l0 + math.log(pi0) if pi0 > 0.0 else -np.inf
                        A1 = l1 + math.log(pi1) if pi1 > 0.0 else -np.inf
                        lse = _logaddexp(A0, A1)
                        buf[r, i] = math.exp(A1 - lse)
                        buf[7, i] += lse
                        part_l[b, c, j, 0] = _logaddexp(part_l[b, c, j, 0], A0 + ce)
                        part_l[b, c, j, 1] = _logaddexp(part_l[b, c, j, 1], A1 + ce)
            if em:
                for i in range(m):
                    qn = 1.0 if gs else buf[r, i]
                    dx = buf[0, i] - nx
                    dy = buf[1, i] - ny
                    e = th - math.sqrt(dx * dx + dy * dy)
                    em_pp[b, i0 + i, 0] += qn
                    em_pp[b, i0 + i, 1] += qn * e * e
                    em_pp[b, i0 + i, 2] += (1.0 - qn) * e
        if not gs and link_major:
            for j in range(nl):
                if valid[b, j]:
                    for i in range(m):
                        q_new[b, j, i0 + i] = buf[_ROWS + j, i]
        elif not gs:
            for t0 in range(0, m, 8):
                t1 = min(m, t0 + 8)
                for i in range(t0, t1):
                    for j in range(nl):
                        q_new[b, i0 + i, j] = buf[_ROWS + j, i]
        if gs:
            for i in range(m):
                log_w[b, i0 + i] = nvalid * cg + buf[7, i]
            continue
        else:
            for i in range(m):
                log_w[b, i0 + i] = (nvalid * ce + buf[7, i] + buf[3, i] * _LN2
                                    + math.log(buf[2, i]))
        # a link whose two sums are both below 1e-200 (every particle metres off): redo
        # its detection sums in the log domain (the linear terms may have underflowed)
        for j in range(nl):
            if not valid[b, j] or part_s[b, c, j, 0] > _SUM_OK or part_s[b, c, j, 1] > _SUM_OK:
                continue
            jp = where_prev[b, j]
            m0 = -np.inf
            m1 = -np.inf
            for i in range(i0, i1):
                dx = particles[b, i, 0] - node_xy[b, j, 0]
                dy = particles[b, i, 1] - node_xy[b, j, 1]
                e = theta[b, j] - math.sqrt(dx * dx + dy * dy)
                z = e / s
                if jp >= 0:
                    pi = (anc[b, i] if carried else i) * qs
                    q = prev_q[b, jp, pi] if link_major else prev_q[b, pi, jp]
                    pi1 = q * t11 + (1.0 - q) * t01
                    pi0 = q * t10 + (1.0 - q) * t00
                else:
                    pi1 = a
                    pi0 = 1.0 - a
                if pi0 > 0.0:
                    m0 = _logaddexp(m0, -lam * e + _log_ndtr(z - ls2) + math.log(pi0) + ce)
                if pi1 > 0.0:
                    m1 = _logaddexp(m1, d1 - 0.5 * z * z + math.log(pi1) + ce)
            part_s[b, c, j, 0] = 0.0
            part_s[b, c, j, 1] = 0.0
            part_l[b, c, j, 0] = m0
            part_l[b, c, j, 1] = m1


@njit(cache=True, inline="always", error_model="numpy", fastmath={"reassoc", "contract"})
def _moment_sums(w, particles, b, i0, i1, sums):
    """``sums = (sum v, sum v^2, sum v dx_d, sum v dx_d dx_g (g <= d))`` over particles
    ``i0..i1`` of filter ``b``, ``dx`` relative to particle 0 of the filter."""
    n = particles.shape[2]
    for t in range(sums.shape[0]):
        sums[t] = 0.0
    if n == 2:                                  # position only: scalar accumulators
        rx = particles[b, 0, 0]
        ry = particles[b, 0, 1]
        s0 = 0.0
        sq = 0.0
        sx = 0.0
        sy = 0.0
        sxx = 0.0
        syx = 0.0
        syy = 0.0
        for i in range(i0, i1):
            v = w[b, i]
            dx = particles[b, i, 0] - rx
            dy = particles[b, i, 1] - ry
            s0 += v
            sq += v * v
            sx += v * dx
            sy += v * dy
            sxx += v * dx * dx
            syx += v * dy * dx
            syy += v * dy * dy
        sums[0] = s0
        sums[1] = sq
        sums[2] = sx
        sums[3] = sy
        sums[4] = sxx
        sums[5] = syx
        sums[6] = syy
        return
    for i in range(i0, i1):
        v = w[b, i]
        sums[0] += v
        sums[1] += v * v
        t = 2 + n
        for d in range(n):
            dd = particles[b, i, d] - particles[b, 0, d]
            sums[2 + d] += v * dd
            for g in range(d + 1):
                sums[t] += v * dd * (particles[b, i, g] - particles[b, 0, g])
                t += 1


@njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _moments_from_sums(tot, particles, b, n, mean, cov, ess):  # pragma: no cover - compiled
    """Filter ``b``'s ESS, mean and covariance from its moment sums ``tot`` (the layout of
    :func:`_moment_sums`: sum of w, of w^2, of w dx per coordinate, of w dx dx' over the
    lower triangle, dx relative to particle 0); returns ``1 / sum w``."""
    inv = 1.0 / tot[0]
    ess[b] = tot[0] * tot[0] / tot[1]
    t = 2 + n
    for d in range(n):
        md = tot[2 + d] * inv
        mean[b, d] = particles[b, 0, d] + md
        for g in range(d + 1):
            cv = tot[t] * inv - md * tot[2 + g] * inv
            cov[b, d, g] = cv
            cov[b, g, d] = cv
            t += 1
    return inv


@njit(cache=True, parallel=True, error_model="numpy", fastmath={"contract"})
def weights_moments(log_w, particles, chunk, w, mean, cov, ess):
    """Normalised weights, weighted mean and covariance and ESS (Algorithm 2, line 14).

    Three parallel passes over (filter, chunk of particles) tasks: the maximum log weight,
    then ``v = exp(log w - max)`` and the chunk's sums of ``v``, ``v^2``, ``v dx`` and ``v
    dx dx'`` (``dx`` relative to the filter's first particle, so the covariance
    ``sum v dx dx' / sum v - mean(dx) mean(dx)'`` does not lose the digits of a large
    position), then the normalisation.

    Parameters
    ----------
    log_w : ndarray, shape (B, K)
        Log weights.
    particles : ndarray, shape (B, K, n)
        Particle states.
    chunk : int
        Particles per parallel task.
    w : ndarray, shape (B, K)
        Output: normalised weights.
    mean : ndarray, shape (B, n)
        Output: weighted mean.
    cov : ndarray, shape (B, n, n)
        Output: weighted covariance.
    ess : ndarray, shape (B,)
        Output: ``1 / sum_i w_i^2``.

    Returns
    -------
    None
        The results are written into the output arrays.
    """
    nb, nk, n = particles.shape
    nc = max(1, -(-nk // chunk))
    ns = 2 + n + n * (n + 1) // 2
    cmax = np.empty((nb, nc))
    sums = np.empty((nb, nc, ns))
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        m = -np.inf
        for i in range(c * chunk, min(nk, (c + 1) * chunk)):
            m = max(m, log_w[b, i])
        cmax[b, c] = m
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        m = cmax[b, 0]
        for cc in range(1, nc):
            m = max(m, cmax[b, cc])
        i0 = c * chunk
        i1 = min(nk, i0 + chunk)
        for i in range(i0, i1):
            w[b, i] = vexp(log_w[b, i] - m)
        _moment_sums(w, particles, b, i0, i1, sums[b, c])
    tots = np.empty((nb, ns))
    for b in range(nb):
        # explicit loops: np.zeros here would be a parallel region of its own per filter
        tot = tots[b]
        for t in range(ns):
            tot[t] = 0.0
        for c in range(nc):
            for t in range(ns):
                tot[t] += sums[b, c, t]
        inv = _moments_from_sums(tot, particles, b, n, mean, cov, ess)
        tot[0] = inv
        sums[b, 0, 0] = inv
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        inv = sums[b, 0, 0]
        for i in range(c * chunk, min(nk, (c + 1) * chunk)):
            w[b, i] *= inv


@njit(cache=True, parallel=True)
def systematic_indices(w, u, idx, chunk=2048):
    """Systematic resampling: ancestor of new particle j is the first i with
    ``cumsum(w)_i > (u + j) / K``.

    Parallel over (filter, chunk of ancestors) tasks: each chunk's weight sum gives where
    its part of the cumulative sum starts, and the task writes the new particles whose
    position ``(u + j) / K`` falls in its part (the last ancestor of a chunk takes any
    position rounding puts past the chunk's end).

    Parameters
    ----------
    w : ndarray, shape (B, K)
        Normalised weights.
    u : ndarray, shape (B,)
        One uniform in [0, 1) per filter.
    idx : ndarray of int64, shape (B, K)
        Output: ancestor indices (non-decreasing).
    chunk : int
        Ancestors per parallel task.

    Returns
    -------
    None
        The result is written into ``idx``.
    """
    nb, nk = w.shape
    nc = max(1, -(-nk // chunk))
    start = np.empty((nb, nc + 1))
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        s = 0.0
        for i in range(c * chunk, min(nk, (c + 1) * chunk)):
            s += w[b, i]
        start[b, c + 1] = s
    first = np.empty((nb, nc + 1), dtype=np.int64)
    for b in range(nb):
        start[b, 0] = 0.0
        for c in range(nc):
            start[b, c + 1] += start[b, c]
        # first new particle of chunk c: the first j with (u + j) / K >= start of c
        for c in range(nc + 1):
            j = int(math.ceil(start[b, c] * nk - u[b]))
            first[b, c] = min(max(j, 0), nk)
            while first[b, c] > 0 and (u[b] + first[b, c] - 1) / nk >= start[b, c]:
                first[b, c] -= 1
            while first[b, c] < nk and (u[b] + first[b, c]) / nk < start[b, c]:
                first[b, c] += 1
        first[b, 0] = 0
        first[b, nc] = nk
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        i = c * chunk
        last = min(nk, (c + 1) * chunk) - 1
        cdf = start[b, c] + w[b, i]
        for j in range(first[b, c], max(first[b, c], first[b, c + 1])):
            pos = (u[b] + j) / nk
            while cdf <= pos and i < last:
                i += 1
                cdf += w[b, i]
            idx[b, j] = i


@njit(cache=True, parallel=True)
def gather_resampled(particles, q, idx, out_particles, out_q, distinct, mark, chunk=2048):
    """Copy the resampled particles and their link posteriors; count distinct ancestors.

    Parameters
    ----------
    particles : ndarray, shape (B, K, n)
    q : ndarray, shape (B, K, L)
        Link posteriors of the step.
    idx : ndarray of int64, shape (B, K)
        Ancestor of each new particle.
    out_particles : ndarray, shape (B, K, n)
        Output.
    out_q : ndarray, shape (B, K, L)
        Output.
    distinct : ndarray of int64, shape (B,)
        Output: number of distinct ancestors.
    mark : ndarray of bool, shape (B, K)
        Scratch.
    chunk : int
        New particles per parallel task.

    Returns
    -------
    None
        The results are written into the output arrays.
    """
    nb, nk, n = particles.shape
    nl = q.shape[2]
    nc = max(1, -(-nk // chunk))
    counts = np.zeros((nb, nc), dtype=np.int64)
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        for i in range(c * chunk, min(nk, (c + 1) * chunk)):
            mark[b, i] = False
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        for i in range(c * chunk, min(nk, (c + 1) * chunk)):
            a = idx[b, i]
            mark[b, a] = True           # every writer writes True: the order is immaterial
            for d in range(n):
                out_particles[b, i, d] = particles[b, a, d]
            for j in range(nl):
                out_q[b, i, j] = q[b, a, j]
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        cnt = 0
        for i in range(c * chunk, min(nk, (c + 1) * chunk)):
            cnt += mark[b, i]
        counts[b, c] = cnt
    # explicit loops: a NumPy reduction inside this serial loop would be a parallel region
    # of its own per filter
    for b in range(nb):
        cnt = 0
        for c in range(nc):
            cnt += counts[b, c]
        distinct[b] = cnt


@njit(cache=True, parallel=True, error_model="numpy")
def walk_gather(particles, anc, gathered, shift, shifted, sd, z, out, chunk):
    """Prediction of a random walk from resampled particles, the resampling's gather folded
    in: ``out[b, i] = (particles[b, anc[b, i]] + shift[b]) + sd * z[b, i]`` (no
    contraction: the roundings of ``z *= sd; z += particles + shift`` in NumPy).

    Parameters
    ----------
    particles : ndarray, shape (B, K, n)
        Particles before the gather.
    anc : ndarray of int64, shape (B, K) (any 2-D shape when not ``gathered``)
        Ancestor of each new particle.
    gathered : bool
        Read ``particles`` through ``anc`` (else ``particles[b, i]``).
    shift : ndarray, shape (B, n) (any 2-D shape when not ``shifted``)
        Displacement of each filter (the control).
    shifted : bool
        Add ``shift`` (else no addition, as NumPy without a control).
    sd : ndarray, shape (n,)
        Noise standard deviation per component.
    z : ndarray, shape (B, K, n)
        Standard normal draws.
    out : ndarray, shape (B, K, n)
        Output: the predicted particles.
    chunk : int
        Particles per parallel task.

    Returns
    -------
    None
        The result is written into ``out``.
    """
    nb, nk, n = z.shape
    nc = max(1, -(-nk // chunk))
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        for i in range(c * chunk, min(nk, (c + 1) * chunk)):
            a = anc[b, i] if gathered else i
            for d in range(n):
                p = particles[b, a, d]
                if shifted:
                    p = p + shift[b, d]
                out[b, i, d] = sd[d] * z[b, i, d] + p


@njit(cache=True, inline="always", error_model="numpy")
def _systematic_counts(w, b, nk, u, idx, h):
    """Systematic resampling of filter ``b`` (one chunk) without a search; returns the
    number of distinct ancestors.

    The search of :func:`systematic_indices` (``cdf`` the running sum ``((0 + w_0) + w_1)
    + ...`` and ``pos_j = (u + j) / K``) gives ``idx_j = #{i < K - 1 : cdf_i <= pos_j}``:
    the running sum of non-negative weights never decreases (a NaN stays NaN and compares
    false), so the ``i`` with ``cdf_i <= pos_j`` are a prefix of ``0..K-2`` and the search
    stops at its end (or at ``K - 1``). ``pos_j`` never decreases in ``j`` either (monotone
    roundings), so ``cdf_i <= pos_j`` holds exactly for ``j >= M_i``, the first such ``j``
    (``K`` if none), and ``idx_j = #{i < K - 1 : M_i <= j}``: a histogram of the ``M_i``
    and its running sum. ``M_i`` starts at ``ceil(cdf_i K - u)`` and moves by the exact
    comparison ``cdf_i <= pos_j``, with ``pos_j`` computed as the search computes it, so the
    indices are the search's bit for bit (tests/test_p2p_run_fused.py, with ties)."""
    last = nk - 1
    for j in range(nk + 1):
        h[j] = 0
    c = 0.0
    for i in range(last):
        c += w[b, i]
        if c == c:
            t = c * nk - u
            jj = nk if t >= nk else (0 if t <= 0.0 else int(math.ceil(t)))
            while jj > 0 and c <= (u + (jj - 1)) / nk:
                jj -= 1
            while jj < nk and not c <= (u + jj) / nk:
                jj += 1
        else:
            jj = nk
        h[jj] += 1
    cnt = 0
    moves = 0
    for j in range(nk):
        prev = cnt
        cnt += h[j]
        idx[b, j] = cnt
        moves += (cnt != prev) if j > 0 else 0
    return 1 + moves


@njit(cache=True, parallel=True, error_model="numpy", fastmath={"contract"})
def moments_resample(log_w, particles, u, w, mean, cov, ess, idx, distinct):
    """:func:`weights_moments` then :func:`systematic_indices` in one parallel pass over the
    filters, for filters of at most one chunk of particles (``K <= chunk``): the same
    operations in the same order as the two kernels with one chunk, so the same values;
    and the number of distinct ancestors, counted on the way.

    Parameters
    ----------
    log_w : ndarray, shape (B, K)
        Log weights.
    particles : ndarray, shape (B, K, n)
        Particle states.
    u : ndarray, shape (B,)
        One uniform in [0, 1) per filter (the systematic positions ``(u + j) / K``).
    w, mean, cov, ess : ndarray
        Outputs of :func:`weights_moments`.
    idx : ndarray of int64, shape (B, K)
        Output: ancestor indices (non-decreasing), as :func:`systematic_indices`.
    distinct : ndarray of int64, shape (B,)
        Output: number of distinct ancestors (one plus the number of ``j`` with
        ``idx[b, j] != idx[b, j - 1]``, the indices being non-decreasing).

    Returns
    -------
    None
        The results are written into the output arrays.
    """
    nb, nk, n = particles.shape
    ns = 2 + n + n * (n + 1) // 2
    for b in prange(nb):
        m = -np.inf
        for i in range(nk):
            m = max(m, log_w[b, i])
        for i in range(nk):
            w[b, i] = vexp(log_w[b, i] - m)
        tot = np.empty(ns)
        _moment_sums(w, particles, b, 0, nk, tot)
        inv = _moments_from_sums(tot, particles, b, n, mean, cov, ess)
        for i in range(nk):
            w[b, i] *= inv
        # systematic resampling (one chunk: the cumulative sum starts at 0), by counts
        distinct[b] = _systematic_counts(w, b, nk, u[b], idx, np.empty(nk + 1, dtype=np.int64))


@njit(cache=True, error_model="numpy")
def reset_filters(reset, mean, z, std, dim, particles, idx, q_rows, valid, q):
    """Reset of degenerate filters (the writes of ``P2PParticleFilter.step``'s reset, in one
    pass): for each filter ``b`` with ``reset[b]``, in order, ``particles[b, i, :dim] =
    mean[b, :dim] + std * z[r, i]`` (``r``: the rank of ``b`` among the reset filters; no
    contraction, the roundings of the NumPy expression), ``idx[b, i] = i`` and
    ``q[b, j, :] = q_rows[b, j]`` for the slots ``j`` of existing links (link-major
    posteriors: the rows of padding slots are never read, see ``link_weights``).

    Parameters
    ----------
    reset : ndarray of bool, shape (B,)
        Filters to reset.
    mean : ndarray, shape (B, n)
        Centre of each filter's new particles (position first).
    z : ndarray, shape (R * K * dim,) or longer
        Standard normal draws of the reset filters, C order ``(R, K, dim)``.
    std : float
        Spread of the new particles.
    dim : int
        Components reset (the position).
    particles : ndarray, shape (B, K, n)
        Particles, overwritten for reset filters.
    idx : ndarray of int64, shape (B, K)
        Ancestor indices, the identity for reset filters.
    q_rows : ndarray, shape (B, L)
        The posterior each link slot of a reset filter takes.
    valid : ndarray of bool, shape (B, L)
        Which link slots exist (the others' rows are left as they are).
    q : ndarray, shape (B, L, K)
        Link-major link posteriors, overwritten for reset filters.

    Returns
    -------
    None
        The results are written into ``particles``, ``idx`` and ``q``.
    """
    nb, nk, _ = particles.shape
    nl = q.shape[1]
    r = 0
    for b in range(nb):
        if not reset[b]:
            continue
        base = r * nk * dim
        for i in range(nk):
            for d in range(dim):
                particles[b, i, d] = mean[b, d] + std * z[base + i * dim + d]
            idx[b, i] = i
        for j in range(nl):
            if valid[b, j]:
                v = q_rows[b, j]
                for i in range(nk):
                    q[b, j, i] = v
        r += 1


@njit(cache=True, nogil=True)
def fill_standard_normal(rng, out):
    """``rng.standard_normal(out=out)`` compiled, without the GIL (numba's ``Generator``
    follows NumPy's ziggurat: the same numbers and the same state afterwards;
    tests/test_p2p_run_fused.py), so a thread can fill it while the caller works.

    Parameters
    ----------
    rng : numpy.random.Generator
        The generator drawn from.
    out : ndarray, shape (n,)
        Output: ``n`` standard normal draws.

    Returns
    -------
    None
        The draws are written into ``out``.
    """
    for i in range(out.size):
        out[i] = rng.standard_normal()
