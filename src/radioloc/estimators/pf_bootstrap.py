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
   pairs_block`: Philox4x32-10 and Box-Muller, one block per particle, draw ``2 (b K + i) +
   d`` of the step's key for coordinate ``d`` of particle ``i`` of filter ``b``: the draws
   of ``pf_random.standard_normal_numpy(shape=(B, K, 2))`` with the same key, bit for bit),
   the particle moved (read through the previous step's ancestors when they are carried:
   the previous step's gather done here) and its Gaussian range log-likelihood summed over
   the links (:func:`radioloc.estimators.pf_kernels._gauss_link`); then ``v = exp(log w -
   m_c)`` relative to the chunk's largest log-likelihood ``m_c`` and the chunk's sums for
   the total, the ESS, the mean and the covariance (relative to the filter's first particle
   moved without noise). The chunks' factors ``exp(m_c - max) / total`` make the weights;
2. systematic resampling (line 12): per ancestor chunk, where its part of the cumulative
   weight starts (from the chunk totals), the cumulative weights ``c_i`` (four quarters of
   the chunk at once), the number ``N_i`` of new positions ``(U + j) / K`` below each ``c_i``
   (an estimate corrected by the two positions either side, in a loop that vectorises; the
   new particles ``N_{i-1} .. N_i - 1`` descend from ``i``), ancestor ``i`` written at slot
   ``N_{i-1}`` and a running maximum filling the other slots, without a data-dependent
   branch; then, if asked, the gather of the resampled particles.

The plain NumPy form of the same maths is ``P2PParticleFilter(kernel="numpy")`` with the
same draws (:func:`radioloc.estimators.pf_random.standard_normal_numpy`); the tests compare
the two. All arithmetic is float64.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from radioloc.estimators.pf_kernels import _gauss_link, vexp
from radioloc.estimators.pf_random import pairs_block

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
def _count_below_div(cdf, u, nk, lo_n, hi_n):
    """:func:`_count_below` clipped to ``[lo_n, hi_n]``, as a float, without a branch: the
    estimate ``ceil(K cdf - u)`` (off by at most one through rounding) corrected by the two
    positions either side of it, each ``(u + j) / K`` as in ``resampling.systematic``; the
    ancestors' counts of a chunk in one loop without a dependence (it vectorises)."""
    j0 = np.ceil(cdf * nk - u)                  # a float (math.ceil's int would not vectorise)
    lo = (u + (j0 - 1.0)) / nk
    hi = (u + j0) / nk
    n = j0 - (1.0 if lo >= cdf else 0.0) + (1.0 if hi < cdf else 0.0)
    return min(max(n, lo_n), hi_n)


@njit(cache=True, inline="always", error_model="numpy")
def _raise_to(vr, a, b):
    """``vr[a:b] = max(vr[a:b], vr[a - 1])`` where ``vr[a:b]`` is non-decreasing: only a
    prefix can be below, so the loop stops at the first that is not."""
    fl = vr[a - 1]
    i = a
    while i < b and vr[i] < fl:
        vr[i] = fl
        i += 1


@njit(cache=True, inline="always", error_model="numpy")
def _mark_offspring_starts(vr, m, q, mk, i0, f0):
    """Ancestor marks of one chunk of the systematic resampling: ``mk[N_{i-1} - f0] = i0 + i``
    in order of ``i`` (the last write to a slot wins: the ancestor whose offspring start
    there), ``N_{i-1}`` the running maximum of the counts ``vr[:i]`` and of ``f0``.

    The counts rise within each quarter ``[0, q)``, ``[q, 2q)``, ``[2q, 3q)``, ``[3q, m)`` of
    the chunk (each a chain of adds of non-negative weights), but a quarter's cumulative
    weights start from its own sum, which can round below the previous quarter's last: the
    first counts of a quarter are raised to the previous one's last (in ``vr``, in place), so
    the running maximum is the previous count and the loop over the ancestors has no
    dependence from one to the next (a loop carrying the maximum took about three times as
    long).

    Parameters
    ----------
    vr : ndarray, shape (>= m,)
        Counts (floats, integers in ``[f0, f0 + len(mk) - 1]``), non-decreasing within each
        quarter; raised in place to their running maximum.
    m, q : int
        Ancestors of the chunk; quarter length (0: one run).
    mk : ndarray of int64
        Marks, slot 0 = new particle ``f0``.
    i0, f0 : int
        First ancestor and first new particle of the chunk.

    Returns
    -------
    None
    """
    if q > 0:
        _raise_to(vr, q, 2 * q)
        _raise_to(vr, 2 * q, 3 * q)
        _raise_to(vr, 3 * q, m)
    if m > 0:
        mk[0] = i0
    vp = vr[:max(m - 1, 0)]
    for i in range(m - 1):
        mk[int(vp[i]) - f0] = i0 + 1 + i


@njit(cache=True, error_model="numpy")
def _rises_below(vr, n, first, hi):
    """Number of ``i < n`` with ``vr[i] > vr[i - 1]`` (``vr[-1]`` read as ``first``) and
    ``vr[i] < hi`` (a loop without a dependence: it vectorises)."""
    cnt = 0
    if n <= 0:
        return 0
    cnt += (vr[0] > first) and (vr[0] < hi)
    cur = vr[1:n]
    prv = vr[0:n - 1]
    for i in range(n - 1):
        cnt += (cur[i] > prv[i]) and (cur[i] < hi)
    return cnt


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


@njit(cache=True, error_model="numpy", fastmath={"nnan", "nsz", "reassoc"})
def _row_max(row, m):
    """Largest of ``row[:m]`` (finite values: the flags let LLVM vectorise the reduction; the
    largest of finite numbers does not depend on the order)."""
    mx = -np.inf
    for i in range(m):
        mx = max(mx, row[i])
    return mx


@njit(cache=True, error_model="numpy", fastmath={"reassoc"})
def _row_sum(row, a, b):
    """``sum(row[a:b])``, reassociated so that it vectorises (the same value for the same
    ``row``, ``a``, ``b``: the chunks are fixed, so it does not depend on the threads)."""
    s = 0.0
    seg = row[a:b]
    for i in range(b - a):
        s += seg[i]
    return s


@njit(cache=True, parallel=True, error_model="numpy", fastmath={"contract"})
def bootstrap_step(particles, anc, carried, shift, sd, key, node_xy, theta, valid, inv_s, u,
                   chunk, gather, out_particles, idx, mean, cov, ess, distinct, pred, v):
    """Predict, weight, moments and systematic resampling of bootstrap filters, fused.

    Parameters
    ----------
    particles : ndarray, shape (B, K', 2)
        Particles of the previous step (positions): resampled (``carried`` false), or the
        previous step's predicted particles, resampled here through ``anc``.
    anc : ndarray of int64, shape (B, K)
        With ``carried``: the ancestors of the previous step (particle ``i`` is
        ``particles[b, anc[b, i]]``, the gather of the previous step done here); else unused.
    carried : bool
        Whether ``particles`` are read through ``anc``.
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
    gather : bool
        Whether to write the resampled particles into ``out_particles`` (else the caller
        carries ``pred`` and ``idx`` into the next step).
    out_particles : ndarray, shape (B, K, 2)
        Output (with ``gather``): resampled particles.
    idx : ndarray of int64, shape (B, K)
        Output: ancestor of each new particle (non-decreasing); not ``anc``.
    mean, cov, ess : ndarray, shapes (B, 2), (B, 2, 2), (B,)
        Output: weighted mean, covariance and ``1 / sum w^2`` of the predicted particles.
    distinct : ndarray of int64, shape (B,)
        Output: number of distinct ancestors.
    pred : ndarray, shape (B, K, 2)
        Output: the predicted particles (not ``particles``).
    v : ndarray, shape (B, K)
        Scratch: unnormalised weights, then cumulative weights, then offspring counts.

    Returns
    -------
    None
        The results are written into the output arrays.
    """
    nb, nk = idx.shape[0], idx.shape[1]
    nl = theta.shape[1]
    nc = max(1, -(-nk // chunk))
    k0, k1, c2, c3 = key[0], key[1], key[2], key[3]
    sx, sy = sd[0], sd[1]
    cmax = np.empty((nb, nc))
    sums = np.empty((nb, nc, 7))
    ref = np.empty((nb, 2))             # the filter's first particle moved without noise
    for b in range(nb):
        a0 = anc[b, 0] if carried else 0
        ref[b, 0] = particles[b, a0, 0] + shift[b, 0]
        ref[b, 1] = particles[b, a0, 1] + shift[b, 1]
    # pass 1: draw, move, Gaussian log-likelihood, weights relative to the chunk's largest,
    # the chunk's moment sums
    for task in prange(nb * nc):
        b = task // nc
        c = task - b * nc
        i0 = c * chunk
        i1 = min(nk, i0 + chunk)
        m = i1 - i0
        buf = np.empty((8, m))                  # rows 0, 1: x, y; row 7: log-likelihood
        pairs_block(buf, b * nk + i0, m, k0, k1, c2, c3)   # no contraction: the reference's draws
        ux = shift[b, 0]
        uy = shift[b, 1]
        # slices, so that the loops index from 0 (a loop over ``i0 + i`` does not vectorise:
        # LLVM cannot rule out a negative, wrapped-around index)
        pseg = pred[b, i0:i1]
        vseg = v[b, i0:i1]
        if carried:
            aseg = anc[b, i0:i1]
            src = particles[b]
            for i in range(m):
                a = aseg[i]
                x = (src[a, 0] + ux) + sx * buf[0, i]
                y = (src[a, 1] + uy) + sy * buf[1, i]
                buf[0, i] = x
                buf[1, i] = y
                pseg[i, 0] = x
                pseg[i, 1] = y
                buf[7, i] = 0.0
        else:
            src = particles[b, i0:i1]
            for i in range(m):
                x = (src[i, 0] + ux) + sx * buf[0, i]
                y = (src[i, 1] + uy) + sy * buf[1, i]
                buf[0, i] = x
                buf[1, i] = y
                pseg[i, 0] = x
                pseg[i, 1] = y
                buf[7, i] = 0.0
        for j in range(nl):
            if valid[b, j]:
                _gauss_link(buf, m, node_xy[b, j, 0], node_xy[b, j, 1], theta[b, j], inv_s[b])
        mx = _row_max(buf[7], m)
        for i in range(m):
            e = vexp(buf[7, i] - mx)
            buf[7, i] = e
            vseg[i] = e
        cmax[b, c] = mx
        _buf_moments(buf, m, ref[b, 0], ref[b, 1], sums[b, c])
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
        mean[b, 0] = ref[b, 0] + mdx
        mean[b, 1] = ref[b, 1] + mdy
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
    # pass 2: systematic resampling (and the gather), per ancestor chunk: the cumulative
    # weights c_i (one add per ancestor, in order), the counts N_i of positions below them
    # (a loop without a dependence between ancestors), then slot N_{i-1} of idx (in the
    # task's own range [first_c, first_{c+1})) gets the last ancestor i with that N_{i-1},
    # the one whose offspring start there, and a running maximum fills the rest.
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
        f = factor[b, c]
        m = i1 - i0
        nf = f1 - f0
        vr = v[b, i0:i1]                        # slices: loops from 0 (see pass 1)
        # cumulative weights in four quarters of the chunk at once (four independent chains
        # of adds instead of one), each from the start given by the sums of the ones before
        q = m // 4
        c0 = start[b, c]
        c1 = c0 + _row_sum(vr, 0, q) * f
        c2 = c1 + _row_sum(vr, q, 2 * q) * f
        c3 = c2 + _row_sum(vr, 2 * q, 3 * q) * f
        v0 = vr[0:q]
        v1 = vr[q:2 * q]
        v2 = vr[2 * q:3 * q]
        v3 = vr[3 * q:m]
        for i in range(q):
            c0 += v0[i] * f
            v0[i] = c0
            c1 += v1[i] * f
            v1[i] = c1
            c2 += v2[i] * f
            v2[i] = c2
            c3 += v3[i] * f
            v3[i] = c3
        for i in range(q, m - 3 * q):
            c3 += v3[i] * f
            v3[i] = c3
        lo_n = float(f0)
        hi_n = float(f1)
        for i in range(m):
            vr[i] = _count_below_div(vr[i], ub, nk, lo_n, hi_n)
        # slot N_{i-1} (relative to f0) of mk gets ancestor i: the last one written, the one
        # whose offspring start there; slot nf is a sink for the ancestors without offspring
        # at the chunk's end (no branch)
        mk = np.empty(nf + 1, dtype=np.int64)
        for j in range(nf + 1):
            mk[j] = -1
        _mark_offspring_starts(vr, m, q, mk, i0, f0)
        # a running maximum fills the slots between
        ir = idx[b, f0:f1]
        a = -1
        for j in range(nf):
            a = max(a, mk[j])
            ir[j] = a
        # each marked slot (below the sink) is a distinct ancestor: slot f0, and each rise of
        # the raised counts N_0 .. N_{m-2} below f1
        counts[b, c] = 1 + _rises_below(vr, m - 1, lo_n, hi_n)
        if gather:
            op = out_particles[b, f0:f1]
            pp = pred[b]
            for j in range(nf):
                a = ir[j]
                op[j, 0] = pp[a, 0]
                op[j, 1] = pp[a, 1]
    for b in range(nb):
        distinct[b] = counts[b].sum()
