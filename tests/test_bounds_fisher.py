"""Generic Cramer-Rao bound of Gaussian measurement models."""

import numpy as np
import pytest

from radioloc.bounds.anchors import range_crb, range_fisher_information
from estimation_helpers import draw_track, ekf_track, rmse_over_bound
from radioloc.bounds.fisher import crb, fisher_information, tracking_crb
from radioloc.core.errors import GeometryError, InputError
from radioloc.models.bearing import BearingModel
from radioloc.models.clock import ClockModel, transition
from radioloc.models.measurement import Context, Observation, StateLayout
from radioloc.models.motion import WhiteAccelerationCV
from radioloc.models.pseudorange import PseudorangeModel
from radioloc.models.ranging import RangeModel
from radioloc.models.tdoa import TdoaModel
from radioloc.sim.measurements import observe

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [0.0, 20.0], [20.0, 20.0], [10.0, -5.0]])


def tdoa_context(anchors, reference=0):
    others = [k for k in range(len(anchors)) if k != reference]
    return Context(points=anchors[others], index=np.array(others),
                   reference=np.broadcast_to(anchors[reference], (len(others), anchors.shape[1])),
                   reference_index=np.full(len(others), reference))


def test_range_bound_equals_the_closed_form():
    x = np.random.default_rng(0).uniform(2, 18, (6, 2))
    model = RangeModel(std_m=0.3)
    layout = StateLayout(dim=2)
    ctx = Context(points=ANCHORS)
    np.testing.assert_allclose(fisher_information(model, x, ctx, layout),
                               range_fisher_information(x, ANCHORS, std_m=0.3), rtol=1e-12)
    bound = crb(model, x, ctx, layout)
    np.testing.assert_allclose(bound.position, range_crb(x, ANCHORS, std_m=0.3), rtol=1e-10)
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
    obs = Observation(RangeModel(std_m=0.1), np.zeros((3, 5)), Context(points=ANCHORS))
    track = np.zeros((3, 2))
    with pytest.raises(InputError, match="observations"):
        tracking_crb([], track, layout, np.eye(2), np.eye(2), np.eye(2))
    with pytest.raises(InputError, match="F"):
        tracking_crb(obs, track, layout, np.eye(3), np.eye(2), np.eye(2))
    with pytest.raises(InputError, match="states"):
        tracking_crb(obs, np.zeros((3, 4)), layout, np.eye(2), np.eye(2), np.eye(2))
    with pytest.raises(InputError, match="observations"):
        tracking_crb(obs, np.zeros((4, 2)), layout, np.eye(2), np.eye(2), np.eye(2))


def test_tracking_bound_of_a_static_state_sums_the_snapshots():
    model = TdoaModel(std_m=0.2)
    ctx = tdoa_context(ANCHORS)
    layout = StateLayout(dim=2)
    x = np.array([6.0, 9.0])
    steps = 4
    z = np.zeros((steps, ctx.rows))
    z[2, 1] = np.nan  # one row missing at one step: the rest of that step still counts
    P0 = 4.0 * np.eye(2)
    bound = tracking_crb(Observation(model, z, ctx), np.broadcast_to(x, (steps, 2)), layout,
                         np.eye(2), np.zeros((2, 2)), P0)
    full = fisher_information(model, x, ctx, layout)
    part = fisher_information(model, x, ctx.take(np.array([0, 2, 3])), layout)
    expected = np.linalg.inv(np.linalg.inv(P0) + 3 * full + part)
    np.testing.assert_allclose(bound.position[-1], expected, rtol=1e-10)
    np.testing.assert_allclose(bound.position[0], np.linalg.inv(np.linalg.inv(P0) + full), rtol=1e-10)
    assert np.all(np.diff(bound.rmse_m) < 0)


def _tracking_case(kind, rng, runs, steps, dt):
    clock = ClockModel(offset_std_m=0.05, drift_std_m_per_s=0.5)
    motion = WhiteAccelerationCV(q=0.5)
    anchors = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0], [15.0, -8.0]])
    if kind == "tdoa":
        model = TdoaModel(std_m=0.02, slot_s=1e-3 * np.arange(5.0))
        ctx = tdoa_context(anchors)
    elif kind == "pseudorange":
        model, ctx = PseudorangeModel(std_m=0.02), Context(points=anchors)
    else:
        model, ctx = BearingModel(std_rad=2e-3), Context(points=anchors)
    layout = StateLayout(dim=2, order=1, clock=2 if kind != "aoa" else 0).with_model(model)
    F, Q = transition(layout, motion, dt, clock if layout.clock else None)
    start = layout.join({"position": np.array([12.0, 14.0]), "velocity": np.array([1.0, 0.5]),
                         "clock_offset": np.array(50.0), "clock_drift": np.array(300.0)})
    P0 = np.diag(np.r_[np.full(2, 0.5), np.full(2, 0.3), np.full(layout.clock, 4.0)][:layout.size] ** 2)
    x0 = start + np.einsum("ij,...j->...i", np.linalg.cholesky(P0), rng.standard_normal((runs, layout.size)))
    truth = draw_track(F, Q, x0, steps, rng)
    obs = observe(model, truth, ctx, rng, layout)
    return obs, truth, layout, F, Q, P0, start


@pytest.mark.parametrize("kind", ["tdoa", "pseudorange", "aoa"])
def test_ekf_tracking_reaches_the_tracking_bound(kind):
    # TDoA with a drifting tag clock, pseudoranges with the clock offset and drift as state,
    # and bearings: an EKF at high SNR sits at the posterior bound
    rng = np.random.default_rng({"tdoa": 31, "pseudorange": 32, "aoa": 33}[kind])
    runs, steps = 300, 30
    obs, truth, layout, F, Q, P0, start = _tracking_case(kind, rng, runs, steps, 0.2)
    est = ekf_track([obs], layout, F, Q, np.broadcast_to(start, (runs, layout.size)), P0)
    bound = tracking_crb(obs, truth, layout, F, Q, P0)
    late = slice(steps // 2, None)
    ratio = rmse_over_bound(est[:, late], truth[:, late], bound.rmse_m[:, late], 2)
    print(f"EKF {kind} tracking: RMSE / tracking CRB = {ratio:.3f}")
    assert 0.85 < ratio < 1.15, ratio
