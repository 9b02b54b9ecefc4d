"""The live view (`radioloc view`, radioloc.locate.live_view): the rows of a growing estimates
file are served from the offset a page asks for, and in headless Chromium the page changes
when rows are appended."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import threading
import urllib.request

import pandas as pd
import pytest

from radioloc.core.errors import InputError
from radioloc.locate.live_view import new_rows, view_server

HEADER = "time,node,x,y,z,uncertainty_m,cov_xx,cov_xy,cov_yy\n"
CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome")
                 if shutil.which(n)), None)


def rows_text(start: int, n: int, node: str = "tag1") -> str:
    return "".join(f"{0.1 * k:.1f},{node},{k * 0.5},{1.0 + 0.1 * k},1.0,0.3,0.04,0.001,0.05\n"
                   for k in range(start, start + n))


def test_rows_come_from_the_offset_asked_and_a_line_being_written_waits(tmp_path):
    est = tmp_path / "est.csv"
    assert new_rows(est, 0)["rows"] == []                      # not there yet
    est.write_text(HEADER + rows_text(0, 3) + "0.3,tag1,1.5")    # the last line unfinished
    first = new_rows(est, 0)
    assert first["columns"] == ["time", "node", "x", "y", "cov_xx", "cov_xy", "cov_yy"]
    assert [r[:4] for r in first["rows"]] == [[0.0, "tag1", 0.0, 1.0], [0.1, "tag1", 0.5, 1.1],
                                              [0.2, "tag1", 1.0, 1.2]]
    assert new_rows(est, first["offset"])["rows"] == []
    with open(est, "a") as f:
        f.write(",1.3,1.0,0.3,0.04,0.001,0.05\n" + rows_text(4, 2))
    more = new_rows(est, first["offset"])
    assert [r[0] for r in more["rows"]] == [0.3, 0.4, 0.5] and not more["reset"]
    est.write_text(HEADER + rows_text(0, 1))                   # a new run writes it anew
    again = new_rows(est, more["offset"])
    assert again["reset"] and len(again["rows"]) == 1


def test_a_file_without_positions_is_named(tmp_path):
    est = tmp_path / "est.csv"
    est.write_text("time,node,lat,lon\n0,t,1,2\n")
    with pytest.raises(InputError, match="no 'x' column"):
        new_rows(est, 0)


def test_the_server_answers_the_page_the_anchors_and_the_rows(tmp_path):
    est = tmp_path / "est.csv"
    est.write_text(HEADER + rows_text(0, 4))
    pd.DataFrame({"id": ["A", "B", "C"], "x": [0.0, 5.0, 0.0], "y": [0.0, 0.0, 5.0]}).to_csv(
        tmp_path / "anchors.csv", index=False)
    server = view_server(est, tmp_path / "anchors.csv")
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}/"
    try:
        page = urllib.request.urlopen(base, timeout=10).read().decode()
        assert "<canvas" in page and "est.csv" in page
        anchors = json.loads(urllib.request.urlopen(base + "anchors", timeout=10).read())
        assert [a["id"] for a in anchors] == ["A", "B", "C"]
        answer = json.loads(urllib.request.urlopen(base + "rows?from=0", timeout=10).read())
        assert len(answer["rows"]) == 4
        with pytest.raises(urllib.error.HTTPError, match="400"):
            urllib.request.urlopen(base + "rows?from=abc", timeout=10)
    finally:
        server.shutdown()
        server.server_close()


@pytest.mark.slow   # a server and a browser
@pytest.mark.skipif(CHROMIUM is None, reason="chromium is not installed (make test installs "
                    "Debian's chromium package: apt-get install chromium)")
def test_the_page_changes_when_rows_are_appended(tmp_path):
    est = tmp_path / "est.csv"
    est.write_text(HEADER + rows_text(0, 30) + rows_text(0, 30, "tag2"))
    proc = subprocess.Popen([sys.executable, "-m", "radioloc.cli", "view", str(est), "--port",
                             "0", "--poll-s", "0.1"], stderr=subprocess.PIPE, text=True)
    try:
        announced = proc.stderr.readline()
        url = re.search(r"http://\S+/", announced)
        assert url, announced + proc.stderr.read()

        def status() -> str:
            dom = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu",
                                  "--disable-dev-shm-usage", "--no-first-run",
                                  "--disable-background-networking",
                                  f"--user-data-dir={tmp_path / 'profile'}",
                                  "--virtual-time-budget=3000", "--dump-dom", url[0]],
                                 capture_output=True, text=True, timeout=120, check=False).stdout
            found = re.search(r'<p id="status">([^<]*)</p>', dom)
            assert found, dom[-2000:]
            return found[1]

        assert status() == "60 rows, 2 node(s), latest time 2.900 s"
        with open(est, "a") as f:
            f.write(rows_text(30, 10, "tag3"))
        assert status() == "70 rows, 3 node(s), latest time 3.900 s"
    finally:
        proc.terminate()
        proc.wait(timeout=30)
