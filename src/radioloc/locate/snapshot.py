"""``radioloc locate`` snapshot methods beside ``gn``: one fix per ``(time, node)`` epoch.

- ``localml``: local maximum likelihood under the LOS/NLOS range mixture
  (:class:`~radioloc.estimators.snapshot_baselines.LocalML`, paper 001 Sect. V);
- ``ransac``: RANSAC multilateration with a least-squares refit on the inliers
  (:class:`~radioloc.estimators.snapshot_baselines.Ransac`, paper 001 Sect. V);
- ``lsq``: the generic :class:`~radioloc.estimators.least_squares.LeastSquares` over every
  kind with a measurement model (ranges, time differences, angles, pseudoranges), with a
  robust loss (``-o loss=linear|huber|cauchy|tukey``).

``localml`` and ``ransac`` locate in 2-D (3-D anchors: give ``tag_height_m``; the ranges
are projected to the horizontal plane) and report no covariance of their own (the health
check, :mod:`radioloc.locate.health`, writes one from its refit); ``lsq`` reports
``(J' W J)^-1`` of each fix, with the rows weighted by the sigma options. The epochs, and
those that do not fix the position (``-o on_degenerate``), are handled as by ``gn``
(:mod:`radioloc.locate.epochs`).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import GeometryError, InputError
from radioloc.estimators.fault_exclusion import exclude_faults
from radioloc.estimators.least_squares import LeastSquares
from radioloc.estimators.robust_loss import LOSSES
from radioloc.estimators.snapshot_baselines import LocalML, Ransac
from radioloc.io.measurements import Measurements
from radioloc.core.kinds import model_kinds
from radioloc.locate.adapter import (anchor_positions, default_models, frame_settings,
                                     node_observations, sigma_options)
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.ekf_track import OPTIONS as EKF_OPTIONS
from radioloc.locate.epochs import (ON_DEGENERATE, Epochs, epoch_error, epoch_table,
                                    horizontal_ranges, range_epochs, solve_epochs)
from radioloc.locate.progress import counted
from radioloc.models.los_nlos import LosNlosRange

__all__ = ["locate_localml", "locate_ransac", "locate_lsq"]

_RADIUS = Option("half width of the coarse search grid around the anchors heard, m (default: "
                 "the longest range of the log)", float, min=0, min_exclusive=True, max=1e7)
_HEIGHT = Option("known node height with 3-D anchors, m (the ranges are projected to the "
                 "horizontal plane)", float, min=-1e4, max=1e4)


def _radius(request: LocateRequest, ep: Epochs) -> float:
    return request.option("radius_m", float(np.nanmax(ep.R)) + 1.0)


@locate_method("localml", "Local maximum-likelihood fix of each node at each time under the "
                          "LOS/NLOS range mixture (paper 001 Sect. V; 2-D)",
               options={"los_std_m": Option("s_LOS, standard deviation of every range's "
                                            "Gaussian error, m (default 0.15)", float, min=0,
                                            min_exclusive=True, max=1e6),
                        "nlos_mean_m": Option("s_NLOS, mean NLOS excess range, m (default 5)",
                                              float, min=0, min_exclusive=True, max=1e6),
                        "alpha": Option("LOS fraction (default 0.7)", float, min=0, max=1),
                        "radius_m": _RADIUS, "tag_height_m": _HEIGHT,
                        "on_degenerate": ON_DEGENERATE},
               kinds=("range",), inputs=("anchors",))
def locate_localml(request: LocateRequest) -> pd.DataFrame:
    """Locate every ``(time, node)`` epoch with :class:`LocalML`.

    Parameters
    ----------
    request : LocateRequest
        Range rows, anchors, ``-o`` options.

    Returns
    -------
    DataFrame
        ``time, node, x, y``, ``ranges`` (anchor ranges used) and ``log_likelihood`` of the
        fix, one row per epoch fixed; ``attrs["summary"]``: epoch counts and the model.

    Raises
    ------
    GeometryError
        An epoch with fewer than three anchor ranges, or an ambiguous (mirror) fix, without
        ``on_degenerate=skip``; the message names the node and the time.
    InputError
        3-D anchors without ``tag_height_m``.
    """
    ep = range_epochs(request, "localml", need=3)
    R, points = horizontal_ranges(request, ep)
    model = LosNlosRange(request.option("los_std_m", 0.15), request.option("nlos_mean_m", 5.0),
                         request.option("alpha", 0.7))
    try:
        fit = solve_epochs(ep, R, points, LocalML(
            model, _radius(request, ep), on_degenerate="flag" if ep.skip else "raise").locate)
    except GeometryError as exc:
        raise epoch_error(ep, exc) from None
    bad = np.asarray(fit.diagnostics["degenerate"])
    out = epoch_table(ep, fit.position, None, bad, bad, ranges=np.isfinite(R).sum(axis=1),
                      log_likelihood=fit.diagnostics["log_likelihood"])
    out.attrs["summary"].update(los_std_m=model.los_std_m, nlos_mean_m=model.nlos_mean_m,
                                alpha=model.alpha)
    return out


@locate_method("ransac", "RANSAC multilateration of each node at each time: the hypothesis "
                         "most ranges agree with, refitted on them (paper 001 Sect. V; 2-D)",
               options={"threshold_m": Option("inlier gate on the range residual, m (default "
                                              "0.5)", float, min=0, min_exclusive=True, max=1e6),
                        "radius_m": _RADIUS, "tag_height_m": _HEIGHT,
                        "on_degenerate": ON_DEGENERATE},
               kinds=("range",), inputs=("anchors",))
def locate_ransac(request: LocateRequest) -> pd.DataFrame:
    """Locate every ``(time, node)`` epoch with :class:`Ransac`.

    Parameters
    ----------
    request : LocateRequest
        Range rows, anchors, ``-o`` options.

    Returns
    -------
    DataFrame
        ``time, node, x, y``, ``ranges`` (anchor ranges heard), ``inliers`` and
        ``residual_rms_m`` of the refit, one row per epoch fixed.

    Raises
    ------
    GeometryError
        As :func:`locate_localml`.
    InputError
        3-D anchors without ``tag_height_m``.
    """
    ep = range_epochs(request, "ransac", need=3)
    R, points = horizontal_ranges(request, ep)
    threshold = request.option("threshold_m", 0.5)
    try:
        fit = solve_epochs(ep, R, points, Ransac(
            threshold, _radius(request, ep), on_degenerate="flag" if ep.skip else "raise").locate)
    except GeometryError as exc:
        raise epoch_error(ep, exc) from None
    d = fit.diagnostics
    bad = np.asarray(d["degenerate"]) | (np.asarray(d["inliers"]) < 3)
    out = epoch_table(ep, fit.position, None, bad, d["degenerate"],
                      detail="fewer than 3 ranges agree within threshold_m with one position",
                      ranges=np.isfinite(R).sum(axis=1), inliers=d["inliers"],
                      residual_rms_m=d["residual_rms_m"])
    out.attrs["summary"]["threshold_m"] = threshold
    return out


_LSQ_OPTIONS = sigma_options()
_LSQ_OPTIONS.update({
    "loss": Option("robust loss of the standardised residual (default linear)", str,
                   choices=LOSSES),
    "loss_scale": Option("the loss's scale, in standard deviations (default 1.5)", float,
                         min=0, min_exclusive=True, max=1e6),
    "tag_height_m": EKF_OPTIONS["tag_height_m"],
    "exclude_faults": Option("1 (default): a fix whose residuals fail their chi-square test "
                             "(99.9 %) is fitted again without its worst row, while a row "
                             "to spare is left; 0: every row kept", bool),
    "earth_rotation": EKF_OPTIONS["earth_rotation"],
    "on_degenerate": ON_DEGENERATE})


@locate_method("lsq", "Nonlinear least squares fix of each node at each time from every "
                      "measurement to anchors (each kind with a model, its sigma option) "
                      "with a robust loss (linear, huber, cauchy, tukey)",
               options=_LSQ_OPTIONS, kinds=tuple(model_kinds()), inputs=("anchors",),
               moving_anchors=True)
def locate_lsq(request: LocateRequest) -> pd.DataFrame:
    """Locate every ``(time, node)`` epoch with the generic :class:`LeastSquares`.

    Each kind present gets its model (:func:`radioloc.locate.adapter.default_models`, the
    sigmas from the options); each node's epochs are one batched fit. An epoch with fewer
    measurements than unknowns (position, and the clock offset with pseudoranges), or whose
    information is singular, does not fix the position (``-o on_degenerate``). Anchors
    may move (an anchors file with a ``time`` column): each epoch uses their positions at
    its time (:func:`radioloc.locate.adapter.anchor_points`).

    Parameters
    ----------
    request : LocateRequest
        Measurements, anchors, ``-o`` options.

    Returns
    -------
    DataFrame
        ``time, node, x, y[, z], uncertainty_m``, covariance columns, ``measurements``
        (rows used) and ``inliers`` (within 3 sigma), one row per epoch fixed. An epoch
        with more rows than unknowns whose fix leaves most of them beyond 3 sigma fits no
        position: it is refused (or left out with ``on_degenerate=skip``).

    Raises
    ------
    GeometryError
        An epoch that does not fix the position, without ``on_degenerate=skip`` (naming the
        node and the time).
    InputError
        An epoch whose measurements fit no position, without ``on_degenerate=skip``.
    """
    table = request.require_anchors("lsq")
    log = Measurements(request.measurements)
    opts = {k: request.option(k) for k in _LSQ_OPTIONS if request.option(k) is not None}
    opts.setdefault("range_std_m", 0.15)
    models = default_models(log.kinds, opts, settings=frame_settings(request))
    height = request.option("tag_height_m")
    solver = LeastSquares(loss=request.option("loss", "linear", str),
                          loss_scale=request.option("loss_scale", 1.5))
    fde = request.option("exclude_faults", True, bool)
    epochs, fits, excluded = [], [], {}
    per_node = log.frame["node"].value_counts()
    for node in counted(log.nodes, len(log.frame), lambda n: int(per_node.get(n, 0)), "lsq"):
        times, obs = node_observations(log, table, node, models, height_m=height,
                                        checked=True)
        if times.size:
            fit, left_out, _ = (exclude_faults(solver.locate, obs) if fde else
                                (solver.locate(obs), [np.zeros(o.z.shape, bool) for o in obs], None))
            epochs.append(pd.DataFrame({"time": times, "node": node,
                                        "excluded": sum(x.sum(-1) for x in left_out)}))
            fits.append(fit)
            for o, x in zip(obs, left_out):
                for s, a in enumerate(o.context.index):
                    if x[:, s].any():
                        key = f"{o.model.kind} {table['id'].iloc[a]}"
                        excluded[key] = excluded.get(key, 0) + int(x[:, s].sum())
    if not fits:
        raise GeometryError("method lsq: no measurement to an anchor in the measurements")
    d = {k: np.concatenate([np.asarray(f.diagnostics[k]) for f in fits])
         for k in ("measurements_used", "degenerate", "inliers")}
    unknowns = max(f.diagnostics["state"].shape[-1] for f in fits)
    points = anchor_positions(table.drop_duplicates("id"))
    if height is not None:
        points = points[:, :2]
    ep = Epochs("lsq", pd.concat(epochs, ignore_index=True), None, points,
                list(dict.fromkeys(table["id"])),
                request.option("on_degenerate", "error", str) == "skip",
                np.zeros(len(d["degenerate"]), dtype=bool), unknowns)
    ep.set_few(d["measurements_used"], unknowns, what="", unit="measurement(s) to anchors")
    keep = ~ep.few
    position = np.concatenate([f.position for f in fits])[keep]
    cov = np.concatenate([f.covariance for f in fits])[keep]
    bad = d["degenerate"][keep]
    # a fix that leaves most of its rows beyond 3 sigma explains none of them: a sign or
    # unit slip, a wrong anchor (its covariance (J' W J)^-1 would claim a precision it lacks)
    used, inl = d["measurements_used"][keep], d["inliers"][keep]
    misfit = ~bad & (used > unknowns) & (2 * inl < used)
    if misfit.any() and not ep.skip:
        i = int(np.flatnonzero(misfit)[0])
        raise InputError(f"method lsq: {ep.where(int(ep.solvable[i]))}: the measurements do not "
                         f"fit one position: {int(used[i] - inl[i])} of {int(used[i])} rows lie "
                         "beyond 3 sigma of the best fix, with the faults excluded that could be (a sign "
                         "or unit slip, a wrong anchor or reference, more outliers than rows to "
                         "spare, or sigmas far too small); -o on_degenerate=skip leaves such "
                         "epochs out")
    bad = bad | misfit
    cov = np.where(bad[:, None, None], np.eye(cov.shape[-1]), cov)
    out = epoch_table(ep, position, cov, bad,
                      detail="the measurements do not fix the position (singular or "
                             "ill-conditioned information)",
                      what="measurements to anchors", measurements=d["measurements_used"][keep],
                      inliers=d["inliers"][keep],
                      misfit=misfit, excluded=ep.epochs["excluded"].to_numpy()[keep])
    out.attrs["summary"].update({**opts, "loss": solver.loss, "loss_scale": solver.loss_scale},
                                rows_excluded=int(sum(excluded.values())),
                                excluded_by_row=dict(sorted(excluded.items())),
                                measurements={k: int(np.isfinite(
                                    log.frame[log.frame["kind"] == k]["value"]).sum())
                                    for k in models})
    return out
