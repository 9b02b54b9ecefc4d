"""``radioloc locate --plot FILE.html``: one self-contained page to look at a run.

The page holds, top to bottom: the run summary (method, options, counts, fitted
parameters: the ``summary.json`` beside ``--out``), the error against the reference (with
``--reference``: overall and per node), the figure of :func:`radioloc.locate.plot.
locate_figure` as inline SVG (vector: it zooms without blurring, its text can be searched,
and each node's track is the element ``id="track-K"``), and one ``<section class="track">``
per node with its rows, time span, path length, uncertainty, flag counts and its first
flagged rows (gated ranges, NLOS probability above one half, restarts).

Nothing is loaded from the network (no script, no font, no style sheet): the file opens
from disk, offline, and can be mailed as is. The SVG's element ids are salted with a fixed
string and it carries no date, so the same run gives the same page byte for byte.
"""

from __future__ import annotations

import html
import io
import json
from typing import Any

import numpy as np
import pandas as pd

#: Flagged rows listed per node (the rest are counted).
FLAGGED_ROWS = 50

_CSS = """
body{font-family:system-ui,-apple-system,"Segoe UI",sans-serif;max-width:1200px;margin:0 auto;
padding:.6em 1.2em 3em;color:#1f2328;line-height:1.4;font-size:15px}
h1{font-size:1.35em} h2{font-size:1.15em;border-bottom:1px solid #d0d7de;margin-top:1.6em}
h3{font-size:1.05em;margin:1.2em 0 .3em}
table{border-collapse:collapse;font-size:.9em;margin:.3em 0}
th,td{border-bottom:1px solid #e5e7eb;padding:.2em .6em;text-align:left;vertical-align:top}
th{background:#f6f8fa} td.num{text-align:right;font-variant-numeric:tabular-nums}
figure{margin:1em 0} figure svg{display:block;max-width:100%;height:auto}
.nodes{display:flex;flex-wrap:wrap;gap:0 2.5em} table.summary td{text-align:left}
.meta{color:#57606a;font-size:.9em} details{margin:.4em 0} summary{cursor:pointer}
"""


def _esc(value: Any) -> str:
    return html.escape(str(value))


def _num(value: Any) -> str:
    """A number with 4 significant digits, an integer as is, anything else as text."""
    if isinstance(value, (bool, np.bool_)) or value is None:
        return _esc(value)
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.4g}"
    return _esc(value if isinstance(value, str) else json.dumps(value, default=str))


def _table(rows: list[tuple[str, Any]], cls: str) -> str:
    body = "".join(f'<tr><th>{_esc(k)}</th><td class="num">{_num(v)}</td></tr>'
                   for k, v in rows)
    return f'<table class="{cls}"><tbody>{body}</tbody></table>'


def _per_node(value: Any) -> bool:
    """A list of per-node records (``[{"node": ..., ...}, ...]``, e.g. fitted models)."""
    return (isinstance(value, list) and bool(value)
            and all(isinstance(v, dict) and "node" in v for v in value))


def summary_rows(summary: dict) -> tuple[list[tuple[str, Any]], dict[str, list[tuple[str, Any]]]]:
    """The run summary as ``(name, value)`` rows, and the per-node entries by node.

    A nested dict gives ``parent.key`` rows; a list of per-node records (``[{"node": n,
    ...}]``, such as the fitted LOS/NLOS models) goes to the nodes' sections as
    ``name.key`` rows; ``reference`` is left out (the page shows it as its own table).

    Parameters
    ----------
    summary : dict

    Returns
    -------
    rows : list of tuple
    per_node : dict of str to list of tuple
    """
    rows: list[tuple[str, Any]] = []
    per_node: dict[str, list[tuple[str, Any]]] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict) and value:
            for k, v in value.items():
                walk(f"{prefix}.{k}" if prefix else str(k), v)
        elif _per_node(value):
            for rec in value:
                per_node.setdefault(str(rec["node"]), []).extend(
                    (f"{prefix}.{k}", v) for k, v in rec.items() if k != "node")
        else:
            rows.append((prefix, "{}" if isinstance(value, dict) else value))

    walk("", {k: v for k, v in summary.items() if k != "reference"})
    return rows, per_node


_ERROR_COLUMNS = (("rows_scored", "rows scored"), ("rmse_m", "RMSE (m)"),
                  ("median_m", "median (m)"), ("p90_m", "p90 (m)"), ("max_m", "max (m)"),
                  ("inside_95", "inside 95 % ellipse"))


def _error_table(reference: dict) -> str:
    head = "".join(f'<th>{_esc(lab)}</th>' for _, lab in _ERROR_COLUMNS)
    rows = [("all nodes", reference)] + list(reference.get("per_node", {}).items())
    body = "".join(
        f"<tr><th>{_esc(name)}</th>"
        + "".join(f'<td class="num">{"-" if s.get(k) is None else _num(s[k])}</td>'
                  for k, _ in _ERROR_COLUMNS) + "</tr>"
        for name, s in rows)
    return (f'<table class="errors"><thead><tr><th>node</th>{head}</tr></thead>'
            f"<tbody>{body}</tbody></table>")


#: Per-row flags: (name in the listing, count's label, column, test of the column).
_FLAGS = (("gated", "rows with a gated range", "gated", lambda v: v > 0),
          ("NLOS", "rows with NLOS probability > 0.5", "p_nlos", lambda v: v > 0.5),
          ("restart", "restarts", "restart", lambda v: v > 0))


def _flag_masks(rows: pd.DataFrame) -> dict[str, tuple[str, np.ndarray]]:
    """``{flag name: (count's label, per-row mask)}`` for the flag columns ``rows`` has."""
    return {name: (label, test(rows[col].to_numpy(float)))
            for name, label, col, test in _FLAGS if col in rows}


