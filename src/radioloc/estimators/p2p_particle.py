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
common to all particles. Since the two values of a normalised posterior sum to one, one
number per particle and link is carried: the LOS probability ``p(z = 1 | .)``.

The parameters of the range model can be estimated inside the filter by online EM
(:class:`OnlineEM`, ``online_em=``), which the paper names (Sect. V).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp

from radioloc.core.arrays import kernel_array
from radioloc.core.errors import ConfigError, InputError
from radioloc.core.links import gather_packed, pack_mask, scatter_packed
from radioloc.core.results import Estimate, Track, track_from_steps
from radioloc.core.validation import (MAX_PARTICLES, as_float_array, check_int, check_positive,
                                      check_probability)
from radioloc.estimators import pf_bootstrap as _bs
from radioloc.estimators import pf_kernels as _k
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.pf_random import draw_key, standard_normal_numpy
from radioloc.estimators.resampling import get_scheme
from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain, emg_logpdf, gaussian_logpdf
from radioloc.models.motion import InputDriven, MotionModel

__all__ = ["P2PParticleFilter", "ParticleState", "OnlineEM", "MESSAGES", "link_log_phi"]

#: How vehicle ``k`` places neighbour ``m`` at step ``t`` (see :class:`P2PParticleFilter`).
MESSAGES = ("previous", "extrapolated", "given")
KERNELS = ("numba", "numpy")
#: Particles per parallel task of the compiled link update.
CHUNK = 2048


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
        ``p(z = 0 | .)`` is one minus it. After a step in which every filter took the
        Gaussian case (alpha = 1, every posterior 1) a read-only view of one row broadcast
        over the particles.
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
    """Plain NumPy reference of :func:`radioloc.estimators.pf_kernels.link_weights`
    (the same maths in the log domain).

    Returns ``log_w`` (..., K), ``q_new`` (..., K, L), ``post`` (..., L, 2) = ``log sum_i
    phi^i(z)`` normalised over ``z`` (the particle-pooled link posterior; -inf where the
    link does not exist), ``em_pp`` (..., K, 3) and None (no Gaussian-case flags).
    """
    s, mu, a = (params[..., i][..., None, None] for i in range(3))       # (..., 1, 1)
    if prev_q.shape[-1]:
        q = np.take_along_axis(prev_q, np.maximum(where_prev, 0)[..., None, :], axis=-1)
    else:
        q = np.zeros(particles.shape[:-1] + (node_xy.shape[-2],))
    was_nb = (valid & (where_prev >= 0))[..., None, :]
    diff = particles[..., :, None, :2] - node_xy[..., None, :, :]          # (..., K, L, 2)
    e = th[..., None, :] - np.sqrt(np.sum(diff * diff, axis=-1))
    l0, l1 = emg_logpdf(e, s, mu), gaussian_logpdf(e, s)
    pi1 = np.where(was_nb, q * (1 + a) / 2 + (1 - q) * a / 2, a)
    pi0 = np.where(was_nb, q * (1 - a) / 2 + (1 - q) * (1 - a / 2), 1 - a)
    with np.errstate(divide="ignore"):
        A0, A1 = l0 + np.log(pi0), l1 + np.log(pi1)
    lse = np.logaddexp(A0, A1)
    ok = valid[..., None, :]
    q_new = np.where(ok, np.exp(A1 - lse), 0.0)
    log_w = np.sum(np.where(ok, lse, 0.0), axis=-1)
    neg = -np.inf
    post = np.stack([logsumexp(np.where(ok, A0, neg), axis=-2),
                     logsumexp(np.where(ok, A1, neg), axis=-2)], axis=-1)
    post = _normalise_post(post)
    ez = np.where(ok, e, 0.0)
    em_pp = np.stack([q_new.sum(-1), (q_new * ez * ez).sum(-1), ((1 - q_new) * ez).sum(-1)], axis=-1)
    return log_w, q_new, post, em_pp, None


#: Work arrays of :meth:`P2PParticleFilter.step` kept between calls, per thread (see
#: :func:`_scratch`).
_SCRATCH = threading.local()
#: Larger work arrays are not kept.
_SCRATCH_MAX_BYTES = 1 << 28


def _scratch(name, shape, dtype=np.float64):
    """A C-contiguous work array of ``shape`` (contents undefined), the same memory on every
    call of this thread with this ``name`` while it is large enough: the arrays a step uses
    and drops (the predicted particles, the new link posteriors before the gather) are not
    fresh memory every step (the kernel's first touch of fresh pages, and their zeroing,
    cost system time)."""
    cache = getattr(_SCRATCH, "arrays", None)
    if cache is None:
        cache = _SCRATCH.arrays = {}
    size = math.prod(shape)
    dtype = np.dtype(dtype)
    if size * dtype.itemsize > _SCRATCH_MAX_BYTES:
        cache.pop((name, dtype), None)
        return np.empty(shape, dtype=dtype)
    a = cache.get((name, dtype))
    if a is None or a.size < size:
        a = np.empty(max(size, 1), dtype=dtype)
        cache[(name, dtype)] = a
    return a[:size].reshape(shape)


def _run_layout(state, r):
    """The links of a whole run packed once, for :meth:`P2PParticleFilter.run`'s compiled
    paths: ``(batch_v, batch, b, nb, mask, links, valid, th, time_first)`` with the batch
    shape of the vehicles ``(..., N)`` and of the runs ``(...)``, their sizes ``b`` and
    ``nb``, the measured mask ``(..., N, T, J)`` of the ranges ``r``, the packed links and
    ranges ``(..., N, T, L)`` (:func:`pack_mask`, :func:`gather_packed`), and
    ``time_first``, which makes an ``(..., N, T, *x)`` array a C-contiguous
    ``(T, b, *x)`` one."""
    batch_v = state.batch_shape                             # (..., N)
    batch = batch_v[:-1]
    T = r.shape[-2]
    b = int(np.prod(batch_v, dtype=int))
    nb = int(np.prod(batch, dtype=int))
    nbd = len(batch_v)
    mask_all = ~np.isnan(r)                                 # (..., N, T, J); no inf
    links, valid = pack_mask(mask_all)                      # (..., N, T, L)
    th = gather_packed(np.where(mask_all, r, 0.0), links)

    def time_first(a):                                      # (..., N, T, *x) -> (T, b, *x)
        return np.ascontiguousarray(np.moveaxis(a.reshape((b, T) + a.shape[nbd + 1:]), 1, 0))

    return batch_v, batch, b, nb, mask_all, links, valid, th, time_first


