"""Fused compiled step of the bootstrap case of the particle filter.

:func:`bootstrap_step` is :meth:`radioloc.estimators.p2p_particle.P2PParticleFilter.step`
for the filters whose range model is Gaussian (LOS fraction alpha = 1 and every carried LOS
posterior 1: the "Gaussian case" of :func:`radioloc.estimators.pf_kernels.link_weights`)
under a motion model ``x' = x + u + diag(sd) z`` (random walk, or the input-driven model;
2-D position states) with systematic resampling: the plain range-only bootstrap particle
filter. Two parallel passes over (filter, chunk of particles) tasks touch each particle
instead of the seven of the general path (draws, motion, link weights, weights and
moments, resampling indices, gather):

1. the motion noise ``z`` is drawn in the pass (:func:`radioloc.estimators.pf_random.
   pairs_into`: Philox4x32-10 and Box-Muller, one block per particle, draw ``2 (b K + i) +
   d`` of the step's key for coordinate ``d`` of particle ``i`` of filter ``b``: the draws
   of ``pf_random.standard_normal(shape=(B, K, 2))`` with the same key), the particle moved
   and its Gaussian range log-likelihood summed over the links
   (:func:`radioloc.estimators.pf_kernels._gauss_link`); then ``v = exp(log w - m_c)``
   relative to the chunk's largest log-likelihood ``m_c`` and the chunk's sums for the
   total, the ESS, the mean and the covariance (relative to the filter's first particle
   moved without noise). The chunks' factors ``exp(m_c - max) / total`` make the weights;
2. systematic resampling (line 12) and the gather: per ancestor chunk, where its part of the
   cumulative weight starts (from the chunk totals), the number ``N_i`` of new positions
   ``(U + j) / K`` below each cumulative weight ``c_i`` (the new particles ``N_{i-1} ..
   N_i - 1`` descend from ``i``; ancestor ``i`` is written at slot ``N_{i-1}`` and a
   running maximum fills the other slots, without a data-dependent branch), then the copy
   of the ancestors.

The plain NumPy form of the same maths is ``P2PParticleFilter(kernel="numpy")`` with the
same draws (:func:`radioloc.estimators.pf_random.standard_normal_numpy`); the tests compare
the two. All arithmetic is float64.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from radioloc.estimators.pf_kernels import _gauss_link, vexp
from radioloc.estimators.pf_random import pairs_into

__all__ = ["bootstrap_step"]


@njit(cache=True, inline="always", error_model="numpy")
def _count_below(cdf, u, nk):
    """Number of ``j >= 0`` with ``(u + j) / K < cdf`` (not clipped above)."""
    j = int(math.ceil(cdf * nk - u))
    j = max(j, 0)
    while j > 0 and (u + j - 1) / nk >= cdf:
        j -= 1
    while (u + j) / nk < cdf:
        j += 1
    return j


@njit(cache=True, inline="always", error_model="numpy")
def _count_below_table(cdf, u, nk, pos, f0, f1):
    """:func:`_count_below` for a ``cdf`` at or above the position ``(u + f0 - 1) / K``,
    clipped above at ``f1``, with the positions ``pos[j] = (u + j) / K`` of ``j`` in ``[f0,
    f1)`` read from a table: the estimate ``ceil(K cdf - u)`` (off by at most one through
    rounding) corrected by two comparisons, without a branch."""
    j0 = int(math.ceil(cdf * nk - u))
    lo = pos[min(max(j0 - 1, f0), f1 - 1)]
    hi = pos[min(max(j0, f0), f1 - 1)]
    down = (j0 - 1 >= f0) & (lo >= cdf)
    up = (j0 >= f0) & (j0 < f1) & (hi < cdf)
    return min(j0 - np.int64(down) + np.int64(up), f1)


@njit(cache=True, error_model="numpy", fastmath={"reassoc", "contract"})
def _buf_moments(buf, m, rx, ry, sums):
    """``sums = (sum v, sum v^2, sum v dx, sum v dy, sum v dx^2, sum v dy dx, sum v dy^2)``
    over the ``m`` particles of a chunk (rows 0, 1 of ``buf`` the position, row 7 ``v``),
    ``dx``, ``dy`` relative to ``(rx, ry)`` (so that the covariance does not lose the digits
    of a large position). Sums reassociated, so that they vectorise (the chunks are fixed:
    the result does not depend on the threads); a function of its own because ``vexp`` must
    not be reassociated (its rounding to an integer, ``(x + 1.5 2^52) - 1.5 2^52``, would
    fold away)."""
    s0 = 0.0
    sq = 0.0
    sx = 0.0
    sy = 0.0
    sxx = 0.0
    syx = 0.0
    syy = 0.0
    for i in range(m):
        w = buf[7, i]
        dx = buf[0, i] - rx
        dy = buf[1, i] - ry
        s0 += w
        sq += w * w
        sx += w * dx
        sy += w * dy
        sxx += w * dx * dx
        syx += w * dy * dx
        syy += w * dy * dy
    sums[0] = s0
    sums[1] = sq
    sums[2] = sx
    sums[3] = sy
    sums[4] = sxx
    sums[5] = syx
    sums[6] = syy


@njit(cache=True, parallel=True, error_model="numpy", fastmath={"contract"})
def bootstrap_step(particles, shift, sd, key, node_xy, theta, valid, inv_s, u, chunk,
                   out_particles, idx, mean, cov, ess, distinct, pred, v):
    """Predict, weight, moments and systematic resampling of bootstrap filters, fused.

    Parameters
    ----------
    particles : ndarray, shape (B, K, 2)
        Particles of the previous step (positions).
    shift : ndarray, shape (B, 2)
        Deterministic displacement ``u`` of the step per filter (the control; zeros
        without).
    sd : ndarray, shape (2,)
        Noise standard deviation per coordinate.
    key : ndarray of uint64, shape (4,)
        The step's draw key (:func:`radioloc.estimators.pf_random.draw_key`).
    node_xy : ndarray, shape (B, L, 2)
        Positions of the linked nodes.
    theta : ndarray, shape (B, L)
        Measured ranges.
    valid : ndarray of bool, shape (B, L)
        Which link slots exist.
    inv_s : ndarray, shape (B,)
        ``1 / s`` of each filter's Gaussian range noise.
    u : ndarray, shape (B,)
        Uniform in [0, 1) of the systematic resampling per filter.
    chunk : int
        Particles per parallel task.
    out_particles : ndarray, shape (B, K, 2)
        Output: resampled particles.
    idx : ndarray of int64, shape (B, K)
        Output: ancestor of each new particle (non-decreasing).
    mean, cov, ess : ndarray, shapes (B, 2), (B, 2, 2), (B,)
        Output: weighted mean, covariance and ``1 / sum w^2`` of the predicted particles.
    distinct : ndarray of int64, shape (B,)
        Output: number of distinct ancestors.
    pred : ndarray, shape (B, K, 2)
        Scratch: the predicted particles.
    v : ndarray, shape (B, K)
        Scratch: log-likelihoods, then unnormalised weights.

    Returns
    -------
    None
        The results are written into the output arrays.
    """
    nb, nk = particles.shape[0], particles.shape[1]
    nl = theta.shape[1]
    nc = max(1, -(-nk // chunk))
    k0, k1, c2, c3 = key[0], key[1], key[2], key[3]
    sx, sy = sd[0], sd[1]
    cmax = np.empty((nb, nc))
    sums = np.empty((nb, nc, 7))
    # pass 1: draw, move, Gaussian log-likelihood, weights relative to the chunk's largest,
    # the chunk's moment sums
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        i0 = c * chunk
        i1 = min(nk, i0 + chunk)
        m = i1 - i0
        buf = np.empty((8, m))                  # rows 0, 1: x, y; row 7: log-likelihood
        pairs_into(buf, b * nk + i0, m, k0, k1, c2, c3)
        ux = shift[b, 0]
        uy = shift[b, 1]
        for i in range(m):
            buf[0, i] = (particles[b, i0 + i, 0] + ux) + sx * buf[0, i]
            buf[1, i] = (particles[b, i0 + i, 1] + uy) + sy * buf[1, i]
            buf[7, i] = 0.0
        for j in range(nl):
            if valid[b, j]:
                _gauss_link(buf, m, node_xy[b, j, 0], node_xy[b, j, 1], theta[b, j], inv_s[b])
        mx = -np.inf
        for i in range(m):
            mx = max(mx, buf[7, i])
        for i in range(m):
            buf[7, i] = vexp(buf[7, i] - mx)
        cmax[b, c] = mx
        for i in range(m):
            pred[b, i0 + i, 0] = buf[0, i]
            pred[b, i0 + i, 1] = buf[1, i]
            v[b, i0 + i] = buf[7, i]
        # relative to the filter's first particle moved without noise (known to every task)
        _buf_moments(buf, m, particles[b, 0, 0] + ux, particles[b, 0, 1] + uy, sums[b, c])
    # moments; the weight factor of each chunk; where each ancestor chunk's part of the
    # cumulative weight starts; the first new particle of each chunk
    start = np.empty((nb, nc + 1))
    first = np.empty((nb, nc + 1), dtype=np.int64)
    factor = np.empty((nb, nc))
    for b in range(nb):
        mx = cmax[b, 0]
        for c in range(1, nc):
            mx = max(mx, cmax[b, c])
        tot = np.zeros(7)
        for c in range(nc):
            e = math.exp(cmax[b, c] - mx)       # chunk c's weights are v e
            factor[b, c] = e
            tot[0] += sums[b, c, 0] * e
            tot[1] += sums[b, c, 1] * (e * e)
            for t in range(2, 7):
                tot[t] += sums[b, c, t] * e
        inv = 1.0 / tot[0]
        ess[b] = tot[0] * tot[0] / tot[1]
        mdx = tot[2] * inv
        mdy = tot[3] * inv
        mean[b, 0] = (particles[b, 0, 0] + shift[b, 0]) + mdx
        mean[b, 1] = (particles[b, 0, 1] + shift[b, 1]) + mdy
        cov[b, 0, 0] = tot[4] * inv - mdx * mdx
        cxy = tot[5] * inv - mdy * mdx
        cov[b, 0, 1] = cxy
        cov[b, 1, 0] = cxy
        cov[b, 1, 1] = tot[6] * inv - mdy * mdy
        for c in range(nc):
            factor[b, c] *= inv                 # normalised weight = v factor
        start[b, 0] = 0.0
        for c in range(nc):
            start[b, c + 1] = start[b, c] + sums[b, c, 0] * factor[b, c]
        first[b, 0] = 0
        for c in range(1, nc):
            first[b, c] = min(_count_below(start[b, c], u[b], nk), nk)
        first[b, nc] = nk
        for c in range(1, nc):                  # monotone whatever the rounding
            first[b, c] = max(first[b, c], first[b, c - 1])
    # pass 3: systematic resampling and the gather, per ancestor chunk. Slot s of idx (in
    # the task's own range [first_c, first_{c+1})) first gets the last ancestor i with
    # N_{i-1} = s, the one whose offspring start at s; a running maximum fills the rest.
    counts = np.zeros((nb, nc), dtype=np.int64)
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        i0 = c * chunk
        i1 = min(nk, i0 + chunk)
        f0 = first[b, c]
        f1 = first[b, c + 1]
        if f1 <= f0:
            continue
        ub = u[b]
        # the positions (u + j) / K, j in [f0, f1), in the task's own part of out_particles
        # (entry f0 + j of the filter's flat rows; the gather overwrites them)
        pos = out_particles[b].reshape(2 * nk)[f0:]
        jf = float(f0)
        for j in range(f0, f1):
            pos[j] = (ub + jf) / nk
            jf += 1.0
            idx[b, j] = -1
        f = factor[b, c]
        cdf = start[b, c]
        prev = f0
        cnt = 0
        for i in range(i0, i1 - 1):
            cdf += v[b, i] * f
            n_i = max(_count_below_table(cdf, ub, nk, pos, f0, f1), prev)
            if prev < f1:                       # false only for empty ancestors at the end
                idx[b, prev] = i
            cnt += n_i > prev
            prev = n_i
        if prev < f1:                           # the last ancestor takes the rest
            idx[b, prev] = i1 - 1
            cnt += 1
        counts[b, c] = cnt
        a = -1
        for j in range(f0, f1):
            a = max(a, idx[b, j])
            idx[b, j] = a
            out_particles[b, j, 0] = pred[b, a, 0]
            out_particles[b, j, 1] = pred[b, a, 1]
    for b in range(nb):
        distinct[b] = counts[b].sum()
