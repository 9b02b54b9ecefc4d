"""Paper 000, complete radiolocation simulation (Figs. 3, 4): urban multipath, DS-CDMA
RTS/ACK ranging with GSIC, then the distributed RLS and EKF.

Six nodes stand on the streets of a seeded synthetic city (:func:`city_grid`); their 15
links are ray traced once (cached). Every node is master in turn and collects ``rounds``
ACK sets (paper: 28); GSIC and the single-user matched filter turn each ACK set into
ranges. The GSIC ranges then feed the RLS (eqs. 1-12) and the EKF (eqs. 13-25) in a random
order of the ACK sets, from random priors (3 GPS-assisted nodes with prior variance
100 m^2 per axis, 3 unassisted with 10,000 m^2), ``runs`` times (paper: 5000).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.channel.cdma import CDMAConfig
from radioloc.channel.gsic import GSICConfig
from radioloc.channel.ranging import NetworkRanges, network_ranges, trace_network
from radioloc.channel.raytrace import TraceConfig, trace_links_cached
from radioloc.channel.scene import Scene, city_grid, street_positions
from radioloc.core.metrics import position_error
from radioloc.estimators.ekf import ekf_init, ekf_iteration
from radioloc.estimators.rls import rls_init, rls_iteration
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, register
from radioloc.report.style import COLORS, LINESTYLES, figure, save


@dataclass(frozen=True)
class UrbanConfig:
    """Settings of ``p000-urban``; (*) marks choices the paper leaves open.

    runs, block_size: realizations of ACK-set order and priors (paper: 5000), per block.
    rounds: ACK sets collected by every master (paper: 28).
    scene_seed, city_size_m: the synthetic city (*) (paper: an urban ray-tracing scene [15]).
    placement_seed, placement_half_width_m, candidates: node placement (*): ``candidates``
        street points in the central square are traced pairwise (order 1) and the first
        6-node set of a seeded search in which every link has a traced path is kept.
    assisted: how many nodes have GPS priors (the first ones); prior variances per axis.
    range_var_m2: range variance the EKF assumes (*): 900 m^2, one chip (the paper's note).
    channel_seed: seed of the hand-shake noise, jitter and path phases (ranges are
        simulated once per configuration, like the paper's 28 recorded ACK sets).
    trace, cdma, gsic: physical-layer settings (*), see their docstrings.
    cache_dir: ray-tracing cache (None: ~/.cache/radioloc/channels or $RADIOLOC_CACHE).
    """

    runs: int = 200
    block_size: int = 100
    rounds: int = 28
    K: int = 6
    assisted: int = 3
    prior_var_assisted_m2: float = 100.0
    prior_var_unassisted_m2: float = 10_000.0
    range_var_m2: float = 900.0
    scene_seed: int = 0
    city_size_m: float = 1000.0
    placement_seed: int = 3
    placement_half_width_m: float = 300.0
    candidates: int = 24
    channel_seed: int = 7
    trace: TraceConfig = field(default_factory=TraceConfig)
    cdma: CDMAConfig = field(default_factory=CDMAConfig)
    gsic: GSICConfig = field(default_factory=GSICConfig)
    cache_dir: str | None = None


def _scene(config: UrbanConfig) -> Scene:
    return city_grid(config.scene_seed, size_m=config.city_size_m)


def place_nodes(scene: Scene, config: UrbanConfig) -> np.ndarray:
    """``K`` street positions in which every pair has at least one traced path."""
    rng = np.random.default_rng(config.placement_seed)
    cand = street_positions(scene, config.candidates, rng, half_width_m=config.placement_half_width_m,
                            clearance_m=3.0)
    i, j = np.triu_indices(len(cand), 1)
    quick = TraceConfig(max_order=1, max_excess_m=config.trace.max_excess_m,
                        carrier_hz=config.trace.carrier_hz,
                        wall_permittivity=config.trace.wall_permittivity)
    ch = trace_links_cached(scene, cand[i], cand[j], quick, config.cache_dir)
    ok = np.zeros((len(cand), len(cand)), bool)
    ok[i, j] = ok[j, i] = ch.n_paths > 0
    # seeded depth-first search for a K-clique of the connectivity graph (small graph)
    order = rng.permutation(len(cand))

    def grow(chosen, rest):
        if len(chosen) == config.K:
            return chosen
        for n, c in enumerate(rest):
            if all(ok[c, p] for p in chosen):
                found = grow(chosen + [c], rest[n + 1:])
                if found:
                    return found
        return None

    found = grow([], list(order))
    if found is None:
        raise RuntimeError("no node set with a path on every link; change placement_seed")
    return cand[np.array(found)]


@lru_cache(maxsize=4)
def simulate(config: UrbanConfig) -> tuple[Scene, np.ndarray, NetworkRanges]:
    """Scene, node positions and the ranges of every ACK set (deterministic per config)."""
    scene = _scene(config)
    pos = place_nodes(scene, config)
    ch = trace_network(scene, pos, config.trace, config.cache_dir)
    rng = np.random.default_rng(config.channel_seed)
    ranges = network_ranges(scene, pos, config.rounds, rng, cdma=config.cdma, gsic=config.gsic,
                            channels=ch)
    return scene, pos, ranges


def range_errors(r: NetworkRanges) -> pd.DataFrame:
    """Tidy range errors: one row per (round, master, node, estimator)."""
    S, K, _ = r.gsic_m.shape
    s, k, i = np.meshgrid(np.arange(S), np.arange(K), np.arange(K), indexing="ij")
    off = k != i
    frames = []
    for name, arr in (("gsic", r.gsic_m), ("matched_filter", r.matched_filter_m)):
        frames.append(pd.DataFrame({
            "round": s[off], "master": k[off], "node": i[off], "estimator": name,
            "range_m": arr[off], "true_m": np.broadcast_to(r.true_m, arr.shape)[off],
            "los": np.broadcast_to(r.los, arr.shape)[off],
            "first_path_m": np.broadcast_to(r.first_path_m, arr.shape)[off]}))
    df = pd.concat(frames, ignore_index=True)
    df["error_m"] = df["range_m"] - df["true_m"]
    return df


@register
class UrbanRadiolocation(Experiment):
    id = "p000-urban"
    paper = "000"
    description = "Ray-traced urban channels, DS-CDMA GSIC ranging, distributed RLS/EKF (Figs. 3-4)"

    def config(self, full: bool) -> UrbanConfig:
        return UrbanConfig(runs=5000 if full else 200)

    def run_block(self, config: UrbanConfig, runs: np.ndarray,
                  rng: np.random.Generator) -> pd.DataFrame:
        _, truth, r = simulate(config)
        R, K, S = runs.size, config.K, config.rounds
        var = np.where(np.arange(K) < config.assisted, config.prior_var_assisted_m2,
                       config.prior_var_unassisted_m2)
        prior_var = np.broadcast_to(var[None, :, None], (R, K, 2))
        prior = truth[None] + rng.standard_normal((R, K, 2)) * np.sqrt(prior_var)
        perm = np.argsort(rng.random((R, K, S)), axis=-1)          # ACK-set order per master
        states = {"rls": rls_init(prior, prior_var), "ekf": ekf_init(prior, prior_var)}
        rows = []
        kk = np.arange(K)

        def record(step):
            for name, st in states.items():
                err = position_error(st.position, truth[None])           # (R, K)
                for grp, sel in (("assisted", kk < config.assisted), ("unassisted", kk >= config.assisted)):
                    rows.append(pd.DataFrame({"run": runs, "estimator": name, "step": step,
                                              "group": grp, "error_m": err[:, sel].mean(axis=1)}))
                if runs[0] == 0:                                         # trace of run 0 (Fig. 3)
                    rows.append(pd.DataFrame({"run": 0, "estimator": name, "step": step,
                                              "group": [f"node{k}" for k in kk],
                                              "error_m": err[0], "x": st.position[0, :, 0],
                                              "y": st.position[0, :, 1]}))

        record(0)
        for n in range(S):                                   # packet number (time step)
            rho = r.gsic_m[perm[:, :, n], kk[None, :], :]                # (R, K, K)
            mask = np.isfinite(rho)
            mask[:, kk, kk] = False
            # a master with fewer than 3 detected ranges sends no packet (RLS needs pairs)
            mask &= (mask.sum(axis=-1) >= 3)[..., None]
            rho = np.where(mask, rho, 0.0)
            states["rls"] = rls_iteration(states["rls"], rho, mask)
            states["ekf"] = ekf_iteration(states["ekf"], rho, mask, range_var=config.range_var_m2)
            record(n + 1)
        return pd.concat(rows, ignore_index=True)

    def summarize(self, config: UrbanConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        scene, truth, r = simulate(config)
        groups = results[results["group"].isin(["assisted", "unassisted"])]
        curve = groups.groupby(["estimator", "group", "step"])["error_m"].mean()
        last = config.rounds
        fin = {(e, g): float(curve[(e, g, last)]) for e in ("rls", "ekf") for g in ("assisted", "unassisted")}
        re = range_errors(r)
        g = re[re["estimator"] == "gsic"]
        m = re[re["estimator"] == "matched_filter"]

        def rmse(d):
            e = d["error_m"].dropna()
            return float(np.sqrt(np.mean(e**2))) if len(e) else float("nan")

        def med(d, los):
            e = d[d["los"] == los]["error_m"].dropna().abs()
            return float(e.median()) if len(e) else float("nan")

        metrics = [
            Metric("rls_final_error_unassisted_m", fin[("rls", "unassisted")], 20.0, "m",
                   f"mean error of unassisted nodes after {last} packets, RLS"),
            Metric("ekf_final_error_unassisted_m", fin[("ekf", "unassisted")], 20.0, "m",
                   f"mean error of unassisted nodes after {last} packets, EKF"),
            Metric("rls_final_error_assisted_m", fin[("rls", "assisted")], None, "m", "GPS-assisted nodes, RLS"),
            Metric("ekf_final_error_assisted_m", fin[("ekf", "assisted")], None, "m", "GPS-assisted nodes, EKF"),
            Metric("range_error_median_los_m", med(g, True), None, "m", "GSIC, median |error|, LOS links"),
            Metric("range_error_median_nlos_m", med(g, False), None, "m", "GSIC, median |error|, NLOS links"),
            Metric("mf_range_error_median_los_m", med(m, True), None, "m", "matched filter, LOS links"),
            Metric("mf_range_error_median_nlos_m", med(m, False), None, "m", "matched filter, NLOS links"),
            Metric("gsic_range_rmse_m", rmse(g), None, "m", "GSIC, detected ranges"),
            Metric("matched_filter_range_rmse_m", rmse(m), None, "m", "matched filter, detected ranges"),
            Metric("gsic_detection_rate", float(g["range_m"].notna().mean()), None, "", "ranges detected"),
            Metric("matched_filter_detection_rate", float(m["range_m"].notna().mean()), None, "", "ranges detected"),
            Metric("los_links", float(r.los[np.triu_indices(config.K, 1)].sum()), None, "",
                   f"of {config.K * (config.K - 1) // 2} links"),
        ]
        excess = (g["first_path_m"] - g["true_m"])[~g["los"]]
        toa_err = (g["range_m"] - g["first_path_m"]).dropna().abs()
        toa_err_mf = (m["range_m"] - m["first_path_m"]).dropna().abs()
        metrics += [
            Metric("first_path_excess_median_nlos_m", float(excess.median()) if len(excess) else float("nan"),
                   None, "m", "ray tracer: earliest path length minus distance, NLOS links"),
            Metric("gsic_first_path_error_median_m", float(toa_err.median()), None, "m",
                   "GSIC |range - earliest traced path|: the detector's own error"),
            Metric("matched_filter_first_path_error_median_m", float(toa_err_mf.median()), None, "m",
                   "matched filter |range - earliest traced path|"),
            Metric("gsic_first_path_within_chip", float((toa_err < 15.0).mean()), None, "",
                   "fraction of GSIC ranges within half a chip (15 m) of the earliest path"),
            Metric("matched_filter_first_path_within_chip", float((toa_err_mf < 15.0).mean()), None, "",
                   "same for the matched filter"),
        ]
        early = min(5, last)
        about = lambda v: 10.0 <= v <= 30.0  # noqa: E731  "about 20 m"
        claims = [
            Claim("the unassisted nodes' average error falls to about 20 m (RLS; taken as 10-30 m)",
                  about(fin[("rls", "unassisted")])),
            Claim("the unassisted nodes' average error falls to about 20 m (EKF; taken as 10-30 m)",
                  about(fin[("ekf", "unassisted")])),
            Claim(f"the error decreases rapidly: after {early} packets the unassisted RLS error is below "
                  "half its prior value",
                  float(curve[("rls", "unassisted", early)]) < 0.5 * float(curve[("rls", "unassisted", 0)])),
            Claim(f"the error decreases rapidly: after {early} packets the unassisted EKF error is below "
                  "half its prior value",
                  float(curve[("ekf", "unassisted", early)]) < 0.5 * float(curve[("ekf", "unassisted", 0)])),
            Claim("GSIC ranges have a lower RMSE than the matched filter's", rmse(g) < rmse(m)),
        ]
        self._fig_map(scene, truth, results, config, out_dir)
        self._fig_curve(curve, config, out_dir)
        self._fig_hist(re, out_dir)
        notes = [f"node positions (m): {np.round(truth, 1).tolist()}",
                 f"traced paths per link: {r.n_paths[np.triu_indices(config.K, 1)].tolist()}"]
        return Summary(metrics, claims, notes)

    @staticmethod
    def _fig_map(scene, truth, results, config, out_dir):
        fig, ax = figure(width=7.0, height=7.0)
        for p in scene.polygons:
            x, y = p.exterior.xy
            ax.fill(x, y, color="#bbbbbb", lw=0)
        tr = results[(results["run"] == 0) & (results["estimator"] == "rls")
                     & results["group"].str.startswith("node")]
        for k in range(config.K):
            t = tr[tr["group"] == f"node{k}"].sort_values("step")
            ax.plot(t["x"], t["y"], "-", color=COLORS["ours"], lw=0.8, alpha=0.8,
                    label="RLS estimates (run 0)" if k == 0 else None)
            ax.plot(t["x"].iloc[0], t["y"].iloc[0], "x", color=COLORS["baseline"], ms=6,
                    label="prior" if k == 0 else None)
        a = np.arange(config.K) < config.assisted
        ax.plot(truth[a, 0], truth[a, 1], "D", color=COLORS["truth"], ms=9, mfc="none", mew=2,
                label="GPS-assisted (true)")
        ax.plot(truth[~a, 0], truth[~a, 1], "o", color=COLORS["truth"], ms=9, mfc="none", mew=2,
                label="unassisted (true)")
        lo = truth.min(axis=0) - 150
        hi = truth.max(axis=0) + 150
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title("Fig. 3: buildings, nodes and one RLS trace")
        ax.legend(loc="upper right", fontsize=8)
        save(fig, out_dir / "fig3_map.png")

    @staticmethod
    def _fig_curve(curve, config, out_dir):
        fig, ax = figure(width=7.0, height=4.5)
        for e, ls in (("rls", LINESTYLES["rls"]), ("ekf", LINESTYLES["ekf"])):
            for grp, col in (("unassisted", COLORS["ours"]), ("assisted", COLORS["alt"])):
                c = curve[(e, grp)]
                ax.plot(c.index, c.values, ls, color=col, label=f"{e.upper()}, {grp}")
        ax.axhline(20.0, color=COLORS["bound"], ls=":", lw=1, label="paper: about 20 m")
        ax.set_yscale("log")
        ax.set_xlabel("packet number (ACK set)")
        ax.set_ylabel("average position error [m]")
        ax.set_title(f"Fig. 4: average error over {config.runs} orderings and priors")
        ax.legend(ncol=2, fontsize=8)
        save(fig, out_dir / "fig4_error_vs_packet.png")

    @staticmethod
    def _fig_hist(re, out_dir):
        fig, axes = figure(1, 2, width=10.0, height=4.0)
        for ax, los in zip(axes, (True, False)):
            d = re[re["los"] == los]
            lim = 200.0 if los else 600.0
            bins = np.linspace(-lim, lim, 41)
            for name, col, lab in (("gsic", COLORS["ours"], "GSIC"),
                                   ("matched_filter", COLORS["baseline"], "matched filter")):
                e = d[d["estimator"] == name]["error_m"]
                miss = e.isna().mean() if len(e) else 0.0
                ax.hist(np.clip(e.dropna(), -lim, lim), bins=bins, histtype="step", lw=1.6, color=col,
                        label=f"{lab} (missed {miss:.0%})")
            ax.set_xlabel("range error [m] (clipped to the axis)")
            ax.set_ylabel("count")
            ax.set_title("LOS links" if los else "NLOS links")
            ax.legend(fontsize=8)
        save(fig, out_dir / "range_error_hist.png")
