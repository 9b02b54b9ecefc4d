"""P2PParticleFilter.run on its own loop (inputs checked once, work arrays reused, the
bootstrap case on one compiled kernel per step) gives exactly what init, step and estimate
give step by step: the same draws in the same order and the same numbers, bit for bit."""

import numpy as np
import pytest

from radioloc.core.errors import InputError
from radioloc.core.results import track_from_steps
from radioloc.estimators import p2p_particle as pp
from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import ConstantVelocity, InputDriven, RandomWalk

ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]])


def run_by_steps(pf, ranges, initial, rng, anchors, controls=None, time=None, given=None):
    """The loop of ``run`` written with the public init, step and estimate."""
    r = np.asarray(ranges, dtype=float)
    n_veh, T = r.shape[-3:-1]
    t = np.arange(T, dtype=float) if time is None else np.asarray(time, dtype=float)
    dts = np.diff(t, prepend=t[0])
    state = pf.init(initial, rng, time=t[0])
    batch = state.batch_shape[:-1]
    a = np.broadcast_to(anchors, batch + anchors.shape[-2:])
    estimates = []
    for k in range(T):
        uk = None if controls is None else controls[..., k, :]
        if pf.messages == "previous":
            peers = state.mean[..., :2]
        elif pf.messages == "extrapolated":
            peers = pf.motion.predict(state.mean, dts[k], control=uk)[..., :2]
        else:
            peers = given[..., k, :]
        nodes = np.concatenate([np.broadcast_to(peers, batch + (n_veh, 2)), a], axis=-2)
        state = pf.step(state, r[..., k, :], nodes, rng, control=uk, dt=dts[k])
        estimates.append(pf.estimate(state))
    return track_from_steps(estimates, t)


def assert_same_track(a, b):
    for x, y in [(a.position, b.position), (a.covariance, b.covariance), (a.time, b.time)]:
        assert x.dtype == y.dtype and x.shape == y.shape
        assert np.array_equal(x, y, equal_nan=True)
    assert sorted(a.diagnostics) == sorted(b.diagnostics)
    for key in a.diagnostics:
        x, y = np.asarray(a.diagnostics[key]), np.asarray(b.diagnostics[key])
        assert x.dtype == y.dtype and x.shape == y.shape, key
        assert np.array_equal(x, y, equal_nan=True), key


def scene(runs=2, vehicles=3, steps=9, seed=5):
    """Ranges (runs, N, T, N + 4) to the vehicles' truth and the anchors, some missing."""
    g = np.random.default_rng(seed)
    truth = 15.0 + np.cumsum(0.5 * g.standard_normal((runs, vehicles, steps + 1, 2)), axis=-2)
    nodes = np.concatenate([np.broadcast_to(truth[:, None, :, 1:], (runs, vehicles) + truth[:, :, 1:].shape[1:]),
                            np.broadcast_to(ANCHORS[:, None], (runs, vehicles, 4, steps, 2))], axis=2)
    d = np.linalg.norm(truth[:, :, None, 1:] - nodes, axis=-1)          # (runs, N, J, T)
    r = np.moveaxis(d + 0.2 * g.standard_normal(d.shape), 2, 3)          # (runs, N, T, J)
    idx = np.arange(vehicles)
    r[:, idx, :, idx] = np.nan                                           # a vehicle to itself
    r[g.random(r.shape) < 0.15] = np.nan
    r[0, 1, 3, :] = np.nan                                              # a step with no link
    return truth, r


@pytest.fixture
def count_fast(monkeypatch):
    calls = []
    orig = P2PParticleFilter._run_bootstrap

    def wrapped(self, *args):
        calls.append(1)
        return orig(self, *args)
    monkeypatch.setattr(P2PParticleFilter, "_run_bootstrap", wrapped)
    return calls


