"""The command line: ``radioloc list | reproduce | locate``.

Errors are one line on standard error, never a traceback or a usage box:

- ``error: ...``, exit code 2: the toolkit's own errors (:class:`RadiolocError`: bad input,
  configuration, geometry, output path) and command-line usage errors;
- ``internal error: ...``, exit code 3: anything else (a bug), with a request to report it;
  ``RADIOLOC_DEBUG=1`` prints the traceback as well;
- ``interrupted``, exit code 130: Ctrl-C.

Floating-point trouble never reaches the terminal as ``RuntimeWarning`` noise: inside
``locate`` a RuntimeWarning (overflow, invalid value, division by zero) is an error; other
warnings are printed as one ``warning: ...`` line each when the command succeeds (a failure
prints its error line only).
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading
import time
import traceback
import warnings
from pathlib import Path
from typing import Annotated, Any, Iterator, Optional


def _interrupted_while_importing(signum, frame):  # pragma: no cover - timing dependent
    """Ctrl-C during the imports below (a second or more on a loaded machine): nothing has
    been read or written yet, so end at once with the CLI's own one-line message."""
    sys.stderr.write("interrupted\n")
    sys.stderr.flush()
    os._exit(130)


# only in the `radioloc` console script: a program that imports this module keeps its own
# Ctrl-C; the script's handler is restored when the command line starts (OneLineErrors.main)
_SIGINT_BEFORE = None
if (threading.current_thread() is threading.main_thread()
        and os.path.basename(sys.argv[0] if sys.argv else "").startswith("radioloc")):
    _SIGINT_BEFORE = signal.signal(signal.SIGINT, _interrupted_while_importing)

import click  # noqa: E402
import typer
from rich.console import Console
from rich.table import Table
from typer.core import TyperGroup

from radioloc.cli_datasets import datasets_app
from radioloc.core.errors import DataUnavailable, RadiolocError
from radioloc.report.tables import wide_console

EXIT_ERROR = 2
EXIT_INTERNAL = 3
EXIT_INTERRUPTED = 130
EXIT_TERMINATED = 143
REPORT_HINT = ("this is a bug in radioloc: please report it with the command and its input "
               "files (RADIOLOC_DEBUG=1 shows the traceback)")


def _click_classes(name: str) -> tuple[type, ...]:
    """Exception class ``name`` of click and of the click that typer vendors (if any)."""
    classes = [getattr(click.exceptions, name, None)]
    try:
        from typer._click import exceptions as vendored
        classes.append(getattr(vendored, name, None))
    except ImportError:  # pragma: no cover - older typer uses click itself
        pass
    return tuple(c for c in dict.fromkeys(classes) if isinstance(c, type))


_NO_ARGS = _click_classes("NoArgsIsHelpError")
_CLICK_ERRORS = _click_classes("ClickException")
_ABORT = _click_classes("Abort") + (typer.Abort, KeyboardInterrupt)


def _one_line(text: object) -> str:
    return " ".join(str(text).split())


def _echo_err(text: str) -> None:
    click.echo(text, err=True)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where the program is, so that every clean-up of an interrupt runs
    (a staging folder removed, the previous results kept)."""


_TERM = {"received": False}


def _terminate(signum, frame):
    _TERM["received"] = True
    raise Terminated()


@contextlib.contextmanager
def _sigterm_as_interrupt() -> Iterator[None]:
    """Within the command, SIGTERM ends it as Ctrl-C does (main thread only)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _TERM["received"] = False
    before = signal.signal(signal.SIGTERM, _terminate)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


def _stopped() -> tuple[str, int]:
    """The message and exit code of a command stopped by a signal."""
    return ("terminated", EXIT_TERMINATED) if _TERM["received"] else ("interrupted",
                                                                       EXIT_INTERRUPTED)


