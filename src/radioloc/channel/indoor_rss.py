"""Indoor received signal strength: log-distance path loss, wall attenuation per crossing,
log-normal shadowing and Rayleigh multipath fading, quantised to the 0..100 RSSI scale.

Used by the tethering simulation of paper 003 (Sect. V: "simulation of RSS interference
effects based on walls"). The paper does not give its simulator's channel; this one is ours::

    P [dBm] = P0 - 10 n log10(max(d, d0) / d0) - W * crossings + X_sh + F,
    X_sh ~ N(0, shadow_std_db),  F = 10 log10 |h|^2, h ~ CN(0, 1)

and ``rssi = dbm_to_rssi100(P)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.validation import as_float_array
from radioloc.models.rssi_trapezoid import dbm_to_rssi100


@dataclass(frozen=True)
class IndoorChannel:
    """Channel parameters (2.4 GHz indoor defaults).

    p0_dbm: received power at ``d0_m``; exponent: path-loss exponent n; wall_db: loss per
    wall crossed; shadow_std_db: i.i.d. log-normal shadowing per reading; rayleigh: add
    Rayleigh fading in dB.
    """

    p0_dbm: float = -40.0
    d0_m: float = 1.0
    exponent: float = 2.5
    wall_db: float = 5.0
    shadow_std_db: float = 3.0
    rayleigh: bool = True
    packets: int = 1

    def mean_dbm(self, d, crossings) -> np.ndarray:
        """Mean received power without shadowing or fading."""
        d = np.maximum(np.asarray(d, float), self.d0_m)
        return self.p0_dbm - 10.0 * self.exponent * np.log10(d / self.d0_m) - self.wall_db * crossings

    def sample_rssi(self, a, b, walls, rng: np.random.Generator) -> np.ndarray:
        """Quantised RSSI (int 0..100) between points ``a`` and ``b`` ``(..., 2)``."""
        a = as_float_array(a, "a", last_dim=2)
        b = as_float_array(b, "b", last_dim=2)
        d = np.linalg.norm(a - b, axis=-1)
        p = self.mean_dbm(d, wall_crossings(a, b, walls))
        p = p + rng.normal(0.0, self.shadow_std_db, p.shape)
        if self.rayleigh:
            h2 = rng.exponential(1.0, (int(self.packets), *p.shape)).mean(axis=0)
            p = p + 10.0 * np.log10(np.maximum(h2, 1e-6))
        return dbm_to_rssi100(p)


def wall_crossings(a, b, walls) -> np.ndarray:
    """Number of wall segments crossed by the segments ``a -> b`` (``(..., 2)`` each).

    ``walls`` is ``(M, 4)`` rows ``x1, y1, x2, y2``. Proper intersections only (touching
    endpoints does not count).
    """
    walls = np.asarray(walls, float).reshape(-1, 4)
    if walls.shape[0] == 0:
        return np.zeros(np.broadcast_shapes(np.shape(a)[:-1], np.shape(b)[:-1]))
    a = np.asarray(a, float)[..., None, :]
    b = np.asarray(b, float)[..., None, :]
    p, q = walls[:, :2], walls[:, 2:]

    def cross(o, u, v):
        return (u[..., 0] - o[..., 0]) * (v[..., 1] - o[..., 1]) - (u[..., 1] - o[..., 1]) * (v[..., 0] - o[..., 0])

    d1, d2 = cross(a, b, p), cross(a, b, q)
    d3, d4 = cross(p, q, a), cross(p, q, b)
    hit = (d1 * d2 < 0) & (d3 * d4 < 0)
    return hit.sum(axis=-1).astype(float)


def office_walls(size_m: float = 40.0, rooms: int = 4) -> np.ndarray:
    """A square floor of side ``size_m`` divided into ``rooms x rooms`` rooms, each inner wall
    with a 1.5 m door gap in its middle; the outer walls are included."""
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
