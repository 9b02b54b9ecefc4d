"""Static multilateration by Gauss-Newton (:class:`Multilateration`) against the Cramer-Rao bound.

Not a paper reproduction: the toolkit's end-to-end check. Nodes are drawn uniformly in a
square with an anchor at each corner; ranges carry Gaussian noise of several standard
deviations; the batched Gauss-Newton estimate is compared with the CRB averaged over the
same node positions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.bounds.anchors import range_crb
from radioloc.core.geometry import distances
from radioloc.core.metrics import position_error
from radioloc.estimators.multilateration import Multilateration
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, register
from radioloc.models.ranging import GaussianRange
from radioloc.report.style import COLORS, LINESTYLES, figure, save


@dataclass(frozen=True)
class MultilaterationConfig:
    """Settings of ``gn-multilateration``.

    side_m: side of the square; anchors at its four corners; nodes uniform inside.
    range_std_m: the swept range-noise standard deviations.
    efficiency_tolerance: the claim "GN attains the CRB" means RMSE <= (1 + tol) x CRB.
    """

    runs: int = 2000
    block_size: int = 1000
    side_m: float = 100.0
    range_std_m: tuple[float, ...] = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0)
    efficiency_tolerance: float = 0.10


@register
class GaussNewtonMultilateration(Experiment):
    """``gn-multilateration``: :class:`Multilateration` RMSE against the anchor CRB."""

    id = "gn-multilateration"
    paper = "-"
    description = "Static Gauss-Newton multilateration to 4 anchors: RMSE vs the CRB over range noise"

    def config(self, full: bool) -> MultilaterationConfig:
        """The quick (2000 runs) or full (100,000 runs) configuration.

        Parameters
        ----------
        full : bool
            The full size.

        Returns
        -------
        MultilaterationConfig
        """
        return MultilaterationConfig(runs=100_000 if full else 2000)

    def run_block(self, config: MultilaterationConfig, runs: np.ndarray,
                  rng: np.random.Generator) -> pd.DataFrame:
        """Locate one block of random nodes at every range-noise level.

        Parameters
        ----------
        config : MultilaterationConfig
        runs : ndarray of int
            Run indices of the block.
        rng : Generator
            The block's generator.

        Returns
        -------
        DataFrame
            One row per (run, range_std_m): truth, estimate, error, CRB trace and the
            solver's iterations and convergence flag.
        """
        s = config.side_m
        anchors = np.array([[0.0, 0.0], [s, 0.0], [s, s], [0.0, s]])
        truth = rng.uniform(0.0, s, size=(runs.size, 2))
        true_ranges = distances(truth[:, None, :], anchors)          # (R, 4)
        frames = []
        for std in config.range_std_m:
            model = GaussianRange(std)
            measured = np.abs(model.sample(true_ranges, rng))
            fit = Multilateration(std_m=std).locate(measured, anchors)
            crb = range_crb(truth, anchors, std_m=std)
            frames.append(pd.DataFrame({
                "run": runs, "range_std_m": std,
                "x_true": truth[:, 0], "y_true": truth[:, 1],
                "x_est": fit.position[:, 0], "y_est": fit.position[:, 1],
                "error_m": position_error(fit.position, truth),
                "crb_trace_m2": np.trace(crb, axis1=-2, axis2=-1),
                "iterations": fit.diagnostics["iterations"],
                "converged": fit.diagnostics["converged"],
            }))
        return pd.concat(frames, ignore_index=True)

    def claims(self, config: MultilaterationConfig, results: pd.DataFrame) -> list[Claim]:
        """The claims, from ``results`` (each run one independent node, so one unit).

        Parameters
        ----------
        config : MultilaterationConfig
        results : DataFrame
            The blocks of :meth:`run_block`.

        Returns
        -------
        list of Claim
            GN within ``efficiency_tolerance`` of the CRB for range noise <= 1 m, and the
            RMSE growing with the noise (paired over runs).
        """
        g = results.groupby("range_std_m")
        tol2 = (1 + config.efficiency_tolerance) ** 2
        sq = {std: gg.set_index("run")["error_m"] ** 2 for std, gg in g}
        excess = {std: sq[std] - tol2 * gg.set_index("run")["crb_trace_m2"] for std, gg in g}
        stds = sorted(sq)
        return [Claim.all_of(f"Gauss-Newton RMSE is within {config.efficiency_tolerance:.0%} of "
                             "the CRB for range noise <= 1 m (mean of squared error minus "
                             f"{tol2:.3g} x CRB trace <= 0)",
                             [Claim.below("", excess[s_], 0.0, "m^2") for s_ in stds if s_ <= 1.0]),
                Claim.all_of("RMSE grows with the range noise (squared error, paired over runs)",
                             [Claim.lower("", sq[a], sq[b], unit="m^2")
                              for a, b in zip(stds, stds[1:])])]

    def summarize(self, config: MultilaterationConfig, results: pd.DataFrame,
                  out_dir: Path) -> Summary:
        """RMSE and CRB per noise level, the claims and the figure, from ``results``.

        Parameters
        ----------
        config : MultilaterationConfig
        results : DataFrame
            The blocks of :meth:`run_block`.
        out_dir : Path
            Where the figure goes.

        Returns
        -------
        Summary
        """
        g = results.groupby("range_std_m")
        table = pd.DataFrame({
            "rmse": np.sqrt(g["error_m"].apply(lambda e: np.mean(e**2))),
            "crb": np.sqrt(g["crb_trace_m2"].mean()),
            "mean": g["error_m"].mean(),
        })
        table["efficiency"] = table["rmse"] / table["crb"]
        metrics = []
        for std, gg in g:
            tag = f"{std:g}".replace(".", "p")
            metrics += [
                Metric.over_runs(f"gn_rmse_m_std{tag}", gg["error_m"] ** 2, None, "m",
                                 "Gauss-Newton RMSE (interval over runs)", stat="rms"),
                Metric.over_runs(f"crb_rmse_m_std{tag}", gg["crb_trace_m2"], None, "m",
                                 "sqrt(mean trace CRB) over the runs' node positions",
                                 stat="rms"),
            ]
        claims = self.claims(config, results)

        fig, (ax, ax2) = figure(1, 2, width=10.0, height=4.0)
        ax.loglog(table.index, table["rmse"], "o-", color=COLORS["ours"], label="Gauss-Newton RMSE")
        ax.loglog(table.index, table["crb"], LINESTYLES["bound"], color=COLORS["bound"],
                  label="CRB (sqrt mean trace)")
        ax.set_xlabel("range noise standard deviation [m]")
        ax.set_ylabel("position RMSE [m]")
        ax.set_title("RMSE and Cramer-Rao bound")
        ax.legend()
        ax2.semilogx(table.index, table["efficiency"], "o-", color=COLORS["ours"])
        ax2.axhline(1.0, color=COLORS["bound"], ls=LINESTYLES["bound"], label="bound attained")
        ax2.axhspan(1.0, 1.0 + config.efficiency_tolerance, color=COLORS["truth"], alpha=0.12,
                    label=f"within {config.efficiency_tolerance:.0%} of the bound")
        ax2.set_xlabel("range noise standard deviation [m]")
        ax2.set_ylabel("RMSE / CRB")
        ax2.set_title("Efficiency")
        ax2.legend()
        fig.suptitle(f"Multilateration, 4 anchors on a {config.side_m:g} m square, "
                     f"{config.runs} runs")
        save(fig, out_dir / "rmse_vs_noise.png", caption=(
            "Static Gauss-Newton multilateration to 4 anchors: position RMSE and the "
            "Cramer-Rao bound against the range noise standard deviation (left) and their "
            "ratio, the efficiency (right)."))
        notes = [f"efficiency RMSE/CRB at std {k:g} m: {v:.3f}" for k, v in table["efficiency"].items()]
        return Summary(metrics, claims, notes)
