"""Log-distance Gaussian RSSI model, the parametric peer of the trapezoid model (paper 003).

``rssi ~ N(a - 10 n log10(max(d, d_ref)), s^2)`` on the same 0..100 (or dBm) scale, fitted
by least squares. :meth:`LogDistanceGaussian.likelihood` has peak value 1 like the trapezoid
``L(dist | rssi)``, so either model plugs into the grid filter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array, check_positive, check_real


@dataclass(frozen=True)
class LogDistanceGaussian:
    """Log-distance Gaussian RSSI model.

    Parameters
    ----------
    a : float
        Mean RSSI at 1 m.
    n : float
        Path-loss exponent.
    s : float
        Residual standard deviation (RSSI units).
    d_ref_m : float
        Distances below this read as ``d_ref_m``, metres.
    """

    a: float
    n: float
    s: float
    d_ref_m: float = 0.1

    def __post_init__(self) -> None:
        check_real(self.a, "a")
        check_real(self.n, "n")
        check_positive(self.s, "s")
        check_positive(self.d_ref_m, "d_ref_m")

    @classmethod
    def fit(cls, rssi, dist, d_ref_m: float = 0.1) -> "LogDistanceGaussian":
        """Least-squares fit of ``a`` and ``n``; ``s`` is the residual standard deviation.

        Parameters
        ----------
        rssi : array_like, shape (N,)
            Readings.
        dist : array_like, shape (N,)
            True distances, metres.
        d_ref_m : float
            Distance floor, metres.

        Returns
        -------
        LogDistanceGaussian
        """
        r = as_float_array(rssi, "rssi", ndim=1)
        d = as_float_array(dist, "dist", ndim=1, nonnegative=True)
        if r.shape != d.shape or r.size < 3:
            raise InputError(f"rssi/dist: need >= 3 pairs of equal length, got {r.shape}, {d.shape}")
        x = -10.0 * np.log10(np.maximum(d, d_ref_m))
        A = np.stack([np.ones_like(x), x], axis=1)
        coef, *_ = np.linalg.lstsq(A, r, rcond=None)
        s = float(np.std(r - A @ coef))
        return cls(float(coef[0]), float(coef[1]), max(s, 1e-6), d_ref_m)

    def mean(self, dist) -> np.ndarray:
        """Mean RSSI ``a - 10 n log10(max(d, d_ref))``.

        Parameters
        ----------
        dist : array_like
            Distances, metres.

        Returns
        -------
        ndarray
        """
        return self.a - 10.0 * self.n * np.log10(np.maximum(np.asarray(dist, float), self.d_ref_m))

    def likelihood(self, dist, rssi) -> np.ndarray:
        """``exp(-(rssi - mean(dist))^2 / (2 s^2))`` (peak 1), broadcast.

        Parameters
        ----------
        dist : array_like
            Distances, metres.
        rssi : array_like
            Readings.

        Returns
        -------
        ndarray
            Likelihood in (0, 1].
        """
        d = as_float_array(dist, "dist", nonnegative=True)
        r = as_float_array(rssi, "rssi")
        return np.exp(-0.5 * ((r - self.mean(d)) / self.s) ** 2)

    def logpdf(self, rssi, dist) -> np.ndarray:
        """Gaussian log-density of readings given distances.

        Parameters
        ----------
        rssi : array_like
            Readings.
        dist : array_like
            Distances, metres (broadcast against ``rssi``).

        Returns
        -------
        ndarray
        """
        z = (as_float_array(rssi, "rssi") - self.mean(as_float_array(dist, "dist",
                                                                     nonnegative=True))) / self.s
        return -0.5 * z * z - np.log(self.s) - 0.5 * np.log(2.0 * np.pi)

    def sample(self, dist, rng: np.random.Generator) -> np.ndarray:
        """Draw readings at the given distances.

        Parameters
        ----------
        dist : array_like
            Distances, metres.
        rng : numpy.random.Generator

        Returns
        -------
        ndarray
            Readings ``mean(dist) + s N(0, 1)``.
        """
        m = self.mean(as_float_array(dist, "dist", nonnegative=True))
        return m + self.s * rng.standard_normal(m.shape)
