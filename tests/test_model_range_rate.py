"""The range-rate (Doppler) kind: its model against finite differences and a known answer,
and the kind through ``radioloc locate`` (ekf-track, smoother, pf, lsq), ``radioloc
methods`` and the docs' kinds table, from its one model file."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.core.kinds import markdown_table
from radioloc.locate.base import LocateRequest, run_method
from radioloc.models.measurement import Context, numerical_jacobian
from radioloc.models.range_rate import RangeRateModel

ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0.0, 20.0, 20.0, 0.0],
                        "y": [0.0, 0.0, 15.0, 15.0]})


@pytest.mark.parametrize("dim", [2, 3])
def test_jacobian_matches_finite_differences_with_moving_anchors(dim):
    rng = np.random.default_rng(0)
    pts = rng.uniform(-20, 20, (5, dim))
    vel = rng.normal(0, 3, (5, dim))
    ctx = Context(points=pts, columns={c: vel[:, i] for i, c in enumerate(("vx", "vy", "vz")[:dim])})
    state = {"position": rng.uniform(-5, 5, (4, dim)), "velocity": rng.normal(0, 2, (4, dim))}
    model = RangeRateModel(std_mps=0.1)
    z, J = model.predict_with_jacobian(state, ctx)
    num = numerical_jacobian(model, state, ctx)
    for name in ("position", "velocity"):
        np.testing.assert_allclose(J[name], num[name], atol=1e-6)
    # the known answer: the relative velocity along the line of sight
    d = state["position"][:, None] - pts
    expect = np.sum(d * (state["velocity"][:, None] - vel), -1) / np.linalg.norm(d, axis=-1)
    np.testing.assert_allclose(z, expect, rtol=1e-12)


def test_a_node_at_a_known_height_among_3d_anchors():
    ctx = Context(points=np.array([[0.0, 0.0, 3.0], [10.0, 0.0, 0.0]]), height_m=1.0)
    state = {"position": np.array([3.0, 4.0]), "velocity": np.array([1.0, 0.0])}
    z, J = RangeRateModel(std_mps=0.1).predict_with_jacobian(state, ctx)
    np.testing.assert_allclose(z, [3.0 / np.sqrt(29.0), -7.0 / np.sqrt(66.0)])
    assert J["position"].shape == (2, 2) and J["velocity"].shape == (2, 2)
    np.testing.assert_allclose(J["velocity"], numerical_jacobian(
        RangeRateModel(std_mps=0.1), state, ctx)["velocity"], atol=1e-7)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="std_mps"):
        RangeRateModel(std_mps=0.0)


def walk(seed: int, rate_std: float = 0.3):
    """A walker on an ellipse at about 1.2 m/s, ranges (1 m noise) and range rates to four
    anchors at rest, 4 Hz, 40 s; returns the log and the truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 40.0, 0.25)
    phase = 0.2 * t
    xy = np.stack([10 + 7 * np.cos(phase), 7.5 + 5 * np.sin(phase)], -1)
    vel = np.stack([-7 * np.sin(phase), 5 * np.cos(phase)], -1) * 0.2
    d = xy[:, None] - ANCHORS[["x", "y"]].to_numpy()[None]
    r = np.linalg.norm(d, axis=-1)
    rr = np.sum(d * vel[:, None], -1) / r
    rows = []
    for kind, value, std in (("range", r, 1.0), ("range_rate", rr, rate_std)):
        rows.append(pd.DataFrame({"time": np.repeat(t, 4), "node": "tag",
                                  "peer": np.tile(ANCHORS["id"], t.size), "kind": kind,
                                  "value": (value + std * rng.standard_normal(value.shape)).ravel()}))
    log = pd.concat(rows).sort_values("time", kind="stable").reset_index(drop=True)
    return log, pd.DataFrame({"time": t, "x": xy[:, 0], "y": xy[:, 1]})


def rmse(est: pd.DataFrame, truth: pd.DataFrame) -> float:
    m = est.merge(truth, on="time", suffixes=("", "_true"))
    return float(np.sqrt(np.mean((m.x - m.x_true) ** 2 + (m.y - m.y_true) ** 2)))


@pytest.mark.parametrize("method", ["ekf-track", "smoother", "pf", "lsq"])
def test_range_rates_through_locate(method):
    """Every method that reads the kinds' models takes the rows; the trackers gain from them
    (the velocity they measure) over the same ranges alone."""
    log, truth = walk(1)
    # pf's and the smoother's ranges have a LOS/NLOS noise (given here: its EM fit is not
    # what is tested)
    options = {"range_rate_std_mps": "0.3"} | (
        {"los_std_m": "1.0", "nlos_mean_m": "3.0", "alpha": "0.99"}
        if method in ("pf", "smoother") else {"range_std_m": "1.0"})
    if method == "pf":
        options["seed"] = "3"
    both = run_method(method, LocateRequest(log, ANCHORS, options=options))
    assert len(both) == truth.shape[0] and np.isfinite(both[["x", "y"]].to_numpy()).all()
    assert both.attrs["summary"]["measurements"]["range_rate"] == 4 * truth.shape[0]
    if method == "lsq":          # one fix per epoch: position and velocity from 8 rows
        assert rmse(both, truth) < 1.0
        return
    # measured (seed 1): ranges alone 0.60 m (ekf-track, pf); with range rates ekf-track
    # 0.23 m, smoother 0.18 m, pf 0.37 m
    assert rmse(both, truth) < 0.5
    if method != "smoother":        # (its ranges-only run of this log is not a reference)
        ranges = run_method(method, LocateRequest(log[log.kind == "range"], ANCHORS,
                                                  options={k: v for k, v in options.items()
                                                           if k != "range_rate_std_mps"}))
        assert rmse(both, truth) < 0.75 * rmse(ranges, truth)


def test_the_kind_in_radioloc_methods_and_the_docs_table():
    res = CliRunner().invoke(app, ["methods"], env={"COLUMNS": "400"})
    assert res.exit_code == 0, res.output
    rows = [ln for ln in res.output.splitlines() if "range_rate" in ln]
    assert any("range_rate_std_mps" in ln for ln in res.output.splitlines())
    assert rows, res.output
    assert "| `range_rate` | m/s |" in markdown_table()


def test_a_random_walk_with_range_rates_is_refused_in_one_line(tmp_path):
    log, _ = walk(2)
    log.to_csv(tmp_path / "m.csv", index=False)
    ANCHORS.to_csv(tmp_path / "a.csv", index=False)
    res = CliRunner().invoke(app, ["locate", str(tmp_path / "m.csv"), "--anchors",
                                   str(tmp_path / "a.csv"), "--method", "ekf-track", "-o",
                                   "motion=rw"])
    out = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(out) == 1, res.output
    assert "RangeRateModel (kind range_rate) reads velocity" in out[0]
    assert "RandomWalk" in out[0] and "Traceback" not in res.output
