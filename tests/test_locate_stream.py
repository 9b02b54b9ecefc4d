"""Live tracking (`radioloc.locate.Tracker`, `radioloc locate --follow`): the estimates equal
the batch causal run of the same rows."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.locate import LocateRequest, Tracker, run_method

ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D", "E"], "x": [0.0, 20.0, 20.0, 0.0, 10.0],
                        "y": [0.0, 0.0, 15.0, 15.0, 16.0]})
OPTIONS = {"q": "0.5", "init_s": "1.5"}


def simulated_log(seed: int = 3) -> pd.DataFrame:
    """Two tags: ``t1`` asynchronous (one anchor per time stamp) with an outlier range; ``t2``
    synchronous (several anchors per time stamp), silent for 8 s (longer than max_gap_s)."""
    rng = np.random.default_rng(seed)
    frames = []
    for node, n in (("t1", 700), ("t2", 200)):
        t = np.round(np.cumsum(rng.uniform(0.02, 0.08 if node == "t1" else 0.2, n)), 4)
        if node == "t2":
            t = np.where(t > 8, t + 8, t)
        phase = 0.0 if node == "t1" else 2.0
        xy = np.stack([10 + 6 * np.cos(t / 5 + phase), 7.5 + 4 * np.sin(t / 5 + phase)], -1)
        peers = (np.arange(n) % 5)[:, None] if node == "t1" else np.tile(np.arange(4), (n, 1))
        for j in range(peers.shape[1]):
            p = peers[:, j]
            d = np.linalg.norm(xy - ANCHORS[["x", "y"]].to_numpy()[p], axis=1)
            frames.append(pd.DataFrame({"time": t, "node": node, "peer": ANCHORS["id"].to_numpy()[p],
                                        "kind": "range", "value": d + 0.1 * rng.standard_normal(n)}))
    log = pd.concat(frames, ignore_index=True)
    log.loc[300, "value"] += 12.0                     # an outlier the gate refuses
    log = log[rng.random(len(log)) > 0.1]             # rows lost at random
    return log.sort_values(["time", "node", "peer"], kind="stable").reset_index(drop=True)


def batch(rows: pd.DataFrame) -> pd.DataFrame:
    return run_method("ekf-track", LocateRequest(rows.reset_index(drop=True), ANCHORS,
                                                 options=dict(OPTIONS)))


def streamed(tracker: Tracker, chunks) -> pd.DataFrame:
    parts = [tracker.update(c) for c in chunks] + [tracker.close()]
    out = pd.concat([p for p in parts if len(p)], ignore_index=True)
    return out.sort_values(["time", "node"], kind="stable").reset_index(drop=True)


def assert_same(stream: pd.DataFrame, expected: pd.DataFrame) -> None:
    assert list(stream.columns) == list(expected.columns)
    assert len(stream) == len(expected)
    assert (stream["node"].to_numpy() == expected["node"].to_numpy()).all()
    numeric = [c for c in expected.columns if c != "node"]
    np.testing.assert_allclose(stream[numeric].to_numpy(float), expected[numeric].to_numpy(float),
                               rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def log() -> pd.DataFrame:
    return simulated_log()


@pytest.fixture(scope="module")
def expected(log) -> pd.DataFrame:
    out = batch(log)
    assert out["restart"].sum() == 1 and out["gated"].sum() >= 1   # the log exercises both
    return out


def random_chunks(rows: pd.DataFrame, rng) -> list[pd.DataFrame]:
    cuts = np.sort(rng.choice(np.arange(1, len(rows)), size=60, replace=False))
    return [rows.iloc[a:b] for a, b in zip([0, *cuts], [*cuts, len(rows)])]


def test_chunks_of_any_size_give_the_batch_causal_run(log, expected):
    rng = np.random.default_rng(0)
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS)
    assert_same(streamed(tracker, random_chunks(log, rng)), expected)
    summary = tracker.summary()
    assert summary["rows_in"] == len(log) and summary["rows_late"] == 0
    assert summary["rows_out"] == len(expected) and summary["restarts"] == 1


def test_rows_shuffled_within_the_window_are_placed(log, expected):
    rng = np.random.default_rng(1)
    arrival = log["time"].to_numpy() + rng.uniform(0, 0.45, len(log))   # window 0.5 s
    shuffled = log.iloc[np.argsort(arrival, kind="stable")]
    assert not shuffled["time"].is_monotonic_increasing
    records = shuffled.to_dict("records")                              # list of dicts too
    cuts = np.sort(rng.choice(np.arange(1, len(records)), size=200, replace=False))
    chunks = [records[a:b] for a, b in zip([0, *cuts], [*cuts, len(records)])]
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS, reorder_s=0.5)
    assert_same(streamed(tracker, chunks), expected)
    assert tracker.summary()["rows_late"] == 0


def test_rows_later_than_the_window_are_counted_and_left_out(log):
    rng = np.random.default_rng(2)
    arrival = log["time"].to_numpy() + np.where(rng.random(len(log)) < 0.03, 2.0, 0.0)
    order = np.argsort(arrival, kind="stable")
    arrived = log.iloc[order].reset_index(drop=True)
    # one row per update: a row is late when it is older than the window behind the latest
    times = arrived["time"].to_numpy()
    seen = np.maximum.accumulate(np.concatenate([[-np.inf], times[:-1]]))
    late = times <= seen - 0.5
    assert late.sum() > 5
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS, reorder_s=0.5)
    out = streamed(tracker, [arrived.iloc[[i]] for i in range(len(arrived))])
    assert tracker.summary()["rows_late"] == int(late.sum())
    kept = arrived[~late].sort_values(["time", "node", "peer"], kind="stable")
    assert_same(out, batch(kept))


def test_state_survives_pauses_between_updates(log, expected):
    tracker = Tracker("ekf-track", ANCHORS, OPTIONS)
    first = tracker.update(log.iloc[:400])
    assert len(first) > 0                        # estimates come before the end of input
    rest = [tracker.update(log.iloc[400:]), tracker.update(log.iloc[:0]), tracker.close()]
    out = pd.concat([first, *rest], ignore_index=True).sort_values(["time", "node"],
                                                                    kind="stable")
    assert_same(out.reset_index(drop=True), expected)
    assert tracker.close().empty


def test_tracker_refuses_what_it_cannot_stream():
    with pytest.raises(ConfigError, match="ekf-track"):
        Tracker("pf", ANCHORS)
    with pytest.raises(ConfigError, match="smooth"):
        Tracker("ekf-track", ANCHORS, {"smooth": "1"})
    with pytest.raises(ConfigError, match="unknown option 'bogus'"):
        Tracker("ekf-track", ANCHORS, {"bogus": "1"})
    with pytest.raises(ConfigError, match="reorder_s"):
        Tracker("ekf-track", ANCHORS, reorder_s=-1)
    tracker = Tracker("ekf-track", ANCHORS)
    with pytest.raises(InputError, match="row 1, column 'value'"):
        tracker.update([{"time": 0, "node": "t", "peer": "A", "kind": "range", "value": 1},
                        {"time": 0, "node": "t", "peer": "B", "kind": "range", "value": "x"}])
    with pytest.raises(InputError, match="missing column"):
        tracker.update([{"time": 0, "node": "t", "kind": "range", "value": 1}])
