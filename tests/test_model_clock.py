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
