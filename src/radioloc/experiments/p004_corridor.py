"""Paper 004, Sects. 3.1.1 and 5: mixture signal-strength models in a corridor with a door.

Each Monte Carlo run draws its own calibration set (positions uniform along the corridor,
door open or closed with probability 1/2 per sample), builds the two per-station models by
our reading of the paper's Progressive Bayes calibration in the parameter space (Fig. 3:
one Gaussian over the parameters, updated in two linearised steps per sample, i.e.
Titterington's recursive EM; the paper progressively re-approximates a Gaussian mixture
over the parameters, which is not implemented; the kernel-insertion calibration runs beside
it as a labelled variant), then (i) a static user at 45 m takes 8
measurements (the door in one state for the whole run) and is localized by successive
measurement updates (Fig. 10), (ii) a user walks the corridor and is tracked with the
uniform-disk motion model, (iii) a user walks, pauses and walks on (tracked and located one
shot at a time). Both noise
levels of the paper (2 dB, 10 dB) are run. Per run the block also records how many modes
station 1's D(m | x) has past the door (Fig. 6, judged over runs).

An ablation tests why the disk tracker is over-confident: a walker at a third of v_max,
tracked (a) as the paper does, every update's density mixing both door states independently,
(b) with the door state shared by every update of the run (a bank of one tracker per door
state, calibrated on the samples of that state, weighted by the run's evidence), and (c)
with the door redrawn at every update in the simulation (the independence the per-update
density assumes made true).

Accuracy claims are judged per run: RMSE over runs of the posterior mean, and whether the
posterior's uncertainty is calibrated (NEES = mean of (error / std)^2, 1 if calibrated;
2-sigma coverage, 0.95 if Gaussian and calibrated).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pandas as pd

from radioloc.core.rng import stream
from radioloc.estimators.mixture_localization import (MixtureLocalizer, MixtureTracker,
                                                      posterior_mixture)
from radioloc.experiments.base import (Claim, Experiment, Metric, Summary, paired_differences,
                                       per_run, register)
from radioloc.models.mixture import DiagMixture, convolve, product, reduce, uniform_ball
from radioloc.models.mixture_calibration import parameter_calibration, progressive_calibration
from radioloc.models.motion import BoundedSpeedCV, UniformDisk
from radioloc.models.progressive_bayes import inner, isd, progressive_reduce
from radioloc.report.style import COLORS, figure, save
from radioloc.report.tables import claim_evidence, fmt, interval, verdict
from radioloc.sim.corridor import Corridor, walk_positions


@dataclass(frozen=True)
class CorridorConfig:
    """Settings of ``p004-corridor`` (choices the paper leaves open are ours).

    noise_db: measurement (and calibration) noise levels, the paper's 2 and 10 dB.
    calib_samples: calibration samples per run, x uniform on the corridor, door closed
        with probability 1/2 per sample (the paper: "calibration in both door states").
    pb_box: (x_lo, x_hi, m_lo, m_hi), the box of the uniform prior of the component means
        of the calibration in the parameter space (our reading of Fig. 3; m in dBm).
    pb_std_range: (lo, hi), the uniform prior's range of the component standard deviations
        (both axes; m and dB).
    pb_steps: Euler steps of the progression per calibration sample.
    bandwidth: kernel standard deviations (x in m, m in dB) of the kernel-insertion
        calibration (the labelled variant, run beside it on the static user).
    model_components: components of each station's model (both calibrations).
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
    slow_speed: walking speed of the door ablation (a third of v_max); its trackers use
        alt_reduction.
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
    pb_box: tuple[float, float, float, float] = (0.0, 60.0, -90.0, -30.0)
    pb_std_range: tuple[float, float] = (1.0, 30.0)
    pb_steps: int = 2
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
    slow_speed: float = 0.5
    cv_q: float = 0.1
    cv_components: int = 16


#: Name of the calibration every run uses, wherever a metric, claim or table shows it.
PB_OURS = "parameter-space calibration (our reading of Progressive Bayes, one Gaussian)"

#: grids of the figure rows
_X_GRID = np.linspace(0.0, 60.0, 301)
_M_GRID = np.linspace(-90.0, -20.0, 141)
_X_COARSE = np.linspace(0.0, 60.0, 121)
_M_COARSE = np.linspace(-90.0, -20.0, 71)


