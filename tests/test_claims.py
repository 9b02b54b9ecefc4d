"""Claims decided by a paired comparison with a confidence interval over runs, and metrics
with their interval: known answers, coverage, pairing, the three verdicts, bad input."""

import json

import numpy as np
import pandas as pd
import pytest
from scipy.stats import t as student_t

from radioloc.core.errors import ConfigError
from radioloc.experiments.base import (FAILS, HOLDS, UNDECIDED, Claim, Metric, mean_interval,
                                       median_interval, paired_differences, per_run)


def test_mean_interval_known_answer():
    mean, lo, hi, n = mean_interval([1.0, 2.0, 3.0, 4.0, np.nan])
    half = student_t.ppf(0.975, 3) * np.std([1, 2, 3, 4], ddof=1) / 2
    assert n == 4 and mean == 2.5
    assert lo == pytest.approx(2.5 - half) and hi == pytest.approx(2.5 + half)
    assert np.isnan(mean_interval([3.0])[1]) and mean_interval([])[3] == 0


def test_median_interval_is_the_order_statistic_pair():
    med, lo, hi, n = median_interval(np.arange(20.0)[::-1])
    assert (med, lo, hi, n) == (9.5, 5.0, 14.0, 20)       # x_(6), x_(15) for n = 20


def test_mean_interval_covers_the_true_mean_95_percent():
    rng = np.random.default_rng(5)
    x = rng.normal(3.0, 2.0, (2000, 12))
    hit = [lo <= 3.0 <= hi for _, lo, hi, _ in map(mean_interval, x)]
    assert 0.935 <= np.mean(hit) <= 0.965       # binomial s.d. 0.005


def test_median_interval_covers_the_true_median_at_least_95_percent():
    rng = np.random.default_rng(6)
    x = rng.exponential(1.0, (1000, 15))
    hit = [lo <= np.log(2) <= hi for _, lo, hi, _ in map(median_interval, x)]
    assert np.mean(hit) >= 0.93


def test_three_verdicts_of_a_paired_comparison():
    rng = np.random.default_rng(1)
    b = rng.normal(10.0, 3.0, 40)
    assert Claim.lower("a < b", b - 1.0 + rng.normal(0, 0.1, 40), b).verdict == HOLDS
    assert Claim.lower("a < b", b + 1.0 + rng.normal(0, 0.1, 40), b).verdict == FAILS
    assert Claim.lower("a < b", b + rng.normal(0, 1.0, 40), b).verdict == UNDECIDED
    assert Claim.lower("a < b", b, b).verdict == FAILS             # equal: not lower
    one = Claim.lower("a < b", b[:1] - 1, b[:1])
    assert one.verdict == UNDECIDED and one.n == 1                # no interval from one run


def test_pairing_removes_what_the_settings_share():
    """Shared per-run noise (the same world) cancels in the paired difference: a small
    gain over a wide spread of runs is decided."""
    rng = np.random.default_rng(2)
    world = rng.normal(0.0, 50.0, 30)
    c = Claim.lower("a < b", world + rng.normal(0, 0.1, 30), world + 0.5)
    assert c.holds and c.ci[0] > 0 and c.estimate == pytest.approx(0.5, abs=0.1)


def test_series_pair_on_their_run_index():
    rng = np.random.default_rng(3)
    a = pd.Series(rng.normal(0, 1, 20), index=np.arange(20))
    b = a + 1.0 + pd.Series(rng.normal(0, 0.2, 20), index=np.arange(20))
    b.iloc[3] = np.nan
    shuffled = b.sample(frac=1.0, random_state=0)
    assert np.allclose(np.sort(paired_differences(b, a)), np.sort(paired_differences(shuffled, a)))
    assert paired_differences(b, a).size == 19
    with pytest.raises(ConfigError, match="paired comparison"):
        paired_differences(np.zeros(3), np.zeros(4))


