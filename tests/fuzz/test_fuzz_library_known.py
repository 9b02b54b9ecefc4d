"""Regression inputs from the library and CLI failures the long fuzz found (one per class):
each must now end in a clean error naming the place, or a correct answer."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fuzz_harness import HEAD, classify, render, run
from library_harness import CASES, Case, classify_call, mixture_arrays
from radioloc.estimators import LocalML, Multilateration, Ransac
from radioloc.models import (
    DiagMixture,
    GaussianRange,
    LogDistanceGaussian,
    LosNlosRange,
    TrapezoidModel,
    UniformDisk,
)


def _mutated(name, settings=None, **args):
    case = CASES[name]()
    return Case(case.name, {**case.settings, **(settings or {})}, {**case.args, **args},
                case.fields, case.solve)


def _clean(case: Case, names, invalid=True):
    outcome, detail = classify_call(lambda: case.solve(case.settings, case.args), names=names,
                                    invalid=invalid)
    assert outcome == "error", f"{outcome}: {detail}"
    return detail


def _subnormal(a, index):
    a = np.array(a, float)
    a[index] = 2.2250738585e-313
    return a


@pytest.mark.parametrize("value", [1e-300, 5e-324, 1e20])
def test_network_prior_var_out_of_range(value):
    for name in ("NetworkRLS", "NetworkEKF"):
        var = CASES[name]().args["prior_var"].copy()
        var[0, 1, 0] = value
        assert "prior_var" in _clean(_mutated(name, prior_var=var), ("prior_var",))


@pytest.mark.parametrize("value", ["abc", None, 1e300, math.inf])
def test_range_ekf_scalar_settings(value):
    for setting in ("range_bias_m", "gate", "height_m"):
        if value is None and setting in ("gate", "height_m"):
            continue                       # None is their default (off)
        _clean(_mutated("RangeEKF", {setting: value}), (setting,))


@pytest.mark.parametrize("value", ["abc", 1e300, -1.0])
def test_particle_filter_init_std(value):
    _clean(_mutated("P2PParticleFilter", {"init_std": value}), ("init_std",))


@pytest.mark.parametrize("name", ["ClosedFormTracker", "NewtonTracker"])
def test_sensor_path_batch_mismatch(name):
    path = CASES[name]().args["sensor_path"]
    _clean(_mutated(name, sensor_path=np.broadcast_to(path, (3,) + path.shape).copy()),
           ("sensor_path",))


def test_particle_filter_anchor_batch_mismatch():
    a = CASES["P2PParticleFilter"]().args["anchors"]
    _clean(_mutated("P2PParticleFilter", anchors=np.broadcast_to(a, (3,) + a.shape).copy()),
           ("anchors",))


@pytest.mark.parametrize("name,setting", [("Multilateration", "max_iter"),
                                          ("Ransac", "max_iter"),
                                          ("ClosedFormTracker", "max_iter"),
                                          ("P2PParticleFilter", "particles"),
                                          ("MixtureLocalizer", "max_components"),
                                          ("MixtureTracker", "max_components")])
@pytest.mark.parametrize("value", ["abc", None, math.inf, -math.inf, True, 10**15])
def test_integer_settings(name, setting, value):
    _clean(_mutated(name, {setting: value}), (setting,))


def test_mixture_components_beyond_memory_refused_before_allocating():
    detail = _clean(_mutated("MixtureTracker", {"max_components": 99_999}), ("max_components",))
    assert "memory" in detail


@pytest.mark.parametrize("kw", [{"a": "abc"}, {"n": None}, {"s": 0.0}, {"s": -1.0},
                                {"d_ref_m": math.inf}, {"a": math.nan}])
def test_log_distance_parameters(kw):
    args = {"a": 60.0, "n": 2.0, "s": 2.0, "d_ref_m": 0.1, **kw}
    outcome, detail = classify_call(lambda: LogDistanceGaussian(**args).likelihood(
        np.array([1.0, 5.0]), np.array(50.0)), names=tuple(kw), invalid=True)
    assert outcome == "error", f"{outcome}: {detail}"


@pytest.mark.parametrize("ctor,kw", [(GaussianRange, {"std_m": 1e-300}),
                                     (GaussianRange, {"std_m": 5e-324}),
                                     (LosNlosRange, {"los_std_m": 1e300}),
                                     (LosNlosRange, {"nlos_mean_m": 1e-300}),
                                     (UniformDisk, {"v_max_m_per_s": 1e300})])
def test_model_scalar_magnitudes(ctor, kw):
    outcome, detail = classify_call(lambda: ctor(**kw), names=tuple(kw), invalid=True)
    assert outcome == "error", f"{outcome}: {detail}"


def test_trapezoid_and_mixture_arrays():
    mu = np.linspace(40.0, 0.5, 101)
    for count in (np.full(101, -1.0), np.full(101, np.inf), np.array(["abc"] * 101, object)):
        outcome, detail = classify_call(lambda: TrapezoidModel(mu, np.ones(101), np.ones(101),
                                                               count), names=("count",),
                                        invalid=True)
        assert outcome == "error", f"{outcome}: {detail}"
    arrays = mixture_arrays()
    arrays["variances"] = arrays["variances"] * 1e-300
    outcome, detail = classify_call(lambda: DiagMixture.create(**arrays).logpdf(
        np.array([[1.0, 1.0]])), names=("variances",), invalid=True)
    assert outcome == "error", f"{outcome}: {detail}"


@pytest.mark.parametrize("anchors,truth", [
    ([(24.751, 0.0), (99.424, 1e-06), (-20.188, 0.0)], (12.0, 12.0)),
    ([(-20.0, 19.164), (-0.0, 54.824000999999996), (-86.66, -99.69077999999998)],
     (-49.473, 0.631)),
    ([(-20.0, 0.0), (-15.619, 1e-06), (20.196, 0.0), (-67.317, 0.0)], (0.0, 89.245)),
    ([(300020.66, 300020.66), (300002.5, 300005.0), (300000.0, 300083.878),
      (300002.5, 299954.398)], (299941.122, 300005.986)),
    # the solver lands in the mirror basin and the reflection of that fix misses the true
    # solution by the anchors' 1e-6 m offset: the fix must be the truth or refused
    ([(0.0, 0.0), (16.0, 1e-06), (-4.0, 0.0)], (0.0, -1.0)),
    # the closed-form start lies on the anchors' line, a saddle of the cost where
    # Gauss-Newton stalls with a 15 m residual rms
    ([(-69.622, -0.068622), (-81.241, -0.08024), (2.0, 0.003), (-0.0, 0.001),
      (11.507, 0.012507), (-93.319, -0.092319)], (0.0, 24.558)),
    ([(0.15, -0.1443), (-99.69, 95.901781), (-41.262, 39.694044), (-15.293, 14.711866)],
     (-0.962, -0.962)),
])
@pytest.mark.parametrize("method", ["gauss-newton", "levenberg-marquardt"])
@pytest.mark.parametrize("std", [None, 0.01])
def test_multilateration_near_collinear_and_far_anchors(anchors, truth, method, std):
    a, t = np.array(anchors), np.array(truth)
    r = np.linalg.norm(a - t, axis=-1)
    outcome, detail = classify_call(
        lambda: Multilateration(method=method, std_m=std).locate(r, a),
        names=("anchors",), truth=t, tol_m=1e-3 * max(1.0, float(r.max())))
    assert outcome in ("error", "success"), f"{outcome}: {detail}"


@pytest.mark.parametrize("cls", ["LocalML", "Ransac"])
def test_link_estimators_refuse_collinear_and_coincident_points(cls):
    for anchors in ([(0.0, 3.0), (5.0, 3.0), (10.0, 3.0), (20.0, 3.0)], [(1.0, 2.0)] * 4):
        a = np.array(anchors)
        r = np.linalg.norm(a - [6.0, 8.0], axis=-1)
        est = (LocalML(LosNlosRange(0.02, 5.0, 0.9), 40.0, on_degenerate="raise")
               if cls == "LocalML" else Ransac(0.5, 40.0, on_degenerate="raise"))
        outcome, detail = classify_call(lambda: est.locate(r, a), names=("centres",),
                                        invalid=True)
        assert outcome == "error", f"{outcome}: {detail}"
        flagged = (LocalML(LosNlosRange(0.02, 5.0, 0.9), 40.0) if cls == "LocalML"
                   else Ransac(0.5, 40.0)).locate(r, a)
        assert bool(flagged.diagnostics["degenerate"])


def test_cli_gn_near_collinear_mirror(scenarios, workdir):
    pts, truth = [(24.751, 0.0), (99.424, 1e-06), (-20.188, 0.0)], (12.0, 12.0)
    sc = scenarios["gn"]
    afile = workdir / "nc-anchors.csv"
    afile.write_text("id,x,y\n" + "".join(f"A{i},{x!r},{y!r}\n" for i, (x, y) in enumerate(pts)))
    meas = workdir / "nc.csv"
    meas.write_text(render([HEAD] + [["0.0", "t", f"A{i}", "range", repr(math.dist(truth, p))]
                                     for i, p in enumerate(pts)]))
    sc2 = type(sc)(**{**sc.__dict__, "files": {"anchors": afile}})
    res = run(sc2.args(meas))
    outcome, detail = classify(res, sc2, meas)
    assert outcome in ("error", "success"), f"{outcome}: {detail}"
    if outcome == "success":
        import io

        import pandas as pd
        est = pd.read_csv(io.StringIO(res.stdout))
        assert math.dist((est.x.iloc[0], est.y.iloc[0]), truth) < 1e-3 * 100


@pytest.mark.parametrize("cell", ["2.2250738585e-313", "1e30", "0"])
def test_cli_rls_prior_variance_out_of_range(scenarios, workdir, cell):
    sc = scenarios["rls"]
    lines = sc.files["priors"].read_text().splitlines()
    parts = lines[1].split(",")
    parts[4] = cell
    lines[1] = ",".join(parts)
    p = workdir / "priors-tiny.csv"
    p.write_text("\n".join(lines) + "\n")
    sc2 = type(sc)(**{**sc.__dict__, "files": {"priors": p}})
    meas = workdir / "rls.csv"
    meas.write_text(render(sc.rows))
    outcome, detail = classify(run(sc2.args(meas)), sc2, meas)
    assert outcome == "error" and "line 2" in detail and "var_y" in detail, f"{outcome}: {detail}"


def test_cli_gmm_text_in_calibration_position(scenarios, workdir):
    sc = scenarios["gmm"]
    lines = sc.files["calibration"].read_text().splitlines()
    lines[0] = " x , y ," + lines[0].split(",", 2)[2]
    parts = lines[3].split(",")
    parts[0] = "âbÔ?"
    lines[3] = ",".join(parts)
    p = workdir / "cal-text.csv"
    p.write_text("\n".join(lines) + "\n")
    sc2 = type(sc)(**{**sc.__dict__, "files": {"calibration": p}})
    meas = workdir / "gmm.csv"
    meas.write_text(render(sc.rows))
    outcome, detail = classify(run(sc2.args(meas)), sc2, meas)
    assert outcome == "error" and "line 4" in detail and "column x" in detail, f"{outcome}: {detail}"


def test_range_ekf_huge_prior_variance():
    cov = np.eye(4)
    cov[1, 1] = 1e20
    _clean(_mutated("RangeEKF", prior_cov=cov), ("prior_cov",))


def test_batch_smoother_flat_prior_gives_the_track_of_a_proper_one():
    """A prior variance of 1e20 (no prior) once made the smoother's starting pass solve a
    singular system; the data fix the track, so it equals the track under a unit prior."""
    case = CASES["BatchSmoother"]()
    flat = np.eye(4)
    flat[0, 0] = 1e20
    proper = case.solve(case.settings, case.args).position
    loose = case.solve(case.settings, {**case.args, "prior_cov": flat}).position
    np.testing.assert_allclose(loose, proper, atol=1e-6)


def test_particle_filter_controls_batch_mismatch():
    c = CASES["P2PParticleFilter"]().args["controls"]
    _clean(_mutated("P2PParticleFilter", controls=np.broadcast_to(c, (3,) + c.shape).copy()),
           ("controls",))


def test_range_ekf_time_with_a_batch_axis_that_does_not_broadcast():
    t = CASES["RangeEKF"]().args["time"]
    detail = _clean(_mutated("RangeEKF", time=np.broadcast_to(t, (3,) + t.shape).copy()),
                    names=("time",))
    assert "time: batch shape" in detail


def test_cli_network_priors_node_without_ranges_is_left_out_with_a_warning(scenarios, workdir):
    for method in ("rls", "ekf"):
        sc = scenarios[method]
        lines = sc.files["priors"].read_text().splitlines()
        extra = lines[1].split(",")
        extra[0] = "inf"
        p = workdir / "priors-extra.csv"
        p.write_text("\n".join([lines[0], ",".join(extra)] + lines[1:]) + "\n")
        sc2 = type(sc)(**{**sc.__dict__, "files": {"priors": p}})
        meas = workdir / "net.csv"
        meas.write_text(render(sc.rows))
        res = run(sc2.args(meas))
        outcome, detail = classify(res, sc2, meas)
        assert outcome == "success", f"{outcome}: {detail}"
        assert "'inf' (priors line 2)" in res.stderr and "inf" not in res.stdout


# Nearly collinear anchors (anchor 1 is 1e-6 m off the line y = -1.5 x) and a node 0.28 m
# from their line: the closed-form start lies on the line, a saddle of the cost where the
# Gauss-Newton information across the line is about 1e-13 of that along it, so a restart
# from a small offset overshot and stalled; the fix returned was the point on the line,
# 0.277 m from the truth. The two mirror fixes differ in cost by 5e-18 m^2: not
# distinguishable by the ranges, so the fix must be refused as ambiguous, naming the anchors.
NEAR_LINE = [(28.5, -42.75), (60.5, -90.749999), (-22.0, 33.0)]


@pytest.mark.parametrize("method", ["gauss-newton", "levenberg-marquardt"])
@pytest.mark.parametrize("std", [None, 0.01, 0.1])
def test_multilateration_node_near_the_anchors_line_is_ambiguous(method, std):
    from radioloc.core.errors import GeometryError
    a = np.array(NEAR_LINE)
    r = np.linalg.norm(a - [0.0, 0.5], axis=-1)
    with pytest.raises(GeometryError, match=r"ambiguous fix.*anchors 0, 1, 2 nearly collinear"):
        Multilateration(method=method, std_m=std).locate(r, a)
    fit = Multilateration(method=method, std_m=std, on_degenerate="flag").locate(r, a)
    assert bool(fit.diagnostics["ambiguous"]) and np.isnan(fit.covariance).all()


def _mirror_gap(a, truth):
    """Cost of the best fit in the mirror basin of ``truth`` (exact ranges: the truth's
    cost is 0), from the reflection of the truth across the anchors' best-fit line/plane."""
    from radioloc.estimators.nlls import solve_nlls
    from radioloc.models.ranging import range_geometry
    c = a.mean(0)
    _, sv, vt = np.linalg.svd(a - c)
    n = vt[-1]
    mirror = truth - 2 * np.dot(truth - c, n) * n
    r = np.linalg.norm(a - truth, axis=-1)

    def residuals(x):
        d, J = range_geometry(x, a)
        return r - d, J
    fit = solve_nlls(residuals, mirror, method="levenberg-marquardt", max_iter=500, tol=1e-13)
    return float(fit.cost), float(np.linalg.norm(fit.x - truth)), float(sv[0])


