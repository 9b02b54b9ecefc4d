"""Localization and tracking with Gaussian-mixture signal-strength models (paper 004, Sects. 3.2, 4).

- :func:`localize`: each received base station's model ``D^(k)(x, y, m)`` is conditioned on
  its measured ``m^(k)`` (closed form, :meth:`DiagMixture.condition`), and the ``N_r``
  position densities are multiplied and renormalised, eq. (2); after each product the
  result is reduced to ``max_components`` (:func:`radioloc.models.mixture.reduce`). Base
  stations not received (NaN) are left out.
- :func:`track`: per time step, prediction by convolution with the uniform disk of radius
  ``v_max * dt`` re-approximated as a mixture (:func:`uniform_ball`), then the filter step
  (product of the prediction with the measurement density of eq. 2), reduction, and the
  mixture mean and covariance as the per-step estimate. ``v_max = 0`` skips the prediction
  (the static user of Sect. 5).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array
from radioloc.models.mixture import DiagMixture, convolve, product, reduce, uniform_ball


def _pad(mix: DiagMixture, k: int) -> DiagMixture:
    extra = k - mix.n_components
    if extra <= 0:
        return mix
    b = mix.batch_shape
    return DiagMixture(np.concatenate([mix.weights, np.zeros(b + (extra,))], -1),
                       np.concatenate([mix.means, np.zeros(b + (extra, mix.dim))], -2),
                       np.concatenate([mix.variances, np.ones(b + (extra, mix.dim))], -2))


def select(mask, new: DiagMixture, old: DiagMixture) -> DiagMixture:
    """``new`` where ``mask`` ``(...)`` is True, else ``old`` (component counts padded)."""
    k = max(new.n_components, old.n_components)
    new, old = _pad(new, k), _pad(old, k)
    mk = np.asarray(mask)[..., None]
    return DiagMixture(np.where(mk, new.weights, old.weights),
                       np.where(mk[..., None], new.means, old.means),
                       np.where(mk[..., None], new.variances, old.variances))


def localize(models: DiagMixture, rss, max_components: int = 16) -> DiagMixture:
    """Position density ``D(x, y | m)`` of eq. (2) for a batch of measurement vectors.

    Parameters
    ----------
    models : DiagMixture
        Batch shape ``(..., S)`` (one model per base station; extra leading axes
        broadcast against ``rss``), last coordinate = signal strength.
    rss : array (..., S)
        Measured signal strengths; NaN = base station not received.
    max_components : int
        Bound on the components after each product.

    Returns
    -------
    DiagMixture
        Batch shape ``rss.shape[:-1]``, dimension ``models.dim - 1``.
    """
    m = as_float_array(rss, "rss", min_ndim=1, allow_nan=True)
    s = models.batch_shape[-1] if models.batch_shape else 0
    if m.shape[-1] != s:
        raise InputError(f"rss: {m.shape[-1]} base station columns, the models have {s}")
    got = np.isfinite(m)
    if not np.all(got.any(-1)):
        bad = np.argwhere(~got.any(-1))[0]
        raise InputError(f"rss: row {tuple(int(i) for i in bad)} has no received base station")
    cond = models.condition(models.dim - 1, np.where(got, m, 0.0), valid=got)
    post = None
    for k in range(s):
        ck = DiagMixture(np.broadcast_to(cond.weights[..., k, :], m.shape[:-1] + cond.weights.shape[-1:]),
                         np.broadcast_to(cond.means[..., k, :, :], m.shape[:-1] + cond.means.shape[-2:]),
                         np.broadcast_to(cond.variances[..., k, :, :],
                                         m.shape[:-1] + cond.variances.shape[-2:]))
        ck = reduce(ck, max_components)
        if post is None:
            post = ck
            have = got[..., k]
            continue
        both = reduce(product(post, ck), max_components)
        post = select(got[..., k] & have, both, select(got[..., k], ck, post))
        have = have | got[..., k]
    return post


@dataclass(frozen=True)
class TrackResult:
    """Per-step estimates: ``mean`` ``(T, ..., D)``, ``covariance`` ``(T, ..., D, D)`` and
    the final posterior mixture."""

    mean: np.ndarray
    covariance: np.ndarray
    posterior: DiagMixture


def track(models: DiagMixture, rss, dt, v_max: float = 1.5, max_components: int = 16,
          motion_components: int | None = None) -> TrackResult:
    """Recursive Bayesian tracking with mixture densities (Sect. 4, Fig. 7).

    Parameters
    ----------
    models : DiagMixture
        Per-base-station calibration models, batch shape ``(..., S)``.
    rss : array (T, ..., S)
        Measurement vectors per time step (NaN = not received).
    dt : float or array (T,)
        Time since the previous step (the first entry is unused).
    v_max : float
        Maximum speed (m/s); the prediction density is uniform on the disk of radius
        ``v_max * dt``. ``0`` disables the prediction (static user).
    max_components : int
        Bound on the components of every density.
    """
    m = as_float_array(rss, "rss", min_ndim=2, allow_nan=True)
    t_steps = m.shape[0]
    dts = np.broadcast_to(np.asarray(dt, dtype=float), (t_steps,))
    if v_max < 0 or np.any(dts[1:] < 0):
        raise InputError("v_max/dt: must be >= 0")
    measured = localize(models, m, max_components)        # all steps at once, batch (T, ...)
    means, covs = [], []
    post = None
    for t in range(t_steps):
        meas = measured[t]
        if post is None:
            post = meas
        else:
            prior = post
            r = v_max * dts[t]
            if r > 0:
                prior = reduce(convolve(post, uniform_ball(r, post.dim)), max_components)
            post = reduce(product(prior, meas), max_components)
        mu, cov = post.moments()
        means.append(mu)
        covs.append(cov)
    return TrackResult(np.array(means), np.array(covs), post)
