"""Tests of the per-RSSI trapezoid model (paper 003, Sect. III)."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radioloc.core.errors import InputError
from radioloc.models.rssi_trapezoid import (
    RSSI_LEVELS, TrapezoidModel, dbm_to_rssi100, fit_raw, fit_trapezoid_model, smooth, trapezoid)


def test_trapezoid_shape_known_values():
    # mu=5, tau=1, sigma=2: flat on [4, 6], zero beyond 2 and 8, halfway at 3 / 7
    d = np.array([1.9, 3.0, 4.0, 5.0, 6.0, 7.0, 8.1])
    np.testing.assert_allclose(trapezoid(d, 5.0, 1.0, 2.0), [0, 0.5, 1, 1, 1, 0.5, 0])


def test_fit_recovers_known_trapezoid_row():
    # distances uniform on [a, b] for one RSSI value: mu -> (a+b)/2, tau -> (b-a)/2, sigma -> std
    rng = np.random.default_rng(1)
    a, b = 3.0, 9.0
    d = rng.uniform(a, b, 20000)
    mu, tau, sigma, count = fit_raw(np.full(d.size, 40), d, tau_min=0.5, sigma_min=0.1)
    assert count[40] == d.size and np.isnan(mu[39])
    assert mu[40] == pytest.approx((a + b) / 2, abs=0.01)
    assert tau[40] == pytest.approx((b - a) / 2, abs=0.01)
    assert sigma[40] == pytest.approx((b - a) / np.sqrt(12), rel=0.02)


def test_minimum_widths_enforced():
    mu, tau, sigma, _ = fit_raw([10, 10], [4.0, 4.0], tau_min=0.7, sigma_min=0.3)
    assert tau[10] == 0.7 and sigma[10] == 0.3 and mu[10] == 4.0


def test_full_model_recovers_rows_generated_from_known_trapezoids():
    # each RSSI row draws distances uniformly from a known interval; smoothing with window 0
    rng = np.random.default_rng(2)
    rows = np.arange(RSSI_LEVELS)
    centre = 30.0 - 0.25 * rows                     # decreasing distance with RSSI
    d = centre[:, None] + rng.uniform(-1.0, 1.0, (RSSI_LEVELS, 4000))
    r = np.repeat(rows, 4000)
    model = fit_trapezoid_model(r, d.ravel(), tau_min=0.2, sigma_min=0.2, window=0)
    np.testing.assert_allclose(model.mu, centre, atol=0.02)
    np.testing.assert_allclose(model.tau + model.sigma, 1.0 + 2 / np.sqrt(12), atol=0.05)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 100), st.floats(0.0, 50.0)), min_size=1, max_size=60),
       st.integers(0, 4))
def test_smoothing_gives_monotone_complete_boundaries(pairs, window):
    r, d = np.array(pairs, dtype=float).T
    model = fit_trapezoid_model(r, d, tau_min=0.3, sigma_min=0.2, window=window)
    assert np.all(np.isfinite(model.mu))
    # boundaries do not decrease as RSSI decreases
    assert np.all(np.diff(model.lower) <= 1e-9)
    assert np.all(np.diff(model.upper) <= 1e-9)
    assert np.all(model.sigma >= 0.2 - 1e-12)
    assert np.all(model.tau + model.sigma >= 0.5 - 1e-9)


def test_gap_filled_by_interpolation():
    mu = np.full(RSSI_LEVELS, np.nan); tau = mu.copy(); sigma = mu.copy()
    mu[[20, 40]] = [20.0, 10.0]; tau[[20, 40]] = 1.0; sigma[[20, 40]] = 1.0
    model = smooth(mu, tau, sigma, np.zeros(RSSI_LEVELS), window=0, tau_min=0.5, sigma_min=0.5)
    assert model.mu[30] == pytest.approx(15.0)
    assert model.mu[0] == pytest.approx(20.0) and model.mu[100] == pytest.approx(10.0)


def test_likelihood_vectorised_equals_elementwise(tmp_path):
    rng = np.random.default_rng(3)
    model = fit_trapezoid_model(rng.integers(20, 90, 500), rng.uniform(0, 30, 500))
    d = rng.uniform(0, 40, (7, 5))
    r = rng.integers(0, 101, (7, 1))
    L = model.likelihood(d, r)
    ref = np.array([[model.likelihood(d[i, j], r[i, 0]) for j in range(5)] for i in range(7)])
    np.testing.assert_array_equal(L, ref)
    back = TrapezoidModel.load(model.save(tmp_path / "m.json"))
    np.testing.assert_array_equal(back.likelihood(d, r), L)


def test_density_integrates_to_one():
    model = fit_trapezoid_model([50, 50, 50], [5.0, 6.0, 9.0])
    dd = np.linspace(0, 40, 400001)
    assert np.trapezoid(model.density(dd, 50), dd) == pytest.approx(1.0, abs=1e-3)


def test_rssi_out_of_range_raises():
    model = fit_trapezoid_model([50], [5.0])
    with pytest.raises(InputError, match="rssi"):
        model.likelihood(3.0, 101)
    with pytest.raises(InputError, match="rssi"):
        model.likelihood(3.0, -1)
    with pytest.raises(InputError, match="rssi"):
        model.likelihood(3.0, 50.5)
    with pytest.raises(InputError, match="rssi"):
        fit_trapezoid_model([120], [1.0])
    with pytest.raises(InputError, match="dist"):
        model.likelihood(-1.0, 50)


def test_dbm_map_is_affine_and_clipped():
    np.testing.assert_array_equal(dbm_to_rssi100([-110, -60, -10, -130, 0]), [0, 50, 100, 0, 100])
    with pytest.raises(InputError, match="dbm_max"):
        dbm_to_rssi100(-50, dbm_min=-10, dbm_max=-20)


def test_load_bad_file_raises(tmp_path):
    f = tmp_path / "bad.json"
    f.write_text('{"mu": [1, 2]}')
    with pytest.raises(InputError, match="tau"):
        TrapezoidModel.load(f)
