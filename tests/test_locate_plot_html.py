"""`radioloc locate --plot FILE.html`: a self-contained page (summary, reference errors, the
figure as inline SVG, one section per node) that parses, loads nothing and is reproducible."""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from radioloc.cli import app
from radioloc.locate.plot import plot_locate
from radioloc.locate.plot_html import FLAGGED_ROWS

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
MEAS, ANCHORS = str(EXAMPLES / "measurements.csv"), str(EXAMPLES / "anchors.csv")
CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")
                 if shutil.which(n)), None)
runner = CliRunner()


class Page(HTMLParser):
    """The elements of a page: ``(tag, attributes)`` in order; fails on unbalanced tags."""

    VOID = {"meta", "br", "img", "hr", "input", "link"}

    def __init__(self, text: str):
        super().__init__()
        self.elements: list[tuple[str, dict]] = []
        self.stack: list[str] = []
        self.feed(text)
        self.close()
        assert self.stack == [], f"unclosed elements: {self.stack}"

    def handle_starttag(self, tag, attrs):
        self.elements.append((tag, dict(attrs)))
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_startendtag(self, tag, attrs):
        self.elements.append((tag, dict(attrs)))

    def handle_endtag(self, tag):
        assert self.stack and self.stack[-1] == tag, f"</{tag}> closes {self.stack[-1:]}"
        self.stack.pop()

    def find(self, tag: str, **attrs) -> list[dict]:
        return [a for t, a in self.elements if t == tag
                and all(a.get(k.rstrip("_")) == v for k, v in attrs.items())]


def reference(path: Path) -> Path:
    """The example's truth: tag1 x = 10 + 2 t, y = 12; tag2 x = 40, y = 5 + t."""
    t = np.arange(5.0)
    pd.concat([pd.DataFrame({"time": t, "node": "tag1", "x": 10 + 2 * t, "y": 12.0}),
               pd.DataFrame({"time": t, "node": "tag2", "x": 40.0, "y": 5 + t})]
              ).to_csv(path, index=False)
    return path


def flagged_frame(rows: int = 80) -> pd.DataFrame:
    """Three nodes; node b has every third row gated and rows 10-19 NLOS, c restarts once."""
    t = np.arange(rows, dtype=float)
    parts = []
    for k, node in enumerate(("a", "b", "c")):
        parts.append(pd.DataFrame({
            "time": t, "node": node, "x": t * 0.5, "y": 3.0 * k + np.sin(t / 5),
            "uncertainty_m": 0.2 + 0.01 * k, "cov_xx": 0.02, "cov_xy": 0.0, "cov_yy": 0.02,
            "gated": (t % 3 == 0).astype(int) if node == "b" else 0,
            "p_nlos": np.where((t >= 10) & (t < 20), 0.9, 0.05) if node == "b" else 0.0,
            "restart": (t == 40).astype(int) if node == "c" else 0}))
    return pd.concat(parts).sort_values(["time", "node"], kind="stable").reset_index(drop=True)


def test_cli_writes_a_page_with_the_summary_errors_and_one_track_per_node(tmp_path):
    """With --reference: the page parses (balanced tags), shows the summary.json numbers,
    the error table equal to the summary's, one inline SVG holding one track element per
    node and one section per node; it references nothing outside itself."""
    ref = reference(tmp_path / "ref.csv")
    out, page = tmp_path / "t.csv", tmp_path / "t.html"
    res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--method", "ekf-track",
                              "--out", str(out), "--reference", str(ref), "--plot", str(page),
                              "--quiet"])
    assert res.exit_code == 0, res.output
    text = page.read_text()
    doc = Page(text)
    summary = json.loads((tmp_path / "t.summary.json").read_text())
    nodes = list(dict.fromkeys(pd.read_csv(out)["node"]))
    assert nodes == ["tag1", "tag2"]
    sections = doc.find("section", class_="track")
    assert [s["data-node"] for s in sections] == nodes
    assert len(doc.find("svg")) == 1
    assert sorted(a["id"] for t, a in doc.elements if a.get("id", "").startswith("track-")) \
        == [f"track-{k}" for k in range(len(nodes))]
    for tag, attrs in doc.elements:                   # nothing to fetch: no network, no file
        for key in ("src", "href", "xlink:href"):
            assert attrs.get(key) is None or attrs[key].startswith(("#", "data:")), (tag, attrs)
    assert "<script" not in text and "@import" not in text and "url(http" not in text
    errors = text.split('<table class="errors">')[1].split("</table>")[0]
    r = summary["reference"]
    assert f'<th>all nodes</th><td class="num">{r["rows_scored"]}</td>' \
           f'<td class="num">{r["rmse_m"]:.4g}</td>' in errors
    for node in nodes:
        assert f'<td class="num">{r["per_node"][node]["rmse_m"]:.4g}</td>' in errors
    board = text.split('<table class="summary">')[1].split("</table>")[0]
    assert f'<th>rows_read</th><td class="num">{summary["rows_read"]}</td>' in board
    assert f'<th>restarts</th><td class="num">{summary["restarts"]}</td>' in board


