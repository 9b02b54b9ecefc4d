"""Offline smoothing of a particle filter's track by backward simulation.

Forward filtering, backward simulation (FFBSi; Godsill, Doucet and West, 2004): given the
filter's equally weighted particle sets ``{x_k^i}`` after every step ``k`` (approximations of
``p(x_k | y_1:k)``), each smoothed trajectory is drawn backwards,

    x_T ~ uniform over the particles of the last step,
    x_k ~ categorical over i with probability proportional to p(x_{k+1} | x_k^i),

with ``p(x_{k+1} | x_k)`` the Gaussian transition density of the linear-Gaussian motion
model, ``N(x_{k+1}; F(dt) x_k, Q(dt))``. The smoothed mean and covariance of step ``k`` are
those of the drawn trajectories at ``k``. Every trajectory is batched: one ``(M, K)``
log-density array per step (M trajectories, K particles), the only loop is over time.

Unlike the genealogy of the particles (a fixed-lag smoother that follows resampling
indices back), a backward draw can jump to any particle that explains the next state,
so it does not collapse onto few ancestors over long lags. When the transition noise is
much smaller than the particle spread (a constant-velocity model over short steps), the
density is peaked and the draw nearly follows the genealogy.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import ConfigError, InputError

__all__ = ["backward_simulation"]


def backward_simulation(history, times, motion, trajectories: int, rng: np.random.Generator
                        ) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed means and covariances by backward simulation over a filter's particles.

    Parameters
    ----------
    history : sequence of ndarray, each shape (K, n)
        Equally weighted particles after each of the T filter steps (state position first).
    times : ndarray, shape (T,)
        Time of each step, seconds (strictly increasing).
    motion : motion model
        The filter's linear-Gaussian model, with ``F(dt)``, ``Q(dt)`` and ``state_dim``.
    trajectories : int
        Backward trajectories drawn (M).
    rng : numpy.random.Generator

    Returns
    -------
    mean : ndarray, shape (T, n)
        Mean of the drawn trajectories at each step.
    covariance : ndarray, shape (T, n, n)
        Their covariance.

    Raises
    ------
    ConfigError
        ``trajectories`` is not a positive integer.
    InputError
        ``history`` and ``times`` disagree, a particle set has the wrong state size, or the
        times do not increase.
    """
    if int(trajectories) != trajectories or trajectories < 1:
        raise ConfigError(f"trajectories: must be a positive integer, got {trajectories!r}")
    t = np.asarray(times, dtype=float)
    T = len(history)
    if t.shape != (T,):
        raise InputError(f"times: expected shape ({T},) (one per particle set), got {t.shape}")
    if T == 0:
        raise InputError("history: no particle set")
    if T > 1 and not np.all(np.diff(t) > 0):
        raise InputError("times: must be strictly increasing")
    n = motion.state_dim
    for k, h in enumerate(history):
        if np.ndim(h) != 2 or np.shape(h)[1] != n:
            raise InputError(f"history[{k}]: expected shape (K, {n}), got {np.shape(h)}")
    M = int(trajectories)
    mean = np.empty((T, n))
    cov = np.empty((T, n, n))
    last = np.asarray(history[-1], dtype=float)
    x = last[rng.integers(0, last.shape[0], M)]                       # (M, n)
    _moments(x, mean, cov, T - 1)
    for k in range(T - 2, -1, -1):
        parts = np.asarray(history[k], dtype=float)                    # (K, n)
        dt = t[k + 1] - t[k]
        Q = np.asarray(motion.Q(dt), dtype=float)
        Q = Q + 1e-12 * max(float(np.trace(Q)), 1e-300) * np.eye(n)   # keep it invertible
        L_inv = np.linalg.inv(np.linalg.cholesky(Q))
        pred = parts @ np.asarray(motion.F(dt), dtype=float).T         # (K, n)
        z = (x[:, None, :] - pred[None]) @ L_inv.T                     # (M, K, n)
        logw = -0.5 * np.sum(z * z, axis=-1)                           # (M, K)
        logw -= logw.max(axis=-1, keepdims=True)
        w = np.exp(logw)
        cdf = np.cumsum(w, axis=-1)
        u = rng.random(M) * cdf[:, -1]
        pick = np.minimum((cdf < u[:, None]).sum(axis=-1), parts.shape[0] - 1)
        x = parts[pick]
        _moments(x, mean, cov, k)
    return mean, cov


def _moments(x: np.ndarray, mean: np.ndarray, cov: np.ndarray, k: int) -> None:
    mean[k] = x.mean(axis=0)
    dev = x - mean[k]
    cov[k] = dev.T @ dev / x.shape[0]
