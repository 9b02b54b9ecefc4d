"""Fused numba kernel of the particle-link update of the peer-to-peer particle filter.

The numpy form of :meth:`radioloc.estimators.p2p_particle.P2PParticleFilter.step` materialises
several ``(vehicles, particles, links, 2)`` temporaries per step; this kernel computes the
same quantities (LOS/NLOS log-likelihoods, the phi recursion of Algorithm 2, lines 6/8, and
the log-weights of line 11) in one pass with no temporaries. It is the inner loop the
batch axes are flattened into, so it is compiled rather than vectorised.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)
_SQRT1_2 = math.sqrt(0.5)


@njit(cache=True, inline="always")
def _log_ndtr(u: float) -> float:
    """``log Phi(u)``: erfc down to u = -20, the asymptotic series below (rel. err < 1e-10)."""
    if u > -20.0:
        return math.log(0.5 * math.erfc(-u * _SQRT1_2))
    r = 1.0 / (u * u)
    series = 1.0 - r * (1.0 - r * (3.0 - r * (15.0 - 105.0 * r)))
    return -0.5 * u * u - math.log(-u) - _HALF_LOG_2PI + math.log(series)


@njit(cache=True, inline="always")
def _logaddexp(a: float, b: float) -> float:
    if a == -np.inf:
        return b
    if b == -np.inf:
        return a
    if a > b:
        return a + math.log1p(math.exp(b - a))
    return b + math.log1p(math.exp(a - b))


@njit(cache=True, parallel=True)
def link_update(particles, node_xy, theta, valid, where_prev, prev, los_std, nlos_mean,
                log_trans, log_stat, log_phi, log_w):
    """Fill ``log_phi`` and ``log_w`` in place (Algorithm 2, lines 6, 8 and 11).

    Parameters
    ----------
    particles : ndarray, shape (B, K, 2)
        Particle positions.
    node_xy : ndarray, shape (B, L, 2)
        Positions of the linked nodes.
    theta : ndarray, shape (B, L)
        Measured ranges.
    valid : ndarray of bool, shape (B, L)
        Which link slots exist.
    where_prev : ndarray of int, shape (B, L)
        Slot of the link in ``prev``, or -1 if the node was not a neighbour at t-1.
    prev : ndarray, shape (B, K, L', 2)
        Normalised ``log phi_{t-1}``.
    los_std, nlos_mean : float
        ``s_LOS`` and ``s_NLOS`` of the range model.
    log_trans : ndarray, shape (2, 2)
        Log transition matrix of the link chain.
    log_stat : ndarray, shape (2,)
        Log stationary distribution of the link chain.
    log_phi : ndarray, shape (B, K, L, 2)
        Output: unnormalised ``log phi_t``.
    log_w : ndarray, shape (B, K)
        Output: log weights.

    Returns
    -------
    None
        The results are written into ``log_phi`` and ``log_w``.
    """
    nb, nk, nl = log_phi.shape[0], log_phi.shape[1], log_phi.shape[2]
    lam = 1.0 / nlos_mean
    c_emg = math.log(lam) + 0.5 * (lam * los_std) ** 2
    c_gauss = -math.log(los_std) - _HALF_LOG_2PI
    for b in prange(nb):
        for i in range(nk):
            acc = 0.0
            px = particles[b, i, 0]
            py = particles[b, i, 1]
            for j in range(nl):
                if not valid[b, j]:
                    log_phi[b, i, j, 0] = 0.0
                    log_phi[b, i, j, 1] = 0.0
                    continue
                dx = px - node_xy[b, j, 0]
                dy = py - node_xy[b, j, 1]
                e = theta[b, j] - math.sqrt(dx * dx + dy * dy)
                z = e / los_std
                l1 = c_gauss - 0.5 * z * z
                l0 = c_emg - lam * e + _log_ndtr((e - lam * los_std * los_std) / los_std)
                jp = where_prev[b, j]
                if jp >= 0:
                    q0 = prev[b, i, jp, 0]
                    q1 = prev[b, i, jp, 1]
                    p0 = _logaddexp(q0 + log_trans[0, 0], q1 + log_trans[1, 0])
                    p1 = _logaddexp(q0 + log_trans[0, 1], q1 + log_trans[1, 1])
                else:
                    p0 = log_stat[0]
                    p1 = log_stat[1]
                a0 = l0 + p0
                a1 = l1 + p1
                log_phi[b, i, j, 0] = a0
                log_phi[b, i, j, 1] = a1
                acc += _logaddexp(a0, a1)
            log_w[b, i] = acc


@njit(cache=True, parallel=True)
def finish_step(log_phi, valid, idx, post, out):
    """Link posteriors and resampled, normalised ``log phi`` in one pass.

    Parameters
    ----------
    log_phi : ndarray, shape (B, K, L, 2)
        Unnormalised ``log phi_t``.
    valid : ndarray of bool, shape (B, L)
        Which link slots exist.
    idx : ndarray of int, shape (B, K)
        Ancestor of each resampled particle.
    post : ndarray, shape (B, L, 2)
        Output: ``log sum_i phi^i`` (the detection statistic).
    out : ndarray, shape (B, K, L, 2)
        Output: ``log phi^{idx_i} - log sum_z phi^{idx_i}``.

    Returns
    -------
    None
        The results are written into ``post`` and ``out``.
    """
    nb, nk, nl = log_phi.shape[0], log_phi.shape[1], log_phi.shape[2]
    for b in prange(nb):
        for j in range(nl):
            for z in range(2):
                m = -np.inf
                for i in range(nk):
                    if log_phi[b, i, j, z] > m:
                        m = log_phi[b, i, j, z]
                acc = 0.0
                if m > -np.inf:
                    for i in range(nk):
                        acc += math.exp(log_phi[b, i, j, z] - m)
                    post[b, j, z] = m + math.log(acc)
                else:
                    post[b, j, z] = -np.inf
        for i in range(nk):
            a = idx[b, i]
            for j in range(nl):
                if valid[b, j]:
                    q0 = log_phi[b, a, j, 0]
                    q1 = log_phi[b, a, j, 1]
                    n = _logaddexp(q0, q1)
                    out[b, i, j, 0] = q0 - n
                    out[b, i, j, 1] = q1 - n
                else:
                    out[b, i, j, 0] = 0.0
                    out[b, i, j, 1] = 0.0
