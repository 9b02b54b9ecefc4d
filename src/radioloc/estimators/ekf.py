"""Sequential EKF network positioning over the stacked 2K state (Brown & Iltis, eqs. 13-25).

The state is ``x = [x_1; ...; x_K]`` (eq. 13), static, so the prediction is the identity
(eqs. 20, 24). At each packet a master node ``k`` measures its ranges to the others
(eqs. 14-15) and updates the *global* estimate (eqs. 19, 21-23); the next master starts from
that estimate. Missing links are rows with a zero Jacobian and zero innovation, which is
an exact no-op in the update.

The covariance update is the Joseph form ``(I - L H^T) S (I - L H^T)^T + L R L^T``,
algebraically eq. (21) but symmetric and positive semi-definite in floating point; it is
symmetrised after each update.

Every function advances a batch of ``R`` independent runs: state ``(R, 2K)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.validation import as_float_array, check_finite_output
from radioloc.estimators.network import check_packet, check_prior


@dataclass(frozen=True)
class EKFState:
    """State of ``R`` independent runs of the sequential EKF.

    Attributes
    ----------
    mean : (R, 2K) array, m
        Stacked estimate ``[x_1, y_1, x_2, y_2, ...]`` (eq. 13).
    covariance : (R, 2K, 2K) array, m^2
        ``Sigma`` of eq. (21).
    """

    mean: np.ndarray
    covariance: np.ndarray

    @property
    def runs(self) -> int:
        return self.mean.shape[0]

    @property
    def nodes(self) -> int:
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


def ekf_init(prior_mean: np.ndarray, prior_var: np.ndarray) -> EKFState:
    """Initial state ``x(0|0)`` and ``Sigma(0|0) = diag(prior_var)`` (eq. 25).

    Parameters
    ----------
    prior_mean : (R, K, 2) array, m
    prior_var : (R, K, 2) array (or broadcastable), m^2, per axis
    """
    mean, var = check_prior(prior_mean, prior_var)
    R, K, _ = mean.shape
    cov = np.zeros((R, 2 * K, 2 * K))
    idx = np.arange(2 * K)
    cov[:, idx, idx] = var.reshape(R, 2 * K)
    return EKFState(mean.reshape(R, 2 * K), cov)


def range_jacobian(position: np.ndarray, master: np.ndarray, valid: np.ndarray | None = None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Predicted ranges ``h_k(x)`` (eq. 15) and Jacobian ``H_k^T`` (eqs. 16-17).

    Row ``p`` of ``H_k^T`` holds ``u^T = (x_p - x_k)^T / |x_p - x_k|`` in column block ``p``
    and ``-u^T`` in column block ``k``. Eq. (17) prints the same sign for both blocks; the
    derivative of ``|x_p - x_k|`` with respect to ``x_k`` is the negative of that with
    respect to ``x_p``, which is what is implemented here.

    Parameters
    ----------
    position : (R, K, 2) array
    master : (R,) int array
    valid : (R, K) bool array, optional
        Rows with a false entry (and the master's own row) are zero.

    Returns
    -------
    h : (R, K) predicted ranges (0 on the master's own entry)
    H : (R, K, 2K) Jacobian, one row per node ``p``

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
                            "estimates; the range Jacobian is undefined")
    u = np.where(valid[..., None], diff / np.where(h > 0, h, 1.0)[..., None], 0.0)
    H = np.zeros((R, K, K, 2))
    kk = np.arange(K)
    H[:, kk, kk, :] = u                                              # d h_p / d x_p = +u^T
    H[rr, :, master, :] = -u                                         # d h_p / d x_k = -u^T
    return h, H.reshape(R, K, 2 * K)


def ekf_update(state: EKFState, master_idx: np.ndarray | int, ranges: np.ndarray,
               mask: np.ndarray | None = None, range_var: float | np.ndarray = 1.0) -> EKFState:
    """One packet per run: the master's ranges update the global state (eqs. 18-23).

    Parameters
    ----------
    state : EKFState
    master_idx : (R,) int array or int
        Node that measured in each run.
    ranges : (R, K) array, m
        The master's ranges to every node (own entry and masked entries ignored).
    mask : (R, K) bool array, optional
        Which ranges exist (missing links).
    range_var : float or (R, K) array, m^2
        ``sigma_v^2``, the diagonal of ``R_k`` (eq. 15).

    Returns
    -------
    EKFState
        A new state (the input is not modified).
    """
    R, K = state.runs, state.nodes
    master, rho, valid = check_packet(master_idx, ranges, mask, R, K)
    var = as_float_array(range_var, "range_var", nonnegative=True)
    try:
        var = np.broadcast_to(var, (R, K))
    except ValueError:
        raise InputError(f"range_var: shape {var.shape} does not broadcast to ({R}, {K})") from None
    if np.any(var[valid] <= 0):
        raise InputError("range_var: must be > 0 (m^2) for every measured range")
    var = np.where(valid, var, 1.0)
    h, H = range_jacobian(state.position, master, valid)
    innov = np.where(valid, rho - h, 0.0)                            # eq. 19 bracket
    S = state.covariance
    SH = S @ H.transpose(0, 2, 1)                                    # Sigma H_k, (R, 2K, K)
    omega = H @ SH                                                   # eq. 23
    idx = np.arange(K)
    omega[:, idx, idx] += var
    L = np.linalg.solve(omega, SH.transpose(0, 2, 1)).transpose(0, 2, 1)  # eq. 22 (Omega sym.)
    mean = state.mean + np.einsum("rij,rj->ri", L, innov)            # eq. 19
    IKH = np.eye(2 * K) - L @ H
    cov = IKH @ S @ IKH.transpose(0, 2, 1) + (L * var[:, None, :]) @ L.transpose(0, 2, 1)
    cov = 0.5 * (cov + cov.transpose(0, 2, 1))                       # eq. 21, Joseph form
    return EKFState(check_finite_output(mean, "ekf mean"), cov)


def ekf_iteration(state: EKFState, ranges: np.ndarray, mask: np.ndarray | None = None,
                  range_var: float | np.ndarray = 1.0) -> EKFState:
    """One iteration ``n``: masters ``k = 0..K-1`` update the global state in turn.

    Parameters
    ----------
    ranges : (R, K, K) array
        ``ranges[r, k, i]``: range measured at master ``k`` to node ``i`` in run ``r``.
    mask : (R, K, K) bool array, optional
    range_var : float or (R, K, K) array, m^2
    """
    rho = as_float_array(ranges, "ranges", ndim=3, allow_nan=True)
    R, K = state.runs, state.nodes
    if rho.shape != (R, K, K):
        raise InputError(f"ranges: expected shape ({R}, {K}, {K}), got {rho.shape}")
    var = np.broadcast_to(np.asarray(range_var, dtype=float), (R, K, K)) \
        if np.ndim(range_var) else range_var
    for k in range(K):
        state = ekf_update(state, np.full(R, k), rho[:, k],
                           None if mask is None else np.asarray(mask)[:, k],
                           var if np.ndim(var) == 0 else var[:, k])
    return state
