"""Per-anchor RSS path-loss models for the trackers, and their self-calibration.

``ekf-track`` reads ``rss`` rows with one log-distance model per anchor
(:class:`~radioloc.models.rss_model.AnchorRssModel`): its parameters are columns of the
anchors file (:data:`~radioloc.io.logs.ANCHOR_RSS_COLUMNS`). Without a calibration walk
they can come from the log itself (:func:`fit_path_loss`): each anchor's RSS against the
distances from a track computed without RSS (e.g. from ranges alone), fitted by least
squares (:meth:`~radioloc.models.rssi_logdistance.LogDistanceGaussian.fit`). No truth is
read; the fit inherits the track's errors.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.io.logs import ANCHOR_RSS_COLUMNS
from radioloc.models.rss_model import AnchorRssModel
from radioloc.models.rssi_logdistance import LogDistanceGaussian

__all__ = ["fit_path_loss", "anchor_rss_model"]

#: Distance floor of the fitted models, metres.
D_REF_M = 1.0


def fit_path_loss(measurements: pd.DataFrame, track: pd.DataFrame, anchors: pd.DataFrame,
                  min_rows: int = 20) -> pd.DataFrame:
    """Fit each anchor's log-distance RSS model against the distances from a track.

    Parameters
    ----------
    measurements : DataFrame
        The log (``time, node, peer, kind, value``); its ``rss`` rows to anchors are used.
    track : DataFrame
        ``time, node, x, y`` of the nodes (a ``locate`` output); positions are interpolated
        linearly to each row's time within its node (rows outside a node's track are left
        out).
    anchors : DataFrame
        ``id, x, y[, z]``.
    min_rows : int
        Fewest rows an anchor needs for a fit.

    Returns
    -------
    DataFrame
        ``anchors`` with the columns ``rss_a_dbm, rss_n, rss_std_db`` (NaN for an anchor
        with fewer than ``min_rows`` rows).

    Raises
    ------
    InputError
        No ``rss`` row to an anchor at the track's times.
    """
    rss = measurements[(measurements["kind"] == "rss") & measurements["peer"].isin(anchors["id"])]
    parts = []
    for node, rows in rss.groupby("node", sort=False):
        est = track[track["node"] == node].sort_values("time")
        t = rows["time"].to_numpy(float)
        inside = (t >= est["time"].min()) & (t <= est["time"].max()) if len(est) else t < -np.inf
        xy = np.stack([np.interp(t[inside], est["time"], est[c]) for c in ("x", "y")], axis=-1)
        parts.append((rows[inside], xy))
    if not parts or not sum(len(r) for r, _ in parts):
        raise InputError("measurements: no rss row to an anchor at the track's times")
    rows = pd.concat([r for r, _ in parts])
    xy = np.concatenate([p for _, p in parts])
    where = anchors.set_index("id").loc[rows["peer"], ["x", "y"]].to_numpy(float)
    dist = np.linalg.norm(xy - where, axis=-1)
    out = anchors.copy()
    for c in ANCHOR_RSS_COLUMNS:
        out[c] = np.nan
    for k, a in enumerate(anchors["id"]):
        mine = (rows["peer"] == a).to_numpy()
        if mine.sum() >= min_rows:
            fit = LogDistanceGaussian.fit(rows["value"].to_numpy(float)[mine], dist[mine], D_REF_M)
            out.loc[out.index[k], list(ANCHOR_RSS_COLUMNS)] = (fit.a, fit.n, fit.s)
    return out


def anchor_rss_model(anchors: pd.DataFrame, used) -> AnchorRssModel:
    """The per-anchor RSS model of an anchors table with :data:`ANCHOR_RSS_COLUMNS`.

    Parameters
    ----------
    anchors : DataFrame
        As read by :func:`radioloc.io.logs.read_anchors`.
    used : iterable of str
        Anchors that ``rss`` rows reach: each needs its three parameters.

    Returns
    -------
    AnchorRssModel

    Raises
    ------
    InputError
        A column missing, or an anchor of ``used`` without its parameters (naming both).
    """
    missing = [c for c in ANCHOR_RSS_COLUMNS if c not in anchors.columns]
    if missing:
        raise InputError(f"anchors: rss rows need the per-anchor path-loss columns "
                         f"{', '.join(ANCHOR_RSS_COLUMNS)} (missing {', '.join(missing)}; "
                         "see radioloc.locate.path_loss.fit_path_loss)")
    values = anchors[list(ANCHOR_RSS_COLUMNS)].to_numpy(float)
    need = anchors["id"].isin(set(used)).to_numpy()
    bad = need & ~np.all(np.isfinite(values), axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise InputError(f"anchors: anchor {anchors['id'].iloc[k]!r} has rss rows but no "
                         f"{'/'.join(ANCHOR_RSS_COLUMNS)} values")
    values = np.where(np.isfinite(values), values, [0.0, 1.0, 1.0])   # anchors without rows
    return AnchorRssModel(values[:, 0], values[:, 1], values[:, 2], D_REF_M)
