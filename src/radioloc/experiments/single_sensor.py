"""Paper 002: closed-form single-sensor tracking (iterative BLUE) against Newton, EKF, OLS and the CRBs.

Fig. 1 RMSE of the current position versus the number of samples n = 10..60; Fig. 2 a
y = sin x trajectory, Newton against the closed form; Fig. 3 CPU time per track versus n,
closed form against Newton at the same stopping rule. Targets follow the constant-acceleration
model (synthetic) and, when the data folder is present, real pen-tip trajectories of the UCI
Character Trajectories set (the paper's UCI ASL hand trajectories are not available).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.bounds.single_sensor import differenced_crb, raw_range_crb
from radioloc.core.errors import DataUnavailable
from radioloc.estimators.closed_form import closed_form_track, ols_track
from radioloc.estimators.nlls_newton import newton_track
from radioloc.estimators.range_ekf import range_ekf
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, data_root, register
from radioloc.io.uci_characters import resampled_tracks
from radioloc.models.track_noise import ConstantAcceleration
from radioloc.report.style import COLORS, LINESTYLES, figure, save

METHODS = ("blue", "newton", "ekf", "ols")
LABELS = {"blue": "closed form (iterative BLUE)", "newton": "Newton on NLLS",
          "ekf": "EKF", "ols": "unweighted linear fit (MANOVA reading)"}


@dataclass(frozen=True)
class SingleSensorConfig:
    """Settings of ``p002-single-sensor`` (choices the paper leaves open are marked *).

    sample_period_s: 10 Hz (section 5).
    accel_var, range_var: reading of "uniform ... with the variance 0.1, 0.15 respectively"
        (listed as "the channel noise and the dynamic motion noise"): channel noise variance
        ``xi = 0.1`` m^2 and acceleration variance ``delta_g^2 = 0.15`` (m/s^2)^2 on both axes,
        both zero-mean uniform.
    n_values: numbers of samples of Fig. 1 / Fig. 3 (the first n samples of each track).
    reference_index*: "last" = k = n-1 (the current position is estimated).
    sensor_radius_m, sensor_step_rad*: the sensor circles the origin at this radius, turning
        ``sensor_step_rad`` per sample (a path that is not quadratic in n; see docs/p002.md
        for how the step size changes the bound).
    target_box_m*, target_speed_std*: initial target position uniform in the box
        [-b, b]^2, initial velocity N(0, std^2) per axis.
    newton_start_std*: Newton starts from the true [Y_k, X_k, V_y, V_x] plus N(0, std^2) per
        component; the EKF prior at sample 0 is the true state plus N(0, std^2), covariance
        std^2 I.
    tol, max_iter: stopping rule |beta_{m+1} - beta_m|^2 <= 0.1 for BLUE and Newton (5.2).
    use_uniform_moments*: if True the BLUE uses the exact uniform-noise kurtosis (-1.2);
        False (default) uses the Gaussian moments printed in eqs. (11)-(14).
    uci_stride, uci_scale*: real pen tracks take every 2nd 200 Hz sample, replayed at 10 Hz,
        positions (arbitrary units) times 0.025 (about 1 m extent); their accel_var is
        estimated from pooled second differences (``2 var(d2 x) / T^4``).
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
    fig2_seed: int = 7


def sensor_path(n: int, radius: float, step_rad: float) -> np.ndarray:
    ang = np.arange(n) * step_rad
    return radius * np.stack([np.cos(ang), np.sin(ang)], axis=-1)


def _uniform(rng, var, shape):
    h = np.sqrt(3.0 * var)
    return rng.uniform(-h, h, size=shape)


