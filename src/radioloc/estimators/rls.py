"""Distributed RLS network positioning from differenced squared ranges (Brown & Iltis,
eq. (1)-eq. (12)).

Each node ``k`` estimates only its own position. From its ranges ``rho_{i,k}`` to the other
nodes it forms, for every pair ``i < j`` of other nodes, the differenced squared range
(eq. (2)) and the transformed measurement (eq. (3), eq. (8))

    z_{i,j,k} = 1/2 (rho_{i,k}^2 - rho_{j,k}^2) - 1/2 (|x_i|^2 - |x_j|^2)
              = (x_j - x_i)^T x_k + v_{i,j,k},

which is linear in ``x_k`` once the other nodes' positions are replaced by their previous
estimates (eq. (7), eq. (8), eq. (9)). Node ``k`` then runs an ordinary RLS update
(eq. (10), eq. (11)) with a forgetting factor ``lambda`` from ``P_k(0) = Cov{x_k(0)}``
(eq. (12)).

Units of eq. (12): the rows of ``A_k`` are position differences (m), so ``A_k^T A_k`` is in
m^2 while ``P_k(0)^{-1}`` is in 1/m^2. eq. (10) adds them as they are: the transformed
measurement noise ``v_{i,j,k}`` (variance about ``(rho_i^2 + rho_j^2) sigma_v^2``, m^4) is
not used as a weight, so a prior of 100 m^2 enters with weight 1e-2 m^-2 against
``A^T A`` of order 1e5-1e6 m^2: after the first update the prior is practically forgotten.
That is the paper's algorithm and what :class:`NetworkRLS` does by default;
``prior_scale`` lets a caller weight the prior consistently
(``P_k(0)^{-1} = sigma_z^2 Cov^{-1}``, see :func:`transformed_noise_var`).

:class:`NetworkRLS` advances a batch of ``R`` independent runs: positions ``(R, K, 2)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.geometry import pairwise_distances
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.results import Estimate, Track
from radioloc.core.validation import (as_float_array, check_finite_output, check_positive,
                                      check_ranges)
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.network import (check_iteration, check_packet, check_prior,
                                         run_iterations)

__all__ = ["NetworkRLS", "RLSState", "pair_rows", "transformed_noise_var"]

_COND_LIMIT = 1e12


@dataclass(frozen=True)
class RLSState:
    """Filter state of ``R`` independent runs of the distributed RLS.

    Attributes
    ----------
    position : ndarray, shape (R, K, 2)
        Current estimate ``x_k(n)`` of every node, metres.
    information : ndarray, shape (R, K, 2, 2)
        ``P_k(n)^{-1}`` of every node (eq. (10)), in the units of ``A^T A`` (m^2).
    used : ndarray of int, shape (R, K)
        Pairs ``i < j`` that entered each node's latest update (0 before its first).
    """

    position: np.ndarray
    information: np.ndarray
    used: np.ndarray

    @property
    def runs(self) -> int:
        """Number of runs ``R``."""
        return self.position.shape[0]

    @property
    def nodes(self) -> int:
        """Number of nodes ``K``."""
        return self.position.shape[1]


@renamed_keywords({"range_var": Renamed("std_m", variance=True)})
def transformed_noise_var(prior_mean: np.ndarray, std_m: float) -> np.ndarray:
    """Variance (m^4) of the differenced squared range ``v_{i,j,k}`` of eq. (2) per node.

    ``1/2 (rho_i^2 - rho_j^2)`` has noise ``d_i v_i - d_j v_j`` to first order, variance
    ``(d_i^2 + d_j^2) sigma_v^2``; averaged over the pairs this is
    ``2 sigma_v^2 mean_i d_i^2``, evaluated at the prior means.

    Parameters
    ----------
    prior_mean : ndarray, shape (..., K, 2)
        Prior mean positions, metres.
    std_m : float
        Range noise standard deviation ``sigma_v``, metres.

    Returns
    -------
    ndarray, shape (..., K)
        ``sigma_z^2`` of every node, m^4.
    """
    d2 = pairwise_distances(prior_mean) ** 2
    K = prior_mean.shape[-2]
    return 2.0 * std_m**2 * d2.sum(axis=-1) / (K - 1)


def pair_rows(reference: np.ndarray, ranges: np.ndarray, valid: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rows of eq. (8) and eq. (9) for every pair ``i < j`` of nodes.

    Parameters
    ----------
    reference : ndarray, shape (R, K, 2)
        Positions used for the other nodes (their previous estimates).
    ranges : ndarray, shape (R, K)
        The master's ranges (entries with ``valid`` false are ignored; must be finite).
    valid : ndarray of bool, shape (R, K)
        Which ranges exist; the master's own entry must be false.

    Returns
    -------
    A : ndarray, shape (R, P, 2)
        Rows ``(x_j - x_i)^T`` (eq. (9)), ``P = K (K - 1) / 2``.
    z : ndarray, shape (R, P)
        Transformed measurements (eq. (8)).
    w : ndarray, shape (R, P)
        1 where both ranges of the pair exist, else 0.
    """
    i, j = np.triu_indices(reference.shape[1], 1)
    A = reference[:, j] - reference[:, i]
    sq = np.einsum("rkd,rkd->rk", reference, reference)
    z = 0.5 * (ranges[:, i] ** 2 - ranges[:, j] ** 2) - 0.5 * (sq[:, i] - sq[:, j])
    w = (valid[:, i] & valid[:, j]).astype(np.float64)
    return A, z, w


