"""Rigid (Procrustes) alignment of estimated node constellations to the truth.

Ranges between nodes fix a network only up to a rigid motion; the error left after the
best translation and rotation measures the estimated *shape* alone.
"""

from __future__ import annotations

import numpy as np


def rigid_aligned_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per-node error ``(..., K)`` after the least-squares rotation + translation per batch.

    Parameters
    ----------
    estimate, truth : (..., K, d) arrays
        The rotation is proper (no reflection).

    Returns
    -------
    (..., K) array
        Error of every node after the alignment.
    """
    a = estimate - estimate.mean(axis=-2, keepdims=True)
    b = truth - truth.mean(axis=-2, keepdims=True)
    U, _, Vt = np.linalg.svd(np.einsum("...ki,...kj->...ij", a, b))
    d = np.sign(np.linalg.det(U @ Vt))
    U[..., :, -1] *= d[..., None]
    return np.linalg.norm(np.einsum("...ki,...ij->...kj", a, U @ Vt) - b, axis=-1)
