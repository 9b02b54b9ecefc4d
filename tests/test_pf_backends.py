"""P2PParticleFilter through its public API: the compiled backend equals the NumPy
definition on the same draws (about 1e-10 relative), run equals a loop of step, and the
filter's invariants (repeatable, earlier states untouched, bad input named)."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import track_from_steps
from radioloc.estimators.p2p_particle import OnlineEM, P2PParticleFilter
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import ConstantVelocity, InputDriven, RandomWalk

ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]])
RTOL = 1e-10


def scene(runs=2, vehicles=3, steps=9, seed=5, nlos=True):
    """Truth (runs, N, T + 1, 2) and ranges (runs, N, T, N + 4) to the vehicles and the
    anchors, some missing, some with an NLOS excess."""
    g = np.random.default_rng(seed)
    truth = 15.0 + np.cumsum(0.5 * g.standard_normal((runs, vehicles, steps + 1, 2)), axis=-2)
    nodes = np.concatenate([np.broadcast_to(truth[:, None, :, 1:],
                                            (runs, vehicles) + truth[:, :, 1:].shape[1:]),
                            np.broadcast_to(ANCHORS[:, None], (runs, vehicles, 4, steps, 2))],
                           axis=2)
    d = np.linalg.norm(truth[:, :, None, 1:] - nodes, axis=-1)          # (runs, N, J, T)
    r = np.moveaxis(d + 0.2 * g.standard_normal(d.shape), 2, 3)          # (runs, N, T, J)
    if nlos:
        r += np.where(g.random(r.shape) < 0.3, g.exponential(2.0, r.shape), 0.0)
    idx = np.arange(vehicles)
    r[:, idx, :, idx] = np.nan                                           # a vehicle to itself
    r[g.random(r.shape) < 0.15] = np.nan
    r[0, 1, 3, :] = np.nan                                              # a step with no link
    return truth, r


def run_by_steps(pf, ranges, initial, rng, anchors, controls=None, given=None):
    """The loop of ``run`` written with the public init, step and estimate."""
    n_veh, T = ranges.shape[-3:-1]
    dts = np.diff(np.arange(T, dtype=float), prepend=0.0)
    state = pf.init(initial, rng, time=0.0)
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
        state = pf.step(state, ranges[..., k, :], nodes, rng, control=uk, dt=dts[k])
        estimates.append(pf.estimate(state))
    return track_from_steps(estimates, np.arange(T, dtype=float))


def assert_tracks_close(a, b, rtol=RTOL):
    np.testing.assert_allclose(a.position, b.position, rtol=rtol, atol=rtol)
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=rtol, atol=rtol)
    assert sorted(a.diagnostics) == sorted(b.diagnostics)
    for key in a.diagnostics:
        x, y = np.asarray(a.diagnostics[key]), np.asarray(b.diagnostics[key])
        if x.dtype == bool or x.dtype.kind == "i":
            np.testing.assert_array_equal(x, y, err_msg=key)
        else:
            np.testing.assert_allclose(x, y, rtol=rtol, atol=rtol, err_msg=key)


def both(**kw):
    motion = kw.pop("motion", RandomWalk(0.25))
    model = kw.pop("model", LosNlosRange(0.2, 2.0, 0.6))
    return [P2PParticleFilter(motion, model, backend=b, **kw) for b in ("numba", "numpy")]


# ------------------------------------------------------------------ backend equivalence
@pytest.mark.parametrize("case", [
    dict(particles=300),
    dict(particles=5000, reset_fraction=0.3),                     # several chunks, resets
    dict(particles=25000, model=LosNlosRange(0.2, 1.0, 1.0)),     # parallel normal draws
    dict(particles=200, model=LosNlosRange(0.2, 1.0, 1.0)),       # alpha = 1: Gaussian ranges
    dict(particles=200, model=LosNlosRange(0.05, 1.0, 0.0)),      # alpha = 0: NLOS only
    dict(particles=200, online_em=OnlineEM(burn_in=2)),
    dict(particles=200, resampling="stratified", messages="extrapolated",
         motion=ConstantVelocity(0.5)),
])
def test_numba_backend_equals_numpy_definition(case):
    """The whole filter (link update, moments, resampling, resets, detection, online EM)
    by both backends from the same generator state: equal to rounding."""
    truth, r = scene(steps=8)
    a, b = both(**case)
    ta = a.run(r, truth[:, :, 0], np.random.default_rng(3), anchors=ANCHORS)
    tb = b.run(r, truth[:, :, 0], np.random.default_rng(3), anchors=ANCHORS)
    assert_tracks_close(ta, tb)


def test_backends_agree_on_far_particles_and_carried_posteriors():
    """Particles metres from every range (the densities' far tails, ``log Phi`` by its
    asymptotic series) and the carried link posteriors, state by state."""
    truth, r = scene(runs=1, vehicles=2, steps=4)
    a, b = both(particles=400, model=LosNlosRange(0.01, 5.0, 0.4), init_std=30.0)
    nodes = np.concatenate([truth[:, :, 1], ANCHORS[None]], axis=1)
    sa = a.init(truth[:, :, 0], np.random.default_rng(1))
    sb = b.init(truth[:, :, 0], np.random.default_rng(1))
    ga, gb = np.random.default_rng(2), np.random.default_rng(2)
    for k in range(3):
        sa = a.step(sa, r[:, :, k], nodes, ga)
        sb = b.step(sb, r[:, :, k], nodes, gb)
        np.testing.assert_array_equal(sa.ancestors, sb.ancestors)
        np.testing.assert_allclose(sa.particles, sb.particles, rtol=RTOL)
        np.testing.assert_allclose(sa.link_los, sb.link_los, rtol=RTOL, atol=1e-12)
        np.testing.assert_allclose(sa.mean, sb.mean, rtol=RTOL)
        np.testing.assert_allclose(sa.ess, sb.ess, rtol=RTOL)
        np.testing.assert_array_equal(sa.los_detected, sb.los_detected)


# ------------------------------------------------------------------ run = loop of step
@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize("messages", ["previous", "extrapolated", "given"])
def test_run_equals_a_loop_of_step(backend, messages):
    truth, r = scene()
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.2, 2.0, 0.6), particles=300,
                           messages=messages, backend=backend)
    given = np.broadcast_to(truth[:, :, 1:], r.shape[:-1] + (2,))
    a = pf.run(r, truth[:, :, 0], np.random.default_rng(5), anchors=ANCHORS,
               given_positions=given)
    b = run_by_steps(pf, r, truth[:, :, 0], np.random.default_rng(5), ANCHORS, given=given)
    assert_tracks_close(a, b, rtol=0.0)


def test_run_with_controls_equals_a_loop_of_step():
    truth, r = scene(nlos=False)
    ins = np.diff(truth, axis=2)
    pf = P2PParticleFilter(InputDriven(0.1), LosNlosRange(0.2, 1.0, 1.0), particles=300)
    a = pf.run(r, truth[:, :, 0], np.random.default_rng(5), anchors=ANCHORS, controls=ins)
    b = run_by_steps(pf, r, truth[:, :, 0], np.random.default_rng(5), ANCHORS, controls=ins)
    assert_tracks_close(a, b, rtol=0.0)


# ------------------------------------------------------------------ invariants
@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_bootstrap_filter_tracks_the_truth(backend):
    """Range-only random-walk bootstrap filter (alpha = 1), small noise: metres -> cm."""
    g = np.random.default_rng(0)
    x = 15.0 + np.cumsum(0.3 * g.standard_normal((40, 2)), axis=0)
    d = np.linalg.norm(x[1:, None] - ANCHORS, axis=-1) + 0.01 * g.standard_normal((39, 4))
    r = np.concatenate([np.full((39, 1), np.nan), d], axis=-1)[None, None]
    pf = P2PParticleFilter(RandomWalk(0.09), LosNlosRange(0.01, 1.0, 1.0), particles=20000,
                           init_std=1.0, backend=backend)
    tr = pf.run(r, x[None, None, 0], np.random.default_rng(1), anchors=ANCHORS)
    err = np.linalg.norm(tr.position[0, 0] - x[1:], axis=-1)
    assert err[20:].mean() < 0.05


def test_repeatable_and_earlier_states_untouched():
    truth, r = scene(vehicles=2, steps=4, seed=8)
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.2, 1.0, 0.6), particles=300)
    nodes = np.concatenate([truth[:, :, 1], np.broadcast_to(ANCHORS, (2, 4, 2))], axis=1)
    st0 = pf.init(truth[:, :, 0], np.random.default_rng(1))
    st1 = pf.step(st0, r[:, :, 0], nodes, np.random.default_rng(2))
    kept = {f: np.array(getattr(st1, f), copy=True)
            for f in ("particles", "link_los", "mean", "ancestors")}
    again = pf.step(st0, r[:, :, 0], nodes, np.random.default_rng(2))
    pf.step(st1, r[:, :, 1], nodes, np.random.default_rng(3))
    pf.run(r, truth[:, :, 0], np.random.default_rng(4), anchors=ANCHORS)
    for f, v in kept.items():
        assert np.array_equal(getattr(st1, f), v), f
        assert np.array_equal(getattr(again, f), v), f


def test_init_draws():
    """init: initial + init_std z with z the generator's standard normals."""
    pf = P2PParticleFilter(ConstantVelocity(0.5), LosNlosRange(0.2, 1.0, 1.0), particles=50,
                           init_std=[1.0, 2.0, 0.5, 0.25])
    x0 = np.array([[3.0, 4.0], [5.0, -6.0]])
    st = pf.init(x0, np.random.default_rng(9))
    z = np.random.default_rng(9).standard_normal((2, 50, 4))
    v0 = np.concatenate([x0, np.zeros((2, 2))], axis=-1)
    np.testing.assert_allclose(st.particles, v0[:, None, :] + np.array([1.0, 2.0, 0.5, 0.25]) * z)


