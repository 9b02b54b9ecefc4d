"""The recursive grid step leaves its posterior unnormalised with a factor per run (the next
step's column pass applies it as it reads the grid), and ``GridFilter(dtype="float32")``
stores that posterior in float32. The normalised posterior a user reads (``GridState.p``,
``estimate``) is bit for bit the one of the pipeline that normalises every step (float64),
and within the stated float32 budget (``3 T 2**-24`` relative after ``T`` steps) of it."""

import pickle

import numpy as np
import pytest

from radioloc.core.errors import ConfigError
from radioloc.core.validation import MAGNITUDE_LIMIT
from radioloc.estimators import grid_kernels as gk
from radioloc.estimators.grid import GridFilter, GridGeometry, GridState
from radioloc.models.rssi_logdistance import LogDistanceGaussian
from radioloc.models.rssi_trapezoid import as_rssi, fit_trapezoid_model

GEOM = GridGeometry.centred(70, 45, 0.5)
EPS = 1e-9
BLUR = 1.5


def _model():
    rng = np.random.default_rng(5)
    d = rng.uniform(0, 30, 6000)
    r = np.clip(np.rint(80 - 2.0 * d + rng.normal(0, 2.0, d.size)), 0, 100)
    return fit_trapezoid_model(r, d, tau_min=0.3, sigma_min=0.3, window=1)


def _readings(seed, B, T):
    rng = np.random.default_rng(seed)
    return rng.uniform(-8, 8, (T, B, 2)), rng.integers(35, 70, (T, B)).astype(float)


def _normalising_step(p, model, xy, r):
    """The step as it was before the deferred normalisation: blur, update, normalisation
    pass (public kernels of the same maths, float64 posterior)."""
    s = np.full(p.shape[0], BLUR / GEOM.cell_m)
    blk, excess, bad = gk.gaussian_blocks(p, s, EPS, np.float32, MAGNITUDE_LIMIT)
    assert bad == 0
    i = as_rssi(r)
    return gk.trapezoid_update_blocks(blk, p.shape, GEOM.x, GEOM.y, xy, model.mu[i],
                                      model.tau[i], model.sigma[i], EPS, excess)


def test_deferred_normalisation_is_bit_for_bit_the_normalising_pipeline():
    model = _model()
    f = GridFilter(GEOM, model, epsilon=EPS, blur_m=BLUR, blur="recursive")
    xy, r = _readings(1, 3, 4)
    state, ref = f.init(3), GEOM.uniform(3)
    states = []
    for t in range(4):
        state = f.step(state, xy[t], r[t])
        ref = _normalising_step(ref, model, xy[t], r[t])
        states.append((state, ref))
        # the step's output holds the unnormalised posterior (its p not yet computed), so
        # the next step reads raw and scale
        assert state._scale is not None and state._p is None
        assert not np.allclose(state._raw.sum(axis=(1, 2)), 1.0)
    for state, ref in states:                  # read only now, after the later steps ran
        np.testing.assert_array_equal(state.p, ref)
        assert state.p.dtype == np.float64
        np.testing.assert_allclose(state.p.sum(axis=(1, 2)), 1.0, rtol=1e-12)
        np.testing.assert_array_equal(state.p, state._raw * state._scale[:, None, None])


def test_deferred_state_reads_like_its_normalised_grid():
    model = _model()
    f = GridFilter(GEOM, model, epsilon=EPS, blur_m=BLUR, blur="recursive", location="peak")
    xy, r = _readings(2, 4, 3)
    deferred = f.step(f.step(f.init(4), xy[0], r[0]), xy[1], r[1])
    plain = GridState(deferred.p.copy(), deferred.time)
    ed, ep = f.estimate(deferred), f.estimate(plain)
    np.testing.assert_array_equal(ed.position, ep.position)
    np.testing.assert_array_equal(ed.covariance, ep.covariance)
    np.testing.assert_array_equal(ed.diagnostics["uncertainty_m"], ep.diagnostics["uncertainty_m"])
    # the next step from either state: the same posterior (the factor applied on reading
    # equals the normalisation pass)
    np.testing.assert_array_equal(f.step(deferred, xy[2], r[2]).p, f.step(plain, xy[2], r[2]).p)
    # the checked paths (predict, update, the FFT filter) read the normalised grid
    fft = GridFilter(GEOM, model, epsilon=EPS, blur_m=BLUR)
    np.testing.assert_array_equal(fft.step(deferred, xy[2], r[2]).p, fft.step(plain, xy[2], r[2]).p)
    np.testing.assert_array_equal(f.predict(deferred, shift_m=np.ones((4, 2))).p,
                                  f.predict(plain, shift_m=np.ones((4, 2))).p)
    # selecting runs, pickling, immutability
    for index in (slice(1, 3), np.array([3, 0]), np.array([True, False, False, True]), 2):
        np.testing.assert_array_equal(deferred[index].p, plain[index].p)
        assert deferred[index].batch == plain[index].batch
    back = pickle.loads(pickle.dumps(deferred))
    np.testing.assert_array_equal(back.p, deferred.p)
    assert back.time == deferred.time
    with pytest.raises(AttributeError):
        deferred.time = 3.0
    # pure: a later step leaves the state it read unchanged
    before = deferred.p.copy()
    f.step(deferred, xy[2], r[2])
    np.testing.assert_array_equal(deferred.p, before)


def test_float32_posterior_within_its_stated_budget():
    model = _model()
    f64 = GridFilter(GEOM, model, epsilon=EPS, blur_m=BLUR, blur="recursive")
    f32 = GridFilter(GEOM, model, epsilon=EPS, blur_m=BLUR, blur="recursive", dtype="float32")
    T, B = 12, 3
    xy, r = _readings(3, B, T)
    a, b = f64.init(B), f32.init(B)
    worst = []
    for t in range(T):
        a, b = f64.step(a, xy[t], r[t]), f32.step(b, xy[t], r[t])
        assert b._raw.dtype == np.float32 and b.p.dtype == np.float64
        rel = np.max(np.abs(b.p - a.p) / a.p)
        worst.append(rel)
        assert rel <= 3 * (t + 1) * 2.0**-24                 # the docstring's bound
        assert np.abs(b.p.sum(axis=(1, 2)) - 1.0).max() <= 2.0**-23
        assert b.p.min() >= EPS * (1 - 2.0**-23)
    assert max(worst) > 0                                    # float32 did round something
    ea, eb = f64.estimate(a), f32.estimate(b)
    np.testing.assert_allclose(eb.position, ea.position, rtol=0, atol=1e-5 * GEOM.cell_m)
    # batch equals one by one (the rounding is per cell)
    one = f32.init(1)
    for t in range(T):
        one = f32.step(one, xy[t, 1:2], r[t, 1:2])
    np.testing.assert_array_equal(one.p[0], b.p[1])


def test_float32_setting_is_validated():
    model = _model()
    with pytest.raises(ConfigError, match="dtype"):
        GridFilter(GEOM, model, blur_m=BLUR, blur="recursive", dtype="float16")
    with pytest.raises(ConfigError, match="dtype"):
        GridFilter(GEOM, model, blur_m=BLUR, dtype="float32")              # FFT blur
    with pytest.raises(ConfigError, match="dtype"):
        GridFilter(GEOM, LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1), blur_m=BLUR,
                   blur="recursive", dtype="float32")
