"""Extended Kalman filter over any measurement model, optionally iterated, with the
Rauch-Tung-Striebel smoother.

The filter knows a motion model and nothing about the measurements: each
:class:`~radioloc.models.measurement.Observation` brings its
:class:`~radioloc.models.measurement.MeasurementModel` (``h(x)``, its Jacobian, its noise),
so ranges, time differences, pseudoranges and angles all run through the same update.

The state
---------
A :class:`~radioloc.models.measurement.StateLayout`: the motion model's kinematic part
(position, velocity, acceleration), then the receiver clock (offset in metres, drift in
metres per second) and one bias per anchor (metres), each present when a model reads it
(:meth:`ExtendedKalmanFilter.state_layout`). The prediction over ``dt`` is block-diagonal:

- kinematics: the motion model's ``F(dt)``, ``Q(dt)`` (plus a control displacement for an
  input-driven model);
- clock: ``offset += drift dt``; white frequency noise of density
  ``clock_offset_std_m_per_sqrt_s^2`` and a drift random walk of density
  ``clock_drift_std_m_per_s_per_sqrt_s^2`` (the two-state clock model of GNSS receivers:
  ``Q = [[q_o dt + q_d dt^3/3, q_d dt^2/2], [q_d dt^2/2, q_d dt]]``);
- anchor biases: constant, plus a random walk of variance ``bias_std_m_per_sqrt_s^2 dt``, or
  with ``bias_time_constant_s`` a first-order Gauss-Markov process (errors that stay
  correlated for seconds, as multipath on a walk; :func:`radioloc.models.clock.transition`).

The update
----------
Per observation, one kind after another within a step: the model's noise mean is taken
off ``z``; the innovation is ``model.residual(z, h(x-))`` (angles wrap), the Jacobian ``H``
is the model's at ``x-`` (analytic, or numerical when the model gives none), the noise
``R = model.noise_cov``. A row whose normalised innovation ``nu_m^2 / (H P H' + R)_mm``
exceeds ``gate`` (a chi-square value with one degree of freedom) is left out as an outlier
and counted in the ``gated`` diagnostic; a NaN row is absent. The update itself is
:func:`~radioloc.estimators.kalman.kalman_update` (Joseph form).

With ``iterations > 1`` the update is the iterated EKF (Bell and Cathey, 1993):
Gauss-Newton on the posterior, relinearising at the current iterate ``x_i``,

    ``x_{i+1} = x- + K_i (r(z, h(x_i)) - H_i (x- - x_i))``,  ``K_i = P- H_i' (H_i P- H_i' + R)^-1``,

the covariance from the last linearisation. One iteration is the EKF.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track
from radioloc.core.validation import (
    MAX_ITERATIONS,
    as_float_array,
    check_covariance,
    check_finite_output,
    check_int,
    check_positive,
    check_positive_values,
    refuse_infinite,
)
from radioloc.estimators.base import RecursiveEstimator, Tags, layout_track
from radioloc.estimators.kalman import (
    GaussianState,
    kalman_predict,
    kalman_update,
    normalised_innovation_squared,
    rts_smooth,
)
from radioloc.estimators.observation_rows import common_steps
from radioloc.models.clock import ClockModel, drifting, transition
from radioloc.models.measurement import (Context, MeasurementModel, Observation, StateLayout,
                                         check_motion)

__all__ = ["ExtendedKalmanFilter", "FilterState", "PRIOR_VARIANCE_LIMIT"]

#: largest prior variance :meth:`ExtendedKalmanFilter.init` accepts (m^2, (m/s)^2, ...)
PRIOR_VARIANCE_LIMIT = 1e12


@dataclass(frozen=True)
class FilterState(GaussianState):
    """A :class:`~radioloc.estimators.kalman.GaussianState` with the layout of its vector.

    Attributes
    ----------
    layout : StateLayout, optional
        Where position, velocity, clock and biases sit in ``mean`` (None: the filter's
        own layout).
    """

    layout: StateLayout | None = None


class ExtendedKalmanFilter(RecursiveEstimator):
    """Extended (optionally iterated) Kalman filter over any measurement model, batched
    over leading axes.

    Parameters
    ----------
    motion : motion model
        Any linear-Gaussian model with ``F(dt)``, ``Q(dt)``, ``dim`` (2 or 3) and
        ``state_dim`` (position first), e.g. ``ConstantVelocity(accel_var)``.
    gate : float or None
        Innovation gate per row (chi-square value, 1 degree of freedom): a row with
        ``nu_m^2 / S_mm > gate`` is skipped and counted in ``diagnostics['gated']``.
        ``16`` drops rows four predicted standard deviations off. None: no gate.
    gate_patience : int
        In :meth:`run`, after this many consecutive steps in which every row was gated, the
        next step's rows are taken ungated, so that a filter that has lost the target finds
        it again instead of coasting away on its motion model.
    iterations : int
        Linearisations per update: 1 is the EKF, more the iterated EKF.
    layout : StateLayout, optional
        The state layout to use (e.g. to fix the size of the anchor table); it is grown to
        what the observations' models read. Default: the motion model's kinematic part.
    bias_prior_std_m : float
        Prior standard deviation of each anchor bias (prior mean 0), metres; used when the
        prior given to :meth:`init` covers the kinematic part only.
    bias_std_m_per_sqrt_s : float or ndarray, shape (..., A)
        Driving-noise intensity of the anchor biases, m/sqrt(s) (0: constant biases); one
        value or one per anchor (per member of the batch).
    bias_time_constant_s : float or ndarray, shape (..., A), optional
        Time constants of the anchor biases, s: each a Gauss-Markov process reverting to 0
        (None: a random walk).
    clock_offset_prior_std_m : float
        Prior standard deviation of the receiver clock offset (times c), metres.
    clock_drift_prior_std_m_per_s : float
        Prior standard deviation of the clock drift (times c), m/s.
    clock_offset_std_m_per_sqrt_s : float
        White frequency noise of the clock offset, m/sqrt(s).
    clock_drift_std_m_per_s_per_sqrt_s : float
        Random-walk intensity of the clock drift, m/s/sqrt(s).

    Examples
    --------
    >>> import numpy as np
    >>> from radioloc.models.measurement import Context, Observation
    >>> from radioloc.models.motion import ConstantVelocity
    >>> from radioloc.models.ranging import RangeModel
    >>> anchors = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    >>> z = np.linalg.norm(np.array([3.0, 4.0]) - anchors, axis=-1) * np.ones((5, 1))
    >>> obs = Observation(RangeModel(std_m=0.1), z, Context(points=anchors))
    >>> track = ExtendedKalmanFilter(ConstantVelocity(0.1)).run(
    ...     obs, prior_mean=[2, 5, 0, 0], prior_cov=np.eye(4))
    >>> track.position[-1].round(1).tolist()
    [3.0, 4.0]
    """

    name = "extended-kalman"
    tags = Tags(kinds=None, uses="jacobian", dims=(2, 3), recursive=True, generic=True)

    def __init__(self, motion, *, gate: float | None = 16.0, gate_patience: int = 10,
                 iterations: int = 1, layout: StateLayout | None = None,
                 bias_prior_std_m: float = 5.0,
                 bias_std_m_per_sqrt_s: float | np.ndarray = 0.0,
                 bias_time_constant_s: float | np.ndarray | None = None,
                 clock_offset_prior_std_m: float = 1e3,
                 clock_drift_prior_std_m_per_s: float = 10.0,
                 clock_offset_std_m_per_sqrt_s: float = 0.0,
                 clock_drift_std_m_per_s_per_sqrt_s: float = 0.0) -> None:
        for attr in ("F", "Q", "dim", "state_dim"):
            if not hasattr(motion, attr):
                raise ConfigError(f"motion: {type(motion).__name__} has no {attr!r}; "
                                  "the EKF needs a linear-Gaussian motion model")
        dim, n = motion.dim, motion.state_dim
        if dim not in (2, 3) or n % dim or not 1 <= n // dim <= 3:
            raise ConfigError(f"motion: {type(motion).__name__} has dim={dim!r}, "
                              f"state_dim={n!r}; the EKF needs 2 or 3 position coordinates "
                              "and a [position, velocity, acceleration] state")
        self.motion = motion
        self.gate = None if gate is None else float(check_positive(gate, "gate"))
        self.gate_patience = check_int(gate_patience, "gate_patience", minimum=1)
        self.iterations = check_int(iterations, "iterations", minimum=1, maximum=MAX_ITERATIONS)
        base = StateLayout(dim=dim, order=n // dim - 1)
        if layout is not None:
            if not isinstance(layout, StateLayout):
                raise ConfigError(f"layout: expected a StateLayout, got {type(layout).__name__}")
            if (layout.dim, layout.order) != (base.dim, base.order):
                raise ConfigError(f"layout: dim={layout.dim}, order={layout.order} does not match "
                                  f"the motion model's dim={base.dim}, order={base.order}")
        self.layout = base if layout is None else layout
        self.bias_prior_std_m = check_positive(bias_prior_std_m, "bias_prior_std_m")
        self.bias_std_m_per_sqrt_s = check_positive_values(bias_std_m_per_sqrt_s,
                                                           "bias_std_m_per_sqrt_s")
        self.bias_time_constant_s = (None if bias_time_constant_s is None else
                                     check_positive_values(bias_time_constant_s,
                                                           "bias_time_constant_s",
                                                           allow_zero=False, allow_inf=True))
        self.clock_offset_prior_std_m = check_positive(clock_offset_prior_std_m,
                                                       "clock_offset_prior_std_m")
        self.clock_drift_prior_std_m_per_s = check_positive(clock_drift_prior_std_m_per_s,
                                                            "clock_drift_prior_std_m_per_s")
        self.clock_offset_std_m_per_sqrt_s = check_positive_values(clock_offset_std_m_per_sqrt_s,
                                                      "clock_offset_std_m_per_sqrt_s")
        self.clock_drift_std_m_per_s_per_sqrt_s = check_positive_values(
            clock_drift_std_m_per_s_per_sqrt_s, "clock_drift_std_m_per_s_per_sqrt_s")

    # ---- the state ------------------------------------------------------------------
    def state_layout(self, observations: Observation | Sequence[Observation] = ()
                     ) -> StateLayout:
        """The layout holding every component the observations' models read.

        Parameters
        ----------
        observations : Observation or sequence of Observation
            A model reading ``anchor_bias`` sizes the bias vector by its context's
            largest anchor index (or the ``layout`` given to the constructor, if larger).

        Returns
        -------
        StateLayout
        """
        layout = self.layout
        for i, obs in enumerate(_as_observations(observations)):
            check_motion(obs.model, self.motion)
            n_anchors = 0
            if "anchor_bias" in obs.model.reads:
                index = obs.context.index
                if index is None or index.size == 0 or np.any(index < 0):
                    raise InputError(f"observations[{i}].context.index: a model with anchor "
                                     "bias needs the anchor-table row of every measurement")
                n_anchors = int(index.max()) + 1
            layout = layout.with_model(obs.model, n_anchors)
        return drifting(layout, self.layout)

    def transition(self, layout: StateLayout, dt: float | np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray]:
        """Transition ``F`` and process noise ``Q`` of a full state over ``dt``.

        Parameters
        ----------
        layout : StateLayout
        dt : float or ndarray, shape (...)
            Seconds.

        Returns
        -------
        F, Q : ndarray, shape (..., n, n)
        """
        clock = None if not layout.clock else ClockModel(
            self.clock_offset_std_m_per_sqrt_s, self.clock_drift_std_m_per_s_per_sqrt_s,
            terms=layout.clock)
        return transition(layout, self.motion, dt, clock, self.bias_std_m_per_sqrt_s,
                          self.bias_time_constant_s)

    # ---- contract -------------------------------------------------------------------
    def init(self, prior_mean, prior_cov, time: float | np.ndarray = 0.0, *,
             observations: Observation | Sequence[Observation] = ()) -> FilterState:
        """The state before the first measurement.

        Parameters
        ----------
        prior_mean : array_like, shape (..., n) or (..., k)
            Prior mean of the full state (``n`` = the layout's size), or of its kinematic
            part only (``k = motion.state_dim``): the clock and biases then start at 0 with
            the constructor's prior standard deviations.
        prior_cov : array_like, shape (..., n, n) or (..., k, k)
            Prior covariance (symmetric positive definite), the size of ``prior_mean``.
        time : float or ndarray
            Time of the prior, seconds.
        observations : Observation or sequence of Observation
            What will be filtered: its models decide the layout (:meth:`state_layout`).

        Returns
        -------
        FilterState
        """
        layout = self.state_layout(observations)
        k, n = layout.motion_size, layout.size
        mean = as_float_array(prior_mean, "prior_mean", min_ndim=1, last_dim=sorted({k, n}))
        size = mean.shape[-1]
        cov = as_float_array(prior_cov, "prior_cov", min_ndim=2, last_dim=size)
        if cov.shape[-2] != size:
            raise InputError(f"prior_cov: expected (..., {size}, {size}) like prior_mean, "
                             f"got {cov.shape}")
        check_covariance(cov, "prior_cov", PRIOR_VARIANCE_LIMIT)
        try:
            batch = np.broadcast_shapes(mean.shape[:-1], cov.shape[:-2])
        except ValueError:
            raise InputError(f"prior_cov: batch shape {cov.shape[:-2]} does not broadcast with "
                             f"prior_mean's {mean.shape[:-1]}") from None
        mean = np.broadcast_to(mean, batch + (size,))
        cov = np.broadcast_to(cov, batch + (size, size))
        if size < n:
            full_mean = np.zeros(batch + (n,))
            full_mean[..., :k] = mean
            full_cov = np.zeros(batch + (n, n))
            full_cov[..., :k, :k] = cov
            extra = np.arange(k, n)
            full_cov[..., extra, extra] = self._augmented_variances(layout)
            mean, cov = full_mean, full_cov
        return FilterState(mean.copy(), cov.copy(), time, layout)

    def _augmented_variances(self, layout: StateLayout) -> np.ndarray:
        """Prior variances of the components after the kinematic part, in state order."""
        var = {"clock_offset": self.clock_offset_prior_std_m ** 2,
               "clock_drift": self.clock_drift_prior_std_m_per_s ** 2,
               "clock_bias": self.clock_offset_prior_std_m ** 2,
               "anchor_bias": self.bias_prior_std_m ** 2}
        return np.concatenate([np.full(size, var[name]) for name, size in layout.sizes.items()
                               if name in var])

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
        layout = self._layout_of(state)
        dt_arr = as_float_array(dt, "dt")
        try:
            np.broadcast_shapes(dt_arr.shape, state.mean.shape[:-1])
        except ValueError:
            raise InputError(f"dt: shape {dt_arr.shape} does not broadcast with the state's "
                             f"batch {state.mean.shape[:-1]}") from None
        u = None
        if control is not None:
            c = as_float_array(control, "control", last_dim=layout.dim)
            u = np.zeros(c.shape[:-1] + (layout.size,))
            u[..., : layout.dim] = c
        F, Q = self.transition(layout, dt_arr)
        mean, cov = kalman_predict(state.mean, state.covariance, F, Q, u)
        return FilterState(mean, cov, state.time + dt_arr, layout)

    def update(self, state: FilterState, observations: Observation | Sequence[Observation],
               ungated=None) -> tuple[FilterState, dict[str, np.ndarray]]:
        """Update with one time step of observations (one kind after another).

        Parameters
        ----------
        state : FilterState
            The predicted state.
        observations : Observation or sequence of Observation
            ``z`` of shape ``(..., m)`` (one step); NaN rows are absent.
        ungated : ndarray of bool, shape (...), optional
            Problems whose rows bypass the innovation gate at this step.

        Returns
        -------
        state : FilterState
        info : dict
            ``innovation`` (..., m) (the rows of every observation in order; NaN where
            absent or gated), ``innovation_covariance`` (..., m, m) (block-diagonal over
            the observations), ``nis`` (...) (these three at the prediction, also for
            the iterated update), ``measurements_used`` (...), ``gated`` (...).
        """
        obs = _as_observations(observations)
        rows = []
        for i, o in enumerate(obs):
            ctx = o.context if o.std is None else replace(o.context, std=o.std)
            rows.append((o.model, o.z, ctx, f"observations[{i}]", None))
        return self._update(state, rows, ungated)

    def _update(self, state: FilterState, rows, ungated, checked: bool = False
                ) -> tuple[FilterState, dict]:
        """Update with ``rows`` (model, z, context, name, noise); ``noise`` is the model's
        ``(noise_mean, noise_cov)`` in that context, or None to work it out here;
        ``checked``: the models and the values were checked by the caller (:meth:`run` does
        so once for all steps)."""
        layout = self._layout_of(state)
        if not checked:
            self._check_models(layout, [r[0] for r in rows], [r[3] for r in rows])
        mean, cov = state.mean, state.covariance
        infos = []
        for model, z, ctx, name, noise in rows:
            mean, cov, info = self._update_one(mean, cov, layout, model, z, ctx, ungated, name,
                                               checked, noise)
            infos.append(info)
        info = infos[0] if len(infos) == 1 else _combine(infos)
        return FilterState(check_finite_output(mean, "EKF state"), cov, state.time, layout), info

    def _check_models(self, layout: StateLayout, models, names) -> None:
        """Refuse a model the filter cannot take or the layout does not hold."""
        for model, name in zip(models, names):
            self.tags.require(model, f"{name}.model", type(self).__name__)
            try:
                layout.check(model)
            except InputError as exc:
                raise InputError(f"{name}.model: {exc}") from None

    def _update_one(self, mean, cov, layout: StateLayout, model: MeasurementModel, z, ctx: Context,
                    ungated, name: str, checked: bool = False, noise=None):
        """One kind's rows: gate, (iterated) Kalman update, diagnostics."""
        noise_mean, R = noise if noise is not None else (model.noise_mean(ctx),
                                                         model.noise_cov(ctx))
        z = np.asarray(z, dtype=float)
        z = (z if checked else refuse_infinite(z, f"{name}.z")) - noise_mean
        z_hat, H = layout.measure(model, mean, ctx)
        nu = model.residual(z, z_hat)
        gated = np.zeros(nu.shape[:-1], dtype=np.int64)
        if self.gate is not None:
            # predicted variance of each row alone: H_m P H_m' + R_mm
            s_mm = (np.einsum("...mi,...ij,...mj->...m", H, cov, H)
                    + np.diagonal(R, axis1=-2, axis2=-1))
            out = np.isfinite(nu) & (nu * nu > self.gate * s_mm)
            if ungated is not None:
                out &= ~np.asarray(ungated, dtype=bool)[..., None]
            nu = np.where(out, np.nan, nu)
            gated = out.sum(axis=-1)
        x, P, S, used = kalman_update(mean, cov, nu, H, R)
        nis = normalised_innovation_squared(nu, S, used)
        innovation, S0 = np.where(used, nu, np.nan), S
        for _ in range(1, self.iterations):
            # Gauss-Newton on the posterior: relinearise at the iterate x, from the prior
            z_i, H_i = layout.measure(model, x, ctx)
            nu_i = model.residual(z, z_i) + np.einsum("...mi,...i->...m", H_i, x - mean)
            x, P, _, used = kalman_update(mean, cov, np.where(used, nu_i, np.nan), H_i, R,
                                          valid=used)
        info = {"innovation": innovation, "innovation_covariance": S0, "nis": nis,
                "measurements_used": used.sum(axis=-1), "gated": gated}
        return x, P, info

    def step(self, state: FilterState, observations: Observation | Sequence[Observation],
             dt=0.0, control=None) -> FilterState:
        """Predict by ``dt``, then update with one step of observations.

        Parameters
        ----------
        state : FilterState
        observations : Observation or sequence of Observation
            ``z`` of shape ``(..., m)``; NaN rows are absent.
        dt : float or ndarray
            Time since ``state``, seconds.
        control : ndarray, shape (..., D), optional
            Displacement over the step (input-driven motion).

        Returns
        -------
        FilterState
        """
        return self.update(self.predict(state, dt, control), observations)[0]

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
        D = self._layout_of(state).dim
        return Estimate(state.mean[..., :D], state.covariance[..., :D, :D], state.time,
                        {"state": state.mean, "state_covariance": state.covariance})

    def run(self, observations: Observation | Sequence[Observation], time=None, *,
            prior_mean=None, prior_cov=None, state: FilterState | None = None,
            streak=None, controls=None, smooth: bool = False, coupling=None,
            on_step: Callable[[int], object] | None = None) -> Track:
        """Filter (or smooth) a series of observations.

        Parameters
        ----------
        observations : Observation or sequence of Observation
            ``z`` of shape ``(..., T, m)`` each, the same ``T``; NaN rows are absent.
        time : array_like, shape (T,) or (..., T), optional
            Step times in seconds; the prior is at ``time[0]``, so the first step is not
            predicted (except for an input-driven model's control). Default ``0..T-1``.
        prior_mean, prior_cov : array_like
            Prior at ``time[0]`` (see :meth:`init`).
        state : FilterState, optional
            Instead of the prior: the state the run goes on from (the last state of an
            earlier run, at a time not after ``time[0]``); the first step is predicted from
            its time, and its layout is kept.
        streak : int or array_like of int, shape (...), optional
            Steps in a row whose every row was gated before the first step (the
            ``gate_streak`` diagnostic of the run this one goes on from); default 0.
        controls : array_like, shape (..., T, D), optional
            Displacement per step for an input-driven motion model.
        smooth : bool
            Return the Rauch-Tung-Striebel smoothed track instead of the filtered one.
        coupling : callable, optional
            ``coupling(k, state) -> list of Observation``: rows of step ``k`` that depend on
            the batch's estimates after the step's own rows (ranges between members of the
            batch, each peer's estimate acting as a moving anchor; see
            :mod:`radioloc.locate.cooperative`). ``z`` of shape ``batch + (m,)``, the same
            ``m`` at every step (NaN: absent); they are a second update of the step.
        on_step : callable, optional
            Called after each step with the number of measurements it received, summed
            over the batch (a progress display).

        Returns
        -------
        Track
            ``position`` (..., T, D), ``covariance`` (..., T, D, D); diagnostics
            ``state``, ``state_covariance`` (the full state: clock, biases), ``innovation``,
            ``innovation_covariance``, ``nis``, ``measurements_used``, ``gated`` (per step),
            ``gate_streak`` (after the last step, per run).
        """
        obs = _as_observations(observations)
        T = common_steps(obs)
        t = np.arange(T, dtype=float) if time is None else as_float_array(time, "time")
        if t.shape[-1:] != (T,):
            raise InputError(f"time: expected {T} steps, got shape {t.shape}")
        dts = np.diff(t, axis=-1)
        if np.any(~np.isfinite(t)) or np.any(dts < 0):
            raise InputError("time: must be finite and non-decreasing")
        if state is None:
            state = self.init(prior_mean, prior_cov, t[..., 0], observations=obs)
        else:
            self._layout_of(state)        # refuses what is not a state of this filter
        first = t[..., :1] - np.asarray(state.time, dtype=float)[..., None]
        if np.any(~(first >= 0)):
            raise InputError("state: its time must be finite and not after time[0]")
        dts = np.concatenate([first, dts], axis=-1)
        u = None if controls is None else as_float_array(controls, "controls", min_ndim=2)
        if u is not None and u.shape[-2] != T:
            raise InputError(f"controls: expected {T} steps on axis -2, got shape {u.shape}")
        layout = state.layout
        shapes = [o.z.shape[:-2] for o in obs] + [o.at(0)[1].points.shape[:-2] for o in obs]
        try:
            batch = np.broadcast_shapes(t.shape[:-1], state.mean.shape[:-1], *shapes)
        except ValueError:
            raise InputError(f"time: batch shape {t.shape[:-1]} does not broadcast with the "
                             f"observations' {[o.z.shape[:-2] for o in obs]} and the prior's "
                             f"{state.mean.shape[:-1]}") from None
        state = FilterState(np.broadcast_to(state.mean, batch + (layout.size,)),
                            np.broadcast_to(state.covariance, batch + (layout.size,) * 2),
                            state.time, layout)
        record: dict[str, np.ndarray] = {}    # per step: batch + (T,) + the value's axes
        # steps in a row with every row gated
        streak = np.zeros(batch, dtype=np.int64) + np.asarray(0 if streak is None else streak,
                                                              dtype=np.int64)
        self._check_models(layout, [o.model for o in obs],
                           [f"observations[{i}]" for i in range(len(obs))])
        # the noise of a context that is the same at every step: worked out once
        noise = [(o.model.noise_mean(o.context), o.model.noise_cov(o.context))
                 if o.static_context else None for o in obs]
        chunk = TRANSITION_CHUNK
        for k in range(T):
            if u is not None:
                pred = self.predict(state, dts[..., k], u[..., k, :])
            else:
                if k % chunk == 0:   # F and Q of the next steps in one call
                    Fs, Qs = self.transition(layout, dts[..., k:k + chunk])
                x, P = kalman_predict(state.mean, state.covariance, Fs[..., k % chunk, :, :],
                                      Qs[..., k % chunk, :, :])
                pred = FilterState(x, P, state.time + dts[..., k], layout)
            rows, heard = [], 0
            for i, o in enumerate(obs):
                z, ctx = o.at(k)
                rows.append((o.model, z, ctx, f"observations[{i}]", noise[i]))
                heard = heard + np.isfinite(z).sum(axis=-1)
            state, info = self._update(pred, rows, streak >= self.gate_patience, checked=True)
            if coupling is not None:
                extra = coupling(k, state)
                state, more = self.update(state, extra, streak >= self.gate_patience)
                info = _combine([info, more])
                heard = heard + sum(np.isfinite(o.z).sum(axis=-1) for o in extra)
            streak = gate_streak(streak, heard, info["gated"])
            if on_step is not None:
                on_step(int(np.sum(heard)))
            _record(record, "state", state.mean, k, batch, T, 1)
            _record(record, "state_covariance", state.covariance, k, batch, T, 2)
            if smooth:
                _record(record, "predicted_mean", pred.mean, k, batch, T, 1)
                _record(record, "predicted_covariance", pred.covariance, k, batch, T, 2)
            for key, trailing in _INFO_AXES.items():
                _record(record, key, info[key], k, batch, T, trailing)
        means, covs = record.pop("state"), record.pop("state_covariance")
        if smooth:
            F = np.broadcast_to(self.transition(layout, dts)[0], batch + (T,) + (layout.size,) * 2)
            means, covs = rts_smooth(means, covs, record.pop("predicted_mean"),
                                     record.pop("predicted_covariance"), F)
        diag = {"state": means, "state_covariance": covs, **record, "gate_streak": streak}
        return layout_track(layout, means, covs, t, diag,
                            {"state": 1, "state_covariance": 2, **_INFO_AXES,
                             "gate_streak": None})

    # ---- helpers --------------------------------------------------------------------
    def _layout_of(self, state) -> StateLayout:
        if not isinstance(state, GaussianState):
            raise InputError(f"state: expected the state from init/predict/update, got "
                             f"{type(state).__name__}")
        layout = getattr(state, "layout", None) or self.layout
        if state.mean.shape[-1:] != (layout.size,):
            raise InputError(f"state: {state.mean.shape[-1:]} entries, the layout {layout} has "
                             f"{layout.size}")
        return layout


#: steps whose transitions :meth:`ExtendedKalmanFilter.run` computes in one call
TRANSITION_CHUNK = 256

#: per-step diagnostics of an update and their axes after the batch axes
_INFO_AXES = {"innovation": 1, "innovation_covariance": 2, "nis": 0, "measurements_used": 0,
              "gated": 0}


def gate_streak(streak, heard, gated):
    """Steps in a row in which every row was gated, after one more step of ``heard`` rows of
    which ``gated`` were refused (a step without rows leaves it as it was); at
    ``gate_patience`` the next step's rows bypass the gate (see :class:`ExtendedKalmanFilter`).

    Parameters
    ----------
    streak, heard, gated : int or ndarray, shape (...)

    Returns
    -------
    ndarray of int, shape (...)
    """
    return np.where((heard > 0) & (gated == heard), streak + 1, np.where(heard > 0, 0, streak))


def _record(record: dict, key: str, value: np.ndarray, step: int, batch: tuple[int, ...],
            steps: int, trailing: int) -> None:
    """Write one step's ``value`` (its last ``trailing`` axes after batch axes, which may
    broadcast) at ``step`` of ``record[key]``, allocated ``batch + (steps,) + those axes`` at
    the first step."""
    value = np.asarray(value)
    if key not in record:
        rest = value.shape[value.ndim - trailing:]
        record[key] = np.empty(batch + (steps,) + rest, dtype=value.dtype)
    record[key][(Ellipsis, step) + (slice(None),) * trailing] = value


def _as_observations(observations) -> list[Observation]:
    """The observations as a list, each checked to be an :class:`Observation`."""
    obs = [observations] if isinstance(observations, Observation) else list(observations)
    for i, o in enumerate(obs):
        if not isinstance(o, Observation):
            raise InputError(f"observations[{i}]: expected an Observation, got {type(o).__name__}")
    return obs


def _combine(infos: list[dict]) -> dict[str, np.ndarray]:
    """Diagnostics of several observations at one step: rows side by side, counts added."""
    batch = np.broadcast_shapes(*(i["nis"].shape for i in infos))
    nu = np.concatenate([np.broadcast_to(i["innovation"], batch + i["innovation"].shape[-1:])
                         for i in infos], axis=-1)
    m = nu.shape[-1]
    S = np.zeros(batch + (m, m))
    start = 0
    for i in infos:
        k = i["innovation"].shape[-1]
        S[..., start:start + k, start:start + k] = i["innovation_covariance"]
        start += k
    return {"innovation": nu, "innovation_covariance": S,
            "nis": sum(i["nis"] for i in infos) + np.zeros(batch),
            "measurements_used": sum(i["measurements_used"] for i in infos) + np.zeros(batch, int),
            "gated": sum(i["gated"] for i in infos) + np.zeros(batch, int)}
