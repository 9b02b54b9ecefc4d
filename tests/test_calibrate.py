"""Anchor self-calibration: the estimator and ``radioloc calibrate``."""

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.core.errors import GeometryError, InputError
from radioloc.estimators.anchor_calibration import calibrate_anchors

TRUTH = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 15.0], [20.0, 15.0], [10.0, -3.0], [25.0, 7.0],
                  [-4.0, 8.0]])
PSTD = np.array([0.0, 0.0, 0.0, 3.0, 3.0, 3.0, 3.0])
PAIRS = [(i, j) for i in range(len(TRUTH)) for j in range(i + 1, len(TRUTH))]
PATH = np.c_[np.linspace(2, 18, 60), 7 + 5 * np.sin(np.linspace(0, 6, 60))]


def simulate(rng, std=0.1, bias=None, truth=TRUTH, path=PATH):
    b = np.zeros(len(truth)) if bias is None else bias
    ar = np.array([(i, j, np.linalg.norm(truth[i] - truth[j]) + b[i] + b[j] + std * rng.normal())
                   for i, j in PAIRS])
    tr = np.array([(t, a, np.linalg.norm(path[t] - truth[a]) + b[a] + std * rng.normal())
                   for t in range(len(path)) for a in range(len(truth))])
    prior = truth + rng.normal(size=truth.shape) * PSTD[:, None]
    return prior, ar, tr


def test_zero_noise_recovers_the_anchors_exactly():
    prior, ar, tr = simulate(np.random.default_rng(0), std=0.0)
    fit = calibrate_anchors(prior, PSTD, anchor_ranges=ar, tag_ranges=tr, std_m=0.01)
    np.testing.assert_allclose(fit.position, TRUTH, atol=1e-3)
    np.testing.assert_allclose(fit.tag_position, PATH, atol=1e-3)


def test_rough_anchors_within_1_5_times_the_crb():
    rng = np.random.default_rng(1)
    err, crb = [], []
    for _ in range(15):
        prior, ar, tr = simulate(rng)
        fit = calibrate_anchors(prior, PSTD, anchor_ranges=ar, tag_ranges=tr, std_m=0.1)
        err.append(np.sum((fit.position - TRUTH) ** 2, axis=1)[3:])
        crb.append(np.trace(fit.crb, axis1=1, axis2=2)[3:])
        np.testing.assert_allclose(fit.covariance, fit.crb, rtol=1e-6, atol=1e-12)
    ratio = np.sqrt(np.mean(err)) / np.sqrt(np.mean(crb))
    assert 0.6 < ratio < 1.5, ratio


def test_biases_are_recovered_within_their_reported_sigma():
    rng = np.random.default_rng(2)
    bias = rng.uniform(0.2, 0.6, len(TRUTH))
    prior, ar, tr = simulate(rng, std=0.05, bias=bias)
    fit = calibrate_anchors(prior, PSTD, anchor_ranges=ar, tag_ranges=tr, std_m=0.05,
                            estimate_bias=True)
    z = (fit.bias_m - bias) / fit.bias_std_m
    assert np.all(np.abs(z) < 4.0), z
    assert abs(fit.tag_bias_m) < 0.1


def test_moving_the_scene_moves_the_estimate():
    rng = np.random.default_rng(3)
    prior, ar, tr = simulate(rng)
    shift = np.array([100.0, -50.0])
    a = calibrate_anchors(prior, PSTD, anchor_ranges=ar, tag_ranges=tr)
    b = calibrate_anchors(prior + shift, PSTD, anchor_ranges=ar, tag_ranges=tr)
    np.testing.assert_allclose(b.position, a.position + shift, atol=1e-5)


def test_robust_loss_resists_nlos_outliers():
    rng = np.random.default_rng(4)
    prior, ar, tr = simulate(rng)
    bad = rng.random(len(tr)) < 0.1
    tr[bad, 2] += rng.uniform(3, 10, bad.sum())
    plain = calibrate_anchors(prior, PSTD, anchor_ranges=ar, tag_ranges=tr)
    robust = calibrate_anchors(prior, PSTD, anchor_ranges=ar, tag_ranges=tr, loss="cauchy")
    err = [np.sqrt(np.mean(np.sum((f.position - TRUTH) ** 2, axis=1)[3:])) for f in (plain, robust)]
    assert err[1] < 0.5 * err[0], err


