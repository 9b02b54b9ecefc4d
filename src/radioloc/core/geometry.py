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
