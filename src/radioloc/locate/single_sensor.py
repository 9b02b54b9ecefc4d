"""``radioloc locate --method closed-form | newton``: paper 002's single-sensor trackers on a
log.

Each node (the target) ranges to ONE sensor that moves along a known track: the sensor is
the node's peer, an anchor whose positions over time are rows of the anchors file with a
``time`` column (:func:`radioloc.io.read_anchors`), interpolated at the measurement times
(:func:`radioloc.locate.adapter.anchor_points`). The node's ranges must lie on a uniform
time grid (period: the median interval; a missing sample is a NaN of the grid). Over a
sliding window of ``window`` samples the node is taken to move on a straight line at
constant velocity (perturbed by white acceleration of standard deviation
``accel_std_mps2``):

- ``closed-form``: :class:`~radioloc.estimators.closed_form.ClosedFormTracker`, the
  iterative BLUE of the third-differenced squared ranges (paper 002, steps 1-3d);
  covariance: its block of eq. (15);
- ``newton``: :class:`~radioloc.estimators.nlls_newton.NewtonTracker`, Newton iterations
  on the range least squares (the paper's baseline), started at the closed-form state of
  the same window; no covariance.

Each window's estimate is the state at its last sample; the first ``window - 1`` samples
are the first window's straight track at those times (covariance propagated along it).
Rows: one per time at which the node has a range. 2-D only.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import GeometryError, InputError
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.estimators.nlls_newton import NewtonTracker
from radioloc.locate.adapter import anchor_points
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.progress import counted
from radioloc.locate.table import add_covariance
from radioloc.models.single_sensor import MIN_SAMPLES

__all__ = ["OPTIONS", "sensor_windows", "locate_closed_form", "locate_newton"]

#: Largest offset of a range's time from the uniform grid, in sample periods.
GRID_TOLERANCE = 0.05

OPTIONS = {
    "window": Option(f"samples per fit (>= {MIN_SAMPLES}; default 10)", int, min=MIN_SAMPLES,
                     max=10**5),
    "accel_std_mps2": Option("standard deviation of the node's acceleration per axis, m/s^2 "
                             "(default 0.1)", float, min=0, max=1e3),
    "range_std_m": Option("range error standard deviation, m (default 0.15)", float, min=0,
                          min_exclusive=True, max=1e6),
}


def sensor_windows(request: LocateRequest, method: str):
    """Each node's ranges to its moving sensor on a uniform grid, cut into windows.

    Parameters
    ----------
    request : LocateRequest
    method : str
        For messages.

    Returns
    -------
    list of (node, times (G,), has (G,) bool, ranges (W, n), sensor (W, n, 2), period_s)
        ``has``: grid samples with a range (the output rows); window ``w`` ends at grid
        sample ``w + n - 1``.

    Raises
    ------
    InputError
        3-D anchors; a node ranging to several peers; ranges off a uniform grid; a time
        outside the sensor's track.
    GeometryError
        A node with fewer grid samples than ``window``.
    """
    anchors = request.require_anchors(method)
    if "z" in anchors.columns:
        raise InputError(f"method {method}: tracks in 2-D; the anchors file has a z column")
    n = request.option("window", 10, int)
    rows = request.kind("range", method)
    rows = rows[rows["peer"].isin(set(anchors["id"]))]
    if rows.empty:
        raise GeometryError(f"method {method}: no range to an anchor in the measurements")
    rows = rows.groupby(["node", "time", "peer"], sort=True, as_index=False)["value"].mean()
    out = []
    for node in dict.fromkeys(request.measurements["node"]):
        r = rows[rows["node"] == node]
        if r.empty:
            continue
        peers = list(dict.fromkeys(r["peer"]))
        if len(peers) > 1:
            raise InputError(f"method {method}: node {node!r} ranges to {len(peers)} anchors "
                             f"({', '.join(map(str, peers[:3]))}); this method takes one "
                             "moving sensor per node")
        t = r["time"].to_numpy(dtype=float)
        if t.size < n:
            raise GeometryError(f"method {method}: node {node!r} has {t.size} ranges; a window "
                                f"needs {n} (-o window)")
        period = float(np.median(np.diff(t)))
        k = (t - t[0]) / period
        off = np.abs(k - np.round(k))
        if off.max() > GRID_TOLERANCE:
            i = int(np.argmax(off))
            raise InputError(f"method {method}: node {node!r}: the range at time {float(t[i])!r} is "
                             f"off the uniform grid of period {period:g} s (this method needs "
                             "evenly spaced samples; a missing sample is fine)")
        idx = np.round(k).astype(int)
        grid = t[0] + period * np.arange(idx[-1] + 1)
        R = np.full(grid.size, np.nan)
        R[idx] = r["value"].to_numpy(dtype=float)
        has = np.zeros(grid.size, dtype=bool)
        has[idx] = True
        grid[idx] = t                            # the rows keep their own time stamps
        S = anchor_points(anchors, peers, grid)[:, 0, :]
        win = np.lib.stride_tricks.sliding_window_view
        out.append((node, grid, has, win(R, n), np.moveaxis(win(S, n, axis=0), -1, -2), period))
    return out


def _rows(node, grid, has, position, cov, first_state, first_cov, n, period):
    """Rows at the grid samples with a range: window ends, and the first window's track."""
    G = grid.size
    lead = np.arange(n - 1) - (n - 1)                       # samples before the first end
    pos = np.concatenate([first_state[:2] + lead[:, None] * period * first_state[2:],
                          position])
    table = pd.DataFrame({"time": grid, "node": node})
    for j, c in enumerate("xy"):
        table[c] = pos[:, j]
    if cov is not None:
        Gm = np.zeros((n - 1, 2, 4))
        Gm[:, :, :2] = np.eye(2)
        Gm[:, :, 2:] = lead[:, None, None] * period * np.eye(2)
        lead_cov = Gm @ first_cov @ np.swapaxes(Gm, -1, -2)
        table = add_covariance(table, np.concatenate([lead_cov, cov]))
    return table[has[:G]].reset_index(drop=True)


