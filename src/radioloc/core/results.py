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
    "gate_streak": "int: steps in a row, up to the last, whose every row the gate refused",
    "ess": "effective sample size of the particle weights",
    "resets": "int: particle-filter resets (degeneracy recoveries)",
    "los_detected": "bool per link: the filter's line-of-sight decision",
    "degenerate": "bool: the geometry does not fix the position (flagged, not raised)",
    "ambiguous": "bool: a mirror solution fits the measurements as well (flagged, not raised)",
    "uncertainty_m": "an estimator's own spread measure (m), e.g. the grid filter's",
    "grid_mean": "the grid filter's posterior mean when it reports the peak",
    "mixture_weights": "posterior mixture weights (mixture estimators)",
    "mixture_means": "posterior mixture means",
    "mixture_variances": "posterior mixture variances",
    "log_likelihood": "log-likelihood of the measurements at the estimate",
    "cost": "the objective a smoother or solver minimised, at its solution",
    "inliers": "int: measurements a robust estimator kept",
    "trajectory": "the whole estimated trajectory of a snapshot track fit, (..., n, D)",
    "ols_state": "the ordinary least-squares state a closed-form fit starts from",
    "gated": "int: measurements the innovation gate refused at each step",
    "used_differences": "int: difference rows a closed-form fit used (rows of missing samples dropped)",
    "em_parameters": "online-EM estimates of the range model, (s_LOS, s_NLOS, alpha) per filter",
    "stations_ignored": "int: received stations the model does not know (unseen or dropped at calibration)",
    "zone": "int labels of the chosen zone per level, coarse to fine (e.g. building, floor)",
}


#: Covariance columns of a position table (:meth:`Track.to_frame`, ``radioloc locate``) by
#: dimension, and the matrix entry of each.
COVARIANCE_COLUMNS: dict[int, tuple[str, ...]] = {
    2: ("cov_xx", "cov_xy", "cov_yy"),
    3: ("cov_xx", "cov_xy", "cov_yy", "cov_xz", "cov_yz", "cov_zz")}
COVARIANCE_ENTRY: dict[str, tuple[int, int]] = {
    "cov_xx": (0, 0), "cov_xy": (0, 1), "cov_yy": (1, 1), "cov_xz": (0, 2), "cov_yz": (1, 2),
    "cov_zz": (2, 2)}


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


@dataclass(frozen=True, repr=False)
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

    def plot(self, ax=None, *, confidence: float = 0.95, every: int | None = None, color=None,
             label: str | None = None, ellipses: bool = True, **kwargs):
        """Draw the estimated positions (every batch entry) in the (x, y) plane with their uncertainty ellipses.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Where to draw; default the current axes of pyplot (imported only then, with
            the backend the user has chosen).
        confidence : float
            Probability mass inside each ellipse (Gaussian, 2 degrees of freedom).
        every : int, optional
            Unused for an estimate.
        color : matplotlib colour, optional
            Default: the axes' next colour.
        label : str, optional
            Legend label.
        ellipses : bool
            Draw the uncertainty ellipses (when there is a covariance).
        **kwargs
            Passed to ``Axes.scatter``.

        Returns
        -------
        matplotlib Axes
        """
        return _plot(self, ax, confidence=confidence, every=every, color=color, label=label,
                     ellipses=ellipses, **kwargs)

    def __repr__(self) -> str:
        return _repr(self)

    def _repr_html_(self) -> str:
        return _repr_html(self)


