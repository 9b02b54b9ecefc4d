"""Fuzz of the log schema's newer kinds (tdoa with its reference column, aoa,
aoa_elevation, pseudorange, odometry_dx/dy, a per-row std column, anchors files with
std_m/bias_m/time columns) and of `radioloc calibrate`: malformed files, option strings,
re-encoded files, and plausible-but-wrong inputs judged by the truth oracle (a success must
lie within the scenario's tolerance of the truth or within k reported sigmas). Scenarios:
``kinds_harness``; outcome classes: ``fuzz_harness``."""

from __future__ import annotations

import csv
import io
import math

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from kinds_harness import BIAS, CAL_TRUTH, calibrate_inputs, calibrate_oracle
from test_fuzz_truth import BAD_BYTES, PRESERVING, SEPARATORS, encode

from fuzz_harness import (FUZZ, NASTY, cells, check, mutated_rows, option_values, render, run,
                          settle)

KIND_SCENARIOS = ["tdoa", "tdoa-lsq", "aoa", "aoa-lsq", "aoa3", "pseudorange", "odometry",
                  "std", "std-gn", "cal-anchors", "moving"]
KINDS = ["range", "rss", "tdoa", "aoa", "aoa_elevation", "pseudorange", "odometry_dx",
         "odometry_dy", "rtt", "TDOA", ""]


@st.composite
def kind_mutations(draw, rows: list[list[str]]) -> list[list[str]]:
    """Mutations of the columns the newer kinds add: the kind, the reference anchor, the
    per-row std; then the generic ones of ``mutated_rows``."""
    rows = [list(r) for r in rows]
    head = rows[0]
    for _ in range(draw(st.integers(1, 2))):
        if len(rows) < 2:                 # every row dropped by a generic mutation
            break
        r = draw(st.integers(1, len(rows) - 1))
        op = draw(st.sampled_from(["kind", "reference", "std", "drop_pair", "generic"]))
        if op == "kind" and len(rows[r]) > 3:
            rows[r][3] = draw(st.sampled_from(KINDS))
        elif op == "reference" and "reference" in head and len(rows[r]) > head.index("reference"):
            rows[r][head.index("reference")] = draw(st.one_of(
                st.sampled_from(["", "A0", "A1", "A9", rows[r][2], " A0", "a0"]), cells))
        elif op == "std" and "std" in head and len(rows[r]) > head.index("std"):
            rows[r][head.index("std")] = draw(st.one_of(
                st.sampled_from(["0", "-0.1", "nan", "inf", "1e-320", "1e30", "", "0.0001"]),
                cells))
        elif op == "drop_pair":
            del rows[r]                   # an odometry_dx without its dy, a lone tdoa...
        else:
            rows = draw(mutated_rows(rows))
    return rows


@FUZZ
@given(data=st.data(), name=st.sampled_from(KIND_SCENARIOS), quoted=st.booleans())
def test_fuzz_kinds_malformed_measurements(scenarios, workdir, data, name, quoted):
    sc = scenarios[name]
    meas = workdir / "kinds-meas.csv"
    meas.write_text(render(data.draw(kind_mutations(sc.rows)), quoted))
    check(sc.args(meas), sc, meas)


@FUZZ
@given(data=st.data(), name=st.sampled_from(KIND_SCENARIOS), quoted=st.booleans())
def test_fuzz_kinds_malformed_anchors(scenarios, workdir, data, name, quoted):
    """Anchors files with z, std_m, bias_m or time columns, mutated."""
    sc = scenarios[name]
    with open(sc.files["anchors"], newline="") as fh:
        rows = [r for r in csv.reader(fh)]
    side = workdir / "kinds-anchors.csv"
    side.write_text(render(data.draw(mutated_rows(rows)), quoted))
    meas = workdir / "kinds-meas.csv"
    meas.write_text(render(sc.rows))
    sc2 = type(sc)(**{**sc.__dict__, "files": {**sc.files, "anchors": side}})
    check(sc2.args(meas), sc2, meas)


@FUZZ
@given(data=st.data(), name=st.sampled_from(KIND_SCENARIOS))
def test_fuzz_kinds_options(scenarios, workdir, data, name):
    sc = scenarios[name]
    keys = st.one_of(st.sampled_from(sc.option_keys),
                     st.text(min_size=1, max_size=8).filter(lambda k: "=" not in k and k.strip()))
    opts = dict(sc.options)
    for _ in range(data.draw(st.integers(1, 3))):
        opts[data.draw(keys).strip()] = data.draw(option_values()).strip()
    meas = workdir / "kinds-meas.csv"
    meas.write_text(render(sc.rows))
    check(sc.args(meas, {k: v.replace("\n", " ") for k, v in opts.items()}), sc, meas)


