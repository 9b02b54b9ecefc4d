"""Odometry rows as the control input of the trackers (``ekf-track``, ``pf``).

A log's ``odometry_dx`` / ``odometry_dy`` rows (see :mod:`radioloc.io.logs`) are the node's
displacement in the anchors' frame since its previous odometry row: a wheel robot's
odometry rotated into that frame, or a phone's pedestrian dead reckoning (step length
along the compass heading). The heading is the sensor's: these kinds are world-frame
displacements, and a body-frame speed with a yaw rate is integrated into them before it
is written as rows.

Summed, the rows are a dead-reckoned path ``P(t)`` (piecewise linear between odometry
time stamps). The control of a filter step from ``t[k-1]`` to ``t[k]`` is
``P(t[k]) - P(t[k-1])``, so odometry at any rate drives steps at any other rate. Before
the first odometry row and after the last the path stands still (the first row's own
displacement, over an interval the log does not give, is not used).

With odometry, the motion model is a random walk about the odometry path,
``x[k] = x[k-1] + u[k] + w``, ``w ~ N(0, odometry_std_m^2 dt I)`` (a
:class:`~radioloc.models.motion.RandomWalk` whose diffusion is ``odometry_std_m^2``
m^2/s, driven by ``u`` as the control): ``odometry_std_m`` is the standard deviation
of the odometry's error accumulated over one second, per axis. The ranges then correct
the odometry's drift. The state has no velocity: the odometry supplies the motion.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.io.logs import MOTION_KINDS
from radioloc.locate.base import Option
from radioloc.models.motion import RandomWalk

__all__ = ["MOTION_KINDS", "ODOMETRY_OPTIONS", "has_odometry", "odometry_controls",
           "odometry_motion"]

#: Default ``odometry_std_m``: odometry error accumulated over one second, m (per axis).
ODOMETRY_STD_M = 0.1

ODOMETRY_OPTIONS = {
    "odometry_std_m": Option("with odometry rows: standard deviation of the odometry's error "
                             "accumulated over one second, m per axis (default 0.1)", float,
                             min=0, min_exclusive=True, max=1e3),
}


def has_odometry(measurements: pd.DataFrame) -> bool:
    """Whether the log holds odometry rows."""
    return bool(measurements["kind"].isin(MOTION_KINDS).any())


def odometry_motion(std_m: float, dim: int) -> RandomWalk:
    """The motion model about the odometry path (see the module docstring).

    Parameters
    ----------
    std_m : float
        Odometry error accumulated over one second, m per axis.
    dim : int
        Position coordinates.

    Returns
    -------
    RandomWalk
    """
    return RandomWalk(std_m ** 2, dim)


def odometry_controls(measurements: pd.DataFrame, node: str, times: np.ndarray,
                      dim: int) -> np.ndarray:
    """The odometry displacement over each filter step of one node.

    Parameters
    ----------
    measurements : DataFrame
        As read by :func:`radioloc.io.read_measurements` (``odometry_dx`` and
        ``odometry_dy`` rows in pairs).
    node : str
    times : ndarray, shape (T,)
        The filter's step times, non-decreasing.
    dim : int
        Position coordinates of the track (2 or 3; the odometry moves x and y only).

    Returns
    -------
    ndarray, shape (T, dim)
        ``P(t[k]) - P(t[k-1])`` of the dead-reckoned path ``P``; row 0 is zero. All zero
        when the node has no odometry rows.
    """
    times = np.asarray(times, dtype=float)
    out = np.zeros((times.size, dim))
    rows = measurements[(measurements["node"] == node)
                        & measurements["kind"].isin(MOTION_KINDS)]
    if rows.empty or times.size == 0:
        return out
    wide = rows.pivot_table(index="time", columns="kind", values="value", aggfunc="sum")
    t = wide.index.to_numpy(dtype=float)
    path = np.cumsum(wide[list(MOTION_KINDS)].to_numpy(dtype=float), axis=0)   # (n, 2)
    at = np.stack([np.interp(times, t, path[:, j]) for j in range(2)], axis=-1)
    out[1:, :2] = np.diff(at, axis=0)
    return out
