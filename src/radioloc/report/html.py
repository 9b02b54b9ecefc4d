"""The one-page HTML report of all experiments (``out/index.html``).

The page opens with a **scoreboard**: one row per experiment with the paper's claims that
hold on our numbers (k of n), the headline numbers (with their interval) beside the paper's
with the gap coloured (the relative gap only where ours and the paper's are within a factor
:data:`~radioloc.report.tables.GAP_FACTOR`; a departure the paper itself predicts is marked
as such, apart from our gaps), and a link to the experiment's section. Each section then shows the claims (holds / does
not hold / undecided at this size, with the confidence interval that decided each), the figures at
full width with their captions (``captions.json`` in the experiment's folder, recorded by
:func:`radioloc.report.style.save`; for a folder written without one, a caption made from the
file name ``figN[a-z]_*.png``), and the full metric table (with each metric's confidence interval
over runs, where it has one) folded in a ``<details>`` element.

Nothing here imports pyplot or switches the matplotlib backend.
"""

from __future__ import annotations

import html
import json
import re
from pathlib import Path
from typing import Any, Iterable

from radioloc.report.captions import read_captions
from radioloc.report.tables import (GAP_FACTOR, PREDICTED, claim_evidence, fmt, gap_is_meaningful,
                                    interval, metric_gap, verdict)

#: Relative gaps (ours against the paper's) up to these bounds are coloured good / fair;
#: larger ones poor.
GAP_GOOD = 0.10
GAP_FAIR = 0.30
#: Headline numbers shown per experiment in the scoreboard.
HEADLINES = 3

_CSS = """
*{box-sizing:border-box}
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;max-width:1180px;margin:0 auto;
padding:.6em 1.2em 3em;color:#1f2328;line-height:1.45;font-size:15px}
h1{font-size:1.45em;margin:.3em 0 .1em} h2{border-bottom:1px solid #d0d7de;padding-bottom:.2em;
margin-top:2.2em;font-size:1.3em}
a{color:#0969da;text-decoration:none} a:hover{text-decoration:underline}
table{border-collapse:collapse;font-size:.9em;width:100%}
th,td{border-bottom:1px solid #e5e7eb;padding:.3em .55em;vertical-align:top;text-align:left}
th{background:#f6f8fa;font-weight:600}
td.num,th.num{text-align:right;white-space:nowrap}
.scoreboard td{padding:.28em .55em} .scoreboard td.exp{white-space:nowrap}
.hl{display:inline-block;margin:0 .9em .1em 0;white-space:nowrap}
.hl .n{color:#57606a}
.good{color:#1a7f37} .fair{color:#9a6700} .poor{color:#cf222e} .skip{color:#9a6700}
.expected{color:#57606a;font-style:italic}
.pill{display:inline-block;border-radius:1em;padding:0 .6em;font-weight:600;font-size:.92em;
white-space:nowrap}
.pill.good{background:#dafbe1} .pill.fair{background:#fff8c5} .pill.poor{background:#ffebe9}
.pill.none{background:#eaeef2;color:#57606a}
.meta{color:#57606a;font-size:.9em} .note{color:#57606a;font-size:.9em}
ul.claims{padding-left:1.2em} ul.claims li{margin:.15em 0} .ci{color:#57606a;font-size:.9em}
figure{margin:1.2em 0;max-width:100%} figure img{display:block;max-width:100%;height:auto;
border:1px solid #eaeef2} figcaption{color:#57606a;font-size:.9em;margin-top:.3em}
details{margin:1em 0} summary{cursor:pointer;font-weight:600}
.wrap{overflow-x:auto;max-width:100%} td.note{min-width:16em}
"""


def _esc(value: Any) -> str:
    return html.escape(str(value))


def gap_class(value: float | None, paper: float | None) -> str:
    """``good`` / ``fair`` / ``poor`` for the relative gap of ``value`` to ``paper`` (see
    :data:`GAP_GOOD`, :data:`GAP_FAIR`), ``""`` when either is missing.

    Parameters
    ----------
    value, paper : float or None
        Our number and the paper's.

    Returns
    -------
    str
    """
    if value is None or paper is None or paper == 0 or value != value:
        return ""
    if not gap_is_meaningful(value, paper):
        return "poor"
    rel = abs(value - paper) / abs(paper)
    return "good" if rel <= GAP_GOOD else "fair" if rel <= GAP_FAIR else "poor"


def claims_score(record: dict[str, Any]) -> tuple[int, int]:
    """``(claims that hold, claims)`` of one ``summary.json`` record.

    Parameters
    ----------
    record : dict
        A ``summary.json`` record.

    Returns
    -------
    tuple of int
    """
    claims = record.get("claims") or []
    return sum(verdict(c) == "holds" for c in claims), len(claims)


