"""``radioloc locate --method gmm``: Gaussian-mixture RSS fingerprinting (paper 004).

Calibration file (``--calibration``), CSV: columns ``x, y`` (metres) and one column per
base station, named with the station id used as ``peer`` in the measurements; a cell is the
signal strength in dBm, empty when that station was not received::

    x,y,ap1,ap2,ap3
    0.0,0.0,-45.2,-61.0,
    0.5,0.0,-46.0,-60.1,-72.3

Measurements: ``rss`` rows, ``node`` = the mobile, ``peer`` = the base station id; all
rows of one ``(time, node)`` form one measurement vector (duplicates are averaged).

The EM initialisation draws from a generator seeded by the content of the calibration file,
so the same file always gives the same models.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError
from radioloc.estimators.mixture_localization import MixtureLocalizer, MixtureTracker
from radioloc.io.logs import LIMITS, RSS_NOT_DETECTED_DBM
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.models.mixture_calibration import em_calibration
from radioloc.models.motion import UniformDisk


def read_calibration(path) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Read a calibration file.

    Parameters
    ----------
    path : str or Path
        The CSV file (columns ``x, y`` and one per base station).

    Returns
    -------
    positions : ndarray, shape (N, 2)
        Calibration positions, metres.
    rss : ndarray, shape (N, S)
        Signal strengths, NaN = not received.
    ids : list of str
        The station ids (column names).
    """
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
    cols = []
    for c in ("x", "y"):
        v = pd.to_numeric(frame[c], errors="coerce")
        bad = v.isna() & frame[c].notna()
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"{path}: line {i + 2}, column {c}: not a number "
                             f"({str(frame[c].iloc[i])[:20]!r})")
        cols.append(v.to_numpy(float))
    pos = np.column_stack(cols)
    if not np.all(np.isfinite(pos)):
        i = int(np.flatnonzero(~np.isfinite(pos).all(1))[0])
        raise InputError(f"{path}: line {i + 2}: x, y must be finite")
    far = np.abs(pos) > LIMITS["coordinate_m"]
    if far.any():
        i, j = (int(k) for k in np.argwhere(far)[0])
        raise InputError(f"{path}: line {i + 2}, column {'xy'[j]}: |{pos[i, j]:g}| m exceeds "
                         f"{LIMITS['coordinate_m']:g} m")
    got = np.isfinite(rss)
    if np.isinf(rss).any():
        i, j = (int(k) for k in np.argwhere(np.isinf(rss))[0])
        raise InputError(f"{path}: line {i + 2}, column {ids[j]}: RSS must be finite "
                         "(leave the cell empty for a station not received)")
    out = got & ((rss > LIMITS["rss_max_dbm"]) | (rss < LIMITS["rss_min_dbm"]))
    if out.any():
        i, j = (int(k) for k in np.argwhere(out)[0])
        hint = (" (+100 is the 'not detected' sentinel of WiFi sets: leave such cells empty)"
                if rss[i, j] == RSS_NOT_DETECTED_DBM else "")
        raise InputError(f"{path}: line {i + 2}, column {ids[j]}: RSS {rss[i, j]:g} dBm outside "
                         f"[{LIMITS['rss_min_dbm']:g}, {LIMITS['rss_max_dbm']:g}]{hint}")
    return pos, rss, ids


@locate_method("gmm", "Gaussian-mixture RSS fingerprinting (paper 004) from a calibration file "
                      "(options: components, position_components, track=0/1, v_max)",
               options={"components": Option("mixture components per station model (16)", int,
                                             min=1, max=256),
                        "position_components": Option("components kept in position densities (8)",
                                                      int, min=1, max=256),
                        "track": Option("1: recursive tracking, 0: one-shot per row (0)", bool),
                        "v_max": Option("maximum speed when tracking, m/s (1.5)", float, min=0,
                                        max=1e3)},
               kinds=("rss",), inputs=("calibration",))
def locate_gmm(request: LocateRequest) -> pd.DataFrame:
    """Fingerprint localization with mixture models fitted to a calibration file.

    Each base station's model is fitted by EM to the calibration file; each
    ``(time, node)`` measurement vector is localized by eq. (2); with ``-o track=1`` each
    node is tracked over time with the uniform-disk motion model of radius ``v_max * dt``.

    Parameters
    ----------
    request : LocateRequest
        Measurements (``rss`` rows), the calibration file and the options.

    Returns
    -------
    pandas.DataFrame
        Columns ``time, node, x, y, uncertainty_m``, one row per ``(time, node)``.
    """
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
    content = np.nan_to_num(np.c_[pos, cal_rss], nan=-1e9)
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(
        np.frombuffer(content.tobytes(), dtype=np.uint32))))
    models = em_calibration(pos, cal_rss, int(request.option("components", 16)), rng=rng)
    kmax = int(request.option("position_components", 8))
    meas = table.to_numpy(float)
    out = table.index.to_frame(index=False)[["time", "node"]]
    if request.option("track", 0.0):
        mean = np.empty((len(out), 2))
        cov = np.empty((len(out), 2, 2))
        tracker = MixtureTracker(models, UniformDisk(float(request.option("v_max", 1.5)), dim=2),
                                 kmax)
        for node in out["node"].unique():         # nodes have different time axes
            idx = np.flatnonzero(out["node"].to_numpy() == node)
            res = tracker.run(meas[idx], out["time"].to_numpy()[idx])
            mean[idx], cov[idx] = res.position, res.covariance
    else:
        est = MixtureLocalizer(models, kmax).locate(meas)
        mean, cov = est.position, est.covariance
    out["x"], out["y"] = mean[:, 0], mean[:, 1]
    out["uncertainty_m"] = np.sqrt(np.trace(cov, axis1=-2, axis2=-1))
    return out
