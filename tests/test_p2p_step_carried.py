"""P2PParticleFilter.run with the resampling's gather of the link posteriors left to the next
step (``_run_carried``: the link kernel reads the carried posteriors through the ancestors)
gives, bit for bit, what init, step and estimate give step by step; the link update read
through ancestors equals the update of the gathered posteriors, batched and one by one; and
a kernel reading the wrong ancestors is caught."""

import numpy as np
import pytest

from radioloc.core.results import track_from_steps
from radioloc.estimators import p2p_particle as pp
from radioloc.estimators.p2p_particle import P2PParticleFilter, _link_update
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import ConstantVelocity, InputDriven
from radioloc.sim.highway import HighwayScenario, simulate


def by_steps(pf, ranges, initial, rng, anchors, controls=None):
    """The loop of ``run`` through the public init, step and estimate."""
    n_veh, T = ranges.shape[-3:-1]
    t = np.arange(T, dtype=float)
    dts = np.diff(t, prepend=t[0])                      # as run: the first step has dt = 0
    state = pf.init(initial, rng, time=t[0])
    batch = state.batch_shape[:-1]
    a = np.broadcast_to(anchors, batch + anchors.shape[-2:])
    out = []
    for k in range(T):
        uk = None if controls is None else controls[..., k, :]
        nodes = np.concatenate([np.broadcast_to(state.mean[..., :2], batch + (n_veh, 2)), a],
                               axis=-2)
        state = pf.step(state, ranges[..., k, :], nodes, rng, control=uk, dt=dts[k])
        out.append(pf.estimate(state))
    return track_from_steps(out, t)


def same_track(a, b):
    """Whether two tracks are equal bit for bit (arrays, dtypes, diagnostics)."""
    if not (np.array_equal(a.position, b.position) and np.array_equal(a.covariance, b.covariance)):
        return False
    if sorted(a.diagnostics) != sorted(b.diagnostics):
        return False
    for key in a.diagnostics:
        x, y = np.asarray(a.diagnostics[key]), np.asarray(b.diagnostics[key])
        if x.dtype != y.dtype or x.shape != y.shape or not np.array_equal(x, y, equal_nan=True):
            return False
    return True


@pytest.fixture
def carried_calls(monkeypatch):
    """Counts the runs that took ``_run_carried`` (so an equality is not a fallback's)."""
    calls = []
    orig = P2PParticleFilter._run_carried

    def wrapped(self, *args):
        calls.append(1)
        return orig(self, *args)
    monkeypatch.setattr(P2PParticleFilter, "_run_carried", wrapped)
    return calls


def highway(runs=2, steps=8, seed=3):
    model = LosNlosRange(0.05, 5.0, 0.3)
    sc = HighwayScenario(vehicles=6, anchors=6, steps=steps, start_width_m=20.0)
    data = simulate(sc, model, runs, np.random.default_rng(seed))
    return sc, model, data


def test_carried_run_equals_steps_highway(carried_calls):
    """The paper 001 highway (InputDriven, s = 5 cm: frequent resets with 64 particles)."""
    sc, model, data = highway()
    pf = P2PParticleFilter(InputDriven(sc.ins_std_m), model, particles=64)
    fast = pf.run(data.ranges, data.truth[:, :, 0], np.random.default_rng(1),
                  anchors=data.anchors, controls=data.ins)
    ref = by_steps(pf, data.ranges, data.truth[:, :, 0], np.random.default_rng(1),
                   data.anchors, controls=data.ins)
    assert carried_calls == [1]
    assert fast.diagnostics["resets"][..., -1].sum() > 0          # the reset branch ran
    assert same_track(fast, ref)


def test_carried_run_equals_steps_velocity_state(carried_calls):
    """A 4-D state (position and velocity): a reset keeps the resampled velocities."""
    sc, _, data = highway(runs=1, steps=6, seed=4)
    model = LosNlosRange(0.3, 4.0, 0.6)
    pf = P2PParticleFilter(ConstantVelocity(0.5), model, particles=48, init_std=[1.0, 1.0, 0.5, 0.5],
                           reset_fraction=0.5)
    fast = pf.run(data.ranges, data.truth[:, :, 0], np.random.default_rng(2), anchors=data.anchors)
    ref = by_steps(pf, data.ranges, data.truth[:, :, 0], np.random.default_rng(2), data.anchors)
    assert carried_calls == [1]
    assert fast.diagnostics["resets"][..., -1].sum() > 0
    assert same_track(fast, ref)


