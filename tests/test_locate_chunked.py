"""``radioloc locate --chunk-rows``: a long log read, estimated and written in chunks gives
the estimates of the whole log at once (the rows, times and nodes exactly; the values to
1e-9 relative, gn's covariances rescaled to the pooled noise to 1e-12), refuses what the
whole run refuses, and gives way to the whole run where it cannot give its result."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.locate.chunked import merge_summaries

runner = CliRunner()
#: The log has a few epochs that hear three anchors on one line.
SKIP = ("-o", "on_degenerate=skip")
#: ekf-track at its fixed defaults (the settings learned from the log, tune=1, are learned in
#: a first pass: test_ekf_track_learns_in_a_first_pass_and_tracks_as_the_whole_run)
FIXED = ("-o", "tune=0")

ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 20.0], [0.0, 20.0], [15.0, 10.0]])


def _log(epochs: int = 150, tags: int = 3, seed: int = 0) -> pd.DataFrame:
    """Tags walking in the room, ranging to every anchor (a few rows missing) every 0.2 s,
    each tag at its own phase; sorted by time."""
    rng = np.random.default_rng(seed)
    rows = []
    for k in range(tags):
        start = rng.uniform([8, 6], [22, 14])
        heading = rng.uniform(0, 2 * np.pi)
        for e in range(epochs):
            t = round(0.2 * e + 0.013 * (k + 1), 6)
            p = start + 0.8 * t * np.array([np.cos(heading), np.sin(heading)]) / 10
            for a, xy in enumerate(ANCHORS):
                if rng.random() < 0.05:
                    continue
                r = float(np.linalg.norm(p - xy) + rng.normal(0, 0.1))
                rows.append((t, f"tag{k + 1}", f"A{a + 1}", "range", round(r, 4)))
    frame = pd.DataFrame(rows, columns=["time", "node", "peer", "kind", "value"])
    return frame.sort_values("time", kind="stable").reset_index(drop=True)


@pytest.fixture()
def files(tmp_path):
    meas = tmp_path / "m.csv"
    _log().to_csv(meas, index=False)
    anchors = tmp_path / "a.csv"
    pd.DataFrame({"id": [f"A{i + 1}" for i in range(len(ANCHORS))], "x": ANCHORS[:, 0],
                  "y": ANCHORS[:, 1]}).to_csv(anchors, index=False)
    return meas, anchors


def _run(meas, anchors, method, out, chunk_rows, *extra):
    res = runner.invoke(app, ["locate", str(meas), "--anchors", str(anchors), "--method",
                              method, "--out", str(out), "-q", "--chunk-rows",
                              str(chunk_rows), *extra])
    assert res.exit_code == 0, res.output
    summary = json.loads(out.with_name(out.stem + ".summary.json").read_text())
    table = pd.read_parquet(out) if out.suffix == ".parquet" else pd.read_csv(
        out, dtype={"node": str})
    return table, summary


def _assert_same(whole: pd.DataFrame, chunked: pd.DataFrame, rtol: float) -> None:
    assert list(chunked.columns) == list(whole.columns)
    assert len(chunked) == len(whole) > 0
    assert (chunked["node"].to_numpy() == whole["node"].to_numpy()).all()
    assert np.array_equal(chunked["time"].to_numpy(), whole["time"].to_numpy())
    for c in whole.columns.drop(["node", "time"]):
        np.testing.assert_allclose(chunked[c].to_numpy(float), whole[c].to_numpy(float),
                                   rtol=rtol, atol=1e-12, err_msg=c)


@pytest.mark.parametrize("method, chunk_rows, extra, rtol", [
    ("ekf-track", 97, FIXED, 1e-9), ("ekf-track", 7, FIXED + ("-o", "range_std_m=0.3"), 1e-9),
    ("lsq", 97, SKIP, 1e-9), ("gn", 500, SKIP, 1e-12)])
def test_chunked_run_equals_the_whole_run(files, tmp_path, method, chunk_rows, extra, rtol):
    """Chunks of 7 rows split the tracks' start windows and every epoch; their noise is
    stated wider than the log's, as a chunk's few rows are judged on their own by the health
    check (which inflates a covariance where they look noisier than stated)."""
    meas, anchors = files
    whole, s_whole = _run(meas, anchors, method, tmp_path / "whole.csv", 0, *extra)
    chunked, s_chunked = _run(meas, anchors, method, tmp_path / "chunked.csv", chunk_rows,
                              *extra)
    _assert_same(whole, chunked, rtol)
    assert "chunks" not in s_whole
    assert s_chunked["chunks"] >= 4            # the chunked path ran
    assert s_chunked["rows_read"] == s_whole["rows_read"]
    assert s_chunked["rows_out"] == s_whole["rows_out"] == len(whole)
    if method == "gn":                          # the noise pooled over every chunk
        assert s_chunked["std_m"] == pytest.approx(s_whole["std_m"], rel=1e-12)
        assert s_chunked["std_m_from"] == s_whole["std_m_from"]


def test_chunked_parquet_output_equals_the_whole_run(files, tmp_path):
    pytest.importorskip("pyarrow")
    meas, anchors = files
    whole, _ = _run(meas, anchors, "lsq", tmp_path / "whole.parquet", 0, *SKIP)
    chunked, summary = _run(meas, anchors, "lsq", tmp_path / "chunked.parquet", 200, *SKIP)
    assert summary["chunks"] > 1
    _assert_same(whole, chunked, 1e-9)


def test_chunked_parquet_input_equals_the_whole_run(files, tmp_path):
    pytest.importorskip("pyarrow")
    meas, anchors = files
    log = tmp_path / "m.parquet"
    pd.read_csv(meas, dtype={"node": str}).to_parquet(log, index=False)
    whole, _ = _run(log, anchors, "ekf-track", tmp_path / "whole.csv", 0, *FIXED)
    chunked, summary = _run(log, anchors, "ekf-track", tmp_path / "chunked.csv", 300, *FIXED)
    assert summary["chunks"] > 1
    _assert_same(whole, chunked, 1e-9)


@pytest.mark.parametrize("chunk_rows", [97, 1000])
def test_ekf_track_learns_in_a_first_pass_and_tracks_as_the_whole_run(files, tmp_path,
                                                                       chunk_rows):
    """The default ``tune=1``: the settings learned from each node's first steps in a first
    pass over the chunks equal the whole run's, and so do the tracks (to 1e-9); a chunk's
    health check may widen a covariance the whole log does not (never narrow it)."""
    meas, anchors = files
    whole, s_whole = _run(meas, anchors, "ekf-track", tmp_path / "whole.csv", 0)
    chunked, s_chunked = _run(meas, anchors, "ekf-track", tmp_path / "chunked.csv", chunk_rows)
    assert s_chunked["chunks"] > 1
    assert s_chunked["learned"] == s_whole["learned"]
    assert list(chunked.columns) == list(whole.columns) and len(chunked) == len(whole)
    np.testing.assert_allclose(chunked[["x", "y"]], whole[["x", "y"]], rtol=1e-9, atol=1e-12)
    for c in ("cov_xx", "cov_yy", "uncertainty_m"):
        assert (chunked[c] >= whole[c] * (1 - 1e-9)).all(), c


def test_rows_out_of_time_order_give_way_to_the_whole_run(files, tmp_path):
    """Rows that go back in time across chunks: the whole run is made (same output)."""
    meas, anchors = files
    log = pd.read_csv(meas, dtype={"node": str})
    shuffled = tmp_path / "shuffled.csv"
    log.sample(frac=1.0, random_state=1).to_csv(shuffled, index=False)
    whole, _ = _run(meas, anchors, "ekf-track", tmp_path / "whole.csv", 0, *FIXED)
    again, summary = _run(shuffled, anchors, "ekf-track", tmp_path / "again.csv", 97, *FIXED)
    assert "chunks" not in summary
    _assert_same(whole, again, 1e-9)


def test_a_bad_cell_in_a_late_chunk_is_refused_at_its_line_and_the_output_kept(files,
                                                                                tmp_path):
    meas, anchors = files
    lines = meas.read_text().splitlines()
    line = len(lines) - 5                          # file line (1-based) of a late row
    cells = lines[line - 1].split(",")
    cells[4] = "-7"
    lines[line - 1] = ",".join(cells)
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out.csv"
    out.write_text("previous\n")
    res = runner.invoke(app, ["locate", str(bad), "--anchors", str(anchors), "--method", "lsq",
                              "--out", str(out), "-q", "--chunk-rows", "97", *SKIP])
    assert res.exit_code == 2
    assert f"line {line}, column 'value': negative range" in res.output
    assert out.read_text() == "previous\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.csv", "bad.csv", "m.csv", "out.csv"]


def test_a_peer_is_known_by_a_node_of_a_later_chunk_and_refused_when_none(files, tmp_path):
    """A peer that is a node first seen in a later chunk is known (its ranges are left out
    by lsq, as in the whole run); one that is no node is refused at its first line."""
    meas, anchors = files
    log = pd.read_csv(meas, dtype={"node": str})
    late = log["node"].iloc[-1]
    early = log.index[(log["node"] != late)][3]
    log.loc[early, "peer"] = "later"
    log.loc[len(log) - 1, "node"] = "later"
    ok = tmp_path / "ok.csv"
    log.to_csv(ok, index=False)
    whole, _ = _run(ok, anchors, "lsq", tmp_path / "whole.csv", 0, *SKIP)
    chunked, summary = _run(ok, anchors, "lsq", tmp_path / "chunked.csv", 97, *SKIP)
    assert summary["chunks"] > 1
    _assert_same(whole, chunked, 1e-9)
    log.loc[len(log) - 1, "node"] = late
    bad = tmp_path / "bad.csv"
    log.to_csv(bad, index=False)
    res = runner.invoke(app, ["locate", str(bad), "--anchors", str(anchors), "--method", "lsq",
                              "--out", str(tmp_path / "x.csv"), "-q", "--chunk-rows", "97",
                              *SKIP])
    assert res.exit_code == 2
    assert f"line {early + 2}, column 'peer': unknown anchor or node 'later'" in res.output
    assert not (tmp_path / "x.csv").exists()


def test_merged_summary_sums_counts_and_keeps_the_largest_figure():
    merged = merge_summaries({"epochs": 3, "std_m": 0.1, "name": "a", "flag": True,
                              "by": {"x": 1}, "findings": [1]},
                             {"epochs": 4, "std_m": 0.3, "name": "b", "flag": False,
                              "by": {"x": 2, "y": 5}, "findings": [2]})
    assert merged == {"epochs": 7, "std_m": 0.3, "name": "a", "flag": True,
                      "by": {"x": 3, "y": 5}, "findings": [1, 2]}


@pytest.mark.parametrize("extra, chunked", [(("-o", "exclude_faults=1"), False),
                                            (("-o", "exclude_faults=1", "-o", "std_m=0.1"), True)])
def test_gn_fault_exclusion_runs_in_chunks_only_with_a_stated_noise(files, tmp_path, extra,
                                                                     chunked):
    """Without ``std_m`` the exclusion test's sigma comes from every fix of the log: the whole
    log is run at once."""
    meas, anchors = files
    whole, _ = _run(meas, anchors, "gn", tmp_path / "whole.csv", 0, *SKIP, *extra)
    again, summary = _run(meas, anchors, "gn", tmp_path / "again.csv", 500, *SKIP, *extra)
    assert ("chunks" in summary) == chunked
    _assert_same(whole, again, 1e-12)
