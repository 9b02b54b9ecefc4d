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

from dataclasses import dataclass

import numpy as np
from scipy.special import logsumexp, softmax

from radioloc.core.arrays import kernel_array
from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import InputError
from radioloc.core.validation import as_float_array
from radioloc.models.mixture_compiled import TIE as _TIE
from radioloc.models.mixture_compiled import reduce_batch

_LOG2PI = np.log(2.0 * np.pi)

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


def log_sum_exp(a: np.ndarray, axis: int = -1) -> np.ndarray:
    """``log sum exp`` along ``axis`` (``-inf`` where every term is), in plain NumPy
    (several times faster than ``scipy.special.logsumexp`` on the large arrays of a
    likelihood evaluated on a grid).

    Parameters
    ----------
    a : ndarray
    axis : int

    Returns
    -------
    ndarray
        ``a`` without ``axis``.
    """
    top = np.max(a, axis=axis, keepdims=True)
    top = np.where(np.isfinite(top), top, 0.0)
    with np.errstate(divide="ignore"):
        return np.log(np.sum(np.exp(a - top), axis=axis)) + np.squeeze(top, axis=axis)


def component_logpdf(points: np.ndarray, means: np.ndarray, variances: np.ndarray
                     ) -> np.ndarray:
    """``log N(x; mu_j, diag v_j)`` of every point under every axis-aligned component.

    The squared distance is expanded into products over the coordinates (no array of
    shape points x components x D) about the components' centre (no cancellation far from
    the origin).

    Parameters
    ----------
    points : ndarray, shape (..., D)
    means, variances : ndarray, shape (C..., D)
        Components (any leading shape ``C...``).

    Returns
    -------
    ndarray, shape (..., C...)
    """
    x = np.asarray(points, dtype=float)
    d = means.shape[-1]
    c = means.reshape(-1, d).mean(axis=0)
    xc, mc, iv = x - c, means - c, 1.0 / variances
    quad = (np.tensordot(xc * xc, iv, axes=([-1], [-1]))
            - 2.0 * np.tensordot(xc, mc * iv, axes=([-1], [-1]))
            + np.sum(mc * mc * iv, axis=-1))
    return -0.5 * (quad + np.sum(np.log(variances), axis=-1) + d * _LOG2PI)


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


def _logdet(v: np.ndarray) -> np.ndarray:
    """``log|P| = sum(log v)`` of axis-aligned covariances."""
    return np.sum(np.log(v), axis=-1)