def test_motion_draws_follow_the_model():
    """Line 3 of a linear-Gaussian model: the particles' spread is Q(dt)."""
    motion = ConstantVelocity(0.5)
    pf = P2PParticleFilter(motion, LosNlosRange(0.2, 1.0, 1.0), particles=40000,
                           init_std=1e-9)
    st = pf.init(np.zeros((1, 1, 4)), np.random.default_rng(0))
    st = pf.step(st, np.full((1, 1, 5), np.nan), np.zeros((1, 1, 5, 2)),
                 np.random.default_rng(1), dt=2.0)
    np.testing.assert_allclose(st.covariance[0, 0], motion.Q(2.0), rtol=0.05, atol=0.05)


def test_bad_input_names_the_field():
    truth, r = scene(runs=1, vehicles=2, steps=4)
    with pytest.raises(ConfigError, match="backend"):
        P2PParticleFilter(RandomWalk(0.25), LosNlosRange(), backend="gpu")
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.2, 1.0, 0.5), particles=100)
    bad = r.copy()
    bad[0, 1, 2, 3] = np.inf
    with pytest.raises(InputError, match="ranges: infinite"):
        pf.run(bad, truth[:, :, 0], np.random.default_rng(0), anchors=ANCHORS)
    with pytest.raises(InputError, match="ranges: leading shape"):
        pf.run(r, np.broadcast_to(truth[:, :, 0], (3, 2, 2)), np.random.default_rng(0),
               anchors=ANCHORS)
    with pytest.raises(InputError, match="control"):
        P2PParticleFilter(InputDriven(0.2), LosNlosRange(), particles=100).run(
            r, truth[:, :, 0], np.random.default_rng(0), anchors=ANCHORS)
    r[0, 0, :, 1] = 5.0                              # vehicle 0 hears vehicle 1 at every step
    given = np.broadcast_to(truth[:, :, 1:], r.shape[:-1] + (2,)).copy()
    given[0, 1, 2] = np.nan
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(), particles=100, messages="given")
    with pytest.raises(InputError, match="non-finite"):
        pf.run(r, truth[:, :, 0], np.random.default_rng(0), anchors=ANCHORS,
               given_positions=given)


