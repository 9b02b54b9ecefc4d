import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.p2p_particle import (ParticleFilterSettings, _link_log_phi_and_weights,
                                              _posterior_and_resample,
                                              compact_links, filter_step, init_filter, track)
from radioloc.estimators.resampling import SCHEMES, get_scheme
from radioloc.estimators.snapshot_baselines import local_ml, ransac
from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain
from radioloc.sim.highway import HighwayScenario, simulate

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 10.0], [20.0, 10.0], [10.0, 5.0]])


def _scenario(alpha, los_std, ins_std, runs=2, steps=25, seed=0, speed=0.2):
    sc = HighwayScenario(vehicles=4, anchors=6, steps=steps, length_m=30.0, width_m=12.0, speed_m=speed,
                         start_width_m=5.0, curve_amplitude_m=1.0, ins_std_m=ins_std,
                         layout="centre")
    model = LosNlosRange(los_std, 5.0, alpha)
    return sc, model, simulate(sc, model, runs, np.random.default_rng(seed))


# ---------------------------------------------------------------- resampling
@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31), k=st.integers(1, 40), scheme=st.sampled_from(sorted(SCHEMES)))
def test_resampling_indices_valid_and_keep_dominant_particle(seed, k, scheme):
    rng = np.random.default_rng(seed)
    w = rng.random((3, 2, k)) ** 4
    idx = get_scheme(scheme)(w, rng)
    assert idx.shape == w.shape and idx.min() >= 0 and idx.max() < k
    # a particle with zero weight is never chosen
    w2 = w.copy()
    if k > 1:
        w2[..., -1] = 0.0
        assert not np.any(get_scheme(scheme)(w2, rng) == k - 1)


@pytest.mark.parametrize("scheme", sorted(SCHEMES))
def test_resampling_unbiased(scheme):
    rng = np.random.default_rng(3)
    w = rng.random((4, 9))
    w /= w.sum(-1, keepdims=True)
    counts = np.zeros_like(w)
    reps = 3000
    for _ in range(reps):
        idx = get_scheme(scheme)(w, rng)
        for r in range(4):
            counts[r] += np.bincount(idx[r], minlength=9)
    np.testing.assert_allclose(counts / reps, 9 * w, atol=0.1)


def test_low_variance_schemes_keep_floor_copies():
    w = np.array([[0.5, 0.25, 0.125, 0.125]])
    for s in ("systematic", "residual"):
        c = np.bincount(get_scheme(s)(w, np.random.default_rng(0))[0], minlength=4)
        assert np.all(c >= np.floor(4 * w[0])) and c.sum() == 4


def test_resampling_bad_input():
    with pytest.raises(InputError, match="weights"):
        get_scheme("systematic")(np.array([[0.0, 0.0]]), np.random.default_rng(0))
    with pytest.raises(ConfigError, match="resampling"):
        get_scheme("bogus")


# ---------------------------------------------------------------- filter
def test_alpha_one_tiny_noise_converges_to_truth():
    sc, model, d = _scenario(alpha=1.0, los_std=0.01, ins_std=0.01)
    s = ParticleFilterSettings(particles=300, ins_std_m=0.01, init_std_m=0.5, reset_std_m=0.05)
    res = track(d.truth[:, 0], d.ins, d.ranges, d.in_range, d.anchors, model, s,
                np.random.default_rng(1), messages="given", given_positions=d.truth[:, 1:])
    err = np.linalg.norm(res.estimate - d.truth[:, 1:], axis=-1)
    assert np.all(np.isfinite(err))
    assert err[:, -5:].mean() < 0.05
    assert err[:, -5:].mean() < 0.1 * s.init_std_m
    # with alpha = 1 every link is LOS and detected as such
    assert np.all(res.los_detected[:, -5:] == d.in_range[:, -5:])


