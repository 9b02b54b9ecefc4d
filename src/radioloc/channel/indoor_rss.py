"""Indoor received signal strength: log-distance path loss, wall attenuation per crossing,
log-normal shadowing and Rayleigh multipath fading, in dBm.

Used by the tethering simulation of paper 003 (Sect. V: "simulation of RSS interference
effects based on walls"). The paper does not give its simulator's channel; this one is ours::

    P [dBm] = P0 - 10 n log10(max(d, d0) / d0) - W * crossings + X_sh + F,
    X_sh ~ N(0, shadow_std_db),  F = 10 log10 |h|^2, h ~ CN(0, 1)

The channel returns the received power ``P`` in dBm. What a radio reports (the paper's
unitless 0..100 RSSI) is the sensor's business: the tethering world
(:mod:`radioloc.sim.tether`) quantises ``P`` with
``dbm_to_rssi100`` of the models layer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.geometry import segments_cross
from radioloc.core.validation import as_float_array


@dataclass(frozen=True)
class IndoorChannel:
    """Channel parameters (2.4 GHz indoor defaults).

    Parameters
    ----------
    p0_dbm : float
        Received power at ``d0_m``, dBm.
    d0_m : float
        Reference distance, metres (closer links read as if at ``d0_m``).
    exponent : float
        Path-loss exponent n.
    wall_db : float
        Loss per wall crossed, dB.
    shadow_std_db : float
        Standard deviation of the i.i.d. log-normal shadowing of each reading, dB.
    rayleigh : bool
        Add Rayleigh fading (in dB) to each reading.
    packets : int
        Each reading averages the faded power of this many independent packets.
    """

    p0_dbm: float = -40.0
    d0_m: float = 1.0
    exponent: float = 2.5
    wall_db: float = 5.0
    shadow_std_db: float = 3.0
    rayleigh: bool = True
    packets: int = 1

    def mean_dbm(self, d, crossings) -> np.ndarray:
        """Mean received power without shadowing or fading.

        Parameters
        ----------
        d : array_like
            Link distances, metres.
        crossings : array_like
            Walls crossed by each link (broadcast with ``d``).

        Returns
        -------
        ndarray
            ``P0 - 10 n log10(max(d, d0) / d0) - W crossings`` in dBm.
        """
        d = np.maximum(np.asarray(d, float), self.d0_m)
        return self.p0_dbm - 10.0 * self.exponent * np.log10(d / self.d0_m) - self.wall_db * crossings

    def sample_dbm(self, a, b, walls, rng: np.random.Generator) -> np.ndarray:
        """Received power (dBm) of one reading between points ``a`` and ``b``.

        Parameters
        ----------
        a, b : array_like, shape (..., 2)
            Transmitter and receiver positions, metres (broadcast).
        walls : array_like, shape (M, 4)
            Wall segments ``x1, y1, x2, y2``.
        rng : numpy.random.Generator
            Source of the shadowing and fading draws.

        Returns
        -------
        ndarray, shape (...)
            Received power in dBm (shadowed and, with ``rayleigh``, faded).
        """
        a = as_float_array(a, "a", last_dim=2)
        b = as_float_array(b, "b", last_dim=2)
        d = np.linalg.norm(a - b, axis=-1)
        p = self.mean_dbm(d, wall_crossings(a, b, walls))
        p = p + rng.normal(0.0, self.shadow_std_db, p.shape)
        if self.rayleigh:
            h2 = rng.exponential(1.0, (int(self.packets), *p.shape)).mean(axis=0)
            p = p + 10.0 * np.log10(np.maximum(h2, 1e-6))
        return p


def wall_crossings(a, b, walls) -> np.ndarray:
    """Number of wall segments crossed by the segments ``a -> b``.

    Proper intersections only (touching an endpoint does not count), decided by
    :func:`radioloc.core.geometry.segments_cross`.

    Parameters
    ----------
    a, b : array_like, shape (..., 2)
        End points of the links (broadcast).
    walls : array_like, shape (M, 4)
        Wall segments, rows ``x1, y1, x2, y2``.

    Returns
    -------
    ndarray of float, shape (...)
        Walls crossed by each link.
    """
    walls = np.asarray(walls, float).reshape(-1, 4)
    if walls.shape[0] == 0:
        return np.zeros(np.broadcast_shapes(np.shape(a)[:-1], np.shape(b)[:-1]))
    a = np.asarray(a, float)[..., None, :]
    b = np.asarray(b, float)[..., None, :]
    hit = segments_cross(a, b, walls[:, :2], walls[:, 2:])
    return hit.sum(axis=-1).astype(float)


def office_walls(size_m: float = 40.0, rooms: int = 4) -> np.ndarray:
    """A square floor divided into ``rooms x rooms`` rooms with door gaps.

    Each inner wall has a 1.5 m door gap in its middle; the outer walls are included.

    Parameters
    ----------
    size_m : float
        Side of the square floor, metres.
    rooms : int
        Rooms along each side.

    Returns
    -------
    ndarray, shape (M, 4)
        Wall segments ``x1, y1, x2, y2``.
    """
    s = size_m
    walls = [[0, 0, s, 0], [s, 0, s, s], [s, s, 0, s], [0, s, 0, 0]]
    step = s / rooms
    gap = 0.75
    for i in range(1, rooms):
        c = i * step
        for j in range(rooms):
            lo, hi = j * step, (j + 1) * step
            mid = 0.5 * (lo + hi)
            walls += [[c, lo, c, mid - gap], [c, mid + gap, c, hi],
                      [lo, c, mid - gap, c], [mid + gap, c, hi, c]]
    return np.asarray(walls, float)
