"""A particle filter over any measurement model, with Rao-Blackwellised discrete row states.

The bootstrap filter (Gordon, Salmond and Smith, 1993; paper 001, Algorithm 1) with the
exact integration of a model's discrete per-row states of paper 001, Algorithm 2:

1. predict: every particle is drawn from the motion model, ``x_t^i ~ p(x_t | x_{t-1}^i)``
   (Algorithm 2, line 3);
2. update: each :class:`~radioloc.models.measurement.Observation` of the step multiplies
   the weights by its likelihood, ``log w_t^i += sum_rows log p(z_t | x_t^i)`` (the model's
   ``logpdf``; a NaN row contributes nothing). For a model with ``modes > 1`` discrete
   states per row (the LOS/NLOS link state of
   :class:`~radioloc.models.ranging.RangeModel` over
   :class:`~radioloc.models.los_nlos.LosNlosRange`), each particle carries the posterior of
   every row's state and the states are summed out exactly (Sect. IV)::

       phi_t^i(z) = p(z_t | z, x_t^i) * sum_{z'} P[z', z] q_{t-1}^i(z')   (row seen at t-1)
       phi_t^i(z) = p(z_t | z, x_t^i) * pi(z)                              (row new)
       log w_t^i += log sum_z phi_t^i(z),   q_t^i(z) = phi_t^i(z) / sum_z phi_t^i(z)

   (lines 6, 8 and 11; ``P = model.mode_transition()``, ``pi = model.mode_prior()``; the
   normalised posterior ``q`` is carried, which stays exact across resampling);
3. estimate: the weighted mean and covariance of the particles (line 14);
4. resample (line 12) when the effective sample size ``1 / sum_i w_i^2`` falls below
   ``ess_threshold * K``, with any scheme of :mod:`radioloc.estimators.resampling`;
   optional roughening (Gordon et al.) jitters the resampled particles.

Degeneracy: when at a step every particle's likelihood of an observation is below the
smallest normal double (``exp(-708)``: ranges that no particle explains), the weights
still follow the log-domain update, but the resampled set is then redrawn around the
new estimate with the predicted spread inflated (``reset_inflation``); it is counted in
the diagnostic ``resets``. The weights are handled in the log domain throughout, so no
step produces a NaN or an overflow.

Random numbers: run ``i`` of a batch (its flat index over the batch axes) draws from its own
generator (:class:`RunGenerators`), so a batch gives the same output as its runs filtered
one by one with the same per-run seeds.

The smoother (``run(..., smooth=True)``) is backward simulation over the stored particle
sets and weights (:func:`radioloc.estimators.pf_smoother.backward_simulation`).
"""

from __future__ import annotations

import copy
import importlib
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
from scipy.special import logsumexp

from radioloc.core.arrays import kernel_array
from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import (MAX_PARTICLES, as_float_array, check_int, check_positive,
                                      check_symmetric)
from radioloc.estimators.base import RecursiveEstimator, Tags
from radioloc.estimators.observation_rows import common_steps
from radioloc.estimators.pf_smoother import backward_simulation
from radioloc.estimators.resampling import get_scheme, systematic
from radioloc.models.clock import ClockModel, transition
from radioloc.models.measurement import Context, Observation, StateLayout, check_motion
from radioloc.models.motion import InputDriven, MotionModel
from radioloc.models.ranging import GaussianRange, RangeModel

__all__ = ["ParticleFilter", "ParticleFilterState", "RunGenerators", "weighted_moments",
           "sample_motion", "mode_update", "standard_normal", "compiled_kernels",
           "compiled_moments", "compiled_systematic", "has_compiled_likelihood"]

#: Particles per parallel task of the compiled kernels.
CHUNK = 2048

#: ``log`` of the smallest normal double: a likelihood below ``exp(LOG_UNDERFLOW)`` for
#: every particle is a degenerate update (see the module docstring).
LOG_UNDERFLOW = float(np.log(np.finfo(float).tiny))


