"""The compiled iterative BLUE of paper 002 (``closed_form._blue_tracks``) against the plain
NumPy path of the same maths (``_differenced_system``, ``S Sigma S'`` by
``SquaredRangeModel.differenced_covariance`` and an LU solve in ``_gls``), on random tracks,
sensor paths, missing samples and model options; a track's result does not depend on the
rest of the batch."""

import numpy as np
import pytest

from radioloc.core.errors import GeometryError
from radioloc.estimators import closed_form as cf
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.models.motion import ConstantVelocity
from radioloc.models.single_sensor import SquaredRangeModel, validate_inputs
from radioloc.sim.single_sensor import circular_sensor_path

T = 0.1


def _reference(tr: ClosedFormTracker, r, s):
    """Steps 1-3d in plain NumPy: the closed-form tracker's loop with ``_gls`` (LU)."""
    r, s, k = validate_inputs(r, s, tr.reference_index, allow_nan=True)
    n = r.shape[-1]
    batch = np.broadcast_shapes(r.shape[:-1], s.shape[:-2], tr.range_var.shape[:-1])
    r = np.broadcast_to(r, batch + (n,))
    s = np.broadcast_to(s, batch + (n, 2))
    model = SquaredRangeModel(n, k, T, tr.accel_var, tr.range_var, tr.accel_excess_kurtosis,
                              tr.range_excess_kurtosis, tr.printed_eq14)
    sa, sy, keep = tr._differenced_system(r, s, k, model)
    beta = cf._ols(sa, sy)
    ols = beta.copy()
    best = np.full(batch, np.inf)
    cov = np.zeros(batch + (4, 4))
    active = np.ones(batch, bool)
    it = np.zeros(batch, int)
    for _ in range(tr.max_iter):
        if not active.any():
            break
        w = cf._mask_covariance(model.differenced_covariance(beta, s), keep)
        new, new_cov, crit = cf._gls(sa, sy, w)
        improved = (crit < best) | (tr.stopping == "change")
        take = active & improved
        change = np.sqrt(np.sum((new - beta) ** 2, axis=-1))
        beta = np.where(take[..., None], new, beta)
        cov = np.where(take[..., None, None], new_cov, cov)
        best = np.where(take, crit, best)
        it = it + take
        active = take & ~(change <= tr.tol)
    return beta, cov, ols, it


def _tracks(rng, runs, n, q=0.15, xi=0.1, sensor=None):
    sensor = circular_sensor_path(n, 5.0, 1.3) if sensor is None else sensor
    x0 = np.concatenate([rng.uniform(-2, 2, (runs, 2)), rng.normal(0, 1, (runs, 2))], -1)
    tracks = ConstantVelocity(q).simulate(x0, n, T, rng)
    r = np.linalg.norm(tracks[..., :2] - sensor, axis=-1)
    return np.abs(r + rng.normal(0, np.sqrt(xi), r.shape)), sensor


def _check(tr, r, s):
    got = tr.locate(r, s, T)
    beta, cov, ols, it = _reference(tr, r, s)
    scale = np.abs(beta).max() + 1.0
    np.testing.assert_allclose(got.diagnostics["ols_state"], ols, rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(got.diagnostics["state"], beta, rtol=0, atol=1e-7 * scale)
    np.testing.assert_allclose(got.diagnostics["state_covariance"], cov, rtol=1e-6,
                               atol=1e-9 * np.abs(cov).max())
    np.testing.assert_array_equal(got.diagnostics["iterations"], it)
    return got


@pytest.mark.parametrize("seed,n", [(0, 10), (1, 25), (2, 60)])
def test_compiled_blue_equals_numpy(seed, n):
    rng = np.random.default_rng(seed)
    r, s = _tracks(rng, 40, n)
    _check(ClosedFormTracker(0.15, 0.1), r, s)


@pytest.mark.parametrize("opts", [dict(printed_eq14=True), dict(range_excess_kurtosis=-1.2,
                                                                accel_excess_kurtosis=-1.2),
                                  dict(reference_index=0), dict(reference_index=7),
                                  dict(stopping="criterion", tol=1e-6)])
def test_compiled_blue_equals_numpy_for_each_option(opts):
    rng = np.random.default_rng(3)
    r, s = _tracks(rng, 25, 20)
    _check(ClosedFormTracker(0.15, 0.1, **opts), r, s)


def test_compiled_blue_missing_samples_per_track_sensors_and_variances():
    rng = np.random.default_rng(4)
    n = 18
    s = circular_sensor_path(n, 5.0, 1.3)[None] + rng.normal(0, 0.3, (12, n, 2))
    r, _ = _tracks(rng, 12, n, sensor=s)
    r[::3, 5] = np.nan
    r[1, [0, 17]] = np.nan
    xi = rng.uniform(0.05, 0.2, (12, n))
    _check(ClosedFormTracker(0.15, xi), r, s)
    _check(ClosedFormTracker(0.15, 0.1), r[:, :], s[0])           # one shared path, NaNs


def test_compiled_blue_batch_equals_one_by_one_and_batch_shape():
    rng = np.random.default_rng(5)
    r, s = _tracks(rng, 6, 15)
    tr = ClosedFormTracker(0.15, 0.1)
    batch = tr.locate(r.reshape(2, 3, 15), s, T)
    assert batch.position.shape == (2, 3, 2)
    for i in range(6):
        one = tr.locate(r[i], s, T)
        np.testing.assert_array_equal(one.diagnostics["state"],
                                      batch.diagnostics["state"].reshape(6, 4)[i])


def test_compiled_blue_singular_covariance_raises():
    n = 12
    s = circular_sensor_path(n, 5.0, 1.3)
    r = np.linalg.norm(np.array([1.0, 0.5]) - s, axis=-1)
    with pytest.raises(GeometryError, match="singular"):
        ClosedFormTracker(0.0, 0.0).locate(r, s, T)
