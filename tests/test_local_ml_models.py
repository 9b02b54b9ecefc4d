"""LocalML as a snapshot ML over any measurement model: its objective is the models'
``logpdf`` through ``Observation``s. Paper 001's configuration (LOS/NLOS ranges) gives the
same fixes through observations as through arrays, and models the paper does not have (a
Gaussian range, a bearing, both at once) land within a few standard deviations of the truth."""

from __future__ import annotations

import numpy as np
import pytest
from model_cases import TRAPEZOIDS, MinimalBearing

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.estimators.least_squares import LeastSquares
from radioloc.estimators.snapshot_baselines import LocalML, log_likelihood
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.measurement import Context, Observation
from radioloc.models.ranging import RangeModel
from radioloc.models.rss_model import TrapezoidRssModel

POINTS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 20.0], [30.0, 20.0], [12.0, 27.0]])
B = 40


def _truth(seed: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).uniform([4.0, 4.0], [26.0, 16.0], (B, 2))


def _ranges(truth, std_m, rng):
    return np.linalg.norm(truth[:, None] - POINTS, axis=-1) + std_m * rng.standard_normal((B, 5))


def _bearings(truth, std_rad, rng):
    d = truth[:, None] - POINTS
    return np.arctan2(d[..., 1], d[..., 0]) + std_rad * rng.standard_normal((B, 5))


def test_paper_configuration_through_observations_equals_the_array_form():
    rng = np.random.default_rng(0)
    noise = LosNlosRange(0.2, 4.0, 0.8)
    truth = _truth()
    z = _ranges(truth, 0.2, rng) + np.where(rng.random((B, 5)) < 0.2, rng.exponential(4.0, (B, 5)), 0)
    z[::5, 2] = np.nan
    arrays = LocalML(noise, 40.0, backend="numpy").locate(z, POINTS)
    obs = Observation(RangeModel(noise=noise), z, Context(points=POINTS))
    through = LocalML(None, 40.0).locate(obs)
    np.testing.assert_allclose(through.position, arrays.position, atol=1e-12)
    np.testing.assert_allclose(through.diagnostics["log_likelihood"],
                               arrays.diagnostics["log_likelihood"], rtol=1e-12)
    np.testing.assert_array_equal(through.diagnostics["measurements_used"], 5 - (np.arange(B) % 5 == 0))


@pytest.mark.parametrize("model,make,std", [
    (RangeModel(std_m=0.3), _ranges, 0.3),
    (MinimalBearing(0.01), _bearings, 0.01),
])
def test_a_model_the_paper_does_not_have_lands_within_a_few_sigma(model, make, std):
    rng = np.random.default_rng(1)
    truth = _truth()
    obs = Observation(model, make(truth, std, rng), Context(points=POINTS))
    fit = LocalML(None, 20.0, coarse_points=61).locate(obs)
    err = np.linalg.norm(fit.position - truth, axis=-1)
    # sigma: the Gaussian fit's claimed position standard deviation (about 0.27 m for the
    # ranges, 0.15 m for the bearings)
    lsq = LeastSquares().locate(obs, initial=truth)
    sigma = np.sqrt(np.mean(np.trace(lsq.covariance, axis1=-2, axis2=-1)))
    assert np.sqrt(np.mean(err ** 2)) < 1.5 * sigma and err.max() < 4 * sigma
    # a Gaussian model's ML is the least-squares fit: the search finds it to its last
    # grid's resolution (5 mm)
    np.testing.assert_allclose(fit.position, lsq.position, atol=0.01)
    # the fix maximises the likelihood: no neighbour 1 cm away scores higher
    offsets = 0.01 * np.array([[1, 0], [-1, 0], [0, 1], [0, -1.0]])
    ll = log_likelihood([obs], fit.position[:, None, :] + offsets)
    assert np.all(ll <= fit.diagnostics["log_likelihood"][:, None] + 1e-9)


def test_ranges_and_bearings_at_once_beat_either_alone():
    rng = np.random.default_rng(2)
    truth = _truth()
    r = Observation(RangeModel(std_m=1.0), _ranges(truth, 1.0, rng), Context(points=POINTS))
    a = Observation(MinimalBearing(0.05), _bearings(truth, 0.05, rng), Context(points=POINTS))
    est = LocalML(None, 20.0, coarse_points=61)

    def rmse(obs):
        return np.sqrt(np.mean(np.sum((est.locate(obs).position - truth) ** 2, -1)))
    both = rmse([r, a])
    assert both < rmse(r) and both < rmse(a)


def test_batch_equals_one_by_one_and_moving_the_scene_moves_the_fix():
    rng = np.random.default_rng(4)
    z = _bearings(_truth(), 0.01, rng)[:6]
    est = LocalML(None, 20.0, coarse_points=41)
    batch = est.locate(Observation(MinimalBearing(0.01), z, Context(points=POINTS))).position
    for i in range(6):
        one = est.locate(Observation(MinimalBearing(0.01), z[i], Context(points=POINTS))).position
        np.testing.assert_allclose(one, batch[i], atol=1e-9)
    shift = np.array([250.0, -120.0])
    moved = est.locate(Observation(MinimalBearing(0.01), z, Context(points=POINTS + shift))).position
    np.testing.assert_allclose(moved, batch + shift, atol=0.06)


def _exact(truth, points):
    """Exact ranges and bearings of ``truth`` (..., 2) from ``points`` (..., L, 2)."""
    d = truth[..., None, :] - points
    return np.linalg.norm(d, axis=-1), np.arctan2(d[..., 1], d[..., 0])


