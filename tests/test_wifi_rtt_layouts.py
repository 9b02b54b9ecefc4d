"""The WiFi RTT reader on any venue of the set's layout, both ground-truth layouts, and files
in another layout refused naming the file (hand-made venues: no data set needed)."""

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import InputError
from radioloc.io import datasets
from radioloc.io.logs import read_measurements
from radioloc.io.wifi_rtt import circles, load_anchors, load_run, venues

APS = {"AP1": (0.0, 0.0), "AP2": (10.0, 0.0), "AP3": (0.0, 8.0)}


def _phone_log(truth: np.ndarray, phone: str, split_truth: bool) -> pd.DataFrame:
    cols = {f"{phone} Time Stamp (ms)": np.arange(len(truth)) * 250.0}
    for j, (ap, xy) in enumerate(APS.items(), 1):
        true = np.linalg.norm(truth - np.array(xy), axis=1)
        cols[f"AP{j} True Distance (m)"] = true
        cols[f"AP{j} RTT Distance (m)"] = true + 1.0
        cols[f"AP{j} RTT std (m)"] = 0.1
        cols[f"AP{j} RSS (dBm)"] = -60.0
    cols["Azimuth"] = 0.5
    if split_truth:
        cols[f"{phone} Ground Truth_x"] = truth[:, 0]
        cols[f"{phone} Ground Truth_y"] = truth[:, 1]
    else:
        cols[f"{phone} Ground Truth"] = [f"[{x}, {y}]" for x, y in truth]
    return pd.DataFrame(cols)


def _venue(root, name: str, split_truth: bool):
    folder = root / "raw_data" / name / "1"
    folder.mkdir(parents=True)
    pd.DataFrame([(k, *v) for k, v in APS.items()], columns=["", "x", "y"]).to_csv(
        folder.parent / f"AP_idx_{name}.csv", index=False)
    truth = np.column_stack([np.linspace(2, 8, 12), np.linspace(1, 6, 12)])
    for phone, suffix in (("M1", "13"), ("M2", "24")):
        _phone_log(truth, phone, split_truth).to_csv(folder / f"1{suffix}.csv", index=False)
    return truth


@pytest.mark.parametrize("split_truth", [False, True], ids=["text-truth", "x-y-truth"])
def test_any_venue_and_both_truth_layouts(tmp_path, split_truth):
    truth = _venue(tmp_path, "Car Park", split_truth)
    assert venues(tmp_path) == ["Car Park"] and circles(tmp_path, "Car Park") == ["1"]
    run = load_run(tmp_path, "Car Park", 1, "M2")
    np.testing.assert_allclose(run.truth_xy, truth)
    assert run.ap_ids == ["AP1", "AP2", "AP3"] and np.all(run.range_m > 1.0)
    assert list(load_anchors(tmp_path, "Car Park")["id"]) == list(APS)


def test_export_takes_a_data_root_and_any_venue(tmp_path):
    _venue(tmp_path / "set", "Laboratory", split_truth=True)
    paths = datasets.export("wifi-rtt", tmp_path / "out", venue="Laboratory", circle=1,
                            root=tmp_path / "set")
    meas = read_measurements(paths["measurements"])
    assert set(meas["node"]) == {"M1", "M2"} and len(meas) == 2 * 12 * 3
    ref = pd.read_csv(paths["reference"])
    assert {"x", "y"} <= set(ref.columns) and np.isfinite(ref[["x", "y"]].to_numpy()).all()


def test_unknown_venue_lists_the_venues(tmp_path):
    _venue(tmp_path, "Canteen", split_truth=False)
    with pytest.raises(InputError, match=r"'Office'.*venues: Canteen"):
        load_run(tmp_path, "Office", 1)
    (tmp_path / "raw_data" / "Office").mkdir()      # a folder in another layout
    with pytest.raises(InputError, match=r"Office: no AP coordinate file AP_idx_Office\.csv"):
        load_run(tmp_path, "Office", 1)


@pytest.mark.parametrize("drop, message", [
    ("M1 Ground Truth", r"113\.csv: no ground-truth column"),
    ("AP2 RSS (dBm)", r"113\.csv: expected the columns"),
    ("M1 Time Stamp (ms)", r"113\.csv: no column ending in 'Time Stamp \(ms\)'"),
])
def test_another_layout_is_refused_naming_the_file(tmp_path, drop, message):
    _venue(tmp_path, "Canteen", split_truth=False)
    path = tmp_path / "raw_data" / "Canteen" / "1" / "113.csv"
    pd.read_csv(path).drop(columns=drop).to_csv(path, index=False)
    with pytest.raises(InputError, match=message):
        load_run(tmp_path, "Canteen", 1, "M1")
