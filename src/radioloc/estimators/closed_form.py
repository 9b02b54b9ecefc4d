"""Closed-form single-sensor tracker: third-difference linearisation + iterative BLUE (paper 002).

Steps of section 3 (ideal channel eq. (11), noisy channel eq. (12), eq. (13), eq. (14)),
batched over problems:

1. subtract the noise mean ``E[e_n]`` from ``y_n = rhat_n^2 - a_n^2 - b_n^2``;
2. apply the third difference S of eq. (10): ``S y = (S A) beta + S e`` (eq. (9));
3a. OLS start ``beta0 = (A~' A~)^{-1} A~' S y``;
3b. evaluate ``Sigma~ = S Sigma(beta_m) S'`` at the current estimate;
3c. BLUE/GLS ``beta_{m+1} = (A~' Sigma~^{-1} A~)^{-1} A~' Sigma~^{-1} S y``;
3d. stop when ``|beta_{m+1} - beta_m| <= tol`` (section 5.2's ``|.|^2 <= 0.1`` is
    ``tol = sqrt(0.1)``) or after ``max_iter`` (the paper's rule, ``stopping="change"``);
    ``stopping="criterion"`` also stops when the GLS criterion ``r' Sigma~^{-1} r`` stops
    decreasing (the previous estimate is kept).

A missing (NaN) range drops the difference rows that involve it: their rows of ``S A``
and ``S y`` are zeroed and their rows and columns of ``S Sigma S'`` decoupled (unit
diagonal), as a Kalman filter masks a missing measurement. The estimate is then the
BLUE of the remaining differences; a NaN at the first sample gives exactly the estimate
of the series without that sample.

The state is ``beta = [x_k, y_k, vx_k, vy_k]`` (the paper orders it ``[Y_k, X_k, V_y, V_x]``);
the model lives in :mod:`radioloc.models.single_sensor`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from radioloc.core.arrays import kernel_array
from radioloc.core.errors import ConfigError, GeometryError
from radioloc.core.results import Estimate
from radioloc.core.validation import (MAX_ITERATIONS, as_float_array, check_finite_output,
                                      check_int, check_positive)
from radioloc.estimators.base import SnapshotEstimator
from radioloc.models.single_sensor import (
    SquaredRangeModel,
    design_matrix,
    difference_both,
    difference_rows,
    resolve_sampling,
    trajectory,
    validate_inputs,
)

__all__ = ["ClosedFormTracker"]

WEIGHTINGS = ("blue", "ols")
STOPPING = ("change", "criterion")


def _gls(sa: np.ndarray, sy: np.ndarray, w: np.ndarray):
    """Generalised least squares for a batch: returns (beta, covariance, criterion).

    One LU solve ``w^{-1} [S A, S y]`` per problem; the criterion is ``r' w^{-1} r``.
    """
    try:
        sol = np.linalg.solve(w, np.concatenate([sa, sy[..., None]], axis=-1))
    except np.linalg.LinAlgError:
        raise GeometryError("S Sigma S^T is singular (not positive definite); the motion and "
                            "channel noise variances cannot both be zero for the BLUE") from None
    at = np.swapaxes(sa, -1, -2)
    info = at @ sol[..., :4]
    rhs = at @ sol[..., 4:]
    cov = np.linalg.inv(info)
    beta = (cov @ rhs)[..., 0]
    crit = (np.einsum("...i,...i->...", sy, sol[..., 4])
            - np.einsum("...i,...i->...", beta, rhs[..., 0]))
    return beta, cov, crit


def _mask_covariance(w: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Decouple the dropped difference rows: zero their rows and columns, unit diagonal."""
    if np.all(keep):
        return w
    both = keep[..., :, None] & keep[..., None, :]
    eye = np.eye(keep.shape[-1], dtype=bool)
    return np.where(both, w, np.where(eye, 1.0, 0.0))


def _ols(sa: np.ndarray, sy: np.ndarray) -> np.ndarray:
    """Step 3a, batched: ``(A~' A~)^{-1} A~' S y``."""
    at = np.swapaxes(sa, -1, -2)
    return np.linalg.solve(at @ sa, (at @ sy[..., None]))[..., 0]


# ---- compiled iterative BLUE ---------------------------------------------------------
# One track at a time per thread (prange over chunks of tracks), each track iterated to
# its own stop inside the kernel (one launch per call); the same maths as _gls, with
# W = S Sigma S' (eq. (11), eq. (14)) built from its parts and factorised by Cholesky:
#   Sigma_ij = 4 c_ij (d_i . d_j) + 2 c2_ij + delta_ij e_i (+ the printed eq. (14) terms),
#   d_i = p_k + t_i v_k - s_i, e_i = 4 xi_i (|d_i|^2 + 2 c_ii) + (2 + kappa) xi_i^2,
# with S (2 c2) S' computed once per call. tests/test_closed_form_kernels.py compares it
# with the NumPy path on random inputs.
#
# Structure of W (used by _structured_gram; tests/test_blue_structured.py):
# * The motion noise eps_n = T^2 sum_m c_{n,m} G_m of eq. (4) has c_{n,m} linear in n on
#   each side of k, so c_pq (p < q) is linear in q for k <= p and linear in p for q <= k
#   (and 0 across k): c_pq = gu_p . gv_q with two generator columns per non-empty side
#   (_noise_generators; eq. (5) is its diagonal). The square term c2_pq = 2 c_pq^2 (+ the
#   kurtosis term) is quadratic there, and the third difference S of eq. (10) annihilates
#   polynomials of degree <= 2: S (2 c2) S' is a band, W_ij = 0 for |i - j| > 3 in that
#   term. The diagonal e_i adds to the band only.
# * The state-dependent term 4 c_pq (dx_p dx_q + dy_p dy_q) is not polynomial (the sensor
#   path s_n is arbitrary), but for j >= i + 4 every pair of the two windows of S has
#   p < q, so W_ij = F_i . U_j with F_i = 4 sum_a S_a [dx, dy]_{i+a} (x) gu_{i+a} and
#   U_j = sum_b S_b [dx, dy]_{j+b} (x) gv_{j+b}: width r = 2 rc (rc = 2 generator columns
#   when k is the first or last sample, else 4), plus 2 for the rank-2 printed eq. (14)
#   terms -2 (S var)_i (S xi)_j - 2 (S xi)_i (S var)_j.
# So W = band of half-width 3 (computed exactly from Sigma's band of half-width 6) plus a
# semiseparable part F U' beyond the band. Its Cholesky factor has the same form:
# L_ij = U_i . q_j for i >= j + 4, with q_j = (F_j - P_{j-3} U_j - sum_{band} L_jk q_k) / L_jj
# and P_t = sum_{l < t} q_l q_l' (r x r); the band of L and the forward solve L^{-1} Z'
# follow row by row in O(r^2 + 5 r) flops: O(n r^2) per GLS step instead of O(n^3). A
# dropped row (missing range) gets zero generators and a unit diagonal. Rounding: the
# structured and the dense factorisation differ by about as much as the dense Cholesky
# and an LU solve of the same W (measured on random and near-degenerate tracks, see
# tests/test_blue_structured.py); a non-positive structured pivot falls back to the dense
# factorisation (_dense_gram) for that step.
_FM = {"contract"}
_S0, _S1, _S2, _S3 = 1.0, -3.0, 3.0, -1.0          # a row of S, eq. (10)
_PARALLEL_MIN_TRACKS = 16                           # fewer tracks: no parallel launch
_STRUCTURED = True                                  # False: the dense O(n^3) path only
_PAD = 6                                            # identity rows before the structured factor


