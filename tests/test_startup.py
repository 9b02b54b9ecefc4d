"""Start-up of the command line: a run imports its own method's module and the libraries that
method uses, nothing more (the CPU budget of a small run is mostly imports; the figures are
rows of ``make bench``, benchmarks/bench_startup.py)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from radioloc.locate.base import MODULE_OF, methods

SRC = Path(__file__).resolve().parent.parent / "src"
HEAVY = ("numpy", "pandas", "scipy", "numba", "sklearn", "matplotlib")

_CHILD = """
import json, sys
sys.argv = ["radioloc", *sys.argv[1:]]
import radioloc.cli
try:
    radioloc.cli.app()
except SystemExit:
    pass
print(json.dumps(sorted(sys.modules)))
"""


def loaded(*args: str) -> set[str]:
    """Modules (packages and submodules) loaded by ``radioloc ARGS`` in a fresh interpreter."""
    res = subprocess.run([sys.executable, "-c", _CHILD, *args], capture_output=True, text=True,
                         timeout=300, env={"PYTHONPATH": str(SRC), "PATH": "/usr/bin:/bin"})
    assert res.returncode == 0, res.stderr[-2000:]
    return set(json.loads(res.stdout.strip().splitlines()[-1]))


def test_every_method_lives_in_the_module_that_method_imports():
    for name, m in methods().items():
        module = MODULE_OF.get(name, name.replace("-", "_"))
        assert m.fn.__module__ == f"radioloc.locate.{module}", name


@pytest.mark.slow
def test_help_loads_no_numerical_library():
    assert not loaded("--help") & set(HEAVY)


@pytest.fixture(scope="module")
def range_log(tmp_path_factory):
    folder = tmp_path_factory.mktemp("startup")
    anchors = {"A1": (0.0, 0.0), "A2": (20.0, 0.0), "A3": (20.0, 20.0), "A4": (0.0, 20.0)}
    (folder / "anchors.csv").write_text(
        "id,x,y\n" + "".join(f"{k},{x},{y}\n" for k, (x, y) in anchors.items()))
    rows = ["time,node,peer,kind,value"]
    for t in range(10):
        p = (5.0 + 0.5 * t, 6.0 + 0.3 * t)
        rows += [f"{t},n1,{a},range,{((p[0] - x) ** 2 + (p[1] - y) ** 2) ** 0.5:.4f}"
                 for a, (x, y) in anchors.items()]
    (folder / "m.csv").write_text("\n".join(rows) + "\n")
    return folder


@pytest.mark.slow
@pytest.mark.parametrize("method, absent", [
    # scipy.special but not scipy.stats or optimize: the health check after every method
    # and lsq's fault exclusion take chi-square quantiles from it
    ("gn", ("numba", "scipy.stats", "scipy.optimize", "sklearn", "matplotlib")),
    ("lsq", ("numba", "scipy.stats", "scipy.optimize", "sklearn", "matplotlib")),
    ("ekf-track", ("numba", "sklearn", "matplotlib")),
])
def test_a_locate_run_loads_only_what_its_method_uses(range_log, tmp_path, method, absent):
    got = loaded("locate", str(range_log / "m.csv"), "--anchors", str(range_log / "anchors.csv"),
                 "--method", method, "--out", str(tmp_path / "out.csv"))
    assert "pandas" in got                       # it ran: the log was read
    assert (tmp_path / "out.csv").is_file()
    assert not got & set(absent), sorted(got & set(absent))
