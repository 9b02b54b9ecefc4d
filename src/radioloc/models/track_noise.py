"""Constant acceleration between samples: the motion model of paper 002, eqs. (1)-(5).

Per axis, ``X_{m+1} = X_m + T V_m + G_m T^2/2`` and ``V_{m+1} = V_m + T G_m`` (eq. 1) with
i.i.d. zero-mean accelerations ``G_m`` of variance ``delta_g^2``. Relative to a reference
sample ``k`` (eq. 4, printed without the velocity; the intended and implemented model is)::

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
from radioloc.core.validation import as_float_array, check_positive


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
    """Eq. (5): ``Var(eps_n) = |n-k| (4 (n-k)^2 - 1) / 12 T^4 delta_g^2`` for n = 0..N-1."""
    n, k = _check_index(n_samples, reference_index)
    T = check_positive(sample_period_s, "sample_period_s")
    q = check_positive(accel_var, "accel_var", allow_zero=True)
    d = np.abs(np.arange(n) - k).astype(float)
    return d * (4.0 * d**2 - 1.0) / 12.0 * T**4 * q


def accumulated_noise_covariance(n_samples: int, reference_index: int, sample_period_s: float,
                                 accel_var: float) -> np.ndarray:
    """``E[eps_i eps_j] = T^4 delta_g^2 (C C^T)_{ij}`` (per axis), shape (n, n).

    Its diagonal equals eq. (5).
    """
    T = check_positive(sample_period_s, "sample_period_s")
    q = check_positive(accel_var, "accel_var", allow_zero=True)
    c = noise_coefficients(n_samples, reference_index)
    return T**4 * q * (c @ c.T)


def squared_noise_covariance(n_samples: int, reference_index: int, sample_period_s: float,
                             accel_var: float, excess_kurtosis: float = 0.0) -> np.ndarray:
    """``cov(eps_i^2, eps_j^2)`` per axis, shape (n, n).

    ``= 2 E[eps_i eps_j]^2 + kappa delta_g^4 T^8 sum_m c_{i,m}^2 c_{j,m}^2`` where ``kappa`` is
    the excess kurtosis of the acceleration (0 Gaussian, -1.2 uniform). Eq. (11) uses the
    Gaussian value (``kappa = 0``).
    """
    T = check_positive(sample_period_s, "sample_period_s")
    q = check_positive(accel_var, "accel_var", allow_zero=True)
    c = noise_coefficients(n_samples, reference_index)
    cov = T**4 * q * (c @ c.T)
    return 2.0 * cov**2 + float(excess_kurtosis) * T**8 * q**2 * ((c**2) @ (c**2).T)


class ConstantAcceleration:
    """Constant acceleration between samples with i.i.d. per-axis accelerations (eq. 1).

    Parameters
    ----------
    sample_period_s : float
        Sampling period T.
    accel_var : float
        Variance ``delta_g^2`` of each acceleration component.
    distribution : {"uniform", "gaussian"}
        Law of the accelerations (zero mean, variance ``accel_var``). Section 5 of the paper
        uses uniform; excess kurtosis -1.2 (uniform) or 0 (Gaussian).
    """

    def __init__(self, sample_period_s: float, accel_var: float, distribution: str = "uniform"):
        self.sample_period_s = check_positive(sample_period_s, "sample_period_s")
        self.accel_var = check_positive(accel_var, "accel_var", allow_zero=True)
        if distribution not in ("uniform", "gaussian"):
            raise InputError(f"distribution: must be 'uniform' or 'gaussian', got {distribution!r}")
        self.distribution = distribution

    @property
    def excess_kurtosis(self) -> float:
        return -1.2 if self.distribution == "uniform" else 0.0

    def sample_accelerations(self, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
        """Draw accelerations of the given shape (zero mean, variance ``accel_var``)."""
        s = np.sqrt(self.accel_var)
        if self.distribution == "uniform":
            return rng.uniform(-np.sqrt(3.0) * s, np.sqrt(3.0) * s, size=shape)
        return rng.normal(0.0, s, size=shape)

    def propagate(self, initial_state: np.ndarray, accelerations: np.ndarray) -> np.ndarray:
        """Apply eq. (1) sample by sample.

        Parameters
        ----------
        initial_state : array (..., 4)
            ``[x, y, vx, vy]`` at sample 0.
        accelerations : array (..., n - 1, 2)
            ``[G_x, G_y]`` between consecutive samples.

        Returns
        -------
        ndarray (..., n, 4)
            ``[x, y, vx, vy]`` at samples 0..n-1.
        """
        s0 = as_float_array(initial_state, "initial_state", last_dim=4, min_ndim=1)
        g = as_float_array(accelerations, "accelerations", last_dim=2, min_ndim=2)
        T = self.sample_period_s
        pos = s0[..., None, :2] + np.zeros(g.shape[:-2] + (1, 2))
        vel = s0[..., None, 2:] + np.zeros(g.shape[:-2] + (1, 2))
        # closed form of eq. (1) iterated: v_n = v_0 + T sum_{m<n} G_m,
        # x_n = x_0 + n T v_0 + T^2 sum_{m<n} (n - m - 1/2) G_m
        dv = np.concatenate([np.zeros_like(g[..., :1, :]), np.cumsum(g, axis=-2)], axis=-2) * T
        n = g.shape[-2] + 1
        c = noise_coefficients(n, 0)                                     # (n, n-1)
        dx = T**2 * np.einsum("nm,...md->...nd", c, g)
        steps = np.arange(n)[:, None] * T
        positions = pos + steps * vel + dx
        velocities = vel + dv
        return np.concatenate([positions, velocities], axis=-1)

    def sample(self, initial_state: np.ndarray, n_samples: int,
               rng: np.random.Generator) -> np.ndarray:
        """Simulate ``n_samples`` states ``[x, y, vx, vy]`` from ``initial_state`` (..., 4)."""
        s0 = as_float_array(initial_state, "initial_state", last_dim=4, min_ndim=1)
        if int(n_samples) < 1:
            raise InputError(f"n_samples: must be >= 1, got {n_samples}")
        g = self.sample_accelerations(s0.shape[:-1] + (int(n_samples) - 1, 2), rng)
        return self.propagate(s0, g)
