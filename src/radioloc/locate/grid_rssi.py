"""``radioloc locate --method grid-rssi``: grid Bayes filter on RSS to anchors (paper 003).

Each node's ``rss`` rows to anchors are applied in time order by the grid filter
(:class:`radioloc.estimators.grid.GridFilter`): one ProbabilityUpdate (Algorithm 1) per row
with the anchor as the "tracker" position; the estimate after each epoch is GetLocation
(Algorithm 2), its uncertainty GetUncertainty (Algorithm 3). All nodes run as one batch. The sensor model is a trapezoid model JSON (``--calibration``, written by
:meth:`radioloc.models.rssi_trapezoid.TrapezoidModel.save`); dBm values are mapped to 0..100
with ``rssi = round(100 (dBm - dbm_min) / (dbm_max - dbm_min))``.

Options: ``cell_m`` (0.5), ``margin_m`` (5: grid extends this far beyond the anchors),
``epsilon`` (1e-9), ``blur_m`` (0: BlurGrid radius applied between epochs for a moving
node), ``dbm_min`` (-110), ``dbm_max`` (-10), ``device_offset`` (none): ``auto`` subtracts
from each node's readings its label-free offset against the model's calibration readings
(:meth:`TrapezoidModel.device_offset`, from the ``count`` histogram of the model file); a
number subtracts that many dB from every reading.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.locate.gmm import _offset_option
from radioloc.estimators.grid import GridFilter, GridGeometry
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.progress import counted
from radioloc.locate.table import add_covariance
from radioloc.models.rssi_trapezoid import TrapezoidModel, dbm_to_rssi100


@locate_method("grid-rssi", "Grid Bayes filter (Zickler & Veloso) on RSS to anchors with a trapezoid "
                            "RSSI/distance model given by --calibration (options: cell_m, margin_m, "
                            "epsilon, blur_m, dbm_min, dbm_max)",
               options={"cell_m": Option("grid cell side, m (0.5)", float, min=0, min_exclusive=True,
                                         max=1e4),
                        "margin_m": Option("grid margin beyond the anchors, m (5)", float, min=0,
                                           max=1e5),
                        "epsilon": Option("floor of a cell's probability (1e-9)", float, min=0,
                                          min_exclusive=True, max=1),
                        "blur_m": Option("blur radius per row, m (0)", float, min=0, max=1e4),
                        "dbm_min": Option("dBm mapped to RSSI 0 (-110)", float, min=-200, max=30),
                        "dbm_max": Option("dBm mapped to RSSI 100 (-10)", float, min=-200, max=30),
                        "device_offset": Option("'auto': label-free per-node RSSI offset against "
                                                "the model's calibration readings; or dB to "
                                                "subtract (none)", str)},
               kinds=("rss",), inputs=("anchors", "calibration"), planar=True)
def locate_grid_rssi(request: LocateRequest) -> pd.DataFrame:
    """Run the grid filter on every node's RSS rows to anchors.

    Parameters
    ----------
    request : LocateRequest
        Measurements (``kind = rss``, dBm), anchors, ``calibration`` (trapezoid model JSON)
        and the options listed in the module docstring.

    Returns
    -------
    pandas.DataFrame
        One row per ``(time, node)`` epoch: ``time, node, x, y, uncertainty_m``
        (GetUncertainty, Algorithm 3) and the covariance columns (the grid's covariance
        about its mean).
    """
    if request.calibration is None:
        raise InputError("method grid-rssi: needs a trapezoid model JSON file (--calibration)")
    model = TrapezoidModel.load(request.calibration)
    anchors = request.require_anchors("grid-rssi")
    rss = request.kind("rss", "grid-rssi")
    rss = rss[rss["peer"].isin(set(anchors["id"]))]
    if rss.empty:
        raise InputError("method grid-rssi: no rss measurement to an anchor")
    cell = request.option("cell_m", 0.5)
    margin = request.option("margin_m", 5.0)
    eps = request.option("epsilon", 1e-9)
    blur = request.option("blur_m", 0.0)
    xy = anchors.set_index("id")[["x", "y"]]
    lo = xy.min().to_numpy() - margin
    hi = xy.max().to_numpy() + margin
    # the cell count in floating point first: a subnormal cell_m or a huge margin_m
    # overflows it (the quotient is inf), and int(inf) is not a size
    with np.errstate(all="ignore"):
        sides = np.ceil((hi - lo) / cell)
    if not np.all(np.isfinite(sides) & (sides <= 4_000_000)) or sides[0] * sides[1] > 4_000_000:
        raise InputError(f"option cell_m: a grid of {sides[0]:.3g} x {sides[1]:.3g} cells of "
                         f"{cell:g} m over the anchors and margin_m={margin:g} is too large "
                         "(limit 4e6 cells); use a larger cell_m or a smaller margin_m")
    w, h = (int(v) for v in sides)
    geom = GridGeometry(w, h, cell, (float(lo[0]), float(lo[1])))

    rss = rss.sort_values(["node", "time", "line"]).reset_index(drop=True)
    offset = _offset_option(request)
    dbm = rss["value"].to_numpy()
    if offset is not None and offset != "auto":
        dbm = dbm - float(offset)
    rssi = dbm_to_rssi100(dbm, request.option("dbm_min", -110.0), request.option("dbm_max", -10.0))
    if offset == "auto":
        node_of = rss["node"].to_numpy()
        for node in pd.unique(node_of):           # one offset per device
            rows = node_of == node
            rssi[rows] = model.correct(rssi[rows], model.device_offset(rssi[rows]))
    nodes = list(dict.fromkeys(rss["node"]))
    if w * h * len(nodes) > 20_000_000:       # one float64 grid per node, several copies a step
        raise InputError(f"option cell_m: {len(nodes)} nodes x {w} x {h} cells need about "
                         f"{w * h * len(nodes) * 8 * 4 / 1e9:.1f} GB; use a larger cell_m or "
                         "smaller margin_m (limit 2e7 node-cells)")
    n_idx = rss["node"].map({n: i for i, n in enumerate(nodes)}).to_numpy()
    j_idx = rss.groupby("node").cumcount().to_numpy()
    N, J = len(nodes), int(j_idx.max()) + 1
    pos = np.zeros((N, J, 2))
    meas = np.zeros((N, J), dtype=np.int64)
    valid = np.zeros((N, J), bool)
    pos[n_idx, j_idx] = xy.loc[rss["peer"]].to_numpy()
    meas[n_idx, j_idx] = rssi
    valid[n_idx, j_idx] = True
    times = rss["time"].to_numpy()
    last = np.zeros((N, J), bool)
    first = np.zeros((N, J), bool)
    same_next = (rss["node"].shift(-1) == rss["node"]) & (rss["time"].shift(-1) == rss["time"])
    same_prev = (rss["node"].shift(1) == rss["node"]) & (rss["time"].shift(1) == rss["time"])
    last[n_idx, j_idx] = ~same_next.to_numpy()
    first[n_idx, j_idx] = ~same_prev.to_numpy() & (j_idx > 0)
    t_of = np.full((N, J), np.nan)
    t_of[n_idx, j_idx] = times

    filt = GridFilter(geom, model, epsilon=eps, location="peak")
    state = filt.init(N)
    reading = np.where(valid, meas, np.nan)
    out = []
    for j in counted(range(J), int(valid.sum()), lambda j: int(valid[:, j].sum()), "grid-rssi"):
        if blur > 0 and first[:, j].any():
            state = filt.predict(state, dt=0.0, extra_blur_m=np.where(first[:, j], blur, 0.0))
        state = filt.update(state, np.where(valid[:, j, None], pos[:, j], np.nan), reading[:, j])
        done = last[:, j]
        if done.any():
            est = filt.estimate(state[done])
            idx = np.flatnonzero(done)
            rows = add_covariance(pd.DataFrame({
                "time": t_of[idx, j], "node": [nodes[i] for i in idx],
                "x": est.position[:, 0], "y": est.position[:, 1]}), est.covariance)
            rows["uncertainty_m"] = est.diagnostics["uncertainty_m"]   # Algorithm 3
            out.append(rows)
    return pd.concat(out, ignore_index=True).sort_values(["time", "node"]).reset_index(drop=True)