@njit(cache=True)
def _spd_inverse4(G, out):
    """``out = inv(G[:4, :4])`` for a symmetric positive definite block (Cholesky); False
    if it is not positive definite."""
    L = np.zeros((4, 4))
    for i in range(4):
        for j in range(i + 1):
            v = G[i, j]
            for k in range(j):
                v -= L[i, k] * L[j, k]
            if i == j:
                if not v > 0.0:
                    return False
                L[i, i] = math.sqrt(v)
            else:
                L[i, j] = v / L[j, j]
    Li = np.zeros((4, 4))                               # L^{-1}
    for i in range(4):
        Li[i, i] = 1.0 / L[i, i]
        for j in range(i):
            v = 0.0
            for k in range(j, i):
                v -= L[i, k] * Li[k, j]
            Li[i, j] = v / L[i, i]
    for i in range(4):                                  # L^{-T} L^{-1}
        for j in range(4):
            v = 0.0
            for k in range(max(i, j), 4):
                v += Li[k, i] * Li[k, j]
            out[i, j] = v
    return True


@njit(cache=True, fastmath=_FM)
def _dense_gram(m, n, dx, dy, ex, c, sks, printed, sv, sx, keep, Z, M, ur, G):
    """``G = [L^{-1} Z']' [L^{-1} Z']`` with ``W = S Sigma S' = L L'`` built densely (its
    upper triangle, row by row) and factorised by a dense Cholesky: O(n^3) per call, the
    fallback of :func:`_structured_gram`. False on a non-positive pivot."""
    # M = [W | Z'], W = S Sigma S' as its upper triangle, row by row (step 3b)
    for row in range(m):
        # row ``row`` of U = S Sigma, columns row..n-1 (all the upper triangle needs)
        ax0, ax1 = _S0 * dx[row], _S1 * dx[row + 1]
        ax2, ax3 = _S2 * dx[row + 2], _S3 * dx[row + 3]
        ay0, ay1 = _S0 * dy[row], _S1 * dy[row + 1]
        ay2, ay3 = _S2 * dy[row + 2], _S3 * dy[row + 3]
        c0, c1, c2, c3 = c[row, row:], c[row + 1, row:], c[row + 2, row:], c[row + 3, row:]
        ux, uy, uo = dx[row:], dy[row:], ur[row:]
        for i in range(n - row):                   # loops from 0: no wrap-around checks
            px = ax0 * c0[i] + ax1 * c1[i] + ax2 * c2[i] + ax3 * c3[i]
            py = ay0 * c0[i] + ay1 * c1[i] + ay2 * c2[i] + ay3 * c3[i]
            uo[i] = 4.0 * (ux[i] * px + uy[i] * py)
        ur[row] += _S0 * ex[row]
        ur[row + 1] += _S1 * ex[row + 1]
        ur[row + 2] += _S2 * ex[row + 2]
        ur[row + 3] += _S3 * ex[row + 3]
        mo, so = M[row, row:m], sks[row, row:]
        u0, u1, u2, u3 = ur[row:], ur[row + 1:], ur[row + 2:], ur[row + 3:]
        for col in range(m - row):
            mo[col] = so[col] + _S0 * u0[col] + _S1 * u1[col] + _S2 * u2[col] + _S3 * u3[col]
        if printed:
            for col in range(m - row):
                mo[col] -= 2.0 * (sv[row] * sx[row + col] + sx[row] * sv[row + col])
        for q in range(5):
            M[row, m + q] = Z[q, row]
    for row in range(m):                            # a dropped row: unit diagonal, decoupled
        if not keep[row]:
            for col in range(row + 1, m):
                M[row, col] = 0.0
            M[row, row] = 1.0
            for r2 in range(row):
                M[r2, row] = 0.0
    # Cholesky of the augmented matrix, right-looking on the upper triangle, two rows
    # at a time (rank-2 updates of contiguous rows): row k becomes [L' | L^{-1} Z'] row k
    k = 0
    while k < m:
        mk = M[k]
        d = mk[k]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        mk[k] = d
        inv = 1.0 / d
        tk = mk[k + 1:]
        for j in range(tk.size):
            tk[j] *= inv
        if k + 1 == m:
            break
        m1 = M[k + 1]
        f = mk[k + 1]
        t1 = m1[k + 1:]
        tj = mk[k + 1:]
        for j in range(t1.size):
            t1[j] -= f * tj[j]
        d = m1[k + 1]
        if not d > 0.0:
            return False
        d = math.sqrt(d)
        m1[k + 1] = d
        inv = 1.0 / d
        t1 = m1[k + 2:]
        for j in range(t1.size):
            t1[j] *= inv
        for i in range(k + 2, m):
            f0 = mk[i]
            f1 = m1[i]
            ti = M[i, i:]
            t0 = mk[i:]
            t1 = m1[i:]
            for j in range(ti.size):
                ti[j] -= f0 * t0[j] + f1 * t1[j]
        k += 2
    for p in range(5):
        for q in range(p + 1):
            acc = 0.0
            for k in range(m):
                acc += M[k, m + p] * M[k, m + q]
            G[p, q] = acc
            G[q, p] = acc
    return True


@njit(cache=True, fastmath=_FM)
def _gram5(X, lo, hi, G):
    """``G = X[:, lo:hi] X[:, lo:hi]'`` for ``X`` of 5 rows: the 15 sums in one pass over the
    columns (15 independent accumulators instead of 15 serial dot products; each sum is
    accumulated in the same order, so the same values)."""
    g00 = g01 = g02 = g03 = g04 = g11 = g12 = g13 = g14 = 0.0
    g22 = g23 = g24 = g33 = g34 = g44 = 0.0
    x0, x1, x2, x3, x4 = X[0], X[1], X[2], X[3], X[4]
    for j in range(lo, hi):
        a0, a1, a2, a3, a4 = x0[j], x1[j], x2[j], x3[j], x4[j]
        g00 += a0 * a0
        g01 += a0 * a1
        g02 += a0 * a2
        g03 += a0 * a3
        g04 += a0 * a4
        g11 += a1 * a1
        g12 += a1 * a2
        g13 += a1 * a3
        g14 += a1 * a4
        g22 += a2 * a2
        g23 += a2 * a3
        g24 += a2 * a4
        g33 += a3 * a3
        g34 += a3 * a4
        g44 += a4 * a4
    G[0, 0], G[1, 1], G[2, 2], G[3, 3], G[4, 4] = g00, g11, g22, g33, g44
    G[0, 1] = G[1, 0] = g01
    G[0, 2] = G[2, 0] = g02
    G[0, 3] = G[3, 0] = g03
    G[0, 4] = G[4, 0] = g04
    G[1, 2] = G[2, 1] = g12
    G[1, 3] = G[3, 1] = g13
    G[1, 4] = G[4, 1] = g14
    G[2, 3] = G[3, 2] = g23
    G[2, 4] = G[4, 2] = g24
    G[3, 4] = G[4, 3] = g34