def _parameter_models(config: CorridorConfig, x: np.ndarray, rss: np.ndarray) -> DiagMixture:
    """Our reading of the paper's Progressive Bayes calibration in the parameter space
    (Fig. 3): one Gaussian over the parameters (see ``parameter_calibration``)."""
    box = np.reshape(config.pb_box, (2, 2))
    return parameter_calibration(x, rss, box, np.tile(config.pb_std_range, (2, 1)),
                                 config.model_components, config.pb_steps)


def _calibrate(config: CorridorConfig, corridor: Corridor, noise: float, n_runs: int,
               rng: np.random.Generator, variants: bool = False):
    """The station models of ``n_runs`` calibration sets (batch ``(n_runs, 2)``).

    With ``variants``, also the kernel-insertion models of the same samples and the
    door-labelled models (batch ``(2, n_runs, 2)``: door open, door closed; each from the
    samples taken in that door state)."""
    x, rss, door = corridor.calibration_set(n_runs, config.calib_samples, noise, rng,
                                            return_door=True)
    models = _parameter_models(config, x, rss)
    if not variants:
        return models
    kernel = progressive_calibration(x, rss, config.bandwidth, config.model_components)
    labelled = np.stack([np.where((door == closed)[..., None], rss, np.nan)
                         for closed in (False, True)])
    by_door = _parameter_models(config, np.broadcast_to(x, (2,) + x.shape), labelled)
    return models, kernel, by_door


def model_isd(models: DiagMixture, corridor: Corridor, noise_db: float) -> np.ndarray:
    """ISD of station models to the true calibration density, relative to ``int true^2``.

    The true density of (x, m) per station: x uniform on the corridor, the door closed
    with probability 1/2, ``m`` Gaussian about :meth:`Corridor.mean_rss` with ``noise_db``.
    ``int model^2`` is closed-form (:func:`radioloc.models.progressive_bayes.inner`); the
    integrals over ``m`` of the other two terms are closed-form too, those over ``x`` a
    trapezoid rule on 0.05 m.

    Parameters
    ----------
    models : DiagMixture
        Batch ``(..., 2)`` (the two stations), dimension 2 (x, m).
    corridor : Corridor
        The simulated corridor.
    noise_db : float
        Standard deviation of the signal strength about its mean, dB.

    Returns
    -------
    ndarray, shape (..., 2)
        ``int (model - true)^2 / int true^2``.
    """
    length = corridor.length_m
    xg = np.linspace(0.0, length, 1201)
    tw = np.full(xg.size, xg[1] - xg[0])
    tw[[0, -1]] *= 0.5
    mu = np.stack([corridor.mean_rss(xg, closed) for closed in (False, True)])   # (2, G, 2)
    mu = np.moveaxis(mu, -1, 0)                                                  # (2, 2, G)

    def gauss(d, var):
        return np.exp(-0.5 * d**2 / var) / np.sqrt(2.0 * np.pi * var)

    w, a, v = models.weights, models.means, models.variances
    nx = gauss(xg - a[..., 0, None], v[..., 0, None])                            # (..., S, K, G)
    nm = 0.5 * sum(gauss(mu[:, door][:, None, :] - a[..., 1, None], v[..., 1, None]
                         + noise_db**2) for door in range(2))
    cross = np.einsum("...k,...kg,g->...", w, nx * nm, tw) / length
    own = inner(w, a, v, w, a, v)
    true = sum(0.25 * gauss(mu[:, i] - mu[:, j], 2.0 * noise_db**2)
               for i in range(2) for j in range(2)) @ tw / length**2             # (S,)
    return (own - 2.0 * cross + true) / true