def test_bounds_within_and_all_of():
    x = np.array([0.9, 1.1, 1.0, 0.95, 1.05])
    assert Claim.below("mean <= 1.5", x, 1.5).holds is True
    assert Claim.below("mean <= 0.5", x, 0.5).holds is False
    assert Claim.below("mean <= 1.02", x, 1.02).holds is None
    assert Claim.above("median > 0.5", x, 0.5, stat="median").holds is True
    assert Claim.within("equal within 10%", x, x + 0.01, 0.10).holds is True
    assert Claim.within("equal within 10%", x, 2 * x, 0.10).holds is False
    h, f, u = (Claim.below("", x, b) for b in (1.5, 0.5, 1.02))
    assert Claim.all_of("chain", [h, h]).verdict == HOLDS
    assert Claim.all_of("chain", [h, u]).verdict == UNDECIDED
    assert Claim.all_of("chain", [u, f, h]).verdict == FAILS
    assert Claim.all_of("chain", [u, f]).ci == f.ci
    record = Claim.all_of("chain", [u, f, h]).as_dict()       # every step, for repetitions
    assert [p["ci_low"] for p in record["parts"]] == [c.ci[0] for c in (u, f, h)]
    assert [p["verdict"] for p in record["parts"]] == [UNDECIDED, FAILS, HOLDS]
    assert "parts" not in h.as_dict()
    with pytest.raises(ConfigError, match="no parts"):
        Claim.all_of("chain", [])
    with pytest.raises(ConfigError, match="stat"):
        Claim.below("", x, 1.0, stat="mode")


def test_records_carry_the_interval():
    c = Claim.lower("a < b", np.arange(5.0), np.arange(5.0) + [1, 1.2, 0.9, 1.1, 1.0], unit="m")
    d = json.loads(json.dumps(c.as_dict()))
    assert d["verdict"] == "holds" and d["holds"] is True and d["n"] == 5 and d["unit"] == "m"
    assert d["ci_low"] < d["estimate"] < d["ci_high"] and d["level"] == 0.95
    u = Claim.below("x", [1.0], 2.0).as_dict()
    assert u["holds"] is None and u["verdict"] == "undecided at this size" and u["ci_low"] is None
    plain = Claim("a statement with no runs", True).as_dict()
    assert plain["verdict"] == "holds" and plain["ci_low"] is None


def test_metric_over_runs():
    runs = pd.DataFrame({"run": np.repeat(np.arange(6), 3), "error_m": np.arange(18.0)})
    values = per_run(runs, "error_m")
    assert list(values) == [1.0, 4.0, 7.0, 10.0, 13.0, 16.0]
    m = Metric.over_runs("e", values, paper=9.0, unit="m")
    assert m.value == 8.5 and m.ci[0] < 8.5 < m.ci[1]
    d = m.as_dict()
    assert d["ci_low"] == pytest.approx(m.ci[0]) and d["paper"] == 9.0
    assert Metric.over_runs("e", values, stat="median").value == 8.5
    assert Metric("plain", 1.0).as_dict()["ci_low"] is None
    with pytest.raises(ConfigError, match="stat"):
        Metric.over_runs("e", values, stat="max")


def test_metric_over_runs_rms_is_the_root_of_the_mean_square_with_the_roots_of_its_interval():
    sq = np.array([0.04, 0.09, 0.16, 0.01, 0.25, 0.0, 0.36])      # per-run squared errors, m^2
    m = Metric.over_runs("rmse_m", sq, unit="m", stat="rms")
    mean, lo, hi, _ = mean_interval(sq)
    assert m.value == pytest.approx(np.sqrt(sq.mean()))
    assert m.ci == pytest.approx((np.sqrt(max(lo, 0.0)), np.sqrt(hi)))
    assert m.ci[0] < m.value < m.ci[1]
    wide = Metric.over_runs("rmse_m", [0.0, 0.0, 9.0], stat="rms")   # t interval below 0
    assert wide.ci[0] == 0.0 and wide.ci[1] > wide.value
    assert Metric.over_runs("e", [1.0], stat="rms").value == 1.0
    assert Metric("x", 1.0, predicted="Sect. I").as_dict()["predicted"] == "Sect. I"
