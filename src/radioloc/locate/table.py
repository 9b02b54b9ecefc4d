"""The output table of ``radioloc locate``: covariance columns and one row order.

Every method returns one row per ``(time, node)``: ``time, node, x, y[, z]``, then, where the
method has a position covariance, ``uncertainty_m`` (square root of its trace, metres) and the
covariance columns ``cov_xx, cov_xy, cov_yy[, cov_xz, cov_yz, cov_zz]`` (m^2), then the
method's per-row flags (e.g. ``gated``, ``restart``, ``p_nlos``). :func:`order_rows` sorts
the rows time-major (time, then node in the order of the file) for every method.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.results import COVARIANCE_COLUMNS, COVARIANCE_ENTRY as _INDEX


def add_covariance(frame: pd.DataFrame, covariance: np.ndarray) -> pd.DataFrame:
    """``frame`` with ``uncertainty_m`` and the covariance columns of ``covariance``.

    Parameters
    ----------
    frame : DataFrame
        One row per estimate.
    covariance : ndarray, shape (N, D, D)
        Position covariance of each row, m^2 (D = 2 or 3).

    Returns
    -------
    DataFrame
        A copy with the new columns.
    """
    return frame.assign(**covariance_columns(covariance))


def covariance_columns(covariance: np.ndarray) -> dict[str, np.ndarray]:
    """``uncertainty_m`` and the covariance columns of ``covariance`` ``(N, D, D)`` (m^2),
    in the table's order."""
    cov = np.asarray(covariance, dtype=float)
    out = {"uncertainty_m": np.sqrt(np.trace(cov, axis1=-2, axis2=-1))}
    for name in COVARIANCE_COLUMNS[cov.shape[-1]]:
        i, j = _INDEX[name]
        out[name] = cov[:, i, j]
    return out


def covariance_of(frame: pd.DataFrame) -> np.ndarray | None:
    """The position covariance ``(N, D, D)`` written in ``frame``'s columns, or None.

    Parameters
    ----------
    frame : DataFrame
        A ``locate`` output table.

    Returns
    -------
    ndarray or None
    """
    dim = 3 if "cov_zz" in frame.columns else 2
    names = COVARIANCE_COLUMNS[dim]
    if any(c not in frame.columns for c in names):
        return None
    cov = np.zeros((len(frame), dim, dim))
    for name in names:
        i, j = _INDEX[name]
        cov[:, i, j] = cov[:, j, i] = frame[name].to_numpy(dtype=float)
    return cov


def order_rows(frame: pd.DataFrame, node_order: list[str] | None = None) -> pd.DataFrame:
    """Rows sorted by time, then node (nodes in ``node_order``, else by name).

    Parameters
    ----------
    frame : DataFrame
        With ``time`` and ``node`` columns.
    node_order : list of str, optional
        Node ids in the order they should appear within one time.

    Returns
    -------
    DataFrame
        Sorted (stable), index reset, ``attrs`` kept.
    """
    attrs = dict(frame.attrs)
    nodes = node_order if node_order is not None else sorted(set(frame["node"]))
    rank = {n: i for i, n in enumerate(nodes)}
    key = frame["node"].map(rank).fillna(len(rank)).to_numpy()
    order = np.lexsort((key, frame["time"].to_numpy(dtype=float)))
    out = frame.iloc[order].reset_index(drop=True)
    out.attrs.update(attrs)
    return out
