"""The documentation's walk-throughs (docs/tutorials/*.py) run end to end at a small size,
so a broken example fails the test suite; each is skipped when its data set is absent."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from radioloc.io import datasets as ds

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = ROOT / "docs" / "tutorials"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"tutorial_{name}", TUTORIALS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _need(dataset: str) -> None:
    if ds.find(dataset) is None:
        pytest.skip(ds.missing_message(dataset))


def test_monte_carlo_tutorial(tmp_path):
    table = _load("monte_carlo").main(tmp_path, small=True)
    gn = table[table.method.str.startswith("Gauss")].rmse_m.to_numpy()
    ls = table[table.method.str.startswith("linear")].rmse_m.to_numpy()
    assert np.all(gn < ls) and (tmp_path / "monte_carlo.png").is_file()


def test_hanyang_tutorial(tmp_path):
    _need("hanyang-uwb-outdoor")
    table = _load("hanyang_uwb").main(tmp_path, small=True)
    assert list(table.method) == ["radioloc gn", "data set LS", "data set ESKF"]
    assert np.all(np.isfinite(table.rmse_2d_m)) and table.rmse_2d_m.iloc[0] < 5.0
    assert (tmp_path / "hanyang.png").is_file()


def test_kolakowski_tutorial(tmp_path):
    _need("kolakowski-ble-fingerprints-2021")
    table = _load("kolakowski_ble").main(tmp_path, small=True)
    assert len(table) == 6 and np.all(table.median_m < 3.0)
    assert (tmp_path / "kolakowski_ble.md").read_text().count("\n| ") == 6
    assert (tmp_path / "kolakowski.png").is_file()


def test_ujiindoorloc_tutorial(tmp_path):
    _need("ujiindoorloc")
    table = _load("ujiindoorloc_wifi").main(tmp_path, small=True)
    assert list(table.method) == ["gmm", "gmm places", "1-NN"]
    assert np.all(table.median_file_units < 30)
    assert (tmp_path / "ujiindoorloc.png").is_file()


def test_docs_site_builds_strict(tmp_path):
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    res = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-q",
                          "-f", str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")],
                         capture_output=True, text=True, cwd=ROOT, timeout=300,
                         env={"PATH": "/usr/bin:/bin", "NO_MKDOCS_2_WARNING": "1",
                              "HOME": str(tmp_path)})
    assert res.returncode == 0, res.stderr[-3000:]
    for page in ("index.html", "api/estimators.html", "your-own-log/hanyang.html"):
        assert (tmp_path / "site" / page).is_file()


@pytest.mark.slow
@pytest.mark.docs_current
@pytest.mark.parametrize("name, dataset", [("kolakowski_ble", "kolakowski-ble-fingerprints-2021"),
                                           ("ujiindoorloc_wifi", "ujiindoorloc"),
                                           ("wifi_rtt", "wifi-rtt-haiyaoyu")])
def test_tutorial_snippet_on_the_page_is_current(tmp_path, name, dataset):
    """The page includes docs/generated/<name>.md: it must equal the tutorial's output at the
    page's size (the full one). `make docs` runs it before the build; `make test` leaves it
    out (the WiFi RTT page alone takes 3-4 minutes)."""
    _need(dataset)
    _load(name).main(tmp_path)
    page = ROOT / "docs" / "generated" / f"{name}.md"
    assert (tmp_path / f"{name}.md").read_text() == page.read_text()
