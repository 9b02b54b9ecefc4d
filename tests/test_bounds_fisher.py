"""Generic Cramer-Rao bound of Gaussian measurement models."""

import numpy as np
import pytest

from radioloc.bounds.anchors import range_crb, range_fisher_information
from radioloc.bounds.fisher import crb, fisher_information
from radioloc.core.errors import GeometryError, InputError
from radioloc.models.bearing import BearingModel
from radioloc.models.measurement import Context, StateLayout
from radioloc.models.pseudorange import PseudorangeModel
from radioloc.models.ranging import RangeModel
from radioloc.models.tdoa import TdoaModel

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0], [20.0, 20.0], [10.0, -5.0]])


def tdoa_context(anchors, reference=0):
    others = [k for k in range(len(anchors)) if k != reference]
    return Context(points=anchors[others],
                   reference=np.broadcast_to(anchors[reference], (len(others), anchors.shape[1])))


def test_range_bound_equals_the_closed_form():
    x = np.random.default_rng(0).uniform(2, 18, (6, 2))
    model = RangeModel(std_m=0.3)
    layout = StateLayout(dim=2)
    ctx = Context(points=ANCHORS)
    np.testing.assert_allclose(fisher_information(model, x, ctx, layout),
                               range_fisher_information(x, ANCHORS, 0.09), rtol=1e-12)
    bound = crb(model, x, ctx, layout)
    np.testing.assert_allclose(bound.position, range_crb(x, ANCHORS, 0.09), rtol=1e-10)
    np.testing.assert_allclose(bound.rmse_m, np.sqrt(np.trace(bound.position, axis1=-2, axis2=-1)))


@pytest.mark.parametrize("reference", [0, 3])
def test_tdoa_bound_equals_pseudoranges_with_an_unknown_offset(reference):
    # differencing against any reference removes exactly the common offset: with the
    # correlated noise of the differences the TDoA bound is the pseudorange bound
    x = np.array([[6.0, 9.0], [15.0, 2.0]])
    tdoa = crb(TdoaModel(std_m=0.2), x, tdoa_context(ANCHORS, reference), StateLayout(dim=2))
    pr_model = PseudorangeModel(std_m=0.2)
    pr_layout = StateLayout(dim=2).with_model(pr_model)
    pr = crb(pr_model, pr_layout.join({"position": x, "clock_offset": np.zeros(2)}),
             Context(points=ANCHORS), pr_layout)
    np.testing.assert_allclose(tdoa.position, pr.position, rtol=1e-9)
    # ignoring the correlation (a diagonal R) gives a different, wrong bound
    ctx = tdoa_context(ANCHORS, reference)
    H = TdoaModel(std_m=0.2).jacobian({"position": x}, ctx)["position"]
    diag = np.einsum("...mi,...mj->...ij", H, H) / (2 * 0.2**2)
    assert np.max(np.abs(np.linalg.inv(diag) - tdoa.position)) > 0.05 * np.max(tdoa.position)


def test_bound_is_unchanged_by_moving_or_rotating_the_scene_and_batches_like_one_by_one():
    rng = np.random.default_rng(1)
    x = rng.uniform(2, 18, (4, 2))
    c, s = np.cos(1.1), np.sin(1.1)
    R = np.array([[c, -s], [s, c]])
    shift = np.array([40.0, -7.0])
    models = [TdoaModel(std_m=0.1), BearingModel(std_rad=0.02)]
    base = crb(models, x, [tdoa_context(ANCHORS), Context(points=ANCHORS)], StateLayout(dim=2))
    moved = crb(models, x @ R.T + shift, [tdoa_context(ANCHORS @ R.T + shift),
                                          Context(points=ANCHORS @ R.T + shift)], StateLayout(dim=2))
    np.testing.assert_allclose(moved.rmse_m, base.rmse_m, rtol=1e-9)
    np.testing.assert_allclose(moved.position, R @ base.position @ R.T, rtol=1e-8, atol=1e-12)
    for b in range(4):
        one = crb(models, x[b], [tdoa_context(ANCHORS), Context(points=ANCHORS)], StateLayout(dim=2))
        np.testing.assert_allclose(one.position, base.position[b], rtol=1e-12)


def test_more_information_lowers_the_bound_and_unread_components_are_left_out():
    x = np.array([6.0, 9.0])
    layout = StateLayout(dim=2, order=1)  # velocity: read by no model, left out
    state = layout.join({"position": x})
    ranges = crb(RangeModel(std_m=0.1), state, Context(points=ANCHORS), layout)
    assert ranges.components == ("position",) and ranges.covariance.shape == (2, 2)
    both = crb([RangeModel(std_m=0.1), BearingModel(std_rad=0.01)], state,
               [Context(points=ANCHORS), Context(points=ANCHORS)], layout)
    assert both.rmse_m < ranges.rmse_m
    assert np.all(np.linalg.eigvalsh(ranges.position - both.position) > 0)


def test_bad_input_names_the_argument():
    layout = StateLayout(dim=2)
    # two anchors: the second state lies on their line, where the bound does not exist
    with pytest.raises(GeometryError, match=r"state \(1,\).*singular"):
        crb(RangeModel(std_m=0.1), np.array([[5.0, 5.0], [15.0, 0.0]]),
            Context(points=np.array([[0.0, 0.0], [10.0, 0.0]])), layout)
    with pytest.raises(InputError, match="contexts"):
        crb([RangeModel(std_m=0.1), BearingModel(0.1)], np.zeros(2), Context(points=ANCHORS), layout)
    with pytest.raises(InputError, match="clock_offset"):
        crb(PseudorangeModel(std_m=0.1), np.zeros(2), Context(points=ANCHORS), layout)
    with pytest.raises(InputError, match="models"):
        crb(["range"], np.zeros(2), [Context(points=ANCHORS)], layout)
