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

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array, check_positive


@dataclass(frozen=True)
class Corridor:
    """Corridor geometry and propagation (all choices of ours where the paper is silent).

    Parameters
    ----------
    length_m : float
        Corridor length (paper: 60 m); stations at 0 and ``length_m``.
    door_m : float
        Door position (paper: the middle).
    p0_dbm : float
        Received power at ``d0_m`` from a station.
    d0_m : float
        Reference distance of the path loss.
    exponent : float
        Path-loss exponent.
    door_loss_db : float
        Extra attenuation of a closed metallic door.
    """

    length_m: float = 60.0
    door_m: float = 30.0
    p0_dbm: float = -30.0
    d0_m: float = 1.0
    exponent: float = 2.0
    door_loss_db: float = 15.0

    @property
    def stations(self) -> np.ndarray:
        """Station positions ``[0, length_m]``."""
        return np.array([0.0, self.length_m])

    def mean_rss(self, x, door_closed) -> np.ndarray:
        """Noise-free signal strength of both stations.

        Parameters
        ----------
        x : array_like, shape (...)
            User positions, metres.
        door_closed : array_like of bool
            Door state, broadcast against ``x``.

        Returns
        -------
        ndarray, shape (..., 2)
            Signal strengths in dBm.
        """
        x = as_float_array(x, "x")
        d = np.abs(x[..., None] - self.stations)
        loss = 10 * self.exponent * np.log10(np.maximum(d, self.d0_m) / self.d0_m)
        between = (np.minimum(x[..., None], self.stations) < self.door_m) & \
                  (np.maximum(x[..., None], self.stations) > self.door_m)
        closed = np.asarray(door_closed, dtype=bool)[..., None]
        return self.p0_dbm - loss - self.door_loss_db * (between & closed)

    def sample_rss(self, x, door_closed, noise_db: float, rng: np.random.Generator) -> np.ndarray:
        """Noisy signal strength of both stations.

        Parameters
        ----------
        x : array_like, shape (...)
            User positions, metres.
        door_closed : array_like of bool
            Door state, broadcast against ``x``.
        noise_db : float
            Standard deviation of the Gaussian noise, dB (>= 0).
        rng : numpy.random.Generator
            Source of the noise.

        Returns
        -------
        ndarray, shape (..., 2)
            Signal strengths in dBm.
        """
        check_positive(noise_db, "noise_db", allow_zero=True)
        mean = self.mean_rss(x, door_closed)
        return mean + noise_db * rng.standard_normal(mean.shape)

    def calibration_set(self, n_runs: int, n_samples: int, noise_db: float,
                        rng: np.random.Generator, return_door: bool = False
                        ) -> tuple[np.ndarray, ...]:
        """Calibration samples in both door states (Sect. 3.1.1).

        Positions are uniform along the corridor, the door is closed with probability 1/2
        per sample, and each sample's signal strengths carry ``noise_db`` of noise.

        Parameters
        ----------
        n_runs : int
            Independent calibration sets (one per Monte Carlo run).
        n_samples : int
            Samples per set.
        noise_db : float
            Measurement noise, dB.
        rng : numpy.random.Generator
            Source of positions, door states and noise (drawn in that order).
        return_door : bool
            Also return each sample's door state (the draws are the same either way).

        Returns
        -------
        positions : ndarray, shape (n_runs, n_samples, 1)
            Sample positions, metres.
        rss : ndarray, shape (n_runs, n_samples, 2)
            Signal strengths of both stations, dBm.
        door_closed : ndarray of bool, shape (n_runs, n_samples)
            Only with ``return_door``.
        """
        x = rng.uniform(0.0, self.length_m, (int(n_runs), int(n_samples)))
        door = rng.random(x.shape) < 0.5
        rss = self.sample_rss(x, door, noise_db, rng)
        return (x[..., None], rss, door) if return_door else (x[..., None], rss)


def walk_positions(start_m: float, end_m: float, speed_m_per_s: float, dt_s: float) -> np.ndarray:
    """Positions of a user walking at constant speed, sampled every ``dt_s``.

    Parameters
    ----------
    start_m, end_m : float
        First position and the position not to pass, metres (``end_m > start_m``).
    speed_m_per_s : float
        Walking speed, > 0.
    dt_s : float
        Sampling interval, > 0.

    Returns
    -------
    ndarray, shape (T,)
        ``start_m + speed dt k`` for every ``k`` that stays at or before ``end_m``.
    """
    check_positive(speed_m_per_s, "speed_m_per_s")
    check_positive(dt_s, "dt_s")
    steps = int(np.floor((end_m - start_m) / (speed_m_per_s * dt_s)))
    if steps < 0:
        raise InputError(f"end_m: {end_m} is before start_m {start_m}")
    return start_m + speed_m_per_s * dt_s * np.arange(steps + 1)
