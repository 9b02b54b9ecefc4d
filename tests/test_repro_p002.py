"""Reduced-size reproduction of ``p002-single-sensor``: the headline numbers within Monte
Carlo bands and the verdict of every claim.

One block of 40 runs (n = 10, 30, 60; synthetic part only) through ``run_block`` and
``summarize``. Each headline number must lie within ``K`` combined standard errors of its
reference: the same reduced configuration run over 400 runs (10 blocks of seed 2024, the
experiment's own ``_se`` metrics; the 2000-run full values in docs/p002.md agree). The
standard error of the test's own number comes from its 40 runs (``*_se`` metrics of the
summary, delta method on the squared errors), so the band follows the runs' spread.
"""

import dataclasses
import os

import numpy as np
import pytest

from radioloc.core.rng import block_generator
from radioloc.experiments.single_sensor import SingleSensorExperiment

#: band half-width in combined standard errors
K = 4.0
#: reference (value, standard error): 400 runs of the reduced configuration, n = 60
REFERENCE = {
    "causal_rmse_blue": (0.2944, 0.0035),
    "causal_rmse_newton": (0.2826, 0.0039),
    "causal_rmse_ekf": (0.2663, 0.0029),
    "causal_rmse_ols": (0.5605, 0.0059),
    "traj_rmse_ekf_straight_n60": (0.4192, 0.0102),
    "traj_rmse_blue_n60": (0.4081, 0.0096),
    "traj_rmse_newton_n60": (0.1800, 0.0027),
    "traj_rmse_ekf_n60": (0.1515, 0.0024),
    "traj_rmse_ols_n60": (0.2430, 0.0046),
    "rmse_blue_n60": (0.2912, 0.0087),
    "rmse_newton_n60": (0.3219, 0.0083),
    "rmse_ekf_n60": (0.2550, 0.0070),
    "rmse_ols_n60": (0.4383, 0.0115),
}
RUNS = 40


def reduced_config(exp):
    """The reduced configuration of the reference and of the test."""
    return dataclasses.replace(exp.config(False), runs=RUNS, block_size=RUNS,
                               n_values=(10, 30, 60))


def summarize_block(exp, cfg, seed, out_dir, empty_data):
    """run_block over one block and summarize it (synthetic part only)."""
    old = os.environ.get("RADIOLOC_DATA")
    os.environ["RADIOLOC_DATA"] = str(empty_data)
    try:
        df = exp.run_block(cfg, np.arange(cfg.runs), block_generator(seed, 0))
        summary = exp.summarize(cfg, df, out_dir)
    finally:
        if old is None:
            os.environ.pop("RADIOLOC_DATA")
        else:
            os.environ["RADIOLOC_DATA"] = old
    return ({m.name: m.value for m in summary.metrics},
            {c.claim: c.verdict for c in summary.claims})


@pytest.fixture(scope="module")
def p002(tmp_path_factory):
    exp = SingleSensorExperiment()
    return summarize_block(exp, reduced_config(exp), 11, tmp_path_factory.mktemp("p002"),
                           tmp_path_factory.mktemp("no-data"))


@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_headline_within_monte_carlo_band(p002, name):
    metrics = p002[0]
    ref, ref_se = REFERENCE[name]
    value, se = metrics[name], metrics[name + "_se"]
    assert np.isfinite(se) and se > 0
    band = K * np.hypot(se, ref_se)
    assert abs(value - ref) <= band, f"{name} = {value:.4f}, reference {ref} +- {band:.4f}"


def test_newton_divergence_rate_is_reported_and_small_from_the_ols_start(p002):
    m = p002[0]
    for name in ("newton_diverged_frac_n10", "newton_diverged_frac_n60",
                 "newton_fixed_diverged_frac_n60", "newton_near_truth_diverged_frac_n10"):
        assert 0.0 <= m[name] <= 1.0
    # reference 400 runs: 0.5 % at n = 10, 0 at n = 60 (OLS start); 5 % from the fixed start
    assert m["newton_diverged_frac_n60"] == 0.0
    assert m["newton_diverged_frac_n10"] <= 0.05


def test_fast_sensor_path_makes_the_blue_usable_at_n10(p002):
    m = p002[0]
    assert m["rmse_blue_n10_step1p3"] < 1.0
    assert m["rmse_blue_n10_step0p4"] > 20.0          # a slower path: tens of metres and more
    assert m["rmse_blue_n60_step0p4"] < 1.0


def test_causal_track_of_one_window_is_the_current_position_error(tmp_path):
    """With one window (n_values = (30,)) the causal track is p_29 from the first 30 samples,
    the p_k reading at n = 30, for every method (the EKF's filtered state at k is the last
    sample of its smoothed window)."""
    exp = SingleSensorExperiment()
    cfg = dataclasses.replace(exp.config(False), runs=8, block_size=8, n_values=(30,))
    m, _ = summarize_block(exp, cfg, 3, tmp_path, tmp_path / "no-data")
    for meth in ("blue", "newton", "ekf", "ols"):
        assert m[f"causal_rmse_{meth}"] == pytest.approx(m[f"rmse_{meth}_n30"], rel=1e-9)
    assert m["traj_rmse_ekf_straight_n30"] != pytest.approx(m["traj_rmse_ekf_n30"], rel=0.05)


def test_no_metric_is_a_cpu_time(p002):
    assert not [k for k in p002[0] if "cpu" in k]


def test_claim_verdicts(p002):
    claims = p002[1]

    def verdict(start):
        (hit,) = [v for c, v in claims.items() if c.startswith(start)]
        return hit

    def holds(start):
        return verdict(start) == "holds"

    def fails(start):          # at this size a claim may also be undecided, never the opposite
        return verdict(start) == "does not hold"

    assert not holds("(synthetic) the closed form has the lowest causal-track RMSE")
    assert not holds("(synthetic) reading, straight tracks at n = 60")
    assert not holds("(synthetic) reading, Fig. 1 trajectories at n = 60")
    assert not holds("(synthetic) reading, p_k (k = n-1) at n = 60 only")
    assert not holds("(synthetic) reading, straight track: the closed-form trajectory RMSE")
    assert not holds("(synthetic) the closed-form causal error (p_k, k = n-1) decreases")
    assert not fails("(synthetic) variant, fixed k = 0 as in Lemma 1")
    assert not holds("(Fig. 2, y = sin x) Newton from a start at the origin fails")