def test_node_sections_count_and_list_the_flagged_rows(tmp_path):
    """Counts of gated, NLOS and restart rows per node; the flagged rows listed (at most
    FLAGGED_ROWS); a per-node list in the summary goes to its node's section; the page is
    the same byte for byte when written twice."""
    frame = flagged_frame()
    summary = {"method": "test", "model": [{"node": "b", "alpha": 0.75}, {"node": "a",
                                                                          "alpha": 0.5}]}
    a = plot_locate(frame, tmp_path / "a.html", summary=summary, title="flags")
    b = plot_locate(frame, tmp_path / "b.html", summary=summary, title="flags")
    text = a.read_text()
    assert text == b.read_text()
    doc = Page(text)
    assert [s["data-node"] for s in doc.find("section", class_="track")] == ["a", "b", "c"]
    sec = {n: text.split(f'data-node="{n}"')[1].split("</section>")[0] for n in "abc"}
    gated, nlos = (np.arange(80) % 3 == 0), (np.arange(80) >= 10) & (np.arange(80) < 20)
    count = lambda s, label: int(re.search(rf"<th>{re.escape(html.escape(label))}</th>"
                                           r'<td class="num">(\d+)</td>', s).group(1))
    assert count(sec["b"], "rows with a gated range") == gated.sum()
    assert count(sec["b"], "rows with NLOS probability > 0.5") == nlos.sum()
    assert count(sec["c"], "restarts") == 1 and count(sec["a"], "restarts") == 0
    flagged = int((gated | nlos).sum())
    assert f"{flagged} flagged rows" in sec["b"]
    assert sec["b"].count("<tr><td") == min(flagged, FLAGGED_ROWS)
    assert "1 flagged rows" in sec["c"] and "flagged rows" not in sec["a"]
    assert "<th>model.alpha</th><td class=\"num\">0.75</td>" in sec["b"]
    assert "<th>model.alpha</th><td class=\"num\">0.5</td>" in sec["a"]
    assert "model" not in text.split('<table class="summary">')[1].split("</table>")[0]
    assert "Error against the reference" not in text


def test_an_unknown_plot_suffix_is_refused_before_any_work(tmp_path):
    res = runner.invoke(app, ["locate", MEAS, "--anchors", ANCHORS, "--plot",
                              str(tmp_path / "t.gif")])
    assert res.exit_code == 2 and "PNG, SVG, PDF, HTML" in res.output
    assert not (tmp_path / "t.gif").exists()


CHECK = """<script>
window.addEventListener('load', () => {
  const svg = document.querySelector('figure svg').getBoundingClientRect();
  const out = {svgWidth: svg.width, svgHeight: svg.height,
               window: document.documentElement.clientWidth,
               scroll: document.documentElement.scrollWidth,
               tracks: document.querySelectorAll('svg [id^="track-"]').length,
               sections: document.querySelectorAll('section.track').length,
               resources: performance.getEntriesByType('resource').map(e => e.name)};
  const pre = document.createElement('pre'); pre.id = 'check';
  pre.textContent = JSON.stringify(out); document.body.appendChild(pre);
});
</script>"""


@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (make test installs "
                    "Debian's chromium package: apt-get install chromium)")
def test_page_opens_from_disk_in_headless_chromium(tmp_path):
    """Opened as a file:// URL with the network cut off: the figure is drawn within the
    window's width, one track per node, and the page loads no resource at all."""
    page = plot_locate(flagged_frame(), tmp_path / "p.html", title="from disk")
    check = tmp_path / "check.html"
    check.write_text(page.read_text().replace("</body>", CHECK + "</body>"))
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
           "--no-first-run", "--disable-background-networking", "--disable-component-update",
           "--host-resolver-rules=MAP * ~NOTFOUND", f"--user-data-dir={tmp_path / 'profile'}",
           "--window-size=1000,800", "--virtual-time-budget=5000", "--dump-dom",
           check.as_uri()]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    m = re.search(r'<pre id="check">(.*?)</pre>', res.stdout, re.S)
    assert m, f"no check result from chromium: {res.stderr[-2000:]}"
    out = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert out["tracks"] == 3 and out["sections"] == 3
    assert out["resources"] == []
    assert 300 < out["svgWidth"] <= out["window"] and out["svgHeight"] > 150
    assert out["scroll"] <= out["window"]
