"""Regression inputs from failures the fuzz found (mirror fixes of collinear anchors,
local minima, coincident anchors, option bounds, calibration magnitudes): each must now end
in a clean one-line error or a correct answer."""

from __future__ import annotations

import pytest

from fuzz_harness import HEAD, classify, oracle, read_output, render, run


def _case(workdir, scenarios, method, rows=None, files=None, options=None, name="known"):
    sc = scenarios[method]
    sc = type(sc)(**{**sc.__dict__, "files": {**sc.files, **(files or {})}})
    meas = workdir / f"{name}.csv"
    meas.write_text(render(rows if rows is not None else sc.rows))
    return sc, meas, sc.args(meas, {**sc.options, **(options or {})})


def _assert_clean(res, sc, meas, truth=None):
    outcome, detail = classify(res, sc, meas)
    assert outcome in ("error", "success"), f"{outcome}: {detail}"
    if outcome == "success" and truth is not None:
        import io

        import pandas as pd
        est = pd.read_csv(io.StringIO(res.stdout))
        assert abs(est["x"].iloc[0] - truth[0]) < 1e-3 and abs(est["y"].iloc[0] - truth[1]) < 1e-3, \
            f"confident wrong answer {est[['x', 'y']].to_numpy()[0]}, truth {truth}"


def _anchors(workdir, pts, name):
    p = workdir / f"{name}-anchors.csv"
    p.write_text("id,x,y\n" + "".join(f"A{i},{x!r},{y!r}\n" for i, (x, y) in enumerate(pts)))
    return p


def _ranges(pts, truth):
    import math
    return [HEAD] + [["0.0", "t", f"A{i}", "range", repr(math.dist(truth, p))]
                     for i, p in enumerate(pts)]


def test_gn_collinear_anchors_mirror(scenarios, workdir):
    pts, truth = [(0.0, 3.0), (5.0, 3.0), (10.0, 3.0)], (6.0, 8.0)
    sc, meas, args = _case(workdir, scenarios, "gn", _ranges(pts, truth),
                           {"anchors": _anchors(workdir, pts, "mirror")}, name="mirror")
    _assert_clean(run(args), sc, meas, truth)


@pytest.mark.parametrize("pts", [[(-10.0, 99.0), (-5.299, -20.834), (-5.299, -5.299)],
                                 [(-10.0, -5.299), (-5.299, -5.299), (-5.299, -5.299)]])
def test_gn_wrong_fix_general_anchors(scenarios, workdir, pts):
    truth = (-5.299, -94.364)
    sc, meas, args = _case(workdir, scenarios, "gn", _ranges(pts, truth),
                           {"anchors": _anchors(workdir, pts, "wrongfix")}, name="wrongfix")
    _assert_clean(run(args), sc, meas, truth)


def test_gn_coincident_anchors(scenarios, workdir):
    pts, truth = [(0.0, 0.0)] * 3, (0.0, 0.0)
    sc, meas, args = _case(workdir, scenarios, "gn", _ranges(pts, truth),
                           {"anchors": _anchors(workdir, pts, "coincident")}, name="coincident")
    _assert_clean(run(args), sc, meas)


@pytest.mark.parametrize("value", ["0", "-5", "0.4"])
def test_gmm_components_out_of_range(scenarios, workdir, value):
    sc, meas, args = _case(workdir, scenarios, "gmm", options={"components": value})
    _assert_clean(run(args), sc, meas)


def test_gmm_calibration_huge_value(scenarios, workdir):
    cal = scenarios["gmm"].files["calibration"].read_text().splitlines()
    cells = cal[1].split(",")
    cells[2] = "1.7976931348623157e+308"
    cal[1] = ",".join(cells)
    p = workdir / "cal-huge.csv"
    p.write_text("\n".join(cal) + "\n")
    sc, meas, args = _case(workdir, scenarios, "gmm", files={"calibration": p}, name="calhuge")
    _assert_clean(run(args), sc, meas)


def test_grid_rssi_zero_cell(scenarios, workdir):
    sc, meas, args = _case(workdir, scenarios, "grid-rssi", options={"cell_m": "0"})
    _assert_clean(run(args), sc, meas)


@pytest.mark.parametrize("cell", ["1e-320", "5e-324", "1e-300"])
def test_grid_subnormal_cell_is_refused_naming_cell_m(scenarios, workdir, cell):
    """``-o cell_m=1e-320``: the grid's side over the cell overflowed (a RuntimeWarning and
    an internal error); now a one-line error naming cell_m and the limit."""
    sc, meas, args = _case(workdir, scenarios, "grid-rssi", options={"cell_m": cell})
    outcome, detail = classify(run(args), sc, meas)
    assert outcome == "error" and "cell_m" in detail and "too large" in detail, detail


