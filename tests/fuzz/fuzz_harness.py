"""Scenarios, mutations and the outcome classifier of the `radioloc locate` fuzz.

Every generated case runs ``radioloc locate`` in-process (typer's CliRunner) and is
classified as:

- ``error``: exit 2 and exactly one line ``error: ...`` (a clean refusal);
- ``success``: exit 0 and a CSV on standard output whose positions are finite, whose times
  are exactly the input's (bit for bit) and whose nodes are the input's;
- a failure otherwise: ``traceback`` (an exception escaped), ``internal error`` (exit 3),
  ``multi-line error``, ``bad success`` (NaN, unknown time or node, unreadable output),
  ``wrong answer`` (a known-answer case far from the truth), ``exit <n>``.

Failures that match an entry of :data:`KNOWN` are bugs already reported to the owners of
the files at fault: they are counted as ``known:<id>`` instead of failing the run, and
each has an xfail regression test with a concrete input in ``test_fuzz_known.py``.
"""

from __future__ import annotations

import csv
import io
import math
import os
import re
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from typer.testing import CliRunner

from radioloc.cli import app

# ---- profiles -------------------------------------------------------------------------

settings.register_profile(
    "radioloc-fuzz-fast", max_examples=12, deadline=None, derandomize=True, database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                           HealthCheck.data_too_large, HealthCheck.function_scoped_fixture])
settings.register_profile(
    "radioloc-fuzz-long", max_examples=1200, deadline=None, database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                           HealthCheck.data_too_large, HealthCheck.function_scoped_fixture])
settings.register_profile(
    "radioloc-fuzz-medium", max_examples=300, deadline=None, database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much,
                           HealthCheck.data_too_large, HealthCheck.function_scoped_fixture])
PROFILE = os.environ.get("RADIOLOC_FUZZ_PROFILE", "fast")
FUZZ = settings.get_profile(f"radioloc-fuzz-{PROFILE}")
if os.environ.get("RADIOLOC_FUZZ_EXAMPLES"):   # cases per test, in place of the profile's
    FUZZ = settings(FUZZ, max_examples=int(os.environ["RADIOLOC_FUZZ_EXAMPLES"]))

runner = CliRunner()
TALLY: Counter = Counter()

HEAD = ["time", "node", "peer", "kind", "value"]


# ---- scenarios: one valid input set per method ---------------------------------------

@dataclass
class Scenario:
    method: str
    rows: list[list[str]]                       # measurements, header first
    files: dict[str, Path] = field(default_factory=dict)   # --anchors/--priors/--calibration
    options: dict[str, str] = field(default_factory=dict)
    option_keys: tuple[str, ...] = ()
    truth: dict[str, tuple[float, float]] = field(default_factory=dict)
    extra_nodes: tuple[str, ...] = ()           # reported nodes not in the measurements
    # truth oracle: where each node was at each time (None: unknown), and how close a
    # success must be when it reports no uncertainty that covers its error
    truth_at: Callable[[float, str], tuple[float, float] | None] | None = None
    tol_m: float = 1e-3

    def args(self, meas: Path, options: dict[str, str] | None = None) -> list[str]:
        a = ["locate", str(meas), "--method", self.method]
        for k, p in self.files.items():
            a += [f"--{k}", str(p)]
        for k, v in (self.options if options is None else options).items():
            a += ["-o", f"{k}={v}"]
        return a


def _fmt(v: float) -> str:
    return repr(float(v))


