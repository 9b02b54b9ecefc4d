"""Tracking over the places of a :class:`~radioloc.models.fingerprint_mixture.FingerprintMixture`:
the recursive Bayes filter of paper 004 (Sect. 4, prediction by the uniform-disk motion model,
filter step by the measurement density) with the density held as weights on the fixed place
components, a forward (hidden-Markov) filter.

Prediction over ``dt`` moves the mass of place ``i`` to the places ``j`` at distance
``d_ij`` with weight 1 for ``d_ij <= r = v_max dt`` (the uniform disk of the motion model,
here on the discrete places) and ``exp(-(d_ij - r)^2 / (2 s^2))`` beyond, cut at ``r + 3 s``,
``s^2`` the mean position variance of the places (the disk convolved with the places' own
spread), each row normalised: ``p_t^-(j) = sum_i p_{t-1}(i) A_ij``. The filter step
multiplies by the tempered scan likelihood: ``p_t(j) ∝ p_t^-(j) L_j(m_t)^(1/T)``. The
estimate at each step is the one-shot rule applied to ``p_t``
(:func:`~radioloc.models.fingerprint_mixture.place_weights`: zone, then the ``M`` heaviest
places) and its moments. One matrix-vector product per step; ``A`` is built once
per distinct ``dt`` rounded to 50 ms.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist
from scipy.special import logsumexp

from radioloc.core.errors import InputError
from radioloc.core.results import Track
from radioloc.core.validation import as_float_array, check_memory
from radioloc.models.fingerprint_mixture import FingerprintMixture, place_moments, place_weights

__all__ = ["place_transition", "track_places"]


def place_transition(model: FingerprintMixture, radius_m: float) -> np.ndarray:
    """Row-stochastic transition ``A`` ``(K, K)`` of the places over one step (module
    docstring).

    Parameters
    ----------
    model : FingerprintMixture
        The fitted model (its place positions and variances).
    radius_m : float
        Disk radius ``r = v_max dt``, metres (>= 0).

    Returns
    -------
    ndarray, shape (K, K)
    """
    k = model.n_places
    check_memory(24.0 * k * k, "places", "the place transition matrix")
    s = float(np.sqrt(np.mean(model.position_variances)))
    d = cdist(model.positions, model.positions)
    a = np.where(d <= radius_m, 1.0, np.exp(-0.5 * ((d - radius_m) / s) ** 2))
    a[d > radius_m + 3 * s] = 0.0
    return a / a.sum(1, keepdims=True)


def track_places(model: FingerprintMixture, rss, time_s, v_max_m_per_s: float = 1.5,
                 temperature: float = 1.0, top_places: int | None = None) -> Track:
    """Track one mobile over its scans (module docstring).

    Parameters
    ----------
    model : FingerprintMixture
        The fitted model.
    rss : array_like, shape (N, S)
        Scans in time order, dBm, NaN = not detected.
    time_s : array_like, shape (N,)
        Non-decreasing scan times, seconds.
    v_max_m_per_s : float
        Maximum speed (>= 0; paper: 1.5 m/s).
    temperature : float
        ``T >= 1`` of the likelihood.
    top_places : int, optional
        Places kept in each estimate (None = all).

    Returns
    -------
    Track
        ``position`` ``(N, D)``, ``covariance`` ``(N, D, D)``, ``time`` ``(N,)``.

    Raises
    ------
    InputError
        Shapes, decreasing times, a negative speed, ``temperature`` < 1.
    """
    m = as_float_array(rss, "rss", ndim=2, allow_nan=True)
    t = as_float_array(time_s, "time_s", ndim=1)
    if m.shape[1] != model.n_stations:
        raise InputError(f"rss: {m.shape[1]} station columns, the model has {model.n_stations}")
    if t.size != m.shape[0]:
        raise InputError(f"time_s: {t.size} times for {m.shape[0]} scans")
    if np.any(np.diff(t) < 0):
        i = int(np.flatnonzero(np.diff(t) < 0)[0]) + 1
        raise InputError(f"time_s: decreases at row {i}")
    if not np.isfinite(v_max_m_per_s) or v_max_m_per_s < 0:
        raise InputError(f"v_max_m_per_s: must be a finite number >= 0, got {v_max_m_per_s!r}")
    if not np.isfinite(temperature) or temperature < 1:
        raise InputError(f"temperature: must be a finite number >= 1, got {temperature!r}")
    ll = model.loglik(m) / temperature + model.log_prior
    cache: dict[int, np.ndarray] = {}
    logp = np.empty_like(ll)
    for i in range(len(t)):                      # a loop over time steps
        if i == 0:
            prior = model.log_prior
        else:
            key = int(round(20.0 * (t[i] - t[i - 1])))
            if key not in cache:
                cache[key] = np.ascontiguousarray(   # A^T, rows contiguous for A^T p
                    place_transition(model, v_max_m_per_s * key / 20.0).T)
            prev = np.exp(logp[i - 1] - logp[i - 1].max())
            with np.errstate(divide="ignore"):
                prior = np.log(cache[key] @ prev)
        logp[i] = prior + ll[i] - model.log_prior
        logp[i] -= logsumexp(logp[i])
    w, _ = place_weights(model, logp, 1.0, top_places)
    mean, cov = place_moments(model, w)
    return Track(mean, cov, t)
