"""Shared input checks of the cooperative network estimators (:mod:`.rls`, :mod:`.ekf`).

Both estimators take one *packet* per run of the batch: the index of the master node
that measured, its ranges to every node (its own entry ignored) and a validity mask.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array


def check_packet(master_idx: object, ranges: object, mask: object | None,
                 runs: int, nodes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate one packet per run.

    Parameters
    ----------
    master_idx : (R,) int array or int
        Node that measured, per run.
    ranges : (R, K) array, metres
        Ranges from the master to each node; the master's own entry and entries with a
        false mask are ignored (they may be NaN).
    mask : (R, K) bool array or None
        Which ranges exist (``None``: all except the master's own).

    Returns
    -------
    master (R,) int, ranges (R, K) float with ignored entries set to 0, valid (R, K) bool
    with the master's own entry cleared.
    """
    master = np.broadcast_to(np.asarray(master_idx), (runs,))
    if not np.issubdtype(master.dtype, np.integer):
        raise InputError(f"master_idx: expected integer node indices, got dtype {master.dtype}")
    if np.any((master < 0) | (master >= nodes)):
        bad = int(np.flatnonzero((master < 0) | (master >= nodes))[0])
        raise InputError(f"master_idx: run {bad} names node {int(master[bad])}, "
                         f"outside 0..{nodes - 1}")
    rho = as_float_array(ranges, "ranges", allow_nan=True)
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
    bad = valid & ~np.isfinite(rho)
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"ranges: non-finite value at (run, node) {idx} marked valid by mask")
    return master.astype(np.intp), np.where(valid, rho, 0.0), valid


def check_prior(prior_mean: object, prior_var: object) -> tuple[np.ndarray, np.ndarray]:
    """Prior means ``(R, K, 2)`` and per-axis variances ``(R, K, 2)`` (broadcast), checked."""
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
    if mean.shape[1] < 3:
        raise InputError(f"prior_mean: a network needs at least 3 nodes, got {mean.shape[1]}")
    return mean.copy(), var
