"""Scenarios of the log schema's newer kinds for the `radioloc locate` fuzz, and of
`radioloc calibrate`: each a valid input set with its truth (exact measurements of a tag
walking among six anchors), so that a success is judged by the truth oracle
(``fuzz_harness.oracle``).

- ``tdoa``, ``tdoa-lsq``: time differences against a reference anchor (``reference``
  column) by ``ekf-track`` and ``lsq``;
- ``aoa``, ``aoa-lsq``: bearings; ``aoa3``: bearings and elevations from 3-D anchors;
- ``pseudorange``: pseudoranges with a receiver clock offset and drift;
- ``odometry``: ranges to one anchor at a time and ``odometry_dx`` / ``odometry_dy`` rows;
- ``std``, ``std-gn``: ranges with a per-row ``std`` column;
- ``cal-anchors``: an anchors file with ``std_m`` and ``bias_m`` columns (ranges biased);
- ``moving``: an anchor that moves (anchors file with a ``time`` column), by ``lsq``;
- ``calibrate``: `radioloc calibrate` of three rough anchors from anchor-to-anchor and
  tag ranges (its output: the calibrated anchors file, judged against the true anchors).
"""

from __future__ import annotations

import io
import math
from pathlib import Path

import numpy as np
import pandas as pd

ANCHORS = {"A0": (0.0, 0.0), "A1": (20.0, 0.0), "A2": (20.0, 15.0), "A3": (0.0, 15.0),
           "A4": (10.0, -3.0), "A5": (23.0, 7.0)}
HEIGHTS = {"A0": 2.5, "A1": 0.3, "A2": 2.8, "A3": 0.5, "A4": 3.0, "A5": 1.2}
TAG_Z = 1.0
C_CLOCK = (150.0, 2.0)             # pseudorange: clock offset (m) and drift (m/s)
BIAS = {"A0": 0.3, "A1": 0.45, "A2": 0.25, "A3": 0.5, "A4": 0.4, "A5": 0.35}
STEPS, DT = 16, 0.5


def walk(t: float, node: str = "tag") -> tuple[float, float] | None:
    """Where the tag is at time ``t`` (a slow arc inside the anchors)."""
    if node != "tag":
        return None
    return (6.0 + 0.8 * t, 5.0 + 0.4 * t + 0.05 * t * t)


def _fmt(v: float) -> str:
    return repr(float(v))


def _times() -> list[float]:
    return [DT * k for k in range(STEPS)]


def _bearing(p, a) -> float:
    return math.atan2(p[1] - a[1], p[0] - a[0])


def kind_rows() -> dict[str, list[list[str]]]:
    """Measurement rows (header first) per scenario."""
    out: dict[str, list[list[str]]] = {}
    head = ["time", "node", "peer", "kind", "value"]
    ids = list(ANCHORS)
    rows = [head + ["reference"]]
    for t in _times():
        p = walk(t)
        for a in ids[1:]:
            rows.append([_fmt(t), "tag", a, "tdoa",
                         _fmt(math.dist(p, ANCHORS[a]) - math.dist(p, ANCHORS["A0"])), "A0"])
    out["tdoa"] = rows
    rows = [head]
    for t in _times():
        for a in ids:
            rows.append([_fmt(t), "tag", a, "aoa", _fmt(_bearing(walk(t), ANCHORS[a]))])
    out["aoa"] = rows
    rows = [head]
    for t in _times():
        p = walk(t)
        for a in ids:
            q = ANCHORS[a]
            rows.append([_fmt(t), "tag", a, "aoa", _fmt(_bearing(p, q))])
            rows.append([_fmt(t), "tag", a, "aoa_elevation",
                         _fmt(math.atan2(TAG_Z - HEIGHTS[a], math.dist(p, q)))])
    out["aoa3"] = rows
    rows = [head]
    for t in _times():
        p = walk(t)
        for a in ids:
            rows.append([_fmt(t), "tag", a, "pseudorange",
                         _fmt(math.dist(p, ANCHORS[a]) + C_CLOCK[0] + C_CLOCK[1] * t)])
    out["pseudorange"] = rows
    rows = [head]
    prev = None
    for k, t in enumerate(_times()):
        p = walk(t)
        a = ids[k % 4]
        rows.append([_fmt(t), "tag", a, "range", _fmt(math.dist(p, ANCHORS[a]))])
        if prev is not None:
            rows.append([_fmt(t), "tag", "wheel", "odometry_dx", _fmt(p[0] - prev[0])])
            rows.append([_fmt(t), "tag", "wheel", "odometry_dy", _fmt(p[1] - prev[1])])
        prev = p
    out["odometry"] = rows
    rows = [head + ["std"]]
    for k, t in enumerate(_times()):
        for j, a in enumerate(ids):
            rows.append([_fmt(t), "tag", a, "range", _fmt(math.dist(walk(t), ANCHORS[a])),
                         ["0.05", "0.2", "", "0.1"][(k + j) % 4]])
    out["std"] = rows
    rows = [head]
    for t in _times():
        for a in ids:
            rows.append([_fmt(t), "tag", a, "range",
                         _fmt(math.dist(walk(t), ANCHORS[a]) + BIAS[a])])
    out["cal-anchors"] = rows
    rows = [head]
    for t in _times():
        for a in ids[:3] + ["M"]:
            q = ANCHORS[a] if a != "M" else _moving(t)
            rows.append([_fmt(t), "tag", a, "range", _fmt(math.dist(walk(t), q))])
    out["moving"] = rows
    return out


