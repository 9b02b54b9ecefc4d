"""Batched multilateration from ranges to known anchors (snapshot estimator).

:class:`Multilateration` solves ``min_x sum_i w_i (r_i - ||x - a_i||)^2`` for a whole batch
of independent problems at once: a configuration of the generic snapshot least squares
(:class:`~radioloc.estimators.least_squares.LeastSquares` with a Gaussian
:class:`~radioloc.models.ranging.RangeModel`, Gauss-Newton or Levenberg-Marquardt) from
the closed-form start of :func:`linear_initial`, with the geometry checks of a range fix
around it (flat anchors, saddle points, mirror fixes, singular information). ``ranges`` is ``(..., M)`` and
``anchors`` ``(M, D)`` or ``(..., M, D)``; a NaN range (or a weight of 0) is a missing
range, so epochs that hear different anchor sets share one array.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.renamed import Renamed, renamed_keywords
from radioloc.core.results import Estimate
from radioloc.core.validation import (MAGNITUDE_LIMIT, MAX_ITERATIONS, POSITIVE_FLOOR, as_float_array,
                                      check_int, check_positive, check_ranges)
from radioloc.estimators.base import SnapshotEstimator
from radioloc.estimators.least_squares import LeastSquares
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

__all__ = ["Multilateration", "anchor_phrase", "linear_initial"]

#: condition number of ``J^T W J`` above which the geometry does not fix the position
_COND_LIMIT = 1e10
#: Gauss-Newton iterations on the whole batch before the open problems go on alone
#: (:meth:`Multilateration._solve`).
FIRST_PASS = 10


def _first(mask: np.ndarray) -> tuple[int, ...]:
    return tuple(int(i) for i in np.argwhere(mask)[0])


def linear_initial(ranges: np.ndarray, anchors: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Closed-form start: weighted least squares on ``||x||^2 - 2 a_i^T x = r_i^2 - ||a_i||^2``.

    ``||x||^2`` is treated as an extra unknown, which makes the system linear; it needs
    ``D + 1`` ranges in general position.

    Parameters
    ----------
    ranges : ndarray, shape (..., M)
        Ranges in metres (entries with weight 0 must be finite, e.g. 0).
    anchors : ndarray, shape (..., M, D)
        Anchor positions in metres.
    weights : ndarray, shape (..., M)
        Non-negative weights; 0 marks a missing range.

    Returns
    -------
    ndarray, shape (..., D)
        The starting positions.
    """
    d = anchors.shape[-1]
    A = np.concatenate([-2.0 * anchors, np.ones(anchors.shape[:-1] + (1,))], axis=-1)
    b = ranges**2 - np.sum(anchors**2, axis=-1)
    AtA = np.einsum("...m,...mi,...mj->...ij", weights, A, A)
    Atb = np.einsum("...m,...mi,...m->...i", weights, A, b)
    # small ridge keeps exactly-determined problems solvable; the NLLS refines afterwards
    AtA = AtA + 1e-9 * np.trace(AtA, axis1=-2, axis2=-1)[..., None, None] * np.eye(d + 1)
    return np.linalg.solve(AtA, Atb[..., None])[..., 0][..., :d]


def anchor_phrase(indices) -> str:
    """``"anchors 0, 2, 3"``: the anchors (indices into ``anchors``) a geometry error is
    about; the command line replaces the phrase by the anchors' ids."""
    return "anchors " + ", ".join(str(int(i)) for i in indices)


def _pick(mask, new, old):
    """The fit (a result of ``solve_nlls``) taking ``new``'s fields where ``mask`` (...) is
    True and ``old``'s elsewhere."""
    return type(new)(**{k: np.where(mask.reshape(mask.shape + (1,) * (np.ndim(v) - mask.ndim)),
                                     v, getattr(old, k)) for k, v in vars(new).items()})


