"""WiFi-scale fingerprinting: the UJIIndoorLoc reader, the shared-place mixture model,
``locate --method gmm -o model=places`` and the reduced-size reproduction of
``real-wifi-fingerprint``."""

import os
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.mixture_localization import MixtureLocalizer
from radioloc.io.logs import read_measurements
from radioloc.io.ujiindoorloc import load_split, read_scans
from radioloc.locate.base import LocateRequest
from radioloc.locate.gmm import locate_gmm
from radioloc.models.fingerprint_mixture import FingerprintMixture, zone_posterior
from radioloc.models.mixture import DiagMixture

HERE = Path(__file__).parent
UJI_ROWS = HERE / "data" / "ujiindoorloc"
UJI = Path(os.environ.get("RADIOLOC_DATA", "/work/shared/data")) / "ujiindoorloc"


# ---- reader ------------------------------------------------------------------------------

def test_reader_sentinel_counts_and_lines():
    tr = load_split(UJI_ROWS, "training")
    raw = pd.read_csv(UJI_ROWS / "trainingData.csv")
    waps = [c for c in raw.columns if c.startswith("WAP")]
    assert tr.stations == waps and len(tr) == len(raw)
    assert np.array_equal(np.isnan(tr.rss), raw[waps].to_numpy() == 100)
    assert tr.counts["not_detected_cells"] == int((raw[waps] == 100).to_numpy().sum())
    np.testing.assert_array_equal(tr.position, raw[["LONGITUDE", "LATITUDE"]].to_numpy())
    assert list(tr.lines[:2]) == [2, 3]
    assert tr.zones.shape == (len(raw), 2)


def test_reader_refuses_sentinel_without_option_and_bad_cells(tmp_path):
    raw = pd.read_csv(UJI_ROWS / "trainingData.csv")
    with pytest.raises(InputError, match=r"line 2, column WAP00\d: RSS 100 dBm.*not_detected=100"):
        read_scans(UJI_ROWS / "trainingData.csv", not_detected=None)
    bad = raw.astype(object)
    bad.loc[3, "WAP002"] = "strong"
    bad.to_csv(tmp_path / "bad.csv", index=False)
    with pytest.raises(InputError, match="line 5, column WAP002"):
        read_scans(tmp_path / "bad.csv")
    raw.drop(columns=["FLOOR"]).to_csv(tmp_path / "nofloor.csv", index=False)
    with pytest.raises(InputError, match="FLOOR"):
        read_scans(tmp_path / "nofloor.csv")


def test_reader_counts_empty_scans():
    tr = load_split(UJI_ROWS, "training")
    rss = tr.rss.copy()
    rss[0] = np.nan
    s = replace(tr, rss=rss)
    assert len(s.without_empty()) == len(tr) - 1


# ---- model -------------------------------------------------------------------------------

def _synthetic(rng, n_places=12, per=6, s=9, zones=True, noise=2.0):
    xy = rng.uniform(0, 40, (n_places, 2))
    aps = rng.uniform(0, 40, (s, 2))
    pos = np.repeat(xy, per, axis=0)
    d = np.linalg.norm(pos[:, None] - aps[None], axis=-1)
    rss = -40 - 25 * np.log10(np.maximum(d, 1)) + rng.normal(0, noise, d.shape)
    rss[rss < -80] = np.nan                          # not detected far away
    z = np.c_[np.repeat(np.arange(n_places) % 2, per), np.repeat(np.arange(n_places) % 3, per)]
    return pos, rss, (z if zones else None)


def _loglik_loop(model, rss):
    """log L_j(m) by the definition: a loop over places and access points."""
    out = np.zeros((rss.shape[0], model.n_places))
    for n in range(rss.shape[0]):
        for j in range(model.n_places):
            acc = 0.0
            for k in range(model.n_stations):
                if not model.active[k]:
                    continue
                p, mu, v = model.detect[j, k], model.mean[j, k], model.variance[j, k]
                if np.isfinite(rss[n, k]):
                    acc += np.log(p) - 0.5 * np.log(2 * np.pi * v) - (rss[n, k] - mu) ** 2 / (2 * v)
                else:
                    acc += np.log1p(-p)
            out[n, j] = acc
    return out


