"""Running an experiment: blocks of runs, in-process, in local processes or on Dask.

The runs ``0..N-1`` are cut into blocks of ``config.block_size``; block ``b`` draws from
:func:`radioloc.core.rng.block_generator` ``(seed, b)``. Blocks run in this process, in a
pool of local processes (``workers > 1``) or on a Dask cluster (``scheduler``), and their
frames are concatenated in block order, so ``results.csv`` is the same byte for byte
whatever the engine and the number of workers.

Output folders are all or nothing: every file of a run (``results.csv``, ``timings.csv``,
the figures, ``summary.json``) is written into a staging folder beside ``OUT/<id>``
(:func:`radioloc.core.atomic.staged_folder`), which replaces ``OUT/<id>`` as a whole once
the run is complete. An interruption at any point (Ctrl-C, an error, a full disk) leaves
``OUT/<id>`` holding the previous complete run, or nothing if there was none.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from radioloc.core.atomic import atomic_write_text, atomic_write_with, staged_folder
from radioloc.core.errors import ConfigError
from radioloc.core.parallel import completed
from radioloc.core.rng import block_generator
from radioloc.experiments.base import Experiment, Summary, get_experiment


@dataclass
class RunOutcome:
    """What :func:`run_experiment` produced."""

    experiment: Experiment
    config: Any
    results: pd.DataFrame
    summary: Summary
    record: dict[str, Any]
    out_dir: Path


def block_ranges(n_runs: int, block_size: int) -> list[np.ndarray]:
    """Run indices of each block: ``[0..B-1], [B..2B-1], ...`` (last one shorter)."""
    if block_size < 1:
        raise ConfigError(f"block_size: must be >= 1, got {block_size}")
    n_blocks = math.ceil(n_runs / block_size)
    return [np.arange(b * block_size, min((b + 1) * block_size, n_runs)) for b in range(n_blocks)]


def run_block(exp_id: str, config: Any, seed: int, block: int, runs: np.ndarray) -> pd.DataFrame:
    """Run one block of one experiment (a top-level function so that it pickles)."""
    exp = get_experiment(exp_id)
    frame = exp.run_block(config, runs, block_generator(seed, block))
    if not isinstance(frame, pd.DataFrame):
        raise TypeError(f"{exp_id}.run_block must return a DataFrame, got {type(frame).__name__}")
    return frame


def run_blocks(exp: Experiment, config: Any, *, seed: int = 0, workers: int = 1,
               scheduler: str | None = None, progress: bool = True,
               label: str | None = None) -> pd.DataFrame:
    """Run every block of ``config.runs`` runs and concatenate the frames in block order.

    With ``progress``, a bar of the blocks (named ``label``, default the experiment's id) is
    drawn on a terminal while they run.
    """
    if workers < 1:
        raise ConfigError(f"--workers: must be >= 1, got {workers}")
    blocks = block_ranges(int(config.runs), int(config.block_size))
    frames: dict[int, pd.DataFrame] = {}
    stream = completed(run_block, [(exp.id, config, seed, b, r) for b, r in enumerate(blocks)],
                       workers, scheduler)
    if progress:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        with Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                      TextColumn("blocks"), TimeElapsedColumn(), transient=True) as bar:
            task = bar.add_task(label or exp.id, total=len(blocks))
            for b, frame in stream:
                frames[b] = frame
                bar.advance(task)
    else:
        frames = dict(stream)
    return pd.concat([frames[b] for b in range(len(blocks))], ignore_index=True)


def _jsonable(value: Any) -> Any:
    if dataclasses.is_dataclass(value):
        return {k: _jsonable(v) for k, v in dataclasses.asdict(value).items()}
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value


def run_experiment(exp_id: str, *, full: bool = False, runs: int | None = None, seed: int = 0,
                   out: Path | str = "out", workers: int = 1, scheduler: str | None = None,
                   progress: bool = True, options: dict[str, str] | None = None,
                   label: str | None = None) -> RunOutcome:
    """Run an experiment end to end and write ``out/<id>/{results.csv,summary.json,*.png}``.

    Raises :class:`~radioloc.core.errors.DataUnavailable` (before any work) when the
    experiment needs a data set that is absent. ``options`` overrides config fields by name
    (text read as each field's type, see :meth:`Experiment.with_options`); the config used
    is recorded in ``summary.json``. ``label`` names the progress bar (default: the id).
    """
    exp = get_experiment(exp_id)
    exp.check_available()
    config = exp.with_options(exp.with_runs(exp.config(full), runs), options)
    out_dir = Path(out) / exp.id
    with staged_folder(out_dir) as stage:
        t0 = time.perf_counter()
        results = run_blocks(exp, config, seed=seed, workers=workers, scheduler=scheduler,
                             progress=progress, label=label)
        summary = exp.summarize(config, results, stage)
        elapsed = time.perf_counter() - t0
        write_results(exp, results, stage)
        record = {
            "experiment": exp.id,
            "paper": exp.paper,
            "seed": int(seed),
            "runs": int(config.runs),
            "full": bool(full),
            "elapsed_s": round(elapsed, 3),
            "metrics": [m.as_dict() for m in summary.metrics],
            "claims": [c.as_dict() for c in summary.claims],
            "notes": list(summary.notes),
            "skipped": None,
            "config": _jsonable(config),
            "changed": changed_options(exp, config, full),
        }
        write_summary(record, stage)
    return RunOutcome(exp, config, results, summary, record, out_dir)


def changed_options(exp: Experiment, config: Any, full: bool) -> list[str]:
    """``field=value`` for each setting of ``config`` that differs from its size's default
    (besides ``runs``), so that the run's summary (and a docs snippet made from it) names
    what the run changed.

    Parameters
    ----------
    exp : Experiment
    config : dataclass
        The configuration the run used.
    full : bool
        The size whose default it is compared with.

    Returns
    -------
    list of str
    """
    base = json.loads(json.dumps(_jsonable(exp.config(bool(full))), default=str))
    used = json.loads(json.dumps(_jsonable(config), default=str))
    return [f"{k}={json.dumps(v)}" for k, v in used.items()
            if k != "runs" and k in base and base[k] != v]


def write_summary(record: dict, out_dir: Path) -> Path:
    """Write ``summary.json`` (atomically) into ``out_dir``.

    Parameters
    ----------
    record : dict
        The run's record (JSON-serialisable).
    out_dir : Path
        The folder.

    Returns
    -------
    Path
        The file written.
    """
    return atomic_write_text(Path(out_dir) / "summary.json", json.dumps(record, indent=2) + "\n")


def write_results(exp: Experiment, results: pd.DataFrame, out_dir: Path) -> None:
    """Write ``results.csv`` (reproducible) and, if the experiment measures CPU time,
    ``timings.csv`` (its timing columns beside the non-float identifying columns).

    Parameters
    ----------
    exp : Experiment
        The experiment (for its ``timing_columns``).
    results : DataFrame
        The concatenated frames of every block.
    out_dir : Path
        The folder; each file is written atomically.

    Returns
    -------
    None
    """
    timing = [c for c in exp.timing_columns if c in results.columns]
    frame = results.drop(columns=timing)
    atomic_write_with(Path(out_dir) / "results.csv", lambda f: frame.to_csv(f, index=False))
    if timing:
        ids = [c for c in results.columns
               if c not in timing and not pd.api.types.is_float_dtype(results[c])]
        atomic_write_with(Path(out_dir) / "timings.csv",
                          lambda f: results[ids + timing].to_csv(f, index=False))


def write_skipped(exp: Experiment, reason: str, *, full: bool, seed: int, out: Path | str) -> dict:
    """Write the ``summary.json`` of an experiment that was skipped (data absent).

    The folder ``OUT/<id>`` is replaced as a whole, like a run's: it then holds only this
    ``summary.json``, never a previous run's results beside a "skipped" summary.

    Parameters
    ----------
    exp : Experiment
        The skipped experiment.
    reason : str
        Why (the :class:`~radioloc.core.errors.DataUnavailable` message).
    full, seed : bool, int
        The command's options, recorded.
    out : path
        The output root.

    Returns
    -------
    dict
        The record written.
    """
    record = {"experiment": exp.id, "paper": exp.paper, "seed": int(seed), "runs": 0,
              "full": bool(full), "elapsed_s": 0.0, "metrics": [], "claims": [], "notes": [],
              "skipped": reason, "config": None}
    with staged_folder(Path(out) / exp.id) as stage:
        write_summary(record, stage)
    return record
