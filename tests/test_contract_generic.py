"""The estimator contract for the generic estimators: every class of
``radioloc.estimators.ESTIMATORS`` whose ``tags.generic`` is set, times every model case of
``tests/model_cases.py`` its tags accept (``Tags.accepts`` and ``Tags.dims``; a snapshot
estimator only on a case one epoch determines). The pairs are generated: a new generic
estimator or a new model case is checked without a new test case.

Per pair: the result type and shapes (``Estimate`` for a snapshot, ``Track`` for a
recursive estimator; batch axes lead, coordinates last, ``(x, y)`` order), accuracy at low
noise (``model_cases.tolerance_m``: the case's, times ``SAMPLING_FACTOR`` for a particle
filter), batch equals one-by-one (``1e-9``: the particle filter takes one seed per run, so
a run draws the same alone as in the batch), a NaN measurement skipped, and a translated
scene translating the estimate. A model the tags refuse is refused with a
:class:`ConfigError` naming it (a dimension the estimator lacks: an error naming the
dimension).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from model_cases import (
    CASES,
    accepted,
    final,
    generic_estimators,
    pairs,
    solve,
    tolerance_m,
    truth_of,
)

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import DIAGNOSTICS, Estimate, Track
from radioloc.estimators import ESTIMATORS
from radioloc.models.measurement import MeasurementModel

PAIRS = pairs()
REFUSED = [(cls, name) for cls in generic_estimators() for name, case in CASES.items()
           if not accepted(cls, case)]
SHIFT = np.array([1234.5, -987.25, 3.0])


def _id(pair):
    return f"{pair[0].__name__}-{pair[1]}"


@pytest.fixture(scope="module")
def problems():
    return {name: case.problem() for name, case in CASES.items()}


def test_every_generic_estimator_runs_every_model_it_accepts():
    """The matrix: every generic estimator and every case is either a pair that runs, a
    refusal, or a snapshot estimator on a case one epoch cannot fix; every estimator has
    at least one pair, and so has every measurement model class of ``radioloc.models``."""
    generic = generic_estimators()
    assert len(generic) >= 4
    for cls in generic:
        ran = {n for c, n in PAIRS if c is cls}
        refused = {n for c, n in REFUSED if c is cls}
        not_fixed = {n for n, case in CASES.items()
                     if not cls.tags.recursive and not case.snapshot and accepted(cls, case)}
        assert ran, f"{cls.__name__}: no model case"
        assert ran | refused | not_fixed == set(CASES), cls.__name__
        assert not (ran & refused)
    modelled = {type(m) for case in CASES.values() for m in case.models}
    from radioloc import models
    classes = {v for v in vars(models).values()
               if isinstance(v, type) and issubclass(v, MeasurementModel) and v is not MeasurementModel}
    assert classes <= modelled, f"models without a case: {classes - modelled}"
    for cls in ESTIMATORS:
        assert cls.tags.generic == (cls in generic)


@pytest.mark.parametrize("pair", PAIRS, ids=_id)
def test_result_type_shapes_and_accuracy(pair, problems):
    cls, name = pair
    p = problems[name]
    case = CASES[name]
    res = solve(cls, p)
    B, T, D = p.truth.shape
    if cls.tags.recursive:
        assert isinstance(res, Track), type(res)
        assert res.position.shape == (B, T, D)
        assert res.time.shape[-1] == T
    else:
        assert isinstance(res, Estimate), type(res)
        assert res.position.shape == (B, D)
    if res.covariance is not None:
        assert res.covariance.shape == res.position.shape + (D,)
        assert np.all(np.isfinite(res.covariance))
    assert np.all(np.isfinite(res.position))
    truth = truth_of(cls, p)
    err = np.linalg.norm(final(res) - truth, axis=-1)
    swapped = truth.copy()
    swapped[:, :2] = truth[:, 1::-1]
    assert np.all(err < tolerance_m(cls, case)), f"{cls.__name__} on {name}: errors {err}"
    assert np.all(np.linalg.norm(final(res) - swapped, axis=-1) > err), "(y, x) order"
    unknown = set(res.diagnostics) - set(DIAGNOSTICS)
    assert not unknown, f"diagnostics not in core.results.DIAGNOSTICS: {sorted(unknown)}"


@pytest.mark.parametrize("pair", PAIRS, ids=_id)
def test_batch_equals_one_by_one(pair, problems):
    cls, name = pair
    p = problems[name]
    whole = solve(cls, p)
    for i in range(p.truth.shape[0]):
        one = solve(cls, p, slice(i, i + 1))
        np.testing.assert_allclose(one.position[0], whole.position[i], rtol=0, atol=1e-9,
                                   err_msg=f"{cls.__name__} on {name}, run {i}")


@pytest.mark.parametrize("pair", PAIRS, ids=_id)
def test_nan_measurement_is_skipped(pair, problems):
    cls, name = pair
    p = problems[name]
    z = [o.z.copy() for o in p.observations]
    z[0][:, 0 if not cls.tags.recursive else 3, 1] = np.nan
    res = solve(cls, p.with_values(z))
    assert np.all(np.isfinite(res.position))
    if res.covariance is not None:
        assert np.all(np.isfinite(res.covariance))
    err = np.linalg.norm(final(res) - truth_of(cls, p), axis=-1)
    assert np.all(err < 2 * tolerance_m(cls, CASES[name])), err


@pytest.mark.parametrize("pair", PAIRS, ids=_id)
def test_translating_the_scene_translates_the_estimate(pair, problems):
    cls, name = pair
    case = CASES[name]
    shift = SHIFT[:case.dim]
    base = final(solve(cls, problems[name]))
    moved = final(solve(cls, case.problem(shift=shift)))
    np.testing.assert_allclose(moved - shift, base, atol=1e-6, rtol=0,
                               err_msg=f"{cls.__name__} on {name}")


@pytest.mark.parametrize("pair", REFUSED, ids=_id)
def test_a_model_the_tags_refuse_is_refused_by_name(pair, problems):
    cls, name = pair
    case = CASES[name]
    model = next(m for m in case.models if not cls.tags.accepts(m)) \
        if not all(cls.tags.accepts(m) for m in case.models) else case.models[0]
    # a model the tags refuse is named; a dimension the estimator lacks names the dimension
    named = type(model).__name__ if case.dim in cls.tags.dims else f"{min(cls.tags.dims)}-D"
    with pytest.raises((ConfigError, InputError), match=named):
        solve(cls, problems[name])


@pytest.mark.parametrize("cls", [c for c in generic_estimators() if c.tags.recursive],
                         ids=lambda c: c.__name__)
def test_an_asymmetric_or_tiny_prior_covariance_is_refused_by_name(cls, problems):
    """Every recursive generic estimator checks its prior covariance the same way: an
    asymmetric matrix (a solver reading one triangle would use half of it) is refused
    naming ``prior_cov``; a variance of 1e-300 is refused where the estimator inverts the
    prior (naming ``prior_cov``), else gives a finite track."""
    name = next(n for c, n in PAIRS if c is cls)
    p = problems[name]
    lopsided = p.prior_cov.copy()
    lopsided[0, 1] = 0.3
    with pytest.raises(InputError, match="prior_cov.*symmetric"):
        solve(cls, replace(p, prior_cov=lopsided))
    tiny = p.prior_cov.copy()
    tiny[0, 0] = 1e-300
    try:
        res = solve(cls, replace(p, prior_cov=tiny))
    except InputError as exc:
        assert "prior_cov" in str(exc), exc
    else:
        assert np.all(np.isfinite(res.position)) and np.all(np.isfinite(res.covariance))