class RunGenerators:
    """One :class:`numpy.random.Generator` per run of a batch, drawn as one array.

    A draw of shape ``batch_shape + s`` takes ``s`` values from the generator of each run,
    so what a run draws depends on its own generator only. It offers the methods of a
    Generator that the filter, the motion models, the resampling schemes and the smoother
    call (``random``, ``standard_normal``, ``normal``, ``uniform``, ``integers``,
    ``exponential``).

    Parameters
    ----------
    seed : int, array_like of int, or list of numpy.random.SeedSequence
        An int ``s``: run ``i`` uses the ``i``-th child of ``SeedSequence(s)``
        (``SeedSequence(s).spawn(B)[i]``); an array of the batch shape: run ``i`` uses
        ``default_rng(seed[i])`` (give a run its own seed to reproduce it alone); a list of
        one ``SeedSequence`` per run (flat order): run ``i`` uses ``default_rng(seed[i])``.
    batch_shape : tuple of int
        The runs.
    """

    def __init__(self, seed, batch_shape: tuple[int, ...]) -> None:
        self.batch_shape = tuple(int(b) for b in batch_shape)
        count = int(np.prod(self.batch_shape, dtype=int))
        if isinstance(seed, (list, tuple)) and seed and \
                all(isinstance(s, np.random.SeedSequence) for s in seed):
            if len(seed) != count:
                raise InputError(f"seed: expected {count} seed sequences (one per run), got "
                                 f"{len(seed)}")
            self.generators = [np.random.default_rng(s) for s in seed]
        elif np.ndim(seed) == 0:
            children = np.random.SeedSequence(int(seed)).spawn(count)
            self.generators = [np.random.default_rng(c) for c in children]
        else:
            seeds = np.asarray(seed)
            if seeds.shape != self.batch_shape:
                raise InputError(f"seed: expected an int or one per run, shape "
                                 f"{self.batch_shape}, got shape {seeds.shape}")
            self.generators = [np.random.default_rng(int(s)) for s in seeds.ravel()]

    def copy(self) -> "RunGenerators":
        """Independent copies of the generators in their current states."""
        out = copy.copy(self)
        out.generators = [copy.deepcopy(g) for g in self.generators]
        return out

    def _draw(self, method: str, size, where=None, **kwargs) -> np.ndarray:
        shape = (size,) if np.ndim(size) == 0 and size is not None else tuple(size or ())
        nb = len(self.batch_shape)
        if shape[:nb] != self.batch_shape:
            raise InputError(f"size: a draw for runs {self.batch_shape} must lead with them, "
                             f"got {shape}")
        per = shape[nb:]
        flat_where = None if where is None else np.broadcast_to(where, self.batch_shape).ravel()
        if method in ("random", "standard_normal") and flat_where is None and not kwargs:
            out = np.empty((len(self.generators),) + per)      # filled in place, run by run
            for g, part in zip(self.generators, out):
                getattr(g, method)(size=per, out=part)
            return out.reshape(shape)
        parts = []
        for i, g in enumerate(self.generators):
            if flat_where is not None and not flat_where[i]:
                parts.append(np.zeros(per))
            else:
                parts.append(np.asarray(getattr(g, method)(size=per, **kwargs)))
        return np.stack(parts).reshape(shape) if parts else np.zeros(shape)

    def random(self, size=None, where=None) -> np.ndarray:
        """Uniforms on [0, 1).

        Parameters
        ----------
        size : tuple of int
            Shape of the draw, leading with the batch shape.
        where : ndarray of bool, shape batch_shape, optional
            Runs that draw; the others draw nothing and get zeros.

        Returns
        -------
        ndarray
        """
        return self._draw("random", size, where)

    def standard_normal(self, size=None, where=None) -> np.ndarray:
        """Standard normal draws (parameters as :meth:`random`).

        Parameters
        ----------
        size : tuple of int
        where : ndarray of bool, optional

        Returns
        -------
        ndarray
        """
        return self._draw("standard_normal", size, where)

    def normal(self, loc=0.0, scale=1.0, size=None) -> np.ndarray:
        """``loc + scale * standard_normal(size)``.

        Parameters
        ----------
        loc, scale : float or ndarray
        size : tuple of int

        Returns
        -------
        ndarray
        """
        return loc + scale * self._draw("standard_normal", size)

    def uniform(self, low=0.0, high=1.0, size=None) -> np.ndarray:
        """Uniforms on ``[low, high)``.

        Parameters
        ----------
        low, high : float or ndarray
        size : tuple of int

        Returns
        -------
        ndarray
        """
        return low + (high - low) * self._draw("random", size)

    def integers(self, low, high=None, size=None) -> np.ndarray:
        """Integers on ``[low, high)`` (``[0, low)`` without ``high``).

        Parameters
        ----------
        low, high : int
        size : tuple of int

        Returns
        -------
        ndarray of int64
        """
        return self._draw("integers", size, low=low, high=high)

    def exponential(self, scale=1.0, size=None) -> np.ndarray:
        """Exponential draws of mean ``scale``.

        Parameters
        ----------
        scale : float
        size : tuple of int

        Returns
        -------
        ndarray
        """
        return self._draw("exponential", size, scale=scale)


