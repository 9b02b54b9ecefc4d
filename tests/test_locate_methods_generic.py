"""`radioloc locate` methods over the generic and snapshot estimators: `smoother`, `localml`,
`ransac`, `lsq` on small simulated logs (accuracy against the truth, one row per (time, node),
covariance columns where the estimator has one, bad input named)."""

import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.io import read_anchors, read_measurements
from radioloc.locate.base import LocateRequest, methods, run_method

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0], [10.0, -5.0]])
IDS = [f"A{i}" for i in range(len(ANCHORS))]


def anchors_table(points=ANCHORS) -> pd.DataFrame:
    out = pd.DataFrame({"id": IDS, "x": points[:, 0], "y": points[:, 1]})
    if points.shape[1] == 3:
        out["z"] = points[:, 2]
    return out


def truth(n_times=8, seed=0):
    """Two nodes moving at constant velocity inside the anchors: times (T,), positions
    {node: (T, 2)}."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_times, dtype=float)
    pos = {}
    for node in ("n1", "n2"):
        start, vel = rng.uniform([4, 3], [16, 12]), rng.uniform(-0.4, 0.4, 2)
        pos[node] = start + t[:, None] * vel
    return t, pos


def range_log(std=0.05, outlier=None, seed=1, n_times=8, anchors=ANCHORS):
    """Every node ranges to every anchor at every time; ``outlier=(node, step, anchor,
    excess)`` adds an NLOS excess to one range."""
    t, pos = truth(n_times)
    rng = np.random.default_rng(seed)
    rows = []
    for node, p in pos.items():
        for i, ti in enumerate(t):
            xyz = p[i] if anchors.shape[1] == 2 else np.r_[p[i], 1.0]
            for a, pa in enumerate(anchors):
                d = np.linalg.norm(xyz - pa) + std * rng.standard_normal()
                if outlier is not None and outlier[:3] == (node, i, a):
                    d += outlier[3]
                rows.append((ti, node, IDS[a], "range", d))
    return pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"]), pos


def error_m(out: pd.DataFrame, pos: dict) -> np.ndarray:
    errs = []
    for node, p in pos.items():
        got = out[out.node == node].sort_values("time")
        errs.append(np.linalg.norm(got[["x", "y"]].to_numpy() - p[got["time"].astype(int)], axis=1))
    return np.concatenate(errs)


def run(method, meas, anchors=None, **options):
    """``method`` on the log ``meas`` written and read back as ``radioloc locate`` reads it."""
    with tempfile.TemporaryDirectory() as tmp:
        meas.to_csv(Path(tmp) / "m.csv", index=False)
        (anchors_table() if anchors is None else anchors).to_csv(Path(tmp) / "a.csv", index=False)
        table = read_anchors(Path(tmp) / "a.csv")
        req = LocateRequest(read_measurements(Path(tmp) / "m.csv", anchors=table), table,
                            options={k: str(v) for k, v in options.items()})
    return run_method(method, req)


@pytest.mark.parametrize("method", ["localml", "ransac", "lsq", "gn"])
def test_snapshot_methods_fix_every_epoch_near_the_truth(method):
    meas, pos = range_log()
    out = run(method, meas)
    assert len(out) == 16 and not out.duplicated(["time", "node"]).any()
    assert error_m(out, pos).max() < 0.2
    # localml and ransac have none of their own: the health check writes its window fits'
    assert "cov_xx" in out.columns and "uncertainty_m" in out.columns


def test_lsq_covariance_is_the_crb_of_the_sigma_given():
    meas, pos = range_log(std=0.0)
    a = run("lsq", meas, range_std_m=0.1)
    b = run("lsq", meas, range_std_m=0.2)
    assert error_m(a, pos).max() < 1e-6
    np.testing.assert_allclose(b["cov_xx"], 4 * a["cov_xx"], rtol=1e-6)
    # at the truth, (J'J)^-1 sigma^2 from the unit vectors to the anchors
    row = a.iloc[0]
    p = pos[row.node][int(row.time)]
    u = (p - ANCHORS) / np.linalg.norm(p - ANCHORS, axis=1, keepdims=True)
    cov = 0.01 * np.linalg.inv(u.T @ u)
    np.testing.assert_allclose([row.cov_xx, row.cov_xy, row.cov_yy],
                               [cov[0, 0], cov[0, 1], cov[1, 1]], rtol=1e-6)


@pytest.mark.parametrize("method,options", [("ransac", {}), ("localml", {}),
                                            ("lsq", {"loss": "tukey"}),
                                            ("lsq", {"loss": "cauchy"})])
def test_robust_methods_resist_one_nlos_range(method, options):
    meas, pos = range_log(outlier=("n1", 3, 2, 6.0))
    out = run(method, meas, **options)
    assert error_m(out, pos).max() < 0.3
    # the linear loss spreads the outlier over every row: a fix that fits none of them,
    # unless the row is excluded (the default)
    with pytest.raises(InputError, match="node 'n1' at time 3.0: the measurements do not fit"):
        run("lsq", meas, exclude_faults="0")
    out = run("lsq", meas)
    assert error_m(out, pos).max() < 0.3 and out.attrs["summary"]["rows_excluded"] == 1


def tdoa_aoa_log(n_times=8):
    """Time differences to A0 from the four other anchors and bearings from A0 and A2."""
    t, pos = truth(n_times)
    rows = []
    rng = np.random.default_rng(3)
    for node, p in pos.items():
        for i, ti in enumerate(t):
            d = np.linalg.norm(p[i] - ANCHORS, axis=1)
            for a in range(1, 5):
                rows.append((ti, node, IDS[a], "tdoa", d[a] - d[0] + 0.01 * rng.standard_normal(),
                             "A0"))
            for a in (0, 2):
                v = p[i] - ANCHORS[a]
                rows.append((ti, node, IDS[a], "aoa", np.arctan2(v[1], v[0])
                             + 0.002 * rng.standard_normal(), ""))
    return pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value", "reference"]), pos


def test_lsq_reads_tdoa_and_aoa_rows():
    meas, pos = tdoa_aoa_log()
    out = run("lsq", meas, tdoa_std_m=0.01, aoa_std_rad=0.002)
    assert len(out) == 16 and error_m(out, pos).max() < 0.1
    assert (out["measurements"] == 6).all() and (out["uncertainty_m"] < 0.1).all()
    aoa_only = run("lsq", meas[meas.kind == "aoa"], aoa_std_rad=0.002)
    err = error_m(aoa_only, pos)
    assert (err < 4 * aoa_only.sort_values(["node", "time"])["uncertainty_m"].to_numpy()).all()


def test_moving_the_anchors_moves_the_fixes():
    meas, pos = range_log(std=0.0)
    shift = np.array([3.0, -2.0])
    for method in ("localml", "ransac", "lsq"):
        a = run(method, meas)
        b = run(method, meas, anchors_table(ANCHORS + shift))
        np.testing.assert_allclose(b[["x", "y"]].to_numpy() - a[["x", "y"]].to_numpy(),
                                   np.broadcast_to(shift, (len(a), 2)), atol=0.05)


def test_3d_anchors_need_the_node_height_for_the_2d_methods():
    points = np.c_[ANCHORS, [3.0, 2.5, 3.0, 2.0, 2.8]]
    meas, pos = range_log(std=0.0, anchors=points)
    with pytest.raises(InputError, match="tag_height_m"):
        run("localml", meas, anchors_table(points))
    for method in ("localml", "ransac", "lsq"):
        out = run(method, meas, anchors_table(points), tag_height_m=1.0)
        assert error_m(out, pos).max() < 0.05, method


@pytest.mark.parametrize("method", ["localml", "ransac", "lsq"])
def test_epochs_with_too_few_anchors_are_named_or_skipped(method):
    meas, pos = range_log()
    thin = meas[~((meas.node == "n2") & (meas.time == 5.0) & meas.peer.isin(IDS[:4]))]
    with pytest.raises(GeometryError, match=r"node 'n2' at time 5\.0.*on_degenerate=skip"):
        run(method, thin)
    with pytest.warns(UserWarning, match="1 of 16 epochs left out"):
        out = run(method, thin, on_degenerate="skip")
    assert len(out) == 15 and out.attrs["summary"]["epochs_skipped_few_ranges"] == 1


def test_bad_options_and_kinds_are_named():
    meas, _ = range_log()
    with pytest.raises(ConfigError, match="option loss"):
        run("lsq", meas, loss="l1")
    with pytest.raises(ConfigError, match="option threshold_m"):
        run("ransac", meas, threshold_m=-1)
    with pytest.raises(ConfigError, match="option alpha"):
        run("localml", meas, alpha=2)
    with pytest.raises(ConfigError, match="option loss"):
        run("smoother", meas, loss="l1")
    rss = meas.assign(kind="rss", value=-60.0)
    for method in ("localml", "ransac", "lsq", "smoother"):
        with pytest.raises(InputError, match="rss"):
            run(method, pd.concat([meas, rss.iloc[:3]]))


def test_smoother_method_reads_tdoa_and_aoa_rows():
    """The smoother takes the kinds ekf-track takes: a log of time differences and bearings
    (no range) is smoothed near the truth, the rows counted per kind; the LOS/NLOS
    max-mixture, a model of ranges, is refused by name on it."""
    meas, pos = tdoa_aoa_log(n_times=20)
    out = run("smoother", meas, tdoa_std_m=0.01, aoa_std_rad=0.002, q=0.01)
    assert len(out) == 40 and error_m(out, pos).max() < 0.1
    summary = out.attrs["summary"]
    assert summary["loss"] == "linear" and summary["measurements"] == {"tdoa": 160, "aoa": 80}
    bearings = run("smoother", meas[meas.kind == "aoa"], aoa_std_rad=0.002, q=0.01)
    err = error_m(bearings, pos)
    assert err.max() < 0.5
    assert (err < 4 * bearings.sort_values(["node", "time"])["uncertainty_m"].to_numpy()).all()
    with pytest.raises(ConfigError, match="max-mixture"):
        run("smoother", meas, loss="max-mixture")
    ranges, _ = range_log(n_times=20)
    both = run("smoother", pd.concat([meas, ranges.assign(reference="")]), tdoa_std_m=0.01,
               aoa_std_rad=0.002, q=0.01, los_std_m=0.05, nlos_mean_m=1.0, alpha=0.9)
    assert both.attrs["summary"]["loss"] == "max-mixture" and error_m(both, pos).max() < 0.1


def test_smoother_method_tracks_each_node_of_a_range_log():
    meas, pos = range_log(std=0.05, n_times=20)
    out = run("smoother", meas, loss="huber", range_std_m=0.05, q=0.01)
    assert len(out) == 40 and not out.duplicated(["time", "node"]).any()
    assert error_m(out, pos).max() < 0.15
    assert {"uncertainty_m", "cov_xx", "cov_xy", "cov_yy"} <= set(out.columns)
    assert out.attrs["summary"]["loss"] == "huber"


def test_cli_lists_kinds_and_runs_the_new_methods(tmp_path):
    meas, pos = range_log()
    meas.to_csv(tmp_path / "m.csv", index=False)
    anchors_table().to_csv(tmp_path / "a.csv", index=False)
    runner = CliRunner()
    listing = runner.invoke(app, ["methods"], env={"COLUMNS": "300"})
    assert listing.exit_code == 0 and "kinds" in listing.output
    for name, m in methods().items():
        assert name in listing.output
    for method in ("localml", "ransac", "lsq", "smoother"):
        res = runner.invoke(app, ["locate", str(tmp_path / "m.csv"), "--anchors",
                                  str(tmp_path / "a.csv"), "--method", method,
                                  "--out", str(tmp_path / f"{method}.csv")])
        assert res.exit_code == 0, res.output
        out = pd.read_csv(tmp_path / f"{method}.csv")
        assert len(out) == 16 and error_m(out, pos).max() < 0.5


def sensor_log(n=30, period=0.5, std=0.0, seed=4):
    """Two targets on straight lines ranged by one sensor circling them, turning 1.3 rad
    per sample (paper 002's setting): measurements, anchors with a ``time`` column (the
    sensor's track, sampled at the range times), truth."""
    rng = np.random.default_rng(seed)
    t = period * np.arange(n)
    track_t = t
    ang = 1.3 * np.arange(n)
    sensor = np.c_[10 * np.cos(ang), 10 * np.sin(ang)]
    anchors = pd.DataFrame({"id": "S", "time": track_t, "x": sensor[:, 0], "y": sensor[:, 1]})
    pos = {"n1": np.array([-3.0, -2.0]) + t[:, None] * [0.4, 0.2],
           "n2": np.array([2.0, -3.0]) + t[:, None] * [-0.3, 0.4]}
    rows = []
    s_t = np.c_[np.interp(t, track_t, sensor[:, 0]), np.interp(t, track_t, sensor[:, 1])]
    for node, p in pos.items():
        d = np.linalg.norm(p - s_t, axis=1) + std * rng.standard_normal(n)
        rows += [(ti, node, "S", "range", di) for ti, di in zip(t, d)]
    meas = pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"])
    return meas, anchors, {k: (t, v) for k, v in pos.items()}


def track_error(out, pos):
    errs = []
    for node, (t, p) in pos.items():
        got = out[out.node == node]
        np.testing.assert_allclose(got["time"], t)
        errs.append(np.linalg.norm(got[["x", "y"]].to_numpy() - p, axis=1))
    return np.concatenate(errs)


@pytest.mark.parametrize("method", ["closed-form", "newton"])
def test_single_sensor_methods_track_targets_from_a_moving_anchor(method):
    meas, anchors, pos = sensor_log()
    out = run(method, meas, anchors, accel_std_mps2=0.001, range_std_m=0.001)
    assert len(out) == 60 and not out.duplicated(["time", "node"]).any()
    assert track_error(out, pos).max() < 0.05
    assert ("cov_xx" in out.columns) == (method == "closed-form")
    noisy, _, _ = sensor_log(std=0.1)
    out = run(method, noisy, anchors, range_std_m=0.1, window=12)
    assert np.sqrt(np.mean(track_error(out, pos) ** 2)) < 0.4


def test_closed_form_covariance_follows_the_range_noise():
    meas, anchors, pos = sensor_log(std=0.1)
    a = run("closed-form", meas, anchors, range_std_m=0.1, accel_std_mps2=0.0)
    b = run("closed-form", meas, anchors, range_std_m=0.2, accel_std_mps2=0.0)
    assert (b["uncertainty_m"] > 1.5 * a["uncertainty_m"]).all()


def test_moving_anchors_are_validated_and_refused_by_methods_that_do_not_take_them(tmp_path):
    meas, anchors, pos = sensor_log()
    with pytest.raises(InputError, match="time column.*closed-form, ekf-track, lsq, newton, smoother"):
        run("gn", meas, anchors)
    short = anchors[anchors["time"] <= 10.0].assign(time=lambda f: f["time"] - 0.01)
    with pytest.raises(InputError, match=r"anchor 'S': no position at time 10\.0"):
        run("closed-form", meas, short)
    twice = pd.concat([anchors, anchors.iloc[[3]]])
    twice.to_csv(tmp_path / "a.csv", index=False)
    with pytest.raises(InputError, match=r"line 32, column 'time'.*anchor 'S' at time 1\.5"):
        read_anchors(tmp_path / "a.csv")
    uneven = meas[~((meas.node == "n1") & (meas.time == 2.0))].copy()
    uneven.loc[(uneven.node == "n1") & (uneven.time == 3.0), "time"] = 3.2
    with pytest.raises(InputError, match=r"node 'n1'.*time 3\.2.*uniform grid"):
        run("newton", uneven, anchors)
    gap = meas[~((meas.node == "n1") & meas.time.isin([2.0, 4.0]))]
    with pytest.raises(GeometryError, match=r"node 'n1', the window ending at time .*-o window"):
        run("closed-form", gap, anchors)
    out = run("closed-form", gap, anchors, accel_std_mps2=0.001, range_std_m=0.001, window=16)
    assert len(out) == 58 and error_m_at(out, pos) < 0.05


def error_m_at(out, pos):
    errs = []
    for node, (t, p) in pos.items():
        got = out[out.node == node]
        i = np.searchsorted(t, got["time"].to_numpy())
        errs.append(np.linalg.norm(got[["x", "y"]].to_numpy() - p[i], axis=1))
    return np.concatenate(errs).max()


def test_lsq_fixes_each_epoch_with_the_anchors_where_they_were_at_its_time():
    """Three fixed anchors and one that moves (rows at 0 s and 10 s, interpolated)."""
    t, pos = truth()
    start, end = np.array([0.0, 0.0]), np.array([6.0, -4.0])
    track = lambda ti: start + (end - start) * ti / 10.0          # noqa: E731
    anchors = pd.DataFrame({"id": ["A0", "A0", "A1", "A2", "A3"], "time": [0.0, 10.0] + [np.nan] * 3,
                            "x": [0.0, 6.0, 20.0, 20.0, 0.0], "y": [0.0, -4.0, 0.0, 15.0, 15.0]})
    rows = []
    for node, p in pos.items():
        for i, ti in enumerate(t):
            pts = np.r_[[track(ti)], ANCHORS[1:4]]
            d = np.linalg.norm(p[i] - pts, axis=1)
            rows += [(ti, node, f"A{a}", "range", d[a]) for a in range(4)]
    meas = pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"])
    out = run("lsq", meas, anchors)
    assert len(out) == 16 and error_m(out, pos).max() < 1e-6
    # A0 held at 0 s: its rows are left out of the fixes, and the health check names it
    with pytest.warns(UserWarning, match="anchor 'A0' is wrong"):
        held = run("lsq", meas, anchors.drop_duplicates("id").drop(columns="time"))
    assert held.attrs["summary"]["excluded_by_row"].keys() == {"range A0"}


@pytest.mark.parametrize("method,options", [("ekf-track", {}), ("smoother", {"loss": "huber"})])
def test_a_stated_range_bias_is_removed_exactly(method, options):
    """Ranges all long by c, with ``-o range_bias_m=c``, give the tracks of the unbiased log
    (the start fix included)."""
    meas, pos = range_log(std=0.05, n_times=12)
    base = run(method, meas, range_std_m=0.05, **options)
    long = meas.assign(value=meas["value"] + 0.7)
    same = run(method, long, range_std_m=0.05, range_bias_m=0.7, **options)
    np.testing.assert_allclose(same[["x", "y"]].to_numpy(), base[["x", "y"]].to_numpy(),
                               atol=1e-6, rtol=0)
