"""Gauss-Newton multilateration and the anchor CRB."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radioloc.bounds.anchors import range_crb
from radioloc.core.errors import GeometryError, InputError
from radioloc.core.geometry import distances
from radioloc.estimators.multilateration import gauss_newton

SQUARE = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]])
coord = st.floats(1.0, 99.0, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(x=coord, y=coord)
def test_noise_free_ranges_give_the_true_position(x, y):
    truth = np.array([x, y])
    fit = gauss_newton(distances(truth, SQUARE), SQUARE, range_std_m=1.0)
    np.testing.assert_allclose(fit.position, truth, atol=1e-6)
    assert fit.converged


def test_three_dimensions_with_five_anchors():
    anchors = np.array([[0, 0, 0], [10, 0, 1], [0, 10, 2], [10, 10, 8], [5, 5, 10.0]])
    truth = np.array([3.0, 6.0, 4.0])
    fit = gauss_newton(distances(truth, anchors), anchors, range_std_m=0.1)
    np.testing.assert_allclose(fit.position, truth, atol=1e-6)


def test_batch_equals_one_by_one():
    rng = np.random.default_rng(1)
    truth = rng.uniform(0, 100, (40, 2))
    r = distances(truth[:, None], SQUARE) + rng.normal(0, 2.0, (40, 4))
    w = (rng.uniform(size=(40, 4)) > 0.15).astype(float)
    w[:, :3] = 1.0
    batch = gauss_newton(r, SQUARE, weights=w)
    for i in range(40):
        one = gauss_newton(r[i], SQUARE, weights=w[i])
        np.testing.assert_allclose(batch.position[i], one.position, atol=1e-9)
        np.testing.assert_allclose(batch.covariance[i], one.covariance, rtol=1e-7)


def test_missing_range_may_be_nan_when_weight_is_zero():
    truth = np.array([30.0, 40.0])
    r = distances(truth, SQUARE)
    r[2] = np.nan
    fit = gauss_newton(r, SQUARE, weights=[1, 1, 0, 1], range_std_m=0.5)
    np.testing.assert_allclose(fit.position, truth, atol=1e-6)


def test_monte_carlo_covariance_matches_the_crb_at_small_noise():
    rng = np.random.default_rng(3)
    truth = np.array([20.0, 70.0])
    std = 0.05
    r = distances(truth, SQUARE) + rng.normal(0, std, (4000, 4))
    fit = gauss_newton(r, SQUARE, range_std_m=std)
    emp = np.cov((fit.position - truth).T)
    crb = range_crb(truth, SQUARE, std**2)
    np.testing.assert_allclose(np.trace(emp), np.trace(crb), rtol=0.1)
    np.testing.assert_allclose(fit.covariance[0], crb, rtol=1e-3)


def test_nan_range_is_rejected_naming_the_index():
    r = distances(np.array([5.0, 5.0]), SQUARE)
    r[1] = np.nan
    with pytest.raises(InputError, match=r"ranges: invalid range nan at index \(1,\)"):
        gauss_newton(r, SQUARE)


def test_negative_range_is_rejected():
    with pytest.raises(InputError, match="ranges"):
        gauss_newton([10.0, -1.0, 3.0, 4.0], SQUARE)


def test_too_few_anchors_is_a_geometry_error():
    with pytest.raises(GeometryError, match="2 ranges, 3 needed"):
        gauss_newton([10.0, 20.0], SQUARE[:2])


def test_collinear_anchors_are_a_geometry_error():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    truth = np.array([12.0, 5.0])
    with pytest.raises(GeometryError, match="collinear"):
        gauss_newton(distances(truth, line), line, range_std_m=1.0)


def test_shape_mismatch_is_an_input_error():
    with pytest.raises(InputError, match="3 ranges per problem but 4 anchors"):
        gauss_newton([1.0, 2.0, 3.0], SQUARE)


def test_crb_of_collinear_anchors_is_a_geometry_error():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    with pytest.raises(GeometryError, match="singular"):
        range_crb(np.array([5.0, 0.0]), line, 1.0)
