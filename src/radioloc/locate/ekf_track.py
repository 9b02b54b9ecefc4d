"""``radioloc locate --method ekf-track``: track each node from its ranges to anchors with an
extended Kalman filter (:class:`radioloc.estimators.ekf_tracker.RangeEKF`).

Ranges are processed as they arrive: the rows of a node that share one time stamp are one
update, whatever anchors they reach (one anchor at a time is fine); a time with no range to
a known anchor is not a step. Ranges to peers that are not anchors are not used.

A gap longer than ``max_gap_s`` between a node's ranges starts a new track (the motion
model alone cannot bridge it; one update from a prior metres wide linearises badly).

The start: the node is assumed to stay within ``prior_std_m`` of one place during its first
``init_s`` seconds; the median range to each anchor over that window is fitted by a coarse
then fine grid search over the horizontal plane (at the tag height, or at the anchors' mean
height in 3-D), which finds the global least-squares minimum rather than a mirror basin. The
filter starts there with position standard deviation ``prior_std_m`` and velocity standard
deviation ``PRIOR_SPEED_STD`` m/s.

Motion models for asynchronous rows are continuous-time: ``cv`` is a constant velocity
driven by white acceleration of spectral density ``q`` (m^2/s^3), so the process noise of an
interval does not depend on how the interval is split (:class:`WhiteAccelerationCV`);
``rw`` is a random walk of diffusion ``q`` (m^2/s).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import GeometryError, InputError
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.locate.base import MAX_GAP_S, LocateRequest, Option, locate_method
from radioloc.models.motion import RandomWalk, WhiteAccelerationCV
from radioloc.models.ranging import GaussianRange

#: Standard deviation of the start velocity, m/s.
PRIOR_SPEED_STD = 3.0


def motion_model(kind: str, q: float, dim: int):
    """The motion model of option ``motion``.

    Parameters
    ----------
    kind : {"cv", "rw"}
        Constant velocity (white acceleration) or random walk.
    q : float
        Acceleration spectral density (m^2/s^3, ``cv``) or diffusion (m^2/s, ``rw``).
    dim : int
        Position coordinates.

    Returns
    -------
    WhiteAccelerationCV or RandomWalk
    """
    return WhiteAccelerationCV(q, dim) if kind == "cv" else RandomWalk(q, dim)


def range_rows(request: LocateRequest, method: str):
    """Ranges to anchors as one ``(T, M)`` array per node (NaN: no range at that time).

    Duplicate ``(time, node, peer)`` measurements are averaged.

    Parameters
    ----------
    request : LocateRequest
    method : str
        For messages.

    Returns
    -------
    anchors : ndarray, shape (M, 2) or (M, 3)
    per_node : list of (node, times (T,), ranges (T, M))
    """
    table = request.require_anchors(method)
    rows = request.kind("range", method)
    rows = rows[rows["peer"].isin(set(table["id"]))]
    if rows.empty:
        raise GeometryError(f"method {method}: no range to an anchor in the measurements")
    dims = ["x", "y"] + (["z"] if "z" in table.columns else [])
    anchors = table[dims].to_numpy(dtype=float)
    index = {a: i for i, a in enumerate(table["id"])}
    rows = rows.groupby(["node", "time", "peer"], sort=True, as_index=False)["value"].mean()
    out = []
    for node, grp in rows.groupby("node", sort=True):
        times, t_idx = np.unique(grp["time"].to_numpy(dtype=float), return_inverse=True)
        R = np.full((times.size, len(anchors)), np.nan)
        R[t_idx, grp["peer"].map(index).to_numpy()] = grp["value"].to_numpy(dtype=float)
        out.append((node, times, R))
    return anchors, out


def _predicted(xy: np.ndarray, anchors: np.ndarray, height: float | None) -> np.ndarray:
    """Ranges from horizontal positions (..., 2) to anchors (M, 2|3) at a node height."""
    d2 = np.sum((xy[..., None, :] - anchors[:, :2]) ** 2, axis=-1)
    if anchors.shape[1] == 3:
        d2 = d2 + (height - anchors[:, 2]) ** 2
    return np.sqrt(d2)


def start_position(times: np.ndarray, R: np.ndarray, anchors: np.ndarray, height: float | None,
                   bias: float, init_s: float) -> np.ndarray:
    """Horizontal start position from the median ranges of the first ``init_s`` seconds.

    Two grid searches (coarse over a square covering every anchor and the largest range,
    then fine around the best cell) minimise the sum of squared range residuals; with at
    least three anchors not on one line this is the global minimum, not a mirror basin.

    Parameters
    ----------
    times : ndarray, shape (T,)
    R : ndarray, shape (T, M)
        Ranges (NaN: absent).
    anchors : ndarray, shape (M, 2) or (M, 3)
    height : float or None
        Node height when anchors are 3-D (None: the anchors' mean height).
    bias : float
        Range bias subtracted from the ranges.
    init_s : float
        Window length, seconds.

    Returns
    -------
    ndarray, shape (2,)

    Raises
    ------
    GeometryError
        Fewer than three anchors heard in the window (and in the whole log).
    """
    window = times <= times[0] + init_s
    med = np.full(R.shape[1], np.nan)
    heard = np.isfinite(R[window]).any(axis=0)
    med[heard] = np.nanmedian(R[window][:, heard], axis=0)
    if heard.sum() < 3:   # widen to the whole log rather than give up
        heard = np.isfinite(R).any(axis=0)
        med[heard] = np.nanmedian(R[:, heard], axis=0)
    if heard.sum() < 3:
        raise GeometryError(f"ranges to {int(heard.sum())} anchor(s) only; the start position "
                            "needs three")
    r = med[heard] - bias
    a = anchors[heard]
    h = None if a.shape[1] == 2 else (float(np.mean(anchors[:, 2])) if height is None else height)
    centre = anchors[:, :2].mean(axis=0)
    half = float(np.max(np.abs(anchors[:, :2] - centre)) + np.max(r) + 1.0)
    best = centre
    for _ in range(3):   # coarse, finer, finest: 201 x 201 cells each
        g = np.linspace(-half, half, 201)
        gx, gy = np.meshgrid(best[0] + g, best[1] + g, indexing="ij")
        xy = np.stack([gx.ravel(), gy.ravel()], axis=-1)
        cost = np.sum((_predicted(xy, a, h) - r) ** 2, axis=-1)
        best = xy[int(np.argmin(cost))]
        half = half / 20
    return best


OPTIONS = {
    "motion": Option("'cv' constant velocity (white acceleration, default) or 'rw' random "
                     "walk", str, choices=("cv", "rw")),
    "q": Option("process noise: acceleration spectral density m^2/s^3 (cv, default 1) or "
                "diffusion m^2/s (rw, default 1)", float, min=0, max=1e6),
    "range_std_m": Option("range error standard deviation, m (default 0.15)", float, min=0,
                          min_exclusive=True, max=1e6),
    "range_bias_m": Option("constant offset of every range (antenna delay), m; subtracted "
                           "(default 0)", float, min=-1e3, max=1e3),
    "tag_height_m": Option("known node height: track in 2-D (x, y) with 3-D anchors (default: "
                           "3-D tracking when the anchors have z)", float, min=-1e4, max=1e4),
    "gate": Option("drop a range whose squared innovation exceeds gate x its predicted "
                   "variance (default 16, i.e. 4 sigma; 0: no gating)", float, min=0, max=1e9),
    "smooth": Option("1: Rauch-Tung-Striebel smoothed track (offline; uses later ranges)",
                     bool),
    "prior_std_m": Option("standard deviation of the start position, m (default 2)", float,
                          min=0, min_exclusive=True, max=1e6),
    "init_s": Option("seconds of ranges whose medians fix the start position (default 2)",
                     float, min=0, max=1e6),
    "max_gap_s": Option("a gap longer than this between a node's ranges restarts its track "
                        "from a new start fix (default 5 s)", float, min=0, min_exclusive=True,
                        max=1e9),
}


def segments(times: np.ndarray, max_gap_s: float) -> list[slice]:
    """Slices of ``times`` split where consecutive times are more than ``max_gap_s`` apart.

    Parameters
    ----------
    times : ndarray, shape (T,)
        Sorted times.
    max_gap_s : float

    Returns
    -------
    list of slice
    """
    cuts = np.flatnonzero(np.diff(times) > max_gap_s) + 1
    edges = np.concatenate([[0], cuts, [times.size]])
    return [slice(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def tracker_settings(request: LocateRequest, anchors: np.ndarray) -> dict:
    """Options common to the trackers, with defaults, checked against the anchors.

    Parameters
    ----------
    request : LocateRequest
    anchors : ndarray, shape (M, 2) or (M, 3)

    Returns
    -------
    dict
        ``motion, q, height, dim, bias, smooth, prior_std, init_s, max_gap_s``.
    """
    kind = request.option("motion", "cv", str)
    height = request.option("tag_height_m")
    if height is not None and anchors.shape[1] != 3:
        raise InputError("option tag_height_m: needs anchors with a z column")
    dim = 2 if (height is not None or anchors.shape[1] == 2) else 3
    return {"motion": kind, "q": request.option("q", 1.0),
            "height": height, "dim": dim, "bias": request.option("range_bias_m", 0.0),
            "smooth": bool(request.option("smooth", False, bool)),
            "prior_std": request.option("prior_std_m", 2.0),
            "init_s": request.option("init_s", 2.0),
            "max_gap_s": request.option("max_gap_s", MAX_GAP_S)}


def run_ekf(times, R, anchors, s: dict, range_std: float, gate: float | None, smooth: bool):
    """One node's :class:`RangeEKF` track (see the module docstring for the start).

    Parameters
    ----------
    times : ndarray, shape (T,)
    R : ndarray, shape (T, M)
    anchors : ndarray, shape (M, 2|3)
    s : dict
        From :func:`tracker_settings`.
    range_std : float
    gate : float or None
    smooth : bool

    Returns
    -------
    Track
    """
    dim = s["dim"]
    xy0 = start_position(times, R, anchors, s["height"], s["bias"], s["init_s"])
    motion = motion_model(s["motion"], s["q"], dim)
    start = np.zeros(motion.state_dim)
    start[:2] = xy0
    var = np.full(motion.state_dim, PRIOR_SPEED_STD ** 2)
    var[:dim] = s["prior_std"] ** 2
    if dim == 3:
        start[2] = float(np.mean(anchors[:, 2]))
    ekf = RangeEKF(motion, GaussianRange(range_std), anchors=anchors, height_m=s["height"],
                   range_bias_m=s["bias"], gate=gate)
    return ekf.run(R, times, prior_mean=start, prior_cov=np.diag(var), smooth=smooth)


def track_table(node, times, track) -> pd.DataFrame:
    """Rows ``time, node, x, y[, z], uncertainty_m`` of one node's track.

    Parameters
    ----------
    node : str
    times : ndarray, shape (T,)
    track : Track

    Returns
    -------
    DataFrame
    """
    out = pd.DataFrame({"time": times, "node": node})
    for k, c in enumerate("xyz"[: track.position.shape[-1]]):
        out[c] = track.position[:, k]
    out["uncertainty_m"] = np.sqrt(np.trace(track.covariance, axis1=-2, axis2=-1))
    return out


@locate_method("ekf-track", "Extended Kalman filter tracking each node from its ranges to "
                            "anchors as they arrive (constant velocity or random walk; RTS "
                            "smoother with -o smooth=1)",
               options=OPTIONS, kinds=("range",), inputs=("anchors",))
def locate_ekf_track(request: LocateRequest) -> pd.DataFrame:
    """Track every node with a :class:`RangeEKF` over its range rows.

    Parameters
    ----------
    request : LocateRequest
        Measurements (range rows), anchors, ``-o`` options (see :data:`OPTIONS`).

    Returns
    -------
    DataFrame
        ``time, node, x, y[, z], uncertainty_m``: one row per time stamp at which the node
        has a range to an anchor (the filtered state, or the smoothed one with
        ``smooth=1``).
    """
    anchors, per_node = range_rows(request, "ekf-track")
    s = tracker_settings(request, anchors)
    gate = request.option("gate", 16.0) or None
    std = request.option("range_std_m", 0.15)
    tables = []
    for node, times, R in per_node:
        for seg in segments(times, s["max_gap_s"]):
            try:
                track = run_ekf(times[seg], R[seg], anchors, s, std, gate, s["smooth"])
            except GeometryError as exc:
                raise GeometryError(f"method ekf-track: node {node!r} from time "
                                    f"{float(times[seg][0])!r}: {exc}") from None
            tables.append(track_table(node, times[seg], track))
    return pd.concat(tables, ignore_index=True)
