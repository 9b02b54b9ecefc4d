"""The fused bootstrap step of the particle filter (radioloc.estimators.pf_bootstrap): the
compiled kernel against plain NumPy of the same maths on the same draws, chunk boundaries,
and when P2PParticleFilter takes it."""

import numpy as np
import pytest

import radioloc.estimators.p2p_particle as pp
from radioloc.estimators import pf_bootstrap as bs
from radioloc.estimators import pf_random as R
from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.estimators.resampling import systematic
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import ConstantVelocity, InputDriven, RandomWalk

ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]])


def _kernel_inputs(b=3, k=1000, seed=0):
    rng = np.random.default_rng(seed)
    particles = 15.0 + rng.normal(size=(b, k, 2))
    shift = rng.normal(size=(b, 2)) * 0.1
    sd = np.array([0.4, 0.6])
    key = R.draw_key(rng)
    node_xy = np.broadcast_to(ANCHORS, (b, 4, 2)).copy()
    theta = np.linalg.norm(node_xy - (15.0 + rng.normal(size=(b, 1, 2))), axis=-1)
    valid = np.ones((b, 4), dtype=bool)
    valid[1, 2] = False                           # a padded link slot
    inv_s = np.array([1 / 0.3, 1 / 0.5, 1 / 0.2])[:b]
    u = rng.random(b)
    u[0] = 0.0
    return particles, shift, sd, key, node_xy, theta, valid, inv_s, u


def _run_kernel(args, chunk):
    particles = args[0]
    b, k = particles.shape[:2]
    out = np.empty((b, k, 2))
    idx = np.empty((b, k), dtype=np.int64)
    mean, cov, ess = np.empty((b, 2)), np.empty((b, 2, 2)), np.empty(b)
    distinct = np.empty(b, dtype=np.int64)
    pred, v = np.empty((b, k, 2)), np.empty((b, k))
    bs.bootstrap_step(args[0], pp._NO_ANCESTORS, False, *args[1:], chunk, True, out, idx, mean, cov,
                      ess, distinct, pred, v)
    return out, idx, mean, cov, ess, distinct, pred, v


