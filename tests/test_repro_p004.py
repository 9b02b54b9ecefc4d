"""Reduced-size reproduction of ``p004-corridor`` (6 runs, 2 dB): headline numbers within
Monte Carlo bands, each stable claim's verdict, and the format of the docs' generated numbers.

Bands: the reference is the quick run (20 runs, seed 0: runs 0-19 of the run that wrote
docs/generated/p004_corridor.md); the band is four combined standard errors: this test's,
from the per-run values of its 6 runs, and the reference's own, from its 20 runs (stored
beside it). The per-run errors are heavy-tailed (a static user's run that settles on the
wrong door mode), so the spread of 6 runs alone can be far too small: with the test's
standard error standing in for the reference's, block seed 2 failed the static user's bands
by up to 0.22 m (the kernel-insertion models included). Checked on six further disjoint
sets of 6 runs (runs 20-55 of the same run) and on block seeds 1, 2 and 7: every value
within its band."""

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest

from radioloc.core.rng import block_generator
from radioloc.experiments.p004_corridor import CorridorExperiment, docs_snippet

RUNS = 6
SNIPPET = Path(__file__).resolve().parents[1] / "docs" / "generated" / "p004_corridor.md"

#: headline per-run RMSEs [m] of the quick run (20 runs), their standard errors (delta
#: method over the 20 runs) and the scenario / step they read
REFERENCE = {
    "rmse_m_after_8": (3.14, 0.416, "static", 8),
    "rmse_m_after_8_runnalls": (3.13, 0.413, "static_runnalls", 8),
    "rmse_m_after_8_kernel": (1.93, 0.261, "static_kernel", 8),
    "tracking_rmse_m": (7.16, 0.282, "tracking", None),
    "tracking_cv_rmse_m": (2.37, 0.082, "tracking_cv", None),
    "pause_tracking_cv_rmse_m": (2.74, 0.098, "pause_tracking_cv", None),
    "walk_oneshot_rmse_m": (3.56, 0.090, "walk_oneshot", None),
    "slow_tracking_rmse_m": (3.87, 0.174, "slow_tracking", None),
    "slow_tracking_door_shared_rmse_m": (4.33, 0.216, "slow_tracking_door_shared", None),
    "slow_oneshot_rmse_m": (3.65, 0.092, "slow_oneshot", None),
}

#: mean over runs and stations of each calibration's ISD to the true density (quick run)
#: and its standard error over the 20 runs
MODEL_ISD = {"parameter": (0.2765, 0.0039), "kernel": (0.1610, 0.0029)}


@pytest.fixture(scope="module")
def repro(tmp_path_factory):
    exp = CorridorExperiment()
    cfg = dataclasses.replace(exp.config(False), runs=RUNS, block_size=RUNS, noise_db=(2.0,))
    df = exp.run_block(cfg, np.arange(RUNS), block_generator(7, 0))
    summary = exp.summarize(cfg, df, tmp_path_factory.mktemp("p004"))
    return (df, {m.name: m.value for m in summary.metrics},
            {c.claim: c.verdict for c in summary.claims}, summary)


def _rmse_and_se(df, scenario, step):
    r = df[(df["table"] == "runs") & (df["scenario"] == scenario)]
    if step is not None:
        r = r[r["step"] == step]
    per_run = ((r["x_est"] - r["x_true"]) ** 2).groupby(r["run"]).mean()
    rmse = float(np.sqrt(per_run.mean()))
    se = float(per_run.std(ddof=1) / np.sqrt(per_run.size) / (2 * rmse))   # delta method
    return rmse, se


@pytest.mark.parametrize("name", sorted(REFERENCE))
def test_headline_numbers_within_monte_carlo_bands(repro, name):
    df, metrics, _, _ = repro
    ref, se_ref, scenario, step = REFERENCE[name]
    rmse, se = _rmse_and_se(df, scenario, step)
    assert metrics[name] == pytest.approx(rmse, rel=1e-9)        # the summary reads the rows
    band = 4.0 * np.hypot(se, se_ref)
    assert abs(rmse - ref) <= band, (name, rmse, ref, band)