@dataclass(frozen=True, repr=False)
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

    def __getitem__(self, index: Any) -> "Track":
        """Select runs (batch entries); the time and coordinate axes are kept.

        ``track[i]`` is run ``i`` as a :class:`Track`, with its covariance, times and the
        diagnostics whose leading axes are the batch's.
        """
        if not self.batch_shape:
            raise InputError("Track: a single run has no batch axis to index")
        idx = index if isinstance(index, tuple) else (index,)
        nb = len(self.batch_shape)
        cov = None if self.covariance is None else self.covariance[idx]
        time = self.time[idx] if self.time.ndim > 1 else self.time
        diag = {}
        for k, v in self.diagnostics.items():
            v = np.asarray(v)
            if v.shape[:nb] == self.batch_shape:
                diag[k] = v[idx[:nb]] if v.ndim == nb else v[idx]   # per run: no time axis
        return Track(self.position[idx], cov, time, diag)

    def to_frame(self, names: Any = None):
        """The track as the table ``radioloc locate`` writes: one row per (step, run).

        Parameters
        ----------
        names : sequence, optional
            A name per run (the ``node`` column), for a track with one batch axis; default
            the run index (column ``run``).

        Returns
        -------
        pandas.DataFrame
            ``time, node`` (or ``run``), ``x, y[, z]`` and, with a covariance,
            ``uncertainty_m`` and ``cov_xx, cov_xy, cov_yy[, cov_xz, cov_yz, cov_zz]``; rows
            sorted by time, then run (time-major, as the command line).

        Raises
        ------
        InputError
            ``names`` does not give one name per run, or the track has more than one batch
            axis and ``names`` is given.
        """
        import pandas as pd

        T, D = self.steps, self.dim
        runs = int(np.prod(self.batch_shape)) if self.batch_shape else 1
        pos = self.position.reshape(runs, T, D)
        time = np.broadcast_to(self.time, self.batch_shape + (T,)).reshape(runs, T)
        if names is None:
            label, ids = "run", np.arange(runs)
        else:
            ids = np.asarray(list(names), dtype=object)
            if len(self.batch_shape) > 1 or ids.shape != (runs,):
                raise InputError(f"names: expected {runs} names (one per run of a track with "
                                 f"one batch axis), got {ids.size}")
            label = "node"
        out = pd.DataFrame({"time": time.T.ravel(), label: np.tile(ids, T)})
        for k, c in enumerate("xyz"[:D]):
            out[c] = pos[:, :, k].T.ravel()
        if self.covariance is not None:
            cov = np.swapaxes(self.covariance.reshape(runs, T, D, D), 0, 1).reshape(-1, D, D)
            out["uncertainty_m"] = np.sqrt(np.trace(cov, axis1=-2, axis2=-1))
            for name in COVARIANCE_COLUMNS.get(D, ()):
                i, j = COVARIANCE_ENTRY[name]
                out[name] = cov[:, i, j]
        order = np.argsort(out["time"].to_numpy(), kind="stable")   # time-major, runs kept
        return out.iloc[order].reset_index(drop=True)

    def error(self, truth: np.ndarray) -> np.ndarray:
        """Euclidean position error ``(..., T)`` against ``truth`` ``(..., T, D)``."""
        truth = np.asarray(truth, dtype=float)
        if truth.shape[-1] != self.dim:
            raise InputError(f"truth: expected {self.dim} coordinates, got shape {truth.shape}")
        return np.sqrt(np.sum((self.position - truth) ** 2, axis=-1))

    def plot(self, ax=None, *, confidence: float = 0.95, every: int | None = None, color=None,
             label: str | None = None, ellipses: bool = True, **kwargs):
        """Draw the track of every run (one line each) in the (x, y) plane with uncertainty ellipses at every ``every``-th step.

        Parameters
        ----------
        ax : matplotlib Axes, optional
            Where to draw; default the current axes of pyplot (imported only then, with
            the backend the user has chosen).
        confidence : float
            Probability mass inside each ellipse (Gaussian, 2 degrees of freedom).
        every : int, optional
            Step stride of the ellipses (default: about 20 per track).
        color : matplotlib colour, optional
            Default: the axes' next colour.
        label : str, optional
            Legend label.
        ellipses : bool
            Draw the uncertainty ellipses (when there is a covariance).
        **kwargs
            Passed to ``Axes.plot``.

        Returns
        -------
        matplotlib Axes
        """
        return _plot(self, ax, confidence=confidence, every=every, color=color, label=label,
                     ellipses=ellipses, **kwargs)

    def __repr__(self) -> str:
        return _repr(self)

    def _repr_html_(self) -> str:
        return _repr_html(self)


# ---- display (repr, notebooks, plots) ---------------------------------------------------

def _shape_text(shape: tuple[int, ...]) -> str:
    return "x".join(str(n) for n in shape)


def _diag_text(diagnostics: Mapping[str, Any]) -> str:
    return ", ".join(sorted(diagnostics)) if diagnostics else "none"


