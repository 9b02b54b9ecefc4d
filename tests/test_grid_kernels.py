"""The compiled grid kernels against plain NumPy references of the same maths (paper 003,
Algorithm 1 and BlurGrid of Algorithm 4), on random inputs: fused trapezoid update, fused
update with any likelihood grid, floor-and-normalise, recursive Gaussian; a run's result does
not depend on the rest of the batch."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.estimators import grid_kernels as gk
from radioloc.estimators.grid import (GridFilter, GridGeometry, GridState, blur_grid,
                                      cell_distances, floor_normalise, probability_update)
from radioloc.models.rssi_logdistance import LogDistanceGaussian
from radioloc.models.rssi_trapezoid import TrapezoidModel, fit_trapezoid_model

GEOM = GridGeometry.centred(37, 29, 0.5)


def _trap():
    rng = np.random.default_rng(3)
    d = rng.uniform(0, 20, 6000)
    r = np.clip(np.rint(80 - 3.0 * d + rng.normal(0, 1.5, d.size)), 0, 100)
    return fit_trapezoid_model(r, d, tau_min=0.3, sigma_min=0.3, window=1)


def _grids(rng, B):
    p = rng.random((B, GEOM.h, GEOM.w)) ** 4
    return p / p.sum(axis=(1, 2), keepdims=True)


def _ref_update(p, lik, eps):                      # Algorithm 1 in plain NumPy
    post = np.maximum(p * lik, eps)
    return post / post.sum(axis=(1, 2), keepdims=True)


def _ref_floor(p, eps):
    k = p.shape[1] * p.shape[2]
    excess = np.maximum(p - eps, 0.0)
    total = excess.sum(axis=(1, 2), keepdims=True)
    share = np.where(total > 0, excess / np.where(total > 0, total, 1.0), 1.0 / k)
    return eps + (1.0 - k * eps) * share


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_trapezoid_update_equals_numpy(seed):
    rng = np.random.default_rng(seed)
    model = _trap()
    p = _grids(rng, 4)
    pos = rng.uniform(-8, 8, (4, 2))
    rssi = rng.integers(30, 75, 4)
    eps = 10.0 ** rng.uniform(-9, -5)
    ref = _ref_update(p, model.likelihood(cell_distances(GEOM, pos), rssi[:, None, None]), eps)
    got = probability_update(p, GEOM, pos, rssi, model, eps)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-300)
    assert isinstance(model, TrapezoidModel)


def test_weighted_update_equals_numpy_for_any_model():
    rng = np.random.default_rng(5)
    model = LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1)
    p = _grids(rng, 3)
    pos = rng.uniform(-5, 5, (3, 2))
    rssi = rng.uniform(-80, -50, 3)
    lik = model.likelihood(cell_distances(GEOM, pos), rssi[:, None, None])
    np.testing.assert_allclose(probability_update(p, GEOM, pos, rssi, model, 1e-9),
                               _ref_update(p, lik, 1e-9), rtol=1e-12, atol=1e-300)


def test_floor_normalise_equals_numpy_and_uniform_without_mass():
    rng = np.random.default_rng(7)
    p = rng.random((3, GEOM.h, GEOM.w)) * 1e-3
    p[2] = 1e-9                                     # nothing above the floor: uniform
    for eps in (0.0, 1e-6, 1e-4):
        np.testing.assert_allclose(floor_normalise(p, eps), _ref_floor(p, eps), rtol=1e-12)
    np.testing.assert_allclose(floor_normalise(p, 1e-6)[2], 1.0 / GEOM.k)
    with pytest.raises(InputError, match="epsilon"):
        floor_normalise(p, 1.0)


def _ref_yvv_1d(x, coef, tail):                     # the same recursions, plain Python/NumPy
    g, a1, a2, a3 = coef
    z = np.concatenate([x, np.zeros(tail)])
    fw = np.zeros(z.size + 3)
    for n in range(z.size):
        fw[n + 3] = g * z[n] + a1 * fw[n + 2] + a2 * fw[n + 1] + a3 * fw[n]
    fw = fw[3:]
    bw = np.zeros(z.size + 3)
    for n in range(z.size - 1, -1, -1):
        bw[n] = g * fw[n] + a1 * bw[n + 1] + a2 * bw[n + 2] + a3 * bw[n + 3]
    return bw[:x.size]


def test_recursive_gaussian_equals_the_plain_recursions():
    rng = np.random.default_rng(11)
    p = rng.random((2, 13, 17))
    s = np.array([2.0, 3.7])
    got, excess = gk.recursive_gaussian(p, s, 0.01)
    coef = gk.yvv_coefficients(s)
    tails = np.ceil(6.0 * s).astype(int) + 3
    for b in range(2):
        rows = np.stack([_ref_yvv_1d(r, coef[b], tails[b]) for r in p[b]])
        ref = np.stack([_ref_yvv_1d(c, coef[b], tails[b]) for c in rows.T]).T
        ref = np.maximum(ref, 0.0)
        np.testing.assert_allclose(got[b], ref, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(excess[b], np.maximum(ref - 0.01, 0).sum(), rtol=1e-10)


@pytest.mark.parametrize("seed", [0, 1])
def test_recursive_gaussian_float32_storage_error_is_four_roundings(seed):
    rng = np.random.default_rng(seed)
    p = rng.random((2, 41, 57)) ** 6
    s = np.array([2.0, 9.5])
    ref, ref_excess = gk.recursive_gaussian(p, s, 1e-6)
    got, excess = gk.recursive_gaussian(p, s, 1e-6, np.float32)
    assert got.dtype == np.float32
    # four stores rounded to float32 (2**-24 each), through positive averaging kernels
    scale = ref.max(axis=(1, 2), keepdims=True)
    assert np.all(np.abs(got - ref) <= 4 * 2.0**-24 * np.abs(ref) + 1e-12 * scale)
    np.testing.assert_allclose(excess, np.maximum(got.astype(float) - 1e-6, 0).sum(axis=(1, 2)),
                               rtol=1e-12)
    np.testing.assert_allclose(excess, ref_excess, rtol=1e-6)
    with pytest.raises(ValueError, match="dtype"):
        gk.recursive_gaussian(p, s, 1e-6, np.float16)


@pytest.mark.parametrize("s", [2.0, 5.0, 15.0])
def test_recursive_impulse_response_has_the_gaussian_variance(s):
    n = 201
    p = np.zeros((1, 1, n))
    p[0, 0, n // 2] = 1.0
    out, _ = gk.recursive_gaussian(p, np.array([s]))
    r = out[0, 0] / out[0, 0].sum()
    x = np.arange(n) - n // 2
    assert abs(np.sqrt((r * x * x).sum()) - s) < 0.01 * s
    g = np.exp(-x**2 / (2 * s * s))
    g /= g.sum()
    assert np.abs(r - g).max() < 0.2 * g.max()      # the approximation's documented size


def test_recursive_blur_is_close_to_the_exact_blur_and_mass_preserving():
    rng = np.random.default_rng(13)
    geom = GridGeometry.centred(60, 50, 1.0)
    p = rng.random((3, 50, 60)) ** 8
    p /= p.sum(axis=(1, 2), keepdims=True)
    rad = np.array([2.5, 4.0, 1.0])                 # the last one below the threshold: FFT
    exact = blur_grid(p, geom, rad, 1e-9)
    fast = blur_grid(p, geom, rad, 1e-9, method="recursive")
    np.testing.assert_allclose(fast.sum(axis=(1, 2)), 1.0, rtol=1e-12)
    assert np.all(fast >= 1e-9 * (1 - 1e-12))
    np.testing.assert_array_equal(fast[2], exact[2])
    assert np.abs(fast - exact).sum(axis=(1, 2)).max() < 0.05      # L1 distance of the grids


def test_recursive_blur_batch_equals_one_by_one():
    rng = np.random.default_rng(17)
    geom = GridGeometry.centred(40, 30, 1.0)
    p = rng.random((4, 30, 40))
    p /= p.sum(axis=(1, 2), keepdims=True)
    rad = np.array([2.0, 3.0, 0.5, 7.0])
    batch = blur_grid(p, geom, rad, 1e-8, method="recursive")
    for b in range(4):
        np.testing.assert_array_equal(batch[b], blur_grid(p[b:b + 1], geom, rad[b:b + 1], 1e-8,
                                                           method="recursive")[0])


def test_filter_with_recursive_blur_batch_equals_one_by_one_and_bad_setting_raises():
    model = _trap()
    f = GridFilter(GEOM, model, epsilon=1e-9, blur_m=1.5, blur="recursive")
    rng = np.random.default_rng(19)
    xy = rng.uniform(-6, 6, (3, 5, 2))
    r = rng.integers(40, 70, (3, 5)).astype(float)
    r[1, 2] = np.nan
    track = f.run(xy, r)
    state = f.step(f.init(3), xy[:, 0], r[:, 0])
    for b in range(3):
        one = f.run(xy[b:b + 1], r[b:b + 1])
        np.testing.assert_allclose(one.position[0], track.position[b], rtol=1e-12, atol=1e-12)
        np.testing.assert_array_equal(f.step(f.init(1), xy[b:b + 1, 0], r[b:b + 1, 0]).p[0],
                                      state.p[b])
    with pytest.raises(ConfigError, match="blur"):
        GridFilter(GEOM, model, blur="box")
    with pytest.raises(InputError, match="method"):
        blur_grid(np.full((1, GEOM.h, GEOM.w), 1.0 / GEOM.k), GEOM, 1.0, method="box")


@pytest.mark.parametrize("blur,model", [("fft", "trap"), ("recursive", "trap"),
                                        ("recursive", "logd")])
def test_fused_step_equals_predict_then_update(blur, model):
    m = _trap() if model == "trap" else LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1)
    f = GridFilter(GEOM, m, epsilon=1e-7, blur_m=1.2, blur=blur)
    rng = np.random.default_rng(23)
    state = f.init(prior=_grids(rng, 3))
    xy = rng.uniform(-6, 6, (3, 2))
    r = rng.integers(40, 70, 3).astype(float) if model == "trap" else rng.uniform(-80, -50, 3)
    fused = f.step(state, xy, r, dt=0.5, extra_blur_m=np.array([0.0, 0.3, 2.0]))
    split = f.update(f.predict(state, dt=0.5, extra_blur_m=np.array([0.0, 0.3, 2.0])), xy, r)
    if (blur, model) == ("recursive", "trap"):
        # the fused recursive step reads the blur's block layout and sums each row cell by
        # cell; the split path's update sums rows in the vectorised order: rounding only
        np.testing.assert_allclose(fused.p, split.p, rtol=1e-13, atol=0)
    else:
        np.testing.assert_array_equal(fused.p, split.p)
    assert fused.time == split.time


@pytest.mark.parametrize("bad,match", [(np.nan, "non-finite"), (-1e-9, "negative"),
                                       (np.inf, "non-finite"), (1e31, "magnitude")])
def test_compiled_grid_check_agrees_with_the_numpy_checks(bad, match):
    rng = np.random.default_rng(29)
    p = _grids(rng, 3)
    assert gk.grids_in_range(p, 1e30)
    f = GridFilter(GEOM, _trap(), epsilon=1e-9, blur_m=1.5, blur="recursive")
    q = p.copy()
    q[2, 5, 7] = bad
    assert not gk.grids_in_range(q, 1e30)
    for call in (lambda: f.step(GridState(q, 0.0), np.zeros((3, 2)), np.full(3, 50.0)),
                 lambda: blur_grid(q, GEOM, 1.0, 1e-9, method="recursive")):
        with pytest.raises(InputError, match=match) as err:
            call()
        assert "(2, 5, 7)" in str(err.value)
