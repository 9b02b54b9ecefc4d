"""Atomic outputs: a file is the complete new version or the old one; a `reproduce` folder
holds one complete run or nothing, whatever point an interruption hits."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import radioloc.core.atomic as atomic
import radioloc.experiments.base as exp_base
import radioloc.experiments.runner as runner_mod
from radioloc.core.atomic import STAGING, atomic_open, atomic_write_text, staged_folder
from radioloc.core.errors import DataUnavailable, OutputError
from radioloc.experiments.base import Claim, Experiment, Metric, Summary
from radioloc.experiments.runner import run_experiment, write_skipped
from reliability_helpers import assert_one_line_error, invoke


# ---- files --------------------------------------------------------------------------

def test_atomic_write_replaces_the_whole_file(tmp_path):
    p = tmp_path / "a.txt"
    atomic_write_text(p, "old\n")
    atomic_write_text(p, "new\n")
    assert p.read_text() == "new\n"
    assert sorted(x.name for x in tmp_path.iterdir()) == ["a.txt"]


@pytest.mark.parametrize("exc", [KeyboardInterrupt, RuntimeError])
def test_interrupted_file_write_keeps_the_previous_file(tmp_path, exc):
    p = tmp_path / "a.csv"
    p.write_text("complete,old\n")
    with pytest.raises(exc):
        with atomic_open(p) as fh:
            fh.write("half of the new")
            raise exc()
    assert p.read_text() == "complete,old\n"
    assert [x.name for x in tmp_path.iterdir()] == ["a.csv"]  # no temporary left


def test_interrupted_first_write_leaves_nothing(tmp_path):
    p = tmp_path / "sub" / "a.csv"
    with pytest.raises(KeyboardInterrupt):
        with atomic_open(p) as fh:
            fh.write("x")
            raise KeyboardInterrupt
    assert not p.exists() and list(p.parent.iterdir()) == []


def test_output_errors_name_the_path_and_reason(tmp_path):
    (tmp_path / "f").write_text("a file")
    with pytest.raises(OutputError, match="is a folder"):
        atomic_write_text(tmp_path, "x")
    with pytest.raises(OutputError, match="is a file, not a folder"):
        atomic_write_text(tmp_path / "f" / "x.csv", "x")


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="no /dev/full")
def test_full_device_is_an_output_error_and_is_not_replaced():
    with pytest.raises(OutputError, match="no space left"):
        atomic_write_text("/dev/full", "x" * 100_000)
    assert not Path("/dev/full").is_file()  # still the device, not a regular file


def test_special_files_are_written_in_place():
    atomic_write_text("/dev/null", "discarded")
    assert not Path("/dev/null").is_file()


# ---- folders ------------------------------------------------------------------------

def _snapshot(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())} if folder.exists() else {}


def test_staged_folder_swaps_in_a_complete_folder(tmp_path):
    target = tmp_path / "exp"
    with staged_folder(target) as stage:
        (stage / "a").write_text("1")
        assert not target.exists()
    assert _snapshot(target) == {"a": b"1"}
    with staged_folder(target) as stage:
        (stage / "b").write_text("2")
        assert _snapshot(target) == {"a": b"1"}  # old run intact while the new one is written
    assert _snapshot(target) == {"b": b"2"}      # nothing of the old run survives
    assert sorted(p.name for p in tmp_path.iterdir()) == ["exp"]


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "two-renames"])
def test_interrupted_folder_keeps_previous_run(tmp_path, monkeypatch, exchange):
    if not exchange:
        monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)
    target = tmp_path / "exp"
    with staged_folder(target) as stage:
        (stage / "a").write_text("1")
    with pytest.raises(KeyboardInterrupt):
        with staged_folder(target) as stage:
            (stage / "a").write_text("half")
            raise KeyboardInterrupt
    assert _snapshot(target) == {"a": b"1"}
    assert not (tmp_path / STAGING).exists()


def test_stale_staging_of_a_dead_process_is_removed(tmp_path):
    stale = tmp_path / STAGING / "exp-999999999-deadbeef"
    stale.mkdir(parents=True)
    (stale / "results.csv").write_text("partial")
    with staged_folder(tmp_path / "exp") as stage:
        (stage / "a").write_text("1")
    assert not stale.exists() and not (tmp_path / STAGING).exists()


def test_staging_folder_is_not_seen_as_an_experiment(tmp_path):
    """write_index globs OUT/*/summary.json: staging lives one level deeper."""
    with staged_folder(tmp_path / "exp") as stage:
        (stage / "summary.json").write_text("{}")
        assert list(tmp_path.glob("*/summary.json")) == []


def test_folder_target_that_is_a_file_is_refused(tmp_path):
    (tmp_path / "exp").write_text("not a folder")
    with pytest.raises(OutputError, match="is a file, not a folder"):
        with staged_folder(tmp_path / "exp"):
            pass


# ---- reproduce with a fake experiment: every interruption point ---------------------

@dataclasses.dataclass
class FakeConfig:
    runs: int = 4
    block_size: int = 2


class Fake(Experiment):
    id = "fake-reliability"
    paper = "-"
    description = "fake experiment for the atomic-output tests"

    def config(self, full):
        return FakeConfig()

    def run_block(self, config, runs, rng):
        return pd.DataFrame({"run": runs, "error_m": rng.random(len(runs))})

    def summarize(self, config, results, out_dir):
        (out_dir / "fig.png").write_bytes(b"png " + str(len(results)).encode())
        return Summary([Metric("mean error", float(results.error_m.mean()), unit="m")],
                       [Claim("it runs", True)], [])


