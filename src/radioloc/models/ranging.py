"""Range measurement models and the geometry of a range.

Every range model has ``sample(true_ranges, rng)``, ``logpdf(measured, true_ranges)`` and
``moments()`` (mean and variance of the range error, what a Kalman filter uses);
:func:`range_geometry` gives the predicted range and its Jacobian for any of them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.kinds import Kind
from radioloc.core.validation import (check_dtype, check_positive, check_ranges, paired_arrays,
                                      range_noise_std)
from radioloc.models.measurement import Context, MeasurementModel, checked_call

_LOG_2PI = float(np.log(2.0 * np.pi))

__all__ = ["GaussianRange", "RangeModel", "range_geometry"]


def range_geometry(position: np.ndarray, anchors: np.ndarray, height_m: float | None = None,
                   min_distance_m: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Predicted ranges ``|x - a_m|`` and their Jacobian with respect to ``x``.

    Parameters
    ----------
    position : ndarray, shape (..., D)
        Positions ``(x, y[, z])``.
    anchors : ndarray, shape (..., M, D) or, with ``height_m``, (..., M, D + 1)
        Anchor positions (broadcast against ``position``'s batch axes).
    height_m : float, optional
        Known height of the node when ``position`` is 2-D and the anchors are 3-D: the
        range is ``sqrt(|xy - a_xy|^2 + (height_m - a_z)^2)`` and the Jacobian is taken
        over ``xy`` only.
    min_distance_m : float
        Distances are floored here so the Jacobian stays finite at an anchor.

    Returns
    -------
    ranges : ndarray, shape (..., M)
    jacobian : ndarray, shape (..., M, D)
        ``d|x - a_m| / dx``, the unit vectors from the anchors to ``x``.
    """
    diff, dist = _offsets(position, anchors, height_m)
    safe = np.maximum(dist, min_distance_m)
    return dist, diff / safe[..., None]


def _offsets(position: np.ndarray, anchors: np.ndarray, height_m: float | None
             ) -> tuple[np.ndarray, np.ndarray]:
    """``x - a_m`` (horizontal with ``height_m``) and the ranges of :func:`range_geometry`."""
    x = np.asarray(position, dtype=float)
    a = np.asarray(anchors, dtype=float)
    D = x.shape[-1]
    if height_m is None:
        if a.shape[-1] != D:
            raise InputError(f"anchors (context.points): {a.shape[-1]} coordinates but "
                             f"positions have {D} (give height_m for 2-D positions with 3-D anchors)")
        diff = x[..., None, :] - a
        dist = np.sqrt(np.sum(diff**2, axis=-1))
    else:
        if a.shape[-1] != D + 1:
            raise InputError(f"anchors: height_m needs {D + 1}-D anchors, got {a.shape[-1]}-D")
        diff = x[..., None, :] - a[..., :D]
        dz = float(height_m) - a[..., D]
        dist = np.sqrt(np.sum(diff**2, axis=-1) + dz**2)
    return diff, dist


