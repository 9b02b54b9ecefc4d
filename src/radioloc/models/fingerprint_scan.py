"""The shared-place fingerprint model (:class:`~radioloc.models.fingerprint_mixture.
FingerprintMixture`) as a measurement model: the likelihood of a WiFi scan at a position.

The fingerprint model explains a scan by a *place* ``j`` (position ``N(x; x_j, S_j)``,
prior ``pi_j``) at which access point ``k`` is detected with probability ``p_jk`` and then
reads ``N(m; mu_jk, v_jk)``. The access points are independent given the place, not given
the position, so the likelihood of a scan ``z = (z_1 .. z_m)`` at a position ``x`` is::

    p(z | x) = sum_j r_j(x) prod_r q_j,k(r)(z_r),   r_j(x) ∝ pi_j N(x; x_j, S_j)

with ``q_jk(m) = p_jk N(m; mu_jk, v_jk)`` for a detection and ``1 - p_jk`` for an access
point scanned but not detected. :class:`FingerprintScanModel` returns it split over the
rows by the chain rule, ``log p(z | x) = sum_r log p(z_r | z_1 .. z_{r-1}, x)`` (row ``r``'s
term: the log of the ratio of the place sums with and without it), so that the rows sum
to the scan's log-likelihood as every estimator sums them; a single row's term depends on
the rows before it.

Values: a reading in dBm is a detection; ``not_detected`` (default ``+100``, the
UJIIndoorLoc convention) marks an access point scanned and not detected, which is
information (``1 - p_jk``); NaN is a row without a scan (skipped). Access points the fit
dropped (``active`` False) are ignored, as the fingerprint localizer ignores them.

Likelihood-only (``gaussian = False``): the reading's distribution has an atom at "not
detected" and no fixed spread, so estimators whose ``tags.uses`` is ``"logpdf"`` take it,
the Jacobian ones refuse it. Rows are access points: ``Context.index`` gives each row's
column in the model.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.errors import InputError
from radioloc.models.fingerprint_mixture import FingerprintMixture
from radioloc.models.measurement import (Context, LikelihoodModel, checked_call,
                                         gaussian_logpdf)
from radioloc.models.mixture import component_logpdf, log_sum_exp

__all__ = ["FingerprintScanModel"]


@dataclass(frozen=True)
class FingerprintScanModel(LikelihoodModel):
    """Likelihood of a scan under a shared-place fingerprint model (module docstring).

    Parameters
    ----------
    model : FingerprintMixture
        The fitted fingerprint model.
    not_detected : float
        The value that marks an access point scanned and not detected.
    """

    model: FingerprintMixture
    not_detected: float = 100.0

    kind: ClassVar[str] = "rss_scan"
    #: an atom at "not detected" and no fixed spread: ``logpdf`` estimators only
    why: ClassVar[str] = ("a scan's readings have an atom at 'not detected' (a likelihood on "
                          "positions: logpdf)")

    def __post_init__(self) -> None:
        if not isinstance(self.model, FingerprintMixture):
            raise InputError(f"model: expected a FingerprintMixture, got "
                             f"{type(self.model).__name__}")
        if not np.isfinite(self.not_detected):
            raise InputError(f"not_detected: must be a finite value, got {self.not_detected!r}")

    def _columns(self, context: Context) -> np.ndarray:
        idx = context.index
        s = self.model.n_stations
        if idx is None:
            raise InputError("context.index: the fingerprint model needs each row's access "
                             "point (its column in the model)")
        bad = (idx < 0) | (idx >= s)
        if bad.any():
            r = int(np.flatnonzero(bad)[0])
            raise InputError(f"context.index: row {r} names access point {int(idx[r])}; the "
                             f"model has {s}")
        return idx

    def place_log_weights(self, state, context: Context) -> np.ndarray:
        """``log r_j(x)`` ``(..., K)``: the places' share of the position density.

        Parameters
        ----------
        state : dict
            Named components, ``position`` ``(..., D)``.
        context : Context

        Returns
        -------
        ndarray, shape (..., K)
        """
        fm = self.model
        x = np.asarray(state["position"], dtype=float)
        if x.shape[-1:] != (fm.dim,):
            raise InputError(f"state['position']: last axis {x.shape[-1:]} does not match the "
                             f"model's {fm.dim} position coordinates")
        lx = fm.log_prior + component_logpdf(x, fm.positions, fm.position_variances)
        return lx - log_sum_exp(lx)[..., None]

    def _row_terms(self, z: np.ndarray, context: Context) -> np.ndarray:
        """``log q_j,k(r)(z_r)`` ``(..., m, K)`` (0 where the row is absent or dropped)."""
        fm, idx = self.model, self._columns(context)
        p, mu, v = fm.detect[:, idx].T, fm.mean[:, idx].T, fm.variance[:, idx].T  # (m, K)
        miss, off = np.isnan(z), z == self.not_detected
        m = np.where(miss | off, 0.0, z)[..., None]
        miss, off = miss[..., None], off[..., None]
        det = np.log(p) + gaussian_logpdf(m - mu, np.sqrt(v))
        out = np.where(off, np.log1p(-p), det)
        return np.where(miss | ~fm.active[idx][:, None], 0.0, out)

    def logpdf(self, z, state, context: Context) -> np.ndarray:
        """Per-row chain-rule terms of ``log p(z | x)`` ``(..., m)`` (their sum is the
        scan's log-likelihood; NaN rows give 0).

        Parameters
        ----------
        z : ndarray, shape (..., m)
            Readings, dBm; ``not_detected``: scanned, not detected; NaN: no scan.
        state : dict
            Named components, ``position`` ``(..., D)``.
        context : Context

        Returns
        -------
        ndarray, shape (..., m)
        """
        z = checked_call(z, state, context, self.reads)
        lr = self.place_log_weights(state, context)[..., None, :]          # (..., 1, K)
        cum = np.cumsum(self._row_terms(z, context), axis=-2)               # (..., m, K)
        total = log_sum_exp(lr + cum)                                         # (..., m)
        before = np.concatenate([np.zeros(total.shape[:-1] + (1,)), total[..., :-1]], -1)
        return total - before

    def sample(self, state, context: Context, rng: np.random.Generator) -> np.ndarray:
        """A scan at each position: a place by ``r_j(x)``, then each access point detected
        with ``p_jk`` and read from ``N(mu_jk, v_jk)`` (``not_detected`` otherwise).

        Parameters
        ----------
        state : dict
            Named components, ``position`` ``(..., D)``.
        context : Context
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (..., m)
        """
        fm, idx = self.model, self._columns(context)
        lr = self.place_log_weights(state, context)
        cdf = np.cumsum(np.exp(lr), axis=-1)
        u = rng.random(lr.shape[:-1] + (1,)) * cdf[..., -1:]
        j = np.minimum(np.sum(cdf < u, axis=-1), fm.n_places - 1)[..., None]   # (..., 1)
        p, mu, v = fm.detect[j, idx], fm.mean[j, idx], fm.variance[j, idx]    # (..., m)
        seen = rng.random(p.shape) < p
        reading = mu + np.sqrt(v) * rng.standard_normal(p.shape)
        return np.where(seen, reading, self.not_detected)
