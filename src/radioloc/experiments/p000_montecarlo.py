"""Paper 000 (Brown & Iltis), Figs. 1-2: distributed RLS vs sequential EKF by Monte Carlo.

K = 6 nodes (3 GPS-assisted, prior variance 100 m^2 per axis; 3 unassisted, 10,000 m^2),
Gaussian range noise of variance 900 m^2 (Fig. 1) and 10,000 m^2 (Fig. 2); every iteration
each node in turn measures its ranges to the other five. The average position error per
iteration of RLS (eq. (1)-eq. (12)) and EKF (eq. (13)-eq. (25)) is compared with the Bayesian
Cramer-Rao bound of the network (all ranges so far plus the priors).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.stats import trim_mean

from radioloc.bounds.cooperative import network_crb_node_traces
from radioloc.core.alignment import rigid_aligned_error
from radioloc.core.metrics import first_step_within
from radioloc.estimators.ekf import NetworkEKF
from radioloc.estimators.rls import NetworkRLS
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, register
from radioloc.report.style import COLORS, LINESTYLES, figure, save
from radioloc.sim.network import draw_network, iteration_ranges

METHODS = ("rls", "ekf", "rlsw")
LABELS = {"rls": "RLS, eq. (12) as printed", "ekf": "EKF",
          "rlsw": "variant: RLS with noise-weighted prior"}
CLASSES = ("assisted", "unassisted")


def _node_mean(a: np.ndarray, nodes: np.ndarray, axis: int) -> np.ndarray:
    """Mean of ``a`` over the ``nodes`` (a mask along ``axis``); NaN when there are none."""
    if not np.any(nodes):
        return np.full(np.delete(a.shape, axis), np.nan)
    return np.compress(nodes, a, axis=axis).mean(axis)


def class_mean(wt: dict, value):
    """``sum_c wt[c] value(c)`` over the node classes with nodes (``wt[c] > 0``): a class with
    no node (every node GPS-assisted, say) has NaN columns and is left out."""
    return sum(wt[c] * value(c) for c in CLASSES if wt[c] > 0)
COLOR = {"rls": COLORS["baseline"], "ekf": COLORS["ours"], "rlsw": COLORS["alt"]}
STYLE = {"rls": LINESTYLES["rls"], "ekf": LINESTYLES["ekf"], "rlsw": "-."}


@dataclass(frozen=True)
class P000Config:
    """Settings of ``p000-montecarlo`` (choices the paper leaves open are marked *).

    runs, block_size: Monte Carlo runs and runs per independently seeded block.
    iterations: iterations n; each is one packet from every node in turn (node 0..K-1).
    nodes, assisted: K = 6 nodes; the first ``assisted`` are GPS-assisted.
    prior_var_assisted_m2, prior_var_unassisted_m2: per-axis prior variances (paper).
    range_var_m2: the range-noise variances of Figs. 1 and 2 (paper).
    side_m (*): true positions uniform in a ``side_m`` square, drawn anew for every run.
    Each ordered pair (master k, node i) gets an independent range draw at each iteration
    (*); ranges are not clipped at 0 (*). RLS uses lambda = ``forgetting`` = 1 (*) and, in
    each iteration, the other nodes' estimates of the previous iteration (eq. (8), eq. (9)). The EKF
    is told the true range variance. Iteration order of masters: 0..K-1 every iteration (*).
    converge_tolerance: "converged" = first iteration within this fraction of the final
    error, staying there.
    equal_tolerance: "nearly identical" final errors = within this fraction of each other.
    clearly_lower: "clearly lower" = at least this fraction lower.
    diverged_m: a run whose final error (mean over its nodes) is non-finite or exceeds
    this has diverged (10 km, ten times the side of the area). Diverged runs are counted and
    left out of the mean curves; medians and trimmed means use every run. A rule on the CRB
    (e.g. 10x) is not used: the RLS as printed loses its frame and ends at a median 15x the
    CRB without diverging (the count over 10x the CRB is reported as a metric).
    trim_fraction: fraction cut from each end for the trimmed means.
    """

    runs: int = 200
    block_size: int = 500
    iterations: int = 50
    nodes: int = 6
    assisted: int = 3
    prior_var_assisted_m2: float = 100.0
    prior_var_unassisted_m2: float = 10_000.0
    range_var_m2: tuple[float, ...] = (900.0, 10_000.0)
    side_m: float = 1000.0
    forgetting: float = 1.0
    converge_tolerance: float = 0.10
    equal_tolerance: float = 0.10
    clearly_lower: float = 0.10
    diverged_m: float = 10_000.0
    trim_fraction: float = 0.05


def robust_curves(rows: pd.DataFrame, wt: dict, diverged_m: float) -> dict:
    """Per-run error curves and the runs that did not diverge, for one range variance.

    Parameters
    ----------
    rows : DataFrame
        The results rows of one range variance (every run and iteration).
    wt : dict
        Weight of each node class in the mean over nodes (its share of the nodes).
    diverged_m : float
        A run diverged when its final error (mean over nodes) is non-finite or above this.

    Returns
    -------
    dict
        ``iterations`` (N + 1,), ``per_run`` {method: (R, N + 1) mean error over nodes},
        ``kept`` {method: (R,) bool, runs that did not diverge}, ``curves`` (DataFrame
        indexed by iteration: each method's columns averaged over its kept runs, the CRB
        columns over all runs), ``crb_final`` (R,) the run's CRB RMSE at the last iteration
        and ``prior_error`` (mean error at iteration 0 over all runs).
    """
    rows = rows.sort_values(["run", "iteration"])
    iters = np.sort(rows["iteration"].unique())
    runs = rows["run"].unique()
    shape = (runs.size, iters.size)

    def grid(col):
        return rows[col].to_numpy(dtype=float).reshape(shape)
    per_run, kept, parts = {}, {}, []
    for m in METHODS:
        e = class_mean(wt, lambda c: grid(f"{m}_err_{c}_m"))
        per_run[m] = e
        kept[m] = np.isfinite(e[:, -1]) & (e[:, -1] <= diverged_m)
        cols = [c for c in rows.columns if c.startswith(f"{m}_")]
        sub = rows[rows["run"].isin(runs[kept[m]])]
        parts.append(sub.groupby("iteration")[cols].mean().reindex(iters))
    crb_cols = [c for c in rows.columns if c.startswith("crb_")]
    parts.append(rows.groupby("iteration")[crb_cols].mean())
    crb_final = np.sqrt(class_mean(wt, lambda c: grid(f"crb_{c}_m2")))[:, -1]
    prior = float(np.mean(per_run[METHODS[0]][:, 0]))
    return {"iterations": iters, "per_run": per_run, "kept": kept,
            "curves": pd.concat(parts, axis=1), "crb_final": crb_final, "prior_error": prior}


@register
class P000MonteCarlo(Experiment):
    """``p000-montecarlo``: :class:`NetworkRLS` vs :class:`NetworkEKF` and the CRB (Figs. 1-2)."""

    id = "p000-montecarlo"
    paper = "000"
    description = "Distributed RLS vs sequential EKF network positioning, Figs. 1-2, with the CRB"

    def config(self, full: bool) -> P000Config:
        """The quick (200 runs) or full (5000 runs, the paper's) configuration.

        Parameters
        ----------
        full : bool
            The paper's size.

        Returns
        -------
        P000Config
        """
        return P000Config(runs=5000 if full else 200)

    def run_block(self, config: P000Config, runs: np.ndarray,
                  rng: np.random.Generator) -> pd.DataFrame:
        """Run one block: per run and range variance, the error curves of RLS, EKF, the
        prior-weighted RLS and the CRB.

        Parameters
        ----------
        config : P000Config
        runs : ndarray of int
            Run indices of the block.
        rng : Generator
            The block's generator.

        Returns
        -------
        DataFrame
            One row per (run, range variance, iteration 0..N), errors per node class.
        """
        R, K, N = runs.size, config.nodes, config.iterations
        net = draw_network(rng, R, K, config.assisted, side_m=config.side_m,
                           var_assisted_m2=config.prior_var_assisted_m2,
                           var_unassisted_m2=config.prior_var_unassisted_m2)
        truth, prior, prior_var = net.truth, net.prior_mean, net.prior_var
        cls = {"assisted": net.assisted, "unassisted": ~net.assisted}
        frames = []
        for rv in config.range_var_m2:
            std = float(np.sqrt(rv))                                       # sigma_v, m
            rho = iteration_ranges(truth, N, std_m=std, rng=rng)           # (R, N, K, K)
            estimators = {
                "rls": NetworkRLS(forgetting=config.forgetting, std_m=std),
                "ekf": NetworkEKF(std_m=std),
                "rlsw": NetworkRLS(forgetting=config.forgetting, prior_scale="transformed-noise",
                                   std_m=std)}
            crb = network_crb_node_traces(truth, std_m=std, prior_var=prior_var,
                                          counts=np.arange(N + 1))       # (N+1, R, K)
            data = {"run": np.repeat(runs, N + 1), "range_var_m2": rv,
                    "iteration": np.tile(np.arange(N + 1), R)}
            for m, est in estimators.items():
                track = est.run(rho, prior, prior_var)
                pos = np.concatenate([prior[:, :, None], track.position], axis=2)  # (R,K,N+1,2)
                err = np.linalg.norm(pos - truth[:, :, None], axis=-1)            # (R, K, N+1)
                aligned = rigid_aligned_error(pos.transpose(0, 2, 1, 3), truth[:, None])
                for c in CLASSES:
                    data[f"{m}_err_{c}_m"] = _node_mean(err, cls[c], 1).ravel()
                    data[f"{m}_sqerr_{c}_m2"] = _node_mean(err**2, cls[c], 1).ravel()
                data[f"{m}_aligned_err_m"] = aligned.mean(-1).ravel()             # (R, N+1)
            for c in CLASSES:
                data[f"crb_{c}_m2"] = _node_mean(crb, cls[c], crb.ndim - 1).T.ravel()
            frames.append(pd.DataFrame(data).round(4))      # 0.1 mm: keeps the CSV small
        return pd.concat(frames, ignore_index=True)

    def summarize(self, config: P000Config, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Error curves, convergence steps, claims and figures, from ``results`` only.

        Statistics are robust to diverged runs: a run diverged (per method and range
        variance) when its final error, mean over its nodes, is non-finite or above
        ``config.diverged_m``. Diverged runs are counted; the curves, final errors and steps
        to converge are computed over the runs that did not diverge (mean), and as medians
        and trimmed means over all runs; every claim is judged on both the mean over the
        runs that did not diverge and the median curve, and holds only if it holds on both.
        The plain mean over all runs is kept as a metric (``*_all_runs_*``).

        Parameters
        ----------
        config : P000Config
        results : DataFrame
            The blocks of :meth:`run_block`.
        out_dir : Path
            Where the figures go.

        Returns
        -------
        Summary
        """
        K, A = config.nodes, config.assisted
        wt = {"assisted": A / K, "unassisted": (K - A) / K}
        metrics, claims, notes = [], [], []
        final, steps, tags, prior = {}, {}, {}, {}
        med_final, med_steps = {}, {}
        for rv in config.range_var_m2:
            tag = f"var{rv:g}"
            tags[rv] = tag
            rob = robust_curves(results[results["range_var_m2"] == rv], wt, config.diverged_m)
            cur, iters = rob["curves"], rob["iterations"]
            crb_final = rob["crb_final"]
            prior[rv] = rob["prior_error"]
            for m in METHODS:
                per_run = rob["per_run"][m]                             # (R, N + 1)
                kept = rob["kept"][m]
                fin = per_run[:, -1]
                mean_kept = per_run[kept].mean(0) if kept.any() else np.full(len(iters), np.nan)
                median = np.median(per_run, axis=0)
                trimmed = trim_mean(per_run, config.trim_fraction, axis=0)
                final[m, rv] = float(mean_kept[-1])
                med_final[m, rv] = float(median[-1])
                steps[m, rv] = first_step_within(mean_kept, config.converge_tolerance)
                med_steps[m, rv] = first_step_within(median, config.converge_tolerance)
                sq = class_mean(wt, lambda c: cur[f"{m}_sqerr_{c}_m2"])
                name = "rls_prior_weighted" if m == "rlsw" else m
                what = LABELS[m]
                metrics += [
                    Metric.over_runs(f"{name}_final_error_m_{tag}", fin[kept], None, "m",
                           f"{what}: mean position error at iteration {config.iterations}, "
                           "all nodes, runs that did not diverge"),
                    (Metric.over_runs(f"{name}_final_error_m_all_runs_{tag}", fin, None, "m",
                                      f"{what}: mean final error over all runs, diverged ones "
                                      "included") if np.all(np.isfinite(fin)) else
                     Metric(f"{name}_final_error_m_all_runs_{tag}", float(np.mean(fin)), None,
                            "m", f"{what}: mean final error over all runs, diverged ones "
                            "included (a run diverged to infinity: no interval)")),
                    Metric(f"{name}_final_trimmed_mean_error_m_{tag}", float(trimmed[-1]), None,
                           "m", f"{what}: {config.trim_fraction:.0%}-trimmed mean over runs "
                           "of the final error"),
                    Metric.over_runs(f"{name}_final_median_error_m_{tag}", fin, None, "m",
                                     f"{what}: median over runs of the final error (mean over "
                                     "nodes)", stat="median"),
                    Metric(f"{name}_final_rmse_m_{tag}", float(np.sqrt(sq.iloc[-1])), None, "m",
                           f"{what}: RMSE at the last iteration, runs that did not diverge "
                           "(compare with the CRB)"),
                    Metric(f"{name}_steps_to_converge_{tag}", steps[m, rv], None, "iterations",
                           f"{what}: first iteration within {config.converge_tolerance:.0%} "
                           "of the final value, mean curve of the runs that did not diverge"),
                    Metric(f"{name}_steps_to_converge_median_{tag}", med_steps[m, rv], None,
                           "iterations", f"{what}: the same on the median curve over all runs"),
                    Metric(f"{name}_final_aligned_error_m_{tag}",
                           float(cur[f"{m}_aligned_err_m"].iloc[-1]), None, "m",
                           f"{what}: mean error after the best rigid motion (shape only), "
                           "runs that did not diverge"),
                    Metric(f"{name}_diverged_runs_{tag}", int((~kept).sum()), None, "runs",
                           f"{what}: runs whose final error is non-finite or above "
                           f"{config.diverged_m:g} m (of {kept.size})"),
                    Metric(f"{name}_diverged_fraction_{tag}", float(np.mean(~kept)), None, "",
                           f"{what}: fraction of runs that diverged"),
                    Metric(f"{name}_runs_over_10x_crb_{tag}", int(np.sum(~(fin <= 10 * crb_final))),
                           None, "runs", f"{what}: runs ending more than 10x the run's CRB "
                           "RMSE off (not a divergence criterion: the RLS as printed drifts)"),
                ]
                for c in (c for c in CLASSES if wt[c] > 0):
                    metrics.append(Metric(f"{name}_final_error_m_{c}_{tag}",
                                          float(cur[f"{m}_err_{c}_m"].iloc[-1]), None, "m",
                                          f"{what}: {c} nodes, runs that did not diverge"))
            crb = np.sqrt(class_mean(wt, lambda c: cur[f"crb_{c}_m2"]))
            metrics.append(Metric(f"crb_rmse_m_{tag}", float(crb.iloc[-1]), None, "m",
                                  "sqrt of the mean per-node trace of the Bayesian CRB after "
                                  f"{config.iterations} iterations"))
            metrics.append(Metric(f"prior_error_m_{tag}", prior[rv], None, "m",
                                  "mean error of the priors (iteration 0)"))
            medians = pd.DataFrame({m: np.median(rob["per_run"][m], axis=0) for m in METHODS},
                                   index=iters)
            self._plot(config, cur, rv, out_dir / f"fig{1 if rv == config.range_var_m2[0] else 2}"
                       f"_error_vs_iteration_{tag}.png", wt, medians)
            self._plot_classes(config, cur, rv, out_dir / f"error_by_class_{tag}.png")

        v1, v2 = config.range_var_m2[0], config.range_var_m2[-1]
        t1, t2 = tags[v1], tags[v2]
        tol, low = config.equal_tolerance, config.clearly_lower

        def run_values(rv):
            """Per run and method: final error and steps to converge, NaN where the run
            diverged (``kept``) and over all runs (``all``)."""
            rob = robust_curves(results[results["range_var_m2"] == rv], wt, config.diverged_m)
            out = {}
            for m in METHODS:
                e = rob["per_run"][m]
                with np.errstate(invalid="ignore"):      # a diverged run's inf errors
                    ok = np.abs(e - e[:, -1:]) <= config.converge_tolerance * np.abs(e[:, -1:])
                last_bad = e.shape[1] - np.argmax(~ok[:, ::-1], axis=1)
                step = np.where((~ok).any(axis=1), last_bad, 0).astype(float)
                keep = rob["kept"][m]
                out[m, "kept"] = (np.where(keep, e[:, -1], np.nan), np.where(keep, step, np.nan))
                out[m, "all"] = (e[:, -1], step)
            return out

        vals = {rv: run_values(rv) for rv in (v1, v2)}

        def claim(text, make) -> Claim:
            """A claim decided on the mean of the runs that did not diverge and on the median
            over all runs (``make(final, steps, stat)`` -> a list of claims)."""
            return Claim.all_of(text, [c for sel, st in (("kept", "mean"), ("all", "median"))
                                       for c in make(lambda rv, m: vals[rv][m, sel][0],
                                                     lambda rv, m: vals[rv][m, sel][1], st)])

        on = " (judged on the mean of the runs that did not diverge and on the median)"

        def both_converge(f, rv, st) -> list[Claim]:
            """Settling is compared only where both methods converge (a method whose error
            grows settles too, on a drifted frame)."""
            return [Claim.below("", f(rv, m), prior[rv], "m", stat=st) for m in ("rls", "ekf")]
        where = " (judged only where both converge: final error below the prior error)"
        claims += [
            claim(f"({t1}) both RLS and EKF converge (final error below the prior error)" + on,
                  lambda f, s, st: [Claim.below("", f(v1, m), prior[v1], "m", stat=st)
                                    for m in ("rls", "ekf")]),
            claim(f"({t1}) EKF converges in fewer iterations than RLS" + where + on,
                  lambda f, s, st: both_converge(f, v1, st)
                  + [Claim.lower("", s(v1, "ekf"), s(v1, "rls"), stat=st)]),
            claim(f"({t1}) final RLS and EKF errors are nearly identical (within {tol:.0%})" + on,
                  lambda f, s, st: [Claim.within("", f(v1, "rls"), f(v1, "ekf"), tol, "m", stat=st)]),
            claim(f"({t2}) EKF ends clearly lower than RLS (at least {low:.0%} lower)" + on,
                  lambda f, s, st: [Claim.lower("", f(v2, "ekf"), (1 - low) * f(v2, "rls"), unit="m",
                                                stat=st)]),
            claim(f"({t2}) EKF converges in fewer iterations than RLS" + where + on,
                  lambda f, s, st: both_converge(f, v2, st)
                  + [Claim.lower("", s(v2, "ekf"), s(v2, "rls"), stat=st)]),
            claim(f"variant rls_prior_weighted ({t1}): final RLS and EKF errors within {tol:.0%}" + on,
                  lambda f, s, st: [Claim.within("", f(v1, "rlsw"), f(v1, "ekf"), tol, "m", stat=st)]),
            claim(f"variant rls_prior_weighted ({t2}): EKF ends clearly lower than RLS" + on,
                  lambda f, s, st: [Claim.lower("", f(v2, "ekf"), (1 - low) * f(v2, "rlsw"), unit="m",
                                                stat=st)]),
        ]
        for rv in config.range_var_m2:
            notes.append(
                f"({tags[rv]}) steps to converge, mean of the runs that did not diverge / median: "
                + ", ".join(f"{m} {steps[m, rv]} / {med_steps[m, rv]}" for m in METHODS)
                + "; final error (m): "
                + ", ".join(f"{m} {final[m, rv]:.4g} / {med_final[m, rv]:.4g}" for m in METHODS))
        notes += self._prior_weight_notes(config)
        return Summary(metrics, claims, notes)

    @staticmethod
    def _prior_weight_notes(config: P000Config) -> list[str]:
        # nodes uniform in a square of side s: E|x_i - x_j|^2 = s^2 / 3
        d2 = config.side_m ** 2 / 3.0
        pairs = (config.nodes - 1) * (config.nodes - 2) // 2
        ata = pairs * d2                                   # trace of A^T A, m^2 (per axis ~half)
        out = [
            "eq. (12) units: the rows of A_k are position differences (m), so A_k^T A_k is in "
            f"m^2 (trace ~ {pairs} pairs x s^2/3 = {ata:.2g} m^2 for a {config.side_m:g} m "
            "square), while P_k(0)^-1 = Cov^-1 is in 1/m^2: the trace ratio prior/A^T A is "
            f"{2 / config.prior_var_assisted_m2 / ata:.1e} for GPS-assisted and "
            f"{2 / config.prior_var_unassisted_m2 / ata:.1e} for unassisted nodes, so the "
            "prior is forgotten at the first update.",
        ]
        for rv in config.range_var_m2:
            sz = 2 * rv * d2
            out.append(
                f"At sigma_v^2 = {rv:g} m^2 the transformed noise v_ijk has variance "
                f"~2 sigma_v^2 s^2/3 = {sz:.2g} m^4: a consistent prior weight is "
                f"P_k(0)^-1 = sigma_z^2 Cov^-1 ({sz / config.prior_var_assisted_m2:.2g} m^2 "
                f"assisted, {sz / config.prior_var_unassisted_m2:.2g} m^2 unassisted), i.e. "
                f"eq. (12) under-weights the prior by a factor ~{sz:.1g}. Variant "
                "rls_prior_weighted uses that weight (evaluated per node at the prior means).")
        out.append(
            "Ranges are invariant to translating, rotating (and reflecting) the whole network: "
            "their Fisher information has rank 2K-3. Only the Gaussian priors fix the "
            "network's position and orientation (in practice the 100 m^2 GPS-assisted "
            "priors). The EKF and the CRB carry them in the joint covariance; the distributed "
            "RLS has no joint state and its priors carry ~no weight, so its frame is the one "
            "of the first iteration's estimates and it random-walks afterwards: compare the "
            "*_final_aligned_error_m_* metrics (shape only) with *_final_error_m_*.")
        return out

    @staticmethod
    def _curve(cur: pd.DataFrame, prefix: str, wt: dict | None, suffix: str) -> np.ndarray:
        if wt is None:
            return cur[prefix + suffix].to_numpy()
        return class_mean(wt, lambda c: cur[f"{prefix}{c}{suffix}"]).to_numpy()

    @staticmethod
    def _limit(ax, ekf: np.ndarray) -> None:
        """y range from the bound to 20x the prior error; curves beyond it are marked."""
        if not np.isfinite(ekf).any() or not np.isfinite(ekf[0]):
            return                                    # no EKF curve to scale by: autoscale
        lo, hi = 0.5 * np.nanmin(ekf), 20.0 * ekf[0]
        off = [ln for ln in ax.get_lines() if np.nanmax(ln.get_ydata()) > hi]
        ax.set_ylim(lo, hi)
        for ln in off:
            ln.set_label(ln.get_label() + " - leaves the axes (diverged runs)")

    def _plot(self, config: P000Config, cur: pd.DataFrame, rv: float, path: Path,
              wt: dict, medians: pd.DataFrame) -> None:
        it = cur.index.to_numpy()
        fig, ax = figure(width=9.6, height=4.4, layout="constrained")
        for m in METHODS:
            ax.plot(it, self._curve(cur, f"{m}_err_", wt, "_m"), STYLE[m], color=COLOR[m],
                    label=f"{LABELS[m]}: mean")
            ax.plot(medians.index, medians[m], STYLE[m], color=COLOR[m], lw=0.8, alpha=0.6,
                    label=f"{LABELS[m]}: median")
        ax.plot(it, np.sqrt(self._curve(cur, "crb_", wt, "_m2")), LINESTYLES["bound"],
                color=COLORS["bound"], lw=2, label="CRB (RMSE bound)")
        ax.set_yscale("log")
        self._limit(ax, self._curve(cur, "ekf_err_", wt, "_m"))
        ax.set_xlabel("iteration n (one packet from every node)")
        ax.set_ylabel("average position error [m]")
        ax.set_title(f"K={config.nodes} nodes, range noise variance {rv:g} m$^2$, "
                     f"{config.runs} runs")
        ax.grid(True, which="both", alpha=0.3)
        fig.legend(*ax.get_legend_handles_labels(), loc="outside right upper", fontsize=8,
                   title="thick: mean of the runs that\ndid not diverge; thin: median",
                   title_fontsize=8)
        num = 1 if rv == config.range_var_m2[0] else 2
        save(fig, path, caption=(
            f"Fig. {num} of paper 000: average position estimation error versus iteration "
            f"number for the RLS-based (dashed) and EKF-based (solid) positioning algorithms, "
            f"range variance sigma_v^2 = {rv:g} m^2. Ours adds the variant RLS with a "
            "noise-weighted prior (dash-dot) and the CRB (dotted); thick lines are the mean "
            "over the runs that did not diverge, thin lines the median over all runs."))

    def _plot_classes(self, config: P000Config, cur: pd.DataFrame, rv: float,
                      path: Path) -> None:
        it = cur.index.to_numpy()
        fig, grid = figure(2, 2, width=11.0, height=5.2, gridspec_kw={"height_ratios": [5, 1]})
        axes = grid[0]
        axes[1].sharey(axes[0])
        for ax, c in zip(axes, CLASSES):
            if not np.isfinite(cur[f"ekf_err_{c}_m"].to_numpy()).any():     # a class with no node
                ax.text(0.5, 0.5, f"no {c} nodes\n(assisted = {config.assisted} of "
                        f"{config.nodes})", ha="center", va="center", transform=ax.transAxes)
                ax.tick_params(left=False, labelleft=False, bottom=False, labelbottom=False,
                               which="both")
                ax.grid(False)
                continue
            for m in METHODS:
                ax.plot(it, cur[f"{m}_err_{c}_m"], STYLE[m], color=COLOR[m], label=LABELS[m])
            ax.plot(it, np.sqrt(cur[f"crb_{c}_m2"]), LINESTYLES["bound"], color=COLORS["bound"],
                    lw=2, label="CRB (RMSE bound)")
            ax.set_yscale("log")
            self._limit(ax, cur[f"ekf_err_{c}_m"].to_numpy())
            ax.set_xlabel("iteration n")
            ax.set_title(f"{c} nodes (prior var "
                         f"{config.prior_var_assisted_m2 if c == 'assisted' else config.prior_var_unassisted_m2:g} m$^2$)")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].set_ylabel("average position error [m]")
        handles = [axes[0].get_legend_handles_labels(), axes[1].get_legend_handles_labels()]
        for g in grid[1]:
            g.axis("off")
        for g, (h, lab) in zip(grid[1], handles):
            if h:
                g.legend(h, lab, loc="center", ncol=1, fontsize=8)
        fig.suptitle(f"By node class, range noise variance {rv:g} m$^2$, {config.runs} runs")
        save(fig, path, caption=(
            f"Average position error versus iteration, GPS-assisted nodes (left) and "
            f"unassisted nodes (right) apart, range variance {rv:g} m^2: RLS as printed "
            "(dashed), EKF (solid), the noise-weighted-prior RLS variant (dash-dot) and the "
            "CRB (dotted), mean over the runs that did not diverge."))
