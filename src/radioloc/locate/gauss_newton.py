"""``radioloc locate --method gn``: per-epoch Gauss-Newton multilateration to anchors
(:class:`radioloc.estimators.multilateration.Multilateration`).

Uncertainty: the covariance of each fix is ``s^2 (J' J)^-1`` with ``s`` the range error
standard deviation of the whole log: ``-o std_m`` when given, otherwise pooled over every
epoch the log fixes, ``s^2 = sum of squared residuals / sum of (ranges - D)``. One epoch's own
residuals are not used: an epoch of three anchors in 2-D has one degree of freedom, and its
residual can be centimetres for a fix metres off.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, GeometryError
from radioloc.estimators.multilateration import Multilateration, anchor_phrase
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.table import add_covariance

#: Smallest pooled range standard deviation (exact ranges leave zero residuals), m.
STD_FLOOR_M = 1e-6


def _inverse_information(position: np.ndarray, anchors: np.ndarray, heard: np.ndarray,
                         skip: np.ndarray) -> np.ndarray:
    """``(J' J)^-1`` of each fix ``(E, D)`` from the unit vectors to the anchors it heard
    (``heard`` (E, M)); NaN for the ``skip`` epochs."""
    d = position[:, None, :] - anchors[None]
    u = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    u = np.where(heard[..., None], u, 0.0)
    info = np.einsum("emi,emj->eij", u, u)
    info = np.where(skip[:, None, None], np.eye(anchors.shape[1]), info)
    return np.where(skip[:, None, None], np.nan, np.linalg.inv(info))


@locate_method("gn", "Gauss-Newton multilateration of each node at each time from its ranges "
                     "to anchors (options: std_m, on_degenerate)",
               options={"std_m": Option("range error standard deviation, m (default: pooled "
                                        "from the residuals of every epoch of the log)", float,
                                        min=0, min_exclusive=True, max=1e7),
                        "range_std_m": Option("the same as std_m (older name)", float, min=0,
                                              min_exclusive=True, max=1e7),
                        "on_degenerate": Option("'error' (default): stop at the first epoch that "
                                                "does not fix the position (too few ranges, "
                                                "collinear anchors, a mirror fix); 'skip': leave "
                                                "such epochs out and say how many", str,
                                                choices=("error", "skip"))},
               kinds=("range",), inputs=("anchors",))
def locate_gn(request: LocateRequest) -> pd.DataFrame:
    """Locate every ``(time, node)`` epoch from its ranges to the anchors.

    Each epoch with at least ``d + 1`` anchor ranges is solved independently; all epochs
    go through one batched :class:`Multilateration` call (missing anchor ranges are NaN).
    Ranges to other nodes are not used by this method. An epoch that does not fix the
    position (fewer than ``d + 1`` ranges, collinear anchors, a mirror fix that fits the
    ranges as well, a singular information matrix) stops the method with a
    :class:`GeometryError`, or, with ``-o on_degenerate=skip``, is left out of the output
    with one warning that counts such epochs by cause and names the first.

    Parameters
    ----------
    request : LocateRequest
        The parsed measurements, the anchors and the ``-o`` options.

    Returns
    -------
    DataFrame
        Columns ``time, node, x, y[, z], uncertainty_m``, the covariance columns and
        ``ranges`` (anchor ranges used), one row per epoch fixed; ``attrs["summary"]``:
        epochs, epochs skipped by cause, ``std_m`` and where it came from.

    Raises
    ------
    GeometryError
        An epoch has too few anchor ranges or a degenerate geometry (without
        ``on_degenerate=skip``); the message names the node and the time.
    """
    anchors = request.require_anchors("gn")
    ranges = request.kind("range", "gn")
    ranges = ranges[ranges["peer"].isin(set(anchors["id"]))]
    dims = ["x", "y"] + (["z"] if "z" in anchors.columns else [])
    if ranges.empty:
        raise GeometryError("method gn: no range to an anchor in the measurements")
    if "std_m" in request.options and "range_std_m" in request.options:
        raise ConfigError("method gn: give std_m or range_std_m (the same option), not both")
    std = request.option("std_m", request.option("range_std_m"))
    skip = request.option("on_degenerate", "error", str) == "skip"
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
    few = counts < need
    if few.any():
        i = int(np.flatnonzero(few)[0])
        text = (f"node {epochs['node'][i]!r} at time {float(epochs['time'][i])!r} has ranges to "
                f"{int(counts[i])} anchor(s); {need} are needed in {len(dims)}-D")
        hint = (" (ranges that arrive one anchor at a time: track them with --method "
                "ekf-track or pf, or sample them on common epochs)"
                if np.median(counts) < need else "")
        if not skip:
            raise GeometryError(f"method gn: {text}{hint}; -o on_degenerate=skip leaves such "
                                "epochs out")
        if few.all():
            raise GeometryError(f"method gn: no epoch has {need} anchor ranges (first: {text})"
                                f"{hint}")
    solvable = np.flatnonzero(~few)
    R_ok = R[solvable]
    a_xyz = anchors[dims].to_numpy()
    try:
        fit = Multilateration(range_std_m=std, on_degenerate="flag" if skip else "raise"
                              ).locate(R_ok, a_xyz)
    except GeometryError as exc:
        if exc.index is None:
            raise GeometryError(f"method gn: {exc}") from None
        i = solvable[exc.index[0]]
        detail = exc.detail
        if exc.anchors is not None:          # name the anchors by their ids, not indices
            ids = ", ".join(str(anchors["id"].iloc[k]) for k in exc.anchors)
            detail = detail.replace(anchor_phrase(exc.anchors), f"anchors {ids}")
        raise GeometryError(f"method gn: node {epochs['node'][i]!r} at time "
                            f"{float(epochs['time'][i])!r}: {detail}; -o on_degenerate=skip "
                            "leaves such epochs out") from None
    bad = np.asarray(fit.diagnostics["degenerate"])
    mirror = np.asarray(fit.diagnostics["ambiguous"])
    if bad.all():
        i = solvable[0]
        raise GeometryError(f"method gn: no epoch has a geometry that fixes the position "
                            f"({int(mirror.sum())} ambiguous mirror fixes; first: node "
                            f"{epochs['node'][i]!r} at time {float(epochs['time'][i])!r})")
    source = "option std_m"
    if std is None:
        used = np.isfinite(R_ok).sum(axis=1)
        rms = np.asarray(fit.diagnostics["residual_rms_m"])
        dof = float(np.sum((used - len(dims))[~bad]))
        std = max(float(np.sqrt(np.sum((rms ** 2 * used)[~bad]) / dof)), STD_FLOOR_M)
        source = f"pooled residuals of {int((~bad).sum())} epochs ({dof:g} degrees of freedom)"
    cov = std ** 2 * _inverse_information(fit.position, a_xyz, np.isfinite(R_ok), bad)
    out = epochs.iloc[solvable].reset_index(drop=True)
    for k, c in enumerate(dims):
        out[c] = fit.position[:, k]
    out = add_covariance(out, cov)
    out["ranges"] = np.isfinite(R_ok).sum(axis=1)
    skipped_few, skipped_geometry = int(few.sum()), int(bad.sum())
    if skipped_few or skipped_geometry:
        first = int(np.flatnonzero(few)[0]) if skipped_few else int(solvable[np.flatnonzero(bad)[0]])
        warnings.warn(f"method gn: {skipped_few + skipped_geometry} of {n_e} epochs left out: "
                      f"{skipped_few} with fewer than {need} anchor ranges, {skipped_geometry} "
                      f"whose geometry does not fix the position ({int(mirror.sum())} of them "
                      f"ambiguous: a mirror fix fits the ranges as well); first: node "
                      f"{epochs['node'][first]!r} at time {float(epochs['time'][first])!r}",
                      stacklevel=2)
        out = out[~bad].reset_index(drop=True)
    out.attrs["summary"] = {"epochs": n_e, "epochs_fixed": int(n_e - skipped_few - skipped_geometry),
                            "epochs_skipped_few_ranges": skipped_few,
                            "epochs_skipped_geometry": skipped_geometry,
                            "std_m": std, "std_m_from": source}
    return out
