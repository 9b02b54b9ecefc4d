"""Axis-aligned Gaussian mixtures with leading batch axes (paper 004, eq. (1), eq. (2)).

A :class:`DiagMixture` holds ``weights`` ``(..., K)``, ``means`` ``(..., K, D)`` and
``variances`` ``(..., K, D)``; every leading axis is an independent mixture (a Monte Carlo
run, a base station, a measurement row). All operations act on the whole batch at once:

- :meth:`DiagMixture.logpdf` evaluation;
- :meth:`DiagMixture.condition` on one coordinate (the signal strength ``m``) in closed
  form, which for axis-aligned components only re-weights them (Sect. 3.2);
- :func:`product` of two mixtures (the product of eq. (2), renormalised);
- :func:`convolve` (density of a sum of independent variables, the prediction step);
- :func:`reduce` to a bounded number of components by West's greedy rule with Runnalls'
  merge cost, merging by moment matching (``method="runnalls"``), or by the Progressive
  Bayes ISD homotopy of :mod:`radioloc.models.progressive_bayes` (``method="progressive"``);
- :func:`pad_components` and :func:`select` to combine batches of mixtures with different
  component counts.

Moment-preserving merge on axis-aligned components: the merged component keeps the total
weight, the mean and the per-axis variances (the diagonal of the covariance) of what it
merges. The cross-covariances between axes that the spread of the merged means creates are
dropped so that components stay axis-aligned as eq. (1) requires; the merge is therefore
exact in mass, mean and diagonal covariance, and an approximation in the off-diagonal terms.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange
from scipy.special import logsumexp, softmax

from radioloc.core import fdlibm as fdl
from radioloc.core.arrays import kernel_array
from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array

_LOG2PI = np.log(2.0 * np.pi)

#: relative tolerance under which two weights or two merge costs count as tied in
#: :func:`reduce` (ties broken by the components' contents, whatever the rounding).
_TIE = 1e-9
#: smallest variance :meth:`DiagMixture.create` accepts (squared distances over it stay
#: far from float64 overflow)
_VARIANCE_FLOOR = 1e-60


@dataclass(frozen=True)
class DiagMixture:
    """A batch of Gaussian mixtures with axis-aligned components, eq. (1).

    Parameters
    ----------
    weights : ndarray, shape (..., K)
        Non-negative component weights; each mixture's weights sum to one (zero weights
        mark unused slots).
    means : ndarray, shape (..., K, D)
        Component means.
    variances : ndarray, shape (..., K, D)
        Positive per-axis variances.
    """

    weights: np.ndarray
    means: np.ndarray
    variances: np.ndarray

    @classmethod
    def create(cls, weights, means, variances, normalize: bool = True) -> "DiagMixture":
        """Validated constructor.

        Parameters
        ----------
        weights : array_like, shape (..., K)
            Non-negative weights, a positive total per mixture.
        means : array_like, shape (..., K, D)
            Finite component means.
        variances : array_like, shape (..., K, D)
            Positive per-axis variances.
        normalize : bool
            Rescale the weights of each mixture to sum to one.

        Returns
        -------
        DiagMixture
            The validated mixture batch.
        """
        m = as_float_array(means, "means", min_ndim=2)
        v = as_float_array(variances, "variances", min_ndim=2)
        w = as_float_array(weights, "weights", min_ndim=1, nonnegative=True)
        if v.shape != m.shape:
            raise InputError(f"variances: shape {v.shape} differs from means {m.shape}")
        if w.shape != m.shape[:-1]:
            raise InputError(f"weights: shape {w.shape} does not match means {m.shape[:-1]}")
        if np.any(v <= 0):
            raise InputError("variances: must be > 0")
        if np.any(v < _VARIANCE_FLOOR):
            idx = tuple(int(i) for i in np.argwhere(v < _VARIANCE_FLOOR)[0])
            raise InputError(f"variances: {v[idx]:g} at index {idx} is below the supported "
                             f"floor of {_VARIANCE_FLOOR:g} (its inverse would overflow)")
        total = w.sum(axis=-1, keepdims=True)
        if np.any(total <= 0):
            raise InputError("weights: every mixture needs a positive total weight")
        return cls(w / total if normalize else w, m, v)

    @property
    def n_components(self) -> int:
        """Number of component slots K (zero-weight slots included)."""
        return self.weights.shape[-1]

    @property
    def dim(self) -> int:
        """Dimension D of the variable."""
        return self.means.shape[-1]

    @property
    def batch_shape(self) -> tuple[int, ...]:
        """The leading (batch) axes."""
        return self.weights.shape[:-1]

    def __getitem__(self, index) -> "DiagMixture":
        """Index the batch axes (not the component axis).

        Parameters
        ----------
        index : int, slice or tuple
            Index into the batch axes.

        Returns
        -------
        DiagMixture
            The selected mixtures.
        """
        if not self.batch_shape:
            raise InputError("index: this mixture has no batch axes")
        return DiagMixture(self.weights[index], self.means[index], self.variances[index])

    def logpdf(self, points) -> np.ndarray:
        """Log density of each mixture at a set of points.

        Parameters
        ----------
        points : array_like, shape (..., P, D)
            Evaluation points; batch axes broadcast against the mixture's.

        Returns
        -------
        ndarray, shape (..., P)
            Log densities.
        """
        x = as_float_array(points, "points", min_ndim=2, last_dim=self.dim)
        diff = x[..., :, None, :] - self.means[..., None, :, :]          # (..., P, K, D)
        v = self.variances[..., None, :, :]
        comp = -0.5 * np.sum(diff**2 / v + np.log(v) + _LOG2PI, axis=-1)
        with np.errstate(divide="ignore"):
            logw = np.log(self.weights)[..., None, :]
        return logsumexp(comp + logw, axis=-1)

    def pdf(self, points) -> np.ndarray:
        """Density at ``points``.

        Parameters
        ----------
        points : array_like, shape (..., P, D)
            Evaluation points.

        Returns
        -------
        ndarray, shape (..., P)
            ``exp(logpdf(points))``.
        """
        return np.exp(self.logpdf(points))

    def moments(self) -> tuple[np.ndarray, np.ndarray]:
        """First two moments of each mixture.

        Returns
        -------
        mean : ndarray, shape (..., D)
            Mixture mean.
        covariance : ndarray, shape (..., D, D)
            Full mixture covariance (spread of the means plus the component variances).
        """
        w = self.weights[..., None]
        mean = np.sum(w * self.means, axis=-2)
        d = self.means - mean[..., None, :]
        cov = np.einsum("...k,...ki,...kj->...ij", self.weights, d, d)
        cov = cov + np.einsum("...k,...ki->...i", self.weights, self.variances)[..., None] \
            * np.eye(self.dim)
        return mean, cov

    def marginal(self, dims) -> "DiagMixture":
        """The marginal over some coordinates (exact for axis-aligned components).

        Parameters
        ----------
        dims : int or sequence of int
            Coordinates kept.

        Returns
        -------
        DiagMixture
            Same weights, the kept coordinates of the means and variances.
        """
        dims = list(np.atleast_1d(dims))
        return DiagMixture(self.weights, self.means[..., dims], self.variances[..., dims])

    def condition(self, dim: int, value, valid=None) -> "DiagMixture":
        """Condition on coordinate ``dim`` equal to ``value`` ``(...)``, in closed form.

        For axis-aligned components ``N(x)N(y)N(m)``, ``D(x, y | m)`` is the mixture of the
        remaining factors with weights ``w_j N(m; mu_mj, s_mj^2)`` renormalised (the section
        of eq. (1) used in Sect. 3.2). Where ``valid`` is False the marginal is returned.

        Parameters
        ----------
        dim : int
            The coordinate conditioned on (the signal strength is the last one).
        value : array_like, shape (...)
            Its value per mixture (batch axes broadcast).
        valid : array_like of bool, shape (...), optional
            False where there is no value (the marginal is returned there).

        Returns
        -------
        DiagMixture
            Dimension ``D - 1``: the conditional densities.
        """
        value = np.asarray(value, dtype=float)
        mu = self.means[..., dim]
        var = self.variances[..., dim]
        loglik = -0.5 * ((value[..., None] - mu) ** 2 / var + np.log(var) + _LOG2PI)
        if valid is not None:
            loglik = np.where(np.asarray(valid)[..., None], loglik, 0.0)
        weights = _normalized_exp(_safe_log(self.weights) + loglik)
        keep = [d for d in range(self.dim) if d != dim]
        return DiagMixture(weights, self.means[..., keep], self.variances[..., keep])


def _safe_log(w: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return np.log(w)


def _normalized_exp(logw: np.ndarray) -> np.ndarray:
    """``exp(logw)`` normalised along the last axis (scipy's softmax); a mixture whose
    log-weights are all ``-inf`` or NaN has lost its mass and raises."""
    ok = np.isfinite(np.max(logw, axis=-1)) & ~np.any(np.isnan(logw), axis=-1)
    if not np.all(ok):
        raise InputError("weights: a mixture lost all its mass (disjoint densities)")
    return softmax(logw, axis=-1)


def product(a: DiagMixture, b: DiagMixture) -> DiagMixture:
    """Normalised product ``c a(x) b(x)`` of two batches of mixtures (eq. (2)).

    Component pairs ``(i, j)`` give ``K_a K_b`` components with variance
    ``(1/v_i + 1/v_j)^-1``, mean ``v (mu_i/v_i + mu_j/v_j)`` and weight
    ``w_i w_j N(mu_i; mu_j, v_i + v_j)``.

    Parameters
    ----------
    a, b : DiagMixture
        Batches of the same dimension (batch axes broadcast).

    Returns
    -------
    DiagMixture
        ``K_a K_b`` components per mixture, weights renormalised.
    """
    if a.dim != b.dim:
        raise InputError(f"product: dimensions differ ({a.dim} and {b.dim})")
    vi, vj = a.variances[..., :, None, :], b.variances[..., None, :, :]
    mi, mj = a.means[..., :, None, :], b.means[..., None, :, :]
    s = vi + vj
    var = vi * vj / s
    mean = (mi * vj + mj * vi) / s
    logc = -0.5 * np.sum((mi - mj) ** 2 / s + np.log(s) + _LOG2PI, axis=-1)
    logw = _safe_log(a.weights)[..., :, None] + _safe_log(b.weights)[..., None, :] + logc
    shape = np.broadcast_shapes(mean.shape[:-3], logw.shape[:-2])
    k = a.n_components * b.n_components
    mean = np.broadcast_to(mean, shape + mean.shape[-3:]).reshape(shape + (k, a.dim))
    var = np.broadcast_to(var, shape + var.shape[-3:]).reshape(shape + (k, a.dim))
    logw = np.broadcast_to(logw, shape + logw.shape[-2:]).reshape(shape + (k,))
    return DiagMixture(_normalized_exp(logw), mean, var)


def product_on(a: DiagMixture, b: DiagMixture, dims) -> DiagMixture:
    """Normalised product ``c a(x) b(x[dims])`` where ``b`` depends on some coordinates only
    (a position likelihood times a (position, velocity) density).

    On the coordinates ``dims`` the component pairs combine as in :func:`product`; the
    other coordinates keep ``a``'s means and variances (``b`` is flat along them).

    Parameters
    ----------
    a : DiagMixture
        Batch of dimension ``D``.
    b : DiagMixture
        Batch of dimension ``len(dims)`` (batch axes broadcast).
    dims : sequence of int
        The coordinates of ``a`` that ``b`` is a density of.

    Returns
    -------
    DiagMixture
        ``K_a K_b`` components per mixture, dimension ``D``.
    """
    dims = [int(i) for i in np.atleast_1d(dims)]
    if len(dims) != b.dim or any(i < 0 or i >= a.dim for i in dims):
        raise InputError(f"dims: {dims} do not match dimensions {a.dim} and {b.dim}")
    part = product(a.marginal(dims), b)
    shape = part.batch_shape
    k = part.n_components
    mean = np.repeat(np.broadcast_to(a.means, shape + a.means.shape[-2:]), b.n_components, -2)
    var = np.repeat(np.broadcast_to(a.variances, shape + a.variances.shape[-2:]),
                    b.n_components, -2)
    mean, var = mean.copy(), var.copy()
    mean[..., dims] = part.means
    var[..., dims] = part.variances
    assert mean.shape[-2] == k
    return DiagMixture(part.weights, mean, var)


def outer(a: DiagMixture, b: DiagMixture) -> DiagMixture:
    """Joint density of independent variables: ``a`` on the first coordinates, ``b`` on the
    next ones.

    Parameters
    ----------
    a, b : DiagMixture
        Batches (batch axes broadcast).

    Returns
    -------
    DiagMixture
        ``K_a K_b`` components, dimension ``D_a + D_b``.
    """
    w = a.weights[..., :, None] * b.weights[..., None, :]
    shape = w.shape[:-2]
    ka, kb = a.n_components, b.n_components
    ma = np.broadcast_to(a.means[..., :, None, :], shape + (ka, kb, a.dim))
    mb = np.broadcast_to(b.means[..., None, :, :], shape + (ka, kb, b.dim))
    va = np.broadcast_to(a.variances[..., :, None, :], shape + (ka, kb, a.dim))
    vb = np.broadcast_to(b.variances[..., None, :, :], shape + (ka, kb, b.dim))
    d = a.dim + b.dim
    return DiagMixture(w.reshape(shape + (ka * kb,)),
                       np.concatenate([ma, mb], -1).reshape(shape + (ka * kb, d)),
                       np.concatenate([va, vb], -1).reshape(shape + (ka * kb, d)))


def linear_predict(mix: DiagMixture, F, Q) -> DiagMixture:
    """Each component through a linear-Gaussian transition ``x' = F x + w``, ``w ~ N(0, Q)``,
    kept axis-aligned: mean ``F mu``, variances ``diag(F diag(v) F^T + Q)`` (the
    cross-covariances the transition creates are dropped, as in the merge of :func:`reduce`).

    Parameters
    ----------
    mix : DiagMixture
        Batch of dimension ``n``.
    F, Q : array_like, shape (n, n)
        Transition matrix and process-noise covariance.

    Returns
    -------
    DiagMixture
        Same weights.
    """
    F, Q = np.asarray(F, float), np.asarray(Q, float)
    mean = mix.means @ F.T
    var = mix.variances @ (F.T ** 2) + np.diagonal(Q)
    return DiagMixture(mix.weights, mean, var)


def convolve(a: DiagMixture, b: DiagMixture) -> DiagMixture:
    """Density of the sum of independent variables with densities ``a`` and ``b``
    (the prediction integral of Sect. 4 with a mixture transition density).

    Parameters
    ----------
    a, b : DiagMixture
        Batches of the same dimension (batch axes broadcast).

    Returns
    -------
    DiagMixture
        ``K_a K_b`` components per mixture.
    """
    if a.dim != b.dim:
        raise InputError(f"convolve: dimensions differ ({a.dim} and {b.dim})")
    mean = a.means[..., :, None, :] + b.means[..., None, :, :]
    var = a.variances[..., :, None, :] + b.variances[..., None, :, :]
    w = a.weights[..., :, None] * b.weights[..., None, :]
    shape = np.broadcast_shapes(mean.shape[:-3], w.shape[:-2])
    k = a.n_components * b.n_components
    return DiagMixture(
        np.broadcast_to(w, shape + w.shape[-2:]).reshape(shape + (k,)),
        np.broadcast_to(mean, shape + mean.shape[-3:]).reshape(shape + (k, a.dim)),
        np.broadcast_to(var, shape + var.shape[-3:]).reshape(shape + (k, a.dim)))


def merge_moments(w1, m1, v1, w2, m2, v2):
    """Moment-matched merge of two axis-aligned components.

    Parameters
    ----------
    w1, w2 : ndarray, shape (...)
        Weights.
    m1, m2 : ndarray, shape (..., D)
        Means.
    v1, v2 : ndarray, shape (..., D)
        Per-axis variances.

    Returns
    -------
    w : ndarray, shape (...)
        Total weight.
    m : ndarray, shape (..., D)
        Mean of the two-component mixture.
    v : ndarray, shape (..., D)
        Its per-axis variances.
    """
    w = w1 + w2
    safe = np.where(w > 0, w, 1.0)[..., None]
    a1, a2 = w1[..., None] / safe, w2[..., None] / safe
    m = a1 * m1 + a2 * m2
    v = a1 * (v1 + (m1 - m) ** 2) + a2 * (v2 + (m2 - m) ** 2)
    return w, m, v


def runnalls_cost(w1, m1, v1, w2, m2, v2) -> np.ndarray:
    """Runnalls' (2007) upper bound on the KL divergence caused by merging two components:
    ``0.5 [(w1+w2) log|P12| - w1 log|P1| - w2 log|P2|]`` with diagonal covariances.

    Parameters
    ----------
    w1, m1, v1, w2, m2, v2 : ndarray
        As in :func:`merge_moments`.

    Returns
    -------
    ndarray, shape (...)
        The merge cost.
    """
    w, _, v = merge_moments(w1, m1, v1, w2, m2, v2)
    return 0.5 * (w * np.sum(np.log(v), -1) - w1 * np.sum(np.log(v1), -1)
                  - w2 * np.sum(np.log(v2), -1))


def compact(mix: DiagMixture) -> DiagMixture:
    """Drop zero-weight slots, keeping as many components as the fullest mixture needs.

    Parameters
    ----------
    mix : DiagMixture
        A batch of mixtures.

    Returns
    -------
    DiagMixture
        Components in the canonical order: decreasing weight, equal weights by their means,
        then their variances, compared lexicographically (the order does not depend on the
        input order); trailing empty slots removed.
    """
    keys = [mix.variances[..., e] for e in range(mix.dim - 1, -1, -1)] \
        + [mix.means[..., e] for e in range(mix.dim - 1, -1, -1)] + [-mix.weights]
    order = np.lexsort(keys, axis=-1)
    keep = max(1, int(np.max(np.sum(mix.weights > 0, axis=-1), initial=1)))
    order = order[..., :keep]
    return DiagMixture(np.take_along_axis(mix.weights, order, -1),
                       np.take_along_axis(mix.means, order[..., None], -2),
                       np.take_along_axis(mix.variances, order[..., None], -2))


def _logdet_np(v: np.ndarray) -> np.ndarray:
    """``sum(log(v), -1)`` with the kernel's arithmetic (:func:`_logdet`): one logarithm of
    the product for up to two coordinates, a sequential sum of logarithms beyond."""
    if v.shape[-1] <= 2:
        return np.log(np.prod(v, axis=-1))
    acc = np.log(v[..., 0])
    for e in range(1, v.shape[-1]):
        acc = acc + np.log(v[..., e])
    return acc


def _canonical_first(mask: np.ndarray, w: np.ndarray, m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Per row of ``mask (B, K)`` (the tie set; ``w > 0`` marks the mixture's components),
    the tie rule of :func:`_pick`: the True component nearest to the mixture's mean, then
    the lowest in the canonical order (means, then variances, then weight,
    lexicographically: :func:`_key_less`)."""
    first = np.argmax(mask, axis=-1)
    many = np.count_nonzero(mask, axis=-1) > 1
    if np.any(many):
        cand = mask[many]
        wm, mm = w[many], m[many]
        mu = np.sum(wm[..., None] * mm, axis=-2) / np.sum(wm, axis=-1)[..., None]
        r = np.sum((mm - mu[..., None, :]) ** 2, axis=-1)
        rmin = np.min(np.where(cand, r, np.inf), axis=-1, keepdims=True)
        cand = cand & (r <= rmin * (1.0 + _TIE))
        pair = (np.count_nonzero(cand, axis=-1) == 2) & (m.shape[-1] >= 2)
        if np.any(pair):
            ab = np.argsort(~cand[pair], axis=-1, kind="stable")[:, :2]
            rows = np.arange(ab.shape[0])
            pa, pb = mm[pair][rows, ab[:, 0]], mm[pair][rows, ab[:, 1]]
            c0 = mu[pair]
            cross = (pa[:, 0] - c0[:, 0]) * (pb[:, 1] - c0[:, 1]) \
                - (pa[:, 1] - c0[:, 1]) * (pb[:, 0] - c0[:, 0])
            lim = rmin[pair][:, 0] * (1.0 + _TIE)
            won = np.where(cross > 0, ab[:, 0], ab[:, 1])
            sure = np.abs(cross) > _TIE * lim
            sub = cand[pair]
            sub[sure] = False
            sub[np.nonzero(sure)[0], won[sure]] = True
            cand[pair] = sub
        keys = [m[many][..., e] for e in range(m.shape[-1])] \
            + [v[many][..., e] for e in range(v.shape[-1])] + [w[many]]
        for key in keys:
            low = np.min(np.where(cand, key, np.inf), axis=-1, keepdims=True)
            cand = cand & (key == low)
        first[many] = np.argmax(cand, axis=-1)
    return first


def _partners(wr, mr, vr, ivr, ldr, act, i):
    """For each row, the partner ``j`` of component ``i`` under the rule of :func:`reduce`
    (lowest Runnalls cost, the tie rule of :func:`_canonical_first`) with the kernel's
    arithmetic (:func:`_partner`); ``ivr = 1 / vr``; returns ``(j, cost, scale)``
    (``scale``: the cost's rounding scale)."""
    n = np.arange(wr.shape[0])
    d = mr.shape[-1]
    wi, ldi = wr[n, i][:, None], ldr[n, i][:, None]
    with np.errstate(all="ignore"):              # empty slots: masked below
        ws = wi + wr
        inv = 1.0 / ws
        a1, a2 = wi * inv, wr * inv
        a12 = a1 * a2
        dm = mr[n, i][:, None, :] - mr
        r = (a1[..., None] * (vr[n, i][:, None, :] - vr) + a12[..., None] * dm * dm) * ivr
        y, ay = r[..., 0], np.abs(r[..., 0])
        for e in range(1, d):
            y = y + r[..., e] + y * r[..., e]
            ay = ay + np.abs(r[..., e]) + ay * np.abs(r[..., e])
        lp = np.log1p(y)
        cost = 0.5 * (wi * (ldr - ldi) + ws * lp)
        scale = 0.5 * (wi * (np.abs(ldr) + np.abs(ldi)) + ws * ay + ws * np.abs(lp))
    cand = act.copy()
    cand[n, i] = False
    cost = np.where(cand, cost, np.inf)
    best = np.min(cost, axis=-1, keepdims=True)
    j = _canonical_first(cand & (cost <= best + 2.0 * _TIE * scale), wr, mr, vr)
    return j, cost[n, j], scale[n, j]


def reduce_reference(mix: DiagMixture, max_components: int) -> DiagMixture:
    """Plain NumPy West/Runnalls reduction with the rules of :func:`reduce`: one merge per
    loop for the whole batch (the reference the compiled kernel is tested against, and the
    benchmark's peer).

    Same choices (lowest weight, lowest Runnalls cost, the order-free tie rule) and the same
    arithmetic as the kernel, so the results agree bit for bit; every cost of a row is
    computed here (the kernel skips candidates by a bound).

    Parameters
    ----------
    mix : DiagMixture
        A batch of mixtures.
    max_components : int
        The bound, >= 1.

    Returns
    -------
    DiagMixture
        As :func:`reduce` with ``method="runnalls"``.
    """
    kmax = int(max_components)
    if kmax < 1:
        raise InputError(f"max_components: must be >= 1, got {max_components}")
    k, d = mix.n_components, mix.dim
    w = mix.weights.reshape(-1, k).astype(float)
    m = mix.means.reshape(-1, k, d).astype(float)
    v = mix.variances.reshape(-1, k, d).astype(float)
    ld = _logdet_np(v)
    iv = 1.0 / v
    rows = np.arange(w.shape[0])
    while True:
        active = w > 0
        r = rows[active.sum(-1) > kmax]
        if r.size == 0:
            break
        n = np.arange(r.size)
        if r.size == w.shape[0]:         # every row still merges: views, no copies
            wr, mr, vr, ivr, ldr, act = w, m, v, iv, ld, active
        else:
            wr, mr, vr, ivr, ldr, act = w[r], m[r], v[r], iv[r], ld[r], active[r]
        wmin = np.min(np.where(act, wr, np.inf), axis=-1, keepdims=True)
        tied = act & (wr * (1.0 - _TIE) <= wmin)
        i = np.argmax(tied, axis=-1)
        many = np.count_nonzero(tied, axis=-1) > 1
        if np.any(many):
            # tied lowest weights: the cheapest best merge, ties by the canonical pick
            q = np.nonzero(many)[0]
            nq = q.size
            rep = np.repeat(q, k)
            ii = np.tile(np.arange(k), nq)
            _, co, sc = _partners(wr[rep], mr[rep], vr[rep], ivr[rep], ldr[rep], act[rep], ii)
            co = np.where(tied[q].reshape(-1), co, np.inf).reshape(nq, k)
            sc = sc.reshape(nq, k)
            bi = np.min(co, axis=-1, keepdims=True)
            i[q] = _canonical_first(co <= bi + 2.0 * _TIE * sc, wr[q], mr[q], vr[q])
        j, _, _ = _partners(wr, mr, vr, ivr, ldr, act, i)
        wj, mj, vj = merge_moments(wr[n, i], mr[n, i], vr[n, i], wr[n, j], mr[n, j], vr[n, j])
        w[r, j], m[r, j], v[r, j] = wj, mj, vj
        ld[r, j] = _logdet_np(vj)
        iv[r, j] = 1.0 / vj
        w[r, i] = 0.0
    out = compact(DiagMixture(w, m, v))
    kk = out.n_components
    bshape = mix.batch_shape
    return DiagMixture(out.weights.reshape(bshape + (kk,)), out.means.reshape(bshape + (kk, d)),
                       out.variances.reshape(bshape + (kk, d)))


#: reduction methods of :func:`reduce`
REDUCTIONS = ("runnalls", "progressive")


def check_reduction(method: object) -> str:
    """Validate a reduction method name.

    Parameters
    ----------
    method : str
        ``"runnalls"`` or ``"progressive"``.

    Returns
    -------
    str
        The name.

    Raises
    ------
    InputError
        Naming ``reduction`` when it is not one of :data:`REDUCTIONS`.
    """
    if not isinstance(method, str) or method not in REDUCTIONS:
        raise InputError(f"reduction: must be one of {', '.join(REDUCTIONS)}, got {method!r}")
    return method


def reduce(mix: DiagMixture, max_components: int, method: str = "runnalls") -> DiagMixture:
    """Reduce every mixture of the batch to at most ``max_components`` components.

    ``method="progressive"``: the Progressive Bayes re-approximation of the paper's
    reference [3] (:func:`radioloc.models.progressive_bayes.progressive_reduce`), a homotopy
    on the integral squared distance started from the West/Runnalls result below (its ISD to
    ``mix`` is never larger than West/Runnalls'; mass is kept, the mean and variances are
    not preserved exactly).

    ``method="runnalls"`` (default): West's (1993) greedy rule: while a mixture has too many
    components, its lowest-weight component is merged (:func:`merge_moments`) into the
    component for which Runnalls' cost :func:`runnalls_cost` of the merge is smallest. Each
    merge preserves the mass, the mean and the per-axis variances of the pair, so the whole
    reduction preserves the mass, the mean and the diagonal of the covariance of the
    mixture. One compiled kernel, the mixtures of the batch in parallel
    (:func:`_reduce_batch`; in 2-D, 32 mixtures of the same component count at a time on
    SIMD lanes, :func:`_west_lanes`).

    Weights that agree to a relative ``1e-9``, and merge costs that agree to ``1e-9`` of
    their rounding scale (Runnalls' cost is computed without cancellation, see
    :func:`_partner`, so the scale is about the cost's own size: a negligible component
    goes to its cheapest partner), count as tied, and ties are
    broken by the components' contents, never their position (see :func:`reduce_reference`:
    of tied lowest weights the one with the cheapest best merge; of tied partners the one
    nearest the mixture mean, then counter-clockwise about it, then the lexicographic order
    of means, variances and weight); the result comes in that canonical order, so permuting
    the components of ``mix`` does not change it. Without a tie rule, exact ties (the symmetric cells of :func:`uniform_ball`) were broken by
    rounding. The greedy rule is still a discrete choice: its result jumps where a near-tie
    flips (a continuous alternative for products: :func:`merge_groups`).

    Parameters
    ----------
    mix : DiagMixture
        A batch of mixtures.
    max_components : int
        The bound, >= 1.
    method : str
        ``"runnalls"`` (West/Runnalls greedy merging) or ``"progressive"`` (Progressive
        Bayes ISD homotopy started from it).

    Returns
    -------
    DiagMixture
        At most ``max_components`` components per mixture (compacted: sorted by decreasing
        weight, stably, no trailing empty slot).
    """
    if int(max_components) < 1:
        raise InputError(f"max_components: must be >= 1, got {max_components}")
    if check_reduction(method) == "progressive":
        from radioloc.models.progressive_bayes import progressive_reduce

        return progressive_reduce(mix, int(max_components))
    bshape = mix.batch_shape
    k, d = mix.n_components, mix.dim
    if k <= max_components:
        return compact(mix)
    w = kernel_array(mix.weights.reshape(-1, k))
    m = kernel_array(mix.means.reshape(-1, k, d))
    v = kernel_array(mix.variances.reshape(-1, k, d))
    ow, om, ov, cnt = _reduce_batch(w, m, v, int(max_components), _TIE)
    kk = max(1, int(cnt.max(initial=1)))
    return DiagMixture(ow[:, :kk].reshape(bshape + (kk,)), om[:, :kk].reshape(bshape + (kk, d)),
                       ov[:, :kk].reshape(bshape + (kk, d)))


@njit(cache=True)
def _key_less(t, d, a, b):  # pragma: no cover - compiled
    """The canonical order of two components ``a``, ``b`` (columns of the scratch ``t`` of
    :func:`_west_soa`): means, then variances, then the weight, compared
    lexicographically. It depends on the components' contents only, never on their
    positions."""
    for r in range(1, 2 * d + 1):
        if t[r, a] != t[r, b]:
            return t[r, a] < t[r, b]
    return t[0, a] < t[0, b]


@njit(cache=True, error_model="numpy")
def _pick(t, d, cnt, ts):  # pragma: no cover - compiled
    """The tie rule of :func:`reduce`: of the columns ``c < cnt`` of ``t`` flagged by
    ``t[ts, c] >= 0`` (unflagged: -1), the one nearest to the mixture's mean (squared
    distances within a relative ``_TIE`` of the nearest count as equal); of two at the same
    distance (in 2-D or more) the one the other follows counter-clockwise about the mean
    (in the first two coordinates); otherwise the lowest in the canonical order
    (:func:`_key_less`). The first two steps are kept by rotations and translations of the
    mixture, none reads a position. Overwrites row ``ts``."""
    first = -1
    many = False
    for c in range(cnt):
        if t[ts, c] >= 0.0:
            if first < 0:
                first = c
            else:
                many = True
    if not many:
        return first
    tot = 0.0
    for c in range(cnt):
        tot += t[0, c]
    mu = np.zeros(d)
    for c in range(cnt):
        for e in range(d):
            mu[e] += t[0, c] * t[1 + e, c]
    for e in range(d):
        mu[e] /= tot
    rmin = np.inf
    for c in range(cnt):
        if t[ts, c] >= 0.0:
            r = 0.0
            for e in range(d):
                r += (t[1 + e, c] - mu[e]) ** 2
            t[ts, c] = r
            rmin = min(rmin, r)
    lim = rmin * (1.0 + _TIE)
    a = -1
    b = -1
    n2 = 0
    for c in range(cnt):
        if t[ts, c] >= 0.0 and t[ts, c] <= lim:
            n2 += 1
            if a < 0:
                a = c
            elif b < 0:
                b = c
    if n2 == 2 and d >= 2:
        # two at the same distance: the one the other follows counter-clockwise (the sign
        # of the cross product about the mean is kept by rotations and translations)
        cross = (t[1, a] - mu[0]) * (t[2, b] - mu[1]) - (t[2, a] - mu[1]) * (t[1, b] - mu[0])
        if abs(cross) > _TIE * lim:
            return a if cross > 0 else b
    j = -1
    for c in range(cnt):
        if t[ts, c] >= 0.0 and t[ts, c] <= lim and (j < 0 or _key_less(t, d, c, j)):
            j = c
    return j


@njit(cache=True)
def _logdet(t, d, c):  # pragma: no cover - compiled
    """``sum(log(v))`` of column ``c`` of the scratch ``t``: one logarithm of the product
    for up to two coordinates (variances floored at ``1e-60`` keep it a normal float), one
    per coordinate beyond."""
    if d <= 2:
        acc = 1.0
        for e in range(d):
            acc *= t[1 + d + e, c]
        return math.log(acc)
    acc = 0.0
    for e in range(d):
        acc += math.log(t[1 + d + e, c])
    return acc


@njit(cache=True)
def _set_logdet(t, d, c):  # pragma: no cover - compiled
    """Rows ``2 D + 1 .. 3 D`` (the inverse variances) and ``3 D + 1`` (the
    log-determinant, :func:`_logdet`) of column ``c`` of the scratch ``t``."""
    for e in range(d):
        t[2 * d + 1 + e, c] = 1.0 / t[1 + d + e, c]
    t[3 * d + 1, c] = _logdet(t, d, c)


@njit(cache=True, inline="always", error_model="numpy")
def _exact_costs(t, LD, cnt, i, c0, wi, ldi, tie, ts):  # pragma: no cover - compiled
    """Pass 2 of :func:`_partner`: the exact Runnalls costs of component ``i``'s candidates
    that the bound does not exclude, the lowest bound ``c0`` first, then the others in
    order. ``t`` is ``(row, component)`` (rows ``LD`` to ``LD + 3``: log-determinant, bound,
    ``y`` then cost, scale's part then scale); the costed candidates are listed in ``ts``.
    Returns ``(best, ne)``: the lowest cost and the number costed."""
    LB = LD + 1
    CO = LD + 2
    SC = LD + 3
    best = np.inf
    ne = 0
    for step in range(cnt + 1):
        if step == 0:
            c = c0
        else:
            c = step - 1
            if c == c0:
                continue
            lb = t[LB, c]
            if c == i or (lb > 0.0 and lb * (1.0 - 2.0 * tie)
                          > best + tie * (2.0 * abs(best) + 4.0 * t[SC, c])):
                continue
        ws = wi + t[0, c]
        lp = math.log1p(t[CO, c])
        cost = 0.5 * (wi * (t[LD, c] - ldi) + ws * lp)
        t[SC, c] = 0.5 * (t[SC, c] + ws * abs(lp))
        t[CO, c] = cost
        ts[ne] = c
        ne += 1
        best = min(best, cost)
    return best, ne


@njit(cache=True, error_model="numpy")
def _partner(t, d, cnt, i, tie):  # pragma: no cover - compiled
    """The partner ``j`` of component ``i`` under the rule of :func:`_west_soa` (passes 1
    and 2 and the tie set); returns ``(j, cost, scale)``. Uses the scratch rows of ``t``
    from the bound to the tie set.

    Runnalls' cost of merging ``i`` into ``c`` is computed without cancellation as
    ``0.5 (wi (log|P_c| - log|P_i|) + ws log1p(y))``, ``1 + y = |P_ic| / |P_c|`` the
    product over the coordinates of ``1 + r_e``,
    ``r_e = (a1 (v_ie - v_ce) + a1 a2 dm_e^2) / v_ce`` (``a1 = wi / ws``, ``a2 = wc / ws``);
    its rounding scale is
    ``0.5 (wi (|log|P_c|| + |log|P_i||) + ws (ay + |log1p(y)|))``, ``ay`` the same product
    of ``1 + |r_e|`` minus one."""
    IVB = 2 * d + 1
    LD = 3 * d + 1
    LB = LD + 1
    CO = LD + 2
    SC = LD + 3
    TS = LD + 4
    wi = t[0, i]
    ldi = t[LD, i]
    ali = abs(ldi)
    # pass 1: y, the bound and the scale's part known before the logarithm (row SC)
    if d == 2:
        mi0 = t[1, i]
        mi1 = t[2, i]
        vi0 = t[3, i]
        vi1 = t[4, i]
        for c in range(cnt):
            wc = t[0, c]
            ws = wi + wc
            inv = 1.0 / ws
            a1 = wi * inv
            a2 = wc * inv
            a12 = a1 * a2
            dm0 = mi0 - t[1, c]
            dm1 = mi1 - t[2, c]
            r0 = (a1 * (vi0 - t[3, c]) + a12 * dm0 * dm0) * t[5, c]
            r1 = (a1 * (vi1 - t[4, c]) + a12 * dm1 * dm1) * t[6, c]
            y = r0 + r1 + r0 * r1
            b0 = abs(r0)
            b1 = abs(r1)
            ay = b0 + b1 + b0 * b1
            ldc = t[LD, c]
            t[CO, c] = y
            t[SC, c] = wi * (abs(ldc) + ali) + ws * ay
            t[LB, c] = _cost_bound(y, ldc, wi, ws, ldi, ali)
    else:
        for c in range(cnt):
            wc = t[0, c]
            ws = wi + wc
            inv = 1.0 / ws
            a1 = wi * inv
            a2 = wc * inv
            a12 = a1 * a2
            y = 0.0
            ay = 0.0
            for e in range(d):
                dm = t[1 + e, i] - t[1 + e, c]
                r = (a1 * (t[1 + d + e, i] - t[1 + d + e, c]) + a12 * dm * dm) * t[IVB + e, c]
                if e == 0:
                    y = r
                    ay = abs(r)
                else:
                    y = y + r + y * r
                    ay = ay + abs(r) + ay * abs(r)
            ldc = t[LD, c]
            t[CO, c] = y
            t[SC, c] = wi * (abs(ldc) + ali) + ws * ay
            t[LB, c] = _cost_bound(y, ldc, wi, ws, ldi, ali)
    t[LB, i] = np.inf
    c0 = 0
    for c in range(1, cnt):
        if t[LB, c] < t[LB, c0]:
            c0 = c
    # pass 2: exact costs where the bound allows a win or a tie (costed: row TS)
    best, ne = _exact_costs(t, LD, cnt, i, c0, wi, ldi, tie, t[TS])
    # the tie set and the canonical choice in it
    j = -1
    many = False
    for q in range(ne):
        c = np.int64(t[TS, q])
        if t[CO, c] <= best + 2.0 * tie * t[SC, c]:
            if j < 0:
                j = c
            else:
                many = True
    if many:
        for c in range(cnt):
            t[LB, c] = -1.0
        for q in range(ne):
            c = np.int64(t[TS, q])
            if t[CO, c] <= best + 2.0 * tie * t[SC, c]:
                t[LB, c] = 0.0
        j = _pick(t, d, cnt, LB)
    return j, t[CO, j], t[SC, j]


@njit(cache=True, inline="always", error_model="numpy")
def _cost_bound(y, ldc, wi, ws, ldi, ali):  # pragma: no cover - compiled
    """A lower bound of Runnalls' cost ``0.5 (wi (ldc - ldi) + ws log1p(y))``
    (:func:`_partner`) without a logarithm: with ``z = y / (y + 2)``,
    ``log(1 + y) = 2 (z + z^3 / 3 + z^5 / 5 + ...)`` (``atanh``); the first three terms
    bound it from below for ``z >= 0``; for ``-0.61 <= z < 0`` the tail's magnitude is at
    most ``2 |z|^7 / (7 (1 - z^2)) <= 0.46 |z|^7``. Below ``z = -0.61`` (``y < -0.757``;
    a merge into a heavier component has ``y >= -3/4`` in 2-D) the bound is ``-inf``.
    ``1e-14 (wi (|ldc| + |ldi|) + ws |log(1 + y)|)`` (about 45 ulps of the cost's terms) is
    subtracted for rounding (a NaN bound excludes nothing)."""
    z = y / (y + 2.0)
    zc = z if abs(z) > 1e-100 else 0.0   # no subnormal powers (slow)
    z2 = zc * zc
    zn = min(zc, 0.0)
    zn2 = zn * zn
    lx = 2.0 * z * (1.0 + z2 * (1.0 / 3.0 + 0.2 * z2)) + 0.46 * zn * zn2 * zn2 * zn2
    lb = 0.5 * (wi * (ldc - ldi) + ws * lx) - 1e-14 * (wi * (abs(ldc) + ali) + ws * abs(lx))
    return lb if z >= -0.61 else -np.inf


@njit(cache=True, error_model="numpy")
def _west_soa(t, n, kmax, tie, fresh):  # pragma: no cover - compiled
    """West's greedy merging of ``n`` components (all weights > 0) down to ``kmax``, in
    place, with Runnalls' cost and the order-free tie rule of :func:`reduce`.

    ``t`` (``3 D + 10`` rows, at least ``n`` columns) holds one component per column: row 0
    the weight, rows ``1..D`` the mean, ``D+1..2D`` the variances, then scratch rows (the
    log-determinant, weight times its absolute value, the inverse of the product of the
    variances, the cost bound, the cost, the cost's rounding scale, the tie set, the best
    cost, its scale and its partner per tied lowest weight). Returns the component count;
    the survivors are the first columns, in no particular order (the rule never reads
    positions).

    - ``i``: the lowest weight. Weights ``w`` with ``w (1 - tie) <= w_min`` tie with it; of
      tied ones, the one whose best merge (below) is cheapest, cost ties by :func:`_pick`
      (equal weights are common: data points, the disk cells).
    - Pass 1 computes, for every candidate ``c``, the product of the merged variances and
      a logarithm-free lower bound of Runnalls' cost from it (:func:`_cost_bound`;
      vectorised, no branch).
    - Pass 2 takes the exact cost (one logarithm) of the candidate with the lowest bound,
      then of every candidate whose bound does not exclude it from the tie set below.
    - ``j``: with ``best`` the lowest exact cost, the candidates with
      ``cost <= best + 2 tie scale`` (``scale``: the cost's rounding scale,
      :func:`_partner`) tie and :func:`_pick` chooses among them. A candidate is skipped
      when ``bound > 0`` and ``bound (1 - 2 tie) > best + tie (2 |best| + 4 B)`` with
      ``B = wi (|log|P_c|| + |log|P_i||) + ws ay`` (then it cannot tie:
      ``scale <= |cost| + B``).
    - ``i`` is merged into ``j`` (moment matching, :func:`_merge_pair`), ``i`` is
      replaced by the last column.

    ``fresh``: set rows ``2 D + 1 .. 3 D + 1`` first; ``False``: rows ``2 D + 1 .. 3 D + 1`` are already set (:func:`_set_logdet`);
    ``_west_soa(t, n, n - 1, tie, False)`` is one merge (:func:`_west_lanes`).
    """
    d = (t.shape[0] - 10) // 3
    LD = 3 * d + 1
    TS = LD + 4
    IC = LD + 5
    IS = LD + 6
    IJ = LD + 7
    if fresh:
        for c in range(n):
            _set_logdet(t, d, c)
    cnt = n
    while cnt > kmax:
        # the lowest weight and the second lowest (a tie needs w2 (1 - tie) <= wmin)
        wmin = np.inf
        w2 = np.inf
        first = -1
        for c in range(cnt):
            wc = t[0, c]
            if wc < wmin:
                w2 = wmin
                wmin = wc
                first = c
            elif wc < w2:
                w2 = wc
        many = w2 * (1.0 - tie) <= wmin
        if not many:
            i = first
            j, _, _ = _partner(t, d, cnt, i, tie)
        else:
            # tied lowest weights: the one with the cheapest merge, ties by _pick
            bi = np.inf
            for c in range(cnt):
                if t[0, c] * (1.0 - tie) <= wmin:
                    jj, co, sc = _partner(t, d, cnt, c, tie)
                    t[IC, c] = co
                    t[IS, c] = sc
                    t[IJ, c] = jj
                    bi = min(bi, co)
                else:
                    t[IC, c] = np.inf
                    t[IS, c] = 0.0
            for c in range(cnt):
                t[TS, c] = 0.0 if t[IC, c] <= bi + 2.0 * tie * t[IS, c] else -1.0
            i = _pick(t, d, cnt, TS)
            j = np.int64(t[IJ, i])
        # merge i into j (moment matching), then replace column i by the last one
        _merge_pair(t, d, i, j)
        cnt -= 1
        if i != cnt:
            for r in range(LD + 1):
                t[r, i] = t[r, cnt]
    return cnt


@njit(cache=True, error_model="numpy")
def _merge_pair(t, d, i, j):  # pragma: no cover - compiled
    """Merge column ``i`` of the scratch ``t`` (:func:`_west_soa`) into column ``j`` by
    moment matching (:func:`merge_moments`' arithmetic) and set ``j``'s inverse variances
    and log-determinant (:func:`_set_logdet`); column ``i`` is left as it was."""
    wi = t[0, i]
    wj = t[0, j]
    ws = wi + wj
    a1 = wi / ws
    a2 = wj / ws
    for e in range(d):
        mie = t[1 + e, i]
        mje = t[1 + e, j]
        mm = a1 * mie + a2 * mje
        vv = a1 * (t[1 + d + e, i] + (mie - mm) ** 2) + a2 * (t[1 + d + e, j] + (mje - mm) ** 2)
        t[1 + e, j] = mm
        t[1 + d + e, j] = vv
    t[0, j] = ws
    _set_logdet(t, d, j)


@njit(cache=True, error_model="numpy")
def _reduce_into(w, m, v, n, kmax, tie, ow, om, ov, t):  # pragma: no cover - compiled
    """:func:`reduce` of one mixture ``w[:n]`` into ``ow, om, ov`` (``t``: scratch of
    ``3 D + 10`` rows and at least ``n`` columns, :func:`_west_soa`); returns the component
    count. The output is in the canonical order of :func:`compact` (:func:`_store`)."""
    d = m.shape[1]
    c = _load(w, m, v, n, t)
    if c > kmax:
        c = _west_soa(t, c, kmax, tie, True)
    _store(t, d, c, ow, om, ov)
    return c


@njit(cache=True)
def _load(w, m, v, n, t):  # pragma: no cover - compiled
    """The components of positive weight of ``w[:n], m, v`` into the columns of the scratch
    ``t`` (:func:`_west_soa`: weight, mean, variances); returns their count."""
    d = m.shape[1]
    c = 0
    for r in range(n):
        if w[r] > 0:
            t[0, c] = w[r]
            for e in range(d):
                t[1 + e, c] = m[r, e]
                t[1 + d + e, c] = v[r, e]
            c += 1
    return c


@njit(cache=True)
def _store(t, d, c, ow, om, ov):  # pragma: no cover - compiled
    """The ``c`` components of the scratch ``t`` into ``ow, om, ov`` in the canonical order
    of :func:`compact`: decreasing weight, equal weights by means, then variances (an
    insertion sort; the mixtures are small)."""
    for r in range(c):                   # sorted column indices in the first slots of ow
        pos = r
        while pos > 0:
            p = np.int64(ow[pos - 1])
            if t[0, p] > t[0, r] or (t[0, p] == t[0, r] and not _key_less(t, d, r, p)):
                break
            ow[pos] = ow[pos - 1]
            pos -= 1
        ow[pos] = r
    for r in range(c):                   # slot r reads index ow[r] before writing it
        i = np.int64(ow[r])
        for e in range(d):
            om[r, e] = t[1 + e, i]
            ov[r, e] = t[1 + d + e, i]
        ow[r] = t[0, i]


#: mixtures reduced together on the SIMD lanes of :func:`_west_lanes` (2-D)
_LANES = 32
#: rows of the lane array of :func:`_west_lanes`
_LANE_ROWS = 11


@njit(cache=True, error_model="numpy")
def _west_lanes(T, cnt, kmax, tie, t, ow, om, ov, nl):  # pragma: no cover - compiled
    """:func:`_west_soa` of ``L`` 2-D mixtures at once, one per SIMD lane, with the same
    choices, arithmetic and component order (so the same results, bit for bit).

    ``T`` (``K x 11 x L``, C order): ``T[c, r, l]`` is row ``r`` of component ``c`` of lane
    ``l``, rows 0-7 as in :func:`_west_soa` (weight, mean, variances, inverse variances,
    log-determinant), then the cost bound, ``y`` and the scale's part of
    :func:`_partner`'s pass 1. Every lane has ``cnt`` components (weights > 0); returns
    ``kmax``; lanes ``l < nl`` are stored by :func:`_store` into ``ow[l], om[l], ov[l]``
    (the others are padding). The loops run over the components with the lanes innermost (a run-time trip
    count, no branch: LLVM vectorises them), so the lowest weight, pass 1, the lowest
    bound and the bound's skip test cost a few vector operations per candidate for ``L``
    mixtures. ``c0``, the candidate of lowest bound, is costed for the skip test by
    :func:`_best_above` (an upper bound of its exact cost, vectorised). A lane merges its
    lowest weight ``i`` into ``c0`` when ``i``'s weight is not tied and the bound excludes
    every other candidate from the tie set of ``c0``'s cost (:func:`_partner`'s test: its
    pass 2 would take no other logarithm); else it takes :func:`_partner`'s pass 2 from
    pass 1's rows (:func:`_lane_pass2`, libm's ``log1p``), and only a tie among the exact
    costs takes one step of :func:`_west_soa` on a copy in the scratch ``t``. The merges
    (:func:`_merge_pair`'s arithmetic) run over the lanes, the logarithm of the merged
    determinant per lane (libm's). Pass 1 and the skip test read ``T`` and the lane state
    through flat views with constant strides (``T.shape[2] == _LANES``): each row an
    immediate offset from one base register. Tied lowest weights: the lane is finished alone
    (:func:`_finish_lane`), and when fewer than half the lanes are left the others are
    too."""
    L = T.shape[2]
    LD = 7
    LB = 8
    CO = 9
    SC = 10
    # per-lane state, one row each (a running minimum alternates between two rows, so no
    # store reads its own address: LLVM would make it a masked store)
    S = np.empty((41, L))
    WI = 6
    MI0 = 7
    MI1 = 8
    VI0 = 9
    VI1 = 10
    LDI = 11
    ALI = 12
    BEST = 17
    NS = 18
    ALIVE = 19
    DO = 20                              # the lane merges this round
    JR = 21                              # its partner
    WJ = 22                              # rows 22-26: the partner's weight, mean, variances
    NW = 27                              # rows 27-34: the merged column (rows 0-7 of T)
    GY = 35                              # rows 35-37: y, weight and log-determinant of c0
    GW = 36
    GL = 37
    Si = S.view(np.int64)                # rows 38-40: _best_above's scratch
    Tf = T.reshape(-1)                   # flat views (L == _LANES)
    Sf = S.reshape(-1)
    for ln in range(L):
        S[ALIVE, ln] = 1.0
    alive = L
    while cnt > kmax and 2 * alive >= L:
        # the lowest weight (rows 0/1), the second lowest (2/3), its index (4/5)
        q = 0
        for c in range(cnt):
            p = q
            q = 1 - q
            cf = float(c)
            for ln in range(L):
                wc = T[c, 0, ln]
                mw = S[p, ln]
                m2 = S[2 + p, ln]
                f = S[4 + p, ln]
                lt = (c == 0) | (wc < mw)
                m2 = wc if wc < m2 else m2
                S[2 + q, ln] = (np.inf if c == 0 else mw) if lt else m2
                S[4 + q, ln] = cf if lt else f
                S[q, ln] = wc if lt else mw
        wq = q
        for ln in range(L):
            i = np.int64(S[4 + wq, ln])
            S[WI, ln] = T[i, 0, ln]
            S[MI0, ln] = T[i, 1, ln]
            S[MI1, ln] = T[i, 2, ln]
            S[VI0, ln] = T[i, 3, ln]
            S[VI1, ln] = T[i, 4, ln]
            S[LDI, ln] = T[i, LD, ln]
            S[ALI, ln] = abs(T[i, LD, ln])
        # pass 1 of _partner (flat views with constant strides: one base register)
        for c in range(cnt):
            o = c * (_LANE_ROWS * _LANES)
            for ln in range(_LANES):
                wi = Sf[WI * _LANES + ln]
                ali = Sf[ALI * _LANES + ln]
                wc = Tf[o + ln]
                ws = wi + wc
                inv = 1.0 / ws
                a1 = wi * inv
                a2 = wc * inv
                a12 = a1 * a2
                dm0 = Sf[MI0 * _LANES + ln] - Tf[o + _LANES + ln]
                dm1 = Sf[MI1 * _LANES + ln] - Tf[o + 2 * _LANES + ln]
                r0 = (a1 * (Sf[VI0 * _LANES + ln] - Tf[o + 3 * _LANES + ln]) + a12 * dm0 * dm0) \
                    * Tf[o + 5 * _LANES + ln]
                r1 = (a1 * (Sf[VI1 * _LANES + ln] - Tf[o + 4 * _LANES + ln]) + a12 * dm1 * dm1) \
                    * Tf[o + 6 * _LANES + ln]
                y = r0 + r1 + r0 * r1
                b0 = abs(r0)
                b1 = abs(r1)
                ay = b0 + b1 + b0 * b1
                Tf[o + CO * _LANES + ln] = y
                Tf[o + SC * _LANES + ln] = wi * (abs(Tf[o + LD * _LANES + ln]) + ali) + ws * ay
            # the bound from y, a loop of its own (fewer live registers in each)
            for ln in range(_LANES):
                wi = Sf[WI * _LANES + ln]
                ws = wi + Tf[o + ln]
                Tf[o + LB * _LANES + ln] = _cost_bound(Tf[o + CO * _LANES + ln],
                                                       Tf[o + LD * _LANES + ln], wi, ws,
                                                       Sf[LDI * _LANES + ln],
                                                       Sf[ALI * _LANES + ln])
        for ln in range(L):
            T[np.int64(S[4 + wq, ln]), LB, ln] = np.inf      # i is no candidate
        # the lowest bound (rows 13/14), its index (15/16): the first of equal ones
        q = 0
        for c in range(cnt):
            p = q
            q = 1 - q
            cf = float(c)
            for ln in range(L):
                lb = T[c, LB, ln]
                mb = S[13 + p, ln]
                f = S[15 + p, ln]
                lt = (c == 0) | (lb < mb)
                S[13 + q, ln] = lb if lt else mb
                S[15 + q, ln] = cf if lt else f
        bq = q
        # the exact cost of the lowest bound (pass 2's first step); its bound set to inf
        # so that the skip test below skips it (an infinite or NaN cost skips nothing)
        for ln in range(L):
            c = np.int64(S[15 + bq, ln])
            T[c, LB, ln] = np.inf
            S[GY, ln] = T[c, CO, ln]
            S[GW, ln] = T[c, 0, ln]
            S[GL, ln] = T[c, LD, ln]
            S[NS, ln] = 0.0
        _best_above(S, Si, GY, GW, GL, WI, LDI, ALI, BEST)
        # pass 2's skip test against it: the candidates it does not skip
        for c in range(cnt):
            o = c * (_LANE_ROWS * _LANES)
            for ln in range(_LANES):
                lb = Tf[o + LB * _LANES + ln]
                bb = Sf[BEST * _LANES + ln]
                skip = (lb > 0.0) & (lb * (1.0 - 2.0 * tie)
                                     > bb + tie * (2.0 * abs(bb) + 4.0 * Tf[o + SC * _LANES + ln]))
                Sf[NS * _LANES + ln] += 0.0 if skip else 1.0
        last = cnt - 1
        # the partner of each lane (DO = 1: merge i into JR; DO = 0: the lane is done)
        for ln in range(L):
            S[DO, ln] = 0.0
            S[JR, ln] = 0.0
            if S[ALIVE, ln] == 0.0:
                continue
            i = np.int64(S[4 + wq, ln])
            if S[2 + wq, ln] * (1.0 - tie) <= S[wq, ln]:
                # tied lowest weights: this lane goes on alone (_west_soa from here)
                S[ALIVE, ln] = 0.0
                alive -= 1
                if ln < nl:
                    _finish_lane(T, ln, cnt, kmax, tie, t, ow[ln], om[ln], ov[ln])
                continue
            if S[NS, ln] == 0.0:
                j = np.int64(S[15 + bq, ln])          # the lowest bound excludes the rest
            else:
                # _partner's pass 2 in the lane: exact costs of the candidates the bound
                # does not exclude (y, the bound and the scale's part are in T from pass 1)
                j = _lane_pass2(T, ln, cnt, i, np.int64(S[15 + bq, ln]), S[WI, ln],
                                S[LDI, ln], tie, t)
                if j < 0:
                    # a tie among the exact costs: one step of _west_soa on a copy
                    for c in range(cnt):
                        for r in range(LD + 1):
                            t[r, c] = T[c, r, ln]
                    _west_soa(t, cnt, last, tie, False)
                    for c in range(last):
                        for r in range(LD + 1):
                            T[c, r, ln] = t[r, c]
                    continue
            S[DO, ln] = 1.0
            S[JR, ln] = float(j)
        # the merges (_merge_pair's arithmetic), vectorised over the lanes: j's columns
        for ln in range(L):
            j = np.int64(S[JR, ln])
            for r in range(5):
                S[WJ + r, ln] = T[j, r, ln]
        for ln in range(L):
            wi = S[WI, ln]
            wj = S[WJ, ln]
            ws = wi + wj
            a1 = wi / ws
            a2 = wj / ws
            mi0 = S[MI0, ln]
            mj0 = S[WJ + 1, ln]
            mm0 = a1 * mi0 + a2 * mj0
            vv0 = a1 * (S[VI0, ln] + (mi0 - mm0) ** 2) + a2 * (S[WJ + 3, ln] + (mj0 - mm0) ** 2)
            mi1 = S[MI1, ln]
            mj1 = S[WJ + 2, ln]
            mm1 = a1 * mi1 + a2 * mj1
            vv1 = a1 * (S[VI1, ln] + (mi1 - mm1) ** 2) + a2 * (S[WJ + 4, ln] + (mj1 - mm1) ** 2)
            S[NW, ln] = ws
            S[NW + 1, ln] = mm0
            S[NW + 2, ln] = mm1
            S[NW + 3, ln] = vv0
            S[NW + 4, ln] = vv1
            S[NW + 5, ln] = 1.0 / vv0
            S[NW + 6, ln] = 1.0 / vv1
            S[NW + 7, ln] = vv0 * vv1
        for ln in range(L):
            if S[DO, ln] != 0.0:
                S[NW + 7, ln] = math.log(S[NW + 7, ln])
                i = np.int64(S[4 + wq, ln])
                j = np.int64(S[JR, ln])
                for r in range(LD + 1):
                    T[j, r, ln] = S[NW + r, ln]
                if i != last:
                    for r in range(LD + 1):
                        T[i, r, ln] = T[last, r, ln]
        cnt -= 1
    for ln in range(min(L, nl)):
        if S[ALIVE, ln] != 0.0:
            _finish_lane(T, ln, cnt, kmax, tie, t, ow[ln], om[ln], ov[ln])
    return kmax


@njit(cache=True, error_model="numpy")
def _reduce_rows(xw, xm, xv, xr, need, nl, kmax, tie, pw, pm, pv, pn, T, t):
    # pragma: no cover - compiled
    """:func:`reduce` (West/Runnalls) of the mixtures ``l < nl`` with ``need[l]`` of a group
    of rows: ``xw[l, :xr[l]], xm[l], xv[l]`` into ``pw[l], pm[l], pv[l]`` (canonical order,
    :func:`_store`), their component counts into ``pn[l]``. When every row of the group
    needs it, there are more than half of ``_LANES`` rows, the mixtures are 2-D
    and all have the same number ``n0 > kmax`` of positive weights, the group is reduced on
    SIMD lanes (:func:`_west_lanes`, ``T``: a lane array of at least ``n0`` components),
    else row by row (:func:`_reduce_into`): the same results bit for bit. Slots of ``xw``
    from ``xr[l]`` on are set to 0."""
    L = _LANES
    d = xm.shape[2]
    big = xw.shape[1]
    same = d == 2 and 2 * nl > L
    n0 = -1
    for ln in range(nl):
        if not need[ln]:
            same = False
            continue
        for r in range(xr[ln], big):
            xw[ln, r] = 0.0
        c = 0
        for r in range(xr[ln]):
            c += 1 if xw[ln, r] > 0 else 0
        if n0 < 0:
            n0 = c
        same = same and c == n0
    if same and n0 > kmax:
        _load_lanes(xw, xm, xv, 0, nl, n0, T, t)
        _west_lanes(T, n0, kmax, tie, t, pw, pm, pv, nl)
        for ln in range(nl):
            pn[ln] = kmax
        return
    for ln in range(nl):
        if need[ln]:
            pn[ln] = _reduce_into(xw[ln], xm[ln], xv[ln], xr[ln], kmax, tie, pw[ln], pm[ln],
                                  pv[ln], t)


@njit(cache=True, error_model="numpy")
def _load_lanes(w, m, v, b0, nl, n0, T, t):  # pragma: no cover - compiled
    """The lane array ``T`` of :func:`_west_lanes` for the 2-D mixtures ``b0 .. b0 + nl - 1``
    (``n0`` components of positive weight each; lanes from ``nl`` on: copies of the last
    mixture): rows 0-4 (through :func:`_load` where a mixture has empty slots), then the
    inverse variances and the log-determinant of :func:`_set_logdet` (same arithmetic:
    ``1.0 * v_0 * v_1`` is ``v_0 v_1``), the reciprocals and products vectorised over the
    lanes, the logarithms one by one (libm's, as :func:`_logdet`)."""
    L = T.shape[2]
    k = w.shape[1]
    if n0 == k:                          # no empty slot: the columns as they are
        for c in range(k):
            for ln in range(L):
                b = b0 + min(ln, nl - 1)
                T[c, 0, ln] = w[b, c]
                T[c, 1, ln] = m[b, c, 0]
                T[c, 2, ln] = m[b, c, 1]
                T[c, 3, ln] = v[b, c, 0]
                T[c, 4, ln] = v[b, c, 1]
    else:
        for ln in range(L):
            b = b0 + min(ln, nl - 1)
            _load(w[b], m[b], v[b], k, t)
            for c in range(n0):
                for r in range(5):
                    T[c, r, ln] = t[r, c]
    for c in range(n0):
        for ln in range(L):
            v0 = T[c, 3, ln]
            v1 = T[c, 4, ln]
            T[c, 5, ln] = 1.0 / v0
            T[c, 6, ln] = 1.0 / v1
            T[c, 7, ln] = v0 * v1
        for ln in range(L):
            T[c, 7, ln] = math.log(T[c, 7, ln])


# fdlibm's e_log.c (radioloc.core.fdlibm)
_SQRT2, _TWO52, _TWO52_BITS, _MANT, _ONE_BITS = (fdl.SQRT2, fdl.TWO52, fdl.TWO52_BITS,
                                                 fdl.MANT, fdl.ONE_I)
#: relative margin added to the vectorised logarithm of :func:`_best_above` (its error
#: and libm's are a few ulps, 1e-12 is about 4500)
_LOG_MARGIN = 1e-12


@njit(cache=True, error_model="numpy")
def _best_above(S, Si, GY, GW, GL, WI, LDI, ALI, BEST):  # pragma: no cover - compiled
    """Row ``BEST`` of the lane state ``S`` (``Si``: its int64 view): an upper bound of
    Runnalls' cost ``0.5 (wi (ldc - ldi) + ws log1p(y))`` of :func:`_partner` with
    ``log1p`` from libm, for ``y``, ``w_c``, ``ldc`` in rows ``GY, GW, GL``, vectorised
    over the lanes (no call, no branch): ``log1p(y) = log(u) + (y - (u - 1)) / u`` with
    ``u = 1 + y`` rounded (the second term is the rounding of ``u``, exact to first
    order) and ``log(u)`` by fdlibm's ``e_log.c`` (exponent from the bits, the polynomial
    in ``s = f / (2 + f)``; within 1 ulp). Both logarithms are within a few ulps of
    ``log1p(y)``, so adding ``_LOG_MARGIN (wi (|ldc| + |ldi|) + ws |log1p(y)|)`` (about
    4500 ulps of the cost's terms) puts the result above the exact cost of libm's
    logarithm, and the skip test of :func:`_west_lanes`, increasing in it, skips no
    candidate that the exact cost would keep (it may keep more: those are costed exactly,
    :func:`_lane_pass2`). ``u`` not a positive normal float: ``inf`` (skips nothing).
    Rows 38-40 of ``S`` are scratch."""
    L = S.shape[1]
    for ln in range(L):
        S[38, ln] = 1.0 + S[GY, ln]
    for ln in range(L):
        bits = Si[38, ln]
        Si[39, ln] = (bits >> 52) | _TWO52_BITS
        Si[40, ln] = (bits & _MANT) | _ONE_BITS
    for ln in range(L):
        y = S[GY, ln]
        u = S[38, ln]
        k = S[39, ln] - (_TWO52 + 1023.0)
        m = S[40, ln]                                    # [1, 2)
        big = m > _SQRT2
        m = m * 0.5 if big else m
        k = k + 1.0 if big else k
        f = m - 1.0
        s = f / (2.0 + f)
        lg = fdl.log_finish(k, f, s, fdl.log_poly(s))
        lp = lg + (y - (u - 1.0)) / u
        wi = S[WI, ln]
        ws = wi + S[GW, ln]
        ldc = S[GL, ln]
        bb = 0.5 * (wi * (ldc - S[LDI, ln]) + ws * lp) \
            + _LOG_MARGIN * (wi * (abs(ldc) + S[ALI, ln]) + ws * abs(lp))
        ok = (u >= 2.2250738585072014e-308) & (u <= 1.7976931348623157e308)
        S[BEST, ln] = bb if ok else np.inf


@njit(cache=True, error_model="numpy")
def _lane_pass2(T, ln, cnt, i, c0, wi, ldi, tie, t):  # pragma: no cover - compiled
    """Pass 2 of :func:`_partner` for lane ``ln`` of :func:`_west_lanes` after its pass 1
    (rows 8-10 of ``T``: the bound, ``y``, the scale's part; ``c0`` the lowest bound, ``i``
    the lowest weight): the same candidates costed in the same order with the same
    arithmetic. Returns the partner ``j`` when the tie set has one member, -1 when it has
    more (then :func:`_pick` decides: the caller runs :func:`_west_soa`). Rows 9 and 10 of
    the costed candidates are overwritten (pass 1 sets them again); row 0 of ``t`` holds
    the costed candidates."""
    CO = 9
    SC = 10
    best, ne = _exact_costs(T[:, :, ln].T, 7, cnt, i, c0, wi, ldi, tie, t[0])
    j = -1
    for q in range(ne):
        c = np.int64(t[0, q])
        if T[c, CO, ln] <= best + 2.0 * tie * T[c, SC, ln]:
            if j >= 0:
                return -1
            j = c
    return j


@njit(cache=True, error_model="numpy")
def _finish_lane(T, ln, cnt, kmax, tie, t, ow, om, ov):  # pragma: no cover - compiled
    """Lane ``ln`` of :func:`_west_lanes` (``cnt`` components) copied into the scratch
    ``t``, reduced to ``kmax`` by :func:`_west_soa` and stored by :func:`_store`."""
    for c in range(cnt):
        for r in range(5):
            t[r, c] = T[c, r, ln]
    if cnt > kmax:
        cnt = _west_soa(t, cnt, kmax, tie, True)
    _store(t, 2, cnt, ow, om, ov)


@njit(cache=True, parallel=True, error_model="numpy")
def _reduce_batch(w, m, v, kmax, tie):  # pragma: no cover - compiled
    """:func:`reduce` (West/Runnalls) of every mixture of ``w (B, K)``, ``m, v (B, K, D)``;
    returns ``(weights (B, kmax), means, variances, counts (B,))`` in the canonical order
    (:func:`_store`) and unused slots at weight 0, mean 0, variance 1. Groups of
    ``_LANES`` mixtures run in parallel; in 2-D a group whose mixtures all have the same
    number of components above ``kmax`` is reduced on SIMD lanes (:func:`_west_lanes`; a
    part group of more than half the lanes is padded with copies of its last mixture: a
    group on the lanes takes about as long as 16 mixtures one by one), any other mixture by
    :func:`_reduce_into` (same results, bit for bit)."""
    nb, k, d = m.shape
    kout = min(kmax, k)
    ow = np.zeros((nb, kout))
    om = np.zeros((nb, kout, d))
    ov = np.ones((nb, kout, d))
    cnt = np.zeros(nb, dtype=np.int64)
    L = _LANES
    ng = (nb + L - 1) // L
    for g in prange(ng):
        t = np.empty((3 * d + 10, k))
        b0 = g * L
        nl = min(L, nb - b0)
        same = d == 2
        n0 = -1
        if same:
            for ln in range(nl):
                c = 0
                for r in range(k):
                    c += 1 if w[b0 + ln, r] > 0 else 0
                if ln == 0:
                    n0 = c
                same = same and c == n0
            same = same and n0 > kout and 2 * nl > L
        if not same:
            for b in range(b0, b0 + nl):
                cnt[b] = _reduce_into(w[b], m[b], v[b], k, kout, tie, ow[b], om[b], ov[b], t)
            continue
        T = np.empty((k, _LANE_ROWS, L))
        _load_lanes(w, m, v, b0, nl, n0, T, t)
        _west_lanes(T, n0, kout, tie, t, ow[b0:b0 + nl], om[b0:b0 + nl], ov[b0:b0 + nl], nl)
        for b in range(b0, b0 + nl):
            cnt[b] = kout
    return ow, om, ov, cnt


def uniform_ball(radius, dim: int) -> DiagMixture:
    """Mixture approximating the uniform density on a ball centred at 0 (the motion model
    of Sect. 4), preserving mass, mean and covariance.

    ``dim=1``: the interval ``[-r, r]`` cut into 5 equal segments, each a Gaussian with the
    segment's centre and variance ``(2r/5)^2/12``. ``dim=2``: the disk cut into 7 cells of
    equal area (a central disk of radius ``r/sqrt 7`` and 6 annular sectors), components
    at the cell centroids, equal weights, one common isotropic variance chosen so that the
    per-axis variance equals the disk's ``r^2/4``. The component count does not depend on
    the radius.

    Parameters
    ----------
    radius : float or ndarray, shape (...)
        Radius ``r`` > 0.
    dim : int
        1 (interval) or 2 (disk).

    Returns
    -------
    DiagMixture
        Batch shape ``radius.shape``, 5 (1-D) or 7 (2-D) components.
    """
    r = np.asarray(radius, dtype=float)
    if np.any(r <= 0):
        raise InputError("radius: must be > 0")
    if dim == 1:
        n = 5
        centres = (np.arange(n) + 0.5) / n * 2.0 - 1.0                  # unit interval cells
        means = r[..., None, None] * centres[:, None]
        var = (2.0 * r / n) ** 2 / 12.0
        variances = np.broadcast_to(var[..., None, None], means.shape).copy()
    elif dim == 2:
        r0 = 1.0 / np.sqrt(7.0)
        half = np.pi / 6.0
        a = (2.0 / 3.0) * (1 - r0**3) / (1 - r0**2) * np.sin(half) / half
        ang = np.arange(6) * 2 * half
        centres = np.vstack([[0.0, 0.0], a * np.c_[np.cos(ang), np.sin(ang)]])
        s2 = 0.25 - (6.0 / 7.0) * a**2 / 2.0
        means = r[..., None, None] * centres
        variances = np.broadcast_to((s2 * r**2)[..., None, None], means.shape).copy()
        n = 7
    else:
        raise InputError(f"dim: uniform_ball supports 1 or 2, got {dim}")
    weights = np.full(means.shape[:-1], 1.0 / n)
    return DiagMixture(weights, means, variances)


def pad_components(mix: DiagMixture, k: int) -> DiagMixture:
    """Pad every mixture with empty slots (weight 0, mean 0, variance 1) up to ``k``.

    Parameters
    ----------
    mix : DiagMixture
        A batch of mixtures.
    k : int
        Number of component slots wanted (no change when ``mix`` has as many or more).

    Returns
    -------
    DiagMixture
        Same densities, ``max(k, K)`` slots.
    """
    extra = int(k) - mix.n_components
    if extra <= 0:
        return mix
    b = mix.batch_shape
    return DiagMixture(np.concatenate([mix.weights, np.zeros(b + (extra,))], -1),
                       np.concatenate([mix.means, np.zeros(b + (extra, mix.dim))], -2),
                       np.concatenate([mix.variances, np.ones(b + (extra, mix.dim))], -2))


def select(mask, new: DiagMixture, old: DiagMixture) -> DiagMixture:
    """Per-mixture choice between two batches: ``new`` where ``mask`` is True, else ``old``.

    Parameters
    ----------
    mask : array_like of bool, shape (...)
        The choice per mixture (broadcast against both batches).
    new, old : DiagMixture
        Batches of the same dimension; component counts are padded to the larger.

    Returns
    -------
    DiagMixture
        The chosen mixtures.
    """
    k = max(new.n_components, old.n_components)
    new, old = pad_components(new, k), pad_components(old, k)
    mk = np.asarray(mask)[..., None]
    return DiagMixture(np.where(mk, new.weights, old.weights),
                       np.where(mk[..., None], new.means, old.means),
                       np.where(mk[..., None], new.variances, old.variances))


def merge_groups(mix: DiagMixture, n_outer: int, keep: str) -> DiagMixture:
    """Moment-matched merge of the components of a product along one of its two factors:
    a fixed-structure reduction, continuous in its input.

    The ``K = n_outer * n_inner`` components of ``mix`` are read as the pairs ``(a, b)`` of
    :func:`product`, :func:`product_on`, :func:`convolve` or :func:`outer` (``a`` outer,
    ``b`` inner). ``keep="outer"`` merges, for every ``a``, its ``n_inner`` components into
    one (``n_outer`` components); ``keep="inner"`` merges, for every ``b``, its ``n_outer``
    components into one (``n_inner`` components). Each merged component has the total
    weight, the mean and the per-axis variances of its group (:func:`merge_moments`
    applied to the whole group), so the mass, the mean and the diagonal of the covariance
    of the mixture are preserved exactly.

    Which components merge is fixed by the structure, not decided by comparing costs: the
    result is a continuous (smooth where the group weights are positive) function of the
    weights, means and variances, it does not depend on the order of the components within
    a factor (sums), and rotating or translating the means rotates or translates it.
    A group of total weight 0 gives an empty slot (weight 0, mean 0, variance 1).

    Parameters
    ----------
    mix : DiagMixture
        A batch of products, ``n_outer * n_inner`` components each.
    n_outer : int
        Components of the outer factor ``a``.
    keep : str
        ``"outer"`` or ``"inner"``: the factor whose components are kept.

    Returns
    -------
    DiagMixture
        ``n_outer`` (``keep="outer"``) or ``n_inner`` components per mixture.
    """
    k = mix.n_components
    n_outer = int(n_outer)
    if n_outer < 1 or k % n_outer:
        raise InputError(f"n_outer: {n_outer} does not divide the {k} components")
    if keep not in ("outer", "inner"):
        raise InputError(f"keep: must be 'outer' or 'inner', got {keep!r}")
    shape = mix.batch_shape + (n_outer, k // n_outer)
    w = mix.weights.reshape(shape)
    m = mix.means.reshape(shape + (mix.dim,))
    v = mix.variances.reshape(shape + (mix.dim,))
    axis = -1 if keep == "outer" else -2
    total = w.sum(axis)
    a = w / np.expand_dims(np.where(total > 0, total, 1.0), axis)
    mean = np.sum(a[..., None] * m, axis=axis - 1)
    var = np.sum(a[..., None] * (v + (m - np.expand_dims(mean, axis - 1)) ** 2), axis=axis - 1)
    empty = (total <= 0)[..., None]
    return DiagMixture(total, np.where(empty, 0.0, mean), np.where(empty, 1.0, var))
