import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.links import gather_packed, pack_mask, scatter_packed
from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.estimators.resampling import SCHEMES, get_scheme
from radioloc.estimators.snapshot_baselines import LocalML, Ransac
from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain
from radioloc.models.motion import InputDriven
from radioloc.sim.highway import HighwayScenario, anchor_layout, simulate

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
    pf = P2PParticleFilter(InputDriven(0.01), model, particles=300, init_std=0.5,
                           reset_std_m=0.05, messages="given")
    res = pf.run(d.ranges, d.truth[:, :, 0], np.random.default_rng(1), anchors=d.anchors,
                 controls=d.ins, given_positions=d.truth[:, :, 1:])
    err = res.error(d.truth[:, :, 1:])
    assert np.all(np.isfinite(err))
    assert err[..., -5:].mean() < 0.05
    assert err[..., -5:].mean() < 0.1 * 0.5
    # with alpha = 1 every link is LOS and detected as such
    det = res.diagnostics["los_detected"]
    assert np.all(det[:, :, -5:] == d.in_range[:, :, -5:])


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
    pf = P2PParticleFilter(InputDriven(0.1), LosNlosRange(), particles=100)
    state = pf.init(np.zeros((1, 2, 2)), rng)
    u = np.array([[[0.2, 0.0], [0.0, 0.2]]])
    ranges = np.full((1, 2, 2), np.nan)
    for _ in range(10):
        state = pf.step(state, ranges, np.zeros((1, 2, 2)), rng, control=u)
    est = pf.estimate(state)
    assert np.all(np.isfinite(est.position))
    np.testing.assert_allclose(est.position, 10 * u, atol=0.8)
    assert not est.diagnostics["los_detected"].any()


def test_filter_bad_input():
    pf = P2PParticleFilter(InputDriven(0.1), LosNlosRange(), particles=10)
    rng = np.random.default_rng(0)
    state = pf.init(np.zeros((1, 2, 2)), rng)
    bad = np.array([[[np.nan, np.inf], [1.0, np.nan]]])
    with pytest.raises(InputError, match="ranges"):
        pf.step(state, bad, np.zeros((1, 2, 2)), rng, control=np.zeros((1, 2, 2)))
    with pytest.raises(InputError, match="ranges"):
        pf.step(state, np.ones((3, 2, 2)), np.zeros((3, 2, 2)), rng, control=np.zeros((1, 2, 2)))
    with pytest.raises(InputError, match="control"):
        pf.step(state, np.full((1, 2, 2), np.nan), np.zeros((1, 2, 2)), rng)
    with pytest.raises(ConfigError, match="backend"):
        P2PParticleFilter(InputDriven(0.1), LosNlosRange(), backend="gpu")
    with pytest.raises(ConfigError, match="messages"):
        P2PParticleFilter(InputDriven(0.1), LosNlosRange(), messages="x")
    with pytest.raises(ConfigError, match="particles"):
        P2PParticleFilter(InputDriven(0.1), LosNlosRange(), particles=0)
    with pytest.raises(ConfigError, match="resampling"):
        P2PParticleFilter(InputDriven(0.1), LosNlosRange(), resampling="bogus")
    with pytest.raises(ConfigError, match="measurement"):
        P2PParticleFilter(InputDriven(0.1), object())
    with pytest.raises(InputError, match="given_positions"):
        P2PParticleFilter(InputDriven(0.1), LosNlosRange(), messages="given").run(
            np.full((1, 2, 3, 2), np.nan), np.zeros((1, 2, 2)), rng, controls=np.zeros((1, 2, 3, 2)))


@pytest.mark.parametrize("messages", ["previous", "extrapolated"])
def test_message_lag_zero_changes_nothing_without_vehicle_links(messages):
    """With no vehicle-to-vehicle range the messages are unused: the lag-free filter takes
    the same draws as the lagged one and gives the same track, bit for bit."""
    _, model, d = _scenario(alpha=0.5, los_std=0.05, ins_std=0.1, steps=12)
    n = d.truth.shape[1]
    ranges = d.ranges.copy()
    ranges[..., :n] = np.nan
    out = {}
    for lag in (1, 0):
        pf = P2PParticleFilter(InputDriven(0.1), model, particles=100, messages=messages,
                               message_lag=lag)
        out[lag] = pf.run(ranges, d.truth[:, :, 0], np.random.default_rng(4),
                          anchors=d.anchors, controls=d.ins).position
    np.testing.assert_array_equal(out[0], out[1])


def test_message_lag_zero_uses_this_steps_estimates():
    """Lag-free messages are the neighbours' estimates of the same step: with exact LOS
    ranges between vehicles moving 1 m per step, they track better than the lagged
    messages (1 m behind), which pull every vehicle toward where its peers were."""
    sc, model, d = _scenario(alpha=1.0, los_std=0.01, ins_std=0.01, steps=20, speed=1.0)
    err = {}
    for lag in (1, 0):
        pf = P2PParticleFilter(InputDriven(0.01), model, particles=200, init_std=0.2,
                               message_lag=lag)
        res = pf.run(d.ranges, d.truth[:, :, 0], np.random.default_rng(2), anchors=d.anchors,
                     controls=d.ins)
        err[lag] = res.error(d.truth[:, :, 1:])[..., 5:].mean()
    assert err[0] < 0.7 * err[1], err          # about 0.49 vs 0.99 m


