"""Paper 003 (Zickler & Veloso): RSS-only localization and tethering, Figs. 2-6.

The RSSI/distance model is fitted on simulated calibration pairs of the same floor (one
calibration set per experiment, drawn from the named stream ``"calibration"`` of the
experiment seed, as the paper builds one model before its runs); every Monte Carlo run then
places tracker and trackee at random poses and runs Algorithm 4 without and with a
compass, with :class:`~radioloc.estimators.grid.GridFilter` injected into the tethering
world as the tracker.

The results table has a ``table`` column: ``"runs"`` rows are the Monte Carlo steps (with
``driving``: the tracker drove toward its estimate in that step, its spread below ``v``);
``"vsweep"`` rows are the same worlds with a compass at each ``v`` of
``TetherConfig.v_sweep_m``; the block holding run 0 adds the rows the figures need (``"model"``: the fitted trapezoid rows
of Fig. 2; ``"fig3"``: three readings' likelihoods and posteriors; ``"fig6"``: grids of an
example simulation, from the named streams ``"fig3-readings"`` and ``"fig6-example"``).
:meth:`TetherExperiment.summarize` only reads that table.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError
from radioloc.core.rng import stream
from radioloc.estimators.grid import GridFilter, GridGeometry
from radioloc.experiments.base import (Claim, Experiment, Metric, Summary,
                                       paired_differences, per_run, register)
from radioloc.models.rssi_trapezoid import RSSI_LEVELS, fit_raw, smooth, trapezoid
from radioloc.report.style import COLORS, figure, save
from radioloc.sim.tether import TetherParams, calibration_pairs, read_rssi, simulate_tether


@dataclass(frozen=True)
class TetherConfig:
    """Settings of ``p003-tether`` (choices the paper leaves open are ours).

    Parameters
    ----------
    (the fields below)

    steps: simulated steps of ``params.dt_s`` seconds per run.
    calibration_pairs: (RSSI, distance) pairs drawn from random placements for the model.
    tau_min_m, sigma_min_m, smooth_window: model fit (Sect. III-B/C); window in RSSI rows.
    grid_extent_m, cell_m: the tracker's grid (square, ``grid_extent_m`` wide, centred on its
        local origin); 2 m cells as in the paper's simulation (variant ``cells_1m``).
    epsilon: minimum cell probability (Algorithm 1). gamma_m: blur per step (Algorithm 4).
    example_runs: runs of the example simulation whose grids Fig. 6 shows.
    near_m: the paper's "typically remaining in range of 1 m during the mobile tracking
        stage" is judged as the mean error over that whole stage (every step once
        localized) <= near_m.
    several_m: the claim "errors peak several metres" means median peak error >= several_m.
    ablations: labelled variants run beside the main setting (metric suffix ``_<label>``),
        each changing one thing: ``cells_1m`` (1 m cells), ``no_fading`` (no Rayleigh
        fading), ``avg<N>`` (each reading averages ``ablation_packets`` faded packets),
        ``narrow_rows`` (trapezoid ``tau`` and ``sigma`` times ``narrow_factor``),
        ``perfect_odometry`` (no odometry noise on either robot), ``no_odometry_sharing``
        (the trackee does not send its odometry: the paper's inter-robot sharing removed;
        the tracker blurs by the trackee's top speed every step). The RSSI model is
        refitted on calibration pairs of each variant's channel. Not the paper's setting.
    team_trackers: trackers of the team experiment (0: none): that many trackers follow
        the same trackee, each alone and then sharing its readings with the others
        (``simulate_tether(trackers=..., share_readings=...)``), on the same worlds.
    team_ablations: labelled variants of the team run (metric suffix ``_<label>``):
        ``perfect_odometry`` (no odometry noise: a team-mate's reading lands exactly where
        it was taken).
    v_sweep_m: values of Algorithm 4's uncertainty threshold ``v`` run beside the main
        setting (with a compass, same worlds; metric prefix ``vsweep_v<v>_``): time to
        localize, fraction of steps driving toward the estimate, error and distance while
        driving. Empty: no sweep.
    """

    runs: int = 16
    block_size: int = 16
    steps: int = 300
    calibration_pairs: int = 20000
    tau_min_m: float = 0.5
    sigma_min_m: float = 0.5
    smooth_window: int = 2
    near_m: float = 1.0
    several_m: float = 3.0
    grid_extent_m: float = 40.0
    cell_m: float = 2.0
    epsilon: float = 1e-6
    gamma_m: float = 0.3
    example_runs: int = 8
    params: TetherParams = field(default_factory=TetherParams)
    ablations: tuple[str, ...] = ("cells_1m", "no_fading", "avg10", "narrow_rows",
                                  "perfect_odometry", "no_odometry_sharing")
    ablation_packets: int = 10
    narrow_factor: float = 0.5
    team_trackers: int = 2
    team_ablations: tuple[str, ...] = ("perfect_odometry",)
    v_sweep_m: tuple[float, ...] = (2.0, 3.0, 4.0, 6.0)

    @property
    def grid_cells(self) -> int:
        """Cells per side of the main grid."""
        return int(round(self.grid_extent_m / self.cell_m))

    def variants(self) -> dict[str, "Variant"]:
        """The simulated settings: the main one and the ablations.

        Returns
        -------
        dict of str to Variant
            Label -> world parameters, cell size and row scale (``"main"`` is the paper's
            setting as we read it).
        """
        P = self.params
        out = {"main": Variant(P, self.cell_m)}
        for label in self.ablations:
            if label == "cells_1m":
                out[label] = Variant(P, 1.0)
            elif label == "no_fading":
                out[label] = Variant(replace(P, channel=replace(P.channel, rayleigh=False)),
                                     self.cell_m)
            elif label.startswith("avg"):
                ch = replace(P.channel, packets=int(self.ablation_packets))
                out[f"avg{int(self.ablation_packets)}"] = Variant(replace(P, channel=ch),
                                                                  self.cell_m)
            elif label == "narrow_rows":
                out[label] = Variant(P, self.cell_m, self.narrow_factor)
            elif label == "perfect_odometry":
                out[label] = Variant(replace(P, odo_scale_std=0.0, odo_heading_std=0.0),
                                     self.cell_m)
            elif label == "no_odometry_sharing":
                out[label] = Variant(replace(P, share_odometry=False), self.cell_m)
            else:
                raise ConfigError(f"ablations: unknown variant {label!r}")
        return out


@dataclass(frozen=True)
class Variant:
    """One simulated setting: world parameters, grid cell size and trapezoid row scale.

    Parameters
    ----------
    params : TetherParams
        World, robots and channel.
    cell_m : float
        Grid cell width, metres.
    row_scale : float
        Factor on the fitted trapezoids' ``tau`` and ``sigma`` (1: as fitted).
    """

    params: TetherParams
    cell_m: float
    row_scale: float = 1.0


def _fit(config: TetherConfig, params: TetherParams, rng: np.random.Generator):
    """Calibration pairs and the trapezoid model: raw rows (Sect. III-B), smoothed model."""
    r, d = calibration_pairs(params, config.calibration_pairs, rng)
    raw = fit_raw(r, d, config.tau_min_m, config.sigma_min_m)
    model = smooth(*raw, window=config.smooth_window, tau_min=config.tau_min_m,
                   sigma_min=config.sigma_min_m)
    return raw, model


def _geometry(config: TetherConfig, cell_m: float | None = None) -> GridGeometry:
    cell = config.cell_m if cell_m is None else cell_m
    n = int(round(config.grid_extent_m / cell))
    return GridGeometry.centred(n, n, cell)


def _tracker(config: TetherConfig, model, cell_m: float | None = None) -> GridFilter:
    """The tracker of Algorithm 4: the grid filter with the paper's GetLocation."""
    return GridFilter(_geometry(config, cell_m), model, epsilon=config.epsilon,
                      blur_m=config.gamma_m, location="peak")


def _scaled(model, factor: float):
    """The model with every trapezoid's ``tau`` and ``sigma`` times ``factor``."""
    if factor == 1.0:
        return model
    return replace(model, tau=model.tau * factor, sigma=model.sigma * factor)


def _table(results: pd.DataFrame, name: str) -> pd.DataFrame:
    """The rows of one table, without the columns of the others."""
    sub = results[results["table"] == name].dropna(axis=1, how="all")
    for col in ("compass", "localized", "synced", "share", "driving"):
        if col in sub.columns:
            sub = sub.assign(**{col: sub[col].astype(bool)})
    return sub


def _cells(geom: GridGeometry, **grids: np.ndarray) -> dict:
    """Columns x, y and one column per ``(h, w)`` grid, one row per cell."""
    X, Y = np.meshgrid(geom.x, geom.y)
    return {"x": X.ravel(), "y": Y.ravel(), **{k: np.asarray(v).ravel() for k, v in grids.items()}}


def _following(df: pd.DataFrame, keys=("run", "compass")) -> pd.DataFrame:
    """Per (run, compass) (or ``keys``): localization time and error statistics once localized.

    ``localized`` never reverts within a run, so the following stage is its True rows. Where
    ``df`` has a ``driving`` column, also the statistics of the steps in which the tracker
    drove toward its estimate (``drive_*``; NaN for a run that never did) and the fraction
    of the following stage's steps that were driving (``drive_frac``).
    """
    keys = list(keys)
    stats = df[df["localized"]].groupby(keys).agg(
        t_loc=("time_s", "min"), mean_err=("error_m", "mean"), peak_err=("error_m", "max"),
        mean_err_odom=("error_odom_m", "mean"), peak_err_odom=("error_odom_m", "max"),
        mean_dist=("true_distance_m", "mean"))
    if "driving" in df.columns:
        stats = stats.join(df[df["localized"]].groupby(keys)["driving"].mean().rename("drive_frac"))
        stats = stats.join(df[df["driving"]].groupby(keys).agg(
            drive_err=("error_m", "mean"), drive_err_odom=("error_odom_m", "mean"),
            drive_dist=("true_distance_m", "mean")))
    every = df[keys].drop_duplicates().set_index(keys)
    return every.join(stats).reset_index()


def _mean_se(x) -> tuple[float, float]:
    """Mean and its Monte Carlo standard error over the finite values of ``x``."""
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return np.nan, np.nan
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(x.size)) if x.size > 1 else np.nan