def build_scenarios(folder: Path) -> dict[str, Scenario]:
    """Valid inputs for gn (2-D and 3-D), ekf-track, pf, gmm, grid-rssi, rls and ekf, and
    those of :mod:`kinds_harness` (small: a case runs in ms)."""
    rng = np.random.default_rng(12345)
    folder = Path(folder)
    out: dict[str, Scenario] = {}

    anchors = {"A1": (0.0, 0.0), "A2": (20.0, 0.0), "A3": (20.0, 20.0), "A4": (0.0, 20.0)}
    (folder / "anchors.csv").write_text(
        "id,x,y\n" + "".join(f"{k},{x},{y}\n" for k, (x, y) in anchors.items()))
    truth = {"t1": (7.0, 12.0), "t2": (15.0, 3.0)}
    rows = [HEAD]
    for t in (0.0, 1.0, 2.5):
        for n, p in truth.items():
            for a, q in anchors.items():
                rows.append([_fmt(t), n, a, "range", _fmt(math.dist(p, q))])
    out["gn"] = Scenario("gn", rows, {"anchors": folder / "anchors.csv"},
                         option_keys=("range_std_m",), truth=truth,
                         truth_at=lambda t, n: truth.get(n), tol_m=1e-3)

    # gn in 3-D: anchors with a height, exact ranges
    anchors3 = {"B1": (0.0, 0.0, 0.5), "B2": (20.0, 0.0, 3.0), "B3": (20.0, 20.0, 0.8),
                "B4": (0.0, 20.0, 2.7), "B5": (10.0, -5.0, 4.0)}
    (folder / "anchors3.csv").write_text(
        "id,x,y,z\n" + "".join(f"{k},{x},{y},{z}\n" for k, (x, y, z) in anchors3.items()))
    truth3 = {"t1": (7.0, 12.0, 1.5)}
    rows = [HEAD]
    for t in (0.0, 1.0):
        for n, p in truth3.items():
            for a, q in anchors3.items():
                rows.append([_fmt(t), n, a, "range", _fmt(math.dist(p, q))])
    out["gn3"] = Scenario("gn", rows, {"anchors": folder / "anchors3.csv"},
                          option_keys=("range_std_m", "on_degenerate"),
                          truth={k: v[:2] for k, v in truth3.items()},
                          truth_at=lambda t, n: truth3[n][:2] if n in truth3 else None,
                          tol_m=1e-3)

    # ekf-track and pf: a node walking past the anchors, ranges arriving one anchor at a
    # time (and a second node hearing all anchors at once every second)
    rows = [HEAD]
    names = list(anchors)
    for k in range(24):
        t = 0.25 * k
        p = (5.0 + 0.5 * t, 6.0 + 0.25 * t)
        a = names[k % 4]
        rows.append([_fmt(t), "w1", a, "range", _fmt(math.dist(p, anchors[a]))])
        if k % 4 == 0:
            for a in names:
                rows.append([_fmt(t), "w2", a, "range", _fmt(math.dist((12.0, 9.0),
                                                                        anchors[a]))])
    def walk(t, n):
        return {"w1": (5.0 + 0.5 * t, 6.0 + 0.25 * t), "w2": (12.0, 9.0)}.get(n)

    out["ekf-track"] = Scenario(
        "ekf-track", rows, {"anchors": folder / "anchors.csv"}, truth_at=walk, tol_m=0.5,
        option_keys=("motion", "q", "range_std_m", "range_bias_m", "tag_height_m", "gate",
                     "smooth", "prior_std_m", "init_s", "max_gap_s"))
    out["pf"] = Scenario(
        "pf", rows, {"anchors": folder / "anchors.csv"}, truth_at=walk, tol_m=1.0,
        options={"particles": "200", "seed": "3", "los_std_m": "0.2", "nlos_mean_m": "1",
                 "alpha": "0.9"},
        option_keys=("motion", "q", "particles", "seed", "los_std_m", "nlos_mean_m", "alpha",
                     "smooth", "smoother", "lag", "trajectories", "min_los_std_m", "gate",
                     "max_gap_s", "init_s", "prior_std_m", "tag_height_m", "range_bias_m"))

    # gmm: a small calibration file and rss rows
    aps = {"ap1": (0.0, 0.0), "ap2": (10.0, 0.0), "ap3": (5.0, 10.0)}
    pos = rng.uniform(0, 10, (60, 2))
    cal = pd.DataFrame({"x": pos[:, 0], "y": pos[:, 1]})
    for k, a in aps.items():
        d = np.hypot(pos[:, 0] - a[0], pos[:, 1] - a[1])
        cal[k] = -40 - 20 * np.log10(np.maximum(d, 0.5)) + rng.normal(0, 1, len(pos))
    cal.to_csv(folder / "cal.csv", index=False)
    rows = [HEAD]
    for t in (0.0, 1.0):
        for k, a in aps.items():
            d = max(math.dist((3.0, 4.0), a), 0.5)
            rows.append([_fmt(t), "phone", k, "rss", _fmt(-40 - 20 * math.log10(d))])
    out["gmm"] = Scenario("gmm", rows, {"calibration": folder / "cal.csv"},
                          truth_at=lambda t, n: (3.0, 4.0) if n == "phone" else None, tol_m=3.0,
                          options={"components": "3", "position_components": "3"},
                          option_keys=("components", "position_components", "track", "v_max"))

    # grid-rssi: a trapezoid model and rss rows to the anchors
    from radioloc.models.rssi_trapezoid import fit_trapezoid_model

    d = rng.uniform(0, 30, 4000)
    model = fit_trapezoid_model(np.clip(np.rint(70 - 2.0 * d + rng.normal(0, 0.3, d.size)), 0, 100),
                                d, tau_min=0.2, sigma_min=0.2, window=0)
    model.save(folder / "model.json")
    rows = [HEAD]
    for t in (0.0, 1.0):
        for a, q in anchors.items():
            rows.append([_fmt(t), "n1", a, "rss", _fmt(70 - 2.0 * math.dist((7.0, 12.0), q) - 110)])
    out["grid-rssi"] = Scenario("grid-rssi", rows, {"anchors": folder / "anchors.csv",
                                                    "calibration": folder / "model.json"},
                                options={"cell_m": "1"}, tol_m=3.0,
                                truth_at=lambda t, n: (7.0, 12.0) if n == "n1" else None,
                                option_keys=("cell_m", "margin_m", "epsilon", "blur_m",
                                             "dbm_min", "dbm_max"))

    # rls / ekf: node priors and pairwise ranges
    nodes = {"N1": (10.0, 10.0), "N2": (40.0, 5.0), "N3": (25.0, 30.0)}
    (folder / "priors.csv").write_text(
        "node,x,y,var_x,var_y\n" + "".join(
            f"{k},{x + 3},{y - 2},100,100\n" for k, (x, y) in nodes.items()))
    rows = [HEAD]
    for t in (0.0, 1.0, 2.0):
        for n, p in nodes.items():
            for m, q in nodes.items():
                if m != n:
                    rows.append([_fmt(t), n, m, "range", _fmt(math.dist(p, q))])
    for meth, keys in (("rls", ("forgetting", "anchor_var_m2")),
                       ("ekf", ("range_std_m", "anchor_var_m2"))):
        # the ranges fix the shape, the priors (offset by (3, -2), 10 m standard deviation)
        # the place: a success lies within the priors' offset and a margin
        out[meth] = Scenario(meth, rows, {"priors": folder / "priors.csv"}, option_keys=keys,
                             extra_nodes=tuple(nodes), truth_at=lambda t, n: nodes.get(n),
                             tol_m=5.0)
    from kinds_harness import build_kind_scenarios     # the newer kinds of the log schema

    out.update(build_kind_scenarios(folder, Scenario))
    return out


