"""Cramer-Rao bounds for the single-sensor tracker of paper 002.

* :func:`differenced_crb` - eq. (23): ``(A' S' (S Sigma S')^{-1} S A)^{-1}``, the bound of the
  differenced linear model ``S y = S A beta + S e`` when ``S e`` is Gaussian with the
  covariance of eq. (11), eq. (14) at the true state. It is a bound for estimators that only
  see ``S y``; it equals the BLUE covariance (Lemma 2 mirrors Lemma 1).
* :func:`raw_range_crb` - the bound from the ranges themselves,
  ``rhat_n = |p_n - s_n| + omega_n`` with ``p_n = p_k + (n-k) T v_k + eps_n``, under the
  Gaussian approximation ``rhat ~ N(h(beta), Sigma_r)``,
  ``Sigma_r,ij = (u_i . u_j) E[eps_i eps_j] + xi delta_ij`` (motion noise projected on the
  line of sight ``u_n``), keeping the ``J' Sigma_r^{-1} J`` term of the Fisher information
  (the term from the dependence of ``Sigma_r`` on beta is dropped). With no motion noise it
  is the exact CRB for Gaussian range noise.

Both return (..., 4, 4) for the state ``[x_k, y_k, vx_k, vy_k]``: the position bound is the
trace of the leading 2 x 2 block.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import GeometryError
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.validation import as_float_array, check_positive
from radioloc.models.single_sensor import SquaredRangeModel, predicted_offsets
from radioloc.models.track_noise import accumulated_noise_covariance

__all__ = ["differenced_crb", "raw_range_crb"]


def _inverse(info: np.ndarray, what: str) -> np.ndarray:
    cond = np.linalg.cond(info)
    if np.any(~np.isfinite(cond) | (cond > 1e14)):
        raise GeometryError(f"{what}: Fisher information is singular "
                            f"(condition {np.max(cond):.3g})")
    return np.linalg.inv(info)


def _reference(n: int, reference_index: int | None) -> int:
    k = n - 1 if reference_index is None else int(reference_index)
    return k + n if k < 0 else k


_RANGE_VAR = {"range_var": Renamed("std_m", variance=True)}


@renamed_keywords(_RANGE_VAR)
def differenced_crb(state, sensor_path, *, sample_period_s: float, accel_var: float,
                    std_m=0.0, reference_index: int | None = None,
                    accel_excess_kurtosis: float = 0.0,
                    range_excess_kurtosis: float = 0.0) -> np.ndarray:
    """The bound of eq. (23) on ``[x_k, y_k, vx_k, vy_k]``, evaluated at the true state.

    Parameters
    ----------
    state : array_like, shape (4,) or (..., 4)
        True ``[x_k, y_k, vx_k, vy_k]``.
    sensor_path : array_like, shape (n, 2) or (..., n, 2)
        Sensor positions.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2`` per axis.
    std_m : float or array_like, shape (..., n)
        Range noise standard deviation, metres (per sample if an array): the paper's channel
        noise variance is ``xi_n = std_m^2``. The old keyword ``range_var`` (``xi_n``) still
        works with a ``FutureWarning``.
    reference_index : int, optional
        k; default n-1.
    accel_excess_kurtosis, range_excess_kurtosis : float
        As in :class:`~radioloc.estimators.closed_form.ClosedFormTracker`.

    Returns
    -------
    ndarray, shape (..., 4, 4)

    Raises
    ------
    GeometryError
        Singular noise covariance or Fisher information.
    """
    beta = as_float_array(state, "state", min_ndim=1, last_dim=4)
    s = as_float_array(sensor_path, "sensor_path", min_ndim=2, last_dim=2)
    n = s.shape[-2]
    model = SquaredRangeModel(n, _reference(n, reference_index), sample_period_s, accel_var,
                              std_m=std_m, accel_excess_kurtosis=accel_excess_kurtosis,
                              range_excess_kurtosis=range_excess_kurtosis)
    return _inverse(model.fisher_information(beta, s), "differenced_crb")


@renamed_keywords(_RANGE_VAR)
def raw_range_crb(state, sensor_path, *, sample_period_s: float, accel_var: float,
                  std_m: float, reference_index: int | None = None) -> np.ndarray:
    """Gaussian-approximation CRB of the raw ranges (see the module docstring).

    Parameters
    ----------
    state : array_like, shape (4,) or (..., 4)
        True ``[x_k, y_k, vx_k, vy_k]``.
    sensor_path : array_like, shape (n, 2) or (..., n, 2)
        Sensor positions.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2`` per axis.
    std_m : float
        Range noise standard deviation, metres (the paper's ``xi = std_m^2``). The old
        keyword ``range_var`` (``xi``) still works with a ``FutureWarning``.
    reference_index : int, optional
        k; default n-1.

    Returns
    -------
    ndarray, shape (..., 4, 4)

    Raises
    ------
    GeometryError
        Singular range covariance or Fisher information.
    """
    beta = as_float_array(state, "state", min_ndim=1, last_dim=4)
    s = as_float_array(sensor_path, "sensor_path", min_ndim=2, last_dim=2)
    T = check_positive(sample_period_s, "sample_period_s")
    xi = check_positive(std_m, "std_m", allow_zero=True) ** 2
    n = s.shape[-2]
    k = _reference(n, reference_index)
    d = predicted_offsets(beta, s, T, k)
    u = d / np.maximum(np.linalg.norm(d, axis=-1), 1e-12)[..., None]
    t = (np.arange(n) - k) * T
    J = np.stack([u[..., 0], u[..., 1], t * u[..., 0], t * u[..., 1]], axis=-1)
    c = accumulated_noise_covariance(n, k, T, accel_var)
    cov = np.einsum("...id,...jd->...ij", u, u) * c + xi * np.eye(n)
    try:
        white = np.linalg.solve(np.linalg.cholesky(cov), J)
    except np.linalg.LinAlgError:
        raise GeometryError("raw_range_crb: range covariance is singular "
                            "(std_m = 0 and no motion noise?)") from None
    return _inverse(np.swapaxes(white, -1, -2) @ white, "raw_range_crb")
