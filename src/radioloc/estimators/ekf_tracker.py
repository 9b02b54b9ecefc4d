"""Extended Kalman filter tracking nodes from ranges to known points.

One filter for every range tracker of the toolkit: any linear-Gaussian motion model of
:mod:`radioloc.models.motion` (random walk, constant velocity, constant acceleration,
odometry/INS driven) and any range model with ``moments()`` (Gaussian, or the LOS/NLOS
mixture of paper 001 matched by its mean and variance). The points ranged to can be fixed
anchors, a moving sensor (paper 002: one sensor at a known position per sample) or the
neighbours' broadcast estimates (paper 001's EKF baseline): they are passed per step.

Ranges arrive in rows ``(..., M)`` per step; a NaN range is absent and skipped, so ranges
that arrive one at a time (one finite entry per row) are filtered as they come. The
update is :func:`radioloc.estimators.kalman.kalman_update` (Joseph form).
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import as_float_array, check_finite_output, check_positive, check_real
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.kalman import (
    GaussianState,
    kalman_predict,
    kalman_update,
    normalised_innovation_squared,
)
from radioloc.models.ranging import range_geometry

#: largest prior variance :meth:`RangeEKF.init` accepts (m^2, (m/s)^2, ...)
PRIOR_VARIANCE_LIMIT = 1e12

__all__ = ["RangeEKF"]


class RangeEKF(RecursiveEstimator):
    """Extended Kalman filter on ranges, batched over leading axes.

    Parameters
    ----------
    motion : motion model
        Any model with ``F(dt)``, ``Q(dt)``, ``dim`` and ``state_dim`` (position first),
        e.g. ``ConstantVelocity(accel_var)`` or ``InputDriven(std_m)``.
    measurement : range model
        Any model with ``moments() -> (bias_m, variance_m2)`` of the range error, e.g.
        ``GaussianRange(std_m)`` or ``LosNlosRange(...)`` (moment matched).
    anchors : array_like, shape (M, D) or (..., M, D), optional
        Default points ranged to; each step may pass its own.
    height_m : float, optional
        Known node height for 2-D tracking with 3-D anchors (see
        :func:`radioloc.models.ranging.range_geometry`).
    range_bias_m : float
        Constant offset of every measured range (e.g. an antenna delay), added to the
        measurement model's own mean error: the filter expects ``d + bias``.
    gate : float, optional
        Innovation gate: a range whose squared innovation over its predicted variance
        ``nu_m^2 / S_mm`` (``S = H P H' + R`` before the update) exceeds ``gate`` is
        treated as absent (an outlier), and counted in ``diagnostics['gated']``. E.g.
        ``gate=9`` drops ranges more than three predicted standard deviations off.
        Default 16 (four standard deviations), the gate of ``radioloc locate --method
        ekf-track``; ``None``: no gating (a filter as published without one).
    gate_patience : int
        In :meth:`run`, after this many consecutive steps in which every range was gated,
        the next step's ranges are taken ungated, so that a filter that has lost the node
        finds it again instead of coasting away on its motion model.

    Examples
    --------
    >>> import numpy as np
    >>> from radioloc.models.motion import ConstantVelocity
    >>> from radioloc.models.ranging import GaussianRange
    >>> ekf = RangeEKF(ConstantVelocity(0.1), GaussianRange(0.1),
    ...                anchors=[[0, 0], [10, 0], [0, 10]])
    >>> ranges = np.full((5, 3), np.nan); ranges[:, 0] = 5.0   # one anchor heard
    >>> track = ekf.run(ranges, time=np.arange(5.0), prior_mean=[3, 4, 0, 0],
    ...                 prior_cov=np.eye(4))
    >>> track.position.shape
    (5, 2)
    """

    name = "ekf-track"

    def __init__(self, motion, measurement, anchors=None, height_m: float | None = None,
                 range_bias_m: float = 0.0, gate: float | None = 16.0,
                 gate_patience: int = 10) -> None:
        for attr in ("F", "Q", "dim", "state_dim"):
            if not hasattr(motion, attr):
                raise ConfigError(f"motion: {type(motion).__name__} has no {attr!r}; "
                                  "the EKF needs a linear-Gaussian motion model")
        if not hasattr(measurement, "moments"):
            raise ConfigError(f"measurement: {type(measurement).__name__} has no moments(); "
                              "the EKF needs a range model")
        self.motion = motion
        self.measurement = measurement
        self.anchors = None if anchors is None else as_float_array(anchors, "anchors", min_ndim=2)
        height_m = None if height_m is None else check_real(height_m, "height_m")
        self.height_m = height_m
        range_bias_m = check_real(range_bias_m, "range_bias_m")
        gate = None if gate is None else check_positive(gate, "gate")
        self.range_bias_m = float(range_bias_m)
        self.gate = None if gate is None else float(gate)
        if int(gate_patience) != gate_patience or gate_patience < 1:
            raise ConfigError(f"gate_patience: must be an integer >= 1, got {gate_patience!r}")
        self.gate_patience = int(gate_patience)
        bias, var = measurement.moments()
        if not var > 0:
            raise ConfigError(f"measurement: range error variance must be > 0, got {var}")
        self._bias, self._var = float(bias) + self.range_bias_m, float(var)

    # ---- contract -------------------------------------------------------------------
    def init(self, prior_mean, prior_cov, time: float | np.ndarray = 0.0) -> GaussianState:
        """The state before the first measurement.

        Parameters
        ----------
        prior_mean : array_like, shape (..., n)
            Prior state mean (position first), n = ``motion.state_dim``.
        prior_cov : array_like, shape (n, n) or (..., n, n)
            Prior covariance (symmetric positive definite).
        time : float or ndarray
            Time of the prior, seconds.

        Returns
        -------
        GaussianState
        """
        n = self.motion.state_dim
        mean = as_float_array(prior_mean, "prior_mean", min_ndim=1, last_dim=n)
        cov = as_float_array(prior_cov, "prior_cov", min_ndim=2, last_dim=n)
        if cov.shape[-2] != n:
            raise InputError(f"prior_cov: expected (..., {n}, {n}), got {cov.shape}")
        diag = np.diagonal(cov, axis1=-2, axis2=-1)
        if np.any(diag > PRIOR_VARIANCE_LIMIT):
            idx = tuple(int(i) for i in np.argwhere(diag > PRIOR_VARIANCE_LIMIT)[0])
            raise InputError(f"prior_cov: variance {diag[idx]:g} at diagonal index {idx} is beyond "
                             f"the supported {PRIOR_VARIANCE_LIMIT:g} (the update would lose "
                             "every digit against metre-scale ranges)")
        asym = np.abs(cov - np.swapaxes(cov, -1, -2)) > 1e-9 * (np.abs(cov) + np.abs(
            np.swapaxes(cov, -1, -2))) + 1e-300
        if np.any(asym):
            raise InputError(f"prior_cov: not symmetric (entry {tuple(int(i) for i in np.argwhere(asym)[0])})")
        try:
            np.linalg.cholesky(cov)
        except np.linalg.LinAlgError:
            raise InputError("prior_cov: not symmetric positive definite") from None
        try:
            batch = np.broadcast_shapes(mean.shape[:-1], cov.shape[:-2])
        except ValueError:
            raise InputError(f"prior_cov: batch shape {cov.shape[:-2]} does not broadcast with "
                             f"prior_mean's {mean.shape[:-1]}") from None
        return GaussianState(np.broadcast_to(mean, batch + (n,)).copy(),
                             np.broadcast_to(cov, batch + (n, n)).copy(), time)

    def predict(self, state: GaussianState, dt, control=None) -> GaussianState:
        """Propagate the state by ``dt`` seconds.

        Parameters
        ----------
        state : GaussianState
        dt : float or ndarray, shape (...)
            Interval in seconds (0: no motion noise for a time-driven model).
        control : ndarray, shape (..., D), optional
            Displacement read over the step, for an input-driven model.

        Returns
        -------
        GaussianState
            The predicted state (a new object).
        """
        dt_arr = as_float_array(dt, "dt")
        try:
            np.broadcast_shapes(dt_arr.shape, state.mean.shape[:-1])
        except ValueError:
            raise InputError(f"dt: shape {dt_arr.shape} does not broadcast with the state's "
                             f"batch {state.mean.shape[:-1]}") from None
        u = None
        if control is not None:
            c = as_float_array(control, "control", last_dim=self.motion.dim)
            u = np.zeros(c.shape[:-1] + (self.motion.state_dim,))
            u[..., : self.motion.dim] = c
        mean, cov = kalman_predict(state.mean, state.covariance, self.motion.F(dt_arr),
                                   self.motion.Q(dt_arr), u)
        return GaussianState(mean, cov, state.time + dt_arr)

    def update(self, state: GaussianState, ranges, anchors=None, ungated=None,
               ) -> tuple[GaussianState, dict[str, np.ndarray]]:
        """Update with one row of ranges (NaN = absent, skipped).

        Parameters
        ----------
        state : GaussianState
            The predicted state.
        ranges : ndarray, shape (..., M)
            Measured ranges, metres.
        anchors : ndarray, shape (M, D) or (..., M, D), optional
            Points ranged to (default: the constructor's).
        ungated : ndarray of bool, shape (...), optional
            Problems whose ranges bypass the innovation gate at this step.

        Returns
        -------
        state : GaussianState
        info : dict
            ``innovation`` (..., M) (NaN where absent), ``innovation_covariance``
            (..., M, M), ``nis`` (...), ``measurements_used`` (...), ``gated`` (...):
            ranges dropped by the innovation gate.
        """
        a = self._anchors(anchors)
        r = as_float_array(ranges, "ranges", min_ndim=1, allow_nan=True)
        if r.shape[-1] != a.shape[-2]:
            raise InputError(f"ranges: {r.shape[-1]} per row but {a.shape[-2]} anchors")
        if np.any(np.isinf(r)):
            idx = tuple(int(i) for i in np.argwhere(np.isinf(r))[0])
            raise InputError(f"ranges: infinite value at index {idx} (NaN marks an absent "
                             "range; a measured range may be slightly negative, not infinite)")
        D, n = self.motion.dim, self.motion.state_dim
        h, J = range_geometry(state.mean[..., :D], a, self.height_m)
        H = np.zeros(J.shape[:-1] + (n,))
        H[..., :D] = J
        nu = r - (h + self._bias)
        gated = np.zeros(nu.shape[:-1], dtype=np.int64)
        if self.gate is not None:
            # predicted variance of each range alone: H_m P H_m' + R_mm
            s_mm = np.einsum("...mi,...ij,...mj->...m", H, state.covariance, H) + self._var
            out = np.isfinite(nu) & (nu * nu > self.gate * s_mm)
            if ungated is not None:
                out &= ~np.asarray(ungated, dtype=bool)[..., None]
            nu = np.where(out, np.nan, nu)
            gated = out.sum(axis=-1)
        mean, cov, S, used = kalman_update(state.mean, state.covariance, nu, H,
                                           R_diag=np.full(nu.shape, self._var))
        info = {"innovation": np.where(used, nu, np.nan), "innovation_covariance": S,
                "nis": normalised_innovation_squared(nu, S, used),
                "measurements_used": used.sum(axis=-1), "gated": gated}
        return GaussianState(check_finite_output(mean, "EKF state"), cov, state.time), info

    def step(self, state: GaussianState, ranges, dt=0.0, anchors=None, control=None
             ) -> GaussianState:
        """Predict by ``dt``, then update with a row of ranges.

        Parameters
        ----------
        state : GaussianState
        ranges : ndarray, shape (..., M)
            Measured ranges (NaN = absent).
        dt : float or ndarray
            Time since ``state``, seconds.
        anchors : ndarray, optional
            Points ranged to (default: the constructor's).
        control : ndarray, shape (..., D), optional
            Displacement over the step (input-driven motion).

        Returns
        -------
        GaussianState
        """
        return self.update(self.predict(state, dt, control), ranges, anchors)[0]

    def estimate(self, state: GaussianState) -> Estimate:
        """Position and its covariance.

        Parameters
        ----------
        state : GaussianState

        Returns
        -------
        Estimate
            ``position`` (..., D), ``covariance`` (..., D, D); the full state and its
            covariance in ``diagnostics['state']`` and ``['state_covariance']``.
        """
        D = self.motion.dim
        return Estimate(state.mean[..., :D], state.covariance[..., :D, :D], state.time,
                        {"state": state.mean, "state_covariance": state.covariance})

    def run(self, ranges, time=None, *, prior_mean, prior_cov, anchors=None, anchor_path=None,
            controls=None, smooth: bool = False) -> Track:
        """Filter a series of range rows.

        Parameters
        ----------
        ranges : array_like, shape (..., T, M)
            Ranges per step; NaN = absent (skipped).
        time : array_like, shape (T,) or (..., T), optional
            Step times in seconds; the prior is at ``time[0]``, so the first step is not
            predicted (except for an input-driven model's control). Default ``0..T-1``.
        prior_mean, prior_cov : array_like
            Prior at ``time[0]`` (see :meth:`init`).
        anchors : array_like, shape (M, D) or (..., M, D), optional
            Fixed points ranged to (default: the constructor's).
        anchor_path : array_like, shape (T, M, D) or (..., T, M, D), optional
            Points ranged to that move (a moving sensor); replaces ``anchors``.
        controls : array_like, shape (..., T, D), optional
            Displacement per step for an input-driven motion model.
        smooth : bool
            Return the Rauch-Tung-Striebel smoothed track instead of the filtered one.

        Returns
        -------
        Track
            ``position`` (..., T, D), ``covariance`` (..., T, D, D); diagnostics
            ``state``, ``state_covariance``, ``innovation``, ``innovation_covariance``,
            ``nis``, ``measurements_used``, ``gated`` (per step).
        """
        r = as_float_array(ranges, "ranges", min_ndim=2, allow_nan=True)
        T = r.shape[-2]
        t = np.arange(T, dtype=float) if time is None else as_float_array(time, "time")
        if t.shape[-1:] != (T,):
            raise InputError(f"time: expected {T} steps, got shape {t.shape}")
        dts = np.diff(t, axis=-1)
        if np.any(~np.isfinite(t)) or np.any(dts < 0):
            raise InputError("time: must be finite and non-decreasing")
        dts = np.concatenate([np.zeros(t.shape[:-1] + (1,)), dts], axis=-1)
        moving = anchor_path is not None
        if moving:
            a = as_float_array(anchor_path, "anchor_path", min_ndim=3)
            if a.shape[-3] != T:
                raise InputError(f"anchor_path: expected {T} steps on axis -3, got {a.shape}")
        else:
            a = self._anchors(anchors)
        u = None if controls is None else as_float_array(controls, "controls", min_ndim=2)
        state = self.init(prior_mean, prior_cov, t[..., 0])
        try:
            np.broadcast_shapes(t.shape[:-1], state.mean.shape[:-1], r.shape[:-2])
        except ValueError:
            raise InputError(f"time: batch shape {t.shape[:-1]} does not broadcast with the "
                             f"ranges' {r.shape[:-2]} and the prior's "
                             f"{state.mean.shape[:-1]}") from None
        estimates, infos, states = [], [], []
        streak = np.zeros(state.mean.shape[:-1], dtype=np.int64)   # steps fully gated in a row
        for k in range(T):
            pred = self.predict(state, dts[..., k], None if u is None else u[..., k, :])
            state, info = self.update(pred, r[..., k, :], a[..., k, :, :] if moving else a,
                                      ungated=streak >= self.gate_patience)
            heard = np.isfinite(r[..., k, :]).sum(axis=-1)
            streak = np.where((heard > 0) & (info["gated"] == heard), streak + 1,
                              np.where(heard > 0, 0, streak))
            states.append((pred, state))
            estimates.append(self.estimate(state))
            infos.append(info)
        track = track_from_steps(estimates, t)
        diag = dict(track.diagnostics)
        nb = len(track.batch_shape)
        for key in infos[0]:
            diag[key] = np.stack([i[key] for i in infos], axis=nb)
        if not smooth:
            return Track(track.position, track.covariance, track.time, diag)
        means, covs = self._rts(states, dts)
        D = self.motion.dim
        diag["state"], diag["state_covariance"] = means, covs
        return Track(means[..., :D], covs[..., :D, :D], track.time, diag)

    # ---- helpers --------------------------------------------------------------------
    def _anchors(self, anchors) -> np.ndarray:
        a = self.anchors if anchors is None else as_float_array(anchors, "anchors", min_ndim=2)
        if a is None:
            raise InputError("anchors: none given to the constructor or to this call")
        return a

    def _rts(self, states, dts) -> tuple[np.ndarray, np.ndarray]:
        """Rauch-Tung-Striebel backward pass over ``(predicted, filtered)`` pairs."""
        nb = states[0][1].mean.ndim - 1
        m_s, P_s = states[-1][1].mean, states[-1][1].covariance
        out_m, out_P = [m_s], [P_s]
        for k in range(len(states) - 2, -1, -1):
            filt = states[k][1]
            pred_next = states[k + 1][0]
            F = self.motion.F(as_float_array(dts[..., k + 1], "dt"))
            C = filt.covariance @ np.swapaxes(F, -1, -2) @ np.linalg.inv(pred_next.covariance)
            m_s = filt.mean + np.einsum("...ij,...j->...i", C, m_s - pred_next.mean)
            P_s = filt.covariance + C @ (P_s - pred_next.covariance) @ np.swapaxes(C, -1, -2)
            P_s = 0.5 * (P_s + np.swapaxes(P_s, -1, -2))
            out_m.append(m_s)
            out_P.append(P_s)
        return np.stack(out_m[::-1], axis=nb), np.stack(out_P[::-1], axis=nb)
