"""The docs site opened from disk: headless Chromium loads site/index.html as a file:// URL
and follows three of its navigation links, each to a page (not a directory listing).
Skipped when chromium or mkdocs is absent."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path
from urllib.parse import urljoin

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")
                 if shutil.which(n)), None)
pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (make test "
                                 "installs Debian's chromium package: apt-get install chromium)")]


def _dom(url: str, profile: Path) -> str:
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
           "--no-first-run", "--allow-file-access-from-files", f"--user-data-dir={profile}",
           "--virtual-time-budget=5000", "--dump-dom", url]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120).stdout


def test_docs_navigate_from_disk(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    site = tmp_path / "site"
    res = subprocess.run([sys.executable, "-m", "mkdocs", "build", "-q", "-f",
                          str(ROOT / "mkdocs.yml"), "-d", str(site)], capture_output=True,
                         text=True, cwd=ROOT, timeout=600,
                         env={"PATH": "/usr/bin:/bin", "NO_MKDOCS_2_WARNING": "1",
                              "HOME": str(tmp_path)})
    assert res.returncode == 0, res.stderr[-2000:]
    start = (site / "index.html").as_uri()
    home = _dom(start, tmp_path / "profile")
    assert "radioloc" in home
    wanted = ("getting-started.html", "your-own-log/wifi-rtt.html", "api/estimators.html")
    links = {h for h in re.findall(r'href="([^"#?]+)"', home)}
    for target in wanted:
        href = next((h for h in links if h.endswith(target)), None)
        assert href is not None, f"no link to {target} on the home page"
        url = urljoin(start, href)
        assert url.startswith("file://") and url.endswith(".html"), url
        page = _dom(url, tmp_path / "profile")
        assert "<h1" in page and "Index of" not in page, url
