"""The iterative BLUE of paper 002 (ClosedFormTracker): the compiled iterations against the
NumPy definition (eq. (7)-eq. (15), an LU solve of S Sigma S' per step) through the public
API, and the invariants of both backends."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, GeometryError
from radioloc.estimators.closed_form import ClosedFormTracker
from radioloc.models.motion import ConstantVelocity
from radioloc.sim.single_sensor import circular_sensor_path

T = 0.1
TOL = 1e-10
KEYS = ("state", "state_covariance", "ols_state", "trajectory")


def _tracks(rng, runs, n, q=0.15, xi=0.1, sensor=None):
    sensor = circular_sensor_path(n, 5.0, 1.3) if sensor is None else sensor
    x0 = np.concatenate([rng.uniform(-2, 2, (runs, 2)), rng.normal(0, 1, (runs, 2))], -1)
    tracks = ConstantVelocity(q).simulate(x0, n, T, rng)
    r = np.linalg.norm(tracks[..., :2] - sensor, axis=-1)
    return np.abs(r + rng.normal(0, np.sqrt(xi), r.shape)), sensor


def _both(r, s, q, xi, **kw):
    return [ClosedFormTracker(q, std_m=np.sqrt(xi), backend=b, **kw).locate(r, s, T).diagnostics
            for b in ("numba", "numpy")]


def _agree(got, ref, tol=TOL):
    for key in KEYS:
        np.testing.assert_allclose(got[key], ref[key], rtol=0,
                                   atol=tol * np.abs(ref[key]).max())
    for key in ("iterations", "converged", "stalled", "used_differences"):
        np.testing.assert_array_equal(got[key], ref[key])


@pytest.mark.parametrize("opts", [dict(), dict(printed_eq14=True),
                                  dict(range_excess_kurtosis=-1.2, accel_excess_kurtosis=-1.2),
                                  dict(reference_index=0), dict(reference_index=7),
                                  dict(stopping="criterion", tol=1e-6)])
def test_backends_agree_for_each_option(opts):
    r, s = _tracks(np.random.default_rng(3), 25, 20)
    _agree(*_both(r, s, 0.15, 0.1, **opts))


def test_backends_agree_on_long_windows():
    # n = 60: S Sigma S' is ill conditioned enough that Cholesky and LU differ beyond 1e-10
    r, s = _tracks(np.random.default_rng(2), 40, 60)
    _agree(*_both(r, s, 0.15, 0.1), tol=1e-8)


def test_backends_agree_with_missing_samples_per_track_sensors_and_variances():
    rng = np.random.default_rng(4)
    n = 18
    s = circular_sensor_path(n, 5.0, 1.3)[None] + rng.normal(0, 0.3, (12, n, 2))
    r, _ = _tracks(rng, 12, n, sensor=s)
    r[::3, 5] = np.nan
    r[1, [0, 17]] = np.nan
    xi = rng.uniform(0.05, 0.2, (12, n))
    _agree(*_both(r, s, 0.15, xi))
    _agree(*_both(r, s[0], 0.15, 0.1))                      # one shared path, NaNs


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_missing_first_sample_gives_the_estimate_without_it(backend):
    rng = np.random.default_rng(35)
    n = 30
    r, s = _tracks(rng, 3, n)
    r[1, 0] = np.nan
    tr = ClosedFormTracker(0.15, std_m=np.sqrt(0.1), backend=backend)
    got = tr.locate(r, s, T).diagnostics["state"][1]
    cut = tr.locate(r[1, 1:], s[1:], T).diagnostics["state"]
    np.testing.assert_allclose(got, cut, rtol=0, atol=1e-9 * np.abs(cut).max())


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_batch_equals_one_by_one_and_batch_shape(backend):
    r, s = _tracks(np.random.default_rng(5), 6, 15)
    r[3, 9] = np.nan
    tr = ClosedFormTracker(0.15, std_m=np.sqrt(0.1), backend=backend)
    batch = tr.locate(r.reshape(2, 3, 15), s, T)
    assert batch.position.shape == (2, 3, 2)
    for i in range(6):
        one = tr.locate(r[i], s, T).diagnostics
        for key in ("state", "state_covariance", "iterations"):
            np.testing.assert_allclose(one[key], batch.diagnostics[key].reshape(
                (6,) + one[key].shape)[i], rtol=1e-13, atol=0)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_noise_free_track_is_recovered(backend):
    n = 20
    sensor = circular_sensor_path(n, 5.0, 1.3)
    truth = np.array([1.0, 0.5]) + (np.arange(n) - (n - 1))[:, None] * T * [0.8, -0.2]
    est = ClosedFormTracker(1e-12, std_m=1e-5, backend=backend).locate(
        np.linalg.norm(truth - sensor, axis=-1), sensor, T)
    np.testing.assert_allclose(est.diagnostics["state"], [1.0, 0.5, 0.8, -0.2], atol=1e-6)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_converged_and_stalled_flags_follow_their_rules(backend):
    r, s = _tracks(np.random.default_rng(20), 40, 30)
    got = ClosedFormTracker(0.15, std_m=np.sqrt(0.1), stopping="criterion", tol=1e-9, max_iter=15,
                            backend=backend).locate(r, s, T).diagnostics
    assert got["stalled"].any()                         # tol = 1e-9: most tracks stall
    assert not np.any(got["stalled"] & got["converged"])
    assert np.all(got["iterations"][got["stalled"]] >= 1)
    loose = ClosedFormTracker(0.15, std_m=np.sqrt(0.1), max_iter=50, backend=backend).locate(r, s, T)
    assert loose.diagnostics["converged"].all() and not loose.diagnostics["stalled"].any()


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_bad_input_raises(backend):
    n = 12
    s = circular_sensor_path(n, 5.0, 1.3)
    r = np.tile(np.linalg.norm(np.array([1.0, 0.5]) - s, axis=-1), (20, 1))
    with pytest.raises(GeometryError, match="singular"):
        ClosedFormTracker(0.0, std_m=0.0, backend=backend).locate(r, s, T)
    r, s = _tracks(np.random.default_rng(37), 20, n)
    r[5, 2:10] = np.nan                          # 1 of 9 difference rows left
    with pytest.raises(GeometryError, match="ranges.*track 5"):
        ClosedFormTracker(0.15, std_m=np.sqrt(0.1), backend=backend).locate(r, s, T)
    with pytest.raises(ConfigError, match="backend"):
        ClosedFormTracker(0.15, std_m=np.sqrt(0.1), backend="cuda")
