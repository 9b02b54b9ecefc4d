"""The measurement-model protocol: a model owns its measurement function ``h(x)``.

One extended Kalman filter, one particle filter, one least-squares solver and one smoother
serve every kind of measurement because each kind is a :class:`MeasurementModel`:

- :meth:`~MeasurementModel.predict` gives the expected measurement ``h(x)``;
- :meth:`~MeasurementModel.jacobian` its derivative (analytic in each model; the base
  class falls back to central differences, :func:`numerical_jacobian`);
- :meth:`~MeasurementModel.noise_cov`, :meth:`~MeasurementModel.logpdf` and
  :meth:`~MeasurementModel.sample` its noise;
- :meth:`~MeasurementModel.residual` the difference ``z - h(x)`` (a subtraction; an angle
  model wraps it to ``(-pi, pi]``);
- :attr:`~MeasurementModel.reads` the state components it depends on.

The state
---------
A state vector is laid out by a :class:`StateLayout`: position first, then velocity (and
acceleration), then the receiver clock (offset, drift, in metres and metres per second,
i.e. multiplied by the speed of light), then one bias per anchor (metres). A model never
sees the vector itself: it receives the named components of a batch of states, a dict
``{"position": (..., D), "clock_offset": (...), "anchor_bias": (..., A), ...}``, and
returns its Jacobian per component. The layout assembles the full ``(..., m, n)``
Jacobian, so a model is written once for every state it may sit in.

The context
-----------
What a measurement depends on besides the state travels in a :class:`Context`: the
reference point(s) of each row (anchor positions, the reference anchor of a time
difference), their indices in the anchor table (for per-anchor biases) and an optional
per-row standard deviation. Rows are the last axis of ``z``; a NaN in ``z`` is a missing
measurement that every estimator skips.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from functools import cached_property
from collections.abc import Collection
from typing import ClassVar, Mapping

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.plausibility import check_values
from radioloc.core.validation import (POSITIVE_FLOOR, as_float_array, check_dtype, check_ranges,
                                      check_real, check_shapes, range_noise_std, refuse_infinite)

__all__ = ["COMPONENTS", "KINEMATIC", "check_motion", "StateLayout", "Context", "Observation", "MeasurementModel", "LikelihoodModel",
           "numerical_jacobian",
           "wrap_angle", "gaussian_logpdf"]

_LOG_2PI = float(np.log(2.0 * np.pi))

#: State components a model may read, in their order in the state vector.
COMPONENTS = ("position", "velocity", "acceleration", "clock_offset", "clock_drift",
              "clock_bias", "anchor_bias")

States = Mapping[str, np.ndarray]


def wrap_angle(angle: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``(-pi, pi]``.

    Parameters
    ----------
    angle : array_like
        Radians.

    Returns
    -------
    ndarray
    """
    a = np.asarray(angle, dtype=float)
    return np.pi - np.mod(np.pi - a, 2.0 * np.pi)


def gaussian_logpdf(residual: np.ndarray, std: np.ndarray) -> np.ndarray:
    """Elementwise ``log N(residual; 0, std^2)``."""
    z = residual / std
    return -0.5 * z * z - np.log(std) - 0.5 * _LOG_2PI