@njit(cache=True, fastmath=_FM)
def _factor_solve4(m, wb, F, U, Z, lb, li, qv, zz, X):
    """The Cholesky recursion and forward solve of :func:`_structured_gram` for generator
    width r = 4 (k at an end of the window, no printed eq. (14) terms): the same operations
    in the same order as its general loop, with ``P`` (r x r, symmetric) and ``H`` (r x 5)
    held in local scalars instead of work arrays, so the compiler keeps them out of the
    aliasing of the arrays written each row. Rows ``_PAD..m + _PAD - 1`` of ``lb``, ``li``,
    ``qv``, ``zz`` and ``X`` are written (the ``_PAD`` rows before them must hold the
    identity block). False on a non-positive pivot."""
    p00 = p01 = p02 = p03 = p11 = p12 = p13 = p22 = p23 = p33 = 0.0
    h00 = h01 = h02 = h03 = h04 = h10 = h11 = h12 = h13 = h14 = 0.0
    h20 = h21 = h22 = h23 = h24 = h30 = h31 = h32 = h33 = h34 = 0.0
    for j in range(_PAD, m + _PAD):
        jr = j - _PAD
        o0, o1, o2, o3 = qv[j - 4, 0], qv[j - 4, 1], qv[j - 4, 2], qv[j - 4, 3]
        x0, x1, x2, x3, x4 = X[0, j - 4], X[1, j - 4], X[2, j - 4], X[3, j - 4], X[4, j - 4]
        p00 += o0 * o0; p01 += o0 * o1; p02 += o0 * o2; p03 += o0 * o3
        p11 += o1 * o1; p12 += o1 * o2; p13 += o1 * o3
        p22 += o2 * o2; p23 += o2 * o3
        p33 += o3 * o3
        h00 += o0 * x0; h01 += o0 * x1; h02 += o0 * x2; h03 += o0 * x3; h04 += o0 * x4
        h10 += o1 * x0; h11 += o1 * x1; h12 += o1 * x2; h13 += o1 * x3; h14 += o1 * x4
        h20 += o2 * x0; h21 += o2 * x1; h22 += o2 * x2; h23 += o2 * x3; h24 += o2 * x4
        h30 += o3 * x0; h31 += o3 * x1; h32 += o3 * x2; h33 += o3 * x3; h34 += o3 * x4
        u0, u1, u2, u3 = U[0, jr], U[1, jr], U[2, jr], U[3, jr]
        z0 = p00 * u0 + p01 * u1 + p02 * u2 + p03 * u3
        z1 = p01 * u0 + p11 * u1 + p12 * u2 + p13 * u3
        z2 = p02 * u0 + p12 * u1 + p22 * u2 + p23 * u3
        z3 = p03 * u0 + p13 * u1 + p23 * u2 + p33 * u3
        zz[j, 0] = z0; zz[j, 1] = z1; zz[j, 2] = z2; zz[j, 3] = z3
        piv = wb[0, j] - u0 * z0 - u1 * z1 - u2 * z2 - u3 * z3
        e4 = u0 * qv[j - 4, 0] + u1 * qv[j - 4, 1] + u2 * qv[j - 4, 2] + u3 * qv[j - 4, 3]
        e5 = u0 * qv[j - 5, 0] + u1 * qv[j - 5, 1] + u2 * qv[j - 5, 2] + u3 * qv[j - 5, 3]
        e6 = u0 * qv[j - 6, 0] + u1 * qv[j - 6, 1] + u2 * qv[j - 6, 2] + u3 * qv[j - 6, 3]
        a3 = (wb[3, j - 3] - u0 * zz[j - 3, 0] - u1 * zz[j - 3, 1] - u2 * zz[j - 3, 2]
              - u3 * zz[j - 3, 3])
        a2 = (wb[2, j - 2] - u0 * zz[j - 2, 0] - u1 * zz[j - 2, 1] - u2 * zz[j - 2, 2]
              - u3 * zz[j - 2, 3])
        a1 = (wb[1, j - 1] - u0 * zz[j - 1, 0] - u1 * zz[j - 1, 1] - u2 * zz[j - 1, 2]
              - u3 * zz[j - 1, 3])
        e3 = (a3 - e4 * lb[j - 3, 1] - e5 * lb[j - 3, 2] - e6 * lb[j - 3, 3]) * li[j - 3]
        e2 = (a2 - e3 * lb[j - 2, 1] - e4 * lb[j - 2, 2] - e5 * lb[j - 2, 3]) * li[j - 2]
        e1 = (a1 - e2 * lb[j - 1, 1] - e3 * lb[j - 1, 2] - e4 * lb[j - 1, 3]) * li[j - 1]
        piv -= e1 * e1 + e2 * e2 + e3 * e3
        if not piv > 0.0:
            return False
        dj = math.sqrt(piv)
        inv = 1.0 / dj
        lb[j, 0] = dj
        lb[j, 1] = e1
        lb[j, 2] = e2
        lb[j, 3] = e3
        li[j] = inv
        qv[j, 0] = (F[0, jr] - z0 - e1 * qv[j - 1, 0] - e2 * qv[j - 2, 0]
                    - e3 * qv[j - 3, 0]) * inv
        qv[j, 1] = (F[1, jr] - z1 - e1 * qv[j - 1, 1] - e2 * qv[j - 2, 1]
                    - e3 * qv[j - 3, 1]) * inv
        qv[j, 2] = (F[2, jr] - z2 - e1 * qv[j - 1, 2] - e2 * qv[j - 2, 2]
                    - e3 * qv[j - 3, 2]) * inv
        qv[j, 3] = (F[3, jr] - z3 - e1 * qv[j - 1, 3] - e2 * qv[j - 2, 3]
                    - e3 * qv[j - 3, 3]) * inv
        X[0, j] = (Z[0, jr] - e1 * X[0, j - 1] - e2 * X[0, j - 2] - e3 * X[0, j - 3]
                   - u0 * h00 - u1 * h10 - u2 * h20 - u3 * h30) * inv
        X[1, j] = (Z[1, jr] - e1 * X[1, j - 1] - e2 * X[1, j - 2] - e3 * X[1, j - 3]
                   - u0 * h01 - u1 * h11 - u2 * h21 - u3 * h31) * inv
        X[2, j] = (Z[2, jr] - e1 * X[2, j - 1] - e2 * X[2, j - 2] - e3 * X[2, j - 3]
                   - u0 * h02 - u1 * h12 - u2 * h22 - u3 * h32) * inv
        X[3, j] = (Z[3, jr] - e1 * X[3, j - 1] - e2 * X[3, j - 2] - e3 * X[3, j - 3]
                   - u0 * h03 - u1 * h13 - u2 * h23 - u3 * h33) * inv
        X[4, j] = (Z[4, jr] - e1 * X[4, j - 1] - e2 * X[4, j - 2] - e3 * X[4, j - 3]
                   - u0 * h04 - u1 * h14 - u2 * h24 - u3 * h34) * inv
    return True


