"""Multilateration (Gauss-Newton / Levenberg-Marquardt through the generic least squares) and the anchor CRB."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from radioloc.bounds.anchors import range_crb
from radioloc.core.errors import GeometryError, InputError
from radioloc.core.validation import MAX_ITERATIONS
from radioloc.core.geometry import distances
from radioloc.estimators.least_squares import LeastSquares
from radioloc.estimators.multilateration import Multilateration
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel

SQUARE = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]])
coord = st.floats(1.0, 99.0, allow_nan=False)


@settings(max_examples=50, deadline=None)
@given(x=coord, y=coord)
def test_noise_free_ranges_give_the_true_position(x, y):
    truth = np.array([x, y])
    fit = Multilateration(std_m=1.0).locate(distances(truth, SQUARE), SQUARE)
    np.testing.assert_allclose(fit.position, truth, atol=1e-6)
    assert fit.diagnostics["converged"] and not fit.diagnostics["stalled"]


def test_three_dimensions_with_five_anchors():
    anchors = np.array([[0, 0, 0], [10, 0, 1], [0, 10, 2], [10, 10, 8], [5, 5, 10.0]])
    truth = np.array([3.0, 6.0, 4.0])
    fit = Multilateration(std_m=0.1).locate(distances(truth, anchors), anchors)
    np.testing.assert_allclose(fit.position, truth, atol=1e-6)


def test_batch_equals_one_by_one():
    rng = np.random.default_rng(1)
    truth = rng.uniform(0, 100, (40, 2))
    r = distances(truth[:, None], SQUARE) + rng.normal(0, 2.0, (40, 4))
    w = (rng.uniform(size=(40, 4)) > 0.15).astype(float)
    w[:, :3] = 1.0
    batch = Multilateration().locate(r, SQUARE, weights=w)
    for i in range(40):
        one = Multilateration().locate(r[i], SQUARE, weights=w[i])
        np.testing.assert_allclose(batch.position[i], one.position, atol=1e-9)
        np.testing.assert_allclose(batch.covariance[i], one.covariance, rtol=1e-7)


@pytest.mark.parametrize("weights", [None, [1, 1, 0, 1], [1, 1, 1, 1]])
def test_nan_range_is_a_missing_range(weights):
    truth = np.array([30.0, 40.0])
    r = distances(truth, SQUARE)
    r[2] = np.nan
    fit = Multilateration(std_m=0.5).locate(r, SQUARE, weights=weights)
    np.testing.assert_allclose(fit.position, truth, atol=1e-6)


def test_monte_carlo_covariance_matches_the_crb_at_small_noise():
    rng = np.random.default_rng(3)
    truth = np.array([20.0, 70.0])
    std = 0.05
    r = distances(truth, SQUARE) + rng.normal(0, std, (4000, 4))
    fit = Multilateration(std_m=std).locate(r, SQUARE)
    emp = np.cov((fit.position - truth).T)
    crb = range_crb(truth, SQUARE, std_m=std)
    np.testing.assert_allclose(np.trace(emp), np.trace(crb), rtol=0.1)
    np.testing.assert_allclose(fit.covariance[0], crb, rtol=1e-3)


def test_infinite_range_is_rejected_naming_the_index():
    r = distances(np.array([5.0, 5.0]), SQUARE)
    r[1] = np.inf
    with pytest.raises(InputError, match=r"ranges: invalid range inf at index \(1,\)"):
        Multilateration().locate(r, SQUARE)


def test_levenberg_marquardt_agrees_with_gauss_newton():
    rng = np.random.default_rng(4)
    truth = rng.uniform(0, 100, (50, 2))
    r = distances(truth[:, None], SQUARE) + rng.normal(0, 1.0, (50, 4))
    gn = Multilateration(std_m=1.0).locate(r, SQUARE)
    lm = Multilateration("levenberg-marquardt", std_m=1.0, max_iter=200).locate(r, SQUARE)
    assert lm.diagnostics["converged"].all()
    np.testing.assert_allclose(lm.position, gn.position, atol=1e-6)


@pytest.mark.parametrize("setting", [dict(method="newton"), dict(std_m=0.0),
                                     dict(max_iter=0), dict(tol_m=-1.0)])
def test_bad_settings_are_config_errors(setting):
    from radioloc.core.errors import ConfigError
    with pytest.raises(ConfigError, match=next(iter(setting))):
        Multilateration(**setting)


def test_negative_range_is_rejected():
    with pytest.raises(InputError, match="ranges"):
        Multilateration().locate([10.0, -1.0, 3.0, 4.0], SQUARE)


def test_too_few_anchors_is_a_geometry_error():
    with pytest.raises(GeometryError, match="2 ranges, 3 needed"):
        Multilateration().locate([10.0, 20.0], SQUARE[:2])


def test_collinear_anchors_are_a_geometry_error():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0], [30.0, 0.0]])
    truth = np.array([12.0, 5.0])
    with pytest.raises(GeometryError, match="collinear"):
        Multilateration(std_m=1.0).locate(distances(truth, line), line)


def test_shape_mismatch_is_an_input_error():
    with pytest.raises(InputError, match="3 ranges per problem but 4 anchors"):
        Multilateration().locate([1.0, 2.0, 3.0], SQUARE)


def test_crb_of_collinear_anchors_is_a_geometry_error():
    line = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 0.0]])
    with pytest.raises(GeometryError, match="singular"):
        range_crb(np.array([5.0, 0.0]), line, std_m=1.0)


def test_collinear_anchors_refuse_the_mirror_ambiguity():
    from radioloc.estimators import Multilateration
    a = np.array([[0.0, 3.0], [5.0, 3.0], [10.0, 3.0]])
    r = np.linalg.norm(a - [6.0, 8.0], axis=-1)
    with pytest.raises(GeometryError, match="collinear"):
        Multilateration().locate(r, a)
    a3 = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [10, 10, 0.0]])
    with pytest.raises(GeometryError, match="coplanar"):
        Multilateration().locate(np.linalg.norm(a3 - [3, 4, 5.0], axis=-1), a3)


def test_a_local_minimum_is_left_for_the_better_mirror_basin():
    from radioloc.estimators import Multilateration
    a = np.array([[-10, 99], [-5.299, -20.834], [-5.299, -5.299]])
    truth = np.array([-5.299, -94.364])
    fit = Multilateration().locate(np.linalg.norm(a - truth, axis=-1), a)
    np.testing.assert_allclose(fit.position, truth, atol=1e-6)


def test_nearly_collinear_anchors_with_noise_give_an_ambiguous_fix_error():
    from radioloc.estimators import Multilateration
    a = np.array([[0.0, 0.0], [5.0, 0.02], [10.0, -0.01], [15.0, 0.0]])
    truth = np.array([7.0, 20.0])
    r = np.linalg.norm(a - truth, axis=-1) + np.array([0.05, -0.03, 0.02, -0.04])
    with pytest.raises(GeometryError, match="ambiguous fix") as err:
        Multilateration(std_m=0.05).locate(r, a)
    assert err.value.index == ()


def test_flag_mode_marks_degenerate_problems_instead_of_raising():
    from radioloc.estimators import Multilateration
    good = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]])
    line = np.array([[0.0, 3.0], [5.0, 3.0], [10.0, 3.0]])
    a = np.stack([good, line])
    r = np.linalg.norm(a - np.array([6.0, 8.0]), axis=-1)
    fit = Multilateration(on_degenerate="flag").locate(r, a)
    np.testing.assert_array_equal(fit.diagnostics["degenerate"], [False, True])
    np.testing.assert_allclose(fit.position[0], [6.0, 8.0], atol=1e-8)
    assert np.isfinite(fit.covariance[0]).all() and np.isnan(fit.covariance[1]).all()
    assert not fit.converged[1]


def _count_solved_problems(monkeypatch):
    """Wrap the least squares that multilateration configures; returns the list of batch
    sizes solved (each solve in one pass: the open problems' second pass not counted)."""
    import radioloc.estimators.multilateration as ml
    from radioloc.estimators.least_squares import LeastSquares
    monkeypatch.setattr(ml, "FIRST_PASS", MAX_ITERATIONS)
    sizes = []
    real = LeastSquares.solve

    def counting(self, observations, *, initial=None):
        sizes.append(int(np.prod(np.shape(initial)[:-1])))
        return real(self, observations, initial=initial)
    monkeypatch.setattr(LeastSquares, "solve", counting)
    return sizes


def test_a_well_posed_batch_is_solved_once(monkeypatch):
    sizes = _count_solved_problems(monkeypatch)
    rng = np.random.default_rng(5)
    truth = rng.uniform(5, 95, (200, 2))
    r = distances(truth[:, None], SQUARE) + rng.normal(0, 0.5, (200, 4))
    fit = Multilateration().locate(r, SQUARE)
    assert sizes == [200]                       # no second solve for the mirror check
    assert not fit.diagnostics["ambiguous"].any()


def test_only_the_near_ties_are_solved_again_and_flagged_ambiguous(monkeypatch):
    sizes = _count_solved_problems(monkeypatch)
    good = np.broadcast_to(SQUARE, (5, 4, 2))
    line = np.array([[0.0, 0.0], [5.0, 0.02], [10.0, -0.01], [15.0, 0.0]])
    a = np.concatenate([good, line[None]])
    truth = np.array([7.0, 20.0])
    r = np.linalg.norm(a - truth, axis=-1) + np.array([0.05, -0.03, 0.02, -0.04])
    fit = Multilateration(std_m=0.05, on_degenerate="flag").locate(r, a)
    # the nearly collinear problem only: from its reflection, and from where it stopped
    assert sizes == [6, 1, 1]
    np.testing.assert_array_equal(fit.diagnostics["ambiguous"], [0, 0, 0, 0, 0, 1])
    np.testing.assert_array_equal(fit.diagnostics["degenerate"], [0, 0, 0, 0, 0, 1])
    # the ambiguous fix lies on one side, its mirror on the other: both near |y| = 20
    assert abs(abs(fit.position[5, 1]) - 20.0) < 1.0


def test_nearly_coplanar_3d_anchors_are_called_coplanar_not_collinear():
    a = np.array([[0, 0, 0], [10, 0, 0.02], [0, 10, -0.01], [10, 10, 0.0], [5, 5, 0.01]])
    truth = np.array([3.0, 4.0, 6.0])
    r = np.linalg.norm(a - truth, axis=-1) + np.array([0.03, -0.02, 0.01, -0.03, 0.02])
    with pytest.raises(GeometryError, match="ambiguous fix") as err:
        Multilateration(std_m=0.05).locate(r, a)
    assert "coplanar" in str(err.value) and "collinear" not in str(err.value)


def test_the_solution_stuck_in_the_worse_basin_is_solved_again(monkeypatch):
    sizes = _count_solved_problems(monkeypatch)
    a = np.array([[-10, 99], [-5.299, -20.834], [-5.299, -5.299]])
    truth = np.array([-5.299, -94.364])
    # started in the mirror basin (the truth reflected across the anchors' principal line,
    # plus 1 m), the first solve ends in the worse local minimum; the check solves again
    c = a.mean(axis=0)
    normal = np.linalg.svd(a - c)[2][1]
    start = truth - 2.0 * ((truth - c) @ normal) * normal + 1.0
    fit = Multilateration().locate(np.linalg.norm(a - truth, axis=-1), a, initial=start)
    np.testing.assert_allclose(fit.position, truth, atol=1e-6)
    assert sizes == [1, 1, 1]


def test_a_range_beyond_any_consistent_geometry_is_refused_naming_ranges():
    """A range of 1e20 m among ranges of tens of metres puts the closed-form start beyond
    1e30 m: the error names the ranges (not the solver's internal start)."""
    a = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0], [30.0, 20.0]])
    r = np.array([[1e20, 25.9, 10.6, 24.3], [21.3, 9.8, 26.4, 18.3]])
    with pytest.raises(InputError, match=r"^ranges: the ranges of problem \(0,\) put the node"):
        Multilateration(std_m=0.01).locate(r, a)


