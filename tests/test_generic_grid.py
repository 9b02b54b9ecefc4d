"""The grid filter over any measurement model (``Observation`` inputs): a log-likelihood on
the cells' positions. The contract loops (``test_contract_generic.py``,
``test_metamorphic.py``) run it on every model case its tags accept; here: known answers
at zero noise, the paper's readings as a configuration of the generic form, the claimed
covariance against the errors, the drift with the prior's velocity, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators import GridFilter, GridGeometry
from radioloc.models import (
    BearingModel,
    Context,
    LogDistanceGaussian,
    Observation,
    PseudorangeModel,
    RandomWalk,
    RangeModel,
    RssModel,
    TrapezoidRssModel,
    WhiteAccelerationCV,
)
from radioloc.models.rssi_trapezoid import TrapezoidModel

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 15.0], [20.0, 15.0]])
TRUTH = np.array([[7.3, 5.1], [12.45, 9.8]])
CELL_M = 0.1


def _snapshot(model, values, prior_offset=(0.7, -0.4)):
    """One step of ``values`` ``(B, m)`` with a prior 2 m wide about the truth + offset."""
    obs = Observation(model, values[:, None, :], Context(points=ANCHORS, index=np.arange(4)))
    f = GridFilter(cell_m=CELL_M)
    return f.run(obs, prior_mean=TRUTH + np.asarray(prior_offset), prior_cov=4.0 * np.eye(2))


def _ranges(points):
    return np.linalg.norm(points[..., None, :] - ANCHORS, axis=-1)


def _bearings(points):
    d = points[..., None, :] - ANCHORS
    return np.arctan2(d[..., 1], d[..., 0])


@pytest.mark.parametrize("model,measure", [
    (RangeModel(std_m=0.005), _ranges),
    (BearingModel(std_rad=1e-4), _bearings),
], ids=["range", "bearing"])
def test_zero_noise_gives_the_truth_within_a_cell(model, measure):
    track = _snapshot(model, measure(TRUTH))
    err = np.linalg.norm(track.position[:, -1] - TRUTH, axis=-1)
    assert np.all(err < CELL_M), err
    # and the posterior is as narrow as the grid allows
    assert np.all(np.sqrt(np.trace(track.covariance[:, -1], axis1=-2, axis2=-1)) < CELL_M)


def test_two_kinds_in_one_step_multiply():
    """A range to one anchor and a bearing from another (crossing the range circle at a
    wide angle) fix the position together, the range alone does not: their likelihoods
    multiply on the cells."""
    ctx = Context(points=ANCHORS[:1])
    rng_obs = Observation(RangeModel(std_m=0.01), _ranges(TRUTH)[:, None, :1], ctx)
    brg = Observation(BearingModel(std_rad=5e-4), _bearings(TRUTH)[:, None, 3:],
                      Context(points=ANCHORS[3:]))
    f = GridFilter(cell_m=CELL_M)
    prior = dict(prior_mean=TRUTH + [0.7, -0.4], prior_cov=4.0 * np.eye(2))
    both = f.run([rng_obs, brg], **prior).position[:, -1]
    assert np.all(np.linalg.norm(both - TRUTH, axis=-1) < CELL_M)
    alone = f.run(rng_obs, **prior).position[:, -1]
    assert np.all(np.linalg.norm(alone - TRUTH, axis=-1) > 5 * CELL_M)


def test_moving_the_anchors_moves_the_estimate():
    base = _snapshot(RangeModel(std_m=0.05), _ranges(TRUTH)).position[:, -1]
    moved = _snapshot(RangeModel(std_m=0.05), _ranges(TRUTH + [1.0, 0.0])).position[:, -1]
    np.testing.assert_allclose(moved - base, np.broadcast_to([1.0, 0.0], base.shape), atol=CELL_M)


def test_claimed_covariance_matches_the_errors():
    """Ranges with 0.3 m noise, one update: the grid posterior is Bayes' rule on the cells,
    so its covariance should hold the errors (NEES near 2, its dimension)."""
    rng = np.random.default_rng(4)
    truth = np.c_[rng.uniform(5, 15, 40), rng.uniform(4, 11, 40)]
    z = _ranges(truth) + 0.3 * rng.standard_normal((40, 4))
    start = truth + 0.5 * rng.standard_normal(truth.shape)      # the prior holds the truth
    obs = Observation(RangeModel(std_m=0.3), z[:, None], Context(points=ANCHORS))
    track = GridFilter(cell_m=0.05).run(obs, prior_mean=start, prior_cov=0.25 * np.eye(2))
    e = track.position[:, -1] - truth
    nees = np.einsum("bi,bij,bj->b", e, np.linalg.inv(track.covariance[:, -1]), e)
    # the mean of 40 chi-square(2) draws: 2 +- 0.32 (1.54 here); the band is 2.5 of those
    assert 1.2 < nees.mean() < 2.8, nees.mean()


def _readings(seed=5, T=6):
    rng = np.random.default_rng(seed)
    logd = LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1)
    truth = np.array([[8.0, 6.0], [13.0, 4.0]])
    xy = rng.uniform([2, 1], [18, 11], (2, T, 2))
    rssi = np.round(logd.mean(np.linalg.norm(xy - truth[:, None], axis=-1))
                    + rng.normal(0, 1, (2, T)))
    return logd, xy, rssi


@pytest.mark.parametrize("kind", ["logdistance", "trapezoid"])
def test_paper_readings_are_a_configuration_of_observations(kind):
    """``run(tracker_xy, rssi)`` with the paper's likelihood ``L(dist | rssi)`` and the same
    filter fed an ``Observation`` of the model's measurement form (a moving reference
    point: the tracker) give the same track: the update normalises, so the likelihood's
    scale does not matter (``epsilon = 0``)."""
    logd, xy, rssi = _readings()
    if kind == "logdistance":
        paper, model = logd, RssModel(logd)
    else:
        k = np.arange(101.0)
        paper = TrapezoidModel(mu=np.clip(40.0 - 0.4 * k, 0.5, None), tau=np.full(101, 1.5),
                               sigma=np.full(101, 3.0), count=np.ones(101))
        model = TrapezoidRssModel(paper)
        rssi = np.clip(np.round((40.0 - np.linalg.norm(xy - [[[8.0, 6.0]], [[13.0, 4.0]]],
                                                       axis=-1)) / 0.4), 0, 100)
    geom = GridGeometry(40, 24, 0.5)
    time = np.arange(xy.shape[1], dtype=float)
    settings = dict(epsilon=0.0, motion=RandomWalk(0.3), backend="numpy")
    a = GridFilter(geom, paper, **settings).run(xy, rssi, time=time)
    obs = Observation(model, rssi[..., None], Context(points=xy[:, :, None, :]))
    b = GridFilter(geom, **settings).run(obs, time)
    np.testing.assert_allclose(b.position, a.position, rtol=0, atol=1e-9)
    np.testing.assert_allclose(b.covariance, a.covariance, rtol=0, atol=1e-9)


def test_the_grid_drifts_with_the_prior_velocity():
    """A constant-velocity motion model: the grid built around the prior moves with the
    prior's velocity, so a target that moves at it is followed with no update at all."""
    motion = WhiteAccelerationCV(1e-4)
    z = np.full((1, 5, 4), np.nan)                              # no measurement
    obs = Observation(RangeModel(std_m=0.1), z, Context(points=ANCHORS))
    track = GridFilter(motion=motion, cell_m=0.2).run(
        obs, np.arange(5.0), prior_mean=[[5.0, 5.0, 0.8, -0.3]],
        prior_cov=np.diag([0.5, 0.5, 0.01, 0.01]))
    want = np.array([5.0, 5.0]) + np.arange(5.0)[:, None] * [0.8, -0.3]
    np.testing.assert_allclose(track.position[0], want, atol=1e-9)
    spread = np.trace(track.covariance[0], axis1=-2, axis2=-1)
    assert np.all(np.diff(spread) > 0), "the blur widens the grid at every step"
    assert np.all(track.diagnostics["measurements_used"] == 0)


