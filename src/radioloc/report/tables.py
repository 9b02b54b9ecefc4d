"""Our numbers beside the paper's, on the console."""

from __future__ import annotations

import math
from typing import Any

from rich.console import Console
from rich.table import Table


def fmt(value: float | None) -> str:
    """Compact number formatting for tables (``-`` for missing)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    v = float(value)
    if v == 0:
        return "0"
    if abs(v) >= 1e4 or abs(v) < 1e-3:
        return f"{v:.3g}"
    return f"{v:.4g}" if abs(v) < 100 else f"{v:.1f}"


def relative_gap(value: float | None, paper: float | None) -> str:
    """``+12%`` style difference of ours against the paper."""
    if value is None or paper is None or paper == 0:
        return ""
    return f"{100.0 * (value - paper) / abs(paper):+.0f}%"


def summary_table(record: dict[str, Any]) -> Table:
    """A rich table of one experiment's ``summary.json`` record."""
    t = Table(title=f"{record['experiment']} (paper {record['paper']}, "
                    f"{record['runs']} runs, {record['elapsed_s']:.1f} s)", title_justify="left")
    t.add_column("metric", no_wrap=True)
    for col in ("ours", "paper", "gap"):
        t.add_column(col, justify="right", no_wrap=True)
    t.add_column("unit", no_wrap=True)
    t.add_column("note", overflow="fold", min_width=30)
    for m in record["metrics"]:
        t.add_row(m["name"], fmt(m["value"]), fmt(m["paper"]), relative_gap(m["value"], m["paper"]),
                  m["unit"], m["note"])
    return t


def wide_console() -> Console:
    """A console at least 150 columns wide when writing to a file or pipe, so that metric
    names are not folded in logs."""
    import sys

    return Console() if sys.stdout.isatty() else Console(width=150)


def print_record(record: dict[str, Any], console: Console | None = None) -> None:
    """Print the metrics table and the claims of one experiment."""
    console = console or wide_console()
    if record.get("skipped"):
        console.print(f"[yellow]{record['skipped']}[/yellow]")
        return
    console.print(summary_table(record))
    for c in record["claims"]:
        mark = "[green]holds[/green]" if c["holds"] else "[red]does not hold[/red]"
        console.print(f"  claim: {c['claim']} -> {mark}")
    for n in record.get("notes", []):
        console.print(f"  [dim]note: {n}[/dim]")