def _methods_on(tracks, config, rng, accel_var, source, runs):
    """All methods on tracks (R, N, 4) [x, y, vx, vy] for every n; tidy frame."""
    T, xi = config.sample_period_s, config.range_var
    n_max = tracks.shape[1]
    sensor_all = sensor_path(n_max, config.sensor_radius_m, config.sensor_step_rad)
    true_r = np.linalg.norm(tracks[..., :2] - sensor_all, axis=-1)
    meas = np.abs(true_r + _uniform(rng, xi, true_r.shape))
    start_noise = rng.normal(0.0, config.newton_start_std, size=(runs.size, 4))
    prior_noise = rng.normal(0.0, config.newton_start_std, size=(runs.size, 4))
    kurt = -1.2 if config.use_uniform_moments else 0.0
    frames = []
    for n in config.n_values:
        if n > n_max:
            continue
        r, s, k = meas[:, :n], sensor_all[:n], n - 1
        truth = tracks[:, k][:, [1, 0, 3, 2]]                      # [Y, X, Vy, Vx]
        common = dict(sample_period_s=T, reference_index=k)
        t0 = time.process_time()
        cf = closed_form_track(r, s, accel_var=accel_var, range_var=xi, tol=config.tol,
                               max_iter=config.max_iter, accel_excess_kurtosis=kurt,
                               range_excess_kurtosis=kurt, **common)
        t_blue = time.process_time() - t0
        t0 = time.process_time()
        nt = newton_track(r, s, truth + start_noise, tol=config.tol,
                          max_iter=config.max_iter, **common)
        t_newton = time.process_time() - t0
        ols = ols_track(r, s, accel_var=accel_var, range_var=xi, **common)
        ekf = range_ekf(r, s, tracks[:, 0] + prior_noise,
                        config.newton_start_std**2 * np.eye(4), sample_period_s=T,
                        accel_var=accel_var, range_var=xi)[:, -1][:, [1, 0, 3, 2]]
        # other readings of eqs. (11)-(14): exact uniform moments; printed eq. (14) terms
        readings = {}
        for name, extra in (("blue_uniform_moments", dict(accel_excess_kurtosis=-1.2,
                                                          range_excess_kurtosis=-1.2)),
                            ("blue_printed_eq14", dict(printed_eq14=True))):
            alt = closed_form_track(r, s, accel_var=accel_var, range_var=xi, tol=config.tol,
                                    max_iter=config.max_iter, **extra, **common)
            readings[name] = np.sum((alt.state[:, :2] - truth[:, :2]) ** 2, axis=-1)
        for name, err in readings.items():
            frames.append(pd.DataFrame({"run": runs, "source": source, "n": n, "method": name,
                                        "pos_err2": err, "traj_err2": np.nan,
                                        "crb_diff_pos": np.nan, "crb_raw_pos": np.nan,
                                        "cpu_s_per_run": np.nan, "iterations": 0,
                                        "newton_converged": True}))
        # variant: fixed reference k = 0 (the setting of Lemma 1: same beta, more samples)
        fixed = closed_form_track(r, s, sample_period_s=T, reference_index=0,
                                  accel_var=accel_var, range_var=xi, tol=config.tol,
                                  max_iter=config.max_iter, accel_excess_kurtosis=kurt,
                                  range_excess_kurtosis=kurt)
        err_fixed = np.sum((fixed.state[:, [1, 0]] - tracks[:, 0, :2]) ** 2, axis=-1)
        frames.append(pd.DataFrame({"run": runs, "source": source, "n": n, "method": "blue_k0",
                                    "pos_err2": err_fixed, "traj_err2": np.nan,
                                    "crb_diff_pos": np.nan, "crb_raw_pos": np.nan,
                                    "cpu_s_per_run": np.nan, "iterations": fixed.iterations,
                                    "newton_converged": True}))
        crb_d = differenced_crb(truth, s, accel_var=accel_var, range_var=xi, **common)
        crb_r = raw_range_crb(truth, s, accel_var=accel_var, range_var=xi, **common)
        est = {"blue": cf.state, "newton": nt.state, "ekf": ekf, "ols": ols}
        traj_true = tracks[:, :n, :2]
        traj = {"blue": cf.trajectory, "newton": nt.trajectory, "ols": None, "ekf": None}
        for m in METHODS:
            err2 = np.sum((est[m][:, :2] - truth[:, :2]) ** 2, axis=-1)
            tr = traj[m]
            frames.append(pd.DataFrame({
                "run": runs, "source": source, "n": n, "method": m,
                "pos_err2": err2,
                "traj_err2": (np.nan if tr is None else
                              np.mean(np.sum((tr - traj_true) ** 2, axis=-1), axis=-1)),
                "crb_diff_pos": crb_d[:, 0, 0] + crb_d[:, 1, 1],
                "crb_raw_pos": crb_r[:, 0, 0] + crb_r[:, 1, 1],
                "cpu_s_per_run": {"blue": t_blue, "newton": t_newton}.get(m, np.nan) / runs.size,
                "iterations": {"blue": cf.iterations, "newton": nt.iterations}.get(m, 0),
                "newton_converged": nt.converged if m == "newton" else True,
            }))
    return frames


