"""Link gathering: pack the entries of a mask (who hears whom) to the front of an axis.

A batch of nodes hears a different set of neighbours each: a boolean mask ``(..., J)``
over all ``J`` candidate nodes. Estimators work on the links that exist, packed to a
common width ``L`` (the largest count in the batch, or a fixed width), with a ``valid``
flag for the padding. This is the one helper for that gather, used by the particle
filter, the peer-to-peer EKF baseline, the snapshot baselines and the GSIC tap refit.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import InputError

__all__ = ["pack_mask", "gather_packed", "scatter_packed"]


def pack_mask(mask: np.ndarray, width: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the True entries of ``mask``, packed to the front in their order.

    Parameters
    ----------
    mask : array_like of bool, shape (..., J)
        Which of the ``J`` entries exist (e.g. links in range, finite ranges).
    width : int, optional
        Packed width ``L``. Default: the largest number of True entries of any batch
        entry (0 for an empty batch). A smaller width keeps the first ``width`` entries.

    Returns
    -------
    index : ndarray of int64, shape (..., L)
        Positions along the last axis of ``mask``: the True ones first, in increasing
        order, then positions of False entries as padding (any index in range; use
        ``valid``).
    valid : ndarray of bool, shape (..., L)
        True where ``index`` points at a True entry.

    Examples
    --------
    >>> index, valid = pack_mask(np.array([[True, False, True], [False, True, False]]))
    >>> index.tolist(), valid.tolist()
    ([[0, 2], [1, 0]], [[True, True], [True, False]])
    """
    m = np.asarray(mask, dtype=bool)
    if m.ndim < 1:
        raise InputError(f"mask: expected at least one axis, got shape {m.shape}")
    order = np.argsort(~m, axis=-1, kind="stable")
    count = m.sum(axis=-1)
    if width is None:
        width = int(count.max()) if count.size else 0
    elif int(width) != width or width < 0:
        raise InputError(f"width: must be an integer >= 0, got {width!r}")
    index = order[..., : int(width)]
    valid = np.arange(index.shape[-1]) < count[..., None]
    return index, valid


def gather_packed(values: np.ndarray, index: np.ndarray, axis: int = -1) -> np.ndarray:
    """``values`` taken at the packed ``index`` along ``axis`` (the link axis).

    Parameters
    ----------
    values : ndarray, shape (..., J) or (..., J, D) with ``axis=-2``
        Per-candidate values (ranges, node positions).
    index : ndarray of int, shape (..., L)
        From :func:`pack_mask`.
    axis : int
        The candidate axis of ``values``: -1 for ``(..., J)``, -2 for ``(..., J, D)``.

    Returns
    -------
    ndarray, shape (..., L) or (..., L, D)
    """
    v = np.asarray(values)
    if axis == -1:
        return np.take_along_axis(v, index, axis=-1)
    if axis == -2:
        return np.take_along_axis(v, index[..., None], axis=-2)
    raise InputError(f"axis: must be -1 or -2, got {axis}")


def scatter_packed(packed: np.ndarray, index: np.ndarray, valid: np.ndarray,
                   size: int, fill=False) -> np.ndarray:
    """Inverse of :func:`gather_packed` on the last axis: packed values back to ``(..., J)``.

    Parameters
    ----------
    packed : ndarray, shape (..., L)
        Values of the packed links.
    index, valid : ndarray, shape (..., L)
        From :func:`pack_mask`.
    size : int
        ``J``, the unpacked width.
    fill : scalar
        Value of the entries no valid link points at.

    Returns
    -------
    ndarray, shape (..., J)
    """
    p = np.asarray(packed)
    out = np.full(p.shape[:-1] + (int(size),), fill, dtype=np.result_type(p, np.asarray(fill)))
    # padding slots point at absent entries; write the fill value there so they are no-ops
    np.put_along_axis(out, index, np.where(valid, p, fill), axis=-1)
    return out
