"""Peer-to-peer particle filter with per-link LOS/NLOS states (paper 001, Algorithm 2).

Each vehicle ``k`` runs its own particle filter over its state ``v_t(k)`` (the position,
or position and velocity for a constant-velocity motion model); the binary link states
``z_t(km)`` are not sampled but summed out exactly per particle through the ``phi``
recursion of Sect. IV::

    phi_t^i(km, z) = p(theta_t(km) | z, v_t^i(k)) * sum_{z'} p(z | z') phi_{t-1}^i(km, z')
    phi_t^i(km, z) = p(z) p(theta_t(km) | z, v_t^i(k))            (m new neighbour)
    w_t^i(k)       = prod_m sum_z phi_t^i(km, z)

(Algorithm 2, lines 6, 8 and 11), the filter of the joint distribution eq. (1) under the
approximation of Fig. 3: neighbour positions are the neighbours' estimates sent as
messages; anchors are known. Everything is batched over
leading axes ``(runs, vehicles)``, particles and links; the only Python loop is the loop
over time in :meth:`P2PParticleFilter.run`.

The models are arguments: the motion model (``InputDriven(s_INS)`` with the INS reading as
control, the paper's; or ``RandomWalk``, ``ConstantVelocity`` with no INS) draws the
prediction (line 3) through its ``sample``; the measurement model ``LosNlosRange`` gives
the per-state likelihoods and its sticky link chain. The likelihood uses the position
part of the state.

Correction of Algorithm 2 as printed: it resamples at every step (line 12) but carries the
unnormalised ``phi_{t-1}`` forward, which would count the history of each link twice (once
in the resampled particle set, once more in ``phi``). We carry the normalised link
posterior ``phi_{t-1}(z) / sum_z phi_{t-1}(z)`` instead, which is the exact
Rao-Blackwellised update after resampling; without resampling both agree up to a factor
common to all particles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.links import gather_packed, pack_mask, scatter_packed
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import (MAX_PARTICLES, as_float_array, check_int, check_positive,
                                      check_probability)
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.pf_kernels import finish_step, link_update
from radioloc.estimators.resampling import get_scheme
from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain

__all__ = ["P2PParticleFilter", "ParticleState", "MESSAGES", "link_log_phi"]

#: How vehicle ``k`` places neighbour ``m`` at step ``t`` (see :class:`P2PParticleFilter`).
MESSAGES = ("previous", "extrapolated", "given")
KERNELS = ("numba", "numpy")


@dataclass(frozen=True)
class ParticleState:
    """State of a batch of peer-to-peer particle filters (one per vehicle).

    Attributes
    ----------
    particles : ndarray, shape (..., N, K, n)
        Equally weighted particles (after resampling) of the ``n``-dimensional state,
        position first.
    log_phi : ndarray, shape (..., N, K, L, 2)
        Normalised log link posteriors ``log p(z | .)`` per particle for the stored links
        (z = 0 NLOS, 1 LOS).
    links : ndarray of int64, shape (..., N, L)
        Node index of each stored link, ``-1`` for padding.
    mean : ndarray, shape (..., N, n)
        Weighted particle mean of the last step (Algorithm 2, line 14); the prior centre
        before the first step.
    covariance : ndarray, shape (..., N, n, n)
        Weighted particle covariance of the last step.
    ess : ndarray, shape (..., N)
        Effective sample size ``1 / sum_i w_i^2`` of the last step's weights.
    los_detected : ndarray of bool, shape (..., N, J)
        Detection rule ``sum_i phi(z=1) > sum_i phi(z=0)`` per node of the last step
        (``J = 0`` before the first step); False where there is no link.
    reset : ndarray of bool, shape (..., N)
        Vehicles whose particles were reset at the last step.
    resets : ndarray of int64, shape (..., N)
        Resets so far.
    time : float or ndarray
        Time of the state.
    ancestors : ndarray of int64, shape (..., N, K), optional
        Index, in the previous step's particle set, of the ancestor of each particle (the
        resampling indices of the last step; None before the first step). Following them
        back gives each particle's history, for a fixed-lag smoother.
    """

    particles: np.ndarray
    log_phi: np.ndarray
    links: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray
    ess: np.ndarray
    los_detected: np.ndarray
    reset: np.ndarray
    resets: np.ndarray
    time: float | np.ndarray = 0.0
    ancestors: np.ndarray | None = None

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The leading axes.

        Returns
        -------
        tuple of int
            ``(..., N)``.
        """
        return self.mean.shape[:-1]