def _moving(t: float) -> tuple[float, float]:
    """The moving anchor ``M``: a straight line from (0, 15) to (15, 18) over 7.5 s."""
    return (2.0 * t, 15.0 + 0.4 * t)


def anchor_files(folder: Path) -> dict[str, Path]:
    folder = Path(folder)
    out = {}
    p = folder / "kinds-anchors.csv"
    p.write_text("id,x,y\n" + "".join(f"{k},{x},{y}\n" for k, (x, y) in ANCHORS.items()))
    out["plain"] = p
    p = folder / "kinds-anchors3.csv"
    p.write_text("id,x,y,z\n" + "".join(f"{k},{x},{y},{HEIGHTS[k]}\n"
                                        for k, (x, y) in ANCHORS.items()))
    out["3d"] = p
    p = folder / "kinds-anchors-cal.csv"
    p.write_text("id,x,y,std_m,bias_m\n" + "".join(
        f"{k},{x},{y},{'' if i < 3 else 0.02},{BIAS[k]}\n"
        for i, (k, (x, y)) in enumerate(ANCHORS.items())))
    out["cal"] = p
    p = folder / "kinds-anchors-moving.csv"
    end = STEPS * DT
    p.write_text("id,time,x,y\n" + "".join(f"{k},,{ANCHORS[k][0]},{ANCHORS[k][1]}\n"
                                           for k in ("A0", "A1", "A2"))
                 + f"M,0.0,{_moving(0.0)[0]},{_moving(0.0)[1]}\n"
                 + f"M,{end},{_moving(end)[0]},{_moving(end)[1]}\n")
    out["moving"] = p
    return out


def build_kind_scenarios(folder: Path, scenario_type) -> dict:
    """The scenarios of the newer kinds (``scenario_type``: ``fuzz_harness.Scenario``)."""
    rows = kind_rows()
    files = anchor_files(folder)
    trk = ("motion", "q", "range_std_m", "tdoa_std_m", "aoa_std_rad", "pseudorange_std_m",
           "gate", "smooth", "init_s", "odometry_std_m", "anchor_bias", "tag_height_m")
    lsq = ("range_std_m", "tdoa_std_m", "aoa_std_rad", "pseudorange_std_m", "loss",
           "loss_scale", "on_degenerate")
    smo = ("motion", "q", "tdoa_std_m", "aoa_std_rad", "pseudorange_std_m", "loss",
           "loss_scale", "init_s", "max_gap_s", "prior_std_m")
    S = scenario_type
    plain = {"anchors": files["plain"]}
    return {
        "tdoa-smoother": S("smoother", rows["tdoa"], plain, {"tdoa_std_m": "0.05"}, smo,
                           truth_at=walk, tol_m=0.5),
        "aoa-smoother": S("smoother", rows["aoa"], plain, {"aoa_std_rad": "0.01"}, smo,
                          truth_at=walk, tol_m=0.5),
        "pseudorange-smoother": S("smoother", rows["pseudorange"], plain,
                                  {"pseudorange_std_m": "0.1"}, smo, truth_at=walk, tol_m=1.0),
        "tdoa": S("ekf-track", rows["tdoa"], plain, {"tdoa_std_m": "0.05"}, trk,
                  truth_at=walk, tol_m=0.5),
        "tdoa-lsq": S("lsq", rows["tdoa"], plain, {"tdoa_std_m": "0.05"}, lsq,
                      truth_at=walk, tol_m=0.05),
        "aoa": S("ekf-track", rows["aoa"], plain, {"aoa_std_rad": "0.01"}, trk,
                 truth_at=walk, tol_m=0.5),
        "aoa-lsq": S("lsq", rows["aoa"], plain, {"aoa_std_rad": "0.01"}, lsq,
                     truth_at=walk, tol_m=0.05),
        "aoa3": S("ekf-track", rows["aoa3"], {"anchors": files["3d"]}, {"aoa_std_rad": "0.01"},
                  trk, truth_at=walk, tol_m=0.5),
        "pseudorange": S("ekf-track", rows["pseudorange"], plain, {"pseudorange_std_m": "0.1"},
                         trk, truth_at=walk, tol_m=1.0),
        "odometry": S("ekf-track", rows["odometry"], plain, {"range_std_m": "0.05"}, trk,
                      truth_at=walk, tol_m=0.5),
        "std": S("ekf-track", rows["std"], plain, {}, trk, truth_at=walk, tol_m=0.5),
        "std-gn": S("gn", rows["std"], plain, {}, ("range_std_m", "on_degenerate"),
                    truth_at=walk, tol_m=1e-3),
        "cal-anchors": S("gn", rows["cal-anchors"], {"anchors": files["cal"]}, {},
                         ("range_std_m", "on_degenerate"), truth_at=walk, tol_m=1e-3),
        "moving": S("lsq", rows["moving"], {"anchors": files["moving"]}, {}, lsq,
                    truth_at=walk, tol_m=0.05),
    }


