"""The grid filter on the estimator contract (paper 003, Algorithms 1-3 and Algorithm 4's
grid operations): result types and shapes, (x, y) order against a truth, batch equals
one-by-one, NaN readings skipped, bad input raising the toolkit's errors."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.results import Estimate, Track
from radioloc.estimators.base import RecursiveEstimator
from radioloc.estimators.grid import GridFilter, GridGeometry, GridState, blur_grid, grid_moments
from radioloc.models.motion import ConstantAcceleration, ConstantVelocity, RandomWalk
from radioloc.models.rssi_logdistance import LogDistanceGaussian
from radioloc.models.rssi_trapezoid import fit_trapezoid_model

GEOM = GridGeometry.centred(30, 24, 0.5)               # 15 m x 12 m, w != h on purpose
LOGD = LogDistanceGaussian(a=60.0, n=2.0, s=2.0, d_ref_m=0.1)
TRUTH = np.array([4.0, -2.5])                          # x != y, both inside the grid


def _trapezoid():
    rng = np.random.default_rng(0)
    d = rng.uniform(0, 20, 6000)
    r = np.clip(np.rint(80 - 3.0 * d + rng.normal(0, 1.5, d.size)), 0, 100)
    return fit_trapezoid_model(r, d, tau_min=0.3, sigma_min=0.3, window=1)


TRAP = _trapezoid()


def _readings(B, T, seed=1, model="logd"):
    """Readings at random tracker positions: noise-free mean RSSI of the true distance."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-6, 6, (B, T, 2))
    d = np.linalg.norm(xy - TRUTH, axis=-1)
    if model == "logd":
        return xy, LOGD.mean(d)
    return xy, np.argmin(np.abs(TRAP.mu[None, None, :] - d[..., None]), axis=-1).astype(float)


def test_is_a_recursive_estimator_with_settings_in_the_constructor():
    f = GridFilter(GEOM, LOGD, epsilon=1e-8, blur_m=0.2)
    assert isinstance(f, RecursiveEstimator)
    params = f.get_params()
    assert params["epsilon"] == 1e-8 and params["blur_m"] == 0.2 and params["location"] == "mean"


def test_types_and_shapes():
    f = GridFilter(GEOM, LOGD, epsilon=1e-9, blur_m=0.1)
    xy, r = _readings(3, 12)
    track = f.run(xy, r, dt=0.5)
    assert isinstance(track, Track)
    assert track.position.shape == (3, 12, 2)
    assert track.covariance.shape == (3, 12, 2, 2)
    np.testing.assert_allclose(track.time, 0.5 * np.arange(1, 13))
    assert track.diagnostics["uncertainty_m"].shape == (3, 12)
    assert track.diagnostics["measurements_used"].shape == (3, 12)
    cov = track.covariance
    np.testing.assert_allclose(cov, np.swapaxes(cov, -1, -2))
    assert np.all(np.linalg.eigvalsh(cov) >= -1e-12)
    state = f.init(3)
    assert isinstance(state, GridState) and state.p.shape == (3, GEOM.h, GEOM.w)
    est = f.estimate(f.step(state, xy[:, 0], r[:, 0]))
    assert isinstance(est, Estimate)
    assert est.position.shape == (3, 2) and est.covariance.shape == (3, 2, 2)
    assert f.locate(xy, r).position.shape == (3, 2)


@pytest.mark.parametrize("model,location", [("logd", "mean"), ("logd", "peak"),
                                            ("trap", "peak"), ("trap", "mean")])
def test_converges_to_the_truth_in_xy_order(model, location):
    f = GridFilter(GEOM, LOGD if model == "logd" else TRAP, epsilon=1e-12, location=location)
    xy, r = _readings(2, 40, model=model)
    track = f.run(xy, r)
    err = track.error(np.broadcast_to(TRUTH, (2, 40, 2)))
    assert np.all(err[:, -1] < 0.75), err[:, -1]          # 0.5 m cells
    assert np.all(err[:, -1] < err[:, 0])
    # (y, x) would be about 9 m off
    assert np.all(np.linalg.norm(track.position[:, -1] - TRUTH[::-1], axis=-1) > 5.0)


