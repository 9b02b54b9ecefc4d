"""Progress of `radioloc locate`: every method counts the rows of the log it has processed;
when standard error is not a terminal, one line per ``LINE_EVERY_S`` seconds of work."""

from __future__ import annotations

import math
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


def _lines(res) -> list:
    assert res.exit_code == 0, res.output
    return [m for m in map(LINE.match, res.stderr.splitlines()) if m]


def test_network_and_single_sensor_methods_count_their_rows(monkeypatch, tmp_path):
    monkeypatch.setattr(progress_module, "LINE_EVERY_S", 0.0)
    nodes = {"N1": (10.0, 10.0), "N2": (40.0, 5.0), "N3": (25.0, 30.0)}
    (tmp_path / "priors.csv").write_text("node,x,y,var_x,var_y\n" + "".join(
        f"{k},{x + 3},{y - 2},100,100\n" for k, (x, y) in nodes.items()))
    rows = [f"{t},{n},{m},range,{((p[0] - q[0]) ** 2 + (p[1] - q[1]) ** 2) ** 0.5:.4f}"
            for t in range(3) for n, p in nodes.items() for m, q in nodes.items() if m != n]
    (tmp_path / "net.csv").write_text("time,node,peer,kind,value\n" + "\n".join(rows) + "\n")
    for method in ("rls", "ekf"):
        lines = _lines(runner.invoke(app, ["locate", str(tmp_path / "net.csv"), "--priors",
                                           str(tmp_path / "priors.csv"), "--method", method]))
        assert lines and lines[-1]["done"] == lines[-1]["total"] == str(len(rows))
    t = [0.5 * k for k in range(20)]
    sensor = [(10 * math.cos(1.3 * k), 10 * math.sin(1.3 * k)) for k in range(20)]
    (tmp_path / "sensor.csv").write_text("id,time,x,y\n" + "".join(
        f"S,{tk},{x},{y}\n" for tk, (x, y) in zip(t, sensor)))
    rows = [f"{tk},{n},S,range,{math.dist((x0 + vx * tk, y0 + vy * tk), s):.6f}"
            for n, x0, y0, vx, vy in (("n1", -3, -2, 0.4, 0.2), ("n2", 2, -3, -0.3, 0.4))
            for tk, s in zip(t, sensor)]
    (tmp_path / "walk.csv").write_text("time,node,peer,kind,value\n" + "\n".join(rows) + "\n")
    for method in ("closed-form", "newton"):
        lines = _lines(runner.invoke(app, ["locate", str(tmp_path / "walk.csv"), "--anchors",
                                           str(tmp_path / "sensor.csv"), "--method", method]))
        assert lines and lines[-1]["done"] == lines[-1]["total"] == str(len(rows))


@pytest.mark.parametrize("method, options", [("ekf-track", []), ("lsq", []), ("gn", [])])
def test_a_run_in_chunks_counts_the_rows_of_the_log(monkeypatch, log, tmp_path, method,
                                                    options):
    """``--chunk-rows``: the rows of every chunk once estimated, of the whole file's rows
    (and the first pass, as rows read: ekf-track's, which learns its settings, and gn's,
    which pools its noise)."""
    folder, n_rows = log
    monkeypatch.setattr(progress_module, "LINE_EVERY_S", 0.0)
    res = runner.invoke(app, ["locate", str(folder / "m.csv"), "--anchors",
                              str(folder / "anchors.csv"), "--method", method, "--out",
                              str(tmp_path / "o.csv"), "--chunk-rows", "20", *options])
    assert res.exit_code == 0, res.output
    passes: dict = {}
    for line in res.stderr.splitlines():
        m = re.match(r"^(?P<what>[a-z-]+(?: \((?:learning|noise) pass\))?): "
                     r"(?P<done>[\d,]+) of (?P<total>[\d,]+) rows \(\d+ %\) after \d+ s$", line)
        if m:
            passes.setdefault(m["what"], []).append(
                (int(m["done"].replace(",", "")), int(m["total"].replace(",", ""))))
    first = {"ekf-track": {"ekf-track (learning pass)"}, "gn": {"gn (noise pass)"}}
    expected = {method} | first.get(method, set())
    assert set(passes) == expected, res.stderr
    for counts in passes.values():
        done = [d for d, _ in counts]
        assert {t for _, t in counts} == {n_rows}
        assert done == sorted(done) and done[-1] == n_rows
    summary = (tmp_path / "o.summary.json").read_text()
    assert '"chunks"' in summary                       # the chunked path ran
