"""The one batched Kalman predict, update and Rauch-Tung-Striebel smoother under every
Kalman filter of the toolkit.

:class:`~radioloc.estimators.extended_kalman.ExtendedKalmanFilter` (and
:class:`~radioloc.estimators.ekf_tracker.RangeEKF`, a configuration of it) and
:class:`~radioloc.estimators.ekf.NetworkEKF` (``backend="numpy"``) call them;
``NetworkEKF(backend="numba")`` runs the compiled form of the same update,
:func:`radioloc.estimators.kalman_compiled.network_ekf_packets`.

Arrays carry any leading batch axes: mean ``(..., n)``, covariance ``(..., n, n)``,
innovation ``(..., m)``, measurement Jacobian ``(..., m, n)``, measurement noise
``(..., m, m)`` (or its diagonal ``(..., m)``).

The update uses the Joseph form ``P+ = (I - K H) P (I - K H)^T + K R K^T`` and symmetrises
its result, so the covariance stays symmetric positive semi-definite in floating point.
A measurement marked invalid (or whose innovation is NaN) is removed exactly: its row of
``H``, its innovation and its cross-terms of ``R`` are zeroed and its variance set to 1,
which leaves the mean and covariance unchanged by that row.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from radioloc.core.errors import InputError

__all__ = ["GaussianState", "kalman_predict", "kalman_update", "rts_smooth", "symmetrise",
           "normalised_innovation_squared"]


@dataclass(frozen=True)
class GaussianState:
    """State of a batch of Kalman filters.

    Attributes
    ----------
    mean : ndarray, shape (..., n)
        State means (position first).
    covariance : ndarray, shape (..., n, n)
        State covariances.
    time : float or ndarray, optional
        Time of the state, seconds.
    """

    mean: np.ndarray
    covariance: np.ndarray
    time: float | np.ndarray = 0.0

    @property
    def batch_shape(self) -> tuple[int, ...]:
        return self.mean.shape[:-1]


def symmetrise(cov: np.ndarray) -> np.ndarray:
    """``(P + P^T) / 2`` on the last two axes."""
    return 0.5 * (cov + np.swapaxes(cov, -1, -2))


def kalman_predict(mean: np.ndarray, cov: np.ndarray, F: np.ndarray, Q: np.ndarray,
                   control: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Prediction ``x- = F x (+ u)``, ``P- = F P F^T + Q`` (symmetrised).

    Parameters
    ----------
    mean : ndarray, shape (..., n)
    cov : ndarray, shape (..., n, n)
    F, Q : ndarray, shape (..., n, n)
        Transition and process noise (broadcast against the batch).
    control : ndarray, shape (..., n), optional
        Added to the predicted mean.

    Returns
    -------
    mean, cov : the predicted moments.
    """
    x = np.einsum("...ij,...j->...i", F, mean)
    if control is not None:
        x = x + control
    P = F @ cov @ np.swapaxes(F, -1, -2) + Q
    return x, symmetrise(P)


