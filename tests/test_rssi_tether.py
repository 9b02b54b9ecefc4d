"""Tests of the tethering simulation, its channel, the Herald loader and the p003 experiments."""

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from radioloc.channel.indoor_rss import IndoorChannel, office_walls, wall_crossings
from radioloc.core.errors import DataUnavailable, InputError
from radioloc.core.rng import block_generator
from radioloc.io.herald import load_session
from radioloc.models.rssi_logdistance import LogDistanceGaussian
from radioloc.models.rssi_trapezoid import fit_trapezoid_model
from radioloc.estimators.grid import GridFilter, GridGeometry
from radioloc.sim.tether import TetherParams, calibration_pairs, read_rssi, simulate_tether

HERALD = Path("/work/shared/data/herald-ble-rssi-distance")


def test_wall_crossings_known_answer():
    walls = np.array([[5.0, -10, 5.0, 10], [10.0, -10, 10.0, 10], [0, 5.0, 20, 5.0]])
    n = wall_crossings(np.array([[0.0, 0.0], [0.0, 0.0], [6.0, 0.0]]),
                       np.array([[12.0, 0.0], [4.0, 0.0], [6.0, 8.0]]), walls)
    np.testing.assert_array_equal(n, [2, 0, 1])


def test_channel_dbm_known_answer_and_radio_quantises():
    ch = IndoorChannel(shadow_std_db=0.0, rayleigh=False)
    walls = office_walls(40.0, 4)
    a, b = np.array([[2.0, 5.0], [2.0, 5.0]]), np.array([[8.0, 5.0], [15.0, 1.0]])
    p = ch.sample_dbm(a, b, walls, np.random.default_rng(0))
    # no shadowing/fading: P0 - 10 n log10(d) - W crossings; the second link crosses x = 10
    d = np.linalg.norm(a - b, axis=-1)
    np.testing.assert_allclose(p, -40.0 - 25.0 * np.log10(d) - 5.0 * np.array([0, 1]))
    r = read_rssi(ch, a, b, walls, np.random.default_rng(0))
    assert r.dtype.kind == "i" and np.all((r >= 0) & (r <= 100))
    np.testing.assert_array_equal(r, np.rint(p + 110).astype(int))
    assert r[0] > r[1]


def _imports(module) -> set[str]:
    import ast
    tree = ast.parse(Path(module.__file__).read_text())
    return {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)} | {
        a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}


def test_channel_does_not_import_the_sensor_quantiser():
    import radioloc.channel.indoor_rss as mod
    assert not any(m.startswith("radioloc.models") for m in _imports(mod))
    assert not hasattr(mod, "dbm_to_rssi100")


def test_tether_world_does_not_import_estimators():
    import radioloc.sim.tether as mod
    assert "radioloc.estimators" not in Path(mod.__file__).read_text()


def test_tether_without_noise_localizes_static_trackee():
    P = TetherParams(channel=IndoorChannel(shadow_std_db=1.0, rayleigh=False, wall_db=0.0))
    rng = np.random.default_rng(1)
    r, d = calibration_pairs(P, 5000, rng)
    model = fit_trapezoid_model(r, d, tau_min=0.5, sigma_min=0.5, window=2)
    tracker = GridFilter(GridGeometry.centred(40, 40, 1.0), model, epsilon=1e-6, blur_m=0.3,
                         location="peak")
    tr = simulate_tether(P, tracker, 4, 120, rng, compass=True, record_steps=(119,))
    assert tr.error_m.shape == (4, 120) and tr.track.position.shape == (4, 120, 2)
    # the recorded error is the injected tracker's estimate against the trackee's truth
    np.testing.assert_allclose(tr.error_m, np.linalg.norm(tr.track.position - tr.trackee_xy, axis=-1))
    assert set(tr.states) == {119}
    assert np.all(tr.localized.any(axis=1))
    first = tr.localized.argmax(axis=1)
    assert np.all(tr.error_m[np.arange(4), first] < 4.0)


def test_error_in_the_odometry_frame_equals_the_initial_frame_without_odometry_noise():
    """With exact odometry (and the robots kept off the outer walls) the tracker's current
    odometry frame is its initial frame: both scorings agree; with drift they differ."""
    P = TetherParams(channel=IndoorChannel(shadow_std_db=1.0, rayleigh=False, wall_db=0.0),
                     odo_scale_std=0.0, odo_heading_std=0.0, explore_radius_m=3.0,
                     roam_radius_m=2.0, start_range_m=(3.0, 5.0))
    rng = np.random.default_rng(3)
    model = fit_trapezoid_model(*calibration_pairs(P, 3000, rng), tau_min=0.5, sigma_min=0.5,
                                window=2)
    tracker = GridFilter(GridGeometry.centred(20, 20, 2.0), model, epsilon=1e-6, blur_m=0.3,
                         location="peak")
    tr = simulate_tether(P, tracker, 3, 60, rng, compass=True)
    np.testing.assert_allclose(tr.error_odom_m, tr.error_m, atol=1e-9)
    drift = simulate_tether(dataclasses.replace(P, odo_heading_std=0.2, odo_scale_std=0.1),
                            tracker, 3, 60, rng, compass=True)
    assert np.all(np.isfinite(drift.error_odom_m))
    assert not np.allclose(drift.error_odom_m, drift.error_m)