def test_bad_input_names_the_argument():
    prior, ar, tr = simulate(np.random.default_rng(5))
    with pytest.raises(InputError, match="prior_std_m"):
        calibrate_anchors(prior, PSTD[:3], anchor_ranges=ar)
    with pytest.raises(InputError, match="anchor_ranges"):
        calibrate_anchors(prior, PSTD, anchor_ranges=np.array([[0, 9, 3.0]]))
    with pytest.raises(InputError, match="tag_ranges"):
        calibrate_anchors(prior, PSTD, tag_ranges=np.array([[0, 1, -3.0]]))
    with pytest.raises(InputError, match="loss"):
        calibrate_anchors(prior, PSTD, anchor_ranges=ar, loss="l3")
    with pytest.raises(GeometryError, match="rough anchors"):    # one surveyed: frame free
        calibrate_anchors(prior, np.r_[0.0, np.full(6, 1e6)], anchor_ranges=ar)
    with pytest.raises(InputError, match=r"prior_std_m: .*\(anchor 3\) is below"):
        calibrate_anchors(prior, np.r_[PSTD[:3], 1e-193, PSTD[4:]], anchor_ranges=ar)


def test_cli_names_the_line_of_a_prior_std_whose_inverse_overflows(tmp_path):
    """A std_m of 1.3e-193 m (its inverse squared overflows) was an internal error; it is
    refused naming the file's line and column, 0 or empty meaning a surveyed anchor."""
    pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0, 20, 20, 0], "y": [0, 0, 15, 15],
                  "std_m": [None, None, 1.3e-193, 2.0]}).to_csv(tmp_path / "a.csv", index=False)
    pd.DataFrame({"time": [0], "node": ["A"], "peer": ["B"], "kind": ["range"], "value": [20.0]}
                 ).to_csv(tmp_path / "m.csv", index=False)
    res = CliRunner().invoke(app, ["calibrate", str(tmp_path / "m.csv"), "--anchors",
                                   str(tmp_path / "a.csv")])
    assert res.exit_code != 0 and "line 4, column 'std_m'" in res.output, res.output


def test_cli_calibrates_and_locate_reads_the_bias(tmp_path):
    rng = np.random.default_rng(6)
    bias = np.full(len(TRUTH), 0.8)
    prior, ar, tr = simulate(rng, std=0.03, bias=bias)
    ids = [f"A{i}" for i in range(len(TRUTH))]
    pd.DataFrame({"id": ids, "x": prior[:, 0], "y": prior[:, 1],
                  "std_m": ["" if s == 0 else s for s in PSTD]}).to_csv(tmp_path / "a.csv", index=False)
    rows = [(0.0, ids[int(i)], ids[int(j)], "range", r) for i, j, r in ar]
    rows += [(0.1 * t, "tag", ids[int(a)], "range", r) for t, a, r in tr]
    pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"]).to_csv(tmp_path / "m.csv", index=False)
    tag = pd.DataFrame([r for r in rows if r[1] == "tag"], columns=["time", "node", "peer", "kind", "value"])
    tag.to_csv(tmp_path / "tag.csv", index=False)
    runner = CliRunner()
    res = runner.invoke(app, ["calibrate", str(tmp_path / "m.csv"), "--anchors", str(tmp_path / "a.csv"),
                              "--bias", "--std-m", "0.03", "--out", str(tmp_path / "cal.csv")])
    assert res.exit_code == 0, res.output
    cal = pd.read_csv(tmp_path / "cal.csv")
    assert {"cov_xx", "cov_xy", "cov_yy", "crb_std_m", "bias_m", "bias_std_m"} <= set(cal.columns)
    np.testing.assert_allclose(cal[["x", "y"]].to_numpy(), TRUTH, atol=0.2)

    def gn_error(anchors):
        r = runner.invoke(app, ["locate", str(tmp_path / "tag.csv"), "--anchors", str(anchors),
                                "--method", "gn", "--out", str(tmp_path / "fix.csv")])
        assert r.exit_code == 0, r.output
        fix = pd.read_csv(tmp_path / "fix.csv")
        return np.sqrt(np.mean(np.sum((fix[["x", "y"]].to_numpy() - PATH) ** 2, axis=1)))

    assert gn_error(tmp_path / "cal.csv") < 0.3 * gn_error(tmp_path / "a.csv")


def test_cli_refuses_a_table_without_rough_anchors(tmp_path):
    pd.DataFrame({"id": ["A", "B", "C"], "x": [0, 1, 0], "y": [0, 0, 1]}).to_csv(tmp_path / "a.csv", index=False)
    pd.DataFrame({"time": [0], "node": ["A"], "peer": ["B"], "kind": ["range"], "value": [1.0]}
                 ).to_csv(tmp_path / "m.csv", index=False)
    res = CliRunner().invoke(app, ["calibrate", str(tmp_path / "m.csv"), "--anchors", str(tmp_path / "a.csv")])
    assert res.exit_code != 0 and "std_m" in res.output
