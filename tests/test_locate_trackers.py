"""`radioloc locate --method ekf-track | pf`: tracking a node from its ranges alone."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.estimators.ekf_tracker import RangeEKF
from radioloc.models.motion import WhiteAccelerationCV
from radioloc.locate.pf import fixed_lag
from radioloc.models.ranging import GaussianRange

runner = CliRunner()
HEIGHT = 1.2
ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0.0, 20.0, 20.0, 0.0],
                        "y": [0.0, 0.0, 15.0, 15.0], "z": [2.5, 0.5, 2.0, 0.8]})


def truth(t: np.ndarray) -> np.ndarray:
    """A tag walking a loop inside the anchor box, about 1 m/s."""
    return np.stack([10 + 6 * np.cos(t / 6), 7.5 + 4 * np.sin(t / 6)], axis=-1)


@pytest.fixture(scope="module")
def log(tmp_path_factory) -> Path:
    """Asynchronous rows (one anchor per time stamp, jittered), rows lost at random, one
    anchor silent for 10 s, one outlier range; 3-D anchors, tag at a known height."""
    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.03, 0.07, 1200))                  # ~20 Hz, uneven, 60 s
    peer = np.arange(t.size) % 4
    keep = rng.random(t.size) > 0.15
    keep &= ~((peer == 2) & (t > 20) & (t < 30))
    xy = truth(t)
    a = ANCHORS[["x", "y", "z"]].to_numpy()[peer]
    d = np.sqrt(np.sum((xy - a[:, :2]) ** 2, axis=1) + (HEIGHT - a[:, 2]) ** 2)
    r = d + 0.1 * rng.standard_normal(t.size)
    r[600] += 15.0                                                # one gross outlier
    rows = pd.DataFrame({"time": t, "node": "tag", "peer": ANCHORS["id"].to_numpy()[peer],
                         "kind": "range", "value": r})[keep]
    folder = tmp_path_factory.mktemp("trackers")
    rows.to_csv(folder / "measurements.csv", index=False)
    ANCHORS.to_csv(folder / "anchors.csv", index=False)
    return folder


def locate(folder: Path, method: str, *opts: str, out: str = "est.csv"):
    args = ["locate", str(folder / "measurements.csv"), "--anchors", str(folder / "anchors.csv"),
            "--method", method, "--out", str(folder / out)]
    for o in opts:
        args += ["-o", o]
    return runner.invoke(app, args)


def rmse(folder: Path, out: str) -> float:
    est = pd.read_csv(folder / out)
    assert {"time", "node", "x", "y", "uncertainty_m"} <= set(est.columns)
    assert np.all(np.isfinite(est[["x", "y", "uncertainty_m"]].to_numpy()))
    late = est[est.time > 5]                       # after the start transient
    err = late[["x", "y"]].to_numpy() - truth(late.time.to_numpy())
    return float(np.sqrt(np.mean(np.sum(err ** 2, axis=1))))


def test_ekf_track_warns_when_the_stated_noise_makes_it_diverge(log):
    """Ranges of 0.1 m sigma: stated as 0.1 m the track holds and nothing is said; stated
    as 0.005 m the filter refuses most ranges and one warning names range_std_m."""
    res = locate(log, "ekf-track", f"tag_height_m={HEIGHT}", "range_std_m=0.1", out="ok.csv")
    assert res.exit_code == 0 and "diverged" not in res.stderr, res.output
    res = locate(log, "ekf-track", f"tag_height_m={HEIGHT}", "range_std_m=0.005",
                 out="div.csv")
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.stderr.splitlines() if "diverged" in ln]
    assert len(lines) == 1 and lines[0].startswith("warning: ")
    assert "range_std_m=0.005 too small" in lines[0]


def test_ekf_track_follows_the_tag_and_smoothing_helps(log):
    res = locate(log, "ekf-track", f"tag_height_m={HEIGHT}", "range_std_m=0.1", out="ekf.csv")
    assert res.exit_code == 0, res.output
    filtered = rmse(log, "ekf.csv")
    args = ["locate", str(log / "measurements.csv"), "--anchors", str(log / "anchors.csv"),
            "--method", "ekf-track", "--smooth", "-o", f"tag_height_m={HEIGHT}",
            "-o", "range_std_m=0.1", "--out", str(log / "ekf_s.csv")]
    res = runner.invoke(app, args)                 # --smooth is -o smooth=1
    assert res.exit_code == 0, res.output
    smoothed = rmse(log, "ekf_s.csv")
    assert filtered < 0.3
    assert smoothed < filtered
    # one row per time stamp with a range
    assert len(pd.read_csv(log / "ekf.csv")) == len(pd.read_csv(log / "measurements.csv"))


def test_ekf_track_random_walk_and_3d(log):
    res = locate(log, "ekf-track", f"tag_height_m={HEIGHT}", "motion=rw", "q=1", out="rw.csv")
    assert res.exit_code == 0, res.output
    assert rmse(log, "rw.csv") < 0.5
    res = locate(log, "ekf-track", out="3d.csv")           # 3-D anchors, no height: 3-D track
    assert res.exit_code == 0, res.output
    est = pd.read_csv(log / "3d.csv")
    assert "z" in est.columns
    assert rmse(log, "3d.csv") < 1.0


def test_pf_follows_the_tag_with_em_fitted_parameters_and_fixed_lag(log):
    opts = (f"tag_height_m={HEIGHT}", "particles=300", "seed=3")
    res = locate(log, "pf", *opts, out="pf.csv")
    assert res.exit_code == 0, res.output
    filtered = rmse(log, "pf.csv")
    res = locate(log, "pf", *opts, "smooth=1", "lag=20", out="pf_s.csv")
    assert res.exit_code == 0, res.output
    smoothed = rmse(log, "pf_s.csv")
    assert filtered < 0.5
    assert smoothed < filtered
    # given parameters: no EM
    res = locate(log, "pf", *opts, "los_std_m=0.1", "nlos_mean_m=1", "alpha=0.9", out="pf_g.csv")
    assert res.exit_code == 0, res.output
    assert rmse(log, "pf_g.csv") < 0.5


@pytest.mark.parametrize("method, opt, message", [
    ("ekf-track", "motion=jerk", "motion"),
    ("ekf-track", "q=-1", "q"),
    ("ekf-track", "range_std_m=0", "range_std_m"),
    ("ekf-track", "smooth=maybe", "smooth"),
    ("ekf-track", "bogus=1", "bogus"),
    ("pf", "particles=2.5", "particles"),
    ("pf", "alpha=1.5", "alpha"),
    ("pf", "lag=0", "lag"),
    ("pf", "range_std_m=0.1", "range_std_m"),     # not a pf option
])
def test_options_are_validated(log, method, opt, message):
    res = locate(log, method, f"tag_height_m={HEIGHT}", opt)
    assert res.exit_code != 0
    assert message in str(res.output) + str(res.exception)


def test_pf_needs_the_height_with_3d_anchors_and_height_needs_3d_anchors(log, tmp_path):
    res = locate(log, "pf", "particles=50")
    assert res.exit_code != 0
    assert "tag_height_m" in str(res.output) + str(res.exception)
    ANCHORS[["id", "x", "y"]].to_csv(tmp_path / "anchors.csv", index=False)
    (tmp_path / "measurements.csv").write_text((log / "measurements.csv").read_text())
    res = locate(tmp_path, "ekf-track", "tag_height_m=1")
    assert res.exit_code != 0
    assert "z column" in str(res.output) + str(res.exception)


def test_gate_drops_an_outlier_and_patience_recovers():
    anchors = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    p = np.array([3.0, 4.0])
    d = np.linalg.norm(p - anchors, axis=1)
    R = np.tile(d, (40, 1))
    R[10, 0] += 20.0
    ekf = RangeEKF(WhiteAccelerationCV(0.1), GaussianRange(0.1), anchors=anchors, gate=16)
    tr = ekf.run(R, np.arange(40.0) * 0.1, prior_mean=[3, 4, 0, 0], prior_cov=np.eye(4))
    assert tr.diagnostics["gated"][10] == 1
    assert np.allclose(tr.position[-1], p, atol=1e-2)
    # a start far off: everything is gated at first, then taken again after the patience
    tr = ekf.run(R, np.arange(40.0) * 0.1, prior_mean=[30, 30, 0, 0],
                 prior_cov=0.01 * np.eye(4))
    gated = tr.diagnostics["gated"]
    assert np.all(gated[:10] == 3)
    assert gated[10] == 0                          # after 10 fully gated steps: taken
    assert np.linalg.norm(tr.position[10] - p) < np.linalg.norm(tr.position[9] - p)


def test_white_acceleration_noise_does_not_depend_on_the_split():
    m = WhiteAccelerationCV(0.7)
    one = m.Q(np.array(1.0))
    F = m.F(np.array(0.5))
    two = F @ m.Q(np.array(0.5)) @ F.T + m.Q(np.array(0.5))
    assert np.allclose(one, two)


def test_fixed_lag_follows_ancestry():
    history = [np.array([[0.0], [1.0]]), np.array([[2.0], [3.0]]), np.array([[4.0], [5.0]])]
    ancestors = [np.array([0, 1]), np.array([1, 1]), np.array([0, 0])]
    mean, cov = fixed_lag(history, ancestors, lag=2)
    # step 0 at lag 2: particles of step 2 descend from 0 of step 1, which descends from 1
    assert mean[0, 0] == 1.0 and cov[0, 0, 0] == 0.0
    assert mean[1, 0] == 2.0
    assert mean[2, 0] == 4.5


HANYANG = Path(os.environ.get("RADIOLOC_DATA", "/work/shared/data")) / "hanyang-uwb-outdoor"


@pytest.mark.skipif(not (HANYANG / "Dynamic_measurements").exists(), reason="Hanyang absent")
def test_hanyang_los_a_1_ekf_track(tmp_path, monkeypatch):
    monkeypatch.setenv("RADIOLOC_DATA", str(HANYANG.parent))
    res = runner.invoke(app, ["datasets", "export", "hanyang", "--run", "LOS/A/1",
                              "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    ref = pd.read_csv(tmp_path / "reference.csv")
    scores = []
    for opts in (["tag_height_m=1.0"], ["tag_height_m=1.0", "smooth=1"]):
        res = locate(tmp_path, "ekf-track", *opts)
        assert res.exit_code == 0, res.output
        est = pd.read_csv(tmp_path / "est.csv")
        est = est[(est.time >= ref.time.min()) & (est.time <= ref.time.max())]
        dx = est.x - np.interp(est.time, ref.time, ref.x)
        dy = est.y - np.interp(est.time, ref.time, ref.y)
        scores.append(float(np.sqrt(np.mean(dx ** 2 + dy ** 2))))
    # measured (docs/real-logs.md): 0.87 m filtered, 0.72 m smoothed
    assert scores[0] < 0.95
    assert scores[1] < 0.80


def test_backward_simulation_matches_the_rts_smoother_on_a_linear_gaussian_model():
    """1-D random walk, Gaussian position readings: a bootstrap filter's particle sets,
    smoothed by backward simulation, give the Kalman (RTS) smoother's means within the
    Monte Carlo error."""
    from radioloc.estimators.pf_smoother import backward_simulation
    from radioloc.models.motion import RandomWalk

    rng = np.random.default_rng(11)
    T, K, q, r_var = 25, 4000, 0.5, 0.3
    t = np.arange(T, dtype=float)
    x = np.cumsum(rng.normal(0, np.sqrt(q), T))
    y = x + rng.normal(0, np.sqrt(r_var), T)
    y[10:15] = np.nan                                   # readings missing: smoothing bridges
    # exact Kalman filter + RTS smoother, prior N(0, 1) at step 0 before its reading
    m_f, P_f, m_p, P_p = np.empty(T), np.empty(T), np.empty(T), np.empty(T)
    m, P = 0.0, 1.0
    for k in range(T):
        if k:
            m, P = m, P + q
        m_p[k], P_p[k] = m, P
        if np.isfinite(y[k]):
            g = P / (P + r_var)
            m, P = m + g * (y[k] - m), (1 - g) * P
        m_f[k], P_f[k] = m, P
    m_s = m_f.copy()
    for k in range(T - 2, -1, -1):
        m_s[k] = m_f[k] + P_f[k] / P_p[k + 1] * (m_s[k + 1] - m_p[k + 1])
    # bootstrap particle filter with the same model
    parts = rng.normal(0, 1, K)
    history = []
    for k in range(T):
        if k:
            parts = parts + rng.normal(0, np.sqrt(q), K)
        if np.isfinite(y[k]):
            w = np.exp(-0.5 * (y[k] - parts) ** 2 / r_var)
            parts = parts[rng.choice(K, K, p=w / w.sum())]
        history.append(parts[:, None].copy())
    mean, cov = backward_simulation(history, t, RandomWalk(q, 1), 400, rng)
    assert mean.shape == (T, 1) and cov.shape == (T, 1, 1)
    # Monte Carlo error of 400 draws of a posterior with sd ~0.5: ~0.03; allow 5 of them
    np.testing.assert_allclose(mean[:, 0], m_s, atol=0.15)
    # and in the gap the smoothed estimate is closer to the truth than the filtered one
    gap = slice(10, 15)
    assert np.mean((mean[gap, 0] - x[gap]) ** 2) < np.mean((m_f[gap] - x[gap]) ** 2)


def test_backward_simulation_rejects_bad_input():
    from radioloc.core.errors import ConfigError, InputError
    from radioloc.estimators.pf_smoother import backward_simulation
    from radioloc.models.motion import RandomWalk

    h = [np.zeros((5, 1)), np.zeros((5, 1))]
    rng = np.random.default_rng(0)
    with pytest.raises(ConfigError, match="trajectories"):
        backward_simulation(h, [0.0, 1.0], RandomWalk(1.0, 1), 0, rng)
    with pytest.raises(InputError, match="increasing"):
        backward_simulation(h, [1.0, 1.0], RandomWalk(1.0, 1), 3, rng)
    with pytest.raises(InputError, match=r"history\[1\]"):
        backward_simulation([h[0], np.zeros((5, 2))], [0.0, 1.0], RandomWalk(1.0, 1), 3, rng)


def test_pf_backward_smoother_from_the_cli(log):
    opts = (f"tag_height_m={HEIGHT}", "particles=300", "seed=3")
    res = locate(log, "pf", *opts, out="pf_f.csv")
    assert res.exit_code == 0, res.output
    res = locate(log, "pf", *opts, "smooth=1", "smoother=backward", "trajectories=50",
                 out="pf_b.csv")
    assert res.exit_code == 0, res.output
    assert rmse(log, "pf_b.csv") < rmse(log, "pf_f.csv")


def test_divergence_leaves_a_consistent_track_far_from_a_compact_cluster_alone():
    """Anchors on a 2.6 m cluster, a tag 50 m away: consistent innovations and almost no gated
    ranges are no sign of divergence; the same track refusing 30 % of its ranges is."""
    from radioloc.core.results import Track
    from radioloc.locate.ekf_track import divergence

    cluster = np.array([[2.6, -0.9], [2.6, 0.9], [0.7, 0.9]])
    steps = 400
    rng = np.random.default_rng(0)
    xy = np.c_[np.linspace(0.0, 50.0, steps), np.zeros(steps)]
    used = np.full(steps, 3.0)
    quiet = {"nis": rng.chisquare(3, steps), "measurements_used": used,
             "gated": np.zeros(steps)}
    assert divergence(Track(position=xy, diagnostics=quiet), cluster, 16.0) is None
    refused = (rng.random(steps) < 0.3).astype(float)
    noisy = dict(quiet, measurements_used=used - refused, gated=refused)
    sign = divergence(Track(position=xy, diagnostics=noisy), cluster, 16.0)
    assert sign is not None and sign["outside_m"] > 40