@pytest.mark.parametrize("messages", ["previous", "extrapolated", "given"])
def test_bootstrap_run_equals_steps(messages, count_fast):
    truth, r = scene()
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.05, 1.0, 1.0), particles=700,
                           reset_fraction=0.2, messages=messages)
    time = np.array([0.0, 0.5, 1.5, 1.5, 2.0, 3.0, 3.25, 4.0, 5.0])
    given = truth[:, :, 1:] + 0.1
    g1, g2 = np.random.default_rng(11), np.random.default_rng(11)
    a = pf.run(r, truth[:, :, 0], g1, anchors=ANCHORS, time=time, given_positions=given)
    b = run_by_steps(pf, r, truth[:, :, 0], g2, ANCHORS, time=time, given=given)
    assert count_fast, "the bootstrap loop of run was not taken"
    assert_same_track(a, b)
    assert a.diagnostics["resets"][..., -1].sum() > 0          # resets are exercised
    assert g1.bit_generator.state == g2.bit_generator.state       # the same draws


def test_bootstrap_run_with_controls_equals_steps(count_fast):
    truth, r = scene(seed=6)
    g = np.random.default_rng(1)
    controls = 0.1 * g.standard_normal(r.shape[:-1] + (2,))
    pf = P2PParticleFilter(InputDriven(0.2), LosNlosRange(0.3, 1.0, 1.0), particles=500,
                           messages="extrapolated")
    g1, g2 = np.random.default_rng(3), np.random.default_rng(3)
    a = pf.run(r, truth[:, :, 0], g1, anchors=ANCHORS, controls=controls)
    b = run_by_steps(pf, r, truth[:, :, 0], g2, ANCHORS, controls=controls)
    assert count_fast
    assert_same_track(a, b)
    assert g1.bit_generator.state == g2.bit_generator.state


@pytest.mark.parametrize("kind", ["nlos", "stratified", "cv", "numpy"])
def test_general_run_equals_steps(kind, count_fast):
    truth, r = scene(vehicles=2, steps=6, seed=7)
    motion, model, kw = RandomWalk(0.25), LosNlosRange(0.2, 2.0, 0.6), {}
    if kind == "stratified":
        model, kw = LosNlosRange(0.2, 1.0, 1.0), {"resampling": "stratified"}
    elif kind == "cv":
        motion = ConstantVelocity(0.5)
    elif kind == "numpy":
        model, kw = LosNlosRange(0.2, 1.0, 1.0), {"kernel": "numpy"}
    pf = P2PParticleFilter(motion, model, particles=400, reset_fraction=0.2, **kw)
    g1, g2 = np.random.default_rng(4), np.random.default_rng(4)
    a = pf.run(r, truth[:, :, 0], g1, anchors=ANCHORS)
    b = run_by_steps(pf, r, truth[:, :, 0], g2, ANCHORS)
    assert not count_fast
    assert_same_track(a, b)
    assert g1.bit_generator.state == g2.bit_generator.state


def test_init_draws():
    """init: initial + init_std z with z the generator's standard normals."""
    pf = P2PParticleFilter(ConstantVelocity(0.5), LosNlosRange(0.2, 1.0, 1.0), particles=50,
                           init_std=[1.0, 2.0, 0.5, 0.25])
    x0 = np.array([[3.0, 4.0], [5.0, -6.0]])
    st = pf.init(x0, np.random.default_rng(9))
    z = np.random.default_rng(9).standard_normal((2, 50, 4))
    v0 = np.concatenate([x0, np.zeros((2, 2))], axis=-1)
    assert np.array_equal(st.particles, v0[:, None, :] + np.array([1.0, 2.0, 0.5, 0.25]) * z)


