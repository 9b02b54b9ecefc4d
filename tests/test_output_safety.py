"""Outputs that cannot destroy data: an output naming an input or another output is refused,
a write-protected file is refused, per-node files have distinct reversible names, temporary
files of a killed write are removed by the next write, and CSV text cells never start a
spreadsheet formula. Each refusal leaves every previous file as it was."""

from __future__ import annotations

import itertools
import os
import shutil
import signal
import stat
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import pandas as pd
import pytest

from radioloc.core.atomic import atomic_write_text, check_outputs
from radioloc.core.errors import OutputError
from radioloc.io.logs import (read_anchors, read_measurements, spreadsheet_cell,
                              spreadsheet_text, write_estimates)
from reliability_helpers import assert_one_line_error, invoke

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


@pytest.fixture
def folder(tmp_path):
    """The example log and anchors copied into a fresh folder."""
    for name in ("measurements.csv", "anchors.csv"):
        shutil.copy(EXAMPLES / name, tmp_path / name)
    return tmp_path


def snapshot(folder: Path) -> dict[str, tuple[bytes, int]]:
    """Every file of ``folder`` (hidden ones too): content and permission bits."""
    return {p.name: (p.read_bytes(), stat.S_IMODE(p.lstat().st_mode))
            for p in sorted(folder.iterdir()) if p.is_file()}


def locate(folder: Path, *args, meas: str = "measurements.csv"):
    return invoke(["locate", folder / meas, "--anchors", folder / "anchors.csv", "--quiet",
                   *args])


def rename_nodes(folder: Path, names: dict[str, str], to: str = "renamed.csv") -> str:
    meas = pd.read_csv(folder / "measurements.csv", dtype=str)
    meas["node"] = meas["node"].map(names)
    meas.to_csv(folder / to, index=False)
    return to


# ---- an output that names an input or another output ----------------------------------

@pytest.mark.parametrize("target", ["measurements.csv", "anchors.csv", "reference.csv"])
def test_out_naming_an_input_is_refused_and_the_input_kept(folder, target):
    (folder / "reference.csv").write_text("time,node,x,y\n0.0,tag1,10.0,12.0\n")
    before = snapshot(folder)
    line = assert_one_line_error(locate(folder, "--reference", folder / "reference.csv",
                                        "--out", folder / target))
    assert f"--out {folder / target}: is also" in line
    assert snapshot(folder) == before


@pytest.mark.parametrize("link", [os.link, os.symlink])
def test_out_reaching_an_input_through_a_link_is_refused(folder, link):
    link(folder / "anchors.csv", folder / "alias.csv")
    before = snapshot(folder)
    assert "is also --anchors" in assert_one_line_error(
        locate(folder, "--out", folder / "alias.csv"))
    assert snapshot(folder) == before


def test_plot_naming_out_is_refused(folder):
    (folder / "r.html").write_text("previous estimates")
    before = snapshot(folder)
    line = assert_one_line_error(locate(folder, "--out", folder / "r.html",
                                        "--plot", folder / "r.html"))
    assert "--plot" in line and "is also --out" in line
    assert snapshot(folder) == before


def test_summary_naming_an_input_is_refused(folder):
    """``--out a.csv`` writes ``a.summary.json``: an input of that name is kept."""
    shutil.copy(folder / "anchors.csv", folder / "a.summary.json")
    before = snapshot(folder)
    args = ["locate", folder / "measurements.csv", "--anchors", folder / "a.summary.json",
            "--out", folder / "a.csv"]
    assert "the summary" in assert_one_line_error(invoke(args))
    assert snapshot(folder) == before


def test_a_per_node_file_naming_an_input_is_refused_before_any_is_written(folder):
    """TUM writes ``t.<node>.tum`` per node: one of them is the measurements file."""
    shutil.copy(folder / "measurements.csv", folder / "t.tag2.tum")
    before = snapshot(folder)
    line = assert_one_line_error(invoke(["locate", folder / "t.tag2.tum", "--anchors",
                                         folder / "anchors.csv", "--out", folder / "t.tum"]))
    assert f"--out {folder / 't.tag2.tum'}: is also the measurements file" in line
    assert snapshot(folder) == before


