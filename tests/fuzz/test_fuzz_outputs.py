"""Fuzz of what `radioloc locate` writes and of inputs put where another kind's columns go:

- output paths: ``--out``, ``--format`` and ``--plot`` drawn from names that include the
  inputs, links to them, each other and write-protected files, with node ids that collide
  once their characters are replaced or their case folded: a run either refuses (exit 2,
  every file of the folder unchanged) or writes exactly the outputs it names, one file per
  node for TUM, and leaves every other file unchanged; which of the two is decided here,
  independently of the CLI;
- formula ids: node ids beginning with ``=``, ``+``, ``-`` or ``@``: no CSV cell may start a
  spreadsheet formula, and the ids read back (escape taken off) are the input's;
- other kinds' columns: a ``reference`` cell on a row that is not tdoa, a tiny ``std``, a
  ``z`` column for a method that locates in the plane, RSS anchors that cannot fix a
  position, ranges between nodes for a snapshot method: refused naming the place, or (the
  last) used with a warning that counts them;
- valid pseudorange logs of any noise draw: tracked, never refused.

Profile: RADIOLOC_FUZZ_PROFILE (see conftest.py)."""

from __future__ import annotations

import csv
import io
import math
import os
import shutil
import stat
import tempfile
from pathlib import Path
from urllib.parse import quote

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from fuzz_harness import FUZZ, HEAD, check, render, run, settle

# ---- output paths -----------------------------------------------------------------------

#: node ids whose replaced-character or case-folded names collide
NODE_NAMES = ["a b", "a_b", "a/b", "a%20b", "A", "a", "=x", "..", "é", "t1"]
#: --out candidates (a name of the folder: an input, an alias of one, or a new file)
OUT_NAMES = ["out.csv", "out.tum", "out.geojson", "r.html", "plot.png", "meas.csv",
             "side.csv", "alias.csv", "hard.csv", "out.summary.json", "locked.csv", "-"]
PLOT_NAMES = [None, "plot.png", "r.html", "out.svg", "locked.png"]
OUT_METHODS = ["gn", "ekf-track"]


def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())
            if p.is_file() and not p.is_symlink()}


def _same(a: Path, b: Path) -> bool:
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.realpath(a) == os.path.realpath(b)


def _fmt_of(out: str, fmt: str | None) -> str:
    if fmt:
        return fmt
    return {".tum": "tum", ".geojson": "geojson", ".parquet": "parquet"}.get(
        Path(out).suffix, "csv")


def _expected_files(folder: Path, out: str, fmt: str, plot: str | None,
                    nodes: list[str]) -> tuple[list[Path], str | None]:
    """The files a run must write, or why it must refuse (independent of the CLI). The
    ``--out`` path itself must not name an input or a write-protected file even when TUM
    writes one file per node beside it instead."""
    if fmt == "geojson":
        return [], "GeoJSON is WGS84 and the anchors' local frame has no place on the Earth"
    if out == "-":
        if fmt == "tum" and len(nodes) > 1:
            return [], "tum to standard output with several nodes"
        files = []
    elif fmt == "tum" and len(nodes) > 1:
        p = folder / out
        names = [f"{p.stem}.{quote(n, safe='')}{p.suffix}" for n in nodes]
        if len({n.casefold() for n in names}) < len(names):
            return [], "two nodes differ only in case"
        files = [folder / n for n in names]
    else:
        files = [folder / out]
    if out != "-":
        files.append(folder / (Path(out).stem + ".summary.json"))
    if plot is not None:
        files.append(folder / plot)
    inputs = [folder / "meas.csv", folder / "side.csv"]
    per_node = out != "-" and fmt == "tum" and len(nodes) > 1
    checked = [folder / out, *files] if per_node else files
    for i, f in enumerate(checked):
        if any(_same(f, x) for x in inputs + checked[:i]):
            return [], f"{f.name} is an input or another output"
        if f.exists() and not os.access(f, os.W_OK) or (f.exists() and not f.stat().st_mode & 0o222):
            return [], f"{f.name} is write-protected"
    return files, None


@FUZZ
@given(data=st.data(), method=st.sampled_from(OUT_METHODS),
       out=st.sampled_from(OUT_NAMES), plot=st.sampled_from(PLOT_NAMES),
       fmt=st.sampled_from([None, None, "csv", "tum", "geojson"]))