def _near_flat_scene(dim, eps, h):
    """Anchors on a line (2-D) or plane (3-D) with anchor 1 ``eps`` m off it, a node ``h`` m
    off it."""
    if dim == 2:
        t, n = np.array([1.0, -1.5]) / np.sqrt(3.25), np.array([1.5, 1.0]) / np.sqrt(3.25)
        a = np.array([28.5, 60.5, -22.0, 7.0])[:, None] * np.sqrt(3.25) * t
        truth = 11.0 * t + h * n
    else:
        b1, b2, n = np.eye(3)[[0, 1, 2]]
        c = np.array([[30.0, -20.0], [60.0, 40.0], [-22.0, 33.0], [5.0, -70.0], [-40.0, -10.0]])
        a = c[:, :1] * b1 + c[:, 1:] * b2
        truth = 11.0 * b1 - 4.0 * b2 + h * n
    a = a + np.array([0.0, 1.0] + [0.0] * (len(a) - 2))[:, None] * eps * n
    rot = np.linalg.qr(np.arange(1.0, dim * dim + 1).reshape(dim, dim) ** 1.5)[0]
    return a @ rot.T + 7.0, truth @ rot.T + 7.0


@pytest.mark.parametrize("dim", [2, 3])
@pytest.mark.parametrize("eps", [1e-6, 1e-3, 0.1, 2.0])
@pytest.mark.parametrize("h", [0.05, 0.28, 3.0])
@pytest.mark.parametrize("method", ["gauss-newton", "levenberg-marquardt"])
@pytest.mark.parametrize("std", [None, 0.01])
def test_multilateration_near_flat_anchors_truth_or_ambiguous(dim, eps, h, method, std):
    """Exact ranges: the truth wherever the mirror minimum fits measurably worse (cost gap
    above 4 s^2 with margin), a refusal as ambiguous wherever it fits within the noise the
    solver assumes (``std_m``, else its floor 1e-9 of the anchors' spread)."""
    from radioloc.core.errors import GeometryError
    a, truth = _near_flat_scene(dim, eps, h)
    r = np.linalg.norm(a - truth, axis=-1)
    gap, dist, spread = _mirror_gap(a, truth)
    s2 = std ** 2 if std is not None else (1e-9 * max(spread, 1.0)) ** 2
    try:
        fit = Multilateration(method=method, std_m=std).locate(r, a)
    except GeometryError as exc:
        assert "ambiguous" in str(exc) or "coplanar" in str(exc) or "collinear" in str(exc), exc
        assert gap <= 8 * s2, f"refused although the mirror fits worse by {gap:.3g} m^2: {exc}"
        return
    assert np.linalg.norm(fit.position - truth) < 1e-6 * max(1.0, float(r.max())), (
        f"{fit.position} returned for {truth} (mirror gap {gap:.3g}, 4 s^2 {4 * s2:.3g})")
    if dist > 1e-3:
        assert gap > 2 * s2, f"mirror fits within the noise ({gap:.3g} m^2) but no refusal"