def test_calibrate_out_naming_the_survey_is_refused(folder):
    before = snapshot(folder)
    line = assert_one_line_error(invoke(["calibrate", folder / "measurements.csv", "--anchors",
                                         folder / "anchors.csv", "--out",
                                         folder / "anchors.csv"]))
    assert "is also --anchors" in line
    assert snapshot(folder) == before


def test_check_outputs_skips_standard_output_and_devices(tmp_path):
    check_outputs([("--out", None), ("--out", "-"), ("--plot", "/dev/null")],
                  [("input", "/dev/null")])
    with pytest.raises(OutputError, match="is also --out"):
        check_outputs([("--out", tmp_path / "a"), ("--plot", tmp_path / "." / "a")])


# ---- a write-protected file ------------------------------------------------------------

@pytest.mark.parametrize("which", ["out", "summary", "plot"])
def test_write_protected_output_is_refused_not_replaced(folder, which):
    target = folder / {"out": "r.csv", "summary": "r.summary.json", "plot": "r.svg"}[which]
    target.write_text("kept")
    target.chmod(0o444)
    before = snapshot(folder)
    line = assert_one_line_error(locate(folder, "--out", folder / "r.csv",
                                        "--plot", folder / "r.svg"))
    assert f"{target}: cannot write (the file is write-protected" in line
    assert snapshot(folder) == before