@dataclass(frozen=True)
class StateLayout:
    """Where each component sits in a state vector ``(..., n)``.

    Parameters
    ----------
    dim : {2, 3}
        Position dimension ``D``.
    order : int
        Motion derivatives carried: 0 position only, 1 with velocity, 2 with acceleration
        (the order of the motion models of :mod:`radioloc.models.motion`).
    clock : int
        Receiver clock terms: 0 none, 1 offset, 2 offset and drift (metres, m/s).
    n_bias : int
        Per-anchor range biases (metres), one per anchor of the anchor table (two with
        :class:`~radioloc.models.ranging.RangeModel`'s ``bias_terms=2``).
    n_clock_bias : int
        Inter-system biases (metres): the receiver clocks beyond the first (one per
        constellation of a GNSS receiver), each ahead of ``clock_offset`` by its bias.

    Examples
    --------
    >>> StateLayout(dim=2, order=1, n_bias=4).size
    8
    """

    dim: int = 2
    order: int = 0
    clock: int = 0
    n_bias: int = 0
    n_clock_bias: int = 0

    def __post_init__(self) -> None:
        if self.dim not in (2, 3):
            raise InputError(f"dim: position dimension must be 2 or 3, got {self.dim!r}")
        if self.order not in (0, 1, 2):
            raise InputError(f"order: motion order must be 0, 1 or 2, got {self.order!r}")
        if self.clock not in (0, 1, 2):
            raise InputError(f"clock: clock terms must be 0, 1 or 2, got {self.clock!r}")
        if int(self.n_bias) != self.n_bias or self.n_bias < 0:
            raise InputError(f"n_bias: must be a whole number >= 0, got {self.n_bias!r}")
        if int(self.n_clock_bias) != self.n_clock_bias or self.n_clock_bias < 0:
            raise InputError(f"n_clock_bias: must be a whole number >= 0, got "
                             f"{self.n_clock_bias!r}")

    @cached_property
    def sizes(self) -> dict[str, int]:
        """Size of each component present, in state order."""
        d = self.dim
        out = {"position": d}
        if self.order >= 1:
            out["velocity"] = d
        if self.order >= 2:
            out["acceleration"] = d
        if self.clock >= 1:
            out["clock_offset"] = 1
        if self.clock >= 2:
            out["clock_drift"] = 1
        if self.n_clock_bias:
            out["clock_bias"] = int(self.n_clock_bias)
        if self.n_bias:
            out["anchor_bias"] = int(self.n_bias)
        return out

    @cached_property
    def slices(self) -> dict[str, slice]:
        """Slice of each component present in the state vector."""
        out, start = {}, 0
        for name, size in self.sizes.items():
            out[name] = slice(start, start + size)
            start += size
        return out

    @cached_property
    def size(self) -> int:
        """Length ``n`` of the state vector."""
        return sum(self.sizes.values())

    @property
    def motion_size(self) -> int:
        """Length of the kinematic part (position, velocity, acceleration)."""
        return self.dim * (self.order + 1)

    def with_model(self, model: "MeasurementModel", n_anchors: int = 0) -> "StateLayout":
        """This layout grown to hold every component ``model`` reads.

        Parameters
        ----------
        model : MeasurementModel
        n_anchors : int
            Anchors in the table (the size of ``anchor_bias`` when the model reads it).

        Returns
        -------
        StateLayout
        """
        reads = set(model.reads)
        clock = max(self.clock, 2 if "clock_drift" in reads else 1 if "clock_offset" in reads else 0)
        order = max(self.order, 2 if "acceleration" in reads else 1 if "velocity" in reads else 0)
        n_bias = max(self.n_bias, int(n_anchors) * getattr(model, "bias_terms", 1)
                     if "anchor_bias" in reads else 0)
        n_clock_bias = max(self.n_clock_bias, getattr(model, "clock_groups", 1) - 1
                           if "clock_bias" in reads else 0)
        return replace(self, clock=clock, order=order, n_bias=n_bias, n_clock_bias=n_clock_bias)

    def kinematic(self, matrix: np.ndarray) -> np.ndarray:
        """A motion model's transition or noise matrix over one node's kinematic state, as
        the matrix of this state's kinematic part (one node: itself;
        :class:`~radioloc.models.pair_range.NetworkLayout`: one block per node).

        Parameters
        ----------
        matrix : ndarray, shape (..., k1, k1)
            ``F(dt)`` or ``Q(dt)`` of the motion model.

        Returns
        -------
        ndarray, shape (..., motion_size, motion_size)
        """
        return matrix

    def position_moments(self, mean: np.ndarray, cov: np.ndarray
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The position's mean and covariance of states.

        Parameters
        ----------
        mean : ndarray, shape (..., n)
        cov : ndarray, shape (..., n, n)

        Returns
        -------
        position : ndarray, shape (..., D)
            (a network: ``(..., K, D)``).
        covariance : ndarray, shape (..., D, D)
            (a network: each node's own block, ``(..., K, D, D)``).
        """
        D = self.dim
        return mean[..., :D], cov[..., :D, :D]

    def split(self, state: np.ndarray) -> dict[str, np.ndarray]:
        """The named components of a batch of states.

        Scalar components (``clock_offset``, ``clock_drift``) come without their axis:
        ``(...)``; the others keep it: ``(..., k)``.

        Parameters
        ----------
        state : ndarray, shape (..., n)

        Returns
        -------
        dict
        """
        x = np.asarray(state, dtype=float)
        if x.shape[-1:] != (self.size,):
            raise InputError(f"state: last axis must have {self.size} entries for {self}, "
                             f"got shape {x.shape}")
        out = {}
        for name, sl in self.slices.items():
            out[name] = x[..., sl.start] if name in ("clock_offset", "clock_drift") else x[..., sl]
        return out

    def join(self, components: Mapping[str, np.ndarray]) -> np.ndarray:
        """The state vectors ``(..., n)`` made of named components (the inverse of
        :meth:`split`; a missing component is zero).

        Parameters
        ----------
        components : dict
            ``{name: (..., k)}`` (scalar components ``(...)``).

        Returns
        -------
        ndarray, shape (..., n)
        """
        parts, shape = [], None
        for name, size in self.sizes.items():
            if name not in components:
                parts.append(None)
                continue
            c = np.asarray(components[name], dtype=float)
            if name in ("clock_offset", "clock_drift"):
                c = c[..., None]
            parts.append(c)
            shape = np.broadcast_shapes(shape or c.shape[:-1], c.shape[:-1])
        if shape is None:
            raise InputError("components: give at least one state component")
        out = np.zeros(shape + (self.size,))
        for (name, sl), c in zip(self.slices.items(), parts):
            if c is not None:
                out[..., sl] = c
        return out

    def measure(self, model: "MeasurementModel", state: np.ndarray,
                context: "Context") -> tuple[np.ndarray, np.ndarray]:
        """Predicted measurements and the full Jacobian for a batch of states.

        Parameters
        ----------
        model : MeasurementModel
        state : ndarray, shape (..., n)
        context : Context

        Returns
        -------
        z_hat : ndarray, shape (..., m)
        H : ndarray, shape (..., m, n)
            ``d h / d x``; zero in the columns of components the model does not read.
        """
        self.check(model)
        z_hat, parts = model.predict_with_jacobian(self.split(state), context)
        H = np.zeros(z_hat.shape + (self.size,))
        for name, block in parts.items():
            sl = self.slices[name]
            H[..., sl] = block
        return z_hat, H

    def check(self, model: "MeasurementModel") -> None:
        """Refuse a model that reads a component this layout lacks, naming both.

        Parameters
        ----------
        model : MeasurementModel
        """
        missing = [c for c in model.reads if c not in self.sizes]
        if missing:
            raise InputError(f"model {type(model).__name__} reads {', '.join(missing)}, which "
                             f"the state {self} does not hold (grow it with "
                             "StateLayout.with_model)")


#: The kinematic components, in the order a motion model of order 0, 1, 2 holds them.
KINEMATIC = ("position", "velocity", "acceleration")


def check_motion(model: "MeasurementModel", motion) -> None:
    """Refuse a measurement model that reads a kinematic component (velocity, acceleration)
    the motion model's state does not hold, in one line naming both.

    Parameters
    ----------
    model : MeasurementModel
    motion : motion model
        With ``dim`` and ``state_dim`` (:mod:`radioloc.models.motion`).

    Raises
    ------
    ConfigError
        E.g. a :class:`~radioloc.models.heading.HeadingModel` (reads velocity) with a
        :class:`~radioloc.models.motion.RandomWalk` (position only).
    """
    held = KINEMATIC[:max(1, int(motion.state_dim) // int(motion.dim))]
    missing = [c for c in model.reads if c in KINEMATIC and c not in held]
    if missing:
        kind = f" (kind {model.kind})" if model.kind else ""
        raise ConfigError(f"{type(model).__name__}{kind} reads {', '.join(missing)}, which the motion "
                          f"model {type(motion).__name__} does not hold (its state: "
                          f"{', '.join(held)}): give a motion model with {missing[-1]} ("
                          + ("a constant acceleration, WhiteJerkCA; locate: -o motion=ca"
                             if missing[-1] == "acceleration" else "a constant velocity, "
                             "WhiteAccelerationCV; locate: -o motion=cv")
                          + ", no odometry rows)")


@dataclass(frozen=True)
class Context:
    """What a batch of measurement rows depends on besides the state.

    Rows are the last axis of every array (``m``); leading axes broadcast against the
    state's batch axes.

    Attributes
    ----------
    points : ndarray, shape (..., m, P)
        The reference point of each row: the anchor a range or an angle is taken to, the
        satellite of a pseudorange, the anchor of a time difference.
    index : ndarray of int, shape (m,), optional
        Row of each ``points`` entry in the anchor table (what ``anchor_bias`` is indexed
        by); ``-1`` where the point is not an anchor of the table.
    reference : ndarray, shape (..., m, P), optional
        The second point of a row: the reference anchor of a time difference (finite,
        within the magnitude limit, as ``points``; it broadcasts to the shape of
        ``points``).
    reference_index : ndarray of int, shape (m,), optional
        Its row in the anchor table.
    std : ndarray, shape (..., m), optional
        A per-row standard deviation that overrides the model's (NaN: the model's).
    height_m : float, optional
        Known height of a 2-D node when the points are 3-D.
    columns : mapping of str to ndarray, optional
        Per-row values of the anchor-file columns a model reads
        (:attr:`radioloc.core.kinds.Kind.anchor_columns`: an anchor's velocity), each of
        shape ``(m,)``.
    group : ndarray of int, shape (m,), optional
        The receiver clock of each row (a constellation: 0, 1, ...; a pseudorange reads
        ``clock_bias[group - 1]`` for ``group > 0``).
    """

    points: np.ndarray
    index: np.ndarray | None = None
    reference: np.ndarray | None = None
    reference_index: np.ndarray | None = None
    std: np.ndarray | None = None
    height_m: float | None = None
    columns: Mapping[str, np.ndarray] | None = None
    group: np.ndarray | None = None

    def __post_init__(self) -> None:
        pts = as_float_array(self.points, "points")
        if pts.ndim < 2:
            raise InputError(f"points: expected shape (..., m, P), got {pts.shape}")
        object.__setattr__(self, "points", pts)
        m = pts.shape[-2]
        for name in ("index", "reference_index", "group"):
            v = getattr(self, name)
            if v is not None:
                v = np.asarray(v)
                if v.shape != (m,) or not np.issubdtype(v.dtype, np.integer):
                    raise InputError(f"{name}: expected {m} integers (one per row), got "
                                     f"{v.dtype} of shape {v.shape}")
                object.__setattr__(self, name, v)
        if self.reference is not None:
            ref = as_float_array(self.reference, "reference")
            if ref.shape[-2:] != pts.shape[-2:] or ref.ndim > pts.ndim or not all(
                    r in (1, p) for r, p in zip(ref.shape[::-1], pts.shape[::-1])):
                raise InputError(f"reference: shape {ref.shape} does not match points "
                                 f"{pts.shape} (the same rows; batch axes only where the "
                                 "points have them)")
            object.__setattr__(self, "reference", ref)
        if self.height_m is not None:
            object.__setattr__(self, "height_m", check_real(self.height_m, "height_m"))
        if self.std is not None:
            s = row_std(self.std, "std")
            if s.shape[-1:] != (m,):
                raise InputError(f"std: expected {m} per-row standard deviations on the last "
                                 f"axis, got shape {s.shape}")
            object.__setattr__(self, "std", s)
        if self.columns is not None:
            cols = {str(k): as_float_array(v, f"columns[{k!r}]", allow_nan=True)
                    for k, v in dict(self.columns).items()}
            bad = [k for k, v in cols.items() if v.shape != (m,)]
            if bad:
                raise InputError(f"columns[{bad[0]!r}]: expected {m} values (one per row), got "
                                 f"shape {cols[bad[0]].shape}")
            object.__setattr__(self, "columns", cols)

    @property
    def rows(self) -> int:
        """Number of measurement rows ``m``."""
        return self.points.shape[-2]

    @property
    def position_dim(self) -> int:
        """Coordinates of the node's position these rows fix: the points' (one less with
        ``height_m``: a 2-D node among 3-D points)."""
        return self.points.shape[-1] - (1 if self.height_m is not None else 0)

    def take(self, rows: np.ndarray) -> "Context":
        """The context of a subset of rows.

        Parameters
        ----------
        rows : ndarray
            An index array or a boolean mask over the rows.

        Returns
        -------
        Context
        """
        def sub(a, axis):
            return None if a is None else np.take(a, rows, axis=axis) if np.asarray(rows).dtype != bool \
                else np.compress(rows, a, axis=axis)

        return Context(points=sub(self.points, -2), index=sub(self.index, 0),
                       reference=sub(self.reference, -2),
                       reference_index=sub(self.reference_index, 0), std=sub(self.std, -1),
                       height_m=self.height_m, group=sub(self.group, 0),
                       columns=None if self.columns is None else
                       {k: sub(v, 0) for k, v in self.columns.items()})


def numerical_jacobian(model: "MeasurementModel", state: States, context: Context,
                       step: float = 1e-6) -> dict[str, np.ndarray]:
    """Central-difference Jacobian of ``model.predict`` per component it reads.

    Parameters
    ----------
    model : MeasurementModel
    state : dict
        Named components (see :meth:`StateLayout.split`).
    context : Context
    step : float
        Relative step (scaled by ``max(1, |x|)`` per entry).

    Returns
    -------
    dict
        ``{component: (..., m, k)}`` for every component in ``model.reads``.
    """
    out = {}
    for name in model.reads:
        x = np.asarray(state[name], dtype=float)
        scalar = name in ("clock_offset", "clock_drift")
        xv = x[..., None] if scalar else x
        cols = []
        for j in range(xv.shape[-1]):
            h = step * np.maximum(1.0, np.abs(xv[..., j]))
            plus, minus = xv.copy(), xv.copy()
            plus[..., j] += h
            minus[..., j] -= h
            sp, sm = dict(state), dict(state)
            sp[name] = plus[..., 0] if scalar else plus
            sm[name] = minus[..., 0] if scalar else minus
            dz = model.residual(model.predict(sp, context), model.predict(sm, context))
            cols.append(dz / (2.0 * h[..., None]))
        out[name] = np.stack(cols, axis=-1)
    return out


class MeasurementModel:
    """Base class of measurement models (see the module docstring).

    A subclass sets :attr:`kind` and :attr:`reads`, implements :meth:`predict` and
    :meth:`std` (or overrides :meth:`noise_cov` and :meth:`logpdf` for a non-Gaussian or
    correlated noise), and should give an analytic :meth:`jacobian`.

    Attributes
    ----------
    kind : str
        The log-schema kind the model explains (``"range"``, ``"tdoa"``, ``"aoa"``, ...).
    reads : tuple of str
        State components it depends on (names of :data:`COMPONENTS`).
    angular : bool
        Whether residuals wrap (angles in radians).
    """

    kind: ClassVar[str] = ""
    reads: ClassVar[tuple[str, ...]] = ("position",)
    angular: ClassVar[bool] = False

    # ---- the measurement function -------------------------------------------------------
    def predict(self, state: States, context: Context) -> np.ndarray:  # pragma: no cover
        """Expected measurements ``h(x)``, shape ``(..., m)``.

        Parameters
        ----------
        state : dict
            Named components of a batch of states (:meth:`StateLayout.split`).
        context : Context
            The rows' reference points.

        Returns
        -------
        ndarray, shape (..., m)
        """
        raise NotImplementedError

    def jacobian(self, state: States, context: Context) -> dict[str, np.ndarray]:
        """``d h / d`` each component read, ``{name: (..., m, k)}`` (scalar components:
        ``k = 1``). The base class differentiates numerically.

        Parameters
        ----------
        state : dict
            Named components of a batch of states (:meth:`StateLayout.split`).
        context : Context
            The rows' reference points.

        Returns
        -------
        dict
        """
        return numerical_jacobian(self, state, context)

    def predict_with_jacobian(self, state: States, context: Context
                              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """:meth:`predict` and :meth:`jacobian` at one state (a model whose two share work,
        such as the geometry of a range, overrides this to do it once).

        Parameters
        ----------
        state : dict
            Named components of a batch of states (:meth:`StateLayout.split`).
        context : Context

        Returns
        -------
        z_hat : ndarray, shape (..., m)
        jacobian : dict
        """
        return self.predict(state, context), self.jacobian(state, context)

    def residual(self, z: np.ndarray, z_hat: np.ndarray) -> np.ndarray:
        """``z - z_hat``, wrapped to ``(-pi, pi]`` for an angular model.

        Parameters
        ----------
        z, z_hat : ndarray
            Measured and predicted values (broadcast).

        Returns
        -------
        ndarray
        """
        r = np.asarray(z, dtype=float) - np.asarray(z_hat, dtype=float)
        return wrap_angle(r) if self.angular else r

    # ---- the noise ----------------------------------------------------------------------
    def std(self, context: Context) -> np.ndarray:  # pragma: no cover - abstract
        """Per-row noise standard deviation ``(..., m)`` (the context's where given).

        Parameters
        ----------
        context : Context
            The rows' reference points (and per-row ``std``).

        Returns
        -------
        ndarray, shape (..., m)
        """
        raise NotImplementedError

    def row_std(self, default: float | np.ndarray, context: Context) -> np.ndarray:
        """``context.std`` where finite, else ``default``, broadcast to ``(..., m)``.

        Parameters
        ----------
        default : float or ndarray
            The model's standard deviation.
        context : Context

        Returns
        -------
        ndarray, shape (..., m)
        """
        base = np.broadcast_to(np.asarray(default, dtype=float), (context.rows,)) \
            if np.ndim(default) == 0 else np.asarray(default, dtype=float)
        if context.std is None:
            return base
        return np.where(np.isfinite(context.std), context.std, base)

    def noise_mean(self, context: Context) -> np.ndarray | float:
        """Mean of the noise (0: unbiased); an estimator subtracts it from ``z``.

        Parameters
        ----------
        context : Context
            The rows' reference points (and per-row ``std``).

        Returns
        -------
        float or ndarray, shape (..., m)
        """
        return 0.0

    def noise_cov(self, context: Context) -> np.ndarray:
        """Noise covariance ``(..., m, m)``: diagonal ``std^2`` unless a model correlates
        its rows.

        Parameters
        ----------
        context : Context
            The rows' reference points (and per-row ``std``).

        Returns
        -------
        ndarray, shape (..., m, m)
        """
        s = self.std(context)
        return s[..., :, None] ** 2 * np.eye(s.shape[-1])

    def logpdf(self, z: np.ndarray, state: States, context: Context) -> np.ndarray:
        """Per-row log-density ``(..., m)`` of ``z`` given the state (NaN rows give 0).

        Parameters
        ----------
        z : ndarray, shape (..., m)
            Measured values (NaN: missing).
        state : dict
            Named components of a batch of states.
        context : Context

        Returns
        -------
        ndarray, shape (..., m)
        """
        z = checked_call(z, state, context, self.reads)
        r = self.residual(z, self.predict(state, context)) - self.noise_mean(context)
        lp = gaussian_logpdf(r, self.std(context))
        return np.where(np.isnan(r), 0.0, lp)

    def sample(self, state: States, context: Context, rng: np.random.Generator) -> np.ndarray:
        """A draw of the measurements ``h(x) + v``, ``v ~ N(noise_mean, noise_cov)``.

        Parameters
        ----------
        state : dict
            Named components of a batch of states (:meth:`StateLayout.split`).
        context : Context
            The rows' reference points.
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (..., m)
        """
        z_hat = self.predict(state, context)
        L = np.linalg.cholesky(self.noise_cov(context))
        v = np.einsum("...ij,...j->...i", L, rng.standard_normal(z_hat.shape))
        z = z_hat + self.noise_mean(context) + v
        return wrap_angle(z) if self.angular else z



class LikelihoodModel(MeasurementModel):
    """A model that gives only a log-likelihood on states (:meth:`logpdf`), with no
    measurement function to linearise and no fixed Gaussian noise: ``gaussian = False``,
    so :meth:`Tags.accepts <radioloc.estimators.base.Tags.accepts>` hands it to estimators
    whose ``tags.uses`` is ``"logpdf"`` only, and :meth:`predict`, :meth:`jacobian` and
    :meth:`std` refuse with a :class:`ConfigError` that says why (:attr:`why`). A subclass
    defines :meth:`logpdf` (and :meth:`predict` or :meth:`sample` where it has them)."""

    gaussian: ClassVar[bool] = False
    #: why the model has none of those (completes the refusal message)
    why: ClassVar[str] = "it is a likelihood on positions (logpdf only)"

    def refuse(self, what: str):
        """Raise the :class:`ConfigError` for a missing ``what``."""
        raise ConfigError(f"{type(self).__name__} has no {what}: {self.why}; use an estimator "
                          "whose tags.uses is 'logpdf'")

    def predict(self, state, context: Context) -> np.ndarray:
        self.refuse("measurement function h(x)")

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        self.refuse("Jacobian")

    def std(self, context: Context) -> np.ndarray:
        self.refuse("Gaussian noise")

def row_std(value, name: str) -> np.ndarray:
    """Per-row standard deviations as given by a user: real, NaN (the model's) or within
    ``[POSITIVE_FLOOR, MAGNITUDE_LIMIT]``.

    Parameters
    ----------
    value : array_like
    name : str
        For the messages.

    Returns
    -------
    ndarray
    """
    s = refuse_infinite(as_float_array(value, name, allow_nan=True), name)
    given = s[np.isfinite(s)]
    if np.any(given < POSITIVE_FLOOR):
        raise InputError(f"{name}: standard deviations must be at least {POSITIVE_FLOOR:g} "
                         f"(NaN: the model's), got {float(given.min())!r}")
    return s


def checked_call(z, state, context: Context, reads: tuple[str, ...] = ("position",)
                 ) -> np.ndarray:
    """The arguments of a model's ``logpdf`` checked at the boundary: ``z`` real numbers
    whose shape broadcasts with the rows the state and context predict.

    Parameters
    ----------
    z : array_like, shape (..., m)
    state : mapping
        Named components of a batch of states, ``position`` (..., P) among them.
    context : Context
    reads : tuple of str
        The components the model reads (:attr:`MeasurementModel.reads`).

    Returns
    -------
    ndarray
        ``z`` as float64.

    Raises
    ------
    InputError
        Naming ``state``, ``z`` or ``context.points``.
    """
    if not isinstance(context, Context):
        raise InputError(f"context: expected a Context, got {type(context).__name__}")
    if not isinstance(state, Mapping) or "position" not in state:
        raise InputError("state: expected a mapping of named components with 'position' "
                         f"(StateLayout.split), got {type(state).__name__}")
    missing = [k for k in reads if k not in state]
    if missing:
        raise InputError(f"state: the model reads {', '.join(missing)}, absent from the "
                         f"state's components {sorted(state)}")
    pos = np.shape(state["position"])
    dim = context.points.shape[-1]
    if not pos or pos[-1] not in (dim, 2 if context.height_m is not None else dim):
        raise InputError(f"state['position']: last axis {pos[-1:] or 'missing'} does not match "
                         f"the {dim}-D context.points")
    zz = check_dtype(z, "z").astype(float, copy=False)
    check_shapes("z", zz.shape, "the rows predicted from state and context",
                 pos[:-1] + (context.rows,))
    return zz


@dataclass(frozen=True)
class Observation:
    """Measurements of one kind for the generic estimators: a model, its values over time
    and the static context of its rows.

    Attributes
    ----------
    model : MeasurementModel
    z : ndarray, shape (..., T, m) for a filter or smoother, (..., m) for a snapshot fit
        Measured values; NaN where a row has no measurement at that step.
    context : Context
        The rows' reference points (the same at every step; a moving anchor gives
        ``points`` of shape ``(..., T, m, P)``, sliced per step by :meth:`at`).
    std : ndarray, shape (..., T, m), optional
        Per-row, per-step standard deviations (NaN: the model's).
    no_check : collection of str
        Checks of :func:`radioloc.core.plausibility.check_values` to leave out
        (``tdoa_units``, ``pseudorange_units``, ``angle_units``): by default a tdoa,
        pseudorange or angle observation whose values break the bound of their kind (a unit
        slip: mm, ns, degrees) is refused.
    """

    model: MeasurementModel
    z: np.ndarray
    context: Context
    std: np.ndarray | None = None
    no_check: Collection[str] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.model, MeasurementModel):
            raise InputError(f"model: expected a MeasurementModel, got {type(self.model).__name__}")
        z = as_float_array(self.z, "z", allow_nan=True)
        if z.shape[-1:] != (self.context.rows,):
            raise InputError(f"z: last axis has {z.shape[-1:] or 'no'} rows but the context has "
                             f"{self.context.rows}")
        object.__setattr__(self, "z", z)
        if self.std is not None:
            s = row_std(self.std, "std")
            if check_shapes("std", s.shape, "z", z.shape) != z.shape:
                raise InputError(f"std: shape {s.shape} does not broadcast to z's {z.shape}")
            object.__setattr__(self, "std", np.broadcast_to(s, z.shape))
        if self.model.kind == "range":
            check_ranges(z, "z", self.range_std_m())
        else:
            check_values(self.model.kind, z, self.context.points, self.context.reference,
                         skip=self.no_check, where=f"z ({self.model.kind})")

    def range_std_m(self) -> np.ndarray:
        """Per-row noise standard deviations of the negative-range rule
        (:func:`~radioloc.core.validation.check_ranges`): the row's ``std`` where given, else
        the context's, else the model's (its LOS standard deviation for a LOS/NLOS noise).

        Returns
        -------
        ndarray, broadcastable to ``z``
        """
        sigma = self.model.row_std(range_noise_std(self.model), self.context)
        if self.std is None:
            return sigma
        check_shapes("std", self.std.shape, "context.std", np.shape(sigma))
        return np.where(np.isfinite(self.std), self.std, sigma)

    @property
    def steps(self) -> int:
        """Number of time steps ``T`` (the second-to-last axis of ``z``)."""
        return self.z.shape[-2]

    @property
    def moving(self) -> bool:
        """Whether the context's points change with the step (``(..., T, m, P)``)."""
        pts = self.context.points
        return pts.ndim >= 3 and pts.shape[-3] == self.steps and pts.ndim == self.z.ndim + 1

    @property
    def static_context(self) -> bool:
        """Whether :meth:`at` gives the same context at every step (no moving points, no
        per-step ``std``), so that what depends on the context alone is worked out once."""
        return self.std is None and not self.moving

    def at(self, step: int) -> tuple[np.ndarray, Context]:
        """``(z_t, context_t)`` of one time step.

        Parameters
        ----------
        step : int
            Index on the time axis.

        Returns
        -------
        tuple of (ndarray, Context)
        """
        ctx = self.context
        if self.moving:
            ctx = _sliced(ctx, points=ctx.points[..., step, :, :],
                          reference=None if ctx.reference is None else ctx.reference[..., step, :, :])
        if self.std is not None:
            ctx = _sliced(ctx, std=self.std[..., step, :])
        return self.z[..., step, :], ctx


def _sliced(ctx: Context, **fields) -> Context:
    """``ctx`` with ``fields`` set to one step's slices of arrays already checked (by the
    :class:`Observation`): :meth:`Observation.at` runs once per step, and checking the
    context again cost as much as the filter's update."""
    new = copy.copy(ctx)
    for name, value in fields.items():
        object.__setattr__(new, name, value)
    return new
