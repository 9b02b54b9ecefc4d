"""The vectorisable exp and erfcx of the particle-filter kernels against NumPy/SciPy on
random inputs over the whole range the link kernel uses, and the Gaussian case of the link
kernel (alpha = 1, every carried LOS posterior 1) against the NumPy reference of the general
LOS/NLOS update (tests/test_pf_kernels_reference.py holds the general path at alpha = 1 with
random carried posteriors)."""

import numpy as np
import pytest
from numba import njit
from scipy.special import erfcx

from radioloc.estimators import pf_kernels as K
from radioloc.estimators.p2p_particle import _link_update, _link_update_numpy


@njit(cache=True)
def _vexp_array(x, out):
    for i in range(x.size):
        out[i] = K.vexp(x[i])


@njit(cache=True)
def _verfcx_array(x, out):
    for i in range(x.size):
        out[i] = K.verfcx(x[i])


def _ulps(got, ref):
    return np.abs(got - ref) / np.spacing(np.abs(ref))


def test_vexp_within_two_ulps_of_numpy():
    rng = np.random.default_rng(0)
    # the kernel's arguments: -z^2/2 + const and -lam e (any sign), log-weight differences
    x = np.concatenate([rng.uniform(-708.0, 709.0, 400_000), rng.uniform(-1.0, 1.0, 100_000),
                        rng.uniform(-40.0, 5.0, 100_000), [0.0, -0.0, 1e-300, 709.0, -708.0]])
    out = np.empty_like(x)
    _vexp_array(x, out)
    assert _ulps(out, np.exp(x)).max() <= 2.0


def test_vexp_subnormal_underflow_and_overflow():
    x = np.concatenate([np.linspace(-745.0, -708.5, 10_001), [-746.0, -1e4, 710.0, 1e4]])
    out = np.empty_like(x)
    _vexp_array(x, out)
    with np.errstate(over="ignore"):
        ref = np.exp(x)
    # subnormal results: within 2 units of the smallest subnormal (their own precision)
    np.testing.assert_allclose(out[:-4], ref[:-4], rtol=1e-12, atol=2 * 5e-324)
    assert out[-4] == 0.0 and out[-3] == 0.0
    assert np.isinf(out[-2]) and np.isinf(out[-1])


def test_verfcx_within_a_few_ulps_of_scipy():
    rng = np.random.default_rng(1)
    # |u| / sqrt(2) for u = z - lam s: 0 to ~1e4 (particles km off); log-uniform tail
    x = np.concatenate([rng.uniform(0.0, 10.0, 300_000), 10 ** rng.uniform(-8, 6, 200_000),
                        [0.0, 3.75, 1e8]])
    out = np.empty_like(x)
    _verfcx_array(x, out)
    u = _ulps(out, erfcx(x))
    assert u.max() <= 32.0            # relative error below 7e-15 (measured: 20 ulps)
    assert np.median(u) <= 4.0        # measured: 3


def _inputs(seed, b=(2, 3), k=300, width=6, spread=3.0):
    rng = np.random.default_rng(seed)
    particles = rng.normal(size=b + (k, 2)) * spread
    node_xy = rng.normal(size=b + (width, 2)) * 5
    th = rng.uniform(0, 12, size=b + (width,))
    valid = rng.random(b + (width,)) < 0.7
    where_prev = np.where(rng.random(b + (width,)) < 0.5, rng.integers(0, width, b + (width,)), -1)
    params = np.stack([rng.uniform(0.02, 0.5, b), rng.uniform(0.5, 8.0, b), np.ones(b)], -1)
    return particles, node_xy, th, valid, where_prev, params


@pytest.mark.parametrize("seed", range(4))
@pytest.mark.parametrize("spread", [3.0, 60.0])
def test_gaussian_case_equals_general_kernel_and_numpy(seed, spread):
    p, nxy, th, valid, wp, params = _inputs(seed, spread=spread)
    ones = np.ones(p.shape[:-1] + (nxy.shape[-2],))
    # q = 1 exactly: the Gaussian path; the reference is the general LOS/NLOS maths
    gauss = _link_update(p, nxy, th, valid, wp, ones, params, "numba", True)
    ref = _link_update_numpy(p, nxy, th, valid, wp, ones, params)
    for other in (ref,):
        np.testing.assert_allclose(gauss[0], other[0], rtol=1e-12, atol=1e-9)       # log w
        np.testing.assert_allclose(gauss[1], np.where(valid[..., None, :], other[1], 0.0),
                                   rtol=0, atol=1e-12)                             # q' = 1
        np.testing.assert_allclose(gauss[3], other[3], rtol=1e-10, atol=1e-9)       # EM sums
    # detection sums: LOS exactly, NLOS -inf (pi_0 = 0)
    ok = valid
    np.testing.assert_allclose(gauss[2][..., 1][ok], ref[2][..., 1][ok], rtol=1e-10, atol=1e-9)
    assert np.all(gauss[2][..., 0][ok] == -np.inf)