class OneLineErrors(TyperGroup):
    """The top-level group: every failure of every (sub)command becomes one line."""

    def main(self, args: Any = None, prog_name: str | None = None,
             complete_var: str | None = None, standalone_mode: bool = True,
             **extra: Any) -> Any:
        global _SIGINT_BEFORE
        if _SIGINT_BEFORE is not None:   # Ctrl-C from here on: KeyboardInterrupt, below
            signal.signal(signal.SIGINT, _SIGINT_BEFORE)
            _SIGINT_BEFORE = None
        code = 0
        try:
            with _sigterm_as_interrupt(), _warnings_on_one_line() as held:
                rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
            for text in held:              # a failure prints its error line only
                _echo_err(text)
            code = rv if isinstance(rv, int) and not isinstance(rv, bool) else 0
            if code == EXIT_INTERRUPTED:  # typer turns KeyboardInterrupt into Exit(130)
                text, code = _stopped()
                _echo_err(text)
        except _NO_ARGS as exc:
            ctx = getattr(exc, "ctx", None)
            _echo_err(ctx.get_help() if ctx is not None else exc.format_message())
            code = EXIT_ERROR
        except _CLICK_ERRORS as exc:  # usage errors: bad option, missing argument
            ctx = getattr(exc, "ctx", None)
            cmd = ctx.command_path if ctx is not None else "radioloc"
            _echo_err(f"error: {_one_line(exc.format_message())} (see '{cmd} --help')")
            code = exc.exit_code
        except _ABORT:
            text, code = _stopped()
            _echo_err(text)
        except RadiolocError as exc:
            if os.environ.get("RADIOLOC_DEBUG") == "1":
                traceback.print_exc()
            _echo_err(f"error: {_one_line(exc)}")
            code = EXIT_ERROR
        except Exception as exc:  # noqa: BLE001 - the boundary: a bug, reported on one line
            if os.environ.get("RADIOLOC_DEBUG") == "1":
                traceback.print_exc()
            what = type(exc).__name__
            if isinstance(exc, (RuntimeWarning, FloatingPointError)):
                what = f"floating-point failure ({what})"
            _echo_err(f"internal error: {what}: {_one_line(exc)}; {REPORT_HINT}")
            code = EXIT_INTERNAL
        if not standalone_mode:
            return code
        sys.exit(code)


@contextlib.contextmanager
def _warnings_on_one_line() -> Iterator[list[str]]:
    """Collect warnings as ``warning: <message>`` lines (one line, once per message), to be
    printed when the command succeeds; a command that fails prints its one error line."""
    held: list[str] = []

    def show(message, category, filename, lineno, file=None, line=None):  # noqa: ARG001
        text = f"warning: {_one_line(message)}"
        if text not in held:
            held.append(text)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield held


