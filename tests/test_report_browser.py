"""The report in a real browser: headless Chromium loads out/index.html; every figure loads
and nothing is wider than the window. Skipped when chromium is absent (`make test` installs
Debian's package)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from test_report import write_fake_report

CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")
                 if shutil.which(n)), None)
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (make test "
                                "installs Debian's chromium package: apt-get install chromium)")

WIDTH, HEIGHT = 1280, 900

CHECK = """
<script>
window.addEventListener('load', () => {
  const w = document.documentElement.clientWidth;
  const imgs = Array.from(document.images);
  const broken = imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.src);
  const wide = Array.from(document.querySelectorAll('body *'))
    .filter(e => !e.closest('.wrap') || e.classList.contains('wrap'))
    .filter(e => e.getBoundingClientRect().right > w + 1)
    .map(e => e.tagName + '.' + e.className);
  const board = document.querySelector('table.scoreboard').getBoundingClientRect();
  const out = {images: imgs.length, broken, wide, scrollWidth: document.documentElement.scrollWidth,
               clientWidth: w, scoreboardBottom: board.bottom};
  const pre = document.createElement('pre');
  pre.id = 'check'; pre.textContent = JSON.stringify(out);
  document.body.appendChild(pre);
});
</script>
"""


def _chromium(*args: str, profile: Path) -> subprocess.CompletedProcess:
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           "--no-first-run", "--hide-scrollbars", f"--user-data-dir={profile}",
           f"--window-size={WIDTH},{HEIGHT}", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def test_report_in_headless_chromium(tmp_path):
    out = tmp_path / "out"
    index = write_fake_report(out)
    check = out / "check.html"
    check.write_text(index.read_text().replace("</body>", CHECK + "</body>"))
    res = _chromium("--virtual-time-budget=10000", "--dump-dom", check.as_uri(),
                    profile=tmp_path / "profile")
    m = re.search(r'<pre id="check">(.*?)</pre>', res.stdout, re.S)
    assert m, f"no check result from chromium: {res.stderr[-2000:]}"
    result = json.loads(m.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    assert result["images"] == 4
    assert result["broken"] == []
    assert result["wide"] == [] and result["scrollWidth"] <= result["clientWidth"]
    assert result["scoreboardBottom"] < HEIGHT          # the scoreboard is in the first screen

    shot = tmp_path / "report.png"
    _chromium(f"--screenshot={shot}", index.as_uri(), profile=tmp_path / "profile2")
    assert shot.is_file() and shot.stat().st_size > 10_000