@njit(cache=True, fastmath=_FM)
def _factor_solve(m, r, wb, F, U, Z, lb, li, qv, zz, P, H, X):
    """The Cholesky recursion and forward solve of :func:`_structured_gram` for any
    generator width ``r`` (``P`` r x r and ``H`` r x 5 in work arrays); see
    :func:`_factor_solve4` for the width-4 case. False on a non-positive pivot."""
    for t in range(r):
        for t2 in range(r):
            P[t, t2] = 0.0
        for q in range(5):
            H[t, q] = 0.0
    for j in range(_PAD, m + _PAD):
        jr = j - _PAD
        for t in range(r):
            ot = qv[j - 4, t]
            for t2 in range(r):
                P[t, t2] += ot * qv[j - 4, t2]
            for q in range(5):
                H[t, q] += ot * X[q, j - 4]
        e4 = 0.0
        e5 = 0.0
        e6 = 0.0
        a3 = wb[3, j - 3]
        a2 = wb[2, j - 2]
        a1 = wb[1, j - 1]
        piv = wb[0, j]
        for t in range(r):
            ut = U[t, jr]
            acc = 0.0
            for t2 in range(r):
                acc += P[t, t2] * U[t2, jr]
            zz[j, t] = acc
            piv -= ut * acc
            e4 += ut * qv[j - 4, t]
            e5 += ut * qv[j - 5, t]
            e6 += ut * qv[j - 6, t]
            a3 -= ut * zz[j - 3, t]
            a2 -= ut * zz[j - 2, t]
            a1 -= ut * zz[j - 1, t]
        e3 = (a3 - e4 * lb[j - 3, 1] - e5 * lb[j - 3, 2] - e6 * lb[j - 3, 3]) * li[j - 3]
        e2 = (a2 - e3 * lb[j - 2, 1] - e4 * lb[j - 2, 2] - e5 * lb[j - 2, 3]) * li[j - 2]
        e1 = (a1 - e2 * lb[j - 1, 1] - e3 * lb[j - 1, 2] - e4 * lb[j - 1, 3]) * li[j - 1]
        piv -= e1 * e1 + e2 * e2 + e3 * e3
        if not piv > 0.0:
            return False
        dj = math.sqrt(piv)
        inv = 1.0 / dj
        lb[j, 0] = dj
        lb[j, 1] = e1
        lb[j, 2] = e2
        lb[j, 3] = e3
        li[j] = inv
        for t in range(r):
            qv[j, t] = (F[t, jr] - zz[j, t] - e1 * qv[j - 1, t] - e2 * qv[j - 2, t]
                        - e3 * qv[j - 3, t]) * inv
        for q in range(5):
            v = Z[q, jr] - e1 * X[q, j - 1] - e2 * X[q, j - 2] - e3 * X[q, j - 3]
            for t in range(r):
                v -= U[t, jr] * H[t, q]
            X[q, j] = v * inv
    return True


@njit(cache=True, fastmath=_FM, inline="always")
def _structured_gram(m, n, dx, dy, ex, cb, sksb, gu, gv, printed, sv, sx, keep, Z,
                     sb, R, wb, F, U, lb, li, qv, zz, P, H, X, G, rc, r):
    """``G = [L^{-1} Z']' [L^{-1} Z']`` with ``W = S Sigma S' = L L'`` built and factorised
    in O(n r^2) from its structure (the comment block "Structure of W" above).

    ``W`` (eq. (11), eq. (14), S of eq. (10)) is a band of half-width 3 (``wb``: the
    motion term's near pairs, ``S diag(e) S'`` and ``S (2 c2) S'``, which the third
    difference makes banded) plus, for ``j >= i + 4``, ``W_ij = F_i . U_j`` with generators
    of width ``r`` (2 per axis and side of k of the motion-noise covariance of eq. (4),
    eq. (5), plus 2 for the printed eq. (14) terms). The Cholesky factor keeps the form
    ``L_ij = U_i . qv_j`` beyond the band. False on a non-positive pivot (the caller then
    uses :func:`_dense_gram`). Arrays are stored transposed (band or generator index
    first) so that the loops over rows vectorise."""
    # band of Sigma' = 4 (Dx C Dx + Dy C Dy) + diag(e): sb[d, p] = Sigma'_{p, p+d}, d <= 6
    for d in range(7):
        cd = cb[d]
        sd = sb[d]
        for p in range(n - d):
            sd[p] = 4.0 * (dx[p] * dx[p + d] + dy[p] * dy[p + d]) * cd[p]
        for p in range(n - d, n):
            sd[p] = 0.0
    for p in range(n):
        sb[0, p] += ex[p]
    # R = S Sigma' on the band: R[qq, j] = sum_a s_a Sigma'_{j+a, j+qq}, qq <= 6
    for qq in range(7):
        rq = R[qq]
        top = min(m, n - qq)
        for j in range(top):
            rq[j] = 0.0
        for a in range(4):
            s_a = _S0 if a == 0 else (_S1 if a == 1 else (_S2 if a == 2 else _S3))
            d = qq - a
            if d >= 0:
                src = sb[d, a:]
            else:
                src = sb[-d, qq:]
            for j in range(top):
                rq[j] += s_a * src[j]
    # band of W: wb[_PAD + j, l] = W_{j, j+l}, l <= 3: R S' plus S (2 C2) S' (sksb)
    for l in range(4):
        sk = sksb[l]
        r0, r1, r2, r3 = R[l], R[l + 1], R[l + 2], R[l + 3]
        for j in range(m - l):
            wb[l, _PAD + j] = sk[j] + _S0 * r0[j] + _S1 * r1[j] + _S2 * r2[j] + _S3 * r3[j]
        if printed:
            for j in range(m - l):
                wb[l, _PAD + j] -= 2.0 * (sv[j] * sx[j + l] + sx[j] * sv[j + l])
    # generators: W_ij = F_j . U_i for i >= j + 4 (F: row side, U: column side)
    for t in range(rc):
        g = gu[t]
        h = gv[t]
        fx, fy, ux, uy = F[t], F[rc + t], U[t], U[rc + t]
        for j in range(m):
            fx[j] = 4.0 * (_S0 * dx[j] * g[j] + _S1 * dx[j + 1] * g[j + 1]
                           + _S2 * dx[j + 2] * g[j + 2] + _S3 * dx[j + 3] * g[j + 3])
            fy[j] = 4.0 * (_S0 * dy[j] * g[j] + _S1 * dy[j + 1] * g[j + 1]
                           + _S2 * dy[j + 2] * g[j + 2] + _S3 * dy[j + 3] * g[j + 3])
            ux[j] = (_S0 * dx[j] * h[j] + _S1 * dx[j + 1] * h[j + 1]
                     + _S2 * dx[j + 2] * h[j + 2] + _S3 * dx[j + 3] * h[j + 3])
            uy[j] = (_S0 * dy[j] * h[j] + _S1 * dy[j + 1] * h[j + 1]
                     + _S2 * dy[j + 2] * h[j + 2] + _S3 * dy[j + 3] * h[j + 3])
    if printed:
        for j in range(m):
            F[2 * rc, j] = -2.0 * sv[j]
            F[2 * rc + 1, j] = -2.0 * sx[j]
            U[2 * rc, j] = sx[j]
            U[2 * rc + 1, j] = sv[j]
    for j in range(m):                              # a dropped row: unit diagonal, decoupled
        if not keep[j]:
            for l in range(4):
                wb[l, _PAD + j] = 0.0
                wb[l, _PAD + j - l] = 0.0
            wb[0, _PAD + j] = 1.0
            for t in range(r):
                F[t, j] = 0.0
                U[t, j] = 0.0
    # Cholesky W = L L' with L_ij = U_i . qv_j for i >= j + 4 and the band
    # lb[j, l] = L_{j, j-l} (li[j] = 1 / L_jj); P = sum_{l <= j-4} qv_l qv_l', zz_j = P U_j;
    # the forward solve X = L^{-1} Z' alongside (H = sum_{l <= j-4} qv_l X_l'). Rows are
    # stored from _PAD on: the _PAD rows before them are an identity block (no branches).
    for i in range(_PAD):
        for l in range(4):
            lb[i, l] = 0.0
            wb[l, i] = 0.0
        lb[i, 0] = 1.0
        li[i] = 1.0
        for t in range(r):
            qv[i, t] = 0.0
            zz[i, t] = 0.0
        for q in range(5):
            X[q, i] = 0.0
    if r == 4:
        if not _factor_solve4(m, wb, F, U, Z, lb, li, qv, zz, X):
            return False
    else:
        if not _factor_solve(m, r, wb, F, U, Z, lb, li, qv, zz, P, H, X):
            return False
    _gram5(X, _PAD, m + _PAD, G)                    # the Gram X' X
    return True


