"""Settings learned from the log (radioloc.locate.self_tuning) through ekf-track and smoother."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError
from radioloc.locate import LocateRequest, run_method
from radioloc.locate.stream import Tracker
from radioloc.models.clock import bias_transition

ANCHORS = pd.DataFrame({"id": [f"A{i}" for i in range(6)],
                        "x": [0.0, 30.0, 30.0, 0.0, 15.0, 15.0],
                        "y": [0.0, 0.0, 20.0, 20.0, -2.0, 22.0]})


def walk(seed: int, white: float, correlated: float, tau: float, nlos: float = 0.0,
         duration_s: float = 300.0, rate_hz: float = 5.0):
    """A walker on an ellipse (1 m/s) ranging six anchors at ``rate_hz``: each anchor's
    ranges carry a constant offset (0.5-3 m), a Gauss-Markov error (``correlated`` m,
    time constant ``tau`` s) and white noise (``white`` m); a share ``nlos`` of the ranges
    is longer by an exponential excess of mean 3 m. Returns log, truth, offsets."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    phase = 2 * np.pi * t / 60.0
    xy = np.stack([15 + 10 * np.cos(phase), 10 + 6 * np.sin(phase)], axis=-1)
    d = np.linalg.norm(xy[:, None] - ANCHORS[["x", "y"]].to_numpy()[None], axis=-1)
    offset = rng.uniform(0.5, 3.0, 6)
    g = np.zeros(d.shape)
    g[0] = correlated * rng.standard_normal(6)
    a = np.exp(-1.0 / rate_hz / tau)
    for k in range(1, t.size):
        g[k] = a * g[k - 1] + correlated * np.sqrt(1 - a * a) * rng.standard_normal(6)
    z = d + offset + g + white * rng.standard_normal(d.shape)
    z = z + (rng.random(d.shape) < nlos) * rng.exponential(3.0, d.shape)
    log = pd.DataFrame({"time": np.repeat(t, 6), "node": "tag",
                        "peer": np.tile(ANCHORS["id"], t.size), "kind": "range",
                        "value": z.ravel()})
    return log, pd.DataFrame({"time": t, "x": xy[:, 0], "y": xy[:, 1]}), offset


def rmse(out: pd.DataFrame, truth: pd.DataFrame) -> float:
    m = out.merge(truth, on="time", suffixes=("", "_true"))
    return float(np.sqrt(np.mean((m.x - m.x_true) ** 2 + (m.y - m.y_true) ** 2)))


def learned(out: pd.DataFrame, key: str) -> np.ndarray:
    anchors = out.attrs["summary"]["learned"]["tag"]["range_anchors"]
    return np.array([a[key] for a in anchors])


@pytest.mark.parametrize("white, correlated, tau", [(0.05, 0.05, 3.0), (1.0, 0.8, 5.0)])
def test_learned_noise_and_offsets_near_the_truth(white, correlated, tau):
    """Measured (seed 1): offsets within 0.01 m (5 cm noise) and 0.22 m (1 m noise); white
    0.05-0.06 for 0.05 and 0.96-1.05 for 1.0; correlated 0.05 and 0.57-0.71 for 0.8."""
    log, truth, offset = walk(1, white, correlated, tau)
    out = run_method("ekf-track", LocateRequest(log, ANCHORS))
    total = np.hypot(white, correlated)
    assert np.all(np.abs(learned(out, "offset_m") - offset) < 0.3 * total + 0.02)
    w = learned(out, "white_m")
    assert np.all(np.abs(w / white - 1) < 0.25), w
    g = learned(out, "correlated_m")
    assert np.all(np.abs(g / correlated - 1) < 0.35), g
    assert rmse(out, truth) < 1.2 * total


def test_every_learned_value_has_an_interval_around_it():
    log, _, _ = walk(2, 0.3, 0.3, 5.0, nlos=0.1)
    summary = run_method("ekf-track", LocateRequest(log, ANCHORS)).attrs["summary"]
    report = summary["learned"]["tag"]
    for a in report["range_anchors"]:
        for key in ("offset_m", "white_m", "correlated_m", "tau_s"):
            lo, hi = a[key + "_95"]
            assert lo <= a[key] <= hi, (key, a)
    lo, hi = report["q_95"]
    assert lo <= report["q"] <= hi
    mix = report["range_mixture"]
    assert 0 < mix["los_fraction"] <= 1 and mix["nlos_mean_m"] > 0
    # 10 % NLOS rows are not white noise: the health check says so, naming what was learned
    for f in summary["health"]["findings"]:
        assert "range_std_m=0.15" not in f["message"]


