"""The measurement rows of a set of :class:`~radioloc.models.measurement.Observation`\\ s,
stacked for the least-squares estimators.

:class:`RowStack` holds one or more observations (several kinds at once) and a
:class:`~radioloc.models.measurement.StateLayout`; for a batch of states ``x (..., n)`` it
gives the stacked residuals ``z - h(x)`` ``(..., M)`` and Jacobians ``dh/dx`` ``(..., M, n)``
(the ``residuals`` callable of :func:`radioloc.estimators.nlls.solve_nlls`) and each row's
cost term, weight and working residual under a robust loss or the max-mixture loss
(:mod:`radioloc.estimators.robust_loss`). The batch axes of ``x`` broadcast against those
of ``z``: a smoother passes states ``(..., T, n)`` with values ``(..., T, m)`` and gets every
step at once.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.results import Estimate
from radioloc.core.validation import refuse_infinite
from radioloc.models.measurement import Context, MeasurementModel, Observation, StateLayout
from radioloc.estimators.robust_loss import max_mixture_terms, row_terms

__all__ = ["observation_list", "common_steps", "layout_for", "RowStack", "with_candidate_axes",
           "log_likelihood_at", "flatten_step", "unflatten_estimate"]


def observation_list(observations: Observation | Sequence[Observation]) -> list[Observation]:
    """The observations as a non-empty list (an :class:`InputError` names a bad entry)."""
    items = [observations] if isinstance(observations, Observation) else observations
    try:
        items = list(items)
    except TypeError:
        raise InputError(f"observations: expected an Observation or a sequence of them, got "
                         f"{type(observations).__name__}") from None
    if not items:
        raise InputError("observations: give at least one Observation")
    for i, o in enumerate(items):
        if not isinstance(o, Observation):
            raise InputError(f"observations[{i}]: expected an Observation, got {type(o).__name__}")
    return items


def common_steps(observations: list[Observation]) -> int:
    """The number of time steps ``T`` that every observation's ``z`` ``(..., T, m)`` shares
    (an :class:`InputError` names the first that is not a time series, holds an infinite
    value or has another length)."""
    T = None
    for i, o in enumerate(observations):
        if o.z.ndim < 2:
            raise InputError(f"observations[{i}].z: expected shape (..., T, m), got {o.z.shape}")
        refuse_infinite(o.z, f"observations[{i}].z")
        if T is None:
            T = o.steps
        elif o.steps != T:
            raise InputError(f"observations[{i}].z: {o.steps} steps, observations[0] has {T}")
    return T


def _n_anchors(obs: Observation) -> int:
    idx = [i for i in (obs.context.index, obs.context.reference_index) if i is not None]
    return max((int(i.max()) + 1 for i in idx if i.size), default=obs.context.rows)


def layout_for(observations: list[Observation], layout: StateLayout | None = None,
               order: int = 0) -> StateLayout:
    """The state layout the observations need.

    Parameters
    ----------
    observations : list of Observation
    layout : StateLayout, optional
        A starting layout (its dimension is kept); default: the dimension of the first
        observation's points (one less with ``height_m``: a 2-D node and 3-D points).
    order : int
        Motion order of the starting layout (0 for a snapshot).

    Returns
    -------
    StateLayout
        Grown by :meth:`StateLayout.with_model` for every observation's model.
    """
    if layout is None:
        ctx = observations[0].context
        dim = ctx.position_dim
        if dim not in (2, 3):
            raise InputError(f"observations[0].context.points: {ctx.points.shape[-1]} coordinates "
                             "give no 2-D or 3-D position (pass layout=)")
        layout = StateLayout(dim=dim, order=order)
    elif not isinstance(layout, StateLayout):
        raise InputError(f"layout: expected a StateLayout, got {type(layout).__name__}")
    for o in observations:
        layout = layout.with_model(o.model, _n_anchors(o))
    return layout


class RowStack:
    """The rows of several observations for one state layout and one loss.

    Parameters
    ----------
    observations : list of Observation
        Values ``z`` ``(..., m)`` (a smoother: ``(..., T, m)``, the steps as a batch axis).
    layout : StateLayout
    loss : str
        A robust loss of :mod:`radioloc.estimators.robust_loss`.
    loss_scale : float
        Its scale in units of each row's standard deviation.
    los_nlos : LosNlosRange, optional
        Score the rows of every ``"range"`` observation by the max-mixture of its LOS and
        NLOS modes under this noise model (the row's own model with ``noise=los_nlos``).
        A model with its own LOS/NLOS modes (a pseudorange model with ``nlos_mean_m``) is
        scored by them in any case.
    null_hypothesis : (float, float), optional
        ``(weight, std)`` of a null-hypothesis mode added to the max-mixture.
    """

    def __init__(self, observations: list[Observation], layout: StateLayout, loss: str,
                 loss_scale: float, los_nlos=None, null_hypothesis=None) -> None:
        self.layout = layout
        self.null = null_hypothesis
        self.loss, self.loss_scale = loss, loss_scale
        self.items: list[tuple[MeasurementModel, np.ndarray, Context, MeasurementModel | None]] = []
        for o in observations:
            layout.check(o.model)
            ctx = o.context if o.std is None else replace(o.context, std=o.std)
            mixture = None
            if los_nlos is not None and o.model.kind == "range":
                mixture = replace(o.model, noise=los_nlos, std_m=None)
            elif getattr(o.model, "nlos_mean_m", None) is not None:   # its own LOS/NLOS
                mixture = o.model
            self.items.append((o.model, o.z, ctx, mixture))
        self.sizes = [z.shape[-1] for _, z, _, _ in self.items]

    def batch_shape(self, x_batch: tuple[int, ...]) -> tuple[int, ...]:
        """Batch shape of the rows for states of batch shape ``x_batch``."""
        named = [("the steps", x_batch)]
        named += [(f"observations[{i}].z", z.shape[:-1]) for i, (_, z, _, _) in
                  enumerate(self.items)]
        named += [(f"observations[{i}].context.points", c.points.shape[:-2])
                  for i, (_, _, c, _) in enumerate(self.items)]
        try:
            return np.broadcast_shapes(*(s for _, s in named))
        except ValueError:
            raise InputError("observations: batch shapes do not broadcast: "
                             + ", ".join(f"{k} {s}" for k, s in named)) from None

    def values(self, batch: tuple[int, ...]) -> np.ndarray:
        """The stacked measured values ``(..., M)`` (NaN = missing row)."""
        return np.concatenate([np.broadcast_to(z, batch + z.shape[-1:]) for _, z, _, _ in
                               self.items], axis=-1)

    def residuals(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(z - h(x), dh/dx)``: ``(..., M)`` and ``(..., M, n)`` (NaN rows stay NaN)."""
        batch = self.batch_shape(x.shape[:-1])
        rs, Js = [], []
        for model, z, ctx, _ in self.items:
            z_hat, H = self.layout.measure(model, x, ctx)
            r = model.residual(z, z_hat)
            rs.append(np.broadcast_to(r, batch + r.shape[-1:]))
            Js.append(np.broadcast_to(H, batch + H.shape[-2:]))
        return np.concatenate(rs, axis=-1), np.concatenate(Js, axis=-2)

    def terms(self, x: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cost term, weight and working residual of every row ``(..., M)`` at ``x``
        with residuals ``r`` (the ``row_terms`` of :func:`~radioloc.estimators.nlls.solve_nlls`)."""
        batch = r.shape[:-1]
        out = [], [], []
        start = 0
        for (model, z, ctx, mixture), m in zip(self.items, self.sizes):
            rr = r[..., start:start + m]
            start += m
            std = np.broadcast_to(model.std(ctx), batch + (m,))
            if mixture is not None:
                parts = self._mixture(mixture, z, x, ctx, std)[:3]
                # a missing row (NaN residual) contributes nothing
                parts = tuple(np.where(np.isfinite(rr), p, 0.0) for p in parts)
            else:
                parts = row_terms(rr, model.noise_mean(ctx), std, self.loss, self.loss_scale)
            for acc, p in zip(out, parts):
                acc.append(p)
        return tuple(np.concatenate(a, axis=-1) for a in out)

    def _mixture(self, mixture, z, x, ctx, std):
        """:func:`max_mixture_terms` of one observation's rows."""
        alpha = mixture.noise.alpha
        zz = np.broadcast_to(z, std.shape)
        if self.null is None:
            return max_mixture_terms(mixture, zz, self.layout.split(x), ctx, std,
                                     np.log([1.0 - alpha, alpha]))
        w, s = self.null
        return max_mixture_terms(mixture, zz, self.layout.split(x), ctx, std,
                                 np.log([(1.0 - w) * (1.0 - alpha), (1.0 - w) * alpha, w]), s)

    def standardised(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        """``(r - noise mean) / std`` of every row ``(..., M)`` (NaN where missing)."""
        batch = r.shape[:-1]
        out, start = [], 0
        for (model, z, ctx, _), m in zip(self.items, self.sizes):
            rr = r[..., start:start + m]
            start += m
            out.append((rr - model.noise_mean(ctx)) / np.broadcast_to(model.std(ctx), batch + (m,)))
        return np.concatenate(out, axis=-1)

    def modes(self, x: np.ndarray, r: np.ndarray) -> np.ndarray:
        """The max-mixture mode chosen for every row ``(..., M)`` (index 1 LOS, 0 NLOS for
        a range; -1 where the row is missing or not scored by the max-mixture)."""
        batch = r.shape[:-1]
        out, start = [], 0
        for (model, z, ctx, mixture), m in zip(self.items, self.sizes):
            rr = r[..., start:start + m]
            start += m
            if mixture is None:
                out.append(np.full(batch + (m,), -1))
                continue
            std = np.broadcast_to(model.std(ctx), batch + (m,))
            k = self._mixture(mixture, z, x, ctx, std)[3]
            out.append(np.where(np.isfinite(rr), k, -1))
        return np.concatenate(out, axis=-1)


def with_candidate_axes(ctx: Context, axes: int = 2) -> Context:
    """A context whose batch axes ``(B, m, ...)`` gain ``axes`` axes of candidate states
    after the batch axis, ``(B, 1, ..., 1, m, ...)``, so that a model evaluated at states
    ``(B, C1, C2, ...)`` broadcasts against it (a context without batch axes broadcasts as
    it is). The grid filter's cells and the mixture tracker's nodes use it."""
    def widen(a, base):
        return a if a is None or a.ndim <= base else a[(slice(None),) + (None,) * axes]
    return replace(ctx, points=widen(ctx.points, 2), reference=widen(ctx.reference, 2),
                   std=widen(ctx.std, 1))


def log_likelihood_at(rows, position: np.ndarray, where: str = "") -> np.ndarray:
    """``sum_rows log p(z | x)`` at two axes of candidate positions per run, through each
    model's ``logpdf`` (a NaN row contributes 0): the grid filter's cells and the mixture
    tracker's nodes.

    Parameters
    ----------
    rows : sequence of (model, z, context)
        Values ``z`` ``(B, m)`` (or broadcasting to it) and a context with the batch axis
        flattened (:func:`flatten_step`), one entry per observation.
    position : ndarray, shape (B, C1, C2, D)
        Candidate positions.
    where : str
        Appended to the message of a model that gives NaN (e.g. the step).

    Returns
    -------
    ndarray, shape (B, C1, C2)

    Raises
    ------
    InputError
        A model's ``logpdf`` gave NaN, naming the observation and the run.
    """
    shape = position.shape[:-1]
    total = np.zeros(shape)
    for i, (model, z, ctx) in enumerate(rows):
        z = np.broadcast_to(z, shape[:1] + z.shape[-1:])
        zc = np.broadcast_to(z[:, None, None, :], shape + z.shape[-1:])
        with np.errstate(invalid="ignore"):     # NaN rows: the model gives them 0
            total = total + model.logpdf(zc, {"position": position},
                                         with_candidate_axes(ctx)).sum(axis=-1)
        if np.isnan(total).any():
            run = int(np.flatnonzero(np.isnan(total).reshape(shape[0], -1).any(-1))[0])
            raise InputError(f"observations[{i}]: {type(model).__name__}.logpdf gave NaN "
                             f"for run {run}{where}")
    return total


def flatten_step(z: np.ndarray, ctx: Context, batch: tuple[int, ...]
                 ) -> tuple[np.ndarray, Context]:
    """One step's values ``(B, m)`` and context with the batch axes ``batch`` flattened
    into one of ``B`` runs."""
    B = int(np.prod(batch, dtype=np.int64))
    m = z.shape[-1]
    z = np.broadcast_to(z, batch + (m,)).reshape(B, m)

    def flat(a, base):
        if a is None or a.ndim <= base:
            return a
        return np.broadcast_to(a, batch + a.shape[-base:]).reshape((B,) + a.shape[-base:])
    return z, replace(ctx, points=flat(ctx.points, 2), reference=flat(ctx.reference, 2),
                      std=flat(ctx.std, 1))


def unflatten_estimate(est: Estimate, batch: tuple[int, ...]) -> Estimate:
    """An estimate of ``B`` flattened runs with its batch axes ``batch`` restored."""
    def back(a):
        a = np.asarray(a)
        return a.reshape(batch + a.shape[1:])
    return Estimate(back(est.position), back(est.covariance), est.time,
                    {k: back(v) for k, v in est.diagnostics.items()})
