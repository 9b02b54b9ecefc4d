"""Throughput of mixture fingerprint localization (paper 004), with its peers measured in the
same process.

Rows (``main()`` returns them, see ``collect.py``):

1. ``MixtureLocalizer.locate`` with 6 station models of 16 components (eq. (2), position
   densities reduced to 8 components after each product), 2000 rows: the compiled kernel
   against its NumPy definition (``backend="numpy"``: condition, product, West/Runnalls
   reduction per station).
2. The same rows against weighted kNN (scikit-learn ``KNeighborsRegressor(k=6,
   weights="distance")``) fitted on 4,104 synthetic fingerprints of the same 6 stations
   (the size of the Kolakowski BLE calibration): the method a user would pick instead.
3. UJIIndoorLoc validation scans (520 access points, the shared-place model of 933 places)
   against weighted kNN (k = 6, "not detected" = -110 dBm) on the 19,861 training scans;
   model fits excluded. Skipped when the data set is absent.

Run: ``PYTHONPATH=src python benchmarks/bench_fingerprint.py``.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from radioloc.estimators.mixture_localization import MixtureLocalizer
from radioloc.models.mixture import DiagMixture
from bench_mixture import localization_flops
from timing import best_of


def _row(workload, ours, peer, peer_t, n, unit="rows/s"):
    return {"workload": workload, "throughput": n / ours, "unit": unit, "peer": peer,
            "peer_throughput": None if peer_t is None else n / peer_t,
            "ratio": None if peer_t is None else peer_t / ours}


def main(rows: int = 2000, seed: int = 0) -> list[dict]:
    """Run the three workloads and print them.

    Parameters
    ----------
    rows : int
        Measurement rows of the 6 x 16 workload.
    seed : int
        Seed of the synthetic models and measurements.

    Returns
    -------
    list of dict
        One row per workload (``workload, throughput, unit, peer, peer_throughput, ratio``).
    """
    from sklearn.neighbors import KNeighborsRegressor

    rng = np.random.default_rng(seed)
    out = []
    models = DiagMixture.create(rng.uniform(0.1, 1, (6, 16)), rng.normal(0, 3, (6, 16, 3)),
                                rng.uniform(0.5, 4, (6, 16, 3)))
    rss = rng.normal(0, 3, (rows, 6))
    loc = MixtureLocalizer(models, 8)
    ref = MixtureLocalizer(models, 8, backend="numpy")
    loc.locate(rss[:10])                                       # compile
    t_ours = best_of(lambda: loc.locate(rss))
    t_ref = best_of(lambda: ref.locate(rss), repeat=1)
    out.append(_row("mixture localization, 6 stations x 16 components (eq. (2), kmax 8)",
                    t_ours, "same maths, NumPy operations per station", t_ref, rows))
    out[-1]["flops_per_unit"] = localization_flops(6, 16, 8)
    cal_pos = rng.uniform(0, 20, (4104, 2))
    cal = rng.normal(0, 3, (4104, 6))
    knn = KNeighborsRegressor(n_neighbors=6, weights="distance").fit(cal, cal_pos)
    t_knn = best_of(lambda: knn.predict(rss))
    out.append(_row("mixture localization, 6 stations x 16 components (eq. (2), kmax 8)",
                    t_ours, "weighted kNN (scikit-learn, 4,104 fingerprints)", t_knn, rows))
    out[-1]["flops_per_unit"] = localization_flops(6, 16, 8)

    root = Path(os.environ.get("RADIOLOC_DATA", "/work/shared/data")) / "ujiindoorloc"
    if (root / "trainingData.csv").is_file():
        from radioloc.io.ujiindoorloc import load_split
        from radioloc.models.fingerprint_mixture import FingerprintMixture

        train = load_split(root, "training").without_empty()
        test = load_split(root, "validation")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            model = FingerprintMixture.fit(train.position, train.rss, train.zones,
                                           ("building", "floor"))
        wifi = MixtureLocalizer(model, 16, temperature=4.0)
        t_wifi = best_of(lambda: wifi.locate(test.rss))
        fill = lambda x: np.where(np.isfinite(x), x, -110.0)
        reg = KNeighborsRegressor(n_neighbors=6, weights="distance").fit(fill(train.rss),
                                                                         train.position)
        xte = fill(test.rss)
        t_wknn = best_of(lambda: reg.predict(xte))
        out.append(_row(f"UJIIndoorLoc fingerprints, 520 APs, {model.n_places} places "
                        "(shared-place mixture)", t_wifi,
                        "weighted kNN (scikit-learn, k=6, 19,861 scans)", t_wknn, len(test)))
    for r in out:
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.1f}x"
        print(f"{r['workload']}: {r['throughput']:,.0f} {r['unit']}; {r['peer']}: "
              f"{r['peer_throughput']:,.0f}; ratio {ratio}")
    return out


if __name__ == "__main__":
    main()
