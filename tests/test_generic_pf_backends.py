"""The generic ParticleFilter's backends: ``backend="numba"`` (compiled likelihood of a
Gaussian range model, moments, systematic resampling; large draws filled in parallel)
equals ``backend="numpy"`` with the same seed, to 1e-10 relative (``assert_tracks_close``);
a model without a compiled likelihood is filtered by its NumPy definition on either
backend; the choice of backend is validated and a missing numba is named."""

import sys

import numpy as np
import pytest

from radioloc.core.errors import ConfigError
from radioloc.estimators.particle_filter import (DRAW_PARALLEL, ParticleFilter, RunGenerators,
                                                 has_compiled_likelihood, standard_normal)
from radioloc.estimators.resampling import stratified
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, Observation
from radioloc.models.motion import RandomWalk, WhiteAccelerationCV
from radioloc.models.ranging import RangeModel

from model_cases import MinimalBearing
from test_pf_backends import assert_tracks_close as assert_same

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 20.0], [0.0, 20.0]])


def scene(runs=3, steps=12, seed=4, anchors=ANCHORS, height=None, nlos=False):
    """Random-walk truths (runs, T, 2) and their ranges (runs, T, M), 15 % missing."""
    g = np.random.default_rng(seed)
    truth = 8.0 + np.cumsum(0.4 * g.standard_normal((runs, steps, 2)), axis=1)
    d2 = np.sum((truth[..., None, :] - anchors[:, :2]) ** 2, axis=-1)
    if height is not None:
        d2 = d2 + (height - anchors[:, 2]) ** 2
    z = np.sqrt(d2) + 0.2 * g.standard_normal(d2.shape)
    if nlos:
        z += np.where(g.random(z.shape) < 0.3, g.exponential(2.0, z.shape), 0.0)
    z[g.random(z.shape) < 0.15] = np.nan
    z[-1, steps // 3] = np.nan                           # a step without any range
    return truth, z


def both(motion=None, **kw):
    return [ParticleFilter(motion or RandomWalk(0.2), backend=b, **kw) for b in ("numba", "numpy")]


@pytest.mark.parametrize("kw", [dict(n_particles=500, ess_threshold=0.5),
                                dict(n_particles=400, ess_threshold=1.0, roughening=0.2),
                                dict(n_particles=300, ess_threshold=0.7, resample=stratified)],
                         ids=["threshold", "every-step-roughened", "stratified"])
def test_gaussian_ranges_agree_over_a_batch_of_runs(kw):
    truth, z = scene()
    obs = Observation(RangeModel(std_m=0.2), z, Context(points=ANCHORS))
    tracks = [pf.run(obs, prior_mean=truth[:, 0], prior_cov=np.eye(2))
              for pf in both(seed=[5, 6, 7], **kw)]
    assert_same(*tracks)
    err = np.linalg.norm(tracks[0].position - truth, axis=-1)
    assert np.median(err) < 0.5                          # and it tracks


def test_constant_velocity_with_3d_anchors_and_a_known_height_and_the_smoother():
    anchors = np.column_stack([ANCHORS, [3.0, 0.5, 2.5, 1.0]])
    truth, z = scene(anchors=anchors, height=1.2, runs=2)
    obs = Observation(RangeModel(std_m=0.2), z, Context(points=anchors, height_m=1.2))
    m0 = np.concatenate([truth[:, 0], np.zeros((2, 2))], axis=-1)
    P0 = np.diag([1.0, 1.0, 0.5, 0.5])
    tracks = [pf.run(obs, prior_mean=m0, prior_cov=P0, smooth=True)
              for pf in both(WhiteAccelerationCV(0.1), n_particles=400, seed=3,
                             trajectories=20)]
    assert_same(*tracks)


def test_three_dimensional_positions_and_per_row_noise_agree():
    anchors = np.array([[0, 0, 0], [10, 0, 3], [10, 10, 0], [0, 10, 3], [5, 5, 6.0]])
    g = np.random.default_rng(6)
    truth = np.array([4.0, 6.0, 1.5]) + np.cumsum(0.1 * g.standard_normal((2, 8, 3)), axis=1)
    std = np.where(g.random((2, 8, 5)) < 0.5, 0.05, 0.2)          # a noise per row
    z = np.linalg.norm(truth[..., None, :] - anchors, axis=-1) + std * g.standard_normal(std.shape)
    obs = Observation(RangeModel(std_m=0.1), z, Context(points=anchors), std=std)
    tracks = [pf.run(obs, prior_mean=truth[:, 0], prior_cov=0.1 * np.eye(3))
              for pf in both(RandomWalk(0.01, dim=3), n_particles=600, seed=[2, 3])]
    assert_same(*tracks)


def test_a_model_without_a_compiled_likelihood_runs_its_numpy_definition_on_both():
    truth, z = scene(nlos=True)
    los_nlos = RangeModel(noise=LosNlosRange(0.2, 2.0, 0.7))
    bearing = MinimalBearing(0.05)
    b = np.arctan2(truth[..., None, 1] - ANCHORS[:, 1], truth[..., None, 0] - ANCHORS[:, 0])
    obs = [Observation(los_nlos, z, Context(points=ANCHORS)),
           Observation(bearing, b + 0.05 * np.random.default_rng(1).standard_normal(b.shape),
                       Context(points=ANCHORS))]
    assert not has_compiled_likelihood(los_nlos) and not has_compiled_likelihood(bearing)
    tracks = [pf.run(obs, prior_mean=truth[:, 0], prior_cov=np.eye(2))
              for pf in both(n_particles=300, seed=[1, 2, 3])]
    assert_same(*tracks)


def test_large_filters_draw_in_parts_with_the_same_numbers_on_both_backends():
    k = DRAW_PARALLEL // 2 + 10                          # 2 K numbers per draw: split
    truth, z = scene(runs=1, steps=3)
    obs = Observation(RangeModel(std_m=0.2), z, Context(points=ANCHORS))
    tracks = [pf.run(obs, prior_mean=truth[:, 0], prior_cov=np.eye(2))
              for pf in both(n_particles=k, ess_threshold=1.0, seed=9)]
    assert_same(*tracks)
    draws = [standard_normal(RunGenerators([8, 9], (2,)), (2, k, 2), b)
             for b in ("numba", "numpy")]
    np.testing.assert_array_equal(*draws)
    assert abs(draws[0].mean()) < 0.01 and abs(draws[0].std() - 1.0) < 0.01
    one = standard_normal(RunGenerators([9], (1,)), (1, k, 2), "numba")
    np.testing.assert_array_equal(one[0], draws[0][1])   # a run's draws are its own


@pytest.mark.parametrize("runs", [1, 3, 11])
def test_small_draws_of_each_run_are_numpys_on_both_backends(runs):
    seeds = list(range(20, 20 + runs))
    draws = [standard_normal(RunGenerators(seeds, (runs,)), (runs, 300, 3), b)
             for b in ("numba", "numpy")]
    np.testing.assert_array_equal(*draws)
    one = np.random.default_rng(seeds[-1]).standard_normal((300, 3))
    np.testing.assert_array_equal(draws[0][-1], one)


def test_which_models_have_a_compiled_likelihood():
    assert has_compiled_likelihood(RangeModel(std_m=0.1))
    assert not has_compiled_likelihood(RangeModel(std_m=0.1, anchor_bias=True))
    assert not has_compiled_likelihood(RangeModel(noise=LosNlosRange(0.1, 1.0, 0.5)))
    assert not has_compiled_likelihood(MinimalBearing(0.1))


def test_bad_backend_is_refused():
    with pytest.raises(ConfigError, match="backend"):
        ParticleFilter(RandomWalk(0.1), backend="cuda")


def test_missing_numba_is_named_and_numpy_still_runs(monkeypatch):
    monkeypatch.setitem(sys.modules, "numba", None)          # import numba raises ImportError
    monkeypatch.delitem(sys.modules, "radioloc.estimators.pf_compiled", raising=False)
    with pytest.raises(ConfigError, match="numba.*backend='numpy'"):
        ParticleFilter(RandomWalk(0.1), backend="numba")
    truth, z = scene(runs=1, steps=3)
    track = ParticleFilter(RandomWalk(0.2), n_particles=100, backend="numpy").run(
        Observation(RangeModel(std_m=0.2), z, Context(points=ANCHORS)),
        prior_mean=truth[:, 0], prior_cov=np.eye(2))
    assert np.all(np.isfinite(track.position))
