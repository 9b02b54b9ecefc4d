"""A user's log smoothed by :class:`~radioloc.estimators.batch_smoother.BatchSmoother`.

:func:`smooth_log` takes a :class:`~radioloc.locate.base.LocateRequest` (the measurements
and anchors of ``radioloc locate``) and returns the smoothed track table of every node.
Every kind ``ekf-track`` reads is used, with the same models and sigma options
(:func:`radioloc.locate.ekf_track.log_models`: ranges, time differences, angles,
pseudoranges, RSS, headings; not odometry), the same start
(:func:`radioloc.locate.ekf_track.track_prior`) and the options of the trackers
(``-o tag_height_m``, ``q``, ``motion``, ``prior_std_m``, ``init_s``, ``max_gap_s``,
``range_std_m``). The range rows take the options of ``pf`` (``los_std_m``, ``nlos_mean_m``,
``alpha`` given, or fitted by EM on the node's ranges as ``pf`` fits them:
:func:`radioloc.locate.pf.node_residuals`, every node's EKF track in one batch,
:func:`radioloc.locate.pf.fit_residuals`; the fitted range bias is removed; ``min_los_std_m``
floors the LOS spread). Option ``loss`` chooses the rows' loss: ``max-mixture`` (default
when the log has ranges: the LOS/NLOS max-mixture of the range rows, the other rows
Gaussian; pseudoranges get their own LOS/NLOS modes, each row's std its LOS spread,
``alpha`` the LOS fraction and ``nlos_mean_m`` the mean excess delay: given, or fitted by
EM to the residuals of a first smoothing from :data:`PSEUDORANGE_LOS_FRACTION` and
:data:`PSEUDORANGE_NLOS_MEAN_M`, then smoothed again: the self-tuning mixture), or a robust loss
``linear`` (default without ranges), ``huber``, ``cauchy``,
``tukey`` with ``loss_scale`` (standard deviations of each row's sigma). Pseudoranges: the
receiver clock's offset and drift (:func:`radioloc.models.clock.drifting`) are random walks
of intensity ``clock_offset_std_m_per_sqrt_s^2``; a clock per anchor group (constellation)
adds their inter-system biases, moving anchors (satellites) are where their tracks put them.
The max-mixture carries a
null-hypothesis mode by default (``null_weight`` 1e-3, ``null_std_m`` 10 m: a range much
too short has no LOS/NLOS mode and would otherwise pull the track as a 0.15 m LOS row;
``-o null_weight=0`` removes it). 3-D anchors with
``tag_height_m``: the ranges are modelled in 3-D at that height (no projection).

Each node's time stamps are the steps (one anchor per step when the anchors answer in
turn); segments split at gaps longer than ``max_gap_s`` are smoothed separately, the
whole segment in one sparse solve.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.estimators.batch_smoother import BatchSmoother
from radioloc.estimators.robust_loss import LOSSES
from radioloc.core.kinds import model_kinds
from radioloc.locate.adapter import (anchor_positions, given_sigmas, log_observations,
                                     sigma_options)
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.ekf_track import OPTIONS as EKF_OPTIONS
from radioloc.locate.ekf_track import (learn_tracks, log_models, motion_model, reads_clock,
                                       segment_tracks, segments, track_prior, track_table, track_window,
                                       tracker_filter, tracker_settings, tuned_prior)
from radioloc.locate.self_tuning import not_learnable, tuned_observations
from radioloc.locate.pf import OPTIONS as PF_OPTIONS
from radioloc.locate.pf import fit_residuals, node_residuals
from radioloc.locate.progress import counted
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.pseudorange import fit_nlos

__all__ = ["smooth_log", "OPTIONS"]

#: The pseudoranges' LOS/NLOS mixture of ``loss=max-mixture`` unless ``alpha`` and
#: ``nlos_mean_m`` are given: a LOS fraction and a mean NLOS excess delay (m) of urban
#: single-frequency GNSS.
PSEUDORANGE_LOS_FRACTION = 0.5
PSEUDORANGE_NLOS_MEAN_M = 20.0

#: The robust loss and its scale (standard deviations of each row's learned white noise) of
#: the rows when the settings are learned (``tune=1``, the default).
TUNED_LOSS = "huber"
TUNED_LOSS_SCALE = 2.0

#: The ``-o`` options of ``locate --method smoother``.
OPTIONS = {k: EKF_OPTIONS[k] for k in ("motion", "q", "range_bias_m", "tune",
                                       "clock_offset_std_m_per_sqrt_s", "earth_rotation",
                                       "tag_height_m", "prior_std_m",
                                       "init_s", "max_gap_s")}
OPTIONS.update(sigma_options())
OPTIONS.update({k: PF_OPTIONS[k] for k in ("los_std_m", "nlos_mean_m", "alpha",
                                           "min_los_std_m")})
OPTIONS.update({
    "loss": Option("'max-mixture' (default: LOS/NLOS max-mixture of each range) or a robust "
                   "loss of the standardised range residual", str,
                   choices=("max-mixture",) + LOSSES),
    "loss_scale": Option("the robust loss's scale, in standard deviations (range_std_m) "
                         "(default 1)", float, min=0, min_exclusive=True, max=1e6),
    "null_weight": Option("weight of the max-mixture's null-hypothesis mode (default 1e-3; 0: "
                          "none)", float, min=0, max=1),
    "null_std_m": Option("standard deviation of the null-hypothesis mode, m (default 10)",
                         float, min=0, min_exclusive=True, max=1e6),
})


@locate_method("smoother", "Batch MAP smoother of each node's whole track from its measurements "
                           "to anchors (the kinds of ekf-track; sparse solve; LOS/NLOS "
                           "max-mixture of the ranges by EM on the log, or a robust loss)",
               options=OPTIONS, kinds=tuple(model_kinds()) + ("rss",), inputs=("anchors",),
               moving_anchors=True)
def smooth_log(request: LocateRequest) -> pd.DataFrame:
    """Smoothed tracks of every node of a log (module docstring).

    Parameters
    ----------
    request : LocateRequest
        Measurement rows, anchors and ``-o`` options.

    Returns
    -------
    DataFrame
        ``time, node, x, y[, z], uncertainty_m`` at every time stamp with a measurement.

    Raises
    ------
    InputError, ConfigError, GeometryError
        As ``locate --method ekf-track`` (a bad option names it); odometry rows;
        ``loss=max-mixture`` on a log without ranges.
    """
    table = request.require_anchors("smoother")
    anchors = anchor_positions(table)
    s = tracker_settings(request, anchors)
    if s["odometry_std"] is not None:
        raise InputError("smoother: the batch smoother does not use odometry rows; remove them "
                         "or use ekf-track or pf")
    learn = (request.option("tune", True, bool)
             and bool((request.measurements["kind"] == "range").any()))
    short = not_learnable(request.measurements, given_sigmas(request)) if learn else None
    learn = learn and short is None
    log, opts, models = log_models(request, request.measurements, table, s,
                                   learn and request.option("range_std_m") is None)
    has_ranges = "range" in models
    loss = request.option("loss", "max-mixture" if has_ranges else "linear", str)
    if loss not in ("max-mixture",) + LOSSES:
        raise ConfigError(f"option loss: must be max-mixture or one of {', '.join(LOSSES)}, "
                          f"got {loss!r}")
    if loss == "max-mixture" and not has_ranges and "pseudorange" not in models:
        raise ConfigError("option loss=max-mixture: the LOS/NLOS max-mixture is a model of "
                          "ranges and pseudoranges, and the log has neither (use a robust "
                          "loss)")
    tune = (loss == "max-mixture" and "pseudorange" in models
            and request.option("alpha") is None and request.option("nlos_mean_m") is None)
    mixed, fitted = {}, {}      # the smoother's models where they differ from the start's
    if loss == "max-mixture" and "pseudorange" in models:   # each row's std is its LOS spread
        mixed["pseudorange"] = replace(
            models["pseudorange"], los_fraction=request.option("alpha", PSEUDORANGE_LOS_FRACTION),
            nlos_mean_m=request.option("nlos_mean_m", PSEUDORANGE_NLOS_MEAN_M))
    given = [request.option(k) for k in ("los_std_m", "nlos_mean_m", "alpha")]
    s0 = dict(s, bias=0.0)                   # the ranges below are without their bias
    tables, counts = [], {}
    nodes = [(node, sum(int(np.isfinite(o.z).sum()) for o in obs), times, obs)
             for node, times, obs in log_observations(log, table, models, "smoother",
                                                      s["height"])]
    if learn:
        tables, learned = _tuned(request, nodes, table, s)
        return _finish(tables, counts_of(nodes), {"loss": request.option("loss", TUNED_LOSS, str),
                                                  "learned": learned})
    noise = _range_noise(request, nodes, anchors, s, given) if loss == "max-mixture" else {}
    for node, _, times, obs in counted(nodes, sum(n[1] for n in nodes), lambda n: n[1],
                                       "smoother"):
        parts = segments(times, s["max_gap_s"])
        los_nlos, bias = noise.get(node, (None, s["bias"]))
        obs = [replace(o, z=o.z - bias) if o.model.kind == "range" else o for o in obs]
        for o in obs:
            counts[o.model.kind] = counts.get(o.model.kind, 0) + int(np.isfinite(o.z).sum())
        null_w = request.option("null_weight", 1e-3)
        null = (null_w, request.option("null_std_m", 10.0)) if los_nlos and null_w else None
        clock = reads_clock(obs)
        smoother = BatchSmoother(motion_model(s["motion"], s["q"], s["dim"]),
                                 loss="linear" if loss == "max-mixture" else loss,
                                 loss_scale=request.option("loss_scale", 1.0), los_nlos=los_nlos,
                                 null_hypothesis=null,
                                 **({"extra_q": s["clock_offset_q"] ** 2} if clock else {}))
        ekf = tracker_filter(anchors, s0, None, clock=clock)
        for seg in parts:
            t, ob = times[seg], track_window(times, obs, seg, s["init_s"])
            try:
                mean, var = track_prior(ekf, t, ob, anchors, s0)   # the same state layout
                ob = [replace(o, model=mixed.get(o.model.kind, o.model)) for o in ob]
                track = smoother.run(ob, t, prior_mean=mean, prior_cov=np.diag(var))
                if tune:                            # the pseudoranges' mixture, refitted
                    ob = _refit_nlos(ob, track, smoother.state_layout(ob))
                    fitted.update({f"pseudorange_{k}": float(getattr(o.model, k)) for o in ob
                                   if o.model.kind == "pseudorange"
                                   for k in ("los_fraction", "nlos_mean_m")})
                    track = smoother.run(ob, t, prior_mean=mean, prior_cov=np.diag(var),
                                         initial=track.diagnostics["state"])
            except GeometryError as exc:
                raise GeometryError(f"smoother: node {node!r} from time {float(t[0])!r}: "
                                    f"{exc}") from None
            tables.append(track_table(node, t, track, restart=seg is not parts[0]))
    return _finish(tables, counts, {"loss": loss, "range_std_m": opts["range_std_m"], **fitted,
                                    **({"tune": short} if short else {})})


def _finish(tables: list, counts: dict, extra: dict) -> pd.DataFrame:
    """The smoothed tracks of every node in one table, with the summary."""
    out = pd.concat(tables, ignore_index=True).sort_values(["time", "node"], kind="stable")
    out = out.reset_index(drop=True)
    out.attrs["summary"] = {"nodes": int(out["node"].nunique()), "steps": len(out),
                            "ranges": counts.get("range", 0), "measurements": counts,
                            "restarts": int(out["restart"].sum()), **extra}
    return out


def counts_of(nodes: list) -> dict[str, int]:
    """Rows of each kind over the nodes' observations."""
    counts: dict[str, int] = {}
    for _, _, _, obs in nodes:
        for o in obs:
            counts[o.model.kind] = counts.get(o.model.kind, 0) + int(np.isfinite(o.z).sum())
    return counts