def _per_run(per: pd.DataFrame, column: str, **where) -> pd.Series:
    """``column`` of the per-(run, ...) table, averaged over the rows of each run that
    match ``where`` (e.g. the trackers of a team); NaN where a run has none."""
    sel = np.ones(len(per), bool)
    for k, v in where.items():
        sel &= (per[k] == v).to_numpy()
    return per[sel].groupby("run")[column].mean()


def _paired(a: pd.Series, b: pd.Series) -> tuple[float, float, int]:
    """Mean and standard error of ``a - b`` over the runs where both are finite."""
    d = (a - b).dropna()
    m, se = _mean_se(d)
    return m, se, int(d.size)


#: what each ablation changes (see TetherConfig.ablations)
ABLATION_LABELS = {"main": "2 m cells, one Rayleigh-faded packet per reading (paper's setting)",
                   "cells_1m": "1 m cells", "no_fading": "no Rayleigh fading",
                   "avg10": "readings average 10 faded packets",
                   "narrow_rows": "trapezoid tau and sigma halved",
                   "perfect_odometry": "no odometry noise",
                   "no_odometry_sharing": "trackee's odometry not shared"}


def _ablation_row(per: pd.DataFrame) -> dict:
    """One setting's summary numbers over runs: name -> (per-run values, unit, statistic)."""
    wc, nc = per[per["compass"]], per[~per["compass"]]
    return {
        "mean_error_m_following_compass": (wc["mean_err"], "m", "mean"),
        "mean_error_m_following_compass_odomframe": (wc["mean_err_odom"], "m", "mean"),
        "mean_error_m_following_nocompass": (nc["mean_err"], "m", "mean"),
        "mean_error_m_following_nocompass_odomframe": (nc["mean_err_odom"], "m", "mean"),
        "peak_error_m_following_nocompass": (nc["peak_err"], "m", "median"),
        "time_to_localize_s": (per["t_loc"], "s", "median"),
        "fraction_localized": (per["t_loc"].notna().astype(float), "", "mean"),
        "mean_error_m_driving_compass_odomframe": (wc["drive_err_odom"], "m", "mean"),
        "fraction_driving_compass": (wc["drive_frac"], "", "mean"),
    }


