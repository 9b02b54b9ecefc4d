"""Which third-party modules a source tree imports without declaring them in pyproject.toml.

A module imported unconditionally at module level (not inside a function, a class body's
method, an ``if TYPE_CHECKING:`` block or a ``try`` that handles ``ImportError``) must come
from a base requirement (``[project].dependencies``): importing the package needs it. A module
imported lazily (inside a function or guarded) serves an optional feature: it must come from
a base requirement or from one of the optional extras other than the test and docs tooling.

Modules are mapped to distributions with :func:`importlib.metadata.packages_distributions`
(what is installed); a module whose distribution is not installed is looked up in
``IMPORT_NAMES`` and otherwise taken to share its distribution's name.
"""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from dataclasses import dataclass
from functools import cache
from importlib import metadata
from pathlib import Path

#: extras that hold tooling for developers, not features of the package
TOOLING_EXTRAS = {"dev", "docs"}

#: import name -> distribution, for distributions that may not be installed where the audit
#: runs (an optional extra whose install can fail) and whose import name differs
IMPORT_NAMES = {"sionna": "sionna-rt", "sklearn": "scikit-learn", "mitsuba": "mitsuba",
                "drjit": "drjit"}


def normalise(name: str) -> str:
    """PEP 503 normalised distribution name."""
    return re.sub(r"[-_.]+", "-", name).lower()


@dataclass(frozen=True)
class Import:
    module: str  #: top-level module name
    file: Path
    line: int
    lazy: bool  #: inside a function or guarded by TYPE_CHECKING / except ImportError


def _requirement(spec: str) -> tuple[str, set[str]]:
    """Distribution name and extras of a requirement string such as ``dask[distributed]>=1``."""
    m = re.match(r"\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(?:\[([^\]]*)\])?", spec)
    if m is None:
        raise ValueError(f"cannot read the requirement {spec!r}")
    extras = {normalise(e) for e in (m.group(2) or "").split(",") if e.strip()}
    return normalise(m.group(1)), extras


def _with_extras(name: str, extras: set[str]) -> set[str]:
    """``name`` and the distributions its requested extras add (one level, from its metadata)."""
    out = {name}
    if not extras:
        return out
    try:
        requires = metadata.requires(name) or []
    except metadata.PackageNotFoundError:
        return out
    for spec in requires:
        m = re.search(r"extra\s*==\s*['\"]([^'\"]+)['\"]", spec)
        if m and normalise(m.group(1)) in extras:
            out.add(_requirement(spec)[0])
    return out


def declared(pyproject: Path, tooling: bool = False) -> tuple[set[str], set[str]]:
    """Distributions of the base install and of the optional extras (the tooling extras
    ``dev`` and ``docs`` only with ``tooling``)."""
    project = tomllib.loads(Path(pyproject).read_text())["project"]
    base: set[str] = set()
    for spec in project.get("dependencies", []):
        base |= _with_extras(*_requirement(spec))
    optional: set[str] = set()
    for extra, specs in project.get("optional-dependencies", {}).items():
        if extra in TOOLING_EXTRAS and not tooling:
            continue
        for spec in specs:
            optional |= _with_extras(*_requirement(spec))
    return base, optional


def _guards_import_error(node: ast.Try) -> bool:
    for handler in node.handlers:
        names = []
        if isinstance(handler.type, ast.Name):
            names = [handler.type.id]
        elif isinstance(handler.type, ast.Tuple):
            names = [e.id for e in handler.type.elts if isinstance(e, ast.Name)]
        if {"ImportError", "ModuleNotFoundError"} & set(names):
            return True
    return False


def _is_type_checking(node: ast.If) -> bool:
    test = node.test
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or (
        isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def imports(src: Path, own: str, siblings: tuple[Path, ...] = ()) -> list[Import]:
    """Third-party imports of every ``*.py`` under ``src`` (not the stdlib, not ``own``, not
    a module of ``src`` or of the ``siblings`` folders it puts on its path)."""
    found: list[Import] = []
    local = {f.stem for d in (Path(src), *siblings) for f in Path(d).rglob("*.py")} | {own}

    def visit(node: ast.AST, file: Path, lazy: bool) -> None:
        for child in ast.iter_child_nodes(node):
            child_lazy = lazy or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef,
                                                    ast.Lambda))
            if isinstance(child, ast.Try) and _guards_import_error(child):
                child_lazy = True
            if isinstance(child, ast.If) and _is_type_checking(child):
                child_lazy = True
            names: list[str] = []
            if isinstance(child, ast.Import):
                names = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom) and child.level == 0 and child.module:
                names = [child.module]
            for name in names:
                top = name.split(".")[0]
                if top not in sys.stdlib_module_names and top not in local:
                    found.append(Import(top, file, child.lineno, child_lazy))
            visit(child, file, child_lazy)

    for file in sorted(Path(src).rglob("*.py")):
        visit(ast.parse(file.read_text(), filename=str(file)), file, False)
    return found


@cache
def _installed() -> dict[str, list[str]]:
    """Top-level module -> distributions, of what is installed (read once: it scans every
    distribution's files)."""
    return metadata.packages_distributions()


def distributions_of(module: str) -> set[str]:
    """Distributions that provide the top-level ``module``."""
    installed = _installed().get(module)
    if installed:
        return {normalise(d) for d in installed}
    return {normalise(IMPORT_NAMES.get(module, module))}


def undeclared(src: Path, pyproject: Path, own: str = "radioloc", *,
               tooling: bool = False, siblings: tuple[Path, ...] = ()) -> list[str]:
    """One message per import that ``pyproject`` does not declare where it is needed.

    With ``tooling`` (test suites, benchmarks) every extra, ``dev`` included, declares a
    module wherever it is imported.
    """
    base, optional = declared(pyproject, tooling)
    problems = []
    for imp in imports(src, own, siblings):
        dists = distributions_of(imp.module)
        where = f"{imp.file}:{imp.line}"
        if dists & base:
            continue
        if (imp.lazy or tooling) and dists & optional:
            continue
        if dists & optional:
            problems.append(f"{imp.module} ({where}): imported at module level, but "
                            f"{'/'.join(sorted(dists))} is only in an optional extra")
        else:
            problems.append(f"{imp.module} ({where}): {'/'.join(sorted(dists))} is not a "
                            f"requirement of the base install or of an optional extra")
    return problems