# ---- mutations ----------------------------------------------------------------------

NASTY = ["", " ", "nan", "NaN", "inf", "-inf", "Infinity", "1e308", "1.7e308", "-1.7e308",
         "1e-320", "-0", "0", "-1", "1e7", "1.0000001e7", "1e12", "1e13", "30", "30.5", "100",
         "+100", "-200", "-201", "1_000", "0x10", "١٢", "abc", "\"", "'", ",", "\n", "\r",
         "\t", "\x00", "9" * 400, "1e-9", "3", "2.5", "1e9", "-1e9", "range", "rss", "RANGE",
         "toa", "A1", "t1", "N1", "ap1", "phone", "n1", "#", "é", "😀", "  7  ", "1,5"]

cells = st.one_of(st.sampled_from(NASTY),
                  st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.integers(-10**12, 10**12).map(str),
                  st.text(max_size=6))


@st.composite
def mutated_rows(draw, rows: list[list[str]]) -> list[list[str]]:
    rows = [list(r) for r in rows]
    for _ in range(draw(st.integers(1, 3))):
        n_rows, width = len(rows), max((len(r) for r in rows), default=0)
        if n_rows == 0 or width == 0:        # every column dropped already
            break
        op = draw(st.sampled_from(
            ["cell", "cell", "cell", "dup_col", "drop_col", "extra_cell", "short_row",
             "dup_row", "drop_rows", "swap_kind", "header_case", "blank", "float_value",
             "rename_header", "shuffle"]))
        r = draw(st.integers(0, n_rows - 1))
        c = draw(st.integers(0, width - 1))
        if op == "cell":
            if c < len(rows[r]):
                rows[r][c] = draw(cells)
        elif op == "dup_col" and c < min(len(x) for x in rows):
            for x in rows:
                x.append(x[c])
        elif op == "drop_col" and c < min(len(x) for x in rows):
            for x in rows:
                del x[c]
        elif op == "extra_cell":
            rows[r].append(draw(cells))
        elif op == "short_row" and rows[r]:
            rows[r].pop()
        elif op == "dup_row":
            rows.insert(r, list(rows[r]))
        elif op == "drop_rows":
            keep = draw(st.integers(0, n_rows - 1))
            rows = rows[:1] + rows[1:][:keep]
        elif op == "swap_kind" and r > 0 and len(rows[r]) > 3:
            rows[r][3] = "rss" if rows[r][3] == "range" else "range"
        elif op == "header_case":
            rows[0] = [h.upper() if draw(st.booleans()) else f" {h} " for h in rows[0]]
        elif op == "blank":
            rows.insert(max(r, 1), [])
        elif op == "float_value" and r > 0 and len(rows[r]) > 4:
            rows[r][draw(st.sampled_from([0, 4]))] = repr(draw(st.floats(
                allow_nan=True, allow_infinity=True, min_value=None, max_value=None)))
        elif op == "rename_header" and c < len(rows[0]):
            rows[0][c] = draw(st.sampled_from(["time", "node", "peer", "kind", "value", "x", ""]))
        elif op == "shuffle":
            body = rows[1:]
            perm = draw(st.permutations(range(len(body))))
            rows = rows[:1] + [body[i] for i in perm]
    return rows


