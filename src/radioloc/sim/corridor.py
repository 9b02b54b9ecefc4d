"""The corridor of paper 004 (Sect. 3.1.1, Fig. 4): one-dimensional user position.

A corridor of ``length_m`` with a base station at each end (x = 0 and x = length) and a
metallic door in the middle with two states. The paper gives no propagation law; we use
log-distance path loss ``m = p0 - 10 n log10(max(d, d0)/d0)`` minus ``door_loss_db`` when
the door is closed and lies between the station and the user, plus Gaussian noise of
``noise_db`` (the paper's 2 dB empty room / 10 dB people nearby).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.validation import as_float_array, check_positive


@dataclass(frozen=True)
class Corridor:
    """Corridor geometry and propagation (all choices of ours where the paper is silent).

    length_m: corridor length (paper: 60 m); stations at 0 and ``length_m``.
    door_m: door position (paper: the middle).
    p0_dbm: received power at ``d0_m`` from a station.
    exponent: path-loss exponent.
    door_loss_db: extra attenuation of a closed metallic door.
    """

    length_m: float = 60.0
    door_m: float = 30.0
    p0_dbm: float = -30.0
    d0_m: float = 1.0
    exponent: float = 2.0
    door_loss_db: float = 15.0

    @property
    def stations(self) -> np.ndarray:
        return np.array([0.0, self.length_m])

    def mean_rss(self, x, door_closed) -> np.ndarray:
        """Noise-free signal strength ``(..., 2)`` at positions ``x`` ``(...)`` for door
        states ``door_closed`` (bool, broadcast against ``x``)."""
        x = as_float_array(x, "x")
        d = np.abs(x[..., None] - self.stations)
        loss = 10 * self.exponent * np.log10(np.maximum(d, self.d0_m) / self.d0_m)
        between = (np.minimum(x[..., None], self.stations) < self.door_m) & \
                  (np.maximum(x[..., None], self.stations) > self.door_m)
        closed = np.asarray(door_closed, dtype=bool)[..., None]
        return self.p0_dbm - loss - self.door_loss_db * (between & closed)

    def sample_rss(self, x, door_closed, noise_db: float, rng: np.random.Generator) -> np.ndarray:
        """Noisy signal strength ``(..., 2)``."""
        check_positive(noise_db, "noise_db", allow_zero=True)
        mean = self.mean_rss(x, door_closed)
        return mean + noise_db * rng.standard_normal(mean.shape)
