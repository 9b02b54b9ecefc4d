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

Gaussian case. A filter whose LOS fraction is exactly 1 and whose carried link posteriors
are all exactly 1 (the invariant of such a filter: ``pi_0 = 0`` for every link) has
``E_0 = 0``, so its link update is the Gaussian range log-likelihood summed over the links
per particle (no exponential per link except the detection sum ``sum_i E_1``); the kernel
checks the condition per task and takes that path by itself.

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
_MANT = (1 << 52) - 1
_ONE_BITS = 1023 << 52
_TINY = 1e-150        # below: evaluate the link in the log domain
_SUM_OK = 1e-200      # a detection sum above this is resolved in the linear domain


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
    kf = math.floor(x * _INV_LN2 + 0.5)
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
    k = np.int64(kf)
    k1 = k >> 1
    return p * _i64_as_f64((k1 + 1023) << 52) * _i64_as_f64((k - k1 + 1023) << 52)


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
def _gauss_link(buf, m, nx, ny, th, s, d1):
    """Gaussian link (pi_0 = 0): log-likelihood into row 7, ``E_1`` into row 5."""
    for i in range(m):
        dx = buf[0, i] - nx
        dy = buf[1, i] - ny
        z = (th - math.sqrt(dx * dx + dy * dy)) / s
        h = -0.5 * z * z
        buf[7, i] += h
        buf[5, i] = vexp(d1 + h)


@njit(cache=True, inline="always", error_model="numpy", fastmath={"contract"})
def _mixture_link(buf, m, nx, ny, th, s, lam, ls2, half_c, big_d1, c11, c10, c01, c00):
    """LOS/NLOS link of every particle of a chunk, vectorised over the particles: prior
    ``pi_1 = c11 q + c10 (1 - q)``, ``pi_0 = c01 q + c00 (1 - q)`` from the carried
    posterior in row 6; new posterior into row 6 (-1 where ``tot <= 1e-150``: log domain),
    ``E_0``, ``E_1`` terms into rows 4, 5, running product rows 2, 3. Returns the number of
    log-domain particles."""
    nbad = 0
    for i in range(m):
        dx = buf[0, i] - nx
        dy = buf[1, i] - ny
        e = th - math.sqrt(dx * dx + dy * dy)
        z = e / s
        q = buf[6, i]
        pi1 = q * c11 + (1.0 - q) * c10
        pi0 = q * c01 + (1.0 - q) * c00
        h = -0.5 * z * z
        e1 = vexp(h)
        u = z - ls2
        g = half_c * verfcx(abs(u) * _SQRT1_2) * e1
        e0 = vexp(min(-lam * e, 0.0))
        a0 = pi0 * (g if u < 0.0 else e0 - g)
        a1 = pi1 * big_d1 * e1
        tot = a0 + a1
        ok = tot > _TINY
        f = buf[2, i] * (tot if ok else 1.0)
        bits = _f64_as_i64(f)
        buf[3, i] += np.float64((bits >> 52) - 1023)
        buf[2, i] = _i64_as_f64((bits & _MANT) | _ONE_BITS)
        buf[6, i] = a1 / tot if ok else -1.0
        buf[4, i] = a0 if ok else 0.0
        buf[5, i] = a1 if ok else 0.0
        nbad += 0 if ok else 1
    return nbad


