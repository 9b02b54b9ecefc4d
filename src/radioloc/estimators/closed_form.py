"""Closed-form single-sensor tracker: third-difference linearisation + iterative BLUE (paper 002).

Steps of section 3 (ideal channel eq. 11, noisy channel eqs. 12-14), batched over runs:

1. subtract the noise mean ``E[e_n]`` from ``y_n = rhat_n^2 - a_n^2 - b_n^2``;
2. apply the third difference S of eq. (10): ``S y = (S A) beta + S e`` (eq. 9);
3a. OLS start ``beta0 = (A~' A~)^{-1} A~' S y``;
3b. evaluate ``Sigma~ = S Sigma(beta_m) S'`` at the current estimate;
3c. BLUE/GLS ``beta_{m+1} = (A~' Sigma~^{-1} A~)^{-1} A~' Sigma~^{-1} S y``;
3d. stop when ``Delta = |beta_{m+1} - beta_m|^2 <= tol`` (the stopping rule of section 5.2)
    or when the GLS criterion ``r' Sigma~^{-1} r`` stops decreasing, or after ``max_iter``.

``beta = [Y_k, X_k, V_y, V_x]``; the model lives in :mod:`radioloc.models.single_sensor`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import GeometryError
from radioloc.core.validation import check_finite_output, check_positive
from radioloc.models.single_sensor import (
    SquaredRangeModel,
    design_matrix,
    difference_rows,
    trajectory,
    validate_inputs,
)


@dataclass
class ClosedFormResult:
    """Output of :func:`closed_form_track`.

    Attributes
    ----------
    state : (..., 4)      ``[Y_k, X_k, V_y, V_x]`` (BLUE).
    covariance : (..., 4, 4)  ``(A~' Sigma~^{-1} A~)^{-1}`` (eq. 15) with the Sigma~ of the
        last accepted BLUE step.
    trajectory : (..., n, 2)  ``(x, y)`` of ``p_k + (n-k) T v_k`` at every sample.
    ols_state : (..., 4)  the OLS start of step 3a (the unweighted linear-model fit).
    iterations : (...,)   BLUE iterations done.
    reference_index : int the k used.
    """

    state: np.ndarray
    covariance: np.ndarray
    trajectory: np.ndarray
    ols_state: np.ndarray
    iterations: np.ndarray
    reference_index: int


def _gls(sa: np.ndarray, sy: np.ndarray, w: np.ndarray):
    """Generalised least squares for a batch: returns (beta, covariance, criterion).

    One LU solve ``w^{-1} [S A, S y]`` per run; the criterion is ``r' w^{-1} r``.
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


def closed_form_track(ranges, sensor, *, sample_period_s: float, accel_var: float,
                      range_var=0.0, reference_index: int | None = None,
                      accel_excess_kurtosis: float = 0.0, range_excess_kurtosis: float = 0.0,
                      tol: float = 0.1, max_iter: int = 20, cond_limit: float = 1e12,
                      covariance_state=None, printed_eq14: bool = False) -> ClosedFormResult:
    """Estimate ``[Y_k, X_k, V_y, V_x]`` from ranges to one moving sensor (steps 1-3d).

    Parameters
    ----------
    ranges : array (..., n)
        Measured ranges ``rhat_n`` (eq. 12); leading axes are independent runs.
    sensor : array (n, 2) or (..., n, 2)
        Known sensor positions ``(a_n, b_n)``. Must not be quadratic in n.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2`` (eq. 1), per axis.
    range_var : float or array (..., n)
        Channel noise variance ``xi_n``; 0 is the ideal channel (eq. 11).
    reference_index : int, optional
        k; default the last sample (n-1), i.e. the current position.
    accel_excess_kurtosis, range_excess_kurtosis : float
        0 (default) uses the Gaussian moments printed in eqs. (11)-(14); -1.2 is exact for
        uniform noise.
    tol : float
        Stopping rule ``|beta_{m+1} - beta_m|^2 <= tol`` (section 5.2 uses 0.1).
    max_iter : int
        Maximum BLUE iterations after the OLS start.
    cond_limit : float
        ``S A`` with a column-scaled condition number above this raises GeometryError.
    covariance_state : array (..., 4), optional
        If given, one BLUE step with ``Sigma~`` evaluated at this state (e.g. the true state:
        the oracle BLUE) instead of the iterations 3b-3d.
    printed_eq14 : bool
        Use eq. (14)'s printed off-diagonal channel terms (a reading kept for comparison;
        see :class:`~radioloc.models.single_sensor.SquaredRangeModel`).

    Returns
    -------
    ClosedFormResult

    Raises
    ------
    InputError
        Bad shapes, negative or NaN ranges, too few samples (< 7), k out of range.
    GeometryError
        Sensor path quadratic in n, or ``S A`` numerically rank deficient.
    """
    r, s, k = validate_inputs(ranges, sensor, reference_index)
    T = check_positive(sample_period_s, "sample_period_s")
    check_positive(tol, "tol")
    n = r.shape[-1]
    batch = np.broadcast_shapes(r.shape[:-1], s.shape[:-2])
    r = np.broadcast_to(r, batch + (n,))
    s = np.broadcast_to(s, batch + (n, 2))
    model = SquaredRangeModel(n, k, T, accel_var, range_var, accel_excess_kurtosis,
                              range_excess_kurtosis, printed_eq14)

    sa, sy = _differenced_system(r, s, k, model)                    # steps 1-2
    col = np.linalg.norm(sa, axis=-2, keepdims=True)
    cond = np.linalg.cond(sa / np.where(col > 0, col, 1.0))
    if np.any(~np.isfinite(cond) | (cond > cond_limit)):
        raise GeometryError(f"sensor: S A is rank deficient (condition number "
                            f"{np.max(cond):.3g} > {cond_limit:.0e}); the sensor path does not "
                            "separate [Y_k, X_k, V_y, V_x]")

    beta = _ols(sa, sy)                                              # step 3a
    if covariance_state is not None:
        fixed = np.broadcast_to(np.asarray(covariance_state, dtype=float), batch + (4,))
        state, cov, _ = _gls(sa, sy, model.differenced_covariance(fixed, s))
        return ClosedFormResult(state=state, covariance=cov, trajectory=trajectory(state, n, T, k),
                                ols_state=beta, iterations=np.ones(batch, dtype=int),
                                reference_index=k)
    ols = beta.copy()
    best_crit = np.full(batch, np.inf)
    cov = np.zeros(batch + (4, 4))
    active = np.ones(batch, dtype=bool)
    iterations = np.zeros(batch, dtype=int)
    for _ in range(int(max_iter)):
        if not np.any(active):
            break
        w = model.differenced_covariance(beta, s)                    # step 3b
        new, new_cov, crit = _gls(sa, sy, w)                         # step 3c
        improved = crit < best_crit
        take = active & improved
        delta = np.sum((new - beta) ** 2, axis=-1)
        beta = np.where(take[..., None], new, beta)
        cov = np.where(take[..., None, None], new_cov, cov)
        best_crit = np.where(take, crit, best_crit)
        iterations = iterations + take
        active = take & (delta > tol)                                # step 3d
    check_finite_output(beta, "closed_form_track state")
    return ClosedFormResult(state=beta, covariance=cov, trajectory=trajectory(beta, n, T, k),
                            ols_state=ols, iterations=iterations, reference_index=k)


def _differenced_system(r, s, k, model):
    """Steps 1-2: mean-removed ``y`` and its third difference; returns ``(S A, S y)``."""
    y = r**2 - np.sum(s**2, axis=-1) - model.noise_mean()
    sa = difference_rows(design_matrix(s, model.T, k))
    sy = difference_rows(y[..., None])[..., 0]
    return np.broadcast_to(sa, sy.shape + (4,)), sy


def _ols(sa: np.ndarray, sy: np.ndarray) -> np.ndarray:
    """Step 3a, batched: ``(A~' A~)^{-1} A~' S y``."""
    at = np.swapaxes(sa, -1, -2)
    return np.linalg.solve(at @ sa, (at @ sy[..., None]))[..., 0]


def ols_track(ranges, sensor, *, sample_period_s: float, accel_var: float, range_var=0.0,
              reference_index: int | None = None) -> np.ndarray:
    """Unweighted multivariate linear-model fit of the differenced model (the MANOVA baseline).

    Reading of the paper's MANOVA comparison: the same linear model ``S y = S A beta + S e``
    fitted by ordinary least squares, i.e. every differenced equation weighted equally
    (step 3a without the BLUE iterations). Returns ``[Y_k, X_k, V_y, V_x]``, shape (..., 4).
    """
    r, s, k = validate_inputs(ranges, sensor, reference_index)
    n = r.shape[-1]
    model = SquaredRangeModel(n, k, sample_period_s, accel_var, range_var)
    sa, sy = _differenced_system(r, s, k, model)
    return check_finite_output(_ols(sa, sy), "ols_track state")