def render(rows: list[list[str]], quoted: bool = True) -> str:
    if quoted:
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        for r in rows:
            w.writerow(r)
        return buf.getvalue()
    return "".join(",".join(r) + "\n" for r in rows)


def option_values():
    return st.one_of(st.sampled_from(NASTY),
                     st.floats(allow_nan=True, allow_infinity=True).map(repr),
                     st.floats(-10, 10).map(repr),
                     st.integers(-5, 50).map(str),
                     st.integers().map(str))


# ---- running and classifying --------------------------------------------------------

def run(args: list[str]):
    return runner.invoke(app, args)


def read_output(text: str, id_column: str = "node") -> pd.DataFrame:
    """A CSV the CLI wrote, its id column as text with the spreadsheet escape taken off
    (an id such as ``=x`` is written ``'=x``)."""
    from radioloc.io.logs import spreadsheet_text

    est = pd.read_csv(io.StringIO(text), dtype={id_column: str})
    if id_column in est.columns:
        est[id_column] = est[id_column].map(lambda v: spreadsheet_text(v) if isinstance(v, str)
                                            else v)
    return est


def input_table(meas: Path) -> pd.DataFrame | None:
    try:
        from radioloc.io.logs import read_measurements
        return read_measurements(meas)
    except Exception:  # noqa: BLE001 - only used to check a success
        return None


#: A progress line, written to standard error once per 10 s of work when it is not a
#: terminal (``radioloc.locate.progress``): part of any outcome, error or success.
PROGRESS_LINE = re.compile(r"^[^\n]+: [\d,]+ of [\d,]+ [^\n]+ \(\d+ %\) after \d+ s$")


