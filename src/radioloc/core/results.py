"""The two result types every estimator returns: :class:`Estimate` and :class:`Track`.

A *snapshot* estimator (one epoch, e.g. multilateration) returns an :class:`Estimate`; a
*recursive* one (a filter over time) returns a :class:`Track` from ``run``. Both follow the
same conventions:

* positions are in ``(x, y[, z])`` order, metres;
* batch axes (Monte Carlo runs, nodes, vehicles) lead; the time axis of a track follows
  them, then the coordinate axis: ``Estimate.position`` is ``(..., D)``,
  ``Track.position`` is ``(..., T, D)``;
* ``covariance`` is the position covariance ``(..., D, D)`` / ``(..., T, D, D)`` in m^2, or
  ``None`` when the estimator has none;
* ``diagnostics`` holds whatever else the estimator knows, under the names of
  :data:`DIAGNOSTICS` where one applies, each an array whose leading axes are the
  position's (without the coordinate axis).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from radioloc.core.errors import InputError

#: Diagnostic names with a fixed meaning across estimators.
DIAGNOSTICS: dict[str, str] = {
    "converged": "bool: the iteration met its stopping rule with a finite result",
    "stalled": "bool: the iteration stopped without meeting its stopping rule",
    "iterations": "int: iterations taken",
    "residual_rms_m": "root-mean-square range residual at the solution (m)",
    "state": "full state vector, e.g. [x, y, vx, vy] (position first)",
    "state_covariance": "covariance of the full state",
    "innovation": "measurement minus prediction; NaN where no measurement",
    "innovation_covariance": "covariance of the innovation (for NIS)",
    "nis": "normalised innovation squared of the measurements used at each step",
    "measurements_used": "int: measurements that entered the update at each step",
    "ess": "effective sample size of the particle weights",
    "resets": "int: particle-filter resets (degeneracy recoveries)",
}


def _as_position(position: Any, name: str) -> np.ndarray:
    p = np.asarray(position, dtype=float)
    if p.ndim < 1 or p.shape[-1] not in (1, 2, 3):
        raise InputError(f"{name}: last axis must hold 1, 2 or 3 coordinates, got shape {p.shape}")
    return p


def _check_covariance(cov: Any, position: np.ndarray, name: str) -> np.ndarray | None:
    if cov is None:
        return None
    c = np.asarray(cov, dtype=float)
    d = position.shape[-1]
    if c.shape != position.shape + (d,):
        raise InputError(f"{name}: expected shape {position.shape + (d,)}, got {c.shape}")
    return c


@dataclass(frozen=True)
class Estimate:
    """A position estimate at one epoch for a batch of problems.

    Attributes
    ----------
    position : ndarray, shape (..., D)
        Estimated positions, ``(x, y[, z])``, metres.
    covariance : ndarray, shape (..., D, D), or None
        Position covariance in m^2 (``None`` if the estimator gives none).
    time : float, ndarray or None
        Time of the epoch in seconds (``None`` when the problem has no time).
    diagnostics : mapping of str to ndarray
        Per-problem diagnostics, e.g. ``converged``, ``stalled``, ``iterations``,
        ``residual_rms_m`` (see :data:`DIAGNOSTICS`).
    """

    position: np.ndarray
    covariance: np.ndarray | None = None
    time: float | np.ndarray | None = None
    diagnostics: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        p = _as_position(self.position, "Estimate.position")
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "covariance", _check_covariance(self.covariance, p,
                                                                 "Estimate.covariance"))
        object.__setattr__(self, "diagnostics", dict(self.diagnostics))

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The leading (batch) axes."""
        return self.position.shape[:-1]

    @property
    def dim(self) -> int:
        """Number of coordinates D."""
        return self.position.shape[-1]

    @property
    def converged(self) -> np.ndarray:
        """``diagnostics['converged']``, or all True for a non-iterative estimator."""
        return np.asarray(self.diagnostics.get("converged", np.ones(self.batch_shape, bool)))

    @property
    def uncertainty_m(self) -> np.ndarray | None:
        """Square root of the trace of the position covariance (m), or None."""
        if self.covariance is None:
            return None
        return np.sqrt(np.trace(self.covariance, axis1=-2, axis2=-1))

    def __getitem__(self, index: Any) -> "Estimate":
        """Select batch entries (the coordinate axis is kept)."""
        idx = index if isinstance(index, tuple) else (index,)
        cov = None if self.covariance is None else self.covariance[idx]
        diag = {k: np.asarray(v)[idx] for k, v in self.diagnostics.items()}
        time = self.time if np.ndim(self.time) == 0 else np.asarray(self.time)[idx]
        return Estimate(self.position[idx], cov, time, diag)