def weighted_moments(log_w: np.ndarray, particles: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Normalised weights, weighted mean, covariance and effective sample size.

    Paper 001, Algorithm 2, line 14 (the definition of
    :func:`radioloc.estimators.pf_compiled.moment_sums`).

    Parameters
    ----------
    log_w : ndarray, shape (..., K)
        Log weights (any constant offset).
    particles : ndarray, shape (..., K, n)

    Returns
    -------
    w : ndarray, shape (..., K)
    mean : ndarray, shape (..., n)
    covariance : ndarray, shape (..., n, n)
    ess : ndarray, shape (...)
        ``1 / sum_i w_i^2``.
    """
    w = np.exp(log_w - log_w.max(axis=-1, keepdims=True))
    w /= w.sum(axis=-1, keepdims=True)
    mean = np.einsum("...k,...kd->...d", w, particles)
    dev = particles - mean[..., None, :]
    cov = np.einsum("...k,...ki,...kj->...ij", w, dev, dev)
    return w, mean, cov, 1.0 / np.sum(w * w, axis=-1)


def sample_motion(motion, particles: np.ndarray, dt, rng, control=None,
                  normal: Callable[[tuple[int, ...]], np.ndarray] | None = None) -> np.ndarray:
    """The prediction step: a draw of every particle's next state from the motion model.

    The model's own ``sample``, except for the input-driven model's ``x + u + std_m z`` and
    the linear-Gaussian models of :class:`radioloc.models.motion.MotionModel`, whose
    ``F x + w, w ~ N(0, Q(dt))`` is drawn here with ``Q(dt)`` factored once per step
    instead of once per particle.

    Parameters
    ----------
    motion : motion model
    particles : ndarray, shape (..., K, n)
    dt : float or ndarray, shape (...)
        Step length, seconds: one for every particle set, or one per set (the batch
        axes of ``particles`` before ``K``).
    rng : numpy.random.Generator or RunGenerators
    control : ndarray, shape (..., 1, D), optional
        Displacement reading of an input-driven model.
    normal : callable, optional
        ``normal(shape)`` standard normal draws (default ``rng.standard_normal``).

    Returns
    -------
    ndarray, shape (..., K, n)
    """
    normal = normal or rng.standard_normal
    if isinstance(motion, InputDriven) and particles.shape[-1] == motion.dim:
        z = normal(particles.shape)
        z *= motion.std_m
        z += particles if control is None else particles + control
        return z
    if type(motion).sample is not MotionModel.sample:
        return motion.sample(particles, np.asarray(dt, dtype=float)[..., None] if np.ndim(dt)
                             else dt, rng, control=control)
    n = particles.shape[-1]
    F = np.asarray(motion.F(dt))                              # (n, n) or (..., n, n)
    if F.shape == (n, n) and np.array_equal(F, np.eye(n)):        # random walk: F = I
        mean = particles if control is None else particles.copy()
        if control is not None:
            mean[..., : motion.dim] += control
    elif F.ndim > 2:                                          # one F per particle set
        mean = particles @ np.swapaxes(F, -1, -2)
        if control is not None:
            mean[..., : motion.dim] += control
    else:
        mean = motion.predict(particles, dt, control=control)
    vals, vecs = np.linalg.eigh(np.asarray(motion.Q(dt), dtype=float))          # (..., n, n)
    factor = vecs * np.sqrt(np.maximum(vals, 0.0))[..., None, :]
    z = normal(mean.shape)
    if factor.ndim == 2 and np.array_equal(factor, np.diag(np.diagonal(factor))):
        d = np.diagonal(factor)
        z *= d[0] if np.all(d == d[0]) else d       # a scalar: one pass at memory speed
        z += mean
        return z
    if factor.ndim == 2:                                    # one Q for every particle
        return mean + z @ factor.T
    return mean + z @ np.swapaxes(factor, -1, -2)           # one Q per particle set


def mode_update(prior: np.ndarray, mode_loglik: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact update of discrete per-row states (paper 001, Algorithm 2, lines 6, 8 and 11).

    Parameters
    ----------
    prior : ndarray, shape (..., m, S)
        Predicted probabilities of each row's ``S`` states.
    mode_loglik : ndarray, shape (..., m, S)
        ``log p(z_row | state, x)`` (0 for a missing row).

    Returns
    -------
    row_loglik : ndarray, shape (..., m)
        ``log sum_s prior(s) p(z_row | s, x)``.
    posterior : ndarray, shape (..., m, S)
        ``prior(s) p(z_row | s, x)`` normalised over the states (the prior where every
        state has zero likelihood).
    """
    with np.errstate(divide="ignore"):
        a = np.log(prior) + mode_loglik
    top = a.max(axis=-1, keepdims=True)
    ok = np.isfinite(top)
    with np.errstate(invalid="ignore"):
        e = np.exp(np.where(ok, a - top, 0.0))
    s = e.sum(axis=-1, keepdims=True)
    row = np.where(ok, top + np.log(s), -np.inf)[..., 0]
    post = np.where(ok, e / s, prior)
    return row, post


def compiled_kernels():
    """The module of compiled kernels, :mod:`radioloc.estimators.pf_compiled` (imported on
    first use: numba is loaded only by a filter that runs ``backend="numba"``).

    Returns
    -------
    module

    Raises
    ------
    ConfigError
        numba cannot be imported; the message says to use ``backend="numpy"``.
    """
    try:
        return importlib.import_module("radioloc.estimators.pf_compiled")
    except ImportError as exc:
        raise ConfigError(f"backend: 'numba' needs numba, which cannot be imported ({exc}); "
                          "install numba or use backend='numpy'") from None


#: Normal draws of at least this many numbers per generator (per run of a
#: :class:`RunGenerators`) are made in ``STREAMS`` contiguous parts, each from its own child
#: generator (``spawn``), in parallel by the compiled backend; the parts depend on the size
#: only.
DRAW_PARALLEL = 1 << 17
STREAMS = 8


def standard_normal(rng, shape: tuple[int, ...], backend: str = "numpy") -> np.ndarray:
    """``shape`` standard normal draws from ``rng``; a large draw (``DRAW_PARALLEL``) in
    ``STREAMS`` parts from child generators, the same numbers on either backend
    (``"numba"`` fills the parts in parallel by ``pf_compiled.standard_normal``, numba's
    form of NumPy's generator; ``"numpy"`` one after the other). ``"numba"`` also fills a
    smaller draw of a :class:`RunGenerators` by that kernel, each run's part from the
    run's own generator (``STREAMS`` runs a call, then one by one), as NumPy would.

    Parameters
    ----------
    rng : numpy.random.Generator or RunGenerators
    shape : tuple of int
        For a :class:`RunGenerators`, leading with its batch shape.
    backend : {"numba", "numpy"}

    Returns
    -------
    ndarray
    """
    shape = tuple(shape)
    runs = rng.generators if isinstance(rng, RunGenerators) else [rng]
    per_run = shape[len(rng.batch_shape):] if isinstance(rng, RunGenerators) else shape
    size = int(np.prod(per_run, dtype=np.int64))
    out = np.empty((len(runs), size))
    if size < DRAW_PARALLEL and backend == "numba" and isinstance(rng, RunGenerators):
        kernel = compiled_kernels().standard_normal
        full = len(runs) - len(runs) % STREAMS
        for first in range(0, full, STREAMS):          # two tuple lengths: two compilations
            kernel(tuple(runs[first:first + STREAMS]), out[first:first + STREAMS].reshape(-1))
        for g, part in zip(runs[full:], out[full:]):
            kernel((g,), part)
        return out.reshape(shape)
    if size < DRAW_PARALLEL or any(getattr(g.bit_generator, "seed_seq", None) is None
                                   for g in runs):
        return rng.standard_normal(shape)
    for g, part in zip(runs, out):
        children = g.spawn(STREAMS)
        if backend == "numba":
            compiled_kernels().standard_normal(tuple(children), part)
        else:
            per = -(-size // STREAMS)
            for s, child in enumerate(children):
                child.standard_normal(out=part[s * per:(s + 1) * per])
    return out.reshape(shape)


def compiled_moments(log_w: np.ndarray, particles: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`weighted_moments` by the compiled kernel ``pf_compiled.moment_sums``, with the
    log of the weights' sum.

    Parameters
    ----------
    log_w : ndarray, shape (..., K)
    particles : ndarray, shape (..., K, n)

    Returns
    -------
    w, mean, covariance, ess : ndarray
        As :func:`weighted_moments`.
    log_total : ndarray, shape (..., 1)
        ``logsumexp(log_w)``.
    """
    batch, (k, n) = particles.shape[:-2], particles.shape[-2:]
    b = int(np.prod(batch, dtype=int))
    x = kernel_array(particles.reshape(b, k, n))
    lw = log_w.reshape(b, k)
    top = lw.max(axis=-1, keepdims=True)
    w = np.exp(lw - top)
    sums = np.empty((b, -(-k // CHUNK), 2 + n + n * n))
    compiled_kernels().moment_sums(w, x, CHUNK, sums)
    s = sums.sum(axis=1)
    total = s[:, 0]
    w /= total[:, None]
    d = s[:, 2:2 + n] / total[:, None]                     # mean - x_0
    cov = s[:, 2 + n:].reshape(b, n, n) / total[:, None, None] - d[:, :, None] * d[:, None, :]
    return (w.reshape(batch + (k,)), (x[:, 0] + d).reshape(batch + (n,)),
            cov.reshape(batch + (n, n)), (total * total / s[:, 1]).reshape(batch),
            (top + np.log(total)[:, None]).reshape(batch + (1,)))


def compiled_systematic(w: np.ndarray, particles: np.ndarray, q: np.ndarray | None, rng
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, np.ndarray]:
    """:func:`radioloc.estimators.resampling.systematic` (the same draw) by the compiled
    kernel ``pf_compiled.systematic_gather``, with the gather of the particles and of
    per-particle rows ``q``.

    Parameters
    ----------
    w : ndarray, shape (..., K)
        Normalised weights.
    particles : ndarray, shape (..., K, n)
    q : ndarray, shape (..., K, L), optional
        Rows that follow their particle (the link posteriors of paper 001's filter).
    rng : numpy.random.Generator or RunGenerators

    Returns
    -------
    idx : ndarray of int64, shape (..., K)
        Ancestors.
    particles : ndarray, shape (..., K, n)
    q : ndarray, shape (..., K, L), or None
    distinct : ndarray of int64, shape (...)
        Distinct ancestors.
    """
    batch, (k, n) = particles.shape[:-2], particles.shape[-2:]
    width = 0 if q is None else q.shape[-1]
    b = int(np.prod(batch, dtype=int))
    u = rng.random(batch + (1,))                    # the draw of resampling.systematic
    idx, distinct = np.empty((b, k), dtype=np.int64), np.empty((b, -(-k // CHUNK)), np.int64)
    out_p, out_q = np.empty((b, k, n)), np.empty((b, k, width))
    q_in = out_q if q is None else kernel_array(q.reshape(b, k, width))
    compiled_kernels().systematic_gather(kernel_array(w.reshape(b, k)), u.reshape(b),
                                         kernel_array(particles.reshape(b, k, n)), q_in, CHUNK,
                                         idx, out_p, out_q, distinct)
    return (idx.reshape(batch + (k,)), out_p.reshape(particles.shape),
            None if q is None else out_q.reshape(q.shape), distinct.sum(axis=1).reshape(batch))


def has_compiled_likelihood(model) -> bool:
    """Whether ``ParticleFilter(backend="numba")`` computes ``model``'s likelihood by a
    compiled kernel: a :class:`~radioloc.models.ranging.RangeModel` with
    :class:`~radioloc.models.ranging.GaussianRange` noise and no anchor bias
    (``pf_compiled.range_loglik``).
    Any other model's likelihood is its NumPy ``logpdf`` (or ``mode_logpdf``) on either
    backend.

    Parameters
    ----------
    model : MeasurementModel

    Returns
    -------
    bool
    """
    return (type(model) is RangeModel and isinstance(model.noise, GaussianRange)
            and not model.anchor_bias)


def _range_loglik(model: RangeModel, z: np.ndarray, x: np.ndarray, layout: StateLayout,
                  ctx: Context, batch: tuple[int, ...]) -> np.ndarray:
    """``sum_rows model.logpdf(z, x, ctx)`` of every particle ``x`` (..., K, n) by the
    compiled kernel (a model of :func:`has_compiled_likelihood`; ``z`` (..., m) checked by
    the caller, ``ctx`` without the particle axis)."""
    k, n = x.shape[-2:]
    m, D = ctx.rows, layout.dim
    b = int(np.prod(batch, dtype=int))
    pts = np.broadcast_to(ctx.points, batch + ctx.points.shape[-2:]).reshape(b, m, -1)
    dz2 = np.zeros((b, m))
    if ctx.height_m is not None:
        dz2 = (float(ctx.height_m) - pts[..., D]) ** 2
    std = np.broadcast_to(model.std(ctx), batch + (m,)).reshape(b, m)
    out = np.empty((b, k))
    compiled_kernels().range_loglik(
        kernel_array(np.broadcast_to(x, batch + (k, n)).reshape(b, k, n)),
        layout.slices["position"].start, D, kernel_array(pts), kernel_array(dz2),
        kernel_array(np.broadcast_to(z, batch + (m,)).reshape(b, m)), 1.0 / std, np.log(std),
        CHUNK, out)
    return out.reshape(batch + (k,))


def _particle_context(ctx: Context) -> Context:
    """``ctx`` with a particle axis before the rows (its batch axes then line up with the
    particles' ``(..., K)``)."""
    pts = ctx.points[..., None, :, :] if ctx.points.ndim > 2 else ctx.points
    ref = ctx.reference
    if ref is not None and ref.ndim > 2:
        ref = ref[..., None, :, :]
    std = ctx.std
    if std is not None and std.ndim > 1:
        std = std[..., None, :]
    return replace(ctx, points=pts, reference=ref, std=std)


@dataclass(frozen=True)
class ParticleFilterState:
    """State of a batch of particle filters.

    Attributes
    ----------
    particles : ndarray, shape (..., K, n)
        Particles of the full state (laid out by the filter's layout).
    log_weights : ndarray, shape (..., K)
        Normalised log weights.
    modes : tuple of (ndarray of shape (..., K, m, S) or None)
        Per observation (in the order given to :meth:`ParticleFilter.step`): each
        particle's posterior of every row's discrete state; None for a model without
        discrete states.
    seen : tuple of (ndarray of bool, shape (..., m), or None)
        Rows measured at the last step (a row not seen restarts from ``mode_prior``).
    mean, covariance : ndarray, shapes (..., n), (..., n, n)
        Weighted particle mean and covariance of the last step.
    ess : ndarray, shape (...)
        Effective sample size of the last update.
    reset : ndarray of bool, shape (...)
        Runs reset at the last step.
    resets : ndarray of int64, shape (...)
        Resets so far.
    time : float
    rng : RunGenerators
        The runs' generators (copied by every step, so a state can be stepped again).
    layout : StateLayout
    """

    particles: np.ndarray
    log_weights: np.ndarray
    modes: tuple
    seen: tuple
    mean: np.ndarray
    covariance: np.ndarray
    ess: np.ndarray
    reset: np.ndarray
    resets: np.ndarray
    time: float
    rng: RunGenerators
    layout: StateLayout

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The runs' axes."""
        return self.mean.shape[:-1]


def _as_observations(observations) -> list[Observation]:
    obs = [observations] if isinstance(observations, Observation) else list(observations)
    if not obs:
        raise InputError("observations: give at least one Observation")
    for i, o in enumerate(obs):
        if not isinstance(o, Observation):
            raise InputError(f"observations[{i}]: expected an Observation, got "
                             f"{type(o).__name__}")
    return obs


class ParticleFilter(RecursiveEstimator):
    """Bootstrap particle filter over any measurement model (see the module docstring).

    Parameters
    ----------
    motion : motion model
        ``sample`` (or ``F``/``Q``), ``predict``, ``dim``, ``state_dim``
        (:mod:`radioloc.models.motion`): moves the kinematic part of the state; further
        components follow :func:`radioloc.models.clock.transition` without noise (a clock
        offset integrates its drift; the drift and anchor biases are held).
    n_particles : int
        Particles per run, K.
    resample : callable or str
        ``resample(weights (..., K), rng) -> ancestors (..., K)``, a function of
        :mod:`radioloc.estimators.resampling` (or its name).
    ess_threshold : float
        Resample when the effective sample size is below ``ess_threshold * K``; 1 (or
        more): at every step.
    seed : int or array_like of int
        Seeds of the runs' generators (see :class:`RunGenerators`).
    layout : StateLayout, optional
        The state; default: the motion model's grown by every observation's model
        (:meth:`StateLayout.with_model`).
    roughening : float
        Jitter of resampled particles, ``roughening * K^(-1/n)`` times each component's
        weighted standard deviation (0: none).
    reset_inflation : float
        On a degenerate update (see the module docstring) the particles are redrawn from
        ``N(estimate, reset_inflation^2 * predicted covariance)``.
    trajectories : int
        Backward trajectories of the smoother (``run(..., smooth=True)``).
    backend : {"numba", "numpy"}
        ``"numba"`` (default) runs three parts of each step by the compiled kernels of
        :mod:`radioloc.estimators.pf_compiled`: the likelihood of an observation whose
        model has a kernel (:func:`has_compiled_likelihood`: a Gaussian
        :class:`~radioloc.models.ranging.RangeModel`), the weighted moments, and the
        systematic resampling with the gather of the particles. The rest runs as
        ``"numpy"`` runs it: the draws (NumPy's generators, the same numbers on both
        backends), the prediction, another model's ``logpdf`` (the fallback: a model
        without a kernel is filtered by its NumPy definition, never refused), another
        resampling scheme, the discrete row states, roughening and resets. The two
        backends agree to about 1e-10 relative with the same seed
        (``tests/test_generic_pf_backends.py``). ``"numpy"``: every part by its NumPy
        definition in this module.

    Examples
    --------
    >>> from radioloc.models.motion import RandomWalk
    >>> pf = ParticleFilter(RandomWalk(0.1), n_particles=500, seed=1)
    """

    name = "pf"
    tags = Tags(kinds=None, uses="logpdf", dims=(2, 3), recursive=True, modes=True,
                generic=True)

    def __init__(self, motion, *, n_particles: int = 1000,
                 resample: Callable | str = systematic, ess_threshold: float = 0.5,
                 seed=0, layout: StateLayout | None = None, roughening: float = 0.0,
                 reset_inflation: float = 2.0, trajectories: int = 100,
                 backend: str = DEFAULT_BACKEND) -> None:
        for attr in ("predict", "dim", "state_dim"):
            if not hasattr(motion, attr):
                raise ConfigError(f"motion: {type(motion).__name__} has no {attr!r}")
        self.motion = motion
        self.n_particles = check_int(n_particles, "n_particles", minimum=1,
                                     maximum=MAX_PARTICLES)
        if isinstance(resample, str):
            try:
                resample = get_scheme(resample)
            except ConfigError as exc:
                raise ConfigError(f"resample: {exc}") from None
        if not callable(resample):
            raise ConfigError(f"resample: expected a function (weights, rng) -> indices, got "
                              f"{type(resample).__name__}")
        self.resample = resample
        self.ess_threshold = check_positive(ess_threshold, "ess_threshold", allow_zero=True)
        if not (isinstance(seed, (list, tuple)) and seed
                and all(isinstance(s, np.random.SeedSequence) for s in seed)):
            for s in np.ravel(np.asarray(seed, dtype=object)):
                check_int(s, "seed", minimum=0)
        self.seed = seed
        if layout is not None:
            if not isinstance(layout, StateLayout):
                raise ConfigError(f"layout: expected a StateLayout, got {type(layout).__name__}")
            self._check_layout(layout)
        self.layout = layout
        if not np.isfinite(roughening) or roughening < 0:
            raise ConfigError(f"roughening: must be >= 0, got {roughening!r}")
        self.roughening = float(roughening)
        if not np.isfinite(reset_inflation) or reset_inflation < 1:
            raise ConfigError(f"reset_inflation: must be >= 1, got {reset_inflation!r}")
        self.reset_inflation = float(reset_inflation)
        self.trajectories = check_int(trajectories, "trajectories", minimum=1,
                                      maximum=10**6)
        self.backend = check_backend(backend)
        if backend == "numba":
            compiled_kernels()

    # ---- the state ------------------------------------------------------------------
    def _check_layout(self, layout: StateLayout) -> None:
        if layout.dim != self.motion.dim or layout.motion_size != self.motion.state_dim:
            raise ConfigError(f"layout: {layout} does not start with the motion model's state "
                              f"({self.motion.dim}-D, {self.motion.state_dim} components)")

    def layout_for(self, observations) -> StateLayout:
        """The state layout for these observations: the ``layout`` given, or the motion
        model's grown by each model (anchor biases sized by the context's anchor index).

        Parameters
        ----------
        observations : Observation or sequence of Observation

        Returns
        -------
        StateLayout
        """
        if self.layout is not None:
            return self.layout
        D, n = self.motion.dim, self.motion.state_dim
        if n % D or n // D > 3 or D not in (2, 3):
            raise ConfigError(f"motion: a {D}-D model with {n} state components has no "
                              "StateLayout; give layout=")
        layout = StateLayout(dim=D, order=n // D - 1)
        for o in _as_observations(observations) if observations is not None else []:
            check_motion(o.model, self.motion)
            idx = o.context.index
            n_anchors = int(idx.max()) + 1 if idx is not None and idx.size else o.context.rows
            layout = layout.with_model(o.model, n_anchors)
        return layout

    def init(self, prior_mean, prior_cov, observations=None, *, time: float = 0.0,
             batch_shape: tuple[int, ...] | None = None) -> ParticleFilterState:
        """Particles drawn from ``N(prior_mean, prior_cov)``, equally weighted.

        Parameters
        ----------
        prior_mean : array_like, shape (..., n)
            Prior mean of the full state (``n = layout.size``).
        prior_cov : array_like, shape (..., n, n)
            Prior covariance (positive semi-definite).
        observations : Observation or sequence, optional
            What the state must hold (see :meth:`layout_for`).
        time : float
            Time of the prior, seconds.
        batch_shape : tuple of int, optional
            The runs (default: the leading axes of ``prior_mean``); the prior broadcasts
            to it.

        Returns
        -------
        ParticleFilterState
        """
        layout = self.layout_for(observations)
        n = layout.size
        m0 = as_float_array(prior_mean, "prior_mean", min_ndim=1, last_dim=n)
        P0 = as_float_array(prior_cov, "prior_cov", min_ndim=2)
        if P0.shape[-2:] != (n, n):
            raise InputError(f"prior_cov: expected shape (..., {n}, {n}) for {layout}, got "
                             f"{P0.shape}")
        check_symmetric(P0, "prior_cov")
        vals, vecs = np.linalg.eigh(P0)
        if np.any(vals < -1e-9 * np.maximum(1.0, np.abs(vals).max())):
            raise InputError("prior_cov: must be positive semi-definite")
        try:
            batch = np.broadcast_shapes(m0.shape[:-1], P0.shape[:-2], tuple(batch_shape or ()))
        except ValueError:
            raise InputError(f"prior_mean: batch shape {m0.shape[:-1]} does not broadcast "
                             f"with prior_cov {P0.shape[:-2]} and the data's "
                             f"{tuple(batch_shape or ())}") from None
        rng = RunGenerators(self.seed, batch)
        K = self.n_particles
        factor = vecs * np.sqrt(np.maximum(vals, 0.0))[..., None, :]
        z = rng.standard_normal(batch + (K, n))
        particles = np.broadcast_to(m0, batch + (n,))[..., None, :] + \
            np.einsum("...ij,...kj->...ki", np.broadcast_to(factor, batch + (n, n)), z)
        return ParticleFilterState(
            particles=particles, log_weights=np.full(batch + (K,), -np.log(K)), modes=(),
            seen=(), mean=np.broadcast_to(m0, batch + (n,)).copy(),
            covariance=np.broadcast_to(P0, batch + (n, n)).copy(), ess=np.full(batch, float(K)),
            reset=np.zeros(batch, dtype=bool), resets=np.zeros(batch, dtype=np.int64),
            time=float(time), rng=rng, layout=layout)

    # ---- one step -------------------------------------------------------------------
    def step(self, state: ParticleFilterState, observations, *, dt: float = 1.0,
             control=None) -> ParticleFilterState:
        """Predict over ``dt`` and update with one step's observations.

        Parameters
        ----------
        state : ParticleFilterState
            Not modified.
        observations : Observation or sequence of Observation
            One step each: ``z`` of shape (..., m) (NaN: no measurement), in the same order
            at every step.
        dt : float
            Seconds since the state's time (>= 0).
        control : array_like, shape (..., D), optional
            Displacement reading of an input-driven motion model.

        Returns
        -------
        ParticleFilterState
        """
        rows = []
        for o in _as_observations(observations):
            ctx = o.context if o.std is None else replace(o.context, std=o.std)
            rows.append((o.model, o.z, ctx))
        if not np.isfinite(dt) or dt < 0:
            raise InputError(f"dt: must be finite and >= 0 s, got {dt!r}")
        u = None
        if control is not None:
            u = as_float_array(control, "control", last_dim=self.motion.dim)[..., None, :]
        return self._step(state, rows, float(dt), u)

    def _step(self, state: ParticleFilterState, rows, dt: float, control) -> ParticleFilterState:
        """:meth:`step` on ``rows`` = [(model, z (..., m), context)] of one step."""
        if self.backend == "numpy":
            return self._update(state, rows, dt, control)
        m = sum(ctx.rows for _, _, ctx in rows)
        work = int(np.prod(state.batch_shape, dtype=int)) * self.n_particles * max(m, 1)
        with compiled_kernels().threads_for(work):
            return self._update(state, rows, dt, control)

    def _update(self, state: ParticleFilterState, rows, dt: float, control
                ) -> ParticleFilterState:
        """The parts of :meth:`_step` (the compiled ones on one thread for a small step)."""
        layout, K = state.layout, self.n_particles
        numba = self.backend == "numba"
        rng = state.rng.copy()
        ns = self.motion.state_dim
        # predict (Algorithm 2, line 3): the kinematic part moves; the rest follows the
        # state's transition without noise (a clock offset integrates its drift)
        normal = lambda shape: standard_normal(rng, shape, self.backend)  # noqa: E731
        if layout.size == ns:
            x = sample_motion(self.motion, state.particles, dt, rng, control, normal)
        else:
            x = state.particles.copy()
            x[..., :ns] = sample_motion(self.motion, x[..., :ns], dt, rng, control, normal)
        if layout.clock == 2:
            F, _ = transition(layout, None, dt, ClockModel(0.0, 0.0, terms=2))
            x[..., ns:] = x[..., ns:] @ F[ns:, ns:].T
        x_pred = x
        log_w = state.log_weights
        modes, seen = list(state.modes), list(state.seen)
        degenerate = np.zeros(state.batch_shape, dtype=bool)
        comps = layout.split(x)
        for i, (model, z, ctx) in enumerate(rows):
            self.tags.require(model, f"observations[{i}].model", type(self).__name__)
            layout.check(model)
            if i >= len(modes):
                modes.append(None)
                seen.append(None)
            zz = z[..., None, :]
            pctx = _particle_context(ctx)
            S = int(getattr(model, "modes", 1))
            if S > 1 and not all(hasattr(model, a) for a in ("mode_logpdf", "mode_transition",
                                                             "mode_prior")):
                raise InputError(f"observations[{i}]: model {type(model).__name__} has {S} "
                                 "modes but no mode_logpdf, mode_transition and mode_prior")
            if S > 1:
                # lines 6, 8, 11: the discrete row states summed out exactly
                lp = model.mode_logpdf(zz, comps, pctx)                  # (..., K, m, S)
                full = np.broadcast_shapes(lp.shape, state.batch_shape + (K, z.shape[-1], S))
                prior = np.broadcast_to(np.asarray(model.mode_prior(), dtype=float), full)
                if modes[i] is not None:
                    pred = modes[i] @ np.asarray(model.mode_transition(), dtype=float)
                    prior = np.where(seen[i][..., None, :, None], pred, prior)
                row_ll, post = mode_update(prior, np.broadcast_to(lp, full))
                modes[i] = post
                seen[i] = np.broadcast_to(np.isfinite(z), full[:-3] + (z.shape[-1],))
            if numba and S == 1 and has_compiled_likelihood(model):
                model.checked(zz, comps, pctx)
                ll = _range_loglik(model, z, x, layout, ctx, state.batch_shape)  # never NaN
            else:
                ll = np.sum(row_ll if S > 1 else model.logpdf(zz, comps, pctx), axis=-1)
                ll = np.where(np.isnan(ll), -np.inf, ll)                  # (..., K)
            ll = np.broadcast_to(ll, state.batch_shape + (K,))
            best = ll.max(axis=-1)
            degenerate |= best < LOG_UNDERFLOW
            # a run no particle explains at all (every likelihood zero) keeps its weights
            explained = np.isfinite(best)
            log_w = log_w + ll if explained.all() else \
                np.where(explained[..., None], log_w + ll, log_w)
        # line 14: the estimate
        if numba:
            w, mean, cov, ess, log_total = compiled_moments(log_w, x)
        else:
            w, mean, cov, ess = weighted_moments(log_w, x)
            log_total = logsumexp(log_w, axis=-1, keepdims=True)
        # line 12: resample where the effective sample size is low (and on a reset)
        need = (ess < self.ess_threshold * K) | (self.ess_threshold >= 1.0) | degenerate
        if numba and self.resample is systematic:
            idx, drawn, _, _ = compiled_systematic(w, x, None, rng)
            keep = ~need[..., None]
            if keep.any():
                x, idx = np.where(keep[..., None], x, drawn), np.where(keep, np.arange(K), idx)
            else:
                x = drawn
        else:
            idx = np.where(need[..., None], self.resample(w, rng), np.arange(K))
            x = np.take_along_axis(x, idx[..., None], axis=-2)
        modes = [None if q is None else np.take_along_axis(q, idx[..., None, None], axis=-3)
                 for q in modes]
        log_w = np.full(log_w.shape, -np.log(K)) if need.all() else \
            np.where(need[..., None], -np.log(K), log_w - log_total)
        if self.roughening > 0:
            n = x.shape[-1]
            scale = self.roughening * K ** (-1.0 / n) * np.sqrt(np.maximum(
                np.diagonal(cov, axis1=-2, axis2=-1), 0.0))
            x = x + np.where(need[..., None, None], scale[..., None, :], 0.0) * \
                rng.standard_normal(x.shape)
        if np.any(degenerate):
            # reset: redraw around the new estimate with the inflated predicted spread
            _, _, pred_cov, _ = weighted_moments(state.log_weights, x_pred)
            vals, vecs = np.linalg.eigh(pred_cov)
            factor = self.reset_inflation * vecs * np.sqrt(np.maximum(vals, 0.0))[..., None, :]
            z = rng.standard_normal(x.shape, where=degenerate)
            fresh = mean[..., None, :] + np.einsum("...ij,...kj->...ki", factor, z)
            x = np.where(degenerate[..., None, None], fresh, x)
            cov = np.where(degenerate[..., None, None], self.reset_inflation ** 2 * pred_cov, cov)
        return ParticleFilterState(
            particles=x, log_weights=log_w, modes=tuple(modes), seen=tuple(seen), mean=mean,
            covariance=cov, ess=ess, reset=degenerate, resets=state.resets + degenerate,
            time=state.time + dt, rng=rng, layout=layout)

    def estimate(self, state: ParticleFilterState) -> Estimate:
        """The weighted particle mean and covariance of the last step.

        Parameters
        ----------
        state : ParticleFilterState

        Returns
        -------
        Estimate
            ``position`` (..., D) and its covariance; diagnostics ``state``,
            ``state_covariance`` (full state), ``ess``, ``resets`` (count so far).
        """
        sl = state.layout.slices["position"]
        return Estimate(state.mean[..., sl], state.covariance[..., sl, sl], state.time,
                        {"state": state.mean, "state_covariance": state.covariance,
                         "ess": state.ess, "resets": state.resets})

    # ---- a whole series -------------------------------------------------------------
    def run(self, observations, time=None, *, prior_mean, prior_cov, smooth: bool = False,
            controls=None) -> Track:
        """Filter (or smooth) every run over the ``T`` steps of the observations.

        Parameters
        ----------
        observations : Observation or sequence of Observation
            ``z`` of shape (..., T, m) each (the same T); batch axes lead.
        time : array_like, shape (T,), optional
            Step times, seconds, non-decreasing (default ``0, 1, ..., T-1``); the prior is
            at ``time[0]``.
        prior_mean : array_like, shape (..., n)
        prior_cov : array_like, shape (..., n, n)
        smooth : bool
            Return the backward-simulation smoother's track (``trajectories`` draws)
            instead of the filter's.
        controls : array_like, shape (..., T, D), optional
            Displacement readings of an input-driven motion model.

        Returns
        -------
        Track
            ``position`` (..., T, D), ``covariance`` (..., T, D, D); diagnostics ``state``,
            ``state_covariance``, ``ess``, ``resets`` (..., T).
        """
        obs = _as_observations(observations)
        T = common_steps(obs)
        if T < 1:
            raise InputError("observations: no time step")
        t = np.arange(T, dtype=float) if time is None else as_float_array(time, "time", ndim=1)
        if t.shape != (T,) or np.any(np.diff(t) < 0):
            raise InputError(f"time: expected {T} non-decreasing step times, got shape {t.shape}")
        if smooth and T > 1 and not np.all(np.diff(t) > 0):
            raise InputError("time: the smoother needs strictly increasing step times")
        u = None
        if controls is not None:
            u = as_float_array(controls, "controls", min_ndim=2, last_dim=self.motion.dim)
            if u.shape[-2] != T:
                raise InputError(f"controls: expected {T} steps on axis -2, got {u.shape}")
        # batch axes: those of z and those of the reference points (a step's context)
        named = [(f"observations[{i}].{k}", s) for i, o in enumerate(obs)
                 for k, s in (("z", o.z.shape[:-2]), ("context.points",
                                                      o.at(0)[1].points.shape[:-2]))]
        try:
            batch = np.broadcast_shapes(*(s for _, s in named))
        except ValueError:
            raise InputError("observations: batch axes do not broadcast: "
                             + ", ".join(f"{k} {s}" for k, s in named)) from None
        state = self.init(prior_mean, prior_cov, obs, time=t[0], batch_shape=batch)
        dts = np.diff(t, prepend=t[0])
        estimates, history, weights = [], [], []
        for k in range(T):
            rows = [(o.model,) + o.at(k) for o in obs]
            state = self._step(state, rows, dts[k], None if u is None else u[..., k, None, :])
            estimates.append(self.estimate(state))
            if smooth:
                history.append(state.particles)
                weights.append(state.log_weights)
        track = track_from_steps(estimates, t)
        if not smooth:
            return track
        mean, cov = backward_simulation(history, t, self.motion, self.trajectories,
                                        state.rng, log_weights=weights)
        mean, cov = np.moveaxis(mean, 0, -2), np.moveaxis(cov, 0, -3)
        sl = state.layout.slices["position"]
        diag = dict(track.diagnostics, state=mean, state_covariance=cov)
        return Track(mean[..., sl], cov[..., sl, sl], track.time, diag)