@pytest.mark.parametrize("bootstrap", [True, False])
def test_run_bad_ranges_raise(bootstrap):
    truth, r = scene(runs=1, vehicles=2, steps=4)
    model = LosNlosRange(0.2, 1.0, 1.0) if bootstrap else LosNlosRange(0.2, 1.0, 0.5)
    pf = P2PParticleFilter(RandomWalk(0.25), model, particles=100)
    bad = r.copy()
    bad[0, 1, 2, 3] = np.inf
    with pytest.raises(InputError, match="ranges: infinite"):
        pf.run(bad, truth[:, :, 0], np.random.default_rng(0), anchors=ANCHORS)
    with pytest.raises(InputError, match="ranges: leading shape"):
        pf.run(r, np.broadcast_to(truth[:, :, 0], (3, 2, 2)), np.random.default_rng(0),
               anchors=ANCHORS)
    with pytest.raises(InputError, match="control"):
        P2PParticleFilter(InputDriven(0.2), model, particles=100).run(
            r, truth[:, :, 0], np.random.default_rng(0), anchors=ANCHORS)


@pytest.mark.parametrize("bootstrap", [True, False])
def test_run_nonfinite_peer_raises(bootstrap):
    """A neighbour placed at a non-finite position is an InputError."""
    truth, r = scene(runs=1, vehicles=2, steps=4)
    r[0, 0, :, 1] = 5.0                              # vehicle 0 hears vehicle 1 at every step
    model = LosNlosRange(0.2, 1.0, 1.0) if bootstrap else LosNlosRange(0.2, 1.0, 0.5)
    pf = P2PParticleFilter(RandomWalk(0.25), model, particles=100, messages="given")
    given = np.broadcast_to(truth[:, :, 1:], r.shape[:-1] + (2,)).copy()
    given[0, 1, 2] = np.nan
    with pytest.raises(InputError, match="given_positions: non-finite"):
        pf.run(r, truth[:, :, 0], np.random.default_rng(0), anchors=ANCHORS,
               given_positions=given)


@pytest.mark.parametrize("alpha", [1.0, 0.6])
def test_step_leaves_earlier_states_alone(alpha):
    """step keeps work arrays between calls; the states it returned are not among them: a
    later step (and a run) changes no earlier state, and the same step repeated from the
    same state and generator state gives the same state."""
    truth, r = scene(vehicles=2, steps=4, seed=8)
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.2, 1.0, alpha), particles=300)
    nodes = np.concatenate([truth[:, :, 1], np.broadcast_to(ANCHORS, (2, 4, 2))], axis=1)
    st0 = pf.init(truth[:, :, 0], np.random.default_rng(1))
    st1 = pf.step(st0, r[:, :, 0], nodes, np.random.default_rng(2))
    kept = {f: np.array(getattr(st1, f), copy=True) for f in ("particles", "link_los", "mean",
                                                               "ancestors")}
    again = pf.step(st0, r[:, :, 0], nodes, np.random.default_rng(2))
    st2 = pf.step(st1, r[:, :, 1], nodes, np.random.default_rng(3))
    pf.run(r, truth[:, :, 0], np.random.default_rng(4), anchors=ANCHORS)
    for f, v in kept.items():
        assert np.array_equal(getattr(st1, f), v), f
        assert np.array_equal(getattr(again, f), v), f
    assert not np.shares_memory(st2.particles, st1.particles)


def test_runs_repeat():
    """Two runs from the same generator state give the same track (work arrays reused)."""
    truth, r = scene(seed=9)
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.05, 1.0, 1.0), particles=700)
    a = pf.run(r, truth[:, :, 0], np.random.default_rng(5), anchors=ANCHORS)
    pf.run(r[:1, :2, :3, :6], truth[:1, :2, 0], np.random.default_rng(6), anchors=ANCHORS)
    b = pf.run(r, truth[:, :, 0], np.random.default_rng(5), anchors=ANCHORS)
    assert_same_track(a, b)


def test_large_draws_into_work_array():
    """The motion draws into the work array are the draws of a fresh array, on the
    sequential and on the parallel (spawned parts) path."""
    for shape in [(3, 500, 2), (2, 3, 12000, 2)]:
        a = pp._standard_normal(np.random.default_rng(np.random.SeedSequence(3)), shape)
        b = pp._standard_normal(np.random.default_rng(np.random.SeedSequence(3)), shape,
                                scratch=True)
        assert b.shape == shape and np.array_equal(a, b)
