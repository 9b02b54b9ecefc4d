"""Progress of `radioloc locate`: every method counts the rows of the log it has processed;
when standard error is not a terminal, one line per ``LINE_EVERY_S`` seconds of work."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

import radioloc.locate.progress as progress_module
from radioloc.cli import app

runner = CliRunner()
LINE = re.compile(r"^(?P<what>[a-z-]+): (?P<done>[\d,]+) of (?P<total>[\d,]+) rows "
                  r"\(\d+ %\) after \d+ s$")
ANCHORS = {"A1": (0.0, 0.0), "A2": (20.0, 0.0), "A3": (20.0, 20.0), "A4": (0.0, 20.0)}


@pytest.fixture(scope="module")
def log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("progress")
    (folder / "anchors.csv").write_text(
        "id,x,y\n" + "".join(f"{k},{x},{y}\n" for k, (x, y) in ANCHORS.items()))
    rows = ["time,node,peer,kind,value"]
    for t in range(12):
        for node, p in (("n1", (5.0 + 0.5 * t, 6.0 + 0.3 * t)), ("n2", (14.0, 9.0 - 0.2 * t))):
            rows += [f"{t},{node},{a},range,{((p[0] - x) ** 2 + (p[1] - y) ** 2) ** 0.5:.4f}"
                     for a, (x, y) in ANCHORS.items()]
    (folder / "m.csv").write_text("\n".join(rows) + "\n")
    return folder, len(rows) - 1


@pytest.mark.parametrize("method, options", [
    ("gn", []), ("lsq", []), ("localml", []), ("ransac", []), ("ekf-track", []),
    ("smoother", []), ("pf", ["-o", "particles=200"]),
])
def test_every_method_counts_the_rows_of_the_log(monkeypatch, log, method, options):
    folder, n_rows = log
    monkeypatch.setattr(progress_module, "LINE_EVERY_S", 0.0)     # a line at every advance
    res = runner.invoke(app, ["locate", str(folder / "m.csv"), "--anchors",
                              str(folder / "anchors.csv"), "--method", method, *options])
    assert res.exit_code == 0, res.output
    lines = [m for m in map(LINE.match, res.stderr.splitlines()) if m]
    assert lines, res.stderr
    done = [int(m["done"].replace(",", "")) for m in lines]
    assert {m["what"] for m in lines} == {method}
    assert {int(m["total"].replace(",", "")) for m in lines} == {n_rows}
    assert done == sorted(done) and done[-1] == n_rows
    assert "rows" not in res.stdout                   # the estimates alone on stdout


def test_no_line_before_its_interval_nor_with_quiet(monkeypatch, log):
    folder, _ = log
    args = ["locate", str(folder / "m.csv"), "--anchors", str(folder / "anchors.csv"),
            "--method", "ekf-track"]
    assert not LINE.match((runner.invoke(app, args).stderr.splitlines() or [""])[0])
    monkeypatch.setattr(progress_module, "LINE_EVERY_S", 0.0)
    res = runner.invoke(app, args + ["--quiet"])
    assert res.exit_code == 0 and not any(map(LINE.match, res.stderr.splitlines()))
