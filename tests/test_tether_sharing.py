"""Inter-robot sharing in the tethering world: the trackee's odometry (paper 003's sharing)
and a team of trackers sharing their readings."""

import dataclasses

import numpy as np
import pytest

from radioloc.core.errors import ConfigError
from radioloc.core.results import Estimate
from radioloc.sim.tether import TetherParams, simulate_tether


class Recorder:
    """A tracker that never localizes (it explores only) and records every call."""

    def __init__(self):
        self.predicts, self.updates = [], []

    def init(self, batch):
        self.batch = batch
        return 0

    def predict(self, state, *, dt, shift_m, extra_blur_m):
        self.predicts.append((np.array(shift_m), np.array(extra_blur_m)))
        return state + 1

    def update(self, state, tracker_xy, rssi):
        self.updates.append((state, np.array(tracker_xy), np.array(rssi, float)))
        return state

    def estimate(self, state):
        B = self.batch
        return Estimate(np.zeros((B, 2)), None, 0.0, {"uncertainty_m": np.full(B, np.inf)})


def quiet_world(**kw):
    """No odometry noise; trackers stay clear of the floor's edge (explore within 2 m of
    their origin, team-mates start within 0.5 m of tracker 0), so odometry equals truth."""
    return dataclasses.replace(TetherParams(), odo_scale_std=0.0, odo_heading_std=0.0,
                               explore_radius_m=2.0, team_start_m=0.5, **kw)


def test_a_team_of_trackers_has_one_row_per_tracker_and_run():
    rec = Recorder()
    tr = simulate_tether(quiet_world(), rec, 3, 5, np.random.default_rng(0), compass=False,
                         trackers=2, share_readings=False)
    assert rec.batch == 6
    assert tr.error_m.shape == (6, 5) and tr.trackee_xy.shape == (6, 5, 2)
    assert len(rec.updates) == 5                      # alone: its own reading only


def test_sharing_applies_every_team_mates_reading_once_per_step():
    rec = Recorder()
    M, B, T = 3, 2, 4
    simulate_tether(quiet_world(), rec, B, T, np.random.default_rng(1), compass=False,
                    trackers=M, share_readings=True)
    assert len(rec.updates) == M * T
    for t in range(T):
        own = rec.updates[M * t][2].reshape(B, M)
        for o in range(1, M):
            mate = rec.updates[M * t + o][2].reshape(B, M)
            # tracker i gets the reading of tracker (i + o) % M
            np.testing.assert_array_equal(mate, np.roll(own, -o, axis=1))


def test_a_shared_reading_is_placed_where_the_team_mate_really_is():
    """Carried into tracker i's frame, team-mate j's reading position is as far from the
    trackee (truth in i's frame) as j really is (true distance of row j)."""
    rec = Recorder()
    M, B, T = 2, 4, 6
    tr = simulate_tether(quiet_world(), rec, B, T, np.random.default_rng(2), compass=False,
                         trackers=M, share_readings=True)
    for t in range(T):
        xy_mate = rec.updates[M * t + 1][1].reshape(B, M, 2)
        truth = tr.trackee_xy[:, t].reshape(B, M, 2)            # trackee in each own frame
        dist = tr.true_distance_m[:, t].reshape(B, M)
        np.testing.assert_allclose(np.linalg.norm(xy_mate - truth, axis=-1),
                                   np.roll(dist, -1, axis=1), atol=1e-9)
        # and its own reading is taken at its own odometry position
        np.testing.assert_allclose(rec.updates[M * t][1], tr.tracker_xy[:, t])


def test_without_shared_odometry_the_tracker_blurs_by_the_trackees_top_speed():
    rec = Recorder()
    P = quiet_world(share_odometry=False)
    simulate_tether(P, rec, 3, 4, np.random.default_rng(3), compass=True)
    for shift, blur in rec.predicts:
        assert np.all(shift == 0.0)
        np.testing.assert_allclose(blur, P.speed_trackee * P.dt_s)


def test_with_shared_odometry_a_stationary_trackee_adds_no_blur():
    rec = Recorder()
    simulate_tether(quiet_world(), rec, 3, 4, np.random.default_rng(3), compass=False)
    for shift, blur in rec.predicts:               # never localized: the trackee stays put
        assert np.all(shift == 0.0) and np.all(blur == 0.0)


def test_one_tracker_world_is_the_same_whatever_the_sharing_switch():
    """Sharing readings needs team-mates: with one tracker the runs are identical."""
    from radioloc.estimators.grid import GridFilter, GridGeometry
    from radioloc.models.rssi_trapezoid import fit_trapezoid_model
    from radioloc.sim.tether import calibration_pairs

    P = TetherParams()
    model = fit_trapezoid_model(*calibration_pairs(P, 3000, np.random.default_rng(4)),
                                tau_min=0.5, sigma_min=0.5, window=2)
    filt = GridFilter(GridGeometry.centred(20, 20, 2.0), model, blur_m=0.3, location="peak")
    a = simulate_tether(P, filt, 2, 30, np.random.default_rng(5), compass=True)
    b = simulate_tether(P, filt, 2, 30, np.random.default_rng(5), compass=True,
                        share_readings=True)
    np.testing.assert_array_equal(a.error_m, b.error_m)


def test_team_size_must_be_positive():
    with pytest.raises(ConfigError, match="trackers"):
        simulate_tether(TetherParams(), Recorder(), 1, 1, np.random.default_rng(0),
                        compass=False, trackers=0)