def headline_metrics(record: dict[str, Any], n: int = HEADLINES) -> list[dict[str, Any]]:
    """The experiment's headline numbers: the first ``n`` metrics that have a paper value,
    else its first metric (the experiment lists its headline first).

    Parameters
    ----------
    record : dict
        A ``summary.json`` record.
    n : int
        How many.

    Returns
    -------
    list of dict
    """
    metrics = record.get("metrics") or []
    return [m for m in metrics if m.get("paper") is not None][:n] or metrics[:1]


def figure_caption(stem: str, paper: str) -> str:
    """Caption of figure file ``stem``: a readable title and the paper figure it reproduces
    (``fig4a_error_cdf`` -> ``Error cdf. Reproduces Fig. 4(a) of paper 001.``).

    Parameters
    ----------
    stem : str
        File name without ``.png``.
    paper : str
        The experiment's paper id.

    Returns
    -------
    str
    """
    m = re.match(r"fig(\d+)([a-z]?)(?:_(.*))?$", stem)
    title = (m.group(3) if m else stem) or stem
    title = title.replace("_", " ").strip()
    title = title[:1].upper() + title[1:]
    if m:
        sub = f"({m.group(2)})" if m.group(2) else ""
        return f"{title}. Reproduces Fig. {m.group(1)}{sub} of paper {paper}."
    return f"{title}."


def _ci_span(metric: dict[str, Any]) -> str:
    """`` <span class="ci">[lo, hi]</span>`` of a metric with an interval, else ``""``."""
    ci = interval(metric.get("ci_low"), metric.get("ci_high"))
    return f' <span class="ci">{_esc(ci)}</span>' if ci else ""


def _headline_cell(record: dict[str, Any]) -> str:
    items = []
    for m in headline_metrics(record):
        cls = "expected" if m.get("predicted") else gap_class(m["value"], m["paper"])
        gap = metric_gap(m)
        paper = f' / paper {fmt(m["paper"])}' if m.get("paper") is not None else ""
        items.append(f'<span class="hl" title="{_esc(m.get("predicted") or m["note"])}">'
                     f'<span class="n">{_esc(m["name"])}</span> {fmt(m["value"])}{_ci_span(m)}'
                     f'{paper} <b class="{cls}">{_esc(gap)}</b></span>')
    return "".join(items) or '<span class="meta">no number with a published value</span>'


def _score_pill(record: dict[str, Any]) -> str:
    k, n = claims_score(record)
    if n == 0:
        return '<span class="pill none">no claim</span>'
    cls = "good" if k == n else "poor" if k == 0 else "fair"
    return f'<span class="pill {cls}">{k} of {n}</span>'


def scoreboard(records: Iterable[dict[str, Any]]) -> str:
    """The scoreboard table (HTML) of the ``summary.json`` records.

    Parameters
    ----------
    records : iterable of dict
        ``summary.json`` records.

    Returns
    -------
    str
        One ``<table>`` with a row per experiment: link to its section, paper, claims that
        hold (k of n), headline numbers ``ours / paper gap``.
    """
    rows = []
    for r in records:
        eid = _esc(r["experiment"])
        link = f'<a href="#{eid}">{eid}</a>'
        if r.get("skipped"):
            rows.append(f'<tr><td class="exp">{link}</td><td>{_esc(r["paper"])}</td>'
                        f'<td><span class="pill none">skipped</span></td>'
                        f'<td class="skip">{_esc(r["skipped"])}</td></tr>')
            continue
        rows.append(f'<tr><td class="exp">{link}</td><td>{_esc(r["paper"])}</td>'
                    f'<td>{_score_pill(r)}</td><td>{_headline_cell(r)}</td></tr>')
    return ('<table class="scoreboard"><thead><tr><th>experiment</th><th>paper</th>'
            '<th>claims hold</th><th>headline numbers: ours [95% CI] / paper, our gap '
            f'(<span class="good">&le;{GAP_GOOD:.0%}</span>, '
            f'<span class="fair">&le;{GAP_FAIR:.0%}</span>, <span class="poor">more</span>; '
            f'shown only within a factor {GAP_FACTOR:g}) or '
            f'<span class="expected">{_esc(PREDICTED)}</span>'
            f'</th></tr></thead><tbody>{"".join(rows)}</tbody></table>')


def _metric_table(record: dict[str, Any]) -> str:
    rows = "".join(
        f'<tr><td>{_esc(m["name"])}</td><td class="num">{fmt(m["value"])}</td>'
        f'<td class="num">{_esc(interval(m.get("ci_low"), m.get("ci_high")))}</td>'
        f'<td class="num">{fmt(m["paper"])}</td>'
        f'<td class="num {"expected" if m.get("predicted") else gap_class(m["value"], m["paper"])}">'
        f'{_esc(metric_gap(m))}</td>'
        f'<td>{_esc(m["unit"])}</td><td class="note">{_esc(m["note"])}</td></tr>'
        for m in record["metrics"])
    return (f'<details><summary>All {len(record["metrics"])} metrics</summary><div class="wrap">'
            '<table><thead><tr><th>metric</th><th class="num">ours</th><th class="num">95% CI</th>'
            '<th class="num">paper</th>'
            '<th class="num">gap</th><th>unit</th><th>note</th></tr></thead>'
            f'<tbody>{rows}</tbody></table></div></details>')