def test_loglik_is_the_product_over_access_points():
    rng = np.random.default_rng(1)
    pos, rss, z = _synthetic(rng)
    model = FingerprintMixture.fit(pos, rss, z, ("building", "floor"))
    test = rss[::7]
    np.testing.assert_allclose(model.loglik(test), _loglik_loop(model, test), rtol=1e-10)


def test_fit_estimates_detection_and_means():
    # one place, 4 scans: AP0 always at -50/-52/-54/-56, AP1 detected once
    pos = np.zeros((4, 2))
    rss = np.array([[-50, np.nan], [-52, np.nan], [-54, -70], [-56, np.nan]], float)
    m = FingerprintMixture.fit(pos, rss, alpha=0.5, shrink=0.0, var_min_db2=1.0,
                               min_samples=1)
    np.testing.assert_allclose(m.detect[0], [(4 + 0.5) / 5, (1 + 0.5) / 5])
    np.testing.assert_allclose(m.mean[0, 0], -53.0)
    np.testing.assert_allclose(m.variance[0, 0], 5.0)            # population variance
    assert m.n_places == 1 and m.dropped_stations == 0


def test_variance_shrinks_towards_the_pooled_within_place_variance():
    # two places 20 dB apart, two readings each: within-place variances 1 and 4 dB^2,
    # pooled (2*1 + 2*4) / (1 + 1) = 5; the total variance (about 101) must not enter
    pos = np.array([[0.0, 0], [0, 0], [10, 0], [10, 0]])
    rss = np.array([[-50.0], [-52.0], [-70.0], [-74.0]])
    m = FingerprintMixture.fit(pos, rss, shrink=2.0, var_min_db2=0.5, min_samples=1)
    order = np.argsort(m.positions[:, 0])
    np.testing.assert_allclose(m.variance[order, 0], [(2 * 1 + 2 * 5) / 4, (2 * 4 + 2 * 5) / 4])


def test_too_few_samples_dropped_with_warning_and_counted():
    rng = np.random.default_rng(2)
    pos, rss, z = _synthetic(rng)
    rss[:, -1] = np.nan
    rss[:2, -1] = -60.0                                        # detected twice only
    with pytest.warns(UserWarning, match="1 of 9 access points dropped"):
        model = FingerprintMixture.fit(pos, rss, z, ("building", "floor"), min_samples=3)
    assert model.dropped_stations == 1 and not model.active[-1]
    est = MixtureLocalizer(model).locate(rss[:4])
    np.testing.assert_array_equal(est.diagnostics["stations_ignored"], [1, 1, 0, 0])
    # the dropped column does not change the estimate
    other = rss[:4].copy()
    other[:, -1] = np.nan
    np.testing.assert_allclose(MixtureLocalizer(model).locate(other).position, est.position)


def test_locate_known_answer_batch_and_translation():
    rng = np.random.default_rng(3)
    pos, rss, z = _synthetic(rng, per=8, noise=0.1)
    fit = dict(var_min_db2=0.01, alpha=0.01, shrink=0.0)
    model = FingerprintMixture.fit(pos, rss, z, ("building", "floor"), **fit)
    loc = MixtureLocalizer(model, 4)
    est = loc.locate(rss)
    # near-zero noise: every calibration scan is placed at its place, in its zone
    err = np.linalg.norm(est.position - pos, axis=1)
    assert err.max() < 1e-6
    np.testing.assert_array_equal(est.diagnostics["zone"], z)
    assert np.all(np.linalg.eigvalsh(est.covariance) > 0)
    # batch equals one by one, and leading axes are kept
    one = np.stack([loc.locate(rss[i]).position for i in range(5)])
    np.testing.assert_allclose(loc.locate(rss[:5]).position, one)
    assert loc.locate(rss[:6].reshape(2, 3, -1)).position.shape == (2, 3, 2)
    # translating the calibration moves the estimate by the same vector
    shifted = MixtureLocalizer(FingerprintMixture.fit(pos + [100.0, -50.0], rss, z,
                                                      ("building", "floor"), **fit), 4).locate(rss)
    np.testing.assert_allclose(shifted.position, est.position + [100.0, -50.0], atol=1e-9)
    # the reported mixture is the heaviest places, weights summing to one
    w = est.diagnostics["mixture_weights"]
    assert w.shape == (len(rss), 4) and np.allclose(w.sum(-1), 1)
    assert np.all(np.diff(w, axis=-1) <= 0)


