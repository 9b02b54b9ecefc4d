"""The README's tables of experiments and `locate` methods list exactly what the command line
offers (`radioloc list`, `radioloc methods`)."""

import re
from pathlib import Path

from radioloc.experiments.base import registry
from radioloc.locate import methods

README = (Path(__file__).resolve().parents[1] / "README.md").read_text()


def _first_column_ids(header: str) -> set[str]:
    """The backticked ids in the first column of the table whose header row starts with
    ``| header |``."""
    lines = README.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith(f"| {header} |"))
    ids = set()
    for ln in lines[start + 2:]:
        if not ln.startswith("|"):
            break
        ids |= set(re.findall(r"`([^`]+)`", ln.split("|")[1]))
    return ids


def test_readme_lists_every_experiment():
    assert _first_column_ids("experiment") == set(registry())


def test_readme_lists_every_locate_method():
    assert _first_column_ids("method") == set(methods())
