"""Robust losses and the max-mixture loss of the generic least-squares estimators.

Every measurement row enters :class:`~radioloc.estimators.least_squares.LeastSquares` and
:class:`~radioloc.estimators.batch_smoother.BatchSmoother` through one function of its
residual ``r = z - h(x)`` (wrapped for angles): a *row term* of the cost (twice a negative
log-likelihood up to a constant) and the weight and working residual of its
Gauss-Newton system. For a loss ``rho`` of the standardised residual ``u = (r - mu) / s``
(``mu``, ``s`` the model's noise mean and standard deviation of the row):

* cost term ``2 rho(u)``;
* iteratively reweighted least squares (IRLS): weight ``w(u) / s^2`` with
  ``w(u) = rho'(u) / u``, working residual ``r - mu``.

The losses, with ``c`` the scale in units of ``s`` (``loss_scale``):

========  ==================================================  =========================
loss      ``rho(u)``                                          ``w(u)``
========  ==================================================  =========================
linear    ``u^2 / 2``                                         ``1``
huber     ``u^2 / 2`` if ``|u| <= c``, else ``c |u| - c^2/2``  ``min(1, c / |u|)``
cauchy    ``c^2 / 2 log(1 + (u / c)^2)``                       ``1 / (1 + (u / c)^2)``
tukey     ``c^2 / 6 (1 - (1 - (u/c)^2)^3)`` if ``|u| < c``,    ``(1 - (u/c)^2)^2`` inside,
          else ``c^2 / 6``                                     0 outside
========  ==================================================  =========================

The *max-mixture* loss (Olson & Agarwal 2013; GTSAM, libRSF and navlie use it for NLOS)
takes a model with discrete per-row modes (:meth:`RangeModel.mode_logpdf
<radioloc.models.ranging.RangeModel.mode_logpdf>`, e.g. LOS and NLOS): each row's cost
is ``min_k -2 (log p_k(r) + log pi_k)``, the mode ``k`` that explains the row best (with
its prior weight ``pi_k``). Optionally a null-hypothesis mode joins them (Olson & Agarwal's
outlier component): a broad zero-mean Gaussian of weight ``pi_null`` (the LOS/NLOS
weights scaled by ``1 - pi_null``), which explains gross errors of either sign (the
LOS/NLOS mixture has no mode for a range much too short). Its Gauss-Newton system is the Newton model of the chosen
mode's negative log-density in the residual: weight ``c_k = -d^2 log p_k / dr^2``
(floored at ``1e-4 / s^2``, ``s`` the model's standard deviation) and working residual
``-(d log p_k / dr) / c_k`` (central differences in ``z``). For a Gaussian mode these are
exactly ``1 / s_k^2`` and ``r - mu_k``; for the exponential NLOS mode of
:class:`~radioloc.models.los_nlos.LosNlosRange` (log-concave) the weight falls as the
excess grows, as a robust loss's does.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import ConfigError
from radioloc.core.validation import check_positive
from radioloc.models.measurement import gaussian_logpdf

__all__ = ["LOSSES", "check_loss", "rho", "irls_weight", "row_terms", "max_mixture_terms"]

#: The robust losses (names of :func:`rho`).
LOSSES = ("linear", "huber", "cauchy", "tukey")


def check_loss(loss: str, loss_scale: float) -> tuple[str, float]:
    """Validate a loss name and its scale (raises :class:`ConfigError` naming them)."""
    if loss not in LOSSES:
        raise ConfigError(f"loss: must be one of {', '.join(LOSSES)}, got {loss!r}")
    try:
        scale = check_positive(loss_scale, "loss_scale")
    except Exception as exc:  # InputError from the validator: a setting, so ConfigError
        raise ConfigError(str(exc)) from None
    return loss, float(scale)


def rho(u: np.ndarray, loss: str, c: float) -> np.ndarray:
    """The loss ``rho(u)`` of standardised residuals (module table)."""
    u = np.asarray(u, dtype=float)
    a = np.abs(u)
    if loss == "linear":
        return 0.5 * u * u
    if loss == "huber":
        return np.where(a <= c, 0.5 * u * u, c * a - 0.5 * c * c)
    if loss == "cauchy":
        return 0.5 * c * c * np.log1p((u / c) ** 2)
    if loss == "tukey":
        inside = 1.0 - np.minimum((u / c) ** 2, 1.0)
        return c * c / 6.0 * (1.0 - inside ** 3)
    raise ConfigError(f"loss: must be one of {', '.join(LOSSES)}, got {loss!r}")


def irls_weight(u: np.ndarray, loss: str, c: float) -> np.ndarray:
    """The IRLS weight ``w(u) = rho'(u) / u`` (module table)."""
    u = np.asarray(u, dtype=float)
    a = np.abs(u)
    if loss == "linear":
        return np.ones_like(u)
    if loss == "huber":
        return np.where(a <= c, 1.0, c / np.maximum(a, 1e-300))
    if loss == "cauchy":
        return 1.0 / (1.0 + (u / c) ** 2)
    if loss == "tukey":
        return np.where(a < c, (1.0 - (u / c) ** 2) ** 2, 0.0)
    raise ConfigError(f"loss: must be one of {', '.join(LOSSES)}, got {loss!r}")


