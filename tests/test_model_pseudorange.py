"""Pseudorange model: range plus the receiver clock offset; CRB with the offset estimated."""

import numpy as np
import pytest

from estimation_helpers import gauss_newton, rmse_over_bound
from radioloc.bounds.anchors import range_crb
from radioloc.bounds.fisher import crb
from radioloc.core.errors import ConfigError, InputError
from radioloc.models.measurement import Context, StateLayout, numerical_jacobian
from radioloc.models.pseudorange import PseudorangeModel
from radioloc.models.clock import ClockModel
from radioloc.sim.measurements import clock_trajectory, observe

SOURCES_3D = np.array([[0.0, 0.0, 10.0], [40.0, 0.0, 15.0], [0.0, 40.0, 8.0], [40.0, 40.0, 20.0],
                       [20.0, -10.0, 30.0], [-10.0, 20.0, 5.0]])
SOURCES_2D = SOURCES_3D[:, :2]


@pytest.mark.parametrize("sources", [SOURCES_2D, SOURCES_3D], ids=["2d", "3d"])
def test_jacobian_equals_finite_differences(sources):
    model = PseudorangeModel(std_m=1.0)
    dim = sources.shape[1]
    layout = StateLayout(dim=dim, order=1).with_model(model)
    assert layout.clock == 1
    rng = np.random.default_rng(8)
    x = layout.join({"position": rng.uniform(0, 30, (6, dim)), "velocity": rng.normal(size=(6, dim)),
                     "clock_offset": 1e3 * rng.normal(size=6)})
    ctx = Context(points=sources)
    _, H = layout.measure(model, x, ctx)
    numeric = numerical_jacobian(model, layout.split(x), ctx)
    for name in ("position", "clock_offset"):
        np.testing.assert_allclose(H[..., layout.slices[name]], numeric[name], atol=1e-6)
    assert np.all(H[..., layout.slices["velocity"]] == 0.0)


def test_offset_adds_to_every_row_and_the_scene_can_move():
    model = PseudorangeModel(std_m=1.0)
    ctx = Context(points=SOURCES_3D)
    x = np.array([5.0, 7.0, 1.0])
    base = model.predict({"position": x, "clock_offset": np.array(0.0)}, ctx)
    late = model.predict({"position": x, "clock_offset": np.array(123.0)}, ctx)
    np.testing.assert_allclose(late - base, 123.0)
    shift = np.array([-300.0, 45.0, 2.0])
    moved = model.predict({"position": x + shift, "clock_offset": np.array(0.0)},
                          Context(points=SOURCES_3D + shift))
    np.testing.assert_allclose(moved, base, atol=1e-10)


def test_ml_estimate_with_clock_offset_reaches_the_crb():
    rng = np.random.default_rng(9)
    runs = 500
    model = PseudorangeModel(std_m=0.01)
    layout = StateLayout(dim=3).with_model(model)
    truth = np.array([12.0, 9.0, 1.5])
    offset = 3000.0 * rng.standard_normal(runs)
    x_true = layout.join({"position": np.broadcast_to(truth, (runs, 3)), "clock_offset": offset})
    ctx = Context(points=SOURCES_3D)
    obs = observe(model, x_true, ctx, rng, layout)
    fit = gauss_newton([obs], layout, x_true + 0.3 * rng.standard_normal(x_true.shape))
    bound = crb(model, x_true[0], ctx, layout)
    ratio = rmse_over_bound(fit, x_true, bound.rmse_m, 3)
    print(f"pseudorange 3-D with clock offset: RMSE / sqrt(trace CRB) = {ratio:.3f}")
    assert 0.85 < ratio < 1.15, ratio
    # estimating the offset costs accuracy: the bound exceeds the one of known-offset ranges
    known = range_crb(truth, SOURCES_3D, std_m=0.01)
    assert np.trace(bound.position) > 1.2 * np.trace(known)


def test_bad_input_names_the_argument():
    with pytest.raises(ConfigError, match="std_m"):
        PseudorangeModel(std_m=-0.5)
    with pytest.raises(InputError, match="clock_offset"):
        StateLayout(dim=2).measure(PseudorangeModel(std_m=1.0), np.zeros(2),
                                   Context(points=SOURCES_2D))
    with pytest.raises(InputError, match="layout"):
        observe(PseudorangeModel(std_m=1.0), np.zeros((3, 2)), Context(points=SOURCES_2D),
                np.random.default_rng(0))


def test_observed_track_with_a_wandering_clock():
    rng = np.random.default_rng(13)
    steps = 25
    model = PseudorangeModel(std_m=1e-9)
    layout = StateLayout(dim=3).with_model(model)
    offset = clock_trajectory(ClockModel(offset_std_m=2.0, terms=1), steps, 0.5, rng,
                              batch_shape=(2,))[..., 0]
    track = np.cumsum(rng.normal(size=(2, steps, 3)), axis=1)
    x = layout.join({"position": track, "clock_offset": offset})
    obs = observe(model, x, Context(points=SOURCES_3D), rng, layout)
    assert obs.z.shape == (2, steps, 6) and obs.steps == steps
    d = np.linalg.norm(track[..., None, :] - SOURCES_3D, axis=-1)
    np.testing.assert_allclose(obs.z, d + offset[..., None], atol=1e-6)
    # moving sources: one set per step, with the batch axes of z (what Observation.at slices)
    moving = np.broadcast_to(SOURCES_3D + 0.1 * np.arange(steps)[:, None, None], (2, steps, 6, 3))
    obs = observe(model, x, Context(points=moving), rng, layout)
    d = np.linalg.norm(track[..., None, :] - moving, axis=-1)
    np.testing.assert_allclose(obs.z, d + offset[..., None], atol=1e-6)
    z_t, ctx_t = obs.at(4)
    np.testing.assert_allclose(ctx_t.points, moving[:, 4])