@njit(cache=True, parallel=True, error_model="numpy", fastmath={"contract"})
def link_weights(particles, node_xy, theta, valid, where_prev, prev_q, los_std, nlos_mean,
                 alpha, chunk, em, log_w, q_new, part_s, part_l, em_pp):
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
    prev_q : ndarray, shape (B, K, L')
        Carried LOS posteriors ``p(z_{t-1} = 1 | .)`` of the previous step's links.
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

    Returns
    -------
    None
        The results are written into the output arrays.
    """
    nb, nk, nl = q_new.shape[0], q_new.shape[1], q_new.shape[2]
    nc = part_s.shape[1]
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
        # link's E_0 / E_1 terms, 6 LOS posterior (carried in, new out; -1 marks a
        # log-domain link), 7 log-domain sum. One array, so the vector loops below need
        # no runtime alias checks.
        buf = np.zeros((8, m))
        for i in range(m):
            buf[0, i] = particles[b, i0 + i, 0]
            buf[1, i] = particles[b, i0 + i, 1]
            buf[2, i] = 1.0
        # Gaussian case: alpha = 1 and every carried LOS posterior exactly 1 (pi_0 = 0)
        gauss = a == 1.0
        if gauss:
            for j in range(nl):
                jp = where_prev[b, j]
                if valid[b, j] and jp >= 0:
                    for i in range(i0, i1):
                        if prev_q[b, i, jp] != 1.0:
                            gauss = False
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
            if not valid[b, j]:
                for i in range(i0, i1):
                    q_new[b, i, j] = 0.0
                continue
            nvalid += 1
            nx = node_xy[b, j, 0]
            ny = node_xy[b, j, 1]
            th = theta[b, j]
            jp = where_prev[b, j]
            if gauss:
                _gauss_link(buf, m, nx, ny, th, s, d1)
                part_s[b, c, j, 1] = _vsum(buf[5], m)
                for i in range(i0, i1):
                    q_new[b, i, j] = 1.0
            else:
                if jp >= 0:
                    for i in range(m):
                        q = prev_q[b, i0 + i, jp]
                        buf[6, i] = q
                    c11, c10, c01, c00 = t11, t01, t10, t00
                else:
                    for i in range(m):
                        buf[6, i] = 1.0
                    c11, c10, c01, c00 = a, 0.0, 1.0 - a, 0.0
                nbad = _mixture_link(buf, m, nx, ny, th, s, lam, ls2, half_c, big_d1,
                                     c11, c10, c01, c00)
                part_s[b, c, j, 0] = _vsum(buf[4], m)
                part_s[b, c, j, 1] = _vsum(buf[5], m)
                if nbad > 0:                                # log domain
                    for i in range(m):
                        if buf[6, i] >= 0.0:
                            continue
                        dx = buf[0, i] - nx
                        dy = buf[1, i] - ny
                        e = th - math.sqrt(dx * dx + dy * dy)
                        z = e / s
                        if jp >= 0:
                            q = prev_q[b, i0 + i, jp]
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
                        buf[6, i] = math.exp(A1 - lse)
                        buf[7, i] += lse
                        part_l[b, c, j, 0] = _logaddexp(part_l[b, c, j, 0], A0 + ce)
                        part_l[b, c, j, 1] = _logaddexp(part_l[b, c, j, 1], A1 + ce)
                for i in range(m):
                    q_new[b, i0 + i, j] = buf[6, i]
            if em:
                for i in range(m):
                    qn = q_new[b, i0 + i, j]
                    dx = buf[0, i] - nx
                    dy = buf[1, i] - ny
                    e = th - math.sqrt(dx * dx + dy * dy)
                    em_pp[b, i0 + i, 0] += qn
                    em_pp[b, i0 + i, 1] += qn * e * e
                    em_pp[b, i0 + i, 2] += (1.0 - qn) * e
        if gauss:
            for i in range(m):
                log_w[b, i0 + i] = nvalid * cg + buf[7, i]
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
                if gauss:
                    pi1 = 1.0
                    pi0 = 0.0
                elif jp >= 0:
                    q = prev_q[b, i, jp]
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


@njit(cache=True)
def normalise_weights(log_w, particles, w, mean, cov, ess):
    """Normalised weights, weighted mean and covariance and ESS (Algorithm 2, line 14).

    Parameters
    ----------
    log_w : ndarray, shape (B, K)
        Log weights.
    particles : ndarray, shape (B, K, n)
        Particle states.
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
    for b in range(nb):
        m = -np.inf
        for i in range(nk):
            if log_w[b, i] > m:
                m = log_w[b, i]
        tot = 0.0
        for i in range(nk):
            v = math.exp(log_w[b, i] - m)
            w[b, i] = v
            tot += v
        inv = 1.0 / tot
        sq = 0.0
        for d in range(n):
            mean[b, d] = 0.0
        for i in range(nk):
            v = w[b, i] * inv
            w[b, i] = v
            sq += v * v
            for d in range(n):
                mean[b, d] += v * particles[b, i, d]
        ess[b] = 1.0 / sq
        for d in range(n):
            for g in range(n):
                cov[b, d, g] = 0.0
        for i in range(nk):
            v = w[b, i]
            for d in range(n):
                dd = particles[b, i, d] - mean[b, d]
                for g in range(d + 1):
                    cov[b, d, g] += v * dd * (particles[b, i, g] - mean[b, g])
        for d in range(n):
            for g in range(d):
                cov[b, g, d] = cov[b, d, g]


@njit(cache=True)
def systematic_indices(w, u, idx):
    """Systematic resampling: ancestor of new particle j is the first i with
    ``cumsum(w)_i > (u + j) / K``.

    Parameters
    ----------
    w : ndarray, shape (B, K)
        Normalised weights.
    u : ndarray, shape (B,)
        One uniform in [0, 1) per filter.
    idx : ndarray of int64, shape (B, K)
        Output: ancestor indices (non-decreasing).

    Returns
    -------
    None
        The result is written into ``idx``.
    """
    nb, nk = w.shape
    for b in range(nb):
        i = 0
        cdf = w[b, 0]
        for j in range(nk):
            pos = (u[b] + j) / nk
            while cdf <= pos and i < nk - 1:
                i += 1
                cdf += w[b, i]
            idx[b, j] = i


@njit(cache=True)
def gather_resampled(particles, q, idx, out_particles, out_q, distinct, mark):
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

    Returns
    -------
    None
        The results are written into the output arrays.
    """
    nb, nk, n = particles.shape
    nl = q.shape[2]
    for b in range(nb):
        for i in range(nk):
            mark[b, i] = False
        cnt = 0
        for i in range(nk):
            a = idx[b, i]
            if not mark[b, a]:
                mark[b, a] = True
                cnt += 1
            for d in range(n):
                out_particles[b, i, d] = particles[b, a, d]
            for j in range(nl):
                out_q[b, i, j] = q[b, a, j]
        distinct[b] = cnt