def row_terms(r: np.ndarray, mean: np.ndarray | float, std: np.ndarray, loss: str,
              c: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cost term, IRLS weight and working residual of each row (module docstring).

    Parameters
    ----------
    r : ndarray, shape (..., m)
        Residuals ``z - h(x)``; NaN = missing row (cost 0, weight 0).
    mean, std : ndarray, broadcast to (..., m)
        The model's noise mean and standard deviation of each row.
    loss : str
    c : float
        Loss scale in units of ``std``.

    Returns
    -------
    cost : ndarray, shape (..., m)
        ``2 rho(u)``.
    weight : ndarray, shape (..., m)
        ``w(u) / std^2``.
    work : ndarray, shape (..., m)
        ``r - mean`` (0 on missing rows).
    """
    e = r - mean
    ok = np.isfinite(e)
    e = np.where(ok, e, 0.0)
    u = e / std
    cost = np.where(ok, 2.0 * rho(u, loss, c), 0.0)
    weight = np.where(ok, irls_weight(u, loss, c) / std ** 2, 0.0)
    return cost, weight, e


def max_mixture_terms(model, z: np.ndarray, state: dict, context, std: np.ndarray,
                      log_prior: np.ndarray, null_std: float | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Cost term, weight, working residual and chosen mode of each row under the max-mixture loss.

    Parameters
    ----------
    model : MeasurementModel
        With ``mode_logpdf(z, state, context) -> (..., m, K)``.
    z : ndarray, shape (..., m)
        Measurements (NaN = missing row).
    state : dict
        The named state components (:meth:`StateLayout.split`).
    context : Context
    std : ndarray, shape (..., m)
        The model's standard deviation of each row (the finite-difference step is
        ``1e-4 std`` and the weight floor ``1e-4 / std^2``).
    log_prior : ndarray, shape (K,) or (K + 1,)
        ``log pi_k`` of each mode (and last of the null hypothesis, with ``null_std``).
    null_std : float, optional
        Add a null-hypothesis mode (Olson & Agarwal's outlier component): a zero-mean
        Gaussian of this standard deviation of the residual, mode index ``K``.

    Returns
    -------
    cost, weight, work : ndarray, shape (..., m)
    mode : ndarray of int, shape (..., m)
        The mode chosen per row (-1 on missing rows).
    """
    z = np.asarray(z, dtype=float)
    ok = np.isfinite(z)
    zf = np.where(ok, z, 0.0)
    h = 1e-4 * std
    def modes(zz):
        lp = model.mode_logpdf(zz, state, context)
        if null_std is not None:
            r = model.residual(zz, model.predict(state, context))
            lp = np.concatenate([lp, gaussian_logpdf(r, null_std)[..., None]], axis=-1)
        return lp + log_prior
    lp0, lpp, lpm = modes(zf), modes(zf + h), modes(zf - h)
    k = np.argmax(lp0, axis=-1)

    def pick(a):
        return np.take_along_axis(a, k[..., None], axis=-1)[..., 0]
    l0, lp, lm = pick(lp0), pick(lpp), pick(lpm)
    # d/dr = d/dz (the residual is z - h(x))
    grad = (lp - lm) / (2.0 * h)                  # d log p / dr
    curv = -(lp - 2.0 * l0 + lm) / (h * h)         # -d^2 log p / dr^2
    curv = np.maximum(curv, 1e-4 / std ** 2)
    cost = np.where(ok, -2.0 * l0, 0.0)
    weight = np.where(ok, curv, 0.0)
    work = np.where(ok, -grad / curv, 0.0)
    return cost, weight, work, np.where(ok, k, -1)
