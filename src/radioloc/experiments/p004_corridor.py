"""Paper 004, Sects. 3.1.1 and 5: mixture signal-strength models in a corridor with a door.

Each Monte Carlo run draws its own calibration set (positions uniform along the corridor,
door open or closed with probability 1/2 per sample), builds the two per-station models by
progressive calibration, then (i) a static user at 45 m takes 8 measurements (the door in
one state for the whole run) and is localized by successive measurement updates (Fig. 10),
(ii) a user walks the corridor and is tracked with the uniform-disk motion model, (iii) a
user walks, pauses and walks on (tracked and located one shot at a time). Both noise
levels of the paper (2 dB, 10 dB) are run. Per run the block also records how many modes
station 1's D(m | x) has past the door (Fig. 6, judged over runs).

Accuracy claims are judged per run: RMSE over runs of the posterior mean, and whether the
posterior's uncertainty is calibrated (NEES = mean of (error / std)^2, 1 if calibrated;
2-sigma coverage, 0.95 if Gaussian and calibrated).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.rng import stream
from radioloc.estimators.mixture_localization import (MixtureLocalizer, MixtureTracker,
                                                      posterior_mixture)
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, per_run, register
from radioloc.models.mixture import DiagMixture, product, reduce
from radioloc.models.mixture_calibration import progressive_calibration
from radioloc.models.motion import BoundedSpeedCV, UniformDisk
from radioloc.models.progressive_bayes import inner, isd
from radioloc.report.style import COLORS, figure, save
from radioloc.sim.corridor import Corridor, walk_positions


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
    converged_tolerance_m: "concentrates at 45 m" means the per-run RMSE of the posterior
        mean after the last update is <= this.
    coverage_min, nees_max: "calibrated" means the 2-sigma interval holds the truth in at
        least ``coverage_min`` of the runs and the NEES is at most ``nees_max`` (1 expected).
    pause_at_m, pause_s: the pausing walker walks to pause_at_m, stands pause_s seconds,
        then walks on to walk_end_m (same speed).
    figure_x_m: position of the expected-signal-strength section of Fig. 6.
    reduction: every re-approximation of the paper's pipeline (product of eq. (2), filter
        step, prediction): "progressive" = Progressive Bayes ISD homotopy (the paper's
        reference [3]); alt_reduction ("runnalls", West/Runnalls merging) is run beside it
        on the static user and the walk.
    cv_q, cv_components: the constant-velocity variant of the tracker (ours): white
        acceleration spectral density (m^2/s^3) and components of the (position, velocity)
        mixture; it uses alt_reduction (the progressive homotopy on 16 two-dimensional
        components is too slow for the Monte Carlo runs).

    The figures' example (one calibration at the first noise level, one static user with
    the door open) is drawn from the named stream ``"figure-example"`` of the experiment
    seed, by the block that holds run 0, as ``table == "figure"`` rows.
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
    coverage_min: float = 0.9
    nees_max: float = 1.5
    pause_at_m: float = 30.0
    pause_s: float = 15.0
    figure_x_m: float = 50.0
    reduction: str = "progressive"
    alt_reduction: str = "runnalls"
    cv_q: float = 0.1
    cv_components: int = 16


#: grids of the figure rows
_X_GRID = np.linspace(0.0, 60.0, 301)
_M_GRID = np.linspace(-90.0, -20.0, 141)
_X_COARSE = np.linspace(0.0, 60.0, 121)
_M_COARSE = np.linspace(-90.0, -20.0, 71)


def _calibrate(config: CorridorConfig, corridor: Corridor, noise: float, n_runs: int,
               rng: np.random.Generator) -> DiagMixture:
    x, rss = corridor.calibration_set(n_runs, config.calib_samples, noise, rng)
    return progressive_calibration(x, rss, config.bandwidth, config.model_components)


def _walk(config: CorridorConfig) -> np.ndarray:
    return walk_positions(config.walk_start_m, config.walk_end_m, config.walk_speed, config.dt_s)


def pause_walk(config: CorridorConfig) -> np.ndarray:
    """Walk to ``pause_at_m``, stand ``pause_s`` seconds, walk on to ``walk_end_m``."""
    first = walk_positions(config.walk_start_m, config.pause_at_m, config.walk_speed,
                           config.dt_s)
    stand = np.full(int(round(config.pause_s / config.dt_s)), first[-1])
    second = walk_positions(first[-1], config.walk_end_m, config.walk_speed, config.dt_s)[1:]
    return np.concatenate([first, stand, second])


def _modes(density: np.ndarray) -> np.ndarray:
    """Local maxima above 10 % of the maximum along the last axis, counted."""
    d = density
    peak = (d[..., 1:-1] > d[..., :-2]) & (d[..., 1:-1] > d[..., 2:]) & (
        d[..., 1:-1] > 0.1 * d.max(axis=-1, keepdims=True))
    return peak.sum(axis=-1)


def error_calibration(err: np.ndarray, std: np.ndarray) -> tuple[float, float, float]:
    """RMSE, NEES and 2-sigma coverage of errors ``err`` with posterior stds ``std``."""
    err, std = np.asarray(err, float), np.asarray(std, float)
    return (float(np.sqrt(np.mean(err**2))), float(np.mean((err / std) ** 2)),
            float(np.mean(np.abs(err) <= 2.0 * std)))


def _rows(run: int, fig: str, series: str, x, value, m=np.nan) -> pd.DataFrame:
    x, value, m = np.broadcast_arrays(np.atleast_1d(x), np.atleast_1d(value), np.atleast_1d(m))
    return pd.DataFrame({"run": run, "table": "figure", "figure": fig, "series": series,
                         "x": x, "m": m, "value": value})


def _run_mse(rows: pd.DataFrame) -> pd.Series:
    """Per run: the mean squared error of ``x_est`` over the run's rows (steps)."""
    return per_run(rows.assign(sq=(rows["x_est"] - rows["x_true"]) ** 2), "sq")