@njit(cache=True, fastmath=_FM)
def _gls_one(b, r, s, xi, mean, st, c, sks, cb, sksb, gu, gv, tv, kap, printed, var, ols_only,
             structured, ws, out_beta, out_cov):
    """Steps 1-2 and the OLS start (step 3a, ``ols_only``), or one GLS step (3b-3c,
    ``Sigma`` at the state ``st``, reusing the differenced rows of the track's OLS call) of
    track ``b``, by :func:`_structured_gram` (``structured``; the dense
    :func:`_dense_gram` if a pivot fails) or by :func:`_dense_gram`. Returns the criterion,
    or NaN when a matrix is not positive definite, and whether the dense path ran."""
    dx, dy, ex, y, am, keep, Z, M, ur, sv, sx, G, sb, R, wb, F, U, lb, li, qv, zz, P, H, X = ws
    n = r.shape[1]
    m = n - 3
    sb_ = b if s.shape[0] > 1 else 0
    xb = b if xi.shape[0] > 1 else 0
    if ols_only:                  # steps 1-2, kept in ``ws`` for the track's BLUE steps
        for i in range(n):
            ai = s[sb_, i, 0]
            bi = s[sb_, i, 1]
            y[i] = r[b, i] * r[b, i] - ai * ai - bi * bi - mean[xb, i]      # step 1
            am[i, 0] = -2.0 * ai
            am[i, 1] = -2.0 * bi
            am[i, 2] = -2.0 * tv[i] * ai
            am[i, 3] = -2.0 * tv[i] * bi
        for row in range(m):                                                # step 2
            ok = not (math.isnan(y[row]) or math.isnan(y[row + 1]) or math.isnan(y[row + 2])
                      or math.isnan(y[row + 3]))
            keep[row] = ok
            for q in range(4):
                Z[q, row] = (_S0 * am[row, q] + _S1 * am[row + 1, q] + _S2 * am[row + 2, q]
                             + _S3 * am[row + 3, q]) if ok else 0.0
            Z[4, row] = (_S0 * y[row] + _S1 * y[row + 1] + _S2 * y[row + 2]
                         + _S3 * y[row + 3]) if ok else 0.0
    else:                         # the offsets d_n and the diagonal e_n at the state ``st``
        bx, by, bvx, bvy = st[0], st[1], st[2], st[3]
        for i in range(n):
            dx[i] = bx + tv[i] * bvx - s[sb_, i, 0]
            dy[i] = by + tv[i] * bvy - s[sb_, i, 1]
            x = xi[xb, i]
            ex[i] = (4.0 * x * (dx[i] * dx[i] + dy[i] * dy[i] + 2.0 * c[i, i])
                     + (2.0 + kap) * x * x)
            if printed:
                ex[i] += 4.0 * x * var[i]
    dense = False
    if ols_only:
        _gram5(Z, 0, m, G)
    else:
        if printed:
            for row in range(m):
                sv[row] = _S0 * var[row] + _S1 * var[row + 1] + _S2 * var[row + 2] + _S3 * var[row + 3]
                sx[row] = (_S0 * xi[xb, row] + _S1 * xi[xb, row + 1] + _S2 * xi[xb, row + 2]
                           + _S3 * xi[xb, row + 3])
        ok = False
        if structured:                                                      # step 3b
            if gu.shape[0] == 2 and not printed:    # the common width, unrolled
                ok = _structured_gram(m, n, dx, dy, ex, cb, sksb, gu, gv, printed, sv, sx, keep,
                                      Z, sb, R, wb, F, U, lb, li, qv, zz, P, H, X, G, 2, 4)
            else:
                ok = _structured_gram(m, n, dx, dy, ex, cb, sksb, gu, gv, printed, sv, sx, keep,
                                      Z, sb, R, wb, F, U, lb, li, qv, zz, P, H, X, G,
                                      gu.shape[0], F.shape[0])
        if not ok:
            dense = True
            if not _dense_gram(m, n, dx, dy, ex, c, sks, printed, sv, sx, keep, Z, M, ur, G):
                return np.nan, dense
    # step 3c: beta = (A~' W^-1 A~)^-1 A~' W^-1 S y; criterion r' W^-1 r
    if not _spd_inverse4(G, out_cov):
        return np.nan, dense
    crit = G[4, 4]
    for p in range(4):
        v = out_cov[p, 0] * G[0, 4] + out_cov[p, 1] * G[1, 4] + out_cov[p, 2] * G[2, 4] \
            + out_cov[p, 3] * G[3, 4]
        out_beta[p] = v
        crit -= v * G[p, 4]
    return crit, dense


@njit(cache=True)
def _gls_workspace(n, r):
    """Scratch arrays of :func:`_gls_one` for tracks of ``n`` samples and generators of
    width ``r``."""
    m = n - 3
    return (np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty((n, 4)),
            np.empty(m, np.bool_), np.empty((5, m)), np.empty((m, m + 5)), np.empty(n),
            np.empty(m), np.empty(m), np.empty((5, 5)),
            np.zeros((7, n)), np.zeros((7, m)), np.zeros((4, m + _PAD)), np.empty((r, m)),
            np.empty((r, m)),
            np.empty((m + _PAD, 4)), np.empty(m + _PAD), np.empty((m + _PAD, r)),
            np.empty((m + _PAD, r)), np.empty((r, r)), np.empty((r, 5)), np.empty((5, m + _PAD)))


