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
leading axes ``(runs, vehicles)``, particles and links; :meth:`P2PParticleFilter.run` is a
loop over :meth:`P2PParticleFilter.step`. A step takes a step length per filter, and its
draws from one generator or from one per filter
(:class:`~radioloc.estimators.particle_filter.RunGenerators`: a batch then gives each
filter what it gives alone, as ``locate --method pf`` runs the segments of a log).

Each part of a step is defined once here in NumPy (``backend="numpy"``): the prediction
(line 3, the motion model's draws), the particle-link update (:func:`_link_update_numpy`,
lines 6, 8, 11, with the densities of :mod:`radioloc.models.los_nlos` and its sticky chain),
the weighted moments (:func:`radioloc.estimators.particle_filter.weighted_moments`, line 14) and the resampling of
:mod:`radioloc.estimators.resampling` (line 12). ``backend="numba"`` runs the kernels of
:mod:`radioloc.estimators.pf_compiled` for the last three on the same draws.

The models are arguments: the motion model (``InputDriven(s_INS)`` with the INS reading as
control, the paper's; or ``RandomWalk``, ``ConstantVelocity`` with no INS) draws the
prediction (line 3) through its ``sample`` (:func:`radioloc.estimators.particle_filter.sample_motion`);
the measurement model is a :class:`~radioloc.models.ranging.RangeModel`. With the LOS/NLOS
noise :class:`~radioloc.models.los_nlos.LosNlosRange` (the paper's) the update above runs on
the mixture's parameters (both backends, and the online EM below); with any other noise
(Gaussian, or another model with per-row states) ``backend="numpy"`` takes the
per-state log-densities from the model's ``mode_logpdf`` and its chain from
``mode_transition``/``mode_prior``, and sums the states out by the generic filter's
:func:`radioloc.estimators.particle_filter.mode_update` (:func:`_link_update_model`). The
likelihood uses the position part of the state.

Correction of Algorithm 2 as printed: it resamples at every step (line 12) but carries the
unnormalised ``phi_{t-1}`` forward, which would count the history of each link twice (once
in the resampled particle set, once more in ``phi``). We carry the normalised link
posterior ``phi_{t-1}(z) / sum_z phi_{t-1}(z)`` instead, which is the exact
Rao-Blackwellised update after resampling; without resampling both agree up to a factor
common to all particles. Since the two values of a normalised posterior sum to one, one
number per particle and link is carried: the LOS probability ``p(z = 1 | .)``.

The parameters of the range model can be estimated inside the filter by online EM
(:class:`OnlineEM`, ``online_em=``), which the paper names (Sect. V).
"""

from __future__ import annotations

import copy
from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from radioloc.core.arrays import kernel_array
from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.links import gather_packed, pack_mask, scatter_packed
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import (MAX_PARTICLES, as_float_array, check_int, check_positive,
                                      check_probability, check_ranges, range_noise_std)
from radioloc.estimators import pf_compiled as _c
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.particle_filter import (CHUNK, RunGenerators, compiled_moments,
                                                 compiled_systematic, mode_update, sample_motion,
                                                 standard_normal, weighted_moments)
from radioloc.estimators.resampling import get_scheme
from radioloc.models.los_nlos import (LosNlosRange, StickyLinkChain, emg_logpdf, gaussian_logpdf,
                                      sticky_transition)
from radioloc.models.measurement import Context
from radioloc.models.ranging import RangeModel

__all__ = ["P2PParticleFilter", "ParticleState", "OnlineEM", "MESSAGES", "link_log_phi"]

#: How vehicle ``k`` places neighbour ``m`` at step ``t`` (see :class:`P2PParticleFilter`).
MESSAGES = ("previous", "extrapolated", "given")


@dataclass(frozen=True)
class OnlineEM:
    """Online EM of the range model inside the filter (paper 001, Sect. V: "the parameters
    of the distributions and the fraction alpha can be estimated using an EM algorithm at
    every step").

    Stochastic-approximation EM in the manner of Cappé and Moulines: every filter (one per
    vehicle, on its own links) keeps running sufficient statistics

        S_n = (1 - g_n) S_{n-1} + g_n s_n,   g_n = n^(-step_exponent),

    where ``n`` counts its steps with at least one link and ``s_n`` sums over the step's
    links the particle-weighted expectations ``(1, q, q e^2, (1 - q) e)``: ``q`` is the
    particle's LOS posterior of the link after the update and ``e`` the range minus the
    particle's distance to the node. The M-step maps ``S = (S_1, S_q, S_qe2, S_e)`` to

        alpha = S_q / S_1,   s_LOS^2 = S_qe2 / S_q,   s_NLOS = S_e / (S_1 - S_q)

    (exact for alpha and the Gaussian LOS spread; for the exponential excess the moment
    equation ``E[e | NLOS] = s_NLOS``, since the EMG's M-step has no closed form). The
    filter uses the parameters of the previous step; they start at the measurement model's
    and move after ``burn_in`` steps with links. The link chain stays the paper's sticky
    chain of the current alpha.

    Parameters
    ----------
    step_exponent : float
        kappa in (0.5, 1] of the step sizes ``g_n = n^(-kappa)``.
    burn_in : int
        Steps with links before the parameters are updated (statistics accumulate from
        the first).
    fit : tuple of str
        Parameters estimated, among ``"alpha"``, ``"los_std_m"``, ``"nlos_mean_m"``; the
        others stay at the measurement model's values.
    alpha_bounds : tuple of float
        Clip of the alpha estimate.
    min_los_std_m, min_nlos_mean_m : float
        Floors of the ``s_LOS`` and ``s_NLOS`` estimates.
    """

    step_exponent: float = 0.6
    burn_in: int = 20
    fit: tuple[str, ...] = ("alpha", "los_std_m", "nlos_mean_m")
    alpha_bounds: tuple[float, float] = (0.01, 0.99)
    min_los_std_m: float = 1e-3
    min_nlos_mean_m: float = 1e-2

    def __post_init__(self) -> None:
        if not 0.5 < float(self.step_exponent) <= 1.0:
            raise ConfigError(f"step_exponent: must be in (0.5, 1], got {self.step_exponent!r}")
        if int(self.burn_in) != self.burn_in or self.burn_in < 0:
            raise ConfigError(f"burn_in: must be an integer >= 0, got {self.burn_in!r}")
        bad = set(self.fit) - set(PARAMETERS)
        if bad or not self.fit:
            raise ConfigError(f"fit: choose among {PARAMETERS}, got {self.fit!r}")
        lo, hi = self.alpha_bounds
        if not 0.0 <= lo < hi <= 1.0:
            raise ConfigError(f"alpha_bounds: need 0 <= low < high <= 1, got {self.alpha_bounds!r}")
        check_positive(self.min_los_std_m, "min_los_std_m")
        check_positive(self.min_nlos_mean_m, "min_nlos_mean_m")


#: Order of the range-model parameters in :attr:`ParticleState.params`.
PARAMETERS = ("los_std_m", "nlos_mean_m", "alpha")


@dataclass(frozen=True)
class ParticleState:
    """State of a batch of peer-to-peer particle filters (one per vehicle).

    Attributes
    ----------
    particles : ndarray, shape (..., N, K, n)
        Equally weighted particles (after resampling) of the ``n``-dimensional state,
        position first.
    link_los : ndarray, shape (..., N, K, L)
        Normalised link posterior ``p(z = 1 | .)`` (LOS) per particle for the stored links;
        ``p(z = 0 | .)`` is one minus it.
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
    params : ndarray, shape (..., N, 3), optional
        Range-model parameters ``(s_LOS, s_NLOS, alpha)`` each filter uses at the next step
        (the measurement model's, or the online EM's estimates); None: the model's.
    em_stats : ndarray, shape (..., N, 4), optional
        Online EM's running statistics ``(S_1, S_q, S_qe2, S_e)`` (None without online EM).
    em_steps : ndarray of int64, shape (..., N), optional
        Online EM's count of steps with links.
    los_certain : ndarray of bool, shape (..., N, L), optional
        Stored links on which every particle's LOS posterior is exactly 1 (None before the
        first step).
    """

    particles: np.ndarray
    link_los: np.ndarray
    links: np.ndarray
    mean: np.ndarray
    covariance: np.ndarray
    ess: np.ndarray
    los_detected: np.ndarray
    reset: np.ndarray
    resets: np.ndarray
    time: float | np.ndarray = 0.0
    ancestors: np.ndarray | None = None
    params: np.ndarray | None = None
    em_stats: np.ndarray | None = None
    em_steps: np.ndarray | None = None
    los_certain: np.ndarray | None = None

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


def _normalise_post(post):
    """``log sum_i phi^i(z)`` (..., L, 2) normalised over ``z``; -inf where both are."""
    top = np.logaddexp(post[..., :1], post[..., 1:])
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(top), post - top, -np.inf)


def _link_update_numpy(particles, node_xy, th, valid, where_prev, prev_q, params):
    """Algorithm 2, lines 6, 8 and 11, in the log domain (the definition of
    :func:`radioloc.estimators.pf_compiled.link_update`).

    ``particles`` (..., K, n); link ``l`` (``valid`` (..., L)) is node ``node_xy`` (..., L, 2)
    at range ``th`` (..., L), slot ``where_prev`` (..., L) of the previous step's links (-1:
    new); ``prev_q`` (..., K, L') the carried LOS posteriors, ``params`` (..., 3) the
    ``(s_LOS, s_NLOS, alpha)`` of each filter. With ``log phi(z) = log p(theta | z, v) +
    log pi(z)``, ``pi`` the sticky chain's prediction of the carried posterior (line 6) or
    its stationary law (line 8), returns ``log w = sum_l log sum_z phi(z)`` (..., K), the new
    posteriors ``phi(1) / sum_z phi(z)`` (..., K, L) (0 on padding), ``log sum_i phi^i(z)``
    normalised over ``z`` (..., L, 2), the online-EM sums (..., K, 3) and the links whose new
    posterior is exactly 1 for every particle (..., L).
    """
    s, mu, a = (params[..., i][..., None, None] for i in range(3))       # (..., 1, 1)
    if prev_q.shape[-1]:
        q = np.take_along_axis(prev_q, np.maximum(where_prev, 0)[..., None, :], axis=-1)
    else:
        q = np.zeros(particles.shape[:-1] + (node_xy.shape[-2],))
    chain = sticky_transition(params[..., 2])                             # (..., 2, 2)
    pred = np.einsum("...klz,...zy->...kly", np.stack([1.0 - q, q], axis=-1), chain)
    stationary = np.stack([1.0 - a, a], axis=-1)                          # (..., 1, 1, 2)
    prior = np.where((where_prev >= 0)[..., None, :, None], pred, stationary)
    diff = particles[..., :, None, :2] - node_xy[..., None, :, :]          # (..., K, L, 2)
    e = th[..., None, :] - np.sqrt(np.sum(diff * diff, axis=-1))
    with np.errstate(divide="ignore"):
        A0 = emg_logpdf(e, s, mu) + np.log(prior[..., 0])
        A1 = gaussian_logpdf(e, s) + np.log(prior[..., 1])
    lse = np.logaddexp(A0, A1)
    ok = valid[..., None, :]
    q_new = np.where(ok, np.exp(A1 - lse), 0.0)
    log_w = np.sum(np.where(ok, lse, 0.0), axis=-1)
    post = np.stack([logsumexp(np.where(ok, A0, -np.inf), axis=-2),
                     logsumexp(np.where(ok, A1, -np.inf), axis=-2)], axis=-1)
    ez = np.where(ok, e, 0.0)
    em_pp = np.stack([q_new.sum(-1), (q_new * ez * ez).sum(-1), ((1 - q_new) * ez).sum(-1)],
                     axis=-1)
    return log_w, q_new, _normalise_post(post), em_pp, np.all(q_new == 1.0, axis=-2) & valid


def _link_update_model(model, particles, node_xy, th, valid, where_prev, prev_q):
    """Lines 6, 8 and 11 for any :class:`~radioloc.models.ranging.RangeModel` with one or
    two states per link (the outputs of :func:`_link_update_numpy` without the online-EM
    sums): the per-state log-densities of ``model.mode_logpdf`` summed out by
    :func:`radioloc.estimators.particle_filter.mode_update` under the prior of the carried
    posterior through ``model.mode_transition()`` (line 6) or ``model.mode_prior()``
    (line 8). A one-state model's link is LOS: its posterior is 1."""
    S = model.modes
    z = np.where(valid, th, np.nan)[..., None, :]                          # (..., 1, L)
    ctx = Context(points=node_xy[..., None, :, :])                         # (..., 1, L, 2)
    lp = model.mode_logpdf(z, {"position": particles[..., :2]}, ctx)      # (..., K, L, S)
    prior = np.broadcast_to(model.mode_prior(), lp.shape)
    if S > 1 and prev_q.shape[-1]:
        q = np.take_along_axis(prev_q, np.maximum(where_prev, 0)[..., None, :], axis=-1)
        pred = np.stack([1.0 - q, q], axis=-1) @ model.mode_transition()
        prior = np.where((where_prev >= 0)[..., None, :, None], pred, prior)
    row_ll, post = mode_update(prior, lp)
    ok = valid[..., None, :]
    log_w = np.sum(np.where(ok, row_ll, 0.0), axis=-1)
    q_new = np.where(ok, post[..., -1], 0.0)
    with np.errstate(divide="ignore"):
        joint = np.where(ok[..., None], np.log(prior) + lp, -np.inf)
    pooled = logsumexp(joint, axis=-3)                                    # (..., L, S)
    if S == 1:
        pooled = np.concatenate([np.full_like(pooled, -np.inf), pooled], axis=-1)
    return log_w, q_new, _normalise_post(pooled), None, np.all(q_new == 1.0, axis=-2) & valid


def _link_update(particles, node_xy, th, valid, where_prev, prev_q, params, certain, backend,
                 em, model=None):
    """:func:`_link_update_numpy` by ``backend`` (the online-EM sums None unless ``em``).
    ``certain`` (..., L'): the previous step's links whose posterior was 1 for every
    particle (the last output; None before the first step). Where such a link is carried
    and alpha is 1, or a new link has alpha 1, the LOS prior of every particle is 1 and the
    pooled posterior is LOS, which the kernel then does not sum. ``model``: a range model
    other than the LOS/NLOS mixture, run by :func:`_link_update_model`."""
    if model is not None:
        return _link_update_model(model, particles, node_xy, th, valid, where_prev, prev_q)
    if backend == "numpy":
        out = _link_update_numpy(particles, node_xy, th, valid, where_prev, prev_q, params)
        return out if em else out[:3] + (None, out[4])
    batch, (k, n), width = particles.shape[:-2], particles.shape[-2:], node_xy.shape[-2]
    b = int(np.prod(batch, dtype=int))
    nch = -(-k // CHUNK)
    log_w, q_new = np.empty((b, k)), np.empty((b, k, width))
    pmax, psum = np.empty((b, nch, width)), np.empty((b, nch, width, 2))
    em_pp = np.empty((b, k, 3) if em else (1, 1, 3))
    uncertain = np.empty((b, nch, width), dtype=bool)
    los_prior_one = (params[..., 2] == 1.0)[..., None] & (where_prev < 0)
    if certain is not None and certain.shape[-1]:
        los_prior_one |= (params[..., 2] == 1.0)[..., None] & (where_prev >= 0) & \
            np.take_along_axis(certain, np.maximum(where_prev, 0), axis=-1)
    if prev_q.shape[-1] == 0:
        prev_q = np.zeros(batch + (k, 1))
    _c.link_update(kernel_array(particles.reshape(b, k, n)),
                   kernel_array(node_xy.reshape(b, width, 2)), kernel_array(th.reshape(b, width)),
                   kernel_array(valid.reshape(b, width), np.bool_),
                   kernel_array(where_prev.reshape(b, width), np.int64),
                   kernel_array(prev_q.reshape((b, k, -1))), kernel_array(params.reshape(b, 3)),
                   kernel_array((valid & ~los_prior_one).reshape(b, width), np.bool_),
                   CHUNK, em, log_w, q_new, pmax, psum, em_pp, uncertain)
    with np.errstate(divide="ignore"):
        post = _normalise_post(np.logaddexp.reduce(pmax[..., None] + np.log(psum), axis=1))
    post[los_prior_one.reshape(b, width)] = [-np.inf, 0.0]
    return (log_w.reshape(batch + (k,)), q_new.reshape(batch + (k, width)),
            post.reshape(batch + (width, 2)), em_pp.reshape(batch + (k, 3)) if em else None,
            (valid.reshape(b, width) & ~uncertain.any(axis=1)).reshape(batch + (width,)))


def _weighted_moments(log_w, particles, backend):
    """:func:`radioloc.estimators.particle_filter.weighted_moments` by ``backend``."""
    if backend == "numpy":
        return weighted_moments(log_w, particles)
    return compiled_moments(log_w, particles)[:4]


def _resample(w, particles, q, scheme, backend, rng):
    """Line 12: ancestors (..., K) of the normalised weights ``w`` by ``scheme`` of
    :mod:`radioloc.estimators.resampling`, the particles and link posteriors ``q`` (..., K, L)
    taken at them, and the number of distinct ancestors (...)."""
    if backend == "numba" and scheme == "systematic":
        return compiled_systematic(w, particles, q, rng)
    idx = get_scheme(scheme)(w, rng)
    distinct = 1 + np.count_nonzero(np.diff(np.sort(idx, axis=-1), axis=-1), axis=-1)
    return (idx, np.take_along_axis(particles, idx[..., None], axis=-2),
            np.take_along_axis(q, idx[..., None], axis=-2), distinct)


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


def _check_nodes(mask, nodes):
    """InputError unless every node with a range (``mask`` (..., J)) has a finite position
    (``nodes`` (..., J, 2))."""
    if np.any(mask & ~np.all(np.isfinite(nodes), axis=-1)):
        raise InputError("node_positions: non-finite position of a node with a range")


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
    measurement : RangeModel or LosNlosRange
        Range model (a ``LosNlosRange`` is taken as ``RangeModel(noise=LosNlosRange)``).
        With the LOS/NLOS noise its sticky link chain carries the link states from step
        to step (both backends); any other noise (e.g. ``RangeModel(std_m=...)``) needs
        ``backend="numpy"`` and runs through the model's ``mode_logpdf`` (see the module
        docstring). No per-anchor bias.
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
    backend : {"numba", "numpy"}
        The particle-link update, the weighted moments and systematic resampling by the
        compiled kernels of :mod:`radioloc.estimators.pf_compiled`, or by their NumPy
        definitions in this module. Both take the same draws from ``rng``, so they agree to
        rounding (about 1e-10 relative).
    messages : {"previous", "extrapolated", "given"}
        How vehicle ``k`` places neighbour ``m`` at step ``t`` in :meth:`run`:
        ``"previous"`` its estimate of step ``t - 1`` (the paper, Fig. 3);
        ``"extrapolated"`` that estimate moved by the motion model's prediction over the
        step (with INS: plus the neighbour's own INS reading, one more number in the
        message); ``"given"`` positions passed to :meth:`run` (e.g. the truth, to measure
        what the approximation costs).
    message_lag : {1, 0}
        Steps between a neighbour's message and the ranges it is used with in
        :meth:`run`. 1 (the paper): the messages above, sent after step ``t - 1``. 0 (an
        ablation that removes the lag): step ``t`` is first filtered with those messages
        from a copy of ``rng``, and each neighbour's estimate of step ``t`` from that pass
        is then its message for the update of step ``t`` itself, which consumes ``rng`` as
        the lagged filter would (same draws; twice the cost). Not with ``"given"``.
    online_em : bool or OnlineEM
        Estimate alpha, s_LOS and s_NLOS inside the filter (each vehicle on its own links),
        starting from the measurement model's values; ``True`` is ``OnlineEM()``. The
        estimates are the diagnostic ``em_parameters`` ``(s_LOS, s_NLOS, alpha)``.

    Examples
    --------
    >>> from radioloc.models.motion import InputDriven
    >>> from radioloc.models.los_nlos import LosNlosRange
    >>> pf = P2PParticleFilter(InputDriven(0.1), LosNlosRange(0.05, 5.0, 0.3), particles=200)
    """

    name = "p2p-particle"

    def __init__(self, motion, measurement, *, particles: int = 900,
                 resampling: str = "systematic", init_std=1.0, reset_fraction: float = 0.05,
                 reset_std_m: float = 0.5, backend: str = DEFAULT_BACKEND,
                 messages: str = "previous", message_lag: int = 1,
                 online_em: bool | OnlineEM = False) -> None:
        for attr in ("sample", "predict", "dim", "state_dim"):
            if not hasattr(motion, attr):
                raise ConfigError(f"motion: {type(motion).__name__} has no {attr!r}")
        if motion.dim != 2:
            raise ConfigError(f"motion: the filter tracks 2-D positions, got dim={motion.dim}")
        if isinstance(measurement, LosNlosRange):
            measurement = RangeModel(noise=measurement)
        if not isinstance(measurement, RangeModel):
            raise ConfigError(f"measurement: expected a RangeModel (or LosNlosRange), got "
                              f"{type(measurement).__name__}")
        if measurement.anchor_bias:
            raise ConfigError("measurement: the peer-to-peer filter has no anchor-bias state; "
                              "give a RangeModel with anchor_bias=False")
        if measurement.modes not in (1, 2):
            raise ConfigError(f"measurement: links with 1 or 2 discrete states, got "
                              f"{measurement.modes}")
        mixture = measurement.noise if isinstance(measurement.noise, LosNlosRange) else None
        if mixture is None and backend == "numba":
            raise ConfigError(f"measurement: backend='numba' runs the LOS/NLOS mixture "
                              f"(RangeModel(noise=LosNlosRange)) only; for "
                              f"{type(measurement.noise).__name__} noise use backend='numpy'")
        if mixture is None and online_em:
            raise ConfigError("online_em: estimates the LOS/NLOS mixture's parameters; the "
                              f"measurement noise is {type(measurement.noise).__name__}")
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
        check_backend(backend)
        if messages not in MESSAGES:
            raise ConfigError(f"messages: must be one of {MESSAGES}, got {messages!r}")
        if message_lag not in (0, 1) or isinstance(message_lag, bool):
            raise ConfigError(f"message_lag: must be 1 (the paper) or 0, got {message_lag!r}")
        if message_lag == 0 and messages == "given":
            raise ConfigError("message_lag: 0 applies to estimated messages ('previous' or "
                              "'extrapolated'), not to messages='given'")
        self.motion = motion
        self.measurement = measurement
        self._mixture = mixture
        self.particles = int(particles)
        self.resampling = resampling
        self.init_std = init_std
        self.reset_fraction = float(reset_fraction)
        self.reset_std_m = float(reset_std_m)
        self.backend = backend
        self.messages = messages
        self.message_lag = int(message_lag)
        if online_em is True:
            online_em = OnlineEM()
        if online_em is not False and online_em is not None and not isinstance(online_em, OnlineEM):
            raise ConfigError(f"online_em: expected a bool or OnlineEM, got {online_em!r}")
        self.online_em = online_em or None
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
        params = np.broadcast_to(self._model_params(), batch + (3,)).copy()
        em = self.online_em is not None
        return ParticleState(particles=particles,
                             link_los=np.zeros(batch + (k, 0)),
                             links=np.full(batch + (0,), -1, dtype=np.int64),
                             mean=v0.copy(), covariance=cov,
                             ess=np.full(batch, float(k)),
                             los_detected=np.zeros(batch + (0,), dtype=bool),
                             reset=np.zeros(batch, dtype=bool),
                             resets=np.zeros(batch, dtype=np.int64), time=time, params=params,
                             em_stats=np.zeros(batch + (4,)) if em else None,
                             em_steps=np.zeros(batch, dtype=np.int64) if em else None)

    def step(self, state: ParticleState, ranges, node_positions, rng: np.random.Generator,
             control=None, dt: float | np.ndarray = 1.0, *, check: bool = True
             ) -> ParticleState:
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
        rng : numpy.random.Generator or RunGenerators
            Source of the prediction noise and the resampling (a
            :class:`~radioloc.estimators.particle_filter.RunGenerators` over the batch
            shape ``(..., N)``: each filter draws from its own generator, so that a batch
            gives what its filters give one by one).
        control : array_like, shape (..., N, 2), optional
            Displacement reading of each vehicle for this step (INS); required by an
            input-driven motion model.
        dt : float or ndarray, shape (..., N)
            Step length in seconds (used by time-based motion models), for every filter
            or one per filter (0 for a filter with nothing to do at this step: no
            motion noise, and with no range its particles keep their place).
        check : bool
            Validate the inputs. False: the caller has checked them once for a whole
            log (``ranges`` a float array finite or NaN, ``node_positions`` of shape
            ``(..., N, J, 2)`` finite wherever there is a range, ``control`` given
            exactly when the motion model is input-driven); this saves their cost at
            every step.

        Returns
        -------
        ParticleState
            The new state (the input state is not modified).
        """
        D = self.motion.dim
        batch = state.batch_shape
        if not check:
            theta = np.asarray(ranges)
            return self._step(state, theta, ~np.isnan(theta), node_positions, rng,
                              None if control is None else np.asarray(control)[..., None, :],
                              dt)
        theta = as_float_array(ranges, "ranges", min_ndim=1, allow_nan=True)
        if theta.shape[:-1] != batch:
            raise InputError(f"ranges: leading shape {theta.shape[:-1]} differs from the "
                             f"filter's {batch}")
        if np.any(np.isinf(theta)):
            raise InputError("ranges: infinite value (NaN marks an absent link)")
        check_ranges(theta, "ranges", range_noise_std(self.measurement))
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
        _check_nodes(mask, nodes)
        u = None
        if control is not None:
            u = as_float_array(control, "control", last_dim=D)
            if u.shape[:-1] != batch:
                raise InputError(f"control: leading shape {u.shape[:-1]} differs from {batch}")
            u = u[..., None, :]
        elif self._input_driven:
            raise InputError("control: the input-driven motion model needs the displacement "
                             "reading of every step")
        return self._step(state, theta, mask, nodes, rng, u, dt)

    def _step(self, state, theta, mask, nodes, rng, u, dt):
        """:meth:`step` on checked inputs: ``theta`` (..., N, J) finite or NaN, ``mask`` its
        finite entries, ``nodes`` (..., N, J, 2) finite where ``mask``, ``u`` (..., N, 1, D)
        or None."""
        k = state.particles.shape[-2]
        links, valid = pack_mask(mask)                                        # (..., N, L)
        node_xy = gather_packed(nodes, links, axis=-2)                        # (..., N, L, 2)
        th = gather_packed(np.where(mask, theta, 0.0), links)                 # (..., N, L)
        where_prev = np.where(valid, _previous_slots(state.links, links, mask.shape[-1]), -1)
        params = self._params(state)
        work = int(np.prod(links.shape, dtype=np.int64)) * max(k, 1)
        with _c.threads_for(work) if self.backend == "numba" else nullcontext():
            return self._update(state, mask, rng, u, dt, links, valid, node_xy, th, where_prev,
                                params)

    def _update(self, state, mask, rng, u, dt, links, valid, node_xy, th, where_prev, params):
        """Lines 3 to 14 of :meth:`_step` on the packed links of the step."""
        D = self.motion.dim
        k = state.particles.shape[-2]
        em = self.online_em is not None
        # line 3: propagate every particle through the motion model
        particles = sample_motion(self.motion, state.particles, dt, rng, u,
                                  normal=lambda shape: standard_normal(rng, shape, self.backend))
        # lines 6, 8, 11: link posteriors and weights
        log_w, q, post, em_pp, certain = _link_update(
            particles, node_xy, th, valid, where_prev, state.link_los, params, state.los_certain,
            self.backend, em, None if self._mixture is not None else self.measurement)
        # line 14: weighted mean; weighted covariance and effective sample size
        w, mean, cov, ess = _weighted_moments(log_w, particles, self.backend)
        # line 12: resample; carry the normalised link posterior of each surviving particle
        idx, particles, q, distinct = _resample(w, particles, q, self.resampling, self.backend,
                                                rng)
        # detection rule sum_i phi^i(z=1) > sum_i phi^i(z=0)
        los_detected = scatter_packed(valid & (post[..., 1] > post[..., 0]), links, valid,
                                      mask.shape[-1]) & mask
        # reset on degeneracy: few distinct ancestors
        reset = distinct < self.reset_fraction * k
        if np.any(reset):
            if isinstance(rng, RunGenerators):          # each run's draws from its own stream
                z = rng.standard_normal(reset.shape + (k, D), where=reset)[reset]
            else:
                z = rng.standard_normal((int(reset.sum()), k, D))
            particles[reset, :, :D] = mean[reset][:, None, :D] + self.reset_std_m * z
            with np.errstate(invalid="ignore"):
                mean_post = np.exp(post[..., 1] - np.logaddexp(post[..., 0], post[..., 1]))
            q[reset] = np.where(valid, np.nan_to_num(mean_post), 0.0)[reset][:, None, :]
        em_stats, em_steps = state.em_stats, state.em_steps
        if em:
            em_stats, em_steps, params = self._em_update(state, w, em_pp, valid, params)
        return ParticleState(particles=particles, link_los=q,
                             links=np.where(valid, links, -1), mean=mean, covariance=cov,
                             ess=ess, los_detected=los_detected, reset=reset,
                             resets=state.resets + reset, time=state.time + dt,
                             ancestors=idx, params=params, em_stats=em_stats,
                             em_steps=em_steps, los_certain=certain)

    def _params(self, state: ParticleState) -> np.ndarray:
        """``(s_LOS, s_NLOS, alpha)`` per filter, (..., N, 3)."""
        if state.params is not None:
            return state.params
        return np.broadcast_to(self._model_params(), state.batch_shape + (3,))

    def _model_params(self) -> np.ndarray:
        """The mixture's ``(s_LOS, s_NLOS, alpha)``; NaN for another noise model."""
        m = self._mixture
        return np.array([np.nan] * 3 if m is None else [m.los_std_m, m.nlos_mean_m, m.alpha])

    def _em_update(self, state, w, em_pp, valid, params):
        """One online EM step (see :class:`OnlineEM`): new statistics, counts, parameters."""
        cfg = self.online_em
        n_links = valid.sum(axis=-1).astype(float)                            # (..., N)
        step_stats = np.concatenate([n_links[..., None],
                                     np.einsum("...k,...kc->...c", w, em_pp)], axis=-1)
        has = n_links > 0
        steps = state.em_steps + has
        gamma = np.where(has, np.maximum(steps, 1) ** (-cfg.step_exponent), 0.0)[..., None]
        stats = (1.0 - gamma) * state.em_stats + gamma * step_stats
        ready = (steps > cfg.burn_in) & has
        s1, sq, sqe2, se = (stats[..., i] for i in range(4))
        with np.errstate(divide="ignore", invalid="ignore"):
            est = {"alpha": np.clip(sq / s1, *cfg.alpha_bounds),
                   "los_std_m": np.maximum(np.sqrt(sqe2 / sq), cfg.min_los_std_m),
                   "nlos_mean_m": np.maximum(se / (s1 - sq), cfg.min_nlos_mean_m)}
        new = params.copy()
        for name in cfg.fit:
            col = PARAMETERS.index(name)
            ok = ready & np.isfinite(est[name])
            new[..., col] = np.where(ok, est[name], params[..., col])
        return stats, steps, new

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
            ``resets`` (count so far); with online EM ``em_parameters`` (..., N, 3), the
            ``(s_LOS, s_NLOS, alpha)`` the next step uses.
        """
        D = self.motion.dim
        diag = {"state": state.mean, "state_covariance": state.covariance,
                "ess": state.ess, "los_detected": state.los_detected, "resets": state.resets}
        if self.online_em is not None:
            diag["em_parameters"] = self._params(state)
        return Estimate(state.mean[..., :D], state.covariance[..., :D, :D], state.time, diag)

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
            (..., N, T, J), ``resets`` (cumulative) and, with online EM,
            ``em_parameters`` (..., N, T, 3).
        """
        r = check_ranges(as_float_array(ranges, "ranges", min_ndim=3, allow_nan=True), "ranges",
                         range_noise_std(self.measurement))
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
        given = None
        if self.messages == "given":
            if given_positions is None:
                raise InputError("given_positions: required when messages='given'")
            given = as_float_array(given_positions, "given_positions", min_ndim=3, last_dim=2)
        state = self.init(initial, rng, t[0])
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
        # checks of step, once for every step (the nodes built below are checked per step
        # only where they can be non-finite: the peers' positions)
        if r.shape[:-2] != state.batch_shape:
            raise InputError(f"ranges: leading shape {r.shape[:-2]} differs from the "
                             f"filter's {state.batch_shape}")
        if np.any(np.isinf(r)):
            raise InputError("ranges: infinite value (NaN marks an absent link)")
        if u is None and self._input_driven:
            raise InputError("control: the input-driven motion model needs the displacement "
                             "reading of every step")
        mask_all = ~np.isnan(r)
        estimates = []
        def nodes_of(peers, mask):
            nodes = np.concatenate([np.broadcast_to(peers, batch + (n_veh, 2)), anchors_b],
                                   axis=-2)
            nodes = np.broadcast_to(nodes[..., None, :, :], mask.shape + (2,))
            if not np.all(np.isfinite(peers)):
                _check_nodes(mask, nodes)
            return nodes

        for k in range(T):
            uk = None if u is None else u[..., k, :]
            uk_p = None if uk is None else uk[..., None, :]
            mask = mask_all[..., k, :]
            nodes = nodes_of(self._peers(state.mean, dts[k], uk, given, k), mask)
            if self.message_lag == 0:       # the neighbours' estimates of this step
                first = self._step(state, r[..., k, :], mask, nodes, copy.deepcopy(rng), uk_p,
                                   dts[k])
                nodes = nodes_of(first.mean[..., : self.motion.dim], mask)
            state = self._step(state, r[..., k, :], mask, nodes, rng, uk_p, dts[k])
            estimates.append(self.estimate(state))
        return track_from_steps(estimates, t)

    def _peers(self, mean, dt, control, given, k):
        """Positions vehicle ``k`` uses for its neighbours at step ``k`` of :meth:`run` (see
        ``messages``), from the estimates ``mean`` (..., N, n) of the previous step."""
        if self.messages == "previous":
            return mean[..., : self.motion.dim]
        if self.messages == "extrapolated":
            return self.motion.predict(mean, dt, control=control)[..., : self.motion.dim]
        return given[..., k, :]
