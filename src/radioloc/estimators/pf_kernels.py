"""Compiled kernels of the peer-to-peer particle filter (one pass over the particles per task).

:func:`link_weights` is the particle-link update of
:meth:`radioloc.estimators.p2p_particle.P2PParticleFilter.step` (Algorithm 2, lines 6, 8
and 11); :func:`normalise_weights`, :func:`systematic_indices` and :func:`gather_resampled`
finish the step (weights, moments, line 12's resampling, the carried link posteriors).
The plain NumPy form of the same maths is ``P2PParticleFilter(kernel="numpy")``; the tests
compare the two on random inputs.

How the link update avoids logarithms. The link posterior carried per particle and link is
the LOS probability ``q = p(z = 1 | .)`` (one number, not two log values). For the new
range the prior is linear in ``q`` (``pi_1 = q P(1|1) + (1 - q) P(1|0)``), and both
likelihoods are evaluated relative to the constant ``c_e = log lam + (lam s)^2 / 2`` of the
exponentially modified Gaussian:

    E_0 = exp(l_0 - c_e) = exp(-lam e) Phi((e - lam s^2) / s)      (NLOS)
    E_1 = exp(l_1 - c_e) = exp(c_g - c_e - (e / s)^2 / 2)           (LOS)

so a particle-link update is a square root, two exponentials (an ``erfc`` only where
``|u| < 8.5``, i.e. the range error is within about 0.4 m of the LOS mode at s = 0.05 m,
and no ``E_0`` at all when the prior NLOS probability is exactly 0, e.g. alpha = 1), one
division for the new posterior ``q' = pi_1 E_1 / (pi_0 E_0 + pi_1 E_1)``, and a product
accumulated per particle whose logarithm is taken once per particle (renormalised before
it can under- or overflow). Where ``pi_0 E_0 + pi_1 E_1`` underflows (a particle metres
from a range) that link is evaluated in the log domain instead, so weights stay exact.

Parallelism: ``prange`` over (batch entry, chunk of particles) tasks, so one filter of
10^5 particles uses every core as well as 20 vehicles of 900. All arithmetic is float64:
at these sizes a vehicle's particles and link posteriors fit in the L2 cache and the
kernel is bound by the exponentials, not by memory, so float32 storage would not pay.
Measured on the paper 001 highway (alpha = 30 %, 2 shared cores): 75 % of the
particle-link updates take the no-``erfc`` branch, 23 % the ``erfc`` one, 1.5 % the
asymptotic ``log Phi``; about 30-35 ns per update, most of it in ``exp`` and ``erfc`` (libm,
scalar: this numba build has no SVML, so the loop is not vectorised).
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
from numba import njit, prange  # noqa: E402

from radioloc.models.los_nlos import log_ndtr_fast as _log_ndtr

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
_SQRT1_2 = math.sqrt(0.5)
_U_ONE = 8.5          # Phi(u) = 1 to 1e-17 above this
_U_ASYM = -20.0       # asymptotic series of log Phi below this
_TINY = 1e-150        # below: evaluate the link in the log domain
_LOW, _HIGH = 1e-150, 1e150  # renormalise the running product outside these
_SUM_OK = 1e-200      # a detection sum above this is resolved in the linear domain
_EXP_MIN = -746.0     # exp(x) == 0.0 in float64 below this


@njit(cache=True, inline="always")
def _logaddexp(a: float, b: float) -> float:
    if a == -np.inf:
        return b
    if b == -np.inf:
        return a
    if a > b:
        return a + math.log1p(math.exp(b - a))
    return b + math.log1p(math.exp(a - b))


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


@njit(cache=True, parallel=True)
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
        particle-links (terms below about 1e-308 are lost to underflow).
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
        # sticky chain: P[z_prev, z]
        t00, t01 = 1.0 - 0.5 * a, 0.5 * a
        t10, t11 = 0.5 * (1.0 - a), 0.5 * (1.0 + a)
        nvalid = 0
        for j in range(nl):
            part_s[b, c, j, 0] = 0.0
            part_s[b, c, j, 1] = 0.0
            part_l[b, c, j, 0] = -np.inf
            part_l[b, c, j, 1] = -np.inf
            if valid[b, j]:
                nvalid += 1
        i0 = c * chunk
        i1 = min(nk, i0 + chunk)
        for i in range(i0, i1):
            px = particles[b, i, 0]
            py = particles[b, i, 1]
            prod = 1.0
            logacc = 0.0
            sa = 0.0
            sb = 0.0
            sc = 0.0
            for j in range(nl):
                if not valid[b, j]:
                    q_new[b, i, j] = 0.0
                    continue
                dx = px - node_xy[b, j, 0]
                dy = py - node_xy[b, j, 1]
                e = theta[b, j] - math.sqrt(dx * dx + dy * dy)
                z = e / s
                jp = where_prev[b, j]
                if jp >= 0:
                    q = prev_q[b, i, jp]
                    pi1 = q * t11 + (1.0 - q) * t01
                    pi0 = q * t10 + (1.0 - q) * t00
                else:
                    pi1 = a
                    pi0 = 1.0 - a
                x1 = d1 - 0.5 * z * z
                a1 = pi1 * math.exp(x1) if x1 > _EXP_MIN else 0.0
                u = z - ls2
                if pi0 == 0.0:
                    a0 = 0.0
                elif u > _U_ONE:
                    a0 = pi0 * math.exp(-lam * e)
                elif u > _U_ASYM:
                    a0 = pi0 * math.exp(-lam * e) * 0.5 * math.erfc(-u * _SQRT1_2)
                else:
                    a0 = pi0 * math.exp(-lam * e + _log_ndtr(u))
                tot = a0 + a1
                if tot > _TINY:
                    qn = a1 / tot
                    if prod < _LOW or prod > _HIGH:     # keep prod * tot representable
                        logacc += math.log(prod)
                        prod = 1.0
                    prod *= tot
                    part_s[b, c, j, 0] += a0
                    part_s[b, c, j, 1] += a1
                else:                                   # log domain
                    l0 = -lam * e + _log_ndtr(u)        # minus c_e
                    l1 = d1 - 0.5 * z * z
                    A0 = l0 + math.log(pi0) if pi0 > 0.0 else -np.inf
                    A1 = l1 + math.log(pi1) if pi1 > 0.0 else -np.inf
                    lse = _logaddexp(A0, A1)
                    qn = math.exp(A1 - lse)
                    logacc += lse
                    part_l[b, c, j, 0] = _logaddexp(part_l[b, c, j, 0], A0 + ce)
                    part_l[b, c, j, 1] = _logaddexp(part_l[b, c, j, 1], A1 + ce)
                q_new[b, i, j] = qn
                if em:
                    sa += qn
                    sb += qn * e * e
                    sc += (1.0 - qn) * e
            log_w[b, i] = nvalid * ce + logacc + math.log(prod)
            if em:
                em_pp[b, i, 0] = sa
                em_pp[b, i, 1] = sb
                em_pp[b, i, 2] = sc
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
