"""`radioloc locate --workers N` and `--scheduler` (radioloc.locate.fleet): a log's nodes spread
over processes or a Dask cluster give the estimates of one process, byte for byte."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pandas as pd
import pytest

from radioloc.core.errors import ConfigError
from radioloc.locate import LocateRequest, run_method
from radioloc.locate.fleet import locate_fleet, node_groups

ANCHORS = pd.DataFrame({"id": ["A", "B", "C", "D"], "x": [0.0, 10.0, 10.0, 0.0],
                        "y": [0.0, 0.0, 8.0, 8.0]})


def fleet_log(nodes: int = 7, seconds: float = 24.0, seed: int = 2) -> pd.DataFrame:
    """Tags on circles of different sizes, each heard for a different span."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, seconds, 0.2)
    rows = []
    for k in range(nodes):
        p = np.c_[5 + (1 + 0.3 * k) * np.cos(t / 5 + k), 4 + (1 + 0.3 * k) * np.sin(t / 5 + k)]
        d = np.linalg.norm(p[:, None] - ANCHORS[["x", "y"]].to_numpy()[None], axis=2)
        d += 0.1 * rng.standard_normal(d.shape)
        n = len(t) - 10 * k
        for j, aid in enumerate(ANCHORS["id"]):
            rows.append(pd.DataFrame({"time": t[:n], "node": f"tag{k}", "peer": aid,
                                      "kind": "range", "value": d[:n, j]}))
    return pd.concat(rows).sort_values(["time", "node"], kind="stable").reset_index(drop=True)


def test_nodes_are_dealt_into_groups_of_about_equal_rows():
    log = fleet_log()
    groups = node_groups(log, 3)
    assert sorted(n for g in groups for n in g) == sorted(log["node"].unique())
    rows = [int(log["node"].isin(g).sum()) for g in groups]
    assert max(rows) - min(rows) <= log.groupby("node").size().max()
    assert node_groups(log, 3) == groups                               # the same every time
    assert len(node_groups(log, 50)) == log["node"].nunique()         # a node to a group
    for g in groups:                                                   # in the log's order
        assert g == [n for n in log["node"].unique() if n in g]


@pytest.mark.parametrize("method, options, log_change, match", [
    ("pf", {}, None, "estimates its nodes together"),
    ("ekf-track", {"cooperative": "1"}, None, "cooperative=1"),
    ("ekf-track", {}, "peer", "node 'tag0' ranges to node 'tag1'"),
])
def test_what_cannot_run_apart_is_refused(method, options, log_change, match):
    log = fleet_log(nodes=2, seconds=4.0)
    if log_change == "peer":
        log.loc[log.index[0], ["node", "peer"]] = ["tag0", "tag1"]
    with pytest.raises(ConfigError, match=match):
        locate_fleet(method, LocateRequest(log, ANCHORS, options=options), workers=2)


@pytest.mark.slow   # subprocesses
@pytest.mark.parametrize("method", ["ekf-track", "lsq"])
def test_workers_write_the_bytes_of_one_process(tmp_path, method):
    fleet_log().to_csv(tmp_path / "log.csv", index=False)
    ANCHORS.to_csv(tmp_path / "anchors.csv", index=False)
    outs = []
    for extra in ([], ["--workers", "2"]):
        out = tmp_path / f"est{len(extra)}.csv"
        subprocess.run([sys.executable, "-m", "radioloc.cli", "locate", str(tmp_path / "log.csv"),
                        "--anchors", str(tmp_path / "anchors.csv"), "--method", method,
                        "--out", str(out), "-q", *extra],
                       check=True, timeout=300, capture_output=True)
        outs.append(out.read_bytes())
    assert outs[0] == outs[1] and len(outs[0]) > 1000


@pytest.mark.slow   # a Dask cluster
def test_a_dask_cluster_gives_the_estimates_of_one_process():
    distributed = pytest.importorskip("dask.distributed")
    log = fleet_log()
    one = run_method("ekf-track", LocateRequest(log.copy(), ANCHORS))
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        spread = locate_fleet("ekf-track", LocateRequest(log.copy(), ANCHORS), workers=2,
                              scheduler=cluster.scheduler_address)
    assert spread.to_csv(index=False) == one.to_csv(index=False)
    summary = spread.attrs["summary"]
    assert summary["fleet"]["groups"] == 7
    assert set(summary["learned"]) == set(one.attrs["summary"]["learned"])


def _parts(tmp_path, log: pd.DataFrame):
    """The log written in parts, partitioned by node (``node=ID/...parquet``)."""
    folder = tmp_path / "parts"
    log.to_parquet(folder, partition_cols=["node"], index=False)
    return folder


def test_a_log_in_parts_reads_as_its_rows_and_names_a_bad_part(tmp_path):
    from radioloc.core.errors import InputError
    from radioloc.io.logs import measurement_parts, read_measurements

    log = fleet_log(nodes=3, seconds=8.0)
    folder = _parts(tmp_path, log)
    parts = measurement_parts(folder)
    assert [node for _, node in parts] == ["tag0", "tag1", "tag2"]
    read = read_measurements(folder, anchors=ANCHORS)
    want = log.sort_values("node", kind="stable").reset_index(drop=True)
    pd.testing.assert_frame_equal(read[["time", "node", "peer", "kind", "value"]],
                                  want, check_dtype=False)
    bad = log[log["node"] == "tag1"].drop(columns="node").reset_index(drop=True)
    bad.loc[3, "peer"] = "Z"
    path = parts[1][0]
    bad.to_parquet(path, index=False)
    with pytest.raises(InputError, match=rf"{path.name}: line 5, column 'peer': unknown "
                                         r"anchor or node 'Z'"):
        read_measurements(folder, anchors=ANCHORS)
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"holds no \*\.parquet file"):
        measurement_parts(tmp_path / "empty")


@pytest.mark.slow   # subprocesses
def test_workers_read_a_log_in_parts_and_write_the_bytes_of_one_process(tmp_path):
    """Partitioned by node: each worker reads its nodes' parts; the output equals one
    process reading the whole folder, and the estimates of the log as one CSV file."""
    log = fleet_log()
    folder = _parts(tmp_path, log)
    log.sort_values("node", kind="stable").to_csv(tmp_path / "log.csv", index=False)
    ANCHORS.to_csv(tmp_path / "anchors.csv", index=False)
    outs = []
    for source, extra in ((folder, []), (folder, ["--workers", "2"]),
                          (tmp_path / "log.csv", [])):
        out = tmp_path / f"est{len(outs)}.csv"
        subprocess.run([sys.executable, "-m", "radioloc.cli", "locate", str(source),
                        "--anchors", str(tmp_path / "anchors.csv"), "--method", "lsq",
                        "--out", str(out), "-q", *extra],
                       check=True, timeout=300, capture_output=True)
        outs.append(out.read_bytes())
    assert outs[0] == outs[1] == outs[2] and len(outs[0]) > 1000
    import json
    summary = json.loads((tmp_path / "est1.summary.json").read_text())
    assert summary["rows_read"] == len(log) and summary["fleet"]["workers"] == 2
