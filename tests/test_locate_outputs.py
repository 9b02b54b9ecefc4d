"""`radioloc locate` outputs: reproducible, one row per (time, node), covariance columns,
summary, reference errors, plot and export formats; the Python side (Track, anchor_ranges)."""

import json
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

import radioloc.locate.progress as progress_module
from radioloc.cli import app
from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.results import Track
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.io import read_anchors, read_measurements
from radioloc.io.measurements import Measurements
from radioloc.locate.adapter import anchor_ranges, default_models, node_observations
from radioloc.locate.base import LocateRequest, methods, run_method
from radioloc.locate.pf import fixed_lag
from radioloc.locate.plot import node_tracks
from radioloc.models.motion import WhiteAccelerationCV
from radioloc.models.ranging import GaussianRange

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MEAS, ANCHORS = str(EXAMPLES / "measurements.csv"), str(EXAMPLES / "anchors.csv")
runner = CliRunner()


def example(**options) -> tuple[pd.DataFrame, pd.DataFrame, dict]:
    a = read_anchors(ANCHORS)
    return read_measurements(MEAS, anchors=a), a, {k: str(v) for k, v in options.items()}


def reference(path: Path) -> Path:
    """The example's truth: tag1 x = 10 + 2 t, y = 12; tag2 x = 40, y = 5 + t."""
    t = np.arange(5.0)
    ref = pd.concat([pd.DataFrame({"time": t, "node": "tag1", "x": 10 + 2 * t, "y": 12.0}),
                     pd.DataFrame({"time": t, "node": "tag2", "x": 40.0, "y": 5 + t})])
    ref.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("args", [["--method", "gn"], ["--method", "ekf-track"],
                                  ["--method", "ekf-track", "--smooth"], ["--method", "pf"],
                                  ["--method", "pf", "--smooth"]])
def test_two_runs_give_byte_identical_output_and_summary(tmp_path, args):
    outs = []
    for k in range(2):
        out = tmp_path / f"run{k}.csv"
        res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--out", str(out),
                                  "--quiet", *args])
        assert res.exit_code == 0, res.output
        summary = json.loads(out.with_name(f"run{k}.summary.json").read_text())
        outs.append((out.read_bytes(), summary))
    assert outs[0][0] == outs[1][0]
    assert outs[0][1] == outs[1][1]
    if "pf" in args:
        assert outs[0][1]["seed"] == 0


def test_pf_smooth_stays_within_half_a_metre_of_the_rts_track_for_several_seeds():
    meas, a, _ = example()
    ref = run_method("ekf-track", LocateRequest(meas, a, options={"smooth": "1"}))
    filt = run_method("ekf-track", LocateRequest(meas, a))
    for seed in (1, 9):
        out = run_method("pf", LocateRequest(meas, a, options={"smooth": "1", "seed": str(seed)}))
        assert out.attrs["summary"]["seed"] == seed
        err = np.hypot(out.x - ref.x, out.y - ref.y)
        for node in ("tag1", "tag2"):
            assert np.sqrt(np.mean(err[out.node == node] ** 2)) < 0.5, (seed, node)
        # the smoothed spread is not orders of magnitude below the filter's
        assert out.uncertainty_m.min() > 0.3 * filt.uncertainty_m.min(), seed
    causal = run_method("pf", LocateRequest(meas, a, options={"seed": "1"}))
    assert np.hypot(causal.x - ref.x, causal.y - ref.y).max() < 0.5    # no jump at the start


def test_fixed_lag_shortens_the_lag_where_one_ancestor_is_left():
    rng = np.random.default_rng(0)
    K = 50
    history = [rng.standard_normal((K, 2)) for _ in range(4)]
    ancestors = [np.arange(K), np.arange(K), np.zeros(K, dtype=int), np.arange(K)]
    mean, cov = fixed_lag(history, ancestors, lag=3)
    # step 3's particles all descend from one particle of step 0 (through step 2): without
    # the rule step 0's smoothed covariance would be exactly zero; with it, the lag is 1
    assert np.trace(cov[0]) > 0.1
    np.testing.assert_allclose(mean[0], history[0].mean(axis=0))
    np.testing.assert_allclose(mean[3], history[3].mean(axis=0))


