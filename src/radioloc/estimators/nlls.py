"""The one batched nonlinear least-squares driver: Gauss-Newton, Newton, Levenberg-Marquardt.

Minimises ``c(x) = sum_m w_m r_m(x)^2`` for a whole batch of independent problems at
once. The caller supplies ``residuals(x) -> (r, J)`` with ``x`` ``(..., n)``, residuals
``r = z - h(x)`` ``(..., M)`` and the Jacobian of the *prediction* ``J = dh/dx``
``(..., M, n)``; weights ``w`` ``(..., M)`` (0 = missing measurement).

Steps (per problem; problems that have stopped are frozen):

* ``"gauss-newton"``: ``(J^T W J) s = J^T W r``;
* ``"newton"``: ``(J^T W J - sum_m w_m r_m d^2h_m/dx^2) s = J^T W r``, with the second
  derivatives from ``curvature(x) -> (..., M, n, n)``;
* ``"levenberg-marquardt"``: ``(J^T W J + lambda diag(J^T W J)) s = J^T W r`` with
  ``lambda`` divided by 10 after an accepted step and multiplied by 10 after a rejected one.

``step_control`` for the first two: ``"halving"`` accepts the largest ``2^-k s``
(k < 8) that does not increase the cost, ``"none"`` takes the full step (the plain
Newton iteration whose divergence paper 002 studies).

A robust or non-Gaussian cost goes through ``row_terms(x, r) -> (cost, W, work)``: each
row's cost term (the cost is their sum instead of ``sum w r^2``), its weight and its
working residual; every iteration then solves ``(J^T W J) s = J^T W work`` with the
weights of the current iterate (iteratively reweighted least squares; the robust losses
and the max-mixture loss of :mod:`radioloc.estimators.robust_loss`). Without it
``W = w`` and ``work = r``.

A problem *converges* when an accepted step is no longer than ``tol`` plus ``RELATIVE_TOL``
times the iterate's norm (the second term is rounding level: far from the origin, as in
Earth-centred coordinates, a step of ``tol`` alone is below the spacing of the numbers
and the cost cannot judge it); it *stalls* when no
step decreases the cost, its system is singular or its iterate stops being finite (it then
keeps its last finite iterate). Problems neither converged nor stalled after ``max_iter``
iterations have both flags False.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from radioloc.core.errors import ConfigError
from radioloc.core.validation import as_float_array, check_positive

__all__ = ["NLLSResult", "solve_nlls", "METHODS"]

METHODS = ("gauss-newton", "newton", "levenberg-marquardt")
_HALVINGS = 8

Residuals = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]]
Curvature = Callable[[np.ndarray], np.ndarray]
RowTerms = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray]]


@dataclass
class NLLSResult:
    """What :func:`solve_nlls` returns.

    Attributes
    ----------
    x : ndarray, shape (..., n)
        Solutions (last finite iterate for stalled problems).
    cost : ndarray, shape (...)
        ``sum_m w_m r_m^2`` at ``x``.
    residuals : ndarray, shape (..., M)
    jacobian : ndarray, shape (..., M, n)
        ``dh/dx`` at ``x``.
    normal_matrix : ndarray, shape (..., n, n)
        ``J^T W J`` at ``x`` (the Gauss-Newton information, for covariances; with
        ``row_terms``, its weights at ``x``).
    iterations : ndarray of int, shape (...)
        Accepted steps per problem.
    converged, stalled : ndarray of bool, shape (...)
    """

    x: np.ndarray
    cost: np.ndarray
    residuals: np.ndarray
    jacobian: np.ndarray
    normal_matrix: np.ndarray
    iterations: np.ndarray
    converged: np.ndarray
    stalled: np.ndarray


RELATIVE_TOL = 1e-12


def _normal(J: np.ndarray, w: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    JtWJ = np.einsum("...m,...mi,...mj->...ij", w, J, J)
    JtWr = np.einsum("...m,...mi,...m->...i", w, J, r)
    return JtWJ, JtWr


def _adjugate(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Adjugate and determinant of a batch of 2 x 2 or 3 x 3 matrices (closed form)."""
    if A.shape[-1] == 2:
        a, b, c, d = A[..., 0, 0], A[..., 0, 1], A[..., 1, 0], A[..., 1, 1]
        adj = np.stack([np.stack([d, -b], -1), np.stack([-c, a], -1)], -2)
        return adj, a * d - b * c
    cof = np.empty_like(A)
    for i in range(3):
        for j in range(3):
            r = [k for k in range(3) if k != i]
            c = [k for k in range(3) if k != j]
            minor = (A[..., r[0], c[0]] * A[..., r[1], c[1]]
                     - A[..., r[0], c[1]] * A[..., r[1], c[0]])
            cof[..., i, j] = (-1) ** (i + j) * minor
    det = np.einsum("...j,...j->...", A[..., 0, :], cof[..., 0, :])
    return np.swapaxes(cof, -1, -2), det


