"""The filter step of a Gaussian mixture under any log-likelihood of the position: a
progressive Gaussian update of each component, moment-matched on deterministic nodes.

A Gaussian-sum filter multiplies each component ``N(s; m_k, P_k)`` of the predicted density
of the state ``s = (x, r)`` (position ``x``, then the rest: a velocity) by the likelihood
``L(x) = p(z | x)`` and re-approximates the product by a Gaussian: its weight ``w_k c_k``
with ``c_k = E_k[L]``, and its mean and covariance. The position moments are taken on the
Gauss-Hermite nodes of the component's position marginal (``order`` points per coordinate
on the principal axes, ``x_i = m_x + V sqrt(Lambda) xi_i``):
``E_k[f] ~= sum_i a_i f(x_i)``. The rest of the state follows through its conditional
Gaussian, which a likelihood of ``x`` leaves unchanged: with ``K = P_rx P_xx^-1``,
``m_r' = m_r + K (m_x' - m_x)``, ``P_rx' = K P_xx'``, ``P_rr' = P_rr + K (P_xx' - P_xx) K^T``.

A likelihood much narrower than the component (a range of 5 cm seen from a prior of 1 m)
would put all the mass on one node. The update is therefore progressive (a homotopy
``L^lambda``, ``lambda`` from 0 to 1, as in Hanebeck's progressive Gaussian filtering): each
sub-step takes the largest ``d lambda`` for which the tempered log-likelihood
``d lambda log L`` spreads over the nodes of the current component by at most
``log_ratio``, moment-matches the component to ``N L^d lambda``, and places the next nodes on
the narrowed component. A likelihood flat over the nodes takes one sub-step; a sharp one a
few (each can shrink the variance along an axis by about ``1 + log_ratio``). A component
whose nodes all have zero likelihood gets weight 0; a run whose components all do keeps
its prediction (the caller is told which).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache

import numpy as np
from numpy.polynomial.hermite_e import hermegauss

__all__ = ["progressive_update", "hermite_nodes"]

#: a sub-step's position covariance gets this fraction of the previous one added: a floor
#: against a collapse onto one node when all but one node have zero likelihood
COVARIANCE_FLOOR = 1e-6


@lru_cache(maxsize=8)
def hermite_nodes(dim: int, order: int) -> tuple[np.ndarray, np.ndarray]:
    """Tensor Gauss-Hermite nodes and weights of the standard normal in ``dim`` coordinates.

    Parameters
    ----------
    dim : int
        Coordinates.
    order : int
        Nodes per coordinate (exact for polynomials of degree ``2 order - 1``).

    Returns
    -------
    nodes : ndarray, shape (order**dim, dim)
    weights : ndarray, shape (order**dim,)
        Positive, summing to one. Both are read-only (cached and shared between calls).
    """
    x, w = hermegauss(order)
    grids = np.meshgrid(*([x] * dim), indexing="ij")
    wgrids = np.meshgrid(*([w] * dim), indexing="ij")
    nodes = np.stack([g.ravel() for g in grids], axis=-1)
    weights = np.prod(np.stack([g.ravel() for g in wgrids], axis=-1), axis=-1)
    weights = weights / weights.sum()
    nodes.setflags(write=False)
    weights.setflags(write=False)
    return nodes, weights


def _sqrt_psd(P: np.ndarray) -> np.ndarray:
    """Square root ``V sqrt(Lambda)`` of symmetric positive semi-definite matrices."""
    lam, V = np.linalg.eigh(P)
    return V * np.sqrt(np.maximum(lam, 0.0))[..., None, :]


def progressive_update(weights: np.ndarray, means: np.ndarray, covs: np.ndarray,
                       loglik: Callable[[np.ndarray], np.ndarray], dim: int, *,
                       order: int = 5, log_ratio: float = 3.0, max_steps: int = 200
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Multiply every component of a Gaussian mixture by a likelihood of the first ``dim``
    state coordinates and re-approximate each product by one Gaussian (module docstring).

    Parameters
    ----------
    weights : ndarray, shape (B, K)
        Component weights of each run (0 = unused slot).
    means : ndarray, shape (B, K, n)
    covs : ndarray, shape (B, K, n, n)
        Symmetric positive definite.
    loglik : callable
        Positions ``(B, K, Q, dim)`` to ``log p(z | x)`` ``(B, K, Q)``; ``-inf`` where the
        likelihood is zero; never NaN.
    dim : int
        Position coordinates (the first ``dim`` of the state).
    order : int
        Gauss-Hermite nodes per coordinate.
    log_ratio : float
        Largest spread ``max - min`` of the tempered log-likelihood over a component's
        nodes in one sub-step.
    max_steps : int
        Sub-steps at most; what remains of ``lambda`` is then taken in one.

    Returns
    -------
    weights, means, covs : ndarray
        The posterior mixture, weights renormalised per run (a run whose every component
        has zero likelihood on its nodes keeps its input).
    explained : ndarray of bool, shape (B,)
        Runs whose likelihood was positive on some node.
    """
    xi, a = hermite_nodes(int(dim), int(order))
    loga = np.log(a)
    m, P = means.copy(), covs.copy()
    logc = np.zeros(weights.shape)                 # log of the component's evidence so far
    lam = np.zeros(weights.shape)
    alive = weights > 0
    p_ = slice(0, dim)
    r_ = slice(dim, None)
    for step in range(max_steps + 1):
        todo = alive & (lam < 1.0)
        if not todo.any():
            break
        Pxx = P[..., p_, p_]
        x = m[..., None, p_] + np.einsum("bkij,qj->bkqi", _sqrt_psd(Pxx), xi)   # (B, K, Q, dim)
        ll = loglik(x)
        finite = np.isfinite(ll)
        dead = todo & ~finite.any(-1)              # zero likelihood on every node
        alive = alive & ~dead
        todo = todo & ~dead
        top = np.where(todo, np.max(np.where(finite, ll, -np.inf), axis=-1), 0.0)
        low = np.where(todo, np.min(np.where(finite, ll, np.inf), axis=-1), 0.0)
        spread = top - low
        rest = 1.0 - lam
        if step < max_steps:
            d = np.where(spread * rest > log_ratio, log_ratio / np.maximum(spread, 1e-300), rest)
        else:
            d = rest
        d = np.where(todo, d, 0.0)
        gap = np.where(finite, ll - top[..., None], 0.0)
        logu = np.where(finite, loga + d[..., None] * gap, -np.inf)
        u = np.exp(logu)
        s = u.sum(-1)
        s_safe = np.where(s > 0, s, 1.0)
        q = u / s_safe[..., None]
        mx = np.einsum("bkq,bkqi->bki", q, x)
        dx = x - mx[..., None, :]
        Pxx_new = np.einsum("bkq,bkqi,bkqj->bkij", q, dx, dx) + COVARIANCE_FLOOR * Pxx
        # the rest of the state through its conditional Gaussian (module docstring)
        K = np.linalg.solve(Pxx, P[..., p_, r_]).swapaxes(-1, -2)             # (B, K, n-d, d)
        m_new = np.concatenate([mx, m[..., r_] + np.einsum("bkij,bkj->bki", K, mx - m[..., p_])],
                               axis=-1)
        Prx = K @ Pxx_new
        Prr = P[..., r_, r_] + K @ (Pxx_new - Pxx) @ K.swapaxes(-1, -2)
        P_new = np.concatenate([np.concatenate([Pxx_new, Prx.swapaxes(-1, -2)], -1),
                                np.concatenate([Prx, Prr], -1)], -2)
        P_new = 0.5 * (P_new + P_new.swapaxes(-1, -2))
        upd = todo[..., None]
        m = np.where(upd, m_new, m)
        P = np.where(upd[..., None], P_new, P)
        logc = logc + np.where(todo, d * top + np.log(s_safe), 0.0)
        lam = lam + d
    logw = np.where(alive, np.log(np.where(alive, weights, 1.0)) + logc, -np.inf)
    top = np.max(logw, axis=-1, keepdims=True)
    explained = np.isfinite(top[..., 0])
    e = np.exp(logw - np.where(np.isfinite(top), top, 0.0))
    w_new = e / np.where(explained[..., None], e.sum(-1, keepdims=True), 1.0)
    keep = ~explained
    return (np.where(keep[..., None], weights, w_new),
            np.where(keep[..., None, None], means, m),
            np.where(keep[..., None, None, None], covs, P),
            explained)
