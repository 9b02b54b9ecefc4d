"""The experiment runner: identical numbers whatever the engine, workers or chunking."""

import dataclasses
import json
import re

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.core.errors import ConfigError, DataUnavailable
from radioloc.core.rng import block_seed
from radioloc.experiments.base import Experiment, get_experiment, registry
from radioloc.experiments.runner import block_ranges, run_blocks

runner = CliRunner()
EXP = "gn-multilateration"


def small_config(runs=300, block=100):
    exp = get_experiment(EXP)
    return exp, dataclasses.replace(exp.config(False), runs=runs, block_size=block,
                                    range_std_m=(1.0, 10.0))


def test_block_ranges_cover_every_run_once():
    blocks = block_ranges(1001, 100)
    assert len(blocks) == 11 and blocks[-1].tolist() == [1000]
    np.testing.assert_array_equal(np.concatenate(blocks), np.arange(1001))


def test_block_seed_is_the_spawned_child():
    child = np.random.SeedSequence(5).spawn(4)[3]
    assert np.array_equal(block_seed(5, 3).generate_state(4), child.generate_state(4))


def test_local_processes_equal_in_process():
    exp, cfg = small_config()
    a = run_blocks(exp, cfg, seed=11, workers=1, progress=False)
    b = run_blocks(exp, cfg, seed=11, workers=2, progress=False)
    pd.testing.assert_frame_equal(a, b)


def test_dask_local_cluster_equals_in_process():
    distributed = pytest.importorskip("dask.distributed")
    exp, cfg = small_config()
    a = run_blocks(exp, cfg, seed=4, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:
        b = run_blocks(exp, cfg, seed=4, scheduler=cluster.scheduler_address, progress=False)
    pd.testing.assert_frame_equal(a, b)


def test_more_runs_extend_fewer_runs_by_whole_blocks():
    """Block b draws the same numbers whatever the total: runs=200 is a prefix of runs=250."""
    exp, cfg = small_config(runs=250)
    a = run_blocks(exp, cfg, seed=2, progress=False)
    b = run_blocks(exp, dataclasses.replace(cfg, runs=200), seed=2, progress=False)
    pd.testing.assert_frame_equal(a[a.run < 200].reset_index(drop=True), b)


def test_different_seeds_differ():
    exp, cfg = small_config(runs=50)
    a = run_blocks(exp, cfg, seed=1, progress=False)
    b = run_blocks(exp, cfg, seed=2, progress=False)
    assert not np.allclose(a.error_m, b.error_m)


def test_reproduce_writes_results_summary_and_figures(tmp_path):
    res = runner.invoke(app, ["reproduce", EXP, "--runs", "200", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    d = tmp_path / EXP
    summary = json.loads((d / "summary.json").read_text())
    assert {"experiment", "paper", "seed", "runs", "full", "elapsed_s", "metrics",
            "claims"} <= set(summary)
    assert summary["runs"] == 200 and summary["full"] is False
    for m in summary["metrics"]:
        assert set(m) == {"name", "value", "paper", "unit", "note", "ci_low", "ci_high",
                          "predicted"}
        assert isinstance(m["value"], float)
    for c in summary["claims"]:
        assert {"claim", "holds", "verdict", "estimate", "ci_low", "ci_high", "n"} <= set(c)
        assert c["verdict"] in ("holds", "does not hold", "undecided at this size")
    assert len(pd.read_csv(d / "results.csv")) == 200 * 6
    assert list(d.glob("*.png"))


def test_reproduce_with_two_workers_writes_the_same_csv(tmp_path):
    args = ["reproduce", EXP, "--runs", "2500", "--seed", "9"]
    assert runner.invoke(app, [*args, "--out", str(tmp_path / "a")]).exit_code == 0
    assert runner.invoke(app, [*args, "--out", str(tmp_path / "b"), "--workers", "2"]).exit_code == 0
    assert (tmp_path / "a" / EXP / "results.csv").read_bytes() == \
           (tmp_path / "b" / EXP / "results.csv").read_bytes()


def test_unknown_experiment_and_bad_runs_are_one_line_errors(tmp_path):
    res = runner.invoke(app, ["reproduce", "nope", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "unknown experiment 'nope'" in res.output
    res = runner.invoke(app, ["reproduce", EXP, "--runs", "0", "--out", str(tmp_path)])
    assert res.exit_code == 2 and "--runs" in res.output


def test_list_shows_every_experiment():
    res = runner.invoke(app, ["list"])
    assert res.exit_code == 0
    for eid in registry():
        assert eid[:12] in res.output


def test_experiment_with_absent_data_is_skipped(tmp_path, monkeypatch):
    monkeypatch.setenv("RADIOLOC_DATA", str(tmp_path / "nowhere"))

    class NeedsData(Experiment):
        id = "needs-data"
        data_folder = "some-set"

    with pytest.raises(DataUnavailable, match="skipped, data set folder .*some-set.* is absent"):
        NeedsData().check_available()


def test_runs_must_be_positive():
    exp = get_experiment(EXP)
    with pytest.raises(ConfigError, match="--runs"):
        exp.with_runs(exp.config(False), 0)


def test_timing_columns_go_to_timings_csv_not_results(tmp_path):
    from radioloc.experiments.runner import write_results

    class Timed(Experiment):
        id = "timed"
        timing_columns = ("cpu_s",)

    frame = pd.DataFrame({"run": [0, 1], "method": ["a", "b"], "error_m": [0.5, 0.7],
                          "cpu_s": [1e-3, 2e-3]})
    write_results(Timed(), frame, tmp_path)
    assert list(pd.read_csv(tmp_path / "results.csv").columns) == ["run", "method", "error_m"]
    assert list(pd.read_csv(tmp_path / "timings.csv").columns) == ["run", "method", "cpu_s"]


def test_reproduce_prints_a_line_per_experiment_when_not_a_terminal(tmp_path):
    """Output to a file or a pipe: where the run is and how long each experiment took."""
    res = runner.invoke(app, ["reproduce", EXP, "--runs", "100", "--out", str(tmp_path)])
    assert res.exit_code == 0, res.output
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith(f"[1/1] {EXP}")]
    assert lines[0] == f"[1/1] {EXP}: running (quick size)"
    assert re.fullmatch(rf"\[1/1\] {EXP}: done in \d+\.\d s \(elapsed \d+\.\d s\)", lines[1])


def test_summary_names_the_settings_a_run_changed(tmp_path):
    res = runner.invoke(app, ["reproduce", EXP, "--runs", "100", "--out", str(tmp_path),
                              "-o", "side_m=50"])
    assert res.exit_code == 0, res.output
    summary = json.loads((tmp_path / EXP / "summary.json").read_text())
    assert summary["changed"] == ["side_m=50.0"]
    res = runner.invoke(app, ["reproduce", EXP, "--runs", "100", "--out", str(tmp_path)])
    assert json.loads((tmp_path / EXP / "summary.json").read_text())["changed"] == []
