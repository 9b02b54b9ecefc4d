"""Your own log, walk-through: BLE RSS fingerprints in a flat (Kolakowski 2021 data set).

Run:  python docs/tutorials/kolakowski_ble.py [OUT_DIR] [--small]
Needs the data set (`radioloc datasets fetch kolakowski`).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from radioloc.cli import app
from radioloc.core.results import Track


def radioloc(*args) -> None:
    """Run a `radioloc ...` command in this process (the same as typing it in a shell)."""
    app([str(a) for a in args], standalone_mode=False)


def weighted_knn(calibration: pd.DataFrame, measurements: pd.DataFrame, k: int = 4,
                 missing_dbm: float = -100.0) -> pd.DataFrame:
    """Baseline: weighted k nearest neighbours in signal space (missing readings = -100 dBm)."""
    ids = [c for c in calibration.columns if c not in ("x", "y")]
    cal = calibration[ids].fillna(missing_dbm).to_numpy()
    table = measurements.astype({"peer": str}).pivot_table(index="time", columns="peer",
                                                           values="value")
    meas = table.reindex(columns=ids).fillna(missing_dbm).to_numpy()
    d = np.linalg.norm(meas[:, None, :] - cal[None, :, :], axis=-1)
    near = np.argsort(d, axis=1)[:, :k]
    w = 1.0 / np.maximum(np.take_along_axis(d, near, 1), 1e-6)
    xy = calibration[["x", "y"]].to_numpy()[near]
    pos = (w[..., None] * xy).sum(1) / w.sum(1)[:, None]
    return pd.DataFrame({"time": table.index, "x": pos[:, 0], "y": pos[:, 1]})


def errors(est: pd.DataFrame, ref: pd.DataFrame) -> np.ndarray:
    m = est.merge(ref, on="time", suffixes=("", "_ref"))
    return np.hypot(m.x - m.x_ref, m.y - m.y_ref).to_numpy()


def main(out: str | Path = "tutorial-kolakowski", small: bool = False) -> pd.DataFrame:
    out = Path(out)
    # 1. Convert: calibration fingerprints (x, y, one column per anchor) and the robot test
    #    run as `rss` measurements.
    radioloc("datasets", "export", "kolakowski", "--out", out)
    calibration = out / "calibration.csv"
    if small:                       # a quarter of the calibration points, for a quick check
        cal = pd.read_csv(calibration)
        cal.iloc[::4].to_csv(out / "calibration_small.csv", index=False)
        calibration = out / "calibration_small.csv"
    # 2. Locate with the Gaussian-mixture fingerprint models (paper 004), snapshot by
    #    snapshot and tracked over time.
    radioloc("locate", out / "measurements.csv", "--method", "gmm", "--calibration",
             calibration, "--out", out / "gmm.csv")
    radioloc("locate", out / "measurements.csv", "--method", "gmm", "--calibration",
             calibration, "-o", "track=1", "--out", out / "gmm_track.csv")
    # 3. Compare with the usual baseline, weighted kNN, against the LiDAR-SLAM reference.
    ref = pd.read_csv(out / "reference.csv")
    est = {"gmm snapshot": pd.read_csv(out / "gmm.csv"),
           "gmm tracking": pd.read_csv(out / "gmm_track.csv"),
           "weighted 4-NN": weighted_knn(pd.read_csv(calibration),
                                         pd.read_csv(out / "measurements.csv"))}
    err = {k: errors(v, ref) for k, v in est.items()}
    table = pd.DataFrame({"method": list(err), "median_m": [np.median(e) for e in err.values()],
                          "rmse_m": [np.sqrt(np.mean(e ** 2)) for e in err.values()]})
    print(table.to_string(index=False, float_format="%.2f"))
    # 4. Plot the tracked path with its uncertainty (isotropic, same trace as reported).
    g = est["gmm tracking"]
    u2 = g.uncertainty_m.to_numpy() ** 2 / 2
    track = Track(g[["x", "y"]].to_numpy(), u2[:, None, None] * np.eye(2), g.time.to_numpy())
    fig = Figure(figsize=(10, 4.5))
    ax, ax2 = fig.subplots(1, 2)
    ax.plot(ref.x, ref.y, color="k", lw=2, label="reference (LiDAR SLAM)")
    track.plot(ax, every=40, color="tab:blue", lw=0.8, label="gmm tracking (95 % circles)")
    anchors = pd.read_csv(out / "anchors.csv")
    ax.plot(anchors.x, anchors.y, "k^", label="anchors")
    ax.legend(fontsize=8, loc="lower right")
    for name, e in err.items():
        ax2.plot(np.sort(e), np.linspace(0, 1, e.size), label=name)
    ax2.set(xlabel="error (m)", ylabel="fraction of test points", title="error CDF")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "kolakowski.png", dpi=110)
    return table


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(args[0] if args else "tutorial-kolakowski", small="--small" in sys.argv)
