"""Shared input checks and run loop of the cooperative network estimators (:mod:`.rls`,
:mod:`.ekf`).

Both estimators take one *packet* per run of the batch: the index of the master node
that measured and its ranges to every node (its own entry ignored). A NaN range, or one
whose mask entry is false, is a missing link and is skipped.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import as_float_array, refuse_infinite

__all__ = ["check_packet", "check_prior", "check_iteration", "run_iterations"]


def check_packet(master_idx: object, ranges: object, mask: object | None,
                 runs: int, nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate one packet per run.

    Parameters
    ----------
    master_idx : int or ndarray of int, shape (R,)
        Node that measured, per run.
    ranges : ndarray, shape (R, K)
        Ranges from the master to each node, metres; the master's own entry, NaN entries
        and entries with a false mask are missing links.
    mask : ndarray of bool, shape (R, K), or None
        Which ranges exist (``None``: every finite range except the master's own).
    runs, nodes : int
        ``R`` and ``K`` of the state.

    Returns
    -------
    master : ndarray of int, shape (R,)
    ranges : ndarray, shape (R, K)
        With missing entries set to 0.
    valid : ndarray of bool, shape (R, K)
        The links used, the master's own entry cleared.

    Raises
    ------
    InputError
        A master index is out of range, a shape disagrees or a range is infinite.
    """
    master = np.broadcast_to(np.asarray(master_idx), (runs,))
    if not np.issubdtype(master.dtype, np.integer):
        raise InputError(f"master_idx: expected integer node indices, got dtype {master.dtype}")
    if np.any((master < 0) | (master >= nodes)):
        bad = int(np.flatnonzero((master < 0) | (master >= nodes))[0])
        raise InputError(f"master_idx: run {bad} names node {int(master[bad])}, "
                         f"outside 0..{nodes - 1}")
    rho = np.asarray(ranges, dtype=float)
    if rho.shape != (runs, nodes):
        raise InputError(f"ranges: expected shape ({runs}, {nodes}), got {rho.shape}")
    if mask is None:
        valid = np.ones((runs, nodes), dtype=bool)
    else:
        valid = np.asarray(mask, dtype=bool)
        if valid.shape != (runs, nodes):
            raise InputError(f"mask: expected shape ({runs}, {nodes}), got {valid.shape}")
        valid = valid.copy()
    valid[np.arange(runs), master] = False
    valid &= ~np.isnan(rho)                                    # NaN = missing link
    bad = valid & ~np.isfinite(rho)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"ranges: infinite value at (run, node) {idx}")
    return master.astype(np.intp), np.where(valid, rho, 0.0), valid


def check_prior(prior_mean: object, prior_var: object) -> tuple[np.ndarray, np.ndarray]:
    """Check the node priors of a batch of networks.

    Parameters
    ----------
    prior_mean : ndarray, shape (R, K, 2)
        Prior mean positions, metres (``K >= 3``).
    prior_var : ndarray, broadcastable to (R, K, 2)
        Per-axis prior variances, m^2 (> 0).

    Returns
    -------
    mean : ndarray, shape (R, K, 2)
        A copy of the prior means.
    var : ndarray, shape (R, K, 2)
        The variances broadcast to the means' shape.

    Raises
    ------
    InputError
        Naming ``prior_mean`` or ``prior_var``.
    """
    mean = as_float_array(prior_mean, "prior_mean", ndim=3, last_dim=2)
    var = as_float_array(prior_var, "prior_var", nonnegative=True)
    try:
        var = np.broadcast_to(var, mean.shape).astype(np.float64)
    except ValueError:
        raise InputError(f"prior_var: shape {var.shape} does not broadcast to prior_mean's "
                         f"{mean.shape}") from None
    if np.any(var <= 0):
        idx = tuple(int(i) for i in np.argwhere(var <= 0)[0])
        raise InputError(f"prior_var: must be > 0 (m^2), got 0 at index {idx}")
    # the filters invert and update these variances against metre-scale range variances:
    # beyond this window the update loses every digit (a NaN estimate) or overflows
    out = (var < 1e-24) | (var > 1e12)
    if np.any(out):
        idx = tuple(int(i) for i in np.argwhere(out)[0])
        raise InputError(f"prior_var: {var[idx]:g} m^2 at index {idx} is outside the supported "
                         "range [1e-24, 1e12] m^2")
    if mean.shape[1] < 3:
        raise InputError(f"prior_mean: a network needs at least 3 nodes, got {mean.shape[1]}")
    return mean.copy(), var


def check_iteration(ranges: object, mask: object | None, runs: int, nodes: int
                    ) -> tuple[np.ndarray, np.ndarray | None]:
    """Check the ranges of one iteration of every master.

    Parameters
    ----------
    ranges : ndarray, shape (R, K, K)
        ``ranges[r, k, i]``: range measured at master ``k`` to node ``i`` in run ``r``
        (NaN = missing link).
    mask : ndarray of bool, shape (R, K, K), or None
        Which ranges exist, besides the NaN test.
    runs, nodes : int
        ``R`` and ``K`` of the state.

    Returns
    -------
    ranges : ndarray, shape (R, K, K)
    mask : ndarray of bool, shape (R, K, K), or None

    Raises
    ------
    InputError
        A shape disagrees.
    """
    rho = refuse_infinite(as_float_array(ranges, "ranges", ndim=3, allow_nan=True), "ranges")
    if rho.shape != (runs, nodes, nodes):
        raise InputError(f"ranges: expected shape ({runs}, {nodes}, {nodes}), got {rho.shape}")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != rho.shape:
            raise InputError(f"mask: expected shape {rho.shape}, got {mask.shape}")
    return rho, mask


def run_iterations(estimator: Any, state: Any, ranges: object, mask: object | None,
                   time: object | None, estimate: Callable[[Any], Estimate]) -> Track:
    """Apply ``estimator.iterate`` over the iterations of ``ranges`` and stack a track.

    Parameters
    ----------
    estimator : NetworkRLS or NetworkEKF
        Provides ``iterate(state, ranges, mask)``.
    state : the initial filter state
    ranges : ndarray, shape (R, N, K, K)
        Ranges of ``N`` iterations (NaN = missing link).
    mask : ndarray of bool, shape (R, N, K, K), or None
    time : ndarray, shape (N,), optional
        Time of each iteration; default the iteration number ``1..N``.
    estimate : callable
        ``estimate(state) -> Estimate`` of the estimator.

    Returns
    -------
    Track
        ``position`` ``(R, K, N, 2)``: batch axes (runs, nodes) lead, iterations follow.
    """
    rho = refuse_infinite(as_float_array(ranges, "ranges", ndim=4, allow_nan=True), "ranges")
    R, N = rho.shape[:2]
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        if mask.shape != rho.shape:
            raise InputError(f"mask: expected shape {rho.shape}, got {mask.shape}")
    if N < 1:
        raise InputError("ranges: no iteration (axis 1 is empty)")
    t = np.arange(1, N + 1, dtype=float) if time is None else as_float_array(time, "time", ndim=1)
    if t.shape != (N,):
        raise InputError(f"time: expected shape ({N},), got {t.shape}")
    steps = []
    for n in range(N):                                       # loop over time only
        state = estimator.iterate(state, rho[:, n], None if mask is None else mask[:, n])
        steps.append(estimate(state))
    return track_from_steps(steps, t)