def node_section(k: int, node: str, rows: pd.DataFrame, errors: dict | None,
                 extra: list[tuple[str, Any]] = ()) -> str:
    """The ``<section class="track">`` of one node.

    Parameters
    ----------
    k : int
        The node's place in the table (its track is ``id="track-K"`` in the figure).
    node : str
    rows : DataFrame
        The node's rows of the ``locate`` output.
    errors : dict, optional
        The node's entry of the reference error summary.
    extra : list of tuple
        More ``(name, value)`` rows (the node's entries of the run summary).

    Returns
    -------
    str
    """
    xy = rows[["x", "y"]].to_numpy(float)
    t = rows["time"].to_numpy(float)
    stats: list[tuple[str, Any]] = [
        ("rows", len(rows)), ("first time (s)", t.min()), ("last time (s)", t.max()),
        ("path length (m)", float(np.sum(np.hypot(*np.diff(xy, axis=0).T))) if len(xy) > 1
         else 0.0)]
    if "uncertainty_m" in rows:
        u = rows["uncertainty_m"].to_numpy(float)
        u = u[np.isfinite(u)]
        if u.size:
            stats += [("median uncertainty_m", float(np.median(u))),
                      ("max uncertainty_m", float(np.max(u)))]
    masks = _flag_masks(rows)
    stats += [(label, int(mask.sum())) for label, mask in masks.values()]
    if errors is not None:
        stats += [(f"reference: {lab}", errors[key]) for key, lab in _ERROR_COLUMNS
                  if errors.get(key) is not None]
    stats += list(extra)
    flagged = np.flatnonzero(np.any([m for _, m in masks.values()], axis=0)) if masks \
        else np.zeros(0, dtype=int)
    listing = ""
    if flagged.size:
        cols = [c for c in ("time", "x", "y", "z", "uncertainty_m", "p_nlos") if c in rows]
        head = "".join(f"<th>{_esc(c)}</th>" for c in cols) + "<th>flags</th>"
        shown = flagged[:FLAGGED_ROWS]
        values = rows[cols].iloc[shown].to_numpy()
        body = "".join("<tr>" + "".join(f'<td class="num">{_num(v)}</td>' for v in vals)
                       + "<td>" + " ".join(n for n, (_, m) in masks.items() if m[i]) + "</td></tr>"
                       for i, vals in zip(shown, values))
        more = f" (the first {FLAGGED_ROWS})" if flagged.size > FLAGGED_ROWS else ""
        listing = (f"<details><summary>{flagged.size} flagged rows{more}</summary>"
                   f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"
                   "</details>")
    return (f'<section class="track" id="node-{k}" data-node="{_esc(node)}">'
            f"<h3>{_esc(node)}</h3>{_table(stats, 'node')}{listing}</section>")


def figure_svg(fig) -> str:
    """``fig`` as an inline ``<svg>`` element (no XML prolog, no date, fixed id salt)."""
    import matplotlib

    buf = io.StringIO()
    with matplotlib.rc_context({"svg.hashsalt": "radioloc-locate", "svg.fonttype": "path"}):
        fig.savefig(buf, format="svg", metadata={"Date": None})
    text = buf.getvalue()
    return text[text.index("<svg"):]


def locate_page(frame: pd.DataFrame, fig, *, summary: dict | None = None,
                errors: pd.DataFrame | None = None, title: str = "") -> str:
    """The HTML page of a ``locate`` output (see the module docstring).

    Parameters
    ----------
    frame : DataFrame
        A ``locate`` output table.
    fig : matplotlib.figure.Figure
        Its figure (:func:`radioloc.locate.plot.locate_figure`).
    summary : dict, optional
        The run summary; default ``frame.attrs["summary"]``. Its ``reference`` entry (else
        one computed from ``errors``) gives the error tables.
    errors : DataFrame, optional
        From :func:`radioloc.locate.scoring.reference_errors`.
    title : str

    Returns
    -------
    str
    """
    from radioloc.locate.scoring import error_summary

    summary = dict(frame.attrs.get("summary", {}) if summary is None else summary)
    reference = summary.get("reference")
    if reference is None and errors is not None:
        reference = error_summary(errors, len(frame))
    title = title or "radioloc locate"
    nodes = list(frame.groupby("node", sort=False).groups)
    meta = (f"{len(frame)} rows, {len(nodes)} node{'s' if len(nodes) != 1 else ''}, time "
            f"{_num(frame['time'].min())} to {_num(frame['time'].max())} s")
    rows, node_rows = summary_rows(summary)
    parts = [f"<h1>{_esc(title)}</h1>", f'<p class="meta">{_esc(meta)}</p>',
             "<h2>Run summary</h2>", _table(rows, "summary")]
    if reference is not None:
        parts += ["<h2>Error against the reference</h2>", _error_table(reference)]
    parts += ["<h2>Figure</h2>",
              '<p class="meta">Anchors (triangles), tracks with their 95 % uncertainty '
              "ellipses, gated rows (crosses), NLOS rows (circles)"
              + (", the reference (dashed) and the error against time" if errors is not None
                 else "") + ".</p>",
              f"<figure>{figure_svg(fig)}</figure>", "<h2>Nodes</h2>"]
    per_node = (reference or {}).get("per_node", {})
    groups = frame.groupby("node", sort=False)
    parts += ['<div class="nodes">']
    parts += [node_section(k, str(node), groups.get_group(node), per_node.get(str(node)),
                           node_rows.get(str(node), []))
              for k, node in enumerate(nodes)]
    parts += ["</div>"]
    return ('<!doctype html><html lang="en"><head><meta charset="utf-8">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{_esc(title)}</title><style>{_CSS}</style></head><body>"
            + "\n".join(parts) + "</body></html>\n")
