"""Reproductions of the papers: one module per experiment, discovered automatically.

Every module in this package that defines a class decorated with
:func:`radioloc.experiments.base.register` becomes a command-line experiment.
"""

from __future__ import annotations

import importlib
import pkgutil

_INFRA = {"base", "runner", "benchmark"}   # benchmark: `radioloc benchmark`, not a paper


def discover() -> None:
    """Import every experiment module of this package (idempotent)."""
    for mod in pkgutil.iter_modules(__path__):
        if mod.name not in _INFRA and not mod.name.startswith("_"):
            importlib.import_module(f"{__name__}.{mod.name}")
