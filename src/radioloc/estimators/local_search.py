"""Snapshot (single-epoch) position search shared by the local ML and RANSAC baselines.

Candidates are the pairwise intersections of the range circles (where two accurate
ranges place the node) plus a coarse grid; the best candidate of an objective is then
polished by two successively finer local grids. Given a search ``centre`` (e.g. a
previous estimate), the coarse grid is centred there and intersections farther than the
grid's half width from it are left out: a local search. Batched over leading axes; the
objective maps candidate positions ``(..., C, 2)`` to scores ``(..., C)`` (larger is better).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

Objective = Callable[[np.ndarray], np.ndarray]


def circle_intersections(centres: np.ndarray, radii: np.ndarray,
                         valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intersections of every pair of circles.

    Parameters
    ----------
    centres : ndarray, shape (..., L, 2)
        Circle centres.
    radii : ndarray, shape (..., L)
        Circle radii.
    valid : ndarray of bool, shape (..., L)
        Which circles exist.

    Returns
    -------
    points : ndarray, shape (..., 2P, 2)
        Both intersections of each of the ``P = L (L - 1) / 2`` pairs.
    ok : ndarray of bool, shape (..., 2P)
        False for pairs with a missing circle, coincident centres or no intersection.
    """
    n = centres.shape[-2]
    i, j = np.triu_indices(n, 1)
    c1, c2 = centres[..., i, :], centres[..., j, :]
    r1, r2 = radii[..., i], radii[..., j]
    delta = c2 - c1
    d = np.sqrt(np.sum(delta * delta, axis=-1))
    ok = valid[..., i] & valid[..., j] & (d > 1e-9) & (d <= r1 + r2) & (d >= np.abs(r1 - r2))
    ds = np.where(ok, d, 1.0)
    a = (r1 * r1 - r2 * r2 + ds * ds) / (2 * ds)
    h = np.sqrt(np.maximum(r1 * r1 - a * a, 0.0))
    e = delta / ds[..., None]
    base = c1 + a[..., None] * e
    perp = np.stack([-e[..., 1], e[..., 0]], axis=-1)
    pts = np.concatenate([base + h[..., None] * perp, base - h[..., None] * perp], axis=-2)
    return pts, np.concatenate([ok, ok], axis=-1)


def local_grid(half_width: float, n: int) -> np.ndarray:
    """Offsets of a square grid.

    Parameters
    ----------
    half_width : float
        Half width of the grid, metres.
    n : int
        Points per axis.

    Returns
    -------
    ndarray, shape (n * n, 2)
    """
    g = np.linspace(-half_width, half_width, n)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


def best_candidate(objective: Objective, candidates: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """The candidate with the highest score among the ``ok`` ones.

    Parameters
    ----------
    objective : callable
        Candidates ``(..., C, 2)`` to scores ``(..., C)`` (larger is better).
    candidates : ndarray, shape (..., C, 2)
    ok : ndarray of bool, shape (..., C)
        Candidates allowed.

    Returns
    -------
    ndarray, shape (..., 2)
    """
    score = np.where(ok, objective(candidates), -np.inf)
    best = np.argmax(score, axis=-1)
    return np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]


def search(objective: Objective, centres: np.ndarray, radii: np.ndarray, valid: np.ndarray,
           coarse_half_width_m: float, coarse_points: int = 21,
           refine: tuple[tuple[float, int], ...] = ((0.5, 21), (0.05, 21)),
           centre: np.ndarray | None = None, circles: np.ndarray | None = None) -> np.ndarray:
    """Maximise ``objective`` over circle intersections and a coarse grid, then refine.

    The coarse grid is centred on the mean of the valid centres (the origin where none),
    or on ``centre`` if given; with ``centre`` only the intersections within the grid's
    square (half width ``coarse_half_width_m`` around ``centre``) are candidates.

    Parameters
    ----------
    objective : callable
        Candidates ``(..., C, 2)`` to scores ``(..., C)`` (larger is better).
    centres : ndarray, shape (..., L, 2)
        Points ranged to.
    radii : ndarray, shape (..., L)
        Measured ranges (any value where not ``valid``).
    valid : ndarray of bool, shape (..., L)
        Which ranges exist.
    coarse_half_width_m : float
        Half width of the coarse grid.
    coarse_points : int
        Points per axis of the coarse grid.
    refine : tuple of (half_width, points)
        Successive local grids around the best candidate.
    centre : ndarray, shape (..., 2), optional
        Centre of a local search (broadcast against the batch axes); default: a global
        search around the centroid of the points heard.
    circles : ndarray of bool, shape (..., L), optional
        Which valid rows are range circles whose intersections are candidates (the
        others, e.g. bearings, only place the grid); default: every valid row.

    Returns
    -------
    ndarray, shape (..., 2)
        The best candidate found.
    """
    pts, ok = circle_intersections(centres, radii, valid if circles is None else circles)
    if centre is None:
        w = valid.astype(float)
        centroid = (centres * w[..., None]).sum(-2) / np.maximum(w.sum(-1), 1.0)[..., None]
    else:
        centroid = np.broadcast_to(np.asarray(centre, dtype=float), pts.shape[:-2] + (2,))
        near = np.all(np.abs(pts - centroid[..., None, :]) <= coarse_half_width_m, axis=-1)
        ok = ok & near
    grid = centroid[..., None, :] + local_grid(coarse_half_width_m, coarse_points)
    cand = np.concatenate([pts, grid], axis=-2)
    cand_ok = np.concatenate([ok, np.ones(grid.shape[:-1], dtype=bool)], axis=-1)
    x = best_candidate(objective, cand, cand_ok)
    for half, n in refine:
        local = x[..., None, :] + local_grid(half, n)
        x = best_candidate(objective, local, np.ones(local.shape[:-1], dtype=bool))
    return x
