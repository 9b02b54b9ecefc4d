"""The batch smoother: the MAP of a whole trajectory by Gauss-Newton on its banded information.

:class:`BatchSmoother` estimates every state ``x_0 ... x_{T-1}`` of a run at once
(a factor graph solved in full, as GTSAM's batch optimiser does), minimising

``||x_0 - m_0||^2_{P_0^-1} + sum_t ||x_{t+1} - F_t x_t||^2_{Q_t^-1} + sum_rows 2 rho(r)``

with ``F_t = F(dt_t)``, ``Q_t = Q(dt_t)`` of the whole state
(:func:`radioloc.models.clock.transition`, the extended Kalman filter's: the motion model,
the receiver clock's offset and drift when a model reads the offset, by default, as
:func:`~radioloc.models.clock.drifting` says, random walks of intensity ``extra_q`` and
``drift_q``, and per-anchor biases, a random walk of intensity ``extra_q``), and the rows of the
observations under a robust loss or the max-mixture LOS/NLOS loss
(:mod:`radioloc.estimators.robust_loss`).

Each Gauss-Newton iteration solves ``H d = b`` where ``H`` is block tridiagonal (blocks of
the state size ``n``): every run's ``T n`` unknowns are stacked into one symmetric banded
system of bandwidth ``2 n - 1`` (the runs of a batch are independent, so one banded
Cholesky solve, :func:`scipy.linalg.solveh_banded`, serves the whole batch: no loop over
runs). A step is halved (up to 8 times) per run until the run's cost does not increase.
The marginal covariances are the diagonal blocks of ``H^-1`` at the solution, from the
block recursion of the banded factorisation (``S_t = D_t - O_{t-1}^T S_{t-1}^-1 O_{t-1}``
forward, ``Sigma_t = S_t^-1 + S_t^-1 O_t Sigma_{t+1} O_t^T S_t^-1`` backward: the RTS
smoother's covariances on a linear-Gaussian model), never a dense inverse.

The iteration starts from an extended Kalman filter pass with the models' Gaussian
moments (rows whose innovation exceeds 5 standard deviations skipped), or from a given
trajectory.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.linalg import LinAlgError, solveh_banded

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Track
from radioloc.core.validation import (MAX_ITERATIONS, POSITIVE_FLOOR, as_float_array,
                                      check_positive_values,
                                      check_covariance, check_int, check_positive,
                                      check_shapes, refuse_infinite)
from radioloc.estimators.base import RecursiveEstimator, Tags, layout_track
from radioloc.estimators.extended_kalman import PRIOR_VARIANCE_LIMIT
from radioloc.estimators.kalman import symmetrise
from radioloc.estimators.observation_rows import RowStack, layout_for, observation_list
from radioloc.estimators.robust_loss import check_loss
from radioloc.models.clock import ClockModel, drifting, transition
from radioloc.models.measurement import Observation, StateLayout, check_motion

__all__ = ["BatchSmoother", "block_tridiagonal_marginals"]

_HALVINGS = 8
#: gate of the initialising filter pass (standard deviations of the innovation)
INIT_GATE_SIGMAS = 5.0


def block_tridiagonal_marginals(D: np.ndarray, O: np.ndarray) -> np.ndarray:
    """Diagonal blocks of the inverse of symmetric positive-definite block-tridiagonal matrices.

    Parameters
    ----------
    D : ndarray, shape (..., T, n, n)
        Diagonal blocks.
    O : ndarray, shape (..., T - 1, n, n)
        Upper off-diagonal blocks (block ``(t, t + 1)``).

    Returns
    -------
    ndarray, shape (..., T, n, n)
        ``(H^-1)_{tt}`` (module docstring; a loop over ``t``, batched over the leading
        axes).
    """
    T = D.shape[-3]
    S_inv = np.empty_like(D)
    S = D[..., 0, :, :]
    S_inv[..., 0, :, :] = np.linalg.inv(S)
    for t in range(1, T):
        Ot = O[..., t - 1, :, :]
        S = D[..., t, :, :] - np.swapaxes(Ot, -1, -2) @ S_inv[..., t - 1, :, :] @ Ot
        S_inv[..., t, :, :] = np.linalg.inv(symmetrise(S))
    out = np.empty_like(D)
    out[..., T - 1, :, :] = S_inv[..., T - 1, :, :]
    for t in range(T - 2, -1, -1):
        G = S_inv[..., t, :, :] @ O[..., t, :, :]
        out[..., t, :, :] = symmetrise(S_inv[..., t, :, :]
                                       + G @ out[..., t + 1, :, :] @ np.swapaxes(G, -1, -2))
    return out


def _banded(D: np.ndarray, O: np.ndarray) -> np.ndarray:
    """Upper banded storage (:func:`scipy.linalg.solveh_banded`) of the block-tridiagonal
    matrices ``D (R, T, n, n)``, ``O (R, T - 1, n, n)`` stacked on the diagonal."""
    R, T, n, _ = D.shape
    u = 2 * n - 1
    ab = np.zeros((u + 1, R * T * n))
    a, b = np.triu_indices(n)
    base = np.arange(R * T) * n
    ab[(u + a - b)[None, :], base[:, None] + b[None, :]] = D.reshape(R * T, n, n)[:, a, b]
    if T > 1:
        aa, bb = (g.ravel() for g in np.meshgrid(np.arange(n), np.arange(n), indexing="ij"))
        base = ((np.arange(R)[:, None] * T + np.arange(T - 1)[None, :]) * n).ravel()
        ab[(n - 1 + aa - bb)[None, :], base[:, None] + n + bb[None, :]] = \
            O.reshape(R * (T - 1), n, n)[:, aa, bb]
    return ab


class BatchSmoother(RecursiveEstimator):
    """MAP trajectory of every run by sparse Gauss-Newton (module docstring).

    Parameters
    ----------
    motion : MotionModel
        ``F(dt)``, ``Q(dt)`` and ``dim`` (:mod:`radioloc.models.motion`).
    loss : {"linear", "huber", "cauchy", "tukey"}
        Robust loss of the measurement rows (standardised by the model's sigma).
    loss_scale : float
        Its scale in standard deviations.
    los_nlos : LosNlosRange, optional
        Score every range row by the max-mixture of its LOS and NLOS modes under this
        noise model (per row the smaller negative log-density of the two, each with its
        prior weight), instead of ``loss``.
    null_hypothesis : (float, float), optional
        ``(weight, std_m)``: a null-hypothesis mode joins the max-mixture (a zero-mean
        Gaussian of standard deviation ``std_m`` of prior weight ``weight``: gross errors
        of either sign). Default None: LOS and NLOS only.
    max_iterations : int
        Gauss-Newton iterations.
    tol : float
        A run converges when its accepted step's largest entry is at most ``tol`` (state
        units), or its cost falls by less than ``1e-10`` of itself.
    extra_q : float
        Random-walk intensity (units^2 / s) of the clock offset and per-anchor bias
        components.
    drift_q : float, optional
        Random-walk intensity (units^2 / s^3) of the clock drift; default ``extra_q`` (in
        its own units: a smoother whose time unit changes scales ``extra_q`` by the unit and
        ``drift_q`` by its cube).
    extra_prior_std : float
        Prior standard deviation of those components when ``prior_mean`` gives the
        motion state only.
    bias_std_m_per_sqrt_s : float or ndarray, shape (..., A), optional
        Driving-noise intensity of the per-anchor biases, m/sqrt(s) (default
        ``sqrt(extra_q)``); one per anchor allowed.
    bias_time_constant_s : float or ndarray, shape (..., A), optional
        Their time constants, s: Gauss-Markov biases reverting to 0 (default: random walks;
        :func:`radioloc.models.clock.transition`).
    layout : StateLayout, optional
        The state to use (grown by what the models read); a
        :class:`~radioloc.models.pair_range.NetworkLayout` smooths every node of a network
        at once (the motion model moving each node; one track per node).

    Examples
    --------
    >>> import numpy as np
    >>> from radioloc.models.motion import WhiteAccelerationCV
    >>> BatchSmoother(WhiteAccelerationCV(1.0), los_nlos=None).tags.recursive
    True
    """

    name = "batch-smoother"
    tags = Tags(kinds=None, uses="jacobian", generic=True, recursive=True)

    def __init__(self, motion, *, loss: str = "linear", loss_scale: float = 1.0,
                 los_nlos=None, null_hypothesis: tuple[float, float] | None = None,
                 max_iterations: int = 30, tol: float = 1e-6,
                 extra_q: float = 1e-6, drift_q: float | None = None,
                 extra_prior_std: float = 100.0,
                 bias_std_m_per_sqrt_s: float | np.ndarray | None = None,
                 bias_time_constant_s: float | np.ndarray | None = None,
                 layout: StateLayout | None = None) -> None:
        if not (hasattr(motion, "F") and hasattr(motion, "Q") and hasattr(motion, "dim")):
            raise ConfigError(f"motion: expected a motion model with F(dt), Q(dt) and dim, got "
                              f"{type(motion).__name__}")
        order = motion.state_dim // motion.dim - 1
        if motion.dim not in (2, 3) or order not in (0, 1, 2) or \
                motion.state_dim != motion.dim * (order + 1):
            raise ConfigError(f"motion: state [position, velocity, ...] in 2-D or 3-D needed, got "
                              f"dim {motion.dim}, state_dim {motion.state_dim}")
        self.motion = motion
        if layout is not None:
            if not isinstance(layout, StateLayout):
                raise ConfigError(f"layout: expected a StateLayout, got {type(layout).__name__}")
            if (layout.dim, layout.order) != (motion.dim, order):
                raise ConfigError(f"layout: dim={layout.dim}, order={layout.order} does not "
                                  f"match the motion model's dim={motion.dim}, order={order}")
        self.layout = layout
        self.loss, self.loss_scale = check_loss(loss, loss_scale)
        if los_nlos is not None and not hasattr(los_nlos, "logpdf_by_state"):
            raise ConfigError(f"los_nlos: expected a LosNlosRange, got {type(los_nlos).__name__}")
        self.los_nlos = los_nlos
        if null_hypothesis is not None:
            try:
                w, sd = (float(v) for v in null_hypothesis)
            except (TypeError, ValueError):
                raise ConfigError("null_hypothesis: expected (weight, std_m)") from None
            if not (0.0 < w < 1.0 and np.isfinite(sd) and sd > 0):
                raise ConfigError(f"null_hypothesis: weight must be in (0, 1) and std_m > 0, "
                                  f"got {null_hypothesis!r}")
            if los_nlos is None:
                raise ConfigError("null_hypothesis: only with los_nlos (a max-mixture mode)")
            null_hypothesis = (w, sd)
        self.null_hypothesis = null_hypothesis
        self.max_iterations = check_int(max_iterations, "max_iterations", minimum=1,
                                        maximum=MAX_ITERATIONS)
        try:
            self.tol = check_positive(tol, "tol", allow_zero=True)
            self.extra_q = check_positive(extra_q, "extra_q")
            self.drift_q = self.extra_q if drift_q is None else check_positive(drift_q,
                                                                               "drift_q")
            self.extra_prior_std = check_positive(extra_prior_std, "extra_prior_std")
            self.bias_std_m_per_sqrt_s = (np.sqrt(self.extra_q) if bias_std_m_per_sqrt_s is None
                                          else check_positive_values(bias_std_m_per_sqrt_s,
                                                        "bias_std_m_per_sqrt_s"))
            self.bias_time_constant_s = (None if bias_time_constant_s is None else
                                         check_positive_values(bias_time_constant_s,
                                                               "bias_time_constant_s",
                                                               allow_zero=False, allow_inf=True))
        except InputError as exc:
            raise ConfigError(str(exc)) from None

    def state_layout(self, observations) -> StateLayout:
        """The state the smoother estimates for ``observations``: the motion model's
        kinematic state, then what the models read (a clock offset, per-anchor biases).

        Parameters
        ----------
        observations : Observation or sequence of Observation

        Returns
        -------
        StateLayout
        """
        base = self.layout or StateLayout(dim=self.motion.dim,
                                          order=self.motion.state_dim // self.motion.dim - 1)
        observations = observation_list(observations)
        for o in observations:
            check_motion(o.model, self.motion)
        return drifting(layout_for(observations, base), base)

    # ---- the model of the whole trajectory ----------------------------------------------
    def _transition(self, layout: StateLayout, dt: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``F_t``, ``Q_t^-1`` ``(..., T - 1, n, n)`` of the full layout."""
        n = layout.size
        if dt.size == 0:                              # one step: no transition
            return np.zeros(dt.shape + (n, n)), np.zeros(dt.shape + (n, n))
        q = np.sqrt(self.extra_q)
        clock = ClockModel(q, np.sqrt(self.drift_q), terms=layout.clock) if layout.clock else None
        F, Q = transition(layout, self.motion, dt, clock, self.bias_std_m_per_sqrt_s,
                          self.bias_time_constant_s)
        # dt = 0 (two steps at one time): tie the states through a tiny, not a zero, Q
        Q = Q + 1e-9 * np.eye(n)
        return F, np.linalg.inv(symmetrise(Q))

    def _prior(self, layout, prior_mean, prior_cov, batch) -> tuple[np.ndarray, np.ndarray]:
        n, k = layout.size, layout.motion_size
        m0 = as_float_array(prior_mean, "prior_mean", min_ndim=1)
        P0 = as_float_array(prior_cov, "prior_cov", min_ndim=2)
        if m0.shape[-1] not in (k, n):
            raise InputError(f"prior_mean: last axis must hold {n} (state {layout}) or {k} "
                             f"(motion state) entries, got shape {m0.shape}")
        if P0.shape[-2:] != (m0.shape[-1],) * 2:
            raise InputError(f"prior_cov: expected shape (..., {m0.shape[-1]}, {m0.shape[-1]}) "
                             f"to match prior_mean, got {P0.shape}")
        if m0.shape[-1] == k and n > k:
            m0 = np.concatenate([m0, np.zeros(m0.shape[:-1] + (n - k,))], axis=-1)
            big = np.zeros(P0.shape[:-2] + (n, n))
            big[..., :k, :k] = P0
            big[..., np.arange(k, n), np.arange(k, n)] = self.extra_prior_std ** 2
            P0 = big
        try:
            m0 = np.broadcast_to(m0, batch + (n,))
            P0 = np.broadcast_to(P0, batch + (n, n))
        except ValueError:
            raise InputError(f"prior_mean, prior_cov: shapes {m0.shape}, {P0.shape} do not "
                             f"broadcast to the batch {batch}") from None
        check_covariance(P0, "prior_cov", max_variance=np.inf, min_variance=POSITIVE_FLOOR)
        return m0, np.linalg.inv(symmetrise(P0))

    def _start(self, obs, layout, F, Qinv, m0, P0inv) -> np.ndarray:
        """The initialising extended Kalman filter pass ``(..., T, n)``.

        The textbook update ``P - K S K^T`` (a starting point only; the smoother's
        covariances come from its own information), rows whose innovation exceeds
        :data:`INIT_GATE_SIGMAS` standard deviations skipped.
        """
        T = obs[0].steps
        mean, cov = m0.copy(), np.linalg.inv(P0inv)
        if not np.all(np.diagonal(cov, axis1=-2, axis2=-1) <= PRIOR_VARIANCE_LIMIT):
            # a flat prior (a variance of 1e20 says "none"): the covariance form loses every
            # digit of the first update, so the pass starts at the filter's largest variance
            cov = np.linalg.inv(P0inv + np.eye(layout.size) / PRIOR_VARIANCE_LIMIT)
        out = np.empty(m0.shape[:-1] + (T, layout.size))
        Q = np.linalg.inv(Qinv)
        Ft = np.swapaxes(F, -1, -2)
        for t in range(T):
            if t:
                mean = np.einsum("...ij,...j->...i", F[..., t - 1, :, :], mean)
                cov = F[..., t - 1, :, :] @ cov @ Ft[..., t - 1, :, :] + Q[..., t - 1, :, :]
            for o in obs:
                z, ctx = o.at(t)
                if not np.any(np.isfinite(z)):
                    continue
                z_hat, H = layout.measure(o.model, mean, ctx)
                nu = o.model.residual(z, z_hat) - o.model.noise_mean(ctx)
                var = np.broadcast_to(o.model.std(ctx) ** 2, nu.shape)
                PHt = cov @ np.swapaxes(H, -1, -2)
                s = np.einsum("...mi,...im->...m", H, PHt) + var
                with np.errstate(invalid="ignore"):
                    ok = np.isfinite(nu) & (nu ** 2 <= INIT_GATE_SIGMAS ** 2 * s)
                H = np.where(ok[..., None], H, 0.0)
                PHt = np.where(ok[..., None, :], PHt, 0.0)
                S = H @ PHt + np.where(ok, var, 1.0)[..., None] * np.eye(nu.shape[-1])
                K = np.swapaxes(np.linalg.solve(S, np.swapaxes(PHt, -1, -2)), -1, -2)
                mean = mean + np.einsum("...ij,...j->...i", K, np.where(ok, nu, 0.0))
                cov = symmetrise(cov - K @ S @ np.swapaxes(K, -1, -2))
            out[..., t, :] = mean
        return out

    def _system(self, X, rows, F, Qinv, m0, P0inv):
        """Cost per run, and the blocks ``D (..., T, n, n)``, ``O (..., T - 1, n, n)`` and
        right-hand side ``b (..., T, n)`` of the Gauss-Newton system at ``X``."""
        cost, D, b = self._measurement_part(X, rows, full=True)
        e0 = X[..., 0, :] - m0
        D[..., 0, :, :] += P0inv
        b[..., 0, :] -= np.einsum("...ij,...j->...i", P0inv, e0)
        cost = cost + np.einsum("...i,...ij,...j->...", e0, P0inv, e0)
        e = X[..., 1:, :] - np.einsum("...ij,...j->...i", F, X[..., :-1, :])
        Qe = np.einsum("...ij,...j->...i", Qinv, e)
        cost = cost + np.sum(e * Qe, axis=(-2, -1))
        Ft = np.swapaxes(F, -1, -2)
        D[..., :-1, :, :] += Ft @ Qinv @ F
        D[..., 1:, :, :] += Qinv
        O = np.broadcast_to(-(Ft @ Qinv), D.shape[:-3] + F.shape[-3:]).copy()
        b[..., :-1, :] += np.einsum("...ij,...j->...i", Ft, Qe)
        b[..., 1:, :] -= Qe
        return cost, D, O, b

    def _measurement_part(self, X, rows, full: bool):
        r, J = rows.residuals(X)
        c, W, work = rows.terms(X, r)
        cost = np.sum(c, axis=(-2, -1))
        if not full:
            return cost
        D = np.einsum("...m,...mi,...mj->...ij", W, J, J)
        b = np.einsum("...m,...mi,...m->...i", W, J, work)
        return cost, D, b

    def _cost(self, X, rows, F, Qinv, m0, P0inv) -> np.ndarray:
        e0 = X[..., 0, :] - m0
        e = X[..., 1:, :] - np.einsum("...ij,...j->...i", F, X[..., :-1, :])
        return (self._measurement_part(X, rows, full=False)
                + np.einsum("...i,...ij,...j->...", e0, P0inv, e0)
                + np.einsum("...ti,...tij,...tj->...", e, Qinv, e))

    # ---- the estimator -------------------------------------------------------------------
    def run(self, observations: Observation | Sequence[Observation], time: np.ndarray | None = None,
            *, prior_mean: np.ndarray, prior_cov: np.ndarray,
            initial: np.ndarray | None = None) -> Track:
        """Smooth every run of the batch.

        Parameters
        ----------
        observations : Observation or sequence of Observation
            Values ``z`` ``(..., T, m)`` (the same ``T`` for all); NaN = no measurement.
        time : ndarray, shape (T,) or (..., T), optional
            Times of the steps, seconds, non-decreasing; default ``0, 1, ..., T - 1``.
        prior_mean : ndarray, shape (..., n) or (..., k)
            Mean of the first state (the full state, or the motion state ``k`` with the
            clock and biases at 0).
        prior_cov : ndarray, shape (..., n, n) or (..., k, k)
            Its covariance.
        initial : ndarray, shape (..., T, n) or (..., T, D), optional
            Starting trajectory (positions: the other components 0). Default: an extended
            Kalman filter pass.

        Returns
        -------
        Track
            Positions and marginal position covariances ``(..., T, D[, D])``;
            diagnostics ``state``, ``state_covariance`` (marginal), ``converged``,
            ``stalled``, ``iterations``, ``cost`` per run, ``residual_rms_m`` per step
            (rows present), and with ``los_nlos`` ``los_detected`` ``(..., T, M)`` (the
            LOS mode chosen; False where no row).

        Raises
        ------
        InputError
            Observations, time, prior or ``initial`` do not fit (the message names them).
        """
        obs = observation_list(observations)
        for i, o in enumerate(obs):
            self.tags.require(o.model, f"observations[{i}].model", type(self).__name__)
        steps = {o.z.ndim >= 2 and o.steps for o in obs}
        if len(steps) != 1 or False in steps:
            raise InputError("observations: each needs values (..., T, m) with the same T, got "
                             + ", ".join(str(o.z.shape) for o in obs))
        T = obs[0].steps
        layout = self.state_layout(obs)
        rows = RowStack(obs, layout, self.loss, self.loss_scale, self.los_nlos,
                        self.null_hypothesis)
        batch = rows.batch_shape((T,))[:-1]
        for i, o in enumerate(obs):
            refuse_infinite(o.z, f"observations[{i}].z")
        if time is None:
            t = np.arange(T, dtype=float)
        else:
            t = as_float_array(time, "time", min_ndim=1)
            if t.shape[-1] != T:
                raise InputError(f"time: expected {T} steps, got shape {t.shape}")
            if np.any(np.diff(t, axis=-1) < 0):
                raise InputError("time: must be non-decreasing")
        if check_shapes("time", t.shape[:-1], "the observations' batch", batch) != batch:
            raise InputError(f"time: batch shape {t.shape[:-1]} does not broadcast to the "
                             f"observations' {batch}")
        dt = np.broadcast_to(np.diff(t, axis=-1), batch + (T - 1,))
        n = layout.size
        F, Qinv = self._transition(layout, dt)
        m0, P0inv = self._prior(layout, prior_mean, prior_cov, batch)
        if initial is None:
            X = self._start(obs, layout, F, Qinv, m0, P0inv)
        else:
            X0 = as_float_array(initial, "initial", min_ndim=2)
            if X0.shape[-2] != T or X0.shape[-1] not in (layout.dim, n):
                raise InputError(f"initial: expected shape (..., {T}, {n}) or (..., {T}, "
                                 f"{layout.dim}), got {X0.shape}")
            X = np.zeros(batch + (T, n))
            X[..., :X0.shape[-1]] = X0
        X = np.broadcast_to(X, batch + (T, n)).copy()

        conv = np.zeros(batch, bool)
        stalled = np.zeros(batch, bool)
        iterations = np.zeros(batch, np.int64)
        cost, D, O, b = self._system(X, rows, F, Qinv, m0, P0inv)
        for _ in range(self.max_iterations):
            active = ~(conv | stalled)
            if not active.any():
                break
            R = int(np.prod(batch, dtype=int))
            ab = _banded(D.reshape(R, T, n, n), O.reshape(R, T - 1, n, n))
            try:
                d = solveh_banded(ab, b.reshape(-1), lower=False, check_finite=False)
            except (LinAlgError, ValueError):
                ab[-1] += 1e-9 * np.max(np.abs(ab[-1]))
                d = solveh_banded(ab, b.reshape(-1), lower=False)
            d = np.where(active[..., None, None], d.reshape(X.shape), 0.0)
            accepted = np.zeros(batch, bool)
            new_X, new_cost = X.copy(), cost.copy()
            for k in range(_HALVINGS):
                trial = X + 0.5 ** k * d
                c_t = self._cost(trial, rows, F, Qinv, m0, P0inv)
                take = active & ~accepted & np.isfinite(c_t) & (c_t <= cost * (1 + 1e-12) + 1e-300)
                new_X = np.where(take[..., None, None], trial, new_X)
                new_cost = np.where(take, c_t, new_cost)
                accepted |= take
                if accepted[active].all():
                    break
            moved = np.max(np.abs(new_X - X), axis=(-2, -1))
            small = (moved <= self.tol) | (cost - new_cost <= 1e-10 * np.abs(cost))
            conv |= accepted & small
            stalled |= active & ~accepted
            iterations += accepted
            X = new_X
            cost, D, O, b = self._system(X, rows, F, Qinv, m0, P0inv)
        P = block_tridiagonal_marginals(D, O)
        r, _ = rows.residuals(X)
        present = np.isfinite(r)
        with np.errstate(invalid="ignore"):
            rms = np.sqrt(np.sum(np.where(present, r, 0.0) ** 2, -1) / present.sum(-1))
        diag = {"state": X, "state_covariance": P, "converged": conv, "stalled": stalled,
                "iterations": iterations, "cost": cost, "residual_rms_m": rms}
        if self.los_nlos is not None:
            diag["los_detected"] = rows.modes(X, r) == 1
        return layout_track(layout, X, P, np.broadcast_to(t, batch + (T,)), diag,
                            {"state": 1, "state_covariance": 2, "converged": None,
                             "stalled": None, "iterations": None, "cost": None,
                             "residual_rms_m": 0, "los_detected": 1})
