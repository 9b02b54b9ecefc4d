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
left out of the inverse. A non-Gaussian noise (LOS/NLOS mixture) enters through its
covariance: the result is then the bound of a Gaussian noise with the same covariance, not the
mixture's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.models.measurement import Context, MeasurementModel, StateLayout

__all__ = ["fisher_information", "crb", "Bound"]


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
        layout.check(model)
        _, H = layout.measure(model, x, ctx)
        R = model.noise_cov(ctx)
        RinvH = np.linalg.solve(np.broadcast_to(R, H.shape[:-1] + R.shape[-1:]), H)
        Jk = np.einsum("...mi,...mj->...ij", H, RinvH)
        J = Jk if J is None else J + Jk
    return J


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