def test_write_protected_file_is_refused_by_every_atomic_write(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("kept")
    p.chmod(0o400)
    with pytest.raises(OutputError, match="write-protected"):
        atomic_write_text(p, "new")
    assert p.read_text() == "kept" and stat.S_IMODE(p.stat().st_mode) == 0o400


# ---- one file per node: distinct, reversible names --------------------------------------

def test_tum_names_are_distinct_and_give_the_node_back(folder):
    nodes = {"tag1": "a b", "tag2": "a_b"}
    meas = rename_nodes(folder, nodes)
    res = locate(folder, "--method", "gn", "--out", folder / "t.tum", meas=meas)
    assert res.exit_code == 0, res.output
    written = sorted(p.name for p in folder.glob("t.*.tum"))
    assert len(written) == 2
    got = {unquote(name[len("t."):-len(".tum")]) for name in written}
    assert got == set(nodes.values())
    est = pd.read_csv(pd.io.common.StringIO(locate(folder, meas=meas).stdout),
                      dtype={"node": str})
    for name in written:
        rows = np.loadtxt(folder / name, ndmin=2)
        node = unquote(name[len("t."):-len(".tum")])
        np.testing.assert_array_equal(rows[:, :3], est[est.node == node][["time", "x", "y"]])


def test_nodes_that_differ_in_case_only_are_refused(folder):
    meas = rename_nodes(folder, {"tag1": "Tag", "tag2": "tag"})
    (folder / "t.tag.tum").write_text("previous trajectory\n")
    before = snapshot(folder)
    line = assert_one_line_error(locate(folder, "--out", folder / "t.tum", meas=meas))
    assert "'Tag' and 'tag'" in line and "case" in line
    assert snapshot(folder) == before


# ---- temporary files of a killed write ---------------------------------------------------

KILLED_WRITE = """
import os, signal, sys
from radioloc.core.atomic import atomic_open
with atomic_open(sys.argv[1]) as fh:
    fh.write("half of the new")
    fh.flush()
    os.kill(os.getpid(), signal.SIGKILL)
"""


def test_temporary_file_of_a_killed_write_is_removed_by_the_next_run(folder):
    (folder / "old.csv").write_text("complete,old\n")
    proc = subprocess.run([sys.executable, "-c", KILLED_WRITE, str(folder / "old.csv")],
                          capture_output=True)
    assert proc.returncode == -signal.SIGKILL
    stale = [p.name for p in folder.iterdir() if p.name.startswith(".old.csv.tmp-")]
    assert len(stale) == 1 and (folder / stale[0]).read_text() == "half of the new"
    # a temporary file of a live process (this one) is not touched
    live = folder / f".x.csv.tmp-{os.getpid()}-0123abcd"
    live.write_text("being written")
    before = {k: v for k, v in snapshot(folder).items() if k != stale[0]}
    res = locate(folder, "--out", folder / "new.csv")
    assert res.exit_code == 0, res.output
    after = snapshot(folder)
    assert stale[0] not in after
    assert {k: after[k] for k in before} == before
    assert after["old.csv"][0] == b"complete,old\n"


# ---- spreadsheet formulas -----------------------------------------------------------------

FORMULA_IDS = ["=cmd|' /C calc'!A0", "+1+1", "-2+3", "@SUM(A1)", "'=A1", "''+x"]


KEPT = ["-5", "+1e3", "a=b", "tag", "'a"]


@pytest.mark.parametrize("text", FORMULA_IDS + KEPT + ["-"])
def test_spreadsheet_escape_is_reversible_and_never_starts_a_formula(text):
    """A formula gets one apostrophe; numbers and other text are written as they are."""
    cell = spreadsheet_cell(text)
    assert spreadsheet_text(cell) == text
    assert cell == (text if text in KEPT else "'" + text)


def test_locate_csv_cells_do_not_start_formulas_and_read_back(folder):
    names = dict(zip(["tag1", "tag2"], FORMULA_IDS[:2]))
    meas = rename_nodes(folder, names)
    res = locate(folder, "--out", folder / "f.csv", meas=meas)
    assert res.exit_code == 0, res.output
    raw = pd.read_csv(folder / "f.csv", dtype=str, keep_default_na=False)
    assert not raw["node"].str.match(r"[=+\-@]").any()
    assert set(raw["node"]) == {"'" + n for n in names.values()}
    # the reference reader takes the escape off: the estimates score against themselves
    res = locate(folder, "--reference", folder / "f.csv", meas=meas)
    assert res.exit_code == 0, res.output
    assert "RMSE 0 m" in res.output


def test_calibrate_writes_formula_ids_escaped_and_locate_reads_them(tmp_path):
    ids = ["=A", "+B", "-C", "@D"]
    xy = np.array([[0.0, 0.0], [20.0, 0.0], [20.0, 15.0], [0.0, 15.0]])
    pd.DataFrame({"id": ids, "x": xy[:, 0], "y": xy[:, 1] + [0, 0, 0, 0.5],
                  "std_m": ["", "", "", 1.0]}).to_csv(tmp_path / "a.csv", index=False)
    rows = [(0.0, ids[i], ids[j], "range", float(np.linalg.norm(xy[i] - xy[j])))
            for i, j in itertools.combinations(range(4), 2)]
    pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"]).to_csv(
        tmp_path / "m.csv", index=False)
    res = invoke(["calibrate", tmp_path / "m.csv", "--anchors", tmp_path / "a.csv", "--out",
                  tmp_path / "cal.csv"])
    assert res.exit_code == 0, res.output
    raw = pd.read_csv(tmp_path / "cal.csv", dtype=str)
    assert list(raw["id"]) == ["'" + i for i in ids]
    cal = read_anchors(tmp_path / "cal.csv")
    assert list(cal["id"]) == ids
    np.testing.assert_allclose(cal[["x", "y"]].to_numpy(), xy, atol=0.05)


def test_measurement_ids_written_and_read_back_are_the_same(tmp_path):
    frame = pd.DataFrame({"time": [0.0, 0.0], "node": ["=x", "'=x"], "x": [1.0, 2.0]})
    write_estimates(frame, tmp_path / "e.csv")
    text = (tmp_path / "e.csv").read_text()
    assert ",'=x," in text and ",''=x," in text
    meas = tmp_path / "m.csv"
    meas.write_text("time,node,peer,kind,value\n0,'=x,A,range,1\n0,''=x,A,range,2\n")
    assert list(read_measurements(meas)["node"]) == ["=x", "'=x"]


def test_a_written_log_reads_back_with_its_formula_ids(tmp_path):
    """Measurements.write escapes every text column, the tdoa reference included."""
    from radioloc.io.measurements import Measurements

    m = Measurements.from_arrays(time=[0.0, 0.0], node="@tag", peer=["=A1", "+A2"],
                                 kind="tdoa", value=[1.0, -2.0], reference="-A0")
    m.write(tmp_path / "log.csv")
    back = Measurements.read(tmp_path / "log.csv").to_frame()
    pd.testing.assert_frame_equal(back, m.to_frame(), check_dtype=False)
