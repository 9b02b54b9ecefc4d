"""Odometry rows (``odometry_dx``, ``odometry_dy``) as the control input of ``ekf-track`` and
``pf``: a simulated wheel robot ranging to four anchors at 1 Hz with odometry at 10 Hz."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter
from radioloc.io.logs import read_measurements
from radioloc.locate.base import LocateRequest, run_method
from radioloc.locate.batch_smooth import smooth_log
from radioloc.locate.odometry import odometry_controls, odometry_motion
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0.0, 20.0, 20.0, 0.0],
                        "y": [0.0, 0.0, 15.0, 15.0]})


def robot(seed: int, duration_s: float = 40.0, scale: float = 0.02,
          gyro_bias_rad_s: float = np.deg2rad(0.1), noise_m: float = 0.01,
          gyro_walk_rad: float = 0.002):
    """A wheel robot at about 0.8 m/s: ranges (0.3 m) to four anchors at 1 Hz, odometry at
    10 Hz from wheels with a scale error and a gyro heading with a bias and a random walk.

    Returns the log (``line`` column as read) and the truth at the odometry times.
    """
    rng = np.random.default_rng(seed)
    dt = 0.1
    t = np.arange(0.0, duration_s + 1e-9, dt)
    speed = 0.8 + 0.4 * np.sin(t / 7)
    heading = np.cumsum(0.35 * np.sin(t / 5) + 0.15) * dt
    step = speed * dt
    xy = np.cumsum(np.stack([step * np.cos(heading), step * np.sin(heading)], -1), axis=0)
    xy = xy - xy[0] + [4.0, 4.0]
    wheel = step * (1 + scale) + noise_m * np.sqrt(dt) * rng.standard_normal(t.size)
    gyro = heading + gyro_bias_rad_s * t + np.cumsum(gyro_walk_rad * rng.standard_normal(t.size))
    n = t.size - 1
    odo = pd.DataFrame({"time": np.r_[t[1:], t[1:]], "node": "bot", "peer": "wheel",
                        "kind": ["odometry_dx"] * n + ["odometry_dy"] * n,
                        "value": np.r_[(wheel * np.cos(gyro))[1:], (wheel * np.sin(gyro))[1:]]})
    tr = np.arange(0.0, duration_s + 1e-9, 1.0) + 0.013
    p = np.stack([np.interp(tr, t, xy[:, 0]), np.interp(tr, t, xy[:, 1])], -1)
    a = ANCHORS[["x", "y"]].to_numpy()
    r = np.linalg.norm(p[:, None] - a[None], axis=-1) + 0.3 * rng.standard_normal((tr.size, 4))
    ranges = pd.DataFrame({"time": np.repeat(tr, 4), "node": "bot",
                           "peer": np.tile(ANCHORS["id"], tr.size), "kind": "range",
                           "value": r.ravel()})
    log = pd.concat([odo, ranges]).sort_values("time", kind="stable").reset_index(drop=True)
    log["line"] = np.arange(len(log)) + 2
    return log, pd.DataFrame({"time": t, "x": xy[:, 0], "y": xy[:, 1]})


def rmse(est: pd.DataFrame, truth: pd.DataFrame) -> float:
    x = np.interp(est["time"], truth["time"], truth["x"])
    y = np.interp(est["time"], truth["time"], truth["y"])
    return float(np.sqrt(np.mean((est["x"] - x) ** 2 + (est["y"] - y) ** 2)))


def gain(method: str, options: dict, seeds=(0, 1), duration_s: float = 40.0
         ) -> tuple[float, float]:
    """Mean RMSE over ``seeds`` without and with the odometry rows."""
    without, with_ = [], []
    for seed in seeds:
        log, truth = robot(seed, duration_s)
        ranges = log[log["kind"] == "range"].reset_index(drop=True)
        without.append(rmse(run_method(method, LocateRequest(ranges, ANCHORS,
                                                             options=dict(options))), truth))
        with_.append(rmse(run_method(method, LocateRequest(log, ANCHORS,
                                                           options=dict(options))), truth))
    return float(np.mean(without)), float(np.mean(with_))


def test_ekf_track_odometry_lowers_rmse():
    # measured: 0.335 m without, 0.176 m with (seeds 0, 1)
    without, with_ = gain("ekf-track", {"range_std_m": "0.3"})
    assert with_ < 0.7 * without
    assert with_ < 0.25


def test_pf_odometry_lowers_rmse():
    # measured: 0.291 m without, 0.169 m with (seeds 0, 1; LOS/NLOS model given, not fitted)
    without, with_ = gain("pf", {"particles": "200", "los_std_m": "0.3", "nlos_mean_m": "1",
                                 "alpha": "0.99"}, duration_s=30.0)
    assert with_ < 0.7 * without
    assert with_ < 0.3


def test_zero_noise_odometry_without_ranges_follows_the_truth():
    log, truth = robot(3, duration_s=10.0, scale=0.0, gyro_bias_rad_s=0.0, noise_m=0.0,
                       gyro_walk_rad=0.0)
    times = truth["time"].to_numpy()[1::3]          # steps at every third odometry row
    u = odometry_controls(log, "bot", times, 2)
    z = np.full((times.size, 4), np.nan)            # no range at all
    obs = Observation(RangeModel(std_m=0.3), z, Context(points=ANCHORS[["x", "y"]].to_numpy()))
    start = truth[["x", "y"]].to_numpy()[1]
    track = ExtendedKalmanFilter(odometry_motion(0.1, 2)).run(
        obs, times, prior_mean=start, prior_cov=1e-6 * np.eye(2), controls=u)
    np.testing.assert_allclose(track.position, truth[["x", "y"]].to_numpy()[1::3], atol=1e-9)
    # the claimed spread grows as a random walk of 0.1 m per sqrt(s)
    var = track.covariance[:, 0, 0]
    np.testing.assert_allclose(var - var[0], 0.01 * (times - times[0]), rtol=1e-9)


def test_controls_are_the_path_between_steps_at_any_rate():
    log, truth = robot(4, duration_s=8.0, scale=0.0, gyro_bias_rad_s=0.0, noise_m=0.0,
                       gyro_walk_rad=0.0)
    times = np.array([0.55, 1.0, 1.03, 3.7, 7.95])
    u = odometry_controls(log, "bot", times, 3)
    P = np.stack([np.interp(times, truth["time"], truth[c]) for c in "xy"], -1)
    np.testing.assert_allclose(u[1:, :2], np.diff(P, axis=0), atol=1e-12)
    assert np.all(u[0] == 0) and np.all(u[:, 2] == 0)
    assert np.all(odometry_controls(log, "other", times, 2) == 0)


def write(tmp_path, rows: list[str]):
    path = tmp_path / "m.csv"
    path.write_text("time,node,peer,kind,value\n" + "\n".join(rows) + "\n")
    return path


def test_odometry_rows_are_read_with_a_sensor_as_peer(tmp_path):
    path = write(tmp_path, ["0,bot,A,range,3", "0.1,bot,wheel,odometry_dx,0.1",
                            "0.1,bot,wheel,odometry_dy,-0.05"])
    m = read_measurements(path, anchors=ANCHORS)
    assert list(m["kind"]) == ["range", "odometry_dx", "odometry_dy"]


@pytest.mark.parametrize("rows, words", [
    (["0.1,bot,wheel,odometry_dx,0.1"], ["line 2", "odometry_dy"]),
    (["0.1,bot,wheel,odometry_dx,0.1", "0.2,bot,wheel,odometry_dy,0.1"], ["line 2", "pairs"]),
    (["0.1,bot,wheel,odometry_dx,0.1", "0.1,bot,wheel,odometry_dy,0.1",
      "0.1,bot,wheel,odometry_dx,0.2"], ["line 4", "second 'odometry_dx'"]),
    (["0.1,bot,wheel,odometry_dx,2e4", "0.1,bot,wheel,odometry_dy,0"], ["line 2", "limit"]),
    (["0.1,bot,wheel,odometry_dx,abc", "0.1,bot,wheel,odometry_dy,0"], ["line 2", "value"]),
])
def test_bad_odometry_rows_are_named(tmp_path, rows, words):
    with pytest.raises(InputError) as err:
        read_measurements(write(tmp_path, rows), anchors=ANCHORS)
    for w in words:
        assert w in str(err.value)


def test_other_methods_refuse_odometry_rows():
    log, _ = robot(5, duration_s=6.0)
    with pytest.raises(InputError, match="odometry_d[xy]"):
        run_method("gn", LocateRequest(log, ANCHORS))
    with pytest.raises(InputError, match="odometry"):
        smooth_log(LocateRequest(log, ANCHORS))


def test_options_that_do_not_apply_are_refused():
    log, _ = robot(6, duration_s=6.0)
    with pytest.raises(ConfigError, match="option motion"):
        run_method("ekf-track", LocateRequest(log, ANCHORS, options={"motion": "cv"}))
    ranges = log[log["kind"] == "range"].reset_index(drop=True)
    with pytest.raises(ConfigError, match="no odometry rows"):
        run_method("ekf-track", LocateRequest(ranges, ANCHORS, options={"odometry_std_m": "1"}))
    with pytest.raises(ConfigError, match="fixed-lag"):
        run_method("pf", LocateRequest(log, ANCHORS, options={"smooth": "1",
                                                              "smoother": "backward"}))
