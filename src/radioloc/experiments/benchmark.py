"""``radioloc benchmark``: every fixed-anchor method on every log at hand, with defaults, scored.

The logs: simulated scenes with known truth (:func:`radioloc.sim.faulty_logs.walk_log`: ranges,
time differences and angles, clean and with gross errors in 8 % of the rows), and the real
data sets found (:func:`radioloc.io.datasets.data_roots`): each circle of each WiFi RTT venue
and the Hanyang UWB runs (as exported by ``radioloc datasets export``). Each method that reads
a log's kinds runs on it with its defaults, through :func:`radioloc.locate.base.run_method`
(so the health check runs too); a refusal is a result, recorded with its message.

Scores against the truth: RMSE, median, third quartile (the indoor competitions' score), the
mean of the median and the 95th percentile (the smartphone GNSS challenge's score), p95, max,
the share of errors inside the 95 % ellipse, the CPU time, and the health check's findings.
One CSV table and one self-contained HTML page (the table and the error CDFs of each log).
"""

from __future__ import annotations

import base64
import html
import io
import tempfile
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import pandas as pd

from radioloc.core.errors import DataUnavailable, RadiolocError

__all__ = ["BenchmarkLog", "benchmark_logs", "run_benchmark", "write_page", "METHODS"]

#: The methods benchmarked (fixed anchors, no priors), with the kinds each reads.
METHODS = {"gn": ("range",), "lsq": ("range", "tdoa", "aoa"), "ekf-track": ("range", "tdoa", "aoa"),
           "smoother": ("range", "tdoa", "aoa"), "pf": ("range",), "localml": ("range",),
           "ransac": ("range",)}


@dataclass(frozen=True)
class BenchmarkLog:
    """One log: its name, how it is loaded, and whether it is simulated."""

    name: str
    load: Callable[[], tuple[pd.DataFrame, pd.DataFrame, pd.DataFrame]]
    simulated: bool


def _simulated() -> list[BenchmarkLog]:
    from radioloc.sim.faulty_logs import walk_log

    out = []
    for kind in ("range", "tdoa", "aoa"):
        for fault in ("clean", "spikes") if kind != "aoa" else ("clean",):
            def load(kind=kind, fault=fault):
                log = walk_log(fault, 0, kind=kind)
                return log.measurements, log.anchors, log.reference
            out.append(BenchmarkLog(f"sim {kind} {fault}", load, True))
    return out


def _exported(export, **options) -> Callable:
    from radioloc.io.logs import read_anchors, read_measurements, read_reference

    def load():
        with tempfile.TemporaryDirectory() as tmp:
            paths = export(tmp, **options)
            anchors = read_anchors(paths["anchors"])
            return (read_measurements(paths["measurements"], anchors=anchors), anchors,
                    read_reference(paths["reference"]))
    return load


def _real(quick: bool) -> list[BenchmarkLog]:
    from radioloc.io import datasets
    from radioloc.io.wifi_rtt import VENUES, circles

    out = []
    try:
        root = datasets.require("wifi-rtt-haiyaoyu")
    except (DataUnavailable, RadiolocError):
        root = None
    if root is not None:
        for venue in VENUES:
            for circle in circles(root, venue)[: 1 if quick else None]:
                out.append(BenchmarkLog(f"wifi-rtt {venue} {circle}",
                                        _exported(datasets.export_wifi_rtt, venue=venue,
                                                  circle=circle), False))
    try:
        datasets.require("hanyang-uwb-outdoor")
    except (DataUnavailable, RadiolocError):
        return out
    for run in ("LOS/A/1",) if quick else ("LOS/A/1", "NLOS/A/1"):
        out.append(BenchmarkLog(f"hanyang {run}", _exported(datasets.export_hanyang, run=run),
                                False))
    return out


def benchmark_logs(real: bool = True, quick: bool = False) -> list[BenchmarkLog]:
    """The simulated scenes, and the real logs found (``quick``: one circle per venue, one
    Hanyang run)."""
    return _simulated() + (_real(quick) if real else [])


