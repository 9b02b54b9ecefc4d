"""Snapshot nonlinear least squares over any measurement model, with robust losses.

:class:`LeastSquares` fits one state per problem of a batch to the rows of one or more
:class:`~radioloc.models.measurement.Observation`\\ s (several kinds at once: ranges, time
differences, bearings, ...):

``min_x sum_rows 2 rho((r_i(x) - mu_i) / s_i)``, ``r_i = z_i - h_i(x)`` (wrapped for angles),

with ``s_i`` and ``mu_i`` the model's noise standard deviation and mean of the row and
``rho`` a robust loss (:mod:`radioloc.estimators.robust_loss`; ``"linear"`` is ordinary
weighted least squares). The iteration is the toolkit's one driver,
:func:`radioloc.estimators.nlls.solve_nlls` (Gauss-Newton with step halving, or
Levenberg-Marquardt), with the weights of iteratively reweighted least squares recomputed
at every iterate; the redescending losses (Cauchy, Tukey) start from the Huber fit. With
``los_nlos`` the range rows are scored by the max-mixture of their
LOS and NLOS modes instead.

The covariance is the inverse of the Gauss-Newton information ``J^T W J`` at the solution,
with the model's standard deviations (and the robust weights) in ``W``: never the
residual scale of the epoch, which a problem without redundancy does not have.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate
from radioloc.core.validation import (MAX_ITERATIONS, as_float_array, check_int, check_positive,
                                      refuse_infinite)
from radioloc.estimators.base import SnapshotEstimator, Tags
from radioloc.estimators.nlls import NLLSResult, solve_nlls
from radioloc.estimators.observation_rows import RowStack, layout_for, observation_list
from radioloc.estimators.robust_loss import check_loss
from radioloc.models.measurement import Observation, StateLayout

__all__ = ["LeastSquares", "initial_position"]

#: condition number of the information above which the state is not fixed by the rows
COND_LIMIT = 1e10
#: standardised residual within which a row counts as an inlier
INLIER_SIGMAS = 3.0


def _linear_range_start(r: np.ndarray, a: np.ndarray, used: np.ndarray) -> np.ndarray:
    """Closed-form position from ranges (``||x||^2`` as an extra unknown), ``(..., D)``."""
    d = a.shape[-1]
    w = used.astype(float)
    r = np.where(used, r, 0.0)
    A = np.concatenate([-2.0 * a, np.ones(a.shape[:-1] + (1,))], axis=-1)
    b = r ** 2 - np.sum(a ** 2, axis=-1)
    AtA = np.einsum("...m,...mi,...mj->...ij", w, A, A)
    Atb = np.einsum("...m,...mi,...m->...i", w, A, b)
    AtA = AtA + (1e-9 * np.trace(AtA, axis1=-2, axis2=-1) + 1e-300)[..., None, None] * np.eye(d + 1)
    with np.errstate(all="ignore"):
        return np.linalg.solve(AtA, Atb[..., None])[..., 0][..., :d]


def initial_position(observations: Sequence[Observation], dim: int,
                     batch: tuple[int, ...]) -> np.ndarray:
    """The default starting position of :class:`LeastSquares`, ``(..., D)``.

    The centroid of the reference points of the rows that hold a value; where the range
    rows (of models without anchor bias) number at least ``D + 1``, the closed-form
    linearised range solve instead (``||x||^2 - 2 a^T x = r^2 - ||a||^2`` with ``||x||^2``
    an extra unknown; ranges to 3-D points with a known node height ``height_m`` projected
    to the horizontal plane), in a frame centred on those points. A non-finite linear
    start, or one farther from the centroid than 1000 times the points' spread (plus
    1 km), falls back to the centroid.

    Parameters
    ----------
    observations : sequence of Observation
        Snapshot values ``z`` ``(..., m)``.
    dim : int
        Position dimension ``D``.
    batch : tuple of int
        Batch shape of the problems.

    Returns
    -------
    ndarray, shape (..., D)
    """
    pts, use, rng_r, rng_a, rng_u = [], [], [], [], []
    for o in observations:
        ctx = o.context
        p = np.broadcast_to(ctx.points[..., :dim], batch + (ctx.rows, dim))
        u = np.broadcast_to(np.isfinite(o.z), batch + (ctx.rows,))
        pts.append(p)
        use.append(u)
        if o.model.kind == "range" and "anchor_bias" not in o.model.reads:
            r = np.broadcast_to(o.z, batch + (ctx.rows,)) - o.model.noise_mean(ctx)
            if ctx.height_m is not None and ctx.points.shape[-1] == dim + 1:
                dz = ctx.height_m - ctx.points[..., dim]
                r = np.sqrt(np.maximum(r ** 2 - dz ** 2, 0.0))
            rng_r.append(r)
            rng_a.append(p)
            rng_u.append(u)
    p, u = np.concatenate(pts, axis=-2), np.concatenate(use, axis=-1)
    w = u.astype(float)
    n = w.sum(-1)
    centroid = np.einsum("...m,...md->...d", w, np.where(u[..., None], p, 0.0)) / np.maximum(n, 1)[..., None]
    if not rng_r:
        return centroid
    r, a, ru = (np.concatenate(rng_r, -1), np.concatenate(rng_a, -2), np.concatenate(rng_u, -1))
    wr = ru.astype(float)
    c = np.einsum("...m,...md->...d", wr, np.where(ru[..., None], a, 0.0)) / np.maximum(wr.sum(-1), 1)[..., None]
    lin = _linear_range_start(r, np.where(ru[..., None], a - c[..., None, :], 0.0), ru) + c
    spread = np.sqrt(np.max(np.where(u, np.sum((p - centroid[..., None, :]) ** 2, -1), 0.0), axis=-1))
    good = (ru.sum(-1) >= dim + 1) & np.all(np.isfinite(lin), -1) & (
        np.linalg.norm(lin - centroid, axis=-1) <= 1e3 * spread + 1e3)
    return np.where(good[..., None], lin, centroid)


class LeastSquares(SnapshotEstimator):
    """Snapshot nonlinear least squares over any measurement model (module docstring).

    Parameters
    ----------
    loss : {"linear", "huber", "cauchy", "tukey"}
        Robust loss of the standardised residual.
    loss_scale : float
        The loss's scale ``c`` in units of each row's standard deviation.
    max_iterations : int
        Iterations of the driver per problem (0: the start is returned).
    tol : float
        A problem converges when its accepted step is no longer than this (state units).
    method : {"gauss-newton", "levenberg-marquardt"}
        Step of :func:`~radioloc.estimators.nlls.solve_nlls`.
    layout : StateLayout, optional
        The state fitted; default position only (grown to what the models read: clock,
        per-anchor bias).
    los_nlos : LosNlosRange, optional
        Score range rows by the max-mixture of their LOS and NLOS modes under this model
        (instead of ``loss``).

    Examples
    --------
    >>> import numpy as np
    >>> from radioloc.models.measurement import Context, Observation
    >>> from radioloc.models.ranging import RangeModel
    >>> anchors = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    >>> z = np.linalg.norm(anchors - [3.0, 4.0], axis=-1)
    >>> obs = Observation(RangeModel(std_m=0.1), z, Context(points=anchors))
    >>> LeastSquares().locate(obs).position.round(6).tolist()
    [3.0, 4.0]
    """

    name = "lsq"
    tags = Tags(kinds=None, uses="jacobian", generic=True, recursive=False)

    def __init__(self, *, loss: str = "linear", loss_scale: float = 1.0,
                 max_iterations: int = 50, tol: float = 1e-9, method: str = "gauss-newton",
                 layout: StateLayout | None = None, los_nlos=None) -> None:
        self.loss, self.loss_scale = check_loss(loss, loss_scale)
        self.max_iterations = check_int(max_iterations, "max_iterations", minimum=0,
                                        maximum=MAX_ITERATIONS)
        try:
            self.tol = check_positive(tol, "tol", allow_zero=True)
        except InputError as exc:
            raise ConfigError(str(exc)) from None
        if method not in ("gauss-newton", "levenberg-marquardt"):
            raise ConfigError("method: must be 'gauss-newton' or 'levenberg-marquardt', "
                              f"got {method!r}")
        self.method = method
        if layout is not None and not isinstance(layout, StateLayout):
            raise ConfigError(f"layout: expected a StateLayout, got {type(layout).__name__}")
        self.layout = layout
        if los_nlos is not None and not hasattr(los_nlos, "logpdf_by_state"):
            raise ConfigError(f"los_nlos: expected a LosNlosRange, got {type(los_nlos).__name__}")
        self.los_nlos = los_nlos

    def solve(self, observations: Observation | Sequence[Observation], *,
              initial: np.ndarray | None = None) -> NLLSResult:
        """The driver's fit of every problem, before the covariance and diagnostics of
        :meth:`locate` (for estimators built on this one that read the cost, the
        information ``J^T W J`` or the convergence flags themselves).

        Parameters
        ----------
        observations, initial
            As for :meth:`locate`.

        Returns
        -------
        NLLSResult
            Over the full state; ``cost`` is the sum of the rows' loss terms
            (``sum ((r_i - mu_i) / s_i)^2`` for the linear loss).
        """
        return self._fit(observations, initial)[0]

    def locate(self, observations: Observation | Sequence[Observation], *,
               initial: np.ndarray | None = None) -> Estimate:
        """Fit every problem of the batch.

        Parameters
        ----------
        observations : Observation or sequence of Observation
            Values ``z`` ``(..., m)`` with leading batch axes; NaN = missing row.
        initial : ndarray, shape (..., D) or (..., n), optional
            Starting position (other state components start at 0) or full state.
            Default: :func:`initial_position` (closed-form range solve, else the centroid
            of the reference points heard).

        Returns
        -------
        Estimate
            ``position`` ``(..., D)``; ``covariance`` the position block of
            ``(J^T W J)^-1`` (NaN where degenerate); diagnostics ``converged``,
            ``stalled``, ``iterations``, ``residual_rms_m`` (root-mean-square raw residual
            of the rows used), ``inliers`` (rows within 3 standard deviations of the
            model), ``measurements_used``, ``degenerate`` (fewer rows than unknowns, a
            singular or ill-conditioned information, or a non-finite fit), ``state`` and
            ``state_covariance``.

        Raises
        ------
        InputError
            An observation, the layout or ``initial`` does not fit (the message names it).
        """
        fit, rows, used, layout = self._fit(observations, initial)
        n = layout.size
        info = fit.normal_matrix
        n_used = used.sum(-1)
        with np.errstate(all="ignore"):
            cond = np.linalg.cond(np.where(np.all(np.isfinite(info), (-2, -1))[..., None, None],
                                           info, np.eye(n)))
        degenerate = ((n_used < n) | ~np.isfinite(cond) | (cond > COND_LIMIT)
                      | ~np.all(np.isfinite(fit.x), -1))
        safe = np.where(degenerate[..., None, None], np.eye(n), info)
        cov = np.where(degenerate[..., None, None], np.nan, np.linalg.inv(safe))
        r = np.where(used, fit.residuals, 0.0)
        rms = np.sqrt(np.sum(r ** 2, -1) / np.maximum(n_used, 1))
        u = rows.standardised(fit.x, fit.residuals)
        inliers = np.sum(used & (np.abs(np.where(used, u, np.inf)) <= INLIER_SIGMAS), -1)
        pos, pos_cov = layout.position_moments(fit.x, cov)
        return Estimate(pos, pos_cov, None, {
            "converged": fit.converged & ~degenerate, "stalled": fit.stalled,
            "iterations": fit.iterations, "residual_rms_m": rms, "inliers": inliers,
            "measurements_used": n_used, "degenerate": degenerate, "state": fit.x,
            "state_covariance": cov})

    def _fit(self, observations, initial):
        """The fit, the row stack, the rows used ``(..., M)`` and the state layout."""
        obs = observation_list(observations)
        for i, o in enumerate(obs):
            self.tags.require(o.model, f"observations[{i}].model", type(self).__name__)
            refuse_infinite(o.z, f"observations[{i}].z")
        layout = layout_for(obs, self.layout)
        rows = RowStack(obs, layout, self.loss, self.loss_scale, self.los_nlos)
        batch = rows.batch_shape(())
        n, dim = layout.size, layout.dim
        z = rows.values(batch)
        used = np.isfinite(z)
        if initial is None:
            if layout.motion_size > layout.dim * (layout.order + 1):
                raise InputError(f"initial: a network state ({layout}) needs a start for "
                                 "every node (initial of its full size)")
            x0 = np.zeros(batch + (n,))
            x0[..., :dim] = initial_position(obs, dim, batch)
        else:
            x0 = as_float_array(initial, "initial", min_ndim=1)
            if x0.shape[-1] not in (dim, n):
                raise InputError(f"initial: last axis must hold {dim} (position) or {n} "
                                 f"(state {layout}) entries, got shape {x0.shape}")
            try:
                x0 = np.broadcast_to(x0, batch + x0.shape[-1:])
            except ValueError:
                raise InputError(f"initial: shape {x0.shape} does not broadcast to the batch "
                                 f"{batch}") from None
            if x0.shape[-1] == dim and n > dim:
                x0 = np.concatenate([x0, np.zeros(batch + (n - dim,))], axis=-1)
        if self.loss in ("cauchy", "tukey") and self.los_nlos is None:
            # a redescending loss has local minima (Tukey's ignores every row beyond c):
            # start it from the Huber fit, which is convex and outlier-resistant
            huber = RowStack(obs, layout, "huber", self.loss_scale)
            x0 = solve_nlls(huber.residuals, x0, weights=used.astype(float), method=self.method,
                            max_iter=self.max_iterations, tol=self.tol, row_terms=huber.terms).x
        fit = solve_nlls(rows.residuals, x0, weights=used.astype(float), method=self.method,
                         max_iter=self.max_iterations, tol=self.tol, row_terms=rows.terms)
        return fit, rows, used, layout
