"""RSS with a log-distance model per anchor (AnchorRssModel), its self-calibration from a
track (radioloc.locate.path_loss) and `ekf-track` on rss rows."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import InputError
from radioloc.io.logs import read_anchors
from radioloc.locate.base import LocateRequest, run_method
from radioloc.locate.path_loss import anchor_rss_model, fit_path_loss
from radioloc.models.measurement import Context, numerical_jacobian
from radioloc.models.rss_model import AnchorRssModel

ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0.0, 20.0, 20.0, 0.0],
                        "y": [0.0, 0.0, 15.0, 15.0]})
A_DBM = np.array([-35.0, -40.0, -30.0, -38.0])
N = np.array([2.0, 2.5, 1.8, 2.2])


def walk(t: np.ndarray) -> np.ndarray:
    return np.stack([10 + 6 * np.cos(t / 6), 7.5 + 4 * np.sin(t / 6)], axis=-1)


def simulate(rss_std_db: float, range_std_m: float = 0.3, seed: int = 0, duration_s=40.0,
             ranges: bool = True):
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 0.25)
    xy = walk(t)
    d = np.linalg.norm(xy[:, None] - ANCHORS[["x", "y"]].to_numpy(), axis=-1)     # (T, 4)
    rss = A_DBM - 10 * N * np.log10(d) + rss_std_db * rng.standard_normal(d.shape)
    kinds = [("rss", rss)] + ([("range", d + range_std_m * rng.standard_normal(d.shape))]
                              if ranges else [])
    rows = [pd.DataFrame({"time": np.repeat(t, 4), "node": "tag",
                          "peer": np.tile(ANCHORS["id"], t.size), "kind": k,
                          "value": v.ravel()}) for k, v in kinds]
    return (pd.concat(rows).sort_values("time", kind="stable").reset_index(drop=True),
            pd.DataFrame({"time": t, "node": "tag", "x": xy[:, 0], "y": xy[:, 1]}))


def test_anchor_rss_jacobian_equals_finite_differences():
    model = AnchorRssModel(A_DBM, N, [3.0, 4.0, 5.0, 6.0])
    ctx = Context(points=ANCHORS[["x", "y"]].to_numpy()[[2, 0, 3]], index=np.array([2, 0, 3]))
    state = {"position": np.array([[4.0, 5.0], [13.0, 2.0]])}
    np.testing.assert_allclose(model.jacobian(state, ctx)["position"],
                               numerical_jacobian(model, state, ctx)["position"], atol=1e-6)
    np.testing.assert_allclose(model.std(ctx), [5.0, 3.0, 6.0])


def test_fit_recovers_each_anchors_parameters_from_a_track():
    """Noise-free readings against the true track give each anchor's a and n exactly."""
    log, truth = simulate(rss_std_db=0.0)
    cal = fit_path_loss(log, truth, ANCHORS)
    np.testing.assert_allclose(cal["rss_a_dbm"], A_DBM, atol=1e-6)
    np.testing.assert_allclose(cal["rss_n"], N, atol=1e-6)
    assert np.all(cal["rss_std_db"] < 1e-3)
    noisy = fit_path_loss(simulate(rss_std_db=3.0, seed=1)[0], truth, ANCHORS)
    np.testing.assert_allclose(noisy["rss_n"], N, atol=0.3)
    np.testing.assert_allclose(noisy["rss_std_db"], 3.0, atol=0.5)


def test_ekf_track_adds_rss_rows_with_the_anchors_parameters(tmp_path):
    """Ranges of 3 m sigma: adding RSS of 1 dB sigma, with the parameters in the anchors
    file (which round-trips through read_anchors), lowers the error; zero rss rows leave
    the range-only track unchanged."""
    log, truth = simulate(rss_std_db=1.0, range_std_m=3.0, seed=2, duration_s=30.0)
    cal = fit_path_loss(simulate(rss_std_db=1.0, seed=3, duration_s=30.0)[0], truth, ANCHORS)
    cal.to_csv(tmp_path / "anchors.csv", index=False)
    anchors = read_anchors(tmp_path / "anchors.csv")
    opts = {"range_std_m": "3"}

    def rmse(out):
        e = out.merge(truth, on=["time", "node"], suffixes=("", "_t"))
        e = e[e.time > 5]
        return float(np.sqrt(np.mean((e.x - e.x_t) ** 2 + (e.y - e.y_t) ** 2)))

    ranges = log[log.kind == "range"].reset_index(drop=True)
    alone = run_method("ekf-track", LocateRequest(ranges, anchors, options=opts))
    both = run_method("ekf-track", LocateRequest(log, anchors, options=opts))
    assert rmse(both) < 0.6 * rmse(alone), (rmse(alone), rmse(both))
    plain = run_method("ekf-track", LocateRequest(ranges, ANCHORS, options=opts))
    pd.testing.assert_frame_equal(plain, alone)


def test_rss_rows_without_the_parameters_name_the_columns_and_the_anchor():
    log, truth = simulate(rss_std_db=1.0, duration_s=5.0)
    with pytest.raises(InputError, match="rss_a_dbm"):
        run_method("ekf-track", LocateRequest(log, ANCHORS, options={}))
    cal = fit_path_loss(simulate(rss_std_db=0.0)[0], truth, ANCHORS)
    cal.loc[1, "rss_n"] = np.nan
    with pytest.raises(InputError, match="'B'"):
        anchor_rss_model(cal, ["A", "B"])
    assert anchor_rss_model(cal, ["A"]).n[0] == pytest.approx(N[0])
    with pytest.raises(InputError, match="no rss row"):
        fit_path_loss(log[log.kind == "range"], truth, ANCHORS)
