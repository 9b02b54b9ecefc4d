"""The generic particle filter (estimators.particle_filter.ParticleFilter) over any
measurement model: known answers, invariants, claimed-covariance consistency, the exact
LOS/NLOS integration against a plain Gaussian model, a model written here, bad input and
degenerate updates."""

import warnings

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.particle_filter import ParticleFilter
from radioloc.estimators.resampling import stratified
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, Observation
from radioloc.models.motion import RandomWalk, WhiteAccelerationCV
from radioloc.models.ranging import RangeModel

from model_cases import MinimalBearing

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 20.0], [0.0, 20.0]])


def _track(T, runs=None, dt=1.0, start=(5.0, 5.0), velocity=(0.4, 0.25)):
    """Straight tracks (runs, T, 2) and the times."""
    t = np.arange(T) * dt
    xy = np.asarray(start) + t[:, None] * np.asarray(velocity)
    return (xy if runs is None else np.broadcast_to(xy, (runs, T, 2))), t


def _ranges(truth, noise_std, rng, anchors=ANCHORS):
    d = np.linalg.norm(truth[..., None, :] - anchors, axis=-1)
    return d + noise_std * rng.standard_normal(d.shape)


def _prior(start=(5.0, 5.0), std=1.0):
    return np.array([*start, 0.0, 0.0]), np.diag([std**2, std**2, 1.0, 1.0])



@pytest.mark.parametrize("model", [RangeModel(std_m=0.01),
                                   RangeModel(noise=LosNlosRange(0.01, 3.0, 0.999))],
                         ids=["gaussian", "los-nlos"])
def test_near_zero_noise_converges_to_the_truth(model):
    rng = np.random.default_rng(0)
    truth, t = _track(30)
    z = _ranges(truth, 0.01, rng)
    m0, P0 = _prior()
    pf = ParticleFilter(WhiteAccelerationCV(0.01), n_particles=1000, seed=3)
    track = pf.run(Observation(model, z, Context(points=ANCHORS)), t, prior_mean=m0,
                   prior_cov=P0)
    err = np.linalg.norm(track.position - truth, axis=-1)
    assert err[-10:].max() < 0.05
    assert track.position.shape == (30, 2) and track.covariance.shape == (30, 2, 2)
    assert np.all(np.isfinite(track.diagnostics["ess"]))


def test_three_dimensional_static_target():
    rng = np.random.default_rng(1)
    anchors = np.array([[0, 0, 0], [10, 0, 3], [10, 10, 0], [0, 10, 3], [5, 5, 6.0]])
    truth = np.array([4.0, 6.0, 1.5])
    z = _ranges(np.broadcast_to(truth, (20, 3)), 0.02, rng, anchors)
    pf = ParticleFilter(RandomWalk(1e-4, dim=3), n_particles=2000, seed=0, roughening=0.2)
    track = pf.run(Observation(RangeModel(std_m=0.02), z, Context(points=anchors)),
                   prior_mean=[5.0, 5.0, 2.0], prior_cov=np.eye(3))
    assert np.linalg.norm(track.position[-1] - truth) < 0.05


def _batch_case():
    rng = np.random.default_rng(2)
    truth, t = _track(15, runs=3)
    noise = LosNlosRange(0.1, 2.0, 0.7)
    los = rng.random((3, 15, 4)) < 0.7
    d = np.linalg.norm(truth[..., None, :] - ANCHORS, axis=-1)
    z = noise.sample(d, los, rng)
    z[1, 4:7, 2] = np.nan                                   # missing rows are skipped
    m0, P0 = _prior()
    return z, t, m0, P0, RangeModel(noise=noise), truth


