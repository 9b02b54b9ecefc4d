"""``radioloc view EST.csv``: a local web page that draws the tracks as their rows arrive.

A small HTTP server (the standard library's, on ``127.0.0.1`` by default) serves one page
and two JSON answers:

- ``/`` the page: a canvas (equal scales, a scale bar) with the anchors (grey triangles),
  each node's track (its last
  :data:`KEPT_POINTS` points, one colour per node) and, at its latest point, the 95 %
  ellipse of its ``cov_xx, cov_xy, cov_yy`` (``chi2_2(0.95) = 5.991``); below it a status
  line (rows read, nodes, latest time) and a table of each node's latest estimate. Nothing is
  loaded from the network.
- ``/anchors`` the anchors (``id, x, y``) of ``--anchors`` (empty without).
- ``/rows?from=OFFSET`` the complete CSV lines of the estimates file after byte
  ``OFFSET``, as ``{"offset": next offset, "columns": [...], "rows": [[...], ...]}``
  (``time, node, x, y`` and the covariance columns where the file has them); at most
  :data:`MAX_BYTES` a request. A file shorter than the offset was written anew: its rows
  are sent from the top with ``"reset": true``, and the page starts over.

The page asks for new rows every ``poll_s`` seconds, so it follows a file that
``radioloc locate --follow --out EST.csv`` is writing (or any estimates CSV with ``time,
node, x, y``). The server reads the file only from the offset a page asks for, and a page
keeps a bounded number of points per node: memory stays flat on endless runs.
"""

from __future__ import annotations

import json
import math
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from radioloc.core.errors import ConfigError, InputError

__all__ = ["KEPT_POINTS", "MAX_BYTES", "new_rows", "serve", "view_server"]

#: Points of each node's track a page keeps and draws.
KEPT_POINTS = 5000
#: Bytes of the estimates file read per request.
MAX_BYTES = 1 << 20
#: Columns sent to the page (those the file has).
COLUMNS = ("time", "node", "x", "y", "cov_xx", "cov_xy", "cov_yy")


def new_rows(path: Path, offset: int, max_bytes: int = MAX_BYTES) -> dict:
    """The complete lines of the estimates CSV ``path`` after byte ``offset`` (0: after
    its header line), as :data:`COLUMNS` present, with the offset to ask from next.

    Raises
    ------
    InputError
        The file's header has no ``time``, ``node``, ``x`` or ``y`` column.
    """
    if not path.is_file():
        return {"offset": 0, "columns": [], "rows": [], "reset": False}
    with open(path, "rb") as f:
        header = f.readline()
        if not header.endswith(b"\n"):
            return {"offset": 0, "columns": [], "rows": [], "reset": False}
        names = header.decode("utf-8", errors="replace").strip().split(",")
        missing = [c for c in COLUMNS[:4] if c not in names]
        if missing:
            raise InputError(f"estimates file {path}: no {missing[0]!r} column "
                             f"(its header: {', '.join(names)})")
        size = f.seek(0, 2)
        reset = offset > size                # the file was written anew: from its top
        start = len(header) if reset else max(offset, len(header))
        f.seek(start)
        data = f.read(max_bytes)
    cut = data.rfind(b"\n") + 1
    keep = [c for c in COLUMNS if c in names]
    where = [names.index(c) for c in keep]
    rows = []
    for line in data[:cut].decode("utf-8", errors="replace").splitlines():
        cells = line.split(",")
        if len(cells) != len(names):
            continue                                   # a line being written
        row = []
        for c, i in zip(keep, where):
            if c == "node":
                row.append(cells[i])
            else:
                try:
                    v = float(cells[i])
                except ValueError:
                    v = math.nan
                row.append(v if math.isfinite(v) else None)
        rows.append(row)
    return {"offset": start + cut, "columns": keep, "rows": rows, "reset": reset}


