"""Extended Kalman filter tracking nodes from ranges to known points.

A configuration of the toolkit's one extended Kalman filter,
:class:`radioloc.estimators.extended_kalman.ExtendedKalmanFilter`, with a
:class:`~radioloc.models.ranging.RangeModel` built from the range-error model given: any
linear-Gaussian motion model of :mod:`radioloc.models.motion` (random walk, constant
velocity, constant acceleration, odometry/INS driven) and any range model with
``moments()`` (Gaussian, or the LOS/NLOS mixture of paper 001 matched by its mean and
variance). The points ranged to can be fixed anchors, a moving sensor (paper 002: one
sensor at a known position per sample) or the neighbours' broadcast estimates (paper 001's
EKF baseline): they are passed per step.

Ranges arrive in rows ``(..., M)`` per step; a NaN range is absent and skipped, so ranges
that arrive one at a time (one finite entry per row) are filtered as they come.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track
from radioloc.core.validation import (as_float_array, check_positive, check_ranges, check_real,
                                      range_noise_std, refuse_infinite)
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter, FilterState
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

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
        if not hasattr(measurement, "moments") or not hasattr(measurement, "logpdf"):
            raise ConfigError(f"measurement: {type(measurement).__name__} has no moments() "
                              "and logpdf(); the EKF needs a range model")
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
        var = measurement.moments()[1]
        if not var > 0:
            raise ConfigError(f"measurement: range error variance must be > 0, got {var}")
        self._model = RangeModel(noise=measurement)
        self._filter = ExtendedKalmanFilter(motion, gate=self.gate,
                                            gate_patience=self.gate_patience)

    # ---- contract -------------------------------------------------------------------
    def init(self, prior_mean, prior_cov, time: float | np.ndarray = 0.0) -> FilterState:
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
        FilterState
        """
        return self._filter.init(prior_mean, prior_cov, time)

    def predict(self, state: FilterState, dt, control=None) -> FilterState:
        """Propagate the state by ``dt`` seconds.

        Parameters
        ----------
        state : FilterState
        dt : float or ndarray, shape (...)
            Interval in seconds (0: no motion noise for a time-driven model).
        control : ndarray, shape (..., D), optional
            Displacement read over the step, for an input-driven model.

        Returns
        -------
        FilterState
            The predicted state (a new object).
        """
        return self._filter.predict(state, dt, control)

    def update(self, state: FilterState, ranges, anchors=None, ungated=None,
               ) -> tuple[FilterState, dict[str, np.ndarray]]:
        """Update with one row of ranges (NaN = absent, skipped).

        Parameters
        ----------
        state : FilterState
            The predicted state.
        ranges : ndarray, shape (..., M)
            Measured ranges, metres.
        anchors : ndarray, shape (M, D) or (..., M, D), optional
            Points ranged to (default: the constructor's).
        ungated : ndarray of bool, shape (...), optional
            Problems whose ranges bypass the innovation gate at this step.

        Returns
        -------
        state : FilterState
        info : dict
            ``innovation`` (..., M) (NaN where absent), ``innovation_covariance``
            (..., M, M), ``nis`` (...), ``measurements_used`` (...), ``gated`` (...):
            ranges dropped by the innovation gate.
        """
        a = self._anchors(anchors)
        r = as_float_array(ranges, "ranges", min_ndim=1, allow_nan=True)
        if r.shape[-1] != a.shape[-2]:
            raise InputError(f"ranges: {r.shape[-1]} per row but {a.shape[-2]} anchors")
        check_ranges(refuse_infinite(r, "ranges"), "ranges", range_noise_std(self.measurement),
                     bias_m=self.range_bias_m, bias_name="range_bias_m")
        return self._filter.update(state, self._observation(r, a), ungated)

    def step(self, state: FilterState, ranges, dt=0.0, anchors=None, control=None
             ) -> FilterState:
        """Predict by ``dt``, then update with a row of ranges.

        Parameters
        ----------
        state : FilterState
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
        FilterState
        """
        return self.update(self.predict(state, dt, control), ranges, anchors)[0]

    def estimate(self, state: FilterState) -> Estimate:
        """Position and its covariance.

        Parameters
        ----------
        state : FilterState

        Returns
        -------
        Estimate
            ``position`` (..., D), ``covariance`` (..., D, D); the full state and its
            covariance in ``diagnostics['state']`` and ``['state_covariance']``.
        """
        return self._filter.estimate(state)

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
        check_ranges(refuse_infinite(r, "ranges"), "ranges", range_noise_std(self.measurement),
                     bias_m=self.range_bias_m, bias_name="range_bias_m")
        T, M = r.shape[-2:]
        if anchor_path is not None:
            a = as_float_array(anchor_path, "anchor_path", min_ndim=3)
            if a.shape[-3] != T:
                raise InputError(f"anchor_path: expected {T} steps on axis -3, got {a.shape}")
            extra = a.shape[:-3]
        else:
            a = self._anchors(anchors)
            extra = a.shape[:-2]
        if a.shape[-2] != M:
            raise InputError(f"ranges: {M} per row but {a.shape[-2]} anchors")
        try:
            batch = np.broadcast_shapes(r.shape[:-2], extra)
        except ValueError:
            raise InputError(f"ranges: batch shape {r.shape[:-2]} does not broadcast with the "
                             f"anchors' {extra}") from None
        # the ranges carry every batch axis, so that a path (..., T, M, D) is read per step
        r = np.broadcast_to(r, batch + (T, M))
        if anchor_path is not None:
            a = np.broadcast_to(a, batch + a.shape[-3:])
        return self._filter.run(self._observation(r, a), time, prior_mean=prior_mean,
                                prior_cov=prior_cov, controls=controls, smooth=smooth)

    # ---- helpers --------------------------------------------------------------------
    def _anchors(self, anchors) -> np.ndarray:
        a = self.anchors if anchors is None else as_float_array(anchors, "anchors", min_ndim=2)
        if a is None:
            raise InputError("anchors: none given to the constructor or to this call")
        return a

    def _observation(self, ranges: np.ndarray, points: np.ndarray) -> Observation:
        """The ranges (less the constant bias) as an observation of the range model."""
        return Observation(self._model, ranges - self.range_bias_m,
                           Context(points=points, height_m=self.height_m))
