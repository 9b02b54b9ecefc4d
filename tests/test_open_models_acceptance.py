"""New measurement kinds through the generic filter at their bound, and through ``locate``.

The truth is drawn from the filter's own model (motion, clock, noise), so at high SNR the
extended Kalman filter is near-optimal and its RMSE meets the posterior Cramer-Rao bound
(:func:`radioloc.bounds.fisher.tracking_crb`): TDoA with a drifting tag clock, pseudoranges
with a clock offset and drift, angles of arrival. Then the same kinds run through
``radioloc locate --method ekf-track`` from a CSV log, with no change to any estimator.
"""

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.bounds.fisher import tracking_crb
from radioloc.cli import app
from radioloc.estimators import ExtendedKalmanFilter
from radioloc.models.bearing import BearingModel
from radioloc.models.measurement import Context, Observation
from radioloc.models.motion import WhiteAccelerationCV
from radioloc.models.pseudorange import PseudorangeModel
from radioloc.models.tdoa import TdoaModel

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 20.0], [0.0, 20.0], [10.0, -4.0], [24.0, 10.0]])
SLOTS_S = np.arange(6) * 1e-3
RUNS, STEPS, DT = 300, 30, 0.2


def _context(kind):
    others = np.arange(1, 6)
    if kind == "tdoa":
        return Context(points=ANCHORS[others], index=others, reference=np.tile(ANCHORS[0], (5, 1)),
                       reference_index=np.zeros(5, dtype=int))
    return Context(points=ANCHORS, index=np.arange(6))


MODELS = {"tdoa": TdoaModel(std_m=0.02, slot_s=SLOTS_S), "pseudorange": PseudorangeModel(std_m=0.02),
          "aoa": BearingModel(std_rad=0.002)}


@pytest.mark.parametrize("kind", list(MODELS))
def test_generic_ekf_tracks_at_the_posterior_crb(kind):
    rng = np.random.default_rng(11)
    model, ctx = MODELS[kind], _context(kind)
    ekf = ExtendedKalmanFilter(WhiteAccelerationCV(0.5, 2), gate=None,
                               clock_offset_prior_std_m=3.0, clock_drift_prior_std_m_per_s=1.0,
                               clock_offset_std_m_per_sqrt_s=0.05,
                               clock_drift_std_m_per_s_per_sqrt_s=0.05)
    dummy = Observation(model, np.zeros((RUNS, STEPS, ctx.rows)), ctx)
    layout = ekf.state_layout(dummy)
    F, Q = ekf.transition(layout, DT)
    mean0 = np.zeros(layout.size)
    mean0[:2] = [8.0, 9.0]
    P0 = ekf.init(np.zeros(4), np.diag([1.0, 1.0, 0.25, 0.25]), observations=dummy).covariance
    states = np.empty((RUNS, STEPS, layout.size))
    states[:, 0] = mean0 + rng.standard_normal((RUNS, layout.size)) @ np.linalg.cholesky(P0).T
    LQ = np.linalg.cholesky(Q + 1e-15 * np.eye(layout.size))
    for t in range(1, STEPS):
        states[:, t] = states[:, t - 1] @ F.T + rng.standard_normal((RUNS, layout.size)) @ LQ.T
    z = model.sample(layout.split(states), ctx, rng)
    obs = Observation(model, z, ctx)
    track = ekf.run(obs, DT * np.arange(STEPS), prior_mean=mean0, prior_cov=P0)
    err2 = np.sum((track.position - states[..., :2]) ** 2, axis=-1)
    bound = tracking_crb(obs, states, layout, F, Q, P0)
    late = slice(STEPS // 2, None)
    ratio = np.sqrt(err2[:, late].mean()) / np.sqrt(np.mean(bound.rmse_m[:, late] ** 2))
    assert 0.85 < ratio < 1.15, (kind, ratio)


def _log(kind, rng):
    """A CSV log of one tag walking a circle, with rows of ``kind`` (no clock terms)."""
    t = 0.2 * np.arange(60)
    xy = np.stack([10 + 5 * np.cos(0.2 * t), 10 + 5 * np.sin(0.2 * t)], axis=-1)
    rows = []
    for k, p in enumerate(xy):
        d = np.linalg.norm(ANCHORS - p, axis=1)
        for a in range(6):
            if kind == "tdoa" and a > 0:
                rows.append((t[k], "tag", f"A{a}", "tdoa", d[a] - d[0] + 0.05 * rng.normal(), "A0"))
            elif kind == "aoa":
                v = p - ANCHORS[a]
                rows.append((t[k], "tag", f"A{a}", "aoa", np.arctan2(v[1], v[0]) + 0.01 * rng.normal(), ""))
    frame = pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value", "reference"])
    return frame, xy


@pytest.mark.parametrize("method", ["ekf-track", "smoother"])
@pytest.mark.parametrize("kind,option", [("tdoa", "tdoa_std_m=0.05"), ("aoa", "aoa_std_rad=0.01")])
def test_new_kinds_run_through_locate(tmp_path, kind, option, method):
    frame, xy = _log(kind, np.random.default_rng(5))
    if kind != "tdoa":
        frame = frame.drop(columns="reference")
    frame.to_csv(tmp_path / "m.csv", index=False)
    pd.DataFrame({"id": [f"A{a}" for a in range(6)], "x": ANCHORS[:, 0], "y": ANCHORS[:, 1]}
                 ).to_csv(tmp_path / "a.csv", index=False)
    res = CliRunner().invoke(app, ["locate", str(tmp_path / "m.csv"), "--anchors", str(tmp_path / "a.csv"),
                                   "--method", method, "-o", option, "--out", str(tmp_path / "t.csv")])
    assert res.exit_code == 0, res.output
    out = pd.read_csv(tmp_path / "t.csv")
    err = np.hypot(out.x - xy[:, 0], out.y - xy[:, 1])
    assert err[10:].mean() < 0.3, err.describe()
    assert {"cov_xx", "cov_xy", "cov_yy"} <= set(out.columns)


def test_new_kinds_walkthrough_table_is_current(tmp_path):
    """docs/your-own-log/new-kinds.md shows docs/generated/new_kinds.md: what the script gives."""
    import importlib.util
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    spec = importlib.util.spec_from_file_location("new_kinds", root / "docs/tutorials/new_kinds.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    module.main(tmp_path)
    assert (tmp_path / "new_kinds.md").read_text() == (root / "docs/generated/new_kinds.md").read_text()