@pytest.mark.parametrize("method", ["gauss-newton", "levenberg-marquardt"])
def test_a_well_posed_fix_is_the_generic_least_squares_fix(method):
    """Multilateration is LeastSquares with Gaussian range rows (weights 1 / std^2): on
    spread anchors both give the same fix and covariance."""
    rng = np.random.default_rng(9)
    truth = rng.uniform(5, 95, (100, 2))
    r = distances(truth[:, None], SQUARE) + rng.normal(0, 0.5, (100, 4))
    w = rng.uniform(0.5, 2.0, (100, 4))
    fit = Multilateration(method, std_m=0.5, max_iter=200).locate(r, SQUARE, weights=w)
    obs = Observation(RangeModel(std_m=0.5), r, Context(points=SQUARE), std=0.5 / np.sqrt(w))
    ref = LeastSquares(method=method, max_iterations=200).locate(obs, initial=truth)
    assert fit.converged.all() and ref.diagnostics["converged"].all()
    np.testing.assert_allclose(fit.position, ref.position, atol=1e-7)
    np.testing.assert_allclose(fit.covariance, ref.covariance, rtol=1e-6)


def test_a_solve_stopped_short_across_nearly_coplanar_anchors_is_finished_before_the_mirror():
    """Two anchors 1e-6 m apart leave three distinct ones: Levenberg-Marquardt stops 0.2 m
    short in the weak direction, and its reflection leads to the mirror basin; the solution is
    solved on from where it stopped, and the exact ranges pick the truth."""
    a = np.array([[0.0, 0.0, 0.0], [0.0, 7.07e-7, 7.07e-7], [0.0, -0.5, 0.5], [1.0, 0.0, 0.0]])
    truth = np.array([0.0, 0.0, 9.0])
    r = np.linalg.norm(a - truth, axis=-1)
    for method in ("levenberg-marquardt", "gauss-newton"):
        fit = Multilateration(method=method).locate(r, a)
        np.testing.assert_allclose(fit.position, truth, atol=1e-6)


