"""Your own log, walk-through: WiFi fingerprints on one floor (UJIIndoorLoc).

Run:  python docs/tutorials/ujiindoorloc_wifi.py [OUT_DIR] [--small]
Needs the data set (`radioloc datasets fetch ujiindoorloc`).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from radioloc.cli import app


def radioloc(*args) -> None:
    """Run a `radioloc ...` command in this process (the same as typing it in a shell)."""
    app([str(a) for a in args], standalone_mode=False)


def nearest_neighbour(calibration: pd.DataFrame, measurements: pd.DataFrame,
                      missing_dbm: float = -105.0) -> pd.DataFrame:
    """Baseline of the data set's paper: 1-NN, Euclidean distance in signal space."""
    ids = [c for c in calibration.columns if c not in ("x", "y")]
    cal = calibration[ids].fillna(missing_dbm).to_numpy()
    table = measurements.astype({"peer": str}).pivot_table(index="time", columns="peer",
                                                           values="value")
    meas = table.reindex(columns=ids).fillna(missing_dbm).to_numpy()
    d = np.linalg.norm(meas[:, None, :] - cal[None, :, :], axis=-1)
    pos = calibration[["x", "y"]].to_numpy()[np.argmin(d, axis=1)]
    return pd.DataFrame({"time": table.index, "x": pos[:, 0], "y": pos[:, 1]})


def main(out: str | Path = "tutorial-uji", small: bool = False) -> pd.DataFrame:
    out = Path(out)
    # 1. Convert building 0, floor 1: training fingerprints -> calibration file, validation
    #    fingerprints (another user, months later, other phones) -> `rss` measurements.
    #    Coordinates are EPSG:3857 "metres" (0.766 ground metres), shifted to a local origin.
    radioloc("datasets", "export", "ujiindoorloc", "--building", "0", "--floor", "1",
             "--min-detections", "200" if small else "20", "--out", out)
    # 2. Locate every validation fingerprint with the Gaussian-mixture models (paper 004).
    radioloc("locate", out / "measurements.csv", "--method", "gmm", "--calibration",
             out / "calibration.csv", "-o", "components=4" if small else "components=8",
             "--out", out / "gmm.csv")
    # 3. Compare with 1-NN (the baseline of the data set's paper).
    ref = pd.read_csv(out / "reference.csv")
    est = {"gmm": pd.read_csv(out / "gmm.csv"),
           "1-NN": nearest_neighbour(pd.read_csv(out / "calibration.csv"),
                                     pd.read_csv(out / "measurements.csv"))}
    err = {}
    for name, e in est.items():
        m = e.merge(ref, on="time", suffixes=("", "_ref"))
        err[name] = np.hypot(m.x - m.x_ref, m.y - m.y_ref).to_numpy()
    table = pd.DataFrame({"method": list(err), "fingerprints": [e.size for e in err.values()],
                          "median_file_units": [np.median(e) for e in err.values()],
                          "mean_file_units": [np.mean(e) for e in err.values()]})
    print(table.to_string(index=False, float_format="%.2f"))
    # 4. Plot: calibration points, validation truth and the gmm estimates.
    cal = pd.read_csv(out / "calibration.csv")
    fig = Figure(figsize=(10, 4.5))
    ax, ax2 = fig.subplots(1, 2)
    ax.plot(cal.x, cal.y, ".", color="0.75", ms=3, label="calibration (training)")
    m = est["gmm"].merge(ref, on="time", suffixes=("", "_ref"))
    ax.plot(np.stack([m.x_ref, m.x]), np.stack([m.y_ref, m.y]), color="tab:red", lw=0.6)
    ax.plot(m.x_ref, m.y_ref, "k.", ms=4, label="validation truth")
    ax.plot(m.x, m.y, ".", color="tab:blue", ms=4, label="gmm estimate")
    ax.set(aspect="equal", xlabel="x (file units)", ylabel="y (file units)")
    ax.legend(fontsize=8)
    for name, e in err.items():
        ax2.plot(np.sort(e), np.linspace(0, 1, e.size), label=name)
    ax2.set(xlabel="error (file units)", ylabel="fraction", title="error CDF")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "ujiindoorloc.png", dpi=110)
    return table


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(args[0] if args else "tutorial-uji", small="--small" in sys.argv)