def test_zone_first_then_position():
    w = np.array([[0.3, 0.3, 0.4]])                             # places 0, 1 in zone 0
    zones = np.array([[0, 0], [0, 1], [1, 0]])
    chosen, inside = zone_posterior(w, zones)
    np.testing.assert_array_equal(chosen, [[0, 0]])             # building 0 (0.6), floor 0
    np.testing.assert_array_equal(inside, [[True, False, False]])


def test_bad_inputs_raise():
    rng = np.random.default_rng(4)
    pos, rss, z = _synthetic(rng)
    with pytest.raises(ConfigError, match="alpha"):
        FingerprintMixture.fit(pos, rss, alpha=0.0)
    with pytest.raises(InputError, match="rss"):
        FingerprintMixture.fit(pos, rss[:-1])
    bad = rss.copy()
    bad[0, 0] = np.inf
    with pytest.raises(InputError, match="infinite"):
        FingerprintMixture.fit(pos, bad)
    model = FingerprintMixture.fit(pos, rss)
    with pytest.raises(InputError, match="temperature"):
        MixtureLocalizer(model, temperature=0.5)
    with pytest.raises(InputError, match="columns"):
        MixtureLocalizer(model).locate(rss[:, :-1])
    with pytest.raises(InputError, match="fingerprint models only"):
        MixtureLocalizer(DiagMixture.create(np.ones((2, 3)), np.zeros((2, 3, 3)),
                                            np.ones((2, 3, 3))), temperature=2.0)


# ---- locate ------------------------------------------------------------------------------

def _uji_calibration(tmp_path):
    tr = pd.read_csv(UJI_ROWS / "trainingData.csv")
    va = pd.read_csv(UJI_ROWS / "validationData.csv")
    waps = [c for c in tr.columns if c.startswith("WAP")]
    cal = pd.DataFrame({"x": tr["LONGITUDE"], "y": tr["LATITUDE"], "building": tr["BUILDINGID"],
                        "floor": tr["FLOOR"]})
    cal[waps] = tr[waps]                                       # 100 = not detected, as in the set
    cal.to_csv(tmp_path / "cal.csv", index=False)
    rows = []
    for i, r in va.iterrows():
        for w in waps:
            if r[w] != 100:
                rows.append((float(i), "phone", w, "rss", float(r[w])))
    rows.append((0.0, "phone", "WAP999", "rss", -70.0))        # never in the calibration
    pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"]).to_csv(
        tmp_path / "meas.csv", index=False)
    return va


def test_locate_places_reads_sentinel_zones_and_ignores_unknown(tmp_path):
    va = _uji_calibration(tmp_path)
    meas = read_measurements(tmp_path / "meas.csv")
    req = LocateRequest(meas, calibration=tmp_path / "cal.csv",
                        options={"model": "places"}, parsed={"model": "places"})
    with pytest.raises(InputError, match="not_detected=100"):
        locate_gmm(req)
    req.parsed.update({"not_detected": 100.0, "min_samples": 2})
    with pytest.warns(UserWarning) as rec:
        out = locate_gmm(req)
    text = " ".join(str(r.message) for r in rec)
    assert "WAP999" in text and "dropped" in text
    assert list(out["stations_ignored"]) == [1, 0, 0]
    assert {"building", "floor"} <= set(out.columns) and len(out) == len(va)
    assert np.all(out["building"] == va["BUILDINGID"])
    assert np.all(np.isfinite(out[["x", "y", "uncertainty_m"]].to_numpy()))


