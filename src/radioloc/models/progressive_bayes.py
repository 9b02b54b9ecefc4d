"""Progressive Bayes re-approximation of Gaussian mixtures (paper 004, reference [3]).

Paper 004 re-approximates every density it produces (the product of eq. (2), the filter
step, the prediction of Sect. 4 and the calibration model of Fig. 3) "using the Progressive
Bayes estimation" of Hanebeck, Briechle and Rauh (2003). Our reading of that framework, as
implemented here:

1. **Distance.** The approximation ``f(x; eta)`` (a mixture of ``K`` axis-aligned Gaussians
   with parameter vector ``eta``) is fitted to the true density ``t(x)`` by the integral
   squared distance ``G(eta) = 1/2 int (t(x) - f(x; eta))^2 dx``. For Gaussian mixtures it
   has a closed form, since ``int N(x; a, A) N(x; b, B) dx = N(a; b, A + B)``:
   ``2 G = sum_ij w_i w_j N(m_i; m_j, V_i + V_j) - 2 sum_il w_i t_l N(m_i; tau_l, V_i + T_l)
   + sum_lk t_l t_k N(tau_l; tau_k, T_l + T_k)`` (:func:`isd`, :func:`inner`).
2. **Progression.** Minimising ``G`` directly gets stuck in local minima, so [3] embeds the
   problem in a homotopy: a progression parameter ``gamma`` runs from 0 to 1, the target
   ``t(x, gamma)`` goes from a density whose approximation is known exactly (``G = 0``) to
   the true one, and ``eta(gamma)`` follows the minimum. The necessary condition
   ``dG/deta = 0`` holds for every ``gamma``; differentiating it in ``gamma`` gives the
   system of ordinary differential equations ``P(eta) deta/dgamma = b(eta, gamma)`` with
   ``P = int (df/deta)(df/deta)^T dx`` and ``b = int (df/deta) (dt/dgamma) dx`` (the term
   ``int (f - t) d^2f/deta^2 dx``, zero where the approximation is exact, is dropped: the
   Gauss-Newton form). Both have closed forms here (:func:`gram`, :func:`cross_gradient`).
3. **Our progression for mixture targets.** [3] progresses the likelihood (``prior x
   likelihood^gamma``); the power of a mixture likelihood is not a mixture, so for a mixture
   target ``T`` we progress linearly from the start approximation ``f0``:
   ``t(x, gamma) = (1 - gamma) f0(x) + gamma T(x)``, ``dt/dgamma = T - f0``. The start
   ``f0`` is West's greedy reduction with Runnalls' cost (:func:`radioloc.models.mixture.reduce`),
   where ``G(eta0, 0) = 0`` exactly. The ODE is integrated in ``steps`` Euler predictor
   steps, each followed by ``corrector`` Levenberg-Marquardt (damped Gauss-Newton) steps on
   ``G(., gamma)``, and ``polish`` more at ``gamma = 1``; a step is kept only where it lowers
   ``G``. Finally, per mixture, the result is kept only if its ISD to ``T`` is not above the
   start's (it never is on the random mixtures of the tests; the guard makes the bound
   "never worse than West/Runnalls at the same component count" hold by construction).
4. **Parameters.** ``eta`` holds per component the softmax logit of the weight (weights stay
   positive and sum to one), the means and the log-variances, clipped to 100 times below
   the smallest and above the largest variance of the target.

Everything is batched over the leading axes of the mixtures; the loops are over the
progression steps only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import InputError
from radioloc.models.mixture import DiagMixture, compact, pad_components, reduce, select

_LOG2PI = float(np.log(2.0 * np.pi))


def _pair(m1, v1, m2, v2, order: int):
    """Log overlaps ``log N(m1_i; m2_j, V1_i + V2_j)`` ``(..., K1, K2)`` and the derivative
    ratios ``h[..., i, j, d, n] = (d^n phi / d delta^n) / phi`` of the 1-D factors,
    ``n = 0..order``, ``delta = m1 - m2``, ``phi = N(delta; 0, s)``, ``s = v1 + v2``.

    ``h_n = (-1/sqrt(s))^n He_n(delta / sqrt(s))`` (Hermite polynomials); their recurrence
    ``He_{n+1}(u) = u He_n(u) - n He_{n-1}(u)`` gives
    ``h_{n+1} = -(delta / s) h_n - (n / s) h_{n-1}``, ``h_0 = 1``, ``h_1 = -delta / s``."""
    delta = m1[..., :, None, :] - m2[..., None, :, :]
    s = v1[..., :, None, :] + v2[..., None, :, :]
    logo = -0.5 * np.sum(delta**2 / s + np.log(s) + _LOG2PI, axis=-1)
    inv = 1.0 / s
    h = np.empty(delta.shape + (order + 1,))
    h[..., 0] = 1.0
    if order >= 1:
        h[..., 1] = -delta * inv
    for n in range(1, order):
        h[..., n + 1] = h[..., 1] * h[..., n] - n * inv * h[..., n - 1]
    return logo, h


def inner(a_w, a_m, a_v, b_w, b_m, b_v) -> np.ndarray:
    """``int f_a(x) f_b(x) dx`` of two batches of axis-aligned mixtures (closed form).

    Parameters
    ----------
    a_w, b_w : ndarray, shape (..., Ka), (..., Kb)
        Weights.
    a_m, b_m : ndarray, shape (..., Ka, D), (..., Kb, D)
        Means.
    a_v, b_v : ndarray, shape (..., Ka, D), (..., Kb, D)
        Per-axis variances.

    Returns
    -------
    ndarray, shape (...)
        ``sum_ij a_i b_j N(m_i; m_j, V_i + V_j)``.
    """
    delta = a_m[..., :, None, :] - b_m[..., None, :, :]
    s = a_v[..., :, None, :] + b_v[..., None, :, :]
    logo = -0.5 * np.sum(delta**2 / s + np.log(s) + _LOG2PI, axis=-1)
    return np.einsum("...i,...ij,...j->...", a_w, np.exp(logo), b_w)


def isd(a, b) -> np.ndarray:
    """Integral squared distance ``int (f_a - f_b)^2 dx`` between two batches of mixtures.

    Parameters
    ----------
    a, b : DiagMixture
        Batches of the same dimension (batch axes broadcast).

    Returns
    -------
    ndarray, shape (...)
        The distance (>= 0 up to rounding).
    """
    if a.dim != b.dim:
        raise InputError(f"isd: dimensions differ ({a.dim} and {b.dim})")
    aa = inner(a.weights, a.means, a.variances, a.weights, a.means, a.variances)
    bb = inner(b.weights, b.means, b.variances, b.weights, b.means, b.variances)
    ab = inner(a.weights, a.means, a.variances, b.weights, b.means, b.variances)
    return aa + bb - 2.0 * ab


def _orders(dim: int) -> np.ndarray:
    """Derivative order per coordinate of each parameter of a component: the weight (0),
    the means (1 on their axis), the log-variances (2 on their axis: heat equation)."""
    eye = np.eye(dim, dtype=int)
    return np.vstack([np.zeros((1, dim), int), eye, 2 * eye])


def _coef(w, v, sign_mean: float):
    """Factors ``A[..., i, a]`` that turn overlap derivatives into parameter derivatives:
    1 for the weight, ``sign w_i`` for a mean, ``w_i v_ip / 2`` for a log-variance."""
    wb = np.broadcast_to(w[..., None], v.shape)
    return np.concatenate([np.ones(w.shape + (1,)), sign_mean * wb, 0.5 * wb * v], axis=-1)


def cross_gradient(w, m, v, t_w, t_m, t_v) -> np.ndarray:
    """Gradient of ``int f(x; theta) g(x) dx`` in the raw parameters ``theta`` of ``f``.

    ``theta`` per component: weight, means (D), log-variances (D). With
    ``phi = N(m_i - tau_l; 0, V_i + T_l)`` and ``d/d log v = v d/ds = (v / 2) d^2/d delta^2``
    (the heat equation), every derivative is a Hermite polynomial times the overlap.

    Parameters
    ----------
    w, m, v : ndarray, shapes (..., K), (..., K, D), (..., K, D)
        The approximating mixture ``f``.
    t_w, t_m, t_v : ndarray, shapes (..., L), (..., L, D), (..., L, D)
        The other mixture ``g``.

    Returns
    -------
    ndarray, shape (..., K, 1 + 2 D)
        ``d/dtheta int f g dx``.
    """
    d = m.shape[-1]
    o = _orders(d)
    logo, h = _pair(m, v, t_m, t_v, 2)
    ov = np.exp(logo) * t_w[..., None, :]                                 # (..., K, L)
    hh = np.prod(h[..., np.arange(d), o], axis=-1)                       # (..., K, L, Q)
    return np.einsum("...il,...ila->...ia", ov, hh) * _coef(w, v, 1.0)


def gram(w, m, v) -> np.ndarray:
    """``P = int (df/dtheta)(df/dtheta)^T dx`` in the raw parameters (closed form).

    Parameters
    ----------
    w, m, v : ndarray, shapes (..., K), (..., K, D), (..., K, D)
        The mixture.

    Returns
    -------
    ndarray, shape (..., K (1 + 2 D), K (1 + 2 D))
        Component-major order: per component the weight, the means, the log-variances.
    """
    k, d = m.shape[-2], m.shape[-1]
    o = _orders(d)
    q = o.shape[0]
    logo, h = _pair(m, v, m, v, 4)
    idx = o[:, None, :] + o[None, :, :]                                  # (Q, Q, D)
    hh = np.prod(h[..., np.arange(d), idx], axis=-1)                     # (..., K, K, Q, Q)
    hh *= np.exp(logo)[..., None, None]
    hh *= _coef(w, v, 1.0)[..., :, None, :, None]
    hh *= _coef(w, v, -1.0)[..., None, :, None, :]
    p = np.swapaxes(hh, -3, -2)                                          # (..., i, a, j, b)
    return p.reshape(p.shape[:-4] + (k * q, k * q))


def _flat(shape, *arrays):
    """Broadcast to the batch ``shape`` and flatten the batch axes (contiguous float64)."""
    out = []
    for a, tail in arrays:
        a = np.broadcast_to(a, shape + a.shape[a.ndim - tail:])
        out.append(np.ascontiguousarray(a.reshape((-1,) + a.shape[len(shape):]), dtype=float))
    return out


@dataclass(frozen=True)
class ProgressionInfo:
    """Diagnostics of :func:`progressive_reduce`.

    Attributes
    ----------
    isd_start : ndarray, shape (...)
        ISD of the start approximation (West/Runnalls) to the target.
    isd : ndarray, shape (...)
        ISD of the returned approximation to the target.
    kept_start : ndarray of bool, shape (...)
        Where the progression did not lower the ISD and the start was returned.
    reduced : ndarray of bool, shape (...)
        Where the target had more than ``k`` components (elsewhere it is returned as is).
    """

    isd_start: np.ndarray
    isd: np.ndarray
    kept_start: np.ndarray
    reduced: np.ndarray


class _Fit:
    """Parameter handling of one batch of K-component approximations."""

    def __init__(self, target, lo, hi):
        self.t = target
        self.lo, self.hi = lo, hi

    @staticmethod
    def unpack(eta, k, d):
        e = eta.reshape(eta.shape[:-1] + (k, 1 + 2 * d))
        logit = e[..., 0]
        w = np.exp(logit - logit.max(-1, keepdims=True))
        w = w / w.sum(-1, keepdims=True)
        return w, np.ascontiguousarray(e[..., 1:1 + d]), np.exp(e[..., 1 + d:])

    def clip(self, eta, k, d):
        e = eta.reshape(eta.shape[:-1] + (k, 1 + 2 * d)).copy()
        e[..., 1 + d:] = np.clip(e[..., 1 + d:], self.lo[..., None, None], self.hi[..., None, None])
        e[..., 0] = e[..., 0] - e[..., 0].max(-1, keepdims=True)
        e[..., 0] = np.maximum(e[..., 0], -700.0)
        return e.reshape(eta.shape)

    def to_eta(self, w, m, v):
        logit = np.log(np.maximum(w, 1e-300))
        return np.concatenate([logit[..., None], m, np.log(v)], -1).reshape(w.shape[:-1] + (-1,))


def _chain_rule(w, g, p, q):
    """Raw (weight) parameters to softmax logits: gradient and Gram matrix."""
    k = w.shape[-1]
    jw = w[..., :, None] * (np.eye(k) - w[..., None, :])                # dw_k/dalpha_i: (k, i)
    n = k * q
    tmat = np.broadcast_to(np.eye(n), w.shape[:-1] + (n, n)).copy()
    wi = np.arange(k) * q
    tmat[..., wi[:, None], wi[None, :]] = jw
    gflat = g.reshape(g.shape[:-2] + (n,))
    tt = np.swapaxes(tmat, -1, -2)
    geta = (tt @ gflat[..., None])[..., 0]
    peta = tt @ p @ tmat
    return geta, peta


def progressive_reduce(target, k: int, start=None, steps: int = 4, corrector: int = 1,
                       polish: int = 4, return_info: bool = False,
                       backend: str = DEFAULT_BACKEND):
    """Progressive Bayes re-approximation of mixtures by ``k`` components (ISD homotopy).

    Parameters
    ----------
    target : DiagMixture
        The true densities (any number of components, batch axes leading).
    k : int
        Components of the approximation, >= 1.
    start : DiagMixture, optional
        The exact approximation at ``gamma = 0`` (at most ``k`` components, same batch).
        Default: West/Runnalls reduction of ``target`` to ``k`` components.
    steps : int
        Euler predictor steps of the progression ``gamma = 0 -> 1`` (>= 1).
    corrector : int
        Levenberg-Marquardt corrector steps after each predictor step (>= 0).
    polish : int
        Further corrector steps at ``gamma = 1`` (>= 0).
    return_info : bool
        Also return a :class:`ProgressionInfo`.
    backend : str
        ``"numba"`` (default): the overlaps, gradients and Gram matrices of each step by the
        compiled kernels of :mod:`radioloc.models.mixture_compiled`; ``"numpy"``:
        :func:`inner`, :func:`cross_gradient` and :func:`gram`. Also the backend of the
        default start's West/Runnalls reduction.

    Returns
    -------
    DiagMixture
        At most ``k`` components per mixture; the target itself where it has at most ``k``.
    ProgressionInfo
        Only with ``return_info``.
    """
    if isinstance(k, bool) or int(k) != k or int(k) < 1:
        raise InputError(f"max_components: must be an integer >= 1, got {k!r}")
    for name, val, low in (("steps", steps, 1), ("corrector", corrector, 0),
                           ("polish", polish, 0)):
        if isinstance(val, bool) or int(val) != val or int(val) < low:
            raise InputError(f"{name}: must be an integer >= {low}, got {val!r}")
    k = int(k)
    backend = check_backend(backend)
    tgt = compact(target)
    active = np.sum(tgt.weights > 0, axis=-1)
    need = active > k
    if start is None:
        start = reduce(tgt, k, backend=backend)
    start = pad_components(start, k)
    if start.n_components > k:
        start = compact(start)
        if start.n_components > k:
            raise InputError(f"start: has more than {k} components")
    if not np.any(need):
        out = tgt                                   # at most k components everywhere
        if return_info:
            z = np.zeros(tgt.batch_shape)
            return out, ProgressionInfo(z, z, np.zeros(tgt.batch_shape, bool), need)
        return out
    d = tgt.dim
    shape = np.broadcast_shapes(tgt.batch_shape, start.batch_shape)
    tw, tm, tv, sw, sm, sv = _flat(shape, (tgt.weights, 1), (tgt.means, 2), (tgt.variances, 2),
                                   (start.weights, 1), (start.means, 2), (start.variances, 2))
    need_all = np.broadcast_to(need, shape).reshape(-1)
    rows = np.flatnonzero(need_all)                 # only these mixtures are re-approximated
    tw, tm, tv, sw, sm, sv = (a[rows] for a in (tw, tm, tv, sw, sm, sv))
    logv = np.log(np.where(tw[..., None] > 0, tv, np.nan))
    lo = np.nanmin(logv, axis=(-2, -1)) - np.log(100.0)
    hi = np.nanmax(logv, axis=(-2, -1)) + np.log(100.0)
    mean = np.einsum("bk,bkd->bd", tw, tm)
    spread = np.einsum("bk,bkd->bd", tw, (tm - mean[:, None, :]) ** 2)
    hi = np.maximum(hi, np.log(np.maximum(spread.max(-1), 1e-300)) + np.log(100.0))
    fit = _Fit(tgt, lo, hi)
    eta = fit.clip(fit.to_eta(sw, sm, sv), k, d)

    q = 1 + 2 * d
    if backend == "numba":
        from radioloc.models import mixture_compiled as mc
        inner_, cross_, gram_ = mc.pb_inner, mc.pb_cross_gradient, mc.pb_gram
    else:
        inner_, cross_, gram_ = inner, cross_gradient, gram

    def objective(eta_, gamma):
        """``2 G(eta, gamma) - int t^2``: ``int f^2 - 2 int f t_gamma``."""
        w, m, v = _Fit.unpack(eta_, k, d)
        return inner_(w, m, v, w, m, v) - 2.0 * ((1.0 - gamma) * inner_(w, m, v, sw, sm, sv)
                                                 + gamma * inner_(w, m, v, tw, tm, tv))

    def system(eta_, c_ff, c_0, c_t):
        """Gradient ``c_ff g(f) + c_0 g(f0) + c_t g(T)`` of ``int f g`` and the Gram matrix,
        in the softmax-logit parameters."""
        w, m, v = _Fit.unpack(eta_, k, d)
        g = sum(c * cross_(w, m, v, *other) for c, other in
                ((c_ff, (w, m, v)), (c_0, (sw, sm, sv)), (c_t, (tw, tm, tv))) if c != 0.0)
        return _chain_rule(w, g, gram_(w, m, v), q)

    def solve(p, rhs, lam):
        diag = np.diagonal(p, axis1=-2, axis2=-1)
        scale = diag + 1e-9 * np.max(diag, axis=-1, keepdims=True) + 1e-300
        a = p + (lam[..., None] * scale)[..., :, None] * np.eye(p.shape[-1])
        for extra in (0.0, 1e-6, 1e-2):
            try:
                b = a + extra * np.max(scale, axis=-1)[..., None, None] * np.eye(a.shape[-1])
                return np.linalg.solve(b, rhs[..., None])[..., 0]
            except np.linalg.LinAlgError:
                continue
        return np.zeros_like(rhs)                   # no step (rejected by the caller)

    lam = np.full(rows.size, 1e-3)
    cur = objective(eta, 0.0)

    def correct(eta_, cur_, lam_, gamma, n_iter):
        for _ in range(n_iter):
            geta, peta = system(eta_, 1.0, -(1.0 - gamma), -gamma)
            cand = fit.clip(eta_ - solve(peta, geta, lam_), k, d)
            val = objective(cand, gamma)
            ok = np.isfinite(val) & (val < cur_)
            eta_ = np.where(ok[:, None], cand, eta_)
            cur_ = np.where(ok, val, cur_)
            lam_ = np.where(ok, np.maximum(lam_ / 3.0, 1e-9), np.minimum(lam_ * 10.0, 1e6))
        return eta_, cur_, lam_

    for n in range(1, int(steps) + 1):
        g0, g1 = (n - 1) / steps, n / steps
        # predictor: P deta/dgamma = b, b = int (df/deta)(T - f0) dx
        geta, peta = system(eta, 0.0, -1.0, 1.0)
        pred = fit.clip(eta + (g1 - g0) * solve(peta, geta, lam), k, d)
        stay = objective(eta, g1)
        moved = objective(pred, g1)
        ok = np.isfinite(moved) & (moved < stay)
        eta = np.where(ok[:, None], pred, eta)
        cur = np.where(ok, moved, stay)
        eta, cur, lam = correct(eta, cur, lam, g1, int(corrector))
    eta, cur, lam = correct(eta, cur, lam, 1.0, int(polish))

    w, m, v = _Fit.unpack(eta, k, d)
    tt = inner_(tw, tm, tv, tw, tm, tv)
    isd_new = inner_(w, m, v, w, m, v) - 2 * inner_(w, m, v, tw, tm, tv) + tt
    isd_start = inner_(sw, sm, sv, sw, sm, sv) - 2 * inner_(sw, sm, sv, tw, tm, tv) + tt
    better = isd_new <= isd_start
    w = np.where(better[:, None], w, sw)
    m = np.where(better[:, None, None], m, sm)
    v = np.where(better[:, None, None], v, sv)
    # scatter back; where no reduction was needed the (compacted) target is kept
    nb = need_all.size
    ow, om, ov = (a.copy() for a in _flat(shape, (start.weights, 1), (start.means, 2),
                                          (start.variances, 2)))
    ow[rows], om[rows], ov[rows] = w / w.sum(-1, keepdims=True), m, v
    out = DiagMixture(ow.reshape(shape + (k,)), om.reshape(shape + (k, d)),
                      ov.reshape(shape + (k, d)))
    if not np.all(need_all):
        out = compact(select(need_all.reshape(shape), out, tgt))
    if return_info:
        i_start, i_fin, kept = np.zeros(nb), np.zeros(nb), np.zeros(nb, bool)
        i_start[rows], i_fin[rows] = isd_start, np.where(better, isd_new, isd_start)
        kept[rows] = ~better
        return out, ProgressionInfo(i_start.reshape(shape), i_fin.reshape(shape),
                                    kept.reshape(shape), need_all.reshape(shape))
    return out
