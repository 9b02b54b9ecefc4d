"""Heading rows in ``locate --method ekf-track``, and the heading offset estimated from a
track: a simulated walker ranging to four anchors at 4 Hz with a compass heading."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.io.logs import read_measurements
from radioloc.locate.base import LocateRequest, run_method
from radioloc.locate.heading_offset import estimate_heading_offset, remove_heading_offset

ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0.0, 20.0, 20.0, 0.0],
                        "y": [0.0, 0.0, 15.0, 15.0]})
OPTIONS = {"range_std_m": "1.0", "heading_std_rad": "0.2"}


def walk(seed: int, duration_s: float = 60.0, offset_rad: float = 0.0, stop: bool = False):
    """A walker on an ellipse at about 1.2 m/s (standing still for 8 s with ``stop``):
    ranges with 1 m noise to four anchors and a heading row (0.2 rad noise, rotated by
    ``offset_rad``) per epoch at 4 Hz. Returns the log and the truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 0.25)
    rate = np.full(t.size, 1.2 / 6.0)              # rad/s along an ellipse of radii 7, 5
    if stop:
        rate[(t > 20) & (t < 28)] = 0.0
    phase = np.cumsum(rate) * 0.25
    xy = np.stack([10 + 7 * np.cos(phase), 7.5 + 5 * np.sin(phase)], axis=-1)
    vel = np.stack([-7 * np.sin(phase), 5 * np.cos(phase)], axis=-1) * rate[:, None]
    a = ANCHORS[["x", "y"]].to_numpy()
    r = np.linalg.norm(xy[:, None] - a[None], axis=-1) + rng.standard_normal((t.size, 4))
    ranges = pd.DataFrame({"time": np.repeat(t, 4), "node": "tag",
                           "peer": np.tile(ANCHORS["id"], t.size), "kind": "range",
                           "value": r.ravel()})
    psi = np.arctan2(vel[:, 1], vel[:, 0]) + offset_rad + 0.2 * rng.standard_normal(t.size)
    moving = np.linalg.norm(vel, axis=-1) > 0
    # standing still, the phone keeps pointing where the walk went
    last = np.maximum.accumulate(np.where(moving, np.arange(t.size), 0))
    psi = np.where(moving, psi, psi[last])
    heading = pd.DataFrame({"time": t, "node": "tag", "peer": "imu", "kind": "heading",
                            "value": np.angle(np.exp(1j * psi))})
    log = pd.concat([ranges, heading]).sort_values("time", kind="stable").reset_index(drop=True)
    return log, pd.DataFrame({"time": t, "x": xy[:, 0], "y": xy[:, 1]})


def rmse(est: pd.DataFrame, truth: pd.DataFrame) -> float:
    m = est.merge(truth, on="time", suffixes=("", "_true"))
    return float(np.sqrt(np.mean((m.x - m.x_true) ** 2 + (m.y - m.y_true) ** 2)))


def ekf(log: pd.DataFrame, **extra) -> pd.DataFrame:
    return run_method("ekf-track", LocateRequest(log, ANCHORS, options={**OPTIONS, **extra}))


@pytest.mark.parametrize("stop", [False, True])
def test_heading_rows_lower_the_rmse(stop):
    # measured (seeds 0-2): 0.606 -> 0.495 m walking; 0.614 -> 0.587 m with an 8 s stop
    without, with_ = [], []
    for seed in range(3):
        log, truth = walk(seed, stop=stop)
        without.append(rmse(ekf(log[log.kind == "range"]), truth))
        with_.append(rmse(ekf(log), truth))
    assert np.mean(with_) < (0.99 if stop else 0.85) * np.mean(without)


def test_a_log_without_heading_rows_is_tracked_as_before():
    log, _ = walk(5)
    ranges = log[log.kind == "range"].reset_index(drop=True)
    a = run_method("ekf-track", LocateRequest(ranges, ANCHORS, options={"range_std_m": "1.0"}))
    b = ekf(ranges)      # heading_std_rad given, no heading row: no effect
    pd.testing.assert_frame_equal(a, b)


def test_offset_estimated_from_the_range_only_track_and_removed():
    log, truth = walk(1, offset_rad=2.5)
    track = ekf(log[log.kind == "range"])
    off = estimate_heading_offset(log, track)
    assert off["node"].tolist() == ["tag"]
    assert abs(np.angle(np.exp(1j * (off["offset_rad"].iloc[0] - 2.5)))) < 0.1
    assert off["concentration"].iloc[0] > 0.7
    fixed = remove_heading_offset(log, off)
    assert rmse(ekf(fixed), truth) < rmse(track, truth)
    # moving the whole scene's heading by an angle moves the estimate by that angle
    turned = log.assign(value=np.where(log.kind == "heading", log.value + 0.4, log.value))
    off2 = estimate_heading_offset(turned, track)
    assert np.angle(np.exp(1j * (off2["offset_rad"].iloc[0] - off["offset_rad"].iloc[0]))) \
        == pytest.approx(0.4, abs=1e-9)


def test_offset_refuses_a_log_without_usable_rows():
    log, _ = walk(2)
    track = ekf(log[log.kind == "range"])
    with pytest.raises(InputError, match="no heading row"):
        estimate_heading_offset(log[log.kind == "range"], track)
    with pytest.raises(InputError, match="node 'tag'"):
        estimate_heading_offset(log, track, min_speed_mps=50.0)


def test_heading_rows_need_the_constant_velocity_motion():
    log, _ = walk(3, duration_s=10.0)
    with pytest.raises(ConfigError, match="heading"):
        ekf(log, motion="rw")


def test_heading_rows_read_from_a_csv(tmp_path):
    log, _ = walk(4, duration_s=5.0)
    path = tmp_path / "log.csv"
    log.to_csv(path, index=False)
    read = read_measurements(path, anchors=ANCHORS)
    assert (read.kind == "heading").sum() == (log.kind == "heading").sum()
    bad = log.copy()
    bad.loc[bad.kind == "heading", "value"] = 90.0
    bad.to_csv(path, index=False)
    with pytest.raises(InputError, match="heading is in radians"):
        read_measurements(path, anchors=ANCHORS)
