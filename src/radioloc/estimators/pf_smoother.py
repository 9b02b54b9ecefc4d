"""Offline smoothing of a particle filter's track by backward simulation.

Forward filtering, backward simulation (FFBSi; Godsill, Doucet and West, 2004): given the
filter's equally weighted particle sets ``{x_k^i}`` after every step ``k`` (approximations of
``p(x_k | y_1:k)``), each smoothed trajectory is drawn backwards,

    x_T ~ uniform over the particles of the last step,
    x_k ~ categorical over i with probability proportional to p(x_{k+1} | x_k^i),

with ``p(x_{k+1} | x_k)`` the Gaussian transition density of the linear-Gaussian motion
model, ``N(x_{k+1}; F(dt) x_k, Q(dt))``. The smoothed mean and covariance of step ``k`` are
those of the drawn trajectories at ``k``. Every trajectory is batched: one ``(..., M, K)``
log-density array per step (runs, M trajectories, K particles), the only loop is over time.

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


def backward_simulation(history, times, motion, trajectories: int, rng,
                        log_weights=None) -> tuple[np.ndarray, np.ndarray]:
    """Smoothed means and covariances by backward simulation over a filter's particles.

    Parameters
    ----------
    history : sequence of ndarray, each shape (..., K, n')
        Particles after each of the T filter steps (state position first, the motion
        model's ``n`` components first, ``n' >= n``); leading axes are independent runs.
    times : ndarray, shape (T,)
        Time of each step, seconds (strictly increasing).
    motion : motion model
        The filter's linear-Gaussian model, with ``F(dt)``, ``Q(dt)`` and ``state_dim``
        (``n``). Components after the first ``n`` are carried along the drawn
        trajectories and do not enter the transition density.
    trajectories : int
        Backward trajectories drawn per run (M).
    rng : numpy.random.Generator
        Or any object with ``integers`` and ``random`` drawing arrays whose leading axes
        are the runs (e.g. :class:`radioloc.estimators.particle_filter.RunGenerators`).
    log_weights : sequence of ndarray, each shape (..., K), optional
        Normalised log weights of each step's particles (a filter that does not resample
        at every step); None: equally weighted sets. With weights the backward
        probability of particle ``i`` is ``w_k^i p(x_{k+1} | x_k^i)``.

    Returns
    -------
    mean : ndarray, shape (T, ..., n')
        Mean of the drawn trajectories at each step.
    covariance : ndarray, shape (T, ..., n', n')
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
    shape = np.shape(history[0])
    if len(shape) < 2 or shape[-1] < n:
        raise InputError(f"history[0]: expected shape (..., K, {n}), got {shape}")
    for k, h in enumerate(history):
        if np.shape(h) != shape:
            raise InputError(f"history[{k}]: expected shape {shape}, got {np.shape(h)}")
    if log_weights is not None and (len(log_weights) != T or
                                    any(np.shape(w) != shape[:-1] for w in log_weights)):
        raise InputError(f"log_weights: expected {T} arrays of shape {shape[:-1]}")
    batch, K = shape[:-2], shape[-2]
    M = int(trajectories)
    mean = np.empty((T,) + batch + shape[-1:])
    cov = np.empty((T,) + batch + shape[-1:] * 2)
    last = np.asarray(history[-1], dtype=float)
    if log_weights is None:
        pick = rng.integers(0, K, batch + (M,))
    else:
        pick = _categorical(np.broadcast_to(np.asarray(log_weights[-1], dtype=float)[..., None, :],
                                            batch + (M, K)), rng)
    x = np.take_along_axis(last, pick[..., None], axis=-2)            # (..., M, n')
    _moments(x, mean, cov, T - 1)
    for k in range(T - 2, -1, -1):
        parts = np.asarray(history[k], dtype=float)                    # (..., K, n')
        dt = t[k + 1] - t[k]
        Q = np.asarray(motion.Q(dt), dtype=float)
        Q = Q + 1e-12 * max(float(np.trace(Q)), 1e-300) * np.eye(n)   # keep it invertible
        L_inv = np.linalg.inv(np.linalg.cholesky(Q))
        pred = parts[..., :n] @ np.asarray(motion.F(dt), dtype=float).T          # (..., K, n)
        z = (x[..., :, None, :n] - pred[..., None, :, :]) @ L_inv.T              # (..., M, K, n)
        logw = -0.5 * np.sum(z * z, axis=-1)                                      # (..., M, K)
        if log_weights is not None:
            logw = logw + np.asarray(log_weights[k], dtype=float)[..., None, :]
        pick = _categorical(logw, rng)
        x = np.take_along_axis(parts, pick[..., None], axis=-2)
        _moments(x, mean, cov, k)
    return mean, cov


def _categorical(logw: np.ndarray, rng) -> np.ndarray:
    """One draw per row of ``logw`` (..., M, K) with probabilities proportional to
    ``exp(logw)``: indices (..., M)."""
    logw = logw - logw.max(axis=-1, keepdims=True)
    cdf = np.cumsum(np.exp(logw), axis=-1)
    u = rng.random(logw.shape[:-1]) * cdf[..., -1]
    return np.minimum((cdf < u[..., None]).sum(axis=-1), logw.shape[-1] - 1)


def _moments(x: np.ndarray, mean: np.ndarray, cov: np.ndarray, k: int) -> None:
    """Mean and covariance over the trajectories (axis -2) of ``x`` (..., M, n)."""
    mean[k] = x.mean(axis=-2)
    dev = x - mean[k][..., None, :]
    cov[k] = np.einsum("...mi,...mj->...ij", dev, dev) / x.shape[-2]