def test_fuzz_output_paths(scenarios, workdir, data, method, out, plot, fmt):
    sc = scenarios[method]
    folder = Path(tempfile.mkdtemp(dir=workdir, prefix="out-"))
    try:
        nodes = sorted({r[1] for r in sc.rows[1:]})
        names = data.draw(st.lists(st.sampled_from(NODE_NAMES), min_size=len(nodes),
                                   max_size=len(nodes), unique=True))
        rename = dict(zip(nodes, names))
        rows = [sc.rows[0]] + [[r[0], rename[r[1]], *r[2:]] for r in sc.rows[1:]]
        (folder / "meas.csv").write_text(render(rows))
        shutil.copy(sc.files["anchors"], folder / "side.csv")
        os.symlink(folder / "side.csv", folder / "alias.csv")
        os.link(folder / "meas.csv", folder / "hard.csv")
        for name in ("locked.csv", "locked.png"):
            (folder / name).write_text("previous\n")
            (folder / name).chmod(0o444)
        if data.draw(st.booleans()):              # a previous run's output is replaced
            (folder / "out.csv").write_text("previous,run\n")
        args = ["locate", str(folder / "meas.csv"), "--method", method, "--anchors",
                str(folder / "side.csv"), "--quiet",
                "--out", out if out == "-" else str(folder / out)]
        args += [] if plot is None else ["--plot", str(folder / plot)]
        args += [] if fmt is None else ["--format", fmt]
        for k, v in sc.options.items():
            args += ["-o", f"{k}={v}"]
        order = list(dict.fromkeys(r[1] for r in rows[1:]))
        files, refusal = _expected_files(folder, out, _fmt_of(out, fmt), plot, order)
        before = _snapshot(folder)
        res = run(args)
        after = _snapshot(folder)
        kept = {k: v for k, v in after.items() if folder / k not in files}
        if res.exit_code == 2:
            outcome, detail = "error", res.output.strip()
            if refusal is None:
                outcome, detail = "valid output refused", detail
            elif after != before:
                outcome, detail = "refusal changed a file", f"{refusal}: {sorted(set(after) ^ set(before))}"
        elif res.exit_code == 0:
            outcome, detail = "success", ""
            missing = [f.name for f in files if not f.is_file()]
            if refusal is not None:
                outcome, detail = "destroying output accepted", refusal
            elif missing:
                outcome, detail = "output not written", f"{missing}"
            elif kept != {k: v for k, v in before.items() if folder / k not in files}:
                outcome, detail = "another file changed", f"{sorted(set(kept) ^ set(before))}"
        else:
            outcome, detail = f"exit {res.exit_code}", res.output
        settle(outcome, f"{detail} (out={out}, plot={plot}, format={fmt}, nodes={names})",
               method, args, folder / "meas.csv", {})
    finally:
        for p in folder.iterdir():
            if not p.is_symlink():
                p.chmod(0o644)
        shutil.rmtree(folder, ignore_errors=True)


# ---- formula ids -------------------------------------------------------------------------

FORMULA_START = st.sampled_from(["=", "+", "-", "@", "'=", "''+"])
ID_TAIL = st.text(st.characters(blacklist_categories=("Cs", "Cc", "Zl", "Zp")), max_size=8)


@FUZZ
@given(data=st.data(), method=st.sampled_from(["gn", "ekf-track", "grid-rssi"]))
def test_fuzz_formula_ids(scenarios, workdir, data, method):
    """Node ids that a spreadsheet would run: no output cell starts a formula, and the ids
    read back are the input's (the truth oracle follows them)."""
    sc = scenarios[method]
    nodes = sorted({r[1] for r in sc.rows[1:]})
    ids = data.draw(st.lists(st.builds(lambda a, b: (a + b).strip(), FORMULA_START, ID_TAIL)
                             .filter(lambda s: len(s) > 1), min_size=len(nodes),
                             max_size=len(nodes), unique=True))
    rename = dict(zip(nodes, ids))
    back = {v: k for k, v in rename.items()}
    rows = [sc.rows[0]] + [[r[0], rename[r[1]], *r[2:]] for r in sc.rows[1:]]
    meas = workdir / "formula.csv"
    meas.write_text(render(rows, quoted=True))
    sc2 = type(sc)(**{**sc.__dict__, "truth_at": lambda t, n: sc.truth_at(t, back.get(n, n))})
    res = run(sc2.args(meas))
    if res.exit_code == 0:
        table = list(csv.reader(io.StringIO(res.stdout)))
        for row in table[1:]:
            for cell in row:
                if cell[:1] in ("=", "+", "-", "@") and not _is_number(cell):
                    settle("formula cell written", repr(cell), method, sc2.args(meas), meas, {})
    check(sc2.args(meas), sc2, meas, truth=True)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


