"""``dir()`` of every package of radioloc lists only names that ``getattr`` resolves, the
lazily imported public names among them."""

from __future__ import annotations

import importlib
import pkgutil

import pytest

import radioloc

PACKAGES = ["radioloc"] + sorted(m.name for m in pkgutil.walk_packages(radioloc.__path__,
                                                                        "radioloc.")
                                 if m.ispkg)


@pytest.mark.parametrize("name", PACKAGES)
def test_every_name_dir_lists_resolves(name):
    package = importlib.import_module(name)
    missing = [n for n in dir(package) if not hasattr(package, n)]
    assert not missing, f"{name}: dir() lists {missing}, which getattr cannot resolve"
    for public in getattr(package, "__all__", ()):
        assert public in dir(package), (name, public)
