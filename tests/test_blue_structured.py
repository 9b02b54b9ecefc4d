"""The O(n) structured factorisation of ``W = S Sigma S'`` in the compiled BLUE
(``closed_form._structured_gram``) against the dense Cholesky of the same kernel
(``closed_form._STRUCTURED = False``) and the plain NumPy path (``_reference``: W built by
``SquaredRangeModel.differenced_covariance``, LU solves).

Tolerance: W is ill-conditioned (condition number about 1e3 at n = 10, 1e6 at n = 30,
1e8-1e10 at n = 60, up to 1e12 with a near-ideal channel), so two exact factorisations
of it differ by rounding amplified by that condition number. Measured on random tracks,
the structured and the dense factorisation differ by about as much as the dense Cholesky
and NumPy's LU solve (state up to 8e-11 relative, covariance up to 2e-9 of its largest
entry, at n = 60). The tests allow 1e-8 relative on the state and 1e-6 on the covariance:
the same bound the compiled kernel is held to against NumPy in
tests/test_closed_form_kernels.py, two orders above the measured spread."""

import numpy as np
import pytest

from radioloc.core.errors import GeometryError
from radioloc.estimators import closed_form as cf
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.models.single_sensor import SquaredRangeModel, difference_both
from radioloc.models.track_noise import squared_noise_covariance
from radioloc.sim.single_sensor import circular_sensor_path
from test_closed_form_kernels import T, _reference, _tracks

STATE_RTOL, COV_RTOL = 1e-8, 1e-6


def _run(tr, r, s, structured):
    """``tr.locate`` with the structured or the dense factorisation; also returns the
    kernel's flags (bit 3: the dense factorisation ran)."""
    seen = []
    run = cf._run_blue_kernel

    def spy(B, args):
        run(B, args)
        seen.append(args[-1].copy())

    old = cf._STRUCTURED
    cf._STRUCTURED, cf._run_blue_kernel = structured, spy
    try:
        est = tr.locate(r, s, T)
    finally:
        cf._STRUCTURED, cf._run_blue_kernel = old, run
    return est.diagnostics, np.concatenate(seen)


def _close(got, ref):
    scale = np.abs(ref["state"]).max()
    np.testing.assert_allclose(got["state"], ref["state"], rtol=0, atol=STATE_RTOL * scale)
    cov_scale = np.abs(ref["state_covariance"]).max(axis=(-1, -2), keepdims=True)
    assert np.all(np.abs(got["state_covariance"] - ref["state_covariance"])
                  <= COV_RTOL * cov_scale)
    np.testing.assert_array_equal(got["iterations"], ref["iterations"])


@pytest.mark.parametrize("k", [0, 7, 19])
def test_generators_reproduce_the_motion_noise_covariance(k):
    n, q = 20, 0.15
    model = SquaredRangeModel(n, k, T, q)
    gu, gv = cf._noise_generators(n, k, T, q)
    assert gu.shape == gv.shape == ((2 if k in (0, n - 1) else 4), n)
    upper = np.triu_indices(n, 1)
    np.testing.assert_allclose((gu.T @ gv)[upper], model.c[upper], rtol=1e-12,
                               atol=1e-14 * np.abs(model.c).max())


@pytest.mark.parametrize("k,kappa", [(0, 0.0), (9, -1.2), (19, 0.0), (19, -1.2)])
def test_differenced_squared_noise_is_a_band_of_half_width_3(k, kappa):
    n = 20
    c2 = 2.0 * squared_noise_covariance(n, k, T, 0.15, kappa)
    w = difference_both(c2)
    i, j = np.indices(w.shape)
    far = np.abs(i - j) > 3
    # rounding of the differences: 64 products of entries up to max |c2|
    assert np.abs(w[far]).max() <= 64 * 1e-15 * np.abs(c2).max()
    assert np.abs(w[~far]).max() > 1e-6 * np.abs(c2).max()


