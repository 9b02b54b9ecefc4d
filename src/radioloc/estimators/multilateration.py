"""Batched multilateration from ranges to known anchors by Gauss-Newton.

Solves ``min_x sum_i w_i (r_i - ||x - a_i||)^2`` for a whole batch of independent
problems at once: ``ranges`` is ``(..., M)``, ``anchors`` ``(..., M, d)`` and the optional
``weights`` mark which ranges exist (0 = missing), so epochs that hear different anchor
sets share one array.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.validation import as_float_array, check_positive


@dataclass
class MultilaterationResult:
    """Result of :func:`gauss_newton`.

    Attributes
    ----------
    position : (..., d) array, metres
    covariance : (..., d, d) array, m^2
        ``s^2 (J^T W J)^{-1}`` at the solution, with ``s`` the given range standard
        deviation or, if none was given, the residual estimate (``M - d`` degrees of
        freedom; the given one is used where there are no spare degrees of freedom).
    iterations : int
    converged : (...,) bool array
    residual_rms_m : (...,) array
    """

    position: np.ndarray
    covariance: np.ndarray
    iterations: int
    converged: np.ndarray
    residual_rms_m: np.ndarray


def _solve(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.linalg.solve(A, b[..., None])[..., 0]


def _first(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def linear_initial(ranges: np.ndarray, anchors: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Closed-form start: least squares on ``||x||^2 - 2 a_i^T x = r_i^2 - ||a_i||^2`` with
    ``||x||^2`` as an extra unknown. Needs ``d + 1`` ranges in general position."""
    d = anchors.shape[-1]
    A = np.concatenate([-2.0 * anchors, np.ones(anchors.shape[:-1] + (1,))], axis=-1)
    b = ranges**2 - np.sum(anchors**2, axis=-1)
    AtA = np.einsum("...m,...mi,...mj->...ij", weights, A, A)
    Atb = np.einsum("...m,...mi,...m->...i", weights, A, b)
    # small ridge keeps exactly-determined problems solvable; GN refines afterwards
    AtA = AtA + 1e-9 * np.trace(AtA, axis1=-2, axis2=-1)[..., None, None] * np.eye(d + 1)
    return _solve(AtA, Atb)[..., :d]


def gauss_newton(ranges: np.ndarray, anchors: np.ndarray, *, weights: np.ndarray | None = None,
                 range_std_m: float | None = None, initial: np.ndarray | None = None,
                 max_iter: int = 50, tol_m: float = 1e-9) -> MultilaterationResult:
    """Batched Gauss-Newton multilateration.

    Parameters
    ----------
    ranges : (..., M) array
        Measured ranges in metres. Entries with weight 0 may be NaN.
    anchors : (M, d) or (..., M, d) array
        Anchor positions in metres.
    weights : (..., M) array, optional
        Non-negative weights; 0 marks a missing range. Default: all ones.
    range_std_m : float, optional
        Range error standard deviation for the covariance. Default: from the residuals.
    initial : (..., d) array, optional
        Starting point. Default: the closed-form solution of :func:`linear_initial`.
    max_iter : int
        Maximum Gauss-Newton steps (a step is halved while it increases the cost).
    tol_m : float
        Stop when every step is shorter than this.

    Raises
    ------
    InputError
        Shapes disagree, or a used range is NaN or negative.
    GeometryError
        Fewer than ``d + 1`` ranges, or collinear anchors, for some batch entry.
    """
    r = as_float_array(ranges, "ranges", min_ndim=1, allow_nan=True)
    a = as_float_array(anchors, "anchors", min_ndim=2, last_dim=(2, 3))
    d = a.shape[-1]
    batch = np.broadcast_shapes(r.shape[:-1], a.shape[:-2])
    if a.shape[-2] != r.shape[-1]:
        raise InputError(f"ranges: {r.shape[-1]} ranges per problem but {a.shape[-2]} anchors")
    w = np.ones(r.shape) if weights is None else as_float_array(weights, "weights", nonnegative=True)
    w = np.broadcast_to(w, batch + r.shape[-1:]).astype(float)
    r = np.broadcast_to(r, w.shape)
    a = np.broadcast_to(a, batch + a.shape[-2:])
    used = w > 0
    bad = used & ~(np.isfinite(r) & (r >= 0))
    if np.any(bad):
        idx = _first(bad)
        raise InputError(f"ranges: invalid range {r[idx]} at index {idx} (must be finite and >= 0)")
    r = np.where(used, r, 0.0)
    n_used = used.sum(axis=-1)
    if np.any(n_used < d + 1):
        idx = _first(n_used < d + 1)
        detail = f"{int(n_used[idx])} ranges, {d + 1} needed in {d}-D"
        raise GeometryError(f"problem {idx}: {detail}", index=idx, detail=detail)
    if range_std_m is not None:
        check_positive(range_std_m, "range_std_m")

    x = linear_initial(r, a, w) if initial is None else np.broadcast_to(
        as_float_array(initial, "initial", last_dim=d), batch + (d,)).copy()

    def residuals(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        diff = pos[..., None, :] - a
        dist = np.sqrt(np.sum(diff**2, axis=-1))
        J = diff / np.maximum(dist, 1e-12)[..., None]     # d||x - a_i|| / dx
        res = r - dist
        return res, J, np.sum(w * res**2, axis=-1)

    res, J, cost = residuals(x)
    converged = np.zeros(batch, dtype=bool)
    it = 0
    for it in range(1, max_iter + 1):
        JtJ = np.einsum("...m,...mi,...mj->...ij", w, J, J)
        Jtr = np.einsum("...m,...mi,...m->...i", w, J, res)
        scale = np.trace(JtJ, axis1=-2, axis2=-1)[..., None, None]
        step = _solve(JtJ + 1e-12 * scale * np.eye(d), Jtr)
        step = np.where(converged[..., None], 0.0, step)
        # step halving: accept the largest 2^-k step that does not increase the cost
        accepted = np.zeros(batch, dtype=bool)
        new_x = x.copy()
        for k in range(8):
            trial = x + step * 0.5**k
            _, _, c_trial = residuals(trial)
            take = ~accepted & (c_trial <= cost * (1 + 1e-12) + 1e-300)
            new_x = np.where(take[..., None], trial, new_x)
            accepted |= take
            if accepted.all():
                break
        moved = np.sqrt(np.sum((new_x - x) ** 2, axis=-1))
        x = new_x
        res, J, cost = residuals(x)
        converged |= moved < tol_m
        if converged.all():
            break

    JtJ = np.einsum("...m,...mi,...mj->...ij", w, J, J)
    cond = np.linalg.cond(JtJ)
    singular = ~np.isfinite(cond) | (cond > 1e10)
    if np.any(singular):
        idx = _first(singular)
        detail = ("anchors are collinear or the position coincides with an anchor; "
                  "the geometry does not fix the position")
        raise GeometryError(f"problem {idx}: {detail}", index=idx, detail=detail)
    dof = n_used - d
    wsum = np.sum(w, axis=-1)
    s2_resid = np.where(dof > 0, cost / np.maximum(dof, 1) * (n_used / wsum), np.nan)
    if range_std_m is not None:
        s2 = np.full(batch, range_std_m**2)
    else:
        s2 = s2_resid
        if np.any(~np.isfinite(s2)):
            raise GeometryError("no spare ranges to estimate the range noise for the covariance: "
                                "pass range_std_m")
    cov = s2[..., None, None] * np.linalg.inv(JtJ)
    rms = np.sqrt(cost / np.maximum(wsum, 1e-300))
    return MultilaterationResult(x, cov, it, converged, rms)