def door_bank(models: DiagMixture, rss: np.ndarray, times: np.ndarray, motion: UniformDisk,
              max_components: int, reduction: str, length_m: float) -> tuple:
    """Tracking with the door state shared by every update of a run (ablation, ours).

    One disk tracker per door state (``models`` batch ``(2, R, S)``: the models calibrated
    on the samples of that state) runs on the same measurements; the run's door posterior
    is ``p(d | z_1:t) ∝ prod_t int pred_d(x) prod_s D_s^d(x, m_s) dx`` (the predictive
    density of tracker ``d`` times the joint station densities of eq. (1) at the readings,
    integrated on a 0.25 m grid over the corridor; before the first update the prediction
    is uniform on the corridor). The estimate is the mixture over the door states: mean
    ``sum_d p_d mu_d``, variance ``sum_d p_d (var_d + (mu_d - mu)^2)``.

    Parameters
    ----------
    models : DiagMixture
        Batch ``(2, R, S)``, dimension 2.
    rss : ndarray, shape (R, T, S)
        Readings.
    times : ndarray, shape (T,)
        Step times, s.
    motion : UniformDisk
        The disk model (1-D).
    max_components : int
        Components of every position density.
    reduction : str
        Re-approximation of the trackers.
    length_m : float
        Corridor length (the evidence grid).

    Returns
    -------
    position : ndarray, shape (R, T, 1)
    covariance : ndarray, shape (R, T, 1, 1)
    p_closed : ndarray, shape (R, T)
        Posterior probability of the closed door after each update.
    """
    xg = np.linspace(0.0, length_m, 241)
    dx = xg[1] - xg[0]
    n_runs, n_steps, n_st = rss.shape
    means, variances, logev = [], [], []
    for d in range(2):
        trk = MixtureTracker(models[d], motion, max_components, reduction).run(rss, times)
        means.append(trk.position[..., 0])
        variances.append(trk.covariance[..., 0, 0])
        ev = np.zeros((n_runs, n_steps))
        for t in range(n_steps):
            if t == 0:
                pred = np.full((n_runs, xg.size), 1.0 / length_m)
            else:
                post = posterior_mixture(trk.at(t - 1))
                r = float(motion.radius(times[t] - times[t - 1]))
                if r > 0:
                    post = convolve(post, uniform_ball(r, 1))
                pred = post.pdf(xg[:, None])
            pts = np.stack([np.broadcast_to(xg, (n_runs, n_st, xg.size)),
                            np.broadcast_to(rss[:, t, :, None], (n_runs, n_st, xg.size))], -1)
            joint = np.prod(models[d].pdf(pts), axis=-2)                         # (R, G)
            ev[:, t] = np.log(np.maximum(np.sum(pred * joint, -1) * dx, 1e-300))
        logev.append(np.cumsum(ev, axis=-1))
    lw = np.stack(logev)                                                         # (2, R, T)
    p = np.exp(lw - lw.max(0))
    p = p / p.sum(0)
    mean = np.sum(p * np.stack(means), 0)
    var = np.sum(p * (np.stack(variances) + (np.stack(means) - mean) ** 2), 0)
    return mean[..., None], var[..., None, None], p[1]


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


def _rows(run: int, fig: str, series: str, x, value, m=np.nan) -> pd.DataFrame:
    x, value, m = np.broadcast_arrays(np.atleast_1d(x), np.atleast_1d(value), np.atleast_1d(m))
    return pd.DataFrame({"run": run, "table": "figure", "figure": fig, "series": series,
                         "x": x, "m": m, "value": value})


def _run_mse(rows: pd.DataFrame) -> pd.Series:
    """Per run: the mean squared error of ``x_est`` over the run's rows (steps)."""
    return per_run(rows.assign(sq=(rows["x_est"] - rows["x_true"]) ** 2), "sq")


