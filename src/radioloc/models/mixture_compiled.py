"""Compiled kernels of the Gaussian-mixture family (paper 004).

Two kernels, each the compiled form of a NumPy definition (the reference, selected by
``backend="numpy"``):

- :func:`reduce_batch`: West's greedy reduction with Runnalls' cost of every mixture of a
  batch, :func:`radioloc.models.mixture.reduce` (NumPy: ``mixture._reduce_numpy``);
- :func:`product_batch`: eq. (2) per measurement row, the station models conditioned on
  their readings, multiplied and reduced after each factor,
  :meth:`radioloc.estimators.mixture_localization.MixtureLocalizer.density_and_mask`
  (NumPy: the composition of ``DiagMixture.condition``, ``product`` and ``reduce``).

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
    """Canonical order: means, then variances, then the weight, lexicographically."""
    for e in range(m.shape[1]):
        if m[a, e] != m[b, e]:
            return m[a, e] < m[b, e]
    for e in range(v.shape[1]):
        if v[a, e] != v[b, e]:
            return v[a, e] < v[b, e]
    return w[a] < w[b]


@njit(cache=True)
def _pick(w, m, v, n, flag):  # pragma: no cover - compiled
    """The tie rule: of the flagged components ``c < n``, the nearest to the mixture mean;
    of two at the same distance (D >= 2), the one the other follows counter-clockwise;
    otherwise the lowest in the canonical order."""
    first, count = -1, 0
    for c in range(n):
        if flag[c]:
            count += 1
            first = c if first < 0 else first
    if count < 2:
        return first
    d = m.shape[1]
    mu = np.zeros(d)
    tot = 0.0
    for c in range(n):
        tot += w[c]
        mu += w[c] * m[c]
    mu /= tot
    r = np.full(n, np.inf)
    for c in range(n):
        if flag[c]:
            r[c] = np.sum((m[c] - mu) ** 2)
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
        cross = (m[a, 0] - mu[0]) * (m[b, 1] - mu[1]) - (m[a, 1] - mu[1]) * (m[b, 0] - mu[0])
        if abs(cross) > TIE * lim:
            return a if cross > 0 else b
    j = -1
    for c in range(n):
        if r[c] <= lim and (j < 0 or _key_less(w, m, v, c, j)):
            j = c
    return j


@njit(cache=True, error_model="numpy")
def _partner(w, m, v, iv, ld, n, i, cost, scale, flag, lb):  # pragma: no cover - compiled
    """Runnalls' cost of merging ``i`` into the other components ``c < n`` and the partner
    chosen (lowest cost, ties by :func:`_pick`); returns ``(j, cost, scale)`` (``iv = 1 /
    v``, ``ld``: the log-determinants; ``cost, scale, flag, lb``: scratch).

    Pass 1 computes ``y`` (``1 + y = |P_ic| / |P_c|``) and a logarithm-free lower bound of
    each cost: ``log1p(y) = 2 atanh(z)``, ``z = y / (y + 2)``, bounded below by its series'
    first three terms for ``z >= 0`` and with the tail bounded by ``0.46 |z|^7`` for
    ``-0.61 <= z < 0`` (below: no bound), less ``1e-14`` of the cost's terms for rounding.
    Pass 2 takes the exact cost of the lowest bound first, then of every candidate whose
    bound does not exclude it from the tie set (``scale <= |cost| + B``); the others cannot
    be chosen, so the result is that of costing every candidate."""
    d = m.shape[1]
    wi, ldi = w[i], ld[i]
    c0 = 0
    for c in range(n):
        ws = wi + w[c]
        inv = 1.0 / ws
        a1 = wi * inv
        a12 = a1 * (w[c] * inv)
        y, ay = 0.0, 0.0
        for e in range(d):
            dm = m[i, e] - m[c, e]
            r = (a1 * (v[i, e] - v[c, e]) + a12 * dm * dm) * iv[c, e]
            y, ay = y + r + y * r, ay + abs(r) + ay * abs(r)
        cost[c] = y
        scale[c] = wi * (abs(ld[c]) + abs(ldi)) + ws * ay
        z = y / (y + 2.0)
        z2 = z * z if abs(z) > 1e-100 else 0.0        # no subnormal powers
        zn = min(z, 0.0) if abs(z) > 1e-100 else 0.0
        lx = 2.0 * z * (1.0 + z2 * (1.0 / 3.0 + 0.2 * z2)) + 0.46 * zn * z2 * z2 * z2
        lb[c] = 0.5 * (wi * (ld[c] - ldi) + ws * lx) \
            - 1e-14 * (wi * (abs(ld[c]) + abs(ldi)) + ws * abs(lx))
        lb[c] = lb[c] if z >= -0.61 else -np.inf
        lb[c] = np.inf if c == i else lb[c]
        c0 = c if lb[c] < lb[c0] else c0
        flag[c] = False
    best = np.inf
    for step in range(n + 1):
        c = c0 if step == 0 else step - 1
        if step > 0 and (c == c0 or c == i or (lb[c] > 0.0 and lb[c] * (1.0 - 2.0 * TIE)
                                               > best + TIE * (2.0 * abs(best) + 4.0 * scale[c]))):
            continue
        ws = wi + w[c]
        lp = math.log1p(cost[c])
        cost[c] = 0.5 * (wi * (ld[c] - ldi) + ws * lp)
        scale[c] = 0.5 * (scale[c] + ws * abs(lp))
        flag[c] = True
        best = min(best, cost[c])
    j, count = -1, 0
    for c in range(n):
        flag[c] = flag[c] and cost[c] <= best + 2.0 * TIE * scale[c]
        if flag[c]:
            j, count = c, count + 1
    if count > 1:
        j = _pick(w, m, v, n, flag)
    return j, cost[j], scale[j]


@njit(cache=True, error_model="numpy")
def _set(tw, tm, tv, iv, ld, c, w, m, v):  # pragma: no cover - compiled
    """Component ``c`` of the scratch: weight, mean, variances, their inverses and
    ``log|P| = sum(log v)``."""
    tw[c] = w
    ld[c] = 0.0
    for e in range(tm.shape[1]):
        tm[c, e], tv[c, e], iv[c, e] = m[e], v[e], 1.0 / v[e]
        ld[c] += math.log(v[e])


@njit(cache=True, error_model="numpy")
def _reduce_one(w, m, v, kmax, ow, om, ov):  # pragma: no cover - compiled
    """West/Runnalls reduction of one mixture ``w (K,), m, v (K, D)`` to ``kmax``
    components into ``ow, om, ov`` (canonical order: decreasing weight, then
    :func:`_key_less`); returns the component count."""
    k, d = m.shape
    tw, tm, tv, iv, ld = np.empty(k), np.empty((k, d)), np.empty((k, d)), np.empty((k, d)), \
        np.empty(k)
    n = 0
    for c in range(k):                                # the components of positive weight
        if w[c] > 0:
            _set(tw, tm, tv, iv, ld, n, w[c], m[c], v[c])
            n += 1
    cost, scale, flag, lb = np.empty(k), np.empty(k), np.empty(k, np.bool_), np.empty(k)
    ic, isc, ij, tied = np.empty(k), np.empty(k), np.empty(k, np.int64), np.empty(k, np.bool_)
    mm, vv = np.empty(d), np.empty(d)
    while n > kmax:
        wmin = tw[:n].min()
        i, count = -1, 0
        for c in range(n):
            tied[c] = tw[c] * (1.0 - TIE) <= wmin
            if tied[c]:
                i, count = c, count + 1
        if count == 1:
            j = _partner(tw, tm, tv, iv, ld, n, i, cost, scale, flag, lb)[0]
        else:                                         # the tied one with the cheapest merge
            for c in range(n):
                ic[c], isc[c] = np.inf, 0.0
                if tied[c]:
                    ij[c], ic[c], isc[c] = _partner(tw, tm, tv, iv, ld, n, c, cost, scale, flag, lb)
            bi = ic[:n].min()
            for c in range(n):
                flag[c] = ic[c] <= bi + 2.0 * TIE * isc[c]
            i = _pick(tw, tm, tv, n, flag)
            j = ij[i]
        ws = tw[i] + tw[j]                            # moment-matched merge of i into j
        a1, a2 = tw[i] / ws, tw[j] / ws
        for e in range(d):
            mm[e] = a1 * tm[i, e] + a2 * tm[j, e]
            vv[e] = a1 * (tv[i, e] + (tm[i, e] - mm[e]) ** 2) \
                + a2 * (tv[j, e] + (tm[j, e] - mm[e]) ** 2)
        _set(tw, tm, tv, iv, ld, j, ws, mm, vv)
        n -= 1
        _set(tw, tm, tv, iv, ld, i, tw[n], tm[n], tv[n])
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
            om[r, e], ov[r, e] = tm[order[r], e], tv[order[r], e]
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
    x[:] = np.exp(x - top)
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
        cw = np.empty(k)
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
            r = 0
            for i in range(pn):                       # the product, pairs (i, j) i-major
                for j in range(qn):
                    sv = pv[i] + qv[j]
                    xv[r] = pv[i] * qv[j] / sv
                    xm[r] = (pm[i] * qv[j] + qm[j] * pv[i]) / sv
                    xw[r] = math.log(pw[i]) + math.log(qw[j]) - 0.5 * np.sum(
                        (pm[i] - qm[j]) ** 2 / sv + np.log(sv) + _LOG2PI)
                    r += 1
            if not _exp_normalise(xw[:r]):
                ok[b] = False
                break
            pn = _reduce_one(xw[:r], xm[:r], xv[:r], kmax, pw, pm, pv)
        if ok[b]:
            ow[b, :pn], om[b, :pn], ov[b, :pn] = pw[:pn], pm[:pn], pv[:pn]
    return ow, om, ov, ok