def test_cli_gn_ambiguous_fix_names_the_anchor_ids(scenarios, workdir):
    sc = scenarios["gn"]
    afile = workdir / "near-line-anchors.csv"
    afile.write_text("id,x,y\n" + "".join(f"N{i},{x!r},{y!r}\n"
                                          for i, (x, y) in enumerate(NEAR_LINE)))
    meas = workdir / "near-line.csv"
    meas.write_text(render([HEAD] + [["1700000000.125", "t", f"N{i}", "range",
                                      repr(math.dist((0.0, 0.5), p))]
                                     for i, p in enumerate(NEAR_LINE)]))
    sc2 = type(sc)(**{**sc.__dict__, "files": {"anchors": afile}})
    res = run(sc2.args(meas))
    outcome, detail = classify(res, sc2, meas)
    assert outcome == "error", f"{outcome}: {detail}"
    # the anchors are collinear to 1e-8 of their span: refused for the whole log, naming them
    assert "collinear" in detail and "(N0, N1, N2)" in detail


@pytest.mark.parametrize("track", [0, 1])
def test_closed_form_missing_ranges_name_ranges(track):
    """A NaN range of an 8-sample track drops difference rows until S A is rank deficient:
    the error names ``ranges`` and that track (flat index), not the sensor path."""
    r = np.array(CASES["ClosedFormTracker"]().args["ranges"], float)
    assert r.ndim == 2 and r.shape[0] >= 2
    r[track, 3] = np.nan
    detail = _clean(_mutated("ClosedFormTracker", ranges=r), ("ranges",))
    assert "sensor_path" not in detail and f"track {track}" in detail


