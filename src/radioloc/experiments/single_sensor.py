"""Paper 002: closed-form single-sensor tracking (iterative BLUE) vs Newton, EKF, OLS and the CRBs.

Headline: the RMSE of the causal track, the current position p_{n-1} estimated from the first
n samples, pooled over every n = 10..60 (the EKF's causal estimate is its filtered state).
Beside it, as labelled readings, Fig. 1's RMSE of the estimated trajectory over the window
(the fitted straight track; the EKF's RTS-smoothed track and its straight track) and of the
current position at each n (uninformed starts primary, near-truth starts as variants); Fig. 2 a
y = sin x trajectory, Newton against the closed form; Fig. 3 CPU time per track versus n
(machine-dependent, in ``timings.csv``; no claim rests on it). Targets follow eq. (1)
(synthetic) and, when the data folder is present, real pen-tip trajectories of the UCI
Character Trajectories set (the paper's UCI ASL hand trajectories are not available).

``run_block`` writes one table with a ``table`` column: ``"runs"`` rows (one per run, n and
method), ``"causal"`` rows (one per run and method: ``pos_err2`` is the squared error of
p_{n-1} averaged over the windows n = min..max of ``n_values``), ``"fig2"`` rows (the y = sin x example, drawn from the named stream ``"fig2"``) and
``"sensitivity"`` rows (the bound of eq. (23) versus the sensor path and k; deterministic).
The last two are per-experiment rows, written once by the block holding run 0 and filed
under ``run = 0``. ``"sensitivity_runs"`` rows (one per run, sensor turn ``param`` and n)
hold the closed form's errors for slower and faster sensor paths. ``summarize`` only reads
the table.
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
from radioloc.experiments.base import (Claim, Experiment, Metric, Summary, data_root, per_run,
                                      register)
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
LABELS = {"blue": "closed form (iterative BLUE)", "newton": "Newton on NLLS (OLS start)",
          "ekf": "EKF (diffuse prior)", "ols": "unweighted linear fit (MANOVA reading)"}
#: trajectory readings: the fitted straight track of each method (the EKF's from its
#: filtered state at k) and, for the EKF, the RTS-smoothed track
STRAIGHT = {"blue": "blue", "newton": "newton", "ekf": "ekf_straight", "ols": "ols"}
#: labelled variants: near-truth starts, a fixed start, the criterion-based stopping rule
VARIANTS = {"newton_fixed": "Newton from a fixed start (scene centre, at rest)",
            "newton_near_truth": "Newton from the truth + N(0, 1) (near-truth start)",
            "ekf_near_truth": "EKF with a prior centred near the truth",
            "blue_criterion_stop": "closed form, criterion-based stopping rule"}
#: Newton variants and their start names
NEWTONS = {"newton": "ols", "newton_fixed": "fixed", "newton_near_truth": "near_truth"}
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
    n_values: numbers of samples of Fig. 1 / Fig. 3 (the first n samples of each track);
        the causal track (headline) takes every n from min to max of these.
    reference_index*: k = n-1 (the current position is estimated).
    sensor_radius_m, sensor_step_rad*: the sensor circles the origin at this radius, turning
        ``sensor_step_rad`` per sample (a path that is not quadratic in n; see docs/p002.md
        for how the step size changes the bound and the error).
    target_box_m*, target_speed_std*: initial target position uniform in the box
        [-b, b]^2, initial velocity N(0, std^2) per axis.
    Starts (primary: uninformed): Newton starts from the OLS solution of step 3a (variants:
        the fixed ``newton_fixed_start`` and, labelled near-truth, the true
        ``[x_k, y_k, vx_k, vy_k]`` plus N(0, ``newton_start_std``^2)); the EKF prior at
        sample 0 is diffuse, mean ``ekf_prior_mean``, std ``ekf_prior_std`` per component
        (variant: the true state plus N(0, std^2), covariance std^2 I).
    divergence_m*: a Newton run diverged when it did not meet the stopping rule or its
        position error at k exceeds this (the sensor circle's radius).
    tol, max_iter: section 5.2's stopping rule |beta_{m+1} - beta_m|^2 <= tol for BLUE and
        Newton (the trackers take the step norm, sqrt(tol)); the BLUE stops on this rule
        alone (variant: also when the GLS criterion stops decreasing).
    use_uniform_moments*: if True the BLUE uses the exact uniform-noise kurtosis (-1.2);
        False (default) uses the Gaussian moments printed in eq. (11)-eq. (14).
    uci_stride, uci_scale*: real pen tracks take every 2nd 200 Hz sample, replayed at 10 Hz,
        positions (arbitrary units) times 0.025 (about 1 m extent); their accel_var is
        estimated from pooled second differences (``2 var(d2 x) / T^4``).
    fig2_samples: length of the y = sin x example of Fig. 2.
    sensitivity_n: windows whose closed-form RMSE is measured versus the sensor's turn.
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
    newton_fixed_start: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    ekf_prior_mean: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    ekf_prior_std: tuple[float, float, float, float] = (10.0, 10.0, 3.0, 3.0)
    divergence_m: float = 5.0
    tol: float = 0.1
    max_iter: int = 20
    use_uniform_moments: bool = False
    uci_stride: int = 2
    uci_scale: float = 0.025
    fig2_samples: int = 60
    sensitivity_n: tuple[int, ...] = (10, 60)


def _trackers(config, accel_var):
    """The estimators compared, configured once per source."""
    kurt = -1.2 if config.use_uniform_moments else 0.0
    step_tol = float(np.sqrt(config.tol))
    common = dict(tol=step_tol, max_iter=config.max_iter)
    std = float(np.sqrt(config.range_var))          # xi = std_m^2
    moments = dict(accel_excess_kurtosis=kurt, range_excess_kurtosis=kurt)
    return {
        "blue": ClosedFormTracker(accel_var, std_m=std, **moments, **common),
        "blue_criterion_stop": ClosedFormTracker(accel_var, std_m=std, stopping="criterion",
                                                 **moments, **common),
        "ols": ClosedFormTracker(accel_var, std_m=std, weighting="ols", **common),
        "blue_uniform_moments": ClosedFormTracker(accel_var, std_m=std, accel_excess_kurtosis=-1.2,
                                                  range_excess_kurtosis=-1.2, **common),
        "blue_printed_eq14": ClosedFormTracker(accel_var, std_m=std, printed_eq14=True, **common),
        "blue_k0": ClosedFormTracker(accel_var, std_m=std, reference_index=0, **moments, **common),
        "newton": NewtonTracker(**common),
        "ekf": RangeEKF(ConstantVelocity(accel_var), GaussianRange(std),
                        gate=None),
    }


def _rows(runs, source, n, method, pos_err2, **extra):
    base = {"table": "runs", "run": runs, "source": source, "n": n, "method": method,
            "pos_err2": pos_err2, "traj_err2": np.nan, "crb_diff_pos": np.nan,
            "crb_raw_pos": np.nan, "cpu_s_per_run": np.nan, "iterations": 0,
            "newton_converged": True, "newton_stalled": False, "diverged": False,
            "param": np.nan}
    base.update(extra)
    return pd.DataFrame(base)


def _err2(position, truth):
    return np.sum((position - truth) ** 2, axis=-1)


def _traj_err2(trajectory, truth):
    """Mean squared position error over the window's samples."""
    return np.mean(np.sum((trajectory - truth) ** 2, axis=-1), axis=-1)


