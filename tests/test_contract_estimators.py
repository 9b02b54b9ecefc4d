"""The estimator contract, for every class of ``radioloc.estimators.ESTIMATORS``.

Each estimator runs on a small generated problem whose truth has ``x != y``: the result
must be an :class:`Estimate` (snapshot) or a :class:`Track` (recursive) of the contract's
shapes, close to the truth in ``(x, y)`` order (and far from the swapped truth), equal
batch-wise and one problem at a time, and a NaN measurement must be skipped (finite
result, no error). A new paper estimator without a case here fails
``test_every_estimator_has_a_case``; a generic one (``tags.generic``) needs none: the pairs
of ``tests/model_cases.py`` check it (``test_contract_generic.py``).
The per-family files (``test_contract_p000.py`` ... ``test_contract_mixture.py``) go further.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pytest
from model_cases import pairs

from radioloc.core.alignment import rigid_aligned_error
from radioloc.core.results import Estimate, Track
from radioloc.estimators import (
    ESTIMATORS,
    ClosedFormTracker,
    GridFilter,
    GridGeometry,
    LocalML,
    MixtureLocalizer,
    MixtureTracker,
    Multilateration,
    NetworkEKF,
    NetworkRLS,
    NewtonTracker,
    P2PParticleFilter,
    RangeEKF,
    Ransac,
)
from radioloc.estimators.base import RecursiveEstimator, SnapshotEstimator
from radioloc.models import (
    ConstantVelocity,
    DiagMixture,
    GaussianRange,
    InputDriven,
    LogDistanceGaussian,
    LosNlosRange,
    UniformDisk,
)

B = 3                                                   # problems per batch
ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0], [30.0, 20.0]])


@dataclass
class Case:
    """``solve(idx)`` runs the estimator on problems ``idx`` (a slice of the batch);
    ``truth`` is ``(B, [T,] 2)`` (leading axes as the result's); ``solve_nan`` runs it with
    one measurement replaced by NaN; ``exact``: batch equals one-by-one to rounding."""

    solve: Callable[[slice], Estimate | Track]
    truth: np.ndarray
    solve_nan: Callable[[], Estimate | Track]
    tol_m: float
    exact: bool = True
    align: bool = False       # compare the shape of a node constellation (rigid alignment)


def _truth(rng, n=B):
    return np.c_[rng.uniform(4, 26, n), rng.uniform(3, 9, n)]


def case_multilateration():
    rng = np.random.default_rng(0)
    truth = _truth(rng)
    r = np.linalg.norm(truth[:, None] - ANCHORS, axis=-1) + 0.01 * rng.standard_normal((B, 4))
    est = Multilateration(std_m=0.01)
    r_nan = np.c_[r, np.full(B, np.nan)]
    a5 = np.r_[ANCHORS, [[15.0, 30.0]]]
    return Case(lambda i: est.locate(r[i], ANCHORS), truth,
                lambda: est.locate(r_nan, a5), 0.05)


def _network(seed=1, K=5, N=6, std=0.05):
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0, 30, (B, K, 2)) * [1.0, 0.6] + [0.0, 3.0]
    d = np.linalg.norm(truth[:, :, None] - truth[:, None], axis=-1)
    ranges = d[:, None] + std * rng.standard_normal((B, N, K, K))
    ranges = 0.5 * (ranges + np.swapaxes(ranges, -1, -2))
    prior = truth + rng.normal(0, 1.0, truth.shape)
    return truth, ranges, prior


def case_network_ekf():
    truth, ranges, prior = _network()
    ekf = NetworkEKF(std_m=0.05)
    nan = ranges.copy()
    nan[:, 2, 0, 3] = nan[:, 2, 3, 0] = np.nan
    # batch axes (runs, nodes) lead, then time: truth per node repeated over iterations
    return Case(lambda i: ekf.run(ranges[i], prior[i], 1.0), truth[:, :, None, :],
                lambda: ekf.run(nan, prior, 1.0), 2.5)   # the frame is fixed by 1 m priors


def case_network_rls():
    truth, ranges, prior = _network(seed=2)
    rls = NetworkRLS(forgetting=0.7)
    nan = ranges.copy()
    nan[:, 3, 1, 2] = nan[:, 3, 2, 1] = np.nan
    # the RLS forgets its priors (units of eq. (12)), so the network's frame drifts: its
    # shape is what it estimates
    return Case(lambda i: rls.run(ranges[i], prior[i], 1.0), truth[:, :, None, :],
                lambda: rls.run(nan, prior, 1.0), 2.0, align=True)


def _walk(seed=3, T=40, dt=0.5):
    rng = np.random.default_rng(seed)
    t = np.arange(T) * dt
    start = _truth(rng)
    truth = start[:, None, :] + np.stack([0.6 * t, 0.2 * t], -1)
    r = np.linalg.norm(truth[..., None, :] - ANCHORS, axis=-1) + 0.05 * rng.standard_normal((B, T, 4))
    return t, truth, r, start


def case_range_ekf():
    t, truth, r, start = _walk()
    ekf = RangeEKF(ConstantVelocity(0.05), GaussianRange(0.05), anchors=ANCHORS)
    prior = np.c_[start, np.zeros((B, 2))]
    nan = r.copy()
    nan[:, 5, 1] = np.nan
    return Case(lambda i: ekf.run(r[i], t, prior_mean=prior[i], prior_cov=np.eye(4)), truth,
                lambda: ekf.run(nan, t, prior_mean=prior, prior_cov=np.eye(4)), 0.1)


def case_particle_filter():
    t, truth, r, start = _walk(seed=4, T=25)
    # one vehicle per run: ranges (runs, vehicles, T, 1 + anchors) with the self column NaN
    ranges = np.concatenate([np.full((B, 1, 25, 1), np.nan), r[:, None]], axis=-1)
    steps = np.diff(np.concatenate([start[:, None], truth], axis=1), axis=1)[:, None]
    pf = P2PParticleFilter(InputDriven(0.02), LosNlosRange(0.05, 5.0, 0.95), particles=400,
                           init_std=0.3, reset_std_m=0.1)
    nan = ranges.copy()
    nan[:, :, 4, 2] = np.nan
    init = start[:, None]

    def solve(i):
        return pf.run(ranges[i], init[i], np.random.default_rng(5), anchors=ANCHORS,
                      controls=steps[i])
    return Case(solve, truth[:, None],
                lambda: pf.run(nan, init, np.random.default_rng(5), anchors=ANCHORS,
                               controls=steps), 0.15, exact=False)


def _snapshot_links(seed):
    rng = np.random.default_rng(seed)
    truth = _truth(rng)
    centres = np.broadcast_to(np.r_[ANCHORS, [[15.0, -5.0]]], (B, 5, 2))
    r = np.linalg.norm(truth[:, None] - centres, axis=-1) + 0.02 * rng.standard_normal((B, 5))
    nan = r.copy()
    nan[:, 4] = np.nan
    return truth, centres, r, nan


def case_local_ml():
    truth, centres, r, nan = _snapshot_links(6)
    ml = LocalML(LosNlosRange(0.02, 5.0, 0.9), radius_m=40.0)
    return Case(lambda i: ml.locate(r[i], centres[i]), truth, lambda: ml.locate(nan, centres),
                0.1)


def case_ransac():
    truth, centres, r, nan = _snapshot_links(7)
    r[:, 0] += 6.0                                      # one NLOS outlier per problem
    rs = Ransac(threshold_m=0.5, radius_m=40.0)
    return Case(lambda i: rs.locate(r[i], centres[i]), truth, lambda: rs.locate(nan, centres),
                0.1)


def _single_sensor(seed, n=12, T=0.5):
    rng = np.random.default_rng(seed)
    k = np.arange(n)
    sensor = np.c_[20 * np.cos(1.3 * k), 20 * np.sin(1.3 * k)]
    start = _truth(rng)
    vel = np.array([0.8, 0.3])
    track = start[:, None] + (k * T)[:, None] * vel                 # (B, n, 2)
    r = np.linalg.norm(track - sensor, axis=-1) + 0.01 * rng.standard_normal((B, n))
    return sensor, track[:, -1], r, T, np.c_[track[:, -1], np.broadcast_to(vel, (B, 2))]


def case_closed_form():
    sensor, truth, r, T, _ = _single_sensor(8)
    cf = ClosedFormTracker(accel_var=1e-6, std_m=0.01)
    nan = r.copy()
    nan[:, 4] = np.nan      # its difference rows are dropped
    return Case(lambda i: cf.locate(r[i], sensor, T), truth,
                lambda: cf.locate(nan, sensor, T), 0.1)


def case_newton():
    sensor, truth, r, T, state = _single_sensor(9)
    nt = NewtonTracker()
    nan = r.copy()
    nan[:, 3] = np.nan
    start = state + 0.3
    return Case(lambda i: nt.locate(r[i], sensor, T, initial_state=start[i]), truth,
                lambda: nt.locate(nan, sensor, T, initial_state=start), 0.1)


GEOM = GridGeometry.centred(40, 24, 0.5, centre=(15.0, 6.0))
LOGD = LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1)


def case_grid():
    rng = np.random.default_rng(10)
    truth = np.array([[20.0, 4.0], [8.0, 9.0], [14.0, 2.0]])
    xy = rng.uniform([6, 0], [24, 12], (B, 30, 2))
    rssi = LOGD.mean(np.linalg.norm(xy - truth[:, None], axis=-1))
    gf = GridFilter(GEOM, LOGD, epsilon=1e-12)
    nan = rssi.copy()
    nan[:, 7] = np.nan
    return Case(lambda i: gf.run(xy[i], rssi[i]), np.broadcast_to(truth[:, None], (B, 30, 2)),
                lambda: gf.run(xy, nan), 0.6)


STATIONS = np.array([[0.0, 0.0], [12.0, 0.0], [0.0, 6.0], [12.0, 6.0]])


def _mean_rss(p):
    d = np.linalg.norm(np.asarray(p, float)[..., None, :] - STATIONS, axis=-1)
    return -40.0 - 20.0 * np.log10(np.maximum(d, 0.5))


def _mixture_models():
    gx, gy = np.meshgrid(np.arange(0.0, 12.1, 1.0), np.arange(0.0, 6.1, 1.0))
    grid = np.c_[gx.ravel(), gy.ravel()]
    m = _mean_rss(grid)
    k, s = m.shape
    means = np.concatenate([np.broadcast_to(grid, (s, k, 2)), m.T[..., None]], axis=-1)
    return DiagMixture.create(np.ones((s, k)), means, np.broadcast_to([0.3, 0.3, 0.5], (s, k, 3)))


def case_mixture_localizer():
    truth = np.array([[8.0, 2.0], [3.0, 5.0], [10.0, 1.0]])
    rss = _mean_rss(truth)
    loc = MixtureLocalizer(_mixture_models(), max_components=8)
    nan = rss.copy()
    nan[:, 1] = np.nan
    return Case(lambda i: loc.locate(rss[i]), truth, lambda: loc.locate(nan), 0.4)


def case_mixture_tracker():
    time = 0.5 * np.arange(8)
    starts = np.array([[2.0, 1.0], [3.0, 4.5], [1.0, 2.0]])
    truth = starts[:, None] + np.c_[1.0 * time, 0.3 * time]
    rss = _mean_rss(truth)
    trk = MixtureTracker(_mixture_models(), UniformDisk(1.5), max_components=8)
    nan = rss.copy()
    nan[:, 3, 2] = np.nan
    return Case(lambda i: trk.run(rss[i], time), truth, lambda: trk.run(nan, time), 0.8)


CASES = {
    Multilateration: case_multilateration, NetworkEKF: case_network_ekf,
    NetworkRLS: case_network_rls, RangeEKF: case_range_ekf,
    P2PParticleFilter: case_particle_filter, LocalML: case_local_ml, Ransac: case_ransac,
    ClosedFormTracker: case_closed_form, NewtonTracker: case_newton, GridFilter: case_grid,
    MixtureLocalizer: case_mixture_localizer, MixtureTracker: case_mixture_tracker,
}


def test_every_estimator_has_a_case():
    import radioloc.estimators as est
    classes = {getattr(est, n) for n in est.__all__}
    assert set(ESTIMATORS) <= classes
    # a generic estimator needs no case: test_contract_generic.py runs it on every model
    # case of tests/model_cases.py its tags accept
    # (a generic one with a paper form of its inputs, the grid filter, keeps its case)
    assert {cls for cls in ESTIMATORS if not cls.tags.generic} <= set(CASES) <= set(ESTIMATORS)
    for cls in ESTIMATORS:
        assert issubclass(cls, SnapshotEstimator)
        if cls.tags.generic:
            assert any(c is cls for c, _ in pairs()), f"{cls.__name__}: no model case accepted"


def _final(result):
    """Position per problem at the last step (Track) or the estimate itself."""
    return result.position[..., -1, :] if isinstance(result, Track) else result.position


@pytest.fixture(params=list(CASES), ids=lambda c: c.__name__)
def case(request):
    return request.param, CASES[request.param]()


def test_result_type_shapes_and_xy_order(case):
    cls, c = case
    res = c.solve(slice(None))
    want = Track if issubclass(cls, RecursiveEstimator) else Estimate
    assert isinstance(res, want), type(res)
    truth = c.truth
    if isinstance(res, Track):
        assert res.position.shape[-1] == 2 and res.position.shape[0] == B
        assert res.time.shape[-1] == res.steps
        truth_last = truth[..., -1, :]
    else:
        assert res.position.shape == truth.shape
        truth_last = truth
    if res.covariance is not None:
        assert res.covariance.shape == res.position.shape + (2,)
    pos = _final(res)
    if c.align:
        err = rigid_aligned_error(pos, truth_last)
        # per constellation: a node near the centre of the alignment can match either
        swapped = np.broadcast_to(
            rigid_aligned_error(pos, truth_last[..., ::-1]).mean(-1, keepdims=True), err.shape)
    else:
        err = np.linalg.norm(pos - truth_last, axis=-1)
        swapped = np.linalg.norm(pos - truth_last[..., ::-1], axis=-1)
    assert np.all(err < c.tol_m), err
    assert np.all(swapped > err), "estimate is closer to the (y, x) truth"
    assert np.all(np.isfinite(res.position))


def test_batch_equals_one_by_one(case):
    _, c = case
    whole = c.solve(slice(None))
    for i in range(B):
        one = c.solve(slice(i, i + 1))
        if c.exact:
            np.testing.assert_allclose(one.position[0], whole.position[i], rtol=1e-9, atol=1e-9)
        else:   # a particle filter's draws depend on the batch: same accuracy, not same draws
            e1 = np.linalg.norm(_final(one)[0] - _final(whole)[i], axis=-1)
            assert np.all(e1 < 2 * c.tol_m)


def test_nan_measurement_is_skipped(case):
    cls, c = case
    if c.solve_nan is None:
        pytest.skip(f"{cls.__name__} needs every sample: a NaN raises InputError (tested in its "
                    "family file)")
    res = c.solve_nan()
    assert np.all(np.isfinite(res.position))
    if res.covariance is not None:
        assert np.all(np.isfinite(res.covariance))


def test_diagnostics_use_the_shared_names(case):
    from radioloc.core.results import DIAGNOSTICS
    _, c = case
    res = c.solve(slice(None))
    unknown = set(res.diagnostics) - set(DIAGNOSTICS)
    assert not unknown, f"diagnostics not in core.results.DIAGNOSTICS: {sorted(unknown)}"
