"""The batch smoother with the max-mixture LOS/NLOS loss on the Hanyang runs, beside
`ekf-track --smooth` and `pf --smooth`, in the data set authors' metric.

Run:  python docs/tutorials/hanyang_smoother.py [OUT_DIR] [--no-cli]
Needs the data set (`radioloc datasets fetch hanyang`, or RADIOLOC_DATA pointing at it).

For every run of trajectory A: export the log as it arrives (`--epoch-s 0`), run
`radioloc locate --method ekf-track --smooth` and `--method pf --smooth` (tag height 1 m,
seed 1; skipped with --no-cli, or where OUT_DIR already holds their tables), smooth the
same log with :func:`radioloc.locate.batch_smooth.smooth_log` (max-mixture with and
without its null-hypothesis mode, and a Huber loss), and score each track with
:func:`radioloc.io.hanyang.authors_rmse` (2-D RMSE on the return leg).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pandas as pd

from radioloc.cli import app
from radioloc.io.hanyang import authors_rmse, dynamic_runs, load_dynamic
from radioloc.io import read_anchors, read_measurements
from radioloc.locate.base import LocateRequest
from radioloc.locate.batch_smooth import smooth_log

RUNS = ("LOS/A/1", "LOS/A/2", "NLOS/A/1", "NLOS/A/2")
SMOOTHERS = {
    "smoother max-mixture + null": {},
    "smoother max-mixture (LOS/NLOS only)": {"null_weight": "0"},
    "smoother huber (c = 3)": {"loss": "huber", "loss_scale": "3"},
}


def radioloc(*args) -> None:
    """Run a `radioloc ...` command in this process (the same as typing it in a shell)."""
    app([str(a) for a in args], standalone_mode=False)


def run_folder(root: Path, run: str) -> Path:
    """The data set folder of a run named like ``LOS/A/1``."""
    los, traj, case = run.split("/")
    return root / "Dynamic_measurements" / los / f"Trajectory_{traj}" / f"Case_{case}"


def main(out: str | Path = "tutorial-hanyang-smoother", cli: bool = True) -> pd.DataFrame:
    out = Path(out)
    root = Path(os.environ.get("RADIOLOC_DATA", "data")) / "hanyang-uwb-outdoor"
    if not any(True for _ in dynamic_runs(root)):
        raise SystemExit(f"no Hanyang runs under {root}")
    rows = []
    for run in RUNS:
        d = out / run.replace("/", "_")
        data = load_dynamic(run_folder(root, run))
        if not (d / "measurements.csv").exists():
            radioloc("datasets", "export", "hanyang", "--run", run, "--epoch-s", "0", "--out", d)
        scores = {}
        for method in ("ekf-track", "pf"):
            table = d / f"{method.split('-')[0]}_smooth.csv"
            if cli and not table.exists():
                extra = ["-o", "seed=1"] if method == "pf" else []
                radioloc("locate", d / "measurements.csv", "--anchors", d / "anchors.csv",
                         "--method", method, "-o", "tag_height_m=1.0", *extra, "--smooth",
                         "--out", table)
            if table.exists():
                est = pd.read_csv(table).rename(columns={"time": "time_s"})
                scores[f"{method} --smooth"] = authors_rmse(data.reference, est, "A")["rmse_2d"]
        meas = read_measurements(d / "measurements.csv")
        anchors = read_anchors(d / "anchors.csv")
        for name, opts in SMOOTHERS.items():
            t0 = time.perf_counter()
            tab = smooth_log(LocateRequest(meas, anchors, options={"tag_height_m": "1.0", **opts}))
            seconds = time.perf_counter() - t0
            est = tab.rename(columns={"time": "time_s"})
            scores[name] = authors_rmse(data.reference, est, "A")["rmse_2d"]
            scores[f"{name} seconds"] = seconds
        rows.append(pd.Series(scores, name=run))
    table = pd.DataFrame(rows).T
    table["mean"] = table.mean(axis=1)
    print(table.to_string(float_format="%.2f"))
    return table


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(args[0] if args else "tutorial-hanyang-smoother", cli="--no-cli" not in sys.argv)