def error_metrics(rows: pd.DataFrame, names: tuple[str | None, str | None, str | None],
                   note: str) -> list[Metric]:
    """RMSE, NEES and 2-sigma coverage of ``rows`` (``x_est``, ``x_true``, ``std_m``), each
    with its interval over runs (the runs are the independent units; a run's steps are not).

    Parameters
    ----------
    rows : pandas.DataFrame
        One row per run and step.
    names : (str or None, str or None, str or None)
        Metric names of the RMSE, the NEES and the coverage; None leaves one out.
    note : str
        What the rows are (the metrics' notes add what each number is).

    Returns
    -------
    list of Metric
        The RMSE is the root of the mean over runs of each run's mean squared error (the
        roots of that mean's interval); NEES and coverage are means over runs of each run's
        mean (error / std)^2 and fraction of steps with |error| <= 2 std.
    """
    e, sd = rows["x_est"] - rows["x_true"], rows["std_m"]
    cols = rows.assign(sq=e ** 2, nees=(e / sd) ** 2, cover=(e.abs() <= 2.0 * sd).astype(float))
    rm, nees, cover = names
    out = []
    if rm:
        out.append(Metric.over_runs(rm, per_run(cols, "sq"), None, "m", note, stat="rms"))
    if nees:
        out.append(Metric.over_runs(nees, per_run(cols, "nees"), 1.0, "",
                                    f"{note}: mean over runs of (error / std)^2 (1: calibrated)"))
    if cover:
        out.append(Metric.over_runs(cover, per_run(cols, "cover"), 0.95, "",
                                    f"{note}: fraction with |error| <= 2 std"))
    return out


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
            steps = np.arange(pos.shape[1]) if steps is None else np.asarray(steps)
            xt = np.broadcast_to(np.asarray(x_true, float), (pos.shape[1],))
            frames.append(pd.DataFrame({                                  # step-major rows
                "run": np.tile(runs, steps.size), "table": "runs", "noise_db": noise,
                "scenario": label, "step": np.repeat(steps + 1, runs.size),
                "x_true": np.repeat(xt[steps], runs.size), "x_est": pos[:, steps].T.ravel(),
                "std_m": np.sqrt(var[:, steps]).T.ravel()}))

        for noise in config.noise_db:
            models, kernel, by_door = _calibrate(config, corridor, noise, n, rng, True)
            door = rng.random(n) < 0.5
            static = MixtureTracker(models, UniformDisk(0.0, dim=1), k, red)
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
            # the kernel-insertion calibration (labelled variant), same measurements
            rows("static_kernel", noise, config.user_m,
                 MixtureTracker(kernel, UniformDisk(0.0, dim=1), k, red).run(rss, times))
            frames.append(pd.DataFrame({
                "run": np.repeat(runs, 2), "table": "model_isd", "noise_db": noise,
                "station": np.tile([1, 2], n),
                "isd_parameter": model_isd(models, corridor, noise).ravel(),
                "isd_kernel": model_isd(kernel, corridor, noise).ravel()}))
            # Fig. 9 over the runs: each station alone at the first update
            for s in range(2):
                alone = rss[:, 0, :].copy()
                alone[:, 1 - s] = np.nan
                est = MixtureLocalizer(models, k, red).locate(alone)
                rows(f"static_station{s + 1}", noise, config.user_m, est, [0])
            # distance to the exact product of eq. (2) at the first update, both reductions
            cond = models.condition(1, rss[:, 0, :], valid=np.ones((n, 2), bool))
            exact = product(cond[:, 0], cond[:, 1])
            approx = {alt: reduce(exact, k, alt)}
            approx[red], info = progressive_reduce(exact, k, return_info=True)
            ref = inner(exact.weights, exact.means, exact.variances, exact.weights, exact.means,
                        exact.variances)                                # int exact^2 dx
            frames.append(pd.DataFrame({
                "run": runs, "table": "isd", "noise_db": noise,
                "components_exact": exact.n_components, "components": k,
                **{f"isd_{m}": isd(approx[m], exact) / ref for m in (red, alt)},
                **{f"mean_{m}": approx[m].moments()[0][:, 0] for m in (red, alt)},
                "mean_exact": exact.moments()[0][:, 0], "pb_guard_fired": info.kept_start,
                f"cpu_s_static_{red}": cpu_red / n, f"cpu_s_static_{alt}": cpu_alt / n}))
            later.append((noise, models, door, by_door))
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
        for noise, models, door, _ in later:
            rss = corridor.sample_rss(np.broadcast_to(walk[:, None], (walk.size, n)),
                                      door, noise, rng).transpose(1, 0, 2)
            self._walk_rows(config, models, rss, walk, noise, "pause_", rows)
        # the door ablation (slow walker), drawn after the scenarios above
        slow = walk_positions(config.walk_start_m, config.walk_end_m, config.slow_speed,
                              config.dt_s)
        times = config.dt_s * np.arange(slow.size)
        disk = UniformDisk(config.v_max, dim=1)
        at = np.broadcast_to(slow[:, None], (slow.size, n))
        for noise, models, door, by_door in later:
            rss = corridor.sample_rss(at, door, noise, rng).transpose(1, 0, 2)
            rows("slow_tracking", noise, slow, MixtureTracker(models, disk, k, alt).run(rss, times))
            rows("slow_oneshot", noise, slow, MixtureLocalizer(models[:, None], k, alt).locate(rss))
            pos, var, p_closed = door_bank(by_door, rss, times, disk, k, alt, corridor.length_m)
            rows("slow_tracking_door_shared", noise, slow,
                 SimpleNamespace(position=pos, covariance=var))
            frames.append(pd.DataFrame({"run": runs, "table": "door", "noise_db": noise,
                                        "door_closed": door, "p_closed": p_closed[:, -1]}))
            redrawn = rng.random(at.shape) < 0.5
            rss = corridor.sample_rss(at, redrawn, noise, rng).transpose(1, 0, 2)
            rows("slow_tracking_door_redrawn", noise, slow,
                 MixtureTracker(models, disk, k, alt).run(rss, times))
            rows("slow_oneshot_door_redrawn", noise, slow,
                 MixtureLocalizer(models[:, None], k, alt).locate(rss))
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
            for k in (1, config.updates):
                last = static[(static["noise_db"] == noise) & (static["step"] == k)]
                metrics += error_metrics(
                    last, (f"rmse_m_after_{k}{tag}", f"nees_after_{k}{tag}",
                           f"coverage_2sigma_after_{k}{tag}"),
                    f"static user after {k} updates, posterior mean, {noise:g} dB; models: "
                    f"{PB_OURS}")
            for k in (1, 2, config.updates):
                paper = config.user_m if k == config.updates else None
                at_k = static[(static["noise_db"] == noise) & (static["step"] == k)]["x_est"]
                metrics.append(Metric.over_runs(f"estimate_m_after_{k}{tag}", at_k, paper, "m",
                                      f"mean over runs of the posterior mean, {noise:g} dB noise"
                                      + ("; paper: Fig. 10 concentrates at 45 m" if paper else "")))
            s_noise = static[static["noise_db"] == noise]
            for k in (1, config.updates):
                metrics.append(Metric.over_runs(
                    f"std_m_after_{k}{tag}", s_noise[s_noise["step"] == k].set_index("run")["std_m"],
                    None, "m", f"mean over runs of the posterior standard deviation after {k} "
                    "update" + ("s" if k > 1 else "")))
            t = trk[trk["noise_db"] == noise]
            metrics += error_metrics(t, (f"tracking_rmse_m{tag}", f"tracking_nees{tag}",
                                          f"tracking_coverage_2sigma{tag}"),
                                      f"walk at {config.walk_speed} m/s, v_max {config.v_max} m/s, "
                                      "every step")
            pz = {k: runs[(runs["scenario"] == k) & (runs["noise_db"] == noise)]
                  for k in ("pause_tracking", "pause_oneshot")}
            metrics += error_metrics(pz["pause_tracking"], (f"pause_tracking_rmse_m{tag}", None, None),
                                      f"walker who pauses {config.pause_s:g} s at "
                                      f"{config.pause_at_m:g} m, tracked (disk motion model)")
            metrics += error_metrics(pz["pause_oneshot"], (f"pause_oneshot_rmse_m{tag}", None, None),
                                      "the same pausing walker located one shot at a time")
            f6 = fig6_runs[fig6_runs["noise_db"] == noise]
            metrics.append(Metric.over_runs(
                f"fig6_bimodal_fraction{tag}", (f6["modes"] >= 2).astype(float), None, "",
                f"runs whose station-1 D(m | x = {config.figure_x_m:g} m) has two or more modes"))
            metrics.append(Metric.over_runs(
                f"tracking_mean_lag_m{tag}", per_run(t.assign(lag=t["x_true"] - t["x_est"]), "lag"),
                None, "m", "mean over runs of true - estimated position on the walk"))
            w1 = runs[(runs["scenario"] == "walk_oneshot") & (runs["noise_db"] == noise)]
            metrics += error_metrics(w1, (f"walk_oneshot_rmse_m{tag}", None, None),
                                      "same walk, each step localized alone (eq. (2), no motion "
                                      "model)")
            claims.append(Claim.lower(f"Tracking with the motion model is more accurate than "
                                      f"one-shot positioning of a walking user (Sect. 2; {noise:g} "
                                      "dB; mean squared error per run, paired)",
                                      _run_mse(t), _run_mse(w1), unit="m^2"))
            one = static[(static["noise_db"] == noise) & (static["step"] == 1)]
            metrics += error_metrics(one, (f"oneshot_rmse_m{tag}", None, None),
                                      "static user, one update (no tracking)")
            st = {k: runs[(runs["scenario"] == k) & (runs["noise_db"] == noise)]
                  .set_index("run")["std_m"] for k in ("static_station1", "static_station2")}
            prod_std = one.set_index("run")["std_m"]
            sharper = (prod_std < np.minimum(st["static_station1"], st["static_station2"]))
            metrics.append(Metric.over_runs(
                f"product_sharper_fraction{tag}", sharper.astype(float), None, "",
                "fraction of runs whose eq. (2) product (first static update) has a smaller "
                "std than each station's density alone"))
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
                    f"{config.converged_tolerance_m:g} m and the std shrinks (models: "
                    f"{PB_OURS})",
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

        for noise in config.noise_db:
            tag = "" if noise == config.noise_db[0] else f"_noise{noise:g}db"
            r = runs[runs["noise_db"] == noise]
            sc = {name: g for name, g in r.groupby("scenario")}
            i = isd_rows[isd_rows["noise_db"] == noise]
            n_exact = int(i["components_exact"].max()) if len(i) else 0
            for m in (red, alt):
                out.append(Metric.over_runs(
                    f"isd_{m}{tag}", per_run(i, f"isd_{m}"), None, "",
                    f"mean over runs of ISD({m} reduction to {config.position_components}, "
                    f"exact eq. (2) product of {n_exact} components) / int exact^2, first "
                    "static update"))
            ratio = per_run(i.assign(ratio=i[f"isd_{red}"] / i[f"isd_{alt}"]), "ratio")
            out += [Metric.over_runs(f"isd_ratio_median{tag}", ratio, None, "",
                                     f"median over runs of ISD({red}) / ISD({alt})",
                                     stat="median"),
                    Metric(f"isd_ratio_max{tag}", float(np.max(ratio)), None, "",
                           f"largest over runs of ISD({red}) / ISD({alt}) (1 where the "
                           "never-worse guard returned the West/Runnalls start); a maximum, "
                           "so no interval"),
                    Metric.over_runs(f"pb_guard_fired_fraction{tag}",
                                     per_run(i.astype({"pb_guard_fired": float}), "pb_guard_fired"),
                                     None, "", "runs whose progression did not lower the ISD, "
                                     "so that the West/Runnalls start was returned (first "
                                     "static update)")]
            mi = results[(results["table"] == "model_isd") & (results["noise_db"] == noise)]
            kern = sc["static_kernel"]
            out += [Metric.over_runs(f"model_isd_parameter{tag}", per_run(mi, "isd_parameter"),
                                     None, "", f"calibration in the parameter space ({PB_OURS}): "
                                     "mean over runs (of the stations' mean) of ISD(model, true "
                                     "density) / int true^2"),
                    Metric.over_runs(f"model_isd_kernel{tag}", per_run(mi, "isd_kernel"), None,
                                     "", "kernel insertion + West/Runnalls calibration "
                                     "(variant), same")]
            for step in (1, config.updates):
                out += error_metrics(
                    kern[kern["step"] == step],
                    (f"rmse_m_after_{step}_kernel{tag}", f"nees_after_{step}_kernel{tag}",
                     f"coverage_2sigma_after_{step}_kernel{tag}"),
                    f"static user after {step} updates, kernel-insertion calibration, {red} "
                    "reduction")
            for step in (1, config.updates):
                out.append(Metric.over_runs(
                    f"calibration_msd_gain_m2_after_{step}{tag}",
                    paired_differences(_run_mse(sc["static"][sc["static"]["step"] == step]),
                                       _run_mse(kern[kern["step"] == step])), None, "m^2",
                    f"static user after {step} updates: squared error with the {PB_OURS} "
                    "minus that with the kernel-insertion calibration, mean over runs of the "
                    "paired difference (> 0: kernel insertion better)"))
            out += CorridorExperiment._door_ablation(config, sc, results, noise, tag, claims)
            last = {m: sc[name][sc[name]["step"] == config.updates]
                    for m, name in ((red, "static"), (alt, f"static_{alt}"))}
            u = config.updates
            out += error_metrics(last[alt], (f"rmse_m_after_{u}_{alt}{tag}",
                                              f"nees_after_{u}_{alt}{tag}",
                                              f"coverage_2sigma_after_{u}_{alt}{tag}"),
                                  f"static user after {u} updates, {alt} reduction (labelled "
                                  "alternative)")
            for prefix, walkname in (("", "walk"), ("pause_", "pausing walk")):
                trk = "tracking" if not prefix else "pause_tracking"
                one = sc["walk_oneshot" if not prefix else "pause_oneshot"]
                cv = sc[f"{trk}_cv"]
                out += error_metrics(sc[f"{trk}_{alt}"], (f"{trk}_rmse_m_{alt}{tag}", None, None),
                                      f"{walkname}, disk model, {alt} reduction")
                out += error_metrics(cv, (f"{trk}_cv_rmse_m{tag}", f"{trk}_cv_nees{tag}",
                                           f"{trk}_cv_coverage_2sigma{tag}"),
                                      f"{walkname}, constant-velocity (position, velocity) "
                                      f"mixture (ours), q = {config.cv_q:g} m^2/s^3, {alt} "
                                      "reduction")
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

    @staticmethod
    def _door_ablation(config: CorridorConfig, sc: dict, results: pd.DataFrame, noise: float,
                       tag: str, claims: list) -> list:
        """Metrics and claim of the door ablation (slow walker) at one noise level."""
        out = []
        speed = f"walker at {config.slow_speed:g} m/s (v_max {config.v_max:g} m/s)"
        labels = {"slow_tracking": "disk tracker, door mixed independently in every update "
                                   "(the paper's density)",
                  "slow_tracking_door_shared": "disk trackers per door state, the door shared "
                                               "by the run's updates (ours)",
                  "slow_tracking_door_redrawn": "disk tracker, door redrawn at every update in "
                                                "the simulation (control)",
                  "slow_oneshot": "one shot at a time",
                  "slow_oneshot_door_redrawn": "one shot at a time, door redrawn per update"}
        for name, label in labels.items():
            tracked = "tracking" in name
            out += error_metrics(sc[name], (f"{name}_rmse_m{tag}",
                                             f"{name}_nees{tag}" if tracked else None,
                                             f"{name}_coverage_2sigma{tag}" if tracked else None),
                                  f"{speed}: {label}, {config.alt_reduction} reduction")
        d = results[(results["table"] == "door") & (results["noise_db"] == noise)]
        out.append(Metric.over_runs(
            f"door_posterior_correct_fraction{tag}",
            per_run(d.assign(ok=((d["p_closed"] > 0.5) == d["door_closed"]).astype(float)), "ok"),
            None, "", "runs whose door posterior after the slow walk favours the true door state"))
        claims.append(Claim.lower(
            f"Ablation (ours): with the door state shared by the run's updates, the disk "
            f"tracker beats one-shot positioning of a walker at {config.slow_speed:g} m/s "
            f"({noise:g} dB; mean squared error per run, paired)",
            _run_mse(sc["slow_tracking_door_shared"]), _run_mse(sc["slow_oneshot"]), unit="m^2"))
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
        save(fig, out_dir / "fig4_corridor_rss.png", caption=(
            "Fig. 4 of paper 004: sample scenario, a user walks along a corridor; the dotted "
            "lines are the signal strength if the metallic door were open, the solid lines "
            f"with the door closed (both stations, noise-free; door at {corridor.door_m:g} m)."))

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
        save(fig, out_dir / "fig5_model_station1.png", caption=(
            "Fig. 5 of paper 004: full propagation model, a probability density function over "
            "the one-dimensional user position and the signal strength measurement (station 1, "
            f"calibrated at {noise:g} dB noise with {n_comp} mixture components)."))

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
        save(fig, out_dir / "fig6_rss_at_50m.png", caption=(
            "Fig. 6 of paper 004: distribution of expected signal strength measurements at a "
            f"given user position x = {config.figure_x_m:g} m (station 1; dashed: the noise-free "
            "values with the door open and closed)."))
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
        save(fig, out_dir / "fig9_product.png", caption=(
            "Fig. 9 of paper 004: the individual position estimates relative to the two base "
            "stations and the global estimate, their product (eq. (2)); the user stands at "
            f"{config.user_m:g} m (grey line)."))

        fig, ax = figure()
        for k, ls in zip((1, 2, config.updates), ("--", ":", "-")):
            r = rows("fig10", f"after_{k}")
            ax.plot(r["x"], r["value"], ls, label=f"after {k} update{'s' if k > 1 else ''}")
        ax.axvline(config.user_m, color="grey", lw=0.8)
        ax.set_xlabel("user position x [m]")
        ax.set_ylabel("density [1/m]")
        ax.set_title(f"Fig. 10: static user at {config.user_m:g} m, {noise:g} dB")
        ax.legend()
        save(fig, out_dir / "fig10_updates.png", caption=(
            f"Fig. 10 of paper 004: position estimate after 1, 2 and {config.updates} "
            f"measurement update steps for a static user at {config.user_m:g} m "
            f"({noise:g} dB noise)."))

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
        save(fig, out_dir / "tracking.png", caption=(
            "Tracking a user walking along the corridor: true position, the estimate of the "
            "paper's model with +/- 2 standard deviations"
            + (" and of our constant-velocity variant" if cv is not None and len(cv) else "")
            + f" against time ({noise:g} dB noise, one run)."))
        notes.append(f"Fig. 9 example (one draw): std station 1 {stds[0]:.2f} m, station 2 "
                     f"{stds[1]:.2f} m, product {stds[2]:.2f} m; the Fig. 9 claim is decided "
                     "over the runs (product_sharper_fraction)")
        notes.append(f"Fig. 6 example (one calibration): {'bimodal' if bimodal else 'not bimodal'}"
                     "; the Fig. 6 claim is decided over the runs (fig6_bimodal_fraction)")
        return []