def test_logdistance_fit_recovers_parameters():
    rng = np.random.default_rng(2)
    d = rng.uniform(0.2, 10, 5000)
    r = 60 - 10 * 2.2 * np.log10(d) + rng.normal(0, 2, d.size)
    m = LogDistanceGaussian.fit(r, d)
    assert m.n == pytest.approx(2.2, abs=0.05) and m.s == pytest.approx(2.0, abs=0.1)
    assert m.likelihood(1.0, m.a) == pytest.approx(1.0)


def test_herald_missing_session_raises(tmp_path):
    with pytest.raises(DataUnavailable, match="herald"):
        load_session(tmp_path, "20210110-2247")


def test_herald_bad_row_raises(tmp_path):
    folder = tmp_path / "reference-data" / "rssi-raw-edison"
    folder.mkdir(parents=True)
    (folder / "s-A.csv").write_text("time,rssi,distance\nx,-60,10\ny,abc,20\n")
    with pytest.raises(InputError, match="line 3"):
        load_session(tmp_path, "s")


@pytest.mark.skipif(not HERALD.is_dir(), reason="Herald data absent")
def test_herald_loads_metres():
    df = load_session(HERALD, "20210110-2247")
    assert set(df["phone"]) == {"A", "B"}
    assert df["distance_m"].max() <= 3.5 and df["rssi_dbm"].max() < 0


def test_experiment_smoke(tmp_path, monkeypatch):
    from dataclasses import replace

    from radioloc.experiments.tether import TetherExperiment
    exp = TetherExperiment()
    cfg = replace(exp.config(False), runs=2, block_size=2, steps=40, calibration_pairs=3000,
                  ablations=("cells_1m",))
    assert exp.config(False).cell_m == 2.0 and exp.config(False).grid_cells == 20
    df = exp.run_block(cfg, np.arange(2), block_generator(0, 0))
    runs = df[df["table"] == "runs"]
    assert set(runs["compass"]) == {False, True} and len(runs) == 2 * 2 * 2 * 40
    assert set(runs["variant"]) == {"main", "cells_1m"}
    assert np.isfinite(runs["error_odom_m"]).all()
    assert set(df["table"]) == {"runs", "model", "fig3", "fig6", "team", "vsweep"}
    team = df[df["table"] == "team"]
    assert len(team) == 2 * 2 * 2 * 2 * 40          # runs x trackers x share x compass x steps
    # a block without run 0 holds no figure rows
    other = exp.run_block(cfg, np.arange(2, 4), block_generator(0, 1))
    assert set(other["table"]) == {"runs", "team", "vsweep"}
    summary = exp.summarize(cfg, df, tmp_path)
    names = {m.name for m in summary.metrics}
    assert {"mean_error_m_following_compass", "peak_error_m_following_nocompass", "time_to_localize_s",
            "mean_error_m_following_compass_odomframe"} <= names
    assert (tmp_path / "ablation.csv").is_file()
    assert any("| cells_1m (1 m cells) |" in n for n in summary.notes)
    assert (tmp_path / "fig2_model.png").is_file() and (tmp_path / "fig6_snapshots.png").is_file()
    assert (tmp_path / "fig_sharing.png").is_file()


@pytest.mark.skipif(not HERALD.is_dir(), reason="Herald data absent")
def test_herald_experiment_smoke(tmp_path, monkeypatch):
    from dataclasses import replace

    from radioloc.experiments.herald_rssi import HeraldRssi
    monkeypatch.setenv("RADIOLOC_DATA", str(HERALD.parent))
    exp = HeraldRssi()
    cfg = replace(exp.config(False), runs=3, block_size=3, steps=10)
    df = exp.run_block(cfg, np.arange(3), block_generator(0, 0))
    assert set(df["table"]) == {"runs", "loglik", "model", "readings", "distance"}
    summary = exp.summarize(cfg, df, tmp_path)
    assert all(np.isfinite(m.value) for m in summary.metrics)


def test_locate_grid_rssi_finds_static_node(tmp_path):
    import pandas as pd

    from radioloc.locate.base import LocateRequest, run_method
    rng = np.random.default_rng(4)
    d = rng.uniform(0, 30, 8000)
    model = fit_trapezoid_model(np.clip(np.rint(70 - 2.0 * d + rng.normal(0, 0.3, d.size)), 0, 100), d,
                                tau_min=0.2, sigma_min=0.2, window=0)
    path = model.save(tmp_path / "model.json")
    anchors = pd.DataFrame({"id": ["a", "b", "c", "d"], "x": [0.0, 20, 20, 0], "y": [0.0, 0, 20, 20]})
    truth = np.array([7.0, 12.0])
    rows = []
    for t in range(10):
        for _, a in anchors.iterrows():
            dist = np.hypot(*(truth - [a.x, a.y]))
            rows.append((float(t), "n1", a.id, "rss", 70 - 2.0 * dist - 110, len(rows) + 2))
    meas = pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value", "line"])
    out = run_method("grid-rssi", LocateRequest(meas, anchors, calibration=path,
                                                options={"cell_m": "0.5"}))
    assert list(out.columns) == ["time", "node", "x", "y", "uncertainty_m", "cov_xx", "cov_xy",
                                 "cov_yy"] and len(out) == 10
    assert np.hypot(out["x"].iloc[-1] - 7.0, out["y"].iloc[-1] - 12.0) < 1.0
    with pytest.raises(InputError, match="calibration"):
        run_method("grid-rssi", LocateRequest(meas, anchors))


# the reduced-size reproduction of p003-tether (Monte Carlo bands, claim verdicts) is
# tests/test_repro_p003.py
