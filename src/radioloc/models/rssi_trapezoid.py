"""Data-driven RSSI -> distance likelihood of Zickler & Veloso (paper 003, Sect. III).

One symmetric trapezoid ``D_i = <mu, tau, sigma>`` per integer RSSI value ``i`` in 0..100
(Sect. III-A, Fig. 1)::

    L(dist | rssi) = D_rssi(dist) = max(0, sigma - max(0, |dist - mu| - tau)) / sigma

fitted from (RSSI, true distance) pairs (Sect. III-B) and post-processed by a sliding-window
smoothing that fills gaps and enforces monotone boundaries (Sect. III-C).

RSSI here is the paper's unitless integer 0..100. Data in dBm is mapped with the explicit
affine map :func:`dbm_to_rssi100` (``rssi = round(100 (dBm - dbm_min) / (dbm_max - dbm_min))``,
default ``dbm_min = -110``, ``dbm_max = -10``, i.e. ``rssi = dBm + 110``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array, check_positive, check_shapes
from radioloc.models.rssi_logdistance import device_offset as _device_offset

RSSI_LEVELS = 101
"""Number of RSSI values (0..100 inclusive)."""

DBM_MIN = -110.0
DBM_MAX = -10.0


def dbm_to_rssi100(dbm, dbm_min: float = DBM_MIN, dbm_max: float = DBM_MAX) -> np.ndarray:
    """Affine map of dBm to the integer 0..100 RSSI scale.

    ``rssi = round(100 * (dBm - dbm_min) / (dbm_max - dbm_min))``, clipped to 0..100
    (readings below ``dbm_min`` read 0 and above ``dbm_max`` read 100, as a saturating
    receiver would). With the defaults this is ``rssi = dBm + 110``. This is the sensor
    quantiser: the radio of the tethering world (``radioloc.sim.tether.read_rssi``) applies
    it to the channel's dBm.

    Parameters
    ----------
    dbm : array_like
        Received power, dBm.
    dbm_min, dbm_max : float
        Powers that map to RSSI 0 and 100.

    Returns
    -------
    ndarray of int64
        RSSI values in 0..100.
    """
    dbm = as_float_array(dbm, "dbm")
    if not dbm_max > dbm_min:
        raise InputError(f"dbm_max: must exceed dbm_min, got {dbm_min} .. {dbm_max}")
    scaled = np.rint(100.0 * (dbm - dbm_min) / (dbm_max - dbm_min))
    return np.clip(scaled, 0, RSSI_LEVELS - 1).astype(np.int64)


def as_rssi(rssi, name: str = "rssi") -> np.ndarray:
    """Validate integer RSSI values in 0..100 and return them as int64.

    Parameters
    ----------
    rssi : array_like
        Values that must be integers in 0..100.
    name : str
        Argument name for the error message.

    Returns
    -------
    ndarray of int64
    """
    arr = as_float_array(rssi, name)
    bad = (arr < 0) | (arr > RSSI_LEVELS - 1) | (arr != np.rint(arr))
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0])
        raise InputError(f"{name}: value {arr[idx]} at index {idx} is not an integer in 0..100 "
                         "(map dBm with dbm_to_rssi100 first)")
    return arr.astype(np.int64)


@dataclass(frozen=True)
class TrapezoidModel:
    """Per-RSSI trapezoids ``<mu, tau, sigma>`` (arrays of length 101, metres).

    Rows are indexed by the RSSI value.

    Parameters
    ----------
    mu, tau, sigma : array_like, shape (101,)
        Centre, half-width of the plateau and width of each flank, metres.
    count : array_like, shape (101,)
        Calibration pairs behind each row (0 for a row filled by smoothing).
    """

    mu: np.ndarray
    tau: np.ndarray
    sigma: np.ndarray
    count: np.ndarray

    def __post_init__(self):
        for name in ("mu", "tau", "sigma", "count"):
            arr = as_float_array(getattr(self, name), name, allow_nan=True)
            if arr.shape != (RSSI_LEVELS,):
                raise InputError(f"{name}: expected {RSSI_LEVELS} rows (RSSI 0..100), got shape {arr.shape}")
            object.__setattr__(self, name, arr)
        if np.any(~np.isfinite(self.mu) | ~np.isfinite(self.tau) | ~np.isfinite(self.sigma)):
            i = int(np.flatnonzero(~np.isfinite(self.mu + self.tau + self.sigma))[0])
            raise InputError(f"mu/tau/sigma: row {i} is not finite (unsmoothed gap?); "
                             "call smooth() to fill gaps")
        if np.any(~np.isfinite(self.count) | (self.count < 0)):
            i = int(np.flatnonzero(~np.isfinite(self.count) | (self.count < 0))[0])
            raise InputError(f"count: row {i} is {self.count[i]}; need a finite count >= 0")
        if np.any(self.sigma <= 0) or np.any(self.tau < 0):
            i = int(np.flatnonzero((self.sigma <= 0) | (self.tau < 0))[0])
            raise InputError(f"sigma/tau: row {i} has sigma={self.sigma[i]}, tau={self.tau[i]}; "
                             "need sigma > 0 and tau >= 0")

    @property
    def lower(self) -> np.ndarray:
        """Smallest modelled distance of each row, ``mu - tau - sigma``."""
        return self.mu - self.tau - self.sigma

    @property
    def upper(self) -> np.ndarray:
        """Largest modelled distance of each row, ``mu + tau + sigma``."""
        return self.mu + self.tau + self.sigma

    def likelihood(self, dist, rssi) -> np.ndarray:
        """``L(dist | rssi)`` of Sect. III-A (peak value 1), broadcast over both arguments.

        Parameters
        ----------
        dist : array_like
            Distances in metres (any shape broadcastable with ``rssi``).
        rssi : array_like of int
            RSSI values in 0..100.

        Returns
        -------
        ndarray
            Likelihood in [0, 1] (broadcast shape).
        """
        d = as_float_array(dist, "dist", nonnegative=True)
        i = as_rssi(rssi)
        check_shapes("dist", d.shape, "rssi", np.shape(i))
        return trapezoid(d, self.mu[i], self.tau[i], self.sigma[i])

    def density(self, dist, rssi) -> np.ndarray:
        """``L(dist | rssi)`` divided by the trapezoid's area ``2 tau + sigma``.

        Parameters
        ----------
        dist : array_like
            Distances, metres.
        rssi : array_like of int
            RSSI values in 0..100.

        Returns
        -------
        ndarray
            A probability density of the distance on the real line, 1/m.
        """
        i = as_rssi(rssi)
        return self.likelihood(dist, i) / (2.0 * self.tau[i] + self.sigma[i])

    def logpdf(self, dist, rssi) -> np.ndarray:
        """Log of :meth:`density`: ``-inf`` outside the trapezoid.

        Parameters
        ----------
        dist : array_like
            Distances, metres.
        rssi : array_like of int
            RSSI values in 0..100.

        Returns
        -------
        ndarray
        """
        with np.errstate(divide="ignore"):
            return np.log(self.density(dist, rssi))

    def sample(self, rssi, rng: np.random.Generator) -> np.ndarray:
        """Draw distances from :meth:`density` given each reading.

        The trapezoid with plateau half-width ``tau`` and flanks ``sigma`` is the sum of
        two centred uniforms of widths ``2 tau + sigma`` and ``sigma``.

        Parameters
        ----------
        rssi : array_like of int
            RSSI values in 0..100.
        rng : numpy.random.Generator

        Returns
        -------
        ndarray
            Distances (metres, same shape as ``rssi``; a row whose trapezoid reaches
            below zero can give a negative draw, as its density does).
        """
        i = as_rssi(rssi)
        tau, sigma = self.tau[i], self.sigma[i]
        wide = (rng.random(np.shape(i)) - 0.5) * (2.0 * tau + sigma)
        narrow = (rng.random(np.shape(i)) - 0.5) * sigma
        return self.mu[i] + wide + narrow

    def device_offset(self, rssi) -> int:
        """Label-free offset of one device's readings (0..100 scale) against the
        calibration readings, whose histogram is ``count``: the Wasserstein-1 aligning
        shift of :func:`radioloc.models.rssi_logdistance.device_offset`, rounded to a whole
        RSSI step. Correct the readings with :meth:`correct`.

        Parameters
        ----------
        rssi : array_like
            All readings of the device (0..100 scale; NaN ignored).

        Returns
        -------
        int
            The offset ``delta`` (RSSI steps; one step is 1 dB with the default map).

        Raises
        ------
        InputError
            The model holds no calibration counts (``count`` all zero).
        """
        if not np.any(self.count > 0):
            raise InputError("device_offset: this model has no calibration counts (count is "
                             "all zero), so no reference distribution")
        levels = np.arange(RSSI_LEVELS, dtype=float)
        return int(np.rint(_device_offset(rssi, levels, reference_weights=self.count)))

    @staticmethod
    def correct(rssi, offset: float) -> np.ndarray:
        """Readings corrected by a device offset: ``rssi - offset`` rounded and clipped to
        0..100.

        Parameters
        ----------
        rssi : array_like of int
            Readings in 0..100.
        offset : float
            The device's offset (:meth:`device_offset`).

        Returns
        -------
        ndarray of int64
        """
        r = as_rssi(rssi)
        return np.clip(np.rint(r - float(offset)), 0, RSSI_LEVELS - 1).astype(np.int64)

    def to_dict(self) -> dict:
        """The model as a JSON-ready dict.

        Returns
        -------
        dict
            Keys ``format``, ``rssi_levels``, ``mu``, ``tau``, ``sigma``, ``count``.
        """
        return {"format": "radioloc-rssi-trapezoid-v1", "rssi_levels": RSSI_LEVELS,
                "mu": self.mu.tolist(), "tau": self.tau.tolist(),
                "sigma": self.sigma.tolist(), "count": self.count.astype(int).tolist()}

    def save(self, path: Path | str) -> Path:
        """Write the model as JSON (keys ``mu``, ``tau``, ``sigma``, ``count``: 101 numbers each).

        Parameters
        ----------
        path : path-like
            File to write.

        Returns
        -------
        pathlib.Path
            The path written.
        """
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1))
        return path

    @classmethod
    def load(cls, path: Path | str) -> "TrapezoidModel":
        """Read a model written by :meth:`save`.

        Parameters
        ----------
        path : path-like
            JSON file.

        Returns
        -------
        TrapezoidModel
        """
        from radioloc.core.textfile import read_json_object

        data = read_json_object(path, "model")
        missing = [k for k in ("mu", "tau", "sigma") if k not in data]
        if missing:
            raise InputError(f"model file {path}: missing key(s) {', '.join(missing)}")
        count = data.get("count", np.zeros(RSSI_LEVELS))
        try:
            return cls(data["mu"], data["tau"], data["sigma"], count)
        except InputError as exc:
            raise InputError(f"model file {path}: {exc}") from None


def trapezoid(dist, mu, tau, sigma) -> np.ndarray:
    """The symmetric trapezoid of Fig. 1: ``max(0, sigma - max(0, |d - mu| - tau)) / sigma``.

    Parameters
    ----------
    dist, mu, tau, sigma : array_like
        Distance and trapezoid parameters, metres (broadcast).

    Returns
    -------
    ndarray
        Values in [0, 1].
    """
    return np.maximum(0.0, sigma - np.maximum(0.0, np.abs(dist - mu) - tau)) / sigma


def fit_raw(rssi, dist, tau_min: float, sigma_min: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per-row statistics of Sect. III-B, NaN for RSSI values with no pair.

    ``mu = (min + max) / 2``, ``tau = max(tau_min, (max - min) / 2)``,
    ``sigma = max(sigma_min, std)`` over the distances recorded with each RSSI value
    (population standard deviation).

    Parameters
    ----------
    rssi : array_like of int, shape (N,)
        RSSI values in 0..100.
    dist : array_like, shape (N,)
        True distances, metres.
    tau_min, sigma_min : float
        Lower bounds of ``tau`` and ``sigma``, metres.

    Returns
    -------
    mu, tau, sigma, count : ndarray, shape (101,)
    """
    i = as_rssi(rssi)
    d = as_float_array(dist, "dist", nonnegative=True)
    if i.shape != d.shape or i.ndim != 1:
        raise InputError(f"rssi/dist: expected two 1-D arrays of equal length, got {i.shape} and {d.shape}")
    check_positive(tau_min, "tau_min", allow_zero=True)
    check_positive(sigma_min, "sigma_min")
    count = np.bincount(i, minlength=RSSI_LEVELS).astype(float)
    dmin = np.full(RSSI_LEVELS, np.inf)
    dmax = np.full(RSSI_LEVELS, -np.inf)
    np.minimum.at(dmin, i, d)
    np.maximum.at(dmax, i, d)
    s1 = np.bincount(i, weights=d, minlength=RSSI_LEVELS)
    s2 = np.bincount(i, weights=d * d, minlength=RSSI_LEVELS)
    have = count > 0
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = s1 / count
        std = np.sqrt(np.maximum(s2 / count - mean**2, 0.0))
        mu = np.where(have, 0.5 * (dmin + dmax), np.nan)
        tau = np.where(have, np.maximum(tau_min, 0.5 * (dmax - dmin)), np.nan)
    sigma = np.where(have, np.maximum(sigma_min, std), np.nan)
    return mu, tau, sigma, count