def _rmse_se(err2) -> float:
    """Monte Carlo standard error of ``sqrt(mean(err2))`` over runs (delta method).

    Parameters
    ----------
    err2 : array_like
        Squared errors, one per run.

    Returns
    -------
    float
        ``std(err2) / sqrt(N) / (2 sqrt(mean(err2)))``.
    """
    e = np.asarray(err2, float)
    if e.size < 2:
        return float("nan")
    return float(e.std(ddof=1) / np.sqrt(e.size) / (2.0 * np.sqrt(e.mean())))


def _methods_on(tracks, config, rng, accel_var, source, runs):
    """All methods on tracks (R, N, 4) ``[x, y, vx, vy]`` for every n; tidy frames.

    Every method reports the error of p_k (k = n-1) and of its trajectory over the window:
    the closed forms and Newton their fitted straight track, the EKF its Rauch-Tung-Striebel
    smoothed track over the same n samples (the filtered and smoothed p_k coincide) and,
    as ``ekf_straight``, the straight track ``p_k + (j-k) T v_k`` of its filtered state.
    The causal track of BLUE, OLS, Newton and the EKF (filtered state) is in ``"causal"``
    rows (:func:`_causal_rows`).
    """
    T, std = config.sample_period_s, float(np.sqrt(config.range_var))
    n_max = tracks.shape[1]
    sensor_all = circular_sensor_path(n_max, config.sensor_radius_m, config.sensor_step_rad)
    meas = noisy_ranges(tracks[..., :2], sensor_all, std_m=std, rng=rng)
    start_noise = rng.normal(0.0, config.newton_start_std, size=(runs.size, 4))
    prior_noise = rng.normal(0.0, config.newton_start_std, size=(runs.size, 4))
    est = _trackers(config, accel_var)
    priors = {"ekf": (np.broadcast_to(np.asarray(config.ekf_prior_mean, float), (runs.size, 4)),
                      np.diag(np.square(config.ekf_prior_std))),
              "ekf_near_truth": (tracks[:, 0] + prior_noise,
                                 config.newton_start_std**2 * np.eye(4))}
    # one filtered pass over the whole track: its state at k is the EKF's estimate from
    # the first k+1 samples (the causal estimate and the last sample of each smoothed window)
    filtered = est["ekf"].run(meas[..., None], time=np.arange(n_max) * T,
                              prior_mean=priors["ekf"][0], prior_cov=priors["ekf"][1],
                              anchor_path=sensor_all[:, None, :]).diagnostics["state"]
    frames = []
    for n in config.n_values:
        if n > n_max:
            continue
        r, s, k = meas[:, :n], sensor_all[:n], n - 1
        truth = tracks[:, k]
        traj_true = tracks[:, :n, :2]
        kw = dict(sample_period_s=T, accel_var=accel_var, std_m=std, reference_index=k)
        crb_d = differenced_crb(truth, s, **kw)
        crb_r = raw_range_crb(truth, s, **kw)
        bounds = dict(crb_diff_pos=crb_d[:, 0, 0] + crb_d[:, 1, 1],
                      crb_raw_pos=crb_r[:, 0, 0] + crb_r[:, 1, 1])
        t0 = time.process_time()
        cf = est["blue"].locate(r, s, T)
        t_blue = time.process_time() - t0
        ols_state = cf.diagnostics["ols_state"]
        starts = {"ols": ols_state, "near_truth": truth + start_noise,
                  "fixed": np.broadcast_to(np.asarray(config.newton_fixed_start, float),
                                           (runs.size, 4))}
        for name in ("blue", "ols", "blue_criterion_stop", "blue_uniform_moments",
                     "blue_printed_eq14"):
            e = cf if name == "blue" else est[name].locate(r, s, T)
            extra = dict(traj_err2=_traj_err2(e.diagnostics["trajectory"], traj_true),
                         iterations=e.diagnostics["iterations"])
            if name in ("blue", "ols"):
                extra.update(bounds)
            if name == "blue":
                extra.update(cpu_s_per_run=t_blue / runs.size)
            frames.append(_rows(runs, source, n, name, _err2(e.position, truth[:, :2]),
                                **extra))
        for name, start in NEWTONS.items():
            t0 = time.process_time()
            nt = est["newton"].locate(r, s, T, initial_state=starts[start])
            t_newton = time.process_time() - t0
            e2 = _err2(nt.position, truth[:, :2])
            conv = nt.diagnostics["converged"]
            extra = dict(traj_err2=_traj_err2(nt.diagnostics["trajectory"], traj_true),
                         iterations=nt.diagnostics["iterations"], newton_converged=conv,
                         newton_stalled=nt.diagnostics["stalled"],
                         diverged=~conv | (np.sqrt(e2) > config.divergence_m))
            if name == "newton":
                extra.update(bounds, cpu_s_per_run=t_newton / runs.size)
            frames.append(_rows(runs, source, n, name, e2, **extra))
        for name, (mean, cov) in priors.items():
            # a smoothed pass over the window: its last sample is the filtered p_k
            tr = est["ekf"].run(r[..., None], time=np.arange(n) * T, prior_mean=mean,
                                prior_cov=cov, anchor_path=s[:, None, :], smooth=True)
            extra = dict(bounds) if name == "ekf" else {}
            frames.append(_rows(runs, source, n, name, _err2(tr.position[:, k], truth[:, :2]),
                                traj_err2=_traj_err2(tr.position, traj_true), **extra))
        frames.append(_rows(runs, source, n, "ekf_straight",
                            _err2(filtered[:, k, :2], truth[:, :2]),
                            traj_err2=_traj_err2(_straight(filtered[:, k], n, k, T), traj_true)))
        # variant: fixed reference k = 0 (the setting of Lemma 1: same beta, more samples)
        fixed = est["blue_k0"].locate(r, s, T)
        frames.append(_rows(runs, source, n, "blue_k0",
                            _err2(fixed.position, tracks[:, 0, :2]),
                            traj_err2=_traj_err2(fixed.diagnostics["trajectory"], traj_true),
                            iterations=fixed.diagnostics["iterations"]))
    frames += _causal_rows(tracks, meas, sensor_all, filtered, est, config, source, runs)
    return frames