def _summary_rows(obj: "Estimate | Track") -> list[tuple[str, str]]:
    """``(field, text)`` rows shared by ``__repr__`` and ``_repr_html_``."""
    p = obj.position
    is_track = isinstance(obj, Track)
    batch = obj.batch_shape
    rows: list[tuple[str, str]] = []
    rows.append(("batch", _shape_text(batch) if batch else "single"))
    if is_track:
        t = np.asarray(obj.time, dtype=float)
        rows.append(("steps", f"{obj.steps} ({t.min():.4g} to {t.max():.4g} s)"))
    coords = "xyz"[: obj.dim]
    flat = p.reshape(-1, obj.dim)
    finite = np.isfinite(flat).all(axis=1)
    if not batch and not is_track:
        rows.append(("position", ", ".join(f"{c}={v:.4g}" for c, v in zip(coords, flat[0])) + " m"))
    elif finite.any():
        lo, hi = flat[finite].min(axis=0), flat[finite].max(axis=0)
        rows.append(("extent", ", ".join(f"{c} {a:.4g}..{b:.4g}" for c, a, b in zip(coords, lo, hi))
                     + " m"))
    if not finite.all():
        rows.append(("NaN positions", f"{int((~finite).sum())} of {finite.size}"))
    unc = obj.uncertainty_m
    if unc is None:
        rows.append(("uncertainty", "none (no covariance)"))
    else:
        u = np.asarray(unc, dtype=float)
        rows.append(("uncertainty", f"{float(u):.3g} m" if u.ndim == 0 else
                     f"median {np.nanmedian(u):.3g} m"))
    if "converged" in obj.diagnostics:
        conv = np.asarray(obj.diagnostics["converged"], dtype=bool)
        rows.append(("converged", f"{int(conv.sum())} of {conv.size}"))
    if not is_track and obj.time is not None and np.ndim(obj.time) == 0:
        rows.append(("time", f"{float(obj.time):.4g} s"))
    rows.append(("diagnostics", _diag_text(obj.diagnostics)))
    return rows


def _repr(obj: "Estimate | Track") -> str:
    name = type(obj).__name__
    body = "; ".join(v if k == "position" else f"{k} {v}" for k, v in _summary_rows(obj)
                     if (k, v) != ("batch", "single"))
    return f"{name}({obj.dim}-D; {body})"


def _repr_html(obj: "Estimate | Track") -> str:
    import html

    rows = "".join(f"<tr><th style='text-align:left'>{html.escape(k)}</th>"
                   f"<td style='text-align:left'>{html.escape(v)}</td></tr>"
                   for k, v in _summary_rows(obj))
    return (f"<div><b>{type(obj).__name__}</b> ({obj.dim}-D)"
            f"<table>{rows}</table></div>")


def _ellipse_collection(ax, centres: np.ndarray, covs: np.ndarray, confidence: float, color,
                        alpha: float):
    """Add the ``confidence`` ellipses of 2-D Gaussians ``(N, 2)``, ``(N, 2, 2)`` to ``ax``."""
    from matplotlib.collections import EllipseCollection

    ok = np.isfinite(centres).all(-1) & np.isfinite(covs).all((-1, -2))
    centres, covs = centres[ok], covs[ok]
    if len(centres) == 0:
        return None
    vals, vecs = np.linalg.eigh(0.5 * (covs + np.swapaxes(covs, -1, -2)))
    scale = np.sqrt(-2.0 * np.log1p(-confidence))          # chi-square quantile, 2 dof
    axes = 2.0 * scale * np.sqrt(np.clip(vals, 0.0, None))  # full widths, ascending
    angles = np.degrees(np.arctan2(vecs[:, 1, 1], vecs[:, 0, 1]))
    coll = EllipseCollection(axes[:, 1], axes[:, 0], angles, units="xy", offsets=centres,
                             offset_transform=ax.transData, facecolors="none",
                             edgecolors=[color], alpha=alpha, linewidths=1.0)
    ax.add_collection(coll)
    return coll


def _plot(obj: "Estimate | Track", ax=None, *, confidence: float = 0.95, every: int | None = None,
          color=None, label: str | None = None, ellipses: bool = True, **kwargs):
    if not 0.0 < confidence < 1.0:
        raise InputError(f"confidence: must be in (0, 1), got {confidence}")
    if obj.dim < 2:
        raise InputError("plot: needs at least 2 coordinates")
    if ax is None:
        import matplotlib.pyplot as plt   # only here: the user's backend, chosen by the user

        ax = plt.gca()
    is_track = isinstance(obj, Track)
    steps = obj.steps if is_track else 1
    pos = obj.position[..., :2].reshape(-1, steps, 2)
    cov = None if obj.covariance is None else obj.covariance[..., :2, :2].reshape(-1, steps, 2, 2)
    color = color if color is not None else ax._get_lines.get_next_color()
    if is_track:
        for k in range(pos.shape[0]):                       # one line per run / node
            ax.plot(pos[k, :, 0], pos[k, :, 1], color=color,
                    label=label if k == 0 else None, **kwargs)
        stride = every if every is not None else max(1, steps // 20)
        sel = np.arange(0, steps, stride)
    else:
        ax.scatter(pos[:, 0, 0], pos[:, 0, 1], color=color, label=label, s=12, **kwargs)
        sel = np.array([0])
    if ellipses and cov is not None:
        _ellipse_collection(ax, pos[:, sel].reshape(-1, 2), cov[:, sel].reshape(-1, 2, 2),
                            confidence, color, 0.6)
    ax.set_aspect("equal", adjustable="datalim")
    ax.autoscale_view()
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    return ax


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
