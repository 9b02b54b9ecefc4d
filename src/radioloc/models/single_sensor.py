"""Squared ranges to one moving sensor as a linear model in [Y_k, X_k, V_y, V_x] (paper 002).

With the motion model of :mod:`radioloc.models.track_noise`, the target at sample n is
``p_n = p_k + (n-k) T v_k + eps_n``. For a sensor at ``s_n = (a_n, b_n)`` and a measured
range ``rhat_n = r_n + omega_n`` (eq. 12)::

    y_n := rhat_n^2 - a_n^2 - b_n^2 = q_n(beta) + A_n [Y_k, X_k, V_y, V_x]^T + e_n
    A_n = [-2 b_n, -2 a_n, -2 (n-k) T b_n, -2 (n-k) T a_n]
    e_n = 2 dx_n eps_x,n + 2 dy_n eps_y,n + eps_x,n^2 + eps_y,n^2 + 2 omega_n r_n + omega_n^2

where ``q_n`` collects the X_k^2, X_k V_x, V_x^2 (and y) terms, whose coefficients are
polynomials of degree <= 2 in n, and ``d_n = p_k + (n-k) T v_k - s_n``. ``e_n`` is ``-Q_{k,n}``
of eq. (13) (``-Z_{k,n}`` of eq. (8) on an ideal channel). The third-difference matrix S of
eq. (10) annihilates ``q_n`` (eq. 9) and leaves ``S y = S A beta + S e``.

Noise moments (own derivation, docs/p002.md; the accelerations and channel noise are
independent, zero-mean and symmetric)::

    E[e_n] = Var(eps_x,n) + Var(eps_y,n) + xi_n                        (step 1)
    cov(e_i, e_j) = 4 (dx_i dx_j + dy_i dy_j) c_ij + 2 cov(eps_i^2, eps_j^2)
                    + delta_ij [4 xi_i E(r_i^2) + (2 + kappa_w) xi_i^2]

with ``c_ij = E[eps_i eps_j]``. With Gaussian accelerations and channel noise this is eq. (11)
(ideal channel) and the diagonal of eq. (13)-(14). Two printed details differ and are not
used: the off-diagonal terms ``-2 xi_j Var(eps_i) - 2 xi_i Var(eps_j)`` of eq. (14) (the
channel noise is independent across samples and of the motion noise, so it adds nothing off
the diagonal), and eq. (14)'s ``S Sigma_Z S^T``, which must read ``S Sigma_Q S^T``.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.validation import as_float_array, check_positive
from radioloc.models.track_noise import (
    accumulated_noise_covariance,
    squared_noise_covariance,
)

#: order of the parameters of the linear model
STATE_NAMES = ("Y_k", "X_k", "V_y", "V_x")
MIN_SAMPLES = 7


def third_difference(n_samples: int) -> np.ndarray:
    """The (n-3) x n third-difference matrix S of eq. (10): rows ``[1, -3, 3, -1]``."""
    n = int(n_samples)
    if n < 4:
        raise InputError(f"n_samples: the third difference needs >= 4 samples, got {n}")
    s = np.zeros((n - 3, n))
    idx = np.arange(n - 3)
    for j, w in enumerate((1.0, -3.0, 3.0, -1.0)):
        s[idx, idx + j] = w
    return s


def difference_rows(m: np.ndarray) -> np.ndarray:
    """``S m`` along axis -2 by slicing (O(n) per column instead of a dense product)."""
    return m[..., :-3, :] - 3.0 * m[..., 1:-2, :] + 3.0 * m[..., 2:-1, :] - m[..., 3:, :]


def difference_both(m: np.ndarray) -> np.ndarray:
    """``S m S^T`` for (..., n, n) by slicing."""
    return np.swapaxes(difference_rows(np.swapaxes(difference_rows(m), -1, -2)), -1, -2)


def check_sensor_path(sensor: np.ndarray, *, rtol: float = 1e-9) -> None:
    """Reject a sensor path whose coordinates are polynomials of degree <= 2 in n.

    S of eq. (10) maps such a coordinate to zero, which deletes the X_k (or Y_k) column of
    ``S A`` and makes the V columns collinear: the state is not identifiable.

    Raises
    ------
    GeometryError
        Naming the coordinate (a_n or b_n) and, for a batch, the first bad run.
    """
    scale = np.max(np.abs(sensor), axis=-2) + 1.0                 # (..., 2)
    third = np.max(np.abs(np.diff(sensor, n=3, axis=-2)), axis=-2)  # (..., 2)
    bad = third <= rtol * scale
    if np.any(bad):
        where = np.argwhere(bad)[0]
        coord = "a_n (x)" if where[-1] == 0 else "b_n (y)"
        run = "" if where.size == 1 else f" in run {tuple(int(i) for i in where[:-1])}"
        raise GeometryError(
            f"sensor: the sensor path coordinate {coord}{run} is a polynomial of degree <= 2 "
            "in the sample index (e.g. a fixed sensor or one moving at constant velocity or "
            "acceleration); the third difference S of eq. (10) annihilates it and the target "
            "state is not identifiable. Move the sensor along a path that is not quadratic in n.")


def design_matrix(sensor: np.ndarray, sample_period_s: float, reference_index: int) -> np.ndarray:
    """Rows ``A_n = [-2 b_n, -2 a_n, -2 (n-k) T b_n, -2 (n-k) T a_n]``, shape (..., n, 4)."""
    n = sensor.shape[-2]
    t = (np.arange(n) - reference_index) * sample_period_s
    a, b = sensor[..., 0], sensor[..., 1]
    return -2.0 * np.stack([b, a, t * b, t * a], axis=-1)


def predicted_offsets(state: np.ndarray, sensor: np.ndarray, sample_period_s: float,
                      reference_index: int) -> np.ndarray:
    """``d_n = p_k + (n-k) T v_k - s_n`` as (..., n, 2) in (x, y) from ``[Y, X, V_y, V_x]``."""
    n = sensor.shape[-2]
    t = (np.arange(n) - reference_index)[:, None] * sample_period_s
    pos = state[..., None, [1, 0]]
    vel = state[..., None, [3, 2]]
    return pos + t * vel - sensor


def trajectory(state: np.ndarray, n_samples: int, sample_period_s: float,
               reference_index: int) -> np.ndarray:
    """Positions ``(x, y)`` of the straight track ``p_k + (n-k) T v_k``, shape (..., n, 2)."""
    t = (np.arange(n_samples) - reference_index)[:, None] * sample_period_s
    return state[..., None, [1, 0]] + t * state[..., None, [3, 2]]


class SquaredRangeModel:
    """Noise moments of the squared-range linear model (eqs. 8, 11-14), per axis variance equal.

    Parameters
    ----------
    n_samples, reference_index : int
        n and k.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2`` per axis.
    range_var : float or array (..., n)
        Channel noise variance ``xi_n`` (0 = ideal channel).
    accel_excess_kurtosis, range_excess_kurtosis : float
        Excess kurtosis of the accelerations and the channel noise; 0 reproduces the printed
        Gaussian-moment formulas, -1.2 is exact for uniform noise.
    printed_eq14 : bool
        Add the off-diagonal terms ``-2 xi_j Var(eps_i) - 2 xi_i Var(eps_j)`` printed in
        eq. (14) (not part of the derived covariance; kept to measure what they change).
    """

    def __init__(self, n_samples: int, reference_index: int, sample_period_s: float,
                 accel_var: float, range_var=0.0, accel_excess_kurtosis: float = 0.0,
                 range_excess_kurtosis: float = 0.0, printed_eq14: bool = False):
        self.printed_eq14 = bool(printed_eq14)
        self.n = int(n_samples)
        if self.n < MIN_SAMPLES:
            raise InputError(f"ranges: need >= {MIN_SAMPLES} samples for 4 unknowns after the "
                             f"third difference, got {self.n}")
        self.k = int(reference_index)
        self.T = check_positive(sample_period_s, "sample_period_s")
        self.c = accumulated_noise_covariance(self.n, self.k, self.T, accel_var)
        self.c_sq = squared_noise_covariance(self.n, self.k, self.T, accel_var,
                                             accel_excess_kurtosis)
        self.xi = as_float_array(range_var, "range_var", nonnegative=True)
        self.kappa_w = float(range_excess_kurtosis)
        self.S = third_difference(self.n)

    def noise_mean(self) -> np.ndarray:
        """``E[e_n] = 2 Var(eps_n) + xi_n`` (step 1), shape (..., n)."""
        return 2.0 * np.diag(self.c) + self.xi * np.ones(self.n)

    def noise_covariance(self, state: np.ndarray, sensor: np.ndarray) -> np.ndarray:
        """``cov(e)`` evaluated at ``state`` (eq. 11 / 13 with the corrections above), (..., n, n)."""
        d = predicted_offsets(state, sensor, self.T, self.k)
        dd = d[..., :, None, 0] * d[..., None, :, 0] + d[..., :, None, 1] * d[..., None, :, 1]
        cov = 4.0 * dd * self.c + 2.0 * self.c_sq
        if np.any(self.xi > 0):
            r2 = np.sum(d**2, axis=-1) + 2.0 * np.diag(self.c)          # E[r_n^2]
            xi = self.xi * np.ones(self.n)
            extra = 4.0 * xi * r2 + (2.0 + self.kappa_w) * xi**2
            cov = cov + extra[..., :, None] * np.eye(self.n)
            if self.printed_eq14:
                var = np.diag(self.c)
                off = 2.0 * (xi[..., None, :] * var[:, None] + xi[..., :, None] * var[None, :])
                cov = cov - off * (1.0 - np.eye(self.n))
        return cov

    def differenced_covariance(self, state: np.ndarray, sensor: np.ndarray) -> np.ndarray:
        """``S cov(e) S^T`` (eq. 11 / 14), shape (..., n-3, n-3)."""
        return difference_both(self.noise_covariance(state, sensor))

    def fisher_information(self, state: np.ndarray, sensor: np.ndarray) -> np.ndarray:
        """``A' S' (S Sigma S')^{-1} S A`` of eq. (22), shape (..., 4, 4)."""
        sa = difference_rows(design_matrix(sensor, self.T, self.k))
        w = self.differenced_covariance(state, sensor)
        try:
            chol = np.linalg.cholesky(w)
        except np.linalg.LinAlgError:
            raise GeometryError("noise covariance S Sigma S^T is not positive definite "
                                "(zero motion and channel noise?)") from None
        white = _solve_lower(chol, sa)
        return np.swapaxes(white, -1, -2) @ white


def _solve_lower(chol: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """``L^{-1} rhs`` for a (batch of) lower-triangular ``L`` (batched LAPACK solve)."""
    return np.linalg.solve(chol, rhs)


def validate_inputs(ranges, sensor, reference_index):
    """Shared boundary checks: ranges (..., n) >= 0, sensor (n, 2) or (..., n, 2), k in range."""
    r = as_float_array(ranges, "ranges", min_ndim=1, nonnegative=True)
    s = as_float_array(sensor, "sensor", min_ndim=2, last_dim=2)
    n = r.shape[-1]
    if s.shape[-2] != n:
        raise InputError(f"sensor: has {s.shape[-2]} positions but ranges has {n} samples")
    if n < MIN_SAMPLES:
        raise InputError(f"ranges: need >= {MIN_SAMPLES} samples, got {n}")
    k = n - 1 if reference_index is None else int(reference_index)
    if not 0 <= k < n:
        raise InputError(f"reference_index: must lie in [0, {n - 1}], got {reference_index}")
    check_sensor_path(s)
    return r, s, k