def test_learning_beats_the_fixed_defaults_on_biased_ranges():
    """Offsets of 0.5-3 m and 1 m noise: the fixed 0.15 m default diverges or warns; the
    learned settings track within the noise."""
    log, truth, _ = walk(3, 1.0, 0.5, 5.0)
    out = run_method("ekf-track", LocateRequest(log, ANCHORS))
    with pytest.warns(UserWarning):
        fixed = run_method("ekf-track", LocateRequest(log, ANCHORS, options={"tune": "0"}))
    assert rmse(out, truth) < 0.5 * rmse(fixed, truth)
    smoothed = run_method("smoother", LocateRequest(log, ANCHORS))
    assert rmse(smoothed, truth) < rmse(out, truth)


def test_a_given_option_is_kept_not_learned():
    log, _, _ = walk(4, 0.3, 0.2, 5.0, duration_s=120.0)
    tuned = run_method("ekf-track", LocateRequest(log, ANCHORS, options={"q": "0.5"}))
    assert tuned.attrs["summary"]["learned"]["tag"]["q"] == 0.5


def test_moving_the_scene_moves_the_track_and_keeps_what_is_learned():
    log, _, _ = walk(5, 0.3, 0.3, 5.0, duration_s=120.0)
    shift = np.array([100.0, -40.0])
    moved = ANCHORS.assign(x=ANCHORS.x + shift[0], y=ANCHORS.y + shift[1])
    a = run_method("ekf-track", LocateRequest(log, ANCHORS))
    b = run_method("ekf-track", LocateRequest(log, moved))
    np.testing.assert_allclose(b[["x", "y"]].to_numpy() - shift, a[["x", "y"]].to_numpy(),
                               atol=1e-6)
    np.testing.assert_allclose(learned(b, "offset_m"), learned(a, "offset_m"), atol=1e-6)


def test_live_tracking_refuses_to_learn():
    with pytest.raises(ConfigError, match="tune"):
        Tracker("ekf-track", ANCHORS, {"tune": "1"})


def test_gauss_markov_bias_tends_to_the_random_walk():
    """Over a short step the Gauss-Markov bias adds the random walk's variance q^2 dt;
    its stationary variance is q^2 tau / 2."""
    a, var = bias_transition(np.array(1e-4), 0.3, 5.0)
    assert var[0] == pytest.approx(0.09 * 1e-4, rel=1e-3)
    a, var = bias_transition(np.array(1e4), 0.3, 5.0)
    assert a[0] == pytest.approx(0.0) and var[0] == pytest.approx(0.09 * 5.0 / 2)
    a, var = bias_transition(np.array(2.0), np.array([0.3, 0.3]), np.array([np.inf, 5.0]))
    assert a[0] == 1.0 and var[0] == pytest.approx(0.09 * 2.0)


def _same_track(a: pd.DataFrame, b: pd.DataFrame) -> None:
    np.testing.assert_allclose(a[["x", "y"]].to_numpy(), b[["x", "y"]].to_numpy(), atol=1e-9)


@pytest.mark.parametrize("method", ["ekf-track", "smoother"])
def test_a_log_too_short_to_learn_from_runs_the_fixed_defaults_and_says_so(method):
    """Five seconds at 5 Hz: 25 ranges per anchor, fewer than the 30 to learn from."""
    log, _, _ = walk(6, 0.1, 0.05, 5.0, duration_s=5.0)
    out = run_method(method, LocateRequest(log, ANCHORS))
    fixed = run_method(method, LocateRequest(log, ANCHORS, options={"tune": "0"}))
    _same_track(out, fixed)
    summary = out.attrs["summary"]
    assert "learned" not in summary and "25 ranges" in summary["tune"]


