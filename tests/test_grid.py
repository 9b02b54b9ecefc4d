"""Tests of the batched grid Bayes filter (paper 003, Algorithms 1-3, BlurGrid, ShiftGrid)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radioloc.core.errors import InputError, RadiolocError
from radioloc.estimators.grid import (
    GridGeometry, blur_grid, get_location, get_uncertainty, probability_update, shift_grid)
from radioloc.models.rssi_trapezoid import fit_trapezoid_model

GEOM = GridGeometry.centred(20, 16, 1.0)


def _model():
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 25, 4000)
    r = np.clip(np.rint(80 - 2.5 * d + rng.normal(0, 4, d.size)), 0, 100)
    return fit_trapezoid_model(r, d, tau_min=0.5, sigma_min=0.5, window=2)


MODEL = _model()


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from([1e-7, 1e-5, 1e-4]))
def test_posterior_sums_to_one_and_respects_floor(seed, eps):
    rng = np.random.default_rng(seed)
    p = GEOM.uniform(3)
    for _ in range(5):
        pos = rng.uniform(-8, 8, (3, 2))
        p = probability_update(p, GEOM, pos, rng.integers(0, 101, 3), MODEL, eps)
        np.testing.assert_allclose(p.sum(axis=(1, 2)), 1.0, rtol=1e-12)
        assert p.min() >= eps * (1 - 1e-12)
        p = blur_grid(p, GEOM, rng.uniform(0, 3, 3), eps)
        assert p.min() >= eps * (1 - 1e-12)
        p = shift_grid(p, GEOM, rng.uniform(-2, 2, (3, 2)), eps)
        np.testing.assert_allclose(p.sum(axis=(1, 2)), 1.0, rtol=1e-12)
        assert p.min() >= eps * (1 - 1e-12)


def test_update_batched_equals_one_by_one():
    rng = np.random.default_rng(5)
    p = rng.uniform(0.5, 1.0, (4, GEOM.h, GEOM.w))
    p /= p.sum(axis=(1, 2), keepdims=True)
    pos = rng.uniform(-5, 5, (4, 2))
    r = rng.integers(30, 80, 4)
    both = probability_update(p, GEOM, pos, r, MODEL, 1e-6)
    for b in range(4):
        one = probability_update(p[b:b + 1], GEOM, pos[b:b + 1], r[b:b + 1], MODEL, 1e-6)
        np.testing.assert_allclose(both[b], one[0])
    np.testing.assert_allclose(get_location(both, GEOM)[2], get_location(both[2:3], GEOM)[0])


def test_location_of_symmetric_peak_is_its_centre():
    p = np.full((1, GEOM.h, GEOM.w), 1e-6)
    p[0, 7, 9] = 1.0
    p[0, 6:9, 8:11] += 0.3             # symmetric 3x3 shoulder
    p /= p.sum()
    np.testing.assert_allclose(get_location(p, GEOM)[0], [GEOM.x[9], GEOM.y[7]], atol=1e-12)


def test_location_offset_is_a_vector():
    # one heavier neighbour to the left-below pulls the estimate left-below (|.| as a vector)
    p = np.full((1, GEOM.h, GEOM.w), 1e-6)
    p[0, 7, 9] = 1.0
    p[0, 6, 8] = 0.5
    loc = get_location(p, GEOM)[0]
    assert loc[0] < GEOM.x[9] and loc[1] < GEOM.y[7]


def test_location_converges_to_truth_without_noise():
    # noise-free RSSI from the model's own rows: posterior peak near the true position
    truth = np.array([3.2, -2.7])
    rng = np.random.default_rng(7)
    p = GEOM.uniform(1)
    for _ in range(40):
        pos = rng.uniform(-8, 8, (1, 2))
        d = np.hypot(*(pos[0] - truth))
        r = np.argmin(np.abs(MODEL.mu - d))           # RSSI whose trapezoid centres on d
        p = probability_update(p, GEOM, pos, [r], MODEL, 1e-9)
    assert np.hypot(*(get_location(p, GEOM)[0] - truth)) < 1.0
    assert get_uncertainty(p, GEOM)[0] < 2.0


def test_uncertainty_known_answer():
    p = np.zeros((1, GEOM.h, GEOM.w))
    p[0, 5, 5] = 0.5
    p[0, 5, 8] = 0.25
    p[0, 9, 5] = 0.25
    # sqrt(0.25 * 3^2 + 0.25 * 4^2) with 1 m cells
    assert get_uncertainty(p, GEOM)[0] == pytest.approx(np.sqrt(0.25 * 9 + 0.25 * 16))


def test_whole_cell_shift_moves_peak_one_cell():
    rng = np.random.default_rng(2)
    p = rng.uniform(0.1, 1.0, (2, GEOM.h, GEOM.w))
    p /= p.sum(axis=(1, 2), keepdims=True)
    q = shift_grid(p, GEOM, [[1.0, 0.0], [0.0, -1.0]])
    a = np.unravel_index(p[0].argmax(), p[0].shape)
    b = np.unravel_index(q[0].argmax(), q[0].shape)
    if a[1] + 1 < GEOM.w:
        assert b == (a[0], a[1] + 1)
    # interior values move exactly (up to renormalisation)
    ratio = q[0, :, 1:] / p[0, :, :-1]
    np.testing.assert_allclose(ratio, ratio[0, 0])
    ratio = q[1, :-1, :] / p[1, 1:, :]
    np.testing.assert_allclose(ratio, ratio[0, 0])


def test_subcell_shift_moves_location_by_shift():
    p = np.zeros((1, GEOM.h, GEOM.w))
    p[0, 6:9, 8:11] = [[0.5, 1, 0.5], [1, 2, 1], [0.5, 1, 0.5]]
    p /= p.sum()
    q = shift_grid(p, GEOM, [[0.5, 0.0]])
    mean_x = lambda g: (g[0].sum(axis=0) * GEOM.x).sum()
    assert mean_x(q) - mean_x(p) == pytest.approx(0.5)


def test_blur_conserves_centre_and_spreads():
    p = np.zeros((2, GEOM.h, GEOM.w))
    p[:, 8, 10] = 1.0
    q = blur_grid(p, GEOM, [0.0, 1.5])
    np.testing.assert_allclose(q[0], p[0], atol=1e-12)
    assert q[1].max() < 0.2
    np.testing.assert_allclose((q[1].sum(axis=0) * GEOM.x).sum(), GEOM.x[10], atol=1e-9)
    # variance of the blurred peak is the blur radius squared (as a std)
    var_x = (q[1].sum(axis=0) * (GEOM.x - GEOM.x[10]) ** 2).sum()
    assert var_x == pytest.approx(1.5**2, rel=0.02)


def test_bad_inputs_raise():
    p = GEOM.uniform(2)
    with pytest.raises(InputError, match="rssi"):
        probability_update(p, GEOM, np.zeros((2, 2)), [50, 101], MODEL, 1e-6)
    with pytest.raises(InputError, match="tracker_xy"):
        probability_update(p, GEOM, np.zeros((3, 2)), [50, 50], MODEL, 1e-6)
    with pytest.raises(InputError, match="grid"):
        get_location(np.ones((2, 3, 3)), GEOM)
    with pytest.raises(InputError, match="radius_m"):
        blur_grid(p, GEOM, -1.0)
    with pytest.raises(RadiolocError, match="cell_m"):
        GridGeometry(3, 3, 0.0)
