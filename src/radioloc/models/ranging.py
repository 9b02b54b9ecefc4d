"""Range measurement models and the geometry of a range.

Every range model has ``sample(true_ranges, rng)``, ``logpdf(measured, true_ranges)`` and
``moments()`` (mean and variance of the range error, what a Kalman filter uses);
:func:`range_geometry` gives the predicted range and its Jacobian for any of them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import check_positive

_LOG_2PI = float(np.log(2.0 * np.pi))

__all__ = ["GaussianRange", "range_geometry"]


def range_geometry(position: np.ndarray, anchors: np.ndarray, height_m: float | None = None,
                   min_distance_m: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Predicted ranges ``|x - a_m|`` and their Jacobian with respect to ``x``.

    Parameters
    ----------
    position : ndarray, shape (..., D)
        Positions ``(x, y[, z])``.
    anchors : ndarray, shape (..., M, D) or, with ``height_m``, (..., M, D + 1)
        Anchor positions (broadcast against ``position``'s batch axes).
    height_m : float, optional
        Known height of the node when ``position`` is 2-D and the anchors are 3-D: the
        range is ``sqrt(|xy - a_xy|^2 + (height_m - a_z)^2)`` and the Jacobian is taken
        over ``xy`` only.
    min_distance_m : float
        Distances are floored here so the Jacobian stays finite at an anchor.

    Returns
    -------
    ranges : ndarray, shape (..., M)
    jacobian : ndarray, shape (..., M, D)
        ``d|x - a_m| / dx``, the unit vectors from the anchors to ``x``.
    """
    x = np.asarray(position, dtype=float)
    a = np.asarray(anchors, dtype=float)
    D = x.shape[-1]
    if height_m is None:
        if a.shape[-1] != D:
            raise InputError(f"anchors: {a.shape[-1]} coordinates but positions have {D} "
                             "(give height_m for 2-D positions with 3-D anchors)")
        diff = x[..., None, :] - a
        dist = np.sqrt(np.sum(diff**2, axis=-1))
    else:
        if a.shape[-1] != D + 1:
            raise InputError(f"anchors: height_m needs {D + 1}-D anchors, got {a.shape[-1]}-D")
        diff = x[..., None, :] - a[..., :D]
        dz = float(height_m) - a[..., D]
        dist = np.sqrt(np.sum(diff**2, axis=-1) + dz**2)
    safe = np.maximum(dist, min_distance_m)
    return dist, diff / safe[..., None]


@dataclass(frozen=True)
class GaussianRange:
    """Range with additive zero-mean Gaussian error: ``r = d + N(0, std_m^2)``.

    Parameters
    ----------
    std_m : float
        Standard deviation of the range error in metres (> 0).
    """

    std_m: float

    def __post_init__(self) -> None:
        check_positive(self.std_m, "std_m")

    @property
    def variance(self) -> float:
        return self.std_m**2

    def moments(self) -> tuple[float, float]:
        """Mean and variance of the range error.

        Returns
        -------
        tuple of float
            ``(0, std_m^2)``.
        """
        return 0.0, self.variance

    def sample(self, true_ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Draw noisy ranges.

        Parameters
        ----------
        true_ranges : ndarray
            Distances, metres.
        rng : numpy.random.Generator

        Returns
        -------
        ndarray
            Ranges of the same shape.
        """
        d = np.asarray(true_ranges, dtype=float)
        return d + self.std_m * rng.standard_normal(d.shape)

    def logpdf(self, measured: np.ndarray, true_ranges: np.ndarray) -> np.ndarray:
        """Elementwise log-density of measured ranges.

        Parameters
        ----------
        measured : ndarray
        true_ranges : ndarray
            Broadcastable against ``measured``.

        Returns
        -------
        ndarray
        """
        z = (np.asarray(measured, dtype=float) - np.asarray(true_ranges, dtype=float)) / self.std_m
        return -0.5 * z**2 - np.log(self.std_m) - 0.5 * _LOG_2PI