def _tuned(request: LocateRequest, nodes: list, table: pd.DataFrame, s: dict
           ) -> tuple[list, dict]:
    """Every node's tracks smoothed with the settings learned from its rows
    (:mod:`radioloc.locate.self_tuning`): each anchor's range offset in the model, its white
    noise per row, its bias a constant (the offset's covariance) plus a Gauss-Markov part
    in the state, the process noise chosen by the evidence; the rows under the robust loss
    ``loss`` (default :data:`TUNED_LOSS`, scale ``loss_scale``, default
    :data:`TUNED_LOSS_SCALE` standard deviations) against the outliers (NLOS) the learned
    white noise does not cover. Returns the track tables and, by node, what was learned."""
    anchors = anchor_positions(table)
    given = given_sigmas(request)
    tracks = segment_tracks([(node, times, obs) for node, _, times, obs in nodes], s)
    learned = learn_tracks(request, tracks, table, s, 16.0, given)
    loss = request.option("loss", TUNED_LOSS, str)
    if loss not in LOSSES:
        raise ConfigError(f"option loss: with the learned settings (tune=1) a robust loss, one "
                          f"of {', '.join(LOSSES)}; got {loss!r}")
    tables, previous = [], None
    for node, times, obs in tracks:
        lr = learned[node]
        obs = tuned_observations(obs, lr)
        clock = reads_clock(obs)
        if lr.offset_m is not None:
            bq, btau, bcov = lr.bias_settings()
            ekf = tracker_filter(anchors, dict(s, q=lr.q), None, True, 3.0, clock, bq, btau, 2)
        else:
            bq, btau, bcov = 0.0, None, None
            ekf = tracker_filter(anchors, dict(s, q=lr.q), None, False, 3.0, clock)
        mean, cov = tuned_prior(ekf, times, obs, anchors, s, bcov)
        layout = ekf.state_layout(obs)
        smoother = BatchSmoother(motion_model(s["motion"], lr.q, s["dim"]), loss=loss,
                                 loss_scale=request.option("loss_scale", TUNED_LOSS_SCALE),
                                 bias_std_m_per_sqrt_s=bq, bias_time_constant_s=btau,
                                 layout=layout,
                                 **({"extra_q": s["clock_offset_q"] ** 2} if clock else {}))
        try:
            track = smoother.run(obs, times, prior_mean=mean, prior_cov=cov)
        except GeometryError as exc:
            raise GeometryError(f"smoother: node {node!r} from time {float(times[0])!r}: "
                                f"{exc}") from None
        tables.append(track_table(node, times, track, restart=node == previous))
        previous = node
    return tables, {str(n): lr.report for n, lr in learned.items()}


