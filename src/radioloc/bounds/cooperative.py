"""Cramer-Rao bound of a cooperative network from pairwise ranges and Gaussian priors.

The unknown is the stacked position vector of all ``K`` nodes. Ranges alone are invariant to
translations, rotations and reflections of the whole network, so their Fisher information
is singular (rank ``2K - 3`` in 2-D); the Gaussian priors on the node positions are what
fix the network's position and orientation, and they enter as the prior information
``diag(1 / prior_var)`` (the Bayesian bound).
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.validation import as_float_array, as_positions

_RANGE_VAR = {"range_var": Renamed("std_m", variance=True)}


@renamed_keywords(_RANGE_VAR, positional=("range_var", "counts"))
def network_range_information(position: np.ndarray, *, std_m: float | np.ndarray,
                              counts: np.ndarray | float = 1.0) -> np.ndarray:
    """Fisher information ``(..., 2K, 2K)`` of Gaussian ranges between all node pairs.

    Parameters
    ----------
    position : (..., K, 2) array, m
        True positions.
    std_m : float or (..., K, K) array
        Range noise standard deviation of one range of each ordered pair, metres (the
        paper's ``sigma_v^2 = 900 m^2`` is ``std_m=30``). The old second argument
        ``range_var`` (m^2) still works with a ``FutureWarning``.
    counts : float or (..., K, K) array
        Number of independent ranges of each ordered pair ``(k, p)`` (k measured p); the
        diagonal is ignored. One iteration of the paper's protocol gives 1 for every
        ordered pair, i.e. 2 per unordered pair.

    Returns
    -------
    (..., 2K, 2K) array
        Information of the stacked positions ``[x_1, y_1, x_2, ...]``, 1/m^2.

    Raises
    ------
    GeometryError
        Two nodes coincide.
    """
    pos = as_positions(position, "position", dims=(2,))
    K = pos.shape[-2]
    diff = pos[..., None, :, :] - pos[..., :, None, :]               # x_p - x_k at [k, p]
    d = np.linalg.norm(diff, axis=-1)
    off = ~np.eye(K, dtype=bool)
    if np.any(d[..., off] <= 0):
        raise GeometryError("position: two nodes coincide; range information is undefined")
    u = diff / np.where(off, d, 1.0)[..., None]
    w = np.broadcast_to(np.asarray(counts, float) / np.asarray(std_m, float) ** 2,
                        d.shape) * off
    c = w + np.swapaxes(w, -1, -2)                 # information of each unordered pair {k, p}
    G = np.einsum("...kp,...kpi,...kpj->...kpij", c, u, u)            # (..., K, K, 2, 2)
    info = -np.swapaxes(G, -3, -2)                 # J[k, :, p, :] = -G_kp for k != p
    diag = G.sum(axis=-4)                          # J[p, :, p, :] = sum_k G_kp
    for p in range(K):                             # K diagonal blocks (K is small)
        info[..., p, :, p, :] = diag[..., p, :, :]
    return info.reshape(pos.shape[:-2] + (2 * K, 2 * K))


@renamed_keywords(_RANGE_VAR, positional=("range_var", "prior_var", "counts"))
def network_crb(position: np.ndarray, *, std_m: float | np.ndarray, prior_var: np.ndarray,
                counts: np.ndarray | float = 1.0) -> np.ndarray:
    """Bayesian Cramer-Rao bound ``(..., 2K, 2K)``: ranges plus Gaussian priors.

    Parameters
    ----------
    position : (..., K, 2) array, m
    std_m : float or (..., K, K) array
        Range noise standard deviation, metres, as in :func:`network_range_information`.
    prior_var : (..., K, 2) array, m^2
        Per-axis prior variances (independent priors).
    counts : float or (..., K, K) array
        Ranges per ordered pair (e.g. the number of iterations ``n``).

    Returns
    -------
    (..., 2K, 2K) array
        The bound on the covariance of the stacked positions, m^2.
    """
    info = network_range_information(position, std_m=std_m, counts=counts)
    var = as_float_array(prior_var, "prior_var", nonnegative=True)
    var = np.broadcast_to(var, np.shape(position))
    if np.any(var <= 0):
        raise InputError("prior_var: must be > 0 (m^2)")
    idx = np.arange(info.shape[-1])
    info = info.copy()
    info[..., idx, idx] += 1.0 / var.reshape(var.shape[:-2] + (-1,))
    return np.linalg.inv(info)


def node_crb_trace(crb: np.ndarray) -> np.ndarray:
    """Per-node ``trace`` of the 2x2 diagonal blocks of a stacked bound.

    Parameters
    ----------
    crb : (..., 2K, 2K) array
        Bound on the stacked positions, m^2.

    Returns
    -------
    (..., K) array
        Trace of each node's block, m^2.
    """
    d = np.diagonal(crb, axis1=-2, axis2=-1)
    return d[..., 0::2] + d[..., 1::2]


@renamed_keywords(_RANGE_VAR, positional=("range_var", "prior_var", "counts"))
def network_crb_node_traces(position: np.ndarray, *, std_m: float | np.ndarray,
                            prior_var: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Per-node CRB traces ``(N, ..., K)`` for a sequence of range counts at once.

    With ``n`` ranges of every ordered pair, the information is ``n J_r + J_p`` (``J_p``
    the diagonal prior information). Whitening by the prior and one eigendecomposition
    ``J_p^{-1/2} J_r J_p^{-1/2} = V diag(l) V^T`` give every bound as
    ``J_p^{-1/2} V diag(1 / (n l + 1)) V^T J_p^{-1/2}``; equal to :func:`network_crb` for
    each ``n``.

    Parameters
    ----------
    position : (..., K, 2) array, m
    std_m : float or (..., K, K) array
        Range noise standard deviation, metres, as in :func:`network_range_information`.
    prior_var : (..., K, 2) array, m^2
    counts : (N,) array
        Ranges per ordered pair (e.g. iterations 0..N-1).

    Returns
    -------
    (N, ..., K) array
        Per-node traces of the bound for each count, m^2.
    """
    info = network_range_information(position, std_m=std_m)
    var = as_float_array(prior_var, "prior_var", nonnegative=True)
    var = np.broadcast_to(var, np.shape(position))
    if np.any(var <= 0):
        raise InputError("prior_var: must be > 0 (m^2)")
    sd = np.sqrt(var.reshape(var.shape[:-2] + (-1,)))                  # (..., 2K)
    lam, V = np.linalg.eigh(sd[..., :, None] * info * sd[..., None, :])
    B2 = (sd[..., :, None] * V) ** 2                                     # (..., 2K, 2K)
    n = np.asarray(counts, dtype=float)
    shrink = 1.0 / (n.reshape((-1,) + (1,) * lam.ndim) * np.maximum(lam, 0.0) + 1.0)
    diag = np.einsum("...ij,n...j->n...i", B2, shrink)
    return diag[..., 0::2] + diag[..., 1::2]