class NetworkRLS(RecursiveEstimator):
    """Distributed RLS network positioning (Brown & Iltis, eq. (1)-eq. (12)).

    Every node updates only its own position, from the pairs of its ranges to the other
    nodes and their current estimates; the other nodes' estimates are taken as exact.

    Parameters
    ----------
    forgetting : float in (0, 1]
        ``lambda`` of eq. (10).
    prior_scale : float or "transformed-noise"
        ``P_k(0) = diag(prior_var) / prior_scale``. 1 is eq. (12) as printed (the prior
        is forgotten at the first update, see the module docstring);
        ``"transformed-noise"`` weights the prior consistently with the rows of eq. (10),
        ``prior_scale = sigma_z^2`` of :func:`transformed_noise_var` at the prior means
        (needs ``std_m``).
    std_m : float, optional
        Range noise standard deviation, metres (the paper's ``sigma_v^2 = 900 m^2`` is
        ``std_m=30``), used by ``prior_scale="transformed-noise"`` and by the negative-range
        rule (:func:`~radioloc.core.validation.check_ranges`: without it every negative range
        is refused). The old keyword ``range_var_m2`` (the variance) still works with a
        ``FutureWarning``.
    backend : {"numba", "numpy"}
        :meth:`iterate` by the compiled kernel
        (:func:`~radioloc.estimators.kalman_compiled.network_rls_iteration`) or as ``K``
        calls of :meth:`step` (the NumPy definition); equal to rounding.

    Raises
    ------
    ConfigError
        A setting is out of range (the message names it).

    Notes
    -----
    ``estimate`` gives no covariance: ``P_k`` is in the units of ``(A^T A)^{-1}`` (1/m^2),
    not a position covariance in m^2.
    """

    name = "rls"

    @renamed_keywords({"range_var_m2": Renamed("std_m", variance=True)},
                      positional=("range_var_m2", "backend"))
    def __init__(self, forgetting: float = 1.0, prior_scale: float | str = 1.0, *,
                 std_m: float | None = None, backend: str = DEFAULT_BACKEND) -> None:
        if not (0 < check_positive(forgetting, "forgetting") <= 1):
            raise ConfigError(f"forgetting: must lie in (0, 1], got {forgetting!r}")
        if isinstance(prior_scale, str):
            if prior_scale != "transformed-noise":
                raise ConfigError("prior_scale: a number > 0 or 'transformed-noise', got "
                                  f"{prior_scale!r}")
            if std_m is None:
                raise ConfigError("std_m: needed by prior_scale='transformed-noise'")
        else:
            prior_scale = check_positive(prior_scale, "prior_scale")
        if std_m is not None:
            std_m = check_positive(std_m, "std_m")
        self.forgetting = float(forgetting)
        self.prior_scale = prior_scale
        self.std_m = None if std_m is None else float(std_m)
        self.backend = check_backend(backend)

    def init(self, prior_mean: np.ndarray, prior_var: np.ndarray) -> RLSState:
        """Initial state from the priors (eq. (12)).

        Parameters
        ----------
        prior_mean : ndarray, shape (R, K, 2)
            ``x_k(0)``, metres.
        prior_var : ndarray, broadcastable to (R, K, 2)
            Per-axis prior variances, m^2.

        Returns
        -------
        RLSState
        """
        mean, var = check_prior(prior_mean, prior_var)
        if isinstance(self.prior_scale, str):
            scale = transformed_noise_var(mean, self.std_m)
        else:
            scale = np.full(mean.shape[:2], self.prior_scale)
        info = np.zeros(mean.shape + (2,))
        info[..., 0, 0] = scale / var[..., 0]
        info[..., 1, 1] = scale / var[..., 1]
        return RLSState(mean, info, np.zeros(mean.shape[:2], dtype=np.int64))

    def step(self, state: RLSState, master_idx: np.ndarray | int, ranges: np.ndarray,
             mask: np.ndarray | None = None, *, reference: np.ndarray | None = None
             ) -> RLSState:
        """One packet per run: the master updates its own position (eq. (10), eq. (11)).

        Parameters
        ----------
        state : RLSState
        master_idx : int or ndarray of int, shape (R,)
            Node that measured in each run; only its estimate changes.
        ranges : ndarray, shape (R, K)
            The master's ranges to every node, metres; NaN = missing link (its pairs are
            dropped); the master's own entry is ignored.
        mask : ndarray of bool, shape (R, K), optional
            Which ranges exist, besides the NaN test.
        reference : ndarray, shape (R, K, 2), optional
            Positions of the other nodes used in eq. (8) and eq. (9); default the current
            estimates. :meth:`iterate` passes the estimates of the previous iteration.

        Returns
        -------
        RLSState
            A new state (the input is not modified).

        Raises
        ------
        GeometryError
            If the master's information matrix is singular (the other nodes' estimates
            are collinear or coincident and the prior carries no weight).
        """
        R, K = state.runs, state.nodes
        master, rho, valid = check_packet(master_idx, ranges, mask, R, K)
        check_ranges(rho, "ranges", self.std_m or 0.0, used=valid)
        ref = state.position if reference is None else as_float_array(
            reference, "reference", ndim=3, last_dim=2)
        A, z, w = pair_rows(ref, rho, valid)
        rr = np.arange(R)
        x = state.position[rr, master]                                       # (R, 2)
        info = (self.forgetting * state.information[rr, master]
                + np.einsum("rp,rpa,rpb->rab", w, A, A))                     # eq. (10)
        a, b, d = info[:, 0, 0], info[:, 0, 1], info[:, 1, 1]
        det = a * d - b * b
        half_tr = 0.5 * (a + d)
        disc = np.sqrt(np.maximum(half_tr**2 - det, 0.0))
        bad = ~((half_tr - disc) * _COND_LIMIT > half_tr + disc)             # 2x2 condition
        if np.any(bad):
            r = int(np.flatnonzero(bad)[0])
            raise GeometryError(f"run {r}, node {int(master[r])}: RLS information matrix is "
                                "singular (the other nodes' estimates are coincident or "
                                "collinear)", index=(r,),
                                detail="RLS information matrix is singular")
        innov = w * (z - np.einsum("rpa,ra->rp", A, x))
        g = np.einsum("rpa,rp->ra", A, innov)
        step = np.stack([d * g[:, 0] - b * g[:, 1], a * g[:, 1] - b * g[:, 0]],
                        axis=-1) / det[:, None]
        position = state.position.copy()
        position[rr, master] = check_finite_output(x + step, "rls position")  # eq. (11)
        information = state.information.copy()
        information[rr, master] = info
        used = state.used.copy()
        used[rr, master] = w.sum(axis=-1).astype(np.int64)
        return RLSState(position, information, used)

    def iterate(self, state: RLSState, ranges: np.ndarray, mask: np.ndarray | None = None
                ) -> RLSState:
        """One iteration ``n`` of the paper: every node ``k = 0..K-1`` updates once.

        All updates of the iteration use the other nodes' estimates of the previous
        iteration (``x_i(n-1)`` in eq. (8) and eq. (9)), as the paper's node delays its
        update until it holds all ranges of the packet epoch.

        Parameters
        ----------
        state : RLSState
        ranges : ndarray, shape (R, K, K)
            ``ranges[r, k, i]``: range measured at master ``k`` to node ``i`` in run
            ``r``; NaN = missing link.
        mask : ndarray of bool, shape (R, K, K), optional
            Which ranges exist, besides the NaN test.

        Returns
        -------
        RLSState
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
        check_ranges(rho, "ranges", self.std_m or 0.0, used=valid)
        if self.backend == "numpy":
            start = state.position
            for k in range(K):
                state = self.step(state, k, rho[:, k], valid[:, k], reference=start)
            return state
        position = np.array(state.position, dtype=float, order="C")
        information = np.array(state.information, dtype=float, order="C")
        used = np.array(state.used, dtype=np.int64, order="C")
        err = np.full(R, -1, dtype=np.int64)
        from radioloc.estimators.kalman_compiled import network_rls_iteration   # numba: imported when the kernel runs (start-up time)

        network_rls_iteration(position, information, used, np.where(valid, rho, 0.0), valid,
                              float(self.forgetting), _COND_LIMIT, err)
        if np.any(err >= 0):
            hit = np.flatnonzero(err >= 0)
            r = int(hit[np.argmin(err[hit])])                    # the first master, lowest run
            raise GeometryError(f"run {r}, node {int(err[r])}: RLS information matrix is "
                                "singular (the other nodes' estimates are coincident or "
                                "collinear)", index=(r,),
                                detail="RLS information matrix is singular")
        check_finite_output(position, "rls position")
        return RLSState(position.reshape(state.position.shape), information, used)

    def estimate(self, state: RLSState) -> Estimate:
        """The current estimate of every node.

        Parameters
        ----------
        state : RLSState

        Returns
        -------
        Estimate
            ``position`` ``(R, K, 2)``, no covariance (see the class notes);
            ``diagnostics["measurements_used"]`` ``(R, K)``: pairs in each node's latest
            update.
        """
        return Estimate(state.position, None, None, {"measurements_used": state.used})

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
            ``position`` ``(R, K, N, 2)`` after each iteration (the prior, iteration 0,
            is not included).
        """
        return run_iterations(self, self.init(prior_mean, prior_var), ranges, mask, time,
                              self.estimate)