def _scores(out: pd.DataFrame, reference: pd.DataFrame) -> dict:
    from radioloc.locate.scoring import reference_errors

    err = reference_errors(out, reference)
    e = err["error_m"].to_numpy(dtype=float)
    med, p95 = float(np.median(e)), float(np.percentile(e, 95))
    return {"rows_scored": int(e.size), "rmse_m": float(np.sqrt(np.mean(e ** 2))),
            "median_m": med, "p75_m": float(np.percentile(e, 75)), "p50_p95_m": (med + p95) / 2,
            "p95_m": p95, "max_m": float(e.max()),
            "inside_95": float(err["inside_95"].mean()) if err["inside_95"].notna().any()
            else float("nan")}, e


def run_benchmark(logs: list[BenchmarkLog], methods: list[str] | None = None,
                  progress: Callable[[str], None] | None = None
                  ) -> tuple[pd.DataFrame, dict[str, dict[str, np.ndarray]]]:
    """Every method of :data:`METHODS` (or ``methods``) that reads a log's kinds, on each log.

    Returns
    -------
    table : DataFrame
        One row per (log, method): the scores (NaN when refused), ``cpu_s``, ``warnings``,
        ``findings`` (of the health check), ``message`` (the refusal or first warning).
    errors : dict
        ``errors[log][method]``: the errors of each row scored (for the CDFs).
    """
    from radioloc.locate.base import LocateRequest, run_method

    rows, errors = [], {}
    for log in logs:
        meas, anchors, reference = log.load()
        kinds = set(meas["kind"])
        errors[log.name] = {}
        for method in methods or list(METHODS):
            if method not in METHODS or not kinds <= set(METHODS[method]):
                continue
            if progress is not None:
                progress(f"{log.name}: {method}")
            record = {"log": log.name, "simulated": log.simulated, "method": method}
            start = time.process_time()
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    out = run_method(method, LocateRequest(meas.copy(), anchors.copy()))
                except RadiolocError as exc:
                    out, record["message"] = None, f"refused: {exc}"
            record["cpu_s"] = time.process_time() - start
            record["warnings"] = len(caught)
            if out is not None:
                scores, e = _scores(out, reference)
                record.update(scores)
                record["findings"] = len(out.attrs["summary"].get("health", {}).get("findings", []))
                record["message"] = str(caught[0].message) if caught else ""
                errors[log.name][method] = e
            rows.append(record)
    return pd.DataFrame(rows), errors


def _cdf_png(errors: dict[str, np.ndarray], title: str) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.4))
    for method, e in sorted(errors.items()):
        x = np.sort(e)
        ax.plot(x, np.arange(1, x.size + 1) / x.size, label=method)
    ax.set_xscale("log")
    ax.set_xlabel("error (m)")
    ax.set_ylabel("share of rows")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    buf = io.BytesIO()
    fig.tight_layout()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode()


def write_page(table: pd.DataFrame, errors: dict, path: Path | str) -> Path:
    """One self-contained HTML page: the table and each log's error CDFs."""
    path = Path(path)
    shown = table.copy()
    for c in shown.columns:
        if shown[c].dtype.kind == "f":
            shown[c] = shown[c].map(lambda v: "" if not np.isfinite(v) else f"{v:.3g}")
    shown["message"] = shown.get("message", "").map(lambda m: str(m)[:160])
    parts = ["<!doctype html><meta charset='utf-8'><title>radioloc benchmark</title>",
             "<style>body{font-family:sans-serif;margin:1.5em}table{border-collapse:collapse;"
             "font-size:12px}td,th{border:1px solid #ccc;padding:2px 6px}</style>",
             "<h1>radioloc benchmark</h1>",
             "<p>Every method with its defaults on every log at hand, scored against the truth: "
             "RMSE, median, third quartile (p75), mean of the median and the 95th percentile "
             "(p50_p95), p95, max (metres), the share of errors inside the claimed 95 % ellipse, "
             "CPU seconds, warnings and health-check findings.</p>",
             shown.to_html(index=False, escape=True)]
    for log, by_method in errors.items():
        if by_method:
            parts.append(f"<h2>{html.escape(log)}</h2><img alt='error CDF' "
                         f"src='data:image/png;base64,{_cdf_png(by_method, log)}'>")
    from radioloc.core.atomic import atomic_write_with

    text = "\n".join(parts) + "\n"
    atomic_write_with(path, lambda f: f.write(text))
    return path