@contextlib.contextmanager
def numeric_errors_raise() -> Iterator[None]:
    """Turn floating-point warnings (overflow, invalid, divide) into exceptions."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        yield


app = typer.Typer(
    help="radioloc: locate and track radio nodes from ranges and signal strength, and "
         "reproduce the published results of the papers it implements.",
    no_args_is_help=True, add_completion=False, pretty_exceptions_enable=False,
    cls=OneLineErrors)
console = wide_console()
err_console = Console(stderr=True)
app.add_typer(datasets_app, name="datasets")


def _parse_options(items: list[str] | None) -> dict[str, str]:
    """``-o key=value`` items as a dict; :class:`RadiolocError` on a malformed or repeated key."""
    opts: dict[str, str] = {}
    for item in items or []:
        k, sep, v = item.partition("=")
        if not sep or not k.strip():
            raise RadiolocError(f"--option {item!r}: expected key=value")
        if k.strip() in opts:
            raise RadiolocError(f"--option {k.strip()!r} given twice")
        opts[k.strip()] = v.strip()
    return opts


def _fail(exc: Exception) -> None:
    """Report ``exc`` as ``error: ...`` and exit 2 (kept for sub-commands that call it)."""
    _echo_err(f"error: {_one_line(exc)}")
    raise typer.Exit(code=EXIT_ERROR)


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
    option: Annotated[Optional[list[str]], typer.Option("--option", "-o", help="Config field key=value (repeatable; one experiment only; see `radioloc config ID`).")] = None,
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

    from radioloc.core.atomic import check_folder_path

    check_folder_path(out)
    opts = _parse_options(option)
    if opts and experiment == "all":
        raise RadiolocError("-o sets one experiment's config fields: name the experiment, not 'all'")
    ids = list(registry()) if experiment == "all" else [get_experiment(experiment).id]
    start = time.perf_counter()
    for i, eid in enumerate(ids, 1):
        label = f"[{i}/{len(ids)}] {eid}"
        # On a terminal the blocks' bar carries the label; otherwise (output to a file or a
        # pipe) one line when an experiment starts and one when it ends, with the times.
        if not err_console.is_terminal:
            err_console.print(f"{label}: running ({'full' if full else 'quick'} size)",
                              markup=False, highlight=False)
        t0 = time.perf_counter()
        try:
            outcome = run_experiment(eid, full=full, runs=runs, seed=seed, out=out,
                                     workers=workers, scheduler=scheduler, options=opts,
                                     label=label)
            record = outcome.record
        except DataUnavailable as exc:
            record = write_skipped(get_experiment(eid), str(exc), full=full, seed=seed, out=out)
        print_record(record, console)
        if not err_console.is_terminal:
            now = time.perf_counter()
            status = "skipped (data absent)" if record.get("skipped") else "done"
            err_console.print(f"{label}: {status} in {now - t0:.1f} s "
                              f"(elapsed {now - start:.1f} s)", markup=False, highlight=False)
    if experiment == "all":
        index = write_index(out, {k: v.description for k, v in registry().items()})
        console.print(f"report: {index}")


@app.command("config")
def show_config(
    experiment: Annotated[str, typer.Argument(help="Experiment id (see `radioloc list`).")],
) -> None:
    """Show an experiment's config fields at the quick and the full size (set with -o)."""
    import dataclasses

    from radioloc.experiments.base import get_experiment

    exp = get_experiment(experiment)
    quick, full = exp.config(False), exp.config(True)
    table = Table("field", "quick", "full", title=f"{exp.id} config (reproduce {exp.id} -o field=value)",
                  title_justify="left")
    for f in dataclasses.fields(quick):
        table.add_row(f.name, repr(getattr(quick, f.name)), repr(getattr(full, f.name)))
    console.print(table)


