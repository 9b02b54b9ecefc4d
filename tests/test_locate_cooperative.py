"""`radioloc locate --method ekf-track -o cooperative=1`: ranges between tags, each peer's
estimate a moving anchor (radioloc.locate.cooperative)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter
from radioloc.locate.base import LocateRequest, run_method
from radioloc.locate.cooperative import align_peer_ranges, peer_ranges
from radioloc.models.measurement import Context, Observation
from radioloc.models.motion import WhiteAccelerationCV
from radioloc.models.ranging import RangeModel

#: Three clusters of anchors; each tag hears one cluster (all on one side of it) and one
#: anchor of another cluster, so alone it is poorly fixed across its anchors' direction.
ANCHORS = pd.DataFrame({"id": [f"A{i}" for i in range(9)],
                        "x": [0, 2, 4, 30, 32, 34, 15, 17, 19.0],
                        "y": [0, 1, 0, 0, 1, 0, 30, 31, 30.0]})
HEARS = {"T1": [0, 1, 2, 6], "T2": [3, 4, 5, 0], "T3": [6, 7, 8, 3], "T4": [0, 3, 6]}
CENTRES = {"T1": (8, 10), "T2": (24, 10), "T3": (16, 20), "T4": (16, 8)}
PAIRS = (("T1", "T2"), ("T2", "T3"), ("T3", "T1"))
ANCHOR_STD, PEER_STD = 0.3, 0.1


def walk(tag: str, t: np.ndarray) -> np.ndarray:
    k = list(CENTRES).index(tag)
    return np.array(CENTRES[tag]) + 2.5 * np.stack([np.cos(t / 5 + k), np.sin(t / 5 + k)], -1)


def simulate(seed: int = 0, duration_s: float = 30.0, hz: float = 4.0, tags=("T1", "T2", "T3"),
             peers: bool = True) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Each tag ranges to its anchors at its own times; pairs of tags range to each other
    at other times (rows of node ``a``, peer ``b``). Returns the log and the truth."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration_s, 1 / hz)
    rows, truth = [], []
    xy_a = ANCHORS[["x", "y"]].to_numpy()
    for k, tag in enumerate(tags):
        tt = t + 0.013 * k
        xy = walk(tag, tt)
        truth.append(pd.DataFrame({"time": tt, "node": tag, "x": xy[:, 0], "y": xy[:, 1]}))
        for a in HEARS[tag]:
            d = np.linalg.norm(xy - xy_a[a], axis=-1)
            rows.append(pd.DataFrame({"time": tt, "node": tag, "peer": ANCHORS.id[a],
                                      "kind": "range",
                                      "value": d + ANCHOR_STD * rng.standard_normal(t.size)}))
    for a, b in PAIRS if peers else ():
        tt = t + 0.1
        d = np.linalg.norm(walk(a, tt) - walk(b, tt), axis=-1)
        rows.append(pd.DataFrame({"time": tt, "node": a, "peer": b, "kind": "range",
                                  "value": d + PEER_STD * rng.standard_normal(t.size)}))
    log = pd.concat(rows).sort_values("time", kind="stable").reset_index(drop=True)
    return log, pd.concat(truth, ignore_index=True)


def track(log: pd.DataFrame, cooperative: bool, **extra) -> pd.DataFrame:
    opts = {"range_std_m": str(ANCHOR_STD), "cooperative": str(int(cooperative)), **extra}
    return run_method("ekf-track", LocateRequest(log, ANCHORS, options=opts))


def errors(out: pd.DataFrame, truth: pd.DataFrame, after_s: float = 5.0):
    """Position errors (N, 2) and their NEES after the start transient."""
    m = out.merge(truth, on=["time", "node"], suffixes=("", "_true"))
    m = m[m.time > after_s]
    e = m[["x", "y"]].to_numpy() - m[["x_true", "y_true"]].to_numpy()
    cov = np.stack([[m.cov_xx, m.cov_xy], [m.cov_xy, m.cov_yy]]).transpose(2, 0, 1)
    return e, np.einsum("ni,nij,nj->n", e, np.linalg.inv(cov), e)


@pytest.fixture(scope="module")
def runs():
    log, truth = simulate()
    return log, truth, track(log, False), track(log, True)


def test_cooperative_ranges_beat_independent_tracks(runs):
    """Measured: RMSE 0.53 m alone, 0.25 m with the tag-to-tag ranges."""
    _, truth, alone, coop = runs
    e0, _ = errors(alone, truth)
    e1, _ = errors(coop, truth)
    rmse0, rmse1 = (float(np.sqrt(np.mean(np.sum(e ** 2, 1)))) for e in (e0, e1))
    assert rmse1 < 0.7 * rmse0, (rmse0, rmse1)
    assert len(coop) == len(alone)          # one row per own time, as without the option
    assert coop[["time", "node"]].equals(alone[["time", "node"]])


def test_claimed_uncertainty_stays_consistent(runs):
    """NEES per 2-D position near 2 (measured 1.5 with the peers, 2.0 alone): the
    peers' uncertainty along the line of sight keeps the shared ranges from making the
    tags overconfident."""
    _, truth, alone, coop = runs
    for out in (alone, coop):
        _, nees = errors(out, truth)
        assert 1.0 < nees.mean() < 3.5, nees.mean()


def test_a_log_without_tag_to_tag_rows_is_unchanged_by_the_option():
    log, _ = simulate(seed=1, duration_s=15.0, peers=False)
    pd.testing.assert_frame_equal(track(log, True), track(log, False))


def test_a_tag_without_peers_is_tracked_as_without_the_option():
    """T4 has no tag-to-tag row: its track is the one of the plain run, whatever the others
    do (it does not share their time grid)."""
    log, _ = simulate(seed=2, duration_s=15.0, tags=("T1", "T2", "T3", "T4"))
    alone, coop = track(log, False), track(log, True)
    a, c = (o[o.node == "T4"].reset_index(drop=True) for o in (alone, coop))
    pd.testing.assert_frame_equal(a, c)
    assert not np.allclose(alone[alone.node == "T1"][["x", "y"]], coop[coop.node == "T1"][["x", "y"]])


def test_peer_ranges_are_the_rows_between_nodes():
    log, _ = simulate(seed=3, duration_s=5.0)
    rows = peer_ranges(log, ANCHORS["id"])
    assert set(zip(rows.node, rows.peer)) == set(PAIRS)
    assert len(rows) == int((~log.peer.isin(ANCHORS.id)).sum()) and rows["std"].isna().all()


def test_cooperative_refuses_odometry_rows():
    log, _ = simulate(seed=4, duration_s=5.0)
    odo = pd.DataFrame({"time": [1.0, 1.0], "node": "T1", "peer": "wheel",
                        "kind": ["odometry_dx", "odometry_dy"], "value": [0.1, 0.0]})
    with pytest.raises(ConfigError, match="cooperative"):
        track(pd.concat([log, odo]).sort_values("time", kind="stable"), True)


def test_coupling_rows_update_like_the_same_rows_given_as_observations():
    """A coupling that returns a fixed anchor's ranges gives the track of the filter given
    those ranges as a second observation (rows of a step are independent, so one update
    after the other equals one joint update)."""
    rng = np.random.default_rng(5)
    anchors = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])
    t = np.arange(20) * 0.5
    xy = np.stack([5 + np.cos(t), 5 + np.sin(t)], -1)
    r = np.linalg.norm(xy[:, None] - anchors, axis=-1) + 0.1 * rng.standard_normal((20, 4))
    model = RangeModel(std_m=0.1)
    first = Observation(model, r[:, :3], Context(points=anchors[:3]))
    second = Observation(model, r[:, 3:], Context(points=anchors[3:]))
    ekf = ExtendedKalmanFilter(WhiteAccelerationCV(1.0, 2), gate=None)
    prior = dict(prior_mean=[5.0, 5.0, 0, 0], prior_cov=np.eye(4))
    both = ekf.run([first, second], t, **prior)
    coupled = ekf.run([first], t, **prior,
                      coupling=lambda k, state: [Observation(model, r[k, 3:], second.context)])
    np.testing.assert_allclose(coupled.position, both.position, atol=1e-9)
    np.testing.assert_allclose(coupled.covariance, both.covariance, atol=1e-9)


def test_align_peer_ranges_recovers_a_clock_offset_and_a_bias():
    """Ranges between two tags logged on a clock 37 s behind theirs, 1.5 m long: the
    tracks alone give the offset and the bias back; a range log that cannot reach the
    tracks names time_s."""
    rng = np.random.default_rng(6)
    t = np.arange(0.0, 120.0, 0.5)
    a = np.stack([10 + 8 * np.cos(t / 9), 5 + 3 * np.sin(t / 5)], -1)
    b = np.stack([12 + 2 * np.cos(t / 4), 9 + 6 * np.sin(t / 7)], -1)
    track = pd.concat([pd.DataFrame({"time": t, "node": n, "x": p[:, 0], "y": p[:, 1]})
                       for n, p in (("T1", a), ("T2", b))])
    own = np.arange(0.0, 70.0, 0.7)                         # the range log's clock
    def at(p, times):
        return np.stack([np.interp(times, t, p[:, 0]), np.interp(times, t, p[:, 1])], -1)

    d = np.linalg.norm(at(a, own + 37.0) - at(b, own + 37.0), axis=-1)
    fit = align_peer_ranges(own, d + 1.5 + 0.2 * rng.standard_normal(own.size), track,
                            "T1", "T2", step_s=0.5)
    assert fit["offset_s"] == pytest.approx(37.0, abs=0.5)
    assert fit["bias_m"] == pytest.approx(1.5, abs=0.1)
    assert fit["correlation"] > 0.95 > fit["runner_up"]
    with pytest.raises(InputError, match="time_s"):
        align_peer_ranges(own + 1000.0, d, track, "T1", "T2", max_offset_s=100.0)
    with pytest.raises(InputError, match="'T9'"):
        align_peer_ranges(own, d, track, "T1", "T9")
