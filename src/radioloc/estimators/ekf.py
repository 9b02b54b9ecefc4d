"""Sequential EKF network positioning over the stacked 2K state (Brown & Iltis,
eq. (13)-eq. (25)).

The state is ``x = [x_1; ...; x_K]`` (eq. (13)), static, so the prediction is the identity
(eq. (20), eq. (24)). At each packet a master node ``k`` measures its ranges to the others
(eq. (14), eq. (15)) and updates the *global* estimate (eq. (19), eq. (21), eq. (22),
eq. (23)); the next master starts from that estimate. A missing link (NaN range, or a
false mask entry) is a row skipped by the update.

The update is the toolkit's one Kalman update
(:func:`radioloc.estimators.kalman.kalman_update`): the Joseph form
``(I - L H^T) S (I - L H^T)^T + L R L^T``, algebraically eq. (21) but symmetric and
positive semi-definite in floating point, symmetrised after each update. :class:`NetworkEKF`
runs the same maths in a compiled kernel (:func:`_packets`, groups of eight runs, the run
the innermost axis) that uses the structure of a master's Jacobian (row ``p`` has nonzeros
only in the blocks of node ``p`` and of the master ``k``): ``A = Sigma H^T`` costs two
2-column products per row instead of a dense product, the ``K x K`` innovation covariance
is solved by Cholesky, and the Joseph form is evaluated as
``Sigma + (L S - A) L^T - L A^T`` (the same expression expanded); results equal
``kalman_update``'s to rounding (``tests/test_bench_network.py`` checks 1e-9).
:meth:`NetworkEKF.iterate`, where packet ``j`` has the same master in every run, uses
:func:`_packets_shared`: the master's own row (zero in ``H``, a unit diagonal in ``S``,
exact zeros in every sum) is left out, so ``A``, ``S`` and the gain have ``K - 1`` rows, and
for ``K = 6`` (paper 000) :func:`_packets_shared6`, whose sizes are compile-time constants
(loops over the rows unrolled inside the SIMD loop over the runs); both give the numbers
of :func:`_packets` bit for bit (tested).

:class:`NetworkEKF` advances a batch of ``R`` independent runs: state ``(R, 2K)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from radioloc.core.arrays import kernel_array
from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.results import Estimate, Track
from radioloc.core.validation import check_finite_output, check_positive
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.network import (check_iteration, check_packet, check_prior,
                                         run_iterations)

__all__ = ["NetworkEKF", "EKFState", "range_jacobian"]


@dataclass(frozen=True)
class EKFState:
    """Filter state of ``R`` independent runs of the sequential EKF.

    Attributes
    ----------
    mean : ndarray, shape (R, 2K)
        Stacked estimate ``[x_1, y_1, x_2, y_2, ...]`` (eq. (13)), metres.
    covariance : ndarray, shape (R, 2K, 2K)
        ``Sigma`` of eq. (21), m^2.
    nis : ndarray, shape (R, K)
        Normalised innovation squared of each node's latest packet as master (NaN
        before its first).
    used : ndarray of int, shape (R, K)
        Ranges that entered each node's latest packet (0 before its first).
    """

    mean: np.ndarray
    covariance: np.ndarray
    nis: np.ndarray
    used: np.ndarray

    @property
    def runs(self) -> int:
        """Number of runs ``R``."""
        return self.mean.shape[0]

    @property
    def nodes(self) -> int:
        """Number of nodes ``K``."""
        return self.mean.shape[1] // 2

    @property
    def position(self) -> np.ndarray:
        """``(R, K, 2)`` view of the estimates."""
        return self.mean.reshape(self.runs, self.nodes, 2)

    @property
    def position_covariance(self) -> np.ndarray:
        """``(R, K, 2, 2)`` diagonal blocks of the covariance (each node's own)."""
        R, K = self.runs, self.nodes
        c = self.covariance.reshape(R, K, 2, K, 2)
        k = np.arange(K)
        return c[:, k, :, k, :].transpose(1, 0, 2, 3)


def range_jacobian(position: np.ndarray, master: np.ndarray, valid: np.ndarray | None = None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Predicted ranges ``h_k(x)`` (eq. (15)) and Jacobian ``H_k^T`` (eq. (16), eq. (17)).

    Row ``p`` of ``H_k^T`` holds ``u^T = (x_p - x_k)^T / |x_p - x_k|`` in column block ``p``
    and ``-u^T`` in column block ``k``. eq. (17) prints the same sign for both blocks; the
    derivative of ``|x_p - x_k|`` with respect to ``x_k`` is the negative of that with
    respect to ``x_p``, which is what is implemented here.

    Parameters
    ----------
    position : ndarray, shape (R, K, 2)
        Current estimates, metres.
    master : ndarray of int, shape (R,)
        The master node of each run.
    valid : ndarray of bool, shape (R, K), optional
        Rows with a false entry (and the master's own row) are zero.

    Returns
    -------
    h : ndarray, shape (R, K)
        Predicted ranges (0 on the master's own entry).
    H : ndarray, shape (R, K, 2K)
        Jacobian, one row per node ``p``.

    Raises
    ------
    GeometryError
        If a valid row has the master and node ``p`` at the same estimated position.
    """
    R, K, _ = position.shape
    rr = np.arange(R)
    if valid is None:
        valid = np.ones((R, K), dtype=bool)
        valid[rr, master] = False
    diff = position - position[rr, master][:, None, :]              # x_p - x_k
    h = np.sqrt(np.einsum("rkd,rkd->rk", diff, diff))
    scale = np.maximum(np.max(np.abs(position), axis=(1, 2)), 1.0)
    coincident = valid & (h <= 1e-9 * scale[:, None])
    if np.any(coincident):
        r, p = (int(i) for i in np.argwhere(coincident)[0])
        raise GeometryError(f"run {r}: nodes {int(master[r])} and {p} have coincident position "
                            "estimates; the range Jacobian is undefined", index=(r,),
                            detail=f"nodes {int(master[r])} and {p} have coincident estimates")
    u = np.where(valid[..., None], diff / np.where(h > 0, h, 1.0)[..., None], 0.0)
    H = np.zeros((R, K, K, 2))
    kk = np.arange(K)
    H[:, kk, kk, :] = u                                              # d h_p / d x_p = +u^T
    H[rr, :, master, :] = -u                                         # d h_p / d x_k = -u^T
    return h, H.reshape(R, K, 2 * K)


_LANES = 8
_SHARED_LANES = 16      # runs per group of _packets_shared (long enough inner loops to vectorise)


@njit(parallel=True, cache=True, error_model="numpy")
def _packets(mean, cov, masters, rho, valid, var, nis, used, err):  # pragma: no cover - jit
    """Sequential EKF updates of every run by its packets ``j`` in order.

    Runs are processed ``_LANES`` at a time, the run being the innermost (SIMD) axis of every
    local array; ``prange`` over the groups. ``mean (R, n)`` and ``cov (R, n, n)`` are
    updated in place; ``masters (R, M)``, ``rho (R, M, K)``, ``valid (R, M, K)``;
    ``nis``/``used (R, K)`` receive each master's NIS and number of ranges; ``err (R, 2)``
    the first packet and node with coincident estimates (-1 if none).
    """
    R, n = mean.shape
    M = masters.shape[1]
    K = n // 2
    W = _LANES
    for g in prange((R + W - 1) // W):
        r0 = g * W
        run = np.empty(W, np.int64)
        for l in range(W):
            run[l] = min(r0 + l, R - 1)                      # the last group is padded
        x = np.empty((n, W))
        P = np.empty((n, n, W))
        for l in range(W):
            for i in range(n):
                x[i, l] = mean[run[l], i]
                for c in range(n):
                    P[i, c, l] = cov[run[l], i, c]
        km = np.empty(W, np.int64)
        u0 = np.empty((K, W))
        u1 = np.empty((K, W))
        nu = np.empty((K, W))
        ok = np.empty((K, W), np.bool_)
        A = np.empty((n, K, W))
        S = np.empty((K, K, W))
        L = np.zeros((K, K, W))
        Kt = np.empty((K, n, W))
        D = np.empty((n, K, W))
        t1 = np.empty(W)
        g0 = np.empty(W)
        g1 = np.empty(W)
        ak0 = np.empty((K, W))
        ak1 = np.empty((K, W))
        scale = np.empty(W)
        for j in range(M):
            for l in range(W):
                km[l] = masters[run[l], j]
                sc = 1.0
                for i in range(n):
                    sc = max(sc, abs(x[i, l]))
                scale[l] = sc
            for p in range(K):
                for l in range(W):
                    k = km[l]
                    o = valid[run[l], j, p]
                    dx = x[2 * p, l] - x[2 * k, l]
                    dy = x[2 * p + 1, l] - x[2 * k + 1, l]
                    h = math.sqrt(dx * dx + dy * dy)
                    if o and h <= 1e-9 * scale[l]:
                        if r0 + l < R and err[run[l], 0] < 0:
                            err[run[l], 0] = j
                            err[run[l], 1] = p
                        o = False
                    ok[p, l] = o
                    u0[p, l] = dx / h if o else 0.0
                    u1[p, l] = dy / h if o else 0.0
                    nu[p, l] = rho[run[l], j, p] - h if o else 0.0
            # A = Sigma H^T: column p = (Sigma[:, block p] - Sigma[:, block k]) u_p
            for i in range(n):
                for l in range(W):                           # the master's block, gathered
                    g0[l] = P[i, 2 * km[l], l]
                    g1[l] = P[i, 2 * km[l] + 1, l]
                for p in range(K):
                    for l in range(W):
                        A[i, p, l] = ((P[i, 2 * p, l] - g0[l]) * u0[p, l]
                                      + (P[i, 2 * p + 1, l] - g1[l]) * u1[p, l])
            # S = H A + R (identity rows and columns for links not used), symmetrised
            for q in range(K):
                for l in range(W):
                    ak0[q, l] = A[2 * km[l], q, l]
                    ak1[q, l] = A[2 * km[l] + 1, q, l]
            for p in range(K):
                for q in range(K):
                    for l in range(W):
                        S[p, q, l] = ((A[2 * p, q, l] - ak0[q, l]) * u0[p, l]
                                      + (A[2 * p + 1, q, l] - ak1[q, l]) * u1[p, l])
                for l in range(W):
                    S[p, p, l] += var if ok[p, l] else 1.0
            for p in range(K):
                for q in range(p + 1, K):
                    for l in range(W):
                        v = 0.5 * (S[p, q, l] + S[q, p, l])
                        S[p, q, l] = v
                        S[q, p, l] = v
            # Cholesky S = L L^T
            for p in range(K):
                for q in range(p + 1):
                    for l in range(W):
                        t1[l] = S[p, q, l]
                    for t in range(q):
                        for l in range(W):
                            t1[l] -= L[p, t, l] * L[q, t, l]
                    if p == q:
                        for l in range(W):
                            L[p, p, l] = math.sqrt(t1[l])
                    else:
                        for l in range(W):
                            L[p, q, l] = t1[l] / L[q, q, l]
            # Kt = S^-1 A^T (the gain, transposed)
            for i in range(n):
                for p in range(K):                           # forward
                    for l in range(W):
                        t1[l] = A[i, p, l]
                    for t in range(p):
                        for l in range(W):
                            t1[l] -= L[p, t, l] * Kt[t, i, l]
                    for l in range(W):
                        Kt[p, i, l] = t1[l] / L[p, p, l]
                for p in range(K - 1, -1, -1):               # backward
                    for l in range(W):
                        t1[l] = Kt[p, i, l]
                    for t in range(p + 1, K):
                        for l in range(W):
                            t1[l] -= L[t, p, l] * Kt[t, i, l]
                    for l in range(W):
                        Kt[p, i, l] = t1[l] / L[p, p, l]
            # NIS = |L^-1 nu|^2 (nu overwritten by L^-1 nu after the mean update)
            for i in range(n):
                for l in range(W):
                    t1[l] = 0.0
                for p in range(K):
                    for l in range(W):
                        t1[l] += Kt[p, i, l] * nu[p, l]
                for l in range(W):
                    x[i, l] += t1[l]
            for p in range(K):
                for t in range(p):
                    for l in range(W):
                        nu[p, l] -= L[p, t, l] * nu[t, l]
                for l in range(W):
                    nu[p, l] /= L[p, p, l]
            for l in range(W):
                if r0 + l < R:
                    acc = 0.0
                    cnt = 0
                    for p in range(K):
                        acc += nu[p, l] * nu[p, l]
                        cnt += 1 if ok[p, l] else 0
                    nis[run[l], km[l]] = acc
                    used[run[l], km[l]] = cnt
            # Joseph form expanded: Sigma + (L S - A) L^T - L A^T, then symmetrised
            for i in range(n):
                for q in range(K):
                    for l in range(W):
                        t1[l] = -A[i, q, l]
                    for p in range(K):
                        for l in range(W):
                            t1[l] += Kt[p, i, l] * S[p, q, l]
                    for l in range(W):
                        D[i, q, l] = t1[l]
            for i in range(n):
                for c in range(i, n):
                    for l in range(W):
                        t1[l] = 0.0
                    for p in range(K):
                        for l in range(W):
                            t1[l] += D[i, p, l] * Kt[p, c, l] - Kt[p, i, l] * A[c, p, l]
                    for l in range(W):
                        a = P[i, c, l] + t1[l]
                        b = P[c, i, l] + t1[l]
                        v = 0.5 * (a + b)
                        P[i, c, l] = v
                        P[c, i, l] = v
        for l in range(W):
            if r0 + l < R:
                r = r0 + l
                for i in range(n):
                    mean[r, i] = x[i, l]
                    for c in range(n):
                        cov[r, i, c] = P[i, c, l]


@njit(parallel=True, cache=True, error_model="numpy")
def _packets_shared(mean, cov, masters, rho, valid, var, nis, used, err):  # pragma: no cover - jit
    """:func:`_packets` when packet ``j`` has the same master ``masters[j]`` in every run
    (:meth:`NetworkEKF.iterate`): the master's own row of the Jacobian, zero, with a unit
    diagonal in ``S`` (it adds exact zeros to every sum of :func:`_packets`), is left out,
    so ``A``, ``S``, its Cholesky factor and the gain have ``K - 1`` rows, and the master's
    blocks are read at a fixed index instead of gathered lane by lane. ``masters (M,)``;
    the other arguments as in :func:`_packets`. The same operations in the same order on
    the rows kept: the results are those of :func:`_packets`."""
    R, n = mean.shape
    M = masters.shape[0]
    K = n // 2
    m = K - 1
    W = _SHARED_LANES
    for g in prange((R + W - 1) // W):
        r0 = g * W
        run = np.empty(W, np.int64)
        for l in range(W):
            run[l] = min(r0 + l, R - 1)                      # the last group is padded
        x = np.empty((n, W))
        P = np.empty((n, n, W))
        for l in range(W):
            for i in range(n):
                x[i, l] = mean[run[l], i]
                for c in range(n):
                    P[i, c, l] = cov[run[l], i, c]
        node = np.empty(m, np.int64)
        u0 = np.empty((m, W))
        u1 = np.empty((m, W))
        nu = np.empty((m, W))
        ok = np.empty((m, W), np.bool_)
        A = np.empty((n, m, W))
        S = np.empty((m, m, W))
        L = np.zeros((m, m, W))
        Kt = np.empty((m, n, W))
        D = np.empty((n, m, W))
        t1 = np.empty(W)
        ak0 = np.empty((m, W))
        ak1 = np.empty((m, W))
        scale = np.empty(W)
        for j in range(M):
            k = masters[j]
            for a in range(m):
                node[a] = a if a < k else a + 1
            for l in range(W):
                sc = 1.0
                for i in range(n):
                    sc = max(sc, abs(x[i, l]))
                scale[l] = sc
            for a in range(m):
                p = node[a]
                for l in range(W):
                    o = valid[run[l], j, p]
                    dx = x[2 * p, l] - x[2 * k, l]
                    dy = x[2 * p + 1, l] - x[2 * k + 1, l]
                    h = math.sqrt(dx * dx + dy * dy)
                    if o and h <= 1e-9 * scale[l]:
                        if r0 + l < R and err[run[l], 0] < 0:
                            err[run[l], 0] = j
                            err[run[l], 1] = p
                        o = False
                    ok[a, l] = o
                    u0[a, l] = dx / h if o else 0.0
                    u1[a, l] = dy / h if o else 0.0
                    nu[a, l] = rho[run[l], j, p] - h if o else 0.0
            # A = Sigma H^T: column a = (Sigma[:, block p] - Sigma[:, block k]) u_a
            for i in range(n):
                Pi = P[i]
                for a in range(m):
                    p = node[a]
                    for l in range(W):
                        A[i, a, l] = ((Pi[2 * p, l] - Pi[2 * k, l]) * u0[a, l]
                                      + (Pi[2 * p + 1, l] - Pi[2 * k + 1, l]) * u1[a, l])
            # S = H A + R (identity rows and columns for links not used), symmetrised
            for q in range(m):
                for l in range(W):
                    ak0[q, l] = A[2 * k, q, l]
                    ak1[q, l] = A[2 * k + 1, q, l]
            for a in range(m):
                p = node[a]
                for q in range(m):
                    for l in range(W):
                        S[a, q, l] = ((A[2 * p, q, l] - ak0[q, l]) * u0[a, l]
                                      + (A[2 * p + 1, q, l] - ak1[q, l]) * u1[a, l])
                for l in range(W):
                    S[a, a, l] += var if ok[a, l] else 1.0
            for a in range(m):
                for q in range(a + 1, m):
                    for l in range(W):
                        v = 0.5 * (S[a, q, l] + S[q, a, l])
                        S[a, q, l] = v
                        S[q, a, l] = v
            # Cholesky S = L L^T
            for a in range(m):
                for q in range(a + 1):
                    for l in range(W):
                        t1[l] = S[a, q, l]
                    for t in range(q):
                        for l in range(W):
                            t1[l] -= L[a, t, l] * L[q, t, l]
                    if a == q:
                        for l in range(W):
                            L[a, a, l] = math.sqrt(t1[l])
                    else:
                        for l in range(W):
                            L[a, q, l] = t1[l] / L[q, q, l]
            # Kt = S^-1 A^T (the gain, transposed)
            for i in range(n):
                for a in range(m):                           # forward
                    for l in range(W):
                        t1[l] = A[i, a, l]
                    for t in range(a):
                        for l in range(W):
                            t1[l] -= L[a, t, l] * Kt[t, i, l]
                    for l in range(W):
                        Kt[a, i, l] = t1[l] / L[a, a, l]
                for a in range(m - 1, -1, -1):               # backward
                    for l in range(W):
                        t1[l] = Kt[a, i, l]
                    for t in range(a + 1, m):
                        for l in range(W):
                            t1[l] -= L[t, a, l] * Kt[t, i, l]
                    for l in range(W):
                        Kt[a, i, l] = t1[l] / L[a, a, l]
            # NIS = |L^-1 nu|^2 (nu overwritten by L^-1 nu after the mean update)
            for i in range(n):
                for l in range(W):
                    t1[l] = 0.0
                for a in range(m):
                    for l in range(W):
                        t1[l] += Kt[a, i, l] * nu[a, l]
                for l in range(W):
                    x[i, l] += t1[l]
            for a in range(m):
                for t in range(a):
                    for l in range(W):
                        nu[a, l] -= L[a, t, l] * nu[t, l]
                for l in range(W):
                    nu[a, l] /= L[a, a, l]
            for l in range(W):
                if r0 + l < R:
                    acc = 0.0
                    cnt = 0
                    for a in range(m):
                        acc += nu[a, l] * nu[a, l]
                        cnt += 1 if ok[a, l] else 0
                    nis[run[l], k] = acc
                    used[run[l], k] = cnt
            # Joseph form expanded: Sigma + (L S - A) L^T - L A^T, then symmetrised
            for i in range(n):
                for q in range(m):
                    for l in range(W):
                        t1[l] = -A[i, q, l]
                    for a in range(m):
                        for l in range(W):
                            t1[l] += Kt[a, i, l] * S[a, q, l]
                    for l in range(W):
                        D[i, q, l] = t1[l]
            for i in range(n):
                for c in range(i, n):
                    for l in range(W):
                        t1[l] = 0.0
                    for a in range(m):
                        for l in range(W):
                            t1[l] += D[i, a, l] * Kt[a, c, l] - Kt[a, i, l] * A[c, a, l]
                    for l in range(W):
                        u = P[i, c, l] + t1[l]
                        b = P[c, i, l] + t1[l]
                        v = 0.5 * (u + b)
                        P[i, c, l] = v
                        P[c, i, l] = v
        for l in range(W):
            if r0 + l < R:
                r = r0 + l
                for i in range(n):
                    mean[r, i] = x[i, l]
                    for c in range(n):
                        cov[r, i, c] = P[i, c, l]


_K6, _M6, _N6 = 6, 5, 12                 # the six-node network of paper 000, specialised


@njit(parallel=True, cache=True, error_model="numpy")
def _packets_shared6(mean, cov, masters, rho, valid, var, nis, used, err):  # pragma: no cover - jit
    """:func:`_packets_shared` for ``K = 6`` nodes: the sizes are compile-time constants,
    so the loops over the ``K - 1`` measurement rows are unrolled inside the loop over the
    runs of a group, which vectorises (the run is the contiguous SIMD axis) and keeps the
    sums in registers. Every entry is computed by the same operations in the same order as
    in :func:`_packets_shared`: the results are the same."""
    R = mean.shape[0]
    M = masters.shape[0]
    m, n = _M6, _N6
    W = _SHARED_LANES
    for g in prange((R + W - 1) // W):
        r0 = g * W
        run = np.empty(W, np.int64)
        for l in range(W):
            run[l] = min(r0 + l, R - 1)                      # the last group is padded
        x = np.empty((n, W))
        P = np.empty((n, n, W))
        for l in range(W):
            for i in range(n):
                x[i, l] = mean[run[l], i]
                for c in range(n):
                    P[i, c, l] = cov[run[l], i, c]
        node = np.empty(m, np.int64)
        u0 = np.empty((m, W))
        u1 = np.empty((m, W))
        nu = np.empty((m, W))
        okv = np.empty((m, W))
        A = np.empty((n, m, W))
        S = np.empty((m, m, W))
        L = np.zeros((m, m, W))
        Kt = np.empty((m, n, W))
        D = np.empty((n, m, W))
        acc = np.empty(W)
        cnt = np.empty(W, np.int64)
        for j in range(M):
            k = masters[j]
            for a in range(m):
                node[a] = a if a < k else a + 1
            for l in range(W):
                sc = 1.0
                for i in range(n):
                    sc = max(sc, abs(x[i, l]))
                for a in range(m):
                    p = node[a]
                    o = valid[run[l], j, p]
                    dx = x[2 * p, l] - x[2 * k, l]
                    dy = x[2 * p + 1, l] - x[2 * k + 1, l]
                    h = math.sqrt(dx * dx + dy * dy)
                    if o and h <= 1e-9 * sc:
                        if r0 + l < R and err[run[l], 0] < 0:
                            err[run[l], 0] = j
                            err[run[l], 1] = p
                        o = False
                    okv[a, l] = 1.0 if o else 0.0
                    u0[a, l] = dx / h if o else 0.0
                    u1[a, l] = dy / h if o else 0.0
                    nu[a, l] = rho[run[l], j, p] - h if o else 0.0
            # A = Sigma H^T: column a = (Sigma[:, block p] - Sigma[:, block k]) u_a
            p0, p1, p2, p3, p4 = node[0], node[1], node[2], node[3], node[4]
            for i in range(n):
                Pi = P[i]
                Ai = A[i]
                for l in range(W):
                    g0 = Pi[2 * k, l]
                    g1 = Pi[2 * k + 1, l]
                    Ai[0, l] = (Pi[2 * p0, l] - g0) * u0[0, l] + (Pi[2 * p0 + 1, l] - g1) * u1[0, l]
                    Ai[1, l] = (Pi[2 * p1, l] - g0) * u0[1, l] + (Pi[2 * p1 + 1, l] - g1) * u1[1, l]
                    Ai[2, l] = (Pi[2 * p2, l] - g0) * u0[2, l] + (Pi[2 * p2 + 1, l] - g1) * u1[2, l]
                    Ai[3, l] = (Pi[2 * p3, l] - g0) * u0[3, l] + (Pi[2 * p3 + 1, l] - g1) * u1[3, l]
                    Ai[4, l] = (Pi[2 * p4, l] - g0) * u0[4, l] + (Pi[2 * p4 + 1, l] - g1) * u1[4, l]
            # S = H A + R (identity rows and columns for links not used), symmetrised
            for a in range(m):
                p = node[a]
                Ap0 = A[2 * p]
                Ap1 = A[2 * p + 1]
                Ak0 = A[2 * k]
                Ak1 = A[2 * k + 1]
                Sa = S[a]
                for l in range(W):
                    ua = u0[a, l]
                    va = u1[a, l]
                    for q in range(m):
                        Sa[q, l] = (Ap0[q, l] - Ak0[q, l]) * ua + (Ap1[q, l] - Ak1[q, l]) * va
                    Sa[a, l] += var if okv[a, l] != 0.0 else 1.0
            for l in range(W):
                for a in range(m):
                    for q in range(a + 1, m):
                        v = 0.5 * (S[a, q, l] + S[q, a, l])
                        S[a, q, l] = v
                        S[q, a, l] = v
            # Cholesky S = L L^T
            for l in range(W):
                for a in range(m):
                    for q in range(a + 1):
                        t = S[a, q, l]
                        for s in range(q):
                            t -= L[a, s, l] * L[q, s, l]
                        if a == q:
                            L[a, a, l] = math.sqrt(t)
                        else:
                            L[a, q, l] = t / L[q, q, l]
            # Kt = S^-1 A^T (the gain, transposed)
            for i in range(n):
                for l in range(W):
                    for a in range(m):                       # forward
                        t = A[i, a, l]
                        for s in range(a):
                            t -= L[a, s, l] * Kt[s, i, l]
                        Kt[a, i, l] = t / L[a, a, l]
                    for a in range(m - 1, -1, -1):           # backward
                        t = Kt[a, i, l]
                        for s in range(a + 1, m):
                            t -= L[s, a, l] * Kt[s, i, l]
                        Kt[a, i, l] = t / L[a, a, l]
            # the mean; NIS = |L^-1 nu|^2
            for i in range(n):
                for l in range(W):
                    t = 0.0
                    for a in range(m):
                        t += Kt[a, i, l] * nu[a, l]
                    x[i, l] += t
            for l in range(W):
                for a in range(m):
                    t = nu[a, l]
                    for s in range(a):
                        t -= L[a, s, l] * nu[s, l]
                    nu[a, l] = t / L[a, a, l]
                t = 0.0
                c = 0
                for a in range(m):
                    t += nu[a, l] * nu[a, l]
                    c += 1 if okv[a, l] != 0.0 else 0
                acc[l] = t
                cnt[l] = c
            for l in range(W):
                if r0 + l < R:
                    nis[run[l], k] = acc[l]
                    used[run[l], k] = cnt[l]
            # Joseph form expanded: Sigma + (L S - A) L^T - L A^T, then symmetrised
            for i in range(n):
                Di = D[i]
                Ai = A[i]
                for l in range(W):
                    for q in range(m):
                        t = -Ai[q, l]
                        for a in range(m):
                            t += Kt[a, i, l] * S[a, q, l]
                        Di[q, l] = t
            for i in range(n):
                Di = D[i]
                for c in range(i, n):
                    Ac = A[c]
                    Pic = P[i, c]
                    Pci = P[c, i]
                    for l in range(W):
                        t = 0.0
                        for a in range(m):
                            t += Di[a, l] * Kt[a, c, l] - Kt[a, i, l] * Ac[a, l]
                        v = 0.5 * ((Pic[l] + t) + (Pci[l] + t))
                        Pic[l] = v
                        Pci[l] = v
        for l in range(W):
            if r0 + l < R:
                r = r0 + l
                for i in range(n):
                    mean[r, i] = x[i, l]
                    for c in range(n):
                        cov[r, i, c] = P[i, c, l]


class NetworkEKF(RecursiveEstimator):
    """Sequential EKF network positioning over the stacked state (Brown & Iltis,
    eq. (13)-eq. (25)).

    Parameters
    ----------
    range_var_m2 : float
        ``sigma_v^2``, the diagonal of ``R_k`` (eq. (15)), m^2.

    Raises
    ------
    ConfigError
        ``range_var_m2`` is not a positive number.
    """

    name = "ekf"

    def __init__(self, range_var_m2: float = 900.0) -> None:
        self.range_var_m2 = check_positive(range_var_m2, "range_var_m2")

    def init(self, prior_mean: np.ndarray, prior_var: np.ndarray) -> EKFState:
        """Initial state ``x(0|0)`` and ``Sigma(0|0) = diag(prior_var)`` (eq. (25)).

        Parameters
        ----------
        prior_mean : ndarray, shape (R, K, 2)
            Prior mean positions, metres.
        prior_var : ndarray, broadcastable to (R, K, 2)
            Per-axis prior variances, m^2.

        Returns
        -------
        EKFState
        """
        mean, var = check_prior(prior_mean, prior_var)
        R, K, _ = mean.shape
        cov = np.zeros((R, 2 * K, 2 * K))
        idx = np.arange(2 * K)
        cov[:, idx, idx] = var.reshape(R, 2 * K)
        return EKFState(mean.reshape(R, 2 * K), cov, np.full((R, K), np.nan),
                        np.zeros((R, K), dtype=np.int64))

    def step(self, state: EKFState, master_idx: np.ndarray | int, ranges: np.ndarray,
             mask: np.ndarray | None = None) -> EKFState:
        """One packet per run: the master's ranges update the global state (eq. (18)-eq. (23)).

        Parameters
        ----------
        state : EKFState
        master_idx : int or ndarray of int, shape (R,)
            Node that measured in each run.
        ranges : ndarray, shape (R, K)
            The master's ranges to every node, metres; NaN = missing link; the master's
            own entry is ignored.
        mask : ndarray of bool, shape (R, K), optional
            Which ranges exist, besides the NaN test.

        Returns
        -------
        EKFState
            A new state (the input is not modified).

        Raises
        ------
        GeometryError
            A used link joins two nodes with coincident estimates.
        """
        R, K = state.runs, state.nodes
        master, rho, valid = check_packet(master_idx, ranges, mask, R, K)
        return self._apply(state, master[:, None], rho[:, None], valid[:, None])

    def _apply(self, state: EKFState, masters: np.ndarray, rho: np.ndarray,
               valid: np.ndarray) -> EKFState:
        """Packets ``j`` of every run in order by the compiled kernel (eq. (18)-eq. (23))."""
        R = state.runs
        mean = np.array(state.mean, dtype=float, order="C")
        cov = np.array(state.covariance, dtype=float, order="C")
        nis = np.array(state.nis, dtype=float, order="C")
        used = np.array(state.used, dtype=np.int64, order="C")
        err = np.full((R, 2), -1, dtype=np.int64)
        masters = np.asarray(masters)
        # every run with the same master per packet (iterate): the kernel without the
        # master's own row (the same numbers)
        shared = R > 0 and bool(np.all(masters == masters[:1]))
        kernel = _packets if not shared else (_packets_shared6 if state.nodes == _K6
                                              else _packets_shared)
        kernel(mean, cov, kernel_array(masters[0] if shared else masters, np.int64),
               kernel_array(rho), kernel_array(valid, np.bool_),
               self.range_var_m2, nis, used, err)
        if np.any(err[:, 0] >= 0):
            hit = np.flatnonzero(err[:, 0] >= 0)
            r = int(hit[np.argmin(err[hit, 0])])          # the earliest packet, lowest run
            k, p = int(masters[r, err[r, 0]]), int(err[r, 1])
            raise GeometryError(f"run {r}: nodes {k} and {p} have coincident position "
                                "estimates; the range Jacobian is undefined", index=(r,),
                                detail=f"nodes {k} and {p} have coincident estimates")
        return EKFState(check_finite_output(mean, "ekf mean"), cov, nis, used)

    def iterate(self, state: EKFState, ranges: np.ndarray, mask: np.ndarray | None = None
                ) -> EKFState:
        """One iteration ``n``: masters ``k = 0..K-1`` update the global state in turn.

        Parameters
        ----------
        state : EKFState
        ranges : ndarray, shape (R, K, K)
            ``ranges[r, k, i]``: range measured at master ``k`` to node ``i`` in run
            ``r``; NaN = missing link.
        mask : ndarray of bool, shape (R, K, K), optional
            Which ranges exist, besides the NaN test.

        Returns
        -------
        EKFState
        """
        R, K = state.runs, state.nodes
        rho, mask = check_iteration(ranges, mask, R, K)
        valid = np.ones((R, K, K), dtype=bool) if mask is None else mask.copy()
        valid[:, np.arange(K), np.arange(K)] = False                 # the master's own entry
        valid &= ~np.isnan(rho)                                      # NaN = missing link
        bad = valid & ~np.isfinite(rho)
        if np.any(bad):
            idx = tuple(int(i) for i in np.argwhere(bad)[0])
            raise InputError(f"ranges: infinite value at (run, master, node) {idx}")
        masters = np.broadcast_to(np.arange(K), (R, K))
        return self._apply(state, masters, np.where(valid, rho, 0.0), valid)

    def estimate(self, state: EKFState) -> Estimate:
        """The current estimate of every node with its own 2x2 covariance block.

        Parameters
        ----------
        state : EKFState

        Returns
        -------
        Estimate
            ``position`` ``(R, K, 2)``, ``covariance`` ``(R, K, 2, 2)``; diagnostics
            ``nis`` and ``measurements_used`` ``(R, K)`` of each node's latest packet as
            master.
        """
        return Estimate(state.position, state.position_covariance, None,
                        {"nis": state.nis, "measurements_used": state.used})

    def run(self, ranges: np.ndarray, prior_mean: np.ndarray, prior_var: np.ndarray,
            mask: np.ndarray | None = None, time: np.ndarray | None = None) -> Track:
        """Run ``N`` iterations of every master from the priors.

        Parameters
        ----------
        ranges : ndarray, shape (R, N, K, K)
            ``ranges[r, n, k, i]``: range at master ``k`` to node ``i`` in iteration
            ``n`` of run ``r``; NaN = missing link.
        prior_mean : ndarray, shape (R, K, 2)
        prior_var : ndarray, broadcastable to (R, K, 2)
            Per-axis prior variances, m^2.
        mask : ndarray of bool, shape (R, N, K, K), optional
        time : ndarray, shape (N,), optional
            Time of each iteration; default the iteration number ``1..N``.

        Returns
        -------
        Track
            ``position`` ``(R, K, N, 2)`` and ``covariance`` ``(R, K, N, 2, 2)`` after each
            iteration (the prior, iteration 0, is not included).
        """
        return run_iterations(self, self.init(prior_mean, prior_var), ranges, mask, time,
                              self.estimate)