def _range_noise(request: LocateRequest, nodes: list, anchors: np.ndarray, s: dict,
                 given: list) -> dict[str, tuple[LosNlosRange, float]]:
    """The LOS/NLOS model of each node's range rows (given, or fitted by EM on them, the
    EKF tracks of every node in one batch) and the range bias to remove, by node (the
    nodes with range rows)."""
    ranging = [(node, times, next(o for o in obs if o.model.kind == "range"))
               for node, _, times, obs in nodes if any(o.model.kind == "range" for o in obs)]
    if not ranging:                          # pseudoranges alone: their own mixture
        return {}
    if all(g is not None for g in given):
        return {node: (LosNlosRange(*given), s["bias"]) for node, _, _ in ranging}
    if s["dim"] != 2:
        raise InputError("option loss=max-mixture: fitting the LOS/NLOS model needs 2-D "
                         "tracking (give tag_height_m) or los_std_m, nlos_mean_m and alpha")
    per_node = []
    for node, times, rng in ranging:
        R = np.full((times.size, len(anchors)), np.nan)
        R[:, rng.context.index] = rng.z
        per_node.append((node, times, R))
    floor = request.option("min_los_std_m", 0.15)
    out = {}
    for node, e in node_residuals(per_node, anchors, s, "smoother").items():
        los_nlos, bias, _ = fit_residuals(e)
        if los_nlos.los_std_m < floor:
            los_nlos = LosNlosRange(floor, los_nlos.nlos_mean_m, los_nlos.alpha)
        out[node] = (los_nlos, s["bias"] if "range_bias_m" in request.options else bias)
    return out


def _refit_nlos(observations: list, track, layout) -> list:
    """The observations with the pseudoranges' LOS fraction and mean NLOS excess fitted by
    EM (:func:`radioloc.models.pseudorange.fit_nlos`) to their residuals at the smoothed
    states of ``track``, starting from the model's."""
    out = []
    for o in observations:
        if o.model.kind == "pseudorange" and o.model.nlos_mean_m is not None:
            ctx = o.context if o.std is None else replace(o.context, std=o.std)
            z_hat, _ = layout.measure(o.model, track.diagnostics["state"], ctx)
            alpha, mu = fit_nlos(o.z - z_hat, o.model.std(ctx), o.model.los_fraction,
                                 o.model.nlos_mean_m)
            o = replace(o, model=replace(o.model, los_fraction=alpha, nlos_mean_m=mu))
        out.append(o)
    return out