def test_locate_gmm_tracks_with_places_and_refuses_bad_offset(tmp_path):
    va = _uji_calibration(tmp_path)
    meas = read_measurements(tmp_path / "meas.csv")
    req = LocateRequest(meas, calibration=tmp_path / "cal.csv",
                        options={"model": "places", "track": "1"},
                        parsed={"model": "places", "track": True, "not_detected": 100.0})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        out = locate_gmm(req)
    assert len(out) == len(va) and np.all(np.isfinite(out[["x", "y"]].to_numpy()))
    req = LocateRequest(meas, calibration=tmp_path / "cal.csv",
                        options={"model": "stations", "top_places": "3"},
                        parsed={"model": "stations", "top_places": 3, "not_detected": 100.0})
    with pytest.raises(ConfigError, match="top_places"):
        locate_gmm(req)
    req = LocateRequest(meas, calibration=tmp_path / "cal.csv",
                        options={"device_offset": "loud"}, parsed={"not_detected": 100.0})
    with pytest.raises(ConfigError, match="device_offset"):
        locate_gmm(req)


def test_calibration_column_case_kept_and_duplicates_refused(tmp_path):
    (tmp_path / "cal.csv").write_text("x,y,AP1,ap1\n0,0,-50,-60\n1,0,-51,-61\n2,0,-52,-62\n")
    from radioloc.locate.gmm import read_calibration
    _, rss, ids = read_calibration(tmp_path / "cal.csv")
    assert ids == ["AP1", "ap1"] and rss.shape == (3, 2)
    (tmp_path / "dup.csv").write_text("x,y,AP1,AP1\n0,0,-50,-60\n")
    with pytest.raises(InputError, match="twice"):
        read_calibration(tmp_path / "dup.csv")
    (tmp_path / "txt.csv").write_text("x,y,AP1\n0,0,-50\n1,0,loud\n")
    with pytest.raises(InputError, match="line 3, column AP1"):
        read_calibration(tmp_path / "txt.csv")


# ---- reproduction (reduced size) ---------------------------------------------------------

@pytest.mark.skipif(not UJI.is_dir(), reason="UJIIndoorLoc data absent (RADIOLOC_DATA)")
def test_wifi_reproduction_reduced_size(tmp_path, monkeypatch):
    from radioloc.experiments.base import Summary
    from radioloc.experiments.real_wifi_fingerprint import WifiFingerprintExperiment
    from radioloc.core.rng import block_generator

    monkeypatch.setenv("RADIOLOC_DATA", str(UJI.parent))
    exp = WifiFingerprintExperiment()
    cfg = replace(exp.config(False), train_stride=3, cv_folds=2, knn_ks=(3, 5, 8),
                  temperatures=(2.0, 4.0), places_folds=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        df = exp.run_block(cfg, np.arange(1), block_generator(0, 0))
    summary: Summary = exp.summarize(cfg, df.drop(columns=list(exp.timing_columns)), tmp_path)
    m = {x.name: x.value for x in summary.metrics}
    test = df[df["table"] == "test"]
    gm = test[test["method"] == "gmm_places"]["error_m"].to_numpy()
    wk = test[test["method"] == "wknn"]["error_m"].to_numpy()
    se_gm = gm.std(ddof=1) / np.sqrt(gm.size)
    se_wk = wk.std(ddof=1) / np.sqrt(wk.size)
    assert np.isclose(m["gmm_places_mean_error"], gm.mean())
    # recorded at this reduced size (seed 0): 8.80 and 9.78 file m;
    # band: 3 standard errors of a mean over the 1,111 validation scans
    assert abs(m["gmm_places_mean_error"] - 8.80) < 3 * se_gm
    assert abs(m["wknn_mean_error"] - 9.78) < 3 * se_wk
    assert m["gmm_places_mean_error"] <= m["wknn_mean_error"]
    assert summary.claims[0].holds
    assert abs(m["gmm_places_floor_hit_rate"] - 0.888) < 3 * np.sqrt(0.888 * 0.112 / gm.size)
    assert m["gmm_places_building_hit_rate"] > 0.99
    assert (tmp_path / "error_cdf.png").is_file()
