"""Scenarios of paper 002: one moving sensor ranging to a moving target.

Sensor paths, target tracks (eq. (1) with uniform accelerations, or recorded trajectories
replayed) and noisy ranges. States are ``[x, y, vx, vy]``; arrays are ``(runs, n, ...)``.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.validation import as_float_array, check_positive
from radioloc.models.motion import ConstantVelocity

__all__ = ["circular_sensor_path", "random_tracks", "noisy_ranges", "states_from_positions",
           "accel_var_from_positions", "place_tracks", "sine_positions"]


def circular_sensor_path(n_samples: int, radius_m: float, step_rad: float) -> np.ndarray:
    """A sensor circling the origin, turning ``step_rad`` per sample.

    Parameters
    ----------
    n_samples : int
        n.
    radius_m : float
        Radius of the circle, metres.
    step_rad : float
        Angle turned per sample (the path is not quadratic in n for any step that is not a
        multiple of 2 pi).

    Returns
    -------
    ndarray, shape (n, 2)
        ``(a_n, b_n)``, starting at ``(radius_m, 0)``.
    """
    if int(n_samples) < 1:
        raise InputError(f"n_samples: must be >= 1, got {n_samples}")
    ang = np.arange(int(n_samples)) * float(step_rad)
    return check_positive(radius_m, "radius_m") * np.stack([np.cos(ang), np.sin(ang)], axis=-1)


def random_tracks(runs: int, n_samples: int, sample_period_s: float, accel_var: float,
                  rng: np.random.Generator, *, box_m: float, speed_std: float,
                  distribution: str = "uniform") -> np.ndarray:
    """Targets starting uniformly in a box with Gaussian velocities, moving by eq. (1).

    Draws, in this order: start positions ``U(-box_m, box_m)^2``, start velocities
    ``N(0, speed_std^2)`` per axis, then the accelerations of
    :meth:`radioloc.models.motion.ConstantVelocity.simulate`.

    Parameters
    ----------
    runs : int
        Number of independent tracks.
    n_samples : int
        Samples per track.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2`` per axis.
    rng : numpy.random.Generator
        Source of every draw.
    box_m : float
        Half-width of the start box, metres.
    speed_std : float
        Standard deviation of each start velocity component, m/s.
    distribution : {"uniform", "gaussian"}
        Law of the accelerations (the paper: uniform).

    Returns
    -------
    ndarray, shape (runs, n_samples, 4)
        ``[x, y, vx, vy]`` at every sample.
    """
    b = check_positive(box_m, "box_m")
    v = check_positive(speed_std, "speed_std", allow_zero=True)
    x0 = np.concatenate([rng.uniform(-b, b, (int(runs), 2)),
                         rng.normal(0.0, v, (int(runs), 2))], axis=-1)
    motion = ConstantVelocity(accel_var, dim=2, distribution=distribution)
    return motion.simulate(x0, n_samples, sample_period_s, rng)


@renamed_keywords({"range_var": Renamed("std_m", variance=True)}, positional=("range_var", "rng"))
def noisy_ranges(positions, sensor_path, *, std_m: float,
                 rng: np.random.Generator) -> np.ndarray:
    """Ranges with zero-mean uniform noise of standard deviation ``std_m``, folded at zero.

    Parameters
    ----------
    positions : array_like, shape (..., n, 2)
        Target positions.
    sensor_path : array_like, shape (n, 2) or (..., n, 2)
        Sensor positions.
    std_m : float
        Range noise standard deviation, metres (the paper's channel noise variance is
        ``xi = std_m^2``; its noise is uniform). The old third argument ``range_var``
        (``xi``, m^2) still works with a ``FutureWarning``.
    rng : numpy.random.Generator
        Source of the noise.

    Returns
    -------
    ndarray, shape (..., n)
        ``|r_n + omega_n|``, ``omega_n ~ U(-sqrt(3) std_m, sqrt(3) std_m)``.
    """
    p = as_float_array(positions, "positions", min_ndim=2, last_dim=2)
    s = as_float_array(sensor_path, "sensor_path", min_ndim=2, last_dim=2)
    true_r = np.linalg.norm(p - s, axis=-1)
    h = np.sqrt(3.0) * check_positive(std_m, "std_m", allow_zero=True)
    return np.abs(true_r + rng.uniform(-h, h, size=true_r.shape))


def states_from_positions(positions, sample_period_s: float) -> np.ndarray:
    """``[x, y, vx, vy]`` from sampled positions, velocities by central differences.

    Parameters
    ----------
    positions : array_like, shape (..., n, 2)
    sample_period_s : float
        T.

    Returns
    -------
    ndarray, shape (..., n, 4)
    """
    p = as_float_array(positions, "positions", min_ndim=2, last_dim=2)
    vel = np.gradient(p, check_positive(sample_period_s, "sample_period_s"), axis=-2)
    return np.concatenate([p, vel], axis=-1)


def accel_var_from_positions(positions, sample_period_s: float) -> float:
    """Acceleration variance of recorded tracks from pooled second differences.

    Under eq. (1) the second difference of positions has variance ``delta_g^2 T^4 / 2``
    per axis (for independent accelerations), hence ``2 var(d^2 x) / T^4``.

    Parameters
    ----------
    positions : array_like, shape (..., n, 2)
    sample_period_s : float
        T.

    Returns
    -------
    float
        ``delta_g^2``, (m/s^2)^2.
    """
    p = as_float_array(positions, "positions", min_ndim=2, last_dim=2)
    T = check_positive(sample_period_s, "sample_period_s")
    return float(2.0 * np.var(np.diff(p, n=2, axis=-2)) / T**4)


def place_tracks(pool, runs: int, box_m: float, rng: np.random.Generator) -> np.ndarray:
    """Draw ``runs`` tracks from a pool (with replacement) and shift each to start in a box.

    Draws, in this order: the pool indices, then the start positions ``U(-box_m, box_m)^2``.

    Parameters
    ----------
    pool : array_like, shape (P, n, 4)
        Recorded states ``[x, y, vx, vy]``.
    runs : int
        Number of tracks to draw.
    box_m : float
        Half-width of the start box, metres.
    rng : numpy.random.Generator

    Returns
    -------
    ndarray, shape (runs, n, 4)
        The drawn tracks, translated (velocities unchanged).
    """
    states = as_float_array(pool, "pool", ndim=3, last_dim=4)
    b = check_positive(box_m, "box_m")
    pick = states[rng.integers(0, states.shape[0], int(runs))]
    shift = rng.uniform(-b, b, (int(runs), 1, 2)) - pick[:, :1, :2]
    return pick + np.concatenate([shift, np.zeros_like(shift)], axis=-1)


def sine_positions(n_samples: int) -> np.ndarray:
    """The ``y = sin x`` target of the paper's Fig. 2, ``x`` evenly over ``[0, 2 pi]``.

    Parameters
    ----------
    n_samples : int

    Returns
    -------
    ndarray, shape (n_samples, 2)
    """
    x = np.linspace(0.0, 2 * np.pi, int(n_samples))
    return np.stack([x, np.sin(x)], axis=-1)