@pytest.mark.parametrize("kind", ["range", "bearing"])
def test_derived_search_square_finds_the_fix_of_a_generous_radius(kind):
    truth = _truth()[:8]
    r, a = _exact(truth, POINTS)
    model, z = (RangeModel(std_m=0.1), r) if kind == "range" else (MinimalBearing(0.01), a)
    obs = Observation(model, z, Context(points=POINTS))
    derived = LocalML().locate(obs).position
    # a square of 80 m around the anchors with a 0.5 m grid and the fixed polish
    generous = LocalML(radius_m=80.0, coarse_points=321).locate(obs).position
    # zero noise: the maximum is the truth, found to the last grid's spacing (5 mm)
    np.testing.assert_allclose(derived, truth, atol=0.01)
    np.testing.assert_allclose(derived, generous, atol=0.01)


def test_derived_search_widens_with_the_scene_and_a_batch_searches_as_one_by_one():
    """A 2 km scene (coarse spacing above 1 m, extra polish stages) in one batch with a
    30 m one: each problem gets its own square and schedule, the same as alone."""
    points = np.stack([POINTS, 70.0 * POINTS - 900.0])                        # (2, 5, 2)
    truth = np.array([[11.0, 7.5], [-123.4, 210.7]])
    r, _ = _exact(truth, points)
    est = LocalML()
    batch = est.locate(Observation(RangeModel(std_m=0.1), r, Context(points=points))).position
    np.testing.assert_allclose(batch, truth, atol=0.01)
    for i in range(2):
        one = est.locate(Observation(RangeModel(std_m=0.1), r[i], Context(points=points[i])))
        np.testing.assert_allclose(one.position, batch[i], rtol=0, atol=1e-12)
    # bearings only: no circle intersections, the grid alone finds the far node
    _, a = _exact(truth[1], points[1])
    far = est.locate(Observation(MinimalBearing(0.001), a, Context(points=points[1]))).position
    np.testing.assert_allclose(far, truth[1], atol=0.01)


def test_derived_search_moves_with_the_scene_and_with_the_node():
    truth = _truth()[:6]
    rng = np.random.default_rng(5)
    r, a = _exact(truth, POINTS)
    r = r + 0.1 * rng.standard_normal(r.shape)
    a = a + 0.01 * rng.standard_normal(a.shape)

    def fix(points, r, a):
        return LocalML().locate([Observation(RangeModel(std_m=0.1), r, Context(points=points)),
                                 Observation(MinimalBearing(0.01), a, Context(points=points))])
    base = fix(POINTS, r, a).position
    shift = np.array([250.0, -120.0])
    np.testing.assert_allclose(fix(POINTS + shift, r, a).position, base + shift, atol=1e-6)
    step = np.array([3.0, -2.0])
    r2, a2 = _exact(truth + step, POINTS)
    moved = fix(POINTS, r2, a2).position
    np.testing.assert_allclose(moved, truth + step, atol=0.01)
    assert np.all(np.linalg.norm(moved - base, axis=-1) > 3.0)


def test_values_impossible_at_every_point_searched_are_flagged_or_raised():
    """RSS trapezoids (paper 003) place the node within 1.2 m of every anchor at once in
    the first problem: no position has a positive likelihood."""
    model = TrapezoidRssModel(TRAPEZOIDS)
    readings = np.array([[100.0] * 5, [60.0, 40.0, 50.0, 30.0, 30.0]])
    d = np.linalg.norm(_truth()[:1, None] - POINTS, axis=-1)
    readings[1] = np.clip(np.round((30.0 - d[0]) / 0.3), 0, 100)
    obs = Observation(model, readings, Context(points=POINTS, index=np.arange(5)))
    fit = LocalML().locate(obs)
    assert fit.diagnostics["log_likelihood"][0] == -np.inf
    np.testing.assert_array_equal(fit.diagnostics["degenerate"], [True, False])
    assert np.linalg.norm(fit.position[1] - _truth()[0]) < 1.0
    with pytest.raises(GeometryError, match=r"ranges: problem \(0,\).*positive likelihood"):
        LocalML(on_degenerate="raise").locate(obs)


def test_bad_input_names_the_argument():
    obs = Observation(RangeModel(std_m=0.3), np.full(5, 10.0), Context(points=POINTS))
    with pytest.raises(InputError, match="centres"):
        LocalML(None, 20.0).locate(obs, POINTS)
    with pytest.raises(InputError, match="ranges"):
        LocalML(None, 20.0).locate(np.full(5, 10.0), POINTS)
    with pytest.raises(ConfigError, match=r"observations\[0\]"):
        LocalML(None, 20.0).locate(Observation(RangeModel(std_m=0.3, anchor_bias=True),
                                               np.full(5, 10.0), Context(points=POINTS,
                                                                         index=np.arange(5))))
    pts3 = np.column_stack([POINTS, np.zeros(5)])
    with pytest.raises(ConfigError, match="points"):
        LocalML(None, 20.0).locate(Observation(RangeModel(std_m=0.3), np.full(5, 10.0),
                                               Context(points=pts3)))
    with pytest.raises(ConfigError, match="measurement"):
        LocalML(MinimalBearing(0.01), 20.0)
    with pytest.raises(ConfigError, match="coarse_points"):
        LocalML(coarse_points=41)            # the derived search sets its own grid
