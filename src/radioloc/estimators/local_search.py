"""Snapshot (single-epoch) position search shared by the local ML and RANSAC baselines.

Candidates are the pairwise intersections of the range circles (where two accurate
ranges place the node) plus a coarse grid; the best candidate of an objective is then
polished by two successively finer local grids. Given a search ``centre`` (e.g. a
previous estimate), the coarse grid is centred there and intersections farther than the
grid's half width from it are left out: a local search. Without a given half width,
:func:`derived_schedule` sizes the coarse grid and the polish of each problem from its
geometry (:func:`best_on_lattice` scores such grids in blocks). Batched over leading axes;
the objective maps candidate positions ``(..., C, 2)`` to scores ``(..., C)`` (larger is
better).
"""

from __future__ import annotations

from typing import Callable

import numpy as np

Objective = Callable[[np.ndarray], np.ndarray]

#: spacing of :func:`derived_schedule`'s coarse grid, metres (the span of the first polish)
COARSE_SPACING_M = 1.0
#: most coarse points on either side of the centroid in :func:`derived_schedule` (a wider
#: search widens the spacing)
MAX_HALF_POINTS = 64
#: half width at which :func:`derived_schedule`'s refinement stops, metres
FINE_HALF_WIDTH_M = 0.05
#: points per axis of each refine grid of :func:`derived_schedule`
REFINE_POINTS = 21
#: most refine stages of :func:`derived_schedule`
MAX_STAGES = 8
#: candidates of a whole batch that :func:`best_on_lattice` scores at once
LATTICE_BLOCK = 2**18


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


def local_grid(half_width: float | np.ndarray, n: int) -> np.ndarray:
    """Offsets of a square grid.

    Parameters
    ----------
    half_width : float or ndarray, shape (...)
        Half width of the grid, metres (an array: one grid per problem of the batch).
    n : int
        Points per axis.

    Returns
    -------
    ndarray, shape (..., n * n, 2)
    """
    if np.ndim(half_width):
        return np.asarray(half_width, dtype=float)[..., None, None] * local_grid(1.0, n)
    g = np.linspace(-half_width, half_width, n)
    gx, gy = np.meshgrid(g, g, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=-1)