def _canonical_first(mask: np.ndarray, w: np.ndarray, m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The tie rule of :func:`reduce`, per row of ``mask (B, K)`` (the tie set; ``w > 0``
    marks the mixture's components): the member nearest to the mixture's mean (squared
    distances within a relative ``_TIE`` count as equal); of two at the same distance (in
    2-D or more) the one the other follows counter-clockwise about the mean; otherwise the
    lowest in the canonical order (means, then variances, then weight, lexicographically).
    It reads the components' contents, never their positions."""
    first = np.argmax(mask, axis=-1)
    many = np.count_nonzero(mask, axis=-1) > 1
    if not np.any(many):
        return first
    cand, wm, mm, vm = mask[many], w[many], m[many], v[many]
    mu = np.sum(wm[..., None] * mm, axis=-2) / np.sum(wm, axis=-1)[..., None]
    r = np.sum((mm - mu[..., None, :]) ** 2, axis=-1)
    lim = np.min(np.where(cand, r, np.inf), axis=-1, keepdims=True) * (1.0 + _TIE)
    cand = cand & (r <= lim)
    pair = (np.count_nonzero(cand, axis=-1) == 2) & (m.shape[-1] >= 2)
    if np.any(pair):
        ab = np.argsort(~cand[pair], axis=-1, kind="stable")[:, :2]
        rows = np.arange(ab.shape[0])
        pa, pb, c0 = mm[pair][rows, ab[:, 0]], mm[pair][rows, ab[:, 1]], mu[pair]
        cross = (pa[:, 0] - c0[:, 0]) * (pb[:, 1] - c0[:, 1]) \
            - (pa[:, 1] - c0[:, 1]) * (pb[:, 0] - c0[:, 0])
        sure = np.abs(cross) > _TIE * lim[pair][:, 0]
        won = np.where(cross > 0, ab[:, 0], ab[:, 1])
        sub = cand[pair]
        sub[sure] = False
        sub[np.nonzero(sure)[0], won[sure]] = True
        cand[pair] = sub
    keys = [mm[..., e] for e in range(m.shape[-1])] + [vm[..., e] for e in range(v.shape[-1])] \
        + [wm]
    for key in keys:
        cand = cand & (key == np.min(np.where(cand, key, np.inf), axis=-1, keepdims=True))
    first[many] = np.argmax(cand, axis=-1)
    return first


def _partners(w, m, v, ld, act, i):
    """Per row, the partner ``j`` of component ``i``: Runnalls' cost of merging ``i`` into
    each active ``c``, the lowest cost, ties by :func:`_canonical_first`; returns
    ``(j, cost, scale)``.

    Runnalls' cost :func:`runnalls_cost` without cancellation:
    ``0.5 (w_i (log|P_c| - log|P_i|) + (w_i + w_c) log1p(y))`` with
    ``1 + y = |P_ic| / |P_c| = prod_e (1 + r_e)``,
    ``r_e = (a_1 (v_ie - v_ce) + a_1 a_2 dm_e^2) / v_ce``, ``a_1 = w_i / (w_i + w_c)``,
    ``a_2 = w_c / (w_i + w_c)``. Its rounding scale is
    ``0.5 (w_i (|log|P_c|| + |log|P_i||) + (w_i + w_c) (ay + |log1p(y)|))`` (``ay``: the
    same product of ``1 + |r_e|``, minus one); costs within ``2 _TIE scale`` of the lowest
    tie."""
    n = np.arange(w.shape[0])
    wi, ldi = w[n, i][:, None], ld[n, i][:, None]
    with np.errstate(all="ignore"):              # empty slots: masked below
        ws = wi + w
        a1, a2 = wi / ws, w / ws
        dm = m[n, i][:, None, :] - m
        r = (a1[..., None] * (v[n, i][:, None, :] - v) + (a1 * a2)[..., None] * dm * dm) / v
        y, ay = np.zeros_like(ws), np.zeros_like(ws)
        for e in range(m.shape[-1]):
            y, ay = y + r[..., e] + y * r[..., e], ay + np.abs(r[..., e]) + ay * np.abs(r[..., e])
        lp = np.log1p(y)
        cost = 0.5 * (wi * (ld - ldi) + ws * lp)
        scale = 0.5 * (wi * (np.abs(ld) + np.abs(ldi)) + ws * (ay + np.abs(lp)))
    cand = act.copy()
    cand[n, i] = False
    cost = np.where(cand, cost, np.inf)
    best = np.min(cost, axis=-1, keepdims=True)
    j = _canonical_first(cand & (cost <= best + 2.0 * _TIE * scale), w, m, v)
    return j, cost[n, j], scale[n, j]


def _reduce_numpy(mix: DiagMixture, kmax: int) -> DiagMixture:
    """West's greedy rule with Runnalls' cost, one merge per loop for the whole batch (the
    definition behind ``reduce(..., backend="numpy")``; see :func:`reduce`)."""
    k, d = mix.n_components, mix.dim
    w = mix.weights.reshape(-1, k).astype(float)
    m = mix.means.reshape(-1, k, d).astype(float)
    v = mix.variances.reshape(-1, k, d).astype(float)
    ld = _logdet(v)
    rows = np.arange(w.shape[0])
    while True:
        active = w > 0
        r = rows[active.sum(-1) > kmax]
        if r.size == 0:
            break
        n = np.arange(r.size)
        wr, mr, vr, ldr, act = w[r], m[r], v[r], ld[r], active[r]
        # i: the lowest weight; of weights tied with it, the one whose merge is cheapest
        wmin = np.min(np.where(act, wr, np.inf), axis=-1, keepdims=True)
        tied = act & (wr * (1.0 - _TIE) <= wmin)
        i = np.argmax(tied, axis=-1)
        q = np.nonzero(np.count_nonzero(tied, axis=-1) > 1)[0]
        if q.size:
            rep = np.repeat(q, k)
            _, co, sc = _partners(wr[rep], mr[rep], vr[rep], ldr[rep], act[rep],
                                  np.tile(np.arange(k), q.size))
            co = np.where(tied[q].reshape(-1), co, np.inf).reshape(q.size, k)
            bi = np.min(co, axis=-1, keepdims=True)
            i[q] = _canonical_first(co <= bi + 2.0 * _TIE * sc.reshape(q.size, k),
                                    wr[q], mr[q], vr[q])
        # j: its partner of lowest Runnalls cost; i is merged into j by moment matching
        j, _, _ = _partners(wr, mr, vr, ldr, act, i)
        wj, mj, vj = merge_moments(wr[n, i], mr[n, i], vr[n, i], wr[n, j], mr[n, j], vr[n, j])
        w[r, j], m[r, j], v[r, j], ld[r, j] = wj, mj, vj, _logdet(vj)
        w[r, i] = 0.0
    out = compact(DiagMixture(w, m, v))
    kk, bshape = out.n_components, mix.batch_shape
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


def reduce(mix: DiagMixture, max_components: int, method: str = "runnalls",
           backend: str = DEFAULT_BACKEND) -> DiagMixture:
    """Reduce every mixture of the batch to at most ``max_components`` components.

    ``method="runnalls"`` (default): West's (1993) greedy rule. While a mixture has more
    than ``max_components`` components, its lowest-weight component ``i`` is merged
    (:func:`merge_moments`) into the component ``j`` for which Runnalls' (2007) cost
    :func:`runnalls_cost` of the merge is smallest (computed without cancellation, see
    :func:`_partners`). Each merge preserves the mass, the mean and the per-axis variances
    of the pair, so the reduction preserves the mass, the mean and the diagonal of the
    covariance of the mixture.

    Ties: weights within a relative ``1e-9`` of the lowest, and costs within ``1e-9`` of
    their rounding scale of the lowest, count as tied. Of tied lowest weights the one with
    the cheapest best merge is merged; of tied partners (or tied cheapest merges) the one
    nearest the mixture mean is chosen, then counter-clockwise about it, then the
    lexicographic order of means, variances and weight (:func:`_canonical_first`). The rule
    reads contents, never positions, and the result comes in the canonical order of
    :func:`compact`: permuting the components of ``mix`` does not change it, rotating or
    translating the means rotates or translates it. The greedy rule is still a discrete
    choice: its result jumps where a near-tie flips (a continuous alternative for products:
    :func:`merge_groups`).

    ``method="progressive"``: the Progressive Bayes re-approximation of the paper's
    reference [3] (:func:`radioloc.models.progressive_bayes.progressive_reduce`, NumPy), a
    homotopy on the integral squared distance started from the West/Runnalls result (its
    ISD to ``mix`` is never larger; mass is kept, the mean and variances are not preserved
    exactly).

    Parameters
    ----------
    mix : DiagMixture
        A batch of mixtures.
    max_components : int
        The bound, >= 1.
    method : str
        ``"runnalls"`` or ``"progressive"``.
    backend : str
        ``"numba"`` (default: the compiled kernel, the mixtures in parallel) or ``"numpy"``
        (the definition, one merge per loop for the whole batch); they agree to rounding.

    Returns
    -------
    DiagMixture
        At most ``max_components`` components per mixture (compacted: sorted by decreasing
        weight, no trailing empty slot).
    """
    backend = check_backend(backend)
    if isinstance(max_components, bool) or int(max_components) < 1:
        raise InputError(f"max_components: must be >= 1, got {max_components}")
    kmax = int(max_components)
    if check_reduction(method) == "progressive":
        from radioloc.models.progressive_bayes import progressive_reduce

        return progressive_reduce(mix, kmax, backend=backend)
    if mix.n_components <= kmax:
        return compact(mix)
    if backend == "numpy":
        return _reduce_numpy(mix, kmax)
    bshape = mix.batch_shape
    k, d = mix.n_components, mix.dim
    ow, om, ov, cnt = reduce_batch(kernel_array(mix.weights.reshape(-1, k)),
                                   kernel_array(mix.means.reshape(-1, k, d)),
                                   kernel_array(mix.variances.reshape(-1, k, d)), kmax)
    kk = max(1, int(cnt.max(initial=1)))
    return DiagMixture(ow[:, :kk].reshape(bshape + (kk,)), om[:, :kk].reshape(bshape + (kk, d)),
                       ov[:, :kk].reshape(bshape + (kk, d)))


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
