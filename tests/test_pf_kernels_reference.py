"""Each compiled kernel of the particle filter against a plain NumPy reference of the same
maths on random inputs (pf_kernels.py vs P2PParticleFilter(kernel="numpy") and resampling)."""

import numpy as np
import pytest

from radioloc.estimators import pf_kernels as K
from radioloc.estimators.p2p_particle import (P2PParticleFilter, _gather, _link_update,
                                              _link_update_numpy, _moments)
from radioloc.estimators.resampling import systematic
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import InputDriven


def _inputs(seed, b=(2, 3), k=50, width=6, width_prev=4, spread=3.0, n=2):
    rng = np.random.default_rng(seed)
    particles = rng.normal(size=b + (k, n)) * spread
    node_xy = rng.normal(size=b + (width, 2)) * 5
    th = rng.uniform(0, 12, size=b + (width,))
    valid = rng.random(b + (width,)) < 0.7
    where_prev = np.where(rng.random(b + (width,)) < 0.5, rng.integers(0, width_prev, b + (width,)), -1)
    prev_q = rng.random(b + (k, width_prev))
    params = np.stack([rng.uniform(0.02, 0.5, b), rng.uniform(0.5, 8.0, b), rng.uniform(0.05, 0.95, b)], -1)
    return particles, node_xy, th, valid, where_prev, prev_q, params


def _check_link(args, em=True):
    ref = _link_update_numpy(*args)
    fast = _link_update(*args, "numba", em)
    valid = args[3]
    np.testing.assert_allclose(fast[0], ref[0], rtol=1e-10, atol=1e-9)                 # log w
    np.testing.assert_allclose(fast[1], np.where(valid[..., None, :], ref[1], 0), rtol=1e-9, atol=1e-12)
    # log sum_i phi^i(z): exact where within 600 of the other state's (else below 1e-260
    # of it); the detection rule and the normalised posterior exactly
    top = np.logaddexp(ref[2][..., 0], ref[2][..., 1])[..., None]
    near = np.isfinite(ref[2]) & (ref[2] > top - 600)
    np.testing.assert_allclose(fast[2][near], ref[2][near], rtol=1e-10, atol=1e-9)
    ok = valid & np.isfinite(top[..., 0])
    with np.errstate(invalid="ignore"):
        p_fast = np.exp(fast[2][..., 1] - np.logaddexp(fast[2][..., 0], fast[2][..., 1]))
        p_ref = np.exp(ref[2][..., 1] - top[..., 0])
    np.testing.assert_array_equal((fast[2][..., 1] > fast[2][..., 0])[ok],
                                  (ref[2][..., 1] > ref[2][..., 0])[ok])
    np.testing.assert_allclose(p_fast[ok], p_ref[ok], atol=1e-12)
    if em:
        np.testing.assert_allclose(fast[3], ref[3], rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_link_weights_equal_numpy_reference(seed):
    _check_link(_inputs(seed))


def test_link_weights_far_particles_use_the_log_domain():
    # particles metres from every range: the linear-domain terms underflow to 0
    args = list(_inputs(7, spread=40.0))
    args[6] = args[6].copy()
    args[6][..., 0] = 0.01                                       # s_LOS 1 cm
    _check_link(tuple(args))
    log_w = _link_update(*args, "numba", False)[0]
    assert np.all(np.isfinite(log_w))


def test_link_weights_alpha_one_and_no_previous_links():
    p, nxy, th, valid, wp, prev_q, params = _inputs(8)
    params[..., 2] = 1.0
    _check_link((p, nxy, th, valid, wp, prev_q, params))
    _check_link((p, nxy, th, valid, np.full_like(wp, -1), prev_q[..., :0], params))


def test_link_weights_chunks_and_full_state():
    # K larger than a chunk, state [x, y, vx, vy]: position first
    import radioloc.estimators.p2p_particle as pp
    args = _inputs(9, b=(2,), k=300, n=4)
    old = pp.CHUNK
    try:
        pp.CHUNK = 64
        _check_link(args)
    finally:
        pp.CHUNK = old


def test_batched_equals_one_by_one():
    args = _inputs(10)
    full = _link_update(*args, "numba", True)
    one = _link_update(*(a[1, 2] for a in args), "numba", True)
    for f, o in zip(full, one):
        np.testing.assert_allclose(o, f[1, 2], rtol=1e-13)


@pytest.mark.parametrize("seed", range(3))
def test_moments_and_systematic_resampling_equal_numpy(seed):
    rng = np.random.default_rng(seed)
    log_w = rng.normal(size=(4, 200)) * 5
    particles = rng.normal(size=(4, 200, 4))
    w, mean, cov, ess = _moments(log_w, particles, "numba")
    rw, rmean, rcov, ress = _moments(log_w, particles, "numpy")
    np.testing.assert_allclose(w, rw, rtol=1e-12)
    np.testing.assert_allclose(mean, rmean, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(cov, rcov, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(ess, ress, rtol=1e-12)
    u = np.random.default_rng(99).random((4, 1))          # the draw systematic() makes
    idx = np.empty((4, 200), dtype=np.int64)
    K.systematic_indices(w, u[:, 0], idx)
    np.testing.assert_array_equal(idx, systematic(w, np.random.default_rng(99)))


def test_systematic_indices_against_searchsorted():
    rng = np.random.default_rng(11)
    w = rng.random((5, 300)) ** 6
    w /= w.sum(-1, keepdims=True)
    u = rng.random(5)
    idx = np.empty(w.shape, dtype=np.int64)
    K.systematic_indices(w, u, idx)
    cdf = np.cumsum(w, -1)
    cdf[:, -1] = 1.0 + 1e-12
    ref = np.stack([np.minimum(np.searchsorted(c, (uu + np.arange(300)) / 300, side="right"), 299)
                    for c, uu in zip(cdf, u)])
    np.testing.assert_array_equal(idx, ref)


def test_gather_equals_numpy():
    rng = np.random.default_rng(12)
    particles, q = rng.normal(size=(3, 2, 40, 2)), rng.random((3, 2, 40, 5))
    idx = rng.integers(0, 40, (3, 2, 40))
    fast, ref = _gather(particles, q, idx, "numba"), _gather(particles, q, idx, "numpy")
    for f, r in zip(fast, ref):
        np.testing.assert_array_equal(f, r)


def test_whole_filter_numba_equals_numpy_with_online_em():
    rng = np.random.default_rng(13)
    anchors = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 10.0], [20.0, 10.0]])
    truth = np.stack([np.linspace(2, 18, 31), np.full(31, 4.0)], -1)[None, None]       # (1, 1, 31, 2)
    d = np.linalg.norm(truth[:, :, 1:, None] - anchors, axis=-1)
    los = rng.random(d.shape) < 0.5
    r = d + np.where(los, 0, rng.exponential(2.0, d.shape)) + 0.05 * rng.normal(size=d.shape)
    ranges = np.concatenate([np.full(d.shape[:-1] + (1,), np.nan), r], -1)
    ins = np.diff(truth, axis=2) + 0.05 * rng.normal(size=truth[:, :, 1:].shape)
    out = {}
    for kernel in ("numba", "numpy"):
        pf = P2PParticleFilter(InputDriven(0.05), LosNlosRange(0.1, 3.0, 0.3), particles=200,
                               kernel=kernel, online_em=True)
        out[kernel] = pf.run(ranges, truth[:, :, 0], np.random.default_rng(3), anchors=anchors,
                             controls=ins)
    np.testing.assert_allclose(out["numba"].position, out["numpy"].position, atol=1e-9)
    np.testing.assert_allclose(out["numba"].diagnostics["em_parameters"],
                               out["numpy"].diagnostics["em_parameters"], rtol=1e-8)
    np.testing.assert_array_equal(out["numba"].diagnostics["los_detected"],
                                  out["numpy"].diagnostics["los_detected"])