@FUZZ
@given(data=st.data(), name=st.sampled_from(KIND_SCENARIOS),
       how=st.sampled_from(PRESERVING + BAD_BYTES + SEPARATORS))
def test_fuzz_kinds_encodings(scenarios, workdir, data, name, how):
    """The same numbers re-encoded: a success on the truth; bad bytes: the right line."""
    sc = scenarios[name]
    target = data.draw(st.sampled_from(["measurements", "anchors"]))
    meas = workdir / "kinds-meas.csv"
    meas.write_text(render(sc.rows))
    source = meas if target == "measurements" else sc.files["anchors"]
    text = source.read_text()
    line = data.draw(st.integers(1, len(text.rstrip("\n").split("\n"))))
    out = workdir / f"kinds-enc-{target}.csv"
    out.write_bytes(encode(text, how, line, False))
    files = dict(sc.files)
    if target == "measurements":
        meas = out
    else:
        files["anchors"] = out
    sc2 = type(sc)(**{**sc.__dict__, "files": files})

    def names_line(msg: str) -> str | None:
        if how in BAD_BYTES and f"line {line}" not in msg:
            return f"expected the line of the bad byte ({line})"
        return None

    check(sc2.args(meas), sc2, meas, truth=True, valid=how in PRESERVING,
          error_check=names_line)


def _scale_kind(rows, kinds, fn):
    head = rows[0]
    for r in rows[1:]:
        if r[3] in kinds:
            r[4] = repr(fn(float(r[4])))
    return head


#: plausible-but-wrong inputs per scenario: (name, what it does to the rows / anchors)
MISTAKES = {
    "tdoa": ["tdoa_sign", "tdoa_mm", "reference_is_peer", "time_ms", "shuffle"],
    "tdoa-lsq": ["tdoa_sign", "tdoa_mm", "reference_is_peer"],
    "aoa": ["aoa_degrees", "aoa_clockwise", "aoa_reversed", "time_ms", "shuffle"],
    "aoa-lsq": ["aoa_degrees", "aoa_clockwise", "aoa_reversed"],
    "aoa3": ["elevation_degrees", "elevation_sign", "aoa_degrees"],
    "pseudorange": ["pseudorange_km", "pseudorange_ns", "time_ms", "shuffle"],
    "odometry": ["odometry_swapped", "odometry_mm", "odometry_sign", "ranges_mm", "shuffle"],
    "std": ["std_variance", "std_mm", "ranges_mm", "shuffle"],
    "std-gn": ["std_variance", "std_mm", "ranges_mm"],
    "cal-anchors": ["bias_sign", "bias_mm", "ranges_mm"],
    "moving": ["anchor_time_ms", "ranges_mm", "shuffle"],
}
C = 299_792_458.0


def _apply_mistake(mistake, rows, anchors_text):
    """``(rows, anchors_text, time_scale)`` after the mistake."""
    body = rows[1:]
    time_scale = 1.0
    if mistake == "tdoa_sign":
        _scale_kind(rows, {"tdoa"}, lambda v: -v)
    elif mistake == "tdoa_mm":
        _scale_kind(rows, {"tdoa"}, lambda v: 1e3 * v)
    elif mistake == "reference_is_peer":
        i = rows[0].index("reference")
        for r in body:
            r[2], r[i] = r[i], r[2]              # peer and reference swapped, values kept
    elif mistake == "aoa_degrees":
        _scale_kind(rows, {"aoa"}, math.degrees)
    elif mistake == "elevation_degrees":
        _scale_kind(rows, {"aoa_elevation"}, math.degrees)
    elif mistake == "elevation_sign":
        _scale_kind(rows, {"aoa_elevation"}, lambda v: -v)
    elif mistake == "aoa_clockwise":
        _scale_kind(rows, {"aoa"}, lambda v: -v)
    elif mistake == "aoa_reversed":             # the bearing from the node to the anchor
        _scale_kind(rows, {"aoa"}, lambda v: math.atan2(-math.sin(v), -math.cos(v)))
    elif mistake == "pseudorange_km":
        _scale_kind(rows, {"pseudorange"}, lambda v: v / 1e3)
    elif mistake == "pseudorange_ns":
        _scale_kind(rows, {"pseudorange"}, lambda v: v / C * 1e9)
    elif mistake == "odometry_swapped":
        for r in body:
            if r[3].startswith("odometry_"):
                r[3] = "odometry_dy" if r[3] == "odometry_dx" else "odometry_dx"
    elif mistake == "odometry_mm":
        _scale_kind(rows, {"odometry_dx", "odometry_dy"}, lambda v: 1e3 * v)
    elif mistake == "odometry_sign":
        _scale_kind(rows, {"odometry_dx", "odometry_dy"}, lambda v: -v)
    elif mistake == "ranges_mm":
        _scale_kind(rows, {"range"}, lambda v: 1e3 * v)
    elif mistake in ("std_variance", "std_mm"):
        i = rows[0].index("std")
        for r in body:
            if r[i]:
                v = float(r[i])
                r[i] = repr(v * v if mistake == "std_variance" else 1e3 * v)
    elif mistake == "time_ms":
        time_scale = 1e3
        for r in body:
            r[0] = repr(float(r[0]) * time_scale)
    elif mistake == "shuffle":                   # rows out of time order: valid
        body.reverse()
    elif mistake in ("bias_sign", "bias_mm", "anchor_time_ms"):
        arows = [r for r in csv.reader(io.StringIO(anchors_text))]
        col = arows[0].index("time" if mistake == "anchor_time_ms" else "bias_m")
        for r in arows[1:]:
            if r[col]:
                v = float(r[col])
                r[col] = repr(-v if mistake == "bias_sign" else 1e3 * v)
        anchors_text = render(arows)
    else:  # pragma: no cover
        raise AssertionError(mistake)
    return rows[:1] + body, anchors_text, time_scale


