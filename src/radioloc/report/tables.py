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


#: A relative gap is shown only while ours and the paper's number are within this factor of
#: each other (and of the same sign); beyond it the two numbers speak for themselves.
GAP_FACTOR = 10.0


def gap_is_meaningful(value: float | None, paper: float | None) -> bool:
    """True when the relative gap of ``value`` to ``paper`` says something: both finite,
    of the same sign, the paper's not zero, and within :data:`GAP_FACTOR` of each other."""
    if value is None or paper is None or paper == 0:
        return False
    v, p = float(value), float(paper)
    return math.isfinite(v) and v * p > 0 and 1 / GAP_FACTOR <= v / p <= GAP_FACTOR


def relative_gap(value: float | None, paper: float | None) -> str:
    """``+12%`` style difference of ours against the paper (``""`` where the gap is not
    meaningful, see :func:`gap_is_meaningful`)."""
    if not gap_is_meaningful(value, paper):
        return ""
    return f"{100.0 * (value - paper) / abs(paper):+.0f}%"


#: What the report shows in place of a gap where the paper predicts the departure.
PREDICTED = "diverges, as the paper predicts"


def metric_gap(metric: dict[str, Any]) -> str:
    """The gap column of one metric record: :data:`PREDICTED` where the record says the paper
    predicts the departure (``predicted``), else :func:`relative_gap`."""
    if metric.get("predicted"):
        return PREDICTED
    return relative_gap(metric.get("value"), metric.get("paper"))


def interval(low: float | None, high: float | None) -> str:
    """``[low, high]`` of a confidence interval (``""`` when it has no ends)."""
    if low is None or high is None:
        return ""
    return f"[{fmt(low)}, {fmt(high)}]"


def verdict(claim: dict[str, Any]) -> str:
    """The verdict of one claim record: ``holds``, ``does not hold`` or ``undecided at this
    size`` (a record without ``verdict`` reads its ``holds``)."""
    if "verdict" in claim:
        return str(claim["verdict"])
    return "holds" if claim["holds"] else "does not hold"


def claim_evidence(claim: dict[str, Any]) -> str:
    """What decided a claim: ``mean paired difference 0.22 m, 95% CI [0.05, 0.39], n = 40``
    (``n``: runs, or the units a run holds where the experiment pairs on them; ``""`` for a
    claim without an interval)."""
    if claim.get("ci_low") is None and claim.get("estimate") is None:
        return ""
    unit = f" {claim['unit']}" if claim.get("unit") else ""
    est = claim.get("estimate")
    level = float(claim.get("level") or 0.95)
    ci = interval(claim.get("ci_low"), claim.get("ci_high")) or "none (fewer than 2 runs)"
    return (f"{claim.get('what') or 'mean'} {'-' if est is None else fmt(est)}{unit}, "
            f"{level:.0%} CI {ci}, n = {claim.get('n', 0)}")


def summary_table(record: dict[str, Any]) -> Table:
    """A rich table of one experiment's ``summary.json`` record."""
    t = Table(title=f"{record['experiment']} (paper {record['paper']}, "
                    f"{record['runs']} runs, {record['elapsed_s']:.1f} s)", title_justify="left")
    t.add_column("metric", no_wrap=True)
    for col in ("ours", "95% CI", "paper", "gap"):
        t.add_column(col, justify="right", no_wrap=True)
    t.add_column("unit", no_wrap=True)
    t.add_column("note", overflow="fold", min_width=30)
    for m in record["metrics"]:
        t.add_row(m["name"], fmt(m["value"]), interval(m.get("ci_low"), m.get("ci_high")),
                  fmt(m["paper"]), metric_gap(m),
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
    colour = {"holds": "green", "does not hold": "red"}
    for c in record["claims"]:
        v = verdict(c)
        mark = f"[{colour.get(v, 'yellow')}]{v}[/{colour.get(v, 'yellow')}]"
        why = claim_evidence(c)
        console.print(f"  claim: {c['claim']} -> {mark}" + (f" ({why})" if why else ""))
    for n in record.get("notes", []):
        console.print(f"  [dim]note: {n}[/dim]")
