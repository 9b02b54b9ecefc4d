"""``radioloc locate --method gmm``: Gaussian-mixture RSS fingerprinting (paper 004).

Calibration file (``--calibration``), CSV: columns ``x, y`` (metres) and one column per
base station, named with the station id used as ``peer`` in the measurements; a cell is the
signal strength in dBm, empty when that station was not received::

    x,y,ap1,ap2,ap3
    0.0,0.0,-45.2,-61.0,
    0.5,0.0,-46.0,-60.1,-72.3

Measurements: ``rss`` rows, ``node`` = the mobile, ``peer`` = the base station id; all
rows of one ``(time, node)`` form one measurement vector (duplicates are averaged).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.estimators.mixture_localization import localize, track
from radioloc.locate.base import LocateRequest, locate_method
from radioloc.models.mixture_calibration import em_calibration


def read_calibration(path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Positions ``(N, 2)``, signal strengths ``(N, S)`` (NaN = not received), station ids."""
    try:
        frame = pd.read_csv(path, dtype={"x": float, "y": float})
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the calibration file ({exc})") from None
    frame.columns = [str(c).strip() for c in frame.columns]
    missing = {"x", "y"} - set(frame.columns)
    if missing:
        raise InputError(f"{path}: calibration column(s) {', '.join(sorted(missing))} missing")
    ids = [c for c in frame.columns if c not in ("x", "y")]
    if not ids:
        raise InputError(f"{path}: no base station column besides x, y")
    try:
        rss = frame[ids].apply(pd.to_numeric, errors="raise").to_numpy(float)
    except ValueError as exc:
        raise InputError(f"{path}: a base station column is not numeric ({exc})") from None
    pos = frame[["x", "y"]].to_numpy(float)
    if not np.all(np.isfinite(pos)):
        i = int(np.flatnonzero(~np.isfinite(pos).all(1))[0])
        raise InputError(f"{path}: line {i + 2}: x, y must be finite")
    return pos, rss, ids


@locate_method("gmm", "Gaussian-mixture RSS fingerprinting (paper 004) from a calibration file "
                      "(options: components, position_components, track=0/1, v_max)")
def locate_gmm(request: LocateRequest) -> pd.DataFrame:
    """Each base station's model is fitted by EM to the calibration file; each
    ``(time, node)`` measurement vector is localized by eq. (2); with ``-o track=1`` each
    node is tracked over time with the uniform-disk motion model of radius ``v_max * dt``."""
    if request.calibration is None:
        raise InputError("method gmm: needs a calibration file (--calibration)")
    pos, cal_rss, ids = read_calibration(request.calibration)
    rss = request.kind("rss", "gmm")
    unknown = ~rss["peer"].isin(ids)
    if unknown.any():
        row = rss[unknown].iloc[0]
        raise InputError(f"method gmm: line {row['line']}: peer {row['peer']!r} is not a base "
                         f"station of the calibration file (known: {', '.join(ids)})")
    rss = rss.groupby(["time", "node", "peer"], sort=True, as_index=False)["value"].mean()
    table = rss.pivot_table(index=["node", "time"], columns="peer", values="value")
    table = table.reindex(columns=ids).sort_index()
    models = em_calibration(pos, cal_rss, int(request.option("components", 16)))
    kmax = int(request.option("position_components", 8))
    meas = table.to_numpy(float)
    out = table.index.to_frame(index=False)[["time", "node"]]
    if request.option("track", 0.0):
        mean = np.empty((len(out), 2))
        cov = np.empty((len(out), 2, 2))
        for node in out["node"].unique():         # nodes have different time axes
            idx = np.flatnonzero(out["node"].to_numpy() == node)
            t = out["time"].to_numpy()[idx]
            res = track(models, meas[idx], np.diff(t, prepend=t[0]),
                        float(request.option("v_max", 1.5)), kmax)
            mean[idx], cov[idx] = res.mean, res.covariance
    else:
        mean, cov = localize(models, meas, kmax).moments()
    out["x"], out["y"] = mean[:, 0], mean[:, 1]
    out["uncertainty_m"] = np.sqrt(np.trace(cov, axis1=-2, axis2=-1))
    return out
