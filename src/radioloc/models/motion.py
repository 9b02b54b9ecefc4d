"""Motion models: how a node's state moves between two measurement times.

Every model is an object with the same small interface, so that any recursive estimator
(Kalman filters, particle filters, grid filters) can take it as an argument:

* ``dim``: number of position coordinates D; ``state_dim``: length n of the state vector,
  whose first D entries are always the position ``(x, y[, z])``;
* ``F(dt)`` ``(..., n, n)`` and ``Q(dt)`` ``(..., n, n)``: the linear transition and its
  process-noise covariance over an interval ``dt`` (seconds, scalar or array; the result
  broadcasts over ``dt``'s shape);
* ``predict(state, dt, control=None)``: the noise-free next state ``F x (+ control)``;
* ``sample(state, dt, rng, control=None)``: a draw of the next state;
* ``logpdf(next_state, state, dt, control=None)``: the transition log-density.

State arrays are ``(..., n)`` with batch axes leading (runs, particles, nodes).
"""

from __future__ import annotations

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.kinds import Kind, Slip
from radioloc.core.validation import as_float_array, check_positive, check_positive_values

_LOG_2PI = float(np.log(2.0 * np.pi))

__all__ = ["MotionModel", "RandomWalk", "ConstantVelocity", "WhiteAccelerationCV",
           "ConstantAcceleration", "WhiteJerkCA",
           "InputDriven", "UniformDisk", "BoundedSpeedCV", "gaussian_logpdf_mv"]


def _check_dim(dim: int) -> int:
    if int(dim) != dim or dim not in (1, 2, 3):
        raise ConfigError(f"dim: must be 1, 2 or 3 position coordinates, got {dim!r}")
    return int(dim)


def _as_dt(dt: object) -> np.ndarray:
    d = as_float_array(dt, "dt")
    if np.any(~np.isfinite(d)) or np.any(d < 0):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(d) | (d < 0))[0]) if d.ndim else ()
        raise InputError(f"dt: time steps must be finite and >= 0 s, bad value at index {bad}")
    return d


def _per_member(q, blocks: np.ndarray) -> np.ndarray:
    """``blocks`` ``(..., b, b)`` scaled by ``q``: a scalar, or an array with one value per
    batch member (broadcast against the leading axes of ``dt``)."""
    return np.asarray(q)[..., None, None] * blocks


def _kron_blocks(blocks: np.ndarray, dim: int) -> np.ndarray:
    """``(..., b, b)`` per-axis blocks -> ``(..., b*dim, b*dim)`` with state order
    ``[pos(dim), vel(dim), ...]`` (i.e. ``kron(blocks, I_dim)``)."""
    b = blocks.shape[-1]
    out = blocks[..., :, None, :, None] * np.eye(dim)[:, None, :]
    return out.reshape(blocks.shape[:-2] + (b * dim, b * dim))