def _straight(state, n, k, T):
    """The straight track ``p_k + (j-k) T v_k``, j = 0..n-1, of states (..., 4): (..., n, 2)."""
    lag = (np.arange(n) - k) * T
    return state[..., None, :2] + lag[:, None] * state[..., None, 2:]


def _causal_rows(tracks, meas, sensor_all, filtered, est, config, source, runs):
    """The causal track (headline): p_{n-1} from the first n samples, for every n from min
    to max of ``n_values``; one ``"causal"`` row per run and method whose ``pos_err2`` is
    the squared error averaged over these windows (the EKF's estimate is its filtered
    state ``filtered`` (R, N, 4); Newton starts from each window's OLS solution)."""
    T = config.sample_period_s
    n_lo, n_hi = min(config.n_values), min(max(config.n_values), tracks.shape[1])
    windows = range(n_lo, n_hi + 1)
    total = {m: np.zeros(runs.size) for m in METHODS}
    for n in windows:
        r, s, k = meas[:, :n], sensor_all[:n], n - 1
        truth = tracks[:, k, :2]
        cf = est["blue"].locate(r, s, T)
        total["blue"] += _err2(cf.position, truth)
        total["ols"] += _err2(est["ols"].locate(r, s, T).position, truth)
        nt = est["newton"].locate(r, s, T, initial_state=cf.diagnostics["ols_state"])
        total["newton"] += _err2(nt.position, truth)
        total["ekf"] += _err2(filtered[:, k, :2], truth)
    frames = []
    for m in METHODS:
        frame = _rows(runs, source, n_hi, m, total[m] / len(windows), param=float(n_lo))
        frame["table"] = "causal"
        frames.append(frame)
    return frames


