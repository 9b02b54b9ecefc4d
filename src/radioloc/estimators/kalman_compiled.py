"""Compiled kernels of the Kalman, network and closed-form estimators.

Each kernel is the compiled form of a NumPy definition elsewhere in the package, selected by
that estimator's ``backend="numba"`` setting (``backend="numpy"`` runs the definition); the
two agree to rounding (about 1e-10 relative, held by the backend-equivalence tests). Every
kernel here is self-contained: it calls only numba, NumPy and :mod:`math`, never a function
of another module, so numba's per-file cache cannot go stale.

- :func:`network_ekf_packets`: :class:`~radioloc.estimators.ekf.NetworkEKF`'s packets, each
  :func:`~radioloc.estimators.ekf.range_jacobian` followed by
  :func:`~radioloc.estimators.kalman.kalman_update` (paper 000, eq. (15)-eq. (23)).
- :func:`network_rls_iteration`: :meth:`~radioloc.estimators.rls.NetworkRLS.iterate`, the
  masters ``k = 0..K-1`` of :meth:`~radioloc.estimators.rls.NetworkRLS.step` (paper 000,
  eq. (8)-eq. (11)).
- :func:`blue_iterations`: the iterations 3b-3d of
  :class:`~radioloc.estimators.closed_form.ClosedFormTracker` (paper 002, eq. (11)-eq. (15)).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange


__all__ = ["network_ekf_packets", "network_rls_iteration", "blue_iterations"]

@njit(parallel=True, cache=True, error_model="numpy")
def network_ekf_packets(mean, cov, masters, rho, valid, var, nis, used, err):  # pragma: no cover
    """Sequential EKF updates of every run (``prange``) by its packets ``j`` in order.

    ``mean (R, n)`` and ``cov (R, n, n)`` are updated in place; ``masters (R, M)``,
    ``rho (R, M, K)``, ``valid (R, M, K)``; ``nis``/``used (R, K)`` receive each master's
    NIS and number of ranges; ``err (R, 2)`` the packet and node of a used link whose two
    estimates coincide (-1 if none; that run stops there). Only the used rows enter (a
    missing row of ``kalman_update`` is an identity row of ``S`` with zero cross terms);
    the matrices with ``n`` columns are stored by row, so the loops over ``n`` are the
    inner, contiguous ones.
    """
    R, n = mean.shape
    M = masters.shape[1]
    K = n // 2
    for r in prange(R):
        x = mean[r]
        P = cov[r]
        node = np.empty(K, np.int64)
        u = np.empty((K, 2))
        nu = np.empty(K)
        At = np.empty((K, n))                # (P H^T)^T = H P
        S = np.empty((K, K))                 # H P H^T + R
        L = np.zeros((K, K))                 # its Cholesky factor
        G = np.empty((K, n))                 # the gain transposed, S^-1 H P
        Dt = np.empty((K, n))                # (K S - P H^T)^T
        for j in range(M):
            k = masters[r, j]
            scale = 1.0
            for i in range(n):
                scale = max(scale, abs(x[i]))
            m = 0                            # eq. (15)-eq. (17): ranges, unit vectors u
            for p in range(K):
                if not valid[r, j, p]:
                    continue
                dx = x[2 * p] - x[2 * k]
                dy = x[2 * p + 1] - x[2 * k + 1]
                h = math.sqrt(dx * dx + dy * dy)
                if h <= 1e-9 * scale:
                    err[r, 0] = j
                    err[r, 1] = p
                    break
                node[m] = p
                u[m, 0] = dx / h
                u[m, 1] = dy / h
                nu[m] = rho[r, j, p] - h
                m += 1
            if err[r, 0] >= 0:
                break
            # row a of H: +u_a in the block of node p_a, -u_a in the master's block
            for a in range(m):
                p = node[a]
                for i in range(n):
                    At[a, i] = ((P[2 * p, i] - P[2 * k, i]) * u[a, 0]
                                + (P[2 * p + 1, i] - P[2 * k + 1, i]) * u[a, 1])
            for a in range(m):
                p = node[a]
                for b in range(m):
                    S[a, b] = ((At[b, 2 * p] - At[b, 2 * k]) * u[a, 0]
                               + (At[b, 2 * p + 1] - At[b, 2 * k + 1]) * u[a, 1])
                S[a, a] += var
            for a in range(m):
                for b in range(a):
                    v = 0.5 * (S[a, b] + S[b, a])
                    S[a, b] = v
                    S[b, a] = v
            for a in range(m):
                for b in range(a + 1):
                    t = S[a, b]
                    for s in range(b):
                        t -= L[a, s] * L[b, s]
                    L[a, b] = math.sqrt(t) if a == b else t / L[b, b]
            for a in range(m):               # G = S^-1 H P by two triangular solves
                for i in range(n):
                    G[a, i] = At[a, i]
                for s in range(a):
                    for i in range(n):
                        G[a, i] -= L[a, s] * G[s, i]
                for i in range(n):
                    G[a, i] /= L[a, a]
            for a in range(m - 1, -1, -1):
                for s in range(a + 1, m):
                    for i in range(n):
                        G[a, i] -= L[s, a] * G[s, i]
                for i in range(n):
                    G[a, i] /= L[a, a]
            t = 0.0                          # the mean x + K nu; NIS = |L^-1 nu|^2
            for a in range(m):
                for i in range(n):
                    x[i] += G[a, i] * nu[a]
                v = nu[a]
                for s in range(a):
                    v -= L[a, s] * nu[s]
                nu[a] = v / L[a, a]
                t += nu[a] * nu[a]
            nis[r, k] = t
            used[r, k] = m
            # Joseph form (I - K H) P (I - K H)^T + K R K^T = P + D K^T - K A^T with
            # A = P H^T and D = K S - A, then symmetrised
            for b in range(m):
                for i in range(n):
                    Dt[b, i] = -At[b, i]
                for a in range(m):
                    for i in range(n):
                        Dt[b, i] += S[a, b] * G[a, i]
            for i in range(n):
                for a in range(m):
                    d = Dt[a, i]
                    g = G[a, i]
                    for c in range(n):
                        P[i, c] += d * G[a, c] - g * At[a, c]
            for i in range(n):
                for c in range(i):
                    v = 0.5 * (P[i, c] + P[c, i])
                    P[i, c] = v
                    P[c, i] = v


@njit(parallel=True, cache=True)
def network_rls_iteration(position, information, used, rho, valid, lam, cond_limit, err):  # pragma: no cover
    """:meth:`NetworkRLS.iterate` compiled, parallel over runs: masters ``k = 0..K-1`` in
    order, each from the pairs ``i < j`` of its valid ranges and the positions at the start
    of the iteration (eq. (8)-eq. (11), the same sums as :meth:`NetworkRLS.step`).
    ``position (R, K, 2)``, ``information (R, K, 2, 2)``, ``used (R, K)`` are updated in place;
    ``err[r]`` receives the first master whose information matrix is singular (-1 if none;
    the run is left as it was before that master)."""
    R, K, _ = position.shape
    for r in prange(R):
        ref = position[r].copy()                        # x_i(n-1), eq. (8), eq. (9)
        sq = np.empty(K)
        for i in range(K):
            sq[i] = ref[i, 0] * ref[i, 0] + ref[i, 1] * ref[i, 1]
        for k in range(K):
            x0, x1 = ref[k, 0], ref[k, 1]
            a = lam * information[r, k, 0, 0]
            b = lam * information[r, k, 0, 1]
            b2 = lam * information[r, k, 1, 0]
            d = lam * information[r, k, 1, 1]
            g0 = 0.0
            g1 = 0.0
            cnt = 0
            for i in range(K):
                for j in range(i + 1, K):
                    if not (valid[r, k, i] and valid[r, k, j]):
                        continue
                    ax = ref[j, 0] - ref[i, 0]
                    ay = ref[j, 1] - ref[i, 1]
                    z = 0.5 * (rho[r, k, i] ** 2 - rho[r, k, j] ** 2) - 0.5 * (sq[i] - sq[j])
                    a += ax * ax
                    b += ax * ay
                    b2 += ay * ax
                    d += ay * ay
                    nu = z - (ax * x0 + ay * x1)
                    g0 += ax * nu
                    g1 += ay * nu
                    cnt += 1
            det = a * d - b * b
            half_tr = 0.5 * (a + d)
            disc = math.sqrt(max(half_tr * half_tr - det, 0.0))
            if not ((half_tr - disc) * cond_limit > half_tr + disc):
                err[r] = k
                break
            position[r, k, 0] = x0 + (d * g0 - b * g1) / det
            position[r, k, 1] = x1 + (a * g1 - b * g0) / det
            information[r, k, 0, 0] = a
            information[r, k, 0, 1] = b
            information[r, k, 1, 0] = b2
            information[r, k, 1, 1] = d
            used[r, k] = cnt


@njit(cache=True, error_model="numpy")
def blue_iterations(sa, sy, keep, s, xi, c, sks, tv, kap, printed, var, tol, max_iter,
                    crit_stop, beta, cov, iterations, flags):  # pragma: no cover
    """Steps 3b-3d of :meth:`ClosedFormTracker.locate` for every track, each
    iterated to its own stop from its OLS start ``beta (B, 4)`` (updated in place).

    ``sa (B, m, 4)``, ``sy (B, m)``, ``keep (B, m)``: the differenced system (dropped rows
    zero); ``s (1 or B, n, 2)``, ``xi (1 or B, n)``; ``c (n, n)`` the motion-noise
    covariance, ``sks = S (2 c2) S'`` its square term differenced, ``var = diag(c)``. Per
    step ``Sigma_pq = 4 c_pq d_p . d_q + delta_pq e_p`` (eq. (11), eq. (13); with
    ``printed`` the eq. (14) terms), ``W = S Sigma S' + sks``, and the GLS by Cholesky of
    ``W``. ``cov (B, 4, 4)``, ``iterations (B,)``; ``flags (B,)``: bit 0 converged,
    bit 1 stalled (``crit_stop``), bit 2 ``W`` or the information not positive definite.
    """
    B, m, _ = sa.shape
    n = m + 3
    st = (1.0, -3.0, 3.0, -1.0)                      # a row of S, eq. (10)
    for b in range(B):
        sb = b if s.shape[0] > 1 else 0               # a path shared by every track: row 0
        xb = b if xi.shape[0] > 1 else 0
        dx = np.empty(n)
        dy = np.empty(n)
        sig = np.empty((n, n))
        t = np.empty((n, m))                          # Sigma S'
        W = np.empty((m, m))
        X = np.empty((m, 5))                          # L^-1 [S A, S y]
        G = np.empty((5, 5))
        inv = np.empty((4, 4))
        new = np.empty(4)
        cov[b] = 0.0
        best = np.inf
        it = 0
        fl = 0
        for _ in range(max_iter):
            for p in range(n):                        # d_n at the current state
                dx[p] = beta[b, 0] + tv[p] * beta[b, 2] - s[sb, p, 0]
                dy[p] = beta[b, 1] + tv[p] * beta[b, 3] - s[sb, p, 1]
            for p in range(n):
                for q in range(n):
                    sig[p, q] = 4.0 * c[p, q] * (dx[p] * dx[q] + dy[p] * dy[q])
                    if printed:
                        sig[p, q] -= 2.0 * (xi[xb, q] * var[p] + xi[xb, p] * var[q])
                x = xi[xb, p]
                sig[p, p] += (4.0 * x * (dx[p] * dx[p] + dy[p] * dy[p] + 2.0 * c[p, p])
                              + (2.0 + kap) * x * x)
                if printed:
                    sig[p, p] += 4.0 * x * var[p]
            for p in range(n):
                for j in range(m):
                    t[p, j] = (st[0] * sig[p, j] + st[1] * sig[p, j + 1] + st[2] * sig[p, j + 2]
                               + st[3] * sig[p, j + 3])
            for i in range(m):
                for j in range(m):
                    W[i, j] = sks[i, j] + (st[0] * t[i, j] + st[1] * t[i + 1, j]
                                           + st[2] * t[i + 2, j] + st[3] * t[i + 3, j])
                    if not (keep[b, i] and keep[b, j]):
                        W[i, j] = 1.0 if i == j else 0.0
            ok = True                                 # W = L L' in place (lower triangle)
            for i in range(m):
                for j in range(i + 1):
                    v = W[i, j]
                    for k in range(j):
                        v -= W[i, k] * W[j, k]
                    if i == j:
                        if not v > 0.0:
                            ok = False
                            break
                        W[i, i] = np.sqrt(v)
                    else:
                        W[i, j] = v / W[j, j]
                if not ok:
                    break
            if ok:
                for i in range(m):                    # X = L^-1 [S A, S y]
                    for q in range(5):
                        v = sa[b, i, q] if q < 4 else sy[b, i]
                        for k in range(i):
                            v -= W[i, k] * X[k, q]
                        X[i, q] = v / W[i, i]
                for p in range(5):
                    for q in range(5):
                        v = 0.0
                        for i in range(m):
                            v += X[i, p] * X[i, q]
                        G[p, q] = v
                for p in range(4):                    # inv = (A~' W^-1 A~)^-1, Gauss-Jordan
                    for q in range(4):
                        inv[p, q] = 1.0 if p == q else 0.0
                for p in range(4):
                    piv = G[p, p]
                    if not piv > 0.0:
                        ok = False
                        break
                    for q in range(4):
                        G[p, q] /= piv
                        inv[p, q] /= piv
                    for r in range(4):
                        if r != p:
                            f = G[r, p]
                            for q in range(4):
                                G[r, q] -= f * G[p, q]
                                inv[r, q] -= f * inv[p, q]
            if not ok:
                fl |= 4
                break
            crit = G[4, 4]                            # step 3c and r' W^-1 r
            for p in range(4):
                v = 0.0
                for q in range(4):
                    v += inv[p, q] * G[q, 4]
                new[p] = v
                crit -= v * G[p, 4]
            if crit_stop and not crit < best:
                fl |= 2
                break
            change = 0.0
            for p in range(4):
                change += (new[p] - beta[b, p]) ** 2
                beta[b, p] = new[p]
            cov[b] = inv
            best = crit
            it += 1
            if np.sqrt(change) <= tol:                # step 3d
                fl |= 1
                break
        iterations[b] = it
        flags[b] = fl
