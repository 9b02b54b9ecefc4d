"""Newton's method on the range nonlinear least squares of one moving sensor (paper 002 baseline).

Unknowns ``beta = [x_k, y_k, vx_k, vy_k]`` of the straight track ``p_n = p_k + (n-k) T v_k``
(eq. (4) without its noise); cost ``sum_n (rhat_n - |p_n - s_n|)^2``. The iteration is the
one nonlinear least-squares driver :func:`radioloc.estimators.nlls.solve_nlls` with
``method="newton"`` (the exact Hessian ``J'J - sum_n res_n B_n' (I - u_n u_n') B_n / h_n``)
and ``step_control="none"``: full Newton steps, no line search, no damping. The paper's
point is that Newton leaves its convergence region from a poor start or an indefinite
Hessian, and that is what this baseline shows. The stopping rule is the closed-form
tracker's, ``|step| <= tol`` (section 5.2's ``|step|^2 <= 0.1`` is ``tol = sqrt(0.1)``).
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import ConfigError
from radioloc.core.results import Estimate
from radioloc.core.validation import MAX_ITERATIONS, as_float_array, check_int, check_positive
from radioloc.estimators.base import SnapshotEstimator
from radioloc.estimators.nlls import solve_nlls
from radioloc.models.single_sensor import (
    predicted_offsets,
    resolve_sampling,
    trajectory,
    validate_inputs,
)

__all__ = ["NewtonTracker", "range_residuals"]


def range_residuals(state, ranges, sensor_path, sample_period_s: float, reference_index: int,
                    *, curvature: bool = False):
    """Residuals, Jacobian (and curvature) of the range model of the straight track.

    Parameters
    ----------
    state : ndarray, shape (..., 4)
        ``[x_k, y_k, vx_k, vy_k]``.
    ranges : ndarray, shape (..., n)
        Measured ranges (NaN allowed: its residual is NaN).
    sensor_path : ndarray, shape (..., n, 2)
        Sensor positions.
    sample_period_s : float
        T.
    reference_index : int
        k.
    curvature : bool
        Also return the second derivatives.

    Returns
    -------
    residuals : ndarray, shape (..., n)
        ``rhat_n - h_n``, ``h_n = |p_k + (n-k) T v_k - s_n|``.
    jacobian : ndarray, shape (..., n, 4)
        ``dh_n / d beta = [u_n, t_n u_n]`` with ``u_n = d_n / h_n``, ``t_n = (n-k) T``.
    curvature : ndarray, shape (..., n, 4, 4)
        Only with ``curvature=True``: ``d^2 h_n / d beta^2 = B_n' P_n B_n`` with
        ``B_n = [I, t_n I]`` and ``P_n = (I - u_n u_n') / h_n``, i.e. the blocks
        ``[[P_n, t_n P_n], [t_n P_n, t_n^2 P_n]]``.
    """
    n = sensor_path.shape[-2]
    d = predicted_offsets(state, sensor_path, sample_period_s, reference_index)
    h = np.maximum(np.linalg.norm(d, axis=-1), 1e-12)
    u = d / h[..., None]
    t = (np.arange(n) - reference_index) * sample_period_s
    J = np.concatenate([u, t[:, None] * u], axis=-1)
    if not curvature:
        return ranges - h, J
    P = (np.eye(2) - u[..., :, None] * u[..., None, :]) / h[..., None, None]
    tP = t[:, None, None] * P
    curv = np.concatenate([np.concatenate([P, tP], axis=-1),
                           np.concatenate([tP, t[:, None, None] * tP], axis=-1)], axis=-2)
    return ranges - h, J, curv


class NewtonTracker(SnapshotEstimator):
    """Newton iterations on the range NLLS of one moving sensor (the paper's baseline).

    Parameters
    ----------
    reference_index : int, optional
        k; default the last sample (n-1); negative values count from the end.
    tol : float
        Stop when the Newton step's Euclidean norm is ``<= tol`` (default ``sqrt(0.1)``,
        section 5.2's ``|step|^2 <= 0.1``).
    max_iter : int
        Iteration cap.
    step_control : {"none", "halving"}
        ``"none"`` (default): the plain Newton iteration of the paper; ``"halving"``: a
        backtracking line search (a safer variant).

    Examples
    --------
    >>> import numpy as np
    >>> n, T = 20, 0.1
    >>> ang = 1.3 * np.arange(n)
    >>> sensor = 5.0 * np.stack([np.cos(ang), np.sin(ang)], -1)
    >>> truth = np.array([1.0, 0.5]) + (np.arange(n) - (n - 1))[:, None] * T * [0.8, -0.2]
    >>> ranges = np.linalg.norm(truth - sensor, axis=-1)
    >>> est = NewtonTracker(tol=1e-10).locate(ranges, sensor, T,
    ...                                       initial_state=[1.2, 0.3, 0.5, 0.0])
    >>> np.round(est.position, 6).tolist(), bool(est.converged)
    ([1.0, 0.5], True)
    """

    name = "newton"

    def __init__(self, *, reference_index: int | None = None, tol: float = 0.1**0.5,
                 max_iter: int = 50, step_control: str = "none") -> None:
        if reference_index is not None and not isinstance(reference_index, (int, np.integer)):
            raise ConfigError(f"reference_index: must be an int or None, got {reference_index!r}")
        self.reference_index = None if reference_index is None else int(reference_index)
        self.tol = check_positive(tol, "tol")
        self.max_iter = check_int(max_iter, "max_iter", minimum=0, maximum=MAX_ITERATIONS)
        if step_control not in ("none", "halving"):
            raise ConfigError(f"step_control: must be 'none' or 'halving', got {step_control!r}")
        self.step_control = step_control

    def locate(self, ranges, sensor_path, sample_period_s: float | None = None, *,
               time=None, initial_state) -> Estimate:
        """Newton iterations from ``initial_state`` for every problem of the batch.

        Parameters
        ----------
        ranges : array_like, shape (..., n)
            Measured ranges; leading axes are independent problems. A NaN range is a
            missing sample and is left out of the sum of squares.
        sensor_path : array_like, shape (n, 2) or (..., n, 2)
            Known sensor positions ``(a_n, b_n)`` (same checks as the closed form).
        sample_period_s : float, optional
            T; or give ``time``.
        time : array_like, shape (n,) or (..., n), optional
            Uniformly spaced sample times, seconds.
        initial_state : array_like, shape (4,) or (..., 4)
            Start ``[x_k, y_k, vx_k, vy_k]``.

        Returns
        -------
        Estimate
            ``position`` (..., 2) = ``(x_k, y_k)``, no covariance, ``time`` of sample k;
            diagnostics ``state`` (..., 4), ``trajectory`` (..., n, 2), ``iterations``,
            ``converged``, ``stalled`` (singular Hessian or non-finite iterate: the last
            finite iterate is kept) and ``residual_rms_m``, all from the driver.

        Raises
        ------
        InputError
            Bad shapes or values of ``ranges``, ``sensor_path``, ``time`` or
            ``initial_state``.
        """
        r, s, k = validate_inputs(ranges, sensor_path, self.reference_index, allow_nan=True)
        n = r.shape[-1]
        T, t_k = resolve_sampling(n, k, sample_period_s, time)
        beta0 = as_float_array(initial_state, "initial_state", last_dim=4, min_ndim=1)
        batch = np.broadcast_shapes(r.shape[:-1], s.shape[:-2], beta0.shape[:-1])
        r = np.broadcast_to(r, batch + (n,))
        s = np.broadcast_to(s, batch + (n, 2))
        w = np.isfinite(r).astype(float)
        z = np.where(w > 0, r, 0.0)

        def residuals(x):
            return range_residuals(x, z, s, T, k)

        def curvature(x):
            return range_residuals(x, z, s, T, k, curvature=True)[2]

        out = solve_nlls(residuals, np.broadcast_to(beta0, batch + (4,)), weights=w,
                         method="newton", curvature=curvature, step_control=self.step_control,
                         max_iter=self.max_iter, tol=self.tol)
        used = np.maximum(w.sum(axis=-1), 1.0)
        diag = {"state": out.x, "trajectory": trajectory(out.x, n, T, k),
                "iterations": out.iterations, "converged": out.converged,
                "stalled": out.stalled, "residual_rms_m": np.sqrt(out.cost / used)}
        return Estimate(out.x[..., :2], None, t_k, diag)
