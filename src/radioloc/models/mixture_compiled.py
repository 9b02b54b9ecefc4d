"""Compiled kernels of the Gaussian-mixture family (paper 004).

Kernels, each the compiled form of a NumPy definition (the reference, selected by
``backend="numpy"``):

- :func:`reduce_batch`: West's greedy reduction with Runnalls' cost of every mixture of a
  batch, :func:`radioloc.models.mixture.reduce` (NumPy: ``mixture._reduce_numpy``);
- :func:`product_batch`: eq. (2) per measurement row, the station models conditioned on
  their readings, multiplied and reduced after each factor,
  :meth:`radioloc.estimators.mixture_localization.MixtureLocalizer.density_and_mask`
  (NumPy: the composition of ``DiagMixture.condition``, ``product`` and ``reduce``);
- :func:`pb_inner`, :func:`pb_cross_gradient`, :func:`pb_gram`: the overlaps, gradients and
  Gram matrix of each step of the Progressive Bayes homotopy,
  :func:`radioloc.models.progressive_bayes.progressive_reduce` (NumPy: ``inner``,
  ``cross_gradient``, ``gram`` of that module).

The rules (lowest weight, Runnalls' cost without cancellation, the tie tolerance and the
order-free tie rule) are documented with the NumPy definitions; the kernels follow them step
by step. The kernels call only functions of this module.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

#: relative tie tolerance (``radioloc.models.mixture._TIE``)
TIE = 1e-9
_LOG2PI = math.log(2.0 * math.pi)


@njit(cache=True)
def _key_less(w, m, v, a, b):  # pragma: no cover - compiled
    """Canonical order of components ``a``, ``b`` (columns of ``m, v (D, K)``): means, then
    variances, then the weight, lexicographically."""
    for e in range(m.shape[0]):
        if m[e, a] != m[e, b]:
            return m[e, a] < m[e, b]
    for e in range(v.shape[0]):
        if v[e, a] != v[e, b]:
            return v[e, a] < v[e, b]
    return w[a] < w[b]


@njit(cache=True)
def _pick(w, m, v, n, flag):  # pragma: no cover - compiled
    """The tie rule: of the flagged components ``c < n``, the nearest to the mixture mean;
    of two at the same distance (D >= 2), the one the other follows counter-clockwise;
    otherwise the lowest in the canonical order."""
    d = m.shape[0]
    mu = np.zeros(d)
    tot = 0.0
    for c in range(n):
        tot += w[c]
        for e in range(d):
            mu[e] += w[c] * m[e, c]
    mu /= tot
    r = np.full(n, np.inf)
    for c in range(n):
        if flag[c]:
            r[c] = 0.0
            for e in range(d):
                r[c] += (m[e, c] - mu[e]) ** 2
    lim = r.min() * (1.0 + TIE)
    a, b, n2 = -1, -1, 0
    for c in range(n):
        if r[c] <= lim:
            n2 += 1
            if a < 0:
                a = c
            elif b < 0:
                b = c
    if n2 == 2 and d >= 2:
        cross = (m[0, a] - mu[0]) * (m[1, b] - mu[1]) - (m[1, a] - mu[1]) * (m[0, b] - mu[0])
        if abs(cross) > TIE * lim:
            return a if cross > 0 else b
    j = -1
    for c in range(n):
        if r[c] <= lim and (j < 0 or _key_less(w, m, v, c, j)):
            j = c
    return j


@njit(cache=True, error_model="numpy")
def _partner(w, m, v, iv, ld, n, i, s):  # pragma: no cover - compiled
    """Runnalls' cost of merging ``i`` into the other components ``c < n`` (columns of
    ``m, v, iv = 1 / v (D, K)``, ``ld``: log-determinants) and the partner chosen (lowest
    cost, ties by :func:`_pick`); returns ``(j, cost, scale)``. ``s (7, K)``: scratch.

    Pass 1 (loops over the candidates) computes ``y`` (``1 + y = |P_ic| / |P_c|``) and a
    logarithm-free lower bound of each cost: ``log1p(y) = 2 atanh(z)``, ``z = y / (y + 2)``,
    bounded below by its series' first three terms for ``z >= 0`` and with the tail bounded
    by ``0.46 |z|^7`` for ``-0.61 <= z < 0`` (below: no bound), less ``1e-14`` of the cost's
    terms for rounding. Pass 2 takes the exact cost of the lowest bound first, then of every
    candidate whose bound does not exclude it from the tie set (``scale <= |cost| + B``);
    the others cannot be chosen, so the result is that of costing every candidate."""
    a1, a12, y, ay, lb, cost, scale = s[0], s[1], s[2], s[3], s[4], s[5], s[6]
    wi, ldi = w[i], ld[i]
    for c in range(n):
        inv = 1.0 / (wi + w[c])
        a1[c] = wi * inv
        a12[c] = a1[c] * (w[c] * inv)
        y[c] = 0.0
        ay[c] = 0.0
    for e in range(m.shape[0]):
        mie, vie = m[e, i], v[e, i]
        for c in range(n):
            r = (a1[c] * (vie - v[e, c]) + a12[c] * (mie - m[e, c]) ** 2) * iv[e, c]
            y[c] = y[c] + r + y[c] * r
            ay[c] = ay[c] + abs(r) + ay[c] * abs(r)
    for c in range(n):
        ws = wi + w[c]
        scale[c] = wi * (abs(ld[c]) + abs(ldi)) + ws * ay[c]
        z = y[c] / (y[c] + 2.0)
        small = abs(z) <= 1e-100                      # no subnormal powers
        z2 = 0.0 if small else z * z
        zn = 0.0 if small else min(z, 0.0)
        lx = 2.0 * z * (1.0 + z2 * (1.0 / 3.0 + 0.2 * z2)) + 0.46 * zn * z2 * z2 * z2
        b = 0.5 * (wi * (ld[c] - ldi) + ws * lx) - 1e-14 * (wi * (abs(ld[c]) + abs(ldi))
                                                            + ws * abs(lx))
        lb[c] = b if z >= -0.61 else -np.inf
        cost[c] = np.inf
    lb[i] = np.inf
    c0 = 0
    for c in range(1, n):
        c0 = c if lb[c] < lb[c0] else c0
    best = np.inf
    for step in range(n + 1):
        c = c0 if step == 0 else step - 1
        if step > 0 and (c == c0 or c == i or (lb[c] > 0.0 and lb[c] * (1.0 - 2.0 * TIE)
                                               > best + TIE * (2.0 * abs(best) + 4.0 * scale[c]))):
            continue
        ws = wi + w[c]
        lp = math.log1p(y[c])
        cost[c] = 0.5 * (wi * (ld[c] - ldi) + ws * lp)
        scale[c] = 0.5 * (scale[c] + ws * abs(lp))
        best = min(best, cost[c])
    j, count = -1, 0
    flag = lb                                         # the tie set (pass 1's bounds are spent)
    for c in range(n):
        flag[c] = cost[c] <= best + 2.0 * TIE * scale[c]
        if flag[c]:
            j, count = c, count + 1
    if count > 1:
        j = _pick(w, m, v, n, flag)
    return j, cost[j], scale[j]


@njit(cache=True, error_model="numpy")
def _set(tw, tm, tv, iv, ld, c, w, m, v):  # pragma: no cover - compiled
    """Column ``c`` of the scratch: weight, mean, variances, their inverses and
    ``log|P| = sum(log v)``."""
    tw[c] = w
    ld[c] = 0.0
    for e in range(tm.shape[0]):
        tm[e, c], tv[e, c], iv[e, c] = m[e], v[e], 1.0 / v[e]
        ld[c] += math.log(v[e])


@njit(cache=True, error_model="numpy")
def _reduce_one(w, m, v, kmax, ow, om, ov):  # pragma: no cover - compiled
    """West/Runnalls reduction of one mixture ``w (K,), m, v (K, D)`` to ``kmax``
    components into ``ow, om, ov`` (canonical order: decreasing weight, then
    :func:`_key_less`); returns the component count."""
    k, d = m.shape
    tw, ld, tm, tv, iv = np.empty(k), np.empty(k), np.empty((d, k)), np.empty((d, k)), \
        np.empty((d, k))
    n = 0
    for c in range(k):                                # the components of positive weight
        if w[c] > 0:
            _set(tw, tm, tv, iv, ld, n, w[c], m[c], v[c])
            n += 1
    s = np.empty((7, k))
    ic, isc, ij, tied = np.empty(k), np.empty(k), np.empty(k, np.int64), np.empty(k)
    mm, vv = np.empty(d), np.empty(d)
    while n > kmax:
        i, wmin, w2 = 0, np.inf, np.inf               # the lowest weight and the second
        for c in range(n):
            if tw[c] < wmin:
                i, wmin, w2 = c, tw[c], wmin
            else:
                w2 = min(w2, tw[c])
        if w2 * (1.0 - TIE) > wmin:
            j = _partner(tw, tm, tv, iv, ld, n, i, s)[0]
        else:                                         # the tied one with the cheapest merge
            for c in range(n):
                tied[c] = tw[c] * (1.0 - TIE) <= wmin
                ic[c], isc[c] = np.inf, 0.0
                if tied[c]:
                    ij[c], ic[c], isc[c] = _partner(tw, tm, tv, iv, ld, n, c, s)
            bi = ic[:n].min()
            for c in range(n):
                tied[c] = ic[c] <= bi + 2.0 * TIE * isc[c]
            i = _pick(tw, tm, tv, n, tied)
            j = ij[i]
        ws = tw[i] + tw[j]                            # moment-matched merge of i into j
        a1, a2 = tw[i] / ws, tw[j] / ws
        for e in range(d):
            mm[e] = a1 * tm[e, i] + a2 * tm[e, j]
            vv[e] = a1 * (tv[e, i] + (tm[e, i] - mm[e]) ** 2) \
                + a2 * (tv[e, j] + (tm[e, j] - mm[e]) ** 2)
        _set(tw, tm, tv, iv, ld, j, ws, mm, vv)
        n -= 1                                        # the last column replaces i
        tw[i], ld[i] = tw[n], ld[n]
        for e in range(d):
            tm[e, i], tv[e, i], iv[e, i] = tm[e, n], tv[e, n], iv[e, n]
    order = np.empty(n, np.int64)                     # insertion sort into canonical order
    for r in range(n):
        pos = r
        while pos > 0:
            p = order[pos - 1]
            if tw[p] > tw[r] or (tw[p] == tw[r] and not _key_less(tw, tm, tv, r, p)):
                break
            order[pos] = p
            pos -= 1
        order[pos] = r
    for r in range(n):
        ow[r] = tw[order[r]]
        for e in range(d):
            om[r, e], ov[r, e] = tm[e, order[r]], tv[e, order[r]]
    return n


@njit(cache=True, parallel=True)
def reduce_batch(w, m, v, kmax):  # pragma: no cover - compiled
    """:func:`_reduce_one` of every mixture of ``w (B, K)``, ``m, v (B, K, D)``; returns
    ``(weights (B, kout), means, variances, counts (B,))``, ``kout = min(kmax, K)``, unused
    slots at weight 0, mean 0, variance 1."""
    nb, k, d = m.shape
    kout = min(kmax, k)
    ow, om, ov = np.zeros((nb, kout)), np.zeros((nb, kout, d)), np.ones((nb, kout, d))
    cnt = np.zeros(nb, np.int64)
    for b in prange(nb):
        cnt[b] = _reduce_one(w[b], m[b], v[b], kmax, ow[b], om[b], ov[b])
    return ow, om, ov, cnt


@njit(cache=True)
def _exp_normalise(x):  # pragma: no cover - compiled
    """Weights from log weights (False when all are -inf: the mass is lost)."""
    top = x.max()
    if not np.isfinite(top):
        return False
    for c in range(x.size):
        x[c] = math.exp(x[c] - top)
    x /= x.sum()
    return True


@njit(cache=True, parallel=True)
def product_batch(w, mu, var, rss, order, kmax):  # pragma: no cover - compiled
    """Eq. (2) per row: each station model ``w (B, S, K)``, ``mu, var (B, S, K, D + 1)``
    conditioned on its reading ``rss (B, S)`` (NaN: not received, the marginal), reduced to
    ``kmax``, multiplied into the running product (stations in the row's ``order``; the
    stations not received enter only when none is) and reduced. Returns
    ``(weights (B, kmax), means, variances, ok (B,))``; ``ok`` False where all mass is lost."""
    nb, ns, k, d1 = mu.shape
    d = d1 - 1
    ow, om, ov = np.zeros((nb, kmax)), np.zeros((nb, kmax, d)), np.ones((nb, kmax, d))
    ok = np.ones(nb, np.bool_)
    for b in prange(nb):
        pw, pm, pv = np.empty(kmax), np.empty((kmax, d)), np.empty((kmax, d))
        qw, qm, qv = np.empty(kmax), np.empty((kmax, d)), np.empty((kmax, d))
        xw, xm, xv = np.empty(kmax * kmax), np.empty((kmax * kmax, d)), np.empty((kmax * kmax, d))
        cw, lq = np.empty(k), np.empty(kmax)
        pn, have = -1, False
        for si in range(ns):
            s = order[b, si]
            got = np.isfinite(rss[b, s])
            if pn >= 0 and not got:
                continue
            for c in range(k):                        # condition on the reading
                cw[c] = math.log(w[b, s, c]) if w[b, s, c] > 0 else -np.inf
                if got:
                    vc = var[b, s, c, d]
                    cw[c] -= 0.5 * ((rss[b, s] - mu[b, s, c, d]) ** 2 / vc + math.log(vc)
                                    + _LOG2PI)
            if not _exp_normalise(cw):
                ok[b] = False
                break
            qn = _reduce_one(cw, mu[b, s, :, :d], var[b, s, :, :d], kmax, qw, qm, qv)
            if pn < 0 or not have:
                pn, have = qn, got
                pw[:qn], pm[:qn], pv[:qn] = qw[:qn], qm[:qn], qv[:qn]
                continue
            for j in range(qn):
                lq[j] = math.log(qw[j])
            r = 0
            for i in range(pn):                       # the product, pairs (i, j) i-major
                lp = math.log(pw[i])
                for j in range(qn):
                    xw[r] = lp + lq[j]
                    for e in range(d):
                        sv = pv[i, e] + qv[j, e]
                        xv[r, e] = pv[i, e] * qv[j, e] / sv
                        xm[r, e] = (pm[i, e] * qv[j, e] + qm[j, e] * pv[i, e]) / sv
                        xw[r] -= 0.5 * ((pm[i, e] - qm[j, e]) ** 2 / sv + math.log(sv) + _LOG2PI)
                    r += 1
            if not _exp_normalise(xw[:r]):
                ok[b] = False
                break
            pn = _reduce_one(xw[:r], xm[:r], xv[:r], kmax, pw, pm, pv)
        if ok[b]:
            ow[b, :pn], om[b, :pn], ov[b, :pn] = pw[:pn], pm[:pn], pv[:pn]
    return ow, om, ov, ok


# --- Progressive Bayes re-approximation (radioloc.models.progressive_bayes) --------------
# The compiled forms of ``inner``, ``cross_gradient`` and ``gram`` on flat batches (leading
# axis B, every mixture of the batch its own partners), the per-step system of the homotopy.


@njit(cache=True)
def _hermite(delta, s, order, h):  # pragma: no cover - compiled
    """``h[n] = (d^n phi / d delta^n) / phi``, ``phi = N(delta; 0, s)``, ``n = 0..order``:
    ``h_{n+1} = -(delta / s) h_n - (n / s) h_{n-1}`` (``progressive_bayes._pair``)."""
    h[0] = 1.0
    h[1] = -delta / s
    for n in range(1, order):
        h[n + 1] = h[1] * h[n] - n / s * h[n - 1]


@njit(cache=True)
def _log_overlap(m1, v1, m2, v2):  # pragma: no cover - compiled
    """``log N(m1; m2, V1 + V2)`` of two axis-aligned components."""
    lo = 0.0
    for e in range(m1.size):
        s = v1[e] + v2[e]
        lo += (m1[e] - m2[e]) ** 2 / s + math.log(s) + _LOG2PI
    return -0.5 * lo


@njit(cache=True)
def pb_inner(aw, am, av, bw, bm, bv):  # pragma: no cover - compiled
    """``int f_a f_b dx`` per mixture: ``aw (B, Ka)``, ``am, av (B, Ka, D)``, likewise b."""
    out = np.zeros(aw.shape[0])
    for b in range(aw.shape[0]):
        for i in range(aw.shape[1]):
            for j in range(bw.shape[1]):
                out[b] += aw[b, i] * bw[b, j] * math.exp(
                    _log_overlap(am[b, i], av[b, i], bm[b, j], bv[b, j]))
    return out


@njit(cache=True)
def pb_cross_gradient(w, m, v, tw, tm, tv):  # pragma: no cover - compiled
    """``d/dtheta int f g dx`` ``(B, K, 1 + 2 D)`` per mixture: the weight, the means and the
    log-variances of each component of ``f``; ``g`` is ``tw, tm, tv``."""
    nb, k, d = m.shape
    out = np.zeros((nb, k, 1 + 2 * d))
    h = np.empty(3)
    for b in range(nb):
        for i in range(k):
            for j in range(tw.shape[1]):
                o = tw[b, j] * math.exp(_log_overlap(m[b, i], v[b, i], tm[b, j], tv[b, j]))
                out[b, i, 0] += o
                for e in range(d):
                    _hermite(m[b, i, e] - tm[b, j, e], v[b, i, e] + tv[b, j, e], 2, h)
                    out[b, i, 1 + e] += o * w[b, i] * h[1]
                    out[b, i, 1 + d + e] += o * 0.5 * w[b, i] * v[b, i, e] * h[2]
    return out


@njit(cache=True)
def pb_gram(w, m, v):  # pragma: no cover - compiled
    """``P = int (df/dtheta)(df/dtheta)^T dx`` ``(B, K Q, K Q)``, ``Q = 1 + 2 D``, per mixture
    (component-major: per component the weight, the means, the log-variances)."""
    nb, k, d = m.shape
    q = 1 + 2 * d
    order = np.zeros((q, d), np.int64)             # derivative order per parameter and axis
    for e in range(d):
        order[1 + e, e] = 1
        order[1 + d + e, e] = 2
    out = np.empty((nb, k * q, k * q))
    h = np.empty((d, 5))
    ca, cb = np.empty(q), np.empty(q)
    for b in range(nb):
        for i in range(k):
            for j in range(k):
                o = math.exp(_log_overlap(m[b, i], v[b, i], m[b, j], v[b, j]))
                ca[0], cb[0] = 1.0, 1.0
                for e in range(d):
                    _hermite(m[b, i, e] - m[b, j, e], v[b, i, e] + v[b, j, e], 4, h[e])
                    ca[1 + e], cb[1 + e] = w[b, i], -w[b, j]
                    ca[1 + d + e] = 0.5 * w[b, i] * v[b, i, e]
                    cb[1 + d + e] = 0.5 * w[b, j] * v[b, j, e]
                for a in range(q):
                    for c in range(q):
                        hh = 1.0
                        for e in range(d):
                            hh *= h[e, order[a, e] + order[c, e]]
                        out[b, i * q + a, j * q + c] = o * ca[a] * cb[c] * hh
    return out