@pytest.mark.parametrize("chunk", [7, 64, 2048])
def test_kernel_equals_numpy_of_the_same_maths(chunk):
    args = _kernel_inputs()
    particles, shift, sd, key, node_xy, theta, valid, inv_s, u = args
    out, idx, mean, cov, ess, distinct, pred, v = _run_kernel(args, chunk)
    # motion: (x + u) + sd z with the draws of standard_normal(shape) under the key
    z = R.standard_normal_numpy(None, particles.shape, key=key)
    ref_pred = (particles + shift[:, None, :]) + sd * z
    np.testing.assert_allclose(pred, ref_pred, rtol=0, atol=1e-13)
    # weights: Gaussian range likelihood over the valid links
    d = np.linalg.norm(ref_pred[:, :, None, :] - node_xy[:, None], axis=-1)
    loglik = np.sum(np.where(valid[:, None], -0.5 * ((theta[:, None] - d) * inv_s[:, None, None]) ** 2,
                             0.0), axis=-1)
    w = np.exp(loglik - loglik.max(-1, keepdims=True))
    w /= w.sum(-1, keepdims=True)
    ref_mean = np.einsum("bk,bkd->bd", w, ref_pred)
    dev = ref_pred - ref_mean[:, None]
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-13)
    np.testing.assert_allclose(cov, np.einsum("bk,bki,bkj->bij", w, dev, dev), rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(ess, 1 / np.sum(w * w, -1), rtol=1e-10)
    # systematic resampling with the given uniforms, and the gather
    class Fixed:
        def random(self, shape):
            return u.reshape(shape)
    np.testing.assert_array_equal(idx, systematic(w, Fixed()))
    assert np.all(np.diff(idx, axis=-1) >= 0)
    np.testing.assert_array_equal(out, np.take_along_axis(pred, idx[..., None], axis=1))
    np.testing.assert_array_equal(distinct, [len(np.unique(r)) for r in idx])


def test_kernel_draws_are_the_reference_draws_bit_for_bit():
    """The motion noise drawn inside the kernel (compiled with contraction) is
    ``standard_normal_numpy`` under the step's key, bit for bit: with unit noise std, no
    shift and particles at 0 the predicted particles are the draws themselves."""
    args = list(_kernel_inputs(b=2, k=3000, seed=11))
    args[0] = np.zeros_like(args[0])
    args[1] = np.zeros_like(args[1])
    args[2] = np.ones(2)
    pred = _run_kernel(tuple(args), 64)[6]
    np.testing.assert_array_equal(pred, R.standard_normal_numpy(None, pred.shape, key=args[3]))


def test_kernel_reading_through_ancestors_equals_the_gathered_particles():
    """``carried``: the particles read as ``particles[b, anc[b, i]]`` (the previous step's
    gather done in this step's first pass) give the same step, bit for bit, as the gathered
    array; without ``gather`` the kernel leaves ``out_particles`` alone."""
    args = _kernel_inputs(b=2, k=700, seed=8)
    src = args[0]
    rng = np.random.default_rng(2)
    anc = np.sort(rng.integers(0, 700, size=(2, 700)), axis=-1)
    gathered = np.take_along_axis(src, anc[..., None], axis=1)
    ref = _run_kernel((gathered,) + args[1:], 64)
    b, k = anc.shape
    out = np.full((b, k, 2), -7.0)
    idx = np.empty((b, k), dtype=np.int64)
    mean, cov, ess = np.empty((b, 2)), np.empty((b, 2, 2)), np.empty(b)
    distinct = np.empty(b, dtype=np.int64)
    pred, v = np.empty((b, k, 2)), np.empty((b, k))
    bs.bootstrap_step(src, anc, True, *args[1:], 64, False, out, idx, mean, cov, ess, distinct,
                      pred, v)
    for got, want in zip((idx, mean, cov, ess, distinct, pred), (ref[1], ref[2], ref[3], ref[4],
                                                                   ref[5], ref[6])):
        np.testing.assert_array_equal(got, want)
    assert np.all(out == -7.0)
    np.testing.assert_array_equal(ref[0], np.take_along_axis(pred, idx[..., None], axis=1))


def test_kernel_with_concentrated_and_empty_chunks():
    """Most weight on a few particles: chunks without offspring, chunks with one ancestor."""
    args = list(_kernel_inputs(b=2, k=500, seed=4))
    args[0] = args[0].copy()
    args[0][:, 100:] += 50.0                       # far from the ranges: weight ~ 0
    args[7] = np.array([1 / 0.05, 1 / 0.05])
    args = tuple(args)
    ref = None
    for chunk in (1, 13, 100, 4096):
        out, idx, *_, pred, v = _run_kernel(args, chunk)
        assert idx.max() < 100
        assert np.all(np.diff(idx, axis=-1) >= 0)
        if ref is None:
            ref = idx
        np.testing.assert_array_equal(idx, ref)         # the same whatever the chunking
        np.testing.assert_array_equal(out, np.take_along_axis(pred, idx[..., None], axis=1))


def _scene(steps=12, runs=2, seed=3):
    rng = np.random.default_rng(seed)
    x = np.cumsum(0.5 * rng.normal(size=(runs, 1, steps + 1, 2)), axis=2) + 15.0
    d = np.linalg.norm(x[:, :, 1:, None, :] - ANCHORS, axis=-1)
    y = d + 0.3 * rng.normal(size=d.shape)
    y[0, 0, min(3, steps - 1), 1] = np.nan        # a missing range
    ranges = np.concatenate([np.full(y.shape[:-1] + (1,), np.nan), y], axis=-1)
    return x, ranges


@pytest.mark.parametrize("motion", [RandomWalk(0.25), InputDriven(0.5)])
def test_filter_numba_equals_numpy_in_the_bootstrap_case(motion):
    x, ranges = _scene()
    controls = np.diff(x, axis=2) if isinstance(motion, InputDriven) else None
    out = {}
    for kernel in ("numba", "numpy"):
        pf = P2PParticleFilter(motion, LosNlosRange(0.3, 1.0, 1.0), particles=5000, kernel=kernel)
        out[kernel] = pf.run(ranges, x[:, :, 0], np.random.default_rng(5), anchors=ANCHORS,
                             controls=controls)
    a, b = out["numba"], out["numpy"]
    np.testing.assert_allclose(a.position, b.position, atol=1e-9)
    np.testing.assert_allclose(a.covariance, b.covariance, atol=1e-9)
    np.testing.assert_allclose(a.diagnostics["ess"], b.diagnostics["ess"], rtol=1e-8)
    np.testing.assert_array_equal(a.diagnostics["los_detected"], b.diagnostics["los_detected"])
    np.testing.assert_array_equal(a.diagnostics["resets"], b.diagnostics["resets"])
    # the filter tracks: mean error well below the range noise times the geometry
    err = np.linalg.norm(a.position[..., 1:, :] - x[:, :, 2:], axis=-1).mean()
    assert err < 0.5


def test_reset_in_the_bootstrap_case_matches_numpy():
    x, ranges = _scene(steps=4, runs=1)
    ranges = ranges.copy()
    ranges[..., 2, 1:] += 5.0                     # a step far from every particle
    out = {}
    for kernel in ("numba", "numpy"):
        pf = P2PParticleFilter(RandomWalk(0.01), LosNlosRange(0.05, 1.0, 1.0), particles=3000,
                               kernel=kernel, reset_fraction=0.2)
        out[kernel] = pf.run(ranges, x[:, :, 0], np.random.default_rng(9), anchors=ANCHORS)
    assert out["numba"].diagnostics["resets"][..., -1].max() >= 1
    np.testing.assert_allclose(out["numba"].position, out["numpy"].position, atol=1e-9)


def _count_fused(monkeypatch):
    calls = []
    real = bs.bootstrap_step

    class Spy:
        def bootstrap_step(self, *a):
            calls.append(1)
            return real(*a)
    monkeypatch.setattr(pp, "_bs", Spy())
    return calls


@pytest.mark.parametrize("case, fused", [
    (dict(), True),
    (dict(resampling="stratified"), False),
    (dict(measurement=LosNlosRange(0.3, 1.0, 0.9)), False),
    (dict(online_em=True), False),
    (dict(motion=ConstantVelocity(0.1), init_std=1.0), False),
])
def test_when_the_fused_step_is_taken(monkeypatch, case, fused):
    calls = _count_fused(monkeypatch)
    x, ranges = _scene(steps=3, runs=1)
    kw = dict(motion=RandomWalk(0.25), measurement=LosNlosRange(0.3, 1.0, 1.0), particles=300)
    kw.update(case)
    pf = P2PParticleFilter(kw.pop("motion"), kw.pop("measurement"), **kw)
    pf.run(ranges, x[:, :, 0], np.random.default_rng(1), anchors=ANCHORS)
    assert (len(calls) == 3) if fused else not calls


def test_carried_non_los_posterior_leaves_the_bootstrap_case():
    """A state whose carried LOS posteriors are not all 1 takes the general path."""
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.3, 1.0, 1.0), particles=200)
    x, ranges = _scene(steps=5, runs=1)                # no missing range at step 1
    nodes = np.concatenate([np.zeros((1, 1, 2)), ANCHORS[None]], axis=1)[None]
    state = pf.init(x[:, :, 0], np.random.default_rng(0))
    state = pf.step(state, ranges[:, :, 1], nodes, np.random.default_rng(1))
    params = pf._params(state)
    valid = np.ones((1, 1, 4), dtype=bool)
    slots = np.arange(4)[None, None]
    assert pf._bootstrap_noise(state, params, valid, slots, 1.0) is not None
    q = np.array(state.link_los)
    q[0, 0, 5, 2] = 0.5
    import dataclasses
    mixed = dataclasses.replace(state, link_los=q)
    assert pf._bootstrap_noise(mixed, params, valid, slots, 1.0) is None