def test_stated_stds_are_kept():
    """A log whose every row states its std runs as stated; one std stated among learned
    rows is kept for its row."""
    log, _, _ = walk(7, 0.3, 0.2, 5.0, duration_s=60.0)
    stated = log.assign(std=0.4)
    out = run_method("ekf-track", LocateRequest(stated, ANCHORS))
    _same_track(out, run_method("ekf-track", LocateRequest(stated, ANCHORS,
                                                          options={"tune": "0"})))
    assert "every row states its std" in out.attrs["summary"]["tune"]
    some = log.assign(std=np.where(log["peer"] == "A0", 1e3, np.nan))   # A0's rows: no weight
    without = run_method("ekf-track", LocateRequest(some, ANCHORS))
    assert "learned" in without.attrs["summary"]
    moved = some.assign(value=np.where(some["peer"] == "A0", some["value"] + 5.0,
                                       some["value"]))
    far = run_method("ekf-track", LocateRequest(moved, ANCHORS))
    assert np.max(np.abs(far[["x", "y"]].to_numpy() - without[["x", "y"]].to_numpy())) < 0.5


def test_every_sigma_given_runs_the_fixed_defaults():
    log, _, _ = walk(8, 0.3, 0.2, 5.0, duration_s=60.0)
    opts = {"range_std_m": "0.4"}
    out = run_method("ekf-track", LocateRequest(log, ANCHORS, options=opts))
    _same_track(out, run_method("ekf-track", LocateRequest(log, ANCHORS,
                                                          options={**opts, "tune": "0"})))
    assert "range_std_m" in out.attrs["summary"]["tune"]


@pytest.mark.parametrize("seed", [3, 4])
def test_pf_takes_each_anchors_learned_offset_off_its_ranges(seed):
    """pf at its defaults learns as ekf-track does: each anchor's offset (0.5-3 m) within
    0.35 m, and a track at least 4x closer than with its EM fit of one bias per node
    (-o tune=0). Measured (300 particles, 120 s): 0.24 and 0.30 m against 6.2 and 2.8 m."""
    log, truth, offset = walk(seed, 0.3, 0.2, 5.0, nlos=0.1, duration_s=120.0)
    runs = {tune: run_method("pf", LocateRequest(log, ANCHORS, options={
        "particles": "300", "tune": tune})) for tune in ("1", "0")}
    model = runs["1"].attrs["summary"]["model"][0]
    assert model["fitted"] == "learned" and "tag" in runs["1"].attrs["summary"]["learned"]
    bias = np.array([model["range_bias_m"][a] for a in ANCHORS["id"]])
    assert np.all(np.abs(bias - offset) < 0.35), bias - offset
    assert runs["0"].attrs["summary"]["model"][0]["fitted"] == "em"
    assert rmse(runs["1"], truth) < 0.25 * rmse(runs["0"], truth)


def test_a_nodes_learned_settings_do_not_depend_on_the_other_nodes():
    """Two walkers of different lengths, offsets and speeds learned and tracked in one
    batch, each with its own process noise: each node's learned values and track equal
    those of a log of that node alone (to 1e-9)."""
    one, _, _ = walk(5, 0.3, 0.3, 4.0, nlos=0.05, duration_s=120.0)
    two, _, _ = walk(6, 0.6, 0.2, 8.0, duration_s=80.0)
    two = two.assign(node="tag2", time=two["time"] * 0.25)     # 4 m/s, 20 Hz
    both = run_method("ekf-track", LocateRequest(pd.concat([one, two], ignore_index=True),
                                                 ANCHORS))
    learned = both.attrs["summary"]["learned"]
    assert learned["tag"]["q"] != learned["tag2"]["q"]
    for node, log in (("tag", one), ("tag2", two)):
        alone = run_method("ekf-track", LocateRequest(log, ANCHORS))
        mine = both[both.node == node].reset_index(drop=True)
        np.testing.assert_allclose(mine[["x", "y"]], alone[["x", "y"]], atol=1e-9)
        a = alone.attrs["summary"]["learned"][node]
        b = both.attrs["summary"]["learned"][node]
        assert a["scale"] == b["scale"] and a["q"] == b["q"]
        assert a["correlation_scale"] == b["correlation_scale"]
        for key in ("evidence_by_scale", "evidence_by_correlation_scale"):
            np.testing.assert_allclose(list(a[key].values()), list(b[key].values()), rtol=1e-9)
        for x, y in zip(a["range_anchors"], b["range_anchors"]):
            for k in ("offset_m", "white_m", "correlated_m", "tau_s"):
                assert x[k] == pytest.approx(y[k], rel=1e-9, abs=1e-12), (node, k)