def _link_update(particles, node_xy, th, valid, where_prev, prev_q, params, kernel, em,
                 scratch=False, anc=None, q_out=None, link_major=False):
    """``log w`` (..., K), new link posteriors (..., K, L), ``log sum_i phi^i(z)``
    normalised over ``z`` (..., L, 2), the online-EM per-particle sums (..., K, 3) and
    which filters took the Gaussian case (..., bool; see ``pf_kernels``) (lines 6-11).
    ``scratch``: ``log w`` and the new link posteriors in this thread's work arrays (see
    :func:`_scratch`; valid until the next scratch call). ``anc`` (..., K), the compiled
    kernel only: particle ``i`` carries the posteriors of row ``anc[..., i]`` of ``prev_q``
    (the resampling's gather done by the kernel's read; the same values as ``prev_q``
    gathered beforehand). ``q_out`` (B, K, L): the array the new posteriors are written to.
    ``link_major`` (the compiled kernel only): ``prev_q`` (..., L', K) and the new
    posteriors (..., L, K) with the link axis before the particles (one contiguous row per
    link; the rows of padding slots are left unwritten, so only what a later step reads,
    the rows of existing links, is defined).

    A ``prev_q`` whose particle axis has stride 0 (the broadcast posterior a Gaussian-case
    step leaves) is passed to the kernel as one row shared by every particle."""
    if kernel == "numpy":
        if link_major:
            raise ValueError("link_major: the compiled kernel only")
        if anc is not None and prev_q.shape[-1] and prev_q.strides[-2] != 0:
            prev_q = np.take_along_axis(prev_q, anc[..., None], axis=-2)
        return _link_update_numpy(particles, node_xy, th, valid, where_prev, prev_q, params)
    batch = particles.shape[:-2]
    k, n, width = particles.shape[-2], particles.shape[-1], node_xy.shape[-2]
    b = math.prod(batch)
    nc = _k.n_chunks(k, CHUNK)
    log_w = _scratch("log_w", (b, k)) if scratch else np.empty((b, k))
    shape = (b, width, k) if link_major else (b, k, width)
    if q_out is not None:
        q_new = q_out
    else:
        q_new = _scratch("q_new", shape) if scratch else np.empty(shape)
    part_s = np.empty((b, nc, width, 2))
    part_l = np.empty((b, nc, width, 2))
    em_pp = np.empty((b, k, 3) if em else (1, 1, 3))
    wp = np.where(valid, where_prev, -1)
    if prev_q.shape[-2 if link_major else -1] == 0:
        wp = np.full_like(wp, -1)
        prev_q = np.zeros(batch + (1, 1))
    elif link_major and prev_q.strides[-1] == 0:
        prev_q = prev_q[..., :1]
    elif not link_major and prev_q.strides[-2] == 0:
        prev_q = prev_q[..., :1, :]
    gauss = np.empty(b, dtype=bool)
    p = params.reshape(b, 3)
    cols = p.T.copy()                               # (3, b): s_LOS, s_NLOS, alpha rows
    _k.link_weights(kernel_array(particles.reshape(b, k, n)),
                    kernel_array(node_xy.reshape(b, width, 2)),
                    kernel_array(th.reshape(b, width)),
                    kernel_array(valid.reshape(b, width), np.bool_),
                    kernel_array(wp.reshape(b, width), np.int64),
                    kernel_array(prev_q.reshape((b,) + prev_q.shape[-2:])),
                    _NO_ANCESTORS if anc is None else kernel_array(anc.reshape(b, k), np.int64),
                    anc is not None, link_major, cols[0], cols[1], cols[2], CHUNK, em, log_w,
                    q_new, part_s, part_l, em_pp, gauss)
    lam = 1.0 / p[:, 1]
    ce = np.log(lam) + 0.5 * (lam * p[:, 0]) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        post = np.logaddexp(np.log(part_s.sum(axis=1)) + ce[:, None, None],
                            np.logaddexp.reduce(part_l, axis=1))
    post = _normalise_post(post)
    # the kernel leaves q_new of a Gaussian-case filter unwritten: 1 on its links; when
    # every filter is, one row broadcast over the particles (read-only, no copy)
    rows = valid.reshape(b, width, 1) if link_major else valid.reshape(b, 1, width)
    if gauss.all():
        q_new = np.broadcast_to(rows.astype(float), shape)
    elif gauss.any():
        q_new[gauss] = rows[gauss]
    out = (log_w.reshape(batch + (k,)), q_new.reshape(batch + shape[1:]),
           post.reshape(batch + (width, 2)))
    return out + ((em_pp.reshape(batch + (k, 3)) if em else None), gauss.reshape(batch))


def _moments(log_w, particles, kernel, scratch=False):
    """Normalised weights (..., K), weighted mean (..., n), covariance (..., n, n), ESS;
    ``scratch``: the weights in this thread's work array (see :func:`_scratch`)."""
    if kernel == "numpy":
        w = np.exp(log_w - log_w.max(axis=-1, keepdims=True))
        w /= w.sum(axis=-1, keepdims=True)
        mean = np.einsum("...k,...kd->...d", w, particles)
        dev = particles - mean[..., None, :]
        cov = np.einsum("...k,...ki,...kj->...ij", w, dev, dev)
        return w, mean, cov, 1.0 / np.sum(w * w, axis=-1)
    batch, (k, n) = particles.shape[:-2], particles.shape[-2:]
    b = math.prod(batch)
    w = _scratch("w", (b, k)) if scratch else np.empty((b, k))
    mean, cov, ess = np.empty((b, n)), np.empty((b, n, n)), np.empty(b)
    _k.weights_moments(kernel_array(log_w.reshape(b, k)),
                       kernel_array(particles.reshape(b, k, n)), CHUNK, w, mean, cov, ess)
    return (w.reshape(batch + (k,)), mean.reshape(batch + (n,)), cov.reshape(batch + (n, n)),
            ess.reshape(batch))


