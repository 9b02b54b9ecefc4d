"""Fault detection and exclusion (radioloc.estimators.fault_exclusion) and its use by
`locate --method lsq`: gross errors are left out, and the errors stay those of a clean log."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from radioloc.estimators.fault_exclusion import exclude_faults
from radioloc.estimators.least_squares import LeastSquares
from radioloc.locate.base import LocateRequest, run_method
from radioloc.locate.scoring import reference_errors
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel
from radioloc.sim.faulty_logs import walk_log

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0], [10.0, -3.0],
                    [23.0, 7.0]])


def _ranges(rng, n=200, std=0.1):
    truth = rng.uniform([2, 2], [18, 13], (n, 2))
    z = np.linalg.norm(truth[:, None] - ANCHORS[None], axis=-1) + std * rng.standard_normal((n, 6))
    return truth, z


def test_a_gross_range_is_excluded_and_the_fix_recovers():
    rng = np.random.default_rng(1)
    truth, z = _ranges(rng)
    bad = rng.integers(0, 6, len(z))
    z[np.arange(len(z)), bad] += rng.uniform(40, 250, len(z))
    obs = Observation(RangeModel(std_m=0.1), z, Context(points=ANCHORS))
    est, excluded, failing = exclude_faults(LeastSquares().locate, [obs])
    assert np.array_equal(np.argmax(excluded[0], axis=1), bad)
    assert excluded[0].sum() == len(z) and not failing.any()
    assert np.max(np.linalg.norm(est.position - truth, axis=1)) < 0.5


def test_clean_fixes_keep_their_rows():
    rng = np.random.default_rng(2)
    truth, z = _ranges(rng, n=1000)
    obs = Observation(RangeModel(std_m=0.1), z, Context(points=ANCHORS))
    _, excluded, failing = exclude_faults(LeastSquares().locate, [obs], probability=0.999)
    assert excluded[0].any(axis=1).sum() <= 5         # 0.1 % expected: 1 in 1000
    assert not failing.any()


def test_a_fix_with_no_row_to_spare_is_reported_failing_not_changed():
    rng = np.random.default_rng(3)
    _, z = _ranges(rng, n=20)
    z = z[:, :4]
    z[:, 0] += 100.0
    obs = Observation(RangeModel(std_m=0.1), z, Context(points=ANCHORS[:4]))
    _, excluded, failing = exclude_faults(LeastSquares().locate, [obs])
    assert excluded[0].sum() == 20                    # 4 rows, 2 unknowns: one can go
    obs3 = Observation(RangeModel(std_m=0.1), z[:, :3], Context(points=ANCHORS[:3]))
    _, excluded3, failing3 = exclude_faults(LeastSquares().locate, [obs3])
    assert not excluded3[0].any() and failing3.all()  # 3 rows: the last spare one is kept


def test_a_batch_excludes_what_each_fix_alone_excludes():
    """Anchors that move (points per fix) and a noise per row and fix: the batch leaves out
    the rows, and ends at the positions, that each fix run on its own does."""
    rng = np.random.default_rng(5)
    truth, z = _ranges(rng, n=12)
    points = ANCHORS[None] + rng.uniform(-1, 1, (12, 6, 2))
    z = np.linalg.norm(truth[:, None] - points, axis=-1) + 0.1 * rng.standard_normal((12, 6))
    std = rng.uniform(0.08, 0.12, (12, 6))
    z[::2, 3] += 60.0
    z[::3, 1] += 45.0
    est, excluded, failing = exclude_faults(
        LeastSquares().locate, [Observation(RangeModel(std_m=0.1), z, Context(points=points), std)])
    for i in range(12):
        one = Observation(RangeModel(std_m=0.1), z[i:i + 1], Context(points=points[i:i + 1]),
                          std[i:i + 1])
        est_i, excluded_i, failing_i = exclude_faults(LeastSquares().locate, [one])
        assert np.array_equal(excluded_i[0][0], excluded[0][i]), i
        assert failing_i[0] == failing[i]
        np.testing.assert_allclose(est_i.position[0], est.position[i], atol=1e-9)
    assert np.array_equal(excluded[0][:, 3], np.arange(12) % 2 == 0)


def test_a_fit_that_fails_whatever_is_left_out_ends_the_search():
    from radioloc.core.results import Estimate

    rng = np.random.default_rng(4)
    _, z = _ranges(rng, n=5)
    obs = Observation(RangeModel(std_m=0.1), z, Context(points=ANCHORS))
    never = lambda o: Estimate(np.full((5, 2), np.nan), None, None, {})     # noqa: E731
    _, excluded, failing = exclude_faults(never, [obs])
    assert not excluded[0].any() and not failing.any()     # no row is used: nothing to test


def _rmse(method, fault, seed, kind, **options):
    log = walk_log(fault, seed, kind=kind)
    request = LocateRequest(log.measurements.copy(), log.anchors.copy(),
                            options={**log.options, **options})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_method(method, request)
    err = reference_errors(out, log.reference)["error_m"].to_numpy()
    return float(np.sqrt(np.mean(err ** 2))), out.attrs["summary"]


@pytest.mark.slow
@pytest.mark.parametrize("method,kind", [("lsq", "tdoa"), ("lsq", "range"), ("ekf-track", "tdoa"),
                                         ("ekf-track", "range"), ("gn", "range")])
def test_gross_errors_in_8_percent_of_rows_cost_at_most_20_percent(method, kind):
    """TDoA steps of 25-100 m or range spikes of 40-250 m in 8 % of the rows: the RMSE over
    3 logs stays within 20 % of the same logs without them (gn: with -o exclude_faults=1)."""
    options = {"lsq": {"on_degenerate": "skip"}, "gn": {"exclude_faults": "1"}}.get(method, {})
    clean = np.mean([_rmse(method, "clean", s, kind, **options)[0] for s in range(3)])
    runs = [_rmse(method, "spikes", s, kind, **options) for s in range(3)]
    assert np.mean([r for r, _ in runs]) < 1.2 * clean
    if method in ("lsq", "gn"):
        assert all(summary["rows_excluded"] > 0 for _, summary in runs)
