"""Squared ranges to one moving sensor as a linear model in the state (paper 002).

With the motion model of :mod:`radioloc.models.track_noise`, the target at sample n is
``p_n = p_k + (n-k) T v_k + eps_n``. For a sensor at ``s_n = (a_n, b_n)`` and a measured
range ``rhat_n = r_n + omega_n`` (eq. (12))::

    y_n := rhat_n^2 - a_n^2 - b_n^2 = q_n(beta) + A_n beta + e_n
    beta = [x_k, y_k, vx_k, vy_k]
    A_n = [-2 a_n, -2 b_n, -2 (n-k) T a_n, -2 (n-k) T b_n]
    e_n = 2 dx_n eps_x,n + 2 dy_n eps_y,n + eps_x,n^2 + eps_y,n^2 + 2 omega_n r_n + omega_n^2

(the paper orders the unknowns ``[Y_k, X_k, V_y, V_x]``; every public array here is
``(x, y)`` first), where ``q_n`` collects the ``x_k^2``, ``x_k vx_k``, ``vx_k^2`` (and y)
terms, whose coefficients are polynomials of degree <= 2 in n, and
``d_n = p_k + (n-k) T v_k - s_n``. ``e_n`` is ``-Q_{k,n}`` of eq. (13) (``-Z_{k,n}`` of
eq. (8) on an ideal channel). The third-difference matrix S of eq. (10) annihilates ``q_n``
(eq. (9)) and leaves ``S y = S A beta + S e``.

Noise moments (own derivation, docs/p002.md; the accelerations and channel noise are
independent, zero-mean and symmetric)::

    E[e_n] = Var(eps_x,n) + Var(eps_y,n) + xi_n                        (step 1)
    cov(e_i, e_j) = 4 (dx_i dx_j + dy_i dy_j) c_ij + 2 cov(eps_i^2, eps_j^2)
                    + delta_ij [4 xi_i E(r_i^2) + (2 + kappa_w) xi_i^2]

with ``c_ij = E[eps_i eps_j]``. With Gaussian accelerations and channel noise this is
eq. (11) (ideal channel) and the diagonal of eq. (13), eq. (14). Two printed details differ
and are not used: the off-diagonal terms ``-2 xi_j Var(eps_i) - 2 xi_i Var(eps_j)`` of
eq. (14) (the channel noise is independent across samples and of the motion noise, so it
adds nothing off the diagonal), and eq. (14)'s ``S Sigma_Z S^T``, which must read
``S Sigma_Q S^T``.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.validation import as_float_array, check_positive, check_ranges
from radioloc.models.track_noise import (
    accumulated_noise_covariance,
    squared_noise_covariance,
)

__all__ = [
    "STATE_NAMES", "MIN_SAMPLES", "third_difference", "difference_rows", "difference_both",
    "check_sensor_path", "design_matrix", "predicted_offsets", "trajectory",
    "SquaredRangeModel", "validate_inputs", "resolve_sampling",
]

#: order of the state (and of the parameters of the linear model)
STATE_NAMES = ("x_k", "y_k", "vx_k", "vy_k")
#: 4 unknowns need 4 equations after the third difference removes 3
MIN_SAMPLES = 7


def third_difference(n_samples: int) -> np.ndarray:
    """The third-difference matrix S of eq. (10): rows ``[1, -3, 3, -1]``.

    Parameters
    ----------
    n_samples : int
        Number of samples n (>= 4).

    Returns
    -------
    ndarray, shape (n - 3, n)
    """
    n = int(n_samples)
    if n < 4:
        raise InputError(f"n_samples: the third difference needs >= 4 samples, got {n}")
    s = np.zeros((n - 3, n))
    idx = np.arange(n - 3)
    for j, w in enumerate((1.0, -3.0, 3.0, -1.0)):
        s[idx, idx + j] = w
    return s


def difference_rows(m: np.ndarray) -> np.ndarray:
    """``S m`` along axis -2 by slicing (O(n) per column instead of a dense product).

    Parameters
    ----------
    m : ndarray, shape (..., n, p)

    Returns
    -------
    ndarray, shape (..., n - 3, p)
    """
    return m[..., :-3, :] - 3.0 * m[..., 1:-2, :] + 3.0 * m[..., 2:-1, :] - m[..., 3:, :]


def difference_both(m: np.ndarray) -> np.ndarray:
    """``S m S^T`` by slicing.

    Parameters
    ----------
    m : ndarray, shape (..., n, n)

    Returns
    -------
    ndarray, shape (..., n - 3, n - 3)
    """
    return np.swapaxes(difference_rows(np.swapaxes(difference_rows(m), -1, -2)), -1, -2)


def check_sensor_path(sensor: np.ndarray, *, rtol: float = 1e-9) -> None:
    """Reject a sensor path whose coordinates are polynomials of degree <= 2 in n.

    S of eq. (10) maps such a coordinate to zero, which deletes the x_k (or y_k) column of
    ``S A`` and makes the velocity columns collinear: the state is not identifiable.

    Parameters
    ----------
    sensor : ndarray, shape (..., n, 2)
        Sensor positions ``(a_n, b_n)``.
    rtol : float
        A coordinate whose largest third difference is below ``rtol`` times its scale
        counts as quadratic.

    Returns
    -------
    None

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
            f"sensor_path: the sensor path coordinate {coord}{run} is a polynomial of degree "
            "<= 2 in the sample index (e.g. a fixed sensor or one moving at constant velocity "
            "or acceleration); the third difference S of eq. (10) annihilates it and the "
            "target state is not identifiable. Move the sensor along a path that is not "
            "quadratic in n.")