# ---- radioloc calibrate ---------------------------------------------------------------

CAL_TRUTH = {"A0": (0.0, 0.0), "A1": (20.0, 0.0), "A2": (20.0, 15.0), "A3": (0.6, 16.1),
             "A4": (10.0, -3.0), "A5": (23.0, 7.0)}
CAL_ROUGH = {"A3": (1.4, 15.0), "A4": (9.0, -2.0), "A5": (22.0, 8.5)}


def calibrate_inputs(folder: Path, bias: bool = True) -> tuple[Path, Path]:
    """(measurements, rough anchors) of a calibration: ranges between anchors and of a tag
    walking; biases ``BIAS`` added when ``bias``."""
    folder = Path(folder)
    anchors = folder / "cal-rough.csv"
    anchors.write_text("id,x,y,std_m\n" + "".join(
        f"{k},{CAL_ROUGH.get(k, p)[0]},{CAL_ROUGH.get(k, p)[1]},{2.0 if k in CAL_ROUGH else ''}\n"
        for k, p in CAL_TRUTH.items()))
    ids = list(CAL_TRUTH)
    b = BIAS if bias else dict.fromkeys(ids, 0.0)
    rows = [["time", "node", "peer", "kind", "value"]]
    for i in ids:
        for j in ids:
            if i != j:
                rows.append(["0.0", i, j, "range",
                             _fmt(math.dist(CAL_TRUTH[i], CAL_TRUTH[j]) + b[i] + b[j])])
    for t in _times():
        for a in ids:
            rows.append([_fmt(t), "tag", a, "range", _fmt(math.dist(walk(t), CAL_TRUTH[a]) + b[a])])
    meas = folder / "cal-meas.csv"
    meas.write_text("".join(",".join(r) + "\n" for r in rows))
    return meas, anchors


def calibrate_oracle(stdout: str, anchor_ids: set[str], tol_m: float = 0.05,
                     k_sigma: float = 5.0, bias: dict[str, float] | None = None) -> str | None:
    """Judge a calibrated anchors file: every input anchor once, finite coordinates, each
    within ``tol_m`` of the truth or ``k_sigma`` of its reported standard deviation (and
    so each ``bias_m``, when ``bias`` gives the true ones)."""
    try:
        from fuzz_harness import read_output

        est = read_output(stdout, "id")
    except Exception as exc:  # noqa: BLE001
        return f"unreadable output: {exc}"
    if not {"id", "x", "y"} <= set(est.columns):
        return f"columns {list(est.columns)}"
    if set(est["id"]) != anchor_ids or est["id"].duplicated().any():
        return f"anchors {sorted(est['id'])}, expected {sorted(anchor_ids)}"
    xy = est[["x", "y"]].to_numpy(float)
    if not np.isfinite(xy).all():
        return "non-finite coordinate"
    truth = np.array([CAL_TRUTH[a] for a in est["id"]])
    err = np.linalg.norm(xy - truth, axis=1)
    if {"cov_xx", "cov_yy"} <= set(est.columns):
        sd = np.sqrt(np.nan_to_num(est["cov_xx"].to_numpy(float))
                     + np.nan_to_num(est["cov_yy"].to_numpy(float)))
    else:
        sd = np.zeros(len(est))
    bad = (err > tol_m) & (err > k_sigma * sd)
    if bad.any():
        i = int(np.argmax(np.where(bad, err, -1)))
        return (f"confidently wrong: anchor {est['id'].iloc[i]} {err[i]:.3g} m off the truth, "
                f"claiming {sd[i]:.3g} m")
    if bias is not None and "bias_m" in est.columns:
        b = est["bias_m"].to_numpy(float)
        berr = np.abs(b - np.array([bias[a] for a in est["id"]]))
        bsd = np.nan_to_num(est["bias_std_m"].to_numpy(float)) if "bias_std_m" in est.columns \
            else np.zeros(len(est))
        bad = ~np.isfinite(b) | ((berr > tol_m) & (berr > k_sigma * bsd))
        if bad.any():
            i = int(np.argmax(bad))
            return (f"confidently wrong: bias of {est['id'].iloc[i]} {b[i]:.3g} m, truth "
                    f"{bias[est['id'].iloc[i]]:.3g} m, claiming {bsd[i]:.3g} m")
    return None