@pytest.mark.parametrize("seed", ["3", "7"])
def test_pf_walk_within_its_reported_uncertainty(scenarios, workdir, seed):
    """pf on the walking scenario (200 particles): every row within the oracle's tolerance
    or three of its reported sigmas of the truth."""
    import io

    import pandas as pd

    from fuzz_harness import oracle

    sc, meas, args = _case(workdir, scenarios, "pf", options={"seed": seed}, name="pf-walk")
    res = run(args)
    assert classify(res, sc, meas)[0] == "success"
    assert oracle(pd.read_csv(io.StringIO(res.stdout), dtype={"node": str}), sc) is None


@pytest.mark.parametrize("method", ["ekf", "rls"])
def test_priors_coordinate_beyond_the_limit_is_refused_naming_the_line(scenarios, workdir,
                                                                      method):
    """A prior at y = -5.7e265 m overflowed inside the network EKF (an internal error); now a
    one-line error naming the priors file's line and column."""
    lines = scenarios[method].files["priors"].read_text().splitlines()
    cells = lines[2].split(",")
    cells[2] = "-5.677550083027445e+265"
    lines[2] = ",".join(cells)
    p = workdir / "priors-huge.csv"
    p.write_text("\n".join(lines) + "\n")
    sc, meas, args = _case(workdir, scenarios, method, files={"priors": p}, name="prihuge")
    outcome, detail = classify(run(args), sc, meas)
    assert outcome == "error" and "line 3" in detail and "'y'" in detail, detail


def _kind_mistake(scenarios, workdir, name, mistake):
    """A scenario of the newer kinds with one mistake of ``test_fuzz_kinds.MISTAKES``."""
    from test_fuzz_kinds import _apply_mistake

    sc = scenarios[name]
    rows, anchors_text, scale = _apply_mistake(mistake, [list(r) for r in sc.rows],
                                               sc.files["anchors"].read_text())
    anchors = workdir / f"{name}-{mistake}-anchors.csv"
    anchors.write_text(anchors_text)
    sc, meas, args = _case(workdir, scenarios, name, rows, {"anchors": anchors},
                           name=f"{name}-{mistake}")
    return sc, meas, args, scale


@pytest.mark.parametrize("name,mistake", [("cal-anchors", "bias_mm"), ("tdoa-lsq", "tdoa_sign"),
                                          ("tdoa-lsq", "reference_is_peer"),
                                          ("aoa-lsq", "aoa_clockwise"),
                                          ("moving", "anchor_time_ms")])
def test_kind_mistakes_end_in_a_clean_error(scenarios, workdir, name, mistake):
    """A bias_m in mm left every corrected range at 0 (ZeroDivisionError in the range-unit
    check); lsq reported fixes 10 m off claiming 5 cm on sign-flipped tdoa or aoa rows and
    on a moving anchor's times in ms: now one-line errors naming the node and time (or the
    line)."""
    sc, meas, args, _ = _kind_mistake(scenarios, workdir, name, mistake)
    res = run(args)
    outcome, detail = classify(res, sc, meas)
    if mistake == "anchor_time_ms" and outcome == "success":
        # lsq's fault exclusion leaves the moving anchor's misfitting rows out of each fix:
        # then the fixes from the other anchors must be right, and the rows left out counted
        est = read_output(res.stdout)
        assert oracle(est, sc) is None
        assert est["excluded"].sum() >= 1
        return
    assert outcome == "error", detail
    assert ("line 2" in detail) if mistake == "bias_mm" else ("node 'tag' at time" in detail)


@pytest.mark.parametrize("name,mistake,question", [
    ("tdoa", "tdoa_sign", "tdoa values with the wrong sign"),
    ("aoa", "aoa_clockwise", "aoa values counted clockwise"),
    ("pseudorange", "pseudorange_km", "pseudoranges in km"),
    ("pseudorange", "pseudorange_ns", "pseudoranges in ns"),
    ("odometry", "odometry_mm", "odometry in mm"),
    ("odometry", "odometry_sign", "odometry with the wrong sign")])
def test_ekf_track_on_inconsistent_kinds_names_the_slip(scenarios, workdir, name, mistake,
                                                        question):
    """ekf-track followed sign-flipped tdoa or aoa rows, pseudoranges in km or ns and
    odometry in mm or of the wrong sign, 5-5000 m off claiming 4-340 mm, with a warning that
    blamed the noise options: now a one-line error naming the kind and the slip that, undone,
    makes the track consistent."""
    sc, meas, args, _ = _kind_mistake(scenarios, workdir, name, mistake)
    outcome, detail = classify(run(args), sc, meas)
    assert outcome == "error", detail
    kind = "odometry_dx" if name == "odometry" else name
    assert f"the {kind}" in detail and question in detail and "fit no track" in detail, detail