@pytest.fixture
def fake(monkeypatch):
    exp = Fake()
    monkeypatch.setitem(exp_base._REGISTRY, exp.id, exp)
    return exp


def _complete(folder: Path) -> bool:
    s = json.loads((folder / "summary.json").read_text())
    r = pd.read_csv(folder / "results.csv")
    return len(r) == s["runs"] and (folder / "fig.png").exists()


class Boom(KeyboardInterrupt):
    pass


def _interrupt_run_block(monkeypatch, exp):
    calls = {"n": 0}
    orig = Fake.run_block

    def run_block(self, config, runs, rng):
        calls["n"] += 1
        if calls["n"] == 2:
            raise Boom
        return orig(self, config, runs, rng)
    monkeypatch.setattr(Fake, "run_block", run_block)


def _interrupt_summarize(monkeypatch, exp):
    orig = Fake.summarize

    def summarize(self, config, results, out_dir):
        orig(self, config, results, out_dir)   # a new figure is written, then Ctrl-C
        raise Boom
    monkeypatch.setattr(Fake, "summarize", summarize)


def _interrupt_results_csv(monkeypatch, exp):
    def to_csv(self, f, **kw):
        f.write("run,error_m\n")               # the header only, then Ctrl-C
        raise Boom
    monkeypatch.setattr(pd.DataFrame, "to_csv", to_csv)


def _interrupt_summary_json(monkeypatch, exp):
    def write_summary(record, out_dir):
        (Path(out_dir) / "summary.json").write_text('{"experiment": ')
        raise Boom
    monkeypatch.setattr(runner_mod, "write_summary", write_summary)


def _interrupt_swap(monkeypatch, exp):
    def exchange(a, b):
        raise Boom
    real = os.replace

    def replace(a, b):
        if Path(b).name == exp.id:              # first run: just before the move
            raise Boom
        real(a, b)
    monkeypatch.setattr(atomic, "_exchange", exchange)
    monkeypatch.setattr(atomic.os, "replace", replace)


def _interrupt_between_renames(monkeypatch, exp):
    monkeypatch.setattr(atomic, "_exchange", lambda a, b: False)
    real = os.replace

    def replace(a, b):
        if Path(b).name == exp.id:              # the old run moved away, the new not yet in
            raise Boom
        real(a, b)
    monkeypatch.setattr(atomic.os, "replace", replace)


INTERRUPTIONS = {
    "run_block": _interrupt_run_block,
    "summarize": _interrupt_summarize,
    "results.csv": _interrupt_results_csv,
    "summary.json": _interrupt_summary_json,
    "swap": _interrupt_swap,
    "between renames": _interrupt_between_renames,
}


@pytest.mark.parametrize("point", sorted(INTERRUPTIONS))
@pytest.mark.parametrize("previous", [True, False], ids=["after-a-run", "first-run"])
def test_interrupted_reproduce_leaves_previous_run_or_nothing(tmp_path, monkeypatch, fake,
                                                               point, previous):
    out = tmp_path / "out"
    folder = out / fake.id
    if previous:
        run_experiment(fake.id, runs=6, seed=1, out=out, progress=False)
        assert _complete(folder)
    before = _snapshot(folder)
    INTERRUPTIONS[point](monkeypatch, fake)
    with pytest.raises(Boom):
        run_experiment(fake.id, runs=4, seed=2, out=out, progress=False)
    after = _snapshot(folder)
    if point == "between renames":
        assert after in ({}, before)           # nothing, or the previous run
    else:
        assert after == before                 # the previous complete run, byte for byte
    if after:
        assert _complete(folder)
    monkeypatch.undo()
    exp_base._REGISTRY[fake.id] = fake
    run_experiment(fake.id, runs=4, seed=2, out=out, progress=False)  # next run cleans up
    assert _complete(folder) and json.loads((folder / "summary.json").read_text())["runs"] == 4
    assert sorted(p.name for p in out.iterdir()) == [fake.id]
    del exp_base._REGISTRY[fake.id]


def test_a_new_run_replaces_every_file_of_the_old_one(tmp_path, fake, monkeypatch):
    out = tmp_path / "out"
    run_experiment(fake.id, runs=4, out=out, progress=False)
    (out / fake.id / "stale_figure.png").write_bytes(b"from an older version")
    run_experiment(fake.id, runs=4, out=out, progress=False)
    assert sorted(p.name for p in (out / fake.id).iterdir()) == ["fig.png", "results.csv",
                                                                 "summary.json"]


def test_skipped_experiment_replaces_the_folder(tmp_path, fake):
    out = tmp_path / "out"
    run_experiment(fake.id, runs=4, out=out, progress=False)
    write_skipped(fake, "data absent", full=False, seed=0, out=out)
    assert sorted(p.name for p in (out / fake.id).iterdir()) == ["summary.json"]
    assert json.loads((out / fake.id / "summary.json").read_text())["skipped"] == "data absent"


def test_reproduce_cli_out_errors_are_one_line(tmp_path, fake):
    f = tmp_path / "file"
    f.write_text("x")
    line = assert_one_line_error(invoke(["reproduce", fake.id, "--out", f]))
    assert "is a file, not a folder" in line
    line = assert_one_line_error(invoke(["reproduce", fake.id, "--out", f / "sub"]))
    assert "is a file, not a folder" in line
    res = invoke(["reproduce", fake.id, "--out", tmp_path / "ok"])
    assert res.exit_code == 0, res.output
    assert _complete(tmp_path / "ok" / fake.id)