def design_matrix(sensor: np.ndarray, sample_period_s: float, reference_index: int) -> np.ndarray:
    """Rows ``A_n`` of the linear model (eq. (7)) for the state ``[x_k, y_k, vx_k, vy_k]``.

    ``A_n = [-2 a_n, -2 b_n, -2 (n-k) T a_n, -2 (n-k) T b_n]``; the paper prints the same
    rows for its order ``[Y_k, X_k, V_y, V_x]``, i.e. with the columns swapped in pairs.

    Parameters
    ----------
    sensor : ndarray, shape (..., n, 2)
        Sensor positions ``(a_n, b_n)``.
    sample_period_s : float
        T.
    reference_index : int
        k.

    Returns
    -------
    ndarray, shape (..., n, 4)
    """
    n = sensor.shape[-2]
    t = (np.arange(n) - reference_index) * sample_period_s
    a, b = sensor[..., 0], sensor[..., 1]
    return -2.0 * np.stack([a, b, t * a, t * b], axis=-1)


def predicted_offsets(state: np.ndarray, sensor: np.ndarray, sample_period_s: float,
                      reference_index: int) -> np.ndarray:
    """``d_n = p_k + (n-k) T v_k - s_n``.

    Parameters
    ----------
    state : ndarray, shape (..., 4)
        ``[x_k, y_k, vx_k, vy_k]``.
    sensor : ndarray, shape (..., n, 2)
        Sensor positions.
    sample_period_s : float
        T.
    reference_index : int
        k.

    Returns
    -------
    ndarray, shape (..., n, 2)
        ``(x, y)`` offsets from the sensor to the straight track.
    """
    return trajectory(state, sensor.shape[-2], sample_period_s, reference_index) - sensor


def trajectory(state: np.ndarray, n_samples: int, sample_period_s: float,
               reference_index: int) -> np.ndarray:
    """The straight track ``p_k + (n-k) T v_k`` (eq. (4) without its noise) at every sample.

    Parameters
    ----------
    state : ndarray, shape (..., 4)
        ``[x_k, y_k, vx_k, vy_k]``.
    n_samples : int
        n.
    sample_period_s : float
        T.
    reference_index : int
        k.

    Returns
    -------
    ndarray, shape (..., n, 2)
        Positions ``(x, y)``.
    """
    t = (np.arange(n_samples) - reference_index)[:, None] * sample_period_s
    state = np.asarray(state, dtype=float)
    return state[..., None, :2] + t * state[..., None, 2:]