def test_gn_skips_epochs_with_too_few_ranges_and_counts_them(tmp_path):
    meas, a, _ = example()
    short = meas[~((meas.time == 2.0) & (meas.node == "tag1") & meas.peer.isin(["A3", "A4"]))]
    with pytest.raises(GeometryError, match="on_degenerate=skip"):
        run_method("gn", LocateRequest(short, a))
    with pytest.warns(UserWarning, match="1 of 10 epochs left out: 1 with fewer than 3"):
        out = run_method("gn", LocateRequest(short, a, options={"on_degenerate": "skip"}))
    assert len(out) == 9 and not ((out.time == 2.0) & (out.node == "tag1")).any()
    assert out.attrs["summary"]["epochs_skipped_few_ranges"] == 1


def test_gn_uncertainty_uses_one_sigma_for_the_log_not_each_epochs_residuals():
    meas, a, _ = example()
    pooled = run_method("gn", LocateRequest(meas, a))
    std = pooled.attrs["summary"]["std_m"]
    assert 0.01 < std < 1.0
    given = run_method("gn", LocateRequest(meas, a, options={"std_m": repr(std)}))
    np.testing.assert_allclose(given.uncertainty_m, pooled.uncertainty_m, rtol=1e-9)
    double = run_method("gn", LocateRequest(meas, a, options={"std_m": repr(2 * std)}))
    np.testing.assert_allclose(double.uncertainty_m, 2 * pooled.uncertainty_m, rtol=1e-9)
    # three anchors in 2-D: one degree of freedom; a range 4 m off moves the fix by metres
    bent = meas[~((meas.node == "tag1") & (meas.peer == "A4"))].copy()
    bent.loc[(bent.node == "tag1") & (bent.time == 2.0) & (bent.peer == "A1"), "value"] += 4.0
    out = run_method("gn", LocateRequest(bent, a))
    row = out[(out.node == "tag1") & (out.time == 2.0)].iloc[0]
    assert np.hypot(row.x - 14.0, row.y - 12.0) > 1.0
    assert row.uncertainty_m > 0.5      # not centimetres from its own residual


@pytest.mark.parametrize("method", ["gn", "ekf-track", "pf"])
def test_rows_are_time_major_one_per_time_and_node_with_covariance_columns(method):
    meas, a, _ = example()
    out = run_method(method, LocateRequest(meas, a))
    assert not out.duplicated(["time", "node"]).any()
    assert list(out.time) == sorted(out.time)
    assert list(out.node[:2]) == ["tag1", "tag2"]
    np.testing.assert_allclose(out.uncertainty_m ** 2, out.cov_xx + out.cov_yy, rtol=1e-12)
    assert (out.cov_xy ** 2 < out.cov_xx * out.cov_yy).all()