# ------------------------------------------------------------------ range models
class _WrappedMixture:
    """The LOS/NLOS mixture behind another type: a range model with two link states that
    the filter runs through the model's mode_logpdf and chain (the generic update)."""

    def __init__(self, mixture):
        self.mixture = mixture

    def moments(self):
        return self.mixture.moments()

    def logpdf(self, measured, true_ranges):
        return self.mixture.logpdf(measured, true_ranges)

    def logpdf_by_state(self, measured, true_ranges):
        return self.mixture.logpdf_by_state(measured, true_ranges)

    @property
    def chain(self):
        return self.mixture.chain


def test_a_range_model_with_the_mixture_equals_the_mixture_on_both_backends():
    from radioloc.models.ranging import RangeModel

    truth, r = scene(steps=6)
    mix = LosNlosRange(0.2, 2.0, 0.6)
    ref = P2PParticleFilter(RandomWalk(0.25), mix, particles=300, backend="numpy").run(
        r, truth[:, :, 0], np.random.default_rng(3), anchors=ANCHORS)
    for backend in ("numba", "numpy"):
        pf = P2PParticleFilter(RandomWalk(0.25), RangeModel(noise=mix), particles=300,
                               backend=backend)
        assert_tracks_close(pf.run(r, truth[:, :, 0], np.random.default_rng(3),
                                   anchors=ANCHORS), ref)
    # the generic per-state update (mode_logpdf, mode_transition) gives the same filter
    generic = P2PParticleFilter(RandomWalk(0.25), RangeModel(noise=_WrappedMixture(mix)),
                                particles=300, backend="numpy")
    assert_tracks_close(generic.run(r, truth[:, :, 0], np.random.default_rng(3),
                                    anchors=ANCHORS), ref, rtol=1e-9)