def test_batch_equals_one_by_one_with_the_same_seed_per_run():
    z, t, m0, P0, model, _ = _batch_case()
    seeds = np.array([11, 12, 13])
    kw = dict(n_particles=300, ess_threshold=0.6, roughening=0.1)
    ctx = Context(points=ANCHORS)
    batch = ParticleFilter(WhiteAccelerationCV(0.05), seed=seeds, **kw).run(
        Observation(model, z, ctx), t, prior_mean=m0, prior_cov=P0)
    for i in range(3):
        one = ParticleFilter(WhiteAccelerationCV(0.05), seed=seeds[i:i + 1], **kw).run(
            Observation(model, z[i:i + 1], ctx), t, prior_mean=m0, prior_cov=P0)
        np.testing.assert_allclose(batch.position[i], one.position[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(batch.covariance[i], one.covariance[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(batch.diagnostics["ess"][i], one.diagnostics["ess"][0],
                                   rtol=1e-9)


def test_same_seed_same_output_and_another_seed_differs():
    z, t, m0, P0, model, _ = _batch_case()
    obs = Observation(model, z, Context(points=ANCHORS))
    runs = [ParticleFilter(WhiteAccelerationCV(0.05), n_particles=200, seed=s).run(
        obs, t, prior_mean=m0, prior_cov=P0) for s in (4, 4, 5)]
    np.testing.assert_array_equal(runs[0].position, runs[1].position)
    np.testing.assert_array_equal(runs[0].covariance, runs[1].covariance)
    assert not np.array_equal(runs[0].position, runs[2].position)


def test_step_is_pure_and_run_is_a_loop_of_step():
    z, t, m0, P0, model, _ = _batch_case()
    ctx = Context(points=ANCHORS)
    pf = ParticleFilter(WhiteAccelerationCV(0.05), n_particles=200, seed=[1, 2, 3])
    track = pf.run(Observation(model, z, ctx), t, prior_mean=m0, prior_cov=P0)
    state = pf.init(m0, P0, Observation(model, z, ctx), time=t[0], batch_shape=(3,))
    first = None
    for k in range(len(t)):
        state = pf.step(state, Observation(model, z[:, k], ctx), dt=t[k] - t[k - 1] if k else 0.0)
        if k == 0:
            first = state
        np.testing.assert_allclose(pf.estimate(state).position, track.position[:, k], atol=1e-12)
    again = pf.step(first, Observation(model, z[:, 1], ctx), dt=1.0)
    np.testing.assert_allclose(pf.estimate(again).position, track.position[:, 1], atol=1e-12)


def test_translating_the_scene_translates_the_estimate():
    z, t, m0, P0, model, _ = _batch_case()
    shift = np.array([130.0, -45.0])
    pf = ParticleFilter(WhiteAccelerationCV(0.05), n_particles=300, seed=7)
    a = pf.run(Observation(model, z, Context(points=ANCHORS)), t, prior_mean=m0, prior_cov=P0)
    m1 = m0.copy()
    m1[:2] += shift
    b = pf.run(Observation(model, z, Context(points=ANCHORS + shift)), t, prior_mean=m1,
               prior_cov=P0)
    np.testing.assert_allclose(b.position, a.position + shift, atol=1e-6)
    np.testing.assert_allclose(b.covariance, a.covariance, atol=1e-6)


def test_claimed_covariance_is_consistent_on_a_simulated_track():
    """Position NEES averaged over 20 runs x 30 steps near its dimension 2."""
    rng = np.random.default_rng(5)
    runs, T, q = 20, 40, 0.05
    motion = WhiteAccelerationCV(q)
    x0 = np.array([5.0, 5.0, 0.4, 0.2])
    states = [np.broadcast_to(x0, (runs, 4))]
    for _ in range(T - 1):
        states.append(motion.sample(states[-1], 1.0, rng))
    truth = np.stack(states, axis=1)[..., :2]
    z = _ranges(truth, 0.3, rng)
    P0 = np.diag([1.0, 1.0, 0.25, 0.25])
    m0 = x0 + rng.multivariate_normal(np.zeros(4), P0, runs)
    track = ParticleFilter(motion, n_particles=1000, seed=2).run(
        Observation(RangeModel(std_m=0.3), z, Context(points=ANCHORS)), np.arange(T, dtype=float),
        prior_mean=m0, prior_cov=P0)
    e = (track.position - truth)[:, 10:]
    nees = np.einsum("...i,...ij,...j->...", e, np.linalg.inv(track.covariance[:, 10:]), e)
    assert 1.4 < nees.mean() < 3.0, nees.mean()


def test_los_nlos_integrated_beats_a_gaussian_model_with_30_percent_nlos():
    """30 % NLOS (exponential excess of mean 3 m): the Rao-Blackwellised LOS/NLOS filter
    (measured 0.11 m mean error, seed 8) against the same filter with a Gaussian of the
    mixture's standard deviation (measured 1.11 m)."""
    rng = np.random.default_rng(8)
    runs, T = 4, 40
    truth, t = _track(T, runs=runs, dt=0.5)
    noise = LosNlosRange(0.1, 3.0, 0.7)
    los = noise.chain.sample(T, (runs, 4), rng).transpose(1, 0, 2)
    z = noise.sample(np.linalg.norm(truth[..., None, :] - ANCHORS, axis=-1), los, rng)
    assert 0.2 < 1 - los.mean() < 0.4
    m0, P0 = _prior()
    err = {}
    for name, model in [("rb", RangeModel(noise=noise)),
                        ("gauss", RangeModel(std_m=float(np.sqrt(noise.moments()[1]))))]:
        track = ParticleFilter(WhiteAccelerationCV(0.1), n_particles=1000, seed=1).run(
            Observation(model, z, Context(points=ANCHORS)), t, prior_mean=m0, prior_cov=P0)
        err[name] = float(np.linalg.norm(track.position - truth, axis=-1)[:, 5:].mean())
    assert err["rb"] < 0.25
    assert err["rb"] < 0.4 * err["gauss"], err


def test_a_model_with_only_predict_and_std_tracks_a_target():
    rng = np.random.default_rng(4)
    stations = np.array([[0.0, 0.0], [30.0, 0.0], [15.0, 30.0]])
    truth, t = _track(30)
    d = truth[:, None, :] - stations
    z = np.arctan2(d[..., 1], d[..., 0]) + 0.02 * rng.standard_normal((30, 3))
    z = (z + np.pi) % (2 * np.pi) - np.pi
    m0, P0 = _prior()
    track = ParticleFilter(WhiteAccelerationCV(0.05), n_particles=1000, seed=0).run(
        Observation(MinimalBearing(0.02), z, Context(points=stations)), t, prior_mean=m0, prior_cov=P0)
    assert np.linalg.norm(track.position - truth, axis=-1)[10:].mean() < 0.3


def test_two_observations_in_one_step_and_the_smoother():
    rng = np.random.default_rng(6)
    truth, t = _track(25, runs=2)
    stations = np.array([[0.0, 0.0], [30.0, 0.0]])
    d = truth[..., None, :] - stations
    bearings = np.arctan2(d[..., 1], d[..., 0]) + 0.05 * rng.standard_normal((2, 25, 2))
    ranges = _ranges(truth, 0.5, rng)
    obs = [Observation(RangeModel(std_m=0.5), ranges, Context(points=ANCHORS)),
           Observation(MinimalBearing(0.02), bearings, Context(points=stations), std=0.05)]
    m0, P0 = _prior()
    pf = ParticleFilter(WhiteAccelerationCV(0.05), n_particles=500, seed=0)
    filt = pf.run(obs, t, prior_mean=m0, prior_cov=P0)
    smooth = pf.run(obs, t, prior_mean=m0, prior_cov=P0, smooth=True)
    assert smooth.position.shape == filt.position.shape == (2, 25, 2)
    e_f = np.linalg.norm(filt.position - truth, axis=-1).mean()
    e_s = np.linalg.norm(smooth.position - truth, axis=-1).mean()
    assert e_s < e_f < 0.4
    # at the last step the smoother draws from the filter's weighted particles
    np.testing.assert_allclose(smooth.position[:, -1], filt.position[:, -1], atol=0.1)
    assert smooth.diagnostics["state"].shape == (2, 25, 4)


def test_resampling_function_and_threshold_are_used():
    z, t, m0, P0, model, truth = _batch_case()
    obs = Observation(model, z, Context(points=ANCHORS))
    always = ParticleFilter(WhiteAccelerationCV(0.05), n_particles=300, resample=stratified,
                            ess_threshold=1.0, seed=0).run(obs, t, prior_mean=m0, prior_cov=P0)
    never = ParticleFilter(WhiteAccelerationCV(0.05), n_particles=300, ess_threshold=0.0,
                           seed=0).run(obs, t, prior_mean=m0, prior_cov=P0)
    ess_a, ess_n = always.diagnostics["ess"], never.diagnostics["ess"]
    assert np.all((ess_a > 0) & (ess_a <= 300 + 1e-9))
    # without resampling the weights degenerate
    assert ess_n[..., -1].mean() < ess_a[..., -1].mean()
    assert np.linalg.norm(always.position - truth, axis=-1)[:, 5:].mean() < 0.3


def test_ranges_no_particle_explains_reset_and_recover_without_warnings():
    """Prior 30 m from the target, 5 cm ranges: every likelihood underflows at first."""
    rng = np.random.default_rng(9)
    truth = np.array([12.0, 14.0])
    z = _ranges(np.broadcast_to(truth, (40, 2)), 0.05, rng)
    pf = ParticleFilter(RandomWalk(0.01), n_particles=500, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        track = pf.run(Observation(RangeModel(std_m=0.05), z, Context(points=ANCHORS)),
                       prior_mean=[-10.0, -8.0], prior_cov=np.eye(2))
    assert np.all(np.isfinite(track.position)) and np.all(np.isfinite(track.covariance))
    resets = track.diagnostics["resets"]
    assert resets[0] == 1 and resets[-1] >= 1
    assert np.linalg.norm(track.position[-1] - truth) < 0.1


def test_bad_input_names_the_argument():
    z, t, m0, P0, model, _ = _batch_case()
    obs = Observation(model, z, Context(points=ANCHORS))
    pf = ParticleFilter(WhiteAccelerationCV(0.05), n_particles=50)
    with pytest.raises(InputError, match="prior_mean"):
        pf.run(obs, t, prior_mean=m0[:3], prior_cov=P0)
    with pytest.raises(InputError, match="prior_cov"):
        pf.run(obs, t, prior_mean=m0, prior_cov=np.eye(3))
    with pytest.raises(InputError, match="prior_cov"):
        pf.run(obs, t, prior_mean=m0, prior_cov=-np.eye(4))
    with pytest.raises(InputError, match="observations"):
        pf.run([z], t, prior_mean=m0, prior_cov=P0)
    with pytest.raises(InputError, match="time"):
        pf.run(obs, t[:-1], prior_mean=m0, prior_cov=P0)
    with pytest.raises(InputError, match="time"):
        pf.run(obs, t[::-1], prior_mean=m0, prior_cov=P0)
    with pytest.raises(InputError, match="seed"):
        ParticleFilter(WhiteAccelerationCV(0.05), seed=[1, 2]).run(obs, t, prior_mean=m0,
                                                                   prior_cov=P0)
    with pytest.raises(ConfigError, match="n_particles"):
        ParticleFilter(WhiteAccelerationCV(0.05), n_particles=0)
    with pytest.raises(ConfigError, match="ess_threshold"):
        ParticleFilter(WhiteAccelerationCV(0.05), ess_threshold=-0.1)
    with pytest.raises(ConfigError, match="resample"):
        ParticleFilter(WhiteAccelerationCV(0.05), resample="bogus")
    with pytest.raises(ConfigError, match="seed"):
        ParticleFilter(WhiteAccelerationCV(0.05), seed=-1)


def test_mode_update_is_the_exact_hmm_filter():
    """Two steps of a two-state chain: the recursion (predict through P, multiply by the
    likelihood, normalise; log-likelihood of the row) equals enumerating the four paths."""
    from radioloc.estimators.particle_filter import mode_update

    P = np.array([[0.9, 0.1], [0.3, 0.7]])
    pi = np.array([0.25, 0.75])
    lik = np.array([[0.2, 1.5], [2.0, 0.1]])            # p(z_t | state), t = 0, 1
    ll0, post0 = mode_update(pi, np.log(lik[0]))
    ll1, post1 = mode_update(post0 @ P, np.log(lik[1]))
    joint = pi[:, None] * lik[0][:, None] * P * lik[1][None, :]     # (s0, s1)
    np.testing.assert_allclose(ll0 + ll1, np.log(joint.sum()), rtol=1e-12)
    np.testing.assert_allclose(post1, joint.sum(axis=0) / joint.sum(), rtol=1e-12)
    # a row no state explains keeps its prior and contributes -inf, without a warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ll, post = mode_update(pi, np.array([-np.inf, -np.inf]))
    assert ll == -np.inf and np.array_equal(post, pi)