# ---- inputs on other kinds' columns ------------------------------------------------------

def _with_column(rows: list[list[str]], name: str, fill: str = "") -> list[list[str]]:
    if name in rows[0]:
        return [list(r) for r in rows]
    return [rows[0] + [name]] + [list(r) + [fill] for r in rows[1:]]


@FUZZ
@given(data=st.data(), name=st.sampled_from(["gn", "ekf-track", "pf", "aoa", "aoa-lsq",
                                             "pseudorange", "pseudorange-smoother",
                                             "odometry", "std"]))
def test_fuzz_reference_on_another_kind(scenarios, workdir, data, name):
    """A reference anchor on a row that is not tdoa: refused naming its line."""
    sc = scenarios[name]
    rows = _with_column(sc.rows, "reference")
    r = data.draw(st.integers(1, len(rows) - 1))
    rows[r][rows[0].index("reference")] = data.draw(st.sampled_from(["A0", "A1", "x", "=A0"]))
    meas = workdir / "other-kind.csv"
    meas.write_text(render(rows))

    def names_line(msg):
        return None if (f"line {r + 1}, column 'reference'" in msg) else f"expected line {r + 1}"

    assert check(sc.args(meas), sc, meas, error_check=names_line) != "success"


@FUZZ
@given(data=st.data(), name=st.sampled_from(["gn", "ekf-track", "std", "std-gn", "tdoa-lsq"]),
       std=st.sampled_from(["1e-40", "5e-324", "1e-31", "0", "-0.0", "0.0", "-1e-30"]))
def test_fuzz_tiny_std(scenarios, workdir, data, name, std):
    """A row std below 1e-30 (its inverse squared overflows): refused naming file, line
    and column."""
    sc = scenarios[name]
    rows = _with_column(sc.rows, "std")
    r = data.draw(st.integers(1, len(rows) - 1))
    rows[r][rows[0].index("std")] = std
    meas = workdir / "tiny-std.csv"
    meas.write_text(render(rows))

    def names_place(msg):
        place = f"{meas}: line {r + 1}, column 'std'"
        return None if place in msg else f"expected {place}"

    assert check(sc.args(meas), sc, meas, error_check=names_place) != "success"


@FUZZ
@given(name=st.sampled_from(["grid-rssi", "rls", "ekf"]), z=st.sampled_from(["0", "1.5", ""]))
def test_fuzz_heights_for_a_planar_method(scenarios, workdir, name, z):
    """An anchors file with z for a method that locates in the plane: refused."""
    sc = scenarios[name]
    key = "anchors" if "anchors" in sc.files else None
    side = workdir / "planar-anchors.csv"
    if key is None:                          # rls / ekf: the priors' nodes as anchors
        side.write_text("id,x,y,z\nQ1,0.0,0.0,{z}\nQ2,50.0,0.0,{z}\nQ3,0.0,50.0,{z}\n"
                        .replace("{z}", z or "0"))
    else:
        lines = Path(sc.files[key]).read_text().splitlines()
        side.write_text("\n".join([lines[0] + ",z"] + [ln + f",{z}" for ln in lines[1:]]) + "\n")
    sc2 = type(sc)(**{**sc.__dict__, "files": {**sc.files, "anchors": side}})
    meas = workdir / "planar.csv"
    meas.write_text(render(sc.rows))
    out = check(sc2.args(meas), sc2, meas,
                error_check=lambda m: None if ("locates in the plane" in m or "z" in m)
                else "expected the z column named")
    assert out != "success"