def smooth(mu, tau, sigma, count, *, window: int, tau_min: float, sigma_min: float) -> TrapezoidModel:
    """Post-processing of Sect. III-C: sliding-window average, gap filling, monotone boundaries.

    1. Each row's ``mu``, ``tau``, ``sigma`` become the unweighted mean over the rows with
       data within ``+-window`` RSSI values (a convolution with a box of ``2 window + 1`` rows).
    2. Rows with no data in their window are filled by linear interpolation over the RSSI
       axis (constant extrapolation beyond the first/last row with data).
    3. Monotonicity: the lower boundary ``mu - tau - sigma`` and the upper boundary
       ``mu + tau + sigma`` are replaced by their running maximum from RSSI 100 downwards, so
       neither decreases as RSSI decreases.
    4. ``<mu, tau, sigma>`` are rebuilt from the boundaries: ``mu`` is their midpoint,
       ``sigma`` the smoothed sigma clipped to ``[sigma_min, half_width - tau_min]`` and
       ``tau = half_width - sigma``. The boundaries of step 3 are kept exactly.

    The paper names the operations but not their order or window; this is our choice.

    Parameters
    ----------
    mu, tau, sigma, count : array_like, shape (101,)
        Raw rows of :func:`fit_raw` (NaN where a row has no pair).
    window : int
        Half-width of the sliding window, RSSI rows.
    tau_min, sigma_min : float
        Lower bounds of ``tau`` and ``sigma``, metres.

    Returns
    -------
    TrapezoidModel
    """
    if int(window) != window or window < 0:
        raise InputError(f"window: expected a non-negative integer, got {window}")
    mu, tau, sigma = (np.asarray(a, float) for a in (mu, tau, sigma))
    have = np.isfinite(mu) & np.isfinite(tau) & np.isfinite(sigma)
    if not np.any(have):
        raise InputError("rssi: no calibration pair at all; cannot build a model")
    box = np.ones(2 * int(window) + 1)
    n = np.convolve(have.astype(float), box, mode="same")
    params = []
    for a in (mu, tau, sigma):
        s = np.convolve(np.where(have, a, 0.0), box, mode="same")
        with np.errstate(invalid="ignore", divide="ignore"):
            avg = s / n
        ok = n > 0
        rows = np.arange(RSSI_LEVELS)
        params.append(np.interp(rows, rows[ok], avg[ok]))
    mu_s, tau_s, sigma_s = params
    lo = np.maximum.accumulate((mu_s - tau_s - sigma_s)[::-1])[::-1]
    hi = np.maximum.accumulate((mu_s + tau_s + sigma_s)[::-1])[::-1]
    half = 0.5 * (hi - lo)
    sig = np.clip(sigma_s, sigma_min, np.maximum(half - tau_min, sigma_min))
    return TrapezoidModel(mu=0.5 * (lo + hi), tau=np.maximum(half - sig, 0.0), sigma=sig,
                          count=np.asarray(count, float))


def fit_trapezoid_model(rssi, dist, *, tau_min: float = 0.5, sigma_min: float = 0.5,
                        window: int = 2) -> TrapezoidModel:
    """Fit (Sect. III-B) and smooth (Sect. III-C) the model from (RSSI, distance) pairs.

    Parameters
    ----------
    rssi : array_like of int, shape (N,)
        RSSI values in 0..100.
    dist : array_like, shape (N,)
        True distances, metres.
    tau_min, sigma_min : float
        Lower bounds of ``tau`` and ``sigma``, metres.
    window : int
        Smoothing half-width, RSSI rows.

    Returns
    -------
    TrapezoidModel
    """
    mu, tau, sigma, count = fit_raw(rssi, dist, tau_min, sigma_min)
    return smooth(mu, tau, sigma, count, window=window, tau_min=tau_min, sigma_min=sigma_min)