@app.command()
def locate(
    measurements: Annotated[Path, typer.Argument(help="Measurements CSV or Parquet (time, node, peer, kind, value), or a folder of Parquet files (a log in parts, e.g. node=ID/*.parquet).")],
    anchors: Annotated[Optional[Path], typer.Option(help="Anchors CSV: id, x, y[, z].")] = None,
    method: Annotated[str, typer.Option(help="Estimator; see `radioloc methods`.")] = "gn",
    out: Annotated[Optional[Path], typer.Option(help="Output file (default: CSV on standard output); its format by --format or the suffix (.csv, .parquet, .tum, .geojson). A summary OUT-stem.summary.json is written beside it.")] = None,
    format: Annotated[Optional[str], typer.Option("--format", help="Output format: csv, parquet, tum (TUM trajectory: timestamp tx ty tz qx qy qz qw; one file per node), geojson (a LineString per node and a Point per row). Default: from the --out suffix, else csv.")] = None,
    priors: Annotated[Optional[Path], typer.Option(help="Priors CSV for methods that use one (see `radioloc methods`).")] = None,
    calibration: Annotated[Optional[Path], typer.Option(help="Calibration file for methods that use one.")] = None,
    option: Annotated[Optional[list[str]], typer.Option("--option", "-o", help="Method option key=value (repeatable).")] = None,
    smooth: Annotated[bool, typer.Option("--smooth", help="Offline log: smoothed track (the same as -o smooth=1; trackers only).")] = False,
    plot: Annotated[Optional[Path], typer.Option("--plot", help="Figure of the anchors, the tracks with 95 % uncertainty ellipses and the gated rows (.png, .svg or .pdf; .html: a self-contained page with the figure, the run summary and a section per node); with --reference also the error against time.")] = None,
    reference: Annotated[Optional[Path], typer.Option("--reference", help="Reference trajectory CSV: time[, node], x, y[, z][, frame] (e.g. reference.csv of `radioloc datasets export`): prints RMSE, median, p90 and the fraction of errors inside the 95 % ellipse, and adds them to the summary. An ECEF run is scored horizontally in the east-north-up frame at the reference's first point.")] = None,
    quiet: Annotated[bool, typer.Option("--quiet", "-q", help="No progress (on standard error: a bar when a run lasts more than 2 s, or, when standard error is not a terminal, a line per 10 s of work).")] = False,
    strict: Annotated[bool, typer.Option("--strict", help="Exit non-zero (1) when the run warns: a finding of the health check (summary.json, health) or any other warning; the outputs are written first.")] = False,
    follow: Annotated[bool, typer.Option("--follow", help="Live: read rows as they arrive (MEASUREMENTS '-' for standard input, a file that grows, or udp://HOST:PORT, CSV or JSON lines; serial://DEVICE, a DWM1001 module's lec output; mqtt://HOST[:PORT]/TOPIC, a broker's messages) and write each estimate at once (ekf-track); ends at end of input or Ctrl-C.")] = False,
    reorder_s: Annotated[Optional[float], typer.Option("--reorder-s", help="With --follow: rows up to this many seconds out of order are placed (default 0.5); older ones are counted and left out.")] = None,
    idle_s: Annotated[Optional[float], typer.Option("--idle-s", help="With --follow: also process the rows held once the input has been idle this many seconds (default: only once a later time has come); a row of a time processed so that comes after is late.")] = None,
    frame: Annotated[Optional[str], typer.Option("--frame", help="Frame of the anchors (and reference) coordinates when their file has no 'frame' column: local (default), ecef, or wgs84 (x longitude, y latitude in degrees, z height in m).")] = None,
    origin: Annotated[Optional[str], typer.Option("--origin", help="lat,lon[,h]: work and write in the east-north-up frame at this point (a local frame is then taken as that ENU frame; ecef or wgs84 anchors are converted to it).")] = None,
    workers: Annotated[int, typer.Option("--workers", min=1, help="ekf-track, smoother and lsq: estimate the nodes in this many local processes (the estimates are those of one process).")] = 1,
    scheduler: Annotated[Optional[str], typer.Option("--scheduler", help="ekf-track, smoother and lsq: estimate the nodes on the Dask cluster at this address (tcp://HOST:PORT; needs radioloc[cluster]).")] = None,
    chunk_rows: Annotated[int, typer.Option("--chunk-rows", min=0, help="ekf-track, lsq and gn on a long log (a CSV file sorted by time) written to --out (CSV or Parquet): read, estimate and write this many rows at a time, so that memory does not grow with the log (0: the whole log at once). The health and plausibility checks then judge each chunk on its own rows.")] = 200_000,
) -> None:
    """Apply an estimator to your own measurement log.

    Output: one row per (time, node), sorted by time then node: time, node, x, y[, z] and,
    where the method has them, uncertainty_m (square root of the trace of the position
    covariance, metres), the covariance columns cov_xx, cov_xy, cov_yy[, cov_xz, cov_yz,
    cov_zz] (m^2) and per-row flags (gated: ranges refused by the gate; restart: the track
    starts again after a gap; p_nlos: largest NLOS probability of the row's ranges). The
    same input and options always give the same output (the particle filter's seed is 0
    unless -o seed=N). Positions are in the working frame (see --frame, --origin); when it
    has a place on the Earth, the columns lat, lon, height (WGS84) follow, and GeoJSON is
    written in longitude, latitude (RFC 7946).
    """
    from radioloc.core.atomic import check_outputs
    from radioloc.io.logs import (read_anchors, read_measurements, read_reference,
                                  subtract_anchor_bias)
    from radioloc.locate.base import LocateRequest, run_method
    from radioloc.locate.export import output_files, output_format, with_geodetic, write_output
    from radioloc.locate.plot import check_plot_path, plot_locate
    from radioloc.locate.progress import show_progress
    from radioloc.locate.scoring import error_lines, error_summary, reference_errors

    fmt = output_format(out, format)
    if plot is not None:
        check_plot_path(plot)
    inputs = [("the measurements file", measurements), ("--anchors", anchors),
              ("--priors", priors), ("--calibration", calibration), ("--reference", reference)]
    summary_file = _summary_path(out)
    others = [("the summary", summary_file), ("--plot", plot)]
    check_outputs([("--out", out), *others], inputs)
    opts = _parse_options(option)
    if smooth:
        if opts.get("smooth", "1").lower() in ("0", "false", "no", "off"):
            raise RadiolocError("--smooth contradicts -o smooth=0")
        opts["smooth"] = "1"
    if follow:
        from radioloc.locate.follow import follow_locate

        with numeric_errors_raise():
            written = follow_locate(measurements, anchors, method, opts, out, fmt, reorder_s, {
                "--plot": plot, "--reference": reference, "--priors": priors,
                "--calibration": calibration, "--strict": strict, "--frame": frame,
                "--origin": origin, "--workers": workers if workers > 1 else None,
                "--scheduler": scheduler}, idle_s=idle_s)
        for path in written:
            _echo_err(f"wrote {path}")
        return
    with numeric_errors_raise():
        from radioloc.locate.frames import (declared_frame, horizontal_at_start,
                                            parse_origin, to_working, working_frame)

        anchor_table = read_anchors(anchors) if anchors is not None else None
        ref_table = read_reference(reference) if reference is not None else None
        declared = declared_frame(anchor_table, frame)
        work = working_frame(declared, parse_origin(origin))
        if fmt == "geojson" and not work.georeferenced:
            raise RadiolocError(f"--format geojson: GeoJSON is longitude and latitude (RFC "
                                f"7946), and {work.why_not_georeferenced()}")
        if anchor_table is not None:
            anchor_table = to_working(anchor_table, declared, work)
        if ref_table is not None:
            ref_table = to_working(ref_table, declared_frame(ref_table, declared, "reference"),
                                   work, "reference")
        nd = opts.get("not_detected")
        try:
            nd = None if nd is None else float(nd)
        except ValueError:
            raise RadiolocError(f"-o not_detected={nd!r}: expected a number") from None
        chunked = None
        fleet = workers > 1 or scheduler is not None
        parts = measurements.is_dir()           # a log in parts: a folder of Parquet files
        if chunk_rows and plot is None and reference is None and priors is None \
                and calibration is None and not fleet and not parts:
            from radioloc.locate.chunked import locate_in_chunks

            with show_progress(not quiet), warnings.catch_warnings(record=True) as warned:
                chunked = locate_in_chunks(method, measurements, anchor_table, opts, work, out,
                                           fmt, chunk_rows, nd)
        if chunked is None and fleet and parts:     # each worker reads its nodes' parts
            from radioloc.io.logs import measurement_parts
            from radioloc.locate.fleet import locate_fleet_parts

            request = LocateRequest(None, anchor_table, priors, calibration, opts, frame=work)
            with show_progress(not quiet), warnings.catch_warnings(record=True) as warned:
                estimates = locate_fleet_parts(method, measurement_parts(measurements),
                                               request, workers, scheduler, nd)
            rows_read = estimates.attrs["summary"].pop("rows_read")
        elif chunked is None:
            meas = subtract_anchor_bias(read_measurements(measurements, anchors=anchor_table,
                                                          not_detected=nd), anchor_table)
            request = LocateRequest(meas, anchor_table, priors, calibration, opts, frame=work)
            with show_progress(not quiet), warnings.catch_warnings(record=True) as warned:
                if fleet:
                    from radioloc.locate.fleet import locate_fleet

                    estimates = locate_fleet(method, request, workers, scheduler)
                else:
                    estimates = run_method(method, request)
            rows_read = len(meas)
        for w in warned:                    # shown as usual, counted for --strict
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if chunked is not None:
            _finish_locate({"method": method, "options": dict(sorted(opts.items())),
                            "measurements": str(measurements), **chunked}, summary_file,
                           [out], warned, strict)
            return
        estimates = with_geodetic(estimates, work)
        errors = None if ref_table is None else reference_errors(
            *horizontal_at_start(estimates, ref_table, work))
    to_stdout = out is None or str(out) == "-"
    files = output_files(list(estimates["node"].unique()), out, fmt)
    check_outputs([*(("--out", f) for f in files), *others], inputs)
    written = write_output(estimates, out, fmt, anchor_table, work)
    summary = {"method": method, "options": dict(sorted(opts.items())),
               "measurements": str(measurements), "rows_read": int(rows_read),
               "rows_out": int(len(estimates)), **estimates.attrs.get("summary", {})}
    if errors is not None:
        summary["reference"] = error_summary(errors, len(estimates))
        for line in error_lines(summary["reference"]):
            (_echo_err if to_stdout else console.print)(line, **({} if to_stdout else
                                                                {"markup": False,
                                                                 "highlight": False}))
    if plot is not None:
        plot_locate(estimates, plot, anchors=anchor_table, reference=ref_table, errors=errors,
                    title=f"radioloc locate --method {method}: {Path(measurements).name}",
                    summary=summary)
        written.append(plot)
    _finish_locate(summary, summary_file, written, warned, strict, plot is not None)