def test_a_subnormal_weight_is_refused_naming_weights():
    r = np.linalg.norm(SQUARE - np.array([8.5, 13.5]), axis=-1)
    with pytest.raises(InputError, match=r"^weights: 4.94e-324 at index \(0,\) is above 0"):
        Multilateration(std_m=0.01).locate(r, SQUARE, weights=np.full(4, 5e-324))


@pytest.mark.parametrize("method", ["gauss-newton", "levenberg-marquardt"])
def test_a_solve_that_stops_short_in_the_weak_direction_is_still_called_ambiguous(method):
    """Three anchors within 1e-5 m of a line, the node 190 m away: exact ranges fit the
    node and its mirror. Levenberg-Marquardt stopped 8 m short of the node's minimum, whose
    cost then looked worse than the mirror's, and answered the mirror (363 m off) as a
    clean fix; both solvers now name the ambiguity."""
    anchors = np.array([[0.99, 71.276], [-1.679, 69.4078], [0.0, 70.583]])
    truth = np.array([86.661, -90.576])
    r = np.linalg.norm(anchors - truth, axis=-1)
    with pytest.raises(GeometryError, match="ambiguous fix"):
        Multilateration(method=method, std_m=0.01).locate(r, anchors)


def test_a_batch_gives_each_problem_its_own_fit_whatever_its_neighbours_need(monkeypatch):
    """Gauss-Newton's slow problems go on alone after the first pass of the batch: the fit
    of every problem (position, iterations, flags) is the one it gets alone, and the one
    of a single pass over the whole batch."""
    import radioloc.estimators.multilateration as ml

    rng = np.random.default_rng(0)
    anchors = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 20.0], [0.0, 20.0]])
    x = rng.uniform(0, 30, (300, 2))
    r = np.linalg.norm(x[:, None] - anchors, axis=-1) + rng.normal(0, 0.1, (300, 4))
    r[:, 0] += rng.exponential(8, 300)                 # large residuals: slow convergence
    est = Multilateration(on_degenerate="flag")
    batch = est.locate(r, anchors)
    iterations = batch.diagnostics["iterations"]
    assert (iterations > ml.FIRST_PASS).sum() > 10 and (iterations < ml.FIRST_PASS).sum() > 10
    for i in np.flatnonzero(iterations > ml.FIRST_PASS)[:5].tolist() + [0, 1]:
        alone = est.locate(r[i:i + 1], anchors)
        np.testing.assert_allclose(alone.position[0], batch.position[i], rtol=0, atol=1e-12)
        for key in ("iterations", "converged", "stalled"):
            assert alone.diagnostics[key][0] == batch.diagnostics[key][i]
    monkeypatch.setattr(ml, "FIRST_PASS", est.max_iter)          # one pass over the batch
    single = est.locate(r, anchors)
    np.testing.assert_allclose(single.position, batch.position, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(single.diagnostics["iterations"], iterations)
