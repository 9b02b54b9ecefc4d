"""Mixture fingerprinting at WiFi scale on UJIIndoorLoc (520 access points, 3 buildings,
13 floors), against weighted kNN: train on ``trainingData.csv``, test on
``validationData.csv`` (another user and mostly other phones, 3-4 months later).

Methods (one run; the numbers depend on the seed only through the cross-validation folds):

- ``gmm_places``: :class:`~radioloc.estimators.mixture_localization.MixtureLocalizer` with a
  :class:`~radioloc.models.fingerprint_mixture.FingerprintMixture` (place components shared
  by all access points, "not detected" an explicit outcome, eq. (1) extended; see
  docs/fingerprinting.md), temperature ``T`` tuned by cross-validation on the training file;
- ``gmm_places_t1``: the same with ``T = 1`` (the plain product over access points);
- ``gmm_places_cv``: the default of ``locate --method gmm -o model=places``: ``T``, the places
  kept ``M`` and the shrinkage chosen by spatially grouped cross-validation on the training
  file (:func:`~radioloc.models.fingerprint_selection.select_places_settings`);
- ``knn``: k nearest neighbours with uniform weights, the ``k`` of ``wknn``;
- ``wknn``: scikit-learn ``KNeighborsRegressor(weights="distance")``, ``k`` tuned by the same
  cross-validation, "not detected" read as ``knn_missing_dbm``; building and floor by
  ``KNeighborsClassifier`` with the same ``k`` and weights;
- ``knn1``: 1-NN with Euclidean distance, the baseline method of the data set's paper
  (Torres-Sospedra et al., IPIN 2014), computed here (its published numbers are not
  available to us; see the notes).

Cross-validation: the training places (distinct building, floor, x, y) are split into
``cv_folds`` groups (stream ``"cv-folds"``); each fold's scans are localized with models fit
on the other folds' scans, so a held-out position is never a calibration position, as for
the validation file. The candidate with the lowest mean 2-D error wins.

Errors are 2-D Euclidean distances in file units (EPSG:3857 metres, 0.766 ground metres
each; published errors on this set are in file units). The time per fingerprint (model fit
excluded) is in the timing column ``ms_per_fingerprint``; no claim depends on it.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.metrics import error_cdf
from radioloc.core.rng import stream
from radioloc.estimators.mixture_localization import MixtureLocalizer
from radioloc.experiments.base import Claim, Experiment, Metric, Summary, per_run, register
from radioloc.io.ujiindoorloc import GROUND_M_PER_UNIT, UjiScans, load_split
from radioloc.models.fingerprint_mixture import FingerprintMixture, place_weights
from radioloc.models.fingerprint_selection import select_places_settings
from radioloc.report.style import COLORS, figure, save

ZONE_NAMES = ("building", "floor")


@dataclass(frozen=True)
class WifiConfig:
    """Settings of ``real-wifi-fingerprint``.

    train_stride: every ``train_stride``-th training scan is used (1 = all 19,861 non-empty).
    cv_folds: place-grouped folds of the cross-validation.
    knn_ks: candidate ``k`` of weighted kNN.
    temperatures: candidate ``T`` of the mixture method.
    knn_missing_dbm: value given to "not detected" for kNN (below the weakest reading, -104).
    alpha, shrink, var_min_db2, position_var_m2, min_samples: fit settings of
        :meth:`FingerprintMixture.fit` (fixed, not tuned).
    position_components: place components reported per estimate.
    places_folds: folds of the spatially grouped CV of ``gmm_places_cv``.
    """

    runs: int = 1
    block_size: int = 1
    train_stride: int = 1
    cv_folds: int = 5
    knn_ks: tuple[int, ...] = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20)
    temperatures: tuple[float, ...] = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)
    knn_missing_dbm: float = -110.0
    alpha: float = 0.1
    shrink: float = 5.0
    var_min_db2: float = 25.0
    position_var_m2: float = 1.0
    min_samples: int = 3
    position_components: int = 16
    places_folds: int = 5


def _knn_features(rss: np.ndarray, missing: float) -> np.ndarray:
    return np.where(np.isfinite(rss), rss, missing)


def _weighted(dist: np.ndarray, idx: np.ndarray, values: np.ndarray, k: int) -> np.ndarray:
    """scikit-learn's ``weights="distance"`` average of ``values`` over the first ``k``
    neighbours (neighbours at distance 0 share the weight equally)."""
    d, i = dist[:, :k], idx[:, :k]
    zero = d == 0
    with np.errstate(divide="ignore"):
        w = np.where(zero.any(1, keepdims=True), zero.astype(float), 1.0 / d)
    return np.einsum("nk,nk...->n...", w, values[i]) / w.sum(1).reshape(
        (-1,) + (1,) * (values.ndim - 1))


def _weighted_vote(dist, idx, labels, k):
    """Distance-weighted class vote (``KNeighborsClassifier(weights="distance")``)."""
    classes = np.unique(labels)
    onehot = (labels[:, None] == classes[None, :]).astype(float)
    return classes[np.argmax(_weighted(dist, idx, onehot, k), axis=1)]


def _fit_model(train: UjiScans, c: WifiConfig) -> FingerprintMixture:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = FingerprintMixture.fit(train.position, train.rss, train.zones, ZONE_NAMES,
                                       alpha=c.alpha, shrink=c.shrink,
                                       var_min_db2=c.var_min_db2,
                                       position_var_m2=c.position_var_m2,
                                       min_samples=c.min_samples)
    del caught          # the dropped count is read from the model (dropped_stations)
    return model


def _places_estimate(model: FingerprintMixture, loglik: np.ndarray, t: float):
    w, chosen = place_weights(model, loglik, t)
    return w @ model.positions, chosen


def _cross_validate(train: UjiScans, c: WifiConfig, rng: np.random.Generator) -> pd.DataFrame:
    from sklearn.neighbors import NearestNeighbors

    keys = np.c_[train.zones, train.position]
    _, place = np.unique(keys, axis=0, return_inverse=True)
    place = place.ravel()
    fold_of_place = stream(rng, "cv-folds").permutation(place.max() + 1) % c.cv_folds
    fold = fold_of_place[place]
    kmax = max(c.knn_ks)
    rows = []
    for f in range(c.cv_folds):
        tr, te = train.subset(fold != f), train.subset(fold == f)
        model = _fit_model(tr, c)
        ll = model.loglik(te.rss)
        for t in c.temperatures:
            est, _ = _places_estimate(model, ll, t)
            rows.append({"method": "gmm_places", "param": t, "fold": f, "n": len(te),
                         "error_sum": float(np.linalg.norm(est - te.position, axis=1).sum())})
        nn = NearestNeighbors(n_neighbors=kmax).fit(_knn_features(tr.rss, c.knn_missing_dbm))
        dist, idx = nn.kneighbors(_knn_features(te.rss, c.knn_missing_dbm))
        for k in c.knn_ks:
            est = _weighted(dist, idx, tr.position, k)
            rows.append({"method": "wknn", "param": float(k), "fold": f, "n": len(te),
                         "error_sum": float(np.linalg.norm(est - te.position, axis=1).sum())})
    cv = pd.DataFrame(rows).groupby(["method", "param"], as_index=False)[["error_sum", "n"]].sum()
    cv["cv_mean_error"] = cv["error_sum"] / cv["n"]
    return cv[["method", "param", "cv_mean_error"]]


@register
class WifiFingerprintExperiment(Experiment):
    """Experiment ``real-wifi-fingerprint`` (see the module docstring).

    Parameters
    ----------
    (none: settings are in :class:`WifiConfig`)
    """

    id = "real-wifi-fingerprint"
    paper = "004"
    description = ("Mixture fingerprinting at WiFi scale (UJIIndoorLoc: 520 APs, 3 buildings, "
                   "13 floors) vs weighted kNN, train/validation split")
    data_folder = "ujiindoorloc"
    timing_columns = ("ms_per_fingerprint",)

    def config(self, full: bool) -> WifiConfig:
        """The quick or the full configuration.

        Parameters
        ----------
        full : bool
            All training scans and 5 folds (quick: every 2nd training scan, 3 folds).

        Returns
        -------
        WifiConfig
        """
        return WifiConfig() if full else WifiConfig(train_stride=2, cv_folds=3)

    def run_block(self, config: WifiConfig, runs: np.ndarray, rng: np.random.Generator) -> pd.DataFrame:
        """Tune, fit on the training file, localize the validation file.

        Parameters
        ----------
        config : WifiConfig
            Settings.
        runs : ndarray of int
            The block's run indices (one run).
        rng : numpy.random.Generator
            The block's generator (stream ``"cv-folds"``).

        Returns
        -------
        pandas.DataFrame
            ``table = "test"`` rows (one per method and validation scan) and ``table = "cv"``
            rows (cross-validated mean error per candidate), ``table = "data"`` (counts).
        """
        from sklearn.neighbors import KNeighborsClassifier, KNeighborsRegressor

        root = self.data_path()
        full_train = load_split(root, "training")
        train = full_train.without_empty()
        train = train.subset(np.arange(0, len(train), config.train_stride))
        test = load_split(root, "validation")
        cv = _cross_validate(train, config, rng)
        best = {m: cv[cv["method"] == m].sort_values(["cv_mean_error", "param"]).iloc[0]
                for m in ("gmm_places", "wknn")}
        t_best, k_best = float(best["gmm_places"]["param"]), int(best["wknn"]["param"])

        chosen = select_places_settings(train.position, train.rss, train.zones, ZONE_NAMES,
                                        min_samples=config.min_samples, alpha=config.alpha,
                                        var_min_db2=config.var_min_db2,
                                        position_var_m2=config.position_var_m2,
                                        folds=config.places_folds)
        model = _fit_model(train, config)
        cv_model = _fit_model(train, replace(config, shrink=chosen.shrink))
        out = {}
        for name, mod, t, top in (("gmm_places", model, t_best, None),
                                  ("gmm_places_t1", model, 1.0, None),
                                  ("gmm_places_cv", cv_model, chosen.temperature,
                                   chosen.top_places)):
            loc = MixtureLocalizer(mod, config.position_components, temperature=t,
                                   top_places=top)
            t0 = time.perf_counter()
            est = loc.locate(test.rss)
            dt = time.perf_counter() - t0
            out[name] = (est.position, est.diagnostics["zone"], dt,
                         est.diagnostics["stations_ignored"])
        xtr = _knn_features(train.rss, config.knn_missing_dbm)
        xte = _knn_features(test.rss, config.knn_missing_dbm)
        for name, k, wts in (("wknn", k_best, "distance"), ("knn", k_best, "uniform"),
                             ("knn1", 1, "distance")):
            reg = KNeighborsRegressor(n_neighbors=k, weights=wts).fit(xtr, train.position)
            bld = KNeighborsClassifier(n_neighbors=k, weights=wts).fit(xtr, train.building)
            flr = KNeighborsClassifier(n_neighbors=k, weights=wts).fit(
                xtr, train.building * 10 + train.floor)
            t0 = time.perf_counter()
            pos = reg.predict(xte)
            dt = time.perf_counter() - t0
            b = bld.predict(xte)
            f = flr.predict(xte)
            out[name] = (pos, np.c_[b, f % 10], dt, np.zeros(len(test), int))
        frames = []
        for name, (pos, zone, dt, ignored) in out.items():
            frames.append(pd.DataFrame({
                "table": "test", "run": int(runs[0]), "method": name, "row": np.arange(len(test)),
                "x_true": test.position[:, 0], "y_true": test.position[:, 1],
                "x_est": pos[:, 0], "y_est": pos[:, 1],
                "error_m": np.linalg.norm(pos - test.position, axis=1),
                "building_true": test.building, "floor_true": test.floor,
                "building_est": zone[:, 0], "floor_est": zone[:, 1],
                "stations_ignored": ignored,
                "param": {"gmm_places": t_best, "gmm_places_cv": chosen.temperature,
                          "wknn": float(k_best), "knn": float(k_best)}.get(name, 1.0),
                "ms_per_fingerprint": 1e3 * dt / len(test)}))
        frames.append(cv.assign(table="cv", run=int(runs[0])))
        frames.append(chosen.table.assign(table="cv_places", run=int(runs[0])))
        seen = np.isfinite(train.rss).sum(0)
        frames.append(pd.DataFrame([{
            "table": "data", "run": int(runs[0]), "train_scans": len(train),
            "train_empty_dropped": full_train.counts["empty_scans"],
            "test_scans": len(test), "places": model.n_places,
            "aps_dropped": model.dropped_stations,
            "aps_test_only": int(np.sum((seen == 0) & np.isfinite(test.rss).any(0))),
            "test_readings_ignored": int(out["gmm_places"][3].sum()),
            "test_readings": int(np.isfinite(test.rss).sum())}]))
        return pd.concat(frames, ignore_index=True)

    def summarize(self, config: WifiConfig, results: pd.DataFrame, out_dir: Path) -> Summary:
        """Table, claims and the error CDF from the results table.

        Parameters
        ----------
        config : WifiConfig
            Settings.
        results : pandas.DataFrame
            The :meth:`run_block` frame.
        out_dir : pathlib.Path
            Where the figure goes.

        Returns
        -------
        Summary
        """
        tab = lambda name: results[results["table"] == name].dropna(axis=1, how="all")
        test, cv, data = tab("test"), tab("cv"), tab("data").iloc[0]
        cvp = tab("cv_places")
        cvp_best = cvp.loc[cvp["cv_mean_error_m"].idxmin()] if len(cvp) else None
        test = test.assign(bhit=test["building_est"] == test["building_true"],
                           fhit=(test["floor_est"] == test["floor_true"])
                           & (test["building_est"] == test["building_true"]))
        g = test.groupby("method", sort=False)
        stats = pd.DataFrame({"mean": g["error_m"].mean(), "median": g["error_m"].median(),
                              "p75": g["error_m"].quantile(0.75),
                              "p90": g["error_m"].quantile(0.9),
                              "building_hit": g["bhit"].mean(), "floor_hit": g["fhit"].mean(),
                              "param": g["param"].first()})
        if "ms_per_fingerprint" in test.columns:
            stats["ms"] = g["ms_per_fingerprint"].first()
        n = len(test[test["method"] == "wknn"])
        metrics = []
        for name, r in stats.iterrows():
            what = {"gmm_places": f"mixture (places), T={r['param']:g} (CV)",
                    "gmm_places_t1": "mixture (places), T=1",
                    "gmm_places_cv": f"mixture (places), T={r['param']:g}, M and shrink by "
                                     "spatially grouped CV (locate's default)",
                    "wknn": f"weighted kNN, k={r['param']:g} (CV)",
                    "knn": f"kNN (uniform weights), k={r['param']:g}",
                    "knn1": "1-NN Euclidean (the data set paper's baseline method)"}[name]
            metrics += [Metric(f"{name}_mean_error", r["mean"], None, "file m",
                               f"{what}; {n} validation scans"),
                        Metric(f"{name}_median_error", r["median"], None, "file m", what),
                        Metric(f"{name}_p90_error", r["p90"], None, "file m", what),
                        Metric(f"{name}_p75_error", r["p75"], None, "file m", what),
                        Metric(f"{name}_building_hit_rate", r["building_hit"], None, "", what),
                        Metric(f"{name}_floor_hit_rate", r["floor_hit"], None, "",
                               f"{what}; building and floor right")]

        def paired(col, method="gmm_places"):
            """Per validation scan: a mixture method's ``col`` minus weighted kNN's."""
            one = {m: per_run(test[test["method"] == m].astype({col: float}), col, ("row",))
                   for m in (method, "wknn")}
            return (one[method] - one["wknn"]).dropna()

        claims = [
            Claim.decide("The mixture method's mean 2-D error on the validation file is at most "
                         "weighted kNN's (both tuned by cross-validation on the training file "
                         "only; paired over validation scans)",
                         paired("error_m"), high=0.0,
                         unit="file m", what="mean paired difference (mixture - kNN)"),
            Claim.decide("The mixture with spatially grouped CV settings (locate's default) is at "
                         "most weighted kNN's mean 2-D error (paired over validation scans)",
                         paired("error_m", "gmm_places_cv"), high=0.0,
                         unit="file m", what="mean paired difference (mixture - kNN)"),
            Claim.decide("The mixture method's floor hit rate is at least weighted kNN's (paired "
                         "over validation scans)", paired("fhit"), low=-1e-12,
                         what="mean paired difference (mixture - kNN)"),
        ]
        notes = [
            f"training: {int(data['train_scans'])} scans (stride {config.train_stride}; "
            f"{int(data['train_empty_dropped'])} with no AP detected left out), "
            f"{int(data['places'])} places; validation: {int(data['test_scans'])} scans",
            f"{int(data['aps_dropped'])} APs dropped at the fit (detected in fewer than "
            f"{config.min_samples} training scans); {int(data['aps_test_only'])} APs detected "
            f"in validation only; {int(data['test_readings_ignored'])} of "
            f"{int(data['test_readings'])} validation readings ignored for that reason",
            "errors in file units (EPSG:3857 m); ground metres = x "
            f"{GROUND_M_PER_UNIT}; floor hit = building and floor both right",
            "published baselines: none available here (the data set's SOURCE.md quotes none; "
            "the IPIN 2014 paper, whose baseline is 1-NN Euclidean, could not be read); "
            "knn1 is that method computed by us",
            "locate's default (gmm_places_cv): spatially grouped CV (3 m blocks per "
            f"building and floor, {config.places_folds} folds) over T, M (places kept) and "
            "shrink chose "
            + ("none (no table)" if cvp_best is None else
               f"T={cvp_best['temperature']:g}, M={int(cvp_best['top_places']) or 'all'}, "
               f"shrink={cvp_best['shrink']:g} (CV mean error "
               f"{cvp_best['cv_mean_error_m']:.2f})")
            + "; the validation file is never used for tuning; no time series, so no tracking",
            "CV mean error per candidate: " + "; ".join(
                f"{m} {p:g}: {e:.2f}" for m, p, e in
                cv.sort_values(["method", "param"])[["method", "param", "cv_mean_error"]]
                .itertuples(index=False)),
        ]
        if "ms" in stats.columns:
            notes.append("ms per fingerprint (this machine, load-dependent): " + ", ".join(
                f"{k} {v:.3f}" for k, v in stats["ms"].items()))
        fig, ax = figure()
        styles = {"gmm_places": ("-", COLORS["ours"]), "gmm_places_t1": ("--", COLORS["ours"]),
                  "gmm_places_cv": ("-", "tab:green"), "knn": ("--", COLORS["baseline"]),
                  "wknn": ("-", COLORS["baseline"]), "knn1": (":", COLORS["baseline"])}
        for name, e in g["error_m"]:
            x, p = error_cdf(e)
            ls, col = styles[name]
            ax.plot(x, p, ls, color=col, label=f"{name} (mean {e.mean():.2f})")
        ax.set_xlim(0, float(test["error_m"].quantile(0.98)))
        ax.set_xlabel("2-D error [file m = EPSG:3857 m]")
        ax.set_ylabel("empirical CDF")
        ax.set_title("UJIIndoorLoc validation (1,111 scans)")
        ax.legend(fontsize=8)
        save(fig, out_dir / "error_cdf.png", caption=(
            "Empirical CDF of the 2-D position error on the UJIIndoorLoc validation scans "
            "(1,111, never used for tuning): mixture fingerprint models against nearest-"
            "neighbour baselines (kNN, weighted kNN, 1-NN), with each method's mean error."))
        return Summary(metrics, claims, notes)
