"""Distributed RLS network positioning from differenced squared ranges (Brown & Iltis, eqs. 1-12).

Each node ``k`` estimates only its own position. From its ranges ``rho_{i,k}`` to the other
nodes it forms, for every pair ``i < j`` of other nodes, the differenced squared range
(eq. 2) and the transformed measurement (eqs. 3, 8)

    z_{i,j,k} = 1/2 (rho_{i,k}^2 - rho_{j,k}^2) - 1/2 (|x_i|^2 - |x_j|^2)
              = (x_j - x_i)^T x_k + v_{i,j,k},

which is linear in ``x_k`` once the other nodes' positions are replaced by their previous
estimates (eqs. 7-9). Node ``k`` then runs an ordinary RLS update (eqs. 10, 11) with a
forgetting factor ``lambda`` from ``P_k(0) = Cov{x_k(0)}`` (eq. 12).

Units of eq. (12): the rows of ``A_k`` are position differences (m), so ``A_k^T A_k`` is in
m^2 while ``P_k(0)^{-1}`` is in 1/m^2. Eq. (10) adds them as they are: the transformed
measurement noise ``v_{i,j,k}`` (variance about ``(rho_i^2 + rho_j^2) sigma_v^2``, m^4) is
not used as a weight, so a prior of 100 m^2 enters with weight 1e-2 m^-2 against
``A^T A`` of order 1e5-1e6 m^2: after the first update the prior is practically forgotten.
That is the paper's algorithm and what :func:`rls_init` does by default; ``prior_scale``
lets a caller weight the prior consistently (``P_k(0)^{-1} = sigma_z^2 Cov^{-1}``).

Every function advances a batch of ``R`` independent runs: positions ``(R, K, 2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.validation import as_float_array, check_finite_output, check_positive
from radioloc.estimators.network import check_packet, check_prior

_COND_LIMIT = 1e12


@dataclass(frozen=True)
class RLSState:
    """State of ``R`` independent runs of the distributed RLS.

    Attributes
    ----------
    position : (R, K, 2) array, m
        Current estimate ``x_k(n)`` of every node.
    information : (R, K, 2, 2) array
        ``P_k(n)^{-1}`` of every node (eq. 10), in the units of ``A^T A`` (m^2).
    """

    position: np.ndarray
    information: np.ndarray

    @property
    def runs(self) -> int:
        return self.position.shape[0]

    @property
    def nodes(self) -> int:
        return self.position.shape[1]


def rls_init(prior_mean: np.ndarray, prior_var: np.ndarray,
             prior_scale: float | np.ndarray = 1.0) -> RLSState:
    """Initial state from the priors (eq. 12).

    Parameters
    ----------
    prior_mean : (R, K, 2) array, m
        ``x_k(0)``.
    prior_var : (R, K, 2) array (or broadcastable), m^2
        Per-axis prior variances: ``P_k(0) = diag(prior_var) / prior_scale``.
    prior_scale : float or (R, K) array, default 1
        1 is eq. (12) as printed. A caller wanting the prior weighted consistently against
        the unweighted rows of eq. (10) passes the variance of the transformed measurement
        ``v_{i,j,k}`` here (m^4): then ``P_k(0)^{-1} = sigma_z^2 Cov^{-1}`` is in m^2 like
        ``A^T A`` (see the module docstring).
    """
    mean, var = check_prior(prior_mean, prior_var)
    scale = as_float_array(prior_scale, "prior_scale")
    if np.any(scale <= 0):
        raise InputError("prior_scale: must be > 0")
    scale = np.broadcast_to(scale, mean.shape[:2])
    info = np.zeros(mean.shape + (2,))
    info[..., 0, 0] = scale / var[..., 0]
    info[..., 1, 1] = scale / var[..., 1]
    return RLSState(mean, info)


def pair_rows(reference: np.ndarray, ranges: np.ndarray, valid: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of eqs. (8)-(9) for every pair ``i < j`` of nodes.

    Parameters
    ----------
    reference : (R, K, 2) array
        Positions used for the other nodes (their previous estimates).
    ranges : (R, K) array
        The master's ranges (entries with ``valid`` false are ignored).
    valid : (R, K) bool array
        Which ranges exist; the master's own entry must be false.

    Returns
    -------
    A : (R, P, 2) rows ``(x_j - x_i)^T`` (eq. 9), P = K (K - 1) / 2
    z : (R, P) transformed measurements (eq. 8)
    w : (R, P) 1 where both ranges of the pair exist, else 0
    """
    i, j = np.triu_indices(reference.shape[1], 1)
    A = reference[:, j] - reference[:, i]
    sq = np.einsum("rkd,rkd->rk", reference, reference)
    z = 0.5 * (ranges[:, i] ** 2 - ranges[:, j] ** 2) - 0.5 * (sq[:, i] - sq[:, j])
    w = (valid[:, i] & valid[:, j]).astype(np.float64)
    return A, z, w