#: Normal draws of one step at or above this many numbers are made in parts of
#: ``_DRAW_PART`` numbers from child generators of ``rng`` (``rng.spawn``), on threads
#: (NumPy releases the GIL while it fills an array); the parts depend on the size only, so
#: the draws do not depend on the number of threads.
_DRAW_PARALLEL = 1 << 17
_DRAW_PART = 1 << 16
_POOL = None


def _standard_normal(rng, shape, scratch=False, extra=None):
    """``rng.standard_normal(shape)``; large draws in fixed parts from spawned children,
    filled in parallel (see ``_DRAW_PARALLEL``). ``scratch``: into this thread's work array
    (see :func:`_scratch`). ``extra``: a callable run on this thread before the draws from
    ``rng`` (or, when the draws are the children's, while the pool fills them)."""
    global _POOL
    size = int(np.prod(shape, dtype=np.int64))
    out = _scratch("draws", (size,)) if scratch else None
    if size < _DRAW_PARALLEL or getattr(rng.bit_generator, "seed_seq", None) is None:
        if extra is not None:
            extra()
        if out is None:
            return rng.standard_normal(shape)
        return rng.standard_normal(out=out).reshape(shape)
    import numba
    from concurrent.futures import ThreadPoolExecutor
    if out is None:
        out = np.empty(size)
    parts = -(-size // _DRAW_PART)
    children = rng.spawn(parts)
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max(1, numba.get_num_threads()))

    def fill(i):
        # children[i].standard_normal(out=...) by numba's Generator (NumPy's numbers)
        _fill_normal(children[i], out[i * _DRAW_PART:(i + 1) * _DRAW_PART])
    filled = _POOL.map(fill, range(parts))
    if extra is not None:
        extra()
    list(filled)
    return out.reshape(shape)


def _fill_normal(rng, out):
    """``rng.standard_normal(out=out)``, by numba's ``Generator`` when it takes ``rng``
    (NumPy's numbers and state, without the GIL; see ``pf_kernels.fill_standard_normal``),
    else by NumPy."""
    from numba.core.errors import TypingError
    try:
        _k.fill_standard_normal(rng, out)
    except TypingError:
        rng.standard_normal(out=out)


def _sample_motion(motion, particles, dt, rng, control, scratch=False):
    """Line 3 through the motion model: its own ``sample``, except for the linear-Gaussian
    models of :class:`radioloc.models.motion.MotionModel`, whose ``F x + w, w ~ N(0, Q(dt))``
    is drawn here with ``Q(dt)`` factored once per step instead of once per particle (the
    same maths; draws through :func:`_standard_normal`, into its work array when
    ``scratch``)."""
    if isinstance(motion, InputDriven) and particles.shape[-1] == motion.dim:
        # InputDriven.sample without its identity product: (x + u) + std z, the same
        # floating-point result, into the array of the draws
        z = _standard_normal(rng, particles.shape, scratch)
        z *= motion.std_m
        z += particles if control is None else particles + control
        return z
    if type(motion).sample is not MotionModel.sample:
        return motion.sample(particles, dt, rng, control=control)
    F = motion.F(dt)
    n = particles.shape[-1]
    if F.shape == (n, n) and np.array_equal(F, np.eye(n)):
        # F = I (random walk): the product is the identity, skip it (the same result)
        mean = particles
        if control is not None:
            mean = particles.copy()
            mean[..., : motion.dim] += control
    else:
        mean = motion.predict(particles, dt, control=control)
    vals, vecs = np.linalg.eigh(np.asarray(motion.Q(dt), dtype=float))          # (..., n, n)
    factor = vecs * np.sqrt(np.maximum(vals, 0.0))[..., None, :]
    z = _standard_normal(rng, mean.shape, scratch)
    if factor.ndim == 2 and np.array_equal(factor, np.diag(np.diagonal(factor))):
        # diagonal noise: mean + diag(factor) z, the product's values, into the array of
        # the draws
        z *= np.diagonal(factor)
        z += mean
        return z
    if factor.ndim == 2:                                    # one Q for every particle
        return mean + z @ factor.T
    return mean + np.einsum("...ij,...j->...i", factor, z)


def _walk_noise(motion, n, dt):
    """``sd`` (n,) when ``motion`` moves a state by ``x + u + diag(sd) z`` with ``z`` standard
    normal and one ``sd`` for every filter (the input-driven model; a linear-Gaussian model
    with ``F = I`` and a diagonal factor of ``Q``, the random walk), else None. The factor is
    the one :func:`_sample_motion` uses, so both draw the same values from the same ``z``."""
    if isinstance(motion, InputDriven) and n == motion.dim:
        std = np.asarray(motion.std_m, dtype=float)
        return np.full(n, float(std)) if std.ndim == 0 else None
    if type(motion).sample is not MotionModel.sample:
        return None
    F = np.asarray(motion.F(dt))
    if F.shape != (n, n) or not np.array_equal(F, np.eye(n)):
        return None
    vals, vecs = np.linalg.eigh(np.asarray(motion.Q(dt), dtype=float))
    factor = vecs * np.sqrt(np.maximum(vals, 0.0))[..., None, :]
    if factor.shape != (n, n) or not np.array_equal(factor, np.diag(np.diagonal(factor))):
        return None
    return np.diagonal(factor).copy()