def _ablation_markdown(table: pd.DataFrame) -> str:
    """The ablation table as Markdown (the docs copy it)."""
    head = ("| variant | compass, init [m] | compass, odom [m] | no compass, init [m] | "
            "no compass, odom [m] | peak, no compass [m] | t_loc [s] | localized | "
            "compass, driving, odom [m] | compass, driving fraction |")
    lines = [head, "|" + "---|" * 10]
    for label, r in table.iterrows():
        v = [r[c] for c in table.columns]
        lines.append(f"| {label} ({ABLATION_LABELS.get(label, label)}) | "
                     + " | ".join(f"{x:.2f}" for x in v[:5])
                     + f" | {v[5]:.0f} | {v[6]:.2f} | {v[7]:.2f} | {v[8]:.2f} |")
    return "\n".join(lines)


@register
class TetherExperiment(Experiment):
    """Experiment ``p003-tether``: Figs. 2-6 of paper 003.

    Parameters
    ----------
    (none: settings are in :class:`TetherConfig`)
    """

    id = "p003-tether"
    paper = "003"
    description = "RSSI trapezoid model + grid Bayes filter tethering, with and without compass (Figs. 2-6)"

    def config(self, full: bool) -> TetherConfig:
        """The quick or full configuration.

        Parameters
        ----------
        full : bool
            Full size (200 runs of 400 s, every ablation); quick: 16 runs of 300 s with
            the ``cells_1m``, ``perfect_odometry`` and ``no_odometry_sharing`` ablations
            only. Both run the two-tracker team and the ``v`` sweep (2, 3, 4, 6 m); full
            also the team's ``perfect_odometry`` variant.

        Returns
        -------
        TetherConfig
        """
        if full:
            return TetherConfig(runs=200, block_size=50, steps=400)
        return TetherConfig(ablations=("cells_1m", "perfect_odometry", "no_odometry_sharing"),
                            team_ablations=())

    def run_block(self, config: TetherConfig, runs: np.ndarray, rng: np.random.Generator) -> pd.DataFrame:
        """Simulate one block of runs without and with a compass (and the figure rows).

        Parameters
        ----------
        config : TetherConfig
            Settings.
        runs : ndarray of int
            Run indices of the block.
        rng : numpy.random.Generator
            The block's generator (its experiment seed also names the calibration and
            figure streams, so every block fits the same model).

        Returns
        -------
        pandas.DataFrame
            Rows of the tables ``runs`` (every block) and ``model``, ``fig3``, ``fig6``
            (the block holding run 0), told apart by the ``table`` column.
        """
        frames = []
        examples = bool(np.any(runs == 0))
        # every setting (variant, compass) of the block replays the same worlds: paired
        world_seed = int(rng.integers(2**62))
        main_model = None
        for label, var in config.variants().items():
            params = var.params
            raw, model = _fit(config, params, stream(rng, "calibration"))
            model = _scaled(model, var.row_scale)
            if label == "main":
                main_model = model
            if examples:
                frames.append(pd.DataFrame({
                    "table": "model", "variant": label, "run": int(runs[0]),
                    "rssi": np.arange(RSSI_LEVELS), "raw_mu": raw[0], "raw_tau": raw[1],
                    "raw_sigma": raw[2], "count": raw[3], "mu": model.mu, "tau": model.tau,
                    "sigma": model.sigma}))
            for compass in (False, True):
                tr = simulate_tether(params, _tracker(config, model, var.cell_m), runs.size,
                                     config.steps, stream(world_seed, "world"), compass=compass)
                B, T = tr.error_m.shape
                frames.append(pd.DataFrame({
                    "table": "runs", "variant": label, "run": np.repeat(runs, T), "compass": compass,
                    "time_s": tr.time_s.ravel(), "error_m": tr.error_m.ravel(),
                    "error_odom_m": tr.error_odom_m.ravel(),
                    "true_distance_m": tr.true_distance_m.ravel(),
                    "uncertainty_m": tr.uncertainty_m.ravel(), "localized": tr.localized.ravel(),
                    "synced": tr.synced.ravel(), "driving": tr.driving.ravel()}))
        for v in config.v_sweep_m:
            tr = simulate_tether(replace(config.params, v_m=float(v)), _tracker(config, main_model),
                                 runs.size, config.steps, stream(world_seed, "world"), compass=True)
            T = tr.error_m.shape[1]
            frames.append(pd.DataFrame({
                "table": "vsweep", "v_m": float(v), "run": np.repeat(runs, T), "compass": True,
                "time_s": tr.time_s.ravel(), "error_m": tr.error_m.ravel(),
                "error_odom_m": tr.error_odom_m.ravel(),
                "true_distance_m": tr.true_distance_m.ravel(), "localized": tr.localized.ravel(),
                "driving": tr.driving.ravel()}))
        M = int(config.team_trackers)
        team_params = {"main": config.params}
        for label in config.team_ablations:
            if label != "perfect_odometry":
                raise ConfigError(f"team_ablations: unknown variant {label!r}")
            team_params[label] = replace(config.params, odo_scale_std=0.0, odo_heading_std=0.0)
        for label, params in (team_params.items() if M > 1 else ()):
            for share, compass in ((False, False), (False, True), (True, False), (True, True)):
                    tr = simulate_tether(params, _tracker(config, main_model),
                                         runs.size, config.steps, stream(world_seed, "team-world"),
                                         compass=compass, trackers=M, share_readings=share)
                    T = tr.error_m.shape[1]
                    frames.append(pd.DataFrame({
                        "table": "team", "variant": label, "run": np.repeat(runs, M * T),
                        "tracker": np.tile(np.repeat(np.arange(M), T), runs.size),
                        "share": share, "compass": compass,
                        "time_s": tr.time_s.ravel(), "error_m": tr.error_m.ravel(),
                        "error_odom_m": tr.error_odom_m.ravel(),
                        "true_distance_m": tr.true_distance_m.ravel(),
                        "uncertainty_m": tr.uncertainty_m.ravel(),
                        "localized": tr.localized.ravel(), "synced": tr.synced.ravel()}))
        if examples:
            frames.append(self._fig3_rows(config, main_model, stream(rng, "fig3-readings"), int(runs[0])))
            frames.append(self._fig6_rows(config, main_model, stream(rng, "fig6-example"), int(runs[0])))
        return pd.concat(frames, ignore_index=True)

    #: Fig. 3's trackee and three tracker positions (tracker frame, metres)
    FIG3_TRACKEE = (5.0, 4.0)
    FIG3_TRACKERS = ((-6.0, -3.0), (0.0, 6.0), (6.0, -5.0))

    @classmethod
    def _fig3_rows(cls, config: TetherConfig, model, rng: np.random.Generator, run: int) -> pd.DataFrame:
        """Three readings in an empty room: each one's likelihood and the posterior after it."""
        P = config.params
        geom = _geometry(config)
        filt = GridFilter(geom, model, epsilon=config.epsilon, location="peak")
        state = filt.init(1)
        trackee = np.array(cls.FIG3_TRACKEE)
        centre = np.full(2, P.floor_m / 2)
        X, Y = np.meshgrid(geom.x, geom.y)
        frames = []
        for i, pos in enumerate(np.array(cls.FIG3_TRACKERS)):
            rssi = read_rssi(P.channel, pos + centre, trackee + centre, np.zeros((0, 4)), rng)
            lik = model.likelihood(np.hypot(X - pos[0], Y - pos[1]), rssi)
            state = filt.update(state, pos[None], [rssi])
            frames.append(pd.DataFrame({"table": "fig3", "run": run, "step": i, "rssi": int(rssi),
                                        **_cells(geom, likelihood=lik, posterior=state.p[0])}))
        return pd.concat(frames, ignore_index=True)

    @staticmethod
    def _fig6_rows(config: TetherConfig, model, rng: np.random.Generator, run: int) -> pd.DataFrame:
        """Grids while following: the example run localized earliest, at three steps."""
        P, T = config.params, config.steps
        geom = _geometry(config)
        frames = []
        for comp in (False, True):
            tr = simulate_tether(P, _tracker(config, model), config.example_runs, T, rng,
                                 compass=comp, record_steps=tuple(range(T)))
            first = np.where(tr.localized.any(axis=1), tr.localized.argmax(axis=1), T)
            b = int(first.argmin())                      # the run localized earliest
            t0 = int(min(first[b], T - 4))
            for t in np.linspace(t0, T - 1, 4).astype(int)[1:]:
                est = tr.track.position[b, t]
                frames.append(pd.DataFrame({
                    "table": "fig6", "run": run, "compass": comp, "step": int(t),
                    "tracker_x": tr.tracker_xy[b, t, 0], "tracker_y": tr.tracker_xy[b, t, 1],
                    "trackee_x": tr.trackee_xy[b, t, 0], "trackee_y": tr.trackee_xy[b, t, 1],
                    "estimate_x": est[0], "estimate_y": est[1], **_cells(geom, p=tr.states[t].p[b])}))
        return pd.concat(frames, ignore_index=True)

    def summarize(self, config: TetherConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Metrics, claims and figures, all from the results table.

        Parameters
        ----------
        config : TetherConfig
            Settings.
        results : pandas.DataFrame
            The concatenated :meth:`run_block` frames.
        out_dir : pathlib.Path
            Where the figures go.

        Returns
        -------
        Summary
        """
        results_in = results
        models = _table(results, "model")
        runs_all = _table(results, "runs")
        fig3_rows, fig6_rows = _table(results, "fig3"), _table(results, "fig6")
        extra, table_rows = [], []
        for label in config.variants():
            sub = _following(runs_all[runs_all["variant"] == label])
            row = {name: Metric.over_runs(f"{name}_{label}", values, None, unit,
                                          f"VARIANT {label}: {ABLATION_LABELS.get(label, label)}",
                                          stat=stat)
                   for name, (values, unit, stat) in _ablation_row(sub).items()}
            table_rows.append({"variant": label, **{k: m.value for k, m in row.items()}})
            if label != "main":
                extra += list(row.values())
        ablation = pd.DataFrame(table_rows).set_index("variant")
        results = runs_all[runs_all["variant"] == "main"]
        per = _following(results)
        nc, wc = (per[~per["compass"]].set_index("run"), per[per["compass"]].set_index("run"))
        frac = float(per["t_loc"].notna().mean())
        near = f"(mean <= {config.near_m:g} m)"
        metrics = [
            Metric.over_runs("time_to_localize_s", per["t_loc"], 50.0, "s",
                             "median over localized runs of the first time GetUncertainty < v "
                             "(paper: ~50 s in Fig. 4)", stat="median"),
            Metric.over_runs("fraction_localized", per["t_loc"].notna().astype(float), None, "",
                             f"runs localized within {config.steps} steps (both compass settings)"),
            Metric.over_runs("mean_error_m_following_compass_odomframe", wc["mean_err_odom"], 1.0,
                             "m", "HEADLINE: the paper's mobile tracking stage (every step once "
                             "localized, driving and exploring), with a compass, scored in the "
                             "tracker's current odometry frame (the relative position it "
                             "follows; its own drift not counted); mean over runs of each run's "
                             "mean (paper: 'typically remaining in range of 1 m')"),
            Metric.over_runs("mean_error_m_following_compass", wc["mean_err"], 1.0, "m",
                             "labelled reading: the same steps scored in the tracker's initial "
                             "frame (its own odometry drift counted as error)"),
            Metric.over_runs("mean_error_m_following_nocompass_odomframe", nc["mean_err_odom"],
                             None, "m", "as the headline, no compass"),
            Metric.over_runs("mean_error_m_following_nocompass", nc["mean_err"], None, "m",
                             "as the initial-frame reading, no compass"),
        ]
        for sub, cname in ((wc, "compass"), (nc, "nocompass")):
            metrics += [
                Metric.over_runs(f"mean_error_m_driving_{cname}", sub["drive_err"], None, "m",
                                 f"labelled reading, a subset of the paper's steps: "
                                 f"{cname.replace('nocompass', 'no compass')}, mean over runs of "
                                 "the mean error over the steps in which the tracker drives "
                                 "toward its estimate (spread below v), initial frame"),
                Metric.over_runs(f"mean_error_m_driving_{cname}_odomframe", sub["drive_err_odom"],
                                 None, "m", "as above (a subset of the paper's steps), in the "
                                 "tracker's current odometry frame"),
                Metric.over_runs(f"fraction_driving_{cname}", sub["drive_frac"], None, "",
                                 "mean over runs of the fraction of the steps once localized "
                                 "in which the tracker drives toward its estimate (the rest "
                                 "explore)"),
                Metric.over_runs(f"mean_true_distance_m_driving_{cname}", sub["drive_dist"],
                                 3.0 if cname == "compass" else None, "m",
                                 "tracker-trackee distance in the driving steps"),
                Metric(f"mean_error_m_driving_{cname}_odomframe_pooled",
                       float(results.loc[results["driving"] & (results["compass"] == (cname == "compass")),
                                         "error_odom_m"].mean()), None, "m",
                       "the driving steps' odometry-frame error pooled over steps of all runs "
                       "(runs that drive longer weigh more); no interval: the steps of a run "
                       "are not independent, the per-run metric above has one"),
            ]
        metrics += [
            Metric.over_runs("peak_error_m_following_nocompass", nc["peak_err"], 7.0, "m",
                             "median over runs of the largest error once localized (paper: "
                             "peaks near 7 m)", stat="median"),
            Metric.over_runs("peak_error_m_following_compass", wc["peak_err"], None, "m",
                             "as above, with compass", stat="median"),
            Metric.over_runs("mean_true_distance_m_following_nocompass", nc["mean_dist"], 3.0, "m",
                             "tracker-trackee distance once localized (paper: 'typically only "
                             "about 3 m')"),
            Metric.over_runs("mean_error_m_after_sync_compass",
                             per_run(results[results["compass"] & results["synced"]], "error_m"),
                             None, "m", "variant of the compass metric: mean over runs of the "
                             "mean error over the steps after the frames were synchronised"),
            Metric.over_runs("fraction_synced_compass",
                             results[results["compass"]].groupby("run")["synced"].last()
                             .astype(float), None, "",
                             "compass runs whose frames were synchronised by the end"),
        ]
        # Monte Carlo standard errors of the headline means (over runs)
        for name, sub, col in (("mean_error_m_following_compass", wc, "mean_err"),
                               ("mean_error_m_following_compass_odomframe", wc, "mean_err_odom"),
                               ("mean_error_m_following_nocompass", nc, "mean_err"),
                               ("mean_error_m_following_nocompass_odomframe", nc, "mean_err_odom")):
            metrics.append(Metric(f"{name}_se", _mean_se(sub[col])[1], None, "m",
                                  "Monte Carlo standard error of the mean over runs (a spread: "
                                  "no interval; the mean's interval is on its own row)"))
        metrics += extra
        sweep_metrics, sweep_note = self._v_sweep(config, _table(results_in, "vsweep"), out_dir)
        metrics += sweep_metrics
        share_metrics, share_claims, share_notes = self._sharing(
            config, runs_all, _table(results_in, "team"), out_dir)
        metrics += share_metrics
        claims = [
            Claim.below(f"With a compass the error stays within about 1 m during the mobile "
                        f"tracking stage {near}, every step once localized, the tracker's "
                        "current odometry frame (headline)", wc["mean_err_odom"], config.near_m,
                        "m"),
            Claim.below(f"(labelled reading: initial frame) With a compass the error stays "
                        f"within about 1 m during the mobile tracking stage {near}, every step "
                        "once localized, the tracker's own drift counted", wc["mean_err"],
                        config.near_m, "m"),
            Claim.above(f"Without a compass the error peaks several metres (median peak >= "
                        f"{config.several_m:g} m)", nc["peak_err"], config.several_m, "m",
                        stat="median"),
            Claim.lower("Synchronising the frames with a compass lowers the following error",
                        wc["mean_err"], nc["mean_err"], unit="m"),
            Claim.below(f"(labelled reading: a subset of the paper's steps) With a compass, in "
                        f"the steps the tracker drives toward its estimate, the error stays "
                        f"within about 1 m {near}, current odometry frame",
                        wc["drive_err_odom"], config.near_m, "m"),
        ]
        claims += share_claims
        self._fig_model(config, models[models["variant"] == "main"], out_dir)
        self._fig_donuts(config, fig3_rows, out_dir)
        self._fig_traces(results, per, out_dir)
        self._fig_snapshots(config, fig6_rows, out_dir)
        notes = [f"{len(per) // 2} runs per variant, {config.steps} steps of {config.params.dt_s:g} s; "
                 f"grid {config.grid_cells}x{config.grid_cells} cells of {config.cell_m:g} m",
                 "ablations (following error: mean over runs of the per-run mean once localized; "
                 "'init' = tracker's initial frame, 'odom' = its current odometry frame):\n"
                 + _ablation_markdown(ablation)]
        notes += sweep_note + share_notes
        ablation.to_csv(out_dir / "ablation.csv")
        return Summary(metrics, claims, notes)

    # ---- uncertainty threshold v ---------------------------------------------------------
    @staticmethod
    def _v_sweep(config: TetherConfig, rows: pd.DataFrame, out_dir: Path) -> tuple[list, list]:
        """Metrics and the Markdown table of the ``v`` sweep (with a compass, same worlds).

        Parameters
        ----------
        config : TetherConfig
            Settings.
        rows : pandas.DataFrame
            The ``vsweep`` rows (empty without a sweep).
        out_dir : pathlib.Path
            Where ``v_sweep.csv`` goes.

        Returns
        -------
        metrics, notes : list
            Per ``v``: time to localize (median), fraction localized, fraction of steps
            driving, error while driving (both frames), distance while driving, error over
            every step once localized; one note holding the table.
        """
        if not len(rows):
            return [], []
        metrics, table = [], []
        cols = (("drive_frac", "fraction_driving", "", "fraction of the steps once localized "
                 "spent driving toward the estimate"),
                ("drive_err_odom", "mean_error_m_driving_odomframe", "m", "error while driving, "
                 "current odometry frame"),
                ("drive_err", "mean_error_m_driving", "m", "error while driving, initial frame"),
                ("drive_dist", "mean_true_distance_m_driving", "m", "tracker-trackee distance "
                 "while driving"),
                ("mean_err_odom", "mean_error_m_following_odomframe", "m", "error over every "
                 "step once localized, current odometry frame"),
                ("mean_err", "mean_error_m_following", "m", "error over every step once "
                 "localized, initial frame"))
        for v, g in rows.groupby("v_m"):
            per = _following(g).set_index("run")
            tag = f"vsweep_v{v:g}"
            row = {"v_m": float(v)}
            m = Metric.over_runs(f"{tag}_time_to_localize_s", per["t_loc"], None, "s",
                                 f"v = {v:g} m, compass: median over localized runs of the time "
                                 "to localize", stat="median")
            metrics.append(m)
            row["time_to_localize_s"] = (m.value, *m.ci)
            m = Metric.over_runs(f"{tag}_fraction_localized", per["t_loc"].notna().astype(float),
                                 None, "", f"v = {v:g} m, compass: runs localized within "
                                 f"{config.steps} steps")
            metrics.append(m)
            row["fraction_localized"] = (m.value, *m.ci)
            for col, name, unit, what in cols:
                m = Metric.over_runs(f"{tag}_{name}", per[col], None, unit,
                                     f"v = {v:g} m, compass: mean over runs of the {what}")
                metrics.append(m)
                row[name] = (m.value, *m.ci)
            table.append(row)
        head = ("| v [m] | t_loc [s] | localized | driving | error driving, odom [m] | "
                "error driving, init [m] | distance driving [m] | error all steps, odom [m] | "
                "error all steps, init [m] |")
        lines = [head, "|" + "---|" * 9]
        for r in table:
            cells = [f"{r['time_to_localize_s'][0]:.0f} [{r['time_to_localize_s'][1]:.0f}, "
                     f"{r['time_to_localize_s'][2]:.0f}]", f"{r['fraction_localized'][0]:.2f}"]
            cells += [f"{r[n][0]:.2f} [{r[n][1]:.2f}, {r[n][2]:.2f}]" for _, n, _, _ in cols]
            lines.append(f"| {r['v_m']:g} | " + " | ".join(cells) + " |")
        pd.DataFrame([{k: (v[0] if isinstance(v, tuple) else v) for k, v in r.items()}
                      for r in table]).to_csv(out_dir / "v_sweep.csv", index=False)
        note = ("v sweep (compass, the main setting's worlds; median or mean over runs with its "
                "95% CI; 'driving' = steps once localized in which the spread is below v and "
                "the tracker drives toward its estimate):\n" + "\n".join(lines))
        return metrics, [note]

    # ---- inter-robot sharing -----------------------------------------------------------
    @staticmethod
    def _sharing(config: TetherConfig, runs_all: pd.DataFrame, team: pd.DataFrame,
                 out_dir: Path) -> tuple[list, list, list]:
        """What sharing gains: the trackee's odometry (paper) and a team's readings (ours).

        Parameters
        ----------
        config : TetherConfig
            Settings.
        runs_all : pandas.DataFrame
            The ``runs`` rows of every variant.
        team : pandas.DataFrame
            The ``team`` rows (empty without a team).
        out_dir : pathlib.Path
            Where ``fig_sharing.png`` goes.

        Returns
        -------
        metrics, claims, notes : list
            Metrics (with their standard errors), claims and notes.
        """
        metrics, claims, notes, bars = [], [], [], []
        frames = (("", "mean_err", "initial frame"), ("_odomframe", "mean_err_odom",
                                                      "current odometry frame"))
        per_main = _following(runs_all[runs_all["variant"] == "main"])
        for comp, cname in ((True, "compass"), (False, "nocompass")):
            for suffix, col, fname in frames:
                m, se = _mean_se(_per_run(per_main, col, compass=comp))
                bars.append(("one tracker, odometry shared", cname, suffix, m, se))
        if "no_odometry_sharing" in set(runs_all["variant"]):
            per_no = _following(runs_all[runs_all["variant"] == "no_odometry_sharing"])
            for comp, cname in ((True, "compass"), (False, "nocompass")):
                for suffix, col, fname in frames:
                    m, se = _mean_se(_per_run(per_no, col, compass=comp))
                    bars.append(("one tracker, odometry not shared", cname, suffix, m, se))
                    gain = paired_differences(_per_run(per_no, col, compass=comp),
                                              _per_run(per_main, col, compass=comp))
                    g, gse, n = _paired(_per_run(per_no, col, compass=comp),
                                        _per_run(per_main, col, compass=comp))
                    metrics += [
                        Metric.over_runs(
                            f"odometry_sharing_gain_m_{cname}{suffix}", gain, None, "m",
                            f"{cname.replace('nocompass', 'no compass')}, {fname}: mean over "
                            f"{n} runs localized in both of (error without - with the "
                            "trackee's shared odometry), paired worlds; > 0 = sharing helps"),
                        Metric(f"odometry_sharing_gain_m_{cname}{suffix}_se", gse, None, "m",
                               "its Monte Carlo standard error (a spread: no interval)")]
            claims.append(Claim.lower(
                "Inter-robot sharing as in the paper (the trackee sends its odometry) lowers "
                "the following error with a compass (paired over runs, initial frame)",
                _per_run(per_main, "mean_err", compass=True),
                _per_run(per_no, "mean_err", compass=True), unit="m"))
        for tlabel in (list(dict.fromkeys(team["variant"])) if len(team) else []):
            tsub = "" if tlabel == "main" else f"_{tlabel}"
            tteam = team[team["variant"] == tlabel]
            m_, c_, n_ = TetherExperiment._team(config, tteam, tsub, bars if tlabel == "main" else [])
            metrics += m_
            claims += c_ if tlabel == "main" else []
            notes += n_ if tlabel == "main" else []
        TetherExperiment._fig_sharing(bars, team[team["variant"] == "main"] if len(team) else team,
                                      config, out_dir)
        return metrics, claims, notes

    @staticmethod
    def _team(config: TetherConfig, team: pd.DataFrame, tsub: str, bars: list):
        """Metrics, claims and notes of one team setting (``tsub``: metric suffix)."""
        metrics, claims, notes = [], [], []
        frames = (("", "mean_err", "initial frame"), ("_odomframe", "mean_err_odom",
                                                      "current odometry frame"))
        if len(team):
            M = int(team["tracker"].max()) + 1
            keys = ["run", "tracker", "compass", "share"]
            per_team = _following(team, keys=keys)
            half = config.steps * config.params.dt_s / 2
            late = (team[team["time_s"] > half].groupby(keys)[["error_m", "error_odom_m"]].mean()
                    .rename(columns={"error_m": "mean_err", "error_odom_m": "mean_err_odom"})
                    .reset_index())
            for stage, per, what in (
                    ("following", per_team, "the trackers' mean error once localized"),
                    ("second_half", late, f"the trackers' mean error after t = {half:g} s "
                                          "(localized or not)")):
                for comp, cname in ((True, "compass"), (False, "nocompass")):
                    for suffix, col, fname in frames:
                        alone = _per_run(per, col, compass=comp, share=False)
                        shared = _per_run(per, col, compass=comp, share=True)
                        for lab, series in (("alone", alone), ("shared", shared)):
                            m, se = _mean_se(series)
                            how = "each alone" if lab == "alone" else "sharing their readings"
                            if stage == "following":
                                bars.append((f"{M} trackers, {how}", cname, suffix, m, se))
                            metrics += [
                                Metric.over_runs(
                                    f"team_mean_error_m_{stage}_{cname}{suffix}_{lab}{tsub}",
                                    series, None, "m", f"{M} trackers, {how}, {fname}: mean "
                                    f"over runs of {what}"),
                                Metric(f"team_mean_error_m_{stage}_{cname}{suffix}_{lab}{tsub}_se",
                                       se, None, "m", "its Monte Carlo standard error (a spread: no interval)")]
                        g, gse, n = _paired(alone, shared)
                        metrics += [
                            Metric.over_runs(
                                f"team_sharing_gain_m_{stage}_{cname}{suffix}{tsub}",
                                paired_differences(alone, shared), None, "m",
                                f"{fname}, {what}: mean over {n} runs of (alone - sharing), "
                                "same worlds; > 0 = sharing helps"),
                            Metric(f"team_sharing_gain_m_{stage}_{cname}{suffix}{tsub}_se", gse, None,
                                   "m", "its Monte Carlo standard error (a spread: no interval)")]
            for lab, share in (("alone", False), ("shared", True)):
                t = per_team[per_team["share"] == share]
                tl = t.groupby("run")["t_loc"].min()       # first tracker of the team
                m, se = _mean_se(tl)
                metrics += [
                    Metric.over_runs(f"team_time_to_localize_s_{lab}{tsub}", tl, None, "s",
                                     "mean over runs of the first time a tracker of the team is "
                                     "localized"),
                    Metric(f"team_time_to_localize_s_{lab}{tsub}_se", se, None, "s",
                           "its Monte Carlo standard error (a spread: no interval)"),
                    Metric.over_runs(f"team_fraction_localized_{lab}{tsub}",
                                     per_run(t.assign(ok=t["t_loc"].notna().astype(float)), "ok"),
                                     None, "", "trackers localized within the run, mean over "
                                     "runs of the team's fraction")]
            claims.append(Claim.lower(
                f"(ours, beyond the paper) {M} trackers sharing their readings follow with a "
                "lower error than each alone, with a compass (paired over runs, initial frame)",
                _per_run(per_team, "mean_err", compass=True, share=True),
                _per_run(per_team, "mean_err", compass=True, share=False), unit="m"))
            notes.append(f"team: {M} trackers per run, start within {config.params.team_start_m:g} m "
                         "of each other (known relative poses); 'alone' and 'sharing' replay the "
                         "same worlds (stream 'team-world')")
        return metrics, claims, notes

    @staticmethod
    def _fig_sharing(bars, team, config, out_dir):
        labels = list(dict.fromkeys(b[0] for b in bars))
        fig, axes = figure(1, 3 if len(team) else 2, width=15 if len(team) else 10, height=4.6,
                           layout="constrained")
        colors = ["C0", "C7", "C1", "C2"]
        for ax, (cname, title) in zip(axes, (("compass", "with compass"),
                                             ("nocompass", "without compass"))):
            xs = np.arange(2)
            wdt = 0.8 / max(len(labels), 1)
            for i, lab in enumerate(labels):
                vals = [next((b[3], b[4]) for b in bars if b[0] == lab and b[1] == cname
                             and b[2] == suf) for suf in ("", "_odomframe")]
                ax.bar(xs + (i - (len(labels) - 1) / 2) * wdt, [v[0] for v in vals], wdt,
                       yerr=[2 * v[1] if np.isfinite(v[1]) else 0 for v in vals],
                       color=colors[i % len(colors)], capsize=3, label=lab)
            ax.set_xticks(xs, ["initial frame", "current odometry frame"])
            ax.set_ylabel("mean following error [m] (+- 2 s.e.)")
            ax.set_title(f"following error, {title}")
        fig.legend(*axes[0].get_legend_handles_labels(), loc="outside lower center",
                   ncol=len(labels), fontsize=8)
        if len(team):
            ax = axes[2]
            for (share, comp), g in team.groupby(["share", "compass"]):
                med = g.groupby("time_s")["error_m"].median()
                ax.plot(med.index, med.values, color="C2" if share else "C1",
                        ls="-" if comp else "--",
                        label=f"{'sharing' if share else 'alone'}, {'compass' if comp else 'no compass'}")
            ax.set_xlabel("time [s]")
            ax.set_ylabel("median error over trackers and runs [m]")
            ax.set_title("team of trackers: error vs time (initial frame)")
            ax.legend(fontsize=7)
        fig.suptitle("Inter-robot sharing: the trackee's odometry (paper) and a team's readings (ours)")
        save(fig, out_dir / "fig_sharing.png", caption=(
            "Mean following error (bars, +- 2 standard errors) of one tracker with and without "
            "the trackee's shared odometry (the paper's sharing) and, ours beyond the paper, of "
            "a team of trackers each alone or sharing their readings, with and without a "
            "compass, in the initial and the current odometry frame"
            + ("; right: the team's median error against time." if len(team) else ".")))

    # ---- figures ---------------------------------------------------------------------
    @staticmethod
    def _fig_model(config, rows, out_dir):
        dist = np.linspace(0, 60, 301)
        rows = rows.sort_values("rssi")
        col = lambda c: rows[c].to_numpy()[:, None]
        with np.errstate(invalid="ignore"):
            raw = trapezoid(dist[None, :], col("raw_mu"), col("raw_tau"), col("raw_sigma"))
        smooth_img = trapezoid(dist[None, :], col("mu"), col("tau"), col("sigma"))
        fig, axes = figure(1, 2, width=10, height=4.2, sharey=True)
        for ax, img, title in ((axes[0], raw, "(a) before post-processing"),
                               (axes[1], smooth_img, "(b) after smoothing + monotone boundaries")):
            im = ax.imshow(np.ma.masked_invalid(img), origin="lower", aspect="auto", cmap="Blues",
                           extent=(dist[0], dist[-1], -0.5, 100.5), vmin=0, vmax=1)
            ax.set_xlabel("distance [m]")
            ax.set_title(title)
        axes[0].set_ylabel("RSSI (0..100)")
        fig.colorbar(im, ax=axes[1], label="L(dist | rssi)")
        fig.suptitle(f"Fig. 2: RSSI/distance likelihood from {config.calibration_pairs} simulated calibration pairs")
        save(fig, out_dir / "fig2_model.png", caption=(
            "Fig. 2 of paper 003: the RSSI/distance likelihood model before (a) and after (b) "
            "post-processing; each horizontal slice is the trapezoidal distribution D_i for the "
            f"RSSI value i on the vertical axis (here from {config.calibration_pairs} simulated "
            "calibration pairs; darker = more likely, colour bar L(dist | rssi))."))

    @classmethod
    def _fig_donuts(cls, config, rows, out_dir):
        geom = _geometry(config)
        trackee = np.array(cls.FIG3_TRACKEE)
        trackers = np.array(cls.FIG3_TRACKERS)
        fig, axes = figure(2, 3, width=12, height=7.6, layout="constrained")
        steps = [rows[rows["step"] == i].sort_values(["y", "x"]) for i in range(len(trackers))]
        for r, (col, label) in enumerate((("likelihood", "likelihood L(d | RSSI)"),
                                          ("posterior", "cell probability"))):
            top = max(float(g[col].max()) for g in steps)
            for i, g in enumerate(steps):
                ax = axes[r, i]
                img = g[col].to_numpy().reshape(geom.h, geom.w)
                im = ax.imshow(img, origin="lower", extent=geom.extent(), cmap="viridis",
                               vmin=0.0, vmax=top)
                ax.plot(*trackers[:i + 1].T, "o", color="white", mec="k", ms=6,
                        label="tracker positions")
                for j, q in enumerate(trackers[:i + 1]):
                    ax.annotate(str(j + 1), q, xytext=(4, 4), textcoords="offset points",
                                color="white", fontweight="bold")
                ax.plot(*trackee, "s", color=COLORS["baseline"], mfc="none", mew=2, ms=9,
                        label="trackee (true)")
                ax.axhline(0, ls="--", lw=0.6, color="white")
                ax.axvline(0, ls="--", lw=0.6, color="white")
                ax.set_title(f"({'abc'[i]}) L at tracker pos. {i + 1}, RSSI "
                             f"{int(g['rssi'].iloc[0])}" if r == 0 else
                             f"({'def'[i]}) grid after {i + 1} update(s)", fontsize=9)
                ax.grid(False)
                ax.set_xlabel("x [m]")
                ax.set_ylabel("y [m]")
            fig.colorbar(im, ax=axes[r, :], label=label, shrink=0.9)
        axes[0, 0].legend(loc="lower left", fontsize=7)
        fig.suptitle("Fig. 3: distance likelihoods of three readings (top) and the grid "
                     "posterior (bottom); brighter = more likely")
        save(fig, out_dir / "fig3_updates.png", caption=(
            "Fig. 3 of paper 003: distance distributions from multiple RSSI measurements "
            "((a)-(c)) and the resulting progression of the probability grid ((d)-(f)). Here "
            "brighter cells are more likely (colour bars: likelihood 0-1, cell probability); "
            "dashed lines mark the origin of the tracker's coordinate system, the square the "
            "trackee's true location, numbered dots the tracker's three positions."))

    @staticmethod
    def _fig_traces(results, per, out_dir):
        for comp, name, num in ((False, "nocompass", 4), (True, "compass", 5)):
            sub = results[results["compass"] == comp]
            info = per[per["compass"] == comp].sort_values("run")
            run = int(info.dropna(subset=["t_loc"])["run"].iloc[0]) if info["t_loc"].notna().any() else int(info["run"].iloc[0])
            g = sub[sub["run"] == run]
            med = sub.groupby("time_s")["error_m"].median()
            fig, ax = figure(width=8, height=4.4, layout="constrained")
            ax.plot(g["time_s"], g["error_m"], color=COLORS["ours"], label=f"localization error, run {run}")
            ax.plot(g["time_s"], g["true_distance_m"], color=COLORS["truth"], ls="--", label=f"true distance, run {run}")
            ax.plot(med.index, med.values, color=COLORS["bound"], lw=0.8, alpha=0.7, label="median error over all runs")
            t_loc = info.loc[info["run"] == run, "t_loc"].iloc[0]
            if np.isfinite(t_loc):
                ax.axvline(t_loc, color="k", ls=":", lw=1, label="localized (trackee starts moving)")
            ax.set_xlabel("time [s]")
            ax.set_ylabel("[m]")
            ax.set_title(f"Fig. {num}: localization {'with' if comp else 'without'} orientation sensing")
            fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=2,
                       fontsize=8)
            save(fig, out_dir / f"fig{num}_{name}.png", caption=(
                f"Fig. {num} of paper 003: localization {'with' if comp else 'without'} "
                f"orientation sensing: localization error and true distance against time in run "
                f"{run} (the run localized first), the median error over all runs and the time "
                "the trackee is localized and starts moving (dotted)."))

    @staticmethod
    def _fig_snapshots(config, rows, out_dir):
        geom = _geometry(config)
        fig, axes = figure(2, 3, width=11, height=7.4)
        for row, comp in enumerate((False, True)):
            sub = rows[rows["compass"] == comp]
            for col, t in enumerate(sorted(sub["step"].unique())):
                ax = axes[row, col]
                g = sub[sub["step"] == t].sort_values(["y", "x"])
                first = g.iloc[0]
                ax.imshow(g["p"].to_numpy().reshape(geom.h, geom.w), origin="lower",
                          extent=geom.extent(), cmap="Blues")
                ax.plot(first["tracker_x"], first["tracker_y"], "o", color="grey", ms=5, label="tracker (odometry)")
                ax.plot(first["trackee_x"], first["trackee_y"], "s", color=COLORS["baseline"], mfc="none", ms=8,
                        label="trackee (true)")
                ax.plot(first["estimate_x"], first["estimate_y"], ".", color=COLORS["truth"], ms=8, label="estimate")
                ax.set_title(f"({'abcdef'[3 * row + col]}) {'compass' if comp else 'no compass'}, t = {int(t) + 1} s",
                             fontsize=9)
                ax.grid(False)
                ax.set_xlabel("x [m] (tracker frame)")
                ax.set_ylabel("y [m]")
        axes[0, 0].legend(loc="lower left", fontsize=7)
        fig.suptitle(f"Fig. 6: grid while following (run localized earliest of {config.example_runs}); "
                     f"cell width {config.cell_m:g} m")
        save(fig, out_dir / "fig6_snapshots.png", caption=(
            "Fig. 6 of paper 003: two time series of tracking screenshots of a moving target "
            "without ((a)-(c)) and with ((d)-(f)) orientation information. Blue shading "
            f"indicates grid cell probabilities (darker = more likely, scaled per panel); cell "
            f"width {config.cell_m:g} m; grey dot: the tracker, square: the trackee (true), green "
            "dot: the estimate."))
