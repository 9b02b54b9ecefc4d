"""Particle resampling schemes, batched over leading axes.

Every scheme takes normalised weights ``(..., K)`` and a generator and returns ancestor
indices ``(..., K)`` (int64) such that particle ``j`` of the new set is old particle
``idx[..., j]`` of the same batch entry. All are unbiased: the expected number of copies
of particle ``i`` is ``K w_i``.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from radioloc.core.errors import ConfigError, InputError


def _check(weights: np.ndarray) -> np.ndarray:
    w = np.asarray(weights, dtype=float)
    if w.ndim < 1 or w.shape[-1] < 1:
        raise InputError("weights: need at least one particle on the last axis")
    if not np.all(np.isfinite(w)) or np.any(w < 0):
        raise InputError("weights: must be finite and non-negative")
    s = w.sum(axis=-1, keepdims=True)
    if np.any(s <= 0):
        raise InputError("weights: every batch entry needs a positive total weight")
    return w / s


def _inverse_cdf(w: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Batched ``searchsorted(cumsum(w), u)``: offsets each row by its index to flatten."""
    k = w.shape[-1]
    cdf = np.cumsum(w, axis=-1)
    cdf[..., -1] = 1.0 + 1e-12
    rows = np.arange(int(np.prod(w.shape[:-1], dtype=int))).reshape(w.shape[:-1] + (1,))
    flat_cdf = (cdf + 2.0 * rows).ravel()
    flat_u = (u + 2.0 * rows).ravel()
    idx = np.searchsorted(flat_cdf, flat_u, side="right").reshape(u.shape)
    return np.minimum(idx - rows * k, k - 1).astype(np.int64)


def systematic(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniform offset per batch entry, ``u_j = (U + j) / K``.

    Particle ``i`` gets the positions below its cumulative weight ``C_i`` and not below
    ``C_{i-1}``: ``N_i - N_{i-1}`` copies with ``N_i = ceil(K C_i - U)`` (clipped to
    ``[0, K]``, ``N_{K-1} = K``), the number of positions ``u_j < C_i``.

    Parameters
    ----------
    weights : array_like, shape (..., K)
        Non-negative weights (normalised here) of each batch entry.
    rng : numpy.random.Generator
        Source of the uniforms.

    Returns
    -------
    ndarray of int64, shape (..., K)
        Ancestor index of every new particle.
    """
    w = _check(weights)
    k = w.shape[-1]
    below = np.clip(np.ceil(k * np.cumsum(w, axis=-1) - rng.random(w.shape[:-1] + (1,))), 0, k)
    below[..., -1] = k
    copies = np.diff(below, prepend=0.0, axis=-1).astype(np.int64)
    return np.repeat(np.broadcast_to(np.arange(k), w.shape).ravel(),
                     copies.ravel()).reshape(w.shape)


def stratified(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniform per stratum, ``u_j = (U_j + j) / K``.

    Parameters
    ----------
    weights : array_like, shape (..., K)
        Non-negative weights (normalised here) of each batch entry.
    rng : numpy.random.Generator
        Source of the uniforms.

    Returns
    -------
    ndarray of int64, shape (..., K)
        Ancestor index of every new particle.
    """
    w = _check(weights)
    k = w.shape[-1]
    u = (rng.random(w.shape) + np.arange(k)) / k
    return _inverse_cdf(w, u)


def multinomial(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``K`` independent draws from the weights.

    Parameters
    ----------
    weights : array_like, shape (..., K)
        Non-negative weights (normalised here) of each batch entry.
    rng : numpy.random.Generator
        Source of the uniforms.

    Returns
    -------
    ndarray of int64, shape (..., K)
        Ancestor index of every new particle.
    """
    w = _check(weights)
    return _inverse_cdf(w, rng.random(w.shape))


def residual(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``floor(K w_i)`` deterministic copies, the rest multinomial on the residual weights.

    Parameters
    ----------
    weights : array_like, shape (..., K)
        Non-negative weights (normalised here) of each batch entry.
    rng : numpy.random.Generator
        Source of the uniforms.

    Returns
    -------
    ndarray of int64, shape (..., K)
        Ancestor index of every new particle.
    """
    w = _check(weights)
    k = w.shape[-1]
    counts = np.floor(k * w).astype(np.int64)
    n_det = counts.sum(axis=-1, keepdims=True)                     # (..., 1)
    rest = k * w - counts
    rest_sum = rest.sum(axis=-1, keepdims=True)
    rest = np.where(rest_sum > 0, rest / np.where(rest_sum > 0, rest_sum, 1.0), 1.0 / k)
    drawn = _inverse_cdf(rest, rng.random(w.shape))
    # deterministic copies: position j < n_det takes the particle whose cumulative count exceeds j
    j = np.arange(k)
    ccum = np.cumsum(counts, axis=-1)
    flat_rows = np.arange(int(np.prod(w.shape[:-1], dtype=int))).reshape(w.shape[:-1] + (1,))
    det = np.searchsorted((ccum + flat_rows * (k + 1)).ravel(),
                          (j + flat_rows * (k + 1)).ravel(), side="right").reshape(w.shape)
    det = np.minimum(det - flat_rows * k, k - 1)
    shift = np.clip(j - n_det, 0, k - 1)
    from_rest = np.take_along_axis(drawn, shift, axis=-1)
    return np.where(j < n_det, det, from_rest).astype(np.int64)


SCHEMES: dict[str, Callable[[np.ndarray, np.random.Generator], np.ndarray]] = {
    "systematic": systematic, "stratified": stratified,
    "multinomial": multinomial, "residual": residual,
}


def get_scheme(name: str) -> Callable[[np.ndarray, np.random.Generator], np.ndarray]:
    """The resampling function called ``name``.

    Parameters
    ----------
    name : {"systematic", "stratified", "multinomial", "residual"}

    Returns
    -------
    callable
        ``scheme(weights, rng) -> ancestor indices``.

    Raises
    ------
    ConfigError
        If ``name`` is unknown.
    """
    try:
        return SCHEMES[name]
    except KeyError:
        raise ConfigError(f"resampling: unknown scheme {name!r}; choose from {sorted(SCHEMES)}") from None
