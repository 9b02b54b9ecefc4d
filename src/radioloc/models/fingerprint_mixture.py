"""RSS fingerprint model with shared position components and an explicit "not detected"
outcome: paper 004's mixture model (eq. (1)) made workable at WiFi scale.

Eq. (1) models each base station ``k`` by an axis-aligned mixture
``D^(k)(x, y, m) = sum_j w_j N(x) N(y) N(m)``; a WiFi fingerprint set has hundreds of
access points, each detected in a few percent of the scans, and a separate mixture per
access point leaves two questions open: what a station that is *not* detected says (eq. (2)
ignores it), and how to combine hundreds of conditioned densities without a product whose
component count explodes. This model answers both by letting every access point share the
same position components, the *reference places* of the calibration (distinct
``(zone, x, y)`` rows, a zone being e.g. a building and a floor), and giving each place a
detection probability per access point:

- place ``j``: position ``N(x; x_j, s_j^2) N(y; y_j, s_j^2)``, prior weight ``pi_j``
  (uniform: ``1 / K``);
- access point ``k`` at place ``j``: detected with probability ``p_jk``, and then reads
  ``m ~ N(mu_jk, v_jk)``; not detected with probability ``1 - p_jk``.

So ``D^(k)(x, y, m) = sum_j pi_j N(x) N(y) q_jk(m)``, eq. (1) with the signal factor
``N(m)`` extended by the "not detected" outcome, and the joint density of a whole scan
``m = (m_1 .. m_S)`` given place ``j`` is the product over the access points (independent
given the place, as paper 004 assumes between base stations, Sect. 3.1)::

    log L_j(m) = sum_k  d_k [log p_jk - log(2 pi v_jk)/2 - (m_k - mu_jk)^2 / (2 v_jk)]
                        + (1 - d_k) log(1 - p_jk)

with ``d_k = 1`` where access point ``k`` is detected. Expanding the square, this is one
matrix product of the scan features ``[d, d m, d m^2]`` ``(N, 3S)`` with a coefficient
matrix ``(3S, K)`` plus a constant per place (:meth:`FingerprintMixture.loglik`): no loop
over access points or places. The position density given the scan is the mixture
``sum_j w_j N(x; x_j) N(y; y_j)`` with ``w_j ∝ pi_j exp(log L_j / T)``: the place
components re-weighted by the scan, as the conditioning of eq. (1) in Sect. 3.2 re-weights
components. ``T >= 1`` (``temperature``) tempers the product over access points, whose
independence given the place is only approximate (T = 1 is the plain product).

This differs from eq. (2) as written in two labelled ways: stations not detected enter
through ``1 - p_jk`` instead of being ignored, and the fusion is the product of the
per-station likelihoods ``q_jk(m_k)`` over one shared set of place components (the Bayes
posterior of the place), where eq. (2) multiplies per-station conditional densities (which
counts the position prior once per station and multiplies component counts).

Fit (:meth:`FingerprintMixture.fit`), per place ``j`` with ``n_j`` scans and access point
``k`` detected ``c_jk`` times with sample mean ``mbar_jk`` and variance ``s2_jk``:

- ``p_jk = (c_jk + alpha) / (n_j + 2 alpha)`` (``alpha`` pseudo-counts, so that an access
  point never seen at a place is not impossible there);
- ``mu_jk = (c_jk mbar_jk + lam mu_k) / (c_jk + lam)``, shrunk towards the access point's
  mean ``mu_k`` over all scans by ``lam`` pseudo-samples;
- ``v_jk = max(v_min, (c_jk s2_jk + lam max(v_k, v_min)) / (c_jk + lam))``, shrunk towards
  the access point's pooled *within-place* variance
  ``v_k = sum_j c_jk s2_jk / sum_j (c_jk - 1)`` over the places with two or more readings
  (``v_min`` where there is none): the spread of the readings at one place, not the spread
  over the whole area, which also holds the signal's change with position;
- ``s_j^2`` = the spread of the calibration positions of place ``j`` (0 for a single
  point) plus ``position_var_m2``.

Access points detected in fewer than ``min_samples`` calibration scans are dropped (a
``UserWarning`` says how many); their readings are ignored at localization and counted.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.special import softmax

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.validation import as_float_array

_LOG2PI = np.log(2.0 * np.pi)

__all__ = ["FingerprintMixture", "place_moments", "place_weights", "zone_posterior"]


@dataclass(frozen=True)
class FingerprintMixture:
    """Shared-place fingerprint model (see the module docstring for the equations).

    Parameters
    ----------
    positions : ndarray, shape (K, D)
        Place (component) positions.
    position_variances : ndarray, shape (K, D)
        Per-axis position variance of each place.
    log_prior : ndarray, shape (K,)
        Log prior weight of each place (normalised).
    detect : ndarray, shape (K, S)
        Detection probability ``p_jk`` in (0, 1).
    mean : ndarray, shape (K, S)
        RSS mean given detection, dBm.
    variance : ndarray, shape (K, S)
        RSS variance given detection, dB^2.
    active : ndarray of bool, shape (S,)
        Access points the model uses (False: dropped for too few samples).
    zones : ndarray of int, shape (K, L)
        Zone labels of each place, coarse to fine (e.g. building, floor); ``L`` may be 0.
    zone_names : tuple of str
        Names of the ``L`` zone levels.
    """

    positions: np.ndarray
    position_variances: np.ndarray
    log_prior: np.ndarray
    detect: np.ndarray
    mean: np.ndarray
    variance: np.ndarray
    active: np.ndarray
    zones: np.ndarray
    zone_names: tuple[str, ...] = ()

    def __post_init__(self):
        k, d = np.shape(self.positions)
        s = np.shape(self.detect)[-1]
        for name, shape in (("position_variances", (k, d)), ("log_prior", (k,)),
                            ("detect", (k, s)), ("mean", (k, s)), ("variance", (k, s)),
                            ("active", (s,))):
            if np.shape(getattr(self, name)) != shape:
                raise InputError(f"{name}: shape {np.shape(getattr(self, name))}, expected {shape}")
        if np.ndim(self.zones) != 2 or np.shape(self.zones)[0] != k \
                or np.shape(self.zones)[1] != len(self.zone_names):
            raise InputError(f"zones: shape {np.shape(self.zones)}, expected ({k}, "
                             f"{len(self.zone_names)})")
        p = np.asarray(self.detect)
        if np.any(~(p > 0) | ~(p < 1)):
            raise InputError("detect: probabilities must lie in (0, 1)")
        if np.any(~(np.asarray(self.variance) > 0)):
            raise InputError("variance: must be > 0")
        # coefficients of the one-product log-likelihood: features [d, d m, d m^2]
        a, mu, v = self.active, np.asarray(self.mean), np.asarray(self.variance)
        lp, lq = np.log(p), np.log1p(-p)
        c_d = lp - 0.5 * (np.log(v) + _LOG2PI) - 0.5 * mu * mu / v - lq
        coef = np.concatenate([c_d, mu / v, -0.5 / v], axis=1) * np.tile(a, 3)   # (K, 3S)
        object.__setattr__(self, "_coef", np.ascontiguousarray(coef.T))          # (3S, K)
        object.__setattr__(self, "_const", (lq * a).sum(1))

    @property
    def n_places(self) -> int:
        """Number of places (components) K."""
        return self.positions.shape[0]

    @property
    def n_stations(self) -> int:
        """Number of access-point columns S (dropped ones included)."""
        return self.detect.shape[1]

    @property
    def dim(self) -> int:
        """Position coordinates D."""
        return self.positions.shape[1]

    @property
    def dropped_stations(self) -> int:
        """Access points dropped at the fit (too few samples)."""
        return int(np.sum(~self.active))

    @classmethod
    def fit(cls, positions, rss, zones=None, zone_names=(), *, alpha: float = 0.1,
            shrink: float = 5.0, var_min_db2: float = 25.0, position_var_m2: float = 1.0,
            min_samples: int = 3) -> "FingerprintMixture":
        """Fit the model to calibration scans.

        Parameters
        ----------
        positions : array_like, shape (N, D)
            Calibration positions.
        rss : array_like, shape (N, S)
            Signal strengths in dBm, NaN = not detected.
        zones : array_like of int, shape (N, L), optional
            Zone labels of each scan, coarse to fine (e.g. building, floor). Places are the
            distinct ``(zones, position)`` rows.
        zone_names : tuple of str
            Names of the zone levels (length L).
        alpha : float
            Detection pseudo-count (> 0).
        shrink : float
            Pseudo-samples ``lam`` of the shrinkage of place means and variances towards the
            access point's overall ones (>= 0).
        var_min_db2 : float
            Floor ``v_min`` of every RSS variance, dB^2 (> 0).
        position_var_m2 : float
            Variance added to each place's position spread (> 0).
        min_samples : int
            Access points detected in fewer calibration scans are dropped (>= 1).

        Returns
        -------
        FingerprintMixture

        Raises
        ------
        InputError
            Shapes, non-finite positions, infinite RSS, no usable access point.
        ConfigError
            A setting out of range.
        """
        pos = as_float_array(positions, "positions", ndim=2)
        m = as_float_array(rss, "rss", ndim=2, allow_nan=True)
        if m.shape[0] != pos.shape[0]:
            raise InputError(f"rss: {m.shape[0]} rows, positions {pos.shape[0]}")
        if np.any(np.isinf(m)):
            i, j = (int(v) for v in np.argwhere(np.isinf(m))[0])
            raise InputError(f"rss: infinite value at row {i}, column {j}")
        for name, val, lo in (("alpha", alpha, 0.0), ("var_min_db2", var_min_db2, 0.0),
                              ("position_var_m2", position_var_m2, 0.0)):
            if not np.isfinite(val) or val <= lo:
                raise ConfigError(f"{name}: must be a finite number > 0, got {val!r}")
        if not np.isfinite(shrink) or shrink < 0:
            raise ConfigError(f"shrink: must be >= 0, got {shrink!r}")
        if isinstance(min_samples, bool) or int(min_samples) != min_samples or min_samples < 1:
            raise ConfigError(f"min_samples: must be an integer >= 1, got {min_samples!r}")
        n = pos.shape[0]
        z = np.zeros((n, 0), np.int64) if zones is None else np.asarray(zones)
        if z.ndim == 1:
            z = z[:, None]
        if z.shape[0] != n or z.shape[1] != len(zone_names):
            raise InputError(f"zones: shape {z.shape}, expected ({n}, {len(zone_names)})")
        z = z.astype(np.int64)
        keys = np.concatenate([z.astype(float), pos], axis=1)
        _, first, codes = np.unique(keys, axis=0, return_index=True, return_inverse=True)
        codes = codes.ravel()
        k = first.size
        det = np.isfinite(m)
        x = np.where(det, m, 0.0)
        count_ap = det.sum(0)
        active = count_ap >= int(min_samples)
        dropped = int(np.sum(~active))
        if not active.any():
            raise InputError(f"rss: no access point has {min_samples} or more calibration samples")
        if dropped:
            warnings.warn(f"fingerprint model: {dropped} of {m.shape[1]} access points dropped "
                          f"(detected in fewer than {min_samples} calibration scans); their "
                          "readings are ignored", UserWarning, stacklevel=2)
        # per-place sums: one sparse (K, N) indicator product each
        nj = np.bincount(codes, minlength=k).astype(float)
        c = _group_sum(codes, det.astype(float), k)
        s1 = _group_sum(codes, x, k)
        s2 = _group_sum(codes, x * x, k)
        mu_ap = np.where(count_ap > 0, x.sum(0) / np.maximum(count_ap, 1), 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mbar = np.where(c > 0, s1 / c, 0.0)
            s2p = np.where(c > 0, np.maximum(s2 / np.maximum(c, 1) - mbar**2, 0.0), 0.0)
        # pooled within-place variance of each access point (places with >= 2 readings)
        rep = c >= 2
        dof = np.sum(np.where(rep, c - 1, 0.0), axis=0)
        var_ap = np.where(dof > 0, np.sum(np.where(rep, c * s2p, 0.0), axis=0)
                          / np.maximum(dof, 1), var_min_db2)
        var_ap = np.maximum(var_ap, var_min_db2)
        lam = float(shrink)
        denom = np.maximum(c + lam, 1e-300)
        mu = np.where(c + lam > 0, (c * mbar + lam * mu_ap) / denom, mu_ap)
        var = np.maximum(var_min_db2, np.where(c + lam > 0, (c * s2p + lam * var_ap) / denom,
                                               var_ap))
        p = (c + alpha) / (nj[:, None] + 2 * alpha)
        pmean = _group_sum(codes, pos, k) / nj[:, None]
        pvar = np.maximum(_group_sum(codes, pos * pos, k) / nj[:, None] - pmean**2, 0.0)
        return cls(pmean, pvar + position_var_m2, np.full(k, -np.log(k)), p, mu, var, active,
                   z[first], tuple(zone_names))

    def loglik(self, rss: np.ndarray) -> np.ndarray:
        """``log L_j(m)`` of every scan at every place (one matrix product).

        Parameters
        ----------
        rss : ndarray, shape (N, S)
            Signal strengths in dBm, NaN = not detected (validated by the caller).

        Returns
        -------
        ndarray, shape (N, K)
        """
        det = np.isfinite(rss)
        x = np.where(det, rss, 0.0)
        feat = np.concatenate([det.astype(float), x, x * x], axis=1)
        return feat @ self._coef + self._const

    def posterior(self, rss: np.ndarray, temperature: float = 1.0) -> np.ndarray:
        """Place weights ``w_j ∝ pi_j exp(log L_j / T)``.

        Parameters
        ----------
        rss : ndarray, shape (N, S)
            Signal strengths, NaN = not detected.
        temperature : float
            ``T >= 1`` (1: the plain product over access points).

        Returns
        -------
        ndarray, shape (N, K)
            Weights summing to one per row.
        """
        return softmax(self.loglik(rss) / temperature + self.log_prior, axis=-1)


def _group_sum(codes: np.ndarray, values: np.ndarray, k: int) -> np.ndarray:
    """Sum of the rows of ``values`` ``(N, C)`` per group code, ``(k, C)``."""
    from scipy.sparse import csr_matrix

    g = csr_matrix((np.ones(codes.size), (codes, np.arange(codes.size))), shape=(k, codes.size))
    return np.asarray(g @ values)


def zone_posterior(weights: np.ndarray, zones: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hierarchical zone decision from place weights: the level-0 zone (e.g. the building)
    of largest posterior mass, then the level-1 zone (floor) of largest mass within it, ...

    Parameters
    ----------
    weights : ndarray, shape (N, K)
        Place weights per row.
    zones : ndarray of int, shape (K, L)
        Zone labels of the places.

    Returns
    -------
    chosen : ndarray of int, shape (N, L)
        The chosen label of each level.
    inside : ndarray of bool, shape (N, K)
        Places inside the chosen zone (all True when ``L = 0``).
    """
    n, k = weights.shape
    inside = np.ones((n, k), bool)
    chosen = np.zeros((n, zones.shape[1]), np.int64)
    for level in range(zones.shape[1]):            # a loop over the (few) zone levels
        labels, code = np.unique(zones[:, level], return_inverse=True)
        onehot = np.zeros((k, labels.size))
        onehot[np.arange(k), code.ravel()] = 1.0
        mass = (weights * inside) @ onehot            # (N, labels)
        pick = np.argmax(mass, axis=1)
        chosen[:, level] = labels[pick]
        inside &= zones[None, :, level] == chosen[:, level, None]
    return chosen, inside


