"""``radioloc locate --method gn``: per-epoch Gauss-Newton multilateration to anchors
(:class:`radioloc.estimators.multilateration.Multilateration`)."""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from radioloc.core.errors import GeometryError
from radioloc.estimators.multilateration import Multilateration, anchor_phrase
from radioloc.locate.base import LocateRequest, Option, locate_method


@locate_method("gn", "Gauss-Newton multilateration of each node at each time from its ranges "
                     "to anchors (options: range_std_m)",
               options={"range_std_m": Option("range error standard deviation, m (default: from "
                                              "the residuals)", float, min=0, min_exclusive=True,
                                              max=1e7),
                        "on_degenerate": Option("'error' (default): stop at the first epoch whose "
                                                "geometry does not fix the position (e.g. a mirror "
                                                "fix); 'skip': leave such epochs out and say how "
                                                "many", str, choices=("error", "skip"))},
               kinds=("range",), inputs=("anchors",))
def locate_gn(request: LocateRequest) -> pd.DataFrame:
    """Locate every ``(time, node)`` epoch from its ranges to the anchors.

    Each epoch with at least ``d + 1`` anchor ranges is solved independently; all epochs
    go through one batched :class:`Multilateration` call (missing anchor ranges are NaN).
    Ranges to other nodes are not used by this method. Option ``range_std_m`` sets the
    range noise used for the uncertainty (default: estimated from the residuals of each
    epoch). An epoch whose geometry does not fix the position (collinear anchors, a mirror
    fix that fits the ranges as well, a singular information matrix) stops the method with
    a :class:`GeometryError`, or, with ``-o on_degenerate=skip``, is left out of the output
    with one warning that counts such epochs and names the first.

    Parameters
    ----------
    request : LocateRequest
        The parsed measurements, the anchors and the ``-o`` options.

    Returns
    -------
    DataFrame
        Columns ``time, node, x, y[, z], uncertainty_m`` (one row per epoch).

    Raises
    ------
    GeometryError
        An epoch has too few anchor ranges or a degenerate geometry; the message names
        the node and the time.
    """
    anchors = request.require_anchors("gn")
    ranges = request.kind("range", "gn")
    ranges = ranges[ranges["peer"].isin(set(anchors["id"]))]
    dims = ["x", "y"] + (["z"] if "z" in anchors.columns else [])
    if ranges.empty:
        raise GeometryError("method gn: no range to an anchor in the measurements")
    # duplicate (time, node, peer) measurements are averaged
    ranges = ranges.groupby(["time", "node", "peer"], sort=True, as_index=False).agg(
        value=("value", "mean"), line=("line", "min"))
    epochs = ranges[["time", "node"]].drop_duplicates().reset_index(drop=True)
    anchor_index = {a: i for i, a in enumerate(anchors["id"])}
    e_idx = ranges.merge(epochs.reset_index(), on=["time", "node"])["index"].to_numpy()
    a_idx = ranges["peer"].map(anchor_index).to_numpy()
    n_e, n_a = len(epochs), len(anchors)
    R = np.full((n_e, n_a), np.nan)
    R[e_idx, a_idx] = ranges["value"].to_numpy()
    counts = np.isfinite(R).sum(axis=1)
    need = len(dims) + 1
    if np.any(counts < need):
        i = int(np.flatnonzero(counts < need)[0])
        raise GeometryError(f"method gn: node {epochs['node'][i]!r} at time {float(epochs['time'][i])!r} "
                            f"has ranges to {int(counts[i])} anchor(s); {need} are needed in "
                            f"{len(dims)}-D" + (
                                " (ranges that arrive one anchor at a time: track them with "
                                "--method ekf-track or pf, or sample them on common epochs)"
                                if np.median(counts) < need else ""))
    skip = request.option("on_degenerate", "error", str) == "skip"
    try:
        fit = Multilateration(range_std_m=request.option("range_std_m"),
                              on_degenerate="flag" if skip else "raise").locate(
            R, anchors[dims].to_numpy())
    except GeometryError as exc:
        if exc.index is None:
            raise GeometryError(f"method gn: {exc}") from None
        i = exc.index[0]
        detail = exc.detail
        if exc.anchors is not None:          # name the anchors by their ids, not indices
            ids = ", ".join(str(anchors["id"].iloc[k]) for k in exc.anchors)
            detail = detail.replace(anchor_phrase(exc.anchors), f"anchors {ids}")
        raise GeometryError(f"method gn: node {epochs['node'][i]!r} at time {float(epochs['time'][i])!r}: "
                            f"{detail}") from None
    out = epochs.copy()
    for k, c in enumerate(dims):
        out[c] = fit.position[:, k]
    out["uncertainty_m"] = fit.uncertainty_m
    bad = np.asarray(fit.diagnostics["degenerate"])
    mirror = np.asarray(fit.diagnostics["ambiguous"])
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        if bad.all():
            raise GeometryError(f"method gn: no epoch has a geometry that fixes the position "
                                f"({int(mirror.sum())} ambiguous mirror fixes; first: node "
                                f"{epochs['node'][i]!r} at time {float(epochs['time'][i])!r})")
        warnings.warn(f"method gn: {int(bad.sum())} of {bad.size} epochs left out: their geometry "
                      f"does not fix the position ({int(mirror.sum())} of them ambiguous: a "
                      "mirror fix fits the ranges as well; first: node "
                      f"{epochs['node'][i]!r} at time {float(epochs['time'][i])!r})", stacklevel=2)
        out = out[~bad].reset_index(drop=True)
    return out