def _finish_locate(summary: dict, summary_file: Path | None, written: list, warned: list,
                   strict: bool, plotted: bool = False) -> None:
    """The end of ``locate``: the summary file written (before the figure in ``written``,
    the files written, listed), and ``--strict`` applied to the warnings."""
    import json

    if summary_file is not None:
        text = json.dumps(summary, indent=1, default=_json_default) + "\n"
        from radioloc.core.atomic import atomic_write_with

        atomic_write_with(summary_file, lambda f: f.write(text))
        written.insert(len(written) - plotted, summary_file)
    for path in written:
        _echo_err(f"wrote {path}")
    if strict and warned:
        raise RadiolocError(f"--strict: the run warned ({len(warned)} warning(s)); first: "
                            f"{_one_line(warned[0].message)}")


def _summary_path(out: Path | None) -> Path | None:
    """The run summary beside ``--out`` (``OUT-stem.summary.json``); None for standard
    output or a device such as /dev/stdout."""
    if out is None or str(out) == "-" or (out.exists() and not out.is_file()):
        return None
    return out.with_name(out.stem + ".summary.json")


def _json_default(value: Any) -> Any:
    """JSON for NumPy scalars in a locate summary."""
    import numpy as np

    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.bool_):
        return bool(value)
    raise TypeError(f"not JSON: {type(value).__name__}")


