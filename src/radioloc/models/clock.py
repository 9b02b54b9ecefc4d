"""The receiver clock as state: offset and drift, in metres and metres per second.

An unsynchronised tag's clock reads ``t + offset / c`` and runs fast by the fractional
frequency error ``drift / c`` (both multiplied by the speed of light ``c`` so that they add
to ranges). The standard two-state clock model (a random walk on the offset and on the
drift, e.g. Brown & Hwang, *Introduction to Random Signals and Applied Kalman Filtering*,
Sect. 9.3) gives, over ``dt`` seconds,

    F = [[1, dt], [0, 1]]
    Q = [[q_o dt + q_d dt^3 / 3, q_d dt^2 / 2], [q_d dt^2 / 2, q_d dt]]

with ``q_o = offset_std_m^2`` (m^2/s) and ``q_d = drift_std_m_per_s^2`` (m^2/s^3): the
offset's own random walk grows by ``offset_std_m`` and the drift by ``drift_std_m_per_s``
over one second.

How an estimator uses it
------------------------
The state of :class:`~radioloc.models.measurement.StateLayout` is ``[motion, clock,
clock_bias, anchor_bias]``. A filter whose layout holds a clock (``layout.clock`` 1 or 2,
grown by ``with_model`` for a :class:`~radioloc.models.pseudorange.PseudorangeModel` or a
:class:`~radioloc.models.tdoa.TdoaModel` with slot times) transitions the full state with the
block-diagonal ``diag(motion.F(dt), clock.F(dt), I, I)`` and ``diag(motion.Q(dt),
clock.Q(dt), 0, q_b dt I)``: :func:`transition` assembles both. The inter-system biases
``clock_bias`` of a receiver with a clock per constellation (``layout.n_clock_bias``) are
constants (the receivers' hardware delays between the constellations' signals); the anchor
biases take a random walk of intensity ``q_b``. With ``terms=1`` (offset only) the blocks are
``[[1]]`` and ``[[q_o dt]]``. The extended Kalman filter and the batch smoother transition
their states with :func:`transition` too, and hold the drift by default when a model reads
the offset (:func:`drifting`): a clock held still would take a drift of 1 m/s on
pseudoranges into the position (metres off within a minute, with a covariance of
decimetres).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array, check_positive
from radioloc.models.measurement import StateLayout

__all__ = ["ClockModel", "transition", "drifting"]


class ClockModel:
    """Random-walk offset and drift of a receiver clock (see the module docstring).

    Parameters
    ----------
    offset_std_m : float
        Growth of the offset's own random walk over one second, metres (>= 0).
    drift_std_m_per_s : float
        Growth of the drift's random walk over one second, m/s (>= 0).
    terms : {1, 2}
        State terms: 1 the offset only, 2 offset and drift (``StateLayout.clock``).

    Examples
    --------
    >>> clock = ClockModel(offset_std_m=0.1, drift_std_m_per_s=0.01)
    >>> clock.F(0.5).tolist()
    [[1.0, 0.5], [0.0, 1.0]]
    """

    def __init__(self, offset_std_m: float, drift_std_m_per_s: float = 0.0,
                 terms: int = 2) -> None:
        self.offset_std_m = check_positive(offset_std_m, "offset_std_m", allow_zero=True)
        self.drift_std_m_per_s = check_positive(drift_std_m_per_s, "drift_std_m_per_s",
                                                allow_zero=True)
        if terms not in (1, 2):
            raise InputError(f"terms: clock terms must be 1 (offset) or 2 (offset, drift), "
                             f"got {terms!r}")
        self.terms = int(terms)
        self.state_dim = self.terms

    @staticmethod
    def _dt(dt) -> np.ndarray:
        d = as_float_array(dt, "dt")
        if np.any(d < 0):
            raise InputError("dt: time steps must be >= 0 s")
        return d

    def F(self, dt: float | np.ndarray) -> np.ndarray:
        """Transition ``(..., terms, terms)`` over ``dt`` seconds ``(...)``.

        Parameters
        ----------
        dt : float or ndarray
            Seconds (>= 0).

        Returns
        -------
        ndarray, shape (..., terms, terms)
        """
        d = self._dt(dt)
        if self.terms == 1:
            return np.ones(d.shape + (1, 1))
        one, zero = np.ones_like(d), np.zeros_like(d)
        return np.stack([np.stack([one, d], -1), np.stack([zero, one], -1)], -2)

    def Q(self, dt: float | np.ndarray) -> np.ndarray:
        """Process noise ``(..., terms, terms)`` over ``dt`` seconds, m^2 (and m^2/s,
        m^2/s^2).

        Parameters
        ----------
        dt : float or ndarray
            Seconds (>= 0).

        Returns
        -------
        ndarray, shape (..., terms, terms)
        """
        d = self._dt(dt)
        qo, qd = self.offset_std_m**2, self.drift_std_m_per_s**2
        if self.terms == 1:
            return (qo * d)[..., None, None]
        return np.stack([np.stack([qo * d + qd * d**3 / 3, qd * d**2 / 2], -1),
                         np.stack([qd * d**2 / 2, qd * d], -1)], -2)

    def predict(self, state: np.ndarray, dt: float | np.ndarray) -> np.ndarray:
        """Noise-free next clock state ``F x`` ``(..., terms)``.

        Parameters
        ----------
        state : ndarray, shape (..., terms)
            Offset (m) and drift (m/s).
        dt : float or ndarray
            Seconds.

        Returns
        -------
        ndarray, shape (..., terms)
        """
        x = as_float_array(state, "state", min_ndim=1, last_dim=self.terms)
        return np.einsum("...ij,...j->...i", self.F(dt), x)

    def sample(self, state: np.ndarray, dt: float | np.ndarray,
               rng: np.random.Generator) -> np.ndarray:
        """A draw of the next clock state ``F x + w``, ``w ~ N(0, Q(dt))``.

        Parameters
        ----------
        state : ndarray, shape (..., terms)
        dt : float or ndarray
            Seconds.
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (..., terms)
        """
        mean = self.predict(state, dt)
        q = np.broadcast_to(self.Q(dt), mean.shape + (self.terms,))
        vals, vecs = np.linalg.eigh(q)  # Q is singular at dt = 0
        w = rng.standard_normal(mean.shape)
        return mean + np.einsum("...ij,...j->...i", vecs, np.sqrt(np.maximum(vals, 0.0)) * w)

    def __repr__(self) -> str:
        return (f"ClockModel(offset_std_m={self.offset_std_m}, "
                f"drift_std_m_per_s={self.drift_std_m_per_s}, terms={self.terms})")


def drifting(layout: StateLayout, given: StateLayout) -> StateLayout:
    """A filter's state with the clock's drift: ``layout`` (grown by the models) with
    ``clock=2`` when a model asked for the offset alone and the estimator's own layout
    ``given`` did not fix the clock terms. A receiver clock drifts (as the simulator's,
    :class:`ClockModel`); an offset held still would absorb the drift into the position.

    Parameters
    ----------
    layout : StateLayout
        The layout grown by the observations' models.
    given : StateLayout
        The estimator's layout before growing (``clock`` 0: not fixed by the user).

    Returns
    -------
    StateLayout
    """
    return replace(layout, clock=2) if layout.clock == 1 and given.clock == 0 else layout


def transition(layout: StateLayout, motion, dt: float | np.ndarray,
               clock: ClockModel | None = None,
               bias_std_m_per_sqrt_s: float | np.ndarray = 0.0,
               bias_time_constant_s: float | np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
    """``F`` and ``Q`` ``(..., n, n)`` of a whole :class:`StateLayout` state over ``dt``:
    block-diagonal motion, clock, constant inter-system clock biases and anchor biases that
    wander (a random walk, or a first-order Gauss-Markov process with a time constant); the
    one transition of the extended Kalman filter, the batch smoother and the simulator.

    An anchor bias driven by white noise of intensity ``q^2`` (``q`` =
    ``bias_std_m_per_sqrt_s``) with time constant ``tau`` decays by ``a = exp(-dt / tau)``
    and gains variance ``q^2 tau / 2 (1 - a^2)`` over ``dt`` (its stationary standard
    deviation is ``q sqrt(tau / 2)``); as ``tau`` grows this tends to the random walk,
    ``F = 1`` and ``Q = q^2 dt``.

    Parameters
    ----------
    layout : StateLayout
        (A network layout: the motion's blocks per node, :meth:`StateLayout.kinematic`.)
    motion : motion model
        With ``F(dt)``, ``Q(dt)`` of one node's kinematic state (e.g.
        :class:`~radioloc.models.motion.WhiteAccelerationCV`), or None for a static
        position (``F = I``, ``Q = 0``).
    dt : float or ndarray
        Seconds.
    clock : ClockModel, optional
        Needed when the layout holds a clock; its ``terms`` must equal ``layout.clock``.
    bias_std_m_per_sqrt_s : float or ndarray, shape (..., A)
        Intensity of the white noise driving each anchor bias: a random walk's standard
        deviation grows by this over one second (0: constant biases). One value, or one per
        anchor (and per member of the batch).
    bias_time_constant_s : float or ndarray, shape (..., A), optional
        Time constant of each anchor bias (a Gauss-Markov process reverting to 0); None or
        ``inf``: a random walk.

    Returns
    -------
    F, Q : ndarray, shape (..., n, n)
    """
    d = np.asarray(dt, dtype=float)
    n, k = layout.size, layout.motion_size
    if motion is not None:
        Fm, Qm = layout.kinematic(motion.F(d)), layout.kinematic(motion.Q(d))
        if Fm.shape[-1] != k:
            raise InputError(f"motion: its state has {Fm.shape[-1]} entries but the layout's "
                             f"motion part has {k}")
        if n == k:                                   # the kinematic state alone
            return Fm, Qm
    F = np.broadcast_to(np.eye(n), d.shape + (n, n)).copy()
    Q = np.zeros(d.shape + (n, n))
    if motion is not None:
        F[..., :k, :k] = Fm
        Q[..., :k, :k] = Qm
    if layout.clock:
        if clock is None or clock.terms != layout.clock:
            raise InputError(f"clock: the layout holds {layout.clock} clock term(s); give a "
                             f"ClockModel with terms={layout.clock}")
        sl = slice(k, k + layout.clock)
        F[..., sl, sl] = clock.F(d)
        Q[..., sl, sl] = clock.Q(d)
    # clock_bias (layout.n_clock_bias): constants, F = I and Q = 0 as initialised
    if layout.n_bias:
        b = np.arange(layout.slices["anchor_bias"].start, layout.slices["anchor_bias"].stop)
        F[..., b, b], Q[..., b, b] = bias_transition(d, bias_std_m_per_sqrt_s,
                                                     bias_time_constant_s)
    return F, Q


def bias_transition(dt: np.ndarray, q: float | np.ndarray,
                    tau: float | np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Decay ``a`` and added variance of each anchor bias over ``dt`` (see
    :func:`transition`), shape ``dt.shape + (A,)`` (``(..., 1)`` for scalar settings).

    Parameters
    ----------
    dt : ndarray, shape (...)
        Seconds.
    q : float or ndarray, shape (..., A)
        Driving-noise intensity, m/sqrt(s).
    tau : float or ndarray, shape (..., A), optional
        Time constants, s (None or inf: random walk).

    Returns
    -------
    a, var : ndarray
    """
    d = np.asarray(dt, dtype=float)[..., None]
    q2 = np.asarray(q, dtype=float) ** 2
    if tau is None:
        return np.ones_like(d), q2 * d
    tau = np.asarray(tau, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        a = np.exp(-d / tau)
        var = np.where(np.isfinite(tau), q2 * tau / 2 * -np.expm1(-2 * d / tau), q2 * d)
    return np.where(np.isfinite(tau), a, 1.0), var