class SquaredRangeModel:
    """Noise moments of the squared-range linear model (eq. (8), eq. (11), eq. (13),
    eq. (14)); both axes have the same acceleration variance.

    Parameters
    ----------
    n_samples, reference_index : int
        n and k.
    sample_period_s : float
        T.
    accel_var : float
        ``delta_g^2`` per axis.
    std_m : float or array (..., n)
        Channel noise standard deviation, metres: the variance is ``xi_n = std_m^2``
        (0 = ideal channel). The old keyword ``range_var`` (the variance ``xi_n``, also the
        fifth positional argument) still works with a ``FutureWarning``.
    accel_excess_kurtosis, range_excess_kurtosis : float
        Excess kurtosis of the accelerations and the channel noise; 0 reproduces the printed
        Gaussian-moment formulas, -1.2 is exact for uniform noise.
    printed_eq14 : bool
        Add the off-diagonal terms ``-2 xi_j Var(eps_i) - 2 xi_i Var(eps_j)`` printed in
        eq. (14) (not part of the derived covariance; kept to measure what they change).
    """

    @renamed_keywords({"range_var": Renamed("std_m", variance=True)},
                      positional=("range_var", "accel_excess_kurtosis", "range_excess_kurtosis",
                                  "printed_eq14"))
    def __init__(self, n_samples: int, reference_index: int, sample_period_s: float,
                 accel_var: float, *, std_m=0.0, accel_excess_kurtosis: float = 0.0,
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
        self.std_m = as_float_array(std_m, "std_m", nonnegative=True)
        self.xi = self.std_m**2
        self.kappa_w = float(range_excess_kurtosis)
        self.S = third_difference(self.n)

    def noise_mean(self) -> np.ndarray:
        """``E[e_n] = 2 Var(eps_n) + xi_n``, subtracted in step 1.

        Returns
        -------
        ndarray, shape (..., n)
        """
        return 2.0 * np.diag(self.c) + self.xi * np.ones(self.n)

    def noise_covariance(self, state: np.ndarray, sensor: np.ndarray) -> np.ndarray:
        """``cov(e)`` evaluated at ``state`` (eq. (11), eq. (13) with the corrections above).

        Parameters
        ----------
        state : ndarray, shape (..., 4)
            ``[x_k, y_k, vx_k, vy_k]`` at which the covariance is evaluated.
        sensor : ndarray, shape (..., n, 2)
            Sensor positions.

        Returns
        -------
        ndarray, shape (..., n, n)
        """
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
        """``S cov(e) S^T`` (eq. (11), eq. (14)).

        Parameters
        ----------
        state : ndarray, shape (..., 4)
            ``[x_k, y_k, vx_k, vy_k]``.
        sensor : ndarray, shape (..., n, 2)
            Sensor positions.

        Returns
        -------
        ndarray, shape (..., n - 3, n - 3)
        """
        return difference_both(self.noise_covariance(state, sensor))

    def fisher_information(self, state: np.ndarray, sensor: np.ndarray) -> np.ndarray:
        """``A' S' (S Sigma S')^{-1} S A`` of eq. (22) at ``state``.

        Parameters
        ----------
        state : ndarray, shape (..., 4)
            ``[x_k, y_k, vx_k, vy_k]``.
        sensor : ndarray, shape (..., n, 2)
            Sensor positions.

        Returns
        -------
        ndarray, shape (..., 4, 4)
            In the state order ``[x_k, y_k, vx_k, vy_k]``.
        """
        sa = difference_rows(design_matrix(sensor, self.T, self.k))
        w = self.differenced_covariance(state, sensor)
        try:
            chol = np.linalg.cholesky(w)
        except np.linalg.LinAlgError:
            raise GeometryError("noise covariance S Sigma S^T is not positive definite "
                                "(zero motion and channel noise?)") from None
        white = np.linalg.solve(chol, sa)
        return np.swapaxes(white, -1, -2) @ white


def validate_inputs(ranges, sensor, reference_index, *, allow_nan: bool = False,
                    std_m: object = 0.0):
    """Boundary checks shared by the paper-002 estimators and bounds.

    Parameters
    ----------
    ranges : array_like, shape (..., n)
        Measured ranges (>= 0; NaN only with ``allow_nan``).
    sensor : array_like, shape (n, 2) or (..., n, 2)
        Sensor positions; must not be quadratic in n (:func:`check_sensor_path`).
    reference_index : int or None
        k; ``None`` is the last sample n-1; negative values count from the end.
    allow_nan : bool
        Whether NaN ranges (missing samples) are allowed.
    std_m : float or array_like
        Range noise standard deviation of :func:`~radioloc.core.validation.check_ranges`
        (0: every negative range is refused).

    Returns
    -------
    ranges : ndarray, shape (..., n)
    sensor : ndarray, shape (..., n, 2)
    k : int

    Raises
    ------
    InputError
        Bad shapes, negative or infinite ranges, a NaN range (without ``allow_nan``,
        naming the sample), fewer than ``MIN_SAMPLES`` samples, k out of range.
    GeometryError
        A sensor path quadratic in n.
    """
    r = as_float_array(ranges, "ranges", min_ndim=1, allow_nan=True)
    if np.any(np.isinf(r)):
        raise InputError("ranges: must be finite (NaN marks a missing sample)")
    check_ranges(r, "ranges", std_m)
    if not allow_nan and np.any(np.isnan(r)):
        bad = tuple(int(i) for i in np.argwhere(np.isnan(r))[0])
        raise InputError(f"ranges: sample n = {bad[-1]} is NaN (index {bad}); the closed form "
                         "needs every sample of its uniformly sampled window: start the window "
                         "after the missing sample")
    s = as_float_array(sensor, "sensor_path", min_ndim=2, last_dim=2)
    n = r.shape[-1]
    if s.shape[-2] != n:
        raise InputError(f"sensor_path: has {s.shape[-2]} positions but ranges has {n} samples")
    try:
        np.broadcast_shapes(r.shape[:-1], s.shape[:-2])
    except ValueError:
        raise InputError(f"sensor_path: batch shape {s.shape[:-2]} does not broadcast with "
                         f"ranges' {r.shape[:-1]}") from None
    if n < MIN_SAMPLES:
        raise InputError(f"ranges: need >= {MIN_SAMPLES} samples, got {n}")
    k = n - 1 if reference_index is None else int(reference_index)
    k = k + n if k < 0 else k
    if not 0 <= k < n:
        raise InputError(f"reference_index: must lie in [-{n}, {n - 1}], got {reference_index}")
    check_sensor_path(s)
    return r, s, k


def resolve_sampling(n_samples: int, reference_index: int, sample_period_s=None, time=None):
    """The sample period T and the time of sample k from either ``sample_period_s`` or ``time``.

    The model of paper 002 needs uniformly spaced samples.

    Parameters
    ----------
    n_samples : int
        n.
    reference_index : int
        k (already resolved to 0..n-1).
    sample_period_s : float, optional
        T in seconds; the samples are then at ``0, T, ..., (n-1) T``.
    time : array_like, shape (n,) or (..., n), optional
        Sample times in seconds (uniformly spaced, the same spacing for every problem).

    Returns
    -------
    T : float
    time_k : float or ndarray
        Time of sample k, seconds (``(...)`` when ``time`` has batch axes).

    Raises
    ------
    InputError
        Neither or both given, or ``time`` of the wrong length, not increasing or not
        uniformly spaced.
    """
    if (sample_period_s is None) == (time is None):
        raise InputError("sample_period_s, time: give exactly one of them")
    if time is None:
        T = check_positive(sample_period_s, "sample_period_s")
        return T, reference_index * T
    t = as_float_array(time, "time", min_ndim=1)
    if t.shape[-1] != n_samples:
        raise InputError(f"time: expected {n_samples} sample times, got shape {t.shape}")
    dt = np.diff(t, axis=-1)
    T = float(np.mean(dt))
    if not T > 0 or np.any(np.abs(dt - T) > 1e-9 * max(1.0, abs(T)) + 1e-6 * T):
        raise InputError("time: sample times must be increasing and uniformly spaced "
                         "(the closed form assumes a constant sample period)")
    return T, t[..., reference_index]
