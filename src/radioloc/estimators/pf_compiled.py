"""Compiled kernels of the particle filters: paper 001's peer-to-peer filter
(``P2PParticleFilter(backend="numba")``), the generic filter
(``ParticleFilter(backend="numba")``) and paper 001's snapshot baselines.

Each kernel computes what a NumPy function of :mod:`radioloc.estimators.p2p_particle`,
:mod:`radioloc.estimators.particle_filter`, :mod:`radioloc.models.ranging`,
:mod:`radioloc.estimators.resampling` or :mod:`radioloc.estimators.snapshot_baselines`
defines; the backend-equivalence tests hold the two together (about 1e-10 relative on the
same particles and draws). The draws are NumPy's
numbers: made by NumPy before the kernels run, or, for large normal draws, by numba's
``Generator`` from child generators that the NumPy definition draws from in the same way.

* :func:`link_update`: the particle-link update of Algorithm 2, lines 6, 8 and 11
  (``p2p_particle._link_update_numpy``), in the linear domain relative to
  the larger of the two state terms, with the particle-pooled link posterior accumulated per
  chunk of particles;
* :func:`range_loglik`: the Gaussian range likelihood of every particle, summed over the
  rows (``RangeModel.logpdf`` with ``GaussianRange`` noise), for the generic filter;
* :func:`moment_sums`: the weighted sums of the particles around one of them
  (``particle_filter.weighted_moments``);
* :func:`systematic_gather`: systematic resampling (``resampling.systematic``) and the
  gather of the particles and link posteriors (or, for the generic filter, of nothing
  but the particles);
* :func:`standard_normal`: normal draws in parallel, each part from its own generator (a
  child of the filter's, or a run's own: ``particle_filter.standard_normal``);
* :func:`snapshot_scores`: the candidate scores of the paper's snapshot baselines
  (:class:`~radioloc.estimators.snapshot_baselines.LocalML` and ``Ransac``, Sect. V), with
  :func:`mixture_logpdf_scalar`, the scalar form of
  :meth:`~radioloc.models.los_nlos.LosNlosRange.logpdf`; it shares :func:`_log_ndtr` with
  :func:`link_update`.

``prange`` runs over (filter, chunk of particles) tasks, so one filter of 10^5 particles
uses every core as well as twenty filters of 900. A step with less work than
``SERIAL_WORK`` runs them on the calling thread (:func:`threads_for`): waking and
parking the other threads at every step of a small filter costs more processor time than
the work (the kernels give the same numbers on any number of threads).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from typing import Iterator

import numba
import numpy as np
from numba import njit, prange

#: Particle-link evaluations of a step below which its kernels run on one thread.
SERIAL_WORK = 1 << 18


@contextmanager
def threads_for(work: int) -> Iterator[None]:
    """Run the kernels called inside on one thread when ``work`` is below ``SERIAL_WORK``.

    Parameters
    ----------
    work : int
        Particle-link evaluations (or particles) of the step.
    """
    if work >= SERIAL_WORK or numba.get_num_threads() == 1:
        yield
        return
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        yield
    finally:
        numba.set_num_threads(before)

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
_SQRT1_2 = math.sqrt(0.5)


@njit(cache=True)
def _log_ndtr(u):
    """``log Phi(u)``: 0 at or above 8.5 (``Phi(-8.5) < 1e-17``), ``erfc`` down to -20, the
    asymptotic series below (as ``scipy.special.log_ndtr``)."""
    if u >= 8.5:
        return 0.0
    if u > -20.0:
        return math.log(0.5 * math.erfc(-u * _SQRT1_2))
    r = 1.0 / (u * u)
    series = 1.0 - r * (1.0 - r * (3.0 - r * (15.0 - 105.0 * r)))
    return -0.5 * u * u - math.log(-u) - _HALF_LOG_2PI + math.log(series)


@njit(cache=True)
def _exp(x):
    """``exp(x)``; 0 at or below -745.2, where ``exp`` rounds to 0, without the C library's
    slow underflow path."""
    return math.exp(x) if x > -745.2 else 0.0


@njit(cache=True, parallel=True)
def link_update(parts, node_xy, th, valid, where_prev, prev_q, params, pool, chunk, em,
                log_w, q_new, pmax, psum, em_pp, uncertain):
    """Algorithm 2, lines 6, 8 and 11, for filters ``b`` of particles ``parts (B, K, n)``.

    Link ``l`` of filter ``b`` (``valid[b, l]``) is node ``node_xy[b, l]`` at measured range
    ``th[b, l]``; its LOS prior is the sticky chain's step from the carried posterior
    ``prev_q[b, i, where_prev[b, l]]`` (``where_prev < 0``: a new link, the stationary
    ``alpha``). With ``phi_z = pi_z exp(l_z)`` (``l_1`` Gaussian, ``l_0`` the EMG of
    ``params[b] = (s_LOS, s_NLOS, alpha)``) it writes ``log_w[b, i] = sum_l log(phi_0 +
    phi_1)``, ``q_new[b, i, l] = phi_1 / (phi_0 + phi_1)`` (0 on padding), the pooled
    ``sum_i phi_z`` of chunk ``c`` as ``exp(pmax[b, c, l]) psum[b, c, l, z]`` and, when
    ``em``, ``em_pp[b, i] = sum_l (q', q' e^2, (1 - q') e)``. The pooled sums are left
    alone where ``pool[b, l]`` is False (a link whose LOS prior is 1 for every particle);
    ``uncertain[b, c, l]``: some new posterior of the chunk is not exactly 1. Where both
    states are possible and ``u = z - lam s > -20``, the NLOS term relative to the LOS one
    is ``exp(x) Phi(u)`` (``x = l_0 - l_1 - log Phi(u)`` within +-200 and the LOS prior
    above 1e-50, so that a particle's running product of totals, logged once it leaves
    ``[1e-200, 1e200]``, stays finite and nonzero), without the logarithm of ``Phi``.
    """
    nb, k = parts.shape[0], parts.shape[1]
    width = th.shape[1]
    nch = pmax.shape[1]
    for task in prange(nb * nch):
        b = task // nch
        c = task - b * nch
        s, a = params[b, 0], params[b, 2]
        inv_s, lam = 1.0 / s, 1.0 / params[b, 1]
        c1 = -math.log(s) - _HALF_LOG_2PI
        c0 = math.log(lam) + 0.5 * (lam * s) ** 2
        m_run = np.full(width, -np.inf)
        s0 = np.zeros(width)
        s1 = np.zeros(width)
        unsure = np.zeros(width, dtype=np.bool_)
        for i in range(c * chunk, min(k, (c + 1) * chunk)):
            # log w = sum_l (m + log tot): the m summed, the tot multiplied (the product
            # moved into the sum before it can underflow)
            lw, prod, e0, e1, e2 = 0.0, 1.0, 0.0, 0.0, 0.0
            for l in range(width):
                if not valid[b, l]:
                    q_new[b, i, l] = 0.0
                    continue
                j = where_prev[b, l]
                if j >= 0:
                    q = prev_q[b, i, j]
                    p1 = q * (1.0 + a) * 0.5 + (1.0 - q) * a * 0.5
                    p0 = q * (1.0 - a) * 0.5 + (1.0 - q) * (1.0 - a * 0.5)
                else:
                    p1, p0 = a, 1.0 - a
                dx = parts[b, i, 0] - node_xy[b, l, 0]
                dy = parts[b, i, 1] - node_xy[b, l, 1]
                e = th[b, l] - math.sqrt(dx * dx + dy * dy)
                z = e * inv_s
                l1 = c1 - 0.5 * z * z
                u = z - lam * s
                # l_0 - l_1 - log Phi(u): where it and u are moderate, phi_z / exp(l_1)
                # takes exp(l_0 - l_1) = exp(x) Phi(u) without the logarithm of Phi
                x = c0 - c1 - lam * e + 0.5 * z * z
                if p0 > 0.0 and p1 > 1e-50 and u > -20.0 and x < 200.0 and x > -200.0:
                    m, f1, f0 = l1, p1, p0 * math.exp(x) * 0.5 * math.erfc(-u * _SQRT1_2)
                else:
                    l0 = -np.inf
                    if p0 > 0.0:
                        l0 = c0 - lam * e + _log_ndtr(u)
                    # phi_z / exp(m) with m the larger of the two state terms
                    if p0 > 0.0 and (p1 == 0.0 or l0 > l1):
                        m, f0, f1 = l0, p0, p1 * _exp(l1 - l0)
                    else:
                        m, f1 = l1, p1
                        f0 = p0 * _exp(l0 - l1) if p0 > 0.0 else 0.0
                tot = f0 + f1
                lw += m
                prod *= tot
                if prod < 1e-200 or prod > 1e200:
                    lw += math.log(prod)
                    prod = 1.0
                if f0 == 0.0:
                    qn = 1.0
                elif f1 == 0.0:
                    qn = 0.0
                else:
                    qn = f1 / tot
                q_new[b, i, l] = qn
                if qn != 1.0:
                    unsure[l] = True
                # the pooled sums of the chunk, relative to their running maximum
                if pool[b, l]:
                    if m > m_run[l]:
                        r = _exp(m_run[l] - m)
                        s0[l] = s0[l] * r + f0
                        s1[l] = s1[l] * r + f1
                        m_run[l] = m
                    else:
                        r = _exp(m - m_run[l])
                        s0[l] += f0 * r
                        s1[l] += f1 * r
                if em:
                    e0 += qn
                    e1 += qn * e * e
                    e2 += (1.0 - qn) * e
            log_w[b, i] = lw + math.log(prod)
            if em:
                em_pp[b, i, 0] = e0
                em_pp[b, i, 1] = e1
                em_pp[b, i, 2] = e2
        for l in range(width):
            pmax[b, c, l] = m_run[l]
            psum[b, c, l, 0] = s0[l]
            psum[b, c, l, 1] = s1[l]
            uncertain[b, c, l] = unsure[l]


@njit(cache=True, parallel=True)
def range_loglik(x, pos, dim, points, dz2, z, inv_std, log_std, chunk, out):
    """The Gaussian range likelihood of every particle (``ParticleFilter(backend="numba")``;
    the NumPy definition is :meth:`RangeModel.logpdf <radioloc.models.ranging.RangeModel.logpdf>`
    with :class:`~radioloc.models.ranging.GaussianRange` noise and no anchor bias, summed
    over the rows).

    ``out[b, i] = sum_j -r^2 / 2 - log_std[b, j] - log(2 pi) / 2`` with ``r = (z[b, j] - d)
    inv_std[b, j]`` and ``d`` the distance from the position ``x[b, i, pos:pos + dim]``
    (``dim`` 2 or 3) to ``points[b, j, :dim]`` (plus ``dz2[b, j]``, the squared height
    difference, under the root); a row whose residual is NaN (no measurement) adds nothing.
    Each task takes ``chunk`` particles row by row, so that the loop over the particles
    vectorises.
    """
    nb, k = out.shape
    m = z.shape[1]
    nch = (k + chunk - 1) // chunk
    for task in prange(nb * nch):
        b = task // nch
        c = task - b * nch
        lo, hi = c * chunk, min(k, (c + 1) * chunk)
        acc = np.zeros(hi - lo)
        h = np.empty(hi - lo)
        for j in range(m):
            p0, p1, hj = points[b, j, 0], points[b, j, 1], dz2[b, j]
            if dim == 2:
                for i in range(lo, hi):
                    d0 = x[b, i, pos] - p0
                    d1 = x[b, i, pos + 1] - p1
                    h[i - lo] = math.sqrt(d0 * d0 + d1 * d1 + hj)
            else:
                p2 = points[b, j, 2]
                for i in range(lo, hi):
                    d0 = x[b, i, pos] - p0
                    d1 = x[b, i, pos + 1] - p1
                    d2 = x[b, i, pos + 2] - p2
                    h[i - lo] = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2 + hj)
            zj, sj, cj = z[b, j], inv_std[b, j], log_std[b, j] + _HALF_LOG_2PI
            for i in range(lo, hi):
                r = (zj - h[i - lo]) * sj
                acc[i - lo] += -0.5 * r * r - cj if r == r else 0.0
        for i in range(lo, hi):
            out[b, i] = acc[i - lo]


@njit(cache=True, parallel=True)
def moment_sums(w, parts, chunk, sums):
    """Per chunk ``c`` of the particles ``parts (B, K, n)`` with weights ``w (B, K)``, the sums
    ``sums[b, c] = (sum w, sum w^2, sum w d, sum w d d^T)`` with ``d = x_i - x_0`` (the
    deviation from the filter's first particle, which keeps the second moments free of
    cancellation), ``n`` and ``n * n`` numbers for the last two."""
    nb, k, n = parts.shape
    nch = sums.shape[1]
    for task in prange(nb * nch):
        b = task // nch
        c = task - b * nch
        acc = np.zeros(sums.shape[2])
        for i in range(c * chunk, min(k, (c + 1) * chunk)):
            wi = w[b, i]
            acc[0] += wi
            acc[1] += wi * wi
            for p in range(n):
                dp = parts[b, i, p] - parts[b, 0, p]
                acc[2 + p] += wi * dp
                for r in range(n):
                    acc[2 + n + p * n + r] += wi * dp * (parts[b, i, r] - parts[b, 0, r])
        sums[b, c] = acc


@njit(cache=True, parallel=True)
def systematic_gather(w, u, parts, q, chunk, idx, out_p, out_q, distinct):
    """Systematic resampling (``resampling.systematic``) of the normalised weights ``w (B, K)``
    with offsets ``u (B,)`` and the gather of the particles ``parts`` and link posteriors
    ``q``: particle ``i`` fills the new slots ``[N_{i-1}, N_i)``, ``N_i = ceil(K C_i - u)``
    (clipped to ``[0, K]``; ``N_{K-1} = K``) the number of positions ``(u + j) / K`` below its
    cumulative weight ``C_i`` (the sequential sum). The ancestor of slot ``j`` is the number
    of particles ``i`` with ``N_i <= j`` (a prefix sum of the counts of each ``N_i``, without
    a branch per copy). ``distinct[b, c]``: the particles of chunk ``c`` with at least one
    copy."""
    nb, k = w.shape
    nch = distinct.shape[1]
    for b in prange(nb):
        marks = np.zeros(k + 1, dtype=np.int64)
        t = 0.0
        before = 0
        for c in range(nch):
            count = 0
            for i in range(c * chunk, min(k, (c + 1) * chunk)):
                t += w[b, i]
                stop = min(k, max(0, math.ceil(k * t - u[b])))
                stop = k if i == k - 1 else stop
                marks[stop] += 1
                count += stop > before
                before = stop
            distinct[b, c] = count
        acc = 0
        for j in range(k):
            acc += marks[j]
            idx[b, j] = acc
    for task in prange(nb * nch):
        b = task // nch
        c = task - b * nch
        for j in range(c * chunk, min(k, (c + 1) * chunk)):
            i = idx[b, j]
            for p in range(parts.shape[2]):
                out_p[b, j, p] = parts[b, i, p]
            for p in range(q.shape[2]):
                out_q[b, j, p] = q[b, i, p]


@njit(cache=True, parallel=True)
def standard_normal(gens, out):
    """``out`` filled with standard normal draws: part ``s`` (``ceil(size / len(gens))``
    numbers, contiguous) by generator ``gens[s]`` (numba's ``Generator``: NumPy's numbers)."""
    size = out.shape[0]
    per = (size + len(gens) - 1) // len(gens)
    for s in prange(len(gens)):
        g = gens[s]
        for i in range(s * per, min(size, (s + 1) * per)):
            out[i] = g.standard_normal()


@njit(cache=True)
def mixture_logpdf_scalar(e, inv_std, lam, lam_std, c_los, c_nlos, k_tail):
    """``log(alpha N(e; s) + (1 - alpha) EMG(e; s, mu))`` of one range error, for compiled
    code (the constants from :meth:`LosNlosRange.mixture_constants`; the NumPy definition is
    :meth:`LosNlosRange.logpdf`).

    With ``l_1 = c_los - z^2 / 2`` (``z = e / s``, ``c_los = log alpha - log s - log(2 pi)/2``)
    and ``l_0 = c_nlos - lam e + log Phi(u)`` (``u = z - lam s``, ``c_nlos = log(1 - alpha)
    + log lam + (lam s)^2 / 2``) the result is ``l_1 + log1p(exp(l_0 - l_1))`` where

    * ``u >= 8.5``: ``log Phi(u) = 0`` to 1e-17 (no ``erfc``; no ``exp`` once
      ``l_1 - l_0 < -746``);
    * ``-20 < u < 8.5``: ``exp(l_0 - l_1) = exp(c_nlos - c_los - lam e + z^2 / 2) Phi(u)``;
    * ``u <= -20``: the asymptotic series of ``Phi`` makes the Gaussian tails cancel:
      ``exp(l_0 - l_1) = k_tail series(u) / (-u)``, ``k_tail = exp(c_nlos - c_los -
      (lam s)^2 / 2 - log(2 pi) / 2)``.

    Parameters
    ----------
    e : float
        Range error ``theta - d``, metres.
    inv_std, lam, lam_std, c_los, c_nlos, k_tail : float
        ``1 / s``, ``lam``, ``lam s`` and the three constants above.

    Returns
    -------
    float
        The mixture log-density.
    """
    z = e * inv_std
    l1 = c_los - 0.5 * z * z
    if c_nlos == -np.inf:
        return l1
    u = z - lam_std
    if c_los == -np.inf or k_tail <= 0.0 or (u < 8.5 and u > -20.0 and (c_nlos - c_los) - lam * e + 0.5 * z * z > 700.0):
        # alpha = 0, or so small that exp(l_0 - l_1) would overflow: plain log-sum
        l0 = c_nlos - lam * e
        if u < 8.5:
            l0 += _log_ndtr(u)
        if c_los == -np.inf:
            return l0
        if l0 > l1:
            return l0 + math.log1p(math.exp(l1 - l0))
        return l1 + math.log1p(math.exp(l0 - l1))
    if u >= 8.5:
        l0 = c_nlos - lam * e
        if l1 > l0:
            return l1 + math.log1p(math.exp(l0 - l1))
        d = l1 - l0
        return l0 + math.log1p(math.exp(d)) if d > -746.0 else l0
    if u > -20.0:
        x = (c_nlos - c_los) - lam * e + 0.5 * z * z
        return l1 + math.log1p(math.exp(x) * 0.5 * math.erfc(-u * _SQRT1_2))
    r = 1.0 / (u * u)
    series = 1.0 - r * (1.0 - r * (3.0 - r * (15.0 - 105.0 * r)))
    return l1 + math.log1p(k_tail * series / (-u))


@njit(cache=True, error_model="numpy")
def snapshot_scores(kind, cand, cen, th, valid, c0, c1, c2, c3, c4, c5, out):  # pragma: no cover
    """Scores of candidates ``cand (B, C, 2)`` against the links ``cen (B, L, 2)``,
    ``th (B, L)``, ``valid (B, L)`` into ``out (B, C)``: residuals ``e = th - ||x - cen||``, then ``kind`` 0: ``sum_m log p(e_m)``
    of the LOS/NLOS mixture (constants ``c0..c5`` of ``LosNlosRange.mixture_constants``);
    1: the RANSAC consensus ``n_in - sum_in e^2 / (n_in c0 + 1)`` with inliers
    ``|e| < c1`` (``c0 = c1^2``)."""
    nb, nc = cand.shape[0], cand.shape[1]
    nl = th.shape[1]
    for b in range(nb):
        for k in range(nc):
            x = cand[b, k, 0]
            y = cand[b, k, 1]
            n_in = 0
            acc = 0.0
            for j in range(nl):
                if not valid[b, j]:
                    continue
                dx = x - cen[b, j, 0]
                dy = y - cen[b, j, 1]
                e = th[b, j] - math.sqrt(dx * dx + dy * dy)
                if kind == 0:
                    acc += mixture_logpdf_scalar(e, c0, c1, c2, c3, c4, c5)
                elif abs(e) < c1:
                    acc += e * e
                    n_in += 1
            out[b, k] = acc if kind == 0 else n_in - acc / (n_in * c0 + 1.0)
