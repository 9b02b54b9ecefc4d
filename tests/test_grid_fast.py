"""The block-layout kernels of the recursive grid step (paper 003, BlurGrid of Algorithm 4 and
Algorithm 1) against plain NumPy references of the same maths on random inputs: the blur in
the block layout equals the plain recursions (float64 to 1e-10, float32 storage within two
roundings of each cell), the fused step equals the NumPy update of that blur, the fused input
check names the bad cell, and the recursive filter stays close to the exact (FFT) filter in
probability mass, mode and mean position."""

import numpy as np
import pytest

from radioloc.core.errors import InputError
from radioloc.estimators import grid_kernels as gk
from radioloc.estimators.grid import GridFilter, GridGeometry, GridState, cell_distances
from radioloc.models.rssi_trapezoid import fit_trapezoid_model
from test_grid_kernels import _ref_yvv_1d


def _ref_blur(p, s):
    coef = gk.yvv_coefficients(s)
    tails = np.ceil(6.0 * s).astype(int) + 3
    out = np.empty_like(p)
    for b in range(p.shape[0]):
        cols = np.stack([_ref_yvv_1d(c, coef[b], tails[b]) for c in p[b].T]).T
        out[b] = np.stack([_ref_yvv_1d(r, coef[b], tails[b]) for r in cols])
    return out


def _unblock(blk, h):
    B, nb, w, L = blk.shape
    return blk.transpose(0, 1, 3, 2).reshape(B, nb * L, w)[:, :h]