def test_message_lag_bad_values():
    with pytest.raises(ConfigError, match="message_lag"):
        P2PParticleFilter(InputDriven(0.1), LosNlosRange(), message_lag=2)
    with pytest.raises(ConfigError, match="message_lag"):
        P2PParticleFilter(InputDriven(0.1), LosNlosRange(), messages="given", message_lag=0)


def test_pack_mask_gather_and_scatter():
    m = np.array([[True, False, True, False], [False, False, False, True]])
    links, valid = pack_mask(m)
    assert links.shape == (2, 2)
    np.testing.assert_array_equal(links[0], [0, 2])
    np.testing.assert_array_equal(valid, [[True, True], [True, False]])
    assert links[1, 0] == 3
    vals = np.array([[1.0, 2.0, 3.0, 4.0], [5.0, 6.0, 7.0, 8.0]])
    packed = gather_packed(vals, links)
    np.testing.assert_array_equal(packed[valid], [1.0, 3.0, 8.0])
    back = scatter_packed(packed, links, valid, 4, fill=np.nan)
    np.testing.assert_array_equal(np.isfinite(back), m)
    np.testing.assert_array_equal(back[m], vals[m])
    # fixed width (the GSIC tap refit): the first `width` of argsort(~mask)
    idx, ok = pack_mask(m, 3)
    np.testing.assert_array_equal(idx, np.argsort(~m, axis=-1, kind="stable")[..., :3])
    np.testing.assert_array_equal(ok, np.take_along_axis(m, idx, axis=-1))
    assert pack_mask(np.zeros((3, 0), bool))[0].shape == (3, 0)
    with pytest.raises(InputError, match="width"):
        pack_mask(m, -1)


# ---------------------------------------------------------------- baselines
def test_ml_and_ransac_exact_with_los_ranges():
    rng = np.random.default_rng(4)
    x = rng.uniform([2, 2], [18, 8], size=(5, 2))
    d = np.linalg.norm(x[:, None] - ANCHORS, axis=-1)
    model = LosNlosRange(0.01, 5.0, 0.9)
    ml = LocalML(model, 20.0).locate(d, ANCHORS)
    rs = Ransac(0.05, 20.0).locate(d + np.array([0, 0, 0, 0, 4.0]), ANCHORS)
    np.testing.assert_allclose(ml.position, x, atol=0.01)
    # the Gauss-Newton refit on the inliers is exact with exact inlier ranges
    np.testing.assert_allclose(rs.position, x, atol=1e-8)
    assert rs.converged.all() and np.all(rs.diagnostics["inliers"] == 4)
    one = LocalML(model, 20.0).locate(d[2], ANCHORS)
    np.testing.assert_allclose(one.position, ml.position[2])


def test_highway_simulation_shapes_and_links():
    sc, model, d = _scenario(alpha=0.3, los_std=0.05, ins_std=0.1, runs=2, steps=5)
    j = sc.vehicles + sc.anchors
    assert d.ranges.shape == (2, sc.vehicles, 5, j) and d.truth.shape == (2, sc.vehicles, 6, 2)
    assert d.ins.shape == (2, sc.vehicles, 5, 2) and d.los.shape == d.ranges.shape
    assert not d.in_range[:, np.arange(4), :, np.arange(4)].any()
    assert d.node_positions().shape == (2, 5, j, 2)
    np.testing.assert_array_equal(d.node_positions()[:, :, :4], np.moveaxis(d.truth[:, :, 1:], 1, 2))
    # measured ranges sit near the true distances of the links that exist
    dist = np.linalg.norm(d.node_positions()[:, None] - d.truth[:, :, 1:, None], axis=-1)
    ok = d.in_range
    assert np.all(dist[ok] < sc.radius_m)
    assert np.all(d.ranges[ok] - dist[ok] > -0.5)


def test_uniform_anchor_layout_needs_a_generator():
    with pytest.raises(InputError, match="rng"):
        anchor_layout("uniform", 5, 100.0, 20.0)
    a = anchor_layout("uniform", 5, 100.0, 20.0, np.random.default_rng(1))
    b = anchor_layout("uniform", 5, 100.0, 20.0, np.random.default_rng(1))
    np.testing.assert_array_equal(a, b)
    assert a.shape == (5, 2) and np.all((a >= 0) & (a <= [100.0, 20.0]))


def test_ekf_alpha_one_converges_and_batched_equals_one_by_one():
    from radioloc.estimators.ekf_ranging import run_peer_ekf
    from radioloc.estimators.ekf_tracker import RangeEKF
    # slow vehicles: the one-step lag of the neighbours' messages is negligible
    sc, model, d = _scenario(alpha=1.0, los_std=0.01, ins_std=0.01, speed=1e-4, steps=80)
    assert model.moments() == pytest.approx((0.0, 1e-4))
    ekf = RangeEKF(InputDriven(0.01), model, gate=None)
    tr = run_peer_ekf(ekf, d.ranges, d.truth[:, :, 0] + 0.3, init_std_m=0.5, anchors=d.anchors,
                      controls=d.ins)
    assert tr.position.shape == (2, 4, 80, 2)
    err = tr.error(d.truth[:, :, 1:])
    assert err[..., -5:].mean() < 0.05
    one = run_peer_ekf(ekf, d.ranges[1:2], d.truth[1:2, :, 0] + 0.3, init_std_m=0.5,
                       anchors=d.anchors, controls=d.ins[1:2])
    np.testing.assert_allclose(one.position[0], tr.position[1], atol=1e-10)
