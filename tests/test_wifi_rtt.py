"""The WiFi RTT data set: reader and export to the locate schema (skipped without the data)."""

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import InputError
from radioloc.io import datasets
from radioloc.io.logs import read_anchors, read_measurements
from radioloc.io.wifi_rtt import circles, load_anchors, load_peer_ranges, load_run

ROOT = datasets.find("wifi-rtt-haiyaoyu")
pytestmark = pytest.mark.skipif(ROOT is None, reason="wifi-rtt-haiyaoyu data set not present "
                                "(set RADIOLOC_DATA or run `radioloc datasets fetch wifi-rtt`)")


def test_unmeasured_aps_are_missing_not_zero():
    run = load_run(ROOT, "Conference Room", 2, "M1")        # AP4 is 0 (not measured) here
    ap4 = run.ap_ids.index("AP4")
    assert np.isnan(run.range_m[:, ap4]).mean() > 0.5
    assert np.nanmin(run.range_m) > 0.0
    assert run.truth_xy.shape == (run.time_s.size, 2) and np.all(np.diff(run.time_s) > 0)


def test_ranges_are_biased_long_as_documented():
    run = load_run(ROOT, "Canteen", 1, "M1")
    anchors = load_anchors(ROOT, "Canteen").set_index("id").loc[run.ap_ids, ["x", "y"]].to_numpy()
    true = np.linalg.norm(run.truth_xy[:, None, :] - anchors, axis=-1)
    bias = np.nanmedian(run.range_m - true, axis=0)
    assert np.all((bias > 0.0) & (bias < 8.0))


def test_export_writes_both_phones_and_never_the_truth(tmp_path):
    paths = datasets.export("wifi-rtt", tmp_path, venue="Library", circle=circles(ROOT, "Library")[0])
    anchors = read_anchors(paths["anchors"])
    meas = read_measurements(paths["measurements"], anchors=anchors)
    ref = pd.read_csv(paths["reference"])
    assert set(meas["node"]) == {"M1", "M2"} == set(ref["node"])
    assert set(meas["kind"]) == {"range"} and (meas["value"] > 0).all()
    assert "std" not in meas.columns
    with_std = read_measurements(datasets.export("wifi-rtt", tmp_path / "s", venue="Library",
                                                 circle=circles(ROOT, "Library")[0],
                                                 phone_std=True)["measurements"])
    assert (with_std["std"].dropna() > 0).all()
    run = load_run(ROOT, "Library", circles(ROOT, "Library")[0], "M1")
    m1 = meas[meas["node"] == "M1"]
    assert len(m1) == int(np.isfinite(run.range_m).sum())
    # no measurement equals a truth distance
    anchors_xy = load_anchors(ROOT, "Library").set_index("id").loc[run.ap_ids, ["x", "y"]].to_numpy()
    true = np.linalg.norm(run.truth_xy[:, None, :] - anchors_xy, axis=-1)
    assert not np.isin(np.round(m1["value"].to_numpy(), 6), np.round(true.ravel(), 6)).any()


def test_export_with_rss_adds_rss_rows(tmp_path):
    paths = datasets.export("wifi-rtt", tmp_path, venue="Canteen", circle=1, rss=True)
    meas = read_measurements(paths["measurements"])
    assert set(meas["kind"]) == {"range", "rss"}


def test_export_with_heading_writes_the_negated_azimuth(tmp_path):
    paths = datasets.export("wifi-rtt", tmp_path, venue="Canteen", circle=1, heading=True)
    meas = read_measurements(paths["measurements"], anchors=read_anchors(paths["anchors"]))
    assert set(meas["kind"]) == {"range", "heading"}
    run = load_run(ROOT, "Canteen", 1, "M2")
    head = meas[(meas["kind"] == "heading") & (meas["node"] == "M2")]
    assert len(head) == run.time_s.size and set(head["peer"]) == {"imu"}
    # the compass turns clockwise: the row is minus the azimuth, within (-pi, pi]
    diff = np.angle(np.exp(1j * (head["value"].to_numpy() + run.imu["Azimuth"].to_numpy())))
    np.testing.assert_allclose(diff, 0.0, atol=1e-6)


def test_bad_venue_and_circle_name_the_field():
    with pytest.raises(InputError, match="venue"):
        load_run(ROOT, "Kitchen", 1)
    with pytest.raises(InputError, match="circles of Canteen"):
        load_run(ROOT, "Canteen", 8)
    with pytest.raises(InputError, match="phone"):
        load_run(ROOT, "Canteen", 1, "M3")


def test_phone_to_phone_log_reads_on_its_own_clock():
    peer = load_peer_ranges(ROOT, "Canteen", 1)
    assert list(peer.columns) == ["time_s", "range_m", "range_std_m", "rss_dbm"]
    assert peer["time_s"].iloc[0] == 0.0 and (peer["range_m"] > 0).all() and len(peer) > 100
    with pytest.raises(InputError, match="circles of Canteen"):
        load_peer_ranges(ROOT, "Canteen", 8)