def rls_update(state: RLSState, master_idx: np.ndarray | int, ranges: np.ndarray,
               mask: np.ndarray | None = None, *, forgetting: float = 1.0,
               reference: np.ndarray | None = None) -> RLSState:
    """One packet per run: the master updates its own position (eqs. 10, 11).

    Parameters
    ----------
    state : RLSState
    master_idx : (R,) int array or int
        Node that measured in each run; only its estimate changes.
    ranges : (R, K) array, m
        The master's ranges to every node (own entry and masked entries ignored).
    mask : (R, K) bool array, optional
        Which ranges exist (missing links). Pairs with a missing range are dropped.
    forgetting : float in (0, 1]
        ``lambda`` of eq. (10).
    reference : (R, K, 2) array, optional
        Positions of the other nodes used in eqs. (8)-(9); default the current estimates.
        The synchronous iteration of the paper passes the estimates of the previous
        iteration (see :func:`rls_iteration`).

    Returns
    -------
    RLSState
        A new state (the input is not modified).

    Raises
    ------
    GeometryError
        If the master's information matrix is singular (the other nodes' estimates are
        collinear or coincident and the prior carries no weight).
    """
    lam = check_positive(forgetting, "forgetting")
    if lam > 1:
        raise InputError(f"forgetting: must lie in (0, 1], got {forgetting!r}")
    R, K = state.runs, state.nodes
    master, rho, valid = check_packet(master_idx, ranges, mask, R, K)
    ref = state.position if reference is None else as_float_array(reference, "reference",
                                                                  ndim=3, last_dim=2)
    A, z, w = pair_rows(ref, rho, valid)
    rr = np.arange(R)
    x = state.position[rr, master]                                  # (R, 2)
    info = lam * state.information[rr, master] + np.einsum("rp,rpa,rpb->rab", w, A, A)  # eq. 10
    a, b, d = info[:, 0, 0], info[:, 0, 1], info[:, 1, 1]
    det = a * d - b * b
    half_tr = 0.5 * (a + d)
    disc = np.sqrt(np.maximum(half_tr**2 - det, 0.0))
    bad = ~((half_tr - disc) * _COND_LIMIT > half_tr + disc)        # 2x2 condition number
    if np.any(bad):
        r = int(np.flatnonzero(bad)[0])
        raise GeometryError(f"run {r}, node {int(master[r])}: RLS information matrix is singular "
                            "(the other nodes' estimates are coincident or collinear)")
    innov = w * (z - np.einsum("rpa,ra->rp", A, x))
    g = np.einsum("rpa,rp->ra", A, innov)
    step = np.stack([d * g[:, 0] - b * g[:, 1], a * g[:, 1] - b * g[:, 0]], axis=-1) / det[:, None]
    position = state.position.copy()
    position[rr, master] = check_finite_output(x + step, "rls position")  # eq. 11
    information = state.information.copy()
    information[rr, master] = info
    return RLSState(position, information)


def rls_iteration(state: RLSState, ranges: np.ndarray, mask: np.ndarray | None = None, *,
                  forgetting: float = 1.0) -> RLSState:
    """One iteration ``n`` of the paper: every node ``k = 0..K-1`` updates once.

    All updates of the iteration use the other nodes' estimates of the previous iteration
    (``x_i(n-1)`` in eqs. 8-9), as the paper's node delays its update until it holds all
    ranges of the packet epoch.

    Parameters
    ----------
    ranges : (R, K, K) array
        ``ranges[r, k, i]``: range measured at master ``k`` to node ``i`` in run ``r``.
    mask : (R, K, K) bool array, optional
    """
    rho = as_float_array(ranges, "ranges", ndim=3, allow_nan=True)
    R, K = state.runs, state.nodes
    if rho.shape != (R, K, K):
        raise InputError(f"ranges: expected shape ({R}, {K}, {K}), got {rho.shape}")
    reference = state.position
    for k in range(K):
        state = rls_update(state, np.full(R, k), rho[:, k],
                           None if mask is None else np.asarray(mask)[:, k],
                           forgetting=forgetting, reference=reference)
    return state