# ---- the docs' numbers, generated from summary.json -------------------------------------------
#: rows of the calibration comparison: (label, metric of our reading of the paper's
#: calibration, of the kernel-insertion variant)
_CALIBRATION_ROWS = (
    ("model ISD to the true density / int true^2", "model_isd_parameter", "model_isd_kernel"),
    ("RMSE after 1 update [m]", "rmse_m_after_1", "rmse_m_after_1_kernel"),
    ("NEES after 1 update", "nees_after_1", "nees_after_1_kernel"),
    ("RMSE after 8 updates [m]", "rmse_m_after_8", "rmse_m_after_8_kernel"),
    ("NEES after 8 updates", "nees_after_8", "nees_after_8_kernel"),
    ("2-sigma coverage after 8 updates", "coverage_2sigma_after_8",
     "coverage_2sigma_after_8_kernel"),
)
_SUFFIX = "_noise10db"


def _fmt(metric: dict | None) -> str:
    """A metric's value with its interval over runs (``-`` when absent)."""
    if metric is None or metric["value"] is None:
        return "-"
    ci = interval(metric.get("ci_low"), metric.get("ci_high"))
    return f"{fmt(metric['value'])} {ci}".strip()


def _cell(text: str) -> str:
    """Text for a markdown table cell (a bar would end the cell)."""
    return text.replace("|", "\\|")