def test_summary_reference_errors_and_plot(tmp_path):
    ref = reference(tmp_path / "ref.csv")
    out, png = tmp_path / "t.csv", tmp_path / "t.png"
    res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--method", "ekf-track",
                              "--out", str(out), "--reference", str(ref), "--plot", str(png)])
    assert res.exit_code == 0, res.output
    assert "RMSE" in res.stdout and "inside 95 % ellipse" in res.stdout
    summary = json.loads((tmp_path / "t.summary.json").read_text())
    est = pd.read_csv(out)
    truth = pd.read_csv(ref)
    both = est.merge(truth, on=["time", "node"], suffixes=("", "_ref"))
    e = np.hypot(both.x - both.x_ref, both.y - both.y_ref)
    r = summary["reference"]
    assert r["rows_scored"] == 10 and summary["rows_read"] == 40
    assert r["rmse_m"] == pytest.approx(float(np.sqrt(np.mean(e ** 2))))
    assert r["p90_m"] == pytest.approx(float(np.percentile(e, 90)))
    assert 0.0 <= r["inside_95"] <= 1.0
    assert summary["ranges"] == 40 and summary["restarts"] == 0
    assert not any("time_s" in k or "seconds" in k for k in summary)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_tum_and_geojson_exports(tmp_path):
    res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--out",
                              str(tmp_path / "t.tum")])
    assert res.exit_code == 0, res.output
    csv = run_method("gn", LocateRequest(*example()[:2]))
    for node in ("tag1", "tag2"):
        rows = np.loadtxt(tmp_path / f"t.{node}.tum")
        assert rows.shape == (5, 8)
        mine = csv[csv.node == node]
        np.testing.assert_allclose(rows[:, :3], mine[["time", "x", "y"]].to_numpy())
        np.testing.assert_array_equal(rows[:, 3:], [[0, 0, 0, 0, 1]] * 5)
    res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--format", "geojson",
                              "--out", str(tmp_path / "t.json")])
    assert res.exit_code == 2 and "--origin" in res.output    # metres are no longitude
    assert not (tmp_path / "t.json").exists()
    res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--format", "geojson",
                              "--origin", "52.5,13.37,40", "--out", str(tmp_path / "t.json")])
    assert res.exit_code == 0, res.output
    fc = json.loads((tmp_path / "t.json").read_text())
    kinds = [f["geometry"]["type"] for f in fc["features"]]
    assert kinds.count("LineString") == 2 and kinds.count("Point") == 10 + 4
    res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--format", "kml"])
    assert res.exit_code == 2 and "expected one of csv, parquet, tum, geojson" in res.output


def test_progress_bar_never_reaches_stdout(monkeypatch):
    monkeypatch.setattr(progress_module, "DELAY_S", 0.0)
    res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--method", "ekf-track"])
    assert res.exit_code == 0
    est = pd.read_csv(pd.io.common.StringIO(res.stdout))
    assert len(est) == 10 and list(est.columns[:4]) == ["time", "node", "x", "y"]


def test_track_to_frame_gives_the_cli_table_and_indexing_gives_one_run():
    meas, a, _ = example()
    cli = run_method("ekf-track", LocateRequest(meas, a))
    per_node = node_tracks(cli)
    stacked = Track(np.stack([t.position for t in per_node.values()]),
                    np.stack([t.covariance for t in per_node.values()]),
                    per_node["tag1"].time)
    frame = stacked.to_frame(list(per_node))
    pd.testing.assert_frame_equal(frame, cli[frame.columns.tolist()], check_dtype=False)
    one = stacked[1]
    assert one.batch_shape == () and np.array_equal(one.position, per_node["tag2"].position)
    assert list(one.to_frame().columns[:2]) == ["time", "run"]
    with pytest.raises(InputError, match="names"):
        stacked.to_frame(["only-one"])


def test_range_ekf_gates_by_default_as_the_cli_does():
    anchors = np.array([[0.0, 0.0], [50.0, 0.0], [50.0, 30.0], [0.0, 30.0]])
    truth = np.array([10.0, 12.0])
    r = np.tile(np.linalg.norm(anchors - truth, axis=1), (6, 1))
    r[3, 0] += 8.0                                  # one range 8 m long
    ekf = RangeEKF(WhiteAccelerationCV(1.0, 2), GaussianRange(0.15), anchors=anchors)
    assert ekf.gate == methods()["ekf-track"].options["gate"].parse("gate", "16")
    track = ekf.run(r, np.arange(6.0), prior_mean=[10, 12, 0, 0], prior_cov=np.eye(4))
    assert track.diagnostics["gated"][3] == 1
    assert np.linalg.norm(track.position[-1] - truth) < 0.05
    with pytest.raises(InputError, match="prior_mean"):
        ekf.run(r, prior_mean=[10, 12, 0], prior_cov=np.eye(4))