def test_batch_axes_lead_and_a_bare_series_has_none():
    z = _ranges(TRUTH)[:, None] + np.zeros((2, 3, 4))
    obs = Observation(RangeModel(std_m=0.05), np.stack([z, z]), Context(points=ANCHORS))
    track = GridFilter(cell_m=0.2).run(obs, prior_mean=TRUTH, prior_cov=np.eye(2))
    assert track.position.shape == (2, 2, 3, 2)
    one = GridFilter(cell_m=0.2).run(Observation(RangeModel(std_m=0.05), z[1], obs.context),
                                     prior_mean=TRUTH[1], prior_cov=np.eye(2))
    assert one.position.shape == (3, 2)
    np.testing.assert_allclose(one.position, track.position[1, 1], atol=1e-12)


def test_bad_input_is_named():
    ctx = Context(points=ANCHORS)
    z = _ranges(TRUTH)[:, None]
    obs = Observation(RangeModel(std_m=0.05), z, ctx)
    f = GridFilter(cell_m=0.2)
    with pytest.raises(ConfigError, match="PseudorangeModel.*clock_offset"):
        f.run(Observation(PseudorangeModel(std_m=0.1), z, ctx), prior_mean=TRUTH,
              prior_cov=np.eye(2))
    three = Context(points=np.c_[ANCHORS, np.ones(4)])
    with pytest.raises(ConfigError, match="BearingModel.*3-D"):
        f.run(Observation(BearingModel(std_rad=0.01), np.zeros_like(z), three), prior_mean=TRUTH,
              prior_cov=np.eye(2))
    with pytest.raises(InputError, match="prior_mean"):
        f.run(obs, prior_mean=np.zeros((2, 3)), prior_cov=np.eye(2))
    with pytest.raises(InputError, match="prior_cov"):
        f.run(obs, prior_mean=TRUTH, prior_cov=-np.eye(2))
    with pytest.raises(ConfigError, match="geometry"):
        f.run(obs)                                    # no grid and no prior to build one
    bad = z.copy()
    bad[0, 0, 1] = np.inf
    with pytest.raises(InputError, match=r"observations\[0\].z"):
        f.run(Observation(RangeModel(std_m=0.05), bad, ctx), prior_mean=TRUTH,
              prior_cov=np.eye(2))
    with pytest.raises(ConfigError, match="model"):
        f.run(np.zeros((2, 3, 2)), np.zeros((2, 3)))  # readings need the paper's model
    with pytest.raises(ConfigError, match="cell_m"):
        GridFilter(cell_m=0.0)
