"""The grid filter's two backends (paper 003, Algorithm 1 and BlurGrid of Algorithm 4) and the
recursive blur, through the public API: ``GridFilter(backend="numba")`` gives the grids of
``backend="numpy"`` (the NumPy definitions) to 1e-10 relative, on shapes that are not multiples
of the kernels' chunks, mixed radii and missing readings; the recursive Gaussian has the exact
variance and stays close to the exact filter; posteriors sum to 1 above the floor; moving the
scene moves the estimate; bad cells and settings raise the toolkit's errors."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators.grid import (RECURSIVE_MIN_SIGMA, GridFilter, GridGeometry, GridState,
                                      blur_grid, cell_distances)
from radioloc.models.rssi_logdistance import LogDistanceGaussian
from radioloc.models.rssi_trapezoid import fit_trapezoid_model

RTOL = 1e-10
EPS = 1e-9


def _trap():
    rng = np.random.default_rng(5)
    d = rng.uniform(0, 30, 6000)
    r = np.clip(np.rint(80 - 2.0 * d + rng.normal(0, 2.0, d.size)), 0, 100)
    return fit_trapezoid_model(r, d, tau_min=0.3, sigma_min=0.3, window=1)


TRAP = _trap()
LOGD = LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1)


def _pair(geom, model=TRAP, **kw):
    return [GridFilter(geom, model, epsilon=EPS, backend=b, **kw) for b in ("numba", "numpy")]


def _prior(rng, geom, B):
    p = rng.random((B, geom.h, geom.w)) ** 4
    return GridState(p / p.sum(axis=(1, 2), keepdims=True), 0.0)


def _readings(rng, B, model=TRAP):
    xy = rng.uniform(-8, 8, (B, 2))
    r = rng.integers(35, 70, B).astype(float) if model is TRAP else rng.uniform(-80, -50, B)
    return xy, r


@pytest.mark.parametrize("shape", [(70, 45), (7, 130), (64, 64)])
@pytest.mark.parametrize("blur", ["recursive", "fft"])
def test_step_numba_equals_numpy(shape, blur):
    geom = GridGeometry.centred(*shape, 0.5)
    fast, ref = _pair(geom, blur_m=1.5, blur=blur)
    rng = np.random.default_rng(shape[0] + len(blur))
    state = _prior(rng, geom, 3)
    xy, r = _readings(rng, 3)
    # per-run radii, one below the recursive blur's threshold (the FFT blurs it)
    extra = np.array([0.0, 2.0, 0.0])
    for f in (fast, ref):
        assert f.backend in ("numba", "numpy")
    a = fast.step(state, xy, r, extra_blur_m=extra)
    b = ref.step(state, xy, r, extra_blur_m=extra)
    np.testing.assert_allclose(a.p, b.p, rtol=RTOL, atol=0)
    np.testing.assert_allclose(fast.predict(state).p, ref.predict(state).p, rtol=RTOL, atol=0)
    np.testing.assert_allclose(fast.update(state, xy, r).p, ref.update(state, xy, r).p,
                               rtol=RTOL, atol=0)


def test_below_threshold_blur_is_the_exact_blur():
    geom = GridGeometry.centred(40, 30, 1.0)
    rng = np.random.default_rng(2)
    p = _prior(rng, geom, 2).p
    rad = np.array([0.5 * RECURSIVE_MIN_SIGMA, 3.0])
    fast = blur_grid(p, geom, rad, EPS, method="recursive")
    np.testing.assert_array_equal(fast[0], blur_grid(p, geom, rad, EPS)[0])


def test_run_numba_equals_numpy_with_missing_readings():
    geom = GridGeometry.centred(50, 38, 0.5)
    fast, ref = _pair(geom, blur_m=1.2, blur="recursive", location="peak")
    rng = np.random.default_rng(3)
    xy = rng.uniform(-8, 8, (2, 6, 2))
    r = rng.integers(35, 70, (2, 6)).astype(float)
    r[1, 2] = np.nan
    a, b = fast.run(xy, r), ref.run(xy, r)
    np.testing.assert_allclose(a.position, b.position, rtol=RTOL, atol=0)
    np.testing.assert_allclose(a.diagnostics["uncertainty_m"], b.diagnostics["uncertainty_m"],
                               rtol=RTOL)


def test_other_models_run_the_numpy_definition_on_both_backends():
    geom = GridGeometry.centred(30, 24, 0.5)
    fast, ref = _pair(geom, LOGD, blur_m=1.2, blur="recursive")
    rng = np.random.default_rng(4)
    state = _prior(rng, geom, 2)
    xy, r = _readings(rng, 2, LOGD)
    np.testing.assert_allclose(fast.step(state, xy, r).p, ref.step(state, xy, r).p, rtol=RTOL)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_update_known_answer_from_a_uniform_prior(backend):
    # Algorithm 1 from p_i = 1/k: max(L_i / k, eps) / sum
    geom = GridGeometry.centred(33, 21, 0.5)
    f = GridFilter(geom, TRAP, epsilon=EPS, backend=backend)
    xy, r = np.array([[1.0, -2.0]]), np.array([50.0])
    lik = TRAP.likelihood(cell_distances(geom, xy), r[:, None, None])
    want = np.maximum(lik / geom.k, EPS)
    want /= want.sum()
    np.testing.assert_allclose(f.update(f.init(1), xy, r).p, want, rtol=1e-12)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize("blur", ["recursive", "fft"])
def test_step_equals_predict_then_update(backend, blur):
    geom = GridGeometry.centred(37, 29, 0.5)
    f = GridFilter(geom, TRAP, epsilon=1e-7, blur_m=1.2, blur=blur, backend=backend)
    rng = np.random.default_rng(23)
    state = _prior(rng, geom, 3)
    xy, r = _readings(rng, 3)
    extra = np.array([0.0, 0.3, 2.0])
    fused = f.step(state, xy, r, dt=0.5, extra_blur_m=extra)
    split = f.update(f.predict(state, dt=0.5, extra_blur_m=extra), xy, r)
    np.testing.assert_allclose(fused.p, split.p, rtol=1e-12, atol=0)
    assert fused.time == split.time
    np.testing.assert_allclose(fused.p.sum(axis=(1, 2)), 1.0, rtol=1e-12)
    assert fused.p.min() >= 1e-7 * (1 - 1e-12)


@pytest.mark.parametrize("s", [2.0, 5.0, 15.0])
def test_recursive_impulse_response_has_the_gaussian_variance(s):
    n = 201
    geom = GridGeometry(n, 1, 1.0)
    p = np.zeros((1, 1, n))
    p[0, 0, n // 2] = 1.0
    r = blur_grid(p, geom, s, 0.0, method="recursive")[0, 0]
    x = np.arange(n) - n // 2
    assert abs(np.sqrt((r * x * x).sum()) - s) < 0.01 * s
    g = np.exp(-x**2 / (2 * s * s))
    g /= g.sum()
    assert np.abs(r - g).max() < 0.2 * g.max()      # the approximation's documented size


def test_recursive_filter_tracks_the_exact_filter():
    """Over 20 steps: mass 1, mean position within a fifth of a cell of the exact (FFT)
    filter's, and the recursive filter's mode a cell the exact posterior gives at least 90 %
    of its peak."""
    geom = GridGeometry.centred(120, 100, 0.25)
    rng = np.random.default_rng(11)
    T, B = 20, 3
    truth = rng.uniform(-8, 8, (B, 2))
    trk = truth[:, None] + rng.uniform(-10, 10, (B, T, 2))
    d = np.linalg.norm(trk - truth[:, None], axis=-1)
    rssi = np.clip(np.rint(80 - 2.0 * d + rng.normal(0, 2.0, d.shape)), 0, 100)
    fast = GridFilter(geom, TRAP, epsilon=EPS, blur_m=0.75, blur="recursive")
    exact = GridFilter(geom, TRAP, epsilon=EPS, blur_m=0.75)
    sf, se = fast.init(B), exact.init(B)
    worst_mean, worst_mode = 0.0, 1.0
    for t in range(T):
        sf = fast.step(sf, trk[:, t], rssi[:, t])
        se = exact.step(se, trk[:, t], rssi[:, t])
        np.testing.assert_allclose(sf.p.sum(axis=(1, 2)), 1.0, rtol=1e-12)
        worst_mean = max(worst_mean, np.abs(fast.estimate(sf).position
                                            - exact.estimate(se).position).max())
        mode = sf.p.reshape(B, -1).argmax(1)
        pe = se.p.reshape(B, -1)
        worst_mode = min(worst_mode, (pe[np.arange(B), mode] / pe.max(1)).min())
    assert worst_mean < 0.2 * geom.cell_m
    assert worst_mode > 0.9


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_moving_the_scene_moves_the_estimate(backend):
    # trackers and target moved by whole cells: the estimate moves by the same vector
    geom = GridGeometry.centred(60, 48, 0.5)
    f = GridFilter(geom, TRAP, epsilon=1e-12, blur_m=1.0, blur="recursive", location="peak",
                   backend=backend)
    rng = np.random.default_rng(8)
    truth = np.array([1.0, -1.5])
    xy = truth + rng.uniform(-6, 6, (1, 15, 2))
    r = np.argmin(np.abs(TRAP.mu[None, None, :]
                         - np.linalg.norm(xy - truth, axis=-1)[..., None]), axis=-1).astype(float)
    move = np.array([2.5, -1.0])                       # 5 and -2 cells
    a = f.run(xy, r).position[0, -1]
    b = f.run(xy + move, r).position[0, -1]
    np.testing.assert_allclose(b - a, move, atol=0.05)
    assert np.linalg.norm(a - truth) < 1.0


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_batch_equals_one_by_one(backend):
    geom = GridGeometry.centred(37, 29, 0.5)
    f = GridFilter(geom, TRAP, epsilon=EPS, blur_m=1.5, blur="recursive", backend=backend)
    rng = np.random.default_rng(19)
    xy = rng.uniform(-6, 6, (3, 4, 2))
    r = rng.integers(40, 70, (3, 4)).astype(float)
    track = f.run(xy, r)
    for b in range(3):
        one = f.run(xy[b:b + 1], r[b:b + 1])
        np.testing.assert_allclose(one.position[0], track.position[b], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("backend", ["numba", "numpy"])
@pytest.mark.parametrize("bad,match", [(np.nan, "non-finite"), (-1e-9, "negative"),
                                       (np.inf, "non-finite"), (1e31, "magnitude")])
def test_bad_cell_of_the_state_is_named(backend, bad, match):
    geom = GridGeometry.centred(40, 35, 0.5)
    f = GridFilter(geom, TRAP, epsilon=EPS, blur_m=1.5, blur="recursive", backend=backend)
    p = np.full((2, 35, 40), 1.0 / geom.k)
    p[1, 33, 39] = bad
    with pytest.raises(InputError, match=match) as err:
        f.step(GridState(p, 0.0), np.zeros((2, 2)), np.full(2, 50.0))
    assert "grid" in str(err.value) and "(1, 33, 39)" in str(err.value)


def test_bad_settings_raise():
    geom = GridGeometry.centred(10, 10, 1.0)
    with pytest.raises(ConfigError, match="backend"):
        GridFilter(geom, TRAP, backend="cuda")
    with pytest.raises(ConfigError, match="blur"):
        GridFilter(geom, TRAP, blur="box")
    with pytest.raises(InputError, match="method"):
        blur_grid(geom.uniform(1), geom, 1.0, method="box")
    assert GridFilter(geom, TRAP).get_params()["backend"] == "numba"
