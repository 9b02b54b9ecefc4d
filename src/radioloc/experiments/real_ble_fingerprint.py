"""Paper 004 on real BLE fingerprints (Kolakowski 2021): mixture models vs (weighted) kNN.

Calibration on ``calibration_df.csv`` (4,104 fingerprints, 6 anchors); every row of the
robot test run (719 rows, LiDAR-SLAM truth, never used for tuning) is localized one-shot and
tracked (Sect. 4):

- ``gmm_em`` / ``gmm_progressive``: per-anchor mixtures (eq. (1), (2)) from batch EM
  (``radioloc locate --method gmm -o model=stations``) and from kernel-insertion
  calibration;
- ``gmm_places_default``: the shared-place model (docs/fingerprinting.md) with the fit
  defaults, ``T = 1``, every place kept;
- ``gmm_places_cv``: the same model with ``T``, the places kept ``M`` and the shrinkage chosen
  by spatially grouped cross-validation on the calibration file only
  (:func:`~radioloc.models.fingerprint_selection.select_places_settings`, the settings of
  ``locate --method gmm``'s default model); ``_tracking``: tracked over the places
  (:func:`~radioloc.estimators.place_tracking.track_places`, uniform disk of ``v_max``);
- ``knn`` and ``wknn``: k nearest neighbours in signal space (scikit-learn), uniform and
  inverse-distance weights, the usual baselines, each with ``k`` chosen by the same spatially
  grouped cross-validation on the calibration file
  (:func:`~radioloc.models.fingerprint_selection.select_knn_k`).

No Monte Carlo: one run. Its 719 test rows are consecutive (one scan per 1/3 s), so they are
not independent units: every interval and paired claim is over batch means, the mean of each
``batch_rows`` consecutive rows.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.metrics import error_cdf, position_error
from radioloc.core.rng import stream
from radioloc.estimators.mixture_localization import MixtureLocalizer, MixtureTracker
from radioloc.estimators.place_tracking import track_places
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, per_run, register
from radioloc.io.kolakowski import load_fingerprints
from radioloc.models.fingerprint_mixture import FingerprintMixture
from radioloc.models.fingerprint_selection import select_knn_k, select_places_settings
from radioloc.models.mixture_calibration import em_calibration, progressive_calibration
from radioloc.models.motion import UniformDisk
from radioloc.report.style import COLORS, figure, save


@dataclass(frozen=True)
class BleConfig:
    """Settings of ``real-ble-fingerprint`` (our choices; the paper has no BLE setting).

    model_components: components per anchor model (EM and progressive).
    position_components: bound on the components of every position density.
    bandwidth: kernel standard deviations (x m, y m, rss dB) of progressive calibration.
    calib_stride: progressive calibration inserts every ``calib_stride``-th fingerprint in a
        fixed shuffled order (1 = all 4,104).
    v_max: maximum speed of the tracking motion model (paper: 1.5 m/s).
    knn_ks: candidate ``k`` of kNN and weighted kNN (weights = inverse RSS distance), each
        chosen by the spatially grouped cross-validation of the places settings (3 m blocks,
        5 folds) on the calibration file.
    knn_missing_dbm: value given to a not received anchor for kNN.
    batch_rows: consecutive test rows per batch: the unit of every interval and paired
        claim (batch means). 72 rows are 24 s of the run (10 batches of the 719 rows): the
        standard error of the paired differences still grew from 36 to 72 rows, so shorter
        batches would understate it; the summary notes the lag-1 correlation left between
        consecutive batch means of each claim (near 0: the batches are independent).
    places_stride: the places models use every ``places_stride``-th calibration fingerprint.

    Random draws (EM initialisation, the insertion order of progressive calibration) come
    from the named streams ``"em-init"`` and ``"calibration-order"`` of the experiment seed.
    """

    runs: int = 1
    block_size: int = 1
    model_components: int = 16
    position_components: int = 8
    bandwidth: tuple[float, float, float] = (0.3, 0.3, 2.0)
    calib_stride: int = 2
    v_max: float = 1.5
    knn_ks: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20)
    knn_missing_dbm: float = -100.0
    places_stride: int = 1
    batch_rows: int = 72


@register
class BleFingerprintExperiment(Experiment):
    id = "real-ble-fingerprint"
    paper = "004"
    description = "Mixture RSS models (EM, progressive; one-shot and tracking) vs weighted kNN on real BLE fingerprints"
    data_folder = "kolakowski-ble-fingerprints-2021"

    def config(self, full: bool) -> BleConfig:
        """The configuration at the quick or the full size.

        Parameters
        ----------
        full : bool
            The paper's size instead of the quick one.

        Returns
        -------
        BleConfig
            The settings.
        """
        return BleConfig(calib_stride=1 if full else 2, places_stride=1 if full else 2)

    def run_block(self, config: BleConfig, runs: np.ndarray, rng: np.random.Generator) -> pd.DataFrame:
        """Run one block of runs.

        Parameters
        ----------
        config : BleConfig
            The settings.
        runs : ndarray of int
            The block's run indices.
        rng : numpy.random.Generator
            The block's generator (named streams of the experiment seed derive from it).

        Returns
        -------
        pandas.DataFrame
            The tidy rows of the block (one per method and test row).
        """
        from sklearn.neighbors import KNeighborsRegressor

        folder = self.data_path()
        cal = load_fingerprints(folder, "calibration")
        test = load_fingerprints(folder, "robot")
        est = {}
        em = em_calibration(cal.position, cal.rss, config.model_components,
                            rng=stream(rng, "em-init"))
        order = stream(rng, "calibration-order").permutation(len(cal.time_s))[::config.calib_stride]
        prog = progressive_calibration(cal.position, cal.rss, config.bandwidth,
                                       config.model_components, order=order)
        for name, model in (("gmm_em", em), ("gmm_progressive", prog)):
            est[name] = MixtureLocalizer(model, config.position_components).locate(test.rss).position
            tracker = MixtureTracker(model, UniformDisk(config.v_max, dim=2),
                                     config.position_components)
            est[name + "_tracking"] = tracker.run(test.rss, test.time_s).position
        sub = slice(None, None, config.places_stride)
        chosen = select_places_settings(cal.position[sub], cal.rss[sub], min_samples=1)
        for name, (t, top, lam) in (("gmm_places_default", (1.0, None, 5.0)),
                                     ("gmm_places_cv", (chosen.temperature, chosen.top_places,
                                                        chosen.shrink))):
            model = FingerprintMixture.fit(cal.position[sub], cal.rss[sub], shrink=lam,
                                           min_samples=1)
            est[name] = MixtureLocalizer(model, config.position_components, temperature=t,
                                         top_places=top).locate(test.rss).position
            est[name + "_tracking"] = track_places(model, test.rss, test.time_s, config.v_max,
                                                   t, top).position
        knn_cv = []
        for name, weights in (("knn", "uniform"), ("wknn", "distance")):
            k, table = select_knn_k(cal.position, cal.rss, ks=config.knn_ks, weights=weights,
                                    missing_dbm=config.knn_missing_dbm)
            knn_cv.append(table.assign(method=f"cv_{name}", run=runs[0]))
            knn = KNeighborsRegressor(n_neighbors=k, weights=weights)
            knn.fit(np.nan_to_num(cal.rss, nan=config.knn_missing_dbm), cal.position)
            est[name] = knn.predict(np.nan_to_num(test.rss, nan=config.knn_missing_dbm))
        frames = [pd.DataFrame({"run": runs[0], "method": name, "row": np.arange(len(p)),
                                "x_true": test.position[:, 0], "y_true": test.position[:, 1],
                                "x_est": p[:, 0], "y_est": p[:, 1],
                                "error_m": position_error(p, test.position)})
                  for name, p in est.items()]
        frames.append(chosen.table.assign(method="cv", run=runs[0]))
        return pd.concat(frames + knn_cv, ignore_index=True)

    def summarize(self, config: BleConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Metrics, claims and figures from the rows the blocks returned.

        Parameters
        ----------
        config : BleConfig
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
        metrics = []
        cv = results[results["method"] == "cv"].dropna(axis=1, how="all")
        k_cv = {m[3:]: g.dropna(axis=1, how="all") for m, g in results.groupby("method")
                if m.startswith("cv_")}
        # the chosen k: the first of the lowest CV error (select_knn_k's rule)
        k_best = {m: int(t["k"].iloc[int(np.argmin(t["cv_mean_error_m"].to_numpy()))])
                  for m, t in k_cv.items()}
        results = results[~results["method"].str.startswith("cv")]
        results = results.assign(batch=results["row"] // config.batch_rows)
        g = results.groupby("method", sort=False)["error_m"]
        median, p90 = g.median(), g.quantile(0.9)
        n_rows, n_batches = results["row"].nunique(), results["batch"].nunique()
        batches = {m: per_run(r, "error_m", ("run", "batch")) for m, r in results.groupby("method")}
        for name in median.index:
            what = (f", k = {k_best[name]} (spatially grouped CV)" if name in k_best else "")
            metrics.append(Metric.over_runs(
                f"{name}_mean_error_m", batches[name], None, "m",
                f"robot test run, {n_rows} rows{what}; interval over {n_batches} batch means "
                f"of {config.batch_rows} consecutive rows"))
            metrics.append(Metric(f"{name}_median_error_m", median[name], None, "m",
                                  "median of the position error over the rows (no interval: "
                                  "the rows of one run are not independent)"))
            metrics.append(Metric(f"{name}_p90_error_m", p90[name], None, "m",
                                  "90th percentile of the position error (no interval, as the "
                                  "median)"))
        best = cv.loc[cv["cv_mean_error_m"].idxmin()]
        paired = f"paired over {n_batches} batch means of {config.batch_rows} test rows"
        claims = [Claim.lower("Tracking with the motion model reduces the mean error of one-shot "
                              f"mixture localization (EM models; {paired})",
                              batches["gmm_em_tracking"], batches["gmm_em"], unit="m"),
                  Claim.lower("The places mixture with cross-validated settings is at least as "
                              "good as weighted kNN with cross-validated k (mean error, "
                              f"one-shot; {paired})",
                              batches["gmm_places_cv"], batches["wknn"], unit="m"),
                  Claim.lower("Tracking over the places reduces the mean error of one-shot places "
                              f"localization (cross-validated settings; {paired})",
                              batches["gmm_places_cv_tracking"], batches["gmm_places_cv"],
                              unit="m")]
        notes = []
        for claim, (a, b) in zip(claims, (("gmm_em_tracking", "gmm_em"), ("gmm_places_cv", "wknn"),
                                          ("gmm_places_cv_tracking", "gmm_places_cv"))):
            d = (batches[a] - batches[b]).to_numpy()
            lag1 = float(np.corrcoef(d[:-1], d[1:])[0, 1]) if d.size > 3 else np.nan
            notes.append(f"lag-1 correlation of consecutive batch means of the paired "
                         f"difference ({a} - {b}): {lag1:.2f} (the further above 0, the more "
                         "that claim's interval understates its uncertainty)")
        notes += [f"kNN baselines: k = {k_best.get('knn')} (kNN), {k_best.get('wknn')} (weighted) "
                 f"chosen from {list(config.knn_ks)} by the places' spatially grouped CV on the "
                 "calibration file; the paper publishes no BLE numbers",
                 f"places settings chosen by spatially grouped CV on the calibration file "
                 f"(3 m blocks, 5 folds): T={best['temperature']:g}, "
                 f"M={int(best['top_places']) or 'all'}, shrink={best['shrink']:g} "
                 f"(CV mean error {best['cv_mean_error_m']:.2f} m); the robot run is never "
                 "used for tuning",
                 "the robot moves at 0.08 m/s median (0.75 m/s at most), one scan per 1/3 s; "
                 f"the motion model's v_max = {config.v_max:g} m/s bounds it",
                 "EM is one k-means++ initialisation per anchor (stream 'em-init'): the "
                 "mixture errors, and whether tracking beats one-shot, change with it "
                 "(--seed); see docs/p004.md"]

        fig, ax = figure(width=8.4, height=4.4, layout="constrained")
        styles = {"gmm_em": ("-", COLORS["ours"]), "gmm_em_tracking": ("--", COLORS["ours"]),
                  "gmm_progressive": ("-", COLORS["alt"]),
                  "gmm_progressive_tracking": ("--", COLORS["alt"]),
                  "gmm_places_cv": ("-", "tab:green"),
                  "gmm_places_cv_tracking": ("--", "tab:green"),
                  "gmm_places_default": ("-", COLORS["alt2"]),
                  "gmm_places_default_tracking": ("--", COLORS["alt2"]),
                  "wknn": ("-", COLORS["baseline"]), "knn": (":", COLORS["baseline"])}
        for name, e in g:
            x, p = error_cdf(e)
            ls, c = styles.get(name, ("-.", "k"))
            ax.plot(x, p, ls, color=c, label=f"{name} (mean {np.mean(e):.2f} m)")
        ax.set_xlabel("position error [m]")
        ax.set_ylabel("empirical CDF")
        ax.set_title("BLE fingerprints (Kolakowski 2021), robot test run")
        fig.legend(*ax.get_legend_handles_labels(), loc="outside right upper", fontsize=8)
        save(fig, out_dir / "error_cdf.png", caption=(
            "Empirical CDF of the position error on the robot test run of the BLE fingerprint "
            "data set (Kolakowski 2021): mixture models (EM, progressive, shared places with "
            "default and cross-validated settings; "
            "one-shot solid, tracking dashed) against weighted kNN and kNN, with each mean."))

        fig, ax = figure(width=6.4, height=5.0, layout="constrained")
        first = results[results["method"] == "gmm_em_tracking"]
        ax.plot(first["x_true"], first["y_true"], color="k", lw=1, label="reference (LiDAR SLAM)")
        ax.plot(first["x_est"], first["y_est"], color=COLORS["ours"], lw=1,
                label="mixture tracking (EM models)")
        w = results[results["method"] == "wknn"]
        ax.plot(w["x_est"], w["y_est"], ".", ms=2, color=COLORS["baseline"], label="weighted kNN")
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.set_title("Robot test run: reference and estimates")
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=3,
                   fontsize=8, markerscale=3)
        save(fig, out_dir / "track.png", caption=(
            "The robot test run seen from above: the LiDAR SLAM reference, the mixture "
            "tracker's path (EM models) and the weighted kNN estimates."))
        return Summary(metrics, claims, notes)
