"""Anchor self-calibration: anchors' positions and range biases from the ranges themselves.

Anchors are surveyed (known exactly), roughly known (a prior mean and standard deviation)
or both. What is measured:

- anchor-to-anchor two-way ranges ``r_ij = |a_i - a_j| + delta_i + delta_j + v``;
- and/or a tag's ranges as it moves, ``r_ta = |p_t - a| + delta_a + delta_tag + v``, with the
  tag's position ``p_t`` unknown at every epoch;

where ``delta`` is a device's range bias (antenna delay, an RTT offset), estimated when
asked, and ``v ~ N(0, std_m^2)``. The estimate is the maximum a posteriori of all unknowns
(rough anchors' positions, biases, the tag's positions), by nonlinear least squares
(``scipy.optimize.least_squares``, sparse Jacobian, optional robust loss): the batch
solution to which paper 000's network estimators with priors converge.

The covariance of the anchors is the inverse of the information matrix at the solution,
with the tag's positions marginalised out (Schur complement of their 2x2 / 3x3 blocks).
The Cramer-Rao bound is the same information evaluated with the linear loss: for the
default linear loss they coincide; with a robust loss the covariance uses the loss's
weights. Surveyed anchors are fixed, which also fixes the frame (give at least
``D + 1`` non-collinear surveyed anchors, or priors that pin the frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.validation import (LENGTH_LIMIT_M, POSITIVE_FLOOR, as_float_array, check_dtype,
                                      check_positive)

__all__ = ["AnchorCalibration", "calibrate_anchors"]

LOSSES = ("linear", "huber", "soft_l1", "cauchy")


@dataclass(frozen=True)
class AnchorCalibration:
    """The result of :func:`calibrate_anchors`.

    Attributes
    ----------
    position : ndarray, shape (A, D)
        Anchor positions (surveyed ones as given).
    covariance : ndarray, shape (A, D, D)
        Their posterior covariance (zero for surveyed anchors), m^2.
    crb : ndarray, shape (A, D, D)
        The Cramer-Rao bound (with the priors) at the estimated geometry, m^2.
    bias_m : ndarray, shape (A,) or None
        Estimated range bias of each anchor (None when not estimated).
    bias_std_m : ndarray, shape (A,) or None
    tag_bias_m : float or None
        The tag's own range bias.
    tag_position : ndarray, shape (T, D) or None
        The tag's estimated positions at its epochs.
    residual_rms_m : float
        Root-mean-square range residual at the solution.
    converged : bool
    """

    position: np.ndarray
    covariance: np.ndarray
    crb: np.ndarray
    bias_m: np.ndarray | None
    bias_std_m: np.ndarray | None
    tag_bias_m: float | None
    tag_position: np.ndarray | None
    residual_rms_m: float
    converged: bool


def _rows(value, name: str, n_anchors: int, with_epoch: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    arr = (check_dtype(value, name).astype(float) if value is not None
           else np.zeros((0, 3)))
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name}: expected rows of 3 numbers "
                         f"({'epoch, anchor, range' if with_epoch else 'anchor i, anchor j, range'}),"
                         f" got shape {arr.shape}")
    i, j, r = arr[:, 0], arr[:, 1], arr[:, 2]
    if np.any(i != np.round(i)) or np.any(j != np.round(j)):
        raise InputError(f"{name}: indices must be whole numbers")
    hi = n_anchors        # bounds checked on the floats: a huge index does not fit an int
    if np.any(j < 0) or np.any(j >= hi) or (not with_epoch and (np.any(i < 0) or np.any(i >= hi))):
        raise InputError(f"{name}: anchor index out of range 0..{hi - 1}")
    if with_epoch and (np.any(i < 0) or np.any(i >= 2.0 ** 63)):
        raise InputError(f"{name}: epoch indices must be whole numbers from 0 to 2**63 - 1")
    i, j = i.astype(int), j.astype(int)
    if not with_epoch and np.any(i == j):
        k = int(np.flatnonzero(i == j)[0])
        raise InputError(f"{name}: row {k} ranges anchor {i[k]} to itself")
    if np.any(~np.isfinite(r)) or np.any(r < 0) or np.any(r > LENGTH_LIMIT_M):
        k = int(np.flatnonzero(~np.isfinite(r) | (r < 0) | (r > LENGTH_LIMIT_M))[0])
        raise InputError(f"{name}: row {k}: range {r[k]:g} is not a finite number from 0 to "
                         f"{LENGTH_LIMIT_M:g} m")
    return i, j, r


def calibrate_anchors(prior_position, prior_std_m, *, anchor_ranges=None, tag_ranges=None,
                      std_m: float = 0.1, estimate_bias: bool = False,
                      bias_prior_std_m: float = 1.0, loss: str = "linear",
                      max_iterations: int = 200) -> AnchorCalibration:
    """Estimate anchors' positions (and range biases) from ranges and priors.

    Parameters
    ----------
    prior_position : array_like, shape (A, D)
        Surveyed or rough anchor positions, metres.
    prior_std_m : array_like, shape (A,)
        Prior standard deviation of each anchor's position per axis: 0 for a surveyed
        anchor (held fixed), > 0 for a rough one.
    anchor_ranges : array_like, shape (K, 3), optional
        Rows ``(i, j, range_m)`` between anchors ``i`` and ``j`` (indices into the table).
    tag_ranges : array_like, shape (L, 3), optional
        Rows ``(epoch, anchor, range_m)`` of a moving tag; ranges with the same epoch
        index share one unknown tag position.
    std_m : float
        Standard deviation of a range, metres.
    estimate_bias : bool
        Estimate each device's range bias (anchors and the tag).
    bias_prior_std_m : float
        Prior standard deviation of a bias around 0, metres.
    loss : {"linear", "huber", "soft_l1", "cauchy"}
        Loss on the range residuals in units of ``std_m`` (robust losses down-weight
        outliers such as NLOS ranges).
    max_iterations : int

    Returns
    -------
    AnchorCalibration

    Raises
    ------
    InputError
        Malformed arguments, naming them.
    GeometryError
        The ranges and priors leave some unknown undetermined (a singular information
        matrix: too few surveyed anchors or ranges), naming the anchors concerned.
    """
    prior = as_float_array(prior_position, "prior_position", ndim=2, last_dim=(2, 3))
    A, D = prior.shape
    pstd = as_float_array(prior_std_m, "prior_std_m", ndim=1, nonnegative=True)
    if pstd.shape != (A,):
        raise InputError(f"prior_std_m: expected {A} values (one per anchor), got {pstd.shape}")
    tiny = np.flatnonzero((pstd > 0) & (pstd < POSITIVE_FLOOR))
    if tiny.size:
        raise InputError(f"prior_std_m: {pstd[tiny[0]]:g} (anchor {int(tiny[0])}) is below the "
                         f"supported floor of {POSITIVE_FLOOR:g} m (0: a surveyed anchor)")
    check_positive(std_m, "std_m")
    check_positive(bias_prior_std_m, "bias_prior_std_m")
    if loss not in LOSSES:
        raise InputError(f"loss: expected one of {', '.join(LOSSES)}, got {loss!r}")
    ai, aj, ar = _rows(anchor_ranges, "anchor_ranges", A, with_epoch=False)
    te, ta, tr = _rows(tag_ranges, "tag_ranges", A, with_epoch=True)
    if ai.size + te.size == 0:
        raise InputError("anchor_ranges, tag_ranges: give at least one range")
    free = np.flatnonzero(pstd > 0)
    epochs, te = np.unique(te, return_inverse=True) if te.size else (np.zeros(0, int), te)
    T = epochs.size
    has_tag = T > 0
    n_bias = (A + int(has_tag)) if estimate_bias else 0
    # unknown vector: [free anchors (F*D) | tag positions (T*D) | biases (A [+1])]
    F = free.size
    slot = np.full(A, -1)
    slot[free] = np.arange(F)
    n = F * D + T * D + n_bias
    o_tag, o_bias = F * D, F * D + T * D

    def anchor_pos(u):
        pos = prior.copy()
        pos[free] = u[:o_tag].reshape(F, D)
        return pos

    def residuals(u):
        pos = anchor_pos(u)
        tag = u[o_tag:o_bias].reshape(T, D)
        bias = u[o_bias:] if n_bias else np.zeros(A + 1)
        res = [(ar - np.linalg.norm(pos[ai] - pos[aj], axis=1) - bias[ai] - bias[aj]) / std_m]
        if has_tag:
            res.append((tr - np.linalg.norm(tag[te] - pos[ta], axis=1) - bias[ta]
                        - (bias[A] if n_bias else 0.0)) / std_m)
        return np.concatenate(res)

    def priors(u):
        out = [((u[:o_tag].reshape(F, D) - prior[free]) / pstd[free, None]).ravel()]
        if n_bias:
            out.append(u[o_bias:] / bias_prior_std_m)
        return np.concatenate(out)

    n_range = ai.size + te.size

    def fun(u):
        return np.concatenate([residuals(u), priors(u)])

    n_prior = F * D + n_bias

    def jac(u):
        """Analytic Jacobian of ``fun`` (sparse): unit vectors, bias indicators, prior rows."""
        pos = anchor_pos(u)
        tag = u[o_tag:o_bias].reshape(T, D)
        rows, cols, vals = [], [], []

        def put(r_idx, c_idx, v):
            rows.append(r_idx)
            cols.append(c_idx)
            vals.append(v)

        diff = pos[ai] - pos[aj]
        unit = diff / np.maximum(np.linalg.norm(diff, axis=1), 1e-12)[:, None]
        k = np.arange(ai.size)
        for idx, sign in ((ai, -1.0), (aj, 1.0)):
            ok = slot[idx] >= 0
            for d in range(D):
                put(k[ok], slot[idx][ok] * D + d, sign * unit[ok, d] / std_m)
        if has_tag:
            diff = tag[te] - pos[ta]
            unit = diff / np.maximum(np.linalg.norm(diff, axis=1), 1e-12)[:, None]
            k = ai.size + np.arange(te.size)
            ok = slot[ta] >= 0
            for d in range(D):
                put(k, o_tag + te * D + d, -unit[:, d] / std_m)
                put(k[ok], slot[ta][ok] * D + d, unit[ok, d] / std_m)
        if n_bias:
            k = np.arange(ai.size)
            put(k, o_bias + ai, np.full(k.size, -1.0 / std_m))
            put(k, o_bias + aj, np.full(k.size, -1.0 / std_m))
            if has_tag:
                k = ai.size + np.arange(te.size)
                put(k, o_bias + ta, np.full(k.size, -1.0 / std_m))
                put(k, np.full(k.size, o_bias + A), np.full(k.size, -1.0 / std_m))
        k = n_range + np.arange(n_prior)
        put(k[:F * D], np.arange(F * D), np.repeat(1.0 / pstd[free], D))
        put(k[F * D:], o_bias + np.arange(n_bias), np.full(n_bias, 1.0 / bias_prior_std_m))
        r, c, v = (np.concatenate(x) for x in (rows, cols, vals))
        return sp.coo_matrix((v, (r, c)), shape=(n_range + n_prior, n)).tocsr()

    u0 = np.zeros(n)
    u0[:o_tag] = prior[free].ravel()
    if has_tag:                                   # each epoch starts at the centroid of its anchors
        w = np.bincount(te, minlength=T)
        for d in range(D):
            u0[o_tag + d: o_bias: D] = np.bincount(te, weights=prior[ta, d], minlength=T) / np.maximum(w, 1)
        u0[o_tag:o_bias] += 1e-3 * np.arange(T * D) % 1.0     # off the anchors' exact centroid
    # a robust loss is non-convex: start it from the least-squares solution
    for stage in (("linear", loss) if loss != "linear" else ("linear",)):
        fit = least_squares(fun, u0, jac=jac, loss=stage, f_scale=1.0, max_nfev=max_iterations,
                            x_scale="jac", method="trf", tr_solver="lsmr")
        u0 = fit.x
    u = fit.x
    J = jac(u)                                    # unweighted: the Fisher information's
    info = _information(J, None)
    w = None
    if loss != "linear":                          # IRLS weights of the loss at the solution
        z = fun(u)[:n_range] ** 2
        rho = {"huber": lambda s: np.where(s <= 1, 1.0, 1 / np.sqrt(s)),
               "soft_l1": lambda s: 1 / np.sqrt(1 + s),
               "cauchy": lambda s: 1 / (1 + s)}[loss](z)
        w = np.concatenate([rho, np.ones(n_prior)])
    cov_all = _marginal_cov(_information(J, w), F * D, T, D, n_bias)
    crb_all = _marginal_cov(info, F * D, T, D, n_bias)
    if cov_all is None or crb_all is None:
        raise GeometryError("calibrate_anchors: the ranges and priors do not determine every "
                            f"unknown (rough anchors {free.tolist()}); add surveyed anchors, "
                            "ranges or tighter priors")

    def per_anchor(m):
        out = np.zeros((A, D, D))
        for k, a in enumerate(free):
            out[a] = m[k * D:(k + 1) * D, k * D:(k + 1) * D]
        return out

    pos = anchor_pos(u)
    bias = bias_std = tag_bias = None
    if n_bias:
        nb = F * D
        bias = u[o_bias:o_bias + A]
        bias_std = np.sqrt(np.diag(cov_all)[nb:nb + A])
        tag_bias = float(u[o_bias + A]) if has_tag else None
    res = fun(u)[:n_range] * std_m
    return AnchorCalibration(
        position=pos, covariance=per_anchor(cov_all), crb=per_anchor(crb_all), bias_m=bias,
        bias_std_m=bias_std, tag_bias_m=tag_bias,
        tag_position=u[o_tag:o_bias].reshape(T, D) if has_tag else None,
        residual_rms_m=float(np.sqrt(np.mean(res ** 2))), converged=bool(fit.success))


def _information(J: sp.csr_matrix, w: np.ndarray | None) -> sp.csr_matrix:
    """``J^T W J`` (sparse)."""
    if w is None:
        return (J.T @ J).tocsr()
    return (J.T @ sp.diags(w) @ J).tocsr()


def _marginal_cov(info: sp.csr_matrix, n_anchor: int, T: int, D: int, n_bias: int) -> np.ndarray | None:
    """Covariance of the anchors' coordinates and biases with the tag's epochs marginalised
    (Schur complement of the block-diagonal epoch part); None if singular."""
    info = info.tocsr()
    keep = np.concatenate([np.arange(n_anchor), n_anchor + T * D + np.arange(n_bias)])
    tag = n_anchor + np.arange(T * D)
    Akk = info[keep][:, keep].toarray()
    if T:
        B = info[keep][:, tag].toarray()
        Dtt = info[tag][:, tag].toarray().reshape(T, D, T, D)
        blocks = Dtt[np.arange(T), :, np.arange(T), :]           # (T, D, D)
        if np.any(np.abs(np.linalg.det(blocks)) < 1e-12 * np.max(np.abs(blocks)) ** D):
            return None
        inv = np.linalg.inv(blocks)
        Bt = B.reshape(len(keep), T, D)
        Akk = Akk - np.einsum("ktd,tde,jte->kj", Bt, inv, Bt)
    if Akk.size == 0:
        return Akk
    try:
        w = np.linalg.eigvalsh(Akk)
    except np.linalg.LinAlgError:
        return None
    if w[0] <= 1e-10 * max(w[-1], 1e-300):
        return None
    return np.linalg.inv(Akk)
