"""Paper 002: closed-form single-sensor tracking (iterative BLUE) vs Newton, EKF, OLS and the CRBs.

Fig. 1 RMSE of the current position versus the number of samples n = 10..60; Fig. 2 a
y = sin x trajectory, Newton against the closed form; Fig. 3 CPU time per track versus n
(machine-dependent, in ``timings.csv``; no claim rests on it). Targets follow eq. (1)
(synthetic) and, when the data folder is present, real pen-tip trajectories of the UCI
Character Trajectories set (the paper's UCI ASL hand trajectories are not available).

``run_block`` writes one table with a ``table`` column: ``"runs"`` rows (one per run, n and
method), ``"fig2"`` rows (the y = sin x example, drawn from the named stream ``"fig2"``) and
``"sensitivity"`` rows (the bound of eq. (23) versus the sensor path and k; deterministic).
The last two are per-experiment rows, written once by the block holding run 0 and filed
under ``run = 0``. ``summarize`` only reads the table.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.bounds.single_sensor import differenced_crb, raw_range_crb
from radioloc.core.errors import DataUnavailable
from radioloc.core.rng import stream
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.estimators.nlls_newton import NewtonTracker
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, data_root, register
from radioloc.io.uci_characters import resampled_tracks
from radioloc.models.motion import ConstantVelocity
from radioloc.models.ranging import GaussianRange
from radioloc.report.style import COLORS, LINESTYLES, figure, save
from radioloc.sim.single_sensor import (
    accel_var_from_positions,
    circular_sensor_path,
    noisy_ranges,
    place_tracks,
    random_tracks,
    sine_positions,
    states_from_positions,
)

METHODS = ("blue", "newton", "ekf", "ols")
LABELS = {"blue": "closed form (iterative BLUE)", "newton": "Newton on NLLS",
          "ekf": "EKF", "ols": "unweighted linear fit (MANOVA reading)"}
#: sensor turn per sample and reference indices of the sensitivity figure
SENSITIVITY_STEPS = (0.05, 0.1, 0.2, 0.4, 0.8, 1.3, 2.0, 2.6)
#: the fixed state [x, y, vx, vy] at k of the sensitivity figure
SENSITIVITY_STATE = (1.0, 0.5, 0.6, -0.3)


@dataclass(frozen=True)
class SingleSensorConfig:
    """Settings of ``p002-single-sensor`` (choices the paper leaves open are marked *).

    sample_period_s: 10 Hz (section 5).
    accel_var, range_var: reading of "uniform ... with the variance 0.1, 0.15 respectively"
        (listed as "the channel noise and the dynamic motion noise"): channel noise variance
        ``xi = 0.1`` m^2 and acceleration variance ``delta_g^2 = 0.15`` (m/s^2)^2 on both axes,
        both zero-mean uniform.
    n_values: numbers of samples of Fig. 1 / Fig. 3 (the first n samples of each track).
    reference_index*: k = n-1 (the current position is estimated).
    sensor_radius_m, sensor_step_rad*: the sensor circles the origin at this radius, turning
        ``sensor_step_rad`` per sample (a path that is not quadratic in n; see docs/p002.md
        for how the step size changes the bound).
    target_box_m*, target_speed_std*: initial target position uniform in the box
        [-b, b]^2, initial velocity N(0, std^2) per axis.
    newton_start_std*: Newton starts from the true [x_k, y_k, vx_k, vy_k] plus N(0, std^2)
        per component; the EKF prior at sample 0 is the true state plus N(0, std^2),
        covariance std^2 I.
    tol, max_iter: section 5.2's stopping rule |beta_{m+1} - beta_m|^2 <= tol for BLUE and
        Newton (the trackers take the step norm, sqrt(tol)).
    use_uniform_moments*: if True the BLUE uses the exact uniform-noise kurtosis (-1.2);
        False (default) uses the Gaussian moments printed in eq. (11)-eq. (14).
    uci_stride, uci_scale*: real pen tracks take every 2nd 200 Hz sample, replayed at 10 Hz,
        positions (arbitrary units) times 0.025 (about 1 m extent); their accel_var is
        estimated from pooled second differences (``2 var(d2 x) / T^4``).
    fig2_samples: length of the y = sin x example of Fig. 2.
    """

    runs: int = 100
    block_size: int = 50
    sample_period_s: float = 0.1
    accel_var: float = 0.15
    range_var: float = 0.1
    n_values: tuple[int, ...] = (10, 20, 30, 40, 50, 60)
    sensor_radius_m: float = 5.0
    sensor_step_rad: float = 1.3
    target_box_m: float = 2.0
    target_speed_std: float = 1.0
    newton_start_std: float = 1.0
    tol: float = 0.1
    max_iter: int = 20
    use_uniform_moments: bool = False
    uci_stride: int = 2
    uci_scale: float = 0.025
    fig2_samples: int = 60


def _trackers(config, accel_var):
    """The estimators compared, configured once per source."""
    kurt = -1.2 if config.use_uniform_moments else 0.0
    step_tol = float(np.sqrt(config.tol))
    common = dict(tol=step_tol, max_iter=config.max_iter)
    xi = config.range_var
    return {
        "blue": ClosedFormTracker(accel_var, xi, accel_excess_kurtosis=kurt,
                                  range_excess_kurtosis=kurt, **common),
        "ols": ClosedFormTracker(accel_var, xi, weighting="ols", **common),
        "blue_uniform_moments": ClosedFormTracker(accel_var, xi, accel_excess_kurtosis=-1.2,
                                                  range_excess_kurtosis=-1.2, **common),
        "blue_printed_eq14": ClosedFormTracker(accel_var, xi, printed_eq14=True, **common),
        "blue_k0": ClosedFormTracker(accel_var, xi, reference_index=0,
                                     accel_excess_kurtosis=kurt, range_excess_kurtosis=kurt,
                                     **common),
        "newton": NewtonTracker(**common),
        "ekf": RangeEKF(ConstantVelocity(accel_var), GaussianRange(float(np.sqrt(xi)))),
    }


def _rows(runs, source, n, method, pos_err2, **extra):
    base = {"table": "runs", "run": runs, "source": source, "n": n, "method": method,
            "pos_err2": pos_err2, "traj_err2": np.nan, "crb_diff_pos": np.nan,
            "crb_raw_pos": np.nan, "cpu_s_per_run": np.nan, "iterations": 0,
            "newton_converged": True, "newton_stalled": False}
    base.update(extra)
    return pd.DataFrame(base)


def _methods_on(tracks, config, rng, accel_var, source, runs):
    """All methods on tracks (R, N, 4) ``[x, y, vx, vy]`` for every n; tidy frames."""
    T, xi = config.sample_period_s, config.range_var
    n_max = tracks.shape[1]
    sensor_all = circular_sensor_path(n_max, config.sensor_radius_m, config.sensor_step_rad)
    meas = noisy_ranges(tracks[..., :2], sensor_all, xi, rng)
    start_noise = rng.normal(0.0, config.newton_start_std, size=(runs.size, 4))
    prior_noise = rng.normal(0.0, config.newton_start_std, size=(runs.size, 4))
    est = _trackers(config, accel_var)
    # the EKF is causal: one pass over all samples gives the estimate at every n - 1
    ekf_track = est["ekf"].run(meas[..., None], time=np.arange(n_max) * T,
                               prior_mean=tracks[:, 0] + prior_noise,
                               prior_cov=config.newton_start_std**2 * np.eye(4),
                               anchor_path=sensor_all[:, None, :])
    frames = []
    for n in config.n_values:
        if n > n_max:
            continue
        r, s, k = meas[:, :n], sensor_all[:n], n - 1
        truth = tracks[:, k]
        t0 = time.process_time()
        cf = est["blue"].locate(r, s, T)
        t_blue = time.process_time() - t0
        t0 = time.process_time()
        nt = est["newton"].locate(r, s, T, initial_state=truth + start_noise)
        t_newton = time.process_time() - t0
        ols = est["ols"].locate(r, s, T)
        # other readings of eq. (11)-eq. (14): exact uniform moments; printed eq. (14) terms
        for name in ("blue_uniform_moments", "blue_printed_eq14"):
            alt = est[name].locate(r, s, T)
            frames.append(_rows(runs, source, n, name,
                                np.sum((alt.position - truth[:, :2]) ** 2, axis=-1)))
        # variant: fixed reference k = 0 (the setting of Lemma 1: same beta, more samples)
        fixed = est["blue_k0"].locate(r, s, T)
        frames.append(_rows(runs, source, n, "blue_k0",
                            np.sum((fixed.position - tracks[:, 0, :2]) ** 2, axis=-1),
                            iterations=fixed.diagnostics["iterations"]))
        kw = dict(sample_period_s=T, accel_var=accel_var, range_var=xi, reference_index=k)
        crb_d = differenced_crb(truth, s, **kw)
        crb_r = raw_range_crb(truth, s, **kw)
        position = {"blue": cf.position, "newton": nt.position, "ols": ols.position,
                    "ekf": ekf_track.position[:, k]}
        traj_true = tracks[:, :n, :2]
        for m in METHODS:
            extra = dict(crb_diff_pos=crb_d[:, 0, 0] + crb_d[:, 1, 1],
                         crb_raw_pos=crb_r[:, 0, 0] + crb_r[:, 1, 1])
            if m in ("blue", "newton"):
                e = cf if m == "blue" else nt
                extra.update(
                    traj_err2=np.mean(np.sum((e.diagnostics["trajectory"] - traj_true) ** 2,
                                             axis=-1), axis=-1),
                    cpu_s_per_run=(t_blue if m == "blue" else t_newton) / runs.size,
                    iterations=e.diagnostics["iterations"])
            if m == "newton":
                extra.update(newton_converged=nt.diagnostics["converged"],
                             newton_stalled=nt.diagnostics["stalled"])
            frames.append(_rows(runs, source, n, m,
                                np.sum((position[m] - truth[:, :2]) ** 2, axis=-1), **extra))
    return frames


def _uci_tracks(config):
    """Pen-tip tracks ``[x, y, vx, vy]`` (P, n, 4) and their estimated acceleration variance."""
    folder = data_root() / "uci-character-trajectories"
    pos = resampled_tracks(folder, max(config.n_values), config.uci_stride, config.uci_scale)
    T = config.sample_period_s
    return states_from_positions(pos, T), accel_var_from_positions(pos, T)


def _fig2_rows(config, rng) -> pd.DataFrame:
    """The y = sin x example of Fig. 2 as table rows.

    Growing windows of 10..N samples, each estimating its last position: the closed form,
    Newton warm-started from its previous estimate moved on by one sample, and Newton
    cold-started at the origin with zero velocity. ``rng`` draws the range noise, then the
    noise of the first warm start.
    """
    T, N = config.sample_period_s, config.fig2_samples
    pos = sine_positions(N)
    sensor = circular_sensor_path(N, config.sensor_radius_m, config.sensor_step_rad)
    r = noisy_ranges(pos, sensor, config.range_var, rng)
    state = states_from_positions(pos, T)
    accel_var = accel_var_from_positions(pos, T) + config.accel_var
    step_tol = float(np.sqrt(config.tol))
    blue = ClosedFormTracker(accel_var, config.range_var, tol=step_tol)
    newton = NewtonTracker(tol=step_tol, max_iter=config.max_iter)
    start = state[9] + rng.normal(0.0, 0.3, 4)
    rows = []
    for j in range(9, N):
        win = slice(0, j + 1)
        cf = blue.locate(r[win], sensor[win], T)
        nt = newton.locate(r[win], sensor[win], T, initial_state=start)
        nc = newton.locate(r[win], sensor[win], T, initial_state=np.zeros(4))
        for name, e in (("blue", cf), ("newton_warm", nt), ("newton_cold", nc)):
            rows.append({"table": "fig2", "run": 0, "n": j + 1, "method": name,
                         "x_hat": e.position[0], "y_hat": e.position[1],
                         "x_true": pos[j, 0], "y_true": pos[j, 1],
                         "pos_err2": float(np.sum((e.position - pos[j]) ** 2))})
        st = nt.diagnostics["state"]
        start = st + np.array([T * st[2], T * st[3], 0.0, 0.0])
    return pd.DataFrame(rows)


def _sensitivity_rows(config) -> pd.DataFrame:
    """The bound of eq. (23) (and the raw-range one) versus the sensor's turn per sample
    and versus the reference index k, for a fixed state, as table rows."""
    T, n = config.sample_period_s, max(config.n_values)
    state = np.array(SENSITIVITY_STATE)
    kw = dict(sample_period_s=T, accel_var=config.accel_var, range_var=config.range_var)
    rows = []
    for st in SENSITIVITY_STEPS:
        s = circular_sensor_path(n, config.sensor_radius_m, st)
        c = differenced_crb(state, s, reference_index=n - 1, **kw)
        c_raw = raw_range_crb(state, s, reference_index=n - 1, **kw)
        rows.append({"table": "sensitivity", "run": 0, "n": n, "method": "step",
                     "param": st, "crb_diff_pos": c[0, 0] + c[1, 1],
                     "crb_raw_pos": c_raw[0, 0] + c_raw[1, 1]})
    s = circular_sensor_path(n, config.sensor_radius_m, config.sensor_step_rad)
    for k in np.r_[np.arange(0, n - 1, 5), n - 1]:
        c = differenced_crb(state, s, reference_index=int(k), **kw)
        rows.append({"table": "sensitivity", "run": 0, "n": n, "method": "k",
                     "param": float(k), "crb_diff_pos": c[0, 0] + c[1, 1],
                     "crb_raw_pos": np.nan})
    return pd.DataFrame(rows)


@register
class SingleSensorExperiment(Experiment):
    id = "p002-single-sensor"
    paper = "002"
    description = "Closed-form single-sensor tracker (iterative BLUE) vs Newton, EKF, OLS and CRBs"
    data_folder = None      # the synthetic part always runs; the real-data part checks itself
    timing_columns = ("cpu_s_per_run",)  # Fig. 3 CPU times: machine-dependent

    def config(self, full: bool) -> SingleSensorConfig:
        return SingleSensorConfig(runs=2000 if full else 100, block_size=50)

    def run_block(self, config: SingleSensorConfig, runs: np.ndarray,
                  rng: np.random.Generator) -> pd.DataFrame:
        n_max = max(config.n_values)
        tracks = random_tracks(runs.size, n_max, config.sample_period_s, config.accel_var, rng,
                               box_m=config.target_box_m, speed_std=config.target_speed_std)
        frames = _methods_on(tracks, config, rng, config.accel_var, "synthetic", runs)
        try:
            uci, uci_var = _uci_tracks(config)
        except DataUnavailable:
            uci = None
        if uci is not None:
            pick = place_tracks(uci, runs.size, config.target_box_m, rng)
            frames += _methods_on(pick, config, rng, uci_var, "uci-pen", runs)
        if runs[0] == 0:        # per-experiment rows, written once (by the block of run 0)
            frames.append(_fig2_rows(config, stream(rng, "fig2")))
            frames.append(_sensitivity_rows(config))
        return pd.concat(frames, ignore_index=True)

    def summarize(self, config: SingleSensorConfig, results: pd.DataFrame,
                  out_dir: Path) -> Summary:
        metrics, claims, notes = [], [], []
        table = results["table"] if "table" in results else pd.Series("runs", results.index)
        runs_rows = results[table == "runs"]
        for source, sub in runs_rows.groupby("source"):
            g = sub.groupby(["method", "n"])
            rmse = np.sqrt(g["pos_err2"].mean()).unstack("method")
            traj = np.sqrt(g["traj_err2"].mean()).unstack("method")
            crb_d = np.sqrt(sub[sub.method == "blue"].groupby("n")["crb_diff_pos"].mean())
            crb_r = np.sqrt(sub[sub.method == "blue"].groupby("n")["crb_raw_pos"].mean())
            tag = "" if source == "synthetic" else "_uci"
            n_top = max(rmse.index)
            paper_note = "position at k = n-1, sqrt(mean |p_hat - p|^2)"
            for m in METHODS:
                metrics.append(Metric(f"rmse_{m}_n{n_top}{tag}", rmse.loc[n_top, m], None, "m",
                                      f"{LABELS[m]}: {paper_note}"))
            metrics.append(Metric(f"crb_rmse_n{n_top}{tag}", crb_d.loc[n_top], None, "m",
                                  "eq. (23), differenced model, sqrt(mean trace position block)"))
            metrics.append(Metric(f"crb_raw_rmse_n{n_top}{tag}", crb_r.loc[n_top], None, "m",
                                  "raw-range CRB (Gaussian approximation)"))
            for m in ("blue", "newton"):
                metrics.append(Metric(f"traj_rmse_{m}_n{n_top}{tag}", traj.loc[n_top, m], None,
                                      "m", "RMSE of the straight track over all n samples"))
            newton_top = sub[(sub.method == "newton") & (sub.n == n_top)]
            metrics.append(Metric(f"newton_converged_frac_n{n_top}{tag}",
                                  newton_top["newton_converged"].astype(bool).mean(), None, "",
                                  "Newton runs meeting the stopping rule"))
            metrics.append(Metric(f"newton_stalled_frac_n{n_top}{tag}",
                                  newton_top["newton_stalled"].astype(bool).mean(), None, "",
                                  "Newton runs stopped by a singular Hessian or a non-finite "
                                  "iterate"))
            if "cpu_s_per_run" in sub:
                cpu = g["cpu_s_per_run"].mean().unstack("method")
                ratio = cpu.loc[n_top, "newton"] / cpu.loc[n_top, "blue"]
                metrics.append(Metric(f"cpu_ratio_newton_over_blue{tag}", ratio, 3.3, "",
                                      f"machine-dependent (timings.csv), not a claim: CPU time "
                                      f"per track at n = {n_top}, batched over runs; paper: "
                                      "about 70% less time (benchmarks/bench_closed_form.py)"))
                notes.append(f"({source}) CPU s per track (machine-dependent):\n"
                             + cpu[["blue", "newton"]].to_string())
                self._fig3(cpu, source, out_dir)
            best = rmse.loc[n_top, list(METHODS)].idxmin()
            for name, what in (("blue_uniform_moments", "BLUE with exact uniform-noise moments"),
                               ("blue_printed_eq14", "BLUE with eq. (14)'s printed off-diagonal "
                                                     "channel terms")):
                metrics.append(Metric(f"rmse_{name}_n{n_top}{tag}", rmse.loc[n_top, name], None,
                                      "m", f"reading: {what}"))
            metrics.append(Metric(f"rmse_blue_k0_n{n_top}{tag}", rmse.loc[n_top, "blue_k0"], None,
                                  "m", "variant: closed form estimating p_0 (fixed k = 0)"))
            claims.append(Claim(f"({source}) the closed form has the lowest RMSE of the four "
                                f"methods at n = {n_top} (best: {best})", best == "blue"))
            claims.append(Claim(f"({source}) the closed-form RMSE decreases with n",
                                bool(np.all(np.diff(rmse["blue"].to_numpy()) < 0))))
            claims.append(Claim(f"({source}) variant, fixed k = 0 as in Lemma 1: the closed-form "
                                "RMSE of p_0 decreases with n",
                                bool(np.all(np.diff(rmse["blue_k0"].to_numpy()) < 0))))
            notes.append(f"({source}) RMSE by n:\n" + rmse.round(4).to_string())
            self._fig1(rmse, crb_d, crb_r, config, source, out_dir)
        if "uci-pen" not in set(runs_rows["source"]):
            notes.append("real-data part skipped: folder uci-character-trajectories is absent "
                         f"under {data_root()} (set RADIOLOC_DATA); synthetic part only")
        fig2 = results[table == "fig2"]
        if len(fig2):
            claims.append(self._fig2(fig2, out_dir))
        sens = results[table == "sensitivity"]
        if len(sens):
            m_extra, n_extra = self._sensitivity(sens, config, out_dir)
            metrics += m_extra
            notes += n_extra
        return Summary(metrics, claims, notes)

    # ---- figures ----------------------------------------------------------------------
    def _fig1(self, rmse, crb_d, crb_r, config, source, out_dir):
        fig, ax = figure()
        colors = {"blue": COLORS["ours"], "newton": "C1", "ekf": "C2", "ols": "C4"}
        markers = {"blue": "o", "newton": "s", "ekf": "^", "ols": "v"}
        for m in METHODS:
            ax.semilogy(rmse.index, rmse[m], marker=markers[m], color=colors[m], label=LABELS[m])
        ax.semilogy(rmse.index, rmse["blue_k0"], "o--", mfc="none", color=COLORS["ours"],
                    label="variant: closed form for p_0 (fixed k = 0)")
        ax.semilogy(crb_d.index, crb_d, LINESTYLES["bound"], color=COLORS["bound"],
                    label="CRB eq. (23), differenced")
        ax.semilogy(crb_r.index, crb_r, "--", color="k", label="CRB of raw ranges")
        ax.set_xlabel("number of samples n")
        ax.set_ylabel("position RMSE [m] (p_k, k = n-1 unless noted)")
        ax.set_title(f"Fig. 1 ({source}): {config.runs} runs, 10 Hz, uniform noise")
        ax.legend(fontsize=7)
        save(fig, out_dir / f"fig1_rmse_vs_n_{source}.png")

    def _fig3(self, cpu, source, out_dir):
        fig, ax = figure()
        ax.plot(cpu.index, 1e3 * cpu["blue"], "o-", color=COLORS["ours"],
                label="closed form (iterative BLUE)")
        ax.plot(cpu.index, 1e3 * cpu["newton"], "s-", color="C1", label="Newton on NLLS")
        ax.set_xlabel("number of positions n")
        ax.set_ylabel("CPU time per track [ms] (batched)")
        ax.set_title(f"Fig. 3 ({source}, machine-dependent): same stopping rule |step|^2 <= 0.1")
        ax.legend()
        save(fig, out_dir / f"fig3_cpu_vs_n_{source}.png")

    def _fig2(self, fig2, out_dir):
        """Plot the y = sin x rows and judge the cold-start claim on them (points off the
        axes are clipped: a diverged run)."""
        by = {m: d.sort_values("n") for m, d in fig2.groupby("method")}
        truth = by["blue"][["x_true", "y_true"]].to_numpy()
        x_all = np.linspace(0.0, 2 * np.pi, 200)
        fig, ax = figure()
        ax.plot(x_all, np.sin(x_all), "k-", label="true y = sin x")
        style = {"blue": ("o", 3, COLORS["ours"], "closed form"),
                 "newton_warm": ("s", 3, "C1", "Newton (warm start)"),
                 "newton_cold": ("x", 4, "C3", "Newton (cold start at origin, v = 0)")}
        for m, (mk, ms, c, label) in style.items():
            ax.plot(by[m]["x_hat"], by[m]["y_hat"], mk, ms=ms, color=c, label=label)
        ax.set_xlim(-1, 7.5)
        ax.set_ylim(-3, 3)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title(f"Fig. 2: current-position estimates, windows of "
                     f"{int(by['blue']['n'].min())}..{int(by['blue']['n'].max())} samples")
        ax.legend(fontsize=8)
        save(fig, out_dir / "fig2_sine_trajectory.png")
        err = {m: np.linalg.norm(by[m][["x_hat", "y_hat"]].to_numpy() - truth, axis=-1)
               for m in ("blue", "newton_cold")}
        return Claim("(Fig. 2, y = sin x) Newton from a start at the origin fails (max error > 3x "
                     f"the closed form's): max errors {np.max(err['newton_cold']):.3g} m vs "
                     f"{np.max(err['blue']):.3g} m",
                     bool(np.max(err["newton_cold"]) > 3 * np.max(err["blue"])))

    def _sensitivity(self, sens, config, out_dir):
        """Plot and report the sensitivity rows (eq. (23) versus sensor turn and k)."""
        n = int(sens["n"].iloc[0])
        by_step = sens[sens.method == "step"].sort_values("param")
        by_k = sens[sens.method == "k"].sort_values("param")
        steps = by_step["param"].to_numpy()
        b_step = np.sqrt(by_step["crb_diff_pos"].to_numpy())
        b_raw = np.sqrt(by_step["crb_raw_pos"].to_numpy())
        ks = by_k["param"].to_numpy().astype(int)
        b_k = np.sqrt(by_k["crb_diff_pos"].to_numpy())
        fig, (a1, a2) = figure(1, 2, width=9.0)
        a1.loglog(steps, b_step, "o-", color=COLORS["ours"], label="CRB eq. (23)")
        a1.loglog(steps, b_raw, "s:", color="k", label="raw-range CRB")
        a1.set_xlabel("sensor turn per sample [rad]")
        a1.set_ylabel("position bound [m]")
        a1.set_title(f"sensor path speed (n = {n}, k = n-1)")
        a1.legend(fontsize=8)
        a2.semilogy(ks, b_k, "o-", color=COLORS["ours"])
        a2.set_xlabel("reference index k")
        a2.set_ylabel("eq. (23) bound on p_k [m]")
        a2.set_title(f"reference index (n = {n})")
        save(fig, out_dir / "sensitivity_sensor_path_and_k.png")
        metrics = [Metric(f"crb_rmse_n{n}_step{st:g}".replace(".", "p"), v, None, "m",
                          "eq. (23) for a sensor turning this many rad per sample")
                   for st, v in zip(steps, b_step)]
        pick = [0, len(ks) // 2, len(ks) - 1]
        metrics += [Metric(f"crb_rmse_n{n}_k{ks[i]}", b_k[i], None, "m", "eq. (23) bound on p_k")
                    for i in pick]
        notes = ["eq. (23) position bound vs sensor turn per sample: "
                 + ", ".join(f"{st:g} rad -> {v:.3g} m" for st, v in zip(steps, b_step)),
                 "raw-range bound vs turn: "
                 + ", ".join(f"{st:g} rad -> {v:.3g} m" for st, v in zip(steps, b_raw)),
                 "eq. (23) bound on p_k vs k: "
                 + ", ".join(f"k={k}: {v:.3g} m" for k, v in zip(ks, b_k))]
        return metrics, notes
