"""Error metrics on batched estimates.

All functions take estimates and truths as broadcastable ``(..., d)`` arrays and reduce
over the axes the caller names, so the same code serves one run or a batch of runs.
"""

from __future__ import annotations

import numpy as np
import pandas as pd


def position_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Euclidean position error ``||estimate - truth||`` over the last axis.

    Parameters
    ----------
    estimate, truth : array_like, broadcastable, shape (..., d)

    Returns
    -------
    ndarray, shape (...)
    """
    return np.sqrt(np.sum((np.asarray(estimate) - np.asarray(truth)) ** 2, axis=-1))


def mean_error(estimate: np.ndarray, truth: np.ndarray, axis=None) -> np.ndarray | float:
    """Mean Euclidean error (the papers' "average position error").

    Parameters
    ----------
    estimate, truth : array_like, broadcastable, shape (..., d)
    axis : int or tuple of int, optional
        Axes of the error array to average over (default all).

    Returns
    -------
    float or ndarray
    """
    return np.mean(position_error(estimate, truth), axis=axis)


def rmse(estimate: np.ndarray, truth: np.ndarray, axis=None) -> np.ndarray | float:
    """Root mean square position error: ``sqrt(mean ||e||^2)``.

    Parameters
    ----------
    estimate, truth : array_like, broadcastable, shape (..., d)
    axis : int or tuple of int, optional
        Axes of the error array to average over (default all).

    Returns
    -------
    float or ndarray
    """
    err = position_error(estimate, truth)
    return np.sqrt(np.mean(err**2, axis=axis))


def error_cdf(errors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Empirical CDF of errors.

    Parameters
    ----------
    errors : array_like
        Any shape (flattened).

    Returns
    -------
    values, probabilities : ndarray
        Sorted errors and their cumulative probabilities ``k / n``.
    """
    e = np.sort(np.ravel(np.asarray(errors, dtype=float)))
    p = np.arange(1, e.size + 1) / e.size
    return e, p


def error_vs_step(frame: pd.DataFrame, *, step: str = "step", error: str = "error_m",
                  by: list[str] | None = None) -> pd.DataFrame:
    """Average error per step (and per group) from a tidy results table.

    Parameters
    ----------
    frame : DataFrame
        Tidy table with one error per row.
    step, error : str
        Names of the step and error columns.
    by : list of str, optional
        Grouping columns.

    Returns
    -------
    DataFrame
        Columns ``[*by, step, mean, rmse, count]``.
    """
    keys = [*(by or []), step]
    f = frame[keys].assign(_e=frame[error], _e2=frame[error] ** 2)
    out = f.groupby(keys, sort=True).agg(mean=("_e", "mean"), _ms=("_e2", "mean"),
                                         count=("_e", "count")).reset_index()
    out["rmse"] = np.sqrt(out.pop("_ms"))
    return out


def first_step_within(curve: np.ndarray, tolerance: float = 0.10) -> int:
    """First index at which ``curve`` is within ``tolerance`` (relative) of its final value
    and stays there; a convergence time.

    Parameters
    ----------
    curve : array_like, shape (N,)
    tolerance : float
        Relative band around the final value.

    Returns
    -------
    int
    """
    c = np.asarray(curve, dtype=float)
    final = c[-1]
    ok = np.abs(c - final) <= tolerance * abs(final)
    # last index where it is not ok, plus one
    bad = np.flatnonzero(~ok)
    return int(bad[-1] + 1) if bad.size else 0
