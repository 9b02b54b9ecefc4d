"""Reduced-size reproduction of ``p004-corridor``: headline numbers within Monte Carlo bands
and each claim's verdict (6 runs, 2 dB only)."""

import dataclasses

import numpy as np
import pytest

from radioloc.core.rng import block_generator
from radioloc.experiments.p004_corridor import CorridorExperiment, _calibration, _pause_walk


@pytest.fixture(scope="module")
def corridor_summary(tmp_path_factory):
    exp = CorridorExperiment()
    cfg = dataclasses.replace(exp.config(False), runs=6, block_size=6, noise_db=(2.0,))
    df = exp.run_block(cfg, np.arange(6), block_generator(7, 0))
    summary = exp.summarize(cfg, df, tmp_path_factory.mktemp("p004"))
    return ({m.name: m.value for m in summary.metrics},
            {c.claim: bool(c.holds) for c in summary.claims})


# bands: 20-run quick values 2.2 m (per-run RMSE after 8), 1.6 m (std), 7.0 m (tracking),
# 3.3 m (one-shot walk), 6.0 m (pausing walker tracked)
BANDS = {"rmse_m_after_8": (0.5, 5.0), "std_m_after_8": (0.8, 3.0),
         "tracking_rmse_m": (3.5, 11.0), "walk_oneshot_rmse_m": (1.5, 6.0),
         "pause_tracking_rmse_m": (3.0, 10.0), "tracking_mean_lag_m": (2.5, 10.0)}


@pytest.mark.parametrize("name", sorted(BANDS))
def test_corridor_headline_numbers_within_bands(corridor_summary, name):
    lo, hi = BANDS[name]
    assert lo <= corridor_summary[0][name] <= hi, (name, corridor_summary[0][name])


def test_corridor_uncertainty_metrics_are_reported(corridor_summary):
    m = corridor_summary[0]
    assert 0.0 <= m["coverage_2sigma_after_8"] <= 1.0 and m["nees_after_8"] > 0
    # the disk model without velocity lags the walker: over-confident on the walk
    assert m["tracking_coverage_2sigma"] < 0.9 and m["tracking_nees"] > 2.0


def test_corridor_claim_verdicts(corridor_summary):
    claims = corridor_summary[1]

    def verdict(start):
        (hit,) = [v for c, v in claims.items() if c.startswith(start)]
        return hit

    assert not verdict("Tracking with the motion model is more accurate")
    assert verdict("Calibration in both door states gives a bimodal")
    assert verdict("The product of the per-station densities")


def test_calibration_statistics_known_answers():
    rmse, nees, cov = _calibration([1.0, -1.0, 3.0, 0.0], [1.0, 1.0, 1.0, 1.0])
    assert rmse == pytest.approx(np.sqrt(11 / 4)) and nees == pytest.approx(11 / 4)
    assert cov == pytest.approx(0.75)


def test_pausing_walker_stands_still_then_walks_on():
    cfg = CorridorExperiment().config(False)
    w = _pause_walk(cfg)
    steps = np.diff(w)
    assert np.sum(steps == 0) == int(cfg.pause_s / cfg.dt_s)
    assert np.all((steps == 0) | np.isclose(steps, cfg.walk_speed * cfg.dt_s))
    assert w[0] == cfg.walk_start_m and w[-1] <= cfg.walk_end_m
