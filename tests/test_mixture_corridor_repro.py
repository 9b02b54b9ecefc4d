"""Helpers of ``p004-corridor`` with known answers (the reduced-size reproduction with Monte
Carlo bands is tests/test_repro_p004.py)."""

import numpy as np
import pytest

from radioloc.estimators.mixture_localization import MixtureTracker
from radioloc.experiments.p004_corridor import (CorridorExperiment, door_bank, error_metrics,
                                                model_isd, pause_walk)
from radioloc.models.mixture import DiagMixture
from radioloc.models.motion import UniformDisk
from radioloc.sim.corridor import Corridor


def test_calibration_statistics_known_answers_with_intervals_over_runs():
    import pandas as pd
    from scipy.stats import t as student_t

    # two runs of two steps: squared errors (1, 1) and (9, 0), posterior std 1
    rows = pd.DataFrame({"run": [0, 0, 1, 1], "x_true": 0.0, "std_m": 1.0,
                         "x_est": [1.0, -1.0, 3.0, 0.0]})
    rmse, nees, cov = error_metrics(rows, ("rmse", "nees", "cover"), "test")
    assert rmse.value == pytest.approx(np.sqrt(11 / 4)) and nees.value == pytest.approx(11 / 4)
    assert cov.value == pytest.approx(0.75)
    half = student_t.ppf(0.975, 1) * np.std([1.0, 4.5], ddof=1) / np.sqrt(2)   # per-run MSEs
    assert nees.ci == pytest.approx((2.75 - half, 2.75 + half))
    assert rmse.ci[0] == 0.0 and rmse.ci[1] == pytest.approx(np.sqrt(2.75 + half))
    half_cover = student_t.ppf(0.975, 1) * np.std([1.0, 0.5], ddof=1) / np.sqrt(2)
    assert cov.ci == pytest.approx((0.75 - half_cover, 0.75 + half_cover))


def test_pausing_walker_stands_still_then_walks_on():
    cfg = CorridorExperiment().config(False)
    w = pause_walk(cfg)
    steps = np.diff(w)
    assert np.sum(steps == 0) == int(cfg.pause_s / cfg.dt_s)
    assert np.all((steps == 0) | np.isclose(steps, cfg.walk_speed * cfg.dt_s))
    assert w[0] == cfg.walk_start_m and w[-1] <= cfg.walk_end_m


def test_model_isd_small_for_the_true_density_large_for_a_shifted_one():

    corridor, noise = Corridor(), 2.0
    x = np.arange(0.1, 60.0, 0.2)                        # narrow kernels along both curves
    mu = np.stack([corridor.mean_rss(x, closed) for closed in (False, True)])   # (2, G, 2)
    means = np.stack([np.stack([np.tile(x, 2), mu[:, :, s].ravel()], -1) for s in range(2)])
    var = np.broadcast_to([0.1**2, noise**2], means.shape)
    truth = DiagMixture.create(np.ones((2, means.shape[1])), means, var)
    near = model_isd(truth, corridor, noise)
    assert np.all(near >= 0) and np.all(near < 0.01)
    shifted = DiagMixture.create(truth.weights, means + [0.0, 10.0], var)
    assert np.all(model_isd(shifted, corridor, noise) > 1.0)


def test_door_bank_with_equal_door_models_is_the_single_tracker():

    corridor, rng = Corridor(), np.random.default_rng(3)
    xs = np.linspace(2.0, 58.0, 8)
    models = DiagMixture.create(np.ones((2, 2, 8)),
                                np.stack([np.stack([xs, corridor.mean_rss(xs, False)[:, s]], -1)
                                          for s in range(2)])[None].repeat(2, 0),
                                np.full((2, 2, 8, 2), 9.0))
    walk = 20.0 + 0.5 * np.arange(6)
    rss = corridor.sample_rss(np.broadcast_to(walk, (2, 6)), False, 2.0, rng)
    times = np.arange(6.0)
    disk = UniformDisk(1.5, dim=1)
    bank = np.stack([models.weights] * 2), np.stack([models.means] * 2), \
        np.stack([models.variances] * 2)
    pos, var, p_closed = door_bank(DiagMixture(*bank), rss, times, disk, 4, "runnalls", 60.0)
    one = MixtureTracker(models, disk, 4, "runnalls").run(rss, times)
    np.testing.assert_allclose(p_closed, 0.5)
    np.testing.assert_allclose(pos, one.position, rtol=1e-12)
    np.testing.assert_allclose(var, one.covariance, rtol=1e-12)


def test_door_bank_finds_the_door_state_of_the_run():

    corridor, rng = Corridor(), np.random.default_rng(4)
    xs = np.linspace(1.0, 59.0, 30)
    means = np.stack([np.stack([np.stack([xs, corridor.mean_rss(xs, closed)[:, s]], -1)
                                for s in range(2)]) for closed in (False, True)])
    models = DiagMixture.create(np.ones((2, 1, 2, 30)), means[:, None],
                                np.broadcast_to([1.0, 4.0], (2, 1, 2, 30, 2)))
    walk = 35.0 + 0.5 * np.arange(8)
    for closed in (False, True):
        rss = corridor.sample_rss(walk[None], closed, 2.0, rng)
        pos, var, p_closed = door_bank(models, rss, np.arange(8.0), UniformDisk(1.5, dim=1), 6,
                                       "runnalls", 60.0)
        assert (p_closed[0, -1] > 0.99) if closed else (p_closed[0, -1] < 0.01)
        # the mixture over door states ends as the tracker of the right door
        one = MixtureTracker(models[int(closed)], UniformDisk(1.5, dim=1), 6,
                             "runnalls").run(rss, np.arange(8.0))
        assert abs(pos[0, -1, 0] - one.position[0, -1, 0]) < 0.05
        assert var[0, -1, 0, 0] >= one.covariance[0, -1, 0, 0] * (1 - 1e-9)