def link_log_phi(loglik: np.ndarray, prev_log_phi: np.ndarray, was_neighbour: np.ndarray,
                 chain: StickyLinkChain) -> np.ndarray:
    """Unnormalised ``log phi_t(z)`` of Algorithm 2, lines 6 and 8, in log space.

    Parameters
    ----------
    loglik : ndarray, shape (..., L, 2)
        ``log p(theta_t | z, v_t^i)``.
    prev_log_phi : ndarray, shape (..., L, 2)
        Normalised ``log phi_{t-1}``; ignored where not ``was_neighbour``.
    was_neighbour : ndarray of bool, broadcastable to (..., L)
        Whether the link existed at ``t - 1`` (line 6) or is new (line 8).
    chain : StickyLinkChain
        The link-state chain.

    Returns
    -------
    ndarray, shape (..., L, 2)
    """
    lt = chain.log_transition
    p0, p1 = prev_log_phi[..., 0], prev_log_phi[..., 1]
    pred = np.stack([np.logaddexp(p0 + lt[0, 0], p1 + lt[1, 0]),
                     np.logaddexp(p0 + lt[0, 1], p1 + lt[1, 1])], axis=-1)
    prior = np.where(was_neighbour[..., None], pred, chain.log_stationary)
    return loglik + prior


def _link_log_phi_and_weights(particles, node_xy, th, valid, where_prev, prev_store, model, chain,
                              kernel):
    """Unnormalised ``log phi_t`` (..., N, K, L, 2) and ``log w_t`` (..., N, K) (lines 6-11).

    ``particles`` are the positions (..., N, K, 2); ``where_prev`` (..., N, L): slot of each
    link in ``prev_store`` (..., N, K, L', 2), the normalised ``log phi_{t-1}``, or -1 for a
    new neighbour.
    """
    if kernel == "numpy":
        was_nb = valid & (where_prev >= 0)
        if prev_store.shape[-2]:
            prev = np.take_along_axis(prev_store, np.maximum(where_prev, 0)[..., None, :, None], axis=-2)
        else:
            prev = np.zeros(particles.shape[:-1] + (node_xy.shape[-2], 2))
        diff = particles[..., :, None, :] - node_xy[..., None, :, :]     # (..., N, K, L, 2)
        dist = np.sqrt(np.sum(diff * diff, axis=-1))
        loglik = model.logpdf_by_state(th[..., None, :], dist)
        log_phi = link_log_phi(loglik, prev, was_nb[..., None, :], chain)
        log_phi = np.where(valid[..., None, :, None], log_phi, 0.0)
        per_link = np.logaddexp(log_phi[..., 0], log_phi[..., 1])
        log_w = np.sum(np.where(valid[..., None, :], per_link, 0.0), axis=-1)
        return log_phi, log_w
    batch = particles.shape[:-2]
    k, width = particles.shape[-2], node_xy.shape[-2]
    b = int(np.prod(batch, dtype=int))
    log_phi = np.empty((b, k, width, 2))
    log_w = np.empty((b, k))
    wp = np.where(valid, where_prev, -1)
    if prev_store.shape[-2] == 0:
        wp = np.full_like(wp, -1)
        prev_store = np.zeros(batch + (k, 1, 2))
    link_update(np.ascontiguousarray(particles.reshape(b, k, 2)),
                np.ascontiguousarray(node_xy.reshape(b, width, 2)),
                np.ascontiguousarray(th.reshape(b, width)),
                np.ascontiguousarray(valid.reshape(b, width)),
                np.ascontiguousarray(wp.reshape(b, width)),
                np.ascontiguousarray(prev_store.reshape((b, k) + prev_store.shape[-2:])),
                float(model.los_std_m), float(model.nlos_mean_m),
                chain.log_transition, chain.log_stationary, log_phi, log_w)
    return log_phi.reshape(batch + (k, width, 2)), log_w.reshape(batch + (k,))


def _posterior_and_resample(log_phi, valid, idx, kernel):
    """``log sum_i phi^i(z)`` (..., N, L, 2) and the resampled normalised ``log phi``."""
    if kernel == "numpy":
        post = logsumexp(log_phi, axis=-3)
        norm = log_phi - np.logaddexp(log_phi[..., :1], log_phi[..., 1:])
        norm = np.where(valid[..., None, :, None], norm, 0.0)
        return post, np.take_along_axis(norm, idx[..., None, None], axis=-3)
    shape = log_phi.shape
    b = int(np.prod(shape[:-3], dtype=int))
    post = np.empty((b, shape[-2], 2))
    out = np.empty((b,) + shape[-3:])
    finish_step(np.ascontiguousarray(log_phi.reshape((b,) + shape[-3:])),
                np.ascontiguousarray(valid.reshape(b, shape[-2])),
                np.ascontiguousarray(idx.reshape(b, shape[-3])), post, out)
    return post.reshape(shape[:-3] + (shape[-2], 2)), out.reshape(shape)