#: ``anc`` of :func:`radioloc.estimators.pf_bootstrap.bootstrap_step` when it is not read.
_NO_ANCESTORS = np.zeros((1, 1), dtype=np.int64)
#: ``out_particles`` of the same kernel when it does not gather.
_NO_PARTICLES = np.zeros((1, 1, 2))


def _bootstrap_step(particles, control, sd, key, node_xy, th, valid, params, rng):
    """The fused bootstrap step (:func:`radioloc.estimators.pf_bootstrap.bootstrap_step`):
    resampled particles, ancestors, mean, covariance, ESS and distinct ancestors. Its motion
    draws are ``pf_random.standard_normal(shape=particles.shape, key=key)``; the resampling
    uniform is ``rng.random(batch + (1,))``, the draw of ``resampling.systematic``."""
    batch, k = particles.shape[:-2], particles.shape[-2]
    b = int(np.prod(batch, dtype=int))
    width = node_xy.shape[-2]
    u01 = rng.random(batch + (1,))
    shift = np.zeros((b, 2)) if control is None else \
        kernel_array(np.broadcast_to(control, batch + (1, 2)).reshape(b, 2))
    out = np.empty((b, k, 2))
    idx = np.empty((b, k), dtype=np.int64)
    mean, cov, ess = np.empty((b, 2)), np.empty((b, 2, 2)), np.empty(b)
    distinct = np.empty(b, dtype=np.int64)
    _bs.bootstrap_step(kernel_array(particles.reshape(b, k, 2)), _NO_ANCESTORS, False,
                       shift, kernel_array(sd), key,
                       kernel_array(node_xy.reshape(b, width, 2)),
                       kernel_array(th.reshape(b, width)),
                       kernel_array(valid.reshape(b, width), np.bool_),
                       kernel_array(1.0 / params[..., 0].reshape(b)),
                       u01.reshape(b), CHUNK, True, out, idx, mean, cov, ess, distinct,
                       _scratch("pred", (b, k, 2)), _scratch("v", (b, k)))
    return (out.reshape(batch + (k, 2)), idx.reshape(batch + (k,)), mean.reshape(batch + (2,)),
            cov.reshape(batch + (2, 2)), ess.reshape(batch), distinct.reshape(batch))


