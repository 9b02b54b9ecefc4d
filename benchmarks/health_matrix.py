"""Methods x simulated faults: does a method that is wrong say so?

For every fixed-anchor method of ``radioloc locate`` and every fault of
:data:`radioloc.sim.faulty_logs.FAULTS`, runs the command line in this process on a simulated log
and prints: the exit code, the warnings, and the share of the track whose error exceeds 5 times
the claimed standard deviation (``uncertainty_m``). A run is *silently wrong* when that share is
above 5 % and it exits 0 with no warning. ``--runs N`` repeats the clean case N times per method
(seeds 0..N-1) and counts runs with a warning (false alarms).

Usage: python benchmarks/health_matrix.py [--methods gn,lsq] [--faults clean,nlos] [--runs N]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.sim.faulty_logs import FAULTS, walk_log

METHODS = ("gn", "lsq", "ekf-track", "smoother", "pf", "localml", "ransac")
#: The option naming the range noise of each method (others: range_std_m).
RANGE_OPTION = {"gn": "std_m", "localml": "los_std_m", "ransac": None, "pf": None}
#: Methods that read kinds other than ranges.
ALL_KINDS = ("lsq", "ekf-track", "smoother")


def takes(method: str, kind: str) -> bool:
    return kind == "range" or method in ALL_KINDS


def run(method: str, fault: str, seed: int, folder: Path, extra: tuple[str, ...] = ()) -> dict:
    """One run of ``radioloc locate``: exit code, warnings, errors against the truth."""
    log = walk_log(fault, seed)
    meas, anchors = folder / "m.csv", folder / "a.csv"
    log.measurements.to_csv(meas, index=False)
    log.anchors.to_csv(anchors, index=False)
    options = []
    for key, value in log.options.items():
        name = RANGE_OPTION.get(method, key) if key == "range_std_m" else key
        if name:
            options += ["-o", f"{name}={value}"]
    out = folder / "out.csv"
    res = CliRunner().invoke(app, ["locate", str(meas), "--anchors", str(anchors), "--method",
                                   method, "--out", str(out), "-q", *options, *extra])
    warned = [line for line in res.output.splitlines() if line.startswith("warning:")]
    record = {"method": method, "fault": fault, "seed": seed, "exit": res.exit_code,
              "warnings": len(warned), "message": (warned[0] if warned else res.output.strip()
                                                   .splitlines()[-1] if res.output.strip() else ""),
              "bad_share": np.nan, "rmse_m": np.nan}
    if res.exit_code == 0 and out.is_file():
        est = pd.read_csv(out)
        ref = log.reference.set_index("time")
        truth = ref.loc[est["time"], ["x", "y"]].to_numpy()
        err = np.linalg.norm(est[["x", "y"]].to_numpy() - truth, axis=1)
        claimed = est["uncertainty_m"].to_numpy() if "uncertainty_m" in est else np.zeros(len(est))
        record["bad_share"] = float(np.mean(err > 5 * claimed))
        record["rmse_m"] = float(np.sqrt(np.mean(err ** 2)))
    record["silent_wrong"] = bool(record["exit"] == 0 and not record["warnings"]
                                  and record["bad_share"] > 0.05)
    return record


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--methods", default=",".join(METHODS))
    p.add_argument("--faults", default=",".join(FAULTS))
    p.add_argument("--runs", type=int, default=1)
    args = p.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for method in args.methods.split(","):
            for fault in args.faults.split(","):
                if not takes(method, walk_log(fault, 0, steps=2).kind):
                    continue
                for seed in range(args.runs if fault == "clean" else 1):
                    rows.append(run(method, fault, seed, Path(tmp)))
                    r = rows[-1]
                    print(f"{method:10s} {fault:15s} seed {seed:3d} exit {r['exit']} warn "
                          f"{r['warnings']} rmse {r['rmse_m']:.3g} >5sd {r['bad_share']:.2f} "
                          f"{'SILENT-WRONG ' if r['silent_wrong'] else ''}{r['message'][:150]}",
                          flush=True)
    table = pd.DataFrame(rows)
    clean = table[table["fault"] == "clean"]
    print("false warnings on clean logs:", clean.groupby("method")["warnings"]
          .apply(lambda w: int((w > 0).sum())).to_dict(), "of", args.runs)
    print("silently wrong:", int(table["silent_wrong"].sum()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