def _solve(A: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Batched solve; rows whose system is singular or non-finite get ``ok = False``.

    A system is refused when its 1-norm condition number ``||A|| ||A^-1||`` reaches 1e14
    (within a factor n of the 2-norm one). For n <= 3 the inverse is the closed-form
    adjugate over the determinant, and a system is also refused when its determinant is
    below 1e-14 of the product of its column norms (Hadamard's bound): for a rank-deficient
    matrix the adjugate and the determinant are both rounding noise, so their ratio says
    nothing. Larger systems use LU (``det`` and ``inv``).
    """
    n = A.shape[-1]
    finite = np.all(np.isfinite(A), axis=(-2, -1)) & np.all(np.isfinite(b), axis=-1)
    A = np.where(finite[..., None, None], A, np.eye(n))
    norm = np.abs(A).sum(axis=-2).max(axis=-1)
    with np.errstate(all="ignore"):
        if n <= 3:
            adj, det = _adjugate(A) if n > 1 else (np.ones_like(A), A[..., 0, 0])
            inv = adj / det[..., None, None]
        else:
            det = np.linalg.det(A)
            safe = np.where((det != 0)[..., None, None], A, np.eye(n))
            inv = np.linalg.inv(safe)
        cond = norm * np.abs(inv).sum(axis=-2).max(axis=-1)
        ok = finite & (det != 0) & np.isfinite(cond) & (cond < 1e14)
        if n <= 3:
            hadamard = np.prod(np.sqrt(np.sum(A**2, axis=-2)), axis=-1)
            ok &= np.abs(det) > 1e-14 * hadamard
        s = np.einsum("...ij,...j->...i", np.where(ok[..., None, None], inv, 0.0),
                      np.where(ok[..., None], b, 0.0))
    return np.where(ok[..., None], s, 0.0), ok


def solve_nlls(residuals: Residuals, x0: np.ndarray, *, weights: np.ndarray | None = None,
               method: str = "gauss-newton", curvature: Curvature | None = None,
               step_control: str = "halving", max_iter: int = 50, tol: float = 1e-9,
               ridge: float = 1e-12, lm_lambda0: float = 1e-3,
               row_terms: RowTerms | None = None) -> NLLSResult:
    """Minimise ``sum w r(x)^2`` for every problem of a batch (see the module docstring).

    Parameters
    ----------
    residuals : callable
        ``residuals(x) -> (r, J)``: ``x`` ``(..., n)`` to residuals ``(..., M)`` and the
        prediction Jacobian ``(..., M, n)``.
    x0 : ndarray, shape (..., n)
        Starting points.
    weights : ndarray, shape (..., M), optional
        Non-negative weights; 0 marks a missing measurement. Default all ones.
    method : {"gauss-newton", "newton", "levenberg-marquardt"}
    curvature : callable, optional
        ``curvature(x) -> (..., M, n, n)``, the second derivatives of each prediction;
        required by ``"newton"``.
    step_control : {"halving", "none"}
        Line search of Gauss-Newton and Newton.
    max_iter : int
        Maximum iterations.
    tol : float
        Convergence when the accepted step's Euclidean norm is ``<= tol`` (plus
        ``RELATIVE_TOL`` times the iterate's norm).
    ridge : float
        Relative ridge ``ridge * trace(A) I`` added to the Gauss-Newton system (keeps
        exactly determined problems solvable; 0 disables it).
    lm_lambda0 : float
        Initial damping of Levenberg-Marquardt.
    row_terms : callable, optional
        ``row_terms(x, r) -> (cost, W, work)``, each ``(..., M)``: a robust or
        non-Gaussian cost (module docstring); ``weights`` then only marks missing rows
        (0) and is otherwise ignored. Not with ``"newton"``.

    Returns
    -------
    NLLSResult
    """
    if method not in METHODS:
        raise ConfigError(f"method: must be one of {', '.join(METHODS)}, got {method!r}")
    if step_control not in ("halving", "none"):
        raise ConfigError(f"step_control: must be 'halving' or 'none', got {step_control!r}")
    if method == "newton" and row_terms is not None:
        raise ConfigError("method 'newton' does not take row_terms")
    if method == "newton" and curvature is None:
        raise ConfigError("method 'newton' needs the curvature callable")
    if int(max_iter) < 0:
        raise ConfigError(f"max_iter: must be >= 0, got {max_iter}")
    check_positive(tol, "tol", allow_zero=True)
    x = as_float_array(x0, "x0", min_ndim=1).copy()
    n = x.shape[-1]
    r, J = residuals(x)
    batch = np.broadcast_shapes(x.shape[:-1], r.shape[:-1])
    x = np.broadcast_to(x, batch + (n,)).copy()
    w = np.ones(r.shape) if weights is None else np.asarray(weights, dtype=float)
    w = np.broadcast_to(w, batch + r.shape[-1:])

    def terms(xx: np.ndarray, res: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cost, weight and working residual of each row."""
        if row_terms is None:
            used = np.where(w > 0, res, 0.0)
            return w * used ** 2, w, used
        c, ww, work = row_terms(xx, res)
        return np.where(w > 0, c, 0.0), np.where(w > 0, ww, 0.0), np.where(w > 0, work, 0.0)

    def cost_of(xx: np.ndarray, res: np.ndarray) -> np.ndarray:
        return np.sum(terms(xx, res)[0], axis=-1)

    c_rows, W, work = terms(x, r)
    cost = np.sum(c_rows, axis=-1)
    converged = np.zeros(batch, dtype=bool)
    stalled = np.zeros(batch, dtype=bool)
    iterations = np.zeros(batch, dtype=np.int64)
    lam = np.full(batch, float(lm_lambda0))
    eye = np.eye(n)
    for _ in range(int(max_iter)):
        active = ~(converged | stalled)
        if not active.any():
            break
        A, g = _normal(J, W, work)
        if method == "newton":
            A = A - np.einsum("...m,...mij->...ij", w * np.where(w > 0, r, 0.0), curvature(x))
        if method == "levenberg-marquardt":
            diag = np.diagonal(A, axis1=-2, axis2=-1)
            A = A + lam[..., None, None] * (diag[..., :, None] * eye)
        elif ridge > 0 and method == "gauss-newton":
            A = A + ridge * np.trace(A, axis1=-2, axis2=-1)[..., None, None] * eye
        step, ok = _solve(A, g)
        stalled |= active & ~ok
        active &= ok
        # a step already within tolerance: with a line search, converged where it stands
        # (its cost change is at rounding level, so the line search could not judge it);
        # without one the step is taken and converges below
        searched = method == "levenberg-marquardt" or step_control == "halving"
        limit = tol + RELATIVE_TOL * np.sqrt(np.sum(x**2, axis=-1))
        tiny = active & (np.sqrt(np.sum(step**2, axis=-1)) <= limit) & searched
        converged |= tiny
        active &= ~tiny
        step = np.where(active[..., None], step, 0.0)
        if method == "levenberg-marquardt" or step_control == "halving":
            tries = 1 if method == "levenberg-marquardt" else _HALVINGS
            accepted = np.zeros(batch, dtype=bool)
            new_x = x.copy()
            for k in range(tries):
                trial = x + step * 0.5**k
                r_t, _ = residuals(trial)
                c_t = cost_of(trial, r_t)
                take = active & ~accepted & np.isfinite(c_t) & (c_t <= cost * (1 + 1e-12) + 1e-300)
                new_x = np.where(take[..., None], trial, new_x)
                accepted |= take
                if accepted[active].all():
                    break
            if method == "levenberg-marquardt":
                lam = np.where(active & accepted, lam / 10.0, np.where(active, lam * 10.0, lam))
                stalled |= active & ~accepted & (lam > 1e12)
            else:
                stalled |= active & ~accepted
        else:
            new_x = x + step
            finite = np.all(np.isfinite(new_x), axis=-1) & (np.abs(new_x).max(axis=-1) < 1e12)
            stalled |= active & ~finite
            accepted = active & finite
            new_x = np.where(accepted[..., None], new_x, x)
        moved = np.sqrt(np.sum((new_x - x) ** 2, axis=-1))
        x = new_x
        iterations += accepted
        r, J = residuals(x)
        c_rows, W, work = terms(x, r)
        cost = np.sum(c_rows, axis=-1)
        converged |= accepted & (moved <= limit)
    A, _ = _normal(J, W, work)
    return NLLSResult(x=x, cost=cost, residuals=r, jacobian=J, normal_matrix=A,
                      iterations=iterations, converged=converged, stalled=stalled)