def _uci_tracks(config):
    folder = data_root() / "uci-character-trajectories"
    pos = resampled_tracks(folder, max(config.n_values), config.uci_stride, config.uci_scale)
    T = config.sample_period_s
    vel = np.gradient(pos, T, axis=1)
    d2 = np.diff(pos, n=2, axis=1)
    accel_var = float(2.0 * np.var(d2) / T**4)
    return np.concatenate([pos, vel], axis=-1), accel_var


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
        b, v = config.target_box_m, config.target_speed_std
        x0 = np.concatenate([rng.uniform(-b, b, (runs.size, 2)),
                             rng.normal(0.0, v, (runs.size, 2))], axis=-1)
        motion = ConstantAcceleration(config.sample_period_s, config.accel_var, "uniform")
        tracks = motion.sample(x0, n_max, rng)
        frames = _methods_on(tracks, config, rng, config.accel_var, "synthetic", runs)
        try:
            uci, uci_var = _uci_tracks(config)
        except DataUnavailable:
            uci = None
        if uci is not None:
            pick = uci[rng.integers(0, uci.shape[0], runs.size)]
            shift = rng.uniform(-b, b, (runs.size, 1, 2)) - pick[:, :1, :2]
            pick = pick + np.concatenate([shift, np.zeros_like(shift)], axis=-1)
            frames += _methods_on(pick, config, rng, uci_var, "uci-pen", runs)
        return pd.concat(frames, ignore_index=True)

    def summarize(self, config: SingleSensorConfig, results: pd.DataFrame,
                  out_dir: Path) -> Summary:
        metrics, claims, notes = [], [], []
        figs = {}
        for source, sub in results.groupby("source"):
            g = sub.groupby(["method", "n"])
            rmse = np.sqrt(g["pos_err2"].mean()).unstack("method")
            traj = np.sqrt(g["traj_err2"].mean()).unstack("method")
            crb_d = np.sqrt(sub[sub.method == "blue"].groupby("n")["crb_diff_pos"].mean())
            crb_r = np.sqrt(sub[sub.method == "blue"].groupby("n")["crb_raw_pos"].mean())
            cpu = g["cpu_s_per_run"].mean().unstack("method")
            figs[source] = (rmse, crb_d, crb_r)
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
            conv = sub[(sub.method == "newton") & (sub.n == n_top)]["newton_converged"].mean()
            metrics.append(Metric(f"newton_converged_frac_n{n_top}{tag}", conv, None, "",
                                  "Newton runs meeting the stopping rule"))
            ratio = cpu.loc[n_top, "newton"] / cpu.loc[n_top, "blue"]
            metrics.append(Metric(f"cpu_ratio_newton_over_blue{tag}", ratio, 3.3, "",
                                  f"CPU time per track at n = {n_top}, batched over runs; "
                                  "paper: about 70% less time"))
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
            claims.append(Claim(f"({source}) the closed form takes about 70% less CPU time than "
                                "Newton (ratio >= 2)", bool(ratio >= 2.0)))
            claims.append(Claim(f"({source}) variant, fixed k = 0 as in Lemma 1: the closed-form "
                                "RMSE of p_0 decreases with n",
                                bool(np.all(np.diff(rmse["blue_k0"].to_numpy()) < 0))))
            notes.append(f"({source}) RMSE by n:\n" + rmse.round(4).to_string())
            notes.append(f"({source}) CPU s per track:\n" + cpu[["blue", "newton"]].to_string())
            self._fig1(rmse, crb_d, crb_r, config, source, out_dir)
            self._fig3(cpu, source, out_dir)
        if "uci-pen" not in set(results["source"]):
            notes.append("real-data part skipped: folder uci-character-trajectories is absent "
                         f"under {data_root()} (set RADIOLOC_DATA); synthetic part only")
        claims.append(self._fig2(config, out_dir))
        m_extra, n_extra = self._sensitivity(config, out_dir)
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
        ax.set_title(f"Fig. 3 ({source}): same stopping rule |step|^2 <= 0.1")
        ax.legend()
        save(fig, out_dir / f"fig3_cpu_vs_n_{source}.png")

    def _fig2(self, config, out_dir):
        """y = sin x target; growing windows 10..N; Newton warm-started from its last estimate
        and Newton cold-started at the origin with zero velocity (points off the axes are
        clipped: a diverged run)."""
        rng = np.random.default_rng(config.fig2_seed)
        T, N = config.sample_period_s, config.fig2_samples
        x = np.linspace(0.0, 2 * np.pi, N)
        pos = np.stack([x, np.sin(x)], axis=-1)
        sensor = sensor_path(N, config.sensor_radius_m, config.sensor_step_rad)
        r = np.abs(np.linalg.norm(pos - sensor, axis=-1)
                   + _uniform(rng, config.range_var, N))
        vel = np.gradient(pos, T, axis=0)
        accel_var = float(np.var(np.diff(pos, 2, axis=0)) * 2 / T**4) + config.accel_var
        ours, newton, cold = [], [], []
        start = np.array([pos[9, 1], pos[9, 0], vel[9, 1], vel[9, 0]]) + rng.normal(0, 0.3, 4)
        for j in range(9, N):
            kw = dict(sample_period_s=T, reference_index=j)
            cf = closed_form_track(r[: j + 1], sensor[: j + 1], accel_var=accel_var,
                                   range_var=config.range_var, tol=config.tol, **kw)
            nt = newton_track(r[: j + 1], sensor[: j + 1], start, tol=config.tol,
                              max_iter=config.max_iter, **kw)
            nc = newton_track(r[: j + 1], sensor[: j + 1], np.zeros(4), tol=config.tol,
                              max_iter=config.max_iter, **kw)
            ours.append(cf.state)
            newton.append(nt.state)
            cold.append(nc.state)
            start = nt.state + np.array([T * nt.state[2], T * nt.state[3], 0, 0])
        ours, newton, cold = np.array(ours), np.array(newton), np.array(cold)
        fig, ax = figure()
        ax.plot(pos[:, 0], pos[:, 1], "k-", label="true y = sin x")
        ax.plot(ours[:, 1], ours[:, 0], "o", ms=3, color=COLORS["ours"], label="closed form")
        ax.plot(newton[:, 1], newton[:, 0], "s", ms=3, color="C1", label="Newton (warm start)")
        ax.plot(cold[:, 1], cold[:, 0], "x", ms=4, color="C3",
                label="Newton (cold start at origin, v = 0)")
        ax.set_xlim(-1, 7.5)
        ax.set_ylim(-3, 3)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title("Fig. 2: current-position estimates, windows of 10..60 samples")
        ax.legend(fontsize=8)
        save(fig, out_dir / "fig2_sine_trajectory.png")
        truth = pos[9:]
        err = {name: np.linalg.norm(est[:, [1, 0]] - truth, axis=-1)
               for name, est in (("ours", ours), ("cold", cold))}
        return Claim("(Fig. 2, y = sin x) Newton from a start at the origin fails (max error > 3x "
                     f"the closed form's): max errors {np.max(err['cold']):.3g} m vs "
                     f"{np.max(err['ours']):.3g} m",
                     bool(np.max(err["cold"]) > 3 * np.max(err["ours"])))

    def _sensitivity(self, config, out_dir):
        """Eq. (23) versus the sensor's turn per sample and versus the reference index k."""
        T, n = config.sample_period_s, max(config.n_values)
        state = np.array([0.5, 1.0, -0.3, 0.6])           # [Y, X, Vy, Vx] at k
        kw = dict(sample_period_s=T, accel_var=config.accel_var, range_var=config.range_var)
        steps = np.array([0.05, 0.1, 0.2, 0.4, 0.8, 1.3, 2.0, 2.6])
        by_step = []
        for st in steps:
            s = sensor_path(n, config.sensor_radius_m, st)
            c = differenced_crb(state, s, reference_index=n - 1, **kw)
            c_raw = raw_range_crb(state, s, reference_index=n - 1, **kw)
            by_step.append((np.sqrt(c[0, 0] + c[1, 1]), np.sqrt(c_raw[0, 0] + c_raw[1, 1])))
        by_step = np.array(by_step)
        ks = np.r_[np.arange(0, n - 1, 5), n - 1]
        s = sensor_path(n, config.sensor_radius_m, config.sensor_step_rad)
        by_k = np.array([np.sqrt(np.trace(differenced_crb(state, s, reference_index=int(k),
                                                          **kw)[:2, :2])) for k in ks])
        fig, (a1, a2) = figure(1, 2, width=9.0)
        a1.loglog(steps, by_step[:, 0], "o-", color=COLORS["ours"], label="CRB eq. (23)")
        a1.loglog(steps, by_step[:, 1], "s:", color="k", label="raw-range CRB")
        a1.set_xlabel("sensor turn per sample [rad]")
        a1.set_ylabel("position bound [m]")
        a1.set_title(f"sensor path speed (n = {n}, k = n-1)")
        a1.legend(fontsize=8)
        a2.semilogy(ks, by_k, "o-", color=COLORS["ours"])
        a2.set_xlabel("reference index k")
        a2.set_ylabel("eq. (23) bound on p_k [m]")
        a2.set_title(f"reference index (n = {n})")
        save(fig, out_dir / "sensitivity_sensor_path_and_k.png")
        metrics = [Metric(f"crb_rmse_n{n}_step{st:g}".replace(".", "p"), v, None, "m",
                          "eq. (23) for a sensor turning this many rad per sample")
                   for st, v in zip(steps, by_step[:, 0])]
        metrics += [Metric(f"crb_rmse_n{n}_k{k}", v, None, "m", "eq. (23) bound on p_k")
                    for k, v in zip(ks[[0, len(ks) // 2, -1]], by_k[[0, len(ks) // 2, -1]])]
        notes = ["eq. (23) position bound vs sensor turn per sample: "
                 + ", ".join(f"{st:g} rad -> {v:.3g} m" for st, v in zip(steps, by_step[:, 0])),
                 "raw-range bound vs turn: "
                 + ", ".join(f"{st:g} rad -> {v:.3g} m" for st, v in zip(steps, by_step[:, 1])),
                 "eq. (23) bound on p_k vs k: "
                 + ", ".join(f"k={k}: {v:.3g} m" for k, v in zip(ks, by_k))]
        return metrics, notes
