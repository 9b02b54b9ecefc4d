"""Paper 004, Sects. 3.1.1 and 5: mixture signal-strength models in a corridor with a door.

Each Monte Carlo run draws its own calibration set (positions uniform along the corridor,
door open or closed with probability 1/2 per sample), builds the two per-station models by
progressive calibration, then (i) a static user at 45 m takes 8 measurements (the door in
one state for the whole run) and is localized by successive measurement updates (Fig. 10),
(ii) a user walks the corridor and is tracked with the uniform-disk motion model.
Both noise levels of the paper (2 dB, 10 dB) are run.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.estimators.mixture_localization import localize, track
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, register
from radioloc.models.mixture import DiagMixture, product
from radioloc.models.mixture_calibration import progressive_calibration
from radioloc.report.style import COLORS, figure, save
from radioloc.sim.corridor import Corridor


@dataclass(frozen=True)
class CorridorConfig:
    """Settings of ``p004-corridor`` (choices the paper leaves open are ours).

    noise_db: measurement (and calibration) noise levels, the paper's 2 and 10 dB.
    calib_samples: calibration samples per run, x uniform on the corridor, door closed
        with probability 1/2 per sample (the paper: "calibration in both door states").
    bandwidth: kernel standard deviations (x in m, m in dB) of progressive calibration.
    model_components: bound on the components of each station's model.
    position_components: bound on the components of every position density.
    user_m / updates: the static user of Fig. 10 and the number of measurement updates.
    walk_*: tracking run, constant speed walk from walk_start_m to walk_end_m, one
        measurement per dt_s; the door state is drawn once per run.
    v_max: maximum speed of the motion model (paper: 1.5 m/s).
    converged_tolerance_m: "concentrates at 45 m" means |mean estimate - 45| <= this.
    """

    runs: int = 20
    block_size: int = 10
    noise_db: tuple[float, ...] = (2.0, 10.0)
    calib_samples: int = 400
    bandwidth: tuple[float, float] = (1.0, 1.5)
    model_components: int = 20
    position_components: int = 8
    user_m: float = 45.0
    updates: int = 8
    walk_start_m: float = 5.0
    walk_end_m: float = 55.0
    walk_speed: float = 1.2
    dt_s: float = 1.0
    v_max: float = 1.5
    converged_tolerance_m: float = 1.0
    figure_seed: int = 4


def _calibrate(config: CorridorConfig, corridor: Corridor, noise: float, n_runs: int,
               rng: np.random.Generator) -> DiagMixture:
    x = rng.uniform(0.0, corridor.length_m, (n_runs, config.calib_samples))
    door = rng.random(x.shape) < 0.5
    rss = corridor.sample_rss(x, door, noise, rng)
    return progressive_calibration(x[..., None], rss, config.bandwidth, config.model_components)


def _walk(config: CorridorConfig) -> np.ndarray:
    steps = int(np.floor((config.walk_end_m - config.walk_start_m) / (config.walk_speed * config.dt_s)))
    return config.walk_start_m + config.walk_speed * config.dt_s * np.arange(steps + 1)


@register
class CorridorExperiment(Experiment):
    id = "p004-corridor"
    paper = "004"
    description = ("Gaussian-mixture RSS models in a 60 m corridor with a door: static "
                   "localization updates (Fig. 10) and tracking")

    def config(self, full: bool) -> CorridorConfig:
        return CorridorConfig(runs=200 if full else 20)

    def run_block(self, config: CorridorConfig, runs: np.ndarray,
                  rng: np.random.Generator) -> pd.DataFrame:
        corridor = Corridor()
        n = runs.size
        walk = _walk(config)
        frames = []
        for noise in config.noise_db:
            models = _calibrate(config, corridor, noise, n, rng)              # batch (R, 2)
            door = rng.random(n) < 0.5
            # static user: the models broadcast over the update axis
            rss = corridor.sample_rss(np.full((config.updates, n), config.user_m),
                                      door, noise, rng)
            res = track(models, rss, config.dt_s, v_max=0.0,
                        max_components=config.position_components)
            for t in range(config.updates):
                frames.append(pd.DataFrame({
                    "run": runs, "noise_db": noise, "scenario": "static", "step": t + 1,
                    "x_true": config.user_m, "x_est": res.mean[t, :, 0],
                    "std_m": np.sqrt(res.covariance[t, :, 0, 0])}))
            rss = corridor.sample_rss(np.broadcast_to(walk[:, None], (walk.size, n)),
                                      door, noise, rng)
            res = track(models, rss, config.dt_s, v_max=config.v_max,
                        max_components=config.position_components)
            one, one_cov = localize(models, rss, config.position_components).moments()
            for t in range(walk.size):
                frames.append(pd.DataFrame({
                    "run": runs, "noise_db": noise, "scenario": "tracking", "step": t + 1,
                    "x_true": walk[t], "x_est": res.mean[t, :, 0],
                    "std_m": np.sqrt(res.covariance[t, :, 0, 0])}))
                frames.append(pd.DataFrame({
                    "run": runs, "noise_db": noise, "scenario": "walk_oneshot", "step": t + 1,
                    "x_true": walk[t], "x_est": one[t, :, 0],
                    "std_m": np.sqrt(one_cov[t, :, 0, 0])}))
        return pd.concat(frames, ignore_index=True)

    def summarize(self, config: CorridorConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        metrics, claims, notes = [], [], []
        static = results[results["scenario"] == "static"]
        trk = results[results["scenario"] == "tracking"]
        for noise in config.noise_db:
            tag = "" if noise == config.noise_db[0] else f"_noise{noise:g}db"
            s = static[static["noise_db"] == noise].groupby("step")
            est, std = s["x_est"].mean(), s["std_m"].mean()
            for k in (1, 2, config.updates):
                paper = config.user_m if k == config.updates else None
                metrics.append(Metric(f"estimate_m_after_{k}{tag}", est[k], paper, "m",
                                      f"mean over runs of the posterior mean, {noise:g} dB noise"
                                      + ("; paper: Fig. 10 concentrates at 45 m" if paper else "")))
            metrics.append(Metric(f"std_m_after_1{tag}", std[1], None, "m",
                                  "mean posterior standard deviation after 1 update"))
            metrics.append(Metric(f"std_m_after_{config.updates}{tag}", std[config.updates], None,
                                  "m", "mean posterior standard deviation"))
            t = trk[trk["noise_db"] == noise]
            rmse = float(np.sqrt(np.mean((t["x_est"] - t["x_true"]) ** 2)))
            metrics.append(Metric(f"tracking_rmse_m{tag}", rmse, None, "m",
                                  f"walk at {config.walk_speed} m/s, v_max {config.v_max} m/s"))
            metrics.append(Metric(f"tracking_mean_lag_m{tag}", float(np.mean(t["x_true"] - t["x_est"])),
                                  None, "m", "mean of true - estimated position on the walk"))
            w1 = results[(results["scenario"] == "walk_oneshot") & (results["noise_db"] == noise)]
            rmse_w1 = float(np.sqrt(np.mean((w1["x_est"] - w1["x_true"]) ** 2)))
            metrics.append(Metric(f"walk_oneshot_rmse_m{tag}", rmse_w1, None, "m",
                                  "same walk, each step localized alone (eq. 2, no motion model)"))
            claims.append(Claim(f"Tracking with the motion model is more accurate than one-shot "
                                f"positioning of a walking user (Sect. 2; {noise:g} dB)",
                                bool(rmse < rmse_w1)))
            one = static[(static["noise_db"] == noise) & (static["step"] == 1)]
            rmse1 = float(np.sqrt(np.mean((one["x_est"] - one["x_true"]) ** 2)))
            metrics.append(Metric(f"oneshot_rmse_m{tag}", rmse1, None, "m",
                                  "static user, one update (no tracking)"))
            if noise == config.noise_db[0]:
                claims.append(Claim(
                    f"After {config.updates} updates the estimate concentrates at "
                    f"{config.user_m:g} m ({noise:g} dB)",
                    bool(abs(est[config.updates] - config.user_m) <= config.converged_tolerance_m
                         and std[config.updates] < std[1])))
        notes.append("metric names without suffix are at 2 dB noise; '_noise10db' at 10 dB")
        notes.append("the disk motion model has zero mean: a user walking at a constant speed "
                     "close to v_max is followed with a lag (tracking_mean_lag_m)")
        claims += self._figures(config, trk, out_dir, notes)
        return Summary(metrics, claims, notes)

    # ---- figures -------------------------------------------------------------------
    def _figures(self, config: CorridorConfig, trk: pd.DataFrame, out_dir: Path,
                 notes: list[str]) -> list[Claim]:
        corridor = Corridor()
        rng = np.random.default_rng(config.figure_seed)
        noise = config.noise_db[0]
        models = _calibrate(config, corridor, noise, 1, rng)[0]    # batch (2,)
        xs = np.linspace(0, corridor.length_m, 301)

        fig, ax = figure()
        for closed, ls in ((True, "-"), (False, ":")):
            mean = corridor.mean_rss(xs, closed)
            for k, c in enumerate((COLORS["ours"], COLORS["baseline"])):
                ax.plot(xs, mean[:, k], ls, color=c,
                        label=f"station {k + 1} (x={corridor.stations[k]:g} m), door "
                              f"{'closed' if closed else 'open'}")
        ax.axvline(corridor.door_m, color="grey", lw=0.8)
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("signal strength m [dBm]")
        ax.set_title("Fig. 4: corridor with a metallic door at 30 m (noise-free)")
        ax.legend(fontsize=8, loc="upper center")
        save(fig, out_dir / "fig4_corridor_rss.png")

        ms = np.linspace(-90, -20, 141)
        gx, gm = np.meshgrid(xs, ms)
        dens = models[0].pdf(np.c_[gx.ravel(), gm.ravel()]).reshape(gx.shape)
        fig, ax = figure()
        pc = ax.pcolormesh(gx, gm, dens, shading="auto", cmap="viridis")
        fig.colorbar(pc, ax=ax, label="density D(x, m)")
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("signal strength m of station 1 [dBm]")
        ax.set_title(f"Fig. 5: calibrated model of station 1 ({noise:g} dB, "
                     f"{models.n_components} components)")
        save(fig, out_dir / "fig5_model_station1.png")

        xq = 50.0
        pm = models[0].condition(0, xq)
        dm = pm.pdf(ms[:, None])
        fig, ax = figure()
        ax.plot(ms, dm, color=COLORS["ours"], label="model D(m | x = 50 m)")
        for closed in (False, True):
            ax.axvline(corridor.mean_rss(xq, closed)[0], ls="--", color="grey")
        ax.set_xlabel("signal strength m of station 1 [dBm]")
        ax.set_ylabel("density [1/dB]")
        ax.set_title("Fig. 6: expected signal strength at x = 50 m (dashed: open / closed)")
        ax.legend()
        save(fig, out_dir / "fig6_rss_at_50m.png")
        peaks = np.flatnonzero((dm[1:-1] > dm[:-2]) & (dm[1:-1] > dm[2:]) & (dm[1:-1] > 0.1 * dm.max()))
        bimodal = peaks.size >= 2

        door = False
        rss = corridor.sample_rss(np.full((config.updates, 1), config.user_m), door, noise, rng)
        cond = models.condition(1, rss[0, 0], valid=np.ones(2, bool))
        prod = product(cond[0], cond[1])
        fig, ax = figure()
        stds = []
        for mix, lab, c, ls in ((cond[0], "station 1 (x = 0 m)", COLORS["baseline"], "--"),
                                (cond[1], "station 2 (x = 60 m)", COLORS["alt"], ":"),
                                (prod, "product, eq. (2)", COLORS["ours"], "-")):
            ax.plot(xs, mix.pdf(xs[:, None]), ls, color=c, label=lab)
            stds.append(np.sqrt(mix.moments()[1][0, 0]))
        ax.axvline(config.user_m, color="grey", lw=0.8)
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("density [1/m]")
        ax.set_title(f"Fig. 9: per-station position densities and their product (user at "
                     f"{config.user_m:g} m)")
        ax.legend()
        save(fig, out_dir / "fig9_product.png")

        fig, ax = figure()
        steps = (1, 2, config.updates)
        for k, ls in zip(steps, ("--", ":", "-")):
            res = track(models, rss[:k, 0, :], config.dt_s, v_max=0.0,
                        max_components=config.position_components)
            dens_k = res.posterior.pdf(xs[:, None])
            ax.plot(xs, dens_k, ls, label=f"after {k} update{'s' if k > 1 else ''}")
        ax.axvline(config.user_m, color="grey", lw=0.8)
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("density [1/m]")
        ax.set_title(f"Fig. 10: static user at {config.user_m:g} m, {noise:g} dB")
        ax.legend()
        save(fig, out_dir / "fig10_updates.png")

        t = trk[(trk["noise_db"] == noise) & (trk["run"] == trk["run"].min())]
        fig, ax = figure()
        ax.plot(t["step"] * config.dt_s, t["x_true"], color="k", label="true position")
        ax.plot(t["step"] * config.dt_s, t["x_est"], color=COLORS["ours"], label="mixture filter mean")
        ax.fill_between(t["step"] * config.dt_s, t["x_est"] - 2 * t["std_m"],
                        t["x_est"] + 2 * t["std_m"], color=COLORS["ours"], alpha=0.2,
                        label="+/- 2 std")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("position x [m]")
        ax.set_title(f"Tracking a walking user ({noise:g} dB, run {int(t['run'].iloc[0])})")
        ax.legend()
        save(fig, out_dir / "tracking.png")
        notes.append(f"Fig. 9 example: std station 1 {stds[0]:.2f} m, station 2 {stds[1]:.2f} m, "
                     f"product {stds[2]:.2f} m")
        return [Claim("Calibration in both door states gives a bimodal D(m | x) past the door "
                      "(Fig. 6)", bool(bimodal)),
                Claim("The product of the per-station densities is more concentrated than "
                      "either (Fig. 9)", bool(stds[2] < min(stds[:2])))]