@FUZZ
@given(data=st.data(), shape=st.sampled_from(["collinear", "coincident", "degrees", "general"]))
def test_fuzz_rss_anchor_geometry(scenarios, workdir, data, shape):
    """grid-rssi with anchors that cannot fix a position: refused; a general geometry is
    located near the truth."""
    sc = scenarios["grid-rssi"]
    coord = st.floats(0, 30).map(lambda v: round(v, 2))
    if shape == "collinear":
        x0, slope = data.draw(coord), data.draw(st.floats(-1, 1).map(lambda v: round(v, 2)))
        pts = [(x0 + k * 7.0, slope * k * 7.0) for k in range(4)]
    elif shape == "coincident":
        p = (data.draw(coord), data.draw(coord))
        pts = [p] * 4
    elif shape == "degrees":
        pts = [(2.35 + data.draw(st.floats(0, 0.01)), 48.85 + data.draw(st.floats(0, 0.01)))
               for _ in range(4)]
    else:
        pts = [(0.0, 0.0), (20.0, 0.0), (20.0, 20.0), (0.0, 20.0)]
    node = (7.0, 12.0) if shape == "general" else (data.draw(coord), data.draw(coord))
    side = workdir / "rss-anchors.csv"
    side.write_text("id,x,y\n" + "".join(f"A{k + 1},{x!r},{y!r}\n" for k, (x, y) in enumerate(pts)))
    rows = [HEAD] + [[repr(t), "n1", f"A{k + 1}", "rss", repr(70 - 2.0 * math.dist(node, q) - 110)]
                     for t in (0.0, 1.0) for k, q in enumerate(pts)]
    meas = workdir / "rss-geometry.csv"
    meas.write_text(render(rows))
    sc2 = type(sc)(**{**sc.__dict__, "files": {**sc.files, "anchors": side},
                      "truth_at": lambda t, n: node if n == "n1" else None})
    got = check(sc2.args(meas), sc2, meas, truth=shape == "general", valid=shape == "general")
    if shape != "general":
        assert got != "success", f"{shape} anchors {pts} accepted"


@FUZZ
@given(data=st.data())
def test_fuzz_gn_ranges_between_nodes(scenarios, workdir, data):
    """Ranges between nodes added to a gn log: the fixes are unchanged and a warning counts
    the rows left out."""
    sc = scenarios["gn"]
    extra = data.draw(st.lists(st.tuples(st.sampled_from(["0.0", "1.0", "2.5"]),
                                         st.sampled_from([("t1", "t2"), ("t2", "t1")]),
                                         st.floats(0, 100).map(repr)), min_size=1, max_size=6))
    rows = [list(r) for r in sc.rows] + [[t, a, b, "range", v] for t, (a, b), v in extra]
    meas = workdir / "between.csv"
    meas.write_text(render(rows))
    res = run(sc.args(meas))
    if res.exit_code != 0 or f"{len(extra)} range row(s) between nodes not used" not in res.stderr:
        settle("ranges between nodes not counted", res.output, "gn", sc.args(meas), meas, {})
    check(sc.args(meas), sc, meas, truth=True, valid=True)


# ---- a valid input: pseudoranges of any noise draw ---------------------------------------

@FUZZ
@given(seed=st.integers(0, 2**32 - 1), std=st.sampled_from([0.1, 0.3, 1.0]),
       method=st.sampled_from(["pseudorange", "pseudorange-smoother"]))
def test_fuzz_pseudorange_noise(scenarios, workdir, seed, std, method):
    """The scenario's pseudoranges with Gaussian noise: tracked within the tolerance, never
    refused (the start fit once ran out of iterations for some draws)."""
    sc = scenarios[method]
    rng = np.random.default_rng(seed)
    rows = [sc.rows[0]] + [[*r[:4], repr(float(r[4]) + std * rng.standard_normal())]
                           for r in sc.rows[1:]]
    meas = workdir / "pseudorange-noise.csv"
    meas.write_text(render(rows))
    opts = {**sc.options, "pseudorange_std_m": repr(std)}
    sc2 = type(sc)(**{**sc.__dict__, "options": opts, "tol_m": max(sc.tol_m, 3 * std)})
    check(sc2.args(meas), sc2, meas, truth=True, valid=True)
