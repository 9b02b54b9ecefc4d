"""ekf-track runs every track of a log as one batch: each track equals its own run."""

import numpy as np
import pandas as pd
import pytest

from radioloc.io.measurements import Measurements
from radioloc.locate.adapter import anchor_positions, default_models, node_observations
from radioloc.locate.ekf_track import run_tracker, stack_tracks, track_prior, tracker_filter

ANCHORS = pd.DataFrame({"id": ["A1", "A2", "A3", "A4", "A5"], "x": [0.0, 30.0, 30.0, 0.0, 15.0],
                        "y": [0.0, 0.0, 20.0, 20.0, 0.0]})


def _log(seed=0):
    """Three tags of different lengths and rates; tag3 never hears A5."""
    rng = np.random.default_rng(seed)
    rows = []
    for tag, n, period, heard in (("tag1", 60, 0.1, 5), ("tag2", 35, 0.23, 5), ("tag3", 48, 0.17, 4)):
        t = np.arange(n) * period + rng.uniform(0, 0.05)
        p = np.array([10.0, 8.0]) + np.cumsum(rng.normal(0, 0.05, (n, 2)), axis=0)
        for k in range(n):
            for a in range(heard):
                if rng.random() < 0.15:
                    continue
                xy = ANCHORS[["x", "y"]].to_numpy()[a]
                rows.append((round(t[k], 6), tag, ANCHORS["id"][a], "range",
                             float(np.linalg.norm(p[k] - xy) + rng.normal(0, 0.1))))
    return pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"])


@pytest.mark.parametrize("smooth", [False, True])
@pytest.mark.parametrize("anchor_bias", [False, True])
def test_batched_tracks_equal_one_by_one(smooth, anchor_bias):
    log = Measurements(_log())
    anchors = anchor_positions(ANCHORS)
    s = {"motion": "cv", "q": 1.0, "height": None, "dim": 2, "bias": 0.0, "smooth": smooth,
         "prior_std": 2.0, "init_s": 2.0, "max_gap_s": 5.0}
    models = default_models(log.kinds, {"range_std_m": 0.15}, anchor_bias=anchor_bias)
    tracks = [node_observations(log, ANCHORS, node, models) for node in log.nodes]
    assert len({o.z.shape for _, obs in tracks for o in obs}) == 3
    ekf = tracker_filter(anchors, s, 16.0, anchor_bias)
    priors = [track_prior(ekf, t, obs, anchors, s, anchor_bias) for t, obs in tracks]
    t, batch = stack_tracks([t for t, _ in tracks], [obs for _, obs in tracks])
    together = ekf.run(batch, t, prior_mean=np.stack([m for m, _ in priors]),
                       prior_cov=np.stack([np.diag(v) for _, v in priors]), smooth=smooth)
    for b, (times, obs) in enumerate(tracks):
        alone = run_tracker(times, obs, anchors, s, 16.0, smooth, anchor_bias)
        part = together[b, :times.size]
        np.testing.assert_allclose(part.position, alone.position, rtol=0, atol=1e-9)
        np.testing.assert_allclose(part.covariance, alone.covariance, rtol=0, atol=1e-9)
        np.testing.assert_array_equal(part.diagnostics["gated"], alone.diagnostics["gated"])
        np.testing.assert_array_equal(part.time, times)