def test_fallbacks_do_not_take_the_carried_path(carried_calls):
    """Online EM and other resampling schemes keep the step loop."""
    sc, model, data = highway(runs=1, steps=3)
    for kw in ({"online_em": True}, {"resampling": "stratified"}, {"kernel": "numpy"}):
        pf = P2PParticleFilter(InputDriven(sc.ins_std_m), model, particles=32, **kw)
        pf.run(data.ranges, data.truth[:, :, 0], np.random.default_rng(0), anchors=data.anchors,
               controls=data.ins)
    assert carried_calls == []


def _link_inputs(seed, b=(2, 3), k=40, width=6, width_prev=5):
    rng = np.random.default_rng(seed)
    particles = rng.normal(size=b + (k, 2)) * 3.0
    node_xy = rng.normal(size=b + (width, 2)) * 5
    th = rng.uniform(0, 12, size=b + (width,))
    valid = rng.random(b + (width,)) < 0.8
    where_prev = np.where(rng.random(b + (width,)) < 0.6,
                          rng.integers(0, width_prev, b + (width,)), -1)
    prev_q = rng.random(b + (k, width_prev))
    params = np.stack([rng.uniform(0.02, 0.5, b), rng.uniform(0.5, 8.0, b),
                       rng.uniform(0.05, 0.95, b)], -1)
    # ancestors as systematic resampling leaves them: sorted, with repeats and gaps
    anc = np.sort(rng.integers(0, k, b + (k,)), axis=-1)
    return particles, node_xy, th, valid, where_prev, prev_q, params, anc


def _same(a, b):
    return all(np.array_equal(x, y) for x, y in zip(a, b) if x is not None)


def test_link_update_through_ancestors_equals_gathered():
    """The kernel's read through the ancestors is the gather: equal bit for bit to the
    update of ``prev_q[anc]``, batched and filter by filter, and to the NumPy reference
    given the same ancestors."""
    p, nxy, th, valid, wp, q, params, anc = _link_inputs(7)
    args = (p, nxy, th, valid, wp)
    gathered = np.take_along_axis(q, anc[..., None], axis=-2)
    ref = _link_update(*args, gathered, params, "numba", True)
    fast = _link_update(*args, q, params, "numba", True, anc=anc)
    assert _same(fast, ref)
    for i in range(2):
        for j in range(3):
            one = _link_update(*(a[i, j] for a in args), q[i, j], params[i, j], "numba", True,
                               anc=anc[i, j])
            assert _same(one, tuple(None if x is None else x[i, j] for x in fast))
    np_ref = _link_update(*args, gathered, params, "numpy", True)
    np_anc = _link_update(*args, q, params, "numpy", True, anc=anc)
    assert _same(np_anc, np_ref)


def test_link_update_carried_gaussian_case():
    """Alpha = 1 with every carried posterior 1 among the ancestors' rows (not among the
    others): the Gaussian case is decided on the rows the ancestors point at."""
    p, nxy, th, valid, wp, q, params, anc = _link_inputs(8, b=(3,), k=32)
    params[:, 2] = 1.0
    anc[:] = np.arange(0, 32, 2)[None, :].repeat(2, axis=-1)       # even rows only
    anc.sort(axis=-1)
    q[:, ::2, :] = 1.0                                              # odd rows stay < 1
    gathered = np.take_along_axis(q, anc[..., None], axis=-2)
    ref = _link_update(p, nxy, th, valid, wp, gathered, params, "numba", False)
    fast = _link_update(p, nxy, th, valid, wp, q, params, "numba", False, anc=anc)
    assert fast[4].all() and ref[4].all()
    assert _same(fast, ref)