@FUZZ
@given(data=st.data(), name=st.sampled_from(KIND_SCENARIOS))
def test_fuzz_kinds_wrong_units(scenarios, workdir, data, name):
    """A unit or sign slip in a newer kind's column: a one-line error, or a success on the
    truth (the oracle compares it with the scene the file meant)."""
    sc = scenarios[name]
    mistake = data.draw(st.sampled_from(MISTAKES[name]))
    rows, anchors_text, time_scale = _apply_mistake(
        mistake, [list(r) for r in sc.rows], sc.files["anchors"].read_text())
    meas = workdir / "kinds-wrong.csv"
    meas.write_text(render(rows))
    anchors = workdir / "kinds-wrong-anchors.csv"
    anchors.write_text(anchors_text)
    sc2 = type(sc)(**{**sc.__dict__, "files": {**sc.files, "anchors": anchors}})
    check(sc2.args(meas), sc2, meas, truth=True, time_scale=time_scale,
          valid=mistake == "shuffle", label=mistake)


# ---- radioloc calibrate ----------------------------------------------------------------

def check_calibrate(args, meas, anchors, *, truth=False, bias=None, valid=False) -> str:
    """Run ``radioloc calibrate``: a one-line error, or a calibrated anchors file with every
    input anchor (judged against the true anchors when ``truth``)."""
    res = run(args)
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        outcome, detail = "traceback", f"{type(res.exception).__name__}: {res.exception}"
    elif res.exit_code == 2:
        outcome, detail = (("error", lines[0]) if len(lines) == 1 and
                           lines[0].startswith("error:") else ("multi-line error", res.output))
    elif res.exit_code == 3:
        outcome, detail = "internal error", lines[-1] if lines else res.output
    elif res.exit_code != 0:
        outcome, detail = f"exit {res.exit_code}", res.output
    else:
        from radioloc.io.logs import read_anchors

        try:
            ids = set(read_anchors(anchors)["id"])
        except Exception:  # noqa: BLE001
            ids = None
        if ids is None:
            outcome, detail = "bad success", "exit 0 although the anchors file does not read"
        else:
            problem = calibrate_oracle(res.stdout, ids, bias=bias, k_sigma=5.0,
                                       tol_m=0.05) if truth else _calibrate_form(res.stdout, ids)
            outcome, detail = ("success", "") if problem is None else (
                "confidently wrong" if truth else "bad success", problem)
    if outcome == "error" and valid:
        outcome = "valid input refused"
    return settle(outcome, detail, "calibrate", args, meas, {"anchors": anchors}, truth)


def _calibrate_form(stdout: str, ids: set[str]) -> str | None:
    import pandas as pd

    try:
        est = pd.read_csv(io.StringIO(stdout), dtype={"id": str})
    except Exception as exc:  # noqa: BLE001
        return f"unreadable output: {exc}"
    if not {"id", "x", "y"} <= set(est.columns) or set(est["id"]) != ids:
        return f"output anchors {sorted(map(str, est.get('id', [])))} vs input {sorted(ids)}"
    if not np.isfinite(est[["x", "y"]].to_numpy(float)).all():
        return "non-finite coordinate"
    return None


CAL_OPTIONS = {"--std-m": "0.05", "--bias-prior-std-m": "1.0", "--loss": "linear"}


def _calibrate_args(meas, anchors, options=None, bias=True):
    a = ["calibrate", str(meas), "--anchors", str(anchors)]
    for k, v in (CAL_OPTIONS if options is None else options).items():
        a += [k, v]
    return a + (["--bias"] if bias else [])


