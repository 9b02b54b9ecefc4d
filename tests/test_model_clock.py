"""Clock model: offset and drift of an unsynchronised receiver as state."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.models.clock import ClockModel, transition
from radioloc.models.measurement import StateLayout
from radioloc.models.motion import WhiteAccelerationCV
from radioloc.sim.measurements import clock_trajectory


@pytest.mark.parametrize("terms", [1, 2])
def test_noise_of_an_interval_does_not_depend_on_how_it_is_split(terms):
    clock = ClockModel(offset_std_m=0.3, drift_std_m_per_s=0.05, terms=terms)
    F, Q = clock.F(0.4), clock.Q(0.4)
    two = F @ Q @ F.T + Q
    np.testing.assert_allclose(two, clock.Q(0.8), rtol=1e-12)
    np.testing.assert_allclose(F @ F, clock.F(0.8))


def test_drawn_clocks_have_the_model_covariance():
    clock = ClockModel(offset_std_m=0.2, drift_std_m_per_s=0.5)
    rng = np.random.default_rng(0)
    n, steps, dt = 20000, 5, 0.25
    start = np.array([10.0, 3.0])
    path = clock_trajectory(clock, steps, dt, rng, initial=np.broadcast_to(start, (n, 2)))
    assert path.shape == (n, steps, 2)
    np.testing.assert_array_equal(path[:, 0], np.broadcast_to(start, (n, 2)))
    total = (steps - 1) * dt
    np.testing.assert_allclose(path[:, -1].mean(axis=0), clock.F(total) @ start, atol=0.05)
    S = np.cov(path[:, -1], rowvar=False)
    Q = clock.Q(total)
    se = np.sqrt((np.outer(np.diag(Q), np.diag(Q)) + Q**2) / n)
    assert np.all(np.abs(S - Q) < 4 * se)


def test_transition_is_block_diagonal_in_layout_order():
    layout = StateLayout(dim=2, order=1, clock=2, n_bias=3)
    motion = WhiteAccelerationCV(q=0.5)
    clock = ClockModel(offset_std_m=0.1, drift_std_m_per_s=0.02)
    F, Q = transition(layout, motion, np.array([0.1, 0.5]), clock)
    assert F.shape == Q.shape == (2, 9, 9)
    np.testing.assert_allclose(F[1, :4, :4], motion.F(0.5))
    np.testing.assert_allclose(Q[1, :4, :4], motion.Q(0.5))
    np.testing.assert_allclose(F[0, 4:6, 4:6], clock.F(0.1))
    np.testing.assert_allclose(Q[0, 4:6, 4:6], clock.Q(0.1))
    np.testing.assert_allclose(F[:, 6:, 6:], np.broadcast_to(np.eye(3), (2, 3, 3)))
    assert np.all(Q[:, 6:, :] == 0.0)
    off = np.ones((9, 9), bool)
    off[:4, :4] = off[4:6, 4:6] = off[6:, 6:] = False
    assert np.all(F[:, off] == 0.0) and np.all(Q[:, off] == 0.0)


def test_bad_input_names_the_argument():
    with pytest.raises(InputError, match="terms"):
        ClockModel(0.1, 0.1, terms=3)
    with pytest.raises(ConfigError, match="drift_std_m_per_s"):
        ClockModel(0.1, -0.1)
    with pytest.raises(InputError, match="dt"):
        ClockModel(0.1, 0.1).Q(-1.0)
    with pytest.raises(InputError, match="clock"):
        transition(StateLayout(dim=2, clock=2), None, 0.1, ClockModel(0.1, terms=1))
    with pytest.raises(InputError, match="motion"):
        transition(StateLayout(dim=2), WhiteAccelerationCV(q=1.0), 0.1)
    with pytest.raises(InputError, match="steps"):
        clock_trajectory(ClockModel(0.1), 0, 0.1, np.random.default_rng(0))


@pytest.mark.parametrize("estimator", ["ekf", "smoother"])
def test_filters_hold_a_drifting_clock_by_default(estimator):
    """Pseudoranges from a clock drifting by 1 m/s (the simulator's two-state clock): the
    EKF and the smoother with their defaults track it (they ended 65 m and 50 m off, claiming
    0.5 m and 0.3 m, with a clock offset held still) and their claim covers their error."""
    from radioloc.estimators.batch_smoother import BatchSmoother
    from radioloc.estimators.extended_kalman import ExtendedKalmanFilter
    from radioloc.models.measurement import Context, Observation
    from radioloc.models.pseudorange import PseudorangeModel

    rng = np.random.default_rng(0)
    anchors = np.array([[0, 0], [50, 0], [50, 40], [0, 40], [25, -30], [-20, 20.0]])
    t = np.arange(0, 60, 0.5)
    xy = np.stack([25 + 10 * np.cos(0.1 * t), 20 + 8 * np.sin(0.1 * t)], -1)
    offset = 5.0 + 1.0 * t
    z = (np.linalg.norm(xy[:, None] - anchors, axis=-1) + offset[:, None]
         + 0.3 * rng.standard_normal((t.size, len(anchors))))
    obs = Observation(PseudorangeModel(std_m=0.3), z, Context(points=anchors))
    motion = WhiteAccelerationCV(0.1, 2)
    est = ExtendedKalmanFilter(motion) if estimator == "ekf" else BatchSmoother(motion)
    assert est.state_layout([obs]).clock == 2
    track = est.run([obs], t, prior_mean=np.r_[xy[0], 0, 0], prior_cov=np.diag([4, 4, 9, 9.0]))
    err = np.linalg.norm(track.position - xy, axis=-1)
    claim = np.sqrt(np.trace(track.covariance, axis1=-2, axis2=-1))
    # measured: last error 0.16 m (both), claimed 0.20 m
    assert err[-1] < 0.5 and np.mean(err[20:] < 3 * claim[20:]) > 0.9


def test_the_particle_filter_moves_the_clock_offset_by_its_drift():
    from radioloc.estimators.particle_filter import ParticleFilter
    from radioloc.models.measurement import Context, Observation
    from radioloc.models.motion import RandomWalk
    from radioloc.models.pseudorange import PseudorangeModel

    pf = ParticleFilter(RandomWalk(1e-6, 2), n_particles=20,
                        layout=StateLayout(dim=2, order=0, clock=2))
    state = pf.init(np.array([1.0, 2.0, 10.0, 3.0]), 1e-8 * np.eye(4))
    absent = Observation(PseudorangeModel(std_m=1.0), np.array([np.nan]),
                         Context(points=np.zeros((1, 2))))
    state = pf.step(state, [absent], dt=2.0)
    np.testing.assert_allclose(state.particles[..., 2:], np.broadcast_to([16.0, 3.0], (20, 2)),
                               atol=1e-3)
