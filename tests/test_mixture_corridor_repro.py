"""Helpers of ``p004-corridor`` with known answers (the reduced-size reproduction with Monte
Carlo bands is tests/test_repro_p004.py)."""

import numpy as np
import pytest

from radioloc.experiments.p004_corridor import CorridorExperiment, error_calibration, pause_walk


def test_calibration_statistics_known_answers():
    rmse, nees, cov = error_calibration([1.0, -1.0, 3.0, 0.0], [1.0, 1.0, 1.0, 1.0])
    assert rmse == pytest.approx(np.sqrt(11 / 4)) and nees == pytest.approx(11 / 4)
    assert cov == pytest.approx(0.75)


def test_pausing_walker_stands_still_then_walks_on():
    cfg = CorridorExperiment().config(False)
    w = pause_walk(cfg)
    steps = np.diff(w)
    assert np.sum(steps == 0) == int(cfg.pause_s / cfg.dt_s)
    assert np.all((steps == 0) | np.isclose(steps, cfg.walk_speed * cfg.dt_s))
    assert w[0] == cfg.walk_start_m and w[-1] <= cfg.walk_end_m
