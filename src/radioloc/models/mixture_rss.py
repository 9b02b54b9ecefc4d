"""Paper 004's Gaussian-mixture signal-strength model as a measurement model.

Each base station ``k`` has a calibration mixture over position and signal strength,
eq. (1)::

    D^(k)(x, m) = sum_j w_kj N(x; mu_kj, diag V_kj) N(m; nu_kj, v_kj)

(:class:`~radioloc.models.mixture.DiagMixture`, batch axis the stations, dimension
``D + 1``: the position coordinates, then ``m``). :class:`MixtureRssModel` reads it as the
likelihood of a reading at a position, the conditional density of the mixture::

    p(m | x) = D^(k)(x, m) / D^(k)(x)
             = sum_j r_kj(x) N(m; nu_kj, v_kj),   r_kj(x) ∝ w_kj N(x; mu_kj, V_kj)

(a mixture of the components' signal densities, weighted by how much each component
explains the position). Readings of different stations are independent given the position
(Sect. 3.1), so the log-likelihood of a scan is the sum of its rows.

This differs from the localizer's eq. (2), which multiplies the conditionals
``D^(k)(x | m) ∝ p(m | x) D^(k)(x)`` and so counts each station's position marginal
``D^(k)(x)`` once per station; here the position prior is the estimator's (its prior and
motion model), and a station enters only through ``p(m | x)``.

The noise is not Gaussian and its spread depends on the position, so the model has no
fixed ``std``: it is likelihood-only (``gaussian = False``: estimators whose
``tags.uses`` is ``"logpdf"`` take it, the Jacobian ones refuse it). :meth:`predict` is the
conditional mean ``E[m | x] = sum_j r_kj(x) nu_kj`` and :meth:`sample` draws from
``p(m | x)`` exactly.

Rows are stations: ``Context.index`` gives each row's station (its column in the
mixture's station axis); ``Context.points`` holds where the station is if known (only its
dimension is used, to check the state's).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.errors import InputError
from radioloc.models.measurement import (Context, LikelihoodModel, checked_call,
                                         gaussian_logpdf)
from radioloc.models.mixture import DiagMixture, component_logpdf, log_sum_exp

__all__ = ["MixtureRssModel"]


@dataclass(frozen=True)
class MixtureRssModel(LikelihoodModel):
    """Likelihood of signal strengths under per-station calibration mixtures (module
    docstring).

    Parameters
    ----------
    models : DiagMixture
        Batch shape ``(S,)`` (one mixture per station), dimension ``D + 1``: position
        ``(x, y[, z])`` then the signal strength.

    Examples
    --------
    >>> import numpy as np
    >>> mix = DiagMixture.create(np.ones((1, 2)), [[[0.0, 0.0, -40.0], [10.0, 0.0, -60.0]]],
    ...                          np.full((1, 2, 3), 1.0))
    >>> model = MixtureRssModel(mix)
    >>> ctx = Context(points=np.zeros((1, 2)), index=np.array([0]))
    >>> round(float(model.predict({"position": np.array([0.0, 0.0])}, ctx)[0]), 3)
    -40.0
    """

    models: DiagMixture

    kind: ClassVar[str] = "rss_fingerprint"
    #: no fixed Gaussian noise: ``Tags.accepts`` gives it to ``logpdf`` estimators only
    why: ClassVar[str] = "its noise depends on the position (a likelihood on positions: logpdf)"

    def __post_init__(self) -> None:
        mix = self.models
        if not isinstance(mix, DiagMixture):
            raise InputError(f"models: expected a DiagMixture, got {type(mix).__name__}")
        if len(mix.batch_shape) != 1 or mix.dim < 3:
            raise InputError("models: expected one mixture per station (batch shape (S,)) over "
                             f"position and signal strength (dimension >= 3), got batch shape "
                             f"{mix.batch_shape}, dimension {mix.dim}")
        for name in ("weights", "means", "variances"):
            arr = np.asarray(getattr(mix, name))
            if not np.all(np.isfinite(arr)):
                idx = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
                raise InputError(f"models: non-finite {name} at index {idx}")
        if np.any(mix.variances <= 0):
            raise InputError("models: variances must be > 0")
        if np.any(mix.weights < 0) or np.any(mix.weights.sum(-1) <= 0):
            raise InputError("models: weights must be >= 0 with a positive total per station")

    @property
    def n_stations(self) -> int:
        """Number of stations S."""
        return self.models.batch_shape[0]

    @property
    def dim(self) -> int:
        """Position coordinates D."""
        return self.models.dim - 1

    def _rows(self, context: Context):
        """The row stations' weights ``(m, K)``, position means and variances ``(m, K, D)``
        and signal means and variances ``(m, K)``."""
        idx = context.index
        if idx is None:
            raise InputError("context.index: the mixture model needs each row's station (its "
                             "column in the models' station axis)")
        if np.any((idx < 0) | (idx >= self.n_stations)):
            bad = int(np.flatnonzero((idx < 0) | (idx >= self.n_stations))[0])
            raise InputError(f"context.index: row {bad} names station {int(idx[bad])}; the "
                             f"models have {self.n_stations}")
        mix, d = self.models, self.dim
        return (mix.weights[idx], mix.means[idx, :, :d], mix.variances[idx, :, :d],
                mix.means[idx, :, d], mix.variances[idx, :, d])

    def responsibilities(self, state, context: Context) -> tuple[np.ndarray, ...]:
        """``log r_kj(x)`` ``(..., m, K)`` of every row's components at the state's
        positions, with the rows' signal means and variances ``(m, K)``.

        Parameters
        ----------
        state : dict
            Named components, ``position`` ``(..., D)``.
        context : Context

        Returns
        -------
        log_r : ndarray, shape (..., m, K)
        nu, v : ndarray, shape (m, K)
        """
        w, mu, var, nu, v = self._rows(context)
        x = np.asarray(state["position"], dtype=float)
        if x.shape[-1:] != (self.dim,):
            raise InputError(f"state['position']: last axis {x.shape[-1:]} does not match the "
                             f"models' {self.dim} position coordinates")
        with np.errstate(divide="ignore"):
            lx = np.log(w) + component_logpdf(x, mu, var)                  # (..., m, K)
        return lx - log_sum_exp(lx)[..., None], nu, v

    def predict(self, state, context: Context) -> np.ndarray:
        """The conditional mean ``E[m | x]`` of every row, ``(..., m)``.

        Parameters
        ----------
        state : dict
            Named components, ``position`` ``(..., D)``.
        context : Context

        Returns
        -------
        ndarray, shape (..., m)
        """
        log_r, nu, _ = self.responsibilities(state, context)
        return np.sum(np.exp(log_r) * nu, axis=-1)

    def logpdf(self, z, state, context: Context) -> np.ndarray:
        """``log p(m | x)`` per row ``(..., m)`` (NaN rows give 0).

        Parameters
        ----------
        z : ndarray, shape (..., m)
            Signal strengths (NaN: not received).
        state : dict
            Named components, ``position`` ``(..., D)``.
        context : Context

        Returns
        -------
        ndarray, shape (..., m)
        """
        z = checked_call(z, state, context, self.reads)
        log_r, nu, v = self.responsibilities(state, context)
        miss = np.isnan(z)
        m = np.where(miss, 0.0, z)[..., None]
        lm = gaussian_logpdf(m - nu, np.sqrt(v))
        return np.where(miss, 0.0, log_sum_exp(log_r + lm))

    def sample(self, state, context: Context, rng: np.random.Generator) -> np.ndarray:
        """A draw from ``p(m | x)`` of every row: a component by its responsibility, then
        its signal density.

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
        log_r, nu, v = self.responsibilities(state, context)
        cdf = np.cumsum(np.exp(log_r), axis=-1)
        u = rng.random(log_r.shape[:-1] + (1,)) * cdf[..., -1:]
        j = np.minimum(np.sum(cdf < u, axis=-1), log_r.shape[-1] - 1)       # (..., m)
        rows = np.arange(log_r.shape[-2])
        mean, sd = nu[rows, j], np.sqrt(v[rows, j])
        return mean + sd * rng.standard_normal(mean.shape)
