"""Single-epoch baselines of paper 001: genie-aided local ML and RANSAC multilateration.

Both see, at one instant, the ranges of a vehicle to its neighbours whose positions are
given (the genie of Sect. V supplies the true neighbour positions), batched over leading
axes ``(..., L)`` with a ``valid`` mask for absent links.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.geometry import distances
from radioloc.estimators.local_search import best_candidate, local_grid, search
from radioloc.models.los_nlos import LosNlosRange


def _residuals(x: np.ndarray, centres: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """``theta - ||x_c - centre||`` for candidates ``x (..., C, 2)``: ``(..., C, L)``."""
    return ranges[..., None, :] - distances(x[..., :, None, :], centres[..., None, :, :])


def local_ml(ranges: np.ndarray, centres: np.ndarray, valid: np.ndarray, model: LosNlosRange,
             radius_m: float) -> np.ndarray:
    """Local maximum-likelihood position under the LOS/NLOS mixture ``(..., 2)``.

    Maximises ``sum_m log(alpha p_LOS + (1 - alpha) p_NLOS)`` over the candidates of
    :func:`radioloc.estimators.local_search.search` (coarse grid of half width
    ``radius_m``, since the vehicle is within ``radius_m`` of every neighbour).
    """
    def objective(x):
        e = _residuals(x, centres, ranges)
        lp = model.logpdf(e, 0.0)
        return np.sum(np.where(valid[..., None, :], lp, 0.0), axis=-1)
    return search(objective, centres, np.where(valid, ranges, 0.0), valid, radius_m)


def ransac(ranges: np.ndarray, centres: np.ndarray, valid: np.ndarray, threshold_m: float,
           radius_m: float) -> np.ndarray:
    """RANSAC-style multilateration ``(..., 2)``.

    Hypotheses are the intersections of every pair of range circles (minimal sets of two
    ranges in 2-D); the consensus of a hypothesis is the number of ranges with
    ``|residual| < threshold_m``. The largest consensus wins (ties: smaller squared
    residual over the inliers), then the least-squares fit on that hypothesis's inlier
    set is refined on local grids. Exhaustive over pairs instead of random draws.
    """
    def consensus(x):
        e = _residuals(x, centres, ranges)
        inl = valid[..., None, :] & (np.abs(e) < threshold_m)
        sq = np.sum(np.where(inl, e * e, 0.0), axis=-1)
        return inl.sum(-1) - sq / (inl.sum(-1) * threshold_m**2 + 1.0)
    x0 = search(consensus, centres, np.where(valid, ranges, 0.0), valid, radius_m, refine=())
    e0 = ranges - distances(x0[..., None, :], centres)
    inliers = valid & (np.abs(e0) < threshold_m)

    def least_squares(x):
        e = _residuals(x, centres, ranges)
        return -np.sum(np.where(inliers[..., None, :], e * e, 0.0), axis=-1)
    for half, n in ((0.5, 21), (0.05, 21)):
        local = x0[..., None, :] + local_grid(half, n)
        x0 = best_candidate(least_squares, local, np.ones(local.shape[:-1], dtype=bool))
    return x0