def _gather(particles, q, idx, kernel, slot=None):
    """Resampled particles and link posteriors, and the number of distinct ancestors;
    ``slot`` (:meth:`P2PParticleFilter.run`): the outputs in this thread's work arrays of
    that name (see :func:`_scratch`)."""
    if kernel == "numpy":
        s = np.sort(idx, axis=-1)
        distinct = 1 + np.count_nonzero(np.diff(s, axis=-1), axis=-1)
        return (np.take_along_axis(particles, idx[..., None], axis=-2),
                np.take_along_axis(q, idx[..., None], axis=-2), distinct)
    batch, (k, n), width = particles.shape[:-2], particles.shape[-2:], q.shape[-1]
    b = int(np.prod(batch, dtype=int))
    if slot is None:
        out_p, out_q = np.empty((b, k, n)), np.empty((b, k, width))
    else:
        out_p, out_q = _scratch(f"{slot}_p", (b, k, n)), _scratch(f"{slot}_q", (b, k, width))
    distinct = np.empty(b, dtype=np.int64)
    _k.gather_resampled(particles.reshape(b, k, n), q.reshape(b, k, width),
                        np.ascontiguousarray(idx.reshape(b, k)), out_p, out_q, distinct,
                        _scratch("seen", (b, k), np.bool_), CHUNK)
    return (out_p.reshape(particles.shape), out_q.reshape(q.shape), distinct.reshape(batch))


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
        reference the kernel is tested against). In the plain bootstrap case (systematic
        resampling, no online EM, a random-walk or input-driven motion of 2-D positions,
        alpha = 1 with every carried LOS posterior 1) the compiled step is one kernel
        (:func:`radioloc.estimators.pf_bootstrap.bootstrap_step`) whose motion noise comes
        from the counter-based generator of :mod:`radioloc.estimators.pf_random` keyed by
        ``rng`` (other values than ``rng.standard_normal``, the same distribution);
        ``"numpy"`` draws the same values there.
    messages : {"previous", "extrapolated", "given"}
        How vehicle ``k`` places neighbour ``m`` at step ``t`` in :meth:`run`:
        ``"previous"`` its estimate of step ``t - 1`` (the paper, Fig. 3);
        ``"extrapolated"`` that estimate moved by the motion model's prediction over the
        step (with INS: plus the neighbour's own INS reading, one more number in the
        message); ``"given"`` positions passed to :meth:`run` (e.g. the truth, to measure
        what the approximation costs).
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
                 reset_std_m: float = 0.5, kernel: str = "numba",
                 messages: str = "previous", online_em: bool | OnlineEM = False) -> None:
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
        if online_em is True:
            online_em = OnlineEM()
        if online_em is not False and online_em is not None and not isinstance(online_em, OnlineEM):
            raise ConfigError(f"online_em: expected a bool or OnlineEM, got {online_em!r}")
        self.online_em = online_em or None
        self._init_std = std
        self._input_driven = type(motion).__name__ == "InputDriven"
        self._walk_sd = {}          # dt -> the bootstrap case's noise std (see _walk_noise)

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
        return self._init(initial, rng, time)

    def _init(self, initial, rng, time, scratch=False):
        """:meth:`init`; ``scratch``: the particles in this thread's work array (see
        :func:`_scratch`; :meth:`run` only reads them, at its first step)."""
        n, D = self.motion.state_dim, self.motion.dim
        v0 = as_float_array(initial, "initial", min_ndim=1, last_dim=tuple({D, n}))
        if v0.shape[-1] < n:
            v0 = np.concatenate([v0, np.zeros(v0.shape[:-1] + (n - D,))], axis=-1)
        k = self.particles
        batch = v0.shape[:-1]
        # v0 + init_std z, computed in the array of the draws (the same values)
        if scratch:
            particles = rng.standard_normal(out=_scratch("run_init", batch + (k, n)))
        else:
            particles = rng.standard_normal(batch + (k, n))
        particles *= self._init_std
        particles += v0[..., None, :]
        cov = np.broadcast_to(np.diag(np.broadcast_to(self._init_std, (n,)) ** 2),
                              batch + (n, n)).copy()
        m = self.measurement
        params = np.broadcast_to(np.array([m.los_std_m, m.nlos_mean_m, m.alpha]),
                                 batch + (3,)).copy()
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

    def _step(self, state, theta, mask, nodes, rng, u, dt, slot=None):
        """:meth:`step` on checked inputs: ``theta`` (..., N, J) finite or NaN, ``mask`` its
        finite entries, ``nodes`` (..., N, J, 2) finite where ``mask``, ``u`` (..., N, 1, D)
        or None. ``slot``: the new particles and link posteriors in this thread's work
        arrays of that name (:meth:`run`, which alternates two: a step reads the previous
        step's and writes the other)."""
        D = self.motion.dim
        batch = state.batch_shape
        k = state.particles.shape[-2]
        links, valid = pack_mask(mask)                                        # (..., N, L)
        node_xy = gather_packed(nodes, links, axis=-2)                        # (..., N, L, 2)
        th = gather_packed(np.where(mask, theta, 0.0), links)                 # (..., N, L)
        where_prev = _previous_slots(state.links, links, mask.shape[-1])
        params = self._params(state)
        em = self.online_em is not None
        sd = self._bootstrap_noise(state, params, valid, where_prev, dt)
        if sd is not None and self.kernel == "numba":
            # the bootstrap case: lines 3, 11, 14 and 12 in one compiled kernel
            particles, idx, mean, cov, ess, distinct = _bootstrap_step(
                state.particles, u, sd, draw_key(rng), node_xy, th, valid, params, rng)
            # every link LOS with probability 1 (see _link_update's Gaussian case)
            q = np.broadcast_to(valid[..., None, :].astype(float), batch + (k, valid.shape[-1]))
            post = None
            los_detected = mask.copy()
            w = em_pp = None
        else:
            # line 3: propagate every particle through the motion model
            if sd is not None:              # the bootstrap case's draws (see _bootstrap_step)
                z = standard_normal_numpy(rng, state.particles.shape)
                z *= sd
                z += state.particles if u is None else state.particles + u
                particles = z
            else:
                particles = _sample_motion(self.motion, state.particles, dt, rng, u,
                                           scratch=self.kernel == "numba")
            # lines 6, 8, 11: link posteriors and weights
            log_w, q, post, em_pp, gauss = _link_update(particles, node_xy, th, valid,
                                                        where_prev, state.link_los, params,
                                                        self.kernel, em, scratch=True)
            # line 14: weighted mean; weighted covariance and effective sample size
            w, mean, cov, ess = _moments(log_w, particles, self.kernel, scratch=True)

            # line 12: resample; carry the normalised link posterior of each surviving
            # particle
            if self.resampling == "systematic" and self.kernel == "numba":
                u01 = rng.random(batch + (1,))          # the draw of resampling.systematic
                idx = np.empty(w.shape, dtype=np.int64)
                _k.systematic_indices(w.reshape(-1, k), u01.reshape(-1),
                                      idx.reshape(-1, k), CHUNK)
            else:
                idx = get_scheme(self.resampling)(w, rng)                     # (..., N, K)
            if q.strides[-2] == 0:                  # shared by every particle (Gaussian case)
                particles, _, distinct = _gather(particles, q[..., :0], idx, self.kernel, slot)
            else:
                particles, q, distinct = _gather(particles, q, idx, self.kernel, slot)
            # detection rule sum_i phi^i(z=1) > sum_i phi^i(z=0)
            los_detected = scatter_packed(valid & (post[..., 1] > post[..., 0]), links, valid,
                                          mask.shape[-1]) & mask

        # reset on degeneracy: few distinct ancestors
        reset = distinct < self.reset_fraction * k
        if np.any(reset):
            particles[reset, :, :D] = mean[reset][:, None, :D] + self.reset_std_m * \
                rng.standard_normal((int(reset.sum()), k, D))
            if post is None:                    # the bootstrap case: every link LOS
                mean_post = valid.astype(float)
            else:
                with np.errstate(invalid="ignore"):
                    mean_post = np.exp(post[..., 1] - np.logaddexp(post[..., 0], post[..., 1]))
            if not q.flags.writeable:
                q = q.copy()
            q[reset] = np.where(valid, np.nan_to_num(mean_post), 0.0)[reset][:, None, :]
        em_stats, em_steps = state.em_stats, state.em_steps
        if em:
            em_stats, em_steps, params = self._em_update(state, w, em_pp, valid, params)
        return ParticleState(particles=particles, link_los=q,
                             links=np.where(valid, links, -1), mean=mean, covariance=cov,
                             ess=ess, los_detected=los_detected, reset=reset,
                             resets=state.resets + reset, time=state.time + dt,
                             ancestors=idx, params=params, em_stats=em_stats,
                             em_steps=em_steps)

    def _bootstrap_noise(self, state, params, valid, where_prev, dt):
        """Per-coordinate noise std ``sd`` (2,) when this step is the plain bootstrap filter,
        else None: systematic resampling, no online EM, 2-D position states moved by ``x +
        u + diag(sd) z`` (:func:`_walk_noise`), and every filter in the Gaussian case (alpha
        = 1 and every carried LOS posterior of a current link 1, as ``link_weights`` tests
        it)."""
        if self.resampling != "systematic" or self.online_em is not None:
            return None
        if state.particles.shape[-1] != 2 or not np.all(params[..., 2] == 1.0):
            return None
        sd = self._walk_sd_of(dt)
        if sd is None:
            return None
        q = state.link_los
        if q.shape[-1] and valid.shape[-1]:
            if q.strides[-2] == 0:                      # one row shared by every particle
                q = q[..., :1, :]
            carried = np.broadcast_to((valid & (where_prev >= 0))[..., None, :],
                                      q.shape[:-1] + valid.shape[-1:])
            slot = np.broadcast_to(np.maximum(where_prev, 0)[..., None, :], carried.shape)
            if not np.all(np.take_along_axis(q, slot, axis=-1)[carried] == 1.0):
                return None
        return sd

    def _walk_sd_of(self, dt):
        """:func:`_walk_noise` of the motion model over ``dt`` (2-D states), cached per scalar
        ``dt`` (it depends on the motion model and ``dt`` only)."""
        if np.ndim(dt) != 0:
            return _walk_noise(self.motion, 2, dt)
        key = float(dt)
        if key not in self._walk_sd:
            if len(self._walk_sd) > 64:
                self._walk_sd.clear()
            self._walk_sd[key] = _walk_noise(self.motion, 2, dt)
        return self._walk_sd[key]

    def _params(self, state: ParticleState) -> np.ndarray:
        """``(s_LOS, s_NLOS, alpha)`` per filter, (..., N, 3)."""
        if state.params is not None:
            return state.params
        m = self.measurement
        return np.broadcast_to(np.array([m.los_std_m, m.nlos_mean_m, m.alpha]),
                               state.batch_shape + (3,))

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
        given = None
        if self.messages == "given":
            if given_positions is None:
                raise InputError("given_positions: required when messages='given'")
            given = as_float_array(given_positions, "given_positions", min_ndim=3, last_dim=2)
        state = self._init(initial, rng, t[0], scratch=self.kernel == "numba")
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
        sds = self._bootstrap_run_sd(state, dts)
        if sds is not None:
            return self._run_bootstrap(r, state, anchors_b, dts, u, given, t, sds, rng)
        if self._carried_run_ok(state):
            return self._run_carried(r, state, anchors_b, dts, u, given, t, rng)
        mask_all = ~np.isnan(r)
        estimates = []
        for k in range(T):
            uk = None if u is None else u[..., k, :]
            peers = self._peers(state.mean, dts[k], uk, given, k)
            nodes = np.concatenate([np.broadcast_to(peers, batch + (n_veh, 2)), anchors_b], axis=-2)
            mask = mask_all[..., k, :]
            nodes = np.broadcast_to(nodes[..., None, :, :], mask.shape + (2,))
            if not np.all(np.isfinite(peers)):
                _check_nodes(mask, nodes)
            state = self._step(state, r[..., k, :], mask, nodes, rng,
                               None if uk is None else uk[..., None, :], dts[k],
                               slot=f"run{k % 2}")
            estimates.append(self.estimate(state))
        return track_from_steps(estimates, t)

    def _carried_run_ok(self, state):
        """Whether :meth:`run` from ``state`` (from :meth:`init`) can take
        :meth:`_run_carried`: the compiled kernel, systematic resampling, no online EM, and
        a LOS fraction below 1 in some filter (then no step is the bootstrap case of
        :meth:`_bootstrap_noise`, whose draws differ, since the parameters do not change)."""
        return (self.kernel == "numba" and self.resampling == "systematic"
                and self.online_em is None
                and not np.all(self._params(state)[..., 2] == 1.0))

    def _run_carried(self, r, state, anchors_b, dts, u, given, t, rng):
        """:meth:`run` by the steps of :meth:`_step` with the resampling's gather left to
        the next step: each step's predicted particles, new link posteriors and resampling
        indices (ancestors) are carried; the next step gathers the particles (``n`` numbers
        per particle) before its prediction, and the link kernel reads the carried link
        posteriors through the ancestors (one pass over the posteriors per step instead of
        three). The carried posteriors are link-major, ``(B, L, K)``: the kernel copies the
        rows of existing links in and out instead of transposing ``(K, L)`` tiles, and never
        touches the padding slots. The links are packed once for every step, the inputs checked
        once, the previous slot of every link found for every step at once. The same draws
        in the same order and the same values as :meth:`step` step by step (the width of
        the packed links does not enter the kernel's arithmetic: it skips the padding; the
        gathers only copy; tests/test_p2p_step_carried.py)."""
        D = self.motion.dim
        k, n = state.particles.shape[-2:]
        batch_v, batch, b, nb, mask_all, links, valid, th, time_first = _run_layout(state, r)
        n_veh, T, J = r.shape[-3:]
        width = links.shape[-1]
        links_t, valid_t, th_t = time_first(links), time_first(valid), time_first(th)
        mask_t = time_first(mask_all)
        # slot of each link in the previous step's list (-1: new link, line 8), every step
        wp_t = np.full((T, b, width), -1, dtype=np.int64)
        if T > 1:
            prev = np.where(valid_t[:-1], links_t[:-1], -1)
            wp_t[1:] = np.where(valid_t[1:], _previous_slots(prev, links_t[1:], J), -1)
        node_rows = np.arange(nb)[:, None, None]
        links_nodes = links_t.reshape(T, nb, n_veh, width)
        params = kernel_array(self._params(state).reshape(b, 3))
        ctrl = None if u is None else u.reshape(b, T, 1, u.shape[-1])
        no_q = np.empty((b, k, 0))
        seen = _scratch("seen", (b, k), np.bool_)
        distinct = np.empty(b, dtype=np.int64)
        parts = kernel_array(state.particles.reshape(b, k, n))
        anc, q_prev = None, np.zeros((b, 0, k))        # link-major: (b, L, K)
        # random walks (x + u + diag(sd) z, see _walk_noise): the particles are gathered by
        # the next step's prediction too, so no pass of their own
        sds = [self._walk_sd_of(dt) if n == D else None for dt in dts]
        walk = all(sd is not None for sd in sds)
        no_shift = np.zeros((1, 1))
        det_t = np.empty((T, b, width), dtype=bool)
        steps = []
        mean = state.mean
        resets = state.resets
        time_now = state.time
        pending = None          # a reset not yet drawn and written (see below)
        std = float(self.reset_std_m)

        def draw_reset():
            if pending is not None:
                _fill_normal(rng, pending[0])

        def apply_reset(drawn=False):
            nonlocal pending
            if pending is not None:
                if not drawn:
                    draw_reset()
                z_r, reset_r, mean_r, rows_r, valid_r, out_r, idx_r, q_r = pending
                _k.reset_filters(reset_r, mean_r, z_r, std, D, out_r, idx_r, rows_r, valid_r,
                                 q_r)
                pending = None

        for s in range(T):
            uk = None if u is None else u[..., s, :]
            nodes = self._run_nodes(mean, dts[s], uk, given, s, anchors_b, mask_all, batch_v)
            node_xy = nodes.reshape(nb, J, 2)[node_rows, links_nodes[s]].reshape(b, width, 2)
            # line 3
            if walk:
                # the draws of _sample_motion (same call, same shape), then (x[anc] + u) +
                # sd z, its roundings
                z = _standard_normal(rng, batch_v + (k, n), scratch=True,
                                     extra=draw_reset).reshape(b, k, n)
                apply_reset(drawn=True)
                pred = _scratch(f"carried_p{s % 2}", (b, k, n))
                _k.walk_gather(parts, _NO_ANCESTORS if anc is None else anc, anc is not None,
                               no_shift if ctrl is None else kernel_array(ctrl[:, s, 0]),
                               ctrl is not None, kernel_array(sds[s]), z, pred, CHUNK)
            else:
                pred = _sample_motion(self.motion, parts.reshape(batch_v + (k, n)), dts[s], rng,
                                      None if ctrl is None else ctrl[:, s].reshape(batch_v + (1, -1)),
                                      scratch=True).reshape(b, k, n)
            # lines 6, 8, 11, the link posteriors read through the ancestors
            log_w, q, post, _, gauss = _link_update(
                pred, node_xy, th_t[s], valid_t[s], wp_t[s], q_prev, params, "numba", False,
                scratch=True, anc=anc, q_out=_scratch(f"carried_q{s % 2}", (b, width, k)),
                link_major=True)
            # line 14 and line 12 (systematic resampling; the gather is left to the next step)
            u01 = rng.random(batch_v + (1,))            # the draw of resampling.systematic
            idx = _scratch(f"carried_idx{s % 2}", (b, k), np.int64)
            one_pass = k <= CHUNK
            if one_pass:                    # one pass (the same operations as the two below)
                w = _scratch("w", (b, k))
                mean_f, cov, ess = np.empty((b, n)), np.empty((b, n, n)), np.empty(b)
                _k.moments_resample(log_w, pred, u01.reshape(-1), w, mean_f, cov, ess, idx,
                                    distinct)
            else:
                w, mean_f, cov, ess = _moments(log_w, pred, "numba", scratch=True)
                _k.systematic_indices(w, u01.reshape(-1), idx, CHUNK)
            if walk:
                # the next prediction gathers the particles; the indices are non-decreasing
                if not one_pass:
                    distinct = 1 + np.count_nonzero(idx[:, 1:] != idx[:, :-1], axis=-1)
                out = pred
            else:
                # the resampled particles (n numbers each) and the distinct ancestors; the
                # link posteriors stay unresampled
                out = _scratch(f"carried_p{s % 2}", (b, k, n))
                _k.gather_resampled(pred, no_q, idx, out, no_q, distinct, seen, CHUNK)
            # detection rule sum_i phi^i(z=1) > sum_i phi^i(z=0), scattered after the loop
            det_t[s] = valid_t[s] & (post[..., 1] > post[..., 0])
            reset = distinct < self.reset_fraction * k
            n_reset = int(np.count_nonzero(reset))
            if n_reset:
                # as in _step (each particle of a reset filter then its own ancestor; in the
                # walk case, n = D, every component is reset, so no gather is needed): the
                # draws of its rng.standard_normal((n_reset, k, D)), then the writes of its
                # reset in one pass (pf_kernels.reset_filters)
                # (numba's Generator: NumPy's numbers and state, tests/test_p2p_run_fused.py)
                # In the walk case both are left to the next step: its motion draws (the
                # children's parts on the pool) and these (rng's, on this thread) are taken
                # at once, before its walk_gather reads anything the reset writes; rng gives
                # the same numbers, since spawning children draws nothing from it.
                with np.errstate(invalid="ignore"):
                    mean_post = np.exp(post[..., 1] - np.logaddexp(post[..., 0], post[..., 1]))
                if not q.flags.writeable:
                    q = q.copy()
                pending = (_scratch("reset_z", (n_reset * k * D,)), reset, mean_f,
                           np.nan_to_num(mean_post), valid_t[s], out, idx, q)
                if not walk:
                    apply_reset()
            parts, q_prev = out, q
            anc = idx
            mean = mean_f.reshape(batch_v + (n,))
            cov = cov.reshape(batch_v + (n, n))
            resets = resets + reset.reshape(batch_v)
            time_now = time_now + dts[s]
            steps.append((mean, cov, ess.reshape(batch_v), resets, time_now))
        apply_reset()           # the last step's draws (rng's state as after step)
        los_t = (scatter_packed(det_t, links_t, valid_t, J) & mask_t).reshape((T,) + batch_v + (J,))
        estimates = [Estimate(mean[..., :D], cov[..., :D, :D], time_now,
                              {"state": mean, "state_covariance": cov, "ess": ess,
                               "los_detected": los_t[s], "resets": resets})
                     for s, (mean, cov, ess, resets, time_now) in enumerate(steps)]
        return track_from_steps(estimates, t)

    def _run_nodes(self, mean, dt, control, given, s, anchors_b, mask, batch_v):
        """Node positions ``(..., J, 2)`` of step ``s`` of :meth:`run`'s compiled paths: the
        peers of :meth:`_peers` (vehicles), then the anchors ``anchors_b``; a non-finite
        peer position that a measured link ``mask`` ``(..., N, T, J)`` uses raises (see
        :func:`_check_nodes`)."""
        peers = self._peers(mean, dt, control, given, s)
        nodes = np.concatenate([np.broadcast_to(peers, batch_v + (2,)), anchors_b],
                               axis=-2)                         # (..., J, 2)
        if not np.all(np.isfinite(peers)):
            _check_nodes(mask[..., s, :],
                         np.broadcast_to(nodes[..., None, :, :],
                                         batch_v + nodes.shape[-2:]))
        return nodes

    def _peers(self, mean, dt, control, given, k):
        """Positions vehicle ``k`` uses for its neighbours at step ``k`` of :meth:`run` (see
        ``messages``), from the estimates ``mean`` (..., N, n) of the previous step."""
        if self.messages == "previous":
            return mean[..., : self.motion.dim]
        if self.messages == "extrapolated":
            return self.motion.predict(mean, dt, control=control)[..., : self.motion.dim]
        return given[..., k, :]

    def _bootstrap_run_sd(self, state, dts):
        """The noise std of every step when every step of :meth:`run` from ``state`` (from
        :meth:`init`) is the plain bootstrap filter, else None.

        :meth:`step` takes its bootstrap case when ``_bootstrap_noise`` finds one; in a run
        without online EM the parameters do not change, the first step carries no link, and
        every bootstrap step leaves every carried LOS posterior 1 (a reset sets the mean
        posterior, 1 on every link), so the case holds at every step when it holds at the
        first and ``sd`` exists for every ``dt``."""
        if (self.kernel != "numba" or self.resampling != "systematic"
                or self.online_em is not None or state.particles.shape[-1] != 2
                or state.link_los.shape[-1] != 0 or not np.all(self._params(state)[..., 2] == 1.0)):
            return None
        sds = []
        for dt in dts:
            sd = self._walk_sd_of(dt)
            if sd is None:
                return None
            sds.append(kernel_array(sd))
        return sds

    def _run_bootstrap(self, r, state, anchors_b, dts, u, given, t, sds, rng):
        """:meth:`run` when every step is the plain bootstrap filter (see
        :meth:`_bootstrap_run_sd`): the fused kernel of :func:`_bootstrap_step` on work
        arrays reused across steps, the links packed once for every step, the results of
        each step written into the track's arrays, and the resampling's gather left to the
        next step (each step's predicted particles and ancestors carried; the next reads
        the particles through the ancestors). The same draws in the same order and the
        same values as :meth:`step` step by step (the width of the packed links does not
        enter the kernel's arithmetic: it skips the padding; the gather only copies)."""
        D = 2
        k = state.particles.shape[-2]
        batch_v, batch, b, nb, mask_all, links, valid, th, time_first = _run_layout(state, r)
        nbd = len(batch_v)
        n_veh, T, J = r.shape[-3:]
        width = links.shape[-1]
        links_t = time_first(links).reshape(T, nb, n_veh, width)
        valid_t, th_t = time_first(valid), time_first(th)
        shift_t = np.zeros((T, b, 2)) if u is None else time_first(u)
        rows = np.arange(nb)[:, None, None]
        inv_s = kernel_array(1.0 / self._params(state)[..., 0].reshape(b))
        mean_t, cov_t, ess_t = np.empty((T, b, 2)), np.empty((T, b, 2, 2)), np.empty((T, b))
        resets_t = np.empty((T,) + batch_v, dtype=np.int64)
        # work arrays of this thread, kept between runs (see _scratch): the predicted
        # particles and their ancestors, alternately written by a step and read by the next,
        # which does the gather of the resampling (the particles of the filter after step s
        # are preds[s % 2][b, idxs[s % 2][b, i]])
        preds = (_scratch("run_a", (b, k, 2)), _scratch("run_b", (b, k, 2)))
        idxs = (_scratch("run_idx", (b, k), np.int64), _scratch("run_idx_b", (b, k), np.int64))
        v = _scratch("v", (b, k))
        distinct = np.empty(b, dtype=np.int64)
        parts = kernel_array(state.particles.reshape(b, k, 2))
        anc, carried = _NO_ANCESTORS, False
        mean, resets = state.mean, state.resets
        for s in range(T):
            uk = None if u is None else u[..., s, :]
            nodes = self._run_nodes(mean, dts[s], uk, given, s, anchors_b, mask_all, batch_v)
            node_xy = nodes.reshape(nb, J, 2)[rows, links_t[s]].reshape(b, width, 2)
            key = draw_key(rng)
            u01 = rng.random(batch_v + (1,))    # the draw of resampling.systematic
            pred, idx = preds[s % 2], idxs[s % 2]
            _bs.bootstrap_step(parts, anc, carried, shift_t[s], sds[s], key, node_xy, th_t[s],
                               valid_t[s], inv_s, u01.reshape(b), CHUNK, False, _NO_PARTICLES,
                               idx, mean_t[s], cov_t[s], ess_t[s], distinct, pred, v)
            parts, anc, carried = pred, idx, True
            mean = mean_t[s].reshape(batch_v + (2,))
            # reset on degeneracy, as in step (a reset filter's particles are its predicted
            # ones, each its own ancestor)
            reset = (distinct < self.reset_fraction * k).reshape(batch_v)
            if np.any(reset):
                parts.reshape(batch_v + (k, 2))[reset, :, :D] = mean[reset][:, None, :D] + \
                    self.reset_std_m * rng.standard_normal((int(reset.sum()), k, D))
                idx.reshape(batch_v + (k,))[reset] = np.arange(k)
            resets = resets + reset
            resets_t[s] = resets

        def track_axes(a):                                      # (T, b, *x) -> (..., N, T, *x)
            return np.ascontiguousarray(np.moveaxis(a.reshape((T,) + batch_v + a.shape[2:]),
                                                    0, nbd))

        diag = {"ess": track_axes(ess_t), "los_detected": mask_all.copy(),
                "resets": np.ascontiguousarray(np.moveaxis(resets_t, 0, nbd)),
                "state": track_axes(mean_t), "state_covariance": track_axes(cov_t)}
        return Track(track_axes(mean_t), track_axes(cov_t), t, diag)
