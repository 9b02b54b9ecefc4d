"""Paper 001's filter on real UWB ranges: the Hanyang outdoor data set (4 anchors, RTK truth).

Every method is scored the way the data set's authors score their ``LS.csv`` and
``ESKF.csv`` (:func:`radioloc.io.hanyang.authors_rmse`: 2-D RMSE on the return leg of
trajectory A, reference interpolated to each estimate's time), which reproduces their
``RMSD_results.txt`` exactly. Methods, one table per data set:

- the data set's own LS and ESKF estimates;
- what a user with only the log has, run as ``radioloc locate`` runs them on the log's
  rows as they arrive (:func:`radioloc.io.hanyang.measurement_rows`, tag height 1 m):
  ``ekf-track`` (causal, and RTS-smoothed offline) and ``pf`` (paper 001's LOS/NLOS
  particle filter with a constant-velocity motion and EM on the log; causal, fixed-lag
  and backward-simulation smoothed offline), over several seeds;
- per-epoch snapshot baselines on the ranges resampled to 0.1 s epochs: Gauss-Newton
  multilateration (epochs whose fix is ambiguous or degenerate left out and counted),
  paper 001's local ML and RANSAC;
- ``pf-ins``: the particle filter as paper 001 runs it, with INS readings, which this data
  lacks: they are taken from differences of the RTK reference. A user has no such
  readings, so this row is labelled and carries no claim.

Claims are judged only on causal methods that use the log alone.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.rng import stream
from radioloc.estimators.los_nlos_em import fit_los_nlos
from radioloc.estimators.multilateration import Multilateration
from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.estimators.snapshot_baselines import LocalML, Ransac
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, register
from radioloc.io.hanyang import (authors_reference, dynamic_runs, horizontal_ranges, load_dynamic,
                                 load_static, measurement_rows, resample_epochs)
from radioloc.locate.base import LocateRequest, check_request, methods, run_method
from radioloc.locate.pf import pf_tracks
from radioloc.models.motion import InputDriven
from radioloc.report.style import COLORS, figure, save

#: Run index r is folder ``r % MAX_FOLDERS`` of the data set, seed replicate
#: ``r // MAX_FOLDERS`` (the full data set has 8 dynamic runs; absent folders are skipped).
MAX_FOLDERS = 8

#: method key -> (label, causal, uses reference-derived information)
METHODS = {
    "ls": ("data set LS", True, False),
    "eskf": ("data set ESKF", True, False),
    "ekf-track": ("ekf-track (causal)", True, False),
    "ekf-track-rts": ("ekf-track --smooth (RTS, offline)", False, False),
    "pf": ("pf (causal)", True, False),
    "pf-fixed-lag": ("pf --smooth (fixed lag 20 steps, offline)", False, False),
    "pf-backward": ("pf --smooth smoother=backward (offline)", False, False),
    "gn": ("gn per 0.1 s epoch (ambiguous epochs left out)", True, False),
    "ml": ("local ML per 0.1 s epoch", True, False),
    "ransac": ("RANSAC per 0.1 s epoch", True, False),
    "pf-ins": ("pf-ins: INS from the RTK reference (not available to a user; no claim)", True,
               True),
}


@dataclass(frozen=True)
class RealUwbConfig:
    """Settings of ``real-uwb-hanyang``.

    runs: run r is dynamic run folder ``r % 8`` (sorted; absent folders skipped) and seed
        replicate ``r // 8``; replicate 0 runs every method, later replicates only ``pf``
        (the only random one) for its seed spread.
    tag_height_m: the tag height given to the trackers (``-o tag_height_m``); the data
        set's authors compare with the reference z + 1 m.
    particles: particles of ``pf`` (the ``locate`` default is 900).
    max_time_s: use the first max_time_s seconds of each log (0 = all).
    epoch_s: epoch of the snapshot baselines and of ``pf-ins``.
    velocity_std_m: ``pf-ins`` INS reading = reference difference over a step +
        N(0, velocity_std_m^2) per axis, and its s_INS.
    static_samples: static range errors for the EM fit of ``pf-ins``, ``ml`` and ``ransac``
        (0 = all), drawn from the named stream "em-static-subsample".
    ins_particles, init_std_m, reset_*: ``pf-ins`` settings (prior centred on the
        reference start).
    ransac_threshold_m: inlier gate, 3 fitted s_LOS (at least 0.1 m) when None.
    """

    runs: int = 24
    block_size: int = 1
    tag_height_m: float = 1.0
    particles: int = 900
    max_time_s: float = 0.0
    epoch_s: float = 0.1
    velocity_std_m: float = 0.02
    static_samples: int = 4000
    ins_particles: int = 500
    init_std_m: float = 0.5
    reset_fraction: float = 0.05
    reset_std_m: float = 0.3
    ransac_threshold_m: float | None = None


@register
class RealUwbHanyang(Experiment):
    """``real-uwb-hanyang``: the trackers of ``locate`` and paper 001's filter on Hanyang."""

    id = "real-uwb-hanyang"
    paper = "001"
    description = ("ekf-track, pf (LOS/NLOS, EM on the log) and baselines on Hanyang outdoor "
                   "UWB runs vs the data set's LS and ESKF, in the authors' metric")
    data_folder = "hanyang-uwb-outdoor"

    def config(self, full: bool) -> RealUwbConfig:
        """The settings of the quick or the full size.

        Parameters
        ----------
        full : bool
            Every run, three seeds of ``pf``, all static samples, instead of the quick size.

        Returns
        -------
        RealUwbConfig
        """
        if full:
            return RealUwbConfig(static_samples=0)
        return RealUwbConfig(runs=1, particles=200, ins_particles=200, static_samples=1500,
                             max_time_s=70.0)

    def run_block(self, config: RealUwbConfig, runs: np.ndarray, rng: np.random.Generator) -> pd.DataFrame:
        """Load the runs of one block and run every method on them.

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
            One row per method, run, replicate and estimate time: ``x_est, y_est``, the
            reference the authors compare it with (``x_ref, y_ref``), ``in_window``
            (scored by the authors), ``published_rmse_2d`` for LS and ESKF.
        """
        c = config
        root = self.data_path()
        folders = dynamic_runs(root)
        frames = []
        for r in runs:
            folder, rep = int(r) % MAX_FOLDERS, int(r) // MAX_FOLDERS
            if folder >= len(folders):
                continue
            run = load_dynamic(folders[folder])
            stop = c.max_time_s or np.inf
            meas, anchors = measurement_rows(run)
            meas = meas[meas.time <= stop]
            seed = int(rng.integers(2**63 - 1))          # per run: the block's generator
            base = {"tag_height_m": str(c.tag_height_m)}
            pf = pf_tracks(_request(meas, anchors, dict(base, particles=str(c.particles),
                                                        seed=str(seed))),
                           ("filtered", "fixed-lag", "backward"))
            est = {"pf": pf["filtered"], "pf-fixed-lag": pf["fixed-lag"],
                   "pf-backward": pf["backward"]}
            if rep == 0:
                est["ekf-track"] = run_method("ekf-track", _request(meas, anchors, base))
                est["ekf-track-rts"] = run_method("ekf-track", _request(meas, anchors,
                                                                        dict(base, smooth="1")))
                for key, g in run.estimates.items():
                    est[key] = g.rename(columns={"time_s": "time"})
                est.update(self._epoch_methods(c, run, rng))
            for key, g in est.items():
                g = g[g.time <= stop]
                t = g.time.to_numpy(float)
                ref, inside = authors_reference(run.reference, t, run.trajectory)
                frames.append(pd.DataFrame({
                    "run": folder, "replicate": rep, "name": run.name, "method": key,
                    "time_s": t, "x_est": g.x.to_numpy(float), "y_est": g.y.to_numpy(float),
                    "x_ref": ref[:, 0], "y_ref": ref[:, 1], "in_window": inside,
                    "published_rmse_2d": run.published.get(f"{key}_rmse_2d", np.nan),
                    "extra": g["extra"].to_numpy(float) if "extra" in g else np.nan,
                    "extra2": g["extra2"].to_numpy(float) if "extra2" in g else np.nan}))
        return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()

    def _epoch_methods(self, c: RealUwbConfig, run, rng) -> dict[str, pd.DataFrame]:
        """The 0.1 s epoch methods: gn, local ML, RANSAC, and pf-ins (reference odometry)."""
        static = load_static(self.data_path())
        e = static.error_m.to_numpy()
        if c.static_samples and c.static_samples < e.size:
            # a per-experiment draw: every block fits the same subsample
            e = stream(rng, "em-static-subsample").choice(e, c.static_samples, replace=False)
        fit = fit_los_nlos(e)
        model, bias = fit.model, fit.bias_m
        t, theta, truth = resample_epochs(run, c.epoch_s)
        if c.max_time_s:
            keep = t <= c.max_time_s
            t, theta, truth = t[keep], theta[keep], truth[keep]
        anchors = run.anchors[["x", "y", "z"]].to_numpy()
        # the tag height a user knows (not the reference z): same as the trackers'
        horiz = horizontal_ranges(theta, anchors, np.full(t.size, c.tag_height_m - 1.0), bias)
        out = {}
        enough = np.isfinite(horiz).sum(axis=1) >= 3
        gn = Multilateration(on_degenerate="flag").locate(horiz[enough], anchors[:, :2])
        ok = ~np.asarray(gn.diagnostics["degenerate"])
        out["gn"] = pd.DataFrame({"time": t[enough][ok], "x": gn.position[ok, 0],
                                  "y": gn.position[ok, 1],
                                  # fractions of epochs left out: too few ranges, ambiguous
                                  "extra": float(np.mean(~enough)),
                                  "extra2": float(np.mean(gn.diagnostics["ambiguous"]))})
        ml = LocalML(model, 60.0).locate(horiz, anchors[:, :2]).position
        out["ml"] = pd.DataFrame({"time": t, "x": ml[:, 0], "y": ml[:, 1]})
        ransac = Ransac(c.ransac_threshold_m or max(3 * model.los_std_m, 0.1), 60.0)
        rs = ransac.locate(horiz, anchors[:, :2]).position
        out["ransac"] = pd.DataFrame({"time": t, "x": rs[:, 0], "y": rs[:, 1]})
        # pf-ins: paper 001's filter with INS readings taken from the RTK reference
        xy = truth[:, :2]
        ins = np.diff(xy, axis=0, prepend=xy[:1]) + c.velocity_std_m * rng.standard_normal(xy.shape)
        pf = P2PParticleFilter(InputDriven(c.velocity_std_m), model, particles=c.ins_particles,
                               init_std=c.init_std_m, reset_fraction=c.reset_fraction,
                               reset_std_m=c.reset_std_m)
        ranges = np.concatenate([np.full((t.size, 1), np.nan), horiz], axis=1)[None, None]
        res = pf.run(ranges, xy[None, :1], rng, anchors=anchors[:, :2],
                     controls=ins[None, None], time=t)
        p = res.position[0, 0]
        out["pf-ins"] = pd.DataFrame({"time": t, "x": p[:, 0], "y": p[:, 1]})
        return out

    def summarize(self, config: RealUwbConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Metrics, claims, the table and the figure from the results table only.

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
        scored = results[results.in_window].copy()
        scored["e2"] = (scored.x_est - scored.x_ref) ** 2 + (scored.y_est - scored.y_ref) ** 2
        per = scored.groupby(["method", "name", "replicate"]).e2.mean().pow(0.5)  # authors' RMSE
        per = per.rename("rmse").reset_index()
        names = sorted(results.name.unique())
        by_run = per.groupby(["method", "name"]).rmse.mean().unstack("name")
        run_mean = per.groupby(["method", "replicate"]).rmse.mean()              # mean over runs
        complete = per.groupby(["method", "replicate"]).name.nunique() == len(names)
        run_mean = run_mean[complete]
        mean = run_mean.groupby("method").mean()
        spread = run_mean.groupby("method").std(ddof=1)
        reps = run_mean.groupby("method").size()
        metrics = []
        pub = results.groupby(["method", "name"]).published_rmse_2d.first()
        for meth in [m for m in METHODS if m in by_run.index]:
            for n in names:
                v = by_run.loc[meth].get(n, np.nan)
                p = pub.get((meth, n), np.nan)
                metrics.append(Metric(f"{meth}_rmse2d_{n}", float(v),
                                      None if not np.isfinite(p) else float(p), "m",
                                      "authors' metric" + (" (paper column: RMSD_results.txt)"
                                                           if np.isfinite(p) else "")))
            if meth in mean.index:
                metrics.append(Metric(f"{meth}_rmse2d_mean", float(mean[meth]), None, "m",
                                      f"mean over the {len(names)} runs, authors' metric; "
                                      f"{METHODS[meth][0]}"))
                if reps[meth] > 1:
                    metrics.append(Metric(f"{meth}_rmse2d_mean_seed_std", float(spread[meth]),
                                          None, "m", f"std over {int(reps[meth])} seeds"))
        if "gn" in results.method.values:
            g = results[results.method == "gn"].groupby("name")
            metrics.append(Metric("gn_epochs_too_few_ranges", float(g.extra.first().mean()), None,
                                  "", "fraction of epochs with fewer than 3 ranges (left out)"))
            metrics.append(Metric("gn_epochs_ambiguous", float(g.extra2.first().mean()), None, "",
                                  "fraction of the solved epochs whose fix is ambiguous (mirror "
                                  "across the anchors' line fits as well; left out)"))
        claims = []
        repro = [(m, n) for m in ("ls", "eskf") for n in names if np.isfinite(pub.get((m, n), np.nan))]
        if repro and not config.max_time_s:   # a cropped log scores part of the window only
            claims.append(Claim("our implementation of the authors' metric reproduces "
                                "RMSD_results.txt (LS and ESKF 2-D) within 1 % on every run",
                                all(abs(by_run.loc[m, n] / pub[(m, n)] - 1) <= 0.01 for m, n in repro)))
        if "eskf" in mean.index:
            bar = 0.8 * mean["eskf"]
            for meth in ("pf", "ekf-track"):
                if meth in mean.index:
                    claims.append(Claim(f"{meth} (causal, log only): mean 2-D RMSE over the runs "
                                        f"<= 0.8 x the data set's ESKF, authors' metric",
                                        bool(mean[meth] <= bar)))
            for meth in ("pf", "ekf-track"):
                if meth in by_run.index:
                    claims.append(Claim(f"{meth} (causal, log only) is below the data set's ESKF "
                                        "on every run, authors' metric",
                                        bool(all(by_run.loc[meth, n] < by_run.loc["eskf", n]
                                                 for n in names))))
        if {"pf", "ekf-track"} <= set(mean.index):
            claims.append(Claim.lower("paper 001: the LOS/NLOS particle filter is more accurate "
                                      "than the EKF (causal, log only, paired over the runs)",
                                      by_run.loc["pf"], by_run.loc["ekf-track"], unit="m"))
        table = self._table(by_run, mean, spread, reps, pub, names)
        (out_dir / "table.md").write_text(table + "\n")
        self._figure(results, names, out_dir)
        return Summary(metrics, claims, ["Authors' metric (2-D RMSE, m); rows marked offline "
                                         "use later ranges; pf-ins uses the RTK reference.",
                                         table])

    @staticmethod
    def _table(by_run, mean, spread, reps, pub, names) -> str:
        head = "| method | " + " | ".join(names) + " | mean |"
        lines = [head, "|---" * (len(names) + 2) + "|"]
        for meth, (label, _, _) in METHODS.items():
            if meth not in by_run.index:
                continue
            cells = [f"{by_run.loc[meth, n]:.2f}" if np.isfinite(by_run.loc[meth, n]) else "-"
                     for n in names]
            m = f"{mean[meth]:.2f}" if meth in mean.index else "-"
            if meth in reps.index and reps[meth] > 1:
                m += f" ± {spread[meth]:.2f} ({int(reps[meth])} seeds)"
            lines.append(f"| {label} | " + " | ".join(cells) + f" | {m} |")
        for meth in ("ls", "eskf"):
            vals = [pub.get((meth, n), np.nan) for n in names]
            if np.all(np.isfinite(vals)):
                lines.append(f"| data set {meth.upper()}, RMSD_results.txt | "
                             + " | ".join(f"{v:.2f}" for v in vals) + f" | {np.mean(vals):.2f} |")
        return "\n".join(lines)

    @staticmethod
    def _figure(results, names, out_dir) -> None:
        fig, axes = figure(len(names), 1, width=8.0, height=2.4 * len(names) + 0.5,
                           squeeze=False, layout="constrained")
        for ax, n in zip(axes[:, 0], names):
            g = results[(results.name == n) & (results.replicate == 0)]
            ref = g[g.method == "ekf-track"] if "ekf-track" in g.method.values else g[g.method == "pf"]
            ax.plot(ref.x_ref, ref.y_ref, "-", color=COLORS["truth"], lw=2, label="RTK reference")
            win = ref[ref.in_window]
            ax.plot(win.x_ref, win.y_ref, ".", color=COLORS["truth"], ms=1,
                    label="scored by the authors")
            for meth, col, lab in (("pf", COLORS["ours"], "pf"), ("ekf-track", COLORS["alt"],
                                                                  "ekf-track"),
                                   ("eskf", COLORS["baseline"], "data set ESKF")):
                gm = g[g.method == meth]
                ax.plot(gm.x_est, gm.y_est, "-", color=col, lw=0.8, label=lab)
            ax.set_ylim(-8, 8)
            ax.set_title(n)
            ax.set_ylabel("y [m]")
        axes[-1, 0].set_xlabel("x [m]")
        fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="outside lower center", ncol=5,
                   fontsize=8, markerscale=4)
        save(fig, out_dir / "trajectories.png", caption=(
            "Hanyang outdoor UWB runs, one per row: the RTK reference (the part the authors "
            "score dotted) and the tracks of pf, ekf-track and the data set's ESKF."))


def _request(meas: pd.DataFrame, anchors: pd.DataFrame, options: dict) -> LocateRequest:
    """A ``locate --method pf`` request on a converted log, options checked as the command
    line checks them (``run_method`` does the same for the other methods)."""
    req = LocateRequest(meas, anchors, options=dict(options))
    check_request(methods()["pf"], req)
    return req
