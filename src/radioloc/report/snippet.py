"""A docs page's numbers as a markdown snippet generated from an experiment's ``summary.json``.

The docs pages include the snippet (``--8<-- "generated/<id>.md"``), so the numbers and
verdicts they show are those of a run of the current code, never typed by hand::

    radioloc reproduce p000-montecarlo --out out
    python -m radioloc.report.snippet out/p000-montecarlo/summary.json docs/generated/p000-montecarlo.md
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any

from radioloc.report.tables import claim_evidence, fmt, interval, verdict

#: First line of every snippet.
HEADER = "<!-- generated from summary.json by radioloc.report.snippet; do not edit -->"


def _cell(text: Any) -> str:
    """Text for a markdown table cell (a bar would end the cell)."""
    return str(text).replace("|", "\\|")


def docs_snippet(record: dict[str, Any]) -> str:
    """The markdown snippet of one ``summary.json`` record.

    Parameters
    ----------
    record : dict
        The parsed ``summary.json`` of a ``radioloc reproduce`` run.

    Returns
    -------
    str
        A header naming the run (experiment, runs, size, seed), the table of every metric
        (ours, its 95 % confidence interval over runs, the paper's value, unit, what it is)
        and every claim with its verdict and the interval that decided it.
    """
    size = "full" if record.get("full") else "quick"
    changed = list(record.get("changed") or [])   # written by the runner
    lines = [HEADER,
             f"Run: `{record['experiment']}`, {record['runs']} runs ({size} size), "
             f"seed {record['seed']}"
             + (f"; options: {', '.join(changed)}" if changed else "") + ".", ""]
    if record.get("skipped"):
        return "\n".join(lines + [f"Skipped: {record['skipped']}"]) + "\n"
    lines += ["| metric | ours | 95% CI | paper | unit | what |", "|---|---|---|---|---|---|"]
    for m in record["metrics"]:
        lines.append(f"| `{m['name']}` | {fmt(m['value'])} | "
                     f"{interval(m.get('ci_low'), m.get('ci_high')) or '-'} | {fmt(m['paper'])} | "
                     f"{_cell(m['unit'])} | {_cell(m['note'])} |")
    if record["claims"]:
        lines += ["", "Claims:", ""]
        for c in record["claims"]:
            why = claim_evidence(c)
            lines.append(f"- {c['claim']}: **{verdict(c)}**" + (f" ({why})" if why else ""))
    return "\n".join(lines) + "\n"


def write_docs_snippet(summary_json: Path | str, out_md: Path | str, render=None) -> Path:
    """Write the snippet of a ``summary.json`` file to ``out_md``.

    Parameters
    ----------
    summary_json : path
        ``OUT/<id>/summary.json``.
    out_md : path
        The snippet, e.g. ``docs/generated/p000-montecarlo.md``.
    render : callable, optional
        ``record -> markdown``; default :func:`docs_snippet` (an experiment with its own
        tables passes its writer).

    Returns
    -------
    Path
        ``out_md``.
    """
    record = json.loads(Path(summary_json).read_text())
    out = Path(out_md)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text((render or docs_snippet)(record))
    return out


if __name__ == "__main__":                      # python -m radioloc.report.snippet SUMMARY OUT_MD
    if len(sys.argv) != 3:
        sys.exit("usage: python -m radioloc.report.snippet SUMMARY_JSON OUT_MD")
    write_docs_snippet(sys.argv[1], sys.argv[2])