def centroid_of(centres: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Mean of the valid points (the origin where none).

    Parameters
    ----------
    centres : ndarray, shape (..., L, 2)
    valid : ndarray of bool, shape (..., L)

    Returns
    -------
    ndarray, shape (..., 2)
    """
    w = valid.astype(float)
    return (centres * w[..., None]).sum(-2) / np.maximum(w.sum(-1), 1.0)[..., None]


def derived_schedule(centres: np.ndarray, radii: np.ndarray, valid: np.ndarray,
                     circles: np.ndarray) -> dict:
    """Coarse grid and refine schedule of a global :func:`search` from the geometry of
    each problem.

    The half width ``h`` covers every position the points heard allow: their largest
    distance from their centroid plus the smallest range circle (``radii`` where
    ``circles``; the node is within every circle's radius of its point, so an excess range
    does not widen the search), at least ``COARSE_SPACING_M``. The coarse grid has spacing
    ``s = max(COARSE_SPACING_M, h / MAX_HALF_POINTS)`` and ``ceil(h / s)`` points on
    either side of the centroid, so that a likelihood without circles (RSS, bearings)
    is sampled within its first polish. Refine stage ``k`` (from 0) is a grid of
    ``REFINE_POINTS`` per axis and half width ``s / (2 * 10^k)`` (stage 0 spans the coarse
    cell, each next stage one spacing of the one before on either side), until the half
    width is at most ``FINE_HALF_WIDTH_M`` (``s = 1`` m: the stages 0.5 m and 0.05 m of
    :func:`search`'s default, a last spacing of 5 mm). A problem of the batch with a
    smaller grid or fewer stages than the batch's largest has its own grid
    (:func:`best_on_lattice`) and grids of half width 0 (its estimate stays put): each
    problem searches as it would alone.

    Parameters
    ----------
    centres : ndarray, shape (..., L, 2)
        Points of the rows.
    radii : ndarray, shape (..., L)
        Range circles' radii (any value elsewhere).
    valid : ndarray of bool, shape (..., L)
        Rows heard.
    circles : ndarray of bool, shape (..., L)
        Rows heard that are range circles.

    Returns
    -------
    dict
        ``lattice`` (spacing ``(...)`` and points on either side ``(...)`` of the coarse
        grid) and ``refine`` (stages of per-problem half widths ``(...)``), keywords of
        :func:`search`.
    """
    c = centroid_of(centres, valid)
    spread = np.max(np.where(valid, np.linalg.norm(centres - c[..., None, :], axis=-1), 0.0),
                    axis=-1, initial=0.0)
    reach = np.min(np.where(circles, radii, np.inf), axis=-1, initial=np.inf)
    reach = np.where(np.isfinite(reach), reach, 0.0)
    half = np.maximum(spread + reach, COARSE_SPACING_M)
    spacing = np.maximum(COARSE_SPACING_M, half / MAX_HALF_POINTS)
    points = np.minimum(np.ceil(half / spacing), MAX_HALF_POINTS).astype(int)
    shrink = (REFINE_POINTS - 1) / 2
    first = spacing / 2
    stages = np.clip(np.ceil(np.log(first / FINE_HALF_WIDTH_M) / np.log(shrink) - 1e-9) + 1,
                     1, MAX_STAGES).astype(int)
    refine = tuple((np.where(j < stages, first / shrink**j, 0.0), REFINE_POINTS)
                   for j in range(int(stages.max(initial=1))))
    return {"lattice": (spacing, points), "refine": refine}


def best_on_lattice(objective: Objective, centre: np.ndarray, spacing: np.ndarray,
                    half_points: np.ndarray, block: int = LATTICE_BLOCK
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The best point of a square lattice per problem, scored in blocks.

    The lattice of problem ``b`` is ``centre_b + spacing_b (i, j)`` for integers
    ``|i|, |j| <= half_points_b``, in the order of :func:`local_grid` (``i`` slow). The
    lattices of a batch are scored together, at most ``block`` candidates of the whole
    batch at a time, so the memory does not grow with the lattice; the first of equal
    scores wins, as in :func:`best_candidate`.

    Parameters
    ----------
    objective : callable
        Candidates ``(..., C, 2)`` to scores ``(..., C)`` (larger is better).
    centre : ndarray, shape (..., 2)
    spacing : ndarray, shape (...)
        Metres.
    half_points : ndarray of int, shape (...)
    block : int
        Candidates of the batch scored at once.

    Returns
    -------
    best : ndarray, shape (..., 2)
    score : ndarray, shape (...)
    """
    n = int(np.max(half_points, initial=0))
    k = np.arange(-n, n + 1.0)
    kx, ky = np.meshgrid(k, k, indexing="ij")
    steps = np.stack([kx.ravel(), ky.ravel()], axis=-1)                    # (G, 2)
    batch = centre.shape[:-1]
    size = max(1, block // max(int(np.prod(batch, dtype=int)), 1))
    best = np.broadcast_to(centre, batch + (2,)).copy()
    score = np.full(batch, -np.inf)
    for start in range(0, len(steps), size):
        part = steps[start:start + size]
        cand = centre[..., None, :] + spacing[..., None, None] * part
        ok = np.max(np.abs(part), axis=-1) <= half_points[..., None]
        pick, top = _first_best(np.where(ok, objective(cand), -np.inf), cand)
        better = top > score
        best = np.where(better[..., None], pick, best)
        score = np.where(better, top, score)
    return best, score


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
    return _first_best(np.where(ok, objective(candidates), -np.inf), candidates)[0]


def _first_best(score: np.ndarray, candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The first candidate of the highest score ``(..., 2)``, and that score ``(...)``."""
    best = np.argmax(score, axis=-1)
    return (np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :],
            np.take_along_axis(score, best[..., None], axis=-1)[..., 0])


def search(objective: Objective, centres: np.ndarray, radii: np.ndarray, valid: np.ndarray,
           coarse_half_width_m: float | None, coarse_points: int = 21,
           refine: tuple[tuple[float | np.ndarray, int], ...] = ((0.5, 21), (0.05, 21)),
           centre: np.ndarray | None = None, circles: np.ndarray | None = None,
           lattice: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
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
    coarse_half_width_m : float or None
        Half width of the coarse grid (None with ``lattice``).
    coarse_points : int
        Points per axis of the coarse grid.
    refine : tuple of (half_width, points)
        Successive local grids around the best candidate (a half width may be an array
        per problem, as :func:`derived_schedule` gives).
    centre : ndarray, shape (..., 2), optional
        Centre of a local search (broadcast against the batch axes); default: a global
        search around the centroid of the points heard.
    circles : ndarray of bool, shape (..., L), optional
        Which valid rows are range circles whose intersections are candidates (the
        others, e.g. bearings, only place the grid); default: every valid row.
    lattice : (ndarray (...), ndarray of int (...)), optional
        Instead of the square of ``coarse_points`` (global search only): a coarse grid
        per problem around the centroid, its spacing and its points on either side
        (:func:`best_on_lattice`, as :func:`derived_schedule` gives); the intersections
        win ties with it.

    Returns
    -------
    ndarray, shape (..., 2)
        The best candidate found.
    """
    pts, ok = circle_intersections(centres, radii, valid if circles is None else circles)
    if centre is None:
        centroid = centroid_of(centres, valid)
    else:
        centroid = np.broadcast_to(np.asarray(centre, dtype=float), pts.shape[:-2] + (2,))
        near = np.all(np.abs(pts - centroid[..., None, :]) <= coarse_half_width_m, axis=-1)
        ok = ok & near
    if lattice is None:
        grid = centroid[..., None, :] + local_grid(coarse_half_width_m, coarse_points)
        cand = np.concatenate([pts, grid], axis=-2)
        cand_ok = np.concatenate([ok, np.ones(grid.shape[:-1], dtype=bool)], axis=-1)
        x = best_candidate(objective, cand, cand_ok)
    else:
        x, score = best_on_lattice(objective, centroid, *lattice)
        if pts.shape[-2]:
            pick, top = _first_best(np.where(ok, objective(pts), -np.inf), pts)
            x = np.where((top >= score)[..., None], pick, x)
    for half, n in refine:
        local = x[..., None, :] + local_grid(half, n)
        x = best_candidate(objective, local, np.ones(local.shape[:-1], dtype=bool))
    return x
