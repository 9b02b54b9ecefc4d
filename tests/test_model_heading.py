"""Heading model: the direction of the node's velocity, wrapping, low speed, an EKF turn."""

import numpy as np
import pytest

from radioloc.core.errors import ConfigError
from radioloc.estimators.extended_kalman import ExtendedKalmanFilter
from radioloc.models import HeadingModel, RangeModel
from radioloc.models.measurement import Context, Observation, StateLayout, numerical_jacobian, wrap_angle
from radioloc.models.motion import ConstantVelocity

ONE_ROW = Context(points=np.zeros((1, 2)))


@pytest.mark.parametrize("dim", [2, 3])
def test_jacobian_equals_finite_differences_above_the_speed_floor(dim):
    model = HeadingModel(std_rad=0.2, offset_rad=0.7, min_speed_mps=0.2)
    rng = np.random.default_rng(3)
    v = rng.normal(size=(20, dim))
    v *= (0.3 + 2.0 * rng.random((20, 1))) / np.linalg.norm(v[..., :2], axis=-1, keepdims=True)
    layout = StateLayout(dim=dim, order=1)
    x = layout.join({"position": rng.normal(size=(20, dim)), "velocity": v})
    ctx = Context(points=np.zeros((3, dim)))
    z_hat, H = layout.measure(model, x, ctx)
    assert z_hat.shape == (20, 3) and H.shape == (20, 3, 2 * dim)
    numeric = numerical_jacobian(model, layout.split(x), ctx)
    np.testing.assert_allclose(H[..., dim:], numeric["velocity"], atol=1e-6, rtol=1e-6)
    assert np.all(H[..., :dim] == 0.0)


def test_predict_is_the_velocity_direction_plus_the_offset_wrapped():
    model = HeadingModel(std_rad=0.1, offset_rad=0.5)
    v = np.array([[1.0, 0.0], [0.0, 2.0], [-1.0, -0.01]])
    z = model.predict({"velocity": v}, ONE_ROW)[:, 0]
    np.testing.assert_allclose(z, wrap_angle(np.arctan2(v[:, 1], v[:, 0]) + 0.5))
    assert np.all((z > -np.pi) & (z <= np.pi))
    # just across the cut at -x: the residual is the short way round
    z_hat = HeadingModel(std_rad=0.1).predict({"velocity": np.array([-1.0, -0.001])}, ONE_ROW)
    z_meas = wrap_angle(z_hat - 0.003)
    assert model.residual(z_meas, z_hat)[0] == pytest.approx(-0.003, abs=1e-12)


def test_below_min_speed_the_row_is_skipped():
    model = HeadingModel(std_rad=0.2, min_speed_mps=0.5)
    speeds = np.array([0.0, 1e-6, 0.25, 0.49, 0.5, 1.0, 4.0])
    v = np.stack([speeds, np.zeros_like(speeds)], axis=-1)
    z_hat = model.predict({"velocity": v}, ONE_ROW)[:, 0]
    H = model.jacobian({"velocity": v}, ONE_ROW)["velocity"][:, 0]
    slow = speeds < 0.5
    assert np.all(np.isnan(z_hat[slow])) and np.all(z_hat[~slow] == 0.0)
    assert np.all(H[slow] == 0.0)
    np.testing.assert_allclose(np.linalg.norm(H[~slow], axis=-1), 1.0 / speeds[~slow])
    lp = model.logpdf(np.full((7, 1), 1.0), {"position": np.zeros((7, 2)), "velocity": v}, ONE_ROW)
    assert np.all(lp[slow] == 0.0) and np.all(lp[~slow] < 0.0)


def test_sample_and_logpdf_use_std_rad():
    model = HeadingModel(std_rad=0.2, offset_rad=-0.3)
    state = {"velocity": np.tile([1.0, 1.0], (20000, 1))}
    z = model.sample(state, ONE_ROW, np.random.default_rng(0))
    r = model.residual(z, model.predict(state, ONE_ROW))
    assert abs(r.mean()) < 0.01 and r.std() == pytest.approx(0.2, rel=0.03)
    lp = model.logpdf(np.full((1,), np.nan), {"position": np.zeros(2),
                                               "velocity": np.array([1.0, 0.0])}, ONE_ROW)
    assert lp[0] == 0.0


def test_bad_settings_name_the_setting():
    with pytest.raises(ConfigError, match="std_rad"):
        HeadingModel(std_rad=0.0)
    with pytest.raises(ConfigError, match="min_speed_mps"):
        HeadingModel(std_rad=0.1, min_speed_mps=-1.0)
    with pytest.raises(ConfigError, match="offset_rad"):
        HeadingModel(std_rad=0.1, offset_rad=np.nan)


def test_heading_rows_turn_an_ekf_velocity_and_standstill_is_left_alone():
    """Ranges to one anchor leave the direction of motion unobserved; the heading rows fix
    it. A state at rest with a heading row far from its (undefined) direction is not moved."""
    anchors = np.array([[0.0, 0.0]])
    t = np.arange(0.0, 10.0, 0.5)
    truth = np.stack([5.0 + 0.0 * t, 1.0 * t], axis=-1)     # walking +y at 1 m/s
    ranges = np.linalg.norm(truth - anchors[0], axis=-1)[:, None]
    heading = np.full((t.size, 1), np.pi / 2)
    ctx = Context(points=anchors)
    obs_r = Observation(RangeModel(std_m=0.1), ranges, ctx)
    obs_h = Observation(HeadingModel(std_rad=0.1), heading, ctx)
    ekf = ExtendedKalmanFilter(ConstantVelocity(0.1, dim=2))
    prior = np.array([5.0, 0.0, 1.0, 0.0])         # moving along +x: wrong direction
    cov = np.diag([0.1, 0.1, 1.0, 1.0])
    with_h = ekf.run([obs_r, obs_h], t, prior_mean=prior, prior_cov=cov)
    without = ekf.run([obs_r], t, prior_mean=prior, prior_cov=cov)
    err_h = np.linalg.norm(with_h.position[-5:] - truth[-5:], axis=-1).mean()
    err_0 = np.linalg.norm(without.position[-5:] - truth[-5:], axis=-1).mean()
    assert err_h < 0.5 < err_0
    rest = ekf.run([Observation(HeadingModel(std_rad=0.1), np.full((3, 1), 2.0), ctx)],
                   np.arange(3.0), prior_mean=np.zeros(4), prior_cov=np.eye(4) * 0.01)
    assert np.all(np.isfinite(rest.position))
    np.testing.assert_allclose(rest.diagnostics["state"][..., 2:], 0.0, atol=1e-12)