def gaussian_logpdf_mv(x: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Multivariate normal log-density ``(...)`` of ``x`` ``(..., n)`` under ``N(mean, cov)``."""
    diff = np.asarray(x, dtype=float) - np.asarray(mean, dtype=float)
    chol = np.linalg.cholesky(cov)
    z = np.linalg.solve(chol, diff[..., None])[..., 0]
    logdet = 2.0 * np.sum(np.log(np.diagonal(chol, axis1=-2, axis2=-1)), axis=-1)
    return -0.5 * np.sum(z * z, axis=-1) - 0.5 * logdet - 0.5 * diff.shape[-1] * _LOG_2PI


class MotionModel:
    """Base class of the linear-Gaussian motion models (a position-first state vector).

    Subclasses define ``dim``, ``state_dim`` and the per-axis blocks
    :meth:`_axis_F` / :meth:`_axis_Q` ``(..., b, b)``; the full ``F`` and ``Q`` are their
    Kronecker products with the identity of the position dimension.
    """

    dim: int
    state_dim: int

    def _axis_F(self, dt: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _axis_Q(self, dt: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def F(self, dt: float | np.ndarray) -> np.ndarray:
        """State transition matrix over ``dt`` seconds, ``(..., n, n)`` for ``dt`` ``(...)``."""
        return _kron_blocks(self._axis_F(_as_dt(dt)), self.dim)

    def Q(self, dt: float | np.ndarray) -> np.ndarray:
        """Process-noise covariance over ``dt`` seconds, ``(..., n, n)``."""
        return _kron_blocks(self._axis_Q(_as_dt(dt)), self.dim)

    def position(self, state: np.ndarray) -> np.ndarray:
        """The position part ``(..., D)`` of a state ``(..., n)``."""
        return np.asarray(state)[..., : self.dim]

    def _check_state(self, state: object, name: str = "state") -> np.ndarray:
        return as_float_array(state, name, min_ndim=1, last_dim=self.state_dim)

    def predict(self, state: np.ndarray, dt: float | np.ndarray,
                control: np.ndarray | None = None) -> np.ndarray:
        """Noise-free next state ``F(dt) x`` (plus ``control`` on the position, if given)."""
        x = self._check_state(state)
        out = np.einsum("...ij,...j->...i", self.F(dt), x)
        if control is not None:
            out = out.copy()
            out[..., : self.dim] += as_float_array(control, "control", last_dim=self.dim)
        return out

    def sample(self, state: np.ndarray, dt: float | np.ndarray, rng: np.random.Generator,
               control: np.ndarray | None = None) -> np.ndarray:
        """A draw of the next state ``F x + w``, ``w ~ N(0, Q(dt))``."""
        mean = self.predict(state, dt, control)
        q = np.broadcast_to(self.Q(dt), mean.shape + (self.state_dim,))
        # Q can be singular (e.g. dt = 0): use an eigen-decomposition, not Cholesky
        vals, vecs = np.linalg.eigh(q)
        z = rng.standard_normal(mean.shape)
        return mean + np.einsum("...ij,...j->...i", vecs, np.sqrt(np.maximum(vals, 0.0)) * z)

    def logpdf(self, next_state: np.ndarray, state: np.ndarray, dt: float | np.ndarray,
               control: np.ndarray | None = None) -> np.ndarray:
        """Transition log-density ``log N(next; F x (+ control), Q(dt))``, ``(...)``."""
        mean = self.predict(state, dt, control)
        return gaussian_logpdf_mv(self._check_state(next_state, "next_state"), mean, self.Q(dt))


class RandomWalk(MotionModel):
    """Position random walk: ``x_{t+dt} = x_t + w``, ``w ~ N(0, q dt I)``.

    Parameters
    ----------
    q_m2_per_s : float or ndarray
        Diffusion rate ``q`` in m^2/s (the position variance grows by ``q dt`` per axis); an
        array gives each member of a batch its own (its shape broadcasts against ``dt``'s).
    dim : int
        Position coordinates D (2 or 3; 1 for a line).
    """

    def __init__(self, q_m2_per_s: float, dim: int = 2) -> None:
        self.q_m2_per_s = check_positive_values(q_m2_per_s, "q_m2_per_s")
        self.dim = _check_dim(dim)
        self.state_dim = self.dim

    def _axis_F(self, dt):
        return np.ones(dt.shape + (1, 1))

    def _axis_Q(self, dt):
        return _per_member(self.q_m2_per_s, dt[..., None, None])

    def __repr__(self) -> str:
        return f"RandomWalk(q_m2_per_s={self.q_m2_per_s}, dim={self.dim})"


class ConstantVelocity(MotionModel):
    """Constant velocity driven by a random acceleration held over each interval.

    Per axis ``p' = p + dt v + a dt^2 / 2`` and ``v' = v + dt a`` with zero-mean
    accelerations ``a`` of variance ``accel_var``: this is eq. (1) of paper 002 (there
    called constant acceleration between samples). The state is
    ``[x, y(, z), vx, vy(, vz)]``;
    ``Q(dt) = accel_var [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]`` per axis.

    Parameters
    ----------
    accel_var : float
        Variance of each acceleration component, (m/s^2)^2.
    dim : int
        Position coordinates D.
    distribution : {"gaussian", "uniform"}
        Law of the accelerations drawn by :meth:`simulate` (paper 002 uses uniform); the
        filters use only the first two moments.
    """

    def __init__(self, accel_var: float, dim: int = 2, distribution: str = "gaussian") -> None:
        self.accel_var = check_positive(accel_var, "accel_var", allow_zero=True)
        self.dim = _check_dim(dim)
        self.state_dim = 2 * self.dim
        if distribution not in ("uniform", "gaussian"):
            raise ConfigError(f"distribution: must be 'uniform' or 'gaussian', got {distribution!r}")
        self.distribution = distribution

    @property
    def excess_kurtosis(self) -> float:
        """Excess kurtosis of the acceleration law: -1.2 uniform, 0 Gaussian."""
        return -1.2 if self.distribution == "uniform" else 0.0

    def _axis_F(self, dt):
        one, zero = np.ones_like(dt), np.zeros_like(dt)
        return np.stack([np.stack([one, dt], -1), np.stack([zero, one], -1)], -2)

    def _axis_Q(self, dt):
        q = self.accel_var
        return q * np.stack([np.stack([dt**4 / 4, dt**3 / 2], -1),
                             np.stack([dt**3 / 2, dt**2], -1)], -2)

    def sample_accelerations(self, shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
        """Draw accelerations of :attr:`distribution`.

        Parameters
        ----------
        shape : tuple of int
        rng : numpy.random.Generator

        Returns
        -------
        ndarray
            Zero-mean accelerations of variance ``accel_var``, (m/s^2).
        """
        s = np.sqrt(self.accel_var)
        if self.distribution == "uniform":
            return rng.uniform(-np.sqrt(3.0) * s, np.sqrt(3.0) * s, size=shape)
        return rng.normal(0.0, s, size=shape)

    def propagate(self, initial_state: np.ndarray, accelerations: np.ndarray,
                  dt: float) -> np.ndarray:
        """Apply eq. (1) of paper 002 step by step with the given accelerations.

        Parameters
        ----------
        initial_state : ndarray, shape (..., 2D)
            State at step 0.
        accelerations : ndarray, shape (..., n - 1, D)
            Acceleration held over each interval.
        dt : float
            The (constant) interval T in seconds.

        Returns
        -------
        ndarray, shape (..., n, 2D)
            States at steps 0..n-1.
        """
        s0 = self._check_state(initial_state, "initial_state")
        g = as_float_array(accelerations, "accelerations", last_dim=self.dim, min_ndim=2)
        T = check_positive(dt, "dt")
        D = self.dim
        pos = s0[..., None, :D] + np.zeros(g.shape[:-2] + (1, D))
        vel = s0[..., None, D:] + np.zeros(g.shape[:-2] + (1, D))
        # closed form of the recursion: v_n = v_0 + T sum_{m<n} a_m,
        # p_n = p_0 + n T v_0 + T^2 sum_{m<n} (n - m - 1/2) a_m
        dv = np.concatenate([np.zeros_like(g[..., :1, :]), np.cumsum(g, axis=-2)], axis=-2) * T
        n = g.shape[-2] + 1
        i = np.arange(n)[:, None]
        m = np.arange(n - 1)[None, :]
        c = np.where(m < i, i - m - 0.5, 0.0)
        dx = T**2 * np.einsum("nm,...md->...nd", c, g)
        steps = np.arange(n)[:, None] * T
        return np.concatenate([pos + steps * vel + dx, vel + dv], axis=-1)

    def simulate(self, initial_state: np.ndarray, n_steps: int, dt: float,
                 rng: np.random.Generator) -> np.ndarray:
        """Simulate a track with accelerations of :attr:`distribution`.

        Parameters
        ----------
        initial_state : ndarray, shape (..., 2D)
            State at step 0.
        n_steps : int
            Number of states, the first included.
        dt : float
            Interval T, seconds.
        rng : numpy.random.Generator

        Returns
        -------
        ndarray, shape (..., n_steps, 2D)
        """
        s0 = self._check_state(initial_state, "initial_state")
        if int(n_steps) < 1:
            raise InputError(f"n_steps: must be >= 1, got {n_steps}")
        g = self.sample_accelerations(s0.shape[:-1] + (int(n_steps) - 1, self.dim), rng)
        return self.propagate(s0, g, dt)

    def __repr__(self) -> str:
        return (f"ConstantVelocity(accel_var={self.accel_var}, dim={self.dim}, "
                f"distribution={self.distribution!r})")


class WhiteAccelerationCV(MotionModel):
    """Constant velocity driven by continuous white acceleration (for uneven intervals).

    Per axis ``F = [[1, dt], [0, 1]]`` and ``Q(dt) = q [[dt^3/3, dt^2/2], [dt^2/2, dt]]``: the
    process noise of an interval is the same however the interval is split into steps,
    which asynchronous range rows need. (:class:`ConstantVelocity` holds one random
    acceleration over each interval, paper 002's model: its noise shrinks when the same
    interval is cut into more steps.)

    Parameters
    ----------
    q : float or ndarray
        Spectral density of the acceleration, m^2/s^3 per axis (>= 0); an array gives each
        member of a batch its own (its shape broadcasts against ``dt``'s).
    dim : int
        Position coordinates D.
    """

    def __init__(self, q: float, dim: int = 2) -> None:
        self.q = check_positive_values(q, "q")
        self.dim = _check_dim(dim)
        self.state_dim = 2 * self.dim

    def _axis_F(self, dt):
        one, zero = np.ones_like(dt), np.zeros_like(dt)
        return np.stack([np.stack([one, dt], -1), np.stack([zero, one], -1)], -2)

    def _axis_Q(self, dt):
        return _per_member(self.q, np.stack([np.stack([dt**3 / 3, dt**2 / 2], -1),
                                             np.stack([dt**2 / 2, dt], -1)], -2))

    def __repr__(self) -> str:
        return f"WhiteAccelerationCV(q={self.q}, dim={self.dim})"


class ConstantAcceleration(MotionModel):
    """Constant acceleration driven by a random jerk held over each interval.

    State ``[pos(D), vel(D), acc(D)]``; per axis ``F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]]``
    and ``Q = jerk_var g g^T`` with ``g = [dt^3/6, dt^2/2, dt]``.

    Parameters
    ----------
    jerk_var : float
        Variance of each jerk component, (m/s^3)^2.
    dim : int
        Position coordinates D.
    """

    def __init__(self, jerk_var: float, dim: int = 2) -> None:
        self.jerk_var = check_positive(jerk_var, "jerk_var", allow_zero=True)
        self.dim = _check_dim(dim)
        self.state_dim = 3 * self.dim

    def _axis_F(self, dt):
        one, zero = np.ones_like(dt), np.zeros_like(dt)
        return np.stack([np.stack([one, dt, dt**2 / 2], -1),
                         np.stack([zero, one, dt], -1),
                         np.stack([zero, zero, one], -1)], -2)

    def _axis_Q(self, dt):
        g = np.stack([dt**3 / 6, dt**2 / 2, dt], -1)
        return self.jerk_var * g[..., :, None] * g[..., None, :]

    def __repr__(self) -> str:
        return f"ConstantAcceleration(jerk_var={self.jerk_var}, dim={self.dim})"


class WhiteJerkCA(WhiteAccelerationCV):
    """Constant acceleration driven by continuous white jerk (for uneven intervals).

    Per axis ``F = [[1, dt, dt^2/2], [0, 1, dt], [0, 0, 1]]`` and ``Q(dt) = q [[dt^5/20,
    dt^4/8, dt^3/6], [dt^4/8, dt^3/3, dt^2/2], [dt^3/6, dt^2/2, dt]]`` (Bar-Shalom, Li,
    Kirubarajan, *Estimation with Applications to Tracking and Navigation*, 2001,
    Sect. 6.2.3): full rank, and the same over an interval however it is split into steps
    (:class:`ConstantAcceleration` holds one jerk over each interval: rank one).

    Parameters
    ----------
    q : float or ndarray
        Spectral density of the jerk, m^2/s^5 per axis (>= 0); an array gives each member of
        a batch its own (its shape broadcasts against ``dt``'s).
    dim : int
        Position coordinates D.
    """

    def __init__(self, q: float, dim: int = 2) -> None:
        super().__init__(q, dim)
        self.state_dim = 3 * self.dim

    _axis_F = ConstantAcceleration._axis_F

    def _axis_Q(self, dt):
        rows = [[dt**5 / 20, dt**4 / 8, dt**3 / 6], [dt**4 / 8, dt**3 / 3, dt**2 / 2],
                [dt**3 / 6, dt**2 / 2, dt]]
        return _per_member(self.q, np.stack([np.stack(r, -1) for r in rows], -2))

    def __repr__(self) -> str:
        return f"WhiteJerkCA(q={self.q}, dim={self.dim})"


class InputDriven(MotionModel):
    """Odometry or INS driven motion: ``x_t = x_{t-1} + u_t + w``, ``w ~ N(0, std_m^2 I)``.

    ``u_t`` (the ``control``) is the displacement read from odometry or an inertial
    sensor over the step; the noise is per step, whatever ``dt`` (paper 001:
    ``p(v_t | v_{t-1}) = N(v_{t-1} + u_t, s_INS^2 I)``).

    Parameters
    ----------
    std_m : float
        Standard deviation of the displacement reading per axis and step, metres.
    dim : int
        Position coordinates D.
    """

    def __init__(self, std_m: float, dim: int = 2) -> None:
        self.std_m = check_positive(std_m, "std_m")
        self.dim = _check_dim(dim)
        self.state_dim = self.dim

    def _axis_F(self, dt):
        return np.ones(dt.shape + (1, 1))

    def _axis_Q(self, dt):
        return np.full(dt.shape + (1, 1), self.std_m**2)

    def sample(self, state, dt, rng, control=None):
        """Draw ``x + u + std_m N(0, I)``.

        Parameters
        ----------
        state : ndarray, shape (..., D)
        dt : float or ndarray
            Unused (the noise is per step).
        rng : numpy.random.Generator
        control : ndarray, shape (..., D), optional
            Displacement reading ``u``.

        Returns
        -------
        ndarray, shape (..., D)
        """
        mean = self.predict(state, dt, control)
        return mean + self.std_m * rng.standard_normal(mean.shape)

    def __repr__(self) -> str:
        return f"InputDriven(std_m={self.std_m}, dim={self.dim})"


class UniformDisk:
    """Bounded speed: the next position is uniform in the disk (ball) of radius
    ``v_max dt`` around the current one (paper 004, Sect. 4).

    Not linear-Gaussian: it has no ``F``/``Q``. Its first two moments (mean zero
    displacement, variance ``r^2 / (D + 2)`` per axis) are given by :meth:`Q` so that a
    Kalman filter can use it approximately; the mixture tracker uses the exact disk.

    Parameters
    ----------
    v_max_m_per_s : float
        Maximum speed, m/s (0: a static node).
    dim : int
        Position coordinates D.
    """

    def __init__(self, v_max_m_per_s: float, dim: int = 2) -> None:
        self.v_max_m_per_s = check_positive(v_max_m_per_s, "v_max_m_per_s", allow_zero=True)
        self.dim = _check_dim(dim)
        self.state_dim = self.dim

    def radius(self, dt: float | np.ndarray) -> np.ndarray:
        """Radius of the reachable disk.

        Parameters
        ----------
        dt : float or ndarray
            Interval, seconds.

        Returns
        -------
        ndarray
            ``v_max dt``, metres.
        """
        return self.v_max_m_per_s * _as_dt(dt)

    def F(self, dt):
        """Transition matrix: the identity (the mean displacement is zero).

        Parameters
        ----------
        dt : float or ndarray

        Returns
        -------
        ndarray, shape (..., D, D)
        """
        return np.broadcast_to(np.eye(self.dim), _as_dt(dt).shape + (self.dim, self.dim)).copy()

    def Q(self, dt):
        """Covariance of the uniform displacement.

        Parameters
        ----------
        dt : float or ndarray

        Returns
        -------
        ndarray, shape (..., D, D)
            ``r^2 / (D + 2) I`` with ``r = v_max dt``.
        """
        r = self.radius(dt)
        return (r**2 / (self.dim + 2))[..., None, None] * np.eye(self.dim)

    def position(self, state):
        """The position part of a state.

        Parameters
        ----------
        state : ndarray, shape (..., D)

        Returns
        -------
        ndarray, shape (..., D)
        """
        return np.asarray(state)[..., : self.dim]

    def predict(self, state, dt, control=None):
        """Mean of the next position: the current one (plus ``control``).

        Parameters
        ----------
        state : ndarray, shape (..., D)
        dt : float or ndarray
        control : ndarray, shape (..., D), optional

        Returns
        -------
        ndarray, shape (..., D)
        """
        x = as_float_array(state, "state", last_dim=self.dim)
        return x if control is None else x + as_float_array(control, "control", last_dim=self.dim)

    def sample(self, state, dt, rng, control=None):
        """Uniform draw in the ball of radius ``v_max dt`` around each state.

        Parameters
        ----------
        state : ndarray, shape (..., D)
        dt : float or ndarray
        rng : numpy.random.Generator
        control : ndarray, shape (..., D), optional

        Returns
        -------
        ndarray, shape (..., D)
        """
        mean = self.predict(state, dt, control)
        r = np.broadcast_to(self.radius(dt), mean.shape[:-1])
        direction = rng.standard_normal(mean.shape)
        direction /= np.maximum(np.linalg.norm(direction, axis=-1, keepdims=True), 1e-300)
        radius = r * rng.random(mean.shape[:-1]) ** (1.0 / self.dim)
        return mean + radius[..., None] * direction

    def logpdf(self, next_state, state, dt, control=None):
        """Transition log-density.

        Parameters
        ----------
        next_state, state : ndarray, shape (..., D)
        dt : float or ndarray
        control : ndarray, shape (..., D), optional

        Returns
        -------
        ndarray, shape (...)
            ``-log(volume)`` inside the ball, ``-inf`` outside (a point mass when r = 0).
        """
        from scipy.special import gammaln

        mean = self.predict(state, dt, control)
        d = np.linalg.norm(as_float_array(next_state, "next_state") - mean, axis=-1)
        r = np.broadcast_to(self.radius(dt), d.shape)
        D = self.dim
        log_vol = (0.5 * D * np.log(np.pi) - gammaln(0.5 * D + 1)
                   + D * np.log(np.where(r > 0, r, 1.0)))
        inside = np.where(r > 0, d <= r, d == 0)
        return np.where(inside, np.where(r > 0, -log_vol, 0.0), -np.inf)

    def __repr__(self) -> str:
        return f"UniformDisk(v_max_m_per_s={self.v_max_m_per_s}, dim={self.dim})"


class BoundedSpeedCV(WhiteAccelerationCV):
    """Constant velocity driven by white acceleration, with the initial velocity uniform in
    the ball of radius ``v_max`` (a walking person: paper 004's speed bound, Sect. 4, given
    a velocity that persists between steps).

    ``F`` and ``Q`` are those of :class:`WhiteAccelerationCV`; ``v_max`` only sets the
    velocity prior of a tracker that has no other knowledge of the velocity.

    Parameters
    ----------
    q : float
        Spectral density of the acceleration, m^2/s^3 per axis (>= 0).
    v_max_m_per_s : float
        Maximum initial speed, m/s (> 0).
    dim : int
        Position coordinates D.
    """

    def __init__(self, q: float, v_max_m_per_s: float, dim: int = 2) -> None:
        super().__init__(q, dim)
        self.v_max_m_per_s = check_positive(v_max_m_per_s, "v_max_m_per_s")

    def __repr__(self) -> str:
        return (f"BoundedSpeedCV(q={self.q}, v_max_m_per_s={self.v_max_m_per_s}, "
                f"dim={self.dim})")


def _odometry_kind(axis: str, slips: tuple) -> Kind:
    return Kind(f"odometry_d{axis}", "m", f"the node's displacement along +{axis} since its "
                "previous odometry row (`peer` names the sensor; the motion's control input)",
                limit=1e4, self_measured=True, slips=slips)


#: The log-schema kinds of odometry (:mod:`radioloc.core.kinds`): the control input of
#: :class:`InputDriven`, no measurement model.
KINDS = (
    _odometry_kind("x", (Slip(np.negative, "negated", "odometry with the wrong sign?",
                              ("odometry_dx", "odometry_dy")),
                         Slip(lambda v: v / 1e3, "divided by 1000", "odometry in mm?",
                              ("odometry_dx", "odometry_dy")))),
    _odometry_kind("y", ()),
)
