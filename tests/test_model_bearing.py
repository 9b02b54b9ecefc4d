"""Bearing (angle of arrival) model: azimuth and elevation, wrapping, frames, CRB."""

import numpy as np
import pytest

from estimation_helpers import gauss_newton, rmse_over_bound
from radioloc.bounds.fisher import crb
from radioloc.core.errors import ConfigError, InputError
from radioloc.models.bearing import BearingModel
from radioloc.models.measurement import Context, StateLayout, numerical_jacobian, wrap_angle
from radioloc.sim.measurements import simulate_aoa

ANCHORS_2D = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0], [20.0, 20.0]])
ANCHORS_3D = np.array([[0.0, 0.0, 3.0], [20.0, 0.0, 2.5], [0.0, 20.0, 3.5], [20.0, 20.0, 0.0]])
YAW = np.array([0.3, -1.2, 2.9, 0.0])


def rotation(angle, dim):
    c, s = np.cos(angle), np.sin(angle)
    R = np.eye(dim)
    R[:2, :2] = [[c, -s], [s, c]]
    return R


@pytest.mark.parametrize("component, anchors", [("azimuth", ANCHORS_2D), ("azimuth", ANCHORS_3D),
                                                ("elevation", ANCHORS_3D)])
def test_jacobian_equals_finite_differences(component, anchors):
    model = BearingModel(std_rad=0.01, component=component, orientation_rad=YAW)
    ctx = Context(points=anchors, index=np.arange(4))
    dim = anchors.shape[1]
    layout = StateLayout(dim=dim, order=1)
    rng = np.random.default_rng(4)
    pos = rng.uniform(-5, 25, (9, dim))
    x = layout.join({"position": pos, "velocity": rng.normal(size=(9, dim))})
    _, H = layout.measure(model, x, ctx)
    numeric = numerical_jacobian(model, layout.split(x), ctx)
    np.testing.assert_allclose(H[..., :dim], numeric["position"], atol=1e-6, rtol=1e-6)
    assert np.all(H[..., dim:] == 0.0)


def test_elevation_jacobian_with_known_height():
    model = BearingModel(std_rad=0.01, component="elevation")
    ctx = Context(points=ANCHORS_3D, height_m=1.2)
    state = {"position": np.array([[4.0, 7.0], [15.0, 12.0]])}
    np.testing.assert_allclose(model.jacobian(state, ctx)["position"],
                               numerical_jacobian(model, state, ctx)["position"], atol=1e-7)


def test_residuals_wrap_at_plus_minus_pi():
    model = BearingModel(std_rad=0.01)
    ctx = Context(points=np.array([[0.0, 0.0]]))
    # the tag just below the anchor's -x axis: the azimuth is just above -pi
    state = {"position": np.array([-10.0, -0.01])}
    z_hat = model.predict(state, ctx)
    assert z_hat[0] == pytest.approx(-np.pi + 0.001, abs=1e-6)
    z = wrap_angle(z_hat - 0.003)  # 3 mrad clockwise: across the cut, just below +pi
    assert z[0] > np.pi - 0.003
    assert model.residual(z, z_hat)[0] == pytest.approx(-0.003, abs=1e-12)
    expected = -0.5 * 0.3**2 - np.log(0.01) - 0.5 * np.log(2 * np.pi)
    assert model.logpdf(z, state, ctx)[0] == pytest.approx(expected, abs=1e-9)
    # the Jacobian across the cut is the smooth one
    np.testing.assert_allclose(model.jacobian(state, ctx)["position"],
                               numerical_jacobian(model, state, ctx)["position"], atol=1e-6)
    draws = model.sample({"position": np.broadcast_to([-10.0, 0.0], (2000, 2))}, ctx,
                         np.random.default_rng(0))
    assert np.all((draws > -np.pi) & (draws <= np.pi))
    assert np.std(wrap_angle(draws - np.pi)) == pytest.approx(0.01, rel=0.1)


def test_rotating_the_scene_with_the_anchor_frames_keeps_the_bearings():
    rng = np.random.default_rng(1)
    x = rng.uniform(0, 20, (5, 3))
    ctx = Context(points=ANCHORS_3D, index=np.arange(4))
    angle, shift = 2.4, np.array([50.0, -30.0, 1.0])
    R = rotation(angle, 3)
    moved = Context(points=ANCHORS_3D @ R.T + shift, index=np.arange(4))
    for component in ("azimuth", "elevation"):
        model = BearingModel(std_rad=0.01, component=component, orientation_rad=YAW)
        turned = BearingModel(std_rad=0.01, component=component, orientation_rad=YAW + angle)
        base = model.predict({"position": x}, ctx)
        np.testing.assert_allclose(
            wrap_angle(turned.predict({"position": x @ R.T + shift}, moved) - base), 0.0, atol=1e-12)
        # frames fixed: a rotation of the scene turns every azimuth by the angle
        rotated = model.predict({"position": x @ R.T + shift}, moved)
        expected = wrap_angle(base + angle) if component == "azimuth" else base
        np.testing.assert_allclose(wrap_angle(rotated - expected), 0.0, atol=1e-12)


@pytest.mark.parametrize("dim", [2, 3])
def test_ml_estimate_reaches_the_crb(dim):
    rng = np.random.default_rng(20 + dim)
    runs = 500
    anchors = ANCHORS_2D if dim == 2 else ANCHORS_3D
    truth = np.array([6.0, 11.0, 1.0])[:dim]
    observations = simulate_aoa(np.broadcast_to(truth, (runs, dim)), anchors, rng, std_rad=1e-3,
                                orientation_rad=YAW)
    layout = StateLayout(dim=dim)
    x_true = np.broadcast_to(truth, (runs, dim))
    fit = gauss_newton(observations, layout, x_true + 0.3 * rng.standard_normal((runs, dim)))
    bound = crb([o.model for o in observations], truth, [o.context for o in observations], layout)
    ratio = rmse_over_bound(fit, x_true, bound.rmse_m, dim)
    print(f"AoA {dim}-D: RMSE / sqrt(trace CRB) = {ratio:.3f}")
    assert 0.85 < ratio < 1.15, ratio


def test_kinds_and_bad_input_name_the_argument():
    assert BearingModel(0.1).kind == "aoa" and BearingModel(0.1, "elevation").kind == "aoa_elevation"
    assert BearingModel.angular
    with pytest.raises(ConfigError, match="std_rad"):
        BearingModel(std_rad=-1.0)
    with pytest.raises(InputError, match="component"):
        BearingModel(std_rad=0.1, component="zenith")
    with pytest.raises(InputError, match="component"):
        BearingModel(0.1, "elevation").predict({"position": np.zeros(2)}, Context(points=ANCHORS_2D))
    with pytest.raises(InputError, match="index"):
        BearingModel(0.1, orientation_rad=YAW).predict({"position": np.zeros(2)},
                                                       Context(points=ANCHORS_2D))
    with pytest.raises(InputError, match="index"):
        BearingModel(0.1, orientation_rad=YAW[:2]).predict(
            {"position": np.zeros(2)}, Context(points=ANCHORS_2D, index=np.arange(4)))
    with pytest.raises(InputError, match="points"):
        BearingModel(0.1).predict({"position": np.zeros(2)}, Context(points=ANCHORS_3D))
    with pytest.raises(InputError, match="orientation_rad"):
        BearingModel(0.1, orientation_rad=np.zeros((2, 2)))
