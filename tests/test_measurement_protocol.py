"""The measurement-model protocol: layouts, contexts and the range model."""

import numpy as np
import pytest

from radioloc.core.errors import InputError
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, StateLayout, numerical_jacobian, wrap_angle
from radioloc.models.ranging import RangeModel

ANCHORS = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0], [10.0, 10.0]])


def test_layout_split_join_round_trip():
    layout = StateLayout(dim=3, order=1, clock=2, n_bias=4)
    assert layout.size == 3 + 3 + 2 + 4
    x = np.random.default_rng(0).normal(size=(5, layout.size))
    parts = layout.split(x)
    assert parts["clock_offset"].shape == (5,) and parts["anchor_bias"].shape == (5, 4)
    np.testing.assert_array_equal(layout.join(parts), x)


@pytest.mark.parametrize("noise", [None, LosNlosRange(0.1, 3.0, 0.6)])
@pytest.mark.parametrize("anchor_bias", [False, True])
def test_range_jacobian_equals_finite_differences(noise, anchor_bias):
    model = RangeModel(std_m=0.2 if noise is None else None, noise=noise, anchor_bias=anchor_bias)
    layout = StateLayout(dim=2, order=1).with_model(model, n_anchors=4)
    rng = np.random.default_rng(1)
    x = layout.join({"position": rng.uniform(1, 9, (6, 2)), "velocity": rng.normal(size=(6, 2)),
                     "anchor_bias": rng.normal(size=(6, 4))})
    ctx = Context(points=ANCHORS, index=np.arange(4))
    z_hat, H = layout.measure(model, x, ctx)
    numeric = numerical_jacobian(model, layout.split(x), ctx)
    np.testing.assert_allclose(H[..., :2], numeric["position"], atol=1e-7)
    assert np.all(H[..., 2:4] == 0.0)  # the range does not read velocity
    if anchor_bias:
        np.testing.assert_allclose(H[..., 4:], numeric["anchor_bias"], atol=1e-7)


def test_moving_the_scene_moves_the_prediction():
    model = RangeModel(std_m=0.1)
    pos = {"position": np.array([3.0, 4.0])}
    shift = np.array([5.0, -2.0])
    a = model.predict(pos, Context(points=ANCHORS))
    b = model.predict({"position": pos["position"] + shift}, Context(points=ANCHORS + shift))
    np.testing.assert_allclose(a, b, atol=1e-12)


def test_zero_noise_sample_is_the_prediction_and_logpdf_peaks_there():
    model = RangeModel(std_m=1e-9)
    state = {"position": np.array([2.0, 7.0])}
    ctx = Context(points=ANCHORS)
    z = model.sample(state, ctx, np.random.default_rng(0))
    np.testing.assert_allclose(z, model.predict(state, ctx), atol=1e-7)
    lp = model.logpdf(z, state, ctx)
    assert np.all(lp > model.logpdf(z + 1e-6, state, ctx))


def test_per_row_sigma_overrides_the_model():
    model = RangeModel(std_m=0.5)
    ctx = Context(points=ANCHORS, std=np.array([0.1, np.nan, 2.0, np.nan]))
    np.testing.assert_allclose(model.std(ctx), [0.1, 0.5, 2.0, 0.5])


def test_missing_rows_give_zero_log_density():
    model = RangeModel(std_m=0.5)
    z = np.array([1.0, np.nan, 3.0, 4.0])
    lp = model.logpdf(z, {"position": np.array([1.0, 1.0])}, Context(points=ANCHORS))
    assert lp[1] == 0.0 and np.all(np.isfinite(lp))


def test_los_nlos_modes_sum_to_the_mixture():
    noise = LosNlosRange(0.1, 3.0, 0.6)
    model = RangeModel(noise=noise)
    state = {"position": np.array([4.0, 4.0])}
    ctx = Context(points=ANCHORS)
    z = model.predict(state, ctx) + np.array([0.05, 2.0, -0.1, 6.0])
    by_mode = model.mode_logpdf(z, state, ctx) + np.log([1 - noise.alpha, noise.alpha])
    np.testing.assert_allclose(np.logaddexp(by_mode[..., 0], by_mode[..., 1]),
                               model.logpdf(z, state, ctx), rtol=1e-12)


def test_wrap_angle():
    np.testing.assert_allclose(wrap_angle(np.array([np.pi + 0.1, -np.pi - 0.1, 0.3])),
                               [-np.pi + 0.1, np.pi - 0.1, 0.3])


def test_bad_input_names_the_field():
    with pytest.raises(InputError, match="std_m"):
        RangeModel()
    with pytest.raises(InputError, match="anchor_bias"):
        StateLayout(dim=2).measure(RangeModel(std_m=1.0, anchor_bias=True), np.zeros(2),
                                   Context(points=ANCHORS, index=np.arange(4)))
    with pytest.raises(InputError, match="state"):
        StateLayout(dim=2).split(np.zeros(3))
    with pytest.raises(InputError, match="index"):
        Context(points=ANCHORS, index=np.arange(3))
    with pytest.raises(InputError, match="std"):
        Context(points=ANCHORS, std=np.array([1.0, -1.0, 1.0, 1.0]))
