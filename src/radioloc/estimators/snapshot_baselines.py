"""Single-epoch baselines of paper 001: genie-aided local ML and RANSAC multilateration.

Both see, at one instant, the ranges of a node to the points whose positions are given
(the genie of Sect. V supplies the true neighbour positions; with anchors only, the
anchors), batched over leading axes. A NaN range is an absent link. The links present are
packed with :func:`radioloc.core.links.pack_mask` before the search, so the cost grows with
the number of links heard, not with the number of candidate nodes.
"""

from __future__ import annotations

import numpy as np

from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.geometry import distances
from radioloc.core.links import gather_packed, pack_mask
from radioloc.core.results import Estimate
from radioloc.core.validation import (MAX_ITERATIONS, ambiguous_fixes, as_float_array, check_int,
                                      check_positive, check_ranges, range_noise_std)
from radioloc.estimators.base import SnapshotEstimator
from radioloc.estimators.pf_compiled import snapshot_scores
from radioloc.estimators.local_search import search
from radioloc.estimators.least_squares import LeastSquares
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

__all__ = ["LocalML", "Ransac"]

def _residuals(x: np.ndarray, centres: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """``theta - ||x_c - centre||`` for candidates ``x (..., C, 2)``: ``(..., C, L)``."""
    return ranges[..., None, :] - distances(x[..., :, None, :], centres[..., None, :, :])


def _scores(kind: int, consts: tuple, x: np.ndarray, cen: np.ndarray, th: np.ndarray,
            valid: np.ndarray) -> np.ndarray:
    """:func:`~radioloc.estimators.pf_compiled.snapshot_scores` on candidates
    ``x (..., C, 2)`` of the batch of ``th``."""
    batch, nl = th.shape[:-1], th.shape[-1]
    b = int(np.prod(batch, dtype=int))
    c = x.shape[-2]
    out = np.empty((b, c))
    snapshot_scores(kind, np.ascontiguousarray(np.broadcast_to(x, batch + (c, 2)).reshape(b, c, 2)),
                      np.ascontiguousarray(cen.reshape(b, nl, 2)), np.ascontiguousarray(th.reshape(b, nl)),
                      np.ascontiguousarray(valid.reshape(b, nl)), *(float(v) for v in consts), out)
    return out.reshape(batch + (c,))


def _check_on_degenerate(value: str) -> str:
    if value not in ("flag", "raise"):
        raise ConfigError(f"on_degenerate: must be 'flag' or 'raise', got {value!r}")
    return value


def _degenerate(x, centres, ranges, used, tol_m, action) -> np.ndarray:
    """Ambiguous fixes (:func:`ambiguous_fixes`): flagged, or raised for the first one."""
    mask, reason = ambiguous_fixes(x, centres, ranges, used, tol_m)
    if action == "raise" and np.any(mask):
        idx = tuple(int(i) for i in np.argwhere(mask)[0])
        text = reason(idx)
        raise GeometryError(f"centres: problem {idx}: {text}", index=idx, detail=text)
    return mask


def _packed(ranges, centres, std_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validate and pack: ranges (..., L) with 0 at padding, centres (..., L, 2), valid;
    ``std_m`` the range noise of :func:`check_ranges`."""
    r = as_float_array(ranges, "ranges", min_ndim=1, allow_nan=True)
    if np.any(np.isinf(r)):
        raise InputError("ranges: infinite value (NaN marks an absent link)")
    check_ranges(r, "ranges", std_m)
    c = as_float_array(centres, "centres", min_ndim=2, last_dim=2, allow_nan=True)
    try:
        c = np.broadcast_to(c, r.shape + (2,))
    except ValueError:
        raise InputError(f"centres: shape {c.shape} does not fit ranges {r.shape}") from None
    mask = np.isfinite(r)
    if not mask.any():
        raise InputError(f"ranges: no finite range in any of the {mask.size} entries (NaN marks "
                         "an absent link; every link is absent)")
    if np.any(mask & ~np.all(np.isfinite(c), axis=-1)):
        raise InputError("centres: non-finite position of a point with a range")
    index, valid = pack_mask(mask)
    th = gather_packed(np.where(mask, r, 0.0), index)
    cen = gather_packed(np.where(mask[..., None], c, 0.0), index, axis=-2)
    return th, cen, valid


class LocalML(SnapshotEstimator):
    """Local maximum-likelihood position under the LOS/NLOS mixture (paper 001, Sect. V).

    Maximises ``sum_m log(alpha p_LOS + (1 - alpha) p_NLOS)`` over the candidates of
    :func:`radioloc.estimators.local_search.search`: the pairwise intersections of the
    range circles plus a coarse grid of half width ``radius_m`` around the mean of the
    points heard (the node is within ``radius_m`` of every one), polished by two finer
    local grids. A global search heuristic, not a certified optimum.

    With ``search_radius_m`` set, the search is local instead: the coarse grid (half width
    ``search_radius_m``) and the admissible circle intersections lie around a search
    centre given to :meth:`locate` (e.g. the previous estimate moved by the INS), so a
    distant mode of the likelihood cannot be chosen.

    Parameters
    ----------
    measurement : LosNlosRange
        The mixture range model.
    radius_m : float
        Half width of the coarse grid (the communication radius).
    coarse_points : int
        Points per axis of the coarse grid.
    search_radius_m : float, optional
        Half width of a local search around the centre passed to :meth:`locate`; default
        None: the global search above.
    on_degenerate : {"flag", "raise"}
        A global search whose points heard are coincident or collinear, or whose fix has a
        mirror image that fits the ranges as well (:func:`radioloc.core.validation.ambiguous_fixes`,
        within ``3 los_std_m``), is ``"flag"``-ged in ``diagnostics["degenerate"]``
        (default: the highway geometry of paper 001 is nearly collinear by nature) or
        ``"raise"``-s a :class:`GeometryError` naming the first such problem.
    backend : {"numba", "numpy"}
        The objective (the sum over the links of the model's log-density of the residuals)
        as array expressions (``"numpy"``, the definition) or one compiled pass per
        candidate (:func:`~radioloc.estimators.pf_compiled.snapshot_scores`); equal to
        rounding.
    """

    name = "local-ml"

    def __init__(self, measurement: LosNlosRange, radius_m: float, coarse_points: int = 21,
                 search_radius_m: float | None = None, on_degenerate: str = "flag",
                 backend: str = DEFAULT_BACKEND) -> None:
        self.on_degenerate = _check_on_degenerate(on_degenerate)
        self.backend = check_backend(backend)
        if not isinstance(measurement, LosNlosRange):
            raise ConfigError(f"measurement: expected LosNlosRange, got {type(measurement).__name__}")
        self.measurement = measurement
        self.radius_m = check_positive(radius_m, "radius_m")
        self.coarse_points = check_int(coarse_points, "coarse_points", minimum=2, maximum=4096)
        self.search_radius_m = (None if search_radius_m is None
                                else check_positive(search_radius_m, "search_radius_m"))

    def locate(self, ranges, centres, search_centre=None) -> Estimate:
        """Maximum-likelihood positions for a batch of snapshots.

        Parameters
        ----------
        ranges : array_like, shape (..., L)
            Measured ranges to the points; NaN = absent link.
        centres : array_like, shape (..., L, 2) (broadcast against ``ranges``)
            Positions of the points ranged to.
        search_centre : array_like, shape (..., 2), optional
            Centre of the local search; required when ``search_radius_m`` is set, ignored
            (must be None) otherwise.

        Returns
        -------
        Estimate
            ``position`` (..., 2), no covariance; diagnostics ``log_likelihood`` at the
            estimate and ``measurements_used``.
        """
        th, cen, valid = _packed(ranges, centres, range_noise_std(self.measurement))
        model = self.measurement
        half = self.radius_m
        if self.search_radius_m is not None:
            if search_centre is None:
                raise InputError("search_centre: required by a local search (search_radius_m set)")
            search_centre = as_float_array(search_centre, "search_centre", min_ndim=1, last_dim=2)
            try:
                search_centre = np.broadcast_to(search_centre, th.shape[:-1] + (2,))
            except ValueError:
                raise InputError(f"search_centre: shape {search_centre.shape} does not fit "
                                 f"ranges {th.shape}") from None
            half = self.search_radius_m
        elif search_centre is not None:
            raise InputError("search_centre: only a local search (search_radius_m set) takes one")

        consts = model.mixture_constants()

        def objective(x):
            if self.backend == "numpy":
                e = _residuals(x, cen, th)
                lp = model.logpdf(e, 0.0)
                return np.sum(np.where(valid[..., None, :], lp, 0.0), axis=-1)
            return _scores(0, consts, x, cen, th, valid)
        x = search(objective, cen, th, valid, half, self.coarse_points, centre=search_centre)
        diag = {"log_likelihood": objective(x[..., None, :])[..., 0],
                "measurements_used": valid.sum(axis=-1)}
        if self.search_radius_m is None:
            diag["degenerate"] = _degenerate(x, cen, th, valid, 3.0 * model.los_std_m,
                                             self.on_degenerate)
        return Estimate(x, None, None, diag)


class Ransac(SnapshotEstimator):
    """RANSAC-style multilateration (paper 001, Sect. V).

    Hypotheses are the intersections of every pair of range circles (minimal sets of two
    ranges in 2-D) and a coarse grid; the consensus of a hypothesis is the number of ranges
    with ``|residual| < threshold_m`` (ties: smaller squared residual over the inliers).
    The best hypothesis is refitted by Gauss-Newton least squares on its inlier set
    (:class:`~radioloc.estimators.least_squares.LeastSquares`, the outliers missing rows).
    Exhaustive over pairs instead of random draws.

    Parameters
    ----------
    threshold_m : float
        Inlier gate on the range residual.
    radius_m : float
        Half width of the coarse grid of hypotheses.
    max_iter : int
        Gauss-Newton iterations of the refit.
    on_degenerate : {"flag", "raise"}
        As for :class:`LocalML` (tolerance ``threshold_m``; the refit's inliers are the
        ranges checked).
    backend : {"numba", "numpy"}
        The consensus as array expressions (``"numpy"``, the definition) or one compiled
        pass per hypothesis (:func:`~radioloc.estimators.pf_compiled.snapshot_scores`);
        equal to rounding.
    """

    name = "ransac"

    def __init__(self, threshold_m: float, radius_m: float, max_iter: int = 50,
                 on_degenerate: str = "flag", backend: str = DEFAULT_BACKEND) -> None:
        self.on_degenerate = _check_on_degenerate(on_degenerate)
        self.backend = check_backend(backend)
        self.threshold_m = check_positive(threshold_m, "threshold_m")
        self.radius_m = check_positive(radius_m, "radius_m")
        self.max_iter = check_int(max_iter, "max_iter", minimum=0, maximum=MAX_ITERATIONS)

    def locate(self, ranges, centres) -> Estimate:
        """RANSAC positions for a batch of snapshots.

        Parameters
        ----------
        ranges : array_like, shape (..., L)
            Measured ranges to the points; NaN = absent link.
        centres : array_like, shape (..., L, 2) (broadcast against ``ranges``)
            Positions of the points ranged to.

        Returns
        -------
        Estimate
            ``position`` (..., 2), covariance ``None``; diagnostics ``converged``,
            ``stalled``, ``iterations`` of the refit, ``inliers`` (count),
            ``residual_rms_m`` over the inliers and ``measurements_used``.
        """
        th, cen, valid = _packed(ranges, centres, self.threshold_m)   # its noise scale
        thr = self.threshold_m

        def consensus(x):
            if self.backend == "numpy":
                e = _residuals(x, cen, th)
                inl = valid[..., None, :] & (np.abs(e) < thr)
                sq = np.sum(np.where(inl, e * e, 0.0), axis=-1)
                return inl.sum(-1) - sq / (inl.sum(-1) * thr**2 + 1.0)
            return _scores(1, (thr**2, thr, 0.0, 0.0, 0.0, 0.0), x, cen, th, valid)
        x0 = search(consensus, cen, th, valid, self.radius_m, refine=())
        e0 = th - distances(x0[..., None, :], cen)
        inliers = valid & (np.abs(e0) < thr)

        # the refit: generic least squares on the inlier rows (the others missing)
        obs = Observation(RangeModel(std_m=thr), np.where(inliers, th, np.nan),
                          Context(points=cen))
        fit = LeastSquares(max_iterations=self.max_iter).locate(obs, initial=x0)
        n_in = inliers.sum(axis=-1)
        degenerate = _degenerate(fit.position, cen, th, inliers, thr, self.on_degenerate)
        lsq = fit.diagnostics
        return Estimate(fit.position, None, None, {
            "converged": lsq["converged"], "stalled": lsq["stalled"], "iterations": lsq["iterations"], "inliers": n_in,
            "residual_rms_m": lsq["residual_rms_m"], "degenerate": degenerate,
            "measurements_used": valid.sum(axis=-1)})