@pytest.mark.parametrize("seed,n", [(30, 10), (31, 30), (32, 60)])
def test_structured_equals_dense_and_numpy(seed, n):
    rng = np.random.default_rng(seed)
    r, s = _tracks(rng, 40, n)
    tr = ClosedFormTracker(0.15, 0.1)
    got, flags = _run(tr, r, s, True)
    dense, dflags = _run(tr, r, s, False)
    assert not np.any(flags & 8)                  # the structured path ran, no fallback
    assert np.all(dflags & 8)
    _close(got, dense)
    beta, cov, _, it = _reference(tr, r, s)
    _close(got, {"state": beta, "state_covariance": cov, "iterations": it})


@pytest.mark.parametrize("opts", [dict(printed_eq14=True), dict(reference_index=0),
                                  dict(reference_index=11), dict(accel_excess_kurtosis=-1.2,
                                                                 range_excess_kurtosis=-1.2)])
def test_structured_equals_dense_for_each_option(opts):
    rng = np.random.default_rng(33)
    r, s = _tracks(rng, 24, 30)
    tr = ClosedFormTracker(0.15, 0.1, **opts)
    got, flags = _run(tr, r, s, True)
    dense, _ = _run(tr, r, s, False)
    assert not np.any(flags & 8)
    _close(got, dense)


@pytest.mark.parametrize("q,xi", [(1e-4, 0.1), (0.15, 1e-6), (1e-3, 1e-10)])
def test_structured_equals_dense_on_ill_conditioned_noise(q, xi):
    rng = np.random.default_rng(34)
    r, s = _tracks(rng, 24, 60, q=q, xi=xi)
    tr = ClosedFormTracker(q, xi)
    got, flags = _run(tr, r, s, True)
    dense, _ = _run(tr, r, s, False)
    assert not np.any(flags & 8)
    _close(got, dense)


def test_missing_ranges_per_track_sensors_and_variances():
    rng = np.random.default_rng(35)
    n = 30
    s = circular_sensor_path(n, 5.0, 1.3)[None] + rng.normal(0, 0.3, (20, n, 2))
    r, _ = _tracks(rng, 20, n, sensor=s)
    r[::3, 5] = np.nan
    r[1, [0, n - 1]] = np.nan
    r[2, 10:13] = np.nan
    xi = rng.uniform(0.05, 0.2, (20, n))
    tr = ClosedFormTracker(0.15, xi)
    got, flags = _run(tr, r, s, True)
    assert not np.any(flags & 8)
    dense, _ = _run(tr, r, s, False)
    _close(got, dense)
    beta, cov, _, it = _reference(tr, r, s)
    _close(got, {"state": beta, "state_covariance": cov, "iterations": it})
    # a NaN at the first sample: the estimate of the series without that sample
    cut = ClosedFormTracker(0.15, xi[1:2, 1:]).locate(r[1:2, 1:], s[1:2, 1:], T)
    np.testing.assert_allclose(got["state"][1], cut.diagnostics["state"][0], rtol=0,
                               atol=STATE_RTOL * np.abs(got["state"][1]).max())


def test_batch_equals_one_by_one():
    rng = np.random.default_rng(36)
    n = 60
    r, s = _tracks(rng, 2 * cf._PARALLEL_MIN_TRACKS, n)
    r[3, 20] = np.nan
    tr = ClosedFormTracker(0.15, 0.1)
    batch = tr.locate(r, s, T).diagnostics
    for i in (0, 3, r.shape[0] - 1):
        one = tr.locate(r[i], s, T).diagnostics
        for key in ("state", "state_covariance", "iterations", "converged"):
            np.testing.assert_array_equal(one[key], batch[key][i])


def test_missing_ranges_that_leave_the_blue_unidentified_name_ranges():
    rng = np.random.default_rng(37)
    n = 12
    r, s = _tracks(rng, 20, n)
    r[5, 2:10] = np.nan                          # 1 of 9 difference rows left
    with pytest.raises(GeometryError, match="ranges") as info:
        ClosedFormTracker(0.15, 0.1).locate(r, s, T)
    assert "track 5" in str(info.value)
