"""Sequential EKF network positioning over the stacked 2K state (Brown & Iltis,
eq. (13)-eq. (25)).

The state is ``x = [x_1; ...; x_K]`` (eq. (13)), static, so the prediction is the identity
(eq. (20), eq. (24)). At each packet a master node ``k`` measures its ranges to the others
(eq. (14), eq. (15)) and updates the *global* estimate (eq. (19), eq. (21), eq. (22),
eq. (23)); the next master starts from that estimate. A missing link (NaN range, or a
false mask entry) is a row skipped by the update.

Each packet is one update of the generic
:class:`~radioloc.estimators.extended_kalman.ExtendedKalmanFilter` (``backend="numpy"``):
the state is a :class:`~radioloc.models.pair_range.NetworkLayout` of the ``K`` nodes, the
packet an :class:`~radioloc.models.measurement.Observation` of
:class:`~radioloc.models.pair_range.PairRangeModel` rows ``|x_p - x_k|``, ``p != k``
(eq. (15); its Jacobian is eq. (16)-eq. (17), as :func:`range_jacobian` prints it), and the
update is the toolkit's one Kalman update,
:func:`radioloc.estimators.kalman.kalman_update`: the Joseph form
``(I - L H^T) S (I - L H^T)^T + L R L^T``, algebraically eq. (21) but symmetric and
positive semi-definite in floating point. The masters' packets follow one another, each
linearised at the estimate its predecessor left (eq. (20), eq. (24): the nodes are static,
the prediction is the identity). ``backend="numba"`` (the default) runs the compiled form
of the same update, :func:`radioloc.estimators.kalman_compiled.network_ekf_packets`, which
takes the used rows only and uses the two nonzero blocks of each row of ``H``; the two
agree to rounding.

:class:`NetworkEKF` advances a batch of ``R`` independent runs: state ``(R, 2K)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.arrays import kernel_array
from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import GeometryError, InputError
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.results import Estimate, Track
from radioloc.core.validation import check_finite_output, check_positive, check_ranges
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter, FilterState
from radioloc.estimators.network import (check_iteration, check_packet, check_prior,
                                         run_iterations)
from radioloc.models.measurement import Observation
from radioloc.models.motion import RandomWalk
from radioloc.models.pair_range import NetworkLayout, PairRangeModel, packet_context

__all__ = ["NetworkEKF", "EKFState", "range_jacobian"]


@dataclass(frozen=True)
class EKFState:
    """Filter state of ``R`` independent runs of the sequential EKF.

    Attributes
    ----------
    mean : ndarray, shape (R, 2K)
        Stacked estimate ``[x_1, y_1, x_2, y_2, ...]`` (eq. (13)), metres.
    covariance : ndarray, shape (R, 2K, 2K)
        ``Sigma`` of eq. (21), m^2.
    nis : ndarray, shape (R, K)
        Normalised innovation squared of each node's latest packet as master (NaN
        before its first).
    used : ndarray of int, shape (R, K)
        Ranges that entered each node's latest packet (0 before its first).
    """

    mean: np.ndarray
    covariance: np.ndarray
    nis: np.ndarray
    used: np.ndarray

    @property
    def runs(self) -> int:
        """Number of runs ``R``."""
        return self.mean.shape[0]

    @property
    def nodes(self) -> int:
        """Number of nodes ``K``."""
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


def range_jacobian(position: np.ndarray, master: np.ndarray, valid: np.ndarray | None = None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Predicted ranges ``h_k(x)`` (eq. (15)) and Jacobian ``H_k^T`` (eq. (16), eq. (17)).

    Row ``p`` of ``H_k^T`` holds ``u^T = (x_p - x_k)^T / |x_p - x_k|`` in column block ``p``
    and ``-u^T`` in column block ``k``. eq. (17) prints the same sign for both blocks; the
    derivative of ``|x_p - x_k|`` with respect to ``x_k`` is the negative of that with
    respect to ``x_p``, which is what is implemented here. The rows are those of
    :class:`~radioloc.models.pair_range.PairRangeModel` on the packet's node pairs
    (:func:`~radioloc.models.pair_range.packet_context`), placed at row ``p``.

    Parameters
    ----------
    position : ndarray, shape (R, K, 2)
        Current estimates, metres.
    master : ndarray of int, shape (R,)
        The master node of each run.
    valid : ndarray of bool, shape (R, K), optional
        Rows with a false entry (and the master's own row) are zero.

    Returns
    -------
    h : ndarray, shape (R, K)
        Predicted ranges (0 on the master's own entry).
    H : ndarray, shape (R, K, 2K)
        Jacobian, one row per node ``p``.

    Raises
    ------
    GeometryError
        If a valid row has the master and node ``p`` at the same estimated position.
    """
    R, K, _ = position.shape
    if valid is None:
        valid = np.ones((R, K), dtype=bool)
        valid[np.arange(R), master] = False
    h = _distances_to_master(position, master, valid)
    context, others = packet_context(master, K)
    rows = PairRangeModel(std_m=1.0).jacobian({"position": position.reshape(R, 2 * K)},
                                              context)["position"]           # (R, K - 1, 2K)
    H = np.zeros((R, K, 2 * K))
    np.put_along_axis(H, others[..., None], rows, axis=-2)
    return h, np.where(valid[..., None], H, 0.0)