def test_numba_kernel_equals_numpy_and_batched_equals_one_by_one():
    rng = np.random.default_rng(5)
    b, k, l = (2, 3), 50, 6
    particles = rng.normal(size=b + (k, 2)) * 3
    node_xy = rng.normal(size=b + (l, 2)) * 5
    th = rng.uniform(0, 12, size=b + (l,))
    valid = rng.random(b + (l,)) < 0.7
    where_prev = np.where(rng.random(b + (l,)) < 0.5, rng.integers(0, 4, b + (l,)), -1)
    prev = np.log(rng.dirichlet([1, 1], size=b + (k, 4)))
    model = LosNlosRange(0.05, 5.0, 0.3)
    chain = StickyLinkChain(0.3)
    ref_phi, ref_w = _link_log_phi_and_weights(particles, node_xy, th, valid, where_prev, prev,
                                               model, chain, "numpy")
    phi, w = _link_log_phi_and_weights(particles, node_xy, th, valid, where_prev, prev, model, chain, "numba")
    np.testing.assert_allclose(w, ref_w, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(np.where(valid[..., None, :, None], phi, 0),
                               np.where(valid[..., None, :, None], ref_phi, 0), rtol=1e-9, atol=1e-9)
    one = _link_log_phi_and_weights(particles[1, 2], node_xy[1, 2], th[1, 2], valid[1, 2],
                                    where_prev[1, 2], prev[1, 2], model, chain, "numba")[1]
    np.testing.assert_allclose(one, w[1, 2])
    idx = rng.integers(0, k, b + (k,))
    post_ref, res_ref = _posterior_and_resample(ref_phi, valid, idx, "numpy")
    post, res = _posterior_and_resample(phi, valid, idx, "numba")
    np.testing.assert_allclose(post, post_ref, rtol=1e-9)
    np.testing.assert_allclose(res, res_ref, rtol=1e-9, atol=1e-12)


def test_phi_without_history_is_prior_times_likelihood():
    chain = StickyLinkChain(0.2)
    from radioloc.estimators.p2p_particle import link_log_phi
    ll = np.log(np.array([[0.3, 2.0]]))
    out = link_log_phi(ll, np.zeros((1, 2)), np.array([False]), chain)
    np.testing.assert_allclose(np.exp(out), [[0.8 * 0.3, 0.2 * 2.0]])
    prev = np.log(np.array([[0.25, 0.75]]))
    out = link_log_phi(ll, prev, np.array([True]), chain)
    pred = np.array([0.25, 0.75]) @ chain.transition
    np.testing.assert_allclose(np.exp(out), [pred * [0.3, 2.0]])


def test_vehicle_without_neighbours_keeps_predicting():
    rng = np.random.default_rng(2)
    s = ParticleFilterSettings(particles=100)
    state = init_filter(np.zeros((1, 2, 2)), s, rng)
    u = np.array([[[0.2, 0.0], [0.0, 0.2]]])
    ranges = np.full((1, 2, 2), np.nan)
    no_links = np.zeros((1, 2, 2), dtype=bool)
    model = LosNlosRange()
    for _ in range(10):
        state, out = filter_step(state, u, ranges, no_links, np.zeros((1, 2, 2)), model, s, rng)
    assert np.all(np.isfinite(out.estimate))
    np.testing.assert_allclose(out.estimate, 10 * u, atol=0.8)
    assert not out.los_detected.any()


def test_filter_bad_input():
    s = ParticleFilterSettings(particles=10)
    rng = np.random.default_rng(0)
    state = init_filter(np.zeros((1, 2, 2)), s, rng)
    mask = np.array([[[False, True], [True, False]]])
    with pytest.raises(InputError, match="ranges"):
        filter_step(state, np.zeros((1, 2, 2)), np.full((1, 2, 2), np.nan), mask,
                    np.zeros((1, 2, 2)), LosNlosRange(), s, rng)
    with pytest.raises(InputError, match="in_range"):
        filter_step(state, np.zeros((1, 2, 2)), np.ones((3, 2, 2)), np.ones((3, 2, 2), bool),
                    np.zeros((3, 2, 2)), LosNlosRange(), s, rng)
    with pytest.raises(ConfigError, match="kernel"):
        ParticleFilterSettings(kernel="gpu")
    with pytest.raises(ConfigError, match="messages"):
        track(np.zeros((1, 2, 2)), np.zeros((1, 3, 2, 2)), np.zeros((1, 3, 2, 2)),
              np.zeros((1, 3, 2, 2), bool), np.zeros((0, 2)), LosNlosRange(), s, rng, messages="x")


def test_compact_links():
    m = np.array([[True, False, True, False], [False, False, False, True]])
    links, valid = compact_links(m)
    assert links.shape == (2, 2)
    np.testing.assert_array_equal(links[0], [0, 2])
    np.testing.assert_array_equal(valid, [[True, True], [True, False]])
    assert links[1, 0] == 3


# ---------------------------------------------------------------- baselines
def test_ml_and_ransac_exact_with_los_ranges():
    rng = np.random.default_rng(4)
    x = rng.uniform([2, 2], [18, 8], size=(5, 2))
    d = np.linalg.norm(x[:, None] - ANCHORS, axis=-1)
    valid = np.ones(d.shape, bool)
    model = LosNlosRange(0.01, 5.0, 0.9)
    c = np.broadcast_to(ANCHORS, (5,) + ANCHORS.shape)
    ml = local_ml(d, c, valid, model, 20.0)
    rs = ransac(d + np.array([0, 0, 0, 0, 4.0]), c, valid, 0.05, 20.0)
    np.testing.assert_allclose(ml, x, atol=0.01)
    np.testing.assert_allclose(rs, x, atol=0.01)
    one = local_ml(d[2], c[2], valid[2], model, 20.0)
    np.testing.assert_allclose(one, ml[2])


def test_highway_simulation_shapes_and_links():
    sc, model, d = _scenario(alpha=0.3, los_std=0.05, ins_std=0.1, runs=2, steps=5)
    j = sc.vehicles + sc.anchors
    assert d.ranges.shape == (2, 5, sc.vehicles, j)
    assert not d.in_range[..., np.arange(4), np.arange(4)].any()
    assert np.all(np.isfinite(d.ranges[d.in_range])) and np.all(np.isnan(d.ranges[~d.in_range]))


def test_ekf_alpha_one_converges_and_batched_equals_one_by_one():
    from radioloc.estimators.ekf_ranging import ekf_track, moment_matched
    # slow vehicles: the one-step lag of the neighbours' messages is negligible
    sc, model, d = _scenario(alpha=1.0, los_std=0.01, ins_std=0.01, speed=1e-4, steps=80)
    assert moment_matched(model) == pytest.approx((0.0, 1e-4))
    est = ekf_track(d.truth[:, 0] + 0.3, d.ins, d.ranges, d.in_range, d.anchors, model, 0.01, 0.5)
    err = np.linalg.norm(est - d.truth[:, 1:], axis=-1)
    assert err[:, -5:].mean() < 0.05
    one = ekf_track(d.truth[1:2, 0] + 0.3, d.ins[1:2], d.ranges[1:2], d.in_range[1:2], d.anchors,
                    model, 0.01, 0.5)
    np.testing.assert_allclose(one[0], est[1], atol=1e-10)