def _previous_slots(links_prev: np.ndarray, links: np.ndarray, size: int) -> np.ndarray:
    """Slot of each current link in the previous step's link list, ``-1`` if new.

    ``links_prev`` (..., L') node indices (``-1`` padding); ``links`` (..., L) current node
    indices; ``size`` the number of nodes J.
    """
    width_prev = links_prev.shape[-1]
    pos_prev = np.full(links.shape[:-1] + (size,), -1, dtype=np.int64)
    if width_prev:
        prev_ok = links_prev >= 0
        np.put_along_axis(pos_prev, np.where(prev_ok, links_prev, 0),
                          np.where(prev_ok, np.arange(width_prev), -1), axis=-1)
        # put_along_axis with duplicate index 0 for padding: restore true slot of node 0
        first = np.where(prev_ok & (links_prev == 0), np.arange(width_prev), width_prev)
        slot0 = first.min(axis=-1)
        pos_prev[..., 0] = np.where(slot0 < width_prev, slot0, -1)
    return np.take_along_axis(pos_prev, links, axis=-1)


class P2PParticleFilter(RecursiveEstimator):
    """Peer-to-peer particle filter of paper 001 (Algorithm 2), one filter per vehicle.

    Parameters
    ----------
    motion : motion model
        Draws the prediction (Algorithm 2, line 3) with ``sample(state, dt, rng, control)``;
        2-D position first in the state. ``InputDriven(s_INS)`` with the INS displacement
        as control is the paper's ``p(v_t | v_{t-1}) = N(v_{t-1} + u_t, s_INS^2 I)``;
        ``RandomWalk(q)`` or ``ConstantVelocity(accel_var)`` (state ``[x, y, vx, vy]``)
        track with no INS.
    measurement : LosNlosRange
        Range model; its sticky link chain (``measurement.chain``) carries the link
        states from step to step.
    particles : int
        K particles per vehicle (paper: 900).
    resampling : {"systematic", "stratified", "multinomial", "residual"}
        Resampling scheme of line 12.
    init_std : float or array_like, shape (n,)
        Standard deviation of ``p(v_0)`` around the initial state, per state component
        (m for positions, m/s for velocities); a scalar applies to every component.
    reset_fraction : float
        Reset rule: a vehicle whose resampled set has fewer than this fraction of K
        distinct particles (the paper's "number of distinct particles becomes small") is
        reset.
    reset_std_m : float
        After a reset the particle positions are ``N(estimate, reset_std_m^2 I)`` (other
        state components are kept) and every particle gets the particle-averaged link
        posterior.
    kernel : {"numba", "numpy"}
        Fused compiled particle-link update, or the same maths as array expressions (the
        reference the kernel is tested against).
    messages : {"previous", "extrapolated", "given"}
        How vehicle ``k`` places neighbour ``m`` at step ``t`` in :meth:`run`:
        ``"previous"`` its estimate of step ``t - 1`` (the paper, Fig. 3);
        ``"extrapolated"`` that estimate moved by the motion model's prediction over the
        step (with INS: plus the neighbour's own INS reading, one more number in the
        message); ``"given"`` positions passed to :meth:`run` (e.g. the truth, to measure
        what the approximation costs).

    Examples
    --------
    >>> from radioloc.models.motion import InputDriven
    >>> from radioloc.models.los_nlos import LosNlosRange
    >>> pf = P2PParticleFilter(InputDriven(0.1), LosNlosRange(0.05, 5.0, 0.3), particles=200)
    """

    name = "p2p-particle"

    def __init__(self, motion, measurement, *, particles: int = 900,
                 resampling: str = "systematic", init_std=1.0, reset_fraction: float = 0.05,
                 reset_std_m: float = 0.5, kernel: str = "numba",
                 messages: str = "previous") -> None:
        for attr in ("sample", "predict", "dim", "state_dim"):
            if not hasattr(motion, attr):
                raise ConfigError(f"motion: {type(motion).__name__} has no {attr!r}")
        if motion.dim != 2:
            raise ConfigError(f"motion: the filter tracks 2-D positions, got dim={motion.dim}")
        if not isinstance(measurement, LosNlosRange):
            raise ConfigError(f"measurement: expected LosNlosRange, got {type(measurement).__name__}")
        particles = check_int(particles, "particles", minimum=1, maximum=MAX_PARTICLES)
        get_scheme(resampling)
        try:
            std = as_float_array(init_std, "init_std")
        except InputError as exc:
            raise ConfigError(str(exc)) from None
        if std.ndim > 1 or (std.ndim == 1 and std.shape[0] != motion.state_dim):
            raise ConfigError(f"init_std: expected a scalar or {motion.state_dim} values, "
                              f"got shape {std.shape}")
        if not np.all(np.isfinite(std)) or np.any(std <= 0):
            raise ConfigError(f"init_std: must be finite and > 0, got {init_std!r}")
        check_probability(reset_fraction, "reset_fraction")
        check_positive(reset_std_m, "reset_std_m")
        if kernel not in KERNELS:
            raise ConfigError(f"kernel: must be 'numba' or 'numpy', got {kernel!r}")
        if messages not in MESSAGES:
            raise ConfigError(f"messages: must be one of {MESSAGES}, got {messages!r}")
        self.motion = motion
        self.measurement = measurement
        self.particles = int(particles)
        self.resampling = resampling
        self.init_std = init_std
        self.reset_fraction = float(reset_fraction)
        self.reset_std_m = float(reset_std_m)
        self.kernel = kernel
        self.messages = messages
        self._init_std = std
        self._input_driven = type(motion).__name__ == "InputDriven"

    # ---- contract -------------------------------------------------------------------
    def init(self, initial, rng: np.random.Generator, time: float | np.ndarray = 0.0
             ) -> ParticleState:
        """Particles from ``p(v_0) = N(initial, diag(init_std^2))`` (Algorithm 2, line 1).

        Parameters
        ----------
        initial : array_like, shape (..., N, 2) or (..., N, n)
            Start positions, or full start states (n = ``motion.state_dim``; components
            not given start at 0, e.g. the velocity).
        rng : numpy.random.Generator
            Source of the particle draws.
        time : float or ndarray
            Time of the prior, seconds.

        Returns
        -------
        ParticleState
        """
        n, D = self.motion.state_dim, self.motion.dim
        v0 = as_float_array(initial, "initial", min_ndim=1, last_dim=tuple({D, n}))
        if v0.shape[-1] < n:
            v0 = np.concatenate([v0, np.zeros(v0.shape[:-1] + (n - D,))], axis=-1)
        k = self.particles
        batch = v0.shape[:-1]
        particles = v0[..., None, :] + self._init_std * rng.standard_normal(batch + (k, n))
        cov = np.broadcast_to(np.diag(np.broadcast_to(self._init_std, (n,)) ** 2),
                              batch + (n, n)).copy()
        return ParticleState(particles=particles,
                             log_phi=np.zeros(batch + (k, 0, 2)),
                             links=np.full(batch + (0,), -1, dtype=np.int64),
                             mean=v0.copy(), covariance=cov,
                             ess=np.full(batch, float(k)),
                             los_detected=np.zeros(batch + (0,), dtype=bool),
                             reset=np.zeros(batch, dtype=bool),
                             resets=np.zeros(batch, dtype=np.int64), time=time)

    def step(self, state: ParticleState, ranges, node_positions, rng: np.random.Generator,
             control=None, dt: float | np.ndarray = 1.0) -> ParticleState:
        """One step of Algorithm 2 for every vehicle of every batch entry.

        Parameters
        ----------
        state : ParticleState
            From :meth:`init` or the previous step.
        ranges : array_like, shape (..., N, J)
            Measured range from vehicle ``k`` to node ``j``; NaN where there is no link
            (skipped). ``ranges[..., k, k]`` (a vehicle to itself) must be NaN when the
            vehicles are among the nodes.
        node_positions : array_like, shape (..., N, J, 2) or (..., J, 2)
            Positions each vehicle assumes for node ``j`` (the neighbours' messages and the
            known anchors); the second form is shared by every vehicle.
        rng : numpy.random.Generator
            Source of the prediction noise and the resampling.
        control : array_like, shape (..., N, 2), optional
            Displacement reading of each vehicle for this step (INS); required by an
            input-driven motion model.
        dt : float or ndarray
            Step length in seconds (used by time-based motion models).

        Returns
        -------
        ParticleState
            The new state (the input state is not modified).
        """
        D = self.motion.dim
        batch = state.batch_shape
        k = state.particles.shape[-2]
        theta = as_float_array(ranges, "ranges", min_ndim=1, allow_nan=True)
        if theta.shape[:-1] != batch:
            raise InputError(f"ranges: leading shape {theta.shape[:-1]} differs from the "
                             f"filter's {batch}")
        if np.any(np.isinf(theta)):
            raise InputError("ranges: infinite value (NaN marks an absent link)")
        mask = np.isfinite(theta)
        nodes = as_float_array(node_positions, "node_positions", min_ndim=2, last_dim=2,
                               allow_nan=True)
        if nodes.ndim == theta.ndim:                      # (..., J, 2): same for every vehicle
            nodes = nodes[..., None, :, :]
        try:
            nodes = np.broadcast_to(nodes, theta.shape + (2,))
        except ValueError:
            raise InputError(f"node_positions: shape {nodes.shape} does not fit ranges "
                             f"{theta.shape}") from None
        if np.any(mask & ~np.all(np.isfinite(nodes), axis=-1)):
            raise InputError("node_positions: non-finite position of a node with a range")
        u = None
        if control is not None:
            u = as_float_array(control, "control", last_dim=D)
            if u.shape[:-1] != batch:
                raise InputError(f"control: leading shape {u.shape[:-1]} differs from {batch}")
            u = u[..., None, :]
        elif self._input_driven:
            raise InputError("control: the input-driven motion model needs the displacement "
                             "reading of every step")

        # line 3: propagate every particle through the motion model
        particles = self.motion.sample(state.particles, dt, rng, control=u)
        pos = particles[..., :D]

        links, valid = pack_mask(mask)                                        # (..., N, L)
        node_xy = gather_packed(nodes, links, axis=-2)                        # (..., N, L, 2)
        th = gather_packed(np.where(mask, theta, 0.0), links)                 # (..., N, L)
        where_prev = _previous_slots(state.links, links, mask.shape[-1])
        chain = self.measurement.chain
        log_phi, log_w = _link_log_phi_and_weights(pos, node_xy, th, valid, where_prev,
                                                   state.log_phi, self.measurement, chain,
                                                   self.kernel)
        log_w = log_w - log_w.max(axis=-1, keepdims=True)
        w = np.exp(log_w)
        w /= w.sum(axis=-1, keepdims=True)
        # line 14: weighted mean; weighted covariance and effective sample size
        mean = np.einsum("...k,...kd->...d", w, particles)
        dev = particles - mean[..., None, :]
        cov = np.einsum("...k,...ki,...kj->...ij", w, dev, dev)
        ess = 1.0 / np.sum(w * w, axis=-1)

        # line 12: resample; detection rule sum_i phi^i(z=1) > sum_i phi^i(z=0); carry the
        # normalised link posterior of each surviving particle
        idx = get_scheme(self.resampling)(w, rng)                             # (..., N, K)
        post, log_phi = _posterior_and_resample(log_phi, valid, idx, self.kernel)
        los_detected = scatter_packed(valid & (post[..., 1] > post[..., 0]), links, valid,
                                      mask.shape[-1]) & mask
        particles = np.take_along_axis(particles, idx[..., None], axis=-2)

        # reset on degeneracy: few distinct ancestors
        s = np.sort(idx, axis=-1)
        distinct = 1 + np.count_nonzero(np.diff(s, axis=-1), axis=-1)
        reset = distinct < self.reset_fraction * k
        if np.any(reset):
            particles[reset, :, :D] = mean[reset][:, None, :D] + self.reset_std_m * \
                rng.standard_normal((int(reset.sum()), k, D))
            mean_post = post - np.logaddexp(post[..., :1], post[..., 1:])     # (..., N, L, 2)
            log_phi[reset] = mean_post[reset][:, None, :, :]
        return ParticleState(particles=particles, log_phi=log_phi,
                             links=np.where(valid, links, -1), mean=mean, covariance=cov,
                             ess=ess, los_detected=los_detected, reset=reset,
                             resets=state.resets + reset, time=state.time + dt,
                             ancestors=idx)

    def estimate(self, state: ParticleState) -> Estimate:
        """The weighted particle mean and covariance of the last step.

        Parameters
        ----------
        state : ParticleState

        Returns
        -------
        Estimate
            ``position`` (..., N, 2), ``covariance`` (..., N, 2, 2); diagnostics ``state``
            and ``state_covariance`` (full state), ``ess``, ``los_detected`` (..., N, J),
            ``resets`` (count so far).
        """
        D = self.motion.dim
        return Estimate(state.mean[..., :D], state.covariance[..., :D, :D], state.time,
                        {"state": state.mean, "state_covariance": state.covariance,
                         "ess": state.ess, "los_detected": state.los_detected,
                         "resets": state.resets})

    def run(self, ranges, initial, rng: np.random.Generator, *, anchors=None, controls=None,
            time=None, given_positions=None) -> Track:
        """Filter every vehicle over ``T`` steps (the loop over time).

        Parameters
        ----------
        ranges : array_like, shape (..., N, T, J)
            Ranges from vehicle ``k`` at step ``t`` to node ``j``, ``J = N + M``: the N
            vehicles of the same batch entry first (a vehicle's range to itself NaN), then
            the M anchors. NaN = no link (skipped).
        initial : array_like, shape (..., N, 2) or (..., N, n)
            Centre of ``p(v_0)`` (see :meth:`init`).
        rng : numpy.random.Generator
            Source of every draw of the filter.
        anchors : array_like, shape (M, 2) or (..., M, 2), optional
            Known anchor positions (none: ``J = N``).
        controls : array_like, shape (..., N, T, 2), optional
            INS displacement readings (required by an input-driven motion model).
        time : array_like, shape (T,), optional
            Step times in seconds; the prior is at ``time[0]`` (default ``0..T-1``).
        given_positions : array_like, shape (..., N, T, 2), optional
            Neighbour positions for ``messages="given"``.

        Returns
        -------
        Track
            ``position`` (..., N, T, 2), ``covariance`` (..., N, T, 2, 2); per-step
            diagnostics ``state``, ``state_covariance``, ``ess``, ``los_detected``
            (..., N, T, J) and ``resets`` (cumulative).
        """
        r = as_float_array(ranges, "ranges", min_ndim=3, allow_nan=True)
        n_veh, T, J = r.shape[-3:]
        if anchors is None:
            a = np.zeros((0, 2))
        else:
            a = as_float_array(anchors, "anchors", min_ndim=2, last_dim=2)
        if J != n_veh + a.shape[-2]:
            raise InputError(f"ranges: {J} nodes per row, expected N + M = {n_veh} + "
                             f"{a.shape[-2]} (vehicles first, then anchors)")
        t = np.arange(T, dtype=float) if time is None else as_float_array(time, "time", ndim=1)
        if t.shape != (T,) or np.any(np.diff(t) < 0):
            raise InputError(f"time: expected {T} non-decreasing step times, got {t.shape}")
        dts = np.diff(t, prepend=t[0])
        u = None
        if controls is not None:
            u = as_float_array(controls, "controls", min_ndim=3, last_dim=2)
            if u.shape[-2] != T:
                raise InputError(f"controls: expected {T} steps on axis -2, got {u.shape}")
        if self.messages == "given":
            if given_positions is None:
                raise InputError("given_positions: required when messages='given'")
            given = as_float_array(given_positions, "given_positions", min_ndim=3, last_dim=2)
        state = self.init(initial, rng, time=t[0])
        if state.batch_shape[-1] != n_veh:
            raise InputError(f"initial: {state.batch_shape[-1]} vehicles, ranges have {n_veh}")
        batch = state.batch_shape[:-1]
        if u is not None and u.shape[:-2] != state.batch_shape:
            raise InputError(f"controls: leading shape {u.shape[:-2]} differs from the runs and "
                             f"vehicles {state.batch_shape}")
        try:
            anchors_b = np.broadcast_to(a, batch + a.shape[-2:])
        except ValueError:
            raise InputError(f"anchors: batch shape {a.shape[:-2]} does not broadcast with the "
                             f"runs' {batch}") from None
        estimates = []
        for k in range(T):
            uk = None if u is None else u[..., k, :]
            if self.messages == "previous":
                peers = state.mean[..., : self.motion.dim]
            elif self.messages == "extrapolated":
                peers = self.motion.predict(state.mean, dts[k], control=uk)[..., : self.motion.dim]
            else:
                peers = given[..., k, :]
            nodes = np.concatenate([np.broadcast_to(peers, batch + (n_veh, 2)), anchors_b], axis=-2)
            state = self.step(state, r[..., k, :], nodes, rng, control=uk, dt=dts[k])
            estimates.append(self.estimate(state))
        return track_from_steps(estimates, t)
