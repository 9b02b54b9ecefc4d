"""Paper 001 (Ekambaram & Ramchandran): peer-to-peer particle filter on a highway, Fig. 4.

Table 4(c): mean error of the particle filter (PF) and the genie-aided local ML and the
LOS detection probability P_d for alpha in {5, 15, 30, 45}%; table 4(d): PF mean error for
five (anchors, vehicles) pairs at alpha = 30%; the RANSAC row at alpha = 30%; Fig. 4(a)
error CDFs; Fig. 4(b) true and estimated trajectories. Extra rows at alpha = 30% measure
what the one-step lag of the neighbours' messages costs and run the earlier centre-line
anchor layout (labelled variants); the genie ML is read twice, as a global snapshot search
and as a local search around its previous estimate. ``-o lag_ablation=1`` adds the message-lag
ablation: alpha 5 -> 45 % and N 20 -> 30, ``previous`` and ``extrapolated`` messages, each
with the paper's one-step lag and without it (``P2PParticleFilter(message_lag=0)``), every
reading of a setting on the same simulated data and the same filter draws. The online EM the paper names
(Sect. V) runs inside the filter, started from wrong parameters, and its estimates of
alpha, s_LOS and s_NLOS are reported against the truth.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError
from radioloc.core.metrics import error_cdf, position_error
from radioloc.core.rng import stream
from radioloc.estimators.ekf_ranging import run_peer_ekf
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.estimators.p2p_particle import OnlineEM, P2PParticleFilter
from radioloc.estimators.snapshot_baselines import LocalML, Ransac
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, per_run, register
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import InputDriven
from radioloc.report.style import COLORS, figure, save
from radioloc.sim.highway import HighwayData, HighwayScenario, anchor_layout, simulate

PAPER_C = {5: (0.43, 1.04, 1.05), 15: (0.52, 0.99, 1.01), 30: (0.61, 0.93, 0.94),
           45: (0.68, 0.71, 0.73)}
PAPER_D = {(26, 20): 0.93, (26, 24): 0.82, (26, 30): 0.76, (30, 20): 0.74, (36, 20): 0.70}


@dataclass(frozen=True)
class HighwayConfig:
    """Settings of ``p001-highway``.

    Paper values (Fig. 4): s_INS = 0.1, s_LOS = 0.05, s_NLOS = 5, 900 particles, 0.2 m per
    step, M = 26, N = 20, R = 10 m, 150 m x 30 m road. Choices the paper leaves open:

    steps: 700 at full size (the vehicles, starting within ``start_width_m`` of the left
        end, cross the 150 m road at 0.2 m/step).
    start_width_m: starting x uniform in [0, start_width_m]; y uniform in the road minus
        the curve amplitude. 20 m gives about 8 other vehicles within R, as the paper says.
    layout: anchor layout, see :mod:`radioloc.sim.highway`. "staggered" (three staggered
        rows, 9/8/9 for M = 26) puts every point of the road within R of an anchor. The
        earlier "centre" line (closest to the paper's "about 4 anchors in range", 2.5 on
        average, but 12% of vehicle-steps in the outer lanes hear no anchor) is run as a
        labelled variant (``layout_variants``, at ``layout_variant_alphas``).
    init_std_m, reset_fraction, reset_std_m, resampling: see P2PParticleFilter (init_std).
    ransac_threshold_m: inlier gate of RANSAC (3 s_LOS).
    ml_every: the genie ML (both readings) and RANSAC are evaluated every this many steps
        (cost: they search about 1400 candidate positions per vehicle and step; 5 at full
        size, i.e. 140 of the 700 steps of every run).
    ml_local_radius_m: half width of the local reading of the genie ML: the search is a
        square of this half width around the ML's previous estimate moved by the INS
        readings since (the start: the true start, as the PF's p(v_0) mean).
    lag_variants: message variants run at alpha = 30% besides the paper's "previous".
    layout_variants, layout_variant_alphas: other anchor layouts run (PF only, paper's
        messages) at these alphas, M = 26, N = 20.
    em_alphas: alphas at which the PF with online EM (``OnlineEM``) runs, M = 26, N = 20,
        paper's messages.
    em_initial: (s_LOS, s_NLOS, alpha) the online EM starts from (the truth: 0.05 m,
        5 m, the case's alpha).
    em_step_exponent, em_burn_in: see ``OnlineEM``.
    lag_ablation: also run the message-lag ablation (labelled rows, method
        ``pf_lag_ablation``): the PF with ``lag_ablation_messages`` messages, lag 1 (the
        paper) and lag 0 (the neighbours' estimates of the same step), at alpha in
        ``lag_ablation_alphas`` (N = 20) and at N in ``lag_ablation_vehicles`` (alpha =
        30 %), M = 26. Off by default: at full size it costs about as much as every other
        row together. Every reading of a setting sees the same data and filter draws.
    variant_runs: the variant rows (message lag, other layouts, online EM, the lag ablation;
        none is a row of
        tables 4(c) or 4(d)) run on the runs with index below this only (None: every run).
        4 at full size: a variant row then averages 4 x 20 vehicles x 700 steps = 56,000
        vehicle-steps, and the five variant cases no longer cost 38 % of the PF's time on
        the other 6 runs (the cost that kept ``--full`` above 10 minutes on 2 cores).
    """

    runs: int = 10
    block_size: int = 1
    steps: int = 700
    particles: int = 900
    alphas: tuple[float, ...] = (0.05, 0.15, 0.30, 0.45)
    table_d: tuple[tuple[int, int], ...] = ((26, 20), (26, 24), (26, 30), (30, 20), (36, 20))
    los_std_m: float = 0.05
    nlos_mean_m: float = 5.0
    ins_std_m: float = 0.1
    radius_m: float = 10.0
    start_width_m: float = 20.0
    layout: str = "staggered"
    init_std_m: float = 1.0
    reset_fraction: float = 0.05
    reset_std_m: float = 0.5
    resampling: str = "systematic"
    ransac_threshold_m: float = 0.15
    ml_every: int = 1
    ml_local_radius_m: float = 2.0
    lag_variants: tuple[str, ...] = ("extrapolated", "given")
    layout_variants: tuple[str, ...] = ("centre",)
    layout_variant_alphas: tuple[float, ...] = (0.30,)
    em_alphas: tuple[float, ...] = (0.05, 0.30)
    em_initial: tuple[float, float, float] = (0.15, 2.0, 0.5)
    em_step_exponent: float = 0.6
    em_burn_in: int = 20
    variant_runs: int | None = None
    lag_ablation: bool = False
    lag_ablation_alphas: tuple[float, ...] = (0.05, 0.45)
    lag_ablation_vehicles: tuple[int, ...] = (20, 30)
    lag_ablation_messages: tuple[str, ...] = ("previous", "extrapolated")


def _cases(c: HighwayConfig) -> list[dict]:
    lay = c.layout
    cases = [dict(alpha=a, M=26, N=20, messages="previous", ml=True, layout=lay) for a in c.alphas]
    cases += [dict(alpha=0.30, M=m, N=n, messages="previous", ml=False, layout=lay)
              for m, n in c.table_d if (m, n) != (26, 20)]
    cases += [dict(alpha=0.30, M=26, N=20, messages=v, ml=False, layout=lay, variant=True)
              for v in c.lag_variants]
    cases += [dict(alpha=a, M=26, N=20, messages="previous", ml=False, layout=v, variant=True)
              for v in c.layout_variants if v != lay for a in c.layout_variant_alphas]
    cases += [dict(alpha=a, M=26, N=20, messages="previous", ml=False, layout=lay, em=True,
                   variant=True) for a in c.em_alphas]
    return cases


def _ablation_settings(c: HighwayConfig) -> list[tuple[float, int]]:
    """(alpha, N) of the message-lag ablation, M = 26, in order."""
    if not c.lag_ablation:
        return []
    bad = set(c.lag_ablation_messages) - {"previous", "extrapolated"}
    if bad:
        raise ConfigError(f"lag_ablation_messages: {sorted(bad)} not estimated messages; "
                          "expected 'previous' and/or 'extrapolated'")
    out = [(a, 20) for a in c.lag_ablation_alphas]
    out += [(0.30, n) for n in c.lag_ablation_vehicles if (0.30, n) not in out]
    return out


def _snapshot(data: HighwayData, model: LosNlosRange, c: HighwayConfig, steps: np.ndarray):
    """Genie ML (global and local search) and RANSAC (true neighbour positions) at the
    given steps.

    Returns three arrays (R, N, S, 2); one snapshot call per step (the candidate sets of a
    whole run at once would not fit in memory). The local ML searches around its previous
    estimate (at the first step: the true start) moved by the INS readings since.
    """
    nodes = data.node_positions()                                         # (R, T, J, 2)
    ml_est = LocalML(model, c.radius_m)
    local_est = LocalML(model, c.radius_m, search_radius_m=c.ml_local_radius_m)
    rs_est = Ransac(c.ransac_threshold_m, c.radius_m)
    # dead reckoning: drift[..., s, :] = sum of the INS readings of steps 1..s
    drift = np.concatenate([np.zeros_like(data.ins[:, :, :1]), np.cumsum(data.ins, axis=2)], axis=2)
    prev, prev_step = data.truth[:, :, 0], 0
    ml, local, rs = [], [], []
    for t in steps:
        ranges, centres = data.ranges[:, :, t], nodes[:, None, t]          # (R, N, J), (R, 1, J, 2)
        ml.append(ml_est.locate(ranges, centres).position)
        centre = prev + drift[:, :, t + 1] - drift[:, :, prev_step]
        prev, prev_step = local_est.locate(ranges, centres, search_centre=centre).position, t + 1
        local.append(prev)
        rs.append(rs_est.locate(ranges, centres).position)
    return np.stack(ml, axis=2), np.stack(local, axis=2), np.stack(rs, axis=2)


def _frame(case: dict, runs: np.ndarray, method: str, steps: np.ndarray, est: np.ndarray,
           truth: np.ndarray, extra: dict | None = None) -> pd.DataFrame:
    """Rows (run, step, vehicle) of estimates ``est`` and ``truth`` (R, N, S, 2) and
    per-vehicle-step ``extra`` columns (R, N, S)."""
    est, truth = np.moveaxis(est, 1, 2), np.moveaxis(truth, 1, 2)          # (R, S, N, 2)
    r, s, n = est.shape[:3]
    idx = np.indices((r, s, n)).reshape(3, -1)
    cols = {"alpha": case["alpha"], "M": case["M"], "N": case["N"],
            "messages": case["messages"], "layout": case["layout"], "method": method,
            "run": runs[idx[0]], "step": steps[idx[1]] + 1, "vehicle": idx[2],
            "x_est": est[..., 0].ravel(), "y_est": est[..., 1].ravel(),
            "x_true": truth[..., 0].ravel(), "y_true": truth[..., 1].ravel(),
            "error_m": position_error(est, truth).ravel()}
    for k, v in (extra or {}).items():
        cols[k] = np.moveaxis(v, 1, 2).ravel()
    return pd.DataFrame(cols)


@register
class HighwayExperiment(Experiment):
    """``p001-highway``: tables 4(c), 4(d) and Fig. 4 of paper 001 (see the module docstring)."""

    id = "p001-highway"
    paper = "001"
    description = "P2P particle filter with LOS/NLOS link states on a highway: tables 4(c), 4(d), Fig. 4"

    def config(self, full: bool) -> HighwayConfig:
        """The settings of the quick or the full size.

        Parameters
        ----------
        full : bool
            The paper's size instead of the quick one.

        Returns
        -------
        HighwayConfig
        """
        if full:
            return HighwayConfig(ml_every=5, variant_runs=4)
        return HighwayConfig(runs=6, steps=40, particles=200, ml_every=4)

    def run_block(self, config: HighwayConfig, runs: np.ndarray,
                  rng: np.random.Generator) -> pd.DataFrame:
        """Simulate (or load) and estimate the runs of one block.

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
            The tidy results table (one row per method, run, step and vehicle).
        """
        c = config
        ablation = _ablation_settings(c)            # checked before the long cases run
        frames = []
        for case in _cases(c):
            model = LosNlosRange(c.los_std_m, c.nlos_mean_m, case["alpha"])
            sc = HighwayScenario(vehicles=case["N"], anchors=case["M"], steps=c.steps,
                                 radius_m=c.radius_m, ins_std_m=c.ins_std_m,
                                 start_width_m=c.start_width_m, layout=case["layout"])
            # the layout is a per-experiment draw (only "uniform" uses the stream)
            anchors = anchor_layout(case["layout"], case["M"], sc.length_m, sc.width_m,
                                    rng=stream(rng, f"anchor-layout-M{case['M']}"))
            data = simulate(sc, model, runs.size, rng, anchors=anchors)
            case_runs = runs
            if case.get("variant") and c.variant_runs is not None:
                keep = runs < c.variant_runs
                if not keep.any():
                    continue
                case_runs = runs[keep]
                data = replace(data, truth=data.truth[keep], ins=data.ins[keep],
                               ranges=data.ranges[keep], los=data.los[keep])
            em = case.get("em", False)
            pf = P2PParticleFilter(InputDriven(c.ins_std_m),
                                   LosNlosRange(*c.em_initial) if em else model,
                                   particles=c.particles,
                                   resampling=c.resampling, init_std=c.init_std_m,
                                   reset_fraction=c.reset_fraction, reset_std_m=c.reset_std_m,
                                   messages=case["messages"],
                                   online_em=OnlineEM(c.em_step_exponent, c.em_burn_in) if em else False)
            truth = data.truth[:, :, 1:]                                  # (R, N, T, 2)
            res = pf.run(data.ranges, data.truth[:, :, 0], rng, anchors=data.anchors,
                         controls=data.ins, given_positions=truth)
            in_range = data.in_range
            los = in_range & data.los
            det = res.diagnostics["los_detected"]
            all_steps = np.arange(c.steps)
            extra = {"los_links": los.sum(-1), "los_detected": (det & los).sum(-1),
                     "nlos_as_los": (det & in_range & ~data.los).sum(-1)}
            if em:
                par = res.diagnostics["em_parameters"]                    # (R, N, T, 3)
                extra.update(em_los_std_m=par[..., 0], em_nlos_mean_m=par[..., 1],
                             em_alpha=par[..., 2])
            frames.append(_frame(case, case_runs, "pf_em" if em else "pf", all_steps, res.position,
                                 truth, extra))
            if case["ml"]:
                sub = all_steps[::c.ml_every]
                ml, local, rs = _snapshot(data, model, c, sub)
                frames.append(_frame(case, case_runs, "ml", sub, ml, truth[:, :, sub]))
                frames.append(_frame(case, case_runs, "ml_local", sub, local, truth[:, :, sub]))
                frames.append(_frame(case, case_runs, "ransac", sub, rs, truth[:, :, sub]))
                ekf = run_peer_ekf(RangeEKF(InputDriven(c.ins_std_m), model, gate=None),
                                   data.ranges, data.truth[:, :, 0], init_std_m=c.init_std_m,
                                   anchors=data.anchors, controls=data.ins)
                frames.append(_frame(case, case_runs, "ekf", all_steps, ekf.position, truth))
        frames += self._lag_ablation(c, ablation, runs, rng)
        return pd.concat(frames, ignore_index=True)

    @staticmethod
    def _lag_ablation(c: HighwayConfig, settings: list, runs: np.ndarray,
                      rng: np.random.Generator) -> list:
        """The message-lag ablation rows (after every other case, so those keep their draws):
        per setting one simulation and one filter seed shared by every reading."""
        if c.variant_runs is not None:
            runs = runs[runs < c.variant_runs]
        frames = []
        for alpha, n_veh in settings if runs.size else []:
            model = LosNlosRange(c.los_std_m, c.nlos_mean_m, alpha)
            sc = HighwayScenario(vehicles=n_veh, anchors=26, steps=c.steps, radius_m=c.radius_m,
                                 ins_std_m=c.ins_std_m, start_width_m=c.start_width_m,
                                 layout=c.layout)
            anchors = anchor_layout(c.layout, 26, sc.length_m, sc.width_m,
                                    rng=stream(rng, "anchor-layout-M26"))
            data = simulate(sc, model, runs.size, rng, anchors=anchors)
            seed = int(rng.integers(2**63))
            truth = data.truth[:, :, 1:]
            for messages in c.lag_ablation_messages:
                for lag in (1, 0):
                    pf = P2PParticleFilter(InputDriven(c.ins_std_m), model, particles=c.particles,
                                           resampling=c.resampling, init_std=c.init_std_m,
                                           reset_fraction=c.reset_fraction,
                                           reset_std_m=c.reset_std_m, messages=messages,
                                           message_lag=lag)
                    res = pf.run(data.ranges, data.truth[:, :, 0], np.random.default_rng(seed),
                                 anchors=data.anchors, controls=data.ins)
                    case = dict(alpha=alpha, M=26, N=n_veh, messages=messages, layout=c.layout)
                    lags = np.full(res.position.shape[:-1], lag)
                    frames.append(_frame(case, runs, "pf_lag_ablation", np.arange(c.steps),
                                         res.position, truth, {"message_lag": lags}))
        return frames

    def summarize(self, config: HighwayConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Metrics, claims and figures from the results table only.

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
        r = results
        ablation = r[r.method == "pf_lag_ablation"]
        r = r[r.method != "pf_lag_ablation"]
        variants = r[r.layout != config.layout]
        r = r[r.layout == config.layout]
        prev = r[r.messages == "previous"]
        base = prev[(prev.M == 26) & (prev.N == 20)]
        metrics, notes, claims = [], [], []
        pf_c, ml_c, mll_c, pd_c = {}, {}, {}, {}
        # one number per run: the vehicles of a run exchange messages, so they are not
        # independent units; the runs are
        unit = ("run",)

        def over(name, rows, paper, u, note, col="error_m"):
            return Metric.over_runs(name, per_run(rows, col, unit), paper, u, note)

        for a, g in base.groupby("alpha"):
            tag = int(round(a * 100))
            pf = g[g.method == "pf"]
            pf_c[tag] = pf.error_m.mean()
            ml_c[tag] = g[g.method == "ml"].error_m.mean()
            mll_c[tag] = g[g.method == "ml_local"].error_m.mean()
            pd_c[tag] = pf.los_detected.sum() / max(pf.los_links.sum(), 1)
            paper = PAPER_C.get(tag, (None, None, None))
            pd_rows = pf.assign(pd=pf.los_detected / pf.los_links.where(pf.los_links > 0))
            metrics += [
                over(f"pf_mean_error_m_alpha{tag}", pf, paper[1], "m", "particle filter, table 4(c)"),
                over(f"ml_mean_error_m_alpha{tag}", g[g.method == "ml"], paper[2], "m",
                     "genie local ML, table 4(c); reading: global snapshot search"),
                over(f"ml_local_mean_error_m_alpha{tag}", g[g.method == "ml_local"], paper[2], "m",
                     "genie local ML, table 4(c); reading: local search within "
                     f"+-{config.ml_local_radius_m:g} m of its previous estimate moved by the INS"),
                over(f"pd_alpha{tag}", pd_rows, paper[0], "",
                     "LOS detection probability, mean over vehicle-steps of the detected "
                     "fraction of their LOS links", col="pd"),
                over(f"ekf_mean_error_m_alpha{tag}", g[g.method == "ekf"], None, "m",
                     "Gaussian EKF (moment-matched noise), same messages as the PF"),
                over(f"ransac_mean_error_m_alpha{tag}", g[g.method == "ransac"], None, "m",
                     "RANSAC multilateration, genie neighbour positions"),
            ]
        a30 = prev[(prev.alpha == 0.30) & (prev.method == "pf")]
        pf_d = {}
        for (m, n), g in a30.groupby(["M", "N"]):
            pf_d[(m, n)] = g.error_m.mean()
            metrics.append(over(f"pf_mean_error_m_M{m}_N{n}", g, PAPER_D.get((m, n)), "m",
                                "particle filter, table 4(d)"))
        v30 = r[(r.alpha == 0.30) & (r.M == 26) & (r.N == 20) & (r.method == "pf")]
        for v, g in v30.groupby("messages"):
            if v != "previous":
                metrics.append(over(f"pf_mean_error_m_alpha30_messages_{v}", g, None, "m",
                                    f"variant: neighbour positions = {v} (paper: previous estimates)"))
        vpf = variants[(variants.method == "pf") & (variants.messages == "previous")]
        for (lay, a), g in vpf.groupby(["layout", "alpha"]):
            tag = int(round(a * 100))
            metrics.append(over(f"pf_mean_error_m_alpha{tag}_layout_{lay}", g,
                                PAPER_C.get(tag, (None, None, None))[1], "m",
                                f"variant: anchor layout {lay} (default: {config.layout}), table 4(c)"))
        em_rows = r[r.method == "pf_em"]
        for a, g in em_rows.groupby("alpha"):
            tag = int(round(a * 100))
            last = g[g.step == g.step.max()]
            truth = {"em_alpha": a, "em_los_std_m": config.los_std_m, "em_nlos_mean_m": config.nlos_mean_m}
            start = dict(zip(("em_los_std_m", "em_nlos_mean_m", "em_alpha"), config.em_initial))
            metrics.append(over(f"pf_em_mean_error_m_alpha{tag}", g, PAPER_C.get(tag, (None,) * 3)[1],
                                "m", "variant: PF with online EM from wrong parameters "
                                  f"(s_LOS, s_NLOS, alpha) = {config.em_initial}, table 4(c)"))
            for col, u in (("em_alpha", ""), ("em_los_std_m", "m"), ("em_nlos_mean_m", "m")):
                metrics.append(over(f"{col}_final_alpha{tag}", last, None, u,
                                    f"online EM estimate at the last step, mean over vehicles "
                                    f"(truth {truth[col]:g}, start {start[col]:g})", col=col))
        m_abl, c_abl, n_abl = self._lag_ablation_summary(ablation)
        metrics += m_abl
        notes += n_abl
        # claims: paired over the same runs

        def units(g, method, a=None):
            sel = g.method == method if a is None else (g.method == method) & np.isclose(g.alpha, a / 100)
            return per_run(g[sel], "error_m", unit)

        if 30 in ml_c:
            claims.append(Claim.above("RANSAC-based methods have errors over 5 m (alpha = 30%)",
                                      units(base, "ransac", 30), 5.0, "m"))
        if pf_c:
            tags = sorted(pf_c)
            for ml, reading in (("ml", "global snapshot search"),
                                ("ml_local", "local search around its previous estimate")):
                claims.append(Claim.all_of(
                    f"PF is slightly better than the genie local ML at every alpha (ML reading: {reading})",
                    [Claim.lower("", units(base, "pf", a), units(base, ml, a), unit="m") for a in tags]))
            claims.append(Claim.all_of("the PF beats the Gaussian EKF at every alpha",
                                       [Claim.lower("", units(base, "pf", a), units(base, "ekf", a),
                                                    unit="m") for a in tags]))
            claims.append(Claim.all_of("PF mean error decreases as alpha grows",
                                       [Claim.lower("", units(base, "pf", b), units(base, "pf", a),
                                                    unit="m") for a, b in zip(tags, tags[1:])]))
            pf_rows = base[base.method == "pf"]
            link_sums = pf_rows.groupby(["alpha", *unit])[["los_detected", "los_links"]].sum()
            pd_units = {int(round(a * 100)): (g["los_detected"] / g["los_links"].where(g["los_links"] > 0))
                        .droplevel("alpha") for a, g in link_sums.groupby(level="alpha")}
            claims.append(Claim.all_of("P_d increases with alpha",
                                       [Claim.lower("", pd_units[a], pd_units[b]) for a, b in zip(tags, tags[1:])]))
        if 5 in pf_c:
            e5 = base[(base.alpha == 0.05) & (base.method == "pf")]
            frac = float((e5.error_m < 1.5).mean())
            notes.append(f"alpha = 5%: fraction of PF errors below 1.5 m = {frac:.3f}")
            claims.append(Claim.above("at alpha = 5% more than 80% of the errors are below 1.5 m",
                                      per_run(e5.assign(below=e5.error_m < 1.5), "below", unit), 0.8))
        if len(pf_d) == 5:
            d = {k: per_run(g, "error_m", unit) for k, g in a30.groupby(["M", "N"])}
            claims.append(Claim.all_of(
                "more anchors (26 -> 30 -> 36) lower the PF error, with diminishing returns",
                [Claim.lower("", d[30, 20], d[26, 20], unit="m"),
                 Claim.lower("", d[36, 20], d[30, 20], unit="m"),
                 Claim.decide("", (d[26, 20] - 2 * d[30, 20] + d[36, 20]).dropna(), low=0.0,
                              unit="m", what="mean paired (26 - 30) - (30 - 36) gain")]))
            claims.append(Claim.all_of("more vehicles (20 -> 24 -> 30) lower the PF error",
                                       [Claim.lower("", d[26, 24], d[26, 20], unit="m"),
                                        Claim.lower("", d[26, 30], d[26, 24], unit="m")]))
        claims += c_abl
        if not base.empty:
            self._figures(config, base, out_dir)
        self._lag_figure(r, variants, out_dir)
        self._em_figure(config, em_rows, out_dir)
        notes.append(f"runs={config.runs}, steps={config.steps}, particles={config.particles}, "
                     f"layout={config.layout}, ML/RANSAC every {config.ml_every} steps"
                     + ("" if config.variant_runs is None else
                        f"; variant rows (message lag, other layouts, online EM) on runs "
                        f"0-{config.variant_runs - 1} only"))
        if "x_true" in r and len(r):
            off = float(((r.x_true < 0) | (r.x_true > HighwayScenario().length_m)).mean())
            notes.append(f"fraction of vehicle-step rows off the road: {off:.4f}")
        return Summary(metrics, claims, notes)

    @staticmethod
    def _lag_ablation_summary(abl: pd.DataFrame) -> tuple[list, list, list]:
        """Metrics, claims and the table note of the message-lag ablation rows."""
        if abl.empty:
            return [], [], []
        groups = abl.groupby(["alpha", "N", "messages", "message_lag"])
        runs = {(int(round(a * 100)), int(n), v, int(lag)): per_run(g, "error_m")
                for (a, n, v, lag), g in groups}
        get = {k: float(v.mean()) for k, v in runs.items()}
        metrics, claims = [], []
        for (tag, n, v, lag), values in runs.items():
            paper = PAPER_C[tag][1] if n == 20 and tag in PAPER_C else PAPER_D.get((26, n))
            metrics.append(Metric.over_runs(
                f"pf_mean_error_m_alpha{tag}_N{n}_{v}_lag{lag}", values, paper, "m",
                f"ablation: PF, {v} messages, "
                + ("one-step lag (the paper's timing)" if lag else
                   "no lag (the neighbours' estimates of the same step)")
                + "; same data and draws for every reading of this (alpha, N)"))
        names = sorted({k[2] for k in get}, key=lambda v: (v != "previous", v))
        readings = [(v, lag) for v in names for lag in (1, 0)]
        alphas = sorted({k[0] for k in get if k[1] == 20})
        vehicles = sorted({k[1] for k in get if k[0] == 30})
        rows = [(f"alpha {a} %, N = 20", (a, 20)) for a in alphas]
        rows += [(f"alpha 30 %, N = {n}", (30, n)) for n in vehicles if (30, n) not in
                 [key for _, key in rows]]
        head = "| setting | " + " | ".join(f"{v}, lag {lag}" for v, lag in readings) + " |"
        lines = [head, "|---" * (len(readings) + 1) + "|"]
        for label, (a, n) in rows:
            lines.append(f"| {label} | " + " | ".join(
                f"{get[a, n, v, lag]:.3f}" if (a, n, v, lag) in get else "-"
                for v, lag in readings) + " |")
        for v, lag in readings:
            what = f"ablation ({v} messages, " + ("one-step lag)" if lag else "no lag)")
            if len(alphas) >= 2 and all((a, 20, v, lag) in get for a in alphas):
                lo, hi = alphas[0], alphas[-1]
                claims.append(Claim.lower(f"{what}: PF mean error decreases as alpha grows "
                                          f"({lo} -> {hi} %)", runs[hi, 20, v, lag],
                                          runs[lo, 20, v, lag], unit="m"))
            if len(vehicles) >= 2 and all((30, n, v, lag) in get for n in vehicles):
                lo, hi = vehicles[0], vehicles[-1]
                claims.append(Claim.lower(f"{what}: more vehicles ({lo} -> {hi}) lower the PF "
                                          "error", runs[30, hi, v, lag], runs[30, lo, v, lag],
                                          unit="m"))
        note = ("message-lag ablation, PF mean error [m] (M = 26):\n" + "\n".join(lines))
        return metrics, claims, [note]

    @staticmethod
    def _lag_figure(r: pd.DataFrame, variants: pd.DataFrame, out_dir: Path) -> None:
        g = r[(r.method == "pf") & (r.M == 26) & (r.N == 20) & np.isclose(r.alpha, 0.30)]
        lay = variants[(variants.method == "pf") & np.isclose(variants.alpha, 0.30)
                       & (variants.messages == "previous")]
        if g.empty:
            return
        fig, ax = figure(width=6.4, height=4.6, layout="constrained")
        styles = {"previous": COLORS["ours"], "extrapolated": COLORS["alt"], "given": COLORS["truth"]}
        labels = {"previous": "previous estimates (paper)", "extrapolated": "previous + neighbour's INS",
                  "given": "true neighbour positions"}
        for v, gv in g.groupby("messages"):
            curve = gv.groupby("step").error_m.mean()
            ax.plot(curve.index, curve.to_numpy(), color=styles.get(v, COLORS["alt2"]), label=labels.get(v, v))
        for v, gv in lay.groupby("layout"):
            curve = gv.groupby("step").error_m.mean()
            ax.plot(curve.index, curve.to_numpy(), "--", color=COLORS["baseline"],
                    label=f"previous estimates, variant: {v} anchor layout")
        ax.set_xlabel("step (0.2 m per step)")
        ax.set_ylabel("PF mean error over vehicles and runs [m]")
        ax.set_title("Message lag and anchor layout, alpha = 30%, M = 26, N = 20")
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=2,
                   fontsize=8)
        save(fig, out_dir / "message_lag_error_vs_step.png", caption=(
            "Particle filter mean error over vehicles and runs against the step (alpha = 30 %, "
            "M = 26 anchors, N = 20 vehicles) when a vehicle uses its neighbours' previous "
            "estimates (the paper), those advanced by the neighbour's INS, or their true "
            "positions; dashed: the paper's messages with another anchor layout."))

    @staticmethod
    def _em_figure(config: HighwayConfig, em_rows: pd.DataFrame, out_dir: Path) -> None:
        if em_rows.empty:
            return
        fig, axes = figure(width=10.0, height=3.8, ncols=3, layout="constrained")
        palette = [COLORS["ours"], COLORS["alt"], COLORS["truth"], COLORS["alt2"]]
        cols = (("em_alpha", "alpha (LOS fraction)"), ("em_los_std_m", "s_LOS [m]"),
                ("em_nlos_mean_m", "s_NLOS [m]"))
        for (a, g), col in zip(em_rows.groupby("alpha"), palette):
            curves = g.groupby("step")[[c for c, _ in cols]].mean()
            truth = {"em_alpha": a, "em_los_std_m": config.los_std_m, "em_nlos_mean_m": config.nlos_mean_m}
            for ax, (c, label) in zip(axes, cols):
                ax.plot(curves.index, curves[c].to_numpy(), color=col, label=f"estimate, alpha = {a:.0%}")
                shared = c != "em_alpha"                   # s_LOS, s_NLOS: one truth for all
                ax.axhline(truth[c], color="black" if shared else col, ls="--", lw=1,
                           label=None if shared else f"truth, alpha = {a:.0%}")
                ax.set_xlabel("step")
                ax.set_title(label)
        axes[1].set_yscale("log")
        axes[0].set_ylabel("mean over vehicles and runs")
        handles, labels = axes[0].get_legend_handles_labels()
        fig.legend(handles, labels, loc="outside lower center", ncol=len(labels), fontsize=8)
        fig.suptitle("Online EM inside the PF (M = 26, N = 20): estimates vs truth (dashed)")
        save(fig, out_dir / "online_em_estimates_vs_step.png", caption=(
            "Online EM of the LOS/NLOS parameters inside the particle filter (M = 26, N = 20): "
            "the estimated LOS fraction alpha, LOS noise s_LOS and NLOS bias s_NLOS, mean over "
            "vehicles and runs, against the step, with the simulated values dashed."))

    @staticmethod
    def _figures(config: HighwayConfig, base: pd.DataFrame, out_dir: Path) -> None:
        fig, ax = figure()
        palette = [COLORS["ours"], COLORS["alt"], COLORS["truth"], COLORS["alt2"]]
        for (a, g), col in zip(base.groupby("alpha"), palette):
            for meth, ls in (("pf", "-"), ("ml", "--")):
                e = g[g.method == meth].error_m.to_numpy()
                if e.size:
                    x, p = error_cdf(e)
                    ax.plot(x, p, ls, color=col, label=f"{meth.upper()}, alpha = {a:.0%}")
        ax.set_xlim(0, 4)
        ax.set_xlabel("localization error [m]")
        ax.set_ylabel("CDF")
        ax.set_title("Fig. 4(a): error CDF (solid: particle filter, dashed: genie local ML)")
        ax.legend(ncol=2)
        save(fig, out_dir / "fig4a_error_cdf.png", caption=(
            "Fig. 4(a) of paper 001: cumulative density function of localization error as a "
            "function of alpha (the fraction of LOS signals); solid: the proposed particle "
            "filter, dashed: the local maximum-likelihood algorithm (genie LOS/NLOS labels). "
            "M = 26 anchors, N = 20 vehicles."))

        alpha = 0.15 if np.any(np.isclose(base.alpha, 0.15)) else base.alpha.iloc[0]
        g = base[np.isclose(base.alpha, alpha) & (base.method == "pf") & (base.run == base.run.min())]
        fig, ax = figure(width=8.0, height=3.6)
        for i, (v, gv) in enumerate(g.groupby("vehicle")):
            if i >= 6:
                break
            ax.plot(gv.x_true, gv.y_true, "-", color=COLORS["truth"], lw=1.2,
                    label="true" if i == 0 else None)
            ax.plot(gv.x_est, gv.y_est, ".", color=COLORS["ours"], ms=2, alpha=0.5,
                    label="PF estimates" if i == 0 else None)
            deg = min(3, max(len(gv) - 1, 0))
            coef = np.polyfit(gv.x_est, gv.y_est, deg)
            xs = np.linspace(gv.x_est.min(), gv.x_est.max(), 100)
            ax.plot(xs, np.polyval(coef, xs), "--", color=COLORS["baseline"], lw=1.2,
                    label=f"polynomial fit (degree {deg})" if i == 0 else None)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_ylim(0, 30)
        ax.set_title(f"Fig. 4(b): true and estimated trajectories, alpha = {alpha:.0%} (6 vehicles)")
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=3)
        save(fig, out_dir / "fig4b_trajectories.png", caption=(
            f"Fig. 4(b) of paper 001: true and estimated vehicle trajectories for the proposed "
            f"algorithm, alpha = {alpha:.0%} (six vehicles of one run; dots: particle filter "
            "estimates, dashed: a polynomial fit through them)."))
