"""`locate --method pf` runs every segment of a log as one batch of particle filters, each
from its own random stream: a node's track is the one it gets alone."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import radioloc.estimators.pf_compiled as pf_compiled
from radioloc.core.errors import InputError
from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.estimators.particle_filter import RunGenerators, sample_motion
from radioloc.locate.base import LocateRequest, run_method
from radioloc.locate.ekf_track import run_ekf, segments, tracker_settings
from radioloc.locate.pf import ekf_tracks, pf_tracks
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import WhiteAccelerationCV

ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0.0, 30.0, 30.0, 0.0],
                        "y": [0.0, 0.0, 20.0, 20.0]})


def walk_log(seed: int = 0, tags: int = 2, epochs: int = 120, gap: bool = True):
    """Tags walking inside the anchors' box, each with its own time phase; the ranges of an
    epoch share its time stamp; 5 % of the rows lost; tag1 silent for 8 s (two segments)."""
    rng = np.random.default_rng(seed)
    a = ANCHORS[["x", "y"]].to_numpy()
    frames = []
    for i in range(tags):
        t = np.arange(epochs) * 0.2 + rng.uniform(0, 0.2)
        v = 1.0 * np.tanh(np.cumsum(rng.normal(0, 0.15, (epochs, 2)), axis=0))
        p = np.cumsum(v * 0.2, axis=0) + rng.uniform([8, 6], [22, 14])
        r = np.linalg.norm(p[:, None, :] - a, axis=-1) + rng.normal(0, 0.1, (epochs, 4))
        keep = rng.random(r.shape) > 0.05
        if gap and i == 0:
            keep &= ~((t > 10) & (t < 18))[:, None]
        e, j = np.nonzero(keep)
        frames.append(pd.DataFrame({"time": np.round(t[e], 6), "node": f"tag{i + 1}",
                                    "peer": ANCHORS["id"].to_numpy()[j], "kind": "range",
                                    "value": r[e, j], "tx": p[e, 0], "ty": p[e, 1]}))
    log = pd.concat(frames).sort_values("time", kind="stable").reset_index(drop=True)
    return log


def request(log: pd.DataFrame, **options) -> LocateRequest:
    meas = log[["time", "node", "peer", "kind", "value"]]
    return LocateRequest(meas, ANCHORS, options={k: str(v) for k, v in options.items()})


@pytest.fixture(scope="module")
def log():
    return walk_log()


def test_each_node_of_a_batch_gets_the_track_it_gets_alone(log):
    outputs = ("filtered", "fixed-lag", "backward")
    both = pf_tracks(request(log, particles=200, seed=4), outputs)
    assert both["filtered"]["restart"].sum() == 1          # tag1's gap: two segments
    for node in ("tag1", "tag2"):
        alone = pf_tracks(request(log[log.node == node], particles=200, seed=4), outputs)
        for k in outputs:
            mine = both[k][both[k].node == node].reset_index(drop=True)
            pd.testing.assert_frame_equal(mine, alone[k], check_exact=False, rtol=1e-12,
                                          atol=1e-12)


def test_the_seed_and_the_node_name_choose_the_stream(log):
    one = run_method("pf", request(log, particles=100, seed=1))
    two = run_method("pf", request(log, particles=100, seed=2))
    again = run_method("pf", request(log, particles=100, seed=1))
    pd.testing.assert_frame_equal(one, again)
    assert not np.allclose(one.x, two.x)
    renamed = log.assign(node=log.node.map({"tag1": "tagA", "tag2": "tag2"}))
    other = run_method("pf", request(renamed, particles=100, seed=1))
    same = one.node == "tag2"
    np.testing.assert_array_equal(one.x[same].to_numpy(), other.x[other.node == "tag2"])
    assert not np.allclose(one.x[~same].to_numpy(), other.x[other.node == "tagA"].to_numpy())


def test_a_given_los_std_is_used_and_the_others_fitted(log):
    out = run_method("pf", request(log, particles=100, los_std_m=0.2))
    for model in out.attrs["summary"]["model"]:
        assert model["los_std_m"] == 0.2 and model["fitted"]
        assert model["nlos_mean_m"] > 0 and 0 < model["alpha"] <= 1


def test_ekf_tracks_in_one_batch_equal_each_segment_run_alone(log):
    req = request(log)
    a = ANCHORS[["x", "y"]].to_numpy()
    s = tracker_settings(req, a)
    items = []
    for node in ("tag1", "tag2"):
        rows = log[log.node == node]
        wide = rows.pivot_table(index="time", columns="peer", values="value")
        wide = wide.reindex(columns=ANCHORS["id"])
        times, R = wide.index.to_numpy(), wide.to_numpy()
        items += [(times[seg], R[seg]) for seg in segments(times, s["max_gap_s"])]
    assert len(items) == 3
    stds = [0.1, 0.2, 0.15]
    batch = ekf_tracks(items, a, s, stds, 16.0, smooth=True)
    for (times, R), std, track in zip(items, stds, batch):
        alone = run_ekf(times, R, a, s, std, 16.0, smooth=True)
        np.testing.assert_allclose(track.position, alone.position, rtol=0, atol=1e-9)
        np.testing.assert_allclose(track.covariance, alone.covariance, rtol=0, atol=1e-12)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_filter_batch_with_its_own_steps_equals_each_filter_alone(backend):
    """Three filters with their own step lengths (one idle: dt = 0 and no range) and their
    own generators give what each gives alone; check=False gives what check=True gives."""
    rng = np.random.default_rng(5)
    anchors = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]])
    T, B = 15, 3
    dts = rng.uniform(0.05, 0.3, (B, T))
    dts[2, 8:] = 0.0
    truth = np.array([5.0, 5.0]) + np.cumsum(dts[..., None] * [0.8, 0.4], axis=1)
    ranges = np.linalg.norm(truth[..., None, :] - anchors, axis=-1) + \
        rng.normal(0, 0.1, (B, T, 4))
    ranges[rng.random(ranges.shape) < 0.2] = np.nan
    ranges[2, 8:] = np.nan
    start = np.concatenate([truth[:, 0], np.zeros((B, 2))], axis=-1)
    pf = P2PParticleFilter(WhiteAccelerationCV(1.0), LosNlosRange(0.1, 0.5, 0.9),
                           particles=300, backend=backend)
    seeds = [np.random.SeedSequence([9, b]) for b in range(B)]

    def run(which, check):
        gens = RunGenerators([seeds[b] for b in which], (len(which),))
        state = pf.init(start[which], gens)
        nodes = np.broadcast_to(anchors, (len(which), 4, 2))
        means, covs = [], []
        for k in range(T):
            state = pf.step(state, ranges[which, k], nodes, gens, dt=dts[which, k],
                            check=check)
            means.append(state.mean)
            covs.append(state.covariance)
        return np.stack(means, 1), np.stack(covs, 1)

    mean, cov = run([0, 1, 2], check=False)
    checked = run([0, 1, 2], check=True)
    np.testing.assert_array_equal(mean, checked[0])
    for b in range(B):
        alone = run([b], check=False)
        np.testing.assert_allclose(mean[b], alone[0][0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(cov[b], alone[1][0], rtol=0, atol=1e-12)
    assert np.all(np.linalg.norm(mean[:2, -1, :2] - truth[:2, -1], axis=-1) < 0.5)


def test_kernels_give_the_same_numbers_on_one_thread_and_on_several(monkeypatch):
    rng = np.random.default_rng(2)
    anchors = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]])
    ranges = np.linalg.norm([6.0, 7.0] - anchors, axis=-1) + rng.normal(0, 0.1, (2, 4))
    pf = P2PParticleFilter(WhiteAccelerationCV(1.0), LosNlosRange(0.1, 0.5, 0.9),
                           particles=5000, backend="numba")

    def run():
        g = np.random.default_rng(0)
        state = pf.init(np.array([[6.0, 7.0], [6.2, 7.1]]), g)
        for _ in range(3):
            state = pf.step(state, ranges, anchors, g, dt=0.1)
        return state

    monkeypatch.setattr(pf_compiled, "SERIAL_WORK", 0)           # every step parallel
    parallel = run()
    monkeypatch.setattr(pf_compiled, "SERIAL_WORK", 1 << 40)     # every step on one thread
    serial = run()
    np.testing.assert_allclose(parallel.mean, serial.mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(parallel.covariance, serial.covariance, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(parallel.ancestors, serial.ancestors)


def test_sample_motion_with_a_step_per_set_equals_each_set_alone():
    motion = WhiteAccelerationCV(0.5)
    x = np.random.default_rng(1).normal(size=(3, 50, 4))
    dt = np.array([0.1, 0.0, 0.7])
    seeds = [np.random.SeedSequence([3, b]) for b in range(3)]
    batch = sample_motion(motion, x, dt, RunGenerators(seeds, (3,)))
    for b in range(3):
        alone = sample_motion(motion, x[b:b + 1], float(dt[b]), RunGenerators([seeds[b]], (1,)))
        np.testing.assert_allclose(batch[b], alone[0], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(batch[1], x[1])        # dt = 0: no motion, no noise


def test_run_generators_need_one_seed_sequence_per_run():
    with pytest.raises(InputError, match="seed"):
        RunGenerators([np.random.SeedSequence(1)] * 2, (3,))