_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>radioloc live view</title>
<style>
body{font-family:system-ui,sans-serif;margin:0 auto;max-width:1100px;padding:.5em 1em;
color:#1f2328}
canvas{width:100%;height:auto;border:1px solid #d0d7de;background:#fff}
table{border-collapse:collapse;font-size:.9em} th,td{padding:.15em .6em;text-align:right}
th{background:#f6f8fa} td:first-child,th:first-child{text-align:left}
#status{color:#57606a}
</style></head><body>
<h1 style="font-size:1.2em">radioloc live view: <code>__NAME__</code></h1>
<p id="status">waiting for rows</p>
<canvas id="map" width="1000" height="700"></canvas>
<table id="nodes"><thead><tr><th>node</th><th>time (s)</th><th>x (m)</th><th>y (m)</th>
<th>95 % ellipse, semi-axes (m)</th></tr></thead><tbody></tbody></table>
<script>
"use strict";
const KEEP = __KEEP__, POLL_MS = __POLL_MS__, CHI2 = 5.991464547107979;
const COLOURS = ["#1f77b4","#d62728","#2ca02c","#9467bd","#ff7f0e","#17becf","#8c564b",
                 "#e377c2","#7f7f7f","#bcbd22"];
let anchors = [], tracks = new Map(), offset = 0, total = 0, latest = null;
function axes(p) {            // semi-axes and angle of the 95 % ellipse of [[a,b],[b,c]]
  if (p.cxx == null || p.cyy == null) return null;
  const a = p.cxx, b = p.cxy || 0, c = p.cyy, h = Math.hypot((a - c) / 2, b);
  const l1 = (a + c) / 2 + h, l2 = Math.max((a + c) / 2 - h, 0);
  return [Math.sqrt(CHI2 * l1), Math.sqrt(CHI2 * l2), 0.5 * Math.atan2(2 * b, a - c)];
}
function draw() {
  const cv = document.getElementById("map"), g = cv.getContext("2d");
  g.clearRect(0, 0, cv.width, cv.height);
  let xs = anchors.map(a => a.x), ys = anchors.map(a => a.y);
  for (const t of tracks.values()) for (const p of t) { xs.push(p.x); ys.push(p.y); }
  if (!xs.length) return;
  let x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
  const pad = 0.08 * Math.max(x1 - x0, y1 - y0, 1);
  x0 -= pad; x1 += pad; y0 -= pad; y1 += pad;
  const s = Math.min(cv.width / (x1 - x0), cv.height / (y1 - y0));
  const X = x => (x - x0) * s, Y = y => cv.height - (y - y0) * s;
  g.font = "12px sans-serif";
  for (const a of anchors) {
    g.fillStyle = "#6e7781"; g.beginPath();
    g.moveTo(X(a.x), Y(a.y) - 7); g.lineTo(X(a.x) - 6, Y(a.y) + 5); g.lineTo(X(a.x) + 6, Y(a.y) + 5);
    g.fill(); g.fillText(a.id, X(a.x) + 8, Y(a.y) + 4);
  }
  const span = (cv.width / s) / 5, unit = Math.pow(10, Math.floor(Math.log10(span)));
  const bar = [5, 2, 1].map(m => m * unit).find(v => v <= span) || unit;   // scale bar
  g.strokeStyle = "#1f2328"; g.lineWidth = 2; g.beginPath();
  g.moveTo(12, cv.height - 14); g.lineTo(12 + bar * s, cv.height - 14); g.stroke();
  g.fillStyle = "#1f2328"; g.fillText(bar + " m", 12, cv.height - 20);
  let k = 0;
  for (const [node, t] of tracks) {
    const col = COLOURS[k++ % COLOURS.length];
    g.strokeStyle = col; g.lineWidth = 1.5; g.beginPath();
    t.forEach((p, i) => i ? g.lineTo(X(p.x), Y(p.y)) : g.moveTo(X(p.x), Y(p.y)));
    g.stroke();
    const p = t[t.length - 1], e = axes(p);
    g.fillStyle = col; g.beginPath(); g.arc(X(p.x), Y(p.y), 4, 0, 2 * Math.PI); g.fill();
    if (e) {
      g.beginPath(); g.ellipse(X(p.x), Y(p.y), e[0] * s, e[1] * s, -e[2], 0, 2 * Math.PI);
      g.stroke();
    }
    g.fillText(node, X(p.x) + 8, Y(p.y) - 8);
  }
}
function table() {
  const body = document.querySelector("#nodes tbody");
  body.innerHTML = "";
  for (const [node, t] of tracks) {
    const p = t[t.length - 1], e = axes(p), tr = document.createElement("tr");
    for (const v of [node, p.t.toFixed(3), p.x.toFixed(3), p.y.toFixed(3),
                     e ? e[0].toFixed(3) + ", " + e[1].toFixed(3) : ""]) {
      const td = document.createElement("td"); td.textContent = v; tr.appendChild(td);
    }
    body.appendChild(tr);
  }
}
async function poll() {
  try {
    const r = await (await fetch("rows?from=" + offset)).json();
    if (r.reset) { tracks = new Map(); total = 0; }
    offset = r.offset;
    const at = name => r.columns.indexOf(name);
    const [it, iN, ix, iy, ia, ib, ic] = ["time", "node", "x", "y", "cov_xx", "cov_xy",
                                          "cov_yy"].map(at);
    for (const row of r.rows) {
      if (row[ix] == null || row[iy] == null) continue;
      const node = row[iN];
      if (!tracks.has(node)) tracks.set(node, []);
      const t = tracks.get(node);
      t.push({t: row[it], x: row[ix], y: row[iy], cxx: ia < 0 ? null : row[ia],
              cxy: ib < 0 ? null : row[ib], cyy: ic < 0 ? null : row[ic]});
      if (t.length > KEEP) t.splice(0, t.length - KEEP);
      total += 1; latest = row[it];
    }
    if (r.rows.length) {
      draw(); table();
      document.getElementById("status").textContent = total + " rows, " + tracks.size +
        " node(s), latest time " + latest.toFixed(3) + " s";
    }
  } catch (err) {
    document.getElementById("status").textContent = "no answer from the server: " + err;
  }
  setTimeout(poll, POLL_MS);
}
fetch("anchors").then(r => r.json()).then(a => { anchors = a; draw(); poll(); });
</script></body></html>
"""


def view_server(estimates: Path, anchors: Path | None = None, host: str = "127.0.0.1",
                port: int = 0, poll_s: float = 0.5) -> ThreadingHTTPServer:
    """The server of the live view of ``estimates`` (module docstring), bound, not yet
    serving (``serve_forever`` serves; ``server_address`` tells the port).

    Raises
    ------
    ConfigError
        ``poll_s`` is not a positive number.
    InputError
        The address cannot be listened on, or the anchors file cannot be read.
    """
    if not (math.isfinite(poll_s) and poll_s > 0):
        raise ConfigError(f"--poll-s: expected a number of seconds > 0, got {poll_s!r}")
    anchor_list = []
    if anchors is not None:
        from radioloc.io.logs import read_anchors

        table = read_anchors(anchors)
        anchor_list = [{"id": str(i), "x": float(x), "y": float(y)}
                       for i, x, y in zip(table["id"], table["x"], table["y"])]
    page = (_PAGE.replace("__NAME__", estimates.name.replace("&", "&amp;").replace("<", "&lt;"))
            .replace("__KEEP__", str(KEPT_POINTS))
            .replace("__POLL_MS__", str(int(poll_s * 1000)))).encode("utf-8")
    lock = threading.Lock()

    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args):           # quiet: the terminal is the user's
            pass

        def _send(self, body: bytes, kind: str, code: int = 200) -> None:
            self.send_response(code)
            self.send_header("Content-Type", kind)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def do_GET(self):
            url = urlparse(self.path)
            if url.path == "/":
                self._send(page, "text/html; charset=utf-8")
            elif url.path == "/anchors":
                self._send(json.dumps(anchor_list).encode(), "application/json")
            elif url.path == "/rows":
                try:
                    offset = int(parse_qs(url.query).get("from", ["0"])[-1])
                    with lock:
                        answer = new_rows(estimates, max(offset, 0))
                    self._send(json.dumps(answer).encode(), "application/json")
                except (ValueError, InputError) as exc:
                    self._send(json.dumps({"error": str(exc)}).encode(), "application/json",
                               400)
            else:
                self._send(b"not found", "text/plain", 404)

    try:
        return ThreadingHTTPServer((host, port), Handler)
    except (OSError, OverflowError) as exc:
        raise InputError(f"cannot listen on {host}:{port} "
                         f"({getattr(exc, 'strerror', None) or exc})") from None


def serve(estimates: Path, anchors: Path | None = None, host: str = "127.0.0.1",
          port: int = 0, poll_s: float = 0.5, announce=print) -> None:
    """Serve the live view until Ctrl-C; ``announce`` gets the page's address first."""
    server = view_server(estimates, anchors, host, port, poll_s)
    h, p = server.server_address[:2]
    announce(f"serving the live view of {estimates} at http://{h}:{p}/ (Ctrl-C ends)")
    try:
        server.serve_forever(poll_interval=0.2)
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