@pytest.mark.parametrize("method", sorted(MODEL_ISD))
def test_model_isd_within_monte_carlo_bands(repro, method):
    df, metrics, _, _ = repro
    rows = df[df["table"] == "model_isd"]
    per_run = rows.groupby("run")[f"isd_{method}"].mean()
    assert metrics[f"model_isd_{method}"] == pytest.approx(per_run.mean(), rel=1e-9)
    ref, se_ref = MODEL_ISD[method]
    band = 4.0 * np.hypot(per_run.std(ddof=1) / np.sqrt(per_run.size), se_ref)
    assert abs(per_run.mean() - ref) <= band, (method, per_run.mean(), band)


def test_guard_fraction_and_isd_ratio(repro):
    df, metrics, _, _ = repro
    isd = df[df["table"] == "isd"]
    fired = isd["pb_guard_fired"].astype(bool)
    assert metrics["pb_guard_fired_fraction"] == pytest.approx(fired.mean())
    # where the guard fired the start was returned: ratio exactly one; elsewhere below
    ratio = isd["isd_progressive"] / isd["isd_runnalls"]
    assert np.all(ratio[fired] == 1.0) and np.all(ratio[~fired] < 1.0)
    # quick run: median ratio 0.0028; with 6 runs it stays well below one half
    assert metrics["isd_ratio_median"] < 0.3
    assert metrics["isd_ratio_max"] == pytest.approx(ratio.max())


def test_uncertainty_of_the_trackers(repro):
    m = repro[1]
    # the disk model without velocity lags the walker: over-confident on the walk
    assert m["tracking_coverage_2sigma"] < 0.6 and m["tracking_nees"] > 4.0
    # the constant-velocity variant is about calibrated (quick run: NEES 0.78, 97.5 %)
    assert 0.3 < m["tracking_cv_nees"] < 3.0 and m["tracking_cv_coverage_2sigma"] > 0.8
    # the door bank finds the run's door state
    assert m["door_posterior_correct_fraction"] >= 5 / 6


def test_claim_verdicts(repro):
    claims = repro[2]

    def verdict(start):
        (hit,) = [v for c, v in claims.items() if c.startswith(start)]
        return hit

    def holds(start):
        return verdict(start) == "holds"

    def fails(start):          # at this size a claim may also be undecided, never the opposite
        return verdict(start) == "does not hold"

    assert not holds("Tracking with the motion model is more accurate")
    assert not fails("Calibration in both door states gives a bimodal")
    assert not fails("The product of the per-station densities")
    assert not fails("Variant (ours, not the paper's): a constant-velocity mixture tracker is "
                   "more accurate than one-shot positioning on the walk")
    assert not fails("Variant (ours, not the paper's): a constant-velocity mixture tracker is "
                   "more accurate than one-shot positioning on the pausing walk")
    assert not holds("After 8 updates the estimate concentrates")
    assert not any(c.startswith("Progressive Bayes reduction") for c in claims)


def _names(text):
    """Metric names (first column of the metric table) and claim texts without numbers."""
    metrics = re.findall(r"^\| `([a-z0-9_]+)` \|", text, flags=re.MULTILINE)
    lines = re.findall(r"^- (.*): \*\*(?:holds|does not hold|undecided at this size)\*\*"
                       r"(?: \(.*\))?$", text, flags=re.MULTILINE)
    claims = [re.sub(r"[-+]?\d[\d.]*", "#", c) for c in lines]
    return metrics, claims


def test_docs_snippet_has_the_format_and_lines_of_the_current_experiment(repro):
    summary = repro[3]
    record = {"experiment": "p004-corridor", "seed": 0, "runs": RUNS, "full": False,
              "metrics": [m.as_dict() for m in summary.metrics],
              "claims": [c.as_dict() for c in summary.claims]}
    fresh = docs_snippet(json.loads(json.dumps(record)))
    committed = SNIPPET.read_text()
    assert committed.startswith(fresh.splitlines()[0])              # the generator's header
    m_new, c_new = _names(fresh)
    m_old, c_old = _names(committed)
    assert m_new == m_old                                           # same metrics, same order
    # this run has the 2 dB claims only; each is a line of the committed snippet
    assert set(c_new) <= set(c_old) and len(c_old) > len(c_new)
    head = re.search(r"Run: `p004-corridor`, (\d+) runs", committed)
    assert head and int(head.group(1)) >= 20