def _anchor_frame(anchors: np.ndarray, used: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Centroid ``(..., D)``, singular values ``(..., D)`` and right singular vectors
    ``(..., D, D)`` of the used anchors (centred)."""
    w = used.astype(float)
    centroid = np.einsum("...m,...md->...d", w, anchors) / w.sum(-1)[..., None]
    centred = np.where(used[..., None], anchors - centroid[..., None, :], 0.0)
    _, sv, vt = np.linalg.svd(centred, full_matrices=False)
    return centroid, sv, vt


def _flat_anchors(anchors: np.ndarray, used: np.ndarray) -> tuple[np.ndarray, str]:
    """Where the used anchors are coincident, collinear (2-D) or coplanar (3-D) (the ranges
    then fit a mirror image of the position as well), and the reason."""
    d = anchors.shape[-1]
    _, sv, _ = _anchor_frame(anchors, used)
    flat = sv[..., d - 1] <= 1e-9 * np.maximum(sv[..., 0], 1e-300)
    shape = "collinear" if d == 2 else "coplanar"
    return flat, (f"the anchors used are {shape}: the position and its mirror image across "
                  "them fit the ranges equally")


def _range_cost(pos: np.ndarray, r: np.ndarray, a: np.ndarray, w: np.ndarray) -> np.ndarray:
    """``sum_i w_i (r_i - ||pos - a_i||)^2`` ``(...)`` for ranges ``(..., M)`` to anchors
    ``(..., M, D)``."""
    dist = np.sqrt(np.sum((pos[..., None, :] - a) ** 2, axis=-1))
    return np.sum(w * (r - dist) ** 2, axis=-1)


class Multilateration(SnapshotEstimator):
    """Batched multilateration to anchors by nonlinear least squares.

    Parameters
    ----------
    method : {"gauss-newton", "levenberg-marquardt"}
        Step of the least squares (:func:`radioloc.estimators.nlls.solve_nlls`:
        Gauss-Newton with step halving, or Levenberg-Marquardt).
    std_m : float, optional
        Range error standard deviation, metres, used for the covariance. Default: estimated
        from the residuals of each problem (``M - D`` degrees of freedom). The old keyword
        ``range_std_m`` still works with a ``FutureWarning``.
    max_iter : int
        Maximum iterations per problem.
    tol_m : float
        A problem converges when its accepted step is no longer than this (m).
    on_degenerate : {"raise", "flag"}
        What a problem whose geometry does not fix the position does (collinear or
        coplanar anchors, an ambiguous mirror fix, a singular information matrix, no
        converged fix): ``"raise"`` a :class:`GeometryError` naming the first such problem, or ``"flag"``
        it in ``diagnostics["degenerate"]`` (its covariance is then NaN, and the caller
        must drop or report it).

    Raises
    ------
    ConfigError
        A setting is out of range (the message names it).
    """

    name = "gn"

    @renamed_keywords({"range_std_m": Renamed("std_m")},
                      positional=("range_std_m", "max_iter", "tol_m", "on_degenerate"))
    def __init__(self, method: str = "gauss-newton", *, std_m: float | None = None,
                 max_iter: int = 50, tol_m: float = 1e-9, on_degenerate: str = "raise") -> None:
        if on_degenerate not in ("raise", "flag"):
            raise ConfigError(f"on_degenerate: must be 'raise' or 'flag', got {on_degenerate!r}")
        self.on_degenerate = on_degenerate
        if method not in ("gauss-newton", "levenberg-marquardt"):
            raise ConfigError("method: must be 'gauss-newton' or 'levenberg-marquardt', "
                              f"got {method!r}")
        if std_m is not None:
            try:
                std_m = check_positive(std_m, "std_m")
            except InputError as exc:
                raise ConfigError(str(exc)) from None
        self.method = method
        self.std_m = None if std_m is None else float(std_m)
        self.max_iter = check_int(max_iter, "max_iter", minimum=1, maximum=MAX_ITERATIONS)
        self.tol_m = check_positive(tol_m, "tol_m", allow_zero=True)

    def _solve(self, r, a, w, x0, max_iter: int | None = None):
        """The least-squares fit (:meth:`LeastSquares.solve
        <radioloc.estimators.least_squares.LeastSquares.solve>`) of ranges ``r`` ``(..., M)``
        to anchors ``a`` ``(..., M, D)`` with weights ``w`` (0: missing) from ``x0``.

        The rows are a :class:`~radioloc.models.ranging.RangeModel` observation with the
        standard deviation ``w^-1/2`` each (1 m with unit weights), so the driver's cost is
        ``sum w (r - ||x - a||)^2`` and its information ``J^T W J``.

        Gauss-Newton runs ``FIRST_PASS`` iterations on the whole batch, then the rest on the
        problems still open only: an iterate depends on the previous one alone, so the fit
        is the one of a single run, while one slow problem no longer keeps every problem of
        a large batch iterating (Levenberg-Marquardt carries its damping: a single run)."""
        total = self.max_iter if max_iter is None else max_iter
        if self.method != "gauss-newton" or total <= FIRST_PASS:
            return self._fit(r, a, w, x0, total)
        fit = self._fit(r, a, w, x0, FIRST_PASS)
        open_ = ~(fit.converged | fit.stalled)
        if not open_.any():
            return fit
        more = self._fit(r[open_], a[open_], w[open_], fit.x[open_], total - FIRST_PASS)
        more = dataclasses.replace(more, iterations=more.iterations + fit.iterations[open_])
        joined = {}
        for field in dataclasses.fields(fit):
            value = np.array(getattr(fit, field.name))
            value[open_] = getattr(more, field.name)
            joined[field.name] = value
        return dataclasses.replace(fit, **joined)

    def _fit(self, r, a, w, x0, max_iter: int):
        """One :meth:`LeastSquares.solve` of :meth:`_solve`."""
        with np.errstate(divide="ignore"):
            std = np.where(w > 0, 1.0 / np.sqrt(np.where(w > 0, w, 1.0)), 1.0)
        obs = Observation(RangeModel(std_m=1.0), np.where(w > 0, r, np.nan), Context(points=a),
                          std=std)
        return LeastSquares(method=self.method, tol=self.tol_m,
                            max_iterations=max_iter).solve(obs, initial=x0)

    def _leave_saddles(self, fit, r, a, w):
        """Re-solve the problems whose fit is a saddle point of the cost, not a minimum.

        Gauss-Newton stops (or stalls) wherever the gradient vanishes; on the line (plane) of nearly
        collinear (coplanar) anchors the gradient across it vanishes by symmetry although
        the cost falls on both sides (exact ranges from a node 25 m off such a line gave a
        "converged" fix on the line with a 15 m residual). The exact Hessian of
        ``sum w e^2 / 2`` with ``e_i = r_i - d_i`` is
        ``sum w_i (u_i u_i^T - e_i (I - u_i u_i^T) / d_i)`` (``u_i`` the unit vector from
        anchor i, ``d_i`` the distance); where its smallest eigenvalue is negative the
        cost is searched along that eigenvector on both sides (a geometric grid of step
        lengths from ``1e-12`` to 4 times the anchors' extent, ratio ``sqrt 2``), the
        problem solved again from the best point of each side, and the better of the two
        kept (the mirror check then decides whether they tie). The Gauss-Newton
        information across the line of nearly collinear anchors is almost zero near the
        line, so a Gauss-Newton step from a fixed small offset overshoots by orders of
        magnitude and stalls (a node 0.28 m from such a line stalled on the line); the
        line search puts the restart in the basin itself.

        Returns the fit and the mask of problems still at a saddle point afterwards.
        """
        saddle, down, _ = self._saddles(fit, r, a, w)
        if not np.any(saddle):
            return fit, saddle
        rs, as_, ws = r[saddle], a[saddle], w[saddle]
        down = down[saddle]
        x_s = fit.x[saddle]
        extent = np.max(np.abs(as_ - x_s[..., None, :]), axis=(-2, -1))
        lengths = extent[..., None] * 2.0 ** np.arange(-40.0, 2.25, 0.5)    # (k, T)
        best = None
        for sign in (1.0, -1.0):
            trial = x_s[..., None, :] + sign * lengths[..., None] * down[..., None, :]  # (k, T, D)
            with np.errstate(all="ignore"):
                cost = _range_cost(trial, rs[..., None, :], as_[..., None, :, :],
                                   ws[..., None, :])
            cost = np.where(np.isfinite(cost), cost, np.inf)
            pick = np.argmin(cost, axis=-1)
            start = np.take_along_axis(trial, pick[..., None, None], axis=-2)[..., 0, :]
            sub = self._solve(rs, as_, ws, start)
            if best is None:
                best = sub
            else:
                take = sub.cost < best.cost
                best = _pick(take, sub, best)
        keep = best.cost < fit.cost[saddle]
        out = type(fit)(**{k: np.array(v, copy=True) for k, v in vars(fit).items()})
        kept = _pick(keep, best, type(fit)(**{k: v[saddle] for k, v in vars(out).items()}))
        for k, val in vars(kept).items():
            getattr(out, k)[saddle] = val
        return out, self._saddles(out, r, a, w)[0]

    @staticmethod
    def _saddles(fit, r, a, w):
        """Where the exact Hessian of the cost has a negative eigenvalue ``(...)``, the
        eigenvector of its smallest eigenvalue ``(..., D)``, and the Newton decrement
        ``g^T H^-1 g`` (the cost decrease a Newton step predicts; infinite at a saddle)."""
        diff = fit.x[..., None, :] - a
        dist = np.linalg.norm(diff, axis=-1)
        with np.errstate(all="ignore"):
            u = diff / dist[..., None]
            e = np.where(w > 0, r - dist, 0.0)
            eye = np.eye(a.shape[-1])
            hess = np.einsum("...m,...mi,...mj->...ij", w, u, u) - np.einsum(
                "...m,...mij->...ij", w * e / dist, eye - u[..., :, None] * u[..., None, :])
            grad = -np.einsum("...m,...mi->...i", w * e, u)        # of sum w e^2 / 2
        ok = (np.all(np.isfinite(hess), axis=(-2, -1)) & np.all(np.isfinite(grad), axis=-1)
              & np.all(dist > 0, axis=-1))
        hess = np.where(ok[..., None, None], hess, np.eye(a.shape[-1]))
        grad = np.where(ok[..., None], grad, 0.0)
        lam, vec = np.linalg.eigh(hess)
        saddle = ok & np.isfinite(fit.cost) & (lam[..., 0] < -1e-9 * np.abs(lam[..., -1]))
        proj = np.einsum("...di,...d->...i", vec, grad)
        with np.errstate(all="ignore"):
            dec = 2.0 * np.sum(np.where(lam > 0, proj ** 2 / lam, np.where(proj == 0, 0.0, np.inf)),
                               axis=-1)
        return saddle, vec[..., 0], np.where(saddle, np.inf, dec)

    def _resolve_mirror(self, fit, r, a, used, w, n_used, origin):
        """The mirror check with one solve for the well-posed problems.

        Each solution is reflected across the anchors' best-fit line (2-D) or plane (3-D)
        and the cost of the reflected point is evaluated (one residual evaluation). Only
        where the reflection fits the ranges within ``4 s^2`` of the solution or better
        (nearly collinear / coplanar anchors, or a solution stuck in the worse of two
        basins), or within the reflection's own error where the anchors lie within 1 % of
        their spread of a line (plane), and is a different point (more than ``1e-6`` of the
        anchors' spread from the solution), is the problem solved again from the
        reflection, on that subset only (for anchors that are not nearly flat, only a
        reflection more than ``10 s`` away: closer it is the same fix). Of the two minima the better fit is kept; where
        they are different points (``1e-6`` of the spread apart, beyond the solver's
        tolerance) and their costs differ by at most ``4 s^2`` (``s`` the configured
        ``std_m``, else the residual estimate) the ranges cannot tell them apart
        and the fix is ambiguous. The distance between the two is not compared with
        ``s``: across the line of nearly collinear anchors the position's uncertainty is
        many times ``s`` (a node 0.28 m off such a line with ``s`` = 0.1 m was fixed in
        whichever basin the solver reached). A reflection that fits worse than that is
        not refined: for anchors far from a line or plane the mirror basin is not a near
        tie.

        Returns the (possibly switched) fit, the ambiguous mask, a function wording the
        reason for one problem, and the number of problems solved twice.
        """
        d = a.shape[-1]
        centroid, sv, vt = _anchor_frame(a, used)
        normal = vt[..., d - 1, :]                              # least-spread direction
        offset = np.einsum("...d,...d->...", fit.x - centroid, normal)
        mirror = fit.x - 2.0 * offset[..., None] * normal
        c_mirror = _range_cost(mirror, r, a, w)
        dof = np.maximum(n_used - d, 1)
        scale = np.maximum(sv[..., 0], 1.0)
        distinct = 1e-6 * scale + 10.0 * self.tol_m

        def noise_var(other_cost):
            if self.std_m is not None:
                s2 = np.full(fit.cost.shape, self.std_m ** 2)
            else:
                s2 = np.minimum(fit.cost, other_cost) / dof
            return np.maximum(s2, (1e-9 * scale) ** 2)

        s2_m = noise_var(c_mirror)
        # Anchors that are only nearly on the line (plane): the reflection lands beside the
        # mirror solution. Anchor i at distance e_i from the line moves each reflected range
        # by at most 2 e_i (triangle inequality), so the mirror basin can fit as well as
        # the solution although the reflected point fits worse by up to that much.
        e = np.where(used, np.einsum("...md,...d->...m", a - centroid[..., None, :], normal), 0.0)
        slack = 2.0 * np.sqrt(np.sum(w * e ** 2, axis=-1))
        nearly_flat = slack <= 1e-2 * scale * np.sqrt(np.max(np.where(used, w, 0.0), axis=-1))
        # a reflection within 10 s of the solution is the same fix where the anchors are
        # spread (the position's error is about s); across nearly collinear (coplanar)
        # anchors it is many times s, so there any different point is checked
        far = 2.0 * np.abs(offset) > np.where(nearly_flat, distinct,
                                              10.0 * np.sqrt(s2_m) + 1e-6 * scale)
        tie = c_mirror <= fit.cost + 4.0 * s2_m
        tie |= nearly_flat & (np.sqrt(c_mirror) <= np.sqrt(fit.cost + 4.0 * s2_m) + slack)
        maybe = far & np.isfinite(c_mirror) & tie
        alt = type(fit)(**{k: np.array(v, copy=True) for k, v in vars(fit).items()})
        alt.x = np.array(mirror, copy=True)
        alt.cost = np.array(c_mirror, copy=True)
        alt.converged = np.zeros(fit.cost.shape, dtype=bool)
        if np.any(maybe):
            sub = self._solve(r[maybe], a[maybe], w[maybe], mirror[maybe])
            sub, _ = self._leave_saddles(sub, r[maybe], a[maybe], w[maybe])
            for k, v in vars(sub).items():
                getattr(alt, k)[maybe] = v
            # the solution itself, solved on from where it stopped, or from the reflection
            # of the mirror's minimum where that fits better: across nearly flat anchors
            # the solver can stop short in the weak direction (Levenberg-Marquardt 8 m
            # short, 190 m from 3 anchors within 1e-5 m of a line), and the two basins are
            # compared at their minima
            back_off = np.einsum("...d,...d->...", alt.x - centroid, normal)
            back = alt.x - 2.0 * back_off[..., None] * normal
            start = np.where((_range_cost(back, r, a, w) < fit.cost)[..., None], back, fit.x)
            again = self._solve(r[maybe], a[maybe], w[maybe], start[maybe])
            again, _ = self._leave_saddles(again, r[maybe], a[maybe], w[maybe])
            gain = np.zeros(maybe.shape, dtype=bool)
            gain[maybe] = again.cost < fit.cost[maybe] * (1 - 1e-9) - 1e-300
            if np.any(gain):
                fit = type(fit)(**{k: np.array(v, copy=True) for k, v in vars(fit).items()})
                keep = gain[maybe]
                for k, v in vars(again).items():
                    getattr(fit, k)[gain] = np.asarray(v)[keep]
        better = maybe & (alt.cost < fit.cost * (1 - 1e-9) - 1e-300)
        s2 = noise_var(alt.cost)
        apart = np.linalg.norm(alt.x - fit.x, axis=-1) > distinct
        # the mirror solve is a competing fix where it converged, or where it stalled (no
        # step lowers the cost in rounding, as in a weak direction) with an exact Newton
        # step promising less than s^2: a minimum within the noise
        _, _, dec = self._saddles(alt, r, a, w)
        minimum = alt.converged | (dec <= s2)
        ambiguous = maybe & apart & (np.abs(alt.cost - fit.cost) <= 4.0 * s2) & minimum
        first, second = fit, alt
        shape = "collinear" if d == 2 else "coplanar"

        def detail(idx):
            p, q = first.x[idx] + origin[idx], second.x[idx] + origin[idx]
            return (f"ambiguous fix: {np.array2string(p, precision=3)} and its mirror "
                    f"{np.array2string(q, precision=3)} fit the ranges equally well "
                    f"({anchor_phrase(np.flatnonzero(used[idx]))} nearly {shape} seen from "
                    "the node)")
        if np.any(better):
            def pick(x, y):
                return np.where(better.reshape(better.shape + (1,) * (x.ndim - better.ndim)), y, x)
            fit = type(fit)(**{k: pick(getattr(first, k), getattr(second, k)) for k in vars(first)})
        return fit, ambiguous, detail, int(np.sum(maybe))

    def locate(self, ranges: np.ndarray, anchors: np.ndarray, weights: np.ndarray | None = None,
               initial: np.ndarray | None = None) -> Estimate:
        """Estimate the position of every problem of the batch.

        Parameters
        ----------
        ranges : ndarray, shape (..., M)
            Measured ranges in metres; NaN marks a missing range (weight 0).
        anchors : ndarray, shape (M, D) or (..., M, D)
            Anchor positions in metres, ``D`` = 2 or 3.
        weights : ndarray, shape (..., M), optional
            Non-negative weights; 0 marks a missing range. Default all ones.
        initial : ndarray, shape (..., D), optional
            Starting points. Default: the closed-form :func:`linear_initial`.

        Returns
        -------
        Estimate
            ``position`` ``(..., D)``; ``covariance`` ``s^2 (J^T W J)^-1`` at the solution,
            with ``s`` the configured ``std_m`` or the residual estimate;
            ``diagnostics`` ``converged``, ``stalled``, ``iterations``, ``residual_rms_m``,
            ``degenerate`` (the geometry does not fix the position: flat anchors, an
            ambiguous fix or a singular information matrix) and ``ambiguous`` (a mirror
            solution across the anchors' line or plane fits the ranges as well; with
            ``on_degenerate="flag"``), each ``(...)``.

        Raises
        ------
        InputError
            Shapes disagree, or a used range is infinite or negative.
        GeometryError
            Fewer than ``D + 1`` ranges, or collinear anchors, for some problem; ``index``
            is the batch index of the first such problem and ``detail`` the reason.
        """
        r = as_float_array(ranges, "ranges", min_ndim=1, allow_nan=True)
        a = as_float_array(anchors, "anchors", min_ndim=2, last_dim=(2, 3))
        d = a.shape[-1]
        if a.shape[-2] != r.shape[-1]:
            raise InputError(f"ranges: {r.shape[-1]} ranges per problem but {a.shape[-2]} anchors")
        try:
            batch = np.broadcast_shapes(r.shape[:-1], a.shape[:-2])
        except ValueError:
            raise InputError(f"ranges: batch shape {r.shape[:-1]} does not broadcast with "
                             f"anchors' {a.shape[:-2]}") from None
        w = np.ones(r.shape) if weights is None else as_float_array(weights, "weights",
                                                                   nonnegative=True)
        tiny = (w > 0) & (w < POSITIVE_FLOOR)           # its sigma w^-1/2 would be unbounded
        if np.any(tiny):
            idx = tuple(int(i) for i in np.argwhere(tiny)[0])
            raise InputError(f"weights: {float(w[idx]):.3g} at index {idx} is above 0 and below "
                             f"{POSITIVE_FLOOR:g} (0 marks a missing range)")
        try:
            w = np.broadcast_to(w, batch + r.shape[-1:]).astype(float)
        except ValueError:
            raise InputError(f"weights: shape {w.shape} does not broadcast to "
                             f"{batch + r.shape[-1:]}") from None
        r = np.broadcast_to(r, w.shape)
        # solve in a frame centred on the anchors (the closed-form start squares the
        # coordinates: far from the origin it would lose every digit); shifted back below
        origin = np.broadcast_to(a, batch + a.shape[-2:]).mean(axis=-2)
        a = np.broadcast_to(a, batch + a.shape[-2:]) - origin[..., None, :]
        w = np.where(np.isnan(r), 0.0, w)                 # NaN = missing range
        used = w > 0
        bad = used & ~np.isfinite(r)
        if np.any(bad):
            idx = _first(bad)
            raise InputError(f"ranges: invalid range {r[idx]} at index {idx} "
                             "(must be finite, or NaN for a missing range)")
        check_ranges(r, "ranges", self.std_m or 0.0, used=used)
        r = np.where(used, r, 0.0)
        n_used = used.sum(axis=-1)
        if np.any(n_used < d + 1):
            idx = _first(n_used < d + 1)
            detail = f"{int(n_used[idx])} ranges, {d + 1} needed in {d}-D"
            raise GeometryError(f"problem {idx}: {detail}", index=idx, detail=detail)

        if initial is None:
            with np.errstate(over="ignore", invalid="ignore"):
                x0 = linear_initial(r, a, w)
            far = ~np.all(np.isfinite(x0) & (np.abs(x0) <= MAGNITUDE_LIMIT), axis=-1)
            if np.any(far):
                idx = _first(far)
                raise InputError(f"ranges: the ranges of problem {idx} put the node beyond "
                                 f"{MAGNITUDE_LIMIT:g} m of the anchors (a range far larger "
                                 "than the anchors' spread allows: "
                                 f"{np.array2string(r[idx], precision=4)})")
        else:
            x0 = as_float_array(initial, "initial", last_dim=d)
            try:
                x0 = np.broadcast_to(x0, batch + (d,)) - origin
            except ValueError:
                raise InputError(f"initial: shape {x0.shape} does not broadcast to "
                                 f"{batch + (d,)}") from None

        flat, flat_detail = _flat_anchors(a, used)
        self._degenerate(flat, flat_detail)
        fit = self._solve(r, a, w, x0)
        fit, _ = self._leave_saddles(fit, r, a, w)
        fit, ambiguous, amb_detail, _ = self._resolve_mirror(fit, r, a, used, w, n_used,
                                                             origin)
        self._degenerate(ambiguous & ~flat, amb_detail,
                         lambda idx: tuple(int(i) for i in np.flatnonzero(used[idx])))
        JtWJ = fit.normal_matrix
        with np.errstate(all="ignore"):
            cond = np.linalg.cond(JtWJ)
        singular = ~np.isfinite(cond) | (cond > _COND_LIMIT)
        self._degenerate(singular & ~flat & ~ambiguous,
                         f"anchors are {'collinear' if d == 2 else 'coplanar'} or the position "
                         "coincides with an anchor; the geometry does not fix the position")
        # not converged to tol_m within max_iter: large-residual problems make Gauss-Newton
        # converge slowly (linearly) or zigzag around the minimum. Such a fix is settled
        # (kept, diagnostics["converged"] False) when one more line-searched iteration from
        # where it stopped moves it by at most its standard deviation or lowers the cost by
        # at most 1e-6 of itself; only a problem still travelling (a fix far from where the
        # data put it) is stuck.
        settled = np.zeros(batch, dtype=bool)
        open_ = ~fit.converged & ~flat & ~ambiguous & ~singular
        if np.any(open_):
            more = self._solve(r[open_], a[open_], w[open_], fit.x[open_], max_iter=1)
            s2_now = (np.full(more.cost.shape, self.std_m**2) if self.std_m
                      is not None else fit.cost[open_] / np.maximum(n_used[open_] - d, 1))
            with np.errstate(all="ignore"):
                sd = np.sqrt(s2_now * np.trace(np.linalg.inv(JtWJ[open_]), axis1=-2, axis2=-1))
            moved = np.linalg.norm(more.x - fit.x[open_], axis=-1)
            drop = fit.cost[open_] - more.cost
            # a stalled Gauss-Newton step does not move at all, so the exact Newton
            # decrement must also promise less than the noise (or 1e-6 of the cost)
            _, _, dec = self._saddles(fit, r, a, w)
            small = dec[open_] <= np.maximum(s2_now, 1e-6 * fit.cost[open_])
            settled[open_] = np.isfinite(more.cost) & small & (
                (np.isfinite(sd) & (moved <= sd))
                | (drop <= 1e-6 * np.maximum(fit.cost[open_], s2_now)))
        # a fix where the cost still falls in some direction (a saddle the search along
        # its descent direction could not leave) is never reported, settled or not
        at_saddle = self._saddles(fit, r, a, w)[0]
        stuck = ((~fit.converged & ~settled) | at_saddle) & ~flat & ~ambiguous & ~singular
        self._degenerate(stuck, lambda idx: (
            f"no converged fix after {int(fit.iterations[idx])} iterations (residual rms "
            f"{float(np.sqrt(fit.cost[idx] / max(float(np.sum(w[idx])), 1e-300))):.3g} m"
            + (", at a saddle point of the cost" if at_saddle[idx] else "") + "): the "
            "anchors do not fix the position from this start"))
        degenerate = flat | ambiguous | singular | stuck
        JtWJ = np.where(degenerate[..., None, None], np.eye(d), JtWJ)
        dof = n_used - d                                  # >= 1: D + 1 ranges are required
        wsum = np.sum(w, axis=-1)
        if self.std_m is not None:
            s2 = np.full(batch, self.std_m**2)
        else:
            s2 = fit.cost / dof * (n_used / wsum)
        cov = s2[..., None, None] * np.linalg.inv(JtWJ)
        cov = np.where(degenerate[..., None, None], np.nan, cov)
        rms = np.sqrt(fit.cost / np.maximum(wsum, 1e-300))
        return Estimate(fit.x + origin, cov, None, {
            "converged": fit.converged & ~degenerate, "stalled": fit.stalled,
            "iterations": fit.iterations, "residual_rms_m": rms, "degenerate": degenerate,
            "ambiguous": ambiguous & ~flat})

    def _degenerate(self, mask: np.ndarray, detail, anchors=None) -> None:
        """Raise for the first masked problem when ``on_degenerate="raise"`` (``anchors``:
        a function of the problem's index giving the indices of the anchors named)."""
        if self.on_degenerate == "raise" and np.any(mask):
            idx = _first(mask)
            text = detail(idx) if callable(detail) else detail
            raise GeometryError(f"problem {idx}: {text}", index=idx, detail=text,
                                anchors=None if anchors is None else anchors(idx))
