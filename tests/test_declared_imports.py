"""Every third-party module that ``src/`` imports is declared in pyproject.toml where it is
needed: the base install for module-level imports, the base or an optional extra for imports
made lazily by an optional feature (tests/import_audit.py)."""

from __future__ import annotations

import re
from pathlib import Path

from import_audit import declared, imports, undeclared

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "radioloc"
PYPROJECT = ROOT / "pyproject.toml"


def test_every_import_of_src_is_declared():
    problems = undeclared(SRC, PYPROJECT)
    assert not problems, "undeclared imports:\n" + "\n".join(problems)


#: benchmark peers that `make bench` installs without their dependencies (their metadata pins
#: an older numpy than the project's): not declared in an extra, on purpose
BENCH_ONLY = ("particles",)


def test_tests_and_benchmarks_import_only_declared_tooling():
    folders = (ROOT / "tests", ROOT / "benchmarks")
    problems = [p for d in folders
                for p in undeclared(d, PYPROJECT, tooling=True, siblings=folders)
                if not p.startswith(tuple(f"{m} (" for m in BENCH_ONLY))]
    assert not problems, "undeclared imports:\n" + "\n".join(problems)


def test_removing_a_base_dependency_names_the_module_and_file(tmp_path):
    text = PYPROJECT.read_text()
    edited = re.sub(r'^\s*"click[^"]*",\n', "", text, flags=re.M)
    assert edited != text, "pyproject.toml no longer lists click"
    (tmp_path / "pyproject.toml").write_text(edited)
    problems = undeclared(SRC, tmp_path / "pyproject.toml")
    assert problems and all(p.startswith("click (") for p in problems)
    assert any("cli.py" in p for p in problems)


def _fixture(tmp_path: Path, source: str, deps: str, extras: str) -> list[str]:
    pkg = tmp_path / "src" / "demo"
    pkg.mkdir(parents=True)
    (pkg / "__init__.py").write_text(source)
    (tmp_path / "pyproject.toml").write_text(
        f'[project]\nname = "demo"\ndependencies = [{deps}]\n'
        f'[project.optional-dependencies]\n{extras}\n')
    return undeclared(pkg, tmp_path / "pyproject.toml", own="demo")


def test_module_level_import_of_an_extra_is_refused(tmp_path):
    problems = _fixture(tmp_path, "import numpy\nimport pyarrow\n", '"numpy>=1"',
                        'parquet = ["pyarrow>=14"]')
    assert len(problems) == 1 and problems[0].startswith("pyarrow (")
    assert "module level" in problems[0] and "__init__.py:2" in problems[0]


def test_lazy_import_of_an_extra_is_accepted_but_not_of_a_tooling_extra(tmp_path):
    source = ("def write():\n    import pyarrow\n"
              "try:\n    import hypothesis\nexcept ImportError:\n    hypothesis = None\n")
    problems = _fixture(tmp_path, source, "",
                        'parquet = ["pyarrow>=14"]\ndev = ["hypothesis>=6"]')
    assert len(problems) == 1 and problems[0].startswith("hypothesis (")


def test_extras_of_a_requirement_count_as_declared():
    base, optional = declared(PYPROJECT)
    assert "distributed" in optional  # from dask[distributed] in the cluster extra
    assert {"numpy", "click"} <= base


def test_imports_skip_the_stdlib_and_the_package_itself(tmp_path):
    pkg = tmp_path / "demo"
    pkg.mkdir()
    (pkg / "a.py").write_text("import os, json\nfrom demo import b\nfrom . import c\nimport yaml\n")
    assert [i.module for i in imports(pkg, "demo")] == ["yaml"]
