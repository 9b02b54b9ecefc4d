"""Cramer-Rao bound of a position from ranges to known anchors."""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import GeometryError
from radioloc.core.geometry import unit_vectors
from radioloc.core.renamed import Renamed, renamed_keywords

_RANGE_VARIANCE = {"range_variance": Renamed("std_m", variance=True)}
_OLD_POSITIONAL = ("range_variance", "weights")


@renamed_keywords(_RANGE_VARIANCE, positional=_OLD_POSITIONAL)
def range_fisher_information(position: np.ndarray, anchors: np.ndarray, *,
                             std_m: np.ndarray | float,
                             weights: np.ndarray | None = None) -> np.ndarray:
    """Fisher information of a position from Gaussian ranges to anchors.

    ``J = sum_i w_i u_i u_i^T / std_i^2`` with ``u_i`` the unit vector from anchor ``i`` to
    the position.

    Parameters
    ----------
    position : (..., d) array
    anchors : (..., M, d) array (broadcast against ``position``)
    std_m : float or (..., M) array
        Range noise standard deviation, metres, per anchor if an array. The old third
        argument ``range_variance`` (m^2) still works with a ``FutureWarning``.
    weights : (..., M) array of 0/1, optional
        Which ranges exist.

    Returns
    -------
    (..., d, d) array
    """
    u = unit_vectors(np.asarray(anchors)[...], np.asarray(position)[..., None, :])
    w = 1.0 / np.asarray(std_m, dtype=float) ** 2
    w = np.broadcast_to(w, u.shape[:-1])
    if weights is not None:
        w = w * weights
    return np.einsum("...m,...mi,...mj->...ij", w, u, u)


@renamed_keywords(_RANGE_VARIANCE, positional=_OLD_POSITIONAL)
def range_crb(position: np.ndarray, anchors: np.ndarray, *, std_m: np.ndarray | float,
              weights: np.ndarray | None = None) -> np.ndarray:
    """Cramer-Rao bound ``(..., d, d)``: the inverse of :func:`range_fisher_information`.

    Parameters
    ----------
    position : (..., d) array
        True positions, metres.
    anchors : (..., M, d) array
        Anchor positions (broadcast against ``position``).
    std_m : float or (..., M) array
        Range noise standard deviation, metres, per anchor if an array (the old
        ``range_variance``, m^2, still works with a ``FutureWarning``).
    weights : (..., M) array of 0/1, optional
        Which ranges exist.

    Returns
    -------
    (..., d, d) array
        The bound on the position covariance, m^2.

    Raises
    ------
    GeometryError
        If the information is singular for some batch entry (collinear anchors, too few).
    """
    info = range_fisher_information(position, anchors, std_m=std_m, weights=weights)
    cond = np.linalg.cond(info)
    if not np.all(np.isfinite(cond) & (cond < 1e12)):
        idx = tuple(int(i) for i in np.argwhere(~(np.isfinite(cond) & (cond < 1e12)))[0])
        raise GeometryError(f"position {idx}: Fisher information is singular "
                            "(collinear or too few anchors)")
    return np.linalg.inv(info)
