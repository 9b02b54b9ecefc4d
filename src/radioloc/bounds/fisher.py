"""Cramer-Rao bound of any Gaussian measurement model.

For measurements ``z_k = h_k(x) + v_k``, ``v_k ~ N(0, R_k)`` with ``R_k`` independent of
``x``, the Fisher information of the state is

    J(x) = sum_k H_k(x)^T R_k^{-1} H_k(x),    H_k = d h_k / d x

(the general Gaussian case, Kay, *Fundamentals of Statistical Signal Processing I*,
ch. 3); ``R_k`` is the full
``noise_cov`` of a model, so a TDoA model's correlated rows enter with their correlation.
The bound on an unbiased estimator's covariance is ``J^{-1}``; the position block of the
inverse (not the inverse of the position block) holds the cost of the nuisance components
estimated with it (clock offset and drift, anchor biases), and ``sqrt(trace)`` of that block
bounds the position RMSE.

A state component that no model reads (velocity in a snapshot) carries no information and is
left out of the inverse.

Along a trajectory, :func:`tracking_crb` is the posterior bound of a linear-Gaussian motion
``x_k = F_k x_{k-1} + w_k``, ``w_k ~ N(0, Q_k)``, by the information recursion of Tichavsky,
Muravchik & Nehorai (IEEE Trans. Signal Processing 46(5), 1998) for linear dynamics:

    J_0 = P_0^{-1} + I_0,    J_k = (Q_k + F_k J_{k-1}^{-1} F_k^T)^{-1} + I_k,

with ``I_k`` the information of the rows measured at step ``k``, evaluated on the given true
trajectory (average the bounds of Monte Carlo trajectories for the expectation over them).

A non-Gaussian noise (LOS/NLOS mixture) enters through its covariance: the result is then the
bound of a Gaussian noise with the same covariance, not the mixture's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.models.measurement import Context, MeasurementModel, Observation, StateLayout

__all__ = ["fisher_information", "crb", "tracking_crb", "Bound"]


@dataclass(frozen=True)
class Bound:
    """A Cramer-Rao bound.

    Attributes
    ----------
    covariance : ndarray, shape (..., k, k)
        Bound on the covariance of the components read (``components``, in state order).
    position : ndarray, shape (..., D, D)
        Its position block, m^2.
    rmse_m : ndarray, shape (...)
        ``sqrt(trace(position))``, the bound on the position RMSE, metres.
    components : tuple of str
        The state components the bound covers.
    """

    covariance: np.ndarray
    position: np.ndarray
    rmse_m: np.ndarray
    components: tuple[str, ...]


def _pairs(models, contexts) -> list[tuple[MeasurementModel, Context]]:
    ms = [models] if isinstance(models, MeasurementModel) else list(models)
    cs = [contexts] if isinstance(contexts, Context) else list(contexts)
    if len(ms) != len(cs):
        raise InputError(f"contexts: {len(cs)} context(s) for {len(ms)} model(s)")
    for m, c in zip(ms, cs):
        if not isinstance(m, MeasurementModel):
            raise InputError(f"models: expected MeasurementModel objects, got {type(m).__name__}")
        if not isinstance(c, Context):
            raise InputError(f"contexts: expected Context objects, got {type(c).__name__}")
        if not getattr(m, "gaussian", True):
            raise ConfigError(f"models: {type(m).__name__} has no Gaussian measurement "
                              "function; its Fisher information is not H^T R^-1 H")
    return list(zip(ms, cs))


def fisher_information(models: MeasurementModel | Sequence[MeasurementModel], state: np.ndarray,
                       contexts: Context | Sequence[Context], layout: StateLayout) -> np.ndarray:
    """Fisher information ``sum_k H_k^T R_k^{-1} H_k`` of a state, ``(..., n, n)``.

    Parameters
    ----------
    models : MeasurementModel or sequence of them
        One per group of rows (e.g. a TDoA model and a bearing model).
    state : ndarray, shape (..., n)
        True states, laid out by ``layout``.
    contexts : Context or sequence of Context
        One per model.
    layout : StateLayout
        Must hold every component the models read.

    Returns
    -------
    ndarray, shape (..., n, n)
    """
    x = np.asarray(state, dtype=float)
    J = None
    for model, ctx in _pairs(models, contexts):
        Jk = _information(model, x, ctx, layout)
        J = Jk if J is None else J + Jk
    return J


def _information(model: MeasurementModel, x: np.ndarray, ctx: Context, layout: StateLayout,
                 missing: np.ndarray | None = None) -> np.ndarray:
    """``H^T R^-1 H`` over the rows not ``missing``: a missing row's Jacobian is zeroed and
    its covariance decoupled, which leaves the observed rows' ``R`` block as it is."""
    layout.check(model)
    _, H = layout.measure(model, x, ctx)
    R = np.broadcast_to(model.noise_cov(ctx), H.shape[:-1] + H.shape[-2:-1])
    if missing is not None and np.any(missing):
        miss = np.broadcast_to(missing, H.shape[:-1])
        H = np.where(miss[..., None], 0.0, H)
        eye = np.eye(R.shape[-1], dtype=bool)
        R = np.where(miss[..., :, None] | miss[..., None, :], eye, R)
    RinvH = np.linalg.solve(R, H)
    return np.einsum("...mi,...mj->...ij", H, RinvH)


