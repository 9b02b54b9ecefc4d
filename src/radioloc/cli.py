"""The command line: ``radioloc list | reproduce | locate``."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.console import Console
from rich.table import Table

from radioloc.cli_datasets import datasets_app
from radioloc.core.errors import DataUnavailable, RadiolocError
from radioloc.report.tables import wide_console

app = typer.Typer(
    help="radioloc: locate and track radio nodes from ranges and signal strength, and "
         "reproduce the published results of the papers it implements.",
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False)
console = wide_console()
err_console = Console(stderr=True)
app.add_typer(datasets_app, name="datasets")


def _fail(exc: Exception) -> None:
    err_console.print(f"[bold red]error:[/bold red] {exc}", highlight=False, soft_wrap=True)
    raise typer.Exit(code=2)


@app.command("list")
def list_experiments() -> None:
    """List the experiments: id, paper, and what each reproduces."""
    from radioloc.experiments.base import registry

    table = Table("id", "paper", "description", "data set", title="radioloc experiments",
                  title_justify="left")
    for eid, exp in registry().items():
        table.add_row(eid, exp.paper, exp.description, exp.data_folder or "")
    console.print(table)


@app.command()
def reproduce(
    experiment: Annotated[str, typer.Argument(help="Experiment id (see `radioloc list`) or 'all'.")],
    full: Annotated[bool, typer.Option("--full", help="Run at the paper's size instead of the quick size.")] = False,
    runs: Annotated[Optional[int], typer.Option(help="Number of Monte Carlo runs (overrides the size's default).")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the experiment's SeedSequence.")] = 0,
    out: Annotated[Path, typer.Option(help="Output folder; each experiment writes OUT/<id>/.")] = Path("out"),
    workers: Annotated[int, typer.Option(help="Local worker processes (1 = in this process).")] = 1,
    scheduler: Annotated[Optional[str], typer.Option(help="Dask scheduler address (tcp://host:port) to run the blocks on a cluster.")] = None,
) -> None:
    """Run an experiment (or all) and print our numbers beside the paper's.

    Writes OUT/<id>/results.csv (tidy), OUT/<id>/summary.json and OUT/<id>/*.png; with
    'all', also OUT/index.html, one page with every experiment's table and figures.
    The numbers do not depend on --workers or --scheduler.
    """
    from radioloc.experiments.base import get_experiment, registry
    from radioloc.experiments.runner import run_experiment, write_skipped
    from radioloc.report.html import write_index
    from radioloc.report.tables import print_record

    try:
        ids = list(registry()) if experiment == "all" else [get_experiment(experiment).id]
        for eid in ids:
            try:
                outcome = run_experiment(eid, full=full, runs=runs, seed=seed, out=out,
                                         workers=workers, scheduler=scheduler)
                print_record(outcome.record, console)
            except DataUnavailable as exc:
                print_record(write_skipped(get_experiment(eid), str(exc), full=full, seed=seed,
                                           out=out), console)
        if experiment == "all":
            index = write_index(out, {k: v.description for k, v in registry().items()})
            console.print(f"report: {index}")
    except RadiolocError as exc:
        _fail(exc)


@app.command()
def locate(
    measurements: Annotated[Path, typer.Argument(help="Measurements CSV: time, node, peer, kind, value.")],
    anchors: Annotated[Optional[Path], typer.Option(help="Anchors CSV: id, x, y[, z].")] = None,
    method: Annotated[str, typer.Option(help="Estimator; see `radioloc methods`.")] = "gn",
    out: Annotated[Optional[Path], typer.Option(help="Output CSV (default: standard output).")] = None,
    priors: Annotated[Optional[Path], typer.Option(help="Priors CSV for methods that use one (see `radioloc methods`).")] = None,
    calibration: Annotated[Optional[Path], typer.Option(help="Calibration file for methods that use one.")] = None,
    option: Annotated[Optional[list[str]], typer.Option("--option", "-o", help="Method option key=value (repeatable).")] = None,
) -> None:
    """Apply an estimator to your own measurement log.

    Output: CSV with time, node, x, y and, where the method has one, uncertainty_m
    (square root of the trace of the position covariance, metres).
    """
    from radioloc.io.logs import read_anchors, read_measurements, write_estimates
    from radioloc.locate.base import LocateRequest, run_method

    try:
        opts: dict[str, str] = {}
        for item in option or []:
            if "=" not in item:
                raise RadiolocError(f"--option {item!r}: expected key=value")
            k, v = item.split("=", 1)
            opts[k.strip()] = v.strip()
        anchor_table = read_anchors(anchors) if anchors is not None else None
        meas = read_measurements(measurements, anchors=anchor_table)
        request = LocateRequest(meas, anchor_table, priors, calibration, opts)
        write_estimates(run_method(method, request), out)
    except RadiolocError as exc:
        _fail(exc)
    if out is not None:
        err_console.print(f"wrote {out}")


@app.command("methods")
def list_methods() -> None:
    """List the estimators available to `radioloc locate`."""
    from radioloc.locate.base import methods

    table = Table("method", "what it does", title="radioloc locate methods", title_justify="left")
    for name, m in methods().items():
        table.add_row(name, m.summary)
    console.print(table)


def main() -> None:  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