@app.command()
def calibrate(
    measurements: Annotated[Path, typer.Argument(help="Measurements CSV: anchor-to-anchor and/or tag range rows.")],
    anchors: Annotated[Path, typer.Option(help="Anchors CSV: id, x, y[, z], std_m (prior std of a rough anchor, m; empty or 0: surveyed).")],
    out: Annotated[Optional[Path], typer.Option(help="Calibrated anchors CSV (default: standard output).")] = None,
    std_m: Annotated[float, typer.Option(help="Standard deviation of a range, m.")] = 0.1,
    bias: Annotated[bool, typer.Option("--bias", help="Also estimate each anchor's range bias (antenna delay).")] = False,
    bias_prior_std_m: Annotated[float, typer.Option(help="Prior std of a bias around 0, m.")] = 1.0,
    loss: Annotated[str, typer.Option(help="linear, huber, soft_l1 or cauchy (robust to NLOS outliers).")] = "linear",
) -> None:
    """Estimate anchors' positions (and range biases) from the ranges of a log.

    Output: the anchors file with the estimates, their covariance and the Cramer-Rao bound
    (crb_std_m); `radioloc locate --anchors` reads it and subtracts bias_m from ranges.
    """
    from radioloc.core.atomic import check_outputs
    from radioloc.io.logs import read_anchors, read_measurements, write_estimates
    from radioloc.locate.calibrate import calibrate_log, calibration_table

    check_outputs([("--out", out)], [("the measurements file", measurements),
                                     ("--anchors", anchors)])
    with numeric_errors_raise():
        table = read_anchors(anchors)
        meas = read_measurements(measurements)
        result, counts = calibrate_log(meas, table, std_m=std_m, bias=bias,
                                       bias_prior_std_m=bias_prior_std_m, loss=loss)
    write_estimates(calibration_table(table, result), out)
    _echo_err(f"calibrated {counts['rough_anchors']} anchor(s) from {counts['anchor_ranges']} anchor-to-anchor and "
              f"{counts['tag_ranges']} tag range(s) ({counts['tag_epochs']} tag epochs); "
              f"range residual rms {result.residual_rms_m:.3g} m"
              + ("" if result.converged else "; the solver did not converge"))
    if out is not None and str(out) != "-":
        _echo_err(f"wrote {out}")