@pytest.mark.parametrize("name", ["tdoa", "aoa", "pseudorange", "odometry"])
def test_ekf_track_on_consistent_kinds_is_right(scenarios, workdir, name):
    """The same scenarios as given: no slip named, every row within the oracle's band."""
    import io

    import pandas as pd

    from fuzz_harness import oracle

    sc, meas, args = _case(workdir, scenarios, name, name=f"{name}-right")
    res = run(args)
    outcome, detail = classify(res, sc, meas)
    assert outcome == "success" and not res.stderr.strip(), (detail, res.stderr)
    assert oracle(pd.read_csv(io.StringIO(res.stdout), dtype={"node": str}), sc) is None


@pytest.mark.parametrize("name,kinds,std", [("tdoa", ("tdoa",), 0.05), ("aoa", ("aoa",), 0.01),
                                            ("pseudorange", ("pseudorange",), 0.1),
                                            ("odometry", ("range", "odometry_dx",
                                                          "odometry_dy"), 0.05)])
def test_ekf_track_noise_beyond_the_stated_std_is_not_called_a_slip(scenarios, workdir, name,
                                                                    kinds, std):
    """Rows with five times the noise their option states diverge for want of noise, not
    for a slip: a success with the divergence warning naming the noise options."""
    import numpy as np

    rng = np.random.default_rng(7)
    rows = [list(r) for r in scenarios[name].rows]
    for r in rows[1:]:
        if r[3] in kinds:
            r[4] = repr(float(r[4]) + rng.normal(0.0, 5 * std))
    sc, meas, args = _case(workdir, scenarios, name, rows, name=f"{name}-noisy")
    res = run(args)
    outcome, detail = classify(res, sc, meas)
    assert outcome == "success", detail
    assert "look diverged" in res.stderr and "too small for this log?" in res.stderr, res.stderr


@pytest.mark.parametrize("q", ["0.0", "1e-9"])
def test_pseudoranges_fitted_exactly_by_a_motionless_track(scenarios, workdir, q):
    """Noise-free pseudoranges and no process noise (``-o q=0``): the fixes of each epoch
    fit their rows exactly (residual scale 0), which the health check divided by."""
    sc, meas, args = _case(workdir, scenarios, "pseudorange", options={"q": q},
                           name=f"pseudorange-q{q}")
    _assert_clean(run(args), sc, meas)


@pytest.mark.parametrize("mistake", ["ranges_mm", "ranges_km", "anchors_km", "no_bias_flag"])
def test_calibrate_misfit_is_refused(workdir, mistake):
    """calibrate put a rough anchor 19.6 m to 11 km off claiming 5 cm to 2 m (ranges in mm or
    km, surveyed anchors in km, biased ranges without --bias): now an error naming the
    residual rms against --std-m."""
    import csv
    import io

    from kinds_harness import calibrate_inputs

    folder = workdir / f"cal-{mistake}"
    folder.mkdir(exist_ok=True)
    meas, anchors = calibrate_inputs(folder)
    rows = [r for r in csv.reader(io.StringIO(meas.read_text()))]
    arows = [r for r in csv.reader(io.StringIO(anchors.read_text()))]
    if mistake.startswith("ranges_"):
        for r in rows[1:]:
            r[4] = repr(float(r[4]) * (1e3 if mistake == "ranges_mm" else 1e-3))
    elif mistake == "anchors_km":
        for r in arows[1:]:
            r[1], r[2] = repr(float(r[1]) / 1e3), repr(float(r[2]) / 1e3)
    meas.write_text(render(rows))
    anchors.write_text(render(arows))
    args = ["calibrate", str(meas), "--anchors", str(anchors), "--std-m", "0.05"]
    res = run(args + ([] if mistake == "no_bias_flag" else ["--bias"]))
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(lines) == 1 and "times --std-m" in lines[0], res.output


def test_a_progress_line_of_a_slow_run_is_not_part_of_its_error(workdir, scenarios):
    """A run slower than 10 s (a loaded machine) writes a progress line to standard error
    before its one-line refusal; the fuzz had counted that as a multi-line error."""
    from types import SimpleNamespace

    sc, meas, _ = _case(workdir, scenarios, "gn")
    refusal = "error: method lsq: node 'tag' at time 0.0: the measurements do not fit one position"
    res = SimpleNamespace(exception=SystemExit(2), exit_code=2, stdout="",
                          output=f"lsq: 96 of 96 rows (100 %) after 29 s\n{refusal}\n")
    assert classify(res, sc, meas) == ("error", refusal)
    res.output = f"lsq: 96 of 96 rows (100 %) after 29 s\n{refusal}\nmore\n"
    assert classify(res, sc, meas)[0] == "multi-line error"