@njit(cache=True)
def _blue_tracks_range(a0, a1, r, s, xi, mean, c, sks, cb, sksb, gu, gv, tv, kap, printed, var, tol,
                       max_iter, crit_stop, structured, out_ols, out_beta, out_cov, out_traj,
                       out_it, out_flags):
    """Steps 1-3d for the tracks ``a0 <= b < a1``, each iterated to its own stop (the
    rule of :meth:`ClosedFormTracker.locate`); ``out_flags[b]``: bit 0 converged, bit 1
    stalled (criterion stopping), bit 2 a matrix not positive definite, bit 3 the dense
    factorisation ran at least once (a structured pivot failed, or not ``structured``).
    ``out_traj[b]`` (n, 2): the straight track ``p_k + tv_i v_k`` at the final state, the
    arithmetic of :func:`~radioloc.models.single_sensor.trajectory` (no contraction here, so
    the same values bit for bit)."""
    n = r.shape[1]
    ws = _gls_workspace(n, 2 * gu.shape[0] + (2 if printed else 0))
    ols_step = a0 <= a1     # a run-time bool, not a literal: one compiled _gls_one for both calls
    zero = np.zeros(4)
    new = np.empty(4)
    new_cov = np.empty((4, 4))
    for b in range(a0, a1):
        beta = out_beta[b]
        cov = out_cov[b]
        crit, _ = _gls_one(b, r, s, xi, mean, zero, c, sks, cb, sksb, gu, gv, tv, kap, printed, var,
                           ols_step, structured, ws, out_ols[b], new_cov)
        flags = 4 if math.isnan(crit) else 0                               # step 3a
        beta[:] = out_ols[b]
        cov[:] = 0.0
        best = np.inf
        it = 0
        if flags == 0:
            for _ in range(max_iter):
                crit, dense = _gls_one(b, r, s, xi, mean, beta, c, sks, cb, sksb, gu, gv, tv, kap,
                                       printed, var, not ols_step, structured, ws, new, new_cov)
                if dense:
                    flags |= 8
                if math.isnan(crit):                                       # steps 3b-3c
                    flags |= 4
                    break
                if crit_stop and not crit < best:
                    flags |= 2
                    break
                change = 0.0
                for p in range(4):
                    change += (new[p] - beta[p]) ** 2
                change = math.sqrt(change)
                beta[:] = new
                cov[:] = new_cov
                best = crit
                it += 1
                if change <= tol:                                          # step 3d
                    flags |= 1
                    break
        out_it[b] = it
        out_flags[b] = flags
        traj = out_traj[b]
        for i in range(n):
            traj[i, 0] = beta[0] + tv[i] * beta[2]
            traj[i, 1] = beta[1] + tv[i] * beta[3]


@njit(parallel=True, cache=True)
def _blue_tracks(r, s, xi, mean, c, sks, cb, sksb, gu, gv, tv, kap, printed, var, tol, max_iter,
                 crit_stop, structured, out_ols, out_beta, out_cov, out_traj, out_it, out_flags):
    """:func:`_blue_tracks_range` for every track, in parallel over chunks of tracks that
    share one workspace."""
    B = r.shape[0]
    nch = min(B, 64)
    for ch in prange(nch):
        _blue_tracks_range(ch * B // nch, (ch + 1) * B // nch, r, s, xi, mean, c, sks, cb, sksb, gu, gv,
                           tv, kap, printed, var, tol, max_iter, crit_stop, structured,
                           out_ols, out_beta, out_cov, out_traj, out_it, out_flags)


def _noise_generators(n: int, k: int, T: float, accel_var: float):
    """Generators of the motion-noise covariance ``c`` (eq. (4), eq. (5)):
    ``c_pq = gu[:, p] . gv[:, q]`` for ``p < q``.

    With ``d = p - k`` after the reference sample and ``e = k - q`` before it (sums of
    ``c_{p,m} c_{q,m}`` over the shared accelerations, ``T^4 delta_g^2`` factored out)::

        c_pq = (q - k) d^2 / 2 - d (2 d^2 + 1) / 12     (k <= p < q)
        c_pq = (k - p) e^2 / 2 - e (2 e^2 + 1) / 12     (p < q <= k)
        c_pq = 0                                        (p < k < q)

    Returns
    -------
    gu, gv : ndarray, shape (rc, n)
        ``rc = 4``, or 2 when k is the first or last sample (one side is empty).
    """
    idx = np.arange(n, dtype=float)
    d = np.maximum(idx - k, 0.0)                    # after side
    e = np.maximum(k - idx, 0.0)                    # before side
    scale = T**4 * accel_var
    after = (np.stack([-d * (2.0 * d * d + 1.0) / 12.0, 0.5 * d * d], -1) * scale,
             np.stack([np.ones(n), idx - k], -1))
    before = (np.stack([np.ones(n), k - idx], -1) * scale,
              np.stack([-e * (2.0 * e * e + 1.0) / 12.0, 0.5 * e * e], -1))
    parts = [pr for pr, keep in ((after, k < n - 1), (before, k > 0)) if keep]
    gu = np.concatenate([pr[0] for pr in parts], -1)
    gv = np.concatenate([pr[1] for pr in parts], -1)
    return np.ascontiguousarray(gu.T), np.ascontiguousarray(gv.T)


def _run_blue_kernel(B: int, args: tuple) -> None:
    """Run :func:`_blue_tracks` (``B >= _PARALLEL_MIN_TRACKS``) or one thread of
    :func:`_blue_tracks_range` over the ``B`` tracks; outputs are written into ``args``."""
    if B >= _PARALLEL_MIN_TRACKS:
        _blue_tracks(*args)
    else:
        _blue_tracks_range(0, B, *args)