def test_anchor_ranges_gives_each_node_a_column_per_anchor():
    meas, a, _ = example()
    extra = meas.iloc[[0]].assign(value=meas.value.iloc[0] + 1.0)   # a duplicate row
    peer = meas.iloc[[0]].assign(peer="tag2")                        # a tag-to-tag range
    alone = peer.assign(node="tag3", peer="tag1")                    # a node with no anchor
    per_node = anchor_ranges(Measurements(pd.concat([meas, extra, peer, alone])), a, "pf")
    assert [n for n, _, _ in per_node] == ["tag1", "tag2"]
    for node, times, ranges in per_node:
        assert ranges.shape == (5, 4)
        np.testing.assert_array_equal(times, np.unique(meas.time[meas.node == node]))
    assert per_node[0][2][0, 0] == pytest.approx(meas.value.iloc[0] + 0.5)
    # the columns follow the anchors table, and hold the node's range observation
    log = Measurements(meas)
    _, _, flipped = anchor_ranges(log, a.iloc[::-1], "pf")[1]
    np.testing.assert_array_equal(flipped, per_node[1][2][:, ::-1])
    _, (obs,) = node_observations(log, a, "tag2", default_models(["range"], {}))
    np.testing.assert_array_equal(per_node[1][2][:, obs.context.index], obs.z)
    partial = meas[~((meas.node == "tag2") & (meas.time == 1.0))]
    (_, t1, r1), (_, t2, r2) = anchor_ranges(Measurements(partial), a, "pf")
    assert 1.0 in t1 and 1.0 not in t2 and r2.shape == (4, 4)
    with pytest.raises(InputError, match="method pf: the measurements hold no 'range' rows"):
        anchor_ranges(Measurements(meas.assign(kind="rss")), a, "pf")
    with pytest.raises(GeometryError, match="method smoother: no range to an anchor"):
        anchor_ranges(Measurements(meas.assign(peer=np.where(meas.node == "tag1", "tag2", "tag1"))),
                      a, "smoother")


@pytest.mark.parametrize("name", ["pf", "smoother"])
def test_a_node_without_a_start_is_named(name):
    meas, a, _ = example()
    few = pd.DataFrame({"time": [0.0, 0.0, 1.0], "node": "tag3", "peer": list(a.id[[0, 1, 0]]),
                        "kind": "range", "value": [5.0, 6.0, 5.5], "line": 0})
    with pytest.raises(GeometryError, match=f"method {name}: node 'tag3'.*anchor"):
        run_method(name, LocateRequest(pd.concat([meas, few], ignore_index=True), a))


def test_coverage_counts_an_error_outside_a_point_claim(tmp_path):
    from radioloc.locate.scoring import error_summary, reference_errors

    est = pd.DataFrame({"time": [0.0, 1.0], "node": "t", "x": [0.0, 1.0], "y": 0.0,
                        "uncertainty_m": [0.0, 1.0], "cov_xx": [0.0, 0.5], "cov_xy": 0.0,
                        "cov_yy": [0.0, 0.5]})
    ref = pd.DataFrame({"time": [0.0, 1.0], "x": [0.1, 1.1], "y": 0.0})   # every node's
    errors = reference_errors(est, ref)
    assert list(errors.inside_95) == [False, True]
    s = error_summary(errors, 2)
    assert s["inside_95"] == 0.5 and s["rmse_m"] == pytest.approx(0.1)


@pytest.mark.parametrize("method", ["ekf", "rls"])
def test_network_methods_report_once_per_time_and_node(tmp_path, method):
    (tmp_path / "priors.csv").write_text("node,x,y,var_x,var_y\nn1,1,1,4,4\nn2,9,1,4,4\n")
    a = read_anchors(ANCHORS)
    rows = ["time,node,peer,kind,value"]
    truth = {"n1": (2.0, 2.0), "n2": (8.0, 3.0)}
    for t in (0.0, 1.0):
        for node, p in truth.items():                  # both nodes are masters at each time
            for aid, x, y in zip(a.id, a.x, a.y):
                rows.append(f"{t},{node},{aid},range,{float(np.hypot(p[0] - x, p[1] - y))!r}")
    (tmp_path / "m.csv").write_text("\n".join(rows) + "\n")
    meas = read_measurements(tmp_path / "m.csv", anchors=a)
    out = run_method(method, LocateRequest(meas, a, priors=tmp_path / "priors.csv"))
    assert len(out) == 4 and not out.duplicated(["time", "node"]).any()
    assert list(out.node) == ["n1", "n2", "n1", "n2"]
    assert ("cov_xx" in out) == (method == "ekf")
