"""Paper 001's filter on real UWB ranges: the Hanyang outdoor data set (4 anchors, RTK truth).

The LOS/NLOS error model (with a common ranging bias) is fitted by EM on the static files,
whose true distances are known; the particle filter (one tag, anchors only: no peers in this
data), the local ML and RANSAC then track the moving tag of each dynamic run, and their 2-D
RMSE against the RTK reference is compared with the LS and ESKF estimates shipped with the
data set.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.metrics import position_error
from radioloc.core.rng import stream
from radioloc.estimators.los_nlos_em import fit_los_nlos
from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.estimators.snapshot_baselines import LocalML, Ransac
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, register
from radioloc.io.hanyang import (dynamic_runs, horizontal_ranges, load_dynamic, load_static,
                                 resample_epochs)
from radioloc.models.motion import InputDriven
from radioloc.report.style import COLORS, figure, save


@dataclass(frozen=True)
class RealUwbConfig:
    """Settings of ``real-uwb-hanyang`` (one Monte Carlo run per dynamic run folder).

    epoch_s: filter step; at each epoch every anchor's latest range of the last epoch_s is used.
    velocity_std_m: the data has no IMU; the INS reading of a step is the difference of the
        RTK reference over the step plus N(0, velocity_std_m^2) per axis, and the filter
        uses the same value as s_INS.
    static_samples: static range errors used by EM (0 = all), drawn from the named stream
        "em-static-subsample" of the experiment seed.
    particles, init_std_m, reset_*: particle filter settings; p(v_0) is centred on the
        reference start.
    ransac_threshold_m: inlier gate, 3 fitted s_LOS (at least 0.1 m) when None.
    max_epochs: use only the first max_epochs epochs of each run (0 = all; the quick size
        tracks the first 60 s of the first run).
    Ranges are corrected by the EM bias and projected to the horizontal plane with the tag
    at reference z + 1 m (the data set authors' convention); the filter works in 2-D.
    """

    runs: int = 4
    block_size: int = 1
    epoch_s: float = 0.1
    velocity_std_m: float = 0.02
    static_samples: int = 4000
    particles: int = 500
    init_std_m: float = 0.5
    reset_fraction: float = 0.05
    reset_std_m: float = 0.3
    ransac_threshold_m: float | None = None
    max_epochs: int = 0


@register
class RealUwbHanyang(Experiment):
    """``real-uwb-hanyang``: paper 001's filter on the Hanyang outdoor UWB runs."""

    id = "real-uwb-hanyang"
    paper = "001"
    description = "P2P PF (anchors only) on Hanyang outdoor UWB runs vs the data set's LS and ESKF"
    data_folder = "hanyang-uwb-outdoor"

    def config(self, full: bool) -> RealUwbConfig:
        """The settings of the quick or the full size.

        Parameters
        ----------
        full : bool
            The paper's size instead of the quick one.

        Returns
        -------
        RealUwbConfig
        """
        if full:
            return RealUwbConfig(static_samples=0, particles=900)
        return RealUwbConfig(runs=1, particles=200, static_samples=1500, max_epochs=600)

    def run_block(self, config: RealUwbConfig, runs: np.ndarray, rng: np.random.Generator) -> pd.DataFrame:
        """Simulate (or load) and estimate the runs of one block.

        Parameters
        ----------
        config : the experiment's config
        runs : ndarray of int
            Run indices of the block.
        rng : numpy.random.Generator
            The block's generator (per-experiment draws use named streams of it).

        Returns
        -------
        DataFrame
            The tidy results table (one row per method, run, step and vehicle).
        """
        c = config
        root = self.data_path()
        static = load_static(root)
        e = static.error_m.to_numpy()
        if c.static_samples and c.static_samples < e.size:
            # a per-experiment draw: every block fits the same subsample
            e = stream(rng, "em-static-subsample").choice(e, c.static_samples, replace=False)
        fit = fit_los_nlos(e)
        model, bias = fit.model, fit.bias_m
        folders = dynamic_runs(root)
        pf = P2PParticleFilter(InputDriven(c.velocity_std_m), model, particles=c.particles,
                               init_std=c.init_std_m, reset_fraction=c.reset_fraction,
                               reset_std_m=c.reset_std_m)
        ml = LocalML(model, 60.0)
        ransac = Ransac(c.ransac_threshold_m or max(3 * model.los_std_m, 0.1), 60.0)
        frames = []
        for r in runs:
            if r >= len(folders):
                continue
            run = load_dynamic(folders[r])
            t, theta, truth = resample_epochs(run, c.epoch_s)
            if c.max_epochs:
                t, theta, truth = t[:c.max_epochs], theta[:c.max_epochs], truth[:c.max_epochs]
            anchors = run.anchors[["x", "y", "z"]].to_numpy()
            horiz = horizontal_ranges(theta, anchors, truth[:, 2], bias)         # (T, M)
            xy = truth[:, :2]
            ins = np.diff(xy, axis=0, prepend=xy[:1]) + c.velocity_std_m * rng.standard_normal(xy.shape)
            # one vehicle (N = 1) whose range to itself is absent, then the anchors
            ranges = np.concatenate([np.full((t.size, 1), np.nan), horiz], axis=1)[None, None]
            res = pf.run(ranges, xy[None, :1], rng, anchors=anchors[:, :2],
                         controls=ins[None, None], time=t)
            est = {"pf": res.position[0, 0],
                   "ml": ml.locate(horiz, anchors[:, :2]).position,
                   "ransac": ransac.locate(horiz, anchors[:, :2]).position}
            for meth, p in est.items():
                frames.append(pd.DataFrame({"run": r, "name": run.name, "method": meth, "time_s": t,
                                            "x_est": p[:, 0], "y_est": p[:, 1], "x_true": xy[:, 0],
                                            "y_true": xy[:, 1], "error_m": position_error(p, xy)}))
            for meth, g in run.estimates.items():
                tt = g.time_s.to_numpy()
                ok = (tt >= run.reference.time_s.min()) & (tt <= min(run.reference.time_s.max(), t[-1]))
                tt = tt[ok]
                ref = np.stack([np.interp(tt, run.reference.time_s, run.reference[k]) for k in ("x", "y")], -1)
                p = g[["x", "y"]].to_numpy()[ok]
                frames.append(pd.DataFrame({"run": r, "name": run.name, "method": meth, "time_s": tt,
                                            "x_est": p[:, 0], "y_est": p[:, 1], "x_true": ref[:, 0],
                                            "y_true": ref[:, 1], "error_m": position_error(p, ref),
                                            "published_rmse_2d": run.published.get(f"{meth}_rmse_2d", np.nan)}))
        out = pd.concat(frames, ignore_index=True)
        out["em_alpha"], out["em_los_std_m"] = model.alpha, model.los_std_m
        out["em_nlos_mean_m"], out["em_bias_m"] = model.nlos_mean_m, bias
        return out

    def summarize(self, config: RealUwbConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Metrics, claims and figures from the results table only.

        Parameters
        ----------
        config : the experiment's config
        results : DataFrame
            The concatenated tables of every block.
        out_dir : Path
            Folder of the figures.

        Returns
        -------
        Summary
        """
        metrics, rm = [], {}
        for (name, meth), g in results.groupby(["name", "method"]):
            rm[(name, meth)] = float(np.sqrt(np.mean(g.error_m**2)))
            pub = g["published_rmse_2d"].iloc[0] if "published_rmse_2d" in g else np.nan
            metrics.append(Metric(f"{meth}_rmse_m_{name}", rm[(name, meth)],
                                  None if not np.isfinite(pub) else float(pub), "m",
                                  "2-D RMSE vs RTK" + (" (paper column: RMSD_results.txt 2-D)"
                                                       if np.isfinite(pub) else "")))
        first = results.iloc[0]
        for k, unit in (("em_alpha", ""), ("em_los_std_m", "m"), ("em_nlos_mean_m", "m"), ("em_bias_m", "m")):
            metrics.append(Metric(k, float(first[k]), None, unit, "EM fit on the static files"))
        names = sorted(results.name.unique())
        claims = []
        if all((n, "eskf") in rm for n in names):
            claims.append(Claim("the particle filter's 2-D RMSE is below the data set's ESKF on every run (PF velocity from the RTK reference + noise: not like for like)",
                                all(rm[(n, "pf")] < rm[(n, "eskf")] for n in names)))
            claims.append(Claim("the particle filter's 2-D RMSE is below the data set's LS on every run (PF velocity from the RTK reference + noise: not like for like)",
                                all(rm[(n, "pf")] < rm[(n, "ls")] for n in names)))
        fig, axes = figure(len(names), 1, width=8.0, height=2.4 * len(names), squeeze=False)
        for ax, n in zip(axes[:, 0], names):
            g = results[results.name == n]
            ref = g[g.method == "pf"]
            ax.plot(ref.x_true, ref.y_true, "-", color=COLORS["truth"], lw=2, label="RTK reference")
            for meth, col in (("pf", COLORS["ours"]), ("eskf", COLORS["alt"]), ("ls", COLORS["baseline"])):
                gm = g[g.method == meth]
                ax.plot(gm.x_est, gm.y_est, "-", color=col, lw=0.8, label=meth.upper())
            ax.set_ylim(-8, 8)
            ax.set_title(n)
            ax.set_ylabel("y [m]")
        axes[-1, 0].set_xlabel("x [m]")
        axes[0, 0].legend(ncol=4, loc="upper right")
        save(fig, out_dir / "trajectories.png")
        return Summary(metrics, claims, [f"EM fit: alpha={first.em_alpha:.3f}, s_LOS={first.em_los_std_m:.3f} m, "
                                         f"s_NLOS={first.em_nlos_mean_m:.3f} m, bias={first.em_bias_m:.3f} m"])
