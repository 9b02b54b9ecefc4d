"""The CLI boundary: one-line errors with the right exit code, method declarations
(options, kinds, input files) checked before a method runs, output paths."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import radioloc.locate.base as base
from radioloc.core.errors import ConfigError, GeometryError
from radioloc.locate.base import LocateRequest, Option, locate_method, methods
from reliability_helpers import assert_one_line_error, invoke, lines

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MEAS = EXAMPLES / "measurements.csv"
ANCHORS = EXAMPLES / "anchors.csv"
HEAD = "time,node,peer,kind,value\n"


@pytest.fixture
def fake_methods(monkeypatch):
    """Register fake methods for one test only."""
    methods()  # import the real ones first
    saved = dict(base._METHODS)
    yield base._METHODS
    base._METHODS.clear()
    base._METHODS.update(saved)


def _centroid(request: LocateRequest) -> pd.DataFrame:
    m = request.measurements
    out = m[["time", "node"]].drop_duplicates().reset_index(drop=True)
    out["x"] = float(request.option("k", 1, int))
    out["y"] = 0.0
    return out


def declare(fake_methods, **kw):
    locate_method("fake", "a fake method for the tests", **kw)(_centroid)


@pytest.fixture
def meas_range(tmp_path):
    p = tmp_path / "m.csv"
    p.write_text(HEAD + "0,t,A1,range,3\n0,t,A2,range,4\n")
    return p


# ---- options ------------------------------------------------------------------------

def test_unknown_option_is_refused_listing_the_known_ones(fake_methods, meas_range):
    declare(fake_methods, options={"k": Option("an integer", int, min=1, max=10),
                                   "label": "free text"})
    line = assert_one_line_error(invoke(["locate", meas_range, "--method", "fake", "-o", "kk=3"]))
    assert "unknown option 'kk'" in line and "its options: k, label" in line


def test_method_declaring_no_options_refuses_any(fake_methods, meas_range):
    declare(fake_methods, options={})
    line = assert_one_line_error(invoke(["locate", meas_range, "--method", "fake", "-o", "k=3"]))
    assert "unknown option 'k'; its options: none" in line


@pytest.mark.parametrize("value, message", [
    ("0", "must be >= 1 \\(allowed: 1 to 10\\)"),
    ("11", "must be <= 10"),
    ("1e9", "must be <= 10"),
    ("inf", "must be a finite number"),
    ("nan", "must be a finite number"),
    ("-inf", "must be a finite number"),
    ("2.5", "expected a whole number"),
    ("three", "expected a number"),
    ("", "expected a number"),
])
def test_bad_option_values_are_refused(fake_methods, meas_range, value, message):
    declare(fake_methods, options={"k": Option("an integer", int, min=1, max=10)})
    line = assert_one_line_error(invoke(["locate", meas_range, "--method", "fake", "-o",
                                         f"k={value}"]))
    assert line.startswith("error: option k: ")
    import re
    assert re.search(message, line), line


@pytest.mark.parametrize("value, expected", [("7", 7), ("1e1", 10), (" 3.0 ", 3)])
def test_good_option_values_are_converted(fake_methods, meas_range, value, expected):
    declare(fake_methods, options={"k": Option("an integer", int, min=1, max=10)})
    res = invoke(["locate", meas_range, "--method", "fake", "-o", f"k={value}"])
    assert res.exit_code == 0, res.output
    assert pd.read_csv(__import__("io").StringIO(res.stdout))["x"].tolist() == [expected]


def test_option_spec_types():
    assert Option(type=bool).parse("t", "yes") is True
    assert Option(type=bool).parse("t", "0") is False
    with pytest.raises(ConfigError, match="expected 0/1"):
        Option(type=bool).parse("t", "maybe")
    assert Option(type=str, choices=("a", "b")).parse("m", "b") == "b"
    with pytest.raises(ConfigError, match="expected one of a, b"):
        Option(type=str, choices=("a", "b")).parse("m", "c")
    with pytest.raises(ConfigError, match="must be > 0"):
        Option(type=float, min=0, min_exclusive=True).parse("s", "0")


def test_undeclared_method_accepts_any_option_but_not_inf(fake_methods, meas_range):
    declare(fake_methods)  # no declaration: as the existing methods before theirs land
    res = invoke(["locate", meas_range, "--method", "fake", "-o", "whatever=1", "-o", "k=4"])
    assert res.exit_code == 0, res.output
    line = assert_one_line_error(invoke(["locate", meas_range, "--method", "fake", "-o",
                                         "k=inf"]))
    assert "option k: must be a finite number" in line


def test_malformed_and_repeated_option_items(fake_methods, meas_range):
    declare(fake_methods)
    assert "expected key=value" in assert_one_line_error(
        invoke(["locate", meas_range, "--method", "fake", "-o", "k"]))
    assert "expected key=value" in assert_one_line_error(
        invoke(["locate", meas_range, "--method", "fake", "-o", "=3"]))
    assert "given twice" in assert_one_line_error(
        invoke(["locate", meas_range, "--method", "fake", "-o", "k=1", "-o", "k=2"]))


# ---- kinds and input files ----------------------------------------------------------

def test_rows_of_an_unused_kind_are_refused_with_kind_and_count(fake_methods, tmp_path):
    declare(fake_methods, kinds=("range",))
    p = tmp_path / "m.csv"
    p.write_text(HEAD + "0,t,A1,range,3\n0,t,A1,rss,-60\n1,t,A2,rss,-61\n")
    line = assert_one_line_error(invoke(["locate", p, "--method", "fake"]))
    assert "uses only 'range' rows" in line and "2 'rss' row(s) (first at line 3)" in line


@pytest.mark.parametrize("flag", ["--calibration", "--priors", "--anchors"])
def test_a_file_the_method_does_not_read_is_refused(fake_methods, meas_range, flag):
    declare(fake_methods, inputs=())
    line = assert_one_line_error(invoke(["locate", meas_range, "--method", "fake", flag, ANCHORS]))
    assert f"does not read a {flag[2:]} file" in line


def test_declared_inputs_are_accepted(fake_methods, meas_range):
    declare(fake_methods, inputs=("anchors",), kinds=("range",), options={})
    meas = meas_range.parent / "m3.csv"          # three anchors: a geometry that fixes a position
    meas.write_text(meas_range.read_text() + "0,t,A3,range,40\n")
    res = invoke(["locate", meas, "--method", "fake", "--anchors", ANCHORS])
    assert res.exit_code == 0, res.output


def test_bad_declarations_fail_at_registration():
    with pytest.raises(ValueError, match="unknown input"):
        locate_method("x", "x", inputs=("calibraton",))
    with pytest.raises(ValueError, match="unknown kind"):
        locate_method("x", "x", kinds=("toa",))


# ---- failures of a method: internal errors, NaN, warnings -------------------------

def _register(fn):
    locate_method("fake", "fake")(fn)


def test_bug_in_a_method_is_one_internal_error_line(fake_methods, meas_range):
    def broken(request):
        return {}["missing"]
    _register(broken)
    line = assert_one_line_error(invoke(["locate", meas_range, "--method", "fake"]), code=3,
                                 prefix="internal error:")
    assert "KeyError" in line and "please report it" in line


def test_debug_shows_the_traceback(fake_methods, meas_range):
    def broken(request):
        return 1 / 0
    _register(broken)
    res = invoke(["locate", meas_range, "--method", "fake"], env={"RADIOLOC_DEBUG": "1"})
    assert res.exit_code == 3 and "Traceback" in res.output and "ZeroDivisionError" in res.output


def test_nan_estimate_is_never_printed(fake_methods, meas_range):
    def nan(request):
        out = _centroid(request)
        out["y"] = np.nan
        return out
    _register(nan)
    res = invoke(["locate", meas_range, "--method", "fake"])
    line = assert_one_line_error(res, code=3, prefix="internal error:")
    assert "non-finite y for node 't'" in line


def test_overflow_in_a_method_is_an_error_not_warning_noise(fake_methods, meas_range):
    def overflow(request):
        out = _centroid(request)
        out["x"] = np.exp(np.array([1000.0]))
        return out
    _register(overflow)
    res = invoke(["locate", meas_range, "--method", "fake"])
    line = assert_one_line_error(res, code=3, prefix="internal error:")
    assert "floating-point failure" in line and "overflow" in line


def test_other_warnings_are_one_line_each(fake_methods, meas_range):
    def warns(request):
        warnings.warn("the fit did not converge\nafter 100 iterations", UserWarning)
        warnings.warn("the fit did not converge\nafter 100 iterations", UserWarning)
        return _centroid(request)
    _register(warns)
    res = invoke(["locate", meas_range, "--method", "fake"])
    assert res.exit_code == 0
    assert res.stderr.strip().splitlines() == [
        "warning: the fit did not converge after 100 iterations"]


def test_a_failure_after_a_warning_prints_the_error_line_only(fake_methods, meas_range):
    def warns_then_fails(request):
        warnings.warn("2 readings of 1 station ignored", UserWarning)
        raise GeometryError("no reading left")
    _register(warns_then_fails)
    line = assert_one_line_error(invoke(["locate", meas_range, "--method", "fake"]))
    assert line == "error: no reading left"


def test_geometry_error_is_one_error_line(fake_methods, meas_range):
    def geo(request):
        raise GeometryError("method fake: node 't' at time 0: anchors are collinear")
    _register(geo)
    assert "collinear" in assert_one_line_error(invoke(["locate", meas_range, "--method", "fake"]))


def test_ctrl_c_is_one_line(fake_methods, meas_range):
    def interrupted(request):
        raise KeyboardInterrupt
    _register(interrupted)
    res = invoke(["locate", meas_range, "--method", "fake"])
    assert res.exit_code == 130 and lines(res) == ["interrupted"]


def test_error_message_with_brackets_and_newlines_is_printed_verbatim(fake_methods, meas_range):
    def brackets(request):
        raise ConfigError("option [bold]k[/bold]:\nbad")
    _register(brackets)
    line = assert_one_line_error(invoke(["locate", meas_range, "--method", "fake"]))
    assert line == "error: option [bold]k[/bold]: bad"


# ---- usage errors and output paths --------------------------------------------------

@pytest.mark.parametrize("args", [
    ["locate"],
    ["locate", MEAS, "--bogus"],
    ["reproduce", "gn-multilateration", "--workers", "many"],
    ["frobnicate"],
])
def test_usage_errors_are_one_line_without_a_box(args):
    line = assert_one_line_error(invoke(args))
    assert "--help" in line and "╭" not in line


def test_out_is_a_folder(tmp_path):
    line = assert_one_line_error(invoke(["locate", MEAS, "--anchors", ANCHORS, "--out", tmp_path]))
    assert "it is a folder, not a file" in line


def test_out_below_a_file(tmp_path):
    f = tmp_path / "f"
    f.write_text("x")
    line = assert_one_line_error(invoke(["locate", MEAS, "--anchors", ANCHORS, "--out",
                                         f / "est.csv"]))
    assert "is a file, not a folder" in line


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_out_on_a_full_device():
    line = assert_one_line_error(invoke(["locate", MEAS, "--anchors", ANCHORS, "--out",
                                         "/dev/full"]))
    assert "no space left on the device" in line
    assert Path("/dev/full").is_char_device()


def test_out_writes_a_complete_file_and_stdout_works(tmp_path):
    out = tmp_path / "new" / "est.csv"
    res = invoke(["locate", MEAS, "--anchors", ANCHORS, "--out", out])
    assert res.exit_code == 0, res.output
    assert len(pd.read_csv(out)) > 0 and sorted(p.name for p in out.parent.iterdir()) == [
        "est.csv", "est.summary.json"]
    res = invoke(["locate", MEAS, "--anchors", ANCHORS, "--out", "-"])
    assert res.exit_code == 0 and res.stdout.startswith("time,node,x,y")
