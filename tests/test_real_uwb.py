"""Hanyang UWB logs: converters, the data set authors' metric, every fitting locate method
on a converted log, and the reduced reproduction of ``real-uwb-hanyang``."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.core.errors import InputError
from radioloc.io.hanyang import (authors_reference, authors_rmse, authors_window, dynamic_runs,
                                 load_dynamic, load_static, measurement_rows)

runner = CliRunner()
TEST_DATA = Path(__file__).parent / "data" / "hanyang-uwb-outdoor"
RUN = TEST_DATA / "Dynamic_measurements" / "LOS" / "Trajectory_A" / "Case_1"
REAL = Path(os.environ.get("RADIOLOC_DATA", "/work/shared/data")) / "hanyang-uwb-outdoor"
need_real = pytest.mark.skipif(not (REAL / "Dynamic_measurements").is_dir(),
                               reason=f"Hanyang data set absent ({REAL}); set RADIOLOC_DATA")


# ---- converters on the few rows of tests/data --------------------------------------------

def test_static_files_drop_the_summary_rows():
    s = load_static(TEST_DATA)
    assert len(s) == 10 and set(s.condition) == {"LOS", "NLOS"}    # 5 rows each, 6 summaries out
    true = np.hypot(4.0, 0.25)                                       # anchor 125 cm, tag 100 cm
    np.testing.assert_allclose(s.true_range_m, true)
    los = s[s.condition == "LOS"].error_m.to_numpy()
    np.testing.assert_allclose(los, 0.01 * np.arange(5), atol=1e-9)


def test_measurement_rows_are_the_raw_asynchronous_ranges():
    run = load_dynamic(RUN)
    meas, anchors = measurement_rows(run)
    assert list(meas.columns) == ["time", "node", "peer", "kind", "value"]
    assert len(meas) == 4 * 40                                       # every range, none resampled
    assert set(meas.peer) == {"A3", "A5", "A9", "A12"} and (meas.kind == "range").all()
    assert meas.time.is_monotonic_increasing
    # the anchors answer at staggered times: one anchor per time stamp
    assert meas.groupby("time").size().max() == 1
    assert list(anchors.columns) == ["id", "x", "y", "z"]
    a3 = pd.read_csv(RUN / "A3.csv")
    np.testing.assert_allclose(meas[meas.peer == "A3"].value, a3["field.distanceFromTag"])


def _reference(t, x, y, z=None):
    return pd.DataFrame({"time_s": t, "x": x, "y": y, "z": np.zeros_like(t) if z is None else z})


def test_authors_metric_known_answer_on_a_made_up_trajectory_a():
    # out along y = -4 to x = 50, back along y = 4: the window is the return leg only
    t = np.arange(0.0, 101.0)
    x = np.where(t <= 50, t, 100 - t)
    y = np.where(t <= 50, -4.0, 4.0)
    z = np.zeros_like(t)
    z[70] = 0.8                                          # one reference row left out (|z| >= 0.5)
    ref = _reference(t, x, y, z)
    t0, t1 = authors_window(ref, "A")
    assert (t0, t1) == (50.0, 88.0)                      # x > 49.3; then x <= 12 and y > 3.4
    # estimate 0.3 m off in y everywhere; 3 m off outside the window (not scored)
    te = np.arange(0.5, 100.0, 0.5)
    xe = np.interp(te, t, x)
    ye = np.interp(te, t, y) + np.where((te >= t0) & (te <= t1), 0.3, 3.0)
    est = pd.DataFrame({"time_s": te, "x": xe, "y": ye, "z": np.full(te.size, 1.4)})
    out = authors_rmse(ref, est, "A")
    assert out["samples"] == int(np.sum((te >= t0) & (te <= t1)))
    # the row z = 0.8 at t = 70 is dropped, not interpolated: x, y are straight lines anyway
    np.testing.assert_allclose(out["rmse_2d"], 0.3, rtol=1e-12)
    np.testing.assert_allclose(out["rmse_3d"], np.hypot(0.3, 0.4), rtol=1e-12)
    xyz, inside = authors_reference(ref, np.array([70.0]), "A")
    assert inside[0] and xyz[0, 2] == 0.0                # interpolated over the kept rows


def test_authors_metric_refuses_what_it_cannot_score():
    t = np.arange(0.0, 10.0)
    ref = _reference(t, t, np.zeros_like(t))
    with pytest.raises(InputError, match="start of the authors' window"):
        authors_window(ref, "A")
    with pytest.raises(InputError, match="trajectory"):
        authors_window(ref, "C")
    t = np.arange(0.0, 101.0)
    ref = _reference(t, np.where(t <= 50, t, 100 - t), np.where(t <= 50, -4.0, 4.0))
    est = pd.DataFrame({"time_s": [1.0, 2.0], "x": [0.0, 0.0], "y": [0.0, 0.0]})
    with pytest.raises(InputError, match="no row between"):
        authors_rmse(ref, est, "A")


@need_real
def test_authors_metric_reproduces_rmsd_results_on_every_run():
    runs = [load_dynamic(f) for f in dynamic_runs(REAL)]
    assert runs
    for run in runs:
        for key in ("ls", "eskf"):
            got = authors_rmse(run.reference, run.estimates[key], run.trajectory)
            assert got["rmse_2d"] == pytest.approx(run.published[f"{key}_rmse_2d"], rel=0.01), run.name
            assert got["rmse_3d"] == pytest.approx(run.published[f"{key}_rmse"], rel=0.01), run.name


# ---- every fitting locate method on a converted log ---------------------------------------

def _write(meas, anchors, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    meas.to_csv(folder / "measurements.csv", index=False)
    anchors.to_csv(folder / "anchors.csv", index=False)
    return folder


def _locate(folder: Path, method: str, *opts: str) -> pd.DataFrame:
    args = ["locate", str(folder / "measurements.csv"), "--anchors", str(folder / "anchors.csv"),
            "--method", method, "--out", str(folder / f"{method}.csv")]
    for o in opts:
        args += ["-o", o]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, (method, res.output, res.exception)
    return pd.read_csv(folder / f"{method}.csv")


def _error(run, est) -> float:
    ref = run.reference
    dx = est.x - np.interp(est.time, ref.time_s, ref.x)
    dy = est.y - np.interp(est.time, ref.time_s, ref.y)
    late = est.time > 1.0                                  # after the start
    return float(np.sqrt(np.mean(dx[late] ** 2 + dy[late] ** 2)))


@pytest.mark.parametrize("method, opts, bound", [
    ("ekf-track", ["tag_height_m=1.1"], 0.3),
    ("ekf-track", ["tag_height_m=1.1", "smooth=1"], 0.3),
    ("pf", ["tag_height_m=1.1", "seed=2"], 0.4),
    ("pf", ["tag_height_m=1.1", "seed=2", "smooth=1", "smoother=backward",
            "trajectories=30"], 0.4),
])
def test_trackers_run_on_the_raw_converted_log(tmp_path, method, opts, bound):
    run = load_dynamic(RUN)                     # tag 1 m above trajectory z = 0.1: at 1.1 m
    folder = _write(*measurement_rows(run), tmp_path)
    est = _locate(folder, method, *opts)
    assert len(est) == 160 and np.isfinite(est[["x", "y", "uncertainty_m"]].to_numpy()).all()
    assert _error(run, est) < bound


def test_gn_runs_on_the_synchronous_export(tmp_path, monkeypatch):
    """The epoch export has every anchor at every time stamp: the snapshot method fits."""
    monkeypatch.setenv("RADIOLOC_DATA", str(TEST_DATA.parent))
    res = runner.invoke(app, ["datasets", "export", "hanyang", "--run", "LOS/A/1",
                              "--tag-height", "1.1", "--epoch-s", "0.1", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    est = _locate(tmp_path, "gn")
    run = load_dynamic(RUN)
    assert _error(run, est) < 0.3


def test_gn_refuses_the_asynchronous_rows_naming_node_and_time(tmp_path):
    folder = _write(*measurement_rows(load_dynamic(RUN)), tmp_path)
    res = runner.invoke(app, ["locate", str(folder / "measurements.csv"), "--anchors",
                              str(folder / "anchors.csv"), "--method", "gn"])
    assert res.exit_code != 0          # the anchors are nearly coplanar for a 3-D fix
    assert "coplanar" in str(res.output) + str(res.exception)
    res = runner.invoke(app, ["locate", str(folder / "measurements.csv"), "--anchors",
                              str(folder / "anchors.csv"), "--method", "gn", "-o",
                              "no_check=geometry"])
    assert res.exit_code != 0
    assert "has ranges to 1 anchor(s)" in str(res.output) + str(res.exception)


# ---- reduced reproduction of real-uwb-hanyang ----------------------------------------------

@need_real
def test_real_uwb_hanyang_reduced_reproduction(tmp_path, monkeypatch):
    """First 62 s of LOS/A/1 (the authors' window starts at 51.6 s), two pf seeds."""
    from dataclasses import replace

    from radioloc.experiments.base import get_experiment

    monkeypatch.setenv("RADIOLOC_DATA", str(REAL.parent))
    exp = get_experiment("real-uwb-hanyang")
    cfg = replace(exp.config(False), particles=150, ins_particles=100, max_time_s=62.0)
    from radioloc.core.rng import block_generator

    blocks = [exp.run_block(cfg, np.array([r]), block_generator(20, r)) for r in (0, 8)]
    results = pd.concat(blocks, ignore_index=True)
    summary = exp.summarize(cfg, results, tmp_path)
    m = {x.name: x.value for x in summary.metrics}
    # the data set's own estimates, in the authors' metric on the same 51.6-62 s
    run = load_dynamic(dynamic_runs(REAL)[0])
    for key in ("ls", "eskf"):
        est = run.estimates[key]
        direct = authors_rmse(run.reference, est[est.time_s <= 62.0], "A")["rmse_2d"]
        assert m[f"{key}_rmse2d_LOS_A_Case_1"] == pytest.approx(direct, rel=1e-9)
    # ekf-track is deterministic: the experiment's figure is that of `locate --method
    # ekf-track` at its defaults on the same rows (measured 1.40 m with the settings learned
    # from the log, 1.54 m at the fixed defaults: the far end of the track, x = 46-50 m, where
    # every method is worst)
    from radioloc.locate import LocateRequest, run_method

    meas, anchors = measurement_rows(run)
    with pytest.warns(UserWarning):
        out = run_method("ekf-track", LocateRequest(
            meas[meas.time <= 62.0], anchors, options={"tag_height_m": str(cfg.tag_height_m)}))
    direct = authors_rmse(run.reference, out.rename(columns={"time": "time_s"}), "A")["rmse_2d"]
    assert m["ekf-track_rmse2d_mean"] == pytest.approx(direct, rel=1e-9)
    assert m["ekf-track_rmse2d_mean"] < 1.553                   # below the authors' ESKF
    assert m["ekf-track-rts_rmse2d_mean"] < m["ekf-track_rmse2d_mean"]
    # pf: two seeds; band = 4 standard errors of their mean (at least 0.1 m)
    band = max(4 * m["pf_rmse2d_mean_seed_std"] / np.sqrt(2), 0.1)
    assert m["pf_rmse2d_mean"] == pytest.approx(PF_REDUCED, abs=band)
    assert "pf-ins_rmse2d_mean" in m and "gn_epochs_ambiguous" in m
    # verdicts on this window (ESKF 1.553 m, bar 1.242 m): neither tracker meets the bar here;
    # both are below the ESKF (pf 1.46 m over two seeds with the settings learned from the
    # log; 1.65 m with its EM fit alone, -o tune=0)
    verdicts = [c.holds for c in summary.claims]
    texts = [c.claim for c in summary.claims]
    assert not any("reproduces RMSD_results" in t for t in texts)    # cropped: not judged
    # (one run in this window: the paired PF-vs-EKF claim has no interval, so it is undecided)
    assert verdicts == [False, False, True, True, None], texts
    assert (tmp_path / "table.md").is_file() and (tmp_path / "trajectories.png").is_file()


#: mean authors' RMSE of causal pf on the reduced reproduction (two seeds), measured
PF_REDUCED = 1.465            # seeds of block_generator(20, 0) and (20, 8); their std 0.317 m


def test_cli_export_of_the_raw_rows_runs_the_trackers(tmp_path, monkeypatch):
    """``datasets export hanyang --epoch-s 0``: the rows as they arrive, as
    :func:`measurement_rows` gives them, then ``locate --method ekf-track``."""
    monkeypatch.setenv("RADIOLOC_DATA", str(TEST_DATA.parent))
    res = runner.invoke(app, ["datasets", "export", "hanyang", "--run", "LOS/A/1",
                              "--epoch-s", "0", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    meas = pd.read_csv(tmp_path / "measurements.csv")
    raw, _ = measurement_rows(load_dynamic(RUN))
    assert len(meas) == len(raw)
    np.testing.assert_allclose(meas.value, raw.value, atol=1e-6)
    est = _locate(tmp_path, "ekf-track", "tag_height_m=1.1")
    assert _error(load_dynamic(RUN), est) < 0.3
    # with --tag-height the ranges are projected and the anchors written in 2-D
    res = runner.invoke(app, ["datasets", "export", "hanyang", "--run", "LOS/A/1",
                              "--epoch-s", "0", "--tag-height", "1.1", "--out", str(tmp_path / "2d")])
    assert res.exit_code == 0, res.output
    assert list(pd.read_csv(tmp_path / "2d" / "anchors.csv").columns) == ["id", "x", "y"]
    est = _locate(tmp_path / "2d", "ekf-track")
    assert _error(load_dynamic(RUN), est) < 0.3
