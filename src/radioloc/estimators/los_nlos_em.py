"""EM estimation of the LOS/NLOS mixture parameters from pooled range errors (paper 001, Sect. V).

The paper names EM for estimating ``alpha`` and the noise parameters. With range errors
``e_i = theta_i - d_i`` (true distances known, or residuals against current estimates) and
an optional common offset ``b`` (a ranging bias, e.g. antenna delay),

* E-step: ``r_i = alpha N(e_i - b; s_LOS) / (alpha N + (1 - alpha) EMG(e_i - b; s_LOS, s_NLOS))``;
* M-step: ``alpha = mean(r)``; ``(b, s_LOS, s_NLOS)`` maximise the expected complete
  log-likelihood (no closed form for the EMG part: a few L-BFGS steps, a generalised EM
  step that never decreases the likelihood).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array
from radioloc.models.los_nlos import LosNlosRange, emg_logpdf, gaussian_logpdf


#: Fewest range errors the EM fit accepts.
MIN_SAMPLES = 10


@dataclass
class EmFit:
    """Result of :func:`fit_los_nlos`.

    Attributes
    ----------
    model : LosNlosRange
        The fitted ``s_LOS``, ``s_NLOS`` and ``alpha``.
    bias_m : float
        The fitted common offset ``b`` (0 when not fitted).
    loglik : ndarray, shape (iterations,)
        Mean log-likelihood per iteration (never decreases).
    responsibility : ndarray, shape (n,)
        LOS responsibility of each sample at the last E-step.
    """

    model: LosNlosRange
    bias_m: float
    loglik: np.ndarray
    responsibility: np.ndarray


def _split_logs(e, b, s, mu, alpha):
    x = e - b
    l1 = gaussian_logpdf(x, s) + np.log(max(alpha, 1e-300))
    l0 = emg_logpdf(x, s, mu) + np.log(max(1.0 - alpha, 1e-300))
    return l0, l1


def _m_step_objective(p: np.ndarray, e: np.ndarray, r: np.ndarray, fit_bias: bool
                      ) -> tuple[float, np.ndarray]:
    """The M-step's objective and its gradient in ``p = (b, log s_LOS, log s_NLOS)``: minus
    the responsibility-weighted mean log-density ``r log N(x; s) + (1 - r) log EMG(x; s,
    mu)`` of ``x = e - b`` (:func:`gaussian_logpdf`, :func:`emg_logpdf`). With ``lam =
    1 / mu``, ``z = x / s``, ``w = z - lam s`` and the Mills ratio ``R = phi(w) / Phi(w)``:
    ``d log N / (db, d log s) = (z / s, z^2 - 1)``; ``d log EMG / (db, d log s, d log mu) =
    (lam - R / s, (lam s)^2 - R (z + lam s), lam x + lam s R - 1 - (lam s)^2)``."""
    from scipy.special import log_ndtr               # here: scipy costs start-up time

    x = e - (p[0] if fit_bias else 0.0)
    s, lam = np.exp(p[1]), np.exp(-p[2])
    z = x / s
    w = z - lam * s
    g = gaussian_logpdf(x, s)
    h = emg_logpdf(x, s, 1.0 / lam)
    mills = np.exp(-0.5 * w * w - 0.5 * np.log(2.0 * np.pi) - log_ndtr(w))
    q = 1.0 - r
    grad = np.array([np.mean(r * z / s + q * (lam - mills / s)) if fit_bias else 0.0,
                     np.mean(r * (z * z - 1.0) + q * ((lam * s) ** 2 - mills * (z + lam * s))),
                     np.mean(q * (lam * x + lam * s * mills - 1.0 - (lam * s) ** 2))])
    return -float(np.mean(r * g + q * h)), -grad


def fit_los_nlos(errors: np.ndarray, *, alpha0: float = 0.5, los_std0: float | None = None,
                 nlos_mean0: float | None = None, fit_bias: bool = True, iterations: int = 50,
                 tol: float = 1e-7) -> EmFit:
    """Fit ``alpha``, ``s_LOS``, ``s_NLOS`` (and a common bias) to range errors by EM.

    Parameters
    ----------
    errors : array_like, shape (n,)
        Measured minus true range, metres (n >= 10).
    alpha0 : float
        Starting LOS fraction.
    los_std0, nlos_mean0 : float, optional
        Starting ``s_LOS`` and ``s_NLOS`` (defaults: a robust spread of the lower half of
        the errors, and the mean excess over the median).
    fit_bias : bool
        Estimate a common offset ``b`` (else ``b = 0``).
    iterations : int
        Maximum EM iterations.
    tol : float
        Stop when the mean log-likelihood improves by less than this.

    Returns
    -------
    EmFit
    """
    from scipy.optimize import minimize              # here: scipy costs start-up time

    e = as_float_array(errors, "errors", ndim=1)
    if e.size < MIN_SAMPLES:
        raise InputError(f"errors: need at least {MIN_SAMPLES} samples, got {e.size}")
    med = float(np.median(e))
    b = med if fit_bias else 0.0
    lo = e[e <= np.quantile(e, 0.5)]
    s = los_std0 or max(float(1.4826 * np.median(np.abs(lo - np.median(lo)))), 1e-3)
    mu = nlos_mean0 or max(float(np.mean(e) - med), 1e-2)
    alpha = float(alpha0)
    # the M-step searches bias and log scales within the span of the errors, so that no
    # trial point overflows the mixture's log-density (exp of an unbounded log scale)
    width = max(float(np.ptp(e)), 1e-3)
    lower = np.array([float(e.min()) - width, np.log(1e-6), np.log(1e-6)])
    upper = np.array([float(e.max()) + width, np.log(10 * width), np.log(10 * width)])
    hist = []
    r = np.full(e.shape, alpha)
    for _ in range(iterations):
        l0, l1 = _split_logs(e, b, s, mu, alpha)
        tot = np.logaddexp(l0, l1)
        hist.append(float(tot.mean()))
        if len(hist) > 1 and hist[-1] - hist[-2] < tol:
            break
        r = np.exp(l1 - tot)
        alpha = float(np.clip(r.mean(), 1e-6, 1 - 1e-6))

        res = minimize(_m_step_objective, np.clip([b, np.log(s), np.log(mu)], lower, upper),
                       args=(e, r, fit_bias), jac=True, method="L-BFGS-B",
                       bounds=list(zip(lower, upper)), options={"maxiter": 20})
        b = float(res.x[0]) if fit_bias else 0.0
        s, mu = float(np.exp(res.x[1])), float(np.exp(res.x[2]))
    return EmFit(LosNlosRange(s, mu, alpha), b, np.array(hist), r)
