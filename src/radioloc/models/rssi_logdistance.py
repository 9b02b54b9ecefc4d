"""Log-distance Gaussian RSSI model, the parametric peer of the trapezoid model (paper 003).

``rssi ~ N(a - 10 n log10(max(d, d_ref)), s^2)`` on the same 0..100 (or dBm) scale, fitted
by least squares. :meth:`LogDistanceGaussian.likelihood` has peak value 1 like the trapezoid
``L(dist | rssi)``, so either model plugs into the grid filter.

Per-device offset (label-free): phones read the same field at different levels (chipset,
antenna, case). :func:`device_offset` estimates a device's offset ``delta`` from its readings
alone as the shift that best aligns their distribution with the model's reference
distribution (the calibration readings): the minimiser of the Wasserstein-1 distance
``int_0^1 |Q_dev(u) - delta - Q_ref(u)| du`` between the shifted readings and the reference,
which is the median over ``u`` of the quantile differences ``Q_dev(u) - Q_ref(u)``. The
readings are then corrected to ``rssi - delta`` before the model is applied. It assumes that
the device saw distances distributed as in the calibration (no distance label is used).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import (
    as_float_array,
    check_positive,
    check_real,
    check_shapes,
)


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
    reference : ndarray, shape (Q,), optional
        Quantiles of the calibration readings at :data:`OFFSET_QUANTILES` (set by
        :meth:`fit`): the reference distribution of :meth:`device_offset`.
    """

    a: float
    n: float
    s: float
    d_ref_m: float = 0.1
    reference: np.ndarray | None = field(default=None, compare=False, repr=False)

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
        return cls(float(coef[0]), float(coef[1]), max(s, 1e-6), d_ref_m,
                   np.quantile(r, OFFSET_QUANTILES))

    def device_offset(self, rssi) -> float:
        """Label-free offset of one device's readings against the calibration readings
        (:func:`device_offset`); subtract it from the device's readings.

        Parameters
        ----------
        rssi : array_like
            All readings of the device (any shape, NaN ignored).

        Returns
        -------
        float
            The offset ``delta`` (RSSI units).

        Raises
        ------
        InputError
            The model has no reference distribution (not made by :meth:`fit`), or no reading.
        """
        if self.reference is None:
            raise InputError("device_offset: this model has no reference distribution of "
                             "calibration readings (fit it with LogDistanceGaussian.fit)")
        return device_offset(rssi, reference_quantiles=self.reference)

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
        check_shapes("dist", d.shape, "rssi", r.shape)
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
        r = as_float_array(rssi, "rssi")
        d = as_float_array(dist, "dist", nonnegative=True)
        check_shapes("rssi", r.shape, "dist", d.shape)
        z = (r - self.mean(d)) / self.s
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


#: quantile levels at which device and reference distributions are compared
OFFSET_QUANTILES = np.linspace(0.01, 0.99, 99)


def device_offset(rssi, reference=None, *, reference_weights=None,
                  reference_quantiles=None) -> float:
    """Shift ``delta`` minimising the Wasserstein-1 distance between ``rssi - delta`` and a
    reference distribution: the median over ``u`` of ``Q_rssi(u) - Q_ref(u)`` at the levels
    :data:`OFFSET_QUANTILES` (no distance labels used).

    Parameters
    ----------
    rssi : array_like
        The device's readings (NaN ignored).
    reference : array_like, optional
        Reference readings (e.g. the calibration's), or the values of a histogram with
        ``reference_weights``.
    reference_weights : array_like, optional
        Counts of each ``reference`` value (a histogram such as a trapezoid model's
        ``count``).
    reference_quantiles : array_like, optional
        The reference's quantiles at :data:`OFFSET_QUANTILES` (instead of ``reference``).

    Returns
    -------
    float
        ``delta``, in the readings' unit.

    Raises
    ------
    InputError
        No finite reading, or no reference.
    """
    x = np.asarray(rssi, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if x.size == 0:
        raise InputError("rssi: no finite reading to estimate a device offset from")
    if reference_quantiles is not None:
        q_ref = as_float_array(reference_quantiles, "reference_quantiles", ndim=1,
                               last_dim=OFFSET_QUANTILES.size)
    else:
        if reference is None:
            raise InputError("reference: give reference readings or reference_quantiles")
        ref = as_float_array(reference, "reference", ndim=1)
        if reference_weights is None:
            if ref.size == 0:
                raise InputError("reference: empty")
            q_ref = np.quantile(ref, OFFSET_QUANTILES)
        else:
            w = as_float_array(reference_weights, "reference_weights", ndim=1,
                               nonnegative=True)
            if w.shape != ref.shape or w.sum() <= 0:
                raise InputError("reference_weights: one non-negative count per reference "
                                 "value, with a positive total")
            order = np.argsort(ref, kind="stable")
            cdf = np.cumsum(w[order]) / w.sum()
            pick = np.minimum(np.searchsorted(cdf, OFFSET_QUANTILES), ref.size - 1)
            q_ref = ref[order][pick]
    return float(np.median(np.quantile(x, OFFSET_QUANTILES) - q_ref))