def classify(res, scenario: Scenario, meas: Path) -> tuple[str, str]:
    """``(outcome, detail)``: outcome is ``error``, ``success`` or a failure class."""
    text = "\n".join(ln for ln in res.output.splitlines() if not PROGRESS_LINE.match(ln))
    lines = [ln for ln in text.splitlines() if ln.strip()]
    if res.exception is not None and not isinstance(res.exception, SystemExit):
        tb = "".join(__import__("traceback").format_exception(res.exception)[-3:])
        return "traceback", f"{type(res.exception).__name__}: {res.exception} | {tb}"
    if res.exit_code == 2:
        if len(lines) == 1 and lines[0].startswith("error:"):
            return "error", lines[0]
        return "multi-line error", text
    if res.exit_code == 3:
        return "internal error", lines[-1] if lines else text
    if res.exit_code != 0:
        return f"exit {res.exit_code}", text
    # the CLI's own one-line warnings (readings or stations dropped and counted) are part of
    # a success; anything else on stderr (a RuntimeWarning, a library's message) is noise
    err = [ln for ln in res.stderr.splitlines() if ln.strip() and not ln.startswith("warning: ")]
    if err:
        return "noise on stderr", "\n".join(err)
    try:
        est = read_output(res.stdout)
    except Exception as exc:  # noqa: BLE001
        return "bad success", f"unreadable output: {exc}"
    if not {"time", "node", "x", "y"} <= set(est.columns) or est.empty:
        return "bad success", f"columns {list(est.columns)}, {len(est)} rows"
    vals = est[[c for c in ("x", "y", "uncertainty_m") if c in est.columns]].to_numpy(float)
    if not np.isfinite(vals).all():
        return "bad success", "non-finite value in the output"
    table = input_table(meas)
    if table is None:
        return "bad success", "exit 0 although the measurements file does not read"
    if not set(est["time"].to_numpy()) <= set(table["time"].to_numpy()):
        return "bad success", "an output time is not an input time (precision lost?)"
    nodes = set(table["node"]) | set(scenario.extra_nodes)
    if not set(est["node"].astype(str)) <= nodes:
        return "bad success", f"unknown node in the output: {set(est['node']) - nodes}"
    return "success", ""


#: The oracle's band: a row is confidently wrong when its error exceeds both the scenario's
#: tolerance and SIGMA_K reported uncertainties (sqrt of the covariance trace: a 2-D
#: Gaussian error exceeds 3 of them with probability 1.2e-2 at most); a success is
#: confidently wrong when more than BAD_RATE of its rows are, or one row exceeds the
#: tolerance by GROSS_K times and SIGMA_K * GROSS_K uncertainties.
SIGMA_K = 3.0
BAD_RATE = 0.1
GROSS_K = 10.0


def oracle(est: pd.DataFrame, scenario: Scenario, time_scale: float = 1.0) -> str | None:
    """Judge a success against the truth the case was generated from.

    Parameters
    ----------
    est : DataFrame
        The CLI's output.
    scenario : Scenario
        With ``truth_at`` and ``tol_m``.
    time_scale : float
        Output times divided by this are the scenario's times (a case that rescales time).

    Returns
    -------
    str or None
        Why the success is (confidently) wrong; None: it is right.
    """
    if scenario.truth_at is None:
        return None
    rows = [(float(t) / time_scale, str(n)) for t, n in zip(est["time"], est["node"])]
    truth = [scenario.truth_at(t, n) for t, n in rows]
    known = np.array([p is not None for p in truth])
    if not known.any():
        return None
    xy = est[["x", "y"]].to_numpy(float)[known]
    err = np.linalg.norm(xy - np.array([p for p in truth if p is not None]), axis=1)
    unc = (est["uncertainty_m"].to_numpy(float)[known] if "uncertainty_m" in est.columns
           else np.zeros(err.size))
    bad = (err > scenario.tol_m) & (err > SIGMA_K * unc)
    gross = (err > GROSS_K * scenario.tol_m) & (err > GROSS_K * SIGMA_K * unc)
    if bad.mean() > BAD_RATE or gross.any():
        i = int(np.argmax(np.where(bad, err, -1.0)))
        return (f"confidently wrong: {int(bad.sum())} of {bad.size} rows off the truth by more "
                f"than {scenario.tol_m:g} m and {SIGMA_K:g} reported sigmas (worst: "
                f"{err[i]:.3g} m off, claiming {unc[i]:.3g} m)")
    return None