def test_a_wrong_ancestor_read_is_caught(monkeypatch):
    """A deliberate break (the kernel handed the ancestors of the particle next to each)
    makes the carried run differ from the step loop: the equality above can fail."""
    sc, model, data = highway(runs=1, steps=5)
    pf = P2PParticleFilter(InputDriven(sc.ins_std_m), model, particles=64)
    orig = pp._k.link_weights

    def broken(*args):
        args = list(args)
        if args[7]:                                     # carried: shift the ancestors
            args[6] = np.ascontiguousarray(np.roll(args[6], 1, axis=-1))
        return orig(*args)
    ref = by_steps(pf, data.ranges, data.truth[:, :, 0], np.random.default_rng(1),
                   data.anchors, controls=data.ins)
    monkeypatch.setattr(pp._k, "link_weights", broken)
    bad = pf.run(data.ranges, data.truth[:, :, 0], np.random.default_rng(1),
                 anchors=data.anchors, controls=data.ins)
    assert not same_track(bad, ref)


@pytest.mark.parametrize("carried", [False, True])
def test_link_major_layout_equals_particle_major(carried):
    """``link_major`` (the layout ``run`` carries: one row per link) gives the values of the
    state's ``(K, L)`` layout, on the rows of existing links, batched and one by one."""
    p, nxy, th, valid, wp, q, params, anc = _link_inputs(9)
    args = (p, nxy, th, valid, wp)
    kw = {"anc": anc} if carried else {}
    ref = _link_update(*args, q, params, "numba", True, **kw)
    q_lk = np.ascontiguousarray(np.swapaxes(q, -1, -2))                  # (..., L', K)
    fast = _link_update(*args, q_lk, params, "numba", True, link_major=True, **kw)
    assert fast[1].shape == ref[1].shape[:-2] + ref[1].shape[:-3:-1]
    rows = np.swapaxes(fast[1], -1, -2)
    assert np.array_equal(np.where(valid[..., None, :], rows, 0.0), ref[1])
    assert _same(fast[:1] + fast[2:], ref[:1] + ref[2:])
    one = _link_update(*(a[1, 2] for a in args), q_lk[1, 2], params[1, 2], "numba", True,
                       link_major=True, **({"anc": anc[1, 2]} if carried else {}))
    assert np.array_equal(one[0], fast[0][1, 2]) and np.array_equal(one[2], fast[2][1, 2])
    assert np.array_equal(one[1][valid[1, 2]], fast[1][1, 2][valid[1, 2]])


def test_link_major_shared_row_and_first_step():
    """The broadcast row a Gaussian-case step leaves (stride 0 on the particle axis) and the
    first step's empty posteriors, in the link-major layout."""
    p, nxy, th, valid, wp, q, params, anc = _link_inputs(10, b=(3,), k=24)
    row = np.random.default_rng(0).random((3, 1, 5))
    ref = _link_update(p, nxy, th, valid, wp, np.broadcast_to(row, (3, 24, 5)), params,
                       "numba", False, anc=anc)
    fast = _link_update(p, nxy, th, valid, wp, np.broadcast_to(np.swapaxes(row, 1, 2), (3, 5, 24)),
                        params, "numba", False, anc=anc, link_major=True)
    assert _same((fast[0], fast[2]), (ref[0], ref[2]))
    assert np.array_equal(np.swapaxes(fast[1], 1, 2)[np.broadcast_to(valid[:, None], (3, 24, 6))],
                          ref[1][np.broadcast_to(valid[:, None], (3, 24, 6))])
    ref0 = _link_update(p, nxy, th, valid, wp, np.zeros((3, 24, 0)), params, "numba", False)
    fast0 = _link_update(p, nxy, th, valid, wp, np.zeros((3, 0, 24)), params, "numba", False,
                         link_major=True)
    assert _same((fast0[0], fast0[2]), (ref0[0], ref0[2]))


@pytest.mark.parametrize("control", [False, True])
def test_carried_run_equals_steps_random_walk(carried_calls, control):
    """A random walk (the prediction gathers the resampled particles itself:
    ``pf_kernels.walk_gather``), with and without a displacement control."""
    from radioloc.models.motion import RandomWalk
    sc, model, data = highway(runs=2, steps=6, seed=6)
    pf = P2PParticleFilter(RandomWalk(0.4), model, particles=40)
    ctrl = data.ins if control else None
    fast = pf.run(data.ranges, data.truth[:, :, 0], np.random.default_rng(3), anchors=data.anchors,
                  controls=ctrl)
    ref = by_steps(pf, data.ranges, data.truth[:, :, 0], np.random.default_rng(3), data.anchors,
                   controls=ctrl)
    assert carried_calls == [1]
    assert fast.diagnostics["resets"][..., -1].sum() > 0
    assert same_track(fast, ref)


