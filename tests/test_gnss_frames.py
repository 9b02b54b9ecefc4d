"""GNSS pseudoranges and Earth frames: the pseudorange model's clock groups and Earth-rotation
term, per-row weights, moving anchors measured only part of the time, the frames of the
anchors file, and GeoJSON in WGS84 (RFC 7946)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d
import pytest
import shapely.geometry
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.core.errors import ConfigError, InputError
from radioloc.io.logs import read_anchors
from radioloc.locate.frames import Frame, declared_frame, parse_origin, to_working
from radioloc.models.measurement import Context, StateLayout, numerical_jacobian
from radioloc.models.pseudorange import (EARTH_ROTATION_RAD_S, SPEED_OF_LIGHT_M_S,
                                         PseudorangeModel, cn0_std_m, elevation_std_m,
                                         fit_nlos)

runner = CliRunner()
#: a receiver near Potsdamer Platz, Berlin (ECEF, m) and six GNSS satellites ~2.6e7 m out
RECEIVER = np.array([3785108.0, 899901.5, 5037234.5])
SATELLITES = np.array([[14567933.9, 2809851.0, 21875628.1], [18145814.9, 11532054.2, 13684003.7],
                       [-2627841.0, 14823988.9, 21663854.6], [10451376.8, -15037178.6, 19241858.0],
                       [11874455.8, 6264512.5, 21645305.2], [502038.9, 11070509.5, 22974210.2],
                       [24847700.8, 5136094.4, -2716806.1], [6804981.0, -15005764.6, 21063486.5]])
GROUP = np.array([0, 1, 0, 0, 1, 1, 1, 0])


def sagnac_range(receiver: np.ndarray, satellite: np.ndarray) -> np.ndarray:
    """The range from where each satellite was at emission, in the Earth-fixed frame of
    reception: the satellite rotated about z by the Earth's turn during the flight, the
    flight time iterated to a fixed point (independent of the model's first-order term)."""
    tau = np.linalg.norm(satellite - receiver, axis=-1) / SPEED_OF_LIGHT_M_S
    for _ in range(5):
        a = EARTH_ROTATION_RAD_S * tau
        rotated = np.stack([np.cos(a) * satellite[:, 0] + np.sin(a) * satellite[:, 1],
                            -np.sin(a) * satellite[:, 0] + np.cos(a) * satellite[:, 1],
                            satellite[:, 2]], axis=-1)
        tau = np.linalg.norm(rotated - receiver, axis=-1) / SPEED_OF_LIGHT_M_S
    return tau * SPEED_OF_LIGHT_M_S


# ---- the pseudorange model ----------------------------------------------------------------

def test_earth_rotation_term_matches_the_rotated_satellite_to_millimetres():
    model = PseudorangeModel(std_m=5.0, earth_rotation=True)
    z = model.predict({"position": RECEIVER, "clock_offset": np.array(0.0)},
                      Context(points=SATELLITES))
    expected = sagnac_range(RECEIVER, SATELLITES)
    np.testing.assert_allclose(z, expected, atol=2e-3)
    plain = PseudorangeModel(std_m=5.0).predict(
        {"position": RECEIVER, "clock_offset": np.array(0.0)}, Context(points=SATELLITES))
    assert np.max(np.abs(expected - plain)) > 5.0          # metres: what ignoring it costs


def test_earth_rotation_is_the_same_in_a_local_enu_frame():
    lat, lon, h = pymap3d.ecef2geodetic(*RECEIVER)
    frame = Frame("enu", (lat, lon, h))
    to_local = lambda p: np.column_stack(pymap3d.ecef2enu(*np.atleast_2d(p).T, lat, lon, h))
    ecef = PseudorangeModel(std_m=5.0, earth_rotation=True)
    local = PseudorangeModel(std_m=5.0, earth_rotation=True, to_ecef=frame.to_ecef())
    offset = np.array(123.0)
    z_ecef = ecef.predict({"position": RECEIVER, "clock_offset": offset},
                          Context(points=SATELLITES))
    z_local = local.predict({"position": to_local(RECEIVER)[0], "clock_offset": offset},
                            Context(points=to_local(SATELLITES)))
    np.testing.assert_allclose(z_local, z_ecef, atol=1e-6)


@pytest.mark.parametrize("rotation", [False, True])
def test_clock_groups_and_earth_rotation_jacobian_equals_finite_differences(rotation):
    model = PseudorangeModel(std_m=5.0, groups=2, earth_rotation=rotation)
    layout = StateLayout(dim=3, order=1).with_model(model)
    assert layout.sizes["clock_bias"] == 1 and layout.clock == 1
    x = layout.join({"position": RECEIVER + [10.0, -20.0, 5.0], "velocity": np.ones(3),
                     "clock_offset": np.array(1e4), "clock_bias": np.array([37.0])})
    ctx = Context(points=SATELLITES, group=GROUP)
    z, H = layout.measure(model, x, ctx)
    numeric = numerical_jacobian(model, layout.split(x), ctx)
    for name in ("position", "clock_offset", "clock_bias"):
        np.testing.assert_allclose(H[..., layout.slices[name]], numeric[name], atol=1e-4)  # 2e7 m ranges
    base = PseudorangeModel(std_m=5.0, earth_rotation=rotation).predict(
        {"position": RECEIVER + [10.0, -20.0, 5.0], "clock_offset": np.array(1e4)}, ctx)
    np.testing.assert_allclose(z - base, 37.0 * GROUP, atol=1e-6)   # the second clock's bias


def test_a_group_beyond_the_models_clocks_is_refused():
    model = PseudorangeModel(std_m=5.0, groups=2)
    state = {"position": RECEIVER, "clock_offset": np.array(0.0), "clock_bias": np.zeros(1)}
    with pytest.raises(InputError, match="context.group"):
        model.predict(state, Context(points=SATELLITES, group=GROUP * 2))
    with pytest.raises(InputError, match="groups"):
        PseudorangeModel(std_m=5.0, groups=0)
    with pytest.raises(InputError, match="3-D"):
        PseudorangeModel(std_m=5.0, earth_rotation=True).predict(
            {"position": RECEIVER[:2], "clock_offset": np.array(0.0)},
            Context(points=SATELLITES[:, :2]))


def test_weights_from_elevation_and_cn0():
    np.testing.assert_allclose(elevation_std_m([90.0, 30.0], zenith_std_m=3.0), [3.0, 6.0])
    assert elevation_std_m(0.0) == elevation_std_m(5.0)      # floored, finite on the horizon
    np.testing.assert_allclose(cn0_std_m([45.0, 25.0], std_at_ref_m=5.0), [5.0, 50.0])
    with pytest.raises(ConfigError):
        elevation_std_m(30.0, zenith_std_m=0.0)


@pytest.mark.parametrize("alpha, mean", [(0.6, 35.0), (0.85, 10.0)])
def test_nlos_mixture_is_recovered_by_em(alpha, mean):
    rng = np.random.default_rng(11)
    std = rng.uniform(3.0, 10.0, 20000)
    los = rng.random(std.size) < alpha
    e = rng.normal(0.0, std) + np.where(los, 0.0, rng.exponential(mean, std.size))
    got_alpha, got_mean = fit_nlos(e, std, 0.5, 20.0)
    assert abs(got_alpha - alpha) < 0.03 and abs(got_mean - mean) < 0.1 * mean
    with pytest.raises(InputError, match="at least 10"):
        fit_nlos(np.full(5, 1.0), 1.0)


def test_mixture_modes_of_a_pseudorange():
    model = PseudorangeModel(std_m=2.0, nlos_mean_m=30.0, los_fraction=0.7)
    state = {"position": RECEIVER, "clock_offset": np.array(0.0)}
    ctx = Context(points=SATELLITES)
    z = model.predict(state, ctx) + np.array([0.0, 40.0, 0.0, -8.0, 0.5, 25.0, 1.0, 0.0])
    lp = model.mode_logpdf(z, state, ctx)
    assert lp.shape == (8, 2)
    np.testing.assert_array_equal(np.argmax(lp, -1) == 1,      # LOS wins near 0 only
                                  [True, False, True, True, True, False, True, True])


# ---- frames ---------------------------------------------------------------------------------

def test_frames_convert_with_pymap3d_and_refuse_what_they_cannot_place():
    assert parse_origin("52.5, 13.37") == (52.5, 13.37, 0.0)
    for bad in ("13.37", "a,b", "95,13,0"):
        with pytest.raises(ConfigError, match="--origin"):
            parse_origin(bad)
    lat, lon, h = 52.51, 13.375, 80.0
    table = pd.DataFrame({"id": ["A"], "x": [lon], "y": [lat], "z": [h], "frame": ["wgs84"]})
    assert declared_frame(table) == "wgs84"
    with pytest.raises(InputError, match="--frame"):
        declared_frame(table, "ecef")
    ecef = to_working(table, "wgs84", Frame("ecef"))
    np.testing.assert_allclose(ecef[["x", "y", "z"]].to_numpy()[0],
                               pymap3d.geodetic2ecef(lat, lon, h), atol=1e-6)
    enu = to_working(table, "wgs84", Frame("enu", (lat, lon, h)))
    np.testing.assert_allclose(enu[["x", "y", "z"]].to_numpy()[0], 0.0, atol=1e-6)
    with pytest.raises(ConfigError, match="--origin"):
        Frame("local").geodetic(np.zeros((1, 2)))


def test_anchor_bound_admits_satellites(tmp_path):
    path = tmp_path / "anchors.csv"
    pd.DataFrame({"id": ["G12"], "x": SATELLITES[:1, 0], "y": SATELLITES[:1, 1],
                  "z": SATELLITES[:1, 2], "group": ["GPS"], "frame": ["ecef"]}).to_csv(path, index=False)
    table = read_anchors(path)
    assert table["group"].tolist() == ["GPS"] and table["frame"].tolist() == ["ecef"]


# ---- through `radioloc locate` -----------------------------------------------------------

def simulated_drive(tmp_path: Path, seed: int = 3) -> tuple[Path, Path, pd.DataFrame]:
    """A receiver moving east at 10 m/s for 20 s (ECEF), pseudoranges with the Earth's
    rotation, a GPS and a GLONASS clock (drifting at -50 m/s, 55 m apart), noise 0.3 m;
    satellite G14 sets at t = 12 s."""
    rng = np.random.default_rng(seed)
    lat, lon, h = pymap3d.ecef2geodetic(*RECEIVER)
    t = np.arange(0.0, 20.0, 0.5)
    pos = np.column_stack(pymap3d.enu2ecef(10.0 * t, 0.0 * t, 0.0 * t, lat, lon, h))
    ids = ["G12", "R20", "G19", "G14", "R10", "R19", "R21", "G32"]
    rows, anchors = [], []
    for k, tk in enumerate(t):
        sats = SATELLITES + np.array([1.0, -1.0, 0.5]) * 800.0 * tk
        r = sagnac_range(pos[k], sats) + 3e4 - 50.0 * tk + 55.0 * GROUP
        for j, a in enumerate(ids):
            if a == "G14" and tk > 12.0:
                continue
            rows.append((tk, "rx", a, "pseudorange", r[j] + 0.3 * rng.normal()))
            anchors.append((a, tk, *sats[j], "GPS" if a[0] == "G" else "GLONASS", "ecef"))
    meas = pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"])
    anc = pd.DataFrame(anchors, columns=["id", "time", "x", "y", "z", "group", "frame"])
    anc = anc.sort_values(["id", "time"], kind="stable")
    mp, ap = tmp_path / "measurements.csv", tmp_path / "anchors.csv"
    meas.to_csv(mp, index=False)
    anc.to_csv(ap, index=False)
    truth = pd.DataFrame({"time": t, "x": pos[:, 0], "y": pos[:, 1], "z": pos[:, 2]})
    return mp, ap, truth


def horizontal_error(out: pd.DataFrame, truth: pd.DataFrame) -> np.ndarray:
    lat, lon, h = pymap3d.ecef2geodetic(*truth[["x", "y", "z"]].iloc[0])
    m = out.merge(truth, on="time", suffixes=("", "_t"))
    e, n, _ = pymap3d.geodetic2enu(m["lat"], m["lon"], m["height"], lat, lon, h)
    et, nt, _ = pymap3d.ecef2enu(m["x_t"], m["y_t"], m["z_t"], lat, lon, h)
    return np.hypot(e - et, n - nt)


@pytest.mark.parametrize("method", ["lsq", "ekf-track", "smoother"])
def test_moving_satellites_that_set_early_run_through_locate(tmp_path, method):
    mp, ap, truth = simulated_drive(tmp_path)
    out = tmp_path / "out.csv"
    res = runner.invoke(app, ["locate", str(mp), "--anchors", str(ap), "--method", method,
                              "--out", str(out), "-q", "-o", "pseudorange_std_m=0.3"])
    assert res.exit_code == 0, res.output
    est = pd.read_csv(out)
    assert len(est) == len(truth) and {"lat", "lon", "height"} <= set(est.columns)
    err = horizontal_error(est, truth)
    assert np.sqrt(np.mean(err ** 2)) < 1.5                  # 0.3 m noise, 7-8 satellites


def test_smoother_max_mixture_discounts_nlos_pseudoranges(tmp_path):
    mp, ap, truth = simulated_drive(tmp_path)
    meas = pd.read_csv(mp)
    late = (meas["peer"].isin(["G19", "R10"])) & (meas["time"] >= 5.0)   # reflected: +60 m
    meas.loc[late, "value"] += 60.0
    meas.to_csv(mp, index=False)
    err = {}
    for loss in ("linear", "max-mixture"):
        out = tmp_path / f"{loss}.csv"
        res = runner.invoke(app, ["locate", str(mp), "--anchors", str(ap), "--method",
                                  "smoother", "-o", f"loss={loss}", "-o",
                                  "pseudorange_std_m=0.3", "--out", str(out), "-q"])
        assert res.exit_code == 0, res.output
        err[loss] = np.sqrt(np.mean(horizontal_error(pd.read_csv(out), truth) ** 2))
    assert err["max-mixture"] < 2.0 and err["max-mixture"] < err["linear"] / 5


def test_a_measurement_outside_a_moving_anchors_track_is_refused(tmp_path):
    mp, ap, _ = simulated_drive(tmp_path)
    anc = pd.read_csv(ap)
    anc = anc[~((anc["id"] == "R20") & (anc["time"] > 15.0))]   # R20 measured till 19.5 s
    anc.to_csv(ap, index=False)
    res = runner.invoke(app, ["locate", str(mp), "--anchors", str(ap), "--method", "lsq"])
    assert res.exit_code == 2 and "'R20'" in res.output and "no position" in res.output


def test_earth_rotation_off_costs_metres(tmp_path):
    mp, ap, truth = simulated_drive(tmp_path)
    err = {}
    for flag in ("0", "1"):
        out = tmp_path / f"out{flag}.csv"
        res = runner.invoke(app, ["locate", str(mp), "--anchors", str(ap), "--method", "lsq",
                                  "-o", f"earth_rotation={flag}", "-o", "pseudorange_std_m=0.3",
                                  "--out", str(out)])
        assert res.exit_code == 0, res.output
        err[flag] = np.sqrt(np.mean(horizontal_error(pd.read_csv(out), truth) ** 2))
    assert err["1"] < 1.0 < 3.0 < err["0"]


def test_geojson_is_rfc7946_wgs84_and_matches_pymap3d(tmp_path):
    mp, ap, _ = simulated_drive(tmp_path)
    origin = (52.5, 13.37, 40.0)
    res = runner.invoke(app, ["locate", str(mp), "--anchors", str(ap), "--method", "lsq",
                              "--origin", ",".join(map(str, origin)), "--out",
                              str(tmp_path / "t.csv")])
    assert res.exit_code == 0, res.output
    local = pd.read_csv(tmp_path / "t.csv")                   # ENU at the origin
    res = runner.invoke(app, ["locate", str(mp), "--anchors", str(ap), "--method", "lsq",
                              "--origin", ",".join(map(str, origin)), "--out",
                              str(tmp_path / "t.geojson")])
    assert res.exit_code == 0, res.output
    fc = json.loads((tmp_path / "t.geojson").read_text())
    assert fc["type"] == "FeatureCollection" and "crs" not in fc      # RFC 7946: WGS84 only
    points = [f for f in fc["features"] if f["geometry"]["type"] == "Point"]
    lines = [f for f in fc["features"] if f["geometry"]["type"] == "LineString"]
    assert len(lines) == 1 and len(points) == len(local)   # moving anchors are not drawn
    for f in fc["features"]:
        assert f["type"] == "Feature" and isinstance(f["properties"], dict)
        geom = shapely.geometry.shape(f["geometry"])
        assert geom.is_valid and geom.has_z
        lon, lat = np.asarray(geom.coords)[:, 0], np.asarray(geom.coords)[:, 1]
        assert np.all(np.abs(lon) <= 180) and np.all(np.abs(lat) <= 90)
    lat, lon, h = pymap3d.enu2geodetic(local["x"], local["y"], local["z"], *origin)
    got = np.array([p["geometry"]["coordinates"] for p in points])
    np.testing.assert_allclose(got[:, 0], lon, atol=1e-7)
    np.testing.assert_allclose(got[:, 1], lat, atol=1e-7)
    np.testing.assert_allclose(got[:, 2], h, atol=1e-3)


def test_an_ecef_run_is_scored_horizontally_at_the_reference_start(tmp_path):
    mp, ap, truth = simulated_drive(tmp_path)
    ref = tmp_path / "reference.csv"
    truth.assign(frame="ecef").to_csv(ref, index=False)
    out = tmp_path / "out.csv"
    res = runner.invoke(app, ["locate", str(mp), "--anchors", str(ap), "--method", "lsq",
                              "--reference", str(ref), "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / "out.summary.json").read_text())["reference"]
    err = horizontal_error(pd.read_csv(out), truth)
    assert summary["rmse_m"] == pytest.approx(np.sqrt(np.mean(err ** 2)), rel=1e-6)