def _distances_to_master(position: np.ndarray, master: np.ndarray, valid: np.ndarray
                         ) -> np.ndarray:
    """``|x_p - x_k|`` ``(R, K)``; a GeometryError when a valid link joins coincident
    estimates (its Jacobian is undefined)."""
    rr = np.arange(position.shape[0])
    h = np.linalg.norm(position - position[rr, master][:, None, :], axis=-1)
    scale = np.maximum(np.max(np.abs(position), axis=(1, 2)), 1.0)
    coincident = valid & (h <= 1e-9 * scale[:, None])
    if np.any(coincident):
        r, p = (int(i) for i in np.argwhere(coincident)[0])
        raise GeometryError(f"run {r}: nodes {int(master[r])} and {p} have coincident position "
                            "estimates; the range Jacobian is undefined", index=(r,),
                            detail=f"nodes {int(master[r])} and {p} have coincident estimates")
    return h


class NetworkEKF(RecursiveEstimator):
    """Sequential EKF network positioning over the stacked state (Brown & Iltis,
    eq. (13)-eq. (25)).

    Parameters
    ----------
    std_m : float
        Range noise standard deviation, metres: ``R_k = std_m^2 I`` (eq. (15)); the paper's
        ``sigma_v^2 = 900 m^2`` is ``std_m=30`` (the default). The old keyword
        ``range_var_m2`` (the variance, also the first positional argument) still works
        with a ``FutureWarning``.
    backend : {"numba", "numpy"}
        ``"numpy"``: each packet by the generic
        :class:`~radioloc.estimators.extended_kalman.ExtendedKalmanFilter` update with
        :class:`~radioloc.models.pair_range.PairRangeModel` rows; ``"numba"``: by its
        compiled form (:func:`~radioloc.estimators.kalman_compiled.network_ekf_packets`).

    Raises
    ------
    ConfigError
        ``std_m`` is not a positive number, or ``backend`` is unknown.

    Notes
    -----
    The estimate depends on the labels of the nodes. Within an iteration the masters
    update the global estimate one after another in node order (eq. (18)-eq. (23)), and
    sequential EKF updates do not commute (each relinearises at the estimate its
    predecessor left), so relabelling the nodes changes the estimate. The ranges fix the
    network's shape, which barely moves (within two range standard deviations after a
    rigid alignment); its frame (translation, rotation) is fixed only by the priors and
    moves by up to about two of the filter's claimed standard deviations (about 1 m with
    1 m priors on a five-node network). The order is the paper's model, kept as written.
    It is the whole effect: relabelled nodes whose packets are fed (by :meth:`step`) in the
    original masters' order give the original estimate, relabelled, to rounding.
    """

    name = "ekf"

    @renamed_keywords({"range_var_m2": Renamed("std_m", variance=True)},
                      positional=("range_var_m2", "backend"))
    def __init__(self, *, std_m: float = 30.0, backend: str = DEFAULT_BACKEND) -> None:
        self.std_m = check_positive(std_m, "std_m")
        self._var_m2 = self.std_m**2
        self.backend = check_backend(backend)
        # the packet rows' model and the filter that updates with them (no gate: eq. (19))
        self._model = PairRangeModel(std_m=self.std_m)
        self._filter = ExtendedKalmanFilter(RandomWalk(0.0), gate=None)

    def init(self, prior_mean: np.ndarray, prior_var: np.ndarray) -> EKFState:
        """Initial state ``x(0|0)`` and ``Sigma(0|0) = diag(prior_var)`` (eq. (25)).

        Parameters
        ----------
        prior_mean : ndarray, shape (R, K, 2)
            Prior mean positions, metres.
        prior_var : ndarray, broadcastable to (R, K, 2)
            Per-axis prior variances, m^2.

        Returns
        -------
        EKFState
        """
        mean, var = check_prior(prior_mean, prior_var)
        R, K, _ = mean.shape
        cov = np.zeros((R, 2 * K, 2 * K))
        idx = np.arange(2 * K)
        cov[:, idx, idx] = var.reshape(R, 2 * K)
        return EKFState(mean.reshape(R, 2 * K), cov, np.full((R, K), np.nan),
                        np.zeros((R, K), dtype=np.int64))

    def step(self, state: EKFState, master_idx: np.ndarray | int, ranges: np.ndarray,
             mask: np.ndarray | None = None) -> EKFState:
        """One packet per run: the master's ranges update the global state (eq. (18)-eq. (23)).

        Parameters
        ----------
        state : EKFState
        master_idx : int or ndarray of int, shape (R,)
            Node that measured in each run.
        ranges : ndarray, shape (R, K)
            The master's ranges to every node, metres; NaN = missing link; the master's
            own entry is ignored.
        mask : ndarray of bool, shape (R, K), optional
            Which ranges exist, besides the NaN test.

        Returns
        -------
        EKFState
            A new state (the input is not modified).

        Raises
        ------
        GeometryError
            A used link joins two nodes with coincident estimates.
        """
        R, K = state.runs, state.nodes
        master, rho, valid = check_packet(master_idx, ranges, mask, R, K)
        check_ranges(rho, "ranges", self.std_m, used=valid)
        return self._apply(state, master[:, None], rho[:, None], valid[:, None])

    def _apply(self, state: EKFState, masters: np.ndarray, rho: np.ndarray,
               valid: np.ndarray) -> EKFState:
        """Packets ``j`` of every run in order (eq. (18)-eq. (23)): ``masters (R, M)``,
        ``rho``/``valid (R, M, K)``."""
        if self.backend == "numpy":
            for j in range(masters.shape[1]):
                state = self._packet(state, masters[:, j], rho[:, j], valid[:, j])
            return state
        R = state.runs
        mean = np.array(state.mean, dtype=float, order="C")
        cov = np.array(state.covariance, dtype=float, order="C")
        nis = np.array(state.nis, dtype=float, order="C")
        used = np.array(state.used, dtype=np.int64, order="C")
        err = np.full((R, 2), -1, dtype=np.int64)
        from radioloc.estimators.kalman_compiled import network_ekf_packets   # numba: imported when the kernel runs (start-up time)

        network_ekf_packets(mean, cov, kernel_array(masters, np.int64), kernel_array(rho),
                            kernel_array(valid, np.bool_), self._var_m2, nis, used, err)
        if np.any(err[:, 0] >= 0):
            hit = np.flatnonzero(err[:, 0] >= 0)
            r = int(hit[np.argmin(err[hit, 0])])          # the earliest packet, lowest run
            k, p = int(masters[r, err[r, 0]]), int(err[r, 1])
            raise GeometryError(f"run {r}: nodes {k} and {p} have coincident position "
                                "estimates; the range Jacobian is undefined", index=(r,),
                                detail=f"nodes {k} and {p} have coincident estimates")
        return EKFState(check_finite_output(mean, "ekf mean"), cov, nis, used)

    def _packet(self, state: EKFState, master: np.ndarray, rho: np.ndarray,
                valid: np.ndarray) -> EKFState:
        """One packet per run in NumPy: the generic EKF update with the master's rows."""
        R, K = state.runs, state.nodes
        rr = np.arange(R)
        _distances_to_master(state.position, master, valid)
        # one context for every run when they share the master (the paper's schedule)
        shared = bool(np.all(master == master[0]))
        context, others = packet_context(master[0] if shared else master, K)
        others = np.broadcast_to(others, (R, K - 1))
        z = np.where(np.take_along_axis(valid, others, axis=-1),
                     np.take_along_axis(rho, others, axis=-1), np.nan)
        prior = FilterState(state.mean, state.covariance, 0.0, NetworkLayout(dim=2, nodes=K))
        post, info = self._filter.update(prior, Observation(self._model, z, context))
        nis = state.nis.copy()
        nis[rr, master] = info["nis"]
        n_used = state.used.copy()
        n_used[rr, master] = info["measurements_used"]
        return EKFState(post.mean, post.covariance, nis, n_used)

    def iterate(self, state: EKFState, ranges: np.ndarray, mask: np.ndarray | None = None
                ) -> EKFState:
        """One iteration ``n``: masters ``k = 0..K-1`` update the global state in turn.

        Parameters
        ----------
        state : EKFState
        ranges : ndarray, shape (R, K, K)
            ``ranges[r, k, i]``: range measured at master ``k`` to node ``i`` in run
            ``r``; NaN = missing link.
        mask : ndarray of bool, shape (R, K, K), optional
            Which ranges exist, besides the NaN test.

        Returns
        -------
        EKFState
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
        check_ranges(rho, "ranges", self.std_m, used=valid)
        masters = np.broadcast_to(np.arange(K), (R, K))
        return self._apply(state, masters, np.where(valid, rho, 0.0), valid)

    def estimate(self, state: EKFState) -> Estimate:
        """The current estimate of every node with its own 2x2 covariance block.

        Parameters
        ----------
        state : EKFState

        Returns
        -------
        Estimate
            ``position`` ``(R, K, 2)``, ``covariance`` ``(R, K, 2, 2)``; diagnostics
            ``nis`` and ``measurements_used`` ``(R, K)`` of each node's latest packet as
            master.
        """
        return Estimate(state.position, state.position_covariance, None,
                        {"nis": state.nis, "measurements_used": state.used})

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
            ``position`` ``(R, K, N, 2)`` and ``covariance`` ``(R, K, N, 2, 2)`` after each
            iteration (the prior, iteration 0, is not included).
        """
        return run_iterations(self, self.init(prior_mean, prior_var), ranges, mask, time,
                              self.estimate)
