"""Lazy re-exports for package ``__init__`` modules.

A package lists which submodule defines each public name; a name is imported on first
access (PEP 562 module ``__getattr__``), so importing one submodule does not load the
others (and their heavy dependencies: numba, scipy).
"""

from __future__ import annotations

import importlib
import sys
from typing import Callable, Mapping


def lazy_exports(package: str, where: Mapping[str, str]
                 ) -> tuple[Callable[[str], object], Callable[[], list[str]]]:
    """``__getattr__`` and ``__dir__`` of a package whose names load on first access.

    Parameters
    ----------
    package : str
        The package's ``__name__``.
    where : mapping of str to str
        Public name -> submodule (relative to ``package``) that defines it.

    Returns
    -------
    getattr, dir : callable
        To assign to the package's ``__getattr__`` and ``__dir__``.
    """
    def __getattr__(name: str) -> object:
        if name not in where:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{where[name]}"), name)
        setattr(importlib.import_module(package), name, value)
        return value

    def __dir__() -> list[str]:
        # the lazy names and what the package module holds now (not this module's globals)
        return sorted(set(where) | set(vars(sys.modules[package])))

    return __getattr__, __dir__