@pytest.mark.parametrize("dt", [1.0, np.array([[[0.5], [2.0]]])])
def test_motion_draw_equals_the_models_sample(dt):
    from radioloc.estimators.p2p_particle import _sample_motion
    from radioloc.models.motion import ConstantVelocity, RandomWalk
    for motion in (RandomWalk(0.3), ConstantVelocity(0.2)):
        x = np.random.default_rng(1).normal(size=(1, 2, 50, motion.state_dim))
        a = _sample_motion(motion, x, dt, np.random.default_rng(5), None)
        b = motion.sample(x, dt, np.random.default_rng(5))
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("control", [False, True])
def test_fast_motion_draws_equal_the_models_sample_bit_for_bit(control):
    from radioloc.estimators.p2p_particle import _sample_motion
    from radioloc.models.motion import InputDriven, RandomWalk
    x = np.random.default_rng(1).normal(size=(3, 4, 60, 2))
    u = np.random.default_rng(2).normal(size=(3, 4, 1, 2)) if control else None
    for motion in (InputDriven(0.1), RandomWalk(0.3)):
        for dt in (1.0, 0.0, 2.5):
            a = _sample_motion(motion, x, dt, np.random.default_rng(5), u)
            b = motion.sample(x, dt, np.random.default_rng(5), control=u)
            np.testing.assert_array_equal(a, b)