def _sensitivity_runs(tracks, config, rng, runs):
    """Closed-form error versus the sensor's turn per sample (k = n-1), as table rows."""
    T, std = config.sample_period_s, float(np.sqrt(config.range_var))
    blue = _trackers(config, config.accel_var)["blue"]
    frames = []
    for st in SENSITIVITY_STEPS:
        for n in config.sensitivity_n:
            if n > tracks.shape[1]:
                continue
            s = circular_sensor_path(n, config.sensor_radius_m, st)
            r = noisy_ranges(tracks[:, :n, :2], s, std_m=std, rng=rng)
            cf = blue.locate(r, s, T)
            frame = _rows(runs, "synthetic", n, "blue", _err2(cf.position, tracks[:, n - 1, :2]),
                          traj_err2=_traj_err2(cf.diagnostics["trajectory"], tracks[:, :n, :2]),
                          param=st)
            frame["table"] = "sensitivity_runs"
            frames.append(frame)
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
    Newton started from the first window's OLS solution and then warm-started from its
    previous estimate moved on by one sample, and Newton cold-started at the origin with
    zero velocity. ``rng`` draws the range noise.
    """
    T, N = config.sample_period_s, config.fig2_samples
    pos = sine_positions(N)
    sensor = circular_sensor_path(N, config.sensor_radius_m, config.sensor_step_rad)
    std = float(np.sqrt(config.range_var))
    r = noisy_ranges(pos, sensor, std_m=std, rng=rng)
    accel_var = accel_var_from_positions(pos, T) + config.accel_var
    step_tol = float(np.sqrt(config.tol))
    blue = ClosedFormTracker(accel_var, std_m=std, tol=step_tol)
    newton = NewtonTracker(tol=step_tol, max_iter=config.max_iter)
    start = blue.locate(r[:10], sensor[:10], T).diagnostics["ols_state"]
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
    kw = dict(sample_period_s=T, accel_var=config.accel_var,
              std_m=float(np.sqrt(config.range_var)))
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


#: columns of the per-n table: (method, label); the trajectory is the straight track except
#: where the label says otherwise
BY_N_COLUMNS = (("blue", "BLUE"), ("ekf", "EKF (diffuse; trajectory RTS-smoothed)"),
                ("ekf_straight", "EKF straight track (filtered state)"),
                ("newton", "Newton (OLS start)"), ("ols", "OLS"),
                ("newton_fixed", "Newton (fixed start)"),
                ("newton_near_truth", "Newton (near truth)"))
#: first-line marker of the per-n table note
BY_N = "RMSE by n"


def _by_n_table(rows: pd.DataFrame, source: str) -> str:
    """The per-n table (Markdown) of one source: per method, the trajectory RMSE and the
    p_k RMSE (k = n-1, the causal track at that n), each with its 95 % interval over runs.

    Parameters
    ----------
    rows : pandas.DataFrame
        The ``runs`` rows of one source (columns ``method, n, run, traj_err2, pos_err2``).
    source : str
        Its name (first line of the note).

    Returns
    -------
    str
        A note: a title line holding :data:`BY_N`, then the table.
    """
    def cell(g, col):
        m = Metric.over_runs("", per_run(g, col), stat="rms") if len(g) else None
        if m is None or not np.isfinite(m.value):
            return "-"
        return f"{m.value:.3f} [{m.ci[0]:.3f}, {m.ci[1]:.3f}]"

    cols = [(m, label) for m, label in BY_N_COLUMNS if m in set(rows["method"])]
    lines = [f"({source}) {BY_N} (each cell: trajectory RMSE / p_k RMSE [m], 95 % CI over "
             "runs; the p_k column is the causal track at that n):", "",
             "| n | " + " | ".join(label for _, label in cols) + " |",
             "|---" * (len(cols) + 1) + "|"]
    for n, g in rows.groupby("n"):
        cells = []
        for m, _ in cols:
            gm = g[g["method"] == m]
            traj = cell(gm, "traj_err2")
            cells.append(traj if m == "ekf_straight" else f"{traj} / {cell(gm, 'pos_err2')}")
        lines.append(f"| {int(n)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def docs_snippet(record: dict) -> str:
    """``docs/generated/p002-single-sensor.md``: the generic snippet of the run's metrics and
    claims, then the per-n tables of its notes.

    Parameters
    ----------
    record : dict
        The parsed ``summary.json`` of a ``p002-single-sensor`` run.

    Returns
    -------
    str
        Markdown.
    """
    from radioloc.report.snippet import docs_snippet as metrics_and_claims

    tables = [n for n in record.get("notes", []) if BY_N in n.splitlines()[0]]
    return metrics_and_claims(record) + "".join(f"\n{t}\n" for t in tables)


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
        frames += _sensitivity_runs(tracks, config, rng, runs)
        if runs[0] == 0:        # per-experiment rows, written once (by the block of run 0)
            frames.append(_fig2_rows(config, stream(rng, "fig2")))
            frames.append(_sensitivity_rows(config))
        return pd.concat(frames, ignore_index=True)

    def summarize(self, config: SingleSensorConfig, results: pd.DataFrame,
                  out_dir: Path) -> Summary:
        metrics, claims, notes = [], [], []
        table = results["table"] if "table" in results else pd.Series("runs", results.index)
        runs_rows = results[table == "runs"]
        causal_rows = results[table == "causal"]
        for source, sub in runs_rows.groupby("source"):
            g = sub.groupby(["method", "n"])
            rmse = np.sqrt(g["pos_err2"].mean()).unstack("method")
            traj = np.sqrt(g["traj_err2"].mean()).unstack("method")
            crb_d = np.sqrt(sub[sub.method == "blue"].groupby("n")["crb_diff_pos"].mean())
            crb_r = np.sqrt(sub[sub.method == "blue"].groupby("n")["crb_raw_pos"].mean())
            tag = "" if source == "synthetic" else "_uci"
            n_top, n_low = max(rmse.index), min(rmse.index)
            se_note = ("Monte Carlo standard error of the RMSE over runs (delta method: s.e. "
                       "of the mean square / 2 RMSE)")
            cz = causal_rows[causal_rows.source == source]
            causal = {m: float(np.sqrt(cz.loc[cz.method == m, "pos_err2"].mean()))
                      for m in METHODS}
            window = f"n = {n_low}..{int(cz['n'].max())}" if len(cz) else ""
            top = sub[sub.n == n_top]

            def rms(name, rows, col, note):
                return Metric.over_runs(name, per_run(rows, col), None, "m", note, stat="rms")

            for m in METHODS:
                metrics.append(rms(f"causal_rmse_{m}{tag}", cz[cz.method == m], "pos_err2",
                                      f"{LABELS[m]}: headline, RMSE of the causal track "
                                      f"(p_(n-1) from the first n samples, {window}"
                                      + ("; the filtered state)" if m == "ekf" else ")")))
                metrics.append(Metric(f"causal_rmse_{m}{tag}_se",
                                      _rmse_se(cz.loc[cz.method == m, "pos_err2"]), None, "m",
                                      se_note))
            for m in METHODS:
                what = ("reading: RTS-smoothed track over the n samples" if m == "ekf" else
                        "reading (Fig. 1): fitted straight track over the n samples")
                metrics.append(rms(f"traj_rmse_{m}_n{n_top}{tag}", top[top.method == m],
                                   "traj_err2", f"{LABELS[m]}: {what}"))
            metrics.append(rms(f"traj_rmse_ekf_straight_n{n_top}{tag}",
                               top[top.method == "ekf_straight"], "traj_err2",
                               f"{LABELS['ekf']}: reading: straight track p_k + (j-k) T v_k "
                               "of the filtered state at k (beside the closed form's)"))
            for m in METHODS:
                metrics.append(rms(f"rmse_{m}_n{n_top}{tag}", top[top.method == m], "pos_err2",
                                   f"{LABELS[m]}: reading: current position p_k, k = n-1, "
                                   f"at n = {n_top} only"))
            for m in (*METHODS, "ekf_straight"):
                cols = (("traj_err2", "traj_rmse"),) + (() if m == "ekf_straight" else
                                                        (("pos_err2", "rmse"),))
                for col, name in cols:
                    metrics.append(Metric(f"{name}_{m}_n{n_top}{tag}_se",
                                          _rmse_se(top.loc[top.method == m, col]), None, "m",
                                          se_note))
            blue_top = top[top.method == "blue"]
            metrics.append(rms(f"crb_rmse_n{n_top}{tag}", blue_top, "crb_diff_pos",
                               "eq. (23), differenced model, sqrt(mean trace position block) "
                               "over the runs' tracks"))
            metrics.append(rms(f"crb_raw_rmse_n{n_top}{tag}", blue_top, "crb_raw_pos",
                               "raw-range CRB (Gaussian approximation)"))
            for m, what in VARIANTS.items():
                metrics.append(rms(f"traj_rmse_{m}_n{n_top}{tag}", top[top.method == m],
                                   "traj_err2", f"variant, {what}: trajectory RMSE"))
                metrics.append(rms(f"rmse_{m}_n{n_top}{tag}", top[top.method == m], "pos_err2",
                                   f"variant, {what}: p_k RMSE"))
            for m in NEWTONS:
                for n in (n_low, n_top):
                    nt = sub[(sub.method == m) & (sub.n == n)]
                    metric = Metric.over_runs(
                        f"{m}_diverged_frac_n{n}{tag}",
                        per_run(nt.assign(d=nt["diverged"].astype(float)), "d"), None, "",
                        f"{VARIANTS.get(m, LABELS.get(m))}: runs not meeting the stopping rule "
                        f"or ending > {config.divergence_m:g} m from p_k")
                    metric.predicted = ("Sect. I: Newton's method may diverge (start outside "
                                        "the convergence region, near-singular Hessian)")
                    metrics.append(metric)
            newton_top = sub[(sub.method == "newton") & (sub.n == n_top)]
            metrics.append(Metric.over_runs(
                f"newton_converged_frac_n{n_top}{tag}",
                per_run(newton_top.assign(c=newton_top["newton_converged"].astype(float)), "c"),
                None, "", "Newton (OLS start) runs meeting the stopping rule"))
            if "cpu_s_per_run" in sub and sub["cpu_s_per_run"].notna().any():
                # Fig. 3 only: CPU times are machine-dependent, decide no metric or claim
                # (timings.csv; the comparison is benchmarks/bench_closed_form.py)
                self._fig3(g["cpu_s_per_run"].mean().unstack("method"), source, out_dir)
            for name, what in (("blue_uniform_moments", "BLUE with exact uniform-noise moments"),
                               ("blue_printed_eq14", "BLUE with eq. (14)'s printed off-diagonal "
                                                     "channel terms")):
                metrics.append(rms(f"rmse_{name}_n{n_top}{tag}", top[top.method == name],
                                   "pos_err2", f"reading: {what}"))
            metrics.append(rms(f"rmse_blue_k0_n{n_top}{tag}", top[top.method == "blue_k0"],
                               "pos_err2", "variant: closed form estimating p_0 (fixed k = 0)"))
            best_causal = min(causal, key=causal.get)
            straight = pd.Series({m: traj.loc[n_top, STRAIGHT[m]] for m in METHODS})
            best_straight = straight.idxmin()
            best_traj = traj.loc[n_top, list(METHODS)].idxmin()
            best = rmse.loc[n_top, list(METHODS)].idxmin()
            def sq(m, n, col):
                """Per run: squared error ``col`` of method ``m`` at ``n`` samples."""
                return sub[(sub.method == m) & (sub.n == n)].set_index("run")[col]

            def causal_sq(m):
                """Per run: mean squared error of method ``m``'s causal track."""
                return cz[cz.method == m].set_index("run")["pos_err2"]

            def lowest(col, name=lambda m: m):
                return [Claim.lower("", sq("blue", n_top, col), sq(name(m), n_top, col), unit="m^2")
                        for m in METHODS if m != "blue"]

            def decreasing(m, col):
                ns = sorted(rmse.index)
                return [Claim.lower("", sq(m, b, col), sq(m, a, col), unit="m^2")
                        for a, b in zip(ns, ns[1:])]

            ratio = ", ".join(f"{m} {causal[m]:.3g} m" for m in METHODS)
            claims.append(Claim.all_of(
                f"({source}) the closed form has the lowest causal-track RMSE of the four methods "
                f"(headline: p_(n-1) from the first n samples, {window}; {ratio}; uninformed "
                "starts; squared errors paired over runs)",
                [Claim.lower("", causal_sq("blue"), causal_sq(m), unit="m^2")
                 for m in METHODS if m != "blue"]))
            claims.append(Claim.all_of(
                f"({source}) reading, straight tracks at n = {n_top} (the EKF's from its filtered "
                f"state): the closed form has the lowest trajectory RMSE of the four (best: "
                f"{best_straight})", lowest("traj_err2", lambda m: STRAIGHT[m])))
            claims.append(Claim.all_of(
                f"({source}) reading, Fig. 1 trajectories at n = {n_top} (EKF RTS-smoothed): the "
                f"closed form has the lowest trajectory RMSE of the four (best: {best_traj})",
                lowest("traj_err2")))
            claims.append(Claim.all_of(
                f"({source}) reading, p_k (k = n-1) at n = {n_top} only: the closed form has the "
                f"lowest RMSE of the four (best: {best})", lowest("pos_err2")))
            if len(rmse.index) > 1:              # a trend needs two values of n
                claims.append(Claim.all_of(f"({source}) the closed-form causal error (p_k, "
                                           "k = n-1) decreases with n",
                                           decreasing("blue", "pos_err2")))
                claims.append(Claim.all_of(f"({source}) reading, straight track: the closed-form "
                                           "trajectory RMSE decreases with n",
                                           decreasing("blue", "traj_err2")))
                claims.append(Claim.all_of(f"({source}) variant, fixed k = 0 as in Lemma 1: the "
                                           "closed-form RMSE of p_0 decreases with n",
                                           decreasing("blue_k0", "pos_err2")))
            notes.append(f"({source}) causal-track RMSE ({window}, headline): "
                         + ", ".join(f"{m} {causal[m]:.4f} m" for m in METHODS))
            notes.append(_by_n_table(sub, source))
            self._fig1(rmse, traj, crb_d, crb_r, config, source, out_dir)
        if "uci-pen" not in set(runs_rows["source"]):
            notes.append("real-data part skipped: folder uci-character-trajectories is absent "
                         f"under {data_root()} (set RADIOLOC_DATA); synthetic part only")
        fig2 = results[table == "fig2"]
        if len(fig2):
            claims.append(self._fig2(fig2, out_dir))
        sens = results[table == "sensitivity"]
        if len(sens):
            m_extra, n_extra = self._sensitivity(sens, results[table == "sensitivity_runs"],
                                                 config, out_dir)
            metrics += m_extra
            notes += n_extra
        return Summary(metrics, claims, notes)

    # ---- figures ----------------------------------------------------------------------
    def _fig1(self, rmse, traj, crb_d, crb_r, config, source, out_dir):
        fig, (a1, a2) = figure(1, 2, width=11.0)
        colors = {"blue": COLORS["ours"], "newton": "C1", "ekf": "C2", "ols": "C4"}
        markers = {"blue": "o", "newton": "s", "ekf": "^", "ols": "v"}
        for m in METHODS:
            a1.semilogy(traj.index, traj[m], marker=markers[m], color=colors[m], label=LABELS[m])
            a2.semilogy(rmse.index, rmse[m], marker=markers[m], color=colors[m], label=LABELS[m])
        a1.semilogy(traj.index, traj["ekf_straight"], "^--", mfc="none", color="C2",
                    label="reading: EKF straight track (filtered state)")
        a1.semilogy(traj.index, traj["newton_near_truth"], "s:", mfc="none", color="C1",
                    label="variant: Newton, near-truth start")
        a2.semilogy(rmse.index, rmse["ekf_near_truth"], "^:", mfc="none", color="C2",
                    label="variant: EKF, near-truth prior")
        a2.semilogy(rmse.index, rmse["blue_k0"], "o--", mfc="none", color=COLORS["ours"],
                    label="variant: closed form for p_0 (fixed k = 0)")
        a2.semilogy(crb_d.index, crb_d, LINESTYLES["bound"], color=COLORS["bound"],
                    label="CRB eq. (23), differenced")
        a2.semilogy(crb_r.index, crb_r, "--", color="k", label="CRB of raw ranges")
        a1.set_xlabel("number of samples n")
        a1.set_ylabel("trajectory RMSE [m] (all n samples)")
        a1.set_title(f"Fig. 1 ({source}): trajectory readings, {config.runs} runs")
        a2.set_xlabel("number of samples n")
        a2.set_ylabel("position RMSE of p_k [m] (k = n-1 unless noted)")
        a2.set_title("causal track: current position p_k by n (headline pools n)")
        a1.legend(fontsize=7)
        a2.legend(fontsize=7)
        save(fig, out_dir / f"fig1_rmse_vs_n_{source}.png", caption=(
            "Fig. 1 of paper 002: comparison of the estimation accuracy of the closed form "
            "(iterative BLUE) and traditional methods (Newton, EKF, the unweighted linear fit "
            f"read as MANOVA) for a noisy RSS channel, {source} trajectories: RMSE over the "
            "whole trajectory (left) and of the current position p_k (right, with the "
            "differenced CRB of eq. (23) and the raw-range CRB) against the number of "
            "samples n."))

    def _fig3(self, cpu, source, out_dir):
        fig, ax = figure()
        ax.plot(cpu.index, 1e3 * cpu["blue"], "o-", color=COLORS["ours"],
                label="closed form (iterative BLUE)")
        ax.plot(cpu.index, 1e3 * cpu["newton"], "s-", color="C1", label="Newton on NLLS")
        ax.set_xlabel("number of positions n")
        ax.set_ylabel("CPU time per track [ms] (batched)")
        ax.set_title(f"Fig. 3 ({source}, machine-dependent): same stopping rule |step|^2 <= 0.1")
        ax.legend()
        save(fig, out_dir / f"fig3_cpu_vs_n_{source}.png", caption=(
            "Fig. 3 of paper 002: comparison of the computation time of the closed form and "
            f"Newton's method for a noisy RSS channel, {source} trajectories: CPU time per "
            "track (batched, this machine) against the number of positions n, with the same "
            "stopping rule |step|^2 <= 0.1."))

    def _fig2(self, fig2, out_dir):
        """Plot the y = sin x rows and judge the cold-start claim on them (points off the
        axes are clipped: a diverged run)."""
        by = {m: d.sort_values("n") for m, d in fig2.groupby("method")}
        truth = by["blue"][["x_true", "y_true"]].to_numpy()
        x_all = np.linspace(0.0, 2 * np.pi, 200)
        fig, ax = figure()
        ax.plot(x_all, np.sin(x_all), "k-", label="true y = sin x")
        style = {"blue": ("o", 3, COLORS["ours"], "closed form"),
                 "newton_warm": ("s", 3, "C1", "Newton (OLS start, then warm)"),
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
        save(fig, out_dir / "fig2_sine_trajectory.png", caption=(
            "Fig. 2 of paper 002: comparison of the estimation accuracy of the closed form and "
            "Newton's method for a noisy RSS channel, qualitatively: current-position "
            "estimates along the true trajectory y = sin x, Newton warm-started and "
            "cold-started at the origin (points off the axes: diverged)."))
        err = {m: np.linalg.norm(by[m][["x_hat", "y_hat"]].to_numpy() - truth, axis=-1)
               for m in ("blue", "newton_cold")}
        return Claim("(Fig. 2, y = sin x) Newton from a start at the origin fails (max error > 3x "
                     f"the closed form's): max errors {np.max(err['newton_cold']):.3g} m vs "
                     f"{np.max(err['blue']):.3g} m",
                     bool(np.max(err["newton_cold"]) > 3 * np.max(err["blue"])))

    def _sensitivity(self, sens, sens_runs, config, out_dir):
        """Plot and report the sensitivity rows (eq. (23) and the closed form's RMSE versus
        the sensor's turn per sample; eq. (23) versus k)."""
        n = int(sens["n"].iloc[0])
        by_step = sens[sens.method == "step"].sort_values("param")
        by_k = sens[sens.method == "k"].sort_values("param")
        steps = by_step["param"].to_numpy()
        b_step = np.sqrt(by_step["crb_diff_pos"].to_numpy())
        b_raw = np.sqrt(by_step["crb_raw_pos"].to_numpy())
        ks = by_k["param"].to_numpy().astype(int)
        b_k = np.sqrt(by_k["crb_diff_pos"].to_numpy())
        emp = (np.sqrt(sens_runs.groupby(["n", "param"])[["pos_err2", "traj_err2"]].mean())
               if len(sens_runs) else None)
        fig, (a1, a2) = figure(1, 2, width=9.0)
        a1.loglog(steps, b_step, "o-", color=COLORS["bound"], label=f"CRB eq. (23), n = {n}")
        a1.loglog(steps, b_raw, "s:", color="k", label=f"raw-range CRB, n = {n}")
        metrics, notes = [], []
        if emp is not None:
            for (nn, sub), ls in zip(emp.groupby(level="n"), ("o-", "o--", "o-.")):
                sub = sub.droplevel("n")
                a1.loglog(sub.index, sub["pos_err2"], ls, color=COLORS["ours"],
                          label=f"closed form p_k, n = {nn}")
                a1.loglog(sub.index, sub["traj_err2"], ls, mfc="none", color="C1",
                          label=f"closed form trajectory, n = {nn}")
                rows_n = sens_runs[sens_runs["n"] == nn]
                metrics += [Metric.over_runs(
                    f"rmse_blue_n{nn}_step{st:g}".replace(".", "p"),
                    per_run(rows_n[rows_n["param"] == st], "pos_err2"), None, "m",
                    "closed form p_k (k = n-1) for a sensor turning this many rad per sample",
                    stat="rms") for st in sub.index]
                notes.append(f"closed-form p_k RMSE at n = {nn} vs sensor turn: "
                             + ", ".join(f"{st:g} rad -> {v:.3g} m"
                                         for st, v in sub["pos_err2"].items()))
                notes.append(f"closed-form trajectory RMSE at n = {nn} vs sensor turn: "
                             + ", ".join(f"{st:g} rad -> {v:.3g} m"
                                         for st, v in sub["traj_err2"].items()))
        a1.axvline(config.sensor_step_rad, color="grey", ls=":", lw=1,
                   label=f"experiment's path, {config.sensor_step_rad:g} rad")
        a1.axhline(10.0, color="grey", ls="--", lw=0.6)
        a1.set_xlabel("sensor turn per sample [rad]")
        a1.set_ylabel("position error / bound [m]")
        a1.set_title("sensor path speed (k = n-1)")
        a1.legend(fontsize=7)
        a2.semilogy(ks, b_k, "o-", color=COLORS["ours"])
        a2.axvline(ks[-1], color="grey", ls=":", lw=1)
        a2.annotate("k = n-1 (experiment)", (ks[-1], b_k[-1]), xytext=(-110, -4),
                    textcoords="offset points", fontsize=8)
        a2.set_xlabel("reference index k")
        a2.set_ylabel("eq. (23) bound on p_k [m]")
        a2.set_title(f"reference index (n = {n})")
        save(fig, out_dir / "sensitivity_sensor_path_and_k.png", caption=(
            "Sensitivity of the closed form: its position and trajectory RMSE and the bounds "
            "of eq. (23) and of the raw ranges against how far the sensor turns per sample "
            f"(left), and the eq. (23) bound on p_k against the reference index k (right, "
            f"n = {n})."))
        exact = "; exact for the figure's fixed state, so no interval"
        metrics += [Metric(f"crb_rmse_n{n}_step{st:g}".replace(".", "p"), v, None, "m",
                           "eq. (23) for a sensor turning this many rad per sample" + exact)
                    for st, v in zip(steps, b_step)]
        pick = [0, len(ks) // 2, len(ks) - 1]
        metrics += [Metric(f"crb_rmse_n{n}_k{ks[i]}", b_k[i], None, "m",
                           "eq. (23) bound on p_k" + exact) for i in pick]
        notes += ["eq. (23) position bound vs sensor turn per sample: "
                  + ", ".join(f"{st:g} rad -> {v:.3g} m" for st, v in zip(steps, b_step)),
                  "raw-range bound vs turn: "
                  + ", ".join(f"{st:g} rad -> {v:.3g} m" for st, v in zip(steps, b_raw)),
                  "eq. (23) bound on p_k vs k: "
                  + ", ".join(f"k={k}: {v:.3g} m" for k, v in zip(ks, b_k))]
        return metrics, notes


if __name__ == "__main__":            # python -m radioloc.experiments.single_sensor SUMMARY OUT_MD
    import sys

    from radioloc.report.snippet import write_docs_snippet

    write_docs_snippet(sys.argv[1], sys.argv[2], docs_snippet)