@app.command()
def benchmark(
    out: Annotated[Path, typer.Option(help="Output folder: benchmark.csv and benchmark.html.")] = Path("benchmark"),
    methods: Annotated[Optional[str], typer.Option(help="Comma-separated methods (default: every fixed-anchor method).")] = None,
    real: Annotated[bool, typer.Option("--real/--no-real", help="Also the real data sets found (RADIOLOC_DATA).")] = True,
    quick: Annotated[bool, typer.Option("--quick", help="One circle per WiFi RTT venue and one Hanyang run.")] = False,
) -> None:
    """Every method with its defaults on simulated scenes and the real data sets at hand,
    scored against the truth (RMSE, median, p75, (median + p95) / 2, p95, max, coverage of the
    95 % ellipse, CPU time, health-check findings): a table and an HTML page with error CDFs."""
    from radioloc.experiments.benchmark import benchmark_logs, run_benchmark, write_page

    out.mkdir(parents=True, exist_ok=True)
    chosen = None if methods is None else [m.strip() for m in methods.split(",") if m.strip()]
    table, errors = run_benchmark(benchmark_logs(real=real, quick=quick), chosen,
                                  progress=lambda text: _echo_err(f"benchmark: {text}"))
    table.to_csv(out / "benchmark.csv", index=False)
    write_page(table, errors, out / "benchmark.html")
    _echo_err(f"wrote {out / 'benchmark.csv'}")
    _echo_err(f"wrote {out / 'benchmark.html'}")


@app.command()
def view(
    estimates: Annotated[Path, typer.Argument(help="Estimates CSV (time, node, x, y[, cov_xx, cov_xy, cov_yy]), e.g. the --out of `radioloc locate --follow`, read as it grows.")],
    anchors: Annotated[Optional[Path], typer.Option(help="Anchors CSV to draw.")] = None,
    host: Annotated[str, typer.Option(help="Address to serve on.")] = "127.0.0.1",
    port: Annotated[int, typer.Option(help="Port (0: any free port; the address is printed).")] = 8765,
    poll_s: Annotated[float, typer.Option(help="Seconds between the page's requests for new rows.")] = 0.5,
) -> None:
    """A live view: a local web page drawing each node's track and the 95 % ellipse of its
    latest estimate as rows are appended to ESTIMATES; runs until Ctrl-C."""
    from radioloc.locate.live_view import serve

    with _sigterm_as_interrupt():
        serve(estimates, anchors, host, port, poll_s, announce=_echo_err)


@app.command("methods")
def list_methods() -> None:
    """List the estimators available to `radioloc locate`."""
    from radioloc.locate.base import methods

    table = Table("method", "kinds", "what it does", "options (-o key=value)",
                  title="radioloc locate methods", title_justify="left")
    for name, m in methods().items():
        opts = "" if m.options is None else "\n".join(
            f"{k}: {spec.describe()}" for k, spec in m.options.items()) or "none"
        kinds = "any" if m.kinds is None else "\n".join(m.kinds)
        table.add_row(name, kinds, m.summary, opts)
    console.print(table)


def main() -> None:  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
