"""Fuzz of `radioloc locate`: malformed CSVs, side files, option strings and known-answer
geometry, each outcome classified (see fuzz_harness). Profile: RADIOLOC_FUZZ_PROFILE."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fuzz_harness import FUZZ, HEAD, NASTY, check, mutated_rows, option_values, render

METHODS = ["gn", "gn3", "ekf-track", "pf", "gmm", "grid-rssi", "rls", "ekf"]


@FUZZ
@given(data=st.data(), method=st.sampled_from(METHODS), quoted=st.booleans())
def test_fuzz_malformed_measurements(scenarios, workdir, data, method, quoted):
    sc = scenarios[method]
    rows = data.draw(mutated_rows(sc.rows))
    meas = workdir / "meas.csv"
    meas.write_text(render(rows, quoted))
    check(sc.args(meas), sc, meas)


SIDE = {"gn": "anchors", "gn3": "anchors", "ekf-track": "anchors", "pf": "anchors",
        "grid-rssi": "anchors", "rls": "priors", "ekf": "priors", "gmm": "calibration"}


@FUZZ
@given(data=st.data(), method=st.sampled_from(METHODS), quoted=st.booleans())
def test_fuzz_malformed_side_file(scenarios, workdir, data, method, quoted):
    import csv

    sc = scenarios[method]
    kind = SIDE[method]
    with open(sc.files[kind], newline="") as fh:
        rows = [r for r in csv.reader(fh)]
    rows = data.draw(mutated_rows(rows))
    side = workdir / f"side-{kind}.csv"
    side.write_text(render(rows, quoted))
    meas = workdir / "meas.csv"
    meas.write_text(render(sc.rows))
    files = dict(sc.files)
    files[kind] = side
    sc2 = type(sc)(**{**sc.__dict__, "files": files})
    check(sc2.args(meas), sc2, meas)


@FUZZ
@given(data=st.data(), method=st.sampled_from(METHODS))
def test_fuzz_options(scenarios, workdir, data, method):
    sc = scenarios[method]
    keys = st.one_of(st.sampled_from(sc.option_keys + ("track", "cell_m", "components")),
                     st.text(min_size=1, max_size=8).filter(lambda k: "=" not in k and k.strip()))
    opts = dict(sc.options)
    for _ in range(data.draw(st.integers(1, 3))):
        opts[data.draw(keys).strip()] = data.draw(option_values()).strip()
    meas = workdir / "meas.csv"
    meas.write_text(render(sc.rows))
    check(sc.args(meas, {k: v.replace("\n", " ") for k, v in opts.items()}), sc, meas)


@st.composite
def geometry(draw):
    """Anchors (3..6; sometimes collinear or coincident) and a node, exact ranges."""
    n = draw(st.integers(3, 6))
    coord = st.floats(-100, 100, allow_nan=False).map(lambda v: round(v, 3))
    shape = draw(st.sampled_from(["general", "general", "collinear", "near-collinear",
                                  "near-collinear, node near the line"]))
    if shape == "general":
        anchors = [(draw(coord), draw(coord)) for _ in range(n)]
        truth = (draw(coord), draw(coord))
    else:
        y0, slope = draw(coord), draw(st.floats(-2, 2).map(lambda v: round(v, 3)))
        eps = 0.0 if shape == "collinear" else draw(st.sampled_from([1e-6, 1e-4, 1e-2, 0.3]))
        anchors = [(x, y0 + slope * x + (eps if i == 1 else 0.0))
                   for i, x in enumerate(draw(st.lists(coord, min_size=n, max_size=n,
                                                       unique=True)))]
        x = draw(coord)
        if shape.endswith("near the line"):
            # a node 1 cm .. 10 m from the anchors' line (the mirror fixes nearly tie)
            h = draw(st.sampled_from([0.01, 0.05, 0.28, 1.0, 3.0, 10.0])) * draw(
                st.sampled_from([-1.0, 1.0]))
            truth = (round(x - h * slope / math.hypot(1, slope), 6),
                     round(y0 + slope * x + h / math.hypot(1, slope), 6))
        else:
            truth = (x, draw(coord))
    return shape, anchors, truth


def _conditioning(anchors, truth) -> float:
    """Smallest singular value of the unit line-of-sight matrix (0: no unique fix)."""
    a = np.asarray(anchors)
    d = a - np.asarray(truth)
    r = np.linalg.norm(d, axis=1, keepdims=True)
    if np.any(r < 1e-6):
        return 0.0
    return float(np.linalg.svd(d / r, compute_uv=False)[-1])


@FUZZ
@given(g=geometry())
def test_fuzz_gn_known_answer(scenarios, workdir, g):
    """Exact ranges: either a fix at the truth or a clean refusal; never a confident wrong
    answer (the mirror image across collinear anchors, a local minimum)."""
    shape, anchors, truth = g
    sc = scenarios["gn"]
    afile = workdir / "anchors-geo.csv"
    afile.write_text("id,x,y\n" + "".join(f"A{i},{x!r},{y!r}\n" for i, (x, y) in enumerate(anchors)))
    rows = [HEAD] + [["0.0", "t", f"A{i}", "range", repr(math.dist(truth, p))]
                     for i, p in enumerate(anchors)]
    meas = workdir / "meas-geo.csv"
    meas.write_text(render(rows))
    sc2 = type(sc)(**{**sc.__dict__, "files": {"anchors": afile}})
    scale = max(1.0, max(math.dist(truth, p) for p in anchors))

    def near_truth(est):
        err = math.dist((float(est["x"].iloc[0]), float(est["y"].iloc[0])), truth)
        if err > 1e-3 * scale:
            return (f"{shape} anchors {anchors}, truth {truth}: estimate "
                    f"({est['x'].iloc[0]:.6g}, {est['y'].iloc[0]:.6g}) is {err:.3g} m away "
                    f"(conditioning {_conditioning(anchors, truth):.2g})")
        return None

    check(sc2.args(meas), sc2, meas, est_check=near_truth)


@FUZZ
@given(data=st.data(), bad=st.sampled_from(["abc", "", "inf", "nan", "1e400", "0x10", "1,5"]),
       blank=st.booleans())
def test_fuzz_error_names_the_right_line(scenarios, workdir, data, bad, blank):
    """One bad number: the error names its line (blank lines counted) and its column."""
    sc = scenarios["gn"]
    rows = [list(r) for r in sc.rows]
    r = data.draw(st.integers(1, len(rows) - 1))
    col = data.draw(st.sampled_from(["time", "value"]))
    rows[r][HEAD.index(col)] = bad
    line = r + 1
    if blank:
        rows.insert(1, [])
        line += 1
    meas = workdir / "meas-line.csv"
    meas.write_text(render(rows))

    def names_place(msg):
        if f"line {line}," not in msg or f"column '{col}'" not in msg:
            return f"expected line {line}, column '{col}'"
        return None

    assert check(sc.args(meas), sc, meas, error_check=names_place) != "success"


@st.composite
def geometry3(draw):
    """3-D anchors (4..6; general, coplanar or nearly coplanar) and a node, exact ranges."""
    n = draw(st.integers(4, 6))
    coord = st.floats(-50, 50, allow_nan=False).map(lambda v: round(v, 3))
    shape = draw(st.sampled_from(["general", "coplanar", "near-coplanar"]))
    pts = [(draw(coord), draw(coord), draw(coord)) for _ in range(n)]
    if shape != "general":
        eps = 0.0 if shape == "coplanar" else draw(st.sampled_from([1e-6, 1e-3, 0.1]))
        z0 = draw(coord)
        pts = [(x, y, z0 + (eps if i == 1 else 0.0)) for i, (x, y, _) in enumerate(pts)]
    truth = (draw(coord), draw(coord), draw(coord))
    return shape, pts, truth


@FUZZ
@given(g=geometry3())
def test_fuzz_gn_3d_known_answer(scenarios, workdir, g):
    """3-D exact ranges: a fix at the truth (x, y) or a clean refusal."""
    shape, anchors, truth = g
    sc = scenarios["gn3"]
    afile = workdir / "anchors-geo3.csv"
    afile.write_text("id,x,y,z\n" + "".join(f"B{i},{x!r},{y!r},{z!r}\n"
                                            for i, (x, y, z) in enumerate(anchors)))
    rows = [HEAD] + [["0.0", "t", f"B{i}", "range", repr(math.dist(truth, p))]
                     for i, p in enumerate(anchors)]
    meas = workdir / "meas-geo3.csv"
    meas.write_text(render(rows))
    sc2 = type(sc)(**{**sc.__dict__, "files": {"anchors": afile}})
    scale = max(1.0, max(math.dist(truth, p) for p in anchors))

    def near_truth(est):
        got = [float(est[c].iloc[0]) for c in ("x", "y", "z") if c in est.columns]
        err = math.dist(got, truth[:len(got)])
        if len(got) != 3 or err > 1e-3 * scale:
            return f"{shape} anchors {anchors}, truth {truth}: estimate {got} ({err:.3g} m)"
        return None

    check(sc2.args(meas), sc2, meas, est_check=near_truth)
