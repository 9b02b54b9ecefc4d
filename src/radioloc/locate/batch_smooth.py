"""A user's range log smoothed by :class:`~radioloc.estimators.batch_smoother.BatchSmoother`.

:func:`smooth_log` takes a :class:`~radioloc.locate.base.LocateRequest` (the measurements
and anchors of ``radioloc locate``) and returns the smoothed track table of every node,
with the options of the trackers (``-o tag_height_m``, ``q``, ``motion``, ``prior_std_m``,
``init_s``, ``max_gap_s``, ``range_std_m``) and of ``pf`` (``los_std_m``, ``nlos_mean_m``,
``alpha`` given, or fitted by EM on the log as ``pf`` fits them:
:func:`radioloc.locate.pf.fit_model`; the fitted range bias is removed; ``min_los_std_m``
floors the LOS spread). Option ``loss`` chooses the rows' loss: ``max-mixture`` (default:
the LOS/NLOS max-mixture), or a robust loss ``linear``, ``huber``, ``cauchy``, ``tukey``
with ``loss_scale`` (standard deviations of ``range_std_m``). The max-mixture carries a
null-hypothesis mode by default (``null_weight`` 1e-3, ``null_std_m`` 10 m: a range much
too short has no LOS/NLOS mode and would otherwise pull the track as a 0.15 m LOS row;
``-o null_weight=0`` removes it). 3-D anchors with
``tag_height_m``: the ranges are modelled in 3-D at that height (no projection).

Each node's time stamps are the steps (one anchor per step when the anchors answer in
turn); segments split at gaps longer than ``max_gap_s`` are smoothed separately, the
whole segment in one sparse solve.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.estimators.batch_smoother import BatchSmoother
from radioloc.estimators.robust_loss import LOSSES
from radioloc.io.measurements import Measurements
from radioloc.locate.adapter import anchor_positions, anchor_ranges
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.ekf_track import OPTIONS as EKF_OPTIONS
from radioloc.locate.ekf_track import (PRIOR_SPEED_STD, motion_model, segments, start_position,
                                       track_table, tracker_settings)
from radioloc.locate.pf import OPTIONS as PF_OPTIONS
from radioloc.locate.pf import fit_model
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

__all__ = ["smooth_log", "OPTIONS"]

#: The ``-o`` options of ``locate --method smoother``.
OPTIONS = {k: EKF_OPTIONS[k] for k in ("motion", "q", "range_std_m", "range_bias_m",
                                       "tag_height_m", "prior_std_m", "init_s", "max_gap_s")}
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


@locate_method("smoother", "Batch MAP smoother of each node's whole track from its ranges to "
                           "anchors (sparse solve; LOS/NLOS max-mixture by EM on the log, or "
                           "a robust loss)",
               options=OPTIONS, kinds=("range",), inputs=("anchors",))
def smooth_log(request: LocateRequest) -> pd.DataFrame:
    """Smoothed tracks of every node of a range log (module docstring).

    Parameters
    ----------
    request : LocateRequest
        Range rows, anchors and ``-o`` options.

    Returns
    -------
    DataFrame
        ``time, node, x, y[, z], uncertainty_m`` at every time stamp with a range.

    Raises
    ------
    InputError, ConfigError, GeometryError
        As ``locate --method ekf-track`` (a bad option names it); odometry rows.
    """
    table = request.require_anchors("smoother")
    anchors = anchor_positions(table)
    per_node = anchor_ranges(Measurements(request.measurements), table, "smoother")
    s = tracker_settings(request, anchors)
    if s["odometry_std"] is not None:
        raise InputError("smoother: the batch smoother does not use odometry rows; remove them "
                         "or use ekf-track or pf")
    loss = request.option("loss", "max-mixture", str)
    if loss not in ("max-mixture",) + LOSSES:
        raise ConfigError(f"option loss: must be max-mixture or one of {', '.join(LOSSES)}, "
                          f"got {loss!r}")
    std = request.option("range_std_m", 0.15)
    given = [request.option(k) for k in ("los_std_m", "nlos_mean_m", "alpha")]
    tables = []
    for node, times, R in per_node:
        parts = segments(times, s["max_gap_s"])
        los_nlos, bias = None, s["bias"]
        if loss == "max-mixture":
            if any(g is None for g in given):
                if s["dim"] != 2:
                    raise InputError("option loss=max-mixture: fitting the LOS/NLOS model needs "
                                     "2-D tracking (give tag_height_m) or los_std_m, "
                                     "nlos_mean_m and alpha")
                los_nlos, bias, _ = fit_model(times, R, anchors, s, parts,
                                                label=f"method smoother: node {node!r}")
                floor = request.option("min_los_std_m", 0.15)
                if los_nlos.los_std_m < floor:
                    los_nlos = LosNlosRange(floor, los_nlos.nlos_mean_m, los_nlos.alpha)
                if "range_bias_m" in request.options:
                    bias = s["bias"]
            else:
                los_nlos = LosNlosRange(*given)
        null_w = request.option("null_weight", 1e-3)
        null = (null_w, request.option("null_std_m", 10.0)) if los_nlos and null_w else None
        smoother = BatchSmoother(motion_model(s["motion"], s["q"], s["dim"]),
                                 loss="linear" if loss == "max-mixture" else loss,
                                 loss_scale=request.option("loss_scale", 1.0), los_nlos=los_nlos,
                                 null_hypothesis=null)
        ctx = Context(points=anchors, height_m=s["height"])
        for seg in parts:
            t, r = times[seg], R[seg] - bias
            k = smoother.motion.state_dim
            mean = np.zeros(k)
            var = np.full(k, PRIOR_SPEED_STD ** 2)
            var[:s["dim"]] = s["prior_std"] ** 2
            if s["dim"] == 3:
                mean[2] = float(np.mean(anchors[:, 2]))
            try:
                mean[:2] = start_position(t, r, anchors, s["height"], 0.0, s["init_s"])
                track = smoother.run(Observation(RangeModel(std_m=std), r, ctx), t,
                                     prior_mean=mean, prior_cov=np.diag(var))
            except GeometryError as exc:
                raise GeometryError(f"smoother: node {node!r} from time {float(t[0])!r}: "
                                    f"{exc}") from None
            tables.append(track_table(node, t, track, restart=seg is not parts[0]))
    out = pd.concat(tables, ignore_index=True).sort_values(["time", "node"], kind="stable")
    out = out.reset_index(drop=True)
    out.attrs["summary"] = {"nodes": len(per_node), "steps": len(out),
                            "ranges": int(sum(np.isfinite(R).sum() for _, _, R in per_node)),
                            "restarts": int(out["restart"].sum()), "loss": loss,
                            "range_std_m": std}
    return out