def test_tracker_near_a_target_converges_toward_it():
    # one tracker standing 3 m from the target, moving on a small circle around it
    f = GridFilter(GEOM, LOGD, epsilon=1e-12)
    ang = np.linspace(0, 2 * np.pi, 30, endpoint=False)
    xy = (TRUTH + 3.0 * np.stack([np.cos(ang), np.sin(ang)], -1))[None]
    r = LOGD.mean(np.full((1, 30), 3.0))
    err = f.run(xy, r).error(np.broadcast_to(TRUTH, (1, 30, 2)))[0]
    assert err[-1] < 0.3 and err[-1] < err[0]


def test_batch_equals_one_by_one():
    f = GridFilter(GEOM, TRAP, epsilon=1e-9, motion=RandomWalk(0.04))
    xy, r = _readings(4, 8, seed=3, model="trap")
    r[1, 3] = np.nan
    shift = np.random.default_rng(4).uniform(-0.7, 0.7, (4, 8, 2))
    extra = np.random.default_rng(5).uniform(0, 0.5, (4, 8))
    both = f.run(xy, r, shift_m=shift, extra_blur_m=extra)
    for b in range(4):
        one = f.run(xy[b:b + 1], r[b:b + 1], shift_m=shift[b:b + 1], extra_blur_m=extra[b:b + 1])
        np.testing.assert_allclose(both.position[b], one.position[0], rtol=0, atol=1e-12)
        np.testing.assert_allclose(both.covariance[b], one.covariance[0], rtol=0, atol=1e-12)


def test_nan_reading_is_prediction_only():
    f = GridFilter(GEOM, TRAP, epsilon=1e-9, blur_m=0.4)
    xy, r = _readings(3, 5, model="trap")
    state = f.run(xy, r).at(4)  # noqa: F841  (runs without error)
    s0 = f.step(f.init(3), xy[:, 0], r[:, 0])
    rr = r[:, 1].copy()
    rr[1] = np.nan
    pos = xy[:, 1].copy()
    pos[1] = np.nan                                    # no position needed without a reading
    stepped = f.step(s0, pos, rr)
    predicted = f.predict(s0)
    full = f.step(s0, xy[:, 1], r[:, 1])
    np.testing.assert_array_equal(stepped.p[1], predicted.p[1])
    np.testing.assert_allclose(stepped.p[[0, 2]], full.p[[0, 2]])
    # all NaN: the step is exactly the prediction
    np.testing.assert_array_equal(f.step(s0, xy[:, 1], np.full(3, np.nan)).p, predicted.p)
    # a NaN series gives a finite track that only follows the prediction there
    r2 = r.copy()
    r2[:, 2] = np.nan
    track = f.run(xy, r2)
    assert np.all(np.isfinite(track.position)) and np.all(np.isfinite(track.covariance))
    np.testing.assert_array_equal(track.diagnostics["measurements_used"][:, 2], 0)
    np.testing.assert_array_equal(track.diagnostics["measurements_used"][:, 1], 1)


def test_step_is_pure():
    f = GridFilter(GEOM, LOGD, blur_m=0.3)
    s0 = f.init(2)
    before = s0.p.copy()
    f.step(s0, np.zeros((2, 2)), [50.0, 40.0], shift_m=np.ones((2, 2)))
    np.testing.assert_array_equal(s0.p, before)


