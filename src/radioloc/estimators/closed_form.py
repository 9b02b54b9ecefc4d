"""Closed-form single-sensor tracker: third-difference linearisation + iterative BLUE (paper 002).

Steps of section 3 (ideal channel eq. (11), noisy channel eq. (12), eq. (13), eq. (14)),
batched over problems:

1. subtract the noise mean ``E[e_n]`` from ``y_n = rhat_n^2 - a_n^2 - b_n^2``;
2. apply the third difference S of eq. (10): ``S y = (S A) beta + S e`` (eq. (9));
3a. OLS start ``beta0 = (A~' A~)^{-1} A~' S y``;
3b. evaluate ``Sigma~ = S Sigma(beta_m) S'`` at the current estimate;
3c. BLUE/GLS ``beta_{m+1} = (A~' Sigma~^{-1} A~)^{-1} A~' Sigma~^{-1} S y``;
3d. stop when ``|beta_{m+1} - beta_m| <= tol`` (section 5.2's ``|.|^2 <= 0.1`` is
    ``tol = sqrt(0.1)``) or after ``max_iter`` (the paper's rule, ``stopping="change"``);
    ``stopping="criterion"`` also stops when the GLS criterion ``r' Sigma~^{-1} r`` stops
    decreasing (the previous estimate is kept).

A missing (NaN) range drops the difference rows that involve it: their rows of ``S A``
and ``S y`` are zeroed and their rows and columns of ``S Sigma S'`` decoupled (unit
diagonal), as a Kalman filter masks a missing measurement. The estimate is then the
BLUE of the remaining differences; a NaN at the first sample gives exactly the estimate
of the series without that sample.

The state is ``beta = [x_k, y_k, vx_k, vy_k]`` (the paper orders it ``[Y_k, X_k, V_y, V_x]``);
the model lives in :mod:`radioloc.models.single_sensor`.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.arrays import kernel_array
from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import ConfigError, GeometryError
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.results import Estimate
from radioloc.core.validation import (MAX_ITERATIONS, as_float_array, check_finite_output,
                                      check_int, check_positive, check_real,
                                      range_noise_std)
from radioloc.estimators.base import SnapshotEstimator
from radioloc.models.single_sensor import (
    SquaredRangeModel,
    design_matrix,
    difference_both,
    difference_rows,
    resolve_sampling,
    trajectory,
    validate_inputs,
)

__all__ = ["ClosedFormTracker"]

WEIGHTINGS = ("blue", "ols")
STOPPING = ("change", "criterion")


def _gls(sa: np.ndarray, sy: np.ndarray, w: np.ndarray):
    """Generalised least squares for a batch: returns (beta, covariance, criterion).

    One LU solve ``w^{-1} [S A, S y]`` per problem; the criterion is ``r' w^{-1} r``.
    """
    try:
        sol = np.linalg.solve(w, np.concatenate([sa, sy[..., None]], axis=-1))
    except np.linalg.LinAlgError:
        raise GeometryError("S Sigma S^T is singular (not positive definite); the motion and "
                            "channel noise variances cannot both be zero for the BLUE") from None
    at = np.swapaxes(sa, -1, -2)
    info = at @ sol[..., :4]
    rhs = at @ sol[..., 4:]
    cov = np.linalg.inv(info)
    beta = (cov @ rhs)[..., 0]
    crit = (np.einsum("...i,...i->...", sy, sol[..., 4])
            - np.einsum("...i,...i->...", beta, rhs[..., 0]))
    return beta, cov, crit


def _mask_covariance(w: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """Decouple the dropped difference rows: zero their rows and columns, unit diagonal."""
    if np.all(keep):
        return w
    both = keep[..., :, None] & keep[..., None, :]
    eye = np.eye(keep.shape[-1], dtype=bool)
    return np.where(both, w, np.where(eye, 1.0, 0.0))


def _ols(sa: np.ndarray, sy: np.ndarray) -> np.ndarray:
    """Step 3a, batched: ``(A~' A~)^{-1} A~' S y``."""
    at = np.swapaxes(sa, -1, -2)
    return np.linalg.solve(at @ sa, (at @ sy[..., None]))[..., 0]


class ClosedFormTracker(SnapshotEstimator):
    """The closed-form tracker of paper 002: the iterative BLUE of the differenced model.

    From ranges to one moving sensor over a window of n uniformly spaced samples it
    estimates the straight-track state ``[x_k, y_k, vx_k, vy_k]`` at a reference sample k
    (default the last one: the current position) without iterating on the ranges
    themselves: every step is a linear solve (steps 1-3d, see the module docstring).

    Parameters
    ----------
    accel_var : float
        ``delta_g^2`` of eq. (1), per axis, (m/s^2)^2 (the name and unit of
        :class:`~radioloc.models.motion.ConstantVelocity`'s ``accel_var``).
    std_m : float or array_like, shape (n,) or (..., n), optional
        Range noise standard deviation, metres, per sample if an array: the paper's channel
        noise variance is ``xi_n = std_m^2`` (section 5's ``xi = 0.1 m^2`` is
        ``std_m=sqrt(0.1)``); 0 (the default) is the ideal channel of eq. (11). The old
        keyword ``range_var`` (the variance ``xi_n``, also the second positional argument)
        still works with a ``FutureWarning``.
    measurement : range-error model, optional
        Instead of ``std_m``: a range noise model with ``moments()`` (e.g.
        :class:`~radioloc.models.ranging.GaussianRange`, or
        :class:`~radioloc.models.los_nlos.LosNlosRange`), as :class:`RangeEKF
        <radioloc.estimators.ekf_tracker.RangeEKF>` takes. Its mean error is subtracted from
        the ranges and its variance is ``xi_n``; the fourth moment is still set by
        ``range_excess_kurtosis``.
    reference_index : int, optional
        k; default the last sample (n-1); negative values count from the end.
    weighting : {"blue", "ols"}
        ``"blue"``: the iterative BLUE (the paper's method). ``"ols"``: step 3a only, every
        differenced equation weighted equally (the reading of the paper's MANOVA baseline);
        its covariance is the sandwich ``(A~'A~)^{-1} A~' Sigma~ A~ (A~'A~)^{-1}`` at the
        OLS estimate.
    accel_excess_kurtosis, range_excess_kurtosis : float
        0 (default) uses the Gaussian moments printed in eq. (11)-eq. (14); -1.2 is exact
        for uniform noise.
    tol : float
        Stopping rule ``|beta_{m+1} - beta_m| <= tol`` (Euclidean norm of the change of
        ``[x, y, vx, vy]``); section 5.2's ``|.|^2 <= 0.1`` is the default ``sqrt(0.1)``.
    stopping : {"change", "criterion"}
        ``"change"`` (default, the paper's step 3d): iterate until the change is below
        ``tol`` or ``max_iter``. ``"criterion"``: also stop (keeping the previous estimate)
        as soon as the GLS criterion ``r' Sigma~^{-1} r`` does not decrease.
    max_iter : int
        Maximum BLUE iterations after the OLS start.
    cond_limit : float
        ``S A`` with a column-scaled condition number above this raises ``GeometryError``.
    printed_eq14 : bool
        Use eq. (14)'s printed off-diagonal channel terms (a reading kept for comparison;
        see :class:`~radioloc.models.single_sensor.SquaredRangeModel`).
    backend : {"numba", "numpy"}
        The BLUE iterations 3b-3d by the compiled kernel
        (:func:`~radioloc.estimators.kalman_compiled.blue_iterations`, a Cholesky of
        ``S Sigma S'`` per step) or in NumPy (the batched LU solve); they agree to rounding.
        Steps 1-3a, the OLS weighting and ``covariance_state`` always run in NumPy.

    Examples
    --------
    >>> import numpy as np
    >>> n, T = 20, 0.1
    >>> ang = 1.3 * np.arange(n)
    >>> sensor = 5.0 * np.stack([np.cos(ang), np.sin(ang)], -1)
    >>> truth = np.array([1.0, 0.5]) + (np.arange(n) - (n - 1))[:, None] * T * [0.8, -0.2]
    >>> ranges = np.linalg.norm(truth - sensor, axis=-1)
    >>> est = ClosedFormTracker(accel_var=0.0, std_m=1e-5).locate(ranges, sensor, T)
    >>> np.round(est.position, 6).tolist(), np.round(est.diagnostics["state"][2:], 6).tolist()
    ([1.0, 0.5], [0.8, -0.2])
    """

    name = "closed-form"

    @renamed_keywords({"range_var": Renamed("std_m", variance=True)}, positional=("range_var",))
    def __init__(self, accel_var: float, *, std_m=None, measurement=None,
                 reference_index: int | None = None,
                 weighting: str = "blue", accel_excess_kurtosis: float = 0.0,
                 range_excess_kurtosis: float = 0.0, tol: float = 0.1**0.5,
                 stopping: str = "change", max_iter: int = 20, cond_limit: float = 1e12,
                 printed_eq14: bool = False, backend: str = DEFAULT_BACKEND) -> None:
        self.accel_var = check_positive(accel_var, "accel_var", allow_zero=True)
        self.measurement = measurement
        self._mean_m = 0.0
        if measurement is None:
            self.std_m = as_float_array(0.0 if std_m is None else std_m, "std_m",
                                        nonnegative=True)
            self._range_var = self.std_m**2
            self._floor_std_m = self.std_m
        else:
            if std_m is not None:
                raise ConfigError("ClosedFormTracker: give std_m or measurement, not both")
            if not hasattr(measurement, "moments"):
                raise ConfigError(f"measurement: {type(measurement).__name__} has no moments() "
                                  "(expected a range-error model such as GaussianRange)")
            mean, var = measurement.moments()
            self._mean_m = check_real(mean, "measurement mean error")
            self._range_var = as_float_array(var, "measurement variance", nonnegative=True)
            self.std_m = np.sqrt(self._range_var)
            self._floor_std_m = range_noise_std(measurement)
        if reference_index is not None and not isinstance(reference_index, (int, np.integer)):
            raise ConfigError(f"reference_index: must be an int or None, got {reference_index!r}")
        self.reference_index = None if reference_index is None else int(reference_index)
        if weighting not in WEIGHTINGS:
            raise ConfigError(f"weighting: must be one of {', '.join(WEIGHTINGS)}, "
                              f"got {weighting!r}")
        self.weighting = weighting
        for name, val in (("accel_excess_kurtosis", accel_excess_kurtosis),
                          ("range_excess_kurtosis", range_excess_kurtosis)):
            if not np.isfinite(val) or val < -2.0:
                raise ConfigError(f"{name}: must be finite and >= -2, got {val!r}")
        self.accel_excess_kurtosis = float(accel_excess_kurtosis)
        self.range_excess_kurtosis = float(range_excess_kurtosis)
        self.tol = check_positive(tol, "tol")
        if stopping not in STOPPING:
            raise ConfigError(f"stopping: must be one of {', '.join(STOPPING)}, "
                              f"got {stopping!r}")
        self.stopping = stopping
        self.max_iter = check_int(max_iter, "max_iter", minimum=0, maximum=MAX_ITERATIONS)
        self.cond_limit = check_positive(cond_limit, "cond_limit")
        self.printed_eq14 = bool(printed_eq14)
        self.backend = check_backend(backend)

    def locate(self, ranges, sensor_path, sample_period_s: float | None = None, *,
               time=None, covariance_state=None) -> Estimate:
        """Estimate the state at sample k from one window of ranges (steps 1-3d).

        Parameters
        ----------
        ranges : array_like, shape (..., n)
            Measured ranges ``rhat_n`` (eq. (12)), n >= 7; leading axes are independent
            problems. A NaN range is a missing sample: the difference rows that involve it
            are dropped (at least 4 differences must remain).
        sensor_path : array_like, shape (n, 2) or (..., n, 2)
            Known sensor positions ``(a_n, b_n)``; must not be quadratic in n.
        sample_period_s : float, optional
            T; or give ``time``.
        time : array_like, shape (n,) or (..., n), optional
            Uniformly spaced sample times, seconds.
        covariance_state : array_like, shape (4,) or (..., 4), optional
            If given, one BLUE step with ``Sigma~`` evaluated at this ``[x, y, vx, vy]``
            (e.g. the true state: the oracle BLUE) instead of the iterations 3b-3d.

        Returns
        -------
        Estimate
            ``position`` (..., 2) = ``(x_k, y_k)``, ``covariance`` (..., 2, 2) (its block of
            eq. (15)), ``time`` of sample k; diagnostics ``state`` (..., 4)
            ``[x_k, y_k, vx_k, vy_k]``, ``state_covariance`` (..., 4, 4), ``trajectory``
            (..., n, 2) (the straight track ``p_k + (n-k) T v_k`` at every sample),
            ``ols_state`` (..., 4) (step 3a), ``iterations``, ``converged`` (the step rule
            met), ``stalled`` (``stopping="criterion"``: stopped because the GLS criterion
            no longer decreased), ``used_differences`` (rows of ``S y`` kept).

        Raises
        ------
        InputError
            Bad shapes, negative or infinite ranges, fewer than 7 samples, k out of range,
            non-uniform ``time``.
        GeometryError
            Sensor path quadratic in n, or ``S A`` numerically rank deficient (when missing
            (NaN) ranges leave too few difference rows, the message names ``ranges`` and the
            track), or a singular noise
            covariance (zero motion and channel noise).
        """
        r, s, k = validate_inputs(ranges, sensor_path, self.reference_index, allow_nan=True,
                                  std_m=self._floor_std_m)
        if self._mean_m:
            r = r - self._mean_m                    # the model's mean range error
        n = r.shape[-1]
        T, t_k = resolve_sampling(n, k, sample_period_s, time)
        batch = np.broadcast_shapes(r.shape[:-1], s.shape[:-2], self._range_var.shape[:-1])
        r = np.broadcast_to(r, batch + (n,))
        s = np.broadcast_to(s, batch + (n, 2))
        model = SquaredRangeModel(n, k, T, self.accel_var, std_m=self.std_m,
                                  accel_excess_kurtosis=self.accel_excess_kurtosis,
                                  range_excess_kurtosis=self.range_excess_kurtosis,
                                  printed_eq14=self.printed_eq14)
        sa, sy, keep = self._differenced_system(r, s, k, model)    # steps 1-2

        def cov_at(state):
            return _mask_covariance(model.differenced_covariance(state, s), keep)
        self._check_condition(sa, keep)
        ols = _ols(sa, sy)                                          # step 3a
        ones = np.ones(batch, dtype=bool)
        if self.weighting == "blue" and covariance_state is None and self.backend == "numba":
            return self._iterate_compiled(sa, sy, keep, s, ols, model, batch, t_k)
        if covariance_state is not None:
            fixed = as_float_array(covariance_state, "covariance_state", min_ndim=1, last_dim=4)
            fixed = np.broadcast_to(fixed, batch + (4,))
            beta, cov, _ = _gls(sa, sy, cov_at(fixed))
            return self._estimate(beta, cov, ols, n, T, k, t_k, np.ones(batch, dtype=int),
                                  ones, ~ones, keep)
        if self.weighting == "ols":
            at = np.swapaxes(sa, -1, -2)
            bread = np.linalg.inv(at @ sa)
            cov = bread @ at @ cov_at(ols) @ sa @ bread
            return self._estimate(ols, cov, ols, n, T, k, t_k, np.zeros(batch, dtype=int),
                                  ones, ~ones, keep)
        beta = ols.copy()
        best_crit = np.full(batch, np.inf)
        cov = np.zeros(batch + (4, 4))
        active = np.ones(batch, dtype=bool)
        converged = np.zeros(batch, dtype=bool)
        stalled = np.zeros(batch, dtype=bool)
        iterations = np.zeros(batch, dtype=int)
        for _ in range(self.max_iter):
            if not np.any(active):
                break
            w = cov_at(beta)                                        # step 3b
            new, new_cov, crit = _gls(sa, sy, w)                    # step 3c
            improved = (crit < best_crit) | (self.stopping == "change")
            take = active & improved
            stalled |= active & ~improved
            change = np.sqrt(np.sum((new - beta) ** 2, axis=-1))
            beta = np.where(take[..., None], new, beta)
            cov = np.where(take[..., None, None], new_cov, cov)
            best_crit = np.where(take, crit, best_crit)
            iterations = iterations + take
            done = take & (change <= self.tol)                      # step 3d
            converged |= done
            active = take & ~done
        check_finite_output(beta, "ClosedFormTracker state")
        return self._estimate(beta, cov, ols, n, T, k, t_k, iterations, converged, stalled,
                              keep)

    # ---- helpers --------------------------------------------------------------------
    def _check_condition(self, sa: np.ndarray, keep: np.ndarray | None = None,
                         tracks: np.ndarray | None = None) -> None:
        """GeometryError when ``S A`` (column-scaled) is numerically rank deficient, naming
        ``ranges`` and the track when it is so because difference rows were
        dropped for missing (NaN) ranges (``keep`` (..., n - 3) False). ``tracks``: the
        flat track number of each entry of ``sa`` (default: its flat index)."""
        col = np.linalg.norm(sa, axis=-2, keepdims=True)
        cond = np.linalg.cond(sa / np.where(col > 0, col, 1.0))
        bad = ~np.isfinite(cond) | (cond > self.cond_limit)
        if np.any(bad) and keep is not None:
            rows = keep.reshape(-1, keep.shape[-1])
            gap = np.ravel(bad) & ~np.all(rows, axis=-1)
            if np.any(gap):
                i = int(np.flatnonzero(gap)[0])
                track = int(tracks[i]) if tracks is not None else i
                detail = (f"the missing (NaN) ranges leave {int(np.sum(rows[i]))} of "
                          f"{rows.shape[-1]} difference rows, too few to separate "
                          "[x_k, y_k, vx_k, vy_k] (S A rank deficient)")
                raise GeometryError(f"ranges: track {track}: {detail}", detail=detail,
                                    index=(track,))
        if np.any(bad):
            raise GeometryError(f"sensor_path: S A is rank deficient (condition number "
                                f"{np.max(cond):.3g} > {self.cond_limit:.0e}); the sensor path "
                                "does not separate [x_k, y_k, vx_k, vy_k]")

    def _iterate_compiled(self, sa, sy, keep, s, ols, model, batch, t_k) -> Estimate:
        """Steps 3b-3d by :func:`~radioloc.estimators.kalman_compiled.blue_iterations` from
        the OLS start: the iterations of :meth:`locate`'s NumPy loop, track by track."""
        n, k, T = model.n, model.k, model.T
        B = int(np.prod(batch, dtype=np.int64))
        shared = s.ndim == 2 or all(st == 0 for st in s.strides[:-2])
        ss = (s[(0,) * (s.ndim - 2)] if shared else s).reshape(-1, n, 2)
        xi = np.broadcast_to(model.xi, model.xi.shape[:-1] + (n,)) if model.xi.ndim else \
            np.full(n, float(model.xi))
        xi = np.broadcast_to(xi, batch + (n,)).reshape(B, n) if xi.ndim > 1 else xi[None]
        beta = kernel_array(ols.reshape(B, 4).copy())
        cov = np.empty((B, 4, 4))
        iterations = np.empty(B, dtype=np.int64)
        flags = np.empty(B, dtype=np.int64)
        from radioloc.estimators.kalman_compiled import blue_iterations   # numba: imported when the kernel runs (start-up time)

        blue_iterations(kernel_array(sa.reshape(B, n - 3, 4)), kernel_array(sy.reshape(B, n - 3)),
                        kernel_array(keep.reshape(B, n - 3), np.bool_), kernel_array(ss),
                        kernel_array(xi), kernel_array(model.c),
                        kernel_array(difference_both(2.0 * model.c_sq)), (np.arange(n) - k) * T,
                        self.range_excess_kurtosis, self.printed_eq14,
                        kernel_array(np.diag(model.c)), self.tol, self.max_iter,
                        self.stopping == "criterion", beta, cov, iterations, flags)
        if np.any(flags & 4):
            raise GeometryError("S Sigma S^T is singular (not positive definite); the motion "
                                "and channel noise variances cannot both be zero for the BLUE")
        check_finite_output(beta, "ClosedFormTracker state")
        return self._estimate(beta.reshape(batch + (4,)), cov.reshape(batch + (4, 4)), ols, n,
                              T, k, t_k, iterations.reshape(batch), ((flags & 1) > 0).reshape(batch),
                              ((flags & 2) > 0).reshape(batch), keep)

    @staticmethod
    def _differenced_system(r, s, k, model):
        """Steps 1-2: mean-removed ``y`` and its third difference.

        Returns ``(S A, S y, keep)``; ``keep`` (..., n - 3) marks the difference rows
        whose four samples are all present; the others are zeroed.
        """
        missing = np.isnan(r)
        y = np.where(missing, 0.0, r**2 - np.sum(s**2, axis=-1) - model.noise_mean())
        sa = difference_rows(design_matrix(s, model.T, k))
        sy = difference_rows(y[..., None])[..., 0]
        m = missing.astype(float)[..., None]
        keep = (m[..., :-3, 0] + m[..., 1:-2, 0] + m[..., 2:-1, 0] + m[..., 3:, 0]) == 0
        sa = np.where(keep[..., None], np.broadcast_to(sa, sy.shape + (4,)), 0.0)
        sy = np.where(keep, sy, 0.0)
        return sa, sy, keep

    @staticmethod
    def _estimate(beta, cov, ols, n, T, k, t_k, iterations, converged, stalled, keep
                  ) -> Estimate:
        """The Estimate of :meth:`ClosedFormTracker.locate`."""
        traj = trajectory(beta, n, T, k)
        diag = {"state": beta, "state_covariance": cov, "trajectory": traj,
                "ols_state": ols, "iterations": iterations, "converged": converged,
                "stalled": stalled, "used_differences": np.sum(keep, axis=-1)}
        return Estimate(beta[..., :2], cov[..., :2, :2], t_k, diag)
