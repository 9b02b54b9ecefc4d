"""Rules the whole library keeps: layers, seeds, equation citations, public API docs."""

from __future__ import annotations

import ast
import importlib
import inspect
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "radioloc"

#: which top-level packages each package may import (besides itself)
ALLOWED = {
    "core": set(),
    "models": {"core"},
    "bounds": {"core", "models"},
    "estimators": {"core", "models", "bounds"},
    "channel": {"core"},
    "sim": {"core", "models", "channel"},
    "io": {"core"},
    "report": {"core"},
    "locate": {"core", "io", "models", "estimators", "bounds"},
    "experiments": {"core", "io", "models", "bounds", "estimators", "channel", "sim", "report",
                    "locate"},
}

PUBLIC_PACKAGES = ["radioloc.estimators", "radioloc.models", "radioloc.bounds", "radioloc.sim",
                   "radioloc.io"]


def _modules():
    for f in sorted(SRC.rglob("*.py")):
        yield f, ast.parse(f.read_text(), filename=str(f))


def _package(f: Path) -> str:
    return f.relative_to(SRC).parts[0].removesuffix(".py")


def test_imports_point_downward_only():
    bad = []
    for f, tree in _modules():
        pkg = _package(f)
        if pkg not in ALLOWED:
            continue
        for node in ast.walk(tree):
            names = []
            if isinstance(node, ast.ImportFrom) and node.module:
                names = [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            for name in names:
                parts = name.split(".")
                if parts[0] == "radioloc" and len(parts) > 1:
                    target = parts[1]
                    if target != pkg and target not in ALLOWED[pkg]:
                        bad.append(f"{f.relative_to(SRC)}:{node.lineno} imports {name}")
    assert not bad, "layer violations:\n" + "\n".join(bad)


_SEEDING = {"default_rng", "SeedSequence", "RandomState", "seed", "block_generator", "stream"}


def test_no_literal_seeds_in_src():
    """Every draw comes from a generator passed in or from a named stream of the
    experiment's seed: no literal seed, no ``*_seed`` setting in an experiment config."""
    bad = []
    for f, tree in _modules():
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                fn = node.func
                name = fn.attr if isinstance(fn, ast.Attribute) else getattr(fn, "id", "")
                if name in _SEEDING and node.args and isinstance(node.args[0], ast.Constant) \
                        and isinstance(node.args[0].value, int):
                    bad.append(f"{f.relative_to(SRC)}:{node.lineno} {name}({node.args[0].value})")
                for kw in node.keywords:
                    if kw.arg in ("random_state", "seed") and isinstance(kw.value, ast.Constant) \
                            and isinstance(kw.value.value, int):
                        bad.append(f"{f.relative_to(SRC)}:{node.lineno} {kw.arg}={kw.value.value}")
            if _package(f) == "experiments" and isinstance(node, ast.AnnAssign) \
                    and isinstance(node.target, ast.Name) and node.target.id.endswith("seed"):
                bad.append(f"{f.relative_to(SRC)}:{node.lineno} config field {node.target.id}")
    assert not bad, "literal seeds:\n" + "\n".join(bad)


_CITATION = re.compile(r"\b(eqs?|equations?)\b(?!\s*=)\.?", re.IGNORECASE)
_GOOD = re.compile(r"eq\. \(\d+\)", re.IGNORECASE)


def _citation_problems(text: str) -> list[str]:
    out = []
    for m in _CITATION.finditer(text):
        if not _GOOD.match(text, m.start()):
            # "equation" as a plain word (no number after it) is prose, not a citation
            tail = text[m.end(): m.end() + 6]
            if m.group(1).lower().startswith("equation") and not re.match(r"\s*\(?\d", tail):
                continue
            out.append(text[m.start(): m.end() + 12].replace("\n", " "))
    return out


def test_equation_citations_have_one_form():
    """Citations read ``eq. (N)``, one number each, so that searching ``eq. (17)`` finds
    the code of eq. 17."""
    bad = []
    files = list(SRC.rglob("*.py")) + sorted((SRC.parents[1] / "docs").glob("*.md"))
    for f in files:
        for lineno, line in enumerate(f.read_text().splitlines(), 1):
            for p in _citation_problems(line):
                bad.append(f"{f.name}:{lineno}: {p!r}")
    assert not bad, f"{len(bad)} citations not in the form 'eq. (N)':\n" + "\n".join(bad[:80])


def test_citation_checker_knows_good_from_bad():
    assert _citation_problems("see eq. (17) and eq. (3)") == []
    assert _citation_problems("Eq. (5) gives it; dataclass(eq=False)") == []
    for text in ("eqs. 16-17", "eq. 17", "eq.(17)", "equation 17", "eq. (16-17)",
                 "(eqs. 13-25)"):
        assert _citation_problems(text), text


def _public(module_name: str):
    mod = importlib.import_module(module_name)
    names = getattr(mod, "__all__", None)
    assert names, f"{module_name} has no __all__"
    for name in names:
        yield name, getattr(mod, name)


@pytest.mark.parametrize("module_name", PUBLIC_PACKAGES)
def test_public_callables_document_parameters_and_returns(module_name):
    """numpydoc on every public callable: a Parameters section when it takes arguments
    (Attributes for a dataclass), a Returns section when a function returns a value."""
    missing = []
    for name, obj in _public(module_name):
        if inspect.isclass(obj):
            targets = []
            if obj.__init__ is not object.__init__:
                targets.append((name, obj, obj.__init__))
            targets += [(f"{name}.{m}", f, f) for m, f in vars(obj).items()
                        if inspect.isfunction(f) and not m.startswith("_")]
        elif callable(obj):
            targets = [(name, obj, obj)]
        else:
            continue
        for label, doc_owner, fn in targets:
            doc = inspect.getdoc(doc_owner) or ""
            try:
                sig = inspect.signature(fn)
            except (TypeError, ValueError):
                continue
            params = [n for n, p in sig.parameters.items()
                      if n not in ("self", "cls") and not n.startswith("_")
                      and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
            if not doc:
                missing.append(f"{label}: no docstring")
                continue
            sections = ("Parameters", "Attributes") if inspect.isclass(doc_owner) else ("Parameters",)
            if params and not any(s in doc for s in sections):
                missing.append(f"{label}: no Parameters section")
            if not inspect.isclass(doc_owner) and "." not in label:
                ret = sig.return_annotation
                if ret not in (None, "None", inspect.Signature.empty) and "Returns" not in doc:
                    missing.append(f"{label}: no Returns section")
    assert not missing, "\n".join(missing)
