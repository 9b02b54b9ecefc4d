"""Compiled kernels of the grid Bayes filter (``GridFilter(backend="numba")``, paper 003).

Each kernel computes what a NumPy definition of :mod:`radioloc.estimators.grid` computes,
in plain ``njit``/``prange`` loops over a batch of grids ``(B, h, w)``; every run uses its
own arguments only and every sum runs in a fixed order, so a run's result does not depend on
the rest of the batch. They serve the grid-step budget (one step at least 20x the NumPy
update + ``scipy.ndimage.gaussian_filter`` pipeline, ``benchmarks/bench_grid.py``).

* :func:`yvv_transposed` - one axis of the recursive Gaussian (``_yvv_axis``: Young & van
  Vliet's causal then anti-causal third-order recursions through a zero border), written
  transposed; applied twice it blurs both axes and restores the layout.
* :func:`trapezoid_update` - Algorithm 1 with the trapezoid likelihood computed in the loop
  (``probability_update`` with a ``TrapezoidModel``), the prior read through the floor of
  ``floor_normalise``: ``max(prior_i L_i, eps)`` and its row sums (the caller divides).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

__all__ = ["yvv_transposed", "trapezoid_update", "CHUNK"]

CHUNK = 64
"""Lines (columns of the source) recursed together by one job of :func:`yvv_transposed`."""


@njit(parallel=True, cache=True)
def yvv_transposed(src, coef, tails, eps, limit, dst, excess, bad):
    """The recursions along axis 1 of ``src`` ``(B, n, m)`` into ``dst`` ``(B, m, n)``
    (``dst[b, j, i]`` is line ``j`` at ``i``). Job ``q`` of run ``b`` recurses ``CHUNK``
    lines; ``excess[b, q]`` receives ``sum (v - eps)_+`` of the values it stored and
    ``bad[b, q]`` the number of its source cells outside ``[0, limit]`` (NaN included).
    ``coef[b] = (g, a1, a2, a3)``, ``tails[b]`` zero cells past the far border."""
    B, n, m = src.shape
    nq = (m + CHUNK - 1) // CHUNK
    for job in prange(B * nq):
        b = job // nq
        q = job - b * nq
        c0 = q * CHUNK
        nc = min(m, c0 + CHUNK) - c0
        g, a1, a2, a3 = coef[b, 0], coef[b, 1], coef[b, 2], coef[b, 3]
        t = n + tails[b]
        # w_i, then v_i, of the job's lines at row i + 3 (three zero rows either side)
        buf = np.empty((t + 6, nc))
        buf[:3] = 0.0
        buf[t + 3:] = 0.0
        nbad = 0
        for i in range(t):                            # causal (zeros past the border)
            x = src[b, min(i, n - 1), c0:c0 + nc]
            gx = g if i < n else 0.0
            y0, y1, y2, y3 = buf[i + 3], buf[i + 2], buf[i + 1], buf[i]
            for j in range(nc):
                y0[j] = a1 * y1[j] + (a2 * y2[j] + (a3 * y3[j] + gx * x[j]))
            if i < n:
                for j in range(nc):
                    nbad += 0 if (x[j] >= 0.0 and x[j] <= limit) else 1
        bad[b, q] = nbad
        acc = np.zeros(nc)                            # sum (v - eps)_+ of each line
        for i in range(t - 1, -1, -1):                # anti-causal, in place
            v0, v1, v2, v3 = buf[i + 3], buf[i + 4], buf[i + 5], buf[i + 6]
            for j in range(nc):
                v0[j] = a1 * v1[j] + (a2 * v2[j] + (a3 * v3[j] + g * v0[j]))
            if i < n:
                for j in range(nc):
                    acc[j] += max(v0[j] - eps, 0.0)
        for j in range(nc):                           # transposed into dst
            d = dst[b, c0 + j]
            for i in range(n):
                d[i] = buf[i + 3, j]
        excess[b, q] = acc.sum()


@njit(parallel=True, cache=True, fastmath={"reassoc"})
def trapezoid_update(prior, xs, ys, pos, mu, tau, sig, base, scale, eps, out, rows):
    """``out = max(f(prior) L, eps)`` and ``rows[b, r] = sum_c out[b, r, c]``, with the
    floored prior ``f(v) = base + scale max(v - base, 0)`` per run (``base = 0, scale = 1``:
    the prior as it is) and the trapezoid ``L = max(0, s - max(0, |d - mu| - tau)) / s``
    of the distance ``d`` from ``pos[b]`` to the cell centre ``(xs[c], ys[r])``."""
    B, h, w = prior.shape
    for job in prange(B * h):
        b = job // h
        r = job - b * h
        px, m, t, s, lo, c = pos[b, 0], mu[b], tau[b], sig[b], base[b], scale[b]
        dy = ys[r] - pos[b, 1]
        acc = 0.0
        for j in range(w):
            dx = xs[j] - px
            e = max(abs(math.sqrt(dx * dx + dy * dy) - m) - t, 0.0)
            v = max((lo + c * max(prior[b, r, j] - lo, 0.0)) * (max(s - e, 0.0) / s), eps)
            out[b, r, j] = v
            acc += v
        rows[b, r] = acc
