"""Monte Carlo comparison of estimators: a registered experiment, then one of your own.

Run:  python docs/tutorials/monte_carlo.py [OUT_DIR] [--small]
Needs no data set.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from radioloc.cli import app
from radioloc.experiments.runner import run_experiment


def radioloc(*args) -> None:
    """Run a `radioloc ...` command in this process (the same as typing it in a shell)."""
    app([str(a) for a in args], standalone_mode=False)


def linear_least_squares(ranges: np.ndarray, anchors: np.ndarray) -> np.ndarray:
    """Closed-form baseline: subtract the first anchor's squared-range equation from the
    others and solve the linear system, for a whole batch at once.

    ranges : (N, A), anchors : (A, 2) -> positions (N, 2).
    """
    a0, r0 = anchors[0], ranges[:, :1]
    H = 2.0 * (anchors[1:] - a0)                                   # (A-1, 2)
    b = (r0 ** 2 - ranges[:, 1:] ** 2 + np.sum(anchors[1:] ** 2, 1) - np.sum(a0 ** 2))
    sol, *_ = np.linalg.lstsq(H, b.T, rcond=None)                  # all runs in one solve
    return sol.T


def main(out: str | Path = "tutorial-monte-carlo", small: bool = False) -> pd.DataFrame:
    out = Path(out)
    # 1. A registered experiment: Gauss-Newton multilateration against the Cramer-Rao
    #    bound. The runner returns the tidy table it also writes to results.csv.
    outcome = run_experiment("gn-multilateration", runs=100 if small else 2000, seed=1,
                             out=out, progress=False)
    res = outcome.results
    by_noise = res.groupby("range_std_m").agg(
        rmse_m=("error_m", lambda e: float(np.sqrt(np.mean(e ** 2)))),
        crb_m=("crb_trace_m2", lambda c: float(np.sqrt(np.mean(c)))))
    print(by_noise.to_string(float_format="%.3f"))

    # 2. Your own comparison. Each Monte Carlo run is one node of one log, so that
    #    `radioloc locate` solves all runs in one batched call; the baseline is a
    #    closed-form linear least squares written above with NumPy.
    rng = np.random.default_rng(7)
    runs = 200 if small else 5000
    anchors = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 50.0], [0.0, 50.0]])
    truth = rng.uniform(0.0, 50.0, size=(runs, 2))
    rows = []
    for std in (0.1, 1.0, 3.0):
        dist = np.linalg.norm(truth[:, None, :] - anchors[None], axis=-1)
        ranges = np.abs(dist + std * rng.standard_normal(dist.shape))
        log = pd.DataFrame({"time": 0.0, "node": np.repeat([f"run{i}" for i in range(runs)], 4),
                            "peer": np.tile(["a0", "a1", "a2", "a3"], runs), "kind": "range",
                            "value": ranges.ravel()})
        log.to_csv(out / "mc_measurements.csv", index=False)
        pd.DataFrame({"id": ["a0", "a1", "a2", "a3"], "x": anchors[:, 0],
                      "y": anchors[:, 1]}).to_csv(out / "mc_anchors.csv", index=False)
        radioloc("locate", out / "mc_measurements.csv", "--anchors", out / "mc_anchors.csv",
                 "-o", f"range_std_m={std}", "--out", out / "mc_gn.csv")
        gn = pd.read_csv(out / "mc_gn.csv")
        gn = gn.set_index(gn.node.str[3:].astype(int)).sort_index()
        err_gn = np.linalg.norm(gn[["x", "y"]].to_numpy() - truth, axis=1)
        err_ls = np.linalg.norm(linear_least_squares(ranges, anchors) - truth, axis=1)
        rows += [{"range_std_m": std, "method": "Gauss-Newton (radioloc locate)",
                  "rmse_m": np.sqrt(np.mean(err_gn ** 2)),
                  "mean_reported_uncertainty_m": gn.uncertainty_m.mean()},
                 {"range_std_m": std, "method": "linear least squares",
                  "rmse_m": np.sqrt(np.mean(err_ls ** 2)), "mean_reported_uncertainty_m": np.nan}]
    table = pd.DataFrame(rows)
    print(table.to_string(index=False, float_format="%.3f"))

    fig = Figure(figsize=(10, 4))
    ax, ax2 = fig.subplots(1, 2)
    ax.loglog(by_noise.index, by_noise.rmse_m, "o-", label="Gauss-Newton RMSE")
    ax.loglog(by_noise.index, by_noise.crb_m, "k:", label="CRB")
    ax.set(xlabel="range noise std (m)", ylabel="position error (m)",
           title="gn-multilateration experiment")
    ax.legend()
    for method, g in table.groupby("method"):
        ax2.loglog(g.range_std_m, g.rmse_m, "o-", label=method)
    ax2.set(xlabel="range noise std (m)", ylabel="RMSE (m)", title="your own comparison")
    ax2.legend()
    fig.tight_layout()
    fig.savefig(out / "monte_carlo.png", dpi=110)
    return table


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if not a.startswith("--")]
    main(args[0] if args else "tutorial-monte-carlo", small="--small" in sys.argv)