def kalman_update(mean: np.ndarray, cov: np.ndarray, innovation: np.ndarray, H: np.ndarray,
                  R: np.ndarray | None = None, *, R_diag: np.ndarray | None = None,
                  valid: np.ndarray | None = None,
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Measurement update in Joseph form, with missing measurements skipped.

    Parameters
    ----------
    mean : ndarray, shape (..., n)
    cov : ndarray, shape (..., n, n)
    innovation : ndarray, shape (..., m)
        ``z - h(x-)``; NaN entries count as missing.
    H : ndarray, shape (..., m, n)
        Measurement Jacobian at the predicted mean.
    R : ndarray, shape (..., m, m), optional
        Measurement noise covariance.
    R_diag : ndarray, shape (..., m), optional
        Its diagonal, for independent measurements (give exactly one of ``R``, ``R_diag``).
        Variances must be positive on the rows used.
    valid : ndarray of bool, shape (..., m), optional
        Which measurements exist; default: those with a finite innovation.

    Returns
    -------
    mean, cov : the updated moments (new arrays).
    innovation_covariance : ndarray, shape (..., m, m)
        ``S = H P H^T + R`` with missing rows replaced by identity rows.
    used : ndarray of bool, shape (..., m)
        The measurements that entered the update.
    """
    nu = np.asarray(innovation, dtype=float)
    ok = np.isfinite(nu)
    if valid is not None:
        ok = ok & np.asarray(valid, dtype=bool)
    m = nu.shape[-1]
    if (R is None) == (R_diag is None):
        raise InputError("kalman_update: give exactly one of R and R_diag")
    if R is None:
        R = np.asarray(R_diag, dtype=float)[..., :, None] * _eye(m)
    both = ok[..., :, None] & ok[..., None, :]
    R = np.where(both, np.asarray(R, dtype=float), _eye(m))
    if ((R.diagonal(0, -2, -1) <= 0) & ok).any():
        raise InputError("measurement noise: variance must be > 0 for every measurement used")
    nu = np.where(ok, nu, 0.0)
    H = np.where(ok[..., :, None], H, 0.0)
    PHt = cov @ H.swapaxes(-1, -2)                               # (..., n, m)
    S = H @ PHt + R
    S = symmetrise(S)
    K = np.linalg.solve(S, PHt.swapaxes(-1, -2)).swapaxes(-1, -2)           # P H^T S^-1
    x = mean + np.einsum("...ij,...j->...i", K, nu)
    n = mean.shape[-1]
    IKH = _eye(n) - K @ H
    P = IKH @ cov @ IKH.swapaxes(-1, -2) + K @ R @ K.swapaxes(-1, -2)
    return x, symmetrise(P), S, ok


@lru_cache(maxsize=64)
def _eye(n: int) -> np.ndarray:
    """The identity of size ``n`` (one read-only array per size)."""
    eye = np.eye(n)
    eye.flags.writeable = False
    return eye


def normalised_innovation_squared(innovation: np.ndarray, S: np.ndarray,
                                  used: np.ndarray) -> np.ndarray:
    """NIS ``nu^T S^-1 nu`` over the used measurements ``(...)`` (0 where none were used)."""
    nu = np.where(used, innovation, 0.0)
    if not np.all(np.isfinite(nu)):
        nu = np.nan_to_num(nu)
    return np.einsum("...i,...i->...", nu, np.linalg.solve(S, nu[..., None])[..., 0])


def rts_smooth(mean: np.ndarray, cov: np.ndarray, predicted_mean: np.ndarray,
               predicted_cov: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rauch-Tung-Striebel backward pass over a filtered series.

    From the last step back, with ``C_k = P_k F_{k+1}^T (P-_{k+1})^-1``:
    ``x^s_k = x_k + C_k (x^s_{k+1} - x-_{k+1})``,
    ``P^s_k = P_k + C_k (P^s_{k+1} - P-_{k+1}) C_k^T`` (symmetrised).

    Parameters
    ----------
    mean : ndarray, shape (..., T, n)
        Filtered means ``x_k``.
    cov : ndarray, shape (..., T, n, n)
        Filtered covariances ``P_k``.
    predicted_mean : ndarray, shape (..., T, n)
        Predicted means ``x-_k`` (the prediction that step ``k``'s update started from;
        step 0's is not used).
    predicted_cov : ndarray, shape (..., T, n, n)
        Predicted covariances ``P-_k``.
    F : ndarray, shape (..., T, n, n)
        ``F_k``: the transition from step ``k - 1`` to step ``k`` (``F_0`` is not used).

    Returns
    -------
    mean, cov : the smoothed moments, shaped like the filtered ones.
    """
    T = mean.shape[-2]
    m_s, P_s = mean[..., T - 1, :], cov[..., T - 1, :, :]
    out_m, out_P = [m_s], [P_s]
    for k in range(T - 2, -1, -1):
        P_f, P_p = cov[..., k, :, :], predicted_cov[..., k + 1, :, :]
        # C = P_f F^T P_p^-1 = (P_p^-1 F P_f)^T for symmetric P_f, P_p
        C = np.swapaxes(np.linalg.solve(P_p, F[..., k + 1, :, :] @ P_f), -1, -2)
        m_s = mean[..., k, :] + np.einsum("...ij,...j->...i", C,
                                          m_s - predicted_mean[..., k + 1, :])
        P_s = symmetrise(P_f + C @ (P_s - P_p) @ np.swapaxes(C, -1, -2))
        out_m.append(m_s)
        out_P.append(P_s)
    axis = mean.ndim - 2
    return np.stack(out_m[::-1], axis=axis), np.stack(out_P[::-1], axis=axis)