@dataclass(frozen=True)
class Track:
    """Estimates over time for a batch of independent runs (or nodes).

    Attributes
    ----------
    position : ndarray, shape (..., T, D)
        Estimated positions at every step, ``(x, y[, z])``, metres.
    covariance : ndarray, shape (..., T, D, D), or None
        Position covariance at every step, m^2.
    time : ndarray, shape (T,) or (..., T)
        Time of every step, seconds (step indices when the input had no time).
    diagnostics : mapping of str to ndarray
        Per-step diagnostics with leading axes ``(..., T)``, e.g. ``state``,
        ``innovation``, ``innovation_covariance``, ``nis``, ``ess`` (see
        :data:`DIAGNOSTICS`), and per-run ones with leading axes ``(...)``.
    """

    position: np.ndarray
    covariance: np.ndarray | None = None
    time: np.ndarray | None = None
    diagnostics: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        p = _as_position(self.position, "Track.position")
        if p.ndim < 2:
            raise InputError(f"Track.position: expected shape (..., T, D), got {p.shape}")
        object.__setattr__(self, "position", p)
        object.__setattr__(self, "covariance", _check_covariance(self.covariance, p,
                                                                 "Track.covariance"))
        t = np.arange(p.shape[-2], dtype=float) if self.time is None else np.asarray(
            self.time, dtype=float)
        if t.shape[-1:] != p.shape[-2:-1]:
            raise InputError(f"Track.time: expected {p.shape[-2]} steps, got shape {t.shape}")
        object.__setattr__(self, "time", t)
        object.__setattr__(self, "diagnostics", dict(self.diagnostics))

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The leading (batch) axes, without time and coordinates."""
        return self.position.shape[:-2]

    @property
    def steps(self) -> int:
        """Number of time steps T."""
        return self.position.shape[-2]

    @property
    def dim(self) -> int:
        """Number of coordinates D."""
        return self.position.shape[-1]

    @property
    def uncertainty_m(self) -> np.ndarray | None:
        """Square root of the trace of the position covariance (m), ``(..., T)``, or None."""
        if self.covariance is None:
            return None
        return np.sqrt(np.trace(self.covariance, axis1=-2, axis2=-1))

    def at(self, step: int) -> Estimate:
        """The estimate of one step as an :class:`Estimate`."""
        t = self.time[..., step]
        cov = None if self.covariance is None else self.covariance[..., step, :, :]
        nb = len(self.batch_shape)
        diag = {}
        for k, v in self.diagnostics.items():
            v = np.asarray(v)
            if v.ndim > nb and v.shape[nb] == self.steps:
                diag[k] = np.take(v, step, axis=nb)
        return Estimate(self.position[..., step, :], cov, t, diag)

    def error(self, truth: np.ndarray) -> np.ndarray:
        """Euclidean position error ``(..., T)`` against ``truth`` ``(..., T, D)``."""
        truth = np.asarray(truth, dtype=float)
        if truth.shape[-1] != self.dim:
            raise InputError(f"truth: expected {self.dim} coordinates, got shape {truth.shape}")
        return np.sqrt(np.sum((self.position - truth) ** 2, axis=-1))


def stack_steps(steps: list[np.ndarray], batch_ndim: int) -> np.ndarray:
    """Stack per-step arrays ``(..., *rest)`` into ``(..., T, *rest)`` with time after the
    ``batch_ndim`` leading batch axes."""
    return np.stack(steps, axis=batch_ndim)


def track_from_steps(estimates: list[Estimate], time: np.ndarray | None = None,
                     run_diagnostics: Mapping[str, np.ndarray] | None = None) -> Track:
    """Stack per-step :class:`Estimate` objects (same batch shape) into a :class:`Track`.

    Parameters
    ----------
    estimates : list of Estimate
        One per step, in time order.
    time : ndarray, shape (T,) or (..., T), optional
        Step times in seconds; default the ``time`` of each estimate, else step indices.
    run_diagnostics : mapping, optional
        Per-run diagnostics (leading axes ``(...)``, no time axis), e.g. ``resets``.
    """
    if not estimates:
        raise InputError("track: no steps")
    nb = len(estimates[0].batch_shape)
    pos = stack_steps([e.position for e in estimates], nb)
    cov = None
    if all(e.covariance is not None for e in estimates):
        cov = stack_steps([e.covariance for e in estimates], nb)
    keys = set(estimates[0].diagnostics)
    for e in estimates[1:]:
        keys &= set(e.diagnostics)
    diag = {k: stack_steps([np.asarray(e.diagnostics[k]) for e in estimates], nb)
            for k in sorted(keys)}
    if run_diagnostics:
        diag.update({k: np.asarray(v) for k, v in run_diagnostics.items()})
    if time is None and all(e.time is not None for e in estimates):
        time = np.stack([np.asarray(e.time, dtype=float) for e in estimates], axis=-1)
    return Track(pos, cov, time, diag)