def place_weights(model: FingerprintMixture, loglik: np.ndarray, temperature: float = 1.0,
                  top_places: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Place weights of every scan: tempered posterior, restricted to the chosen zone and,
    optionally, to the ``top_places`` heaviest places.

    ``w_j ∝ pi_j exp(log L_j / T)`` (:meth:`FingerprintMixture.posterior`), the zone chosen
    by :func:`zone_posterior`, weights outside it set to 0; with ``top_places = M`` only the
    places whose weight is at least the ``M``-th largest keep theirs (ties keep all), and
    the rest is renormalised. ``M`` small makes the estimate local, as k nearest neighbours
    are, with the neighbours and their weights from the mixture's likelihood instead of a
    distance in signal space.

    Parameters
    ----------
    model : FingerprintMixture
        The fitted model.
    loglik : ndarray, shape (N, K)
        ``log L_j(m)`` of every scan (:meth:`FingerprintMixture.loglik`).
    temperature : float
        ``T >= 1``.
    top_places : int, optional
        ``M >= 1`` places kept per scan; None or 0 keeps every place of the zone.

    Returns
    -------
    weights : ndarray, shape (N, K)
        Rows summing to one.
    chosen : ndarray of int, shape (N, L)
        The zone label chosen at each level.
    """
    w = softmax(loglik / temperature + model.log_prior, axis=-1)
    chosen, inside = zone_posterior(w, model.zones)
    w = np.where(inside, w, 0.0)
    k = w.shape[1]
    if top_places and top_places < k:
        thr = -np.partition(-w, int(top_places) - 1, axis=1)[:, int(top_places) - 1:int(top_places)]
        w = np.where(w >= thr, w, 0.0)
    return w / w.sum(1, keepdims=True), chosen


def place_moments(model: FingerprintMixture, weights: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the position mixture ``sum_j w_j N(x_j, s_j^2)``.

    Parameters
    ----------
    model : FingerprintMixture
        The fitted model.
    weights : ndarray, shape (N, K)
        Place weights, rows summing to one.

    Returns
    -------
    mean : ndarray, shape (N, D)
    covariance : ndarray, shape (N, D, D)
    """
    pos, pvar = model.positions, model.position_variances
    mean = weights @ pos
    second = np.einsum("nk,ki,kj->nij", weights, pos, pos) \
        + np.einsum("nk,ki->ni", weights, pvar)[..., None] * np.eye(model.dim)
    return mean, second - mean[:, :, None] * mean[:, None, :]
