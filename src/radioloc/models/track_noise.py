"""Accumulated motion noise of paper 002 relative to a reference sample: eq. (4), eq. (5).

The motion itself is :class:`radioloc.models.motion.ConstantVelocity` (eq. (1): per axis
``X_{m+1} = X_m + T V_m + G_m T^2/2`` and ``V_{m+1} = V_m + T G_m`` with i.i.d. zero-mean
accelerations ``G_m`` of variance ``delta_g^2``; ``distribution="uniform"`` for the paper's
simulation). This module holds the paper-specific moments that the closed-form BLUE and its
bound need. Relative to a reference sample ``k`` (eq. (4), printed without the velocity; the
intended and implemented model is)::

    X_n = X_k + (n - k) T V_{x,k} + eps_{x,n},    eps_{x,n} = T^2 sum_m c_{n,m} G_{x,m}

with ``c_{n,m} = n - m - 1/2`` for ``k <= m < n`` and ``c_{n,m} = m - n + 1/2`` for
``n <= m < k`` (derivation in docs/p002.md). Hence eq. (5),
``Var(eps_n) = |n-k| (4 (n-k)^2 - 1) / 12 T^4 delta_g^2``, and the cross-covariances
``E[eps_i eps_j] = T^4 delta_g^2 sum_m c_{i,m} c_{j,m}`` (zero when i and j lie on
opposite sides of k) that eq. (11) needs.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import check_positive

__all__ = ["noise_coefficients", "accumulated_noise_variance", "accumulated_noise_covariance",
           "squared_noise_covariance"]


def _check_index(n_samples: int, reference_index: int) -> tuple[int, int]:
    n = int(n_samples)
    if n < 1:
        raise InputError(f"n_samples: must be >= 1, got {n_samples}")
    k = int(reference_index)
    if not 0 <= k < n:
        raise InputError(f"reference_index: must lie in [0, {n - 1}], got {reference_index}")
    return n, k


def noise_coefficients(n_samples: int, reference_index: int) -> np.ndarray:
    """Coefficients ``c_{n,m}`` of the accumulated noise, ``eps_n = T^2 sum_m c_{n,m} G_m``.

    Parameters
    ----------
    n_samples : int
        Number of samples n (indices 0..n-1).
    reference_index : int
        The reference sample k of eq. (4).

    Returns
    -------
    ndarray, shape (n, n - 1)
        Row ``i`` holds the weights of the accelerations ``G_0..G_{n-2}`` in ``eps_i``.
    """
    n, k = _check_index(n_samples, reference_index)
    i = np.arange(n)[:, None]
    m = np.arange(max(n - 1, 0))[None, :]
    after = (m >= k) & (m < i)           # n > k: G_k .. G_{n-1}
    before = (m >= i) & (m < k)          # n < k: G_n .. G_{k-1}
    return np.where(after, i - m - 0.5, 0.0) + np.where(before, m - i + 0.5, 0.0)


def accumulated_noise_variance(n_samples: int, reference_index: int, sample_period_s: float,
                               accel_var: float) -> np.ndarray:
    """The variance of eq. (5): ``Var(eps_n) = |n-k| (4 (n-k)^2 - 1) / 12 T^4 delta_g^2``.

    Parameters
    ----------
    n_samples : int
        Number of samples N (indices 0..N-1).
    reference_index : int
        k.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2``.

    Returns
    -------
    ndarray, shape (N,)
    """
    n, k = _check_index(n_samples, reference_index)
    T = check_positive(sample_period_s, "sample_period_s")
    q = check_positive(accel_var, "accel_var", allow_zero=True)
    d = np.abs(np.arange(n) - k).astype(float)
    return d * (4.0 * d**2 - 1.0) / 12.0 * T**4 * q


def accumulated_noise_covariance(n_samples: int, reference_index: int, sample_period_s: float,
                                 accel_var: float) -> np.ndarray:
    """``E[eps_i eps_j] = T^4 delta_g^2 (C C^T)_{ij}`` per axis; its diagonal is eq. (5).

    Parameters
    ----------
    n_samples : int
        Number of samples n.
    reference_index : int
        k.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2``.

    Returns
    -------
    ndarray, shape (n, n)
    """
    T = check_positive(sample_period_s, "sample_period_s")
    q = check_positive(accel_var, "accel_var", allow_zero=True)
    c = noise_coefficients(n_samples, reference_index)
    return T**4 * q * (c @ c.T)


def squared_noise_covariance(n_samples: int, reference_index: int, sample_period_s: float,
                             accel_var: float, excess_kurtosis: float = 0.0) -> np.ndarray:
    """``cov(eps_i^2, eps_j^2)`` per axis.

    ``= 2 E[eps_i eps_j]^2 + kappa delta_g^4 T^8 sum_m c_{i,m}^2 c_{j,m}^2`` where ``kappa`` is
    the excess kurtosis of the acceleration (0 Gaussian, -1.2 uniform). The model of
    eq. (11) uses the Gaussian value (``kappa = 0``).

    Parameters
    ----------
    n_samples : int
        Number of samples n.
    reference_index : int
        k.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2``.
    excess_kurtosis : float
        ``kappa`` of the accelerations.

    Returns
    -------
    ndarray, shape (n, n)
    """
    T = check_positive(sample_period_s, "sample_period_s")
    q = check_positive(accel_var, "accel_var", allow_zero=True)
    c = noise_coefficients(n_samples, reference_index)
    cov = T**4 * q * (c @ c.T)
    return 2.0 * cov**2 + float(excess_kurtosis) * T**8 * q**2 * ((c**2) @ (c**2).T)
