"""The rotation between a heading sensor's frame and the map, from a track without it.

A phone's compass azimuth is measured against magnetic north (turned by the building's
steel, the phone's calibration and how the user holds it); the map's x axis points
elsewhere. A ``heading`` row of the ``locate`` schema is in the map's frame, so the
sensor's values are rotated first. :func:`estimate_heading_offset` finds that rotation
from the log itself: the circular mean of the sensor's heading minus the direction of a
track computed without it (e.g. from ranges alone), over the rows where that track moves
faster than ``min_speed_mps`` (the direction of a slow track is noise). No truth is read;
the estimate inherits the track's errors, and one offset per node assumes the sensor is
held the same way throughout.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.models.measurement import wrap_angle

__all__ = ["estimate_heading_offset", "remove_heading_offset", "track_direction"]


def track_direction(track: pd.DataFrame, node: str, times: np.ndarray, window_s: float = 10.0
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Direction and speed of a node's track at ``times``, by the central difference of
    its positions (interpolated linearly) ``window_s`` apart.

    Parameters
    ----------
    track : DataFrame
        ``time, node, x, y`` (a ``locate`` output).
    node : str
    times : ndarray, shape (N,)
    window_s : float
        Span of the difference, seconds.

    Returns
    -------
    direction_rad, speed_mps : ndarray, shape (N,)
        NaN where ``times +- window_s / 2`` leaves the node's track.
    """
    est = track[track["node"] == node].sort_values("time")
    t = est["time"].to_numpy(float)
    times = np.asarray(times, dtype=float)
    if t.size < 2:
        return np.full(times.size, np.nan), np.full(times.size, np.nan)
    lo, hi = times - window_s / 2, times + window_s / 2
    d = np.stack([np.interp(hi, t, est[c].to_numpy(float)) - np.interp(lo, t, est[c].to_numpy(float))
                  for c in ("x", "y")], axis=-1)
    inside = (lo >= t[0]) & (hi <= t[-1])
    speed = np.where(inside, np.linalg.norm(d, axis=-1) / window_s, np.nan)
    return np.where(inside, np.arctan2(d[:, 1], d[:, 0]), np.nan), speed


def estimate_heading_offset(measurements: pd.DataFrame, track: pd.DataFrame,
                            min_speed_mps: float = 0.1, window_s: float = 10.0,
                            min_rows: int = 20) -> pd.DataFrame:
    """Each node's heading offset: the circular mean of its ``heading`` rows minus its
    track's direction where the track is faster than ``min_speed_mps``.

    Parameters
    ----------
    measurements : DataFrame
        The log (``time, node, peer, kind, value``); its ``heading`` rows are used, in the
        sensor's frame (offset not removed).
    track : DataFrame
        ``time, node, x, y`` of the nodes, computed without the heading rows.
    min_speed_mps : float
        Rows where the track is slower are left out.
    window_s : float
        Span of the track's direction (:func:`track_direction`), seconds.
    min_rows : int
        Fewest rows a node needs for an estimate.

    Returns
    -------
    DataFrame
        ``node, offset_rad`` (subtract it from the node's heading rows), ``rows`` used and
        ``concentration`` (the mean resultant length, in [0, 1]: near 1 when the heading
        follows the track closely, near 0 when it does not).

    Raises
    ------
    InputError
        A node (or none at all) with fewer than ``min_rows`` usable heading rows.
    """
    rows = measurements[measurements["kind"] == "heading"]
    if rows.empty:
        raise InputError("measurements: no heading row")
    out = []
    for node, part in rows.groupby("node", sort=True):
        direction, speed = track_direction(track, node, part["time"].to_numpy(float), window_s)
        ok = np.isfinite(speed) & (np.nan_to_num(speed) > min_speed_mps)
        if ok.sum() < min_rows:
            raise InputError(f"node {node!r}: {int(ok.sum())} heading row(s) where its track "
                             f"moves faster than {min_speed_mps:g} m/s; {min_rows} needed")
        mean = np.mean(np.exp(1j * (part["value"].to_numpy(float)[ok] - direction[ok])))
        out.append({"node": node, "offset_rad": float(np.angle(mean)), "rows": int(ok.sum()),
                    "concentration": float(np.abs(mean))})
    return pd.DataFrame(out)


def remove_heading_offset(measurements: pd.DataFrame, offsets: pd.DataFrame) -> pd.DataFrame:
    """The log with each node's offset subtracted from its ``heading`` rows (wrapped).

    Parameters
    ----------
    measurements : DataFrame
    offsets : DataFrame
        ``node, offset_rad`` (:func:`estimate_heading_offset`).

    Returns
    -------
    DataFrame
        A copy; heading rows of a node without an offset are left out.
    """
    off = measurements["node"].map(dict(zip(offsets["node"], offsets["offset_rad"])))
    is_heading = (measurements["kind"] == "heading").to_numpy()
    out = measurements[~is_heading | off.notna().to_numpy()].copy()
    sel = (out["kind"] == "heading").to_numpy()
    out.loc[sel, "value"] = wrap_angle(out.loc[sel, "value"].to_numpy(float)
                                       - off[out.index[sel]].to_numpy(float))
    return out