def crb(models: MeasurementModel | Sequence[MeasurementModel], state: np.ndarray,
        contexts: Context | Sequence[Context], layout: StateLayout) -> Bound:
    """Cramer-Rao bound of a state from Gaussian measurements (see the module docstring).

    Parameters
    ----------
    models, state, contexts, layout
        As for :func:`fisher_information`.

    Returns
    -------
    Bound
        ``covariance`` over the components the models read, its position block and the RMSE
        bound ``sqrt(trace)``.

    Raises
    ------
    GeometryError
        When the information is singular for some batch entry (too few rows, a geometry that
        leaves a direction unobserved), naming its batch index.
    """
    pairs = _pairs(models, contexts)
    read = {c for m, _ in pairs for c in m.reads}
    if "position" not in read:
        raise InputError("models: none of them reads the position")
    J = fisher_information([m for m, _ in pairs], state, [c for _, c in pairs], layout)
    comps = tuple(c for c in layout.sizes if c in read)
    cols = np.concatenate([np.arange(layout.slices[c].start, layout.slices[c].stop)
                           for c in comps])
    J = J[..., cols[:, None], cols]
    cond = np.linalg.cond(J)
    bad = ~(np.isfinite(cond) & (cond < 1e12))
    if np.any(bad):
        idx = tuple(int(i) for i in np.argwhere(bad)[0]) if bad.ndim else ()
        raise GeometryError(f"state {idx}: the Fisher information of {', '.join(comps)} is "
                            "singular (too few rows or an unobservable geometry)", index=idx)
    cov = np.linalg.inv(J)
    D = layout.dim
    pos = cov[..., :D, :D]
    return Bound(covariance=cov, position=pos,
                 rmse_m=np.sqrt(np.trace(pos, axis1=-2, axis2=-1)), components=comps)


def tracking_crb(observations: Observation | Sequence[Observation], states: np.ndarray,
                 layout: StateLayout, F: np.ndarray, Q: np.ndarray,
                 prior_cov: np.ndarray) -> Bound:
    """Posterior Cramer-Rao bound at every step of a trajectory (see the module docstring).

    Parameters
    ----------
    observations : Observation or sequence of Observation
        Their ``z`` ``(..., T, m)`` says which rows exist at each step (NaN: not measured);
        the values themselves are not used.
    states : ndarray, shape (..., T, n)
        The true states, laid out by ``layout``.
    layout : StateLayout
    F, Q : ndarray, shape (n, n) or (T - 1, n, n)
        Transition and process noise into each step after the first (e.g. from
        :func:`radioloc.models.clock.transition`).
    prior_cov : ndarray, shape (n, n) or (..., n, n)
        Covariance of the prior on the first state.

    Returns
    -------
    Bound
        Arrays with a time axis before the matrix axes: ``covariance`` ``(..., T, n, n)``,
        ``position`` ``(..., T, D, D)``, ``rmse_m`` ``(..., T)``.
    """
    obs = [observations] if isinstance(observations, Observation) else list(observations)
    if not obs or not all(isinstance(o, Observation) for o in obs):
        raise InputError("observations: expected one or more Observation objects")
    x = np.asarray(states, dtype=float)
    if x.ndim < 2 or x.shape[-1] != layout.size:
        raise InputError(f"states: expected shape (..., T, {layout.size}), got {x.shape}")
    T, n = x.shape[-2], layout.size
    for o in obs:
        if o.z.ndim < 2 or o.steps != T:
            raise InputError(f"observations: z must have {T} steps on its second-to-last axis, "
                             f"got shape {o.z.shape}")
    F, Q = np.asarray(F, dtype=float), np.asarray(Q, dtype=float)
    for name, a in (("F", F), ("Q", Q)):
        if a.shape not in ((n, n), (T - 1, n, n)):
            raise InputError(f"{name}: expected shape ({n}, {n}) or ({T - 1}, {n}, {n}), got {a.shape}")
    P0 = np.asarray(prior_cov, dtype=float)
    if P0.shape[-2:] != (n, n):
        raise InputError(f"prior_cov: expected shape (..., {n}, {n}), got {P0.shape}")
    out = []
    J = None
    for k in range(T):
        if J is None:
            J = np.linalg.inv(P0)
        else:
            Fk = F if F.ndim == 2 else F[k - 1]
            Qk = Q if Q.ndim == 2 else Q[k - 1]
            J = np.linalg.inv(Qk + Fk @ np.linalg.inv(J) @ Fk.T)
        for o in obs:
            z_k, ctx_k = o.at(k)
            J = J + _information(o.model, x[..., k, :], ctx_k, layout, np.isnan(z_k))
        out.append(J)
    cov = np.linalg.inv(np.stack(out, axis=-3))
    pos = cov[..., :layout.dim, :layout.dim]
    return Bound(covariance=cov, position=pos, rmse_m=np.sqrt(np.trace(pos, axis1=-2, axis2=-1)),
                 components=tuple(layout.sizes))