def _figure_order(path: Path) -> tuple:
    m = re.match(r"fig(\d+)([a-z]?)", path.stem)
    return (0, int(m.group(1)), m.group(2), path.stem) if m else (1, 0, "", path.stem)


_VERDICT_CLASS = {"holds": "good", "does not hold": "poor", "undecided at this size": "fair"}
_VERDICT_MARK = {"holds": "&#10003;", "does not hold": "&#10007;", "undecided at this size": "?"}


def experiment_section(record: dict[str, Any], out: Path, description: str = "") -> str:
    """The HTML section of one experiment (claims, figures with captions, folded metrics).

    Parameters
    ----------
    record : dict
        The experiment's ``summary.json`` record.
    out : Path
        The report folder (figures are read from ``out/<id>/*.png``).
    description : str
        One line describing the experiment.

    Returns
    -------
    str
    """
    eid = _esc(record["experiment"])
    parts = [f'<section id="{eid}"><h2>{eid} {_score_pill(record) if not record.get("skipped") else ""}</h2>',
             f'<p>{_esc(description)} <span class="meta">(paper {_esc(record["paper"])})</span></p>']
    if record.get("skipped"):
        parts.append(f'<p class="skip">Skipped: {_esc(record["skipped"])}</p></section>')
        return "\n".join(parts)
    parts.append(f'<p class="meta">{record["runs"]} runs, seed {record["seed"]}, '
                 f'{"full" if record["full"] else "quick"} size, {record["elapsed_s"]:.1f} s</p>')
    if record["claims"]:
        items = "".join(
            f'<li class="{_VERDICT_CLASS[verdict(c)]}">'
            f'{_VERDICT_MARK[verdict(c)]} {_esc(verdict(c))}: '
            f'<span style="color:#1f2328">{_esc(c["claim"])}</span>'
            + (f' <span class="ci">({_esc(claim_evidence(c))})</span>' if claim_evidence(c) else "")
            + '</li>'
            for c in record["claims"])
        parts.append(f'<p><b>Claims of the paper, checked on our numbers</b></p>'
                     f'<ul class="claims">{items}</ul>')
    folder = out / record["experiment"]
    captions = read_captions(folder)
    for f in sorted(folder.glob("*.png"), key=_figure_order):
        src = _esc(f.relative_to(out).as_posix())
        cap = captions.get(f.stem) or figure_caption(f.stem, str(record["paper"]))
        parts.append(f'<figure><a href="{src}"><img src="{src}" alt="{_esc(f.stem)}" '
                     f'loading="lazy"></a><figcaption>{_esc(cap)}</figcaption></figure>')
    if record["metrics"]:
        parts.append(_metric_table(record))
    if record.get("notes"):
        notes = "".join(f"<li>{_esc(n)}</li>" for n in record["notes"])
        parts.append(f'<details><summary>Notes</summary><ul class="note">{notes}</ul></details>')
    parts.append("</section>")
    return "\n".join(parts)


def render(records: list[dict[str, Any]], out: Path | str,
           descriptions: dict[str, str] | None = None) -> str:
    """The whole report page (HTML text) for ``records``.

    Parameters
    ----------
    records : list of dict
        ``summary.json`` records, in display order.
    out : path
        The report folder (for the figures).
    descriptions : dict of str to str, optional
        One line per experiment id.

    Returns
    -------
    str
    """
    out = Path(out)
    descriptions = descriptions or {}
    ran = [r for r in records if not r.get("skipped")]
    held = sum(claims_score(r)[0] for r in ran)
    total = sum(claims_score(r)[1] for r in ran)
    sections = "\n".join(experiment_section(r, out, descriptions.get(r["experiment"], ""))
                         for r in records)
    return (f'<!doctype html><html lang="en"><head><meta charset="utf-8">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>radioloc report</title><style>{_CSS}</style></head><body>"
            "<h1>radioloc: reproductions</h1>"
            f'<p class="meta">{len(ran)} of {len(records)} experiments ran; {held} of {total} '
            "claims of the papers hold on our numbers. Each row links to its section (figures, "
            "claims, all metrics).</p>"
            f"{scoreboard(records)}{sections}</body></html>\n")


def write_index(out: Path | str, descriptions: dict[str, str]) -> Path:
    """Write ``out/index.html`` from every ``out/<id>/summary.json`` it finds.

    Parameters
    ----------
    out : path
        The report folder.
    descriptions : dict of str to str
        One line per experiment id.

    Returns
    -------
    Path
        The page written.
    """
    out = Path(out)
    records = [json.loads(p.read_text()) for p in sorted(out.glob("*/summary.json"))]
    index = out / "index.html"
    from radioloc.core.atomic import atomic_write_text

    atomic_write_text(index, render(records, out, descriptions))
    return index
