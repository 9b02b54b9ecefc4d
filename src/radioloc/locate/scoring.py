"""Errors of a ``radioloc locate`` output against a reference trajectory (``--reference``).

The reference (``time[, node], x, y[, z]``, :func:`radioloc.io.read_reference`) is
interpolated linearly in time, per node, at each estimate's time; estimates outside the
reference's time span of their node are not scored. A reference without a ``node`` column
is every node's. Errors are horizontal (x, y) unless both tables have ``z``.

Consistency of the claimed uncertainty: the fraction of scored rows whose error lies inside
the row's 95 % ellipse (ellipsoid in 3-D), ``e' C^-1 e <= chi2_D(0.95)``, with ``C`` the
covariance columns; about 0.95 for an honest covariance, much less for an overconfident one.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.locate.table import covariance_of

#: chi-square 95 % quantiles for 2 and 3 degrees of freedom
CHI2_95 = {2: 5.991464547107979, 3: 7.814727903251178}


def reference_errors(estimates: pd.DataFrame, reference: pd.DataFrame) -> pd.DataFrame:
    """Per-row errors of ``estimates`` against ``reference``.

    Parameters
    ----------
    estimates : DataFrame
        A ``locate`` output table.
    reference : DataFrame
        From :func:`radioloc.io.read_reference`.

    Returns
    -------
    DataFrame
        ``time, node, error_m`` and ``inside_95`` (bool; NaN without covariance columns), one
        row per scored estimate, in the estimates' order.

    Raises
    ------
    InputError
        No estimate falls within the reference (wrong nodes or times).
    """
    dims = ["x", "y"] + (["z"] if "z" in estimates and "z" in reference else [])
    cov = covariance_of(estimates)
    rows = []
    for node, idx in estimates.groupby("node", sort=False).indices.items():
        ref = reference if "node" not in reference else reference[reference["node"] == node]
        if ref.empty:
            continue
        t_ref = ref["time"].to_numpy(dtype=float)
        t = estimates["time"].to_numpy(dtype=float)[idx]
        inside = (t >= t_ref[0]) & (t <= t_ref[-1])
        idx, t = idx[inside], t[inside]
        if idx.size == 0:
            continue
        truth = np.stack([np.interp(t, t_ref, ref[c].to_numpy(dtype=float)) for c in dims], -1)
        err = estimates[dims].to_numpy(dtype=float)[idx] - truth
        part = pd.DataFrame({"row": idx, "time": t, "node": node,
                             "error_m": np.sqrt(np.sum(err ** 2, axis=-1))})
        if cov is not None:
            c = cov[idx][:, : len(dims), : len(dims)]
            # a singular covariance (a claimed point) holds no error but zero
            tr = np.trace(c, axis1=-2, axis2=-1)
            c = c + (1e-12 * np.maximum(tr, 1e-300))[:, None, None] * np.eye(len(dims))
            with np.errstate(all="ignore"):
                m2 = np.einsum("ni,ni->n", err, np.linalg.solve(c, err[..., None])[..., 0])
            m2 = np.where(np.isnan(m2), np.inf, m2)
            part["inside_95"] = m2 <= CHI2_95[len(dims)]
        rows.append(part)
    if not rows:
        raise InputError("reference: no estimate lies within the reference's nodes and times")
    out = pd.concat(rows, ignore_index=True).sort_values("row", kind="stable")
    return out.drop(columns="row").reset_index(drop=True)


def error_summary(errors: pd.DataFrame, rows: int) -> dict:
    """RMSE, median, 90th percentile and 95 % coverage of :func:`reference_errors`.

    Parameters
    ----------
    errors : DataFrame
        From :func:`reference_errors`.
    rows : int
        Output rows (scored or not).

    Returns
    -------
    dict
        ``rows_scored``, ``rows``, ``rmse_m``, ``median_m``, ``p90_m``, ``max_m`` and
        ``inside_95`` (fraction, None without covariance), overall and ``per_node``.
    """
    def one(e: pd.DataFrame) -> dict:
        v = e["error_m"].to_numpy()
        return {"rows_scored": int(v.size), "rmse_m": float(np.sqrt(np.mean(v ** 2))),
                "median_m": float(np.median(v)), "p90_m": float(np.percentile(v, 90)),
                "max_m": float(v.max()),
                "inside_95": float(e["inside_95"].mean()) if "inside_95" in e else None}

    out = dict(one(errors), rows=int(rows))
    out["per_node"] = {str(n): one(g) for n, g in errors.groupby("node", sort=False)}
    return out


def error_lines(summary: dict) -> list[str]:
    """The error summary as text lines for the terminal."""
    def text(s: dict) -> str:
        cover = "" if s["inside_95"] is None else f", inside 95 % ellipse {s['inside_95']:.0%}"
        return (f"RMSE {s['rmse_m']:.3g} m, median {s['median_m']:.3g} m, p90 "
                f"{s['p90_m']:.3g} m, max {s['max_m']:.3g} m{cover}")

    lines = [f"reference: {summary['rows_scored']} of {summary['rows']} rows scored: "
             + text(summary)]
    if len(summary["per_node"]) > 1:
        lines += [f"  {node}: {text(s)}" for node, s in summary["per_node"].items()]
    return lines
