"""The one-page HTML report of all experiments (``out/index.html``)."""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

from radioloc.report.tables import fmt, relative_gap

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,sans-serif;max-width:1100px;margin:2em auto;
padding:0 1em;color:#222;line-height:1.45}
h1{margin-bottom:.2em} h2{border-bottom:1px solid #ddd;padding-bottom:.2em;margin-top:2em}
table{border-collapse:collapse;margin:.8em 0;font-size:.92em}
th,td{border:1px solid #ddd;padding:.25em .6em;text-align:right} th{background:#f5f5f5}
td.l,th.l{text-align:left} .holds{color:#1a7f37} .fails{color:#b42318} .skip{color:#9a6700}
.figs{display:flex;flex-wrap:wrap;gap:12px} .figs img{max-width:100%;width:520px;border:1px solid #eee}
nav a{margin-right:1em} .meta{color:#666;font-size:.9em} .note{color:#555;font-size:.9em}
"""


def _experiment_section(record: dict[str, Any], out: Path, description: str) -> str:
    eid = html.escape(record["experiment"])
    parts = [f'<h2 id="{eid}">{eid}</h2>',
             f'<p>{html.escape(description)} <span class="meta">(paper {html.escape(str(record["paper"]))})</span></p>']
    if record.get("skipped"):
        parts.append(f'<p class="skip">Skipped: {html.escape(record["skipped"])}</p>')
        return "\n".join(parts)
    parts.append(f'<p class="meta">{record["runs"]} runs, seed {record["seed"]}, '
                 f'{"full" if record["full"] else "quick"} size, {record["elapsed_s"]:.1f} s</p>')
    rows = "".join(
        f'<tr><td class="l">{html.escape(m["name"])}</td><td>{fmt(m["value"])}</td>'
        f'<td>{fmt(m["paper"])}</td><td>{relative_gap(m["value"], m["paper"])}</td>'
        f'<td class="l">{html.escape(m["unit"])}</td><td class="l">{html.escape(m["note"])}</td></tr>'
        for m in record["metrics"])
    parts.append('<table><tr><th class="l">metric</th><th>ours</th><th>paper</th><th>gap</th>'
                 f'<th class="l">unit</th><th class="l">note</th></tr>{rows}</table>')
    if record["claims"]:
        items = "".join(
            f'<li class="{"holds" if c["holds"] else "fails"}">'
            f'{"holds" if c["holds"] else "does not hold"}: {html.escape(c["claim"])}</li>'
            for c in record["claims"])
        parts.append(f"<p><b>Claims of the paper, checked on our numbers</b></p><ul>{items}</ul>")
    if record.get("notes"):
        notes = "".join(f"<li>{html.escape(n)}</li>" for n in record["notes"])
        parts.append(f'<ul class="note">{notes}</ul>')
    figs = sorted((out / record["experiment"]).glob("*.png"))
    if figs:
        imgs = "".join(f'<a href="{html.escape(str(f.relative_to(out)))}"><img src="{html.escape(str(f.relative_to(out)))}" '
                       f'alt="{html.escape(f.stem)}"></a>' for f in figs)
        parts.append(f'<div class="figs">{imgs}</div>')
    return "\n".join(parts)


def write_index(out: Path | str, descriptions: dict[str, str]) -> Path:
    """Write ``out/index.html`` from every ``out/<id>/summary.json`` it finds."""
    out = Path(out)
    records = []
    for path in sorted(out.glob("*/summary.json")):
        records.append(json.loads(path.read_text()))
    nav = " ".join(f'<a href="#{html.escape(r["experiment"])}">{html.escape(r["experiment"])}</a>'
                   for r in records)
    sections = "\n".join(_experiment_section(r, out, descriptions.get(r["experiment"], ""))
                         for r in records)
    page = (f'<!doctype html><html><head><meta charset="utf-8"><title>radioloc report</title>'
            f"<style>{_CSS}</style></head><body><h1>radioloc: reproductions</h1>"
            f'<p class="meta">Each section shows our numbers beside the published ones, the '
            f"paper's claims checked on our numbers, and the figures.</p><nav>{nav}</nav>"
            f"{sections}</body></html>\n")
    index = out / "index.html"
    from radioloc.core.atomic import atomic_write_text

    atomic_write_text(index, page)
    return index