def docs_snippet(record: dict) -> str:
    """The markdown of ``docs/generated/p004_corridor.md`` from a ``summary.json`` record.

    Parameters
    ----------
    record : dict
        The parsed ``summary.json`` of a ``p004-corridor`` run.

    Returns
    -------
    str
        A header naming the run, the calibration comparison (our reading of the paper's
        Progressive Bayes calibration in the parameter space against kernel insertion), every metric at both
        noise levels, and every claim with its verdict.
    """
    vals = {m["name"]: m for m in record["metrics"]}
    size = "full" if record.get("full") else "quick"
    how = "" if record["runs"] in (20, 200) else ", runs set on the command line"
    header = ("| calibration comparison (static user at 45 m) | parameter space (our reading "
              "of Progressive Bayes), 2 dB | kernel insertion (variant), 2 dB | ours of PB, "
              "10 dB | "
              "kernel, 10 dB |")
    lines = [("<!-- generated from summary.json by radioloc.experiments.p004_corridor; "
              "do not edit -->"),
             (f"Run: `{record['experiment']}`, {record['runs']} runs ({size} configuration"
              f"{how}), seed {record['seed']}."),
             "", header, "|---|---|---|---|---|"]
    for label, a, b in _CALIBRATION_ROWS:
        lines.append(f"| {label} | {_fmt(vals.get(a))} | {_fmt(vals.get(b))} | "
                     f"{_fmt(vals.get(a + _SUFFIX))} | {_fmt(vals.get(b + _SUFFIX))} |")
    lines += ["", "| metric | 2 dB [95% CI] | 10 dB [95% CI] | paper | what |",
              "|---|---|---|---|---|"]
    for name, m in vals.items():
        if name.endswith(_SUFFIX):
            continue
        lines.append(f"| `{name}` | {_fmt(m)} | {_fmt(vals.get(name + _SUFFIX))} | "
                     f"{fmt(m['paper'])} | {_cell(m['note'])} |")
    lines += ["", "Claims:", ""]
    for c in record["claims"]:
        why = claim_evidence(c)
        lines.append(f"- {c['claim']}: **{verdict(c)}**" + (f" ({why})" if why else ""))
    return "\n".join(lines) + "\n"


def write_docs_snippet(summary_json: Path | str, out_md: Path | str) -> Path:
    """Write :func:`docs_snippet` of a ``summary.json`` file to ``out_md``.

    Parameters
    ----------
    summary_json : path
        ``OUT/p004-corridor/summary.json``.
    out_md : path
        The snippet, e.g. ``docs/generated/p004_corridor.md``.

    Returns
    -------
    Path
        ``out_md``.
    """
    from radioloc.report.snippet import write_docs_snippet as write

    return write(summary_json, out_md, docs_snippet)


if __name__ == "__main__":                      # python -m ... SUMMARY_JSON OUT_MD
    import sys

    write_docs_snippet(sys.argv[1], sys.argv[2])