def test_position_counts_at_ties_and_neighbours():
    """The count of positions (u + j) / K below a cumulative weight, at the positions
    themselves and one ulp either side (where the estimate ceil(K c - u) rounds the wrong
    way), equals the definition (searchsorted on the positions), clipped to a chunk's slots."""
    from numba import njit

    @njit
    def counts(cdf, u, nk, pos, f0, f1):
        out = np.empty((2, cdf.size), dtype=np.int64)
        for i in range(cdf.size):
            out[0, i] = min(max(bs._count_below(cdf[i], u, nk), f0), f1)
            out[1, i] = int(bs._count_below_div(cdf[i], u, nk, float(f0), float(f1)))
        return out

    rng = np.random.default_rng(17)
    wrong = 0
    for nk in (7, 1000, 99_991):
        for u in (0.0, rng.random(), 1 - 2.0 ** -53):
            pos = (u + np.arange(nk)) / nk
            f0, f1 = nk // 3, nk - nk // 5
            at = pos[f0:f1]
            cdf = np.concatenate([at, np.nextafter(at, 2.0), np.nextafter(at, -1.0)])
            cdf = cdf[cdf >= pos[f0 - 1]] if f0 else cdf
            ref = np.clip(np.searchsorted(pos, cdf, side="left"), f0, f1)
            got = counts(cdf, u, nk, pos, f0, f1)
            np.testing.assert_array_equal(got[0], ref)
            np.testing.assert_array_equal(got[1], ref)
            wrong += np.sum(np.ceil(cdf * nk - u).astype(np.int64) != ref)
    assert wrong > 0            # the corrections were needed somewhere