@pytest.mark.parametrize("h,w", [(gk.LANES, 19), (2 * gk.LANES + 5, 70), (7, 130)])
def test_blocks_equal_the_plain_recursions_any_shape(h, w):
    rng = np.random.default_rng(h * w)
    p = rng.random((2, h, w)) ** 3
    s = np.array([2.0, 4.6])
    ref = _ref_blur(p, s)
    blk, excess, bad = gk.gaussian_blocks(p, s, 0.01, np.float64)
    assert bad == 0 and blk.shape == (2, -(-h // gk.LANES), w, gk.LANES)
    np.testing.assert_allclose(_unblock(blk, h), ref, rtol=1e-10, atol=1e-14 * ref.max())
    # the lanes past the last row stay zero
    assert np.all(blk.transpose(0, 1, 3, 2).reshape(2, -1, w)[:, h:] == 0.0)
    np.testing.assert_allclose(excess, np.maximum(ref - 0.01, 0).sum(axis=(1, 2)), rtol=1e-10)
    got, ex2 = gk.recursive_gaussian(p, s, 0.01)
    np.testing.assert_array_equal(got, _unblock(blk, h))
    np.testing.assert_array_equal(ex2, excess)


def test_float32_blocks_are_within_two_roundings():
    rng = np.random.default_rng(3)
    p = rng.random((2, 45, 61)) ** 6
    s = np.array([2.0, 9.5])
    ref, _, _ = gk.gaussian_blocks(p, s, 1e-6, np.float64)
    got, excess, _ = gk.gaussian_blocks(p, s, 1e-6, np.float32)
    assert got.dtype == np.float32
    scale = ref.max(axis=(1, 2, 3), keepdims=True)
    assert np.all(np.abs(got - ref) <= 2 * 2.0**-24 * np.abs(ref) + 1e-12 * scale)
    np.testing.assert_allclose(excess, np.maximum(got.astype(float) - 1e-6, 0).sum(axis=(1, 2, 3)),
                               rtol=1e-12)


def _model():
    rng = np.random.default_rng(5)
    d = rng.uniform(0, 30, 6000)
    r = np.clip(np.rint(80 - 2.0 * d + rng.normal(0, 2.0, d.size)), 0, 100)
    return fit_trapezoid_model(r, d, tau_min=0.3, sigma_min=0.3, window=1)


def test_fused_recursive_step_equals_numpy_update_of_the_blur():
    geom = GridGeometry.centred(75, 50, 0.5)
    model = _model()
    rng = np.random.default_rng(7)
    p = rng.random((3, 50, 75)) ** 4
    p /= p.sum(axis=(1, 2), keepdims=True)
    eps = 1e-9
    f = GridFilter(geom, model, epsilon=eps, blur_m=1.5, blur="recursive")
    xy = rng.uniform(-10, 10, (3, 2))
    rssi = rng.integers(30, 70, 3)
    got = f.step(GridState(p, 0.0), xy, rssi).p
    # reference: plain recursions, float32 storage, floor-normalise, Algorithm 1 in NumPy
    v = _ref_blur(p, np.full(3, 1.5 / 0.5)).astype(np.float32).astype(float)
    k = geom.k
    ex = np.maximum(v - eps, 0).sum(axis=(1, 2), keepdims=True)
    prior = eps + (1 - k * eps) * np.maximum(v - eps, 0) / ex
    lik = model.likelihood(cell_distances(geom, xy), rssi[:, None, None])
    post = np.maximum(prior * lik, eps)
    post /= post.sum(axis=(1, 2), keepdims=True)
    # float32 storage of the column pass (one rounding, 2**-24) differs from the kernel's
    # two roundings: 4 * 2**-24 relative bounds both through the normalisation
    np.testing.assert_allclose(got, post, rtol=4 * 2.0**-24, atol=0)
    np.testing.assert_allclose(got.sum(axis=(1, 2)), 1.0, rtol=1e-12)
    assert got.min() >= eps * (1 - 1e-12)


@pytest.mark.parametrize("bad,match", [(np.nan, "non-finite"), (-1e-9, "negative"),
                                       (np.inf, "non-finite"), (1e31, "magnitude")])
def test_fused_check_names_the_bad_cell(bad, match):
    geom = GridGeometry.centred(40, 35, 0.5)
    f = GridFilter(geom, _model(), epsilon=1e-9, blur_m=1.5, blur="recursive")
    p = np.full((2, 35, 40), 1.0 / geom.k)
    p[1, 33, 39] = bad
    with pytest.raises(InputError, match=match) as err:
        f.step(GridState(p, 0.0), np.zeros((2, 2)), np.full(2, 50.0))
    assert "(1, 33, 39)" in str(err.value)


def test_recursive_filter_tracks_the_exact_filter():
    """Error budget of the recursive step (Young-van Vliet approximation + float32 blur
    storage) against the exact FFT filter over 20 steps: mass 1 to 1e-12, mean position within
    a fifth of a cell, and the recursive filter's mode is a cell the exact posterior gives at
    least 90 % of its peak (early posteriors are flat rings whose argmax is not stable)."""
    geom = GridGeometry.centred(120, 100, 0.25)
    model = _model()
    rng = np.random.default_rng(11)
    T, B = 20, 3
    truth = rng.uniform(-8, 8, (B, 2))
    trk = truth[:, None] + rng.uniform(-10, 10, (B, T, 2))
    d = np.linalg.norm(trk - truth[:, None], axis=-1)
    rssi = np.clip(np.rint(80 - 2.0 * d + rng.normal(0, 2.0, d.shape)), 0, 100)
    kw = dict(epsilon=1e-9, blur_m=0.75)
    fast = GridFilter(geom, model, blur="recursive", **kw)
    exact = GridFilter(geom, model, **kw)
    sf, se = fast.init(B), exact.init(B)
    worst_mean, worst_mode = 0.0, 1.0
    for t in range(T):
        sf = fast.step(sf, trk[:, t], rssi[:, t])
        se = exact.step(se, trk[:, t], rssi[:, t])
        np.testing.assert_allclose(sf.p.sum(axis=(1, 2)), 1.0, rtol=1e-12)
        ef, ee = fast.estimate(sf), exact.estimate(se)
        worst_mean = max(worst_mean, np.abs(ef.position - ee.position).max())
        mode = sf.p.reshape(B, -1).argmax(1)
        pe = se.p.reshape(B, -1)
        worst_mode = min(worst_mode, (pe[np.arange(B), mode] / pe.max(1)).min())
    assert worst_mean < 0.2 * geom.cell_m            # measured 0.024 m = 0.095 cell
    assert worst_mode > 0.9                           # measured 0.996
