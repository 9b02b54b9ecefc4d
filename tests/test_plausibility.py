"""Plausibility checks of `radioloc locate`: the typical unit and geometry mistakes each give a
one-line error naming the likely cause (never exit 0 with a confident wrong answer), a named
check can be overruled, and a correct log passes every method."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError, GeometryError, InputError
from radioloc.core.plausibility import (CHECKS, anchor_problem, check_ranges, check_rss, check_time,
                                        parse_skip, range_scale)
from reliability_helpers import assert_one_line_error, invoke, lines, locate

ANCHORS = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]])


def _walk(n: int = 41, dt: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    t = np.arange(n) * dt
    s = t / t[-1]
    xy = np.stack([4 + 12 * s, 4 + 6 * np.sin(np.pi * s)], -1)
    return t, xy


def _write(tmp_path, anchors=ANCHORS, *, range_scale_=1.0, time_scale=1.0, swap=None,
           z=None, rss=False, rss_mw=False):
    """A tag walking inside four anchors, 4 ranges per epoch (or RSS), written as CSV."""
    t, xy = _walk()
    rng = np.random.default_rng(1)
    rows = ["time,node,peer,kind,value"]
    ids = [f"A{k}" for k in range(len(anchors))]
    true_anchors = ANCHORS if len(anchors) == len(ANCHORS) else anchors
    for k in range(t.size):
        for a, pos in zip(ids, true_anchors):
            d = float(np.hypot(*(xy[k] - pos[:2]))) + 0.05 * rng.standard_normal()
            if rss:
                value = -40 - 20 * np.log10(max(d, 0.5))
                value = 10 ** (value / 10) if rss_mw else value
                rows.append(f"{float(t[k] * time_scale)!r},tag,{a},rss,{float(value)!r}")
            else:
                rows.append(f"{float(t[k] * time_scale)!r},tag,{a},range,{abs(d) * range_scale_!r}")
    if swap is not None:                # move 3 rows from `swap` on to the end (time goes back)
        rows += [rows.pop(swap) for _ in range(3)]
    head = "id,x,y" + (",z" if z is not None else "")
    arows = [head] + [f"{i},{float(p[0])!r},{float(p[1])!r}" + (f",{float(z[k])!r}" if z is not None else "")
                      for k, (i, p) in enumerate(zip(ids, anchors))]
    (tmp_path / "m.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "a.csv").write_text("\n".join(arows) + "\n")
    return tmp_path / "m.csv", tmp_path / "a.csv"


RANGE_METHODS = ("gn", "ekf-track", "pf")

MISTAKES = {
    # name: (writer kwargs, expected words in the message, check name)
    "anchors in degrees": (dict(anchors=np.array([[26.9, 119.1], [26.90018, 119.1],
                                                  [26.90018, 119.10014], [26.9, 119.10014]])),
                           "anchors in degrees?", "anchor_units"),
    "ranges in mm": (dict(range_scale_=1e3), "ranges in mm", "range_units"),
    "ranges in cm": (dict(range_scale_=1e2), "ranges in cm?", "range_units"),
    "ranges in km": (dict(range_scale_=1e-3), "ranges in km?", "range_units"),
    "anchors in km": (dict(anchors=ANCHORS / 1e3), "anchors in km", "range_units"),
    "time in ms": (dict(time_scale=1e3), "time in milliseconds?", "time_units"),
    "coincident anchors": (dict(anchors=np.full((4, 2), 5.0)), "coincide", "geometry"),
    "collinear anchors": (dict(anchors=np.array([[0.0, 0], [7, 0], [13, 0], [20, 0]])),
                          "collinear", "geometry"),
    "coplanar 3-D anchors": (dict(z=[3.0, 3.0, 3.0, 3.0]), "coplanar", "geometry"),
    "one anchor's coordinates wrong": (dict(anchors=np.array([[-300.0, 250.0], [20, 0],
                                                              [20, 15], [0, 15]])),
                                       "anchor(s) A0 fit no position", "anchor_ranges"),
}


@pytest.mark.parametrize("method", RANGE_METHODS)
@pytest.mark.parametrize("mistake", [m for m in MISTAKES if m != "time in ms"])
def test_range_mistakes_refused_by_every_range_method(tmp_path, mistake, method):
    kw, words, check = MISTAKES[mistake]
    meas, anchors = _write(tmp_path, **kw)
    line = assert_one_line_error(locate(meas, anchors, method))
    assert words in line and f"no_check={check}" in line, line


@pytest.mark.parametrize("method", ("ekf-track", "pf"))
def test_time_in_milliseconds_refused_by_trackers(tmp_path, method):
    meas, anchors = _write(tmp_path, time_scale=1e3)
    line = assert_one_line_error(locate(meas, anchors, method))
    assert "time in milliseconds?" in line and "max_gap_s = 5" in line


def test_rss_in_milliwatts_refused(tmp_path):
    meas, _ = _write(tmp_path, rss=True, rss_mw=True)
    res = invoke(["locate", meas, "--method", "gmm", "--calibration", tmp_path / "none.csv"])
    line = assert_one_line_error(res)
    assert "RSS in mW?" in line and "no_check=rss_units" in line


def test_time_backwards_warns_with_a_count(tmp_path):
    meas, anchors = _write(tmp_path, swap=5)
    res = locate(meas, anchors, "gn")
    assert res.exit_code == 0, res.output
    warn = [ln for ln in lines(res) if ln.startswith("warning:")]
    assert len(warn) == 1 and "3 row(s) go back in time" in warn[0] and "node 'tag'" in warn[0]
    quiet = locate(meas, anchors, "gn", "no_check=time_order")
    assert quiet.exit_code == 0 and not [ln for ln in lines(quiet) if ln.startswith("warning:")]


@pytest.mark.parametrize("method", RANGE_METHODS)
def test_correct_log_passes_and_lands_on_the_truth(tmp_path, method):
    meas, anchors = _write(tmp_path)
    res = locate(meas, anchors, method, *(("seed=1",) if method == "pf" else ()))
    assert res.exit_code == 0, res.output
    body = [ln for ln in lines(res) if not ln.startswith("warning:")]
    xy = np.array([[float(v) for v in ln.split(",")[2:4]] for ln in body[1:]])
    assert np.median(np.linalg.norm(xy - _walk()[1], axis=1)) < 0.5


def test_overrule_runs_the_method_and_unknown_check_is_refused(tmp_path):
    meas, anchors = _write(tmp_path, range_scale_=1e2)
    res = locate(meas, anchors, "ekf-track", "no_check=range_units")
    assert "ranges in cm" not in res.output
    line = assert_one_line_error(locate(meas, anchors, "gn", "no_check=units"))
    assert "unknown check(s) units" in line and "range_units" in line
    assert parse_skip("all") == frozenset(CHECKS)
    with pytest.raises(ConfigError):
        parse_skip("geometry,bogus")


def test_cooperative_methods_skip_the_anchor_geometry_only(tmp_path):
    """rls/ekf read node priors that fix what two anchors leave open: no geometry refusal,
    but the unit checks still apply."""
    R = np.array([[5.0, 6.0]])
    check_ranges(R, np.array([[0.0, 0.0], [8.0, 0.0]]), skip={"geometry"})
    with pytest.raises(GeometryError, match="collinear"):
        check_ranges(R, np.array([[0.0, 0.0], [8.0, 0.0]]))
    with pytest.raises(InputError, match="ranges in mm"):
        check_ranges(R * 1e3, np.array([[0.0, 0.0], [8.0, 0.0]]), skip={"geometry"})


def test_array_checks_are_unit_free():
    """The triangle statistic is invariant to scaling ranges and anchors together, and to
    moving or rotating the scene."""
    t, xy = _walk()
    R = np.linalg.norm(xy[:, None] - ANCHORS[None], axis=-1)
    assert range_scale(R, ANCHORS) == 1.0
    assert range_scale(R * 1e3, ANCHORS * 1e3) == 1.0
    c, s = np.cos(0.7), np.sin(0.7)
    assert range_scale(R, ANCHORS @ np.array([[c, -s], [s, c]]) + 1e4) == 1.0
    assert range_scale(R * 1e3, ANCHORS) > 100
    assert range_scale(R / 1e3, ANCHORS) < 0.01
    assert anchor_problem(ANCHORS) is None
    assert anchor_problem(np.c_[ANCHORS, [0, 0, 0, 0]])[0] == "coplanar"
    assert anchor_problem(np.c_[ANCHORS, [0, 0, 0, 0]], dim=2) is None
    with pytest.raises(InputError, match="RSS in mW"):
        check_rss(np.array([1e-7, 2e-7]))
    check_rss(np.array([-70.0, -60.0]))


@pytest.mark.parametrize("line", [None, np.nan])
def test_time_backwards_in_a_table_built_in_python_names_the_row(line):
    frame = pd.DataFrame({"time": [0.0, 1.0, 0.5, 2.0], "node": ["t", "t", "t", "t"],
                          "peer": "A1", "kind": "range", "value": 1.0})
    if line is not None:
        frame["line"] = line
    with pytest.warns(UserWarning, match=r"1 row\(s\) go back in time .*first: row 2, node 't'"):
        check_time(frame)


def test_likely_slip_names_the_one_map_that_makes_the_log_consistent():
    """A tracker's verdict that only the negated tdoa rows satisfy: that slip is named; a
    verdict no map satisfies (or one that raises the toolkit's error) names none; the other
    kinds' values are left as they are."""
    from radioloc.locate.slips import likely_slip, undo_slip

    log = pd.DataFrame({"kind": ["tdoa", "tdoa", "range"], "value": [1.5, -2.0, 4.0]})
    truth = np.array([-1.5, 2.0, 4.0])

    def consistent(m: pd.DataFrame) -> bool:
        return bool(np.allclose(m["value"].to_numpy(), truth))

    assert likely_slip(log, consistent) == ("tdoa", "negated",
                                            "tdoa values with the wrong sign (reference minus "
                                            "peer)?")
    assert likely_slip(log.assign(value=truth), consistent) is None   # no map makes it fit

    def refuses(m: pd.DataFrame) -> bool:
        raise InputError("no track")

    assert likely_slip(log, refuses) is None
    mm = undo_slip(log, ("tdoa",), lambda v: v / 1e3)
    np.testing.assert_allclose(mm["value"], [1.5e-3, -2e-3, 4.0])
    np.testing.assert_allclose(log["value"], [1.5, -2.0, 4.0])     # the input is not changed