def _track(request: LocateRequest, method: str) -> pd.DataFrame:
    n = request.option("window", 10, int)
    accel = request.option("accel_std_mps2", 0.1) ** 2
    std = request.option("range_std_m", 0.15)
    tables = []
    for node, grid, has, R, S, period in counted(
            sensor_windows(request, method), len(request.measurements),
            lambda window: int(np.isfinite(window[3]).sum()), method):
        try:
            fit = ClosedFormTracker(accel, std_m=std).locate(R, S, period)
            state = np.asarray(fit.diagnostics["state"])
            cov = fit.covariance
            if method == "newton":
                fit = NewtonTracker().locate(R, S, period, initial_state=state)
                state, cov = np.asarray(fit.diagnostics["state"]), None
        except GeometryError as exc:
            if exc.index is None:
                raise GeometryError(f"method {method}: node {node!r}: {exc}") from None
            end = int(exc.index[0]) + n - 1
            raise GeometryError(f"method {method}: node {node!r}, the window ending at time "
                                f"{float(grid[end])!r}: {exc.detail} (a longer -o window "
                                "bridges missing samples)") from None
        bad = ~np.all(np.isfinite(fit.position), axis=-1)
        if bad.any():
            end = int(np.flatnonzero(bad)[0]) + n - 1
            raise GeometryError(f"method {method}: node {node!r}: the window ending at time "
                                f"{float(grid[end])!r} does not fix the track")
        first_cov = None if cov is None else np.asarray(fit.diagnostics["state_covariance"])[0]
        tables.append(_rows(node, grid, has, np.asarray(fit.position), cov, state[0],
                            first_cov, n, period))
    out = pd.concat(tables, ignore_index=True).sort_values(["time", "node"], kind="stable")
    out = out.reset_index(drop=True)
    out.attrs["summary"] = {"nodes": len(tables), "rows": len(out), "window": n,
                            "accel_std_mps2": float(np.sqrt(accel)), "range_std_m": std}
    return out


@locate_method("closed-form", "Paper 002's closed-form tracker: each node from its ranges to "
                              "one moving sensor (an anchor with a track), straight line at "
                              "constant velocity over a sliding window (2-D)",
               options=OPTIONS, kinds=("range",), inputs=("anchors",), moving_anchors=True)
def locate_closed_form(request: LocateRequest) -> pd.DataFrame:
    """Track every node with :class:`ClosedFormTracker` (module docstring).

    Parameters
    ----------
    request : LocateRequest
        Range rows to one moving anchor per node, the anchors (with ``time``), ``-o``.

    Returns
    -------
    DataFrame
        ``time, node, x, y, uncertainty_m``, covariance columns, one row per range time.
    """
    return _track(request, "closed-form")


@locate_method("newton", "Paper 002's Newton baseline: each node from its ranges to one "
                         "moving sensor, range least squares over a sliding window started "
                         "at the closed form (2-D)",
               options=OPTIONS, kinds=("range",), inputs=("anchors",), moving_anchors=True)
def locate_newton(request: LocateRequest) -> pd.DataFrame:
    """Track every node with :class:`NewtonTracker` (module docstring).

    Parameters
    ----------
    request : LocateRequest
        As :func:`locate_closed_form`.

    Returns
    -------
    DataFrame
        ``time, node, x, y``, one row per range time.
    """
    return _track(request, "newton")