@dataclass(frozen=True)
class GaussianRange:
    """Range with additive zero-mean Gaussian error: ``r = d + N(0, std_m^2)``.

    Parameters
    ----------
    std_m : float
        Standard deviation of the range error in metres (> 0).
    """

    std_m: float

    def __post_init__(self) -> None:
        check_positive(self.std_m, "std_m")

    @property
    def variance(self) -> float:
        return self.std_m**2

    def moments(self) -> tuple[float, float]:
        """Mean and variance of the range error.

        Returns
        -------
        tuple of float
            ``(0, std_m^2)``.
        """
        return 0.0, self.variance

    def sample(self, true_ranges: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Draw noisy ranges.

        Parameters
        ----------
        true_ranges : ndarray
            Distances, metres.
        rng : numpy.random.Generator

        Returns
        -------
        ndarray
            Ranges of the same shape.
        """
        d = check_dtype(true_ranges, "true_ranges").astype(float)
        return d + self.std_m * rng.standard_normal(d.shape)

    def logpdf(self, measured: np.ndarray, true_ranges: np.ndarray) -> np.ndarray:
        """Elementwise log-density of measured ranges.

        Parameters
        ----------
        measured : ndarray
        true_ranges : ndarray
            Broadcastable against ``measured``.

        Returns
        -------
        ndarray
        """
        m, d = paired_arrays("measured", measured, "true_ranges", true_ranges)
        z = (m - d) / self.std_m
        return -0.5 * z**2 - np.log(self.std_m) - 0.5 * _LOG_2PI


@dataclass(frozen=True)
class RangeModel(MeasurementModel):
    """Range (time of arrival, two-way ranging, RTT) to a known point:
    ``h(x) = |x - a| (+ o_a) (+ b_a)``.

    The measurement function of every range estimator; the error distribution is a noise
    model (:class:`GaussianRange`, or the LOS/NLOS mixture
    :class:`~radioloc.models.los_nlos.LosNlosRange` of paper 001, whose discrete link state
    a particle filter integrates exactly through :meth:`mode_logpdf`).

    Parameters
    ----------
    std_m : float, optional
        Standard deviation of a Gaussian range error, metres (the same as
        ``noise=GaussianRange(std_m)``). Give this or ``noise``.
    noise : GaussianRange or LosNlosRange, optional
        The range-error model.
    anchor_bias : bool
        Whether each anchor adds an unknown constant ``b_a`` (antenna delay, RTT offset):
        the model then reads the ``anchor_bias`` state component.
    offset_m : tuple of float, optional
        A known offset ``o_a`` of each anchor's ranges (by row of the anchor table), metres:
        e.g. the biases learned from a log (:mod:`radioloc.locate.self_tuning`).
    bias_terms : {1, 2}
        With ``anchor_bias``: one bias state per anchor, or two (``b_a = c_a + w_a``: a
        constant and a part that wanders, e.g. a Gauss-Markov process; the state's
        ``anchor_bias`` holds the ``A`` constants, then the ``A`` wandering parts).

    Examples
    --------
    >>> import numpy as np
    >>> from radioloc.models.measurement import Context, StateLayout
    >>> model = RangeModel(std_m=0.1)
    >>> ctx = Context(points=np.array([[0.0, 0.0], [10.0, 0.0]]))
    >>> z_hat, H = StateLayout(dim=2).measure(model, np.array([3.0, 4.0]), ctx)
    >>> z_hat.round(3).tolist()
    [5.0, 8.062]
    """

    std_m: float | None = None
    noise: object | None = None
    anchor_bias: bool = False
    offset_m: tuple[float, ...] | None = None
    bias_terms: int = 1

    kind: ClassVar[str] = "range"

    def __post_init__(self) -> None:
        copied = (self.std_m is not None and isinstance(self.noise, GaussianRange)
                  and self.noise.std_m == self.std_m)       # dataclasses.replace of a model
        if (self.std_m is None) == (self.noise is None) and not copied:
            raise InputError("RangeModel: give exactly one of std_m and noise")
        if self.noise is None:
            object.__setattr__(self, "noise", GaussianRange(self.std_m))
        if not hasattr(self.noise, "moments") or not hasattr(self.noise, "logpdf"):
            raise InputError(f"noise: expected a range-error model with moments() and logpdf(), "
                             f"got {type(self.noise).__name__}")
        if self.offset_m is not None:
            off = np.asarray(self.offset_m, dtype=float)
            if off.ndim != 1 or not np.all(np.isfinite(off)):
                raise InputError("offset_m: expected one finite offset (m) per anchor")
            object.__setattr__(self, "offset_m", tuple(float(v) for v in off))
        if self.bias_terms not in (1, 2):
            raise InputError(f"bias_terms: must be 1 or 2, got {self.bias_terms!r}")

    @property
    def reads(self) -> tuple[str, ...]:  # type: ignore[override]
        return ("position", "anchor_bias") if self.anchor_bias else ("position",)

    @property
    def modes(self) -> int:
        """Discrete states of a link (2 for LOS/NLOS: index 0 NLOS, 1 LOS), 1 otherwise."""
        return 2 if hasattr(self.noise, "logpdf_by_state") else 1

    def mode_transition(self) -> np.ndarray:
        """Markov chain of a row's discrete state from one step to the next,
        ``P[s_prev, s]``, shape ``(modes, modes)`` (the LOS/NLOS model's sticky chain)."""
        return self.noise.chain.transition if self.modes > 1 else np.ones((1, 1))

    def mode_prior(self) -> np.ndarray:
        """Probabilities of a new row's discrete states, shape ``(modes,)`` (the chain's
        stationary law)."""
        return self.noise.chain.stationary if self.modes > 1 else np.ones(1)

    def _bias_of(self, state, context: Context) -> np.ndarray | float:
        if not self.anchor_bias and self.offset_m is None:
            return 0.0
        if context.index is None or np.any(context.index < 0):
            raise InputError("context.index: a range model with anchor bias or offsets needs "
                             "the anchor table row of every measurement")
        out = 0.0 if self.offset_m is None else np.asarray(self.offset_m)[context.index]
        if self.anchor_bias:
            b = state["anchor_bias"]
            n = np.shape(b)[-1] // self.bias_terms
            for k in range(self.bias_terms):
                out = out + np.take(b, context.index + k * n, axis=-1)
        return out

    def predict(self, state, context: Context) -> np.ndarray:
        # without the Jacobian: a particle filter predicts for every particle
        d = _offsets(state["position"], context.points, context.height_m)[1]
        return d + self._bias_of(state, context)

    def jacobian(self, state, context: Context) -> dict[str, np.ndarray]:
        return self.predict_with_jacobian(state, context)[1]

    def predict_with_jacobian(self, state, context: Context
                              ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        d, u = range_geometry(state["position"], context.points, context.height_m)
        out = {"position": u}
        if self.anchor_bias:
            n_bias = np.shape(state["anchor_bias"])[-1]
            onehot = (context.index[:, None] % (n_bias // self.bias_terms)
                      == np.arange(n_bias) % (n_bias // self.bias_terms)).astype(float)
            out["anchor_bias"] = np.broadcast_to(onehot, u.shape[:-1] + (n_bias,))
        return d + self._bias_of(state, context), out

    def std(self, context: Context) -> np.ndarray:
        return self.row_std(np.sqrt(self.noise.moments()[1]), context)

    def noise_mean(self, context: Context) -> float:
        """Mean of the range error (the LOS/NLOS mixture's mean excess; 0 for Gaussian).

        Parameters
        ----------
        context : Context

        Returns
        -------
        float
        """
        return float(self.noise.moments()[0])

    def checked(self, z, state, context: Context) -> np.ndarray:
        """``z`` checked as :meth:`logpdf` checks it: real numbers of the rows' shape, no
        range below its floor (:func:`~radioloc.core.validation.check_ranges`).

        Parameters
        ----------
        z : array_like, shape (..., m)
        state : dict
            Named components of a batch of states.
        context : Context

        Returns
        -------
        ndarray
            ``z`` as float64.
        """
        z = checked_call(z, state, context, self.reads)
        return check_ranges(z, "z", self.row_std(range_noise_std(self), context))

    def logpdf(self, z, state, context: Context) -> np.ndarray:
        z = self.checked(z, state, context)
        if context.std is not None or isinstance(self.noise, GaussianRange):
            return super().logpdf(z, state, context)
        lp = self.noise.logpdf(z, self.predict(state, context))
        return np.where(np.isnan(lp), 0.0, lp)

    def mode_logpdf(self, z, state, context: Context) -> np.ndarray:
        """Per-row log-density under each discrete link state, ``(..., m, modes)``.

        Parameters
        ----------
        z : ndarray, shape (..., m)
            Measured ranges (NaN: missing).
        state : dict
            Named components of a batch of states.
        context : Context

        Returns
        -------
        ndarray, shape (..., m, modes)
        """
        if self.modes == 1:
            return self.logpdf(z, state, context)[..., None]
        check_ranges(np.asarray(z, dtype=float), "z", self.row_std(range_noise_std(self), context))
        z_hat = self.predict(state, context)
        lp = self.noise.logpdf_by_state(z, z_hat)
        return np.where(np.isnan(lp), 0.0, lp)

    def sample(self, state, context: Context, rng: np.random.Generator) -> np.ndarray:
        z_hat = self.predict(state, context)
        if context.std is None and hasattr(self.noise, "logpdf_by_state"):
            los = rng.random(z_hat.shape) < self.noise.alpha
            return self.noise.sample(z_hat, los, rng)
        return super().sample(state, context, rng)


#: The log-schema kind this module explains (:mod:`radioloc.core.kinds`).
KINDS = (Kind("range", "m", "distance between the node and `peer` (time of arrival, two-way "
              "ranging, RTT)", model=lambda sigma: RangeModel(std_m=sigma),
              sigma_option="range_std_m", sigma_default=0.15,
              sigma_help="range error standard deviation, m", limit=1e7, slips=()),)
