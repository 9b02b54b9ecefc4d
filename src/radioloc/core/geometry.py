"""Geometry helpers on batched position arrays ``(..., d)``."""

from __future__ import annotations

import numpy as np


def distances(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Euclidean distance between broadcastable position arrays ``(..., d)``."""
    return np.sqrt(np.sum((np.asarray(a) - np.asarray(b)) ** 2, axis=-1))


def pairwise_distances(points: np.ndarray) -> np.ndarray:
    """Distances between all points of each batch: ``(..., K, d) -> (..., K, K)``."""
    p = np.asarray(points)
    return distances(p[..., :, None, :], p[..., None, :, :])


def unit_vectors(from_pts: np.ndarray, to_pts: np.ndarray, eps: float = 1e-12) -> np.ndarray:
    """Unit vectors from ``from_pts`` towards ``to_pts`` (``(..., d)``); zero where they coincide."""
    diff = np.asarray(to_pts) - np.asarray(from_pts)
    norm = np.sqrt(np.sum(diff**2, axis=-1, keepdims=True))
    return np.where(norm > eps, diff / np.maximum(norm, eps), 0.0)


def polygon_area(vertices: np.ndarray) -> float:
    """Signed area of a simple polygon ``(n, 2)`` by the shoelace formula."""
    v = np.asarray(vertices, dtype=float)
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def triangle_area_spread(points: np.ndarray) -> np.ndarray:
    """A collinearity measure of a point set ``(..., n, 2)``: the smallest singular value of
    the centred coordinates (zero when all points lie on a line)."""
    p = np.asarray(points, dtype=float)
    c = p - p.mean(axis=-2, keepdims=True)
    return np.linalg.svd(c, compute_uv=False)[..., -1]


def segment_intersections(p0: np.ndarray, p1: np.ndarray, a: np.ndarray,
                          b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Intersection parameters of the 2-D segments ``p0 -> p1`` and ``a -> b``, broadcast.

    Solves ``p0 + u (p1 - p0) = a + t (b - a)`` with 2-D cross products: with
    ``r = p1 - p0``, ``s = b - a``, ``q = a - p0`` and ``den = r x s``,
    ``u = (q x s) / den`` and ``t = (q x r) / den``. The segments cross where
    ``0 <= u <= 1`` and ``0 <= t <= 1`` (strict inequalities exclude touching endpoints).

    Parameters
    ----------
    p0, p1 : array_like, shape (..., 2)
        Start and end points of the first segments.
    a, b : array_like, shape (..., 2)
        Start and end points of the second segments (broadcast against the first).

    Returns
    -------
    u : ndarray, shape (...)
        Parameter of the intersection along ``p0 -> p1``; non-finite (inf or NaN) where
        the segments are parallel (``den = 0``).
    t : ndarray, shape (...)
        Parameter of the intersection along ``a -> b``; non-finite where parallel.
    """
    p0, p1, a, b = (np.asarray(v, dtype=float) for v in (p0, p1, a, b))
    r = p1 - p0
    s = b - a
    q = a - p0
    den = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = (q[..., 0] * s[..., 1] - q[..., 1] * s[..., 0]) / den
        t = (q[..., 0] * r[..., 1] - q[..., 1] * r[..., 0]) / den
    return u, t


def segments_cross(p0: np.ndarray, p1: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether the 2-D segments ``p0 -> p1`` and ``a -> b`` cross properly, broadcast.

    A proper crossing has both intersection parameters of :func:`segment_intersections`
    strictly inside ``(0, 1)``: touching at an endpoint and parallel or collinear segments
    do not count.

    Parameters
    ----------
    p0, p1 : array_like, shape (..., 2)
        Start and end points of the first segments.
    a, b : array_like, shape (..., 2)
        Start and end points of the second segments (broadcast against the first).

    Returns
    -------
    ndarray of bool, shape (...)
        True where the segments cross.
    """
    u, t = segment_intersections(p0, p1, a, b)
    return (u > 0) & (u < 1) & (t > 0) & (t < 1)
