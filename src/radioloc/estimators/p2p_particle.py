"""Peer-to-peer particle filter with per-link LOS/NLOS states (paper 001, Algorithm 2).

Each vehicle ``k`` runs its own particle filter over its position ``v_t(k)``; the binary
link states ``z_t(km)`` are not sampled but summed out exactly per particle through the
``phi`` recursion of Sect. IV::

    phi_t^i(km, z) = p(theta_t(km) | z, v_t^i(k)) * sum_{z'} p(z | z') phi_{t-1}^i(km, z')
    phi_t^i(km, z) = p(z) p(theta_t(km) | z, v_t^i(k))            (m new neighbour)
    w_t^i(k)       = prod_m sum_z phi_t^i(km, z)

(Algorithm 2, lines 6, 8 and 11). Neighbour positions are the neighbours' estimates sent as
messages (the approximation of Fig. 3); anchors are known. Everything is batched over
leading axes ``(runs, vehicles)``, particles and links; the only Python loop is the
caller's loop over time.

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

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.validation import as_float_array, check_positive, check_probability
from radioloc.estimators.pf_kernels import finish_step, link_update
from radioloc.estimators.resampling import get_scheme
from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain


@dataclass(frozen=True)
class ParticleFilterSettings:
    """Choices of the particle filter the paper leaves open.

    particles: K particles per vehicle (paper: 900).
    ins_std_m: std of the INS velocity reading per axis and step; the prediction adds this
        noise to the reading, ``p(v_t | v_{t-1}) = N(v_{t-1} + u_t, s_INS^2 I)``.
    init_std_m: ``p(v_0)`` is ``N(initial, init_std_m^2 I)`` around the given start.
    reset_fraction: reset when fewer than this fraction of the K particles are distinct
        after resampling (the paper's "number of distinct particles becomes small").
    reset_std_m: after a reset, particles are ``N(estimate, reset_std_m^2 I)``.
    resampling: "systematic" (default), "stratified", "multinomial" or "residual".
    kernel: "numba" (fused compiled particle-link update) or "numpy" (same maths, array
        expressions; the reference the kernel is tested against).
    """

    particles: int = 900
    ins_std_m: float = 0.1
    init_std_m: float = 1.0
    reset_fraction: float = 0.05
    reset_std_m: float = 0.5
    resampling: str = "systematic"
    kernel: str = "numba"

    def __post_init__(self) -> None:
        if int(self.particles) < 1:
            raise InputError(f"particles: must be >= 1, got {self.particles}")
        check_positive(self.ins_std_m, "ins_std_m")
        check_positive(self.init_std_m, "init_std_m")
        check_probability(self.reset_fraction, "reset_fraction")
        check_positive(self.reset_std_m, "reset_std_m")
        get_scheme(self.resampling)
        if self.kernel not in ("numba", "numpy"):
            raise ConfigError(f"kernel: must be 'numba' or 'numpy', got {self.kernel!r}")


@dataclass
class FilterState:
    """State of the batched filter.

    particles : (..., N, K, 2) positions.
    log_phi : (..., N, K, L, 2) normalised log link posteriors ``log p(z | .)`` per particle
        for the links of ``links`` (z = 0 NLOS, 1 LOS).
    links : (..., N, L) node index of each stored link, ``-1`` for padding.
    estimate : (..., N, 2) current position estimates.
    resets : (..., N) number of resets so far.
    """

    particles: np.ndarray
    log_phi: np.ndarray
    links: np.ndarray
    estimate: np.ndarray
    resets: np.ndarray


@dataclass
class StepOutput:
    """What one filter step reports.

    estimate : (..., N, 2) weighted particle mean (Algorithm 2, line 14).
    los_detected : (..., N, J) bool, the detection rule ``sum_i phi(z=1) > sum_i phi(z=0)``;
        False where there is no link.
    reset : (..., N) bool, vehicles whose particles were reset this step.
    """

    estimate: np.ndarray
    los_detected: np.ndarray
    reset: np.ndarray


def init_filter(initial: np.ndarray, settings: ParticleFilterSettings,
                rng: np.random.Generator) -> FilterState:
    """Particles from ``p(v_0) = N(initial, init_std_m^2 I)`` (Algorithm 2, line 1)."""
    v0 = as_float_array(initial, "initial", min_ndim=2, last_dim=2)
    k = int(settings.particles)
    particles = v0[..., None, :] + settings.init_std_m * rng.standard_normal(v0.shape[:-1] + (k, 2))
    batch = v0.shape[:-1]
    return FilterState(particles=particles,
                       log_phi=np.zeros(batch + (k, 0, 2)),
                       links=np.full(batch + (0,), -1, dtype=np.int64),
                       estimate=v0.copy(),
                       resets=np.zeros(batch, dtype=np.int64))


def compact_links(in_range: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node indices of the links in range, packed to the front: ``(links, valid)``, ``(..., L)``.

    ``L`` is the largest number of links of any batch entry; padding has index 0 and
    ``valid`` False.
    """
    order = np.argsort(~in_range, axis=-1, kind="stable")
    count = in_range.sum(axis=-1)
    width = int(count.max()) if count.size else 0
    links = order[..., :width]
    valid = np.arange(width) < count[..., None]
    return links, valid


def link_log_phi(loglik: np.ndarray, prev_log_phi: np.ndarray, was_neighbour: np.ndarray,
                 chain: StickyLinkChain) -> np.ndarray:
    """Unnormalised ``log phi_t(z)`` of Algorithm 2, lines 6 and 8, in log space.

    loglik : (..., L, 2) ``log p(theta_t | z, v_t^i)``.
    prev_log_phi : (..., L, 2) normalised ``log phi_{t-1}``; ignored where not ``was_neighbour``.
    was_neighbour : broadcastable to (..., L) bool.
    """
    lt = chain.log_transition
    p0, p1 = prev_log_phi[..., 0], prev_log_phi[..., 1]
    pred = np.stack([np.logaddexp(p0 + lt[0, 0], p1 + lt[1, 0]),
                     np.logaddexp(p0 + lt[0, 1], p1 + lt[1, 1])], axis=-1)
    prior = np.where(was_neighbour[..., None], pred, chain.log_stationary)
    return loglik + prior


def _logsumexp(x: np.ndarray, axis: int) -> np.ndarray:
    """``log sum exp`` along ``axis`` (max-shifted; all ``-inf`` gives ``-inf``)."""
    m = np.max(x, axis=axis, keepdims=True)
    m = np.where(np.isfinite(m), m, 0.0)
    with np.errstate(divide="ignore"):
        return np.squeeze(m, axis=axis) + np.log(np.sum(np.exp(x - m), axis=axis))


def _link_log_phi_and_weights(particles, node_xy, th, valid, where_prev, prev_store, model, chain,
                              kernel):
    """Unnormalised ``log phi_t`` (..., N, K, L, 2) and ``log w_t`` (..., N, K) (lines 6-11).

    ``where_prev`` (..., N, L): slot of each link in ``prev_store`` (..., N, K, L', 2), the
    normalised ``log phi_{t-1}``, or -1 for a new neighbour.
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
        post = _logsumexp(log_phi, axis=-3)
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


def filter_step(state: FilterState, ins_velocity: np.ndarray, ranges: np.ndarray,
                in_range: np.ndarray, node_positions: np.ndarray, model: LosNlosRange,
                settings: ParticleFilterSettings, rng: np.random.Generator) -> tuple[FilterState, StepOutput]:
    """One step of Algorithm 2 for every vehicle of every batch entry.

    Parameters
    ----------
    state : FilterState
    ins_velocity : (..., N, 2) INS displacement reading of each vehicle for this step.
    ranges : (..., N, J) measured range from vehicle k to node j (NaN where no link).
    in_range : (..., N, J) bool, which links exist this step (``in_range[k, k]`` must be False).
    node_positions : (..., N, J, 2) or (..., J, 2) positions each vehicle assumes for node j:
        the neighbours' messages (their previous estimates) and the known anchors.
    model : LosNlosRange
    settings : ParticleFilterSettings
    rng : numpy Generator

    Returns
    -------
    (FilterState, StepOutput)
    """
    chain = StickyLinkChain(model.alpha)
    batch = state.particles.shape[:-2]
    k = state.particles.shape[-2]
    u = as_float_array(ins_velocity, "ins_velocity", last_dim=2)
    mask = np.asarray(in_range, dtype=bool)
    if mask.shape[:-1] != batch:
        raise InputError(f"in_range: leading shape {mask.shape[:-1]} differs from the filter's {batch}")
    theta = np.asarray(ranges, dtype=float)
    if np.any(mask & ~np.isfinite(theta)):
        raise InputError("ranges: a link marked in_range has a non-finite range")
    nodes = np.asarray(node_positions, dtype=float)
    if nodes.ndim == mask.ndim:                       # (..., J, 2): same for every vehicle
        nodes = np.broadcast_to(nodes[..., None, :, :], mask.shape + (2,))

    # line 3: propagate with the INS reading
    particles = state.particles + u[..., None, :] + settings.ins_std_m * rng.standard_normal(
        state.particles.shape)

    links, valid = compact_links(mask)                                   # (..., N, L)
    node_xy = np.take_along_axis(nodes, links[..., None], axis=-2)       # (..., N, L, 2)
    th = np.take_along_axis(np.where(mask, theta, 0.0), links, axis=-1)  # (..., N, L)
    # where was each current link stored at t-1?
    width_prev = state.links.shape[-1]
    pos_prev = np.full(mask.shape, -1, dtype=np.int64)
    if width_prev:
        prev_ok = state.links >= 0
        np.put_along_axis(pos_prev, np.where(prev_ok, state.links, 0),
                          np.where(prev_ok, np.arange(width_prev), -1), axis=-1)
        # put_along_axis with duplicate index 0 for padding: restore true slot of node 0
        first = np.where(prev_ok & (state.links == 0), np.arange(width_prev), width_prev)
        slot0 = first.min(axis=-1)
        pos_prev[..., 0] = np.where(slot0 < width_prev, slot0, -1)
    where_prev = np.take_along_axis(pos_prev, links, axis=-1)             # (..., N, L)
    log_phi, log_w = _link_log_phi_and_weights(particles, node_xy, th, valid, where_prev,
                                               state.log_phi, model, chain, settings.kernel)
    log_w = log_w - log_w.max(axis=-1, keepdims=True)
    w = np.exp(log_w)
    w /= w.sum(axis=-1, keepdims=True)
    estimate = np.einsum("...k,...kd->...d", w, particles)

    # line 12: resample; detection rule sum_i phi^i(z=1) > sum_i phi^i(z=0); carry the
    # normalised link posterior of each surviving particle
    idx = get_scheme(settings.resampling)(w, rng)                         # (..., N, K)
    post, log_phi = _posterior_and_resample(log_phi, valid, idx, settings.kernel)
    los_compact = valid & (post[..., 1] > post[..., 0])
    los_detected = np.zeros(mask.shape, dtype=bool)
    np.put_along_axis(los_detected, links, los_compact, axis=-1)
    los_detected &= mask
    particles = np.take_along_axis(particles, idx[..., None], axis=-2)

    # reset on degeneracy: few distinct ancestors
    s = np.sort(idx, axis=-1)
    distinct = 1 + np.count_nonzero(np.diff(s, axis=-1), axis=-1)
    reset = distinct < settings.reset_fraction * k
    if np.any(reset):
        particles[reset] = estimate[reset][:, None, :] + settings.reset_std_m * rng.standard_normal(
            (int(reset.sum()), k, 2))
        mean_post = post - np.logaddexp(post[..., :1], post[..., 1:])        # (..., N, L, 2)
        log_phi[reset] = mean_post[reset][:, None, :, :]

    new_state = FilterState(particles=particles, log_phi=log_phi,
                            links=np.where(valid, links, -1), estimate=estimate,
                            resets=state.resets + reset)
    return new_state, StepOutput(estimate=estimate, los_detected=los_detected, reset=reset)


MESSAGES = ("previous", "extrapolated", "given")


@dataclass
class TrackResult:
    """Output of :func:`track`.

    estimate : (..., T, N, 2); los_detected : (..., T, N, J) bool; resets : (..., N).
    """

    estimate: np.ndarray
    los_detected: np.ndarray
    resets: np.ndarray


def track(initial: np.ndarray, ins: np.ndarray, ranges: np.ndarray, in_range: np.ndarray,
          anchors: np.ndarray, model: LosNlosRange, settings: ParticleFilterSettings,
          rng: np.random.Generator, messages: str = "previous",
          given_positions: np.ndarray | None = None) -> TrackResult:
    """Run the filter of every vehicle over ``T`` steps (the loop over time).

    Parameters
    ----------
    initial : (..., N, 2) start positions (centre of ``p(v_0)``).
    ins : (..., T, N, 2) INS displacement readings.
    ranges, in_range : (..., T, N, J) with ``J = N + M``, vehicles first.
    anchors : (M, 2) known anchor positions.
    messages : how vehicle ``k`` places neighbour ``m`` at step ``t``:
        ``"previous"`` its estimate of step ``t - 1`` (the paper, Fig. 3);
        ``"extrapolated"`` that estimate plus ``m``'s own INS reading of step ``t``
        (one more number in the message; removes the 0.2 m/step lag);
        ``"given"`` the positions ``given_positions (..., T, N, 2)`` (e.g. the truth, to
        measure what the approximation costs).
    """
    if messages not in MESSAGES:
        raise ConfigError(f"messages: must be one of {MESSAGES}, got {messages!r}")
    if messages == "given" and given_positions is None:
        raise InputError("given_positions: required when messages='given'")
    a = as_float_array(anchors, "anchors", ndim=2, last_dim=2)
    u = as_float_array(ins, "ins", min_ndim=3, last_dim=2)
    steps = u.shape[-3]
    state = init_filter(initial, settings, rng)
    batch = state.estimate.shape[:-2]
    anchors_b = np.broadcast_to(a, batch + a.shape)
    est, det = [], []
    for t in range(steps):
        ut = u[..., t, :, :]
        if messages == "previous":
            vehicles = state.estimate
        elif messages == "extrapolated":
            vehicles = state.estimate + ut
        else:
            vehicles = given_positions[..., t, :, :]
        nodes = np.concatenate([vehicles, anchors_b], axis=-2)
        state, out = filter_step(state, ut, ranges[..., t, :, :], in_range[..., t, :, :], nodes,
                                 model, settings, rng)
        est.append(out.estimate)
        det.append(out.los_detected)
    return TrackResult(np.stack(est, axis=-3), np.stack(det, axis=-3), state.resets)