@register
class CorridorExperiment(Experiment):
    id = "p004-corridor"
    paper = "004"
    timing_columns = ("cpu_s_static_progressive", "cpu_s_static_runnalls")
    description = ("Gaussian-mixture RSS models in a 60 m corridor with a door: static "
                   "localization updates (Fig. 10) and tracking")

    def config(self, full: bool) -> CorridorConfig:
        """The configuration at the quick or the full size.

        Parameters
        ----------
        full : bool
            The paper's size instead of the quick one.

        Returns
        -------
        CorridorConfig
            The settings.
        """
        return CorridorConfig(runs=200 if full else 20)

    def run_block(self, config: CorridorConfig, runs: np.ndarray,
                  rng: np.random.Generator) -> pd.DataFrame:
        """Run one block of runs.

        Parameters
        ----------
        config : CorridorConfig
            The settings.
        runs : ndarray of int
            The block's run indices.
        rng : numpy.random.Generator
            The block's generator (named streams of the experiment seed derive from it).

        Returns
        -------
        pandas.DataFrame
            The tidy rows of the block (``table`` "runs", and "figure" rows from the
            block of run 0).
        """
        corridor = Corridor()
        n = runs.size
        walks = {"tracking": _walk(config), "pause": pause_walk(config)}
        frames, later = [], []
        red, alt = config.reduction, config.alt_reduction
        k = config.position_components

        def rows(label, noise, x_true, res, steps=None):
            pos, var = res.position[..., 0], res.covariance[..., 0, 0]
            if pos.ndim == 1:
                pos, var = pos[:, None], var[:, None]
            steps = range(pos.shape[1]) if steps is None else steps
            xt = np.broadcast_to(np.asarray(x_true, float), (pos.shape[1],))
            for t in steps:
                frames.append(pd.DataFrame({
                    "run": runs, "table": "runs", "noise_db": noise, "scenario": label,
                    "step": t + 1, "x_true": xt[t], "x_est": pos[:, t],
                    "std_m": np.sqrt(var[:, t])}))

        for noise in config.noise_db:
            models = _calibrate(config, corridor, noise, n, rng)              # batch (R, 2)
            door = rng.random(n) < 0.5
            static = MixtureTracker(models, UniformDisk(0.0, dim=1), k, red)
            moving = MixtureTracker(models, UniformDisk(config.v_max, dim=1), k, red)
            # static user: (R, updates, 2) measurements, the door fixed per run
            rss = corridor.sample_rss(np.full((config.updates, n), config.user_m),
                                      door, noise, rng).transpose(1, 0, 2)
            times = config.dt_s * np.arange(config.updates)
            t0 = time.process_time()
            res = static.run(rss, times)
            cpu_red = time.process_time() - t0
            rows("static", noise, config.user_m, res)
            t0 = time.process_time()
            res_alt = MixtureTracker(models, UniformDisk(0.0, dim=1), k, alt).run(rss, times)
            cpu_alt = time.process_time() - t0
            rows(f"static_{alt}", noise, config.user_m, res_alt)
            # Fig. 9 over the runs: each station alone at the first update
            for s in range(2):
                alone = rss[:, 0, :].copy()
                alone[:, 1 - s] = np.nan
                est = MixtureLocalizer(models, k, red).locate(alone)
                rows(f"static_station{s + 1}", noise, config.user_m, est, [0])
            # distance to the exact product of eq. (2) at the first update, both reductions
            cond = models.condition(1, rss[:, 0, :], valid=np.ones((n, 2), bool))
            exact = product(cond[:, 0], cond[:, 1])
            approx = {m: reduce(exact, k, m) for m in (red, alt)}
            ref = inner(exact.weights, exact.means, exact.variances, exact.weights, exact.means,
                        exact.variances)                                # int exact^2 dx
            frames.append(pd.DataFrame({
                "run": runs, "table": "isd", "noise_db": noise,
                "components_exact": exact.n_components, "components": k,
                **{f"isd_{m}": isd(approx[m], exact) / ref for m in (red, alt)},
                **{f"mean_{m}": approx[m].moments()[0][:, 0] for m in (red, alt)},
                "mean_exact": exact.moments()[0][:, 0],
                f"cpu_s_static_{red}": cpu_red / n, f"cpu_s_static_{alt}": cpu_alt / n}))
            later.append((noise, models, door, moving))
            walk = walks["tracking"]
            rss = corridor.sample_rss(np.broadcast_to(walk[:, None], (walk.size, n)),
                                      door, noise, rng).transpose(1, 0, 2)
            self._walk_rows(config, models, rss, walk, noise, "", rows)
            # Fig. 6 over the runs: modes of station 1's D(m | x) past the door
            dens = models[:, 0].condition(0, config.figure_x_m).pdf(_M_GRID[:, None])
            frames.append(pd.DataFrame({"run": runs, "table": "fig6_runs", "noise_db": noise,
                                        "modes": _modes(dens)}))
        # the pausing walker, drawn after every other scenario (their draws stay as they were)
        walk = walks["pause"]
        for noise, models, door, moving in later:
            rss = corridor.sample_rss(np.broadcast_to(walk[:, None], (walk.size, n)),
                                      door, noise, rng).transpose(1, 0, 2)
            self._walk_rows(config, models, rss, walk, noise, "pause_", rows)
        if runs[0] == 0:
            frames.append(self._figure_rows(config, corridor, rng, int(runs[0])))
        return pd.concat(frames, ignore_index=True)

    @staticmethod
    def _walk_rows(config: CorridorConfig, models: DiagMixture, rss: np.ndarray,
                   walk: np.ndarray, noise: float, prefix: str, rows) -> None:
        """The walking user: disk tracker (both reductions), constant-velocity tracker and
        one-shot localization of every step."""
        red, alt, k = config.reduction, config.alt_reduction, config.position_components
        times = config.dt_s * np.arange(walk.size)
        disk = UniformDisk(config.v_max, dim=1)
        tracking = "tracking" if not prefix else f"{prefix}tracking"
        rows(tracking, noise, walk, MixtureTracker(models, disk, k, red).run(rss, times))
        rows(f"{tracking}_{alt}", noise, walk, MixtureTracker(models, disk, k, alt).run(rss, times))
        cv = BoundedSpeedCV(config.cv_q, config.v_max, dim=1)
        rows(f"{tracking}_cv", noise, walk,
             MixtureTracker(models, cv, config.cv_components, alt).run(rss, times))
        one = MixtureLocalizer(models[:, None], k, red).locate(rss)
        rows("walk_oneshot" if not prefix else f"{prefix}oneshot", noise, walk, one)

    @staticmethod
    def _figure_rows(config: CorridorConfig, corridor: Corridor, rng: np.random.Generator,
                     run: int) -> pd.DataFrame:
        """The example the figures show: one calibration and one static user (door open)
        at the first noise level, from the named stream ``"figure-example"``."""
        ex = stream(rng, "figure-example")
        noise = config.noise_db[0]
        models = _calibrate(config, corridor, noise, 1, ex)[0]                # batch (2,)
        rows = []
        for closed in (True, False):                                          # Fig. 4
            mean = corridor.mean_rss(_X_GRID, closed)
            for k in range(2):
                rows.append(_rows(run, "fig4", f"station{k + 1}_{'closed' if closed else 'open'}",
                                  _X_GRID, mean[:, k]))
        gx, gm = np.meshgrid(_X_COARSE, _M_COARSE)                            # Fig. 5
        dens = models[0].pdf(np.c_[gx.ravel(), gm.ravel()])
        rows.append(_rows(run, "fig5", f"station1_{models.n_components}_components",
                          gx.ravel(), dens, gm.ravel()))
        cond_x = models[0].condition(0, config.figure_x_m)                    # Fig. 6
        rows.append(_rows(run, "fig6", "model", np.nan, cond_x.pdf(_M_GRID[:, None]), _M_GRID))
        for closed in (False, True):
            rows.append(_rows(run, "fig6", f"door_{'closed' if closed else 'open'}", np.nan,
                              np.nan, corridor.mean_rss(config.figure_x_m, closed)[0]))
        rss = corridor.sample_rss(np.full(config.updates, config.user_m), False, noise, ex)
        cond = models.condition(1, rss[0], valid=np.ones(2, bool))            # Fig. 9
        prod = product(cond[0], cond[1])
        for mix, series in ((cond[0], "station1"), (cond[1], "station2"), (prod, "product")):
            rows.append(_rows(run, "fig9", series, _X_GRID, mix.pdf(_X_GRID[:, None])))
            rows.append(_rows(run, "fig9_std", series, np.nan,
                              np.sqrt(mix.moments()[1][0, 0])))
        static = MixtureTracker(models, UniformDisk(0.0, dim=1), config.position_components,
                                config.reduction)
        trk = static.run(rss, config.dt_s * np.arange(config.updates))        # Fig. 10
        for k in (1, 2, config.updates):
            post = posterior_mixture(trk.at(k - 1))
            rows.append(_rows(run, "fig10", f"after_{k}", _X_GRID, post.pdf(_X_GRID[:, None])))
        return pd.concat(rows, ignore_index=True)

    def summarize(self, config: CorridorConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Metrics, claims and figures from the rows the blocks returned.

        Parameters
        ----------
        config : CorridorConfig
            The settings.
        results : pandas.DataFrame
            Every block's rows, concatenated.
        out_dir : Path
            Where the figures go.

        Returns
        -------
        Summary
            Metrics, claims and notes.
        """
        metrics, claims, notes = [], [], []
        runs = results[results["table"] == "runs"]
        static = runs[runs["scenario"] == "static"]
        trk = runs[runs["scenario"] == "tracking"]
        fig6_runs = results[results["table"] == "fig6_runs"]
        for noise in config.noise_db:
            tag = "" if noise == config.noise_db[0] else f"_noise{noise:g}db"
            s = static[static["noise_db"] == noise].groupby("step")
            std = s["std_m"].mean()
            per_run = {}
            for k in (1, config.updates):
                last = static[(static["noise_db"] == noise) & (static["step"] == k)]
                per_run[k] = error_calibration(last["x_est"] - last["x_true"], last["std_m"])
                rm, nees, cov2 = per_run[k]
                e, sd = last["x_est"] - last["x_true"], last["std_m"]
                metrics += [
                    Metric(f"rmse_m_after_{k}{tag}", rm, None, "m",
                           f"per-run RMSE of the posterior mean, static user, {noise:g} dB"),
                    Metric.over_runs(f"nees_after_{k}{tag}", (e / sd) ** 2, 1.0, "",
                                     "mean over runs of (error / posterior std)^2 (1: calibrated)"),
                    Metric.over_runs(f"coverage_2sigma_after_{k}{tag}",
                                     (e.abs() <= 2.0 * sd).astype(float), 0.95, "",
                                     "fraction of runs with |error| <= 2 posterior std")]
            for k in (1, 2, config.updates):
                paper = config.user_m if k == config.updates else None
                at_k = static[(static["noise_db"] == noise) & (static["step"] == k)]["x_est"]
                metrics.append(Metric.over_runs(f"estimate_m_after_{k}{tag}", at_k, paper, "m",
                                      f"mean over runs of the posterior mean, {noise:g} dB noise"
                                      + ("; paper: Fig. 10 concentrates at 45 m" if paper else "")))
            metrics.append(Metric(f"std_m_after_1{tag}", std[1], None, "m",
                                  "mean posterior standard deviation after 1 update"))
            metrics.append(Metric(f"std_m_after_{config.updates}{tag}", std[config.updates], None,
                                  "m", "mean posterior standard deviation"))
            t = trk[trk["noise_db"] == noise]
            rmse = float(np.sqrt(np.mean((t["x_est"] - t["x_true"]) ** 2)))
            e_t = t["x_est"] - t["x_true"]
            by_run = t.assign(nees=(e_t / t["std_m"]) ** 2,
                              cover=(e_t.abs() <= 2.0 * t["std_m"]).astype(float)).groupby("run")
            metrics += [Metric.over_runs(f"tracking_nees{tag}", by_run["nees"].mean(), 1.0, "",
                                         "walk: mean over runs and steps of (error / std)^2 "
                                         "(interval over runs)"),
                        Metric.over_runs(f"tracking_coverage_2sigma{tag}", by_run["cover"].mean(),
                                         0.95, "", "walk: fraction of steps with |error| <= 2 std "
                                         "(interval over runs)")]
            pz = {k: runs[(runs["scenario"] == k) & (runs["noise_db"] == noise)]
                  for k in ("pause_tracking", "pause_oneshot")}
            rm_pt = float(np.sqrt(np.mean((pz["pause_tracking"]["x_est"]
                                           - pz["pause_tracking"]["x_true"]) ** 2)))
            rm_po = float(np.sqrt(np.mean((pz["pause_oneshot"]["x_est"]
                                           - pz["pause_oneshot"]["x_true"]) ** 2)))
            metrics += [Metric(f"pause_tracking_rmse_m{tag}", rm_pt, None, "m",
                               f"walker who pauses {config.pause_s:g} s at "
                               f"{config.pause_at_m:g} m, tracked (disk motion model)"),
                        Metric(f"pause_oneshot_rmse_m{tag}", rm_po, None, "m",
                               "the same pausing walker located one shot at a time")]
            f6 = fig6_runs[fig6_runs["noise_db"] == noise]
            bimodal_frac = float(np.mean(f6["modes"] >= 2)) if len(f6) else np.nan
            metrics.append(Metric(f"fig6_bimodal_fraction{tag}", bimodal_frac, None, "",
                                  f"runs whose station-1 D(m | x = {config.figure_x_m:g} m) "
                                  "has two or more modes"))
            metrics.append(Metric(f"tracking_rmse_m{tag}", rmse, None, "m",
                                  f"walk at {config.walk_speed} m/s, v_max {config.v_max} m/s"))
            metrics.append(Metric(f"tracking_mean_lag_m{tag}", float(np.mean(t["x_true"] - t["x_est"])),
                                  None, "m", "mean of true - estimated position on the walk"))
            w1 = runs[(runs["scenario"] == "walk_oneshot") & (runs["noise_db"] == noise)]
            rmse_w1 = float(np.sqrt(np.mean((w1["x_est"] - w1["x_true"]) ** 2)))
            metrics.append(Metric(f"walk_oneshot_rmse_m{tag}", rmse_w1, None, "m",
                                  "same walk, each step localized alone (eq. (2), no motion model)"))
            claims.append(Claim.lower(f"Tracking with the motion model is more accurate than "
                                      f"one-shot positioning of a walking user (Sect. 2; {noise:g} "
                                      "dB; mean squared error per run, paired)",
                                      _run_mse(t), _run_mse(w1), unit="m^2"))
            one = static[(static["noise_db"] == noise) & (static["step"] == 1)]
            rmse1 = float(np.sqrt(np.mean((one["x_est"] - one["x_true"]) ** 2)))
            metrics.append(Metric(f"oneshot_rmse_m{tag}", rmse1, None, "m",
                                  "static user, one update (no tracking)"))
            st = {k: runs[(runs["scenario"] == k) & (runs["noise_db"] == noise)]
                  .set_index("run")["std_m"] for k in ("static_station1", "static_station2")}
            prod_std = one.set_index("run")["std_m"]
            frac = float(np.mean(prod_std < np.minimum(st["static_station1"],
                                                       st["static_station2"])))
            metrics.append(Metric(f"product_sharper_fraction{tag}", frac, None, "",
                                  "fraction of runs whose eq. (2) product (first static update) "
                                  "has a smaller std than each station's density alone"))
            if noise == config.noise_db[0]:
                claims.append(Claim.above(
                    f"The product of the per-station densities is more concentrated than "
                    f"either (Fig. 9): in most runs ({noise:g} dB)",
                    prod_std < np.minimum(st["static_station1"], st["static_station2"]), 0.5))
                fin = static[(static["noise_db"] == noise) & (static["step"] == config.updates)]
                fin = fin.set_index("run")
                err = fin["x_est"] - fin["x_true"]
                claims.append(Claim.all_of(
                    f"After {config.updates} updates the estimate concentrates at "
                    f"{config.user_m:g} m ({noise:g} dB): per-run RMSE <= "
                    f"{config.converged_tolerance_m:g} m and the std shrinks",
                    [Claim.below("", err ** 2, config.converged_tolerance_m ** 2, "m^2"),
                     Claim.lower("", fin["std_m"], one.set_index("run")["std_m"], unit="m")]))
                claims.append(Claim.all_of(
                    f"... and its uncertainty is calibrated: the 2-sigma interval holds the "
                    f"truth in >= {config.coverage_min:.0%} of the runs and NEES "
                    f"<= {config.nees_max:g} ({noise:g} dB)",
                    [Claim.above("", (err.abs() <= 2 * fin["std_m"]).astype(float),
                                 config.coverage_min),
                     Claim.below("", (err / fin["std_m"]) ** 2, config.nees_max)]))
                claims.append(Claim.above(
                    f"Calibration in both door states gives a bimodal D(m | x) past the door "
                    f"(Fig. 6), over runs: in most runs ({noise:g} dB)",
                    (f6["modes"] >= 2).astype(float), 0.5))
        metrics += self._variant_metrics(config, results, claims, notes)
        notes.append("metric names without suffix are at 2 dB noise; '_noise10db' at 10 dB")
        notes.append("the disk motion model has zero mean: a user walking at a constant speed "
                     "close to v_max is followed with a lag (tracking_mean_lag_m)")
        claims += self._figures(config, results[results["table"] == "figure"], trk, out_dir, notes,
                                runs[runs["scenario"] == "tracking_cv"])
        return Summary(metrics, claims, notes)

    @staticmethod
    def _variant_metrics(config: CorridorConfig, results: pd.DataFrame, claims: list,
                         notes: list) -> list:
        """Reduction comparison (ISD to the exact product, error, time) and the
        constant-velocity tracker, per noise level."""
        red, alt = config.reduction, config.alt_reduction
        runs = results[results["table"] == "runs"]
        isd_rows = results[results["table"] == "isd"]
        out = []

        def rmse(df):
            return float(np.sqrt(np.mean((df["x_est"] - df["x_true"]) ** 2)))

        for noise in config.noise_db:
            tag = "" if noise == config.noise_db[0] else f"_noise{noise:g}db"
            r = runs[runs["noise_db"] == noise]
            sc = {name: g for name, g in r.groupby("scenario")}
            i = isd_rows[isd_rows["noise_db"] == noise]
            n_exact = int(i["components_exact"].max()) if len(i) else 0
            for m in (red, alt):
                out.append(Metric(f"isd_{m}{tag}", float(np.mean(i[f"isd_{m}"])), None, "",
                                  f"mean over runs of ISD({m} reduction to "
                                  f"{config.position_components}, exact eq. (2) product of "
                                  f"{n_exact} components) / int exact^2, first static update"))
            ratio = i[f"isd_{red}"] / i[f"isd_{alt}"]
            frac_le = float(np.mean(i[f"isd_{red}"] <= i[f"isd_{alt}"] * (1 + 1e-9)))
            out += [Metric(f"isd_ratio_median{tag}", float(np.median(ratio)), None, "",
                           f"median over runs of ISD({red}) / ISD({alt})"),
                    Metric(f"isd_{red}_le_{alt}_fraction{tag}", frac_le, None, "",
                           f"runs whose {red} ISD is <= the {alt} ISD")]
            claims.append(Claim(
                f"Progressive Bayes reduction ({config.position_components} components) is never "
                f"farther from the exact eq. (2) product than West/Runnalls in ISD ({noise:g} dB; "
                f"median ratio {float(np.median(ratio)):.3f})", bool(frac_le == 1.0)))
            last = {m: sc[name][sc[name]["step"] == config.updates]
                    for m, name in ((red, "static"), (alt, f"static_{alt}"))}
            e_rm, e_nees, e_cov = error_calibration(last[alt]["x_est"] - last[alt]["x_true"],
                                               last[alt]["std_m"])
            out += [Metric(f"rmse_m_after_{config.updates}_{alt}{tag}", e_rm, None, "m",
                           f"static user, {alt} reduction (labelled alternative)"),
                    Metric(f"nees_after_{config.updates}_{alt}{tag}", e_nees, 1.0, "",
                           f"static user, {alt} reduction"),
                    Metric(f"coverage_2sigma_after_{config.updates}_{alt}{tag}", e_cov, 0.95, "",
                           f"static user, {alt} reduction")]
            for prefix, walkname in (("", "walk"), ("pause_", "pausing walk")):
                trk = "tracking" if not prefix else "pause_tracking"
                one = sc["walk_oneshot" if not prefix else "pause_oneshot"]
                cv = sc[f"{trk}_cv"]
                _, nees_cv, cov_cv = error_calibration(cv["x_est"] - cv["x_true"], cv["std_m"])
                out += [Metric(f"{trk}_rmse_m_{alt}{tag}", rmse(sc[f"{trk}_{alt}"]), None, "m",
                               f"{walkname}, disk model, {alt} reduction"),
                        Metric(f"{trk}_cv_rmse_m{tag}", rmse(cv), None, "m",
                               f"{walkname}, constant-velocity (position, velocity) mixture "
                               f"(ours), q = {config.cv_q:g} m^2/s^3, {alt} reduction"),
                        Metric(f"{trk}_cv_nees{tag}", nees_cv, 1.0, "",
                               f"{walkname}, constant-velocity tracker: mean (error / std)^2"),
                        Metric(f"{trk}_cv_coverage_2sigma{tag}", cov_cv, 0.95, "",
                               f"{walkname}, constant-velocity tracker: |error| <= 2 std")]
                claims.append(Claim.lower(
                    f"Variant (ours, not the paper's): a constant-velocity mixture tracker is "
                    f"more accurate than one-shot positioning on the {walkname} ({noise:g} dB; "
                    "mean squared error per run, paired)", _run_mse(cv), _run_mse(one),
                    unit="m^2"))
            if f"cpu_s_static_{red}" in i.columns:
                notes.append(
                    f"CPU per run, static user ({config.updates} updates, {noise:g} dB): "
                    f"{red} {i[f'cpu_s_static_{red}'].mean():.3f} s, "
                    f"{alt} {i[f'cpu_s_static_{alt}'].mean():.3f} s (timings.csv; no claim)")
        return out

    # ---- figures (plots of the "figure" rows; no computation beyond reading them) -----------
    def _figures(self, config: CorridorConfig, figs: pd.DataFrame, trk: pd.DataFrame,
                 out_dir: Path, notes: list[str], cv: pd.DataFrame | None = None) -> list[Claim]:
        noise = config.noise_db[0]
        corridor = Corridor()                     # labels only: station and door positions

        def rows(fig: str, series: str | None = None) -> pd.DataFrame:
            f = figs[figs["figure"] == fig]
            return f if series is None else f[f["series"] == series]

        fig, ax = figure()
        for closed, ls in (("closed", "-"), ("open", ":")):
            for k, c in enumerate((COLORS["ours"], COLORS["baseline"])):
                r = rows("fig4", f"station{k + 1}_{closed}")
                ax.plot(r["x"], r["value"], ls, color=c,
                        label=f"station {k + 1} (x={corridor.stations[k]:g} m), door {closed}")
        ax.axvline(corridor.door_m, color="grey", lw=0.8)
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("signal strength m [dBm]")
        ax.set_title(f"Fig. 4: corridor with a metallic door at {corridor.door_m:g} m (noise-free)")
        ax.legend(fontsize=8, loc="upper center")
        save(fig, out_dir / "fig4_corridor_rss.png")

        r5 = rows("fig5")
        grid = r5.pivot_table(index="m", columns="x", values="value")
        fig, ax = figure()
        pc = ax.pcolormesh(grid.columns.to_numpy(), grid.index.to_numpy(), grid.to_numpy(),
                           shading="auto", cmap="viridis")
        fig.colorbar(pc, ax=ax, label="density D(x, m)")
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("signal strength m of station 1 [dBm]")
        n_comp = r5["series"].iloc[0].split("_")[1]
        ax.set_title(f"Fig. 5: calibrated model of station 1 ({noise:g} dB, {n_comp} components)")
        save(fig, out_dir / "fig5_model_station1.png")

        r6 = rows("fig6", "model")
        ms, dm = r6["m"].to_numpy(), r6["value"].to_numpy()
        fig, ax = figure()
        ax.plot(ms, dm, color=COLORS["ours"], label=f"model D(m | x = {config.figure_x_m:g} m)")
        for series in ("door_open", "door_closed"):
            ax.axvline(float(rows("fig6", series)["m"].iloc[0]), ls="--", color="grey")
        ax.set_xlabel("signal strength m of station 1 [dBm]")
        ax.set_ylabel("density [1/dB]")
        ax.set_title(f"Fig. 6: expected signal strength at x = {config.figure_x_m:g} m "
                     "(dashed: open / closed)")
        ax.legend()
        save(fig, out_dir / "fig6_rss_at_50m.png")
        peaks = np.flatnonzero((dm[1:-1] > dm[:-2]) & (dm[1:-1] > dm[2:]) & (dm[1:-1] > 0.1 * dm.max()))
        bimodal = peaks.size >= 2

        fig, ax = figure()
        for series, lab, c, ls in (("station1", "station 1 (x = 0 m)", COLORS["baseline"], "--"),
                                   ("station2", "station 2 (x = 60 m)", COLORS["alt"], ":"),
                                   ("product", "product, eq. (2)", COLORS["ours"], "-")):
            r = rows("fig9", series)
            ax.plot(r["x"], r["value"], ls, color=c, label=lab)
        stds = [float(rows("fig9_std", s)["value"].iloc[0]) for s in ("station1", "station2", "product")]
        ax.axvline(config.user_m, color="grey", lw=0.8)
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("density [1/m]")
        ax.set_title(f"Fig. 9: per-station position densities and their product (user at "
                     f"{config.user_m:g} m)")
        ax.legend()
        save(fig, out_dir / "fig9_product.png")

        fig, ax = figure()
        for k, ls in zip((1, 2, config.updates), ("--", ":", "-")):
            r = rows("fig10", f"after_{k}")
            ax.plot(r["x"], r["value"], ls, label=f"after {k} update{'s' if k > 1 else ''}")
        ax.axvline(config.user_m, color="grey", lw=0.8)
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("density [1/m]")
        ax.set_title(f"Fig. 10: static user at {config.user_m:g} m, {noise:g} dB")
        ax.legend()
        save(fig, out_dir / "fig10_updates.png")

        t = trk[(trk["noise_db"] == noise) & (trk["run"] == trk["run"].min())]
        fig, ax = figure()
        ax.plot(t["step"] * config.dt_s, t["x_true"], color="k", label="true position")
        ax.plot(t["step"] * config.dt_s, t["x_est"], color=COLORS["ours"],
                label=f"disk model (paper), {config.reduction} reduction")
        ax.fill_between(t["step"] * config.dt_s, t["x_est"] - 2 * t["std_m"],
                        t["x_est"] + 2 * t["std_m"], color=COLORS["ours"], alpha=0.2,
                        label="+/- 2 std")
        if cv is not None and len(cv):
            c = cv[(cv["noise_db"] == noise) & (cv["run"] == t["run"].iloc[0])]
            ax.plot(c["step"] * config.dt_s, c["x_est"], "--", color=COLORS["baseline"],
                    label="constant velocity (ours)")
            ax.fill_between(c["step"] * config.dt_s, c["x_est"] - 2 * c["std_m"],
                            c["x_est"] + 2 * c["std_m"], color=COLORS["baseline"], alpha=0.15)
        ax.set_xlabel("time [s]")
        ax.set_ylabel("position x [m]")
        ax.set_title(f"Tracking a walking user ({noise:g} dB, run {int(t['run'].iloc[0])})")
        ax.legend()
        save(fig, out_dir / "tracking.png")
        notes.append(f"Fig. 9 example (one draw): std station 1 {stds[0]:.2f} m, station 2 "
                     f"{stds[1]:.2f} m, product {stds[2]:.2f} m; the Fig. 9 claim is decided "
                     "over the runs (product_sharper_fraction)")
        notes.append(f"Fig. 6 example (one calibration): {'bimodal' if bimodal else 'not bimodal'}"
                     "; the Fig. 6 claim is decided over the runs (fig6_bimodal_fraction)")
        return []
