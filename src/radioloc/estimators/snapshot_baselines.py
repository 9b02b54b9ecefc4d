"""Single-epoch baselines of paper 001: genie-aided local ML and RANSAC multilateration.

Both see, at one instant, the ranges of a node to the points whose positions are given
(the genie of Sect. V supplies the true neighbour positions; with anchors only, the
anchors), batched over leading axes. A NaN range is an absent link. The links present are
packed with :func:`radioloc.core.links.pack_mask` before the search, so the cost grows with
the number of links heard, not with the number of candidate nodes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from radioloc.core.backend import DEFAULT_BACKEND, check_backend
from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.geometry import distances
from radioloc.core.links import gather_packed, pack_mask
from radioloc.core.results import Estimate
from radioloc.core.validation import (MAX_ITERATIONS, ambiguous_fixes, as_float_array, check_int,
                                      check_positive, check_ranges, range_noise_std,
                                      refuse_infinite)
from radioloc.estimators.base import SnapshotEstimator, Tags
from radioloc.estimators.least_squares import LeastSquares
from radioloc.estimators.local_search import derived_schedule, search
from radioloc.estimators.observation_rows import observation_list
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

__all__ = ["LocalML", "Ransac", "log_likelihood"]

def _residuals(x: np.ndarray, centres: np.ndarray, ranges: np.ndarray) -> np.ndarray:
    """``theta - ||x_c - centre||`` for candidates ``x (..., C, 2)``: ``(..., C, L)``."""
    return ranges[..., None, :] - distances(x[..., :, None, :], centres[..., None, :, :])


def _scores(kind: int, consts: tuple, x: np.ndarray, cen: np.ndarray, th: np.ndarray,
            valid: np.ndarray) -> np.ndarray:
    """:func:`~radioloc.estimators.pf_compiled.snapshot_scores` on candidates
    ``x (..., C, 2)`` of the batch of ``th``."""
    from radioloc.estimators.pf_compiled import snapshot_scores   # numba: imported when the kernel runs (start-up time)
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


def _impossible(log_likelihood: np.ndarray, action: str) -> np.ndarray:
    """Fixes where no candidate searched has a positive likelihood (``-inf``: the values
    are impossible at every point tried): flagged, or raised for the first one."""
    mask = np.isneginf(log_likelihood)
    if action == "raise" and np.any(mask):
        idx = tuple(int(i) for i in np.argwhere(mask)[0])
        text = "no position searched has a positive likelihood under the models"
        raise GeometryError(f"ranges: problem {idx}: {text}", index=idx, detail=text)
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


def _paper_range_model(model) -> bool:
    """Whether ``model`` is paper 001's configuration: a LOS/NLOS range without anchor bias
    (the one the compiled scores hold)."""
    return (isinstance(model, RangeModel) and isinstance(model.noise, LosNlosRange)
            and not model.anchor_bias)


def _candidate_axis(obs: Observation) -> tuple[np.ndarray, Context]:
    """``z`` and context of ``obs`` with an axis for the candidates before the rows (on
    the arrays that have batch axes), so a state ``(..., C, D)`` predicts ``(..., C, m)``."""
    ctx = obs.context if obs.std is None else replace(obs.context, std=obs.std)

    def row(v, k):
        return v if v is None or v.ndim <= k else np.expand_dims(v, -k - 1)
    return row(obs.z, 1), replace(ctx, points=row(ctx.points, 2),
                                  reference=row(ctx.reference, 2), std=row(ctx.std, 1))


def log_likelihood(observations: list[Observation], x: np.ndarray) -> np.ndarray:
    """``sum_rows log p(z | x)`` of every candidate ``x`` ``(..., C, 2)``: ``(..., C)``,
    through each observation model's ``logpdf`` (a missing row contributes 0).

    Parameters
    ----------
    observations : list of Observation
        Snapshot values ``z`` ``(..., m)`` of models reading the position only.
    x : ndarray, shape (..., C, 2)
        Candidate positions.

    Returns
    -------
    ndarray, shape (..., C)
    """
    total = 0.0
    for o in observations:
        z, ctx = _candidate_axis(o)
        with np.errstate(invalid="ignore"):      # NaN rows (missing) score 0
            total = total + np.sum(o.model.logpdf(z, {"position": x}, ctx), axis=-1)
    return total


def _search_rows(observations: list[Observation], batch: tuple[int, ...]):
    """The points heard ``(..., L, 2)``, the range circles' radii ``(..., L)`` (0 where not
    a circle) and the masks of rows heard and of circles ``(..., L)`` of the candidate
    search (range rows of 2-D points without anchor bias are circles)."""
    pts, radii, heard, circle = [], [], [], []
    for o in observations:
        ctx = o.context
        p = np.broadcast_to(ctx.points[..., :2], batch + (ctx.rows, 2))
        z = np.broadcast_to(o.z, batch + (ctx.rows,))
        ok = np.isfinite(z)
        is_circle = (o.model.kind == "range" and "anchor_bias" not in o.model.reads
                     and ctx.height_m is None and ctx.points.shape[-1] == 2)
        pts.append(p)
        heard.append(ok)
        circle.append(ok & is_circle)
        radii.append(np.where(ok & is_circle, z, 0.0))
    return (np.concatenate(pts, -2), np.concatenate(radii, -1), np.concatenate(heard, -1),
            np.concatenate(circle, -1))


def _batch_shape(observations: list[Observation]) -> tuple[int, ...]:
    """The batch shape of the observations' values and points (an :class:`InputError`
    where they do not broadcast)."""
    shapes = [o.z.shape[:-1] for o in observations]
    shapes += [o.context.points.shape[:-2] for o in observations]
    try:
        return np.broadcast_shapes(*shapes)
    except ValueError:
        raise InputError("observations: batch shapes do not broadcast: "
                         + ", ".join(str(s) for s in shapes)) from None


def _range_tolerance_m(model, context: Context) -> float:
    """Three standard deviations of a range row's error (of the LOS error under the
    LOS/NLOS mixture): the residual under which two fixes fit equally well."""
    los = getattr(getattr(model, "noise", None), "los_std_m", None)
    return 3.0 * float(los if los is not None else np.nanmax(model.std(context)))


class LocalML(SnapshotEstimator):
    """Local maximum-likelihood position over any measurement model with a log-density
    (paper 001, Sect. V: the genie-aided ML under the LOS/NLOS mixture).

    Maximises ``sum_rows log p(z | x)`` (the models' ``logpdf``; paper 001:
    ``sum_m log(alpha p_LOS + (1 - alpha) p_NLOS)``) over the candidates of
    :func:`radioloc.estimators.local_search.search`: the pairwise intersections of the
    range circles plus a coarse grid of half width ``radius_m`` around the mean of the
    points heard (the node is within ``radius_m`` of every one), polished by two finer
    local grids (half widths 0.5 m and 0.05 m). A global search heuristic, not a certified
    optimum; a model without range rows has only the grid, so its spacing
    ``2 radius_m / (coarse_points - 1)`` must stay within the first polish (1 m).

    Without ``radius_m`` (the default) the search square is derived per problem
    (:func:`~radioloc.estimators.local_search.derived_schedule`): its half width is
    ``h = max_i ||p_i - c|| + min_j r_j``, the largest distance of a point heard ``p_i``
    from their mean ``c`` plus the shortest range circle ``r_j`` heard (0 without range
    rows; at least 1 m), which holds every position the range rows allow. The coarse grid
    has spacing ``s = max(1 m, h / 64)`` (at most 129 x 129 points), and the polish has
    stages of half width ``s / 2, s / 20, ...`` down to 0.05 m (``s = 1`` m: the 0.5 m
    and 0.05 m stages above; a last spacing of 5 mm). A model whose likelihood does not
    vanish far from the points (a fingerprint scan beyond its calibration places) has no
    unique maximum there; the search returns one point of the plateau.

    With ``search_radius_m`` set, the search is local instead: the coarse grid (half width
    ``search_radius_m``) and the admissible circle intersections lie around a search
    centre given to :meth:`locate` (e.g. the previous estimate moved by the INS), so a
    distant mode of the likelihood cannot be chosen.

    Parameters
    ----------
    measurement : LosNlosRange or MeasurementModel or None
        The model of the ``ranges`` given to :meth:`locate` as arrays: a
        :class:`~radioloc.models.los_nlos.LosNlosRange` (the paper's configuration,
        ``RangeModel(noise=measurement)``) or any range model with a ``logpdf``. None:
        :meth:`locate` takes :class:`~radioloc.models.measurement.Observation`\\ s only
        (which carry their models).
    radius_m : float, optional
        Half width of the coarse grid (the communication radius); default None: derived
        per problem from the points heard and the range circles (see above).
    coarse_points : int, optional
        Points per axis of the coarse grid of ``radius_m`` or ``search_radius_m``
        (default 21); refused without either (the derived grid sets its own).
    search_radius_m : float, optional
        Half width of a local search around the centre passed to :meth:`locate`; default
        None: the global search above.
    on_degenerate : {"flag", "raise"}
        A global search whose range points heard are coincident or collinear, or whose fix
        has a mirror image that fits the ranges as well
        (:func:`radioloc.core.validation.ambiguous_fixes`, within three standard
        deviations of the range error, of the LOS error under the mixture), is
        ``"flag"``-ged in ``diagnostics["degenerate"]`` (default: the highway geometry of
        paper 001 is nearly collinear by nature) or ``"raise"``-s a
        :class:`GeometryError` naming the first such problem. Rows of other kinds are not
        checked for ambiguity; a fix of any model where no position searched has a
        positive likelihood (``log_likelihood`` ``-inf``, e.g. RSS trapezoids that no
        grid point satisfies at once) is handled the same way.
    backend : {"numba", "numpy"}
        For the paper's configuration given as arrays, the objective as the models'
        ``logpdf`` (``"numpy"``, the definition) or one compiled pass per candidate
        (:func:`~radioloc.estimators.pf_compiled.snapshot_scores`); equal to rounding.
        Every other model (and every ``Observation`` input) uses the definition.
    """

    name = "local-ml"
    tags = Tags(kinds=None, uses="logpdf", dims=(2,), reads=("position",), generic=True)

    def __init__(self, measurement=None, radius_m: float | None = None,
                 coarse_points: int | None = None, search_radius_m: float | None = None,
                 on_degenerate: str = "flag", backend: str = DEFAULT_BACKEND) -> None:
        self.on_degenerate = _check_on_degenerate(on_degenerate)
        self.backend = check_backend(backend)
        if isinstance(measurement, LosNlosRange):
            measurement = RangeModel(noise=measurement)
        if measurement is not None:
            self.tags.require(measurement, "measurement", type(self).__name__)
            if measurement.kind != "range":
                raise ConfigError(f"measurement: ranges given as arrays need a range model, got "
                                  f"{type(measurement).__name__} (pass Observations instead)")
        self.measurement = measurement
        self.radius_m = None if radius_m is None else check_positive(radius_m, "radius_m")
        derived = radius_m is None and search_radius_m is None
        if coarse_points is not None and derived:
            raise ConfigError("coarse_points: sets the grid of a given radius_m (or "
                              "search_radius_m); without one the grid is derived")
        self.coarse_points = None if derived else check_int(
            21 if coarse_points is None else coarse_points, "coarse_points", minimum=2,
            maximum=4096)
        self.search_radius_m = (None if search_radius_m is None
                                else check_positive(search_radius_m, "search_radius_m"))

    def locate(self, ranges, centres=None, search_centre=None) -> Estimate:
        """Maximum-likelihood positions for a batch of snapshots.

        Parameters
        ----------
        ranges : array_like, shape (..., L), or Observation or sequence of Observation
            Measured ranges to the points (NaN = absent link) under ``measurement``; or
            observations of any models reading the 2-D position (values ``(..., m)``,
            leading batch axes; NaN = missing row), ``centres`` then None.
        centres : array_like, shape (..., L, 2) (broadcast against ``ranges``)
            Positions of the points ranged to (with arrays only).
        search_centre : array_like, shape (..., 2), optional
            Centre of the local search; required when ``search_radius_m`` is set, ignored
            (must be None) otherwise.

        Returns
        -------
        Estimate
            ``position`` (..., 2), no covariance; diagnostics ``log_likelihood`` at the
            estimate, ``measurements_used`` and (global search) ``degenerate``.
        """
        compiled = None
        if isinstance(ranges, Observation) or (isinstance(ranges, (list, tuple)) and ranges
                                               and isinstance(ranges[0], Observation)):
            if centres is not None:
                raise InputError("centres: observations carry their points (context.points)")
            obs = self._checked(observation_list(ranges))
        else:
            if self.measurement is None:
                raise InputError("ranges: this LocalML has no measurement model; pass "
                                 "Observations")
            if centres is None:
                raise InputError("centres: required with ranges given as an array")
            th, cen, valid = _packed(ranges, centres, range_noise_std(self.measurement))
            obs = [Observation(self.measurement, np.where(valid, th, np.nan), Context(points=cen))]
            if self.backend == "numba" and _paper_range_model(self.measurement):
                compiled = (self.measurement.noise.mixture_constants(), th, cen, valid)
        batch = _batch_shape(obs)
        pts, radii, heard, circle = _search_rows(obs, batch)
        half, grid = self.radius_m, {"coarse_points": self.coarse_points}
        if self.coarse_points is None:
            grid = derived_schedule(pts, radii, heard, circle)
        if self.search_radius_m is not None:
            if search_centre is None:
                raise InputError("search_centre: required by a local search (search_radius_m set)")
            search_centre = as_float_array(search_centre, "search_centre", min_ndim=1, last_dim=2)
            try:
                search_centre = np.broadcast_to(search_centre, batch + (2,))
            except ValueError:
                raise InputError(f"search_centre: shape {search_centre.shape} does not fit "
                                 f"the batch {batch}") from None
            half = self.search_radius_m
        elif search_centre is not None:
            raise InputError("search_centre: only a local search (search_radius_m set) takes one")

        def objective(x):
            if compiled is None:
                return log_likelihood(obs, x)
            consts, th_, cen_, valid_ = compiled
            return _scores(0, consts, x, cen_, th_, valid_)
        x = search(objective, pts, radii, heard, half, centre=search_centre, circles=circle,
                   **grid)
        diag = {"log_likelihood": objective(x[..., None, :])[..., 0],
                "measurements_used": heard.sum(axis=-1)}
        if self.search_radius_m is None:
            tol = [_range_tolerance_m(o.model, o.context) for o in obs if o.model.kind == "range"]
            diag["degenerate"] = (_degenerate(x, pts, radii, circle, min(tol), self.on_degenerate)
                                  if tol else np.zeros(batch, dtype=bool))
            diag["degenerate"] = diag["degenerate"] | _impossible(diag["log_likelihood"],
                                                                  self.on_degenerate)
        return Estimate(x, None, None, diag)

    def _checked(self, obs: list[Observation]) -> list[Observation]:
        """Refuse a model the tags do not take, or rows whose points give no 2-D position."""
        for i, o in enumerate(obs):
            self.tags.require(o.model, f"observations[{i}].model", type(self).__name__)
            dim = o.context.position_dim
            if dim != 2:
                raise ConfigError(f"observations[{i}].context.points: {type(self).__name__} "
                                  f"searches 2-D positions; the rows have {dim}-D points")
            refuse_infinite(o.z, f"observations[{i}].z")
        return obs


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