class ClosedFormTracker(SnapshotEstimator):
    """The closed-form tracker of paper 002: the iterative BLUE of the differenced model.

    From ranges to one moving sensor over a window of n uniformly spaced samples it
    estimates the straight-track state ``[x_k, y_k, vx_k, vy_k]`` at a reference sample k
    (default the last one: the current position) without iterating on the ranges
    themselves: every step is a linear solve (steps 1-3d, see the module docstring).

    Parameters
    ----------
    accel_var : float
        ``delta_g^2`` of eq. (1), per axis, (m/s^2)^2.
    range_var : float or array_like, shape (n,) or (..., n)
        Channel noise variance ``xi_n`` in m^2; 0 is the ideal channel of eq. (11).
    reference_index : int, optional
        k; default the last sample (n-1); negative values count from the end.
    weighting : {"blue", "ols"}
        ``"blue"``: the iterative BLUE (the paper's method). ``"ols"``: step 3a only, every
        differenced equation weighted equally (the reading of the paper's MANOVA baseline);
        its covariance is the sandwich ``(A~'A~)^{-1} A~' Sigma~ A~ (A~'A~)^{-1}`` at the
        OLS estimate.
    accel_excess_kurtosis, range_excess_kurtosis : float
        0 (default) uses the Gaussian moments printed in eq. (11)-eq. (14); -1.2 is exact
        for uniform noise.
    tol : float
        Stopping rule ``|beta_{m+1} - beta_m| <= tol`` (Euclidean norm of the change of
        ``[x, y, vx, vy]``); section 5.2's ``|.|^2 <= 0.1`` is the default ``sqrt(0.1)``.
    stopping : {"change", "criterion"}
        ``"change"`` (default, the paper's step 3d): iterate until the change is below
        ``tol`` or ``max_iter``. ``"criterion"``: also stop (keeping the previous estimate)
        as soon as the GLS criterion ``r' Sigma~^{-1} r`` does not decrease.
    max_iter : int
        Maximum BLUE iterations after the OLS start.
    cond_limit : float
        ``S A`` with a column-scaled condition number above this raises ``GeometryError``.
    printed_eq14 : bool
        Use eq. (14)'s printed off-diagonal channel terms (a reading kept for comparison;
        see :class:`~radioloc.models.single_sensor.SquaredRangeModel`).

    Examples
    --------
    >>> import numpy as np
    >>> n, T = 20, 0.1
    >>> ang = 1.3 * np.arange(n)
    >>> sensor = 5.0 * np.stack([np.cos(ang), np.sin(ang)], -1)
    >>> truth = np.array([1.0, 0.5]) + (np.arange(n) - (n - 1))[:, None] * T * [0.8, -0.2]
    >>> ranges = np.linalg.norm(truth - sensor, axis=-1)
    >>> est = ClosedFormTracker(accel_var=0.0, range_var=1e-10).locate(ranges, sensor, T)
    >>> np.round(est.position, 6).tolist(), np.round(est.diagnostics["state"][2:], 6).tolist()
    ([1.0, 0.5], [0.8, -0.2])
    """

    name = "closed-form"

    def __init__(self, accel_var: float, range_var=0.0, *, reference_index: int | None = None,
                 weighting: str = "blue", accel_excess_kurtosis: float = 0.0,
                 range_excess_kurtosis: float = 0.0, tol: float = 0.1**0.5,
                 stopping: str = "change", max_iter: int = 20, cond_limit: float = 1e12,
                 printed_eq14: bool = False) -> None:
        self.accel_var = check_positive(accel_var, "accel_var", allow_zero=True)
        self.range_var = as_float_array(range_var, "range_var", nonnegative=True)
        if reference_index is not None and not isinstance(reference_index, (int, np.integer)):
            raise ConfigError(f"reference_index: must be an int or None, got {reference_index!r}")
        self.reference_index = None if reference_index is None else int(reference_index)
        if weighting not in WEIGHTINGS:
            raise ConfigError(f"weighting: must be one of {', '.join(WEIGHTINGS)}, "
                              f"got {weighting!r}")
        self.weighting = weighting
        for name, val in (("accel_excess_kurtosis", accel_excess_kurtosis),
                          ("range_excess_kurtosis", range_excess_kurtosis)):
            if not np.isfinite(val) or val < -2.0:
                raise ConfigError(f"{name}: must be finite and >= -2, got {val!r}")
        self.accel_excess_kurtosis = float(accel_excess_kurtosis)
        self.range_excess_kurtosis = float(range_excess_kurtosis)
        self.tol = check_positive(tol, "tol")
        if stopping not in STOPPING:
            raise ConfigError(f"stopping: must be one of {', '.join(STOPPING)}, "
                              f"got {stopping!r}")
        self.stopping = stopping
        self.max_iter = check_int(max_iter, "max_iter", minimum=0, maximum=MAX_ITERATIONS)
        self.cond_limit = check_positive(cond_limit, "cond_limit")
        self.printed_eq14 = bool(printed_eq14)

    def locate(self, ranges, sensor_path, sample_period_s: float | None = None, *,
               time=None, covariance_state=None) -> Estimate:
        """Estimate the state at sample k from one window of ranges (steps 1-3d).

        Parameters
        ----------
        ranges : array_like, shape (..., n)
            Measured ranges ``rhat_n`` (eq. (12)), n >= 7; leading axes are independent
            problems. A NaN range is a missing sample: the difference rows that involve it
            are dropped (at least 4 differences must remain).
        sensor_path : array_like, shape (n, 2) or (..., n, 2)
            Known sensor positions ``(a_n, b_n)``; must not be quadratic in n.
        sample_period_s : float, optional
            T; or give ``time``.
        time : array_like, shape (n,) or (..., n), optional
            Uniformly spaced sample times, seconds.
        covariance_state : array_like, shape (4,) or (..., 4), optional
            If given, one BLUE step with ``Sigma~`` evaluated at this ``[x, y, vx, vy]``
            (e.g. the true state: the oracle BLUE) instead of the iterations 3b-3d.

        Returns
        -------
        Estimate
            ``position`` (..., 2) = ``(x_k, y_k)``, ``covariance`` (..., 2, 2) (its block of
            eq. (15)), ``time`` of sample k; diagnostics ``state`` (..., 4)
            ``[x_k, y_k, vx_k, vy_k]``, ``state_covariance`` (..., 4, 4), ``trajectory``
            (..., n, 2) (the straight track ``p_k + (n-k) T v_k`` at every sample),
            ``ols_state`` (..., 4) (step 3a), ``iterations``, ``converged`` (the step rule
            met), ``stalled`` (``stopping="criterion"``: stopped because the GLS criterion
            no longer decreased), ``used_differences`` (rows of ``S y`` kept).

        Raises
        ------
        InputError
            Bad shapes, negative or infinite ranges, fewer than 7 samples, k out of range,
            non-uniform ``time``.
        GeometryError
            Sensor path quadratic in n, or ``S A`` numerically rank deficient (when missing
            (NaN) ranges leave too few difference rows, the message names ``ranges`` and the
            track), or a singular noise
            covariance (zero motion and channel noise).
        """
        r, s, k = validate_inputs(ranges, sensor_path, self.reference_index, allow_nan=True)
        n = r.shape[-1]
        T, t_k = resolve_sampling(n, k, sample_period_s, time)
        batch = np.broadcast_shapes(r.shape[:-1], s.shape[:-2], self.range_var.shape[:-1])
        r = np.broadcast_to(r, batch + (n,))
        s = np.broadcast_to(s, batch + (n, 2))
        model = SquaredRangeModel(n, k, T, self.accel_var, self.range_var,
                                  self.accel_excess_kurtosis, self.range_excess_kurtosis,
                                  self.printed_eq14)
        if self.weighting == "blue" and covariance_state is None:
            return self._locate_compiled(r, s, k, T, t_k, model, batch)
        sa, sy, keep = self._differenced_system(r, s, k, model)    # steps 1-2

        def cov_at(state):
            return _mask_covariance(model.differenced_covariance(state, s), keep)
        self._check_condition(sa, keep)
        ols = _ols(sa, sy)                                          # step 3a
        ones = np.ones(batch, dtype=bool)
        if covariance_state is not None:
            fixed = as_float_array(covariance_state, "covariance_state", min_ndim=1, last_dim=4)
            fixed = np.broadcast_to(fixed, batch + (4,))
            beta, cov, _ = _gls(sa, sy, cov_at(fixed))
            return self._estimate(beta, cov, ols, n, T, k, t_k, np.ones(batch, dtype=int),
                                  ones, ~ones, keep)
        if self.weighting == "ols":
            at = np.swapaxes(sa, -1, -2)
            bread = np.linalg.inv(at @ sa)
            cov = bread @ at @ cov_at(ols) @ sa @ bread
            return self._estimate(ols, cov, ols, n, T, k, t_k, np.zeros(batch, dtype=int),
                                  ones, ~ones, keep)
        beta = ols.copy()
        best_crit = np.full(batch, np.inf)
        cov = np.zeros(batch + (4, 4))
        active = np.ones(batch, dtype=bool)
        converged = np.zeros(batch, dtype=bool)
        stalled = np.zeros(batch, dtype=bool)
        iterations = np.zeros(batch, dtype=int)
        for _ in range(self.max_iter):
            if not np.any(active):
                break
            w = cov_at(beta)                                        # step 3b
            new, new_cov, crit = _gls(sa, sy, w)                    # step 3c
            improved = (crit < best_crit) | (self.stopping == "change")
            take = active & improved
            stalled |= active & ~improved
            change = np.sqrt(np.sum((new - beta) ** 2, axis=-1))
            beta = np.where(take[..., None], new, beta)
            cov = np.where(take[..., None, None], new_cov, cov)
            best_crit = np.where(take, crit, best_crit)
            iterations = iterations + take
            done = take & (change <= self.tol)                      # step 3d
            converged |= done
            active = take & ~done
        check_finite_output(beta, "ClosedFormTracker state")
        return self._estimate(beta, cov, ols, n, T, k, t_k, iterations, converged, stalled,
                              keep)

    # ---- helpers --------------------------------------------------------------------
    def _check_condition(self, sa: np.ndarray, keep: np.ndarray | None = None,
                         tracks: np.ndarray | None = None) -> None:
        """GeometryError when ``S A`` (column-scaled) is numerically rank deficient, naming
        ``ranges`` and the track when it is so because difference rows were
        dropped for missing (NaN) ranges (``keep`` (..., n - 3) False). ``tracks``: the
        flat track number of each entry of ``sa`` (default: its flat index)."""
        col = np.linalg.norm(sa, axis=-2, keepdims=True)
        cond = np.linalg.cond(sa / np.where(col > 0, col, 1.0))
        bad = ~np.isfinite(cond) | (cond > self.cond_limit)
        if np.any(bad) and keep is not None:
            rows = keep.reshape(-1, keep.shape[-1])
            gap = np.ravel(bad) & ~np.all(rows, axis=-1)
            if np.any(gap):
                i = int(np.flatnonzero(gap)[0])
                track = int(tracks[i]) if tracks is not None else i
                raise GeometryError(f"ranges: the missing (NaN) ranges of track {track} leave "
                                    f"{int(np.sum(rows[i]))} of {rows.shape[-1]} difference "
                                    "rows, too few to separate [x_k, y_k, vx_k, vy_k] (S A "
                                    "rank deficient)")
        if np.any(bad):
            raise GeometryError(f"sensor_path: S A is rank deficient (condition number "
                                f"{np.max(cond):.3g} > {self.cond_limit:.0e}); the sensor path "
                                "does not separate [x_k, y_k, vx_k, vy_k]")

    def _locate_compiled(self, r, s, k, T, t_k, model, batch) -> Estimate:
        """Steps 1-3d by the compiled kernel (:func:`_blue_tracks`): the same estimate as
        the NumPy path (``_differenced_system`` and ``_gls``) up to rounding."""
        n = r.shape[-1]
        B = int(np.prod(batch, dtype=np.int64))
        rr = np.ascontiguousarray(r.reshape(B, n), dtype=float)
        shared = s.ndim == 2 or all(st == 0 for st in s.strides[:-2])
        ss = np.ascontiguousarray((s[(0,) * (s.ndim - 2)] if shared else s)
                                  .reshape(-1, n, 2), dtype=float)
        xi = np.broadcast_to(model.xi, model.xi.shape[:-1] + (n,)) if model.xi.ndim else \
            np.full(n, float(model.xi))
        xi = np.ascontiguousarray(np.broadcast_to(xi, batch + (n,)).reshape(B, n)
                                  if xi.ndim > 1 else xi[None], dtype=float)
        var = np.ascontiguousarray(np.diag(model.c))
        mean = 2.0 * var + xi                                       # E[e_n], step 1
        sks = np.ascontiguousarray(difference_both(2.0 * model.c_sq))
        tv = (np.arange(n) - k) * T
        missing = np.isnan(rr)
        m = missing.astype(np.int8)
        keep = (m[:, :-3] + m[:, 1:-2] + m[:, 2:-1] + m[:, 3:]) == 0
        # the rank check of S A: once for a shared sensor path and no missing sample,
        # else on the tracks whose S A differs
        odd = ~keep.all(axis=1) if ss.shape[0] == 1 else np.ones(B, dtype=bool)
        if not odd.all():
            self._check_condition(difference_rows(design_matrix(ss[0], T, k)))
        if odd.any():
            sa = np.where(keep[odd][..., None],
                          difference_rows(design_matrix(ss if ss.shape[0] == 1 else ss[odd], T, k)),
                          0.0)
            self._check_condition(sa, keep[odd], np.flatnonzero(odd))
        ols = np.empty((B, 4))
        beta = np.empty((B, 4))
        cov = np.empty((B, 4, 4))
        traj = np.empty((B, n, 2))
        iterations = np.empty(B, dtype=np.int64)
        flags = np.empty(B, dtype=np.int64)
        gu, gv = _noise_generators(n, k, T, self.accel_var)
        cb = np.zeros((7, n))                                       # c_{p, p+d}, d <= 6
        sksb = np.zeros((4, n - 3))                                 # (S 2 C2 S')_{j, j+l}
        for d in range(7):
            cb[d, :n - d] = np.diagonal(model.c, d)
            if d < 4:
                sksb[d, :n - 3 - d] = np.diagonal(sks, d)
        # one array type per argument (C-contiguous, writeable float64): a read-only view
        # (e.g. a broadcast) would otherwise compile the kernels once more
        rr, ss, xi = (kernel_array(x) for x in (rr, ss, xi))
        args = (rr, ss, xi, mean, model.c, sks, cb, sksb, gu, gv, tv, self.range_excess_kurtosis,
                self.printed_eq14, var, self.tol, self.max_iter, self.stopping == "criterion",
                _STRUCTURED, ols, beta, cov, traj, iterations, flags)
        _run_blue_kernel(B, args)                                   # steps 3a-3d
        if np.any(flags & 4):
            raise GeometryError("S Sigma S^T is singular (not positive definite); the motion "
                                "and channel noise variances cannot both be zero for the BLUE")
        converged = (flags & 1) > 0
        stalled = (flags & 2) > 0
        check_finite_output(beta, "ClosedFormTracker state")
        shape = lambda a, tail: a.reshape(batch + tail)             # noqa: E731
        return self._estimate(shape(beta, (4,)), shape(cov, (4, 4)), shape(ols, (4,)), n, T, k,
                              t_k, shape(iterations, ()), shape(converged, ()),
                              shape(stalled, ()), shape(keep, (n - 3,)), shape(traj, (n, 2)))

    @staticmethod
    def _differenced_system(r, s, k, model):
        """Steps 1-2: mean-removed ``y`` and its third difference.

        Returns ``(S A, S y, keep)``; ``keep`` (..., n - 3) marks the difference rows
        whose four samples are all present; the others are zeroed.
        """
        missing = np.isnan(r)
        y = np.where(missing, 0.0, r**2 - np.sum(s**2, axis=-1) - model.noise_mean())
        sa = difference_rows(design_matrix(s, model.T, k))
        sy = difference_rows(y[..., None])[..., 0]
        m = missing.astype(float)[..., None]
        keep = (m[..., :-3, 0] + m[..., 1:-2, 0] + m[..., 2:-1, 0] + m[..., 3:, 0]) == 0
        sa = np.where(keep[..., None], np.broadcast_to(sa, sy.shape + (4,)), 0.0)
        sy = np.where(keep, sy, 0.0)
        return sa, sy, keep

    @staticmethod
    def _estimate(beta, cov, ols, n, T, k, t_k, iterations, converged, stalled, keep,
                  traj=None) -> Estimate:
        """The Estimate of :meth:`ClosedFormTracker.locate`; ``traj``: the trajectory
        diagnostic when the kernel wrote it (else computed here)."""
        if traj is None:
            traj = trajectory(beta, n, T, k)
        diag = {"state": beta, "state_covariance": cov, "trajectory": traj,
                "ols_state": ols, "iterations": iterations, "converged": converged,
                "stalled": stalled, "used_differences": np.sum(keep, axis=-1)}
        return Estimate(beta[..., :2], cov[..., :2, :2], t_k, diag)