def test_walk_gather_equals_numpy():
    """``walk_gather`` is ``z *= sd; z += particles[anc] + shift`` bit for bit."""
    from radioloc.estimators import pf_kernels as K
    g = np.random.default_rng(11)
    x = g.normal(size=(3, 50, 2)) * 1e3
    anc = np.sort(g.integers(0, 50, (3, 50)), axis=-1)
    shift = g.normal(size=(3, 2))
    sd = np.array([0.3, 1.7])
    z = g.standard_normal((3, 50, 2))
    for gathered in (False, True):
        for shifted in (False, True):
            out = np.empty_like(z)
            K.walk_gather(x, anc, gathered, shift, shifted, sd, z, out, 16)
            src = np.take_along_axis(x, anc[..., None], axis=1) if gathered else x
            ref = z * sd
            ref += src + shift[:, None] if shifted else src
            assert np.array_equal(out, ref)


@pytest.mark.parametrize("n", [2, 4])
def test_moments_resample_equals_the_two_kernels(n):
    """``moments_resample`` (one pass per filter) equals ``weights_moments`` then
    ``systematic_indices`` bit for bit, batched and one filter at a time."""
    from radioloc.estimators import pf_kernels as K
    g = np.random.default_rng(12 + n)
    b, k = 5, 300
    log_w = g.normal(size=(b, k)) * 30.0
    log_w[1, :] = -1e3 + g.normal(size=k)                 # far below 0: the maximum matters
    log_w[2, :7] = -np.inf                                # zero weights
    x = g.normal(size=(b, k, n)) * 5 + 1e4
    u = g.random(b)
    w, mean, cov, ess = np.empty((b, k)), np.empty((b, n)), np.empty((b, n, n)), np.empty(b)
    K.weights_moments(log_w, x, 2048, w, mean, cov, ess)
    idx = np.empty((b, k), dtype=np.int64)
    K.systematic_indices(w, u, idx, 2048)
    distinct = np.array([len(np.unique(row)) for row in idx])
    assert distinct.min() < k and distinct.max() > 1               # some ancestors repeat
    out = (np.empty((b, k)), np.empty((b, n)), np.empty((b, n, n)), np.empty(b),
           np.empty((b, k), dtype=np.int64), np.empty(b, dtype=np.int64))
    K.moments_resample(log_w, x, u, *out)
    for a, ref in zip(out, (w, mean, cov, ess, idx, distinct)):
        assert np.array_equal(a, ref)
    one = (np.empty((1, k)), np.empty((1, n)), np.empty((1, n, n)), np.empty(1),
           np.empty((1, k), dtype=np.int64), np.empty(1, dtype=np.int64))
    K.moments_resample(log_w[3:4], x[3:4], u[3:4], *one)
    assert all(np.array_equal(a[0], ref[3])
               for a, ref in zip(one, (w, mean, cov, ess, idx, distinct)))


def test_run_names_a_non_finite_peer_position(carried_calls):
    """``messages="given"``: a NaN neighbour position raises InputError naming the field and
    the index, before any step; the finite ones run the compiled path."""
    from radioloc.core.errors import InputError
    sc, model, data = highway(runs=1, steps=4, seed=8)
    pf = P2PParticleFilter(InputDriven(sc.ins_std_m), model, particles=32, messages="given")
    given = np.array(data.truth[..., :2], dtype=float)          # (runs, N, T, 2)
    tr = pf.run(data.ranges, data.truth[:, :, 0], np.random.default_rng(0), anchors=data.anchors,
                controls=data.ins, given_positions=given)
    assert np.all(np.isfinite(tr.position)) and carried_calls == [1]
    given[:, 2, 1] = np.nan                                     # vehicle 2 at step 1
    with pytest.raises(InputError, match=r"given_positions: .*\(0, 2, 1, 0\)"):
        pf.run(data.ranges, data.truth[:, :, 0], np.random.default_rng(0), anchors=data.anchors,
               controls=data.ins, given_positions=given)
