"""Newton's method on the nonlinear least squares of ranges to one moving sensor (paper 002 baseline).

Unknowns ``beta = [Y_k, X_k, V_y, V_x]`` of the straight track ``p_n = p_k + (n-k) T v_k``;
cost ``f = 1/2 sum_n (rhat_n - |p_n - s_n|)^2``; full Newton steps with the exact Hessian
``H = sum_n J_n' J_n - sum_n res_n B_n' (I - u_n u_n') / h_n B_n``; the stopping rule is the
closed-form tracker's (``|step|^2 <= tol``, section 5.2). No line search, no damping: the
paper's point is that Newton leaves its convergence region from a poor start or an
indefinite Hessian, and that is what this baseline shows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.validation import as_float_array, check_positive
from radioloc.models.single_sensor import predicted_offsets, trajectory, validate_inputs


@dataclass
class NewtonResult:
    """``state`` (..., 4) ``[Y_k, X_k, V_y, V_x]``; ``trajectory`` (..., n, 2); ``iterations``;
    ``converged`` (stopping rule met with a finite, invertible Hessian)."""

    state: np.ndarray
    trajectory: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray


def _gradient_hessian(beta, r, s, T, k):
    d = predicted_offsets(beta, s, T, k)                  # (..., n, 2) x,y
    h = np.maximum(np.linalg.norm(d, axis=-1), 1e-12)
    u = d / h[..., None]
    t = (np.arange(r.shape[-1]) - k) * T
    zeros = np.zeros_like(t)
    ones = np.ones_like(t)
    # B_n maps beta=[Y,X,Vy,Vx] to (x, y): rows x -> [0,1,0,t], y -> [1,0,t,0]
    B = np.stack([np.stack([zeros, ones, zeros, t], -1),
                  np.stack([ones, zeros, t, zeros], -1)], -2)     # (n, 2, 4)
    J = np.einsum("...nd,ndp->...np", u, B)                       # (..., n, 4)
    res = r - h
    grad = -np.einsum("...n,...np->...p", res, J)
    proj = (np.eye(2) - u[..., :, None] * u[..., None, :]) / h[..., None, None]
    curv = np.einsum("ndp,...nde,neq->...npq", B, proj, B)
    hess = np.swapaxes(J, -1, -2) @ J - np.einsum("...n,...npq->...pq", res, curv)
    return grad, hess, 0.5 * np.sum(res**2, axis=-1)


def newton_track(ranges, sensor, initial_state, *, sample_period_s: float,
                 reference_index: int | None = None, tol: float = 0.1,
                 max_iter: int = 50) -> NewtonResult:
    """Newton iterations on the range NLLS from ``initial_state`` (..., 4) ``[Y, X, V_y, V_x]``.

    Parameters
    ----------
    ranges : array (..., n)
        Measured ranges; leading axes are independent runs.
    sensor : array (n, 2) or (..., n, 2)
        Known sensor positions ``(a_n, b_n)`` (same checks as the closed form).
    initial_state : array (4,) or (..., 4)
        Start of the iterations.
    sample_period_s : float
        T.
    reference_index : int, optional
        k; default n-1.
    tol : float
        Stop when ``|step|^2 <= tol`` (section 5.2: 0.1).
    max_iter : int
        Iteration cap.

    Runs whose Hessian is singular or whose iterate becomes non-finite stop at the last
    finite iterate with ``converged = False``; the output is always finite.
    """
    r, s, k = validate_inputs(ranges, sensor, reference_index)
    T = check_positive(sample_period_s, "sample_period_s")
    beta = as_float_array(initial_state, "initial_state", last_dim=4, min_ndim=1)
    n = r.shape[-1]
    batch = np.broadcast_shapes(r.shape[:-1], s.shape[:-2], beta.shape[:-1])
    r = np.broadcast_to(r, batch + (n,))
    s = np.broadcast_to(s, batch + (n, 2))
    beta = np.broadcast_to(beta, batch + (4,)).copy()
    active = np.ones(batch, dtype=bool)
    converged = np.zeros(batch, dtype=bool)
    iterations = np.zeros(batch, dtype=int)
    for _ in range(int(max_iter)):
        if not np.any(active):
            break
        grad, hess, _ = _gradient_hessian(beta, r, s, T, k)
        det_ok = np.abs(np.linalg.det(hess)) > 1e-300
        safe = np.where(det_ok[..., None, None], hess, np.eye(4))
        with np.errstate(all="ignore"):
            step = np.linalg.solve(safe, grad[..., None])[..., 0]
        new = beta - step
        ok = det_ok & np.all(np.isfinite(new), axis=-1) & (np.abs(new).max(axis=-1) < 1e12)
        upd = active & ok
        beta = np.where(upd[..., None], new, beta)
        iterations = iterations + upd
        done = upd & (np.sum(step**2, axis=-1) <= tol)
        converged |= done
        active = upd & ~done
    return NewtonResult(state=beta, trajectory=trajectory(beta, n, T, k),
                        iterations=iterations, converged=converged)
