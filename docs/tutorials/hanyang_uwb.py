"""Your own log, walk-through: a UWB tag ranging to 4 anchors (Hanyang outdoor data set).

Run:  python docs/tutorials/hanyang_uwb.py [OUT_DIR] [--small]
Needs the data set (`radioloc datasets fetch hanyang`).
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


def rmse_2d(est: pd.DataFrame, ref: pd.DataFrame) -> float:
    """2-D RMSE of estimates against the reference interpolated to their times."""
    inside = est[(est.time >= ref.time.min()) & (est.time <= ref.time.max())]
    dx = inside.x - np.interp(inside.time, ref.time, ref.x)
    dy = inside.y - np.interp(inside.time, ref.time, ref.y)
    return float(np.sqrt(np.mean(dx ** 2 + dy ** 2)))


def main(out: str | Path = "tutorial-hanyang", small: bool = False) -> pd.DataFrame:
    out = Path(out)
    # 1. Convert one run to the `radioloc locate` schema. The tag is about 1.1 m above the
    #    ground: projecting the ranges to the horizontal plane lets us solve in 2-D.
    radioloc("datasets", "export", "hanyang", "--run", "LOS/A/1", "--tag-height", "1.1",
             "--epoch-s", "0.5" if small else "0.1", "--out", out)
    # 2. Locate the tag at every epoch (Gauss-Newton multilateration, 4 anchors). Seen from
    #    the tag, this small anchor box can fit the tag's mirror image as well as the tag at
    #    some epochs: `gn` refuses such a fix, and `on_degenerate=skip` leaves those epochs
    #    out with one warning that counts them.
    radioloc("locate", out / "measurements.csv", "--anchors", out / "anchors.csv",
             "-o", "on_degenerate=skip", "--out", out / "gn.csv")
    # 3. Compare with the data set's own estimates (LS, ESKF) against the RTK reference.
    ref = pd.read_csv(out / "reference.csv")
    est = {"radioloc gn": pd.read_csv(out / "gn.csv"), "data set LS": pd.read_csv(out / "ls.csv"),
           "data set ESKF": pd.read_csv(out / "eskf.csv")}
    table = pd.DataFrame({"method": list(est), "epochs": [len(e) for e in est.values()],
                          "rmse_2d_m": [rmse_2d(e, ref) for e in est.values()]})
    print(table.to_string(index=False, float_format="%.2f"))
    # 4. Plot: the reference, the data set's LS, and our track with its uncertainty. `gn`
    #    reports sqrt(trace(covariance)) per epoch; a Track with the isotropic covariance of
    #    that trace draws it as circles.
    gn = est["radioloc gn"]
    u2 = gn.uncertainty_m.to_numpy() ** 2 / 2
    track = Track(gn[["x", "y"]].to_numpy(), u2[:, None, None] * np.eye(2), gn.time.to_numpy())
    fig = Figure(figsize=(10, 4.2))
    ax = fig.subplots()
    ax.plot(ref.x, ref.y, color="k", lw=2, label="RTK reference")
    ax.plot(est["data set LS"].x, est["data set LS"].y, color="tab:red", lw=0.8, label="data set LS")
    track.plot(ax, every=25, color="tab:blue", lw=0.8, label="radioloc gn (95 % circles)")
    anchors = pd.read_csv(out / "anchors.csv")
    ax.plot(anchors.x, anchors.y, "k^", label="anchors")
    ax.legend(loc="upper right", fontsize=8)
    ax.set_title("Hanyang LOS trajectory A, case 1")
    fig.tight_layout()
    fig.savefig(out / "hanyang.png", dpi=110)
    return table


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(args[0] if args else "tutorial-hanyang", small="--small" in sys.argv)