# Known failures not yet fixed: (id, method, outcome, regex on the detail); each needs a
# regression test in test_fuzz_known.py.
KNOWN: list[tuple[str, str, str, str]] = []


def known(method: str, outcome: str, detail: str) -> str | None:
    for kid, m, o, pattern in KNOWN:
        if m in (method, "*") and o == outcome and re.search(pattern, detail, re.S):
            return kid
    return None


def check(args: list[str], scenario: Scenario, meas: Path, *, est_check=None,
          error_check=None, truth: bool = False, time_scale: float = 1.0,
          valid: bool = False, label: str = "") -> str:
    """Run ``radioloc ARGS``, classify, tally, and fail (AssertionError) on an unknown failure.

    ``est_check(estimates) -> problem or None`` judges a success against a known answer;
    ``error_check(line) -> problem or None`` judges an error line (does it name the place?).
    ``truth``: the input still describes the scenario's scene, so a success must pass
    :func:`oracle` (``time_scale``: the factor applied to the times). ``valid``: the input
    is valid (only its bytes differ from the scenario's), so an error is a failure.
    ``label`` names the mutation in a failure's detail (``[label] ...``, for :data:`KNOWN`).
    """
    res = run(args)
    outcome, detail = classify(res, scenario, meas)
    if outcome == "error" and error_check is not None:
        problem = error_check(detail)
        if problem:
            outcome, detail = "error naming the wrong place", f"{problem}: {detail}"
    if outcome == "success" and est_check is not None:
        problem = est_check(read_output(res.stdout))
        if problem:
            outcome, detail = "wrong answer", problem
    if outcome == "success" and truth:
        problem = oracle(read_output(res.stdout), scenario,
                         time_scale)
        if problem:
            outcome, detail = "confidently wrong", problem
    if outcome == "error" and valid:
        outcome = "valid input refused"
    if label and outcome not in ("error", "success"):
        detail = f"[{label}] {detail}"
    return settle(outcome, detail, scenario.method, args, meas, scenario.files, truth)


def settle(outcome: str, detail: str, method: str, args: list[str], meas: Path,
           files: dict[str, Path], truth: bool = False) -> str:
    """Tally a classified case; fail (AssertionError) on a failure not in :data:`KNOWN`
    (with ``RADIOLOC_FUZZ_COLLECT=<file>``: record it there and go on)."""
    if outcome in ("error", "success"):
        TALLY[f"{outcome} (truth)" if truth and outcome == "success" else outcome] += 1
        return outcome
    kid = known(method, outcome, detail)
    if kid is not None:
        TALLY[f"known:{kid}"] += 1
        return f"known:{kid}"
    TALLY["FAILURE"] += 1
    collect = os.environ.get("RADIOLOC_FUZZ_COLLECT")
    if collect:  # discovery mode: record every failure, do not stop
        import json

        with open(collect, "a") as fh:
            fh.write(json.dumps({"method": method, "outcome": outcome,
                                 "detail": detail[:3000], "args": args,
                                 "input": meas.read_text(errors="replace")[:3000],
                                 "files": {k: Path(v).read_text(errors="replace")[:3000]
                                           for k, v in files.items()
                                           if "fuzz-cases" in str(v)}}) + "\n")
        return "collected"
    raise AssertionError(f"{outcome}: {detail}\ncommand: radioloc {' '.join(args)}\n"
                         f"input:\n{meas.read_text(errors='replace')[:2000]}")
