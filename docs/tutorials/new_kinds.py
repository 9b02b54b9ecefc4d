"""Your own log, walk-through: time differences, angles of arrival, pseudoranges, and anchors
that calibrate themselves.

Run:  python docs/tutorials/new_kinds.py [OUT_DIR]
Writes the logs it makes up (a tag walking a loop among six anchors), runs `radioloc`
on them as a user would, and writes the table of docs/generated/new_kinds.md to
OUT_DIR/new_kinds.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.cli import app

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0], [10.0, -3.0],
                    [23.0, 7.0]])
IDS = [f"A{k}" for k in range(len(ANCHORS))]
C = 299_792_458.0


def radioloc(*args) -> None:
    """Run a `radioloc ...` command in this process (the same as typing it in a shell)."""
    app([str(a) for a in args], standalone_mode=False)


def walk(steps: int = 150, dt: float = 0.2) -> tuple[np.ndarray, np.ndarray]:
    """Times and positions of a tag walking a loop at about 1 m/s."""
    t = dt * np.arange(steps)
    return t, np.stack([10 + 6 * np.cos(t / 6), 7 + 4 * np.sin(t / 6)], axis=-1)


def logs(rng: np.random.Generator) -> dict[str, pd.DataFrame]:
    """One measurement log per kind, in the locate schema."""
    t, xy = walk()
    d = np.linalg.norm(xy[:, None, :] - ANCHORS, axis=-1)
    out = {}
    rows = []                                    # tdoa against A0: arrival times differenced
    arrival = d + 0.1 * rng.standard_normal(d.shape)
    for k in range(len(t)):
        rows += [(t[k], "tag", IDS[a], "tdoa", arrival[k, a] - arrival[k, 0], "A0")
                 for a in range(1, len(IDS))]
    out["tdoa"] = pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value", "reference"])
    v = xy[:, None, :] - ANCHORS                # aoa: bearing from each anchor, 2 degrees
    bearing = np.arctan2(v[..., 1], v[..., 0]) + np.deg2rad(2) * rng.standard_normal(d.shape)
    out["aoa"] = pd.DataFrame([(t[k], "tag", IDS[a], "aoa", np.angle(np.exp(1j * bearing[k, a])))
                               for k in range(len(t)) for a in range(len(IDS))],
                              columns=["time", "node", "peer", "kind", "value"])
    offset = 150.0 + 2.0 * t                     # pseudorange: a receiver clock offset (m)
    pr = d + offset[:, None] + 0.3 * rng.standard_normal(d.shape)
    out["pseudorange"] = pd.DataFrame([(t[k], "tag", IDS[a], "pseudorange", pr[k, a])
                                       for k in range(len(t)) for a in range(len(IDS))],
                                      columns=["time", "node", "peer", "kind", "value"])
    return out


def calibration_log(rng: np.random.Generator) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Anchors (three surveyed, three rough by up to 2 m) and ranges with an antenna delay."""
    delay = np.array([0.30, 0.45, 0.25, 0.50, 0.40, 0.35])
    rough = ANCHORS + np.r_[[0.0] * 3, [1.0] * 3][:, None] * rng.normal(0, 1.5, ANCHORS.shape)
    anchors = pd.DataFrame({"id": IDS, "x": rough[:, 0], "y": rough[:, 1],
                            "std_m": ["", "", "", 2.0, 2.0, 2.0]})
    rows = [(0.0, IDS[i], IDS[j], "range", np.linalg.norm(ANCHORS[i] - ANCHORS[j]) + delay[i]
             + delay[j] + 0.05 * rng.normal()) for i in range(6) for j in range(6) if i != j]
    t, xy = walk(60, 0.5)
    d = np.linalg.norm(xy[:, None, :] - ANCHORS, axis=-1) + delay + 0.05 * rng.standard_normal((60, 6))
    rows += [(t[k], "tag", IDS[a], "range", d[k, a]) for k in range(60) for a in range(6)]
    return anchors, pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"])


def rmse(track: Path, truth: np.ndarray, times: np.ndarray) -> float:
    est = pd.read_csv(track)
    ref = truth[np.searchsorted(times, est["time"].to_numpy())]
    return float(np.sqrt(np.mean(np.sum((est[["x", "y"]].to_numpy() - ref) ** 2, axis=1))))


def main(out: str | Path = "tutorial-new-kinds") -> pd.DataFrame:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(7)
    pd.DataFrame({"id": IDS, "x": ANCHORS[:, 0], "y": ANCHORS[:, 1]}).to_csv(out / "anchors.csv",
                                                                            index=False)
    t, xy = walk()
    options = {"tdoa": ["-o", "tdoa_std_m=0.1"], "aoa": ["-o", "aoa_std_rad=0.035"],
               "pseudorange": ["-o", "pseudorange_std_m=0.3"]}
    rows = []
    for kind, frame in logs(rng).items():
        frame.to_csv(out / f"{kind}.csv", index=False)
        for method in ("ekf-track", "smoother"):
            track = out / f"{kind}-{method}.csv"
            radioloc("locate", out / f"{kind}.csv", "--anchors", out / "anchors.csv", "--method",
                     method, *options[kind], "--quiet", "--out", track)
            rows.append({"log": kind, "command": f"--method {method} {' '.join(options[kind])}",
                         "result": f"track RMSE {rmse(track, xy, t):.2f} m"})
    anchors, log = calibration_log(rng)
    anchors.to_csv(out / "rough_anchors.csv", index=False)
    log.to_csv(out / "calibration.csv", index=False)
    radioloc("calibrate", out / "calibration.csv", "--anchors", out / "rough_anchors.csv",
             "--bias", "--std-m", "0.05", "--out", out / "calibrated.csv")
    cal = pd.read_csv(out / "calibrated.csv")
    err = np.linalg.norm(cal[["x", "y"]].to_numpy() - ANCHORS, axis=1)[3:]
    before = np.linalg.norm(anchors[["x", "y"]].to_numpy() - ANCHORS, axis=1)[3:]
    rows.append({"log": "anchor calibration", "command": "calibrate --bias --std-m 0.05",
                 "result": f"rough anchors {before.mean():.2f} m -> {err.mean():.3f} m off "
                           f"(CRB {cal['crb_std_m'].to_numpy()[3:].mean():.3f} m); antenna "
                           f"delays to {np.abs(cal['bias_m'] - [0.30, 0.45, 0.25, 0.50, 0.40, 0.35]).max():.3f} m"})
    table = pd.DataFrame(rows)
    lines = ["<!-- generated by docs/tutorials/new_kinds.py; do not edit -->", "",
             "| log | `radioloc` | result |", "|---|---|---|"]
    lines += [f"| {r.log} | `{r.command}` | {r.result} |" for r in table.itertuples()]
    (out / "new_kinds.md").write_text("\n".join(lines) + "\n")
    return table


if __name__ == "__main__":
    print(main(sys.argv[1] if len(sys.argv) > 1 else "tutorial-new-kinds").to_string(index=False))