def test_a_gaussian_range_model_tracks_on_numpy_and_numba_refuses_it():
    from radioloc.models.ranging import RangeModel

    g = np.random.default_rng(0)
    x = 15.0 + np.cumsum(0.3 * g.standard_normal((30, 2)), axis=0)
    d = np.linalg.norm(x[1:, None] - ANCHORS, axis=-1) + 0.05 * g.standard_normal((29, 4))
    r = np.concatenate([np.full((29, 1), np.nan), d], axis=-1)[None, None]
    pf = P2PParticleFilter(RandomWalk(0.09), RangeModel(std_m=0.05), particles=3000,
                           backend="numpy")
    tr = pf.run(r, x[None, None, 0], np.random.default_rng(1), anchors=ANCHORS)
    assert np.linalg.norm(tr.position[0, 0] - x[1:], axis=-1)[10:].mean() < 0.1
    assert tr.diagnostics["los_detected"][0, 0, :, 1:].all()     # one state: every link LOS
    with pytest.raises(ConfigError, match="backend='numpy'"):
        P2PParticleFilter(RandomWalk(0.09), RangeModel(std_m=0.05), backend="numba")
    with pytest.raises(ConfigError, match="online_em"):
        P2PParticleFilter(RandomWalk(0.09), RangeModel(std_m=0.05), backend="numpy",
                          online_em=True)
    with pytest.raises(ConfigError, match="anchor_bias"):
        P2PParticleFilter(RandomWalk(0.09), RangeModel(std_m=0.05, anchor_bias=True),
                          backend="numpy")
    with pytest.raises(ConfigError, match="measurement"):
        P2PParticleFilter(RandomWalk(0.09), "gaussian", backend="numpy")