def test_batch_smoother_time_with_an_extra_batch_axis_names_time():
    """time of shape (3, T) for observations without a batch raised numpy's ValueError
    inside BatchSmoother.run (broadcast_to); now an error naming time."""
    t = CASES["BatchSmoother"]().args["time"]
    detail = _clean(_mutated("BatchSmoother", time=np.broadcast_to(t, (3,) + t.shape).copy()),
                    ("time",))
    assert "time: batch shape (3,)" in detail


@pytest.mark.parametrize("name", ["BatchSmoother", "ParticleFilter"])
def test_generic_filters_with_batched_points(name):
    """context.points with a leading axis of 3 and z of T = 10 steps: BatchSmoother named
    neither argument ("batch shapes do not broadcast: (10,), (10,), (3,)") and ParticleFilter
    raised numpy's ValueError in its weight update; now the smoother names z and
    context.points, and the particle filter, like the EKF, runs a batch of 3."""
    pts = CASES[name]().args["points"]
    case = _mutated(name, points=np.broadcast_to(pts, (3,) + pts.shape).copy())
    outcome, detail = classify_call(lambda: case.solve(case.settings, case.args),
                                    names=("points",))
    if name == "BatchSmoother":
        assert outcome == "error" and "observations[0].context.points (3,)" in detail, detail
    else:
        assert outcome == "success", detail
        assert case.solve(case.settings, case.args).position.shape == (3, 10, 2)


def test_range_observation_with_row_and_context_std_that_do_not_broadcast():
    """Observation of ranges with std (10, 4) and context.std (3, 4): the negative-range
    rule's per-row sigma raised numpy's ValueError; now an error naming both."""
    std = CASES["ExtendedKalmanFilter"]().args["context_std"]
    detail = _clean(_mutated("ExtendedKalmanFilter",
                             context_std=np.broadcast_to(std, (3,) + std.shape).copy()),
                    ("std",))
    assert "context.std (shape (3, 4))" in detail


def test_batch_smoother_subnormal_prior_covariance_names_prior_cov():
    """prior_cov = 5e-324 I gave an infinite information matrix and NaN covariances from
    BatchSmoother.run; now an error naming prior_cov and the variance."""
    cov = CASES["BatchSmoother"]().args["prior_cov"]
    detail = _clean(_mutated("BatchSmoother", prior_cov=cov * 5e-324), ("prior_cov",))
    assert "below the supported floor" in detail