def test_random_walk_blur_is_its_standard_deviation():
    q, dt = 0.5, 2.0                                   # std 1 m = 2 cells
    f = GridFilter(GEOM, LOGD, epsilon=0.0, motion=RandomWalk(q))
    p = np.zeros((1, GEOM.h, GEOM.w))
    p[0, 12, 15] = 1.0
    pred = f.predict(f.init(prior=p), dt=dt)
    np.testing.assert_allclose(pred.p, blur_grid(p, GEOM, np.sqrt(q * dt)))
    _, cov = grid_moments(pred.p, GEOM)
    np.testing.assert_allclose(np.diag(cov[0]), q * dt, rtol=0.03)
    assert pred.time == pytest.approx(dt)


def test_shift_moves_the_estimate():
    f = GridFilter(GEOM, LOGD, epsilon=0.0)
    p = np.zeros((1, GEOM.h, GEOM.w))
    p[0, 10:13, 12:15] = 1.0
    s = f.init(prior=p)
    moved = f.predict(s, shift_m=[[1.0, -0.5]])
    np.testing.assert_allclose(f.estimate(moved).position - f.estimate(s).position, [[1.0, -0.5]],
                               atol=1e-12)


def test_moments_known_answer():
    p = np.zeros((1, GEOM.h, GEOM.w))
    p[0, 2, 3] = 0.5
    p[0, 6, 9] = 0.5
    est = GridFilter(GEOM, LOGD, epsilon=0.0).estimate(GridState(p))
    a, b = np.array([GEOM.x[3], GEOM.y[2]]), np.array([GEOM.x[9], GEOM.y[6]])
    np.testing.assert_allclose(est.position[0], (a + b) / 2)
    np.testing.assert_allclose(est.covariance[0], np.outer(b - a, b - a) / 4)


def test_bad_input_raises_naming_the_field():
    f = GridFilter(GEOM, TRAP)
    s = f.init(2)
    with pytest.raises(InputError, match="rssi"):
        f.step(s, np.zeros((2, 2)), [50.0])
    with pytest.raises(InputError, match="rssi"):
        f.step(s, np.zeros((2, 2)), [50.0, 101.0])
    with pytest.raises(InputError, match="tracker_xy"):
        f.step(s, np.zeros((3, 2)), [50.0, 50.0])
    with pytest.raises(InputError, match="tracker_xy"):
        f.step(s, [[0.0, 0.0], [np.nan, 0.0]], [50.0, 50.0])
    with pytest.raises(InputError, match="shift_m"):
        f.predict(s, shift_m=np.zeros((2, 3)))
    with pytest.raises(InputError, match="extra_blur_m"):
        f.predict(s, extra_blur_m=[-1.0, 0.0])
    with pytest.raises(InputError, match="state"):
        f.step(np.ones((2, 3, 3)), np.zeros((2, 2)), [50.0, 50.0])
    with pytest.raises(InputError, match="grid"):
        f.estimate(GridState(np.ones((2, 3, 3))))
    with pytest.raises(InputError, match="time"):
        f.run(np.zeros((2, 3, 2)), np.full((2, 3), 50.0), time=[0.0, 1.0])
    with pytest.raises(InputError, match="batch"):
        f.init(0)


@pytest.mark.parametrize("kwargs,field", [
    ({"epsilon": 0.01}, "epsilon"),
    ({"epsilon": -1.0}, "epsilon"),
    ({"blur_m": -0.1}, "blur_m"),
    ({"blur_m": 0.2, "motion": RandomWalk(0.1)}, "blur_m"),
    ({"motion": ConstantAcceleration(0.1)}, "motion"),
    ({"motion": ConstantVelocity(0.1, dim=3)}, "motion"),
    ({"location": "median"}, "location"),
])
def test_bad_settings_raise_at_construction(kwargs, field):
    with pytest.raises(ConfigError, match=field):
        GridFilter(GEOM, TRAP, **kwargs)


def test_bad_geometry_or_model_raise():
    with pytest.raises(ConfigError, match="geometry"):
        GridFilter((10, 10, 1.0), TRAP)
    with pytest.raises(ConfigError, match="model"):
        GridFilter(GEOM, object())
