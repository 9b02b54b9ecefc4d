"""``radioloc locate --method gmm``, the Kolakowski loader and the p004 experiments (smoke)."""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import DataUnavailable, InputError
from radioloc.io.kolakowski import load_fingerprints
from radioloc.io.logs import read_measurements
from radioloc.locate.base import LocateRequest
from radioloc.locate.gmm import locate_gmm

DATA = Path(os.environ.get("RADIOLOC_DATA", "/work/shared/data")) / "kolakowski-ble-fingerprints-2021"


def write_locate_files(tmp_path, peer="ap2"):
    rng = np.random.default_rng(0)
    pos = rng.uniform(0, 10, (800, 2))
    aps = {"ap1": (0.0, 0.0), "ap2": (10.0, 0.0), "ap3": (5.0, 10.0)}
    cal = pd.DataFrame({"x": pos[:, 0], "y": pos[:, 1]})
    for k, a in aps.items():
        d = np.hypot(pos[:, 0] - a[0], pos[:, 1] - a[1])
        cal[k] = -40 - 20 * np.log10(np.maximum(d, 0.5)) + rng.normal(0, 1, 800)
    cal.loc[::5, "ap3"] = np.nan
    cal.to_csv(tmp_path / "cal.csv", index=False)
    truth = np.array([3.0, 4.0])
    rows = []
    for t in range(3):
        for k, a in aps.items():
            d = np.hypot(*(truth - a))
            rows.append((float(t), "phone", peer if k == "ap2" else k, "rss",
                         -40 - 20 * np.log10(d)))
    pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"]).to_csv(
        tmp_path / "meas.csv", index=False)
    return truth


def test_locate_gmm_finds_user_and_tracks(tmp_path):
    truth = write_locate_files(tmp_path)
    req = LocateRequest(read_measurements(tmp_path / "meas.csv"), calibration=tmp_path / "cal.csv",
                        options={"model": "stations"})
    out = locate_gmm(req)
    assert list(out.columns) == ["time", "node", "x", "y", "uncertainty_m", "cov_xx", "cov_xy",
                                 "cov_yy", "stations_ignored"]
    assert len(out) == 3 and np.all(out["stations_ignored"] == 0)
    err = np.hypot(out["x"] - truth[0], out["y"] - truth[1])
    assert np.all(err < 1.5) and np.all(out["uncertainty_m"] > 0)
    req.options = {"model": "stations", "track": "1"}
    tr = locate_gmm(req)
    assert np.all(np.hypot(tr["x"] - truth[0], tr["y"] - truth[1]) < 1.5)


def test_locate_gmm_default_model_is_places(tmp_path):
    # the places model has the lower error on both fingerprint sets of shared/data
    write_locate_files(tmp_path)
    meas = read_measurements(tmp_path / "meas.csv")
    default = locate_gmm(LocateRequest(meas, calibration=tmp_path / "cal.csv"))
    places = locate_gmm(LocateRequest(meas, calibration=tmp_path / "cal.csv",
                                      options={"model": "places"}))
    pd.testing.assert_frame_equal(default, places)


def test_locate_gmm_unknown_station_ignored_and_counted(tmp_path):
    truth = write_locate_files(tmp_path, peer="ap9")
    req = LocateRequest(read_measurements(tmp_path / "meas.csv"), calibration=tmp_path / "cal.csv")
    with pytest.warns(UserWarning, match="ap9"):
        out = locate_gmm(req)
    assert np.all(out["stations_ignored"] == 1) and len(out) == 3
    # the estimate equals the one from a log without the unknown station's rows
    clean = req.measurements[req.measurements["peer"] != "ap9"]
    ref = locate_gmm(LocateRequest(clean, calibration=tmp_path / "cal.csv"))
    np.testing.assert_allclose(out[["x", "y"]], ref[["x", "y"]])
    assert np.all(np.hypot(out["x"] - truth[0], out["y"] - truth[1]) < 3.0)
    with pytest.raises(InputError, match="calibration"):
        locate_gmm(LocateRequest(req.measurements))


def test_loader_missing_folder_and_real_data(tmp_path):
    with pytest.raises(DataUnavailable):
        load_fingerprints(tmp_path, "robot")
    if not DATA.is_dir():
        pytest.skip("data set absent")
    fp = load_fingerprints(DATA, "robot")
    assert fp.rss.shape == (719, 6) and fp.position.shape == (719, 2)
    assert fp.anchor_ids == (1, 2, 3, 4, 5, 6)
    assert np.all(np.diff(fp.time_s) > 0)


def test_corridor_experiment_smoke(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(Path(__file__).parents[1] / "src"))
    r = subprocess.run([sys.executable, "-m", "radioloc.cli", "reproduce", "p004-corridor",
                        "--runs", "2", "--out", str(tmp_path)], capture_output=True, text=True,
                       env=env, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    import json
    summary = json.loads((tmp_path / "p004-corridor" / "summary.json").read_text())
    names = {m["name"] for m in summary["metrics"]}
    assert {"estimate_m_after_1", "estimate_m_after_2", "estimate_m_after_8",
            "std_m_after_8", "tracking_rmse_m"} <= names
    assert (tmp_path / "p004-corridor" / "fig10_updates.png").is_file()