@FUZZ
@given(data=st.data(), target=st.sampled_from(["measurements", "anchors"]),
       quoted=st.booleans())
def test_fuzz_calibrate_malformed_inputs(workdir, data, target, quoted):
    meas, anchors = calibrate_inputs(workdir)
    source = meas if target == "measurements" else anchors
    with open(source, newline="") as fh:
        rows = [r for r in csv.reader(fh)]
    out = workdir / f"cal-bad-{target}.csv"
    out.write_text(render(data.draw(mutated_rows(rows)), quoted))
    if target == "measurements":
        meas = out
    else:
        anchors = out
    check_calibrate(_calibrate_args(meas, anchors), meas, anchors)


@FUZZ
@given(data=st.data())
def test_fuzz_calibrate_options(workdir, data):
    meas, anchors = calibrate_inputs(workdir)
    opts = dict(CAL_OPTIONS)
    for _ in range(data.draw(st.integers(1, 2))):
        key = data.draw(st.sampled_from(sorted(CAL_OPTIONS)))
        opts[key] = data.draw(st.one_of(option_values(), st.sampled_from(
            ["huber", "soft_l1", "cauchy", "tukey", "HUBER", ""] + NASTY[:20]))).strip() or "0"
    args = _calibrate_args(meas, anchors, {k: v.replace("\n", " ") for k, v in opts.items()},
                           bias=data.draw(st.booleans()))
    check_calibrate(args, meas, anchors)


CAL_MISTAKES = ["none", "ranges_mm", "ranges_km", "anchors_km", "std_in_cm", "all_rough",
                "all_surveyed", "no_bias_flag", "shuffle", "crlf", "bom"]


@FUZZ
@given(mistake=st.sampled_from(CAL_MISTAKES))
def test_fuzz_calibrate_wrong_units(workdir, mistake):
    """The calibration scene with one plausible mistake: a one-line error, or anchors (and
    biases) on the truth within 5 cm or 5 reported sigmas."""
    meas, anchors = calibrate_inputs(workdir)
    rows = [r for r in csv.reader(io.StringIO(meas.read_text()))]
    arows = [r for r in csv.reader(io.StringIO(anchors.read_text()))]
    bias, flag = dict(BIAS), True
    if mistake in ("ranges_mm", "ranges_km"):
        k = 1e3 if mistake == "ranges_mm" else 1e-3
        for r in rows[1:]:
            r[4] = repr(float(r[4]) * k)
    elif mistake == "anchors_km":
        for r in arows[1:]:
            r[1], r[2] = repr(float(r[1]) / 1e3), repr(float(r[2]) / 1e3)
    elif mistake == "std_in_cm":
        for r in arows[1:]:
            r[3] = repr(float(r[3]) * 100) if r[3] else ""
    elif mistake == "all_rough":
        for r in arows[1:]:
            r[3] = r[3] or "2.0"
    elif mistake == "all_surveyed":                       # nothing to calibrate: the input
        for r in arows[1:]:
            r[3] = ""
    elif mistake == "no_bias_flag":                       # biased ranges, no --bias
        flag = False
    elif mistake == "shuffle":
        rows = rows[:1] + rows[1:][::-1]
    text = render(rows)
    meas.write_bytes({"crlf": text.replace("\n", "\r\n").encode(),
                      "bom": b"\xef\xbb\xbf" + text.encode()}.get(mistake, text.encode()))
    anchors.write_text(render(arows))
    truth = mistake not in ("all_surveyed",)
    check_calibrate(_calibrate_args(meas, anchors, bias=flag), meas, anchors, truth=truth,
                    bias=bias if flag else None,
                    valid=mistake in ("none", "shuffle", "crlf", "bom", "all_rough"))


def test_calibrate_scenario_is_exact(workdir):
    """The unmutated calibration lands on the truth (the oracle accepts the valid case)."""
    meas, anchors = calibrate_inputs(workdir)
    assert check_calibrate(_calibrate_args(meas, anchors), meas, anchors, truth=True,
                           bias=BIAS, valid=True) == "success"
    assert set(CAL_TRUTH) == {r.split(",")[0] for r in anchors.read_text().split()[1:]}


def test_kind_scenarios_are_exact(scenarios, workdir):
    """Every unmutated scenario of the newer kinds succeeds on its truth."""
    for name in KIND_SCENARIOS:
        sc = scenarios[name]
        meas = workdir / f"exact-{name}.csv"
        meas.write_text(render(sc.rows))
        assert check(sc.args(meas), sc, meas, truth=True, valid=True) == "success", name
