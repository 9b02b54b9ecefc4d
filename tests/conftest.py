"""Shared test set-up.

Tests write only under pytest's temporary directories: the toolkit's cache folder
(``RADIOLOC_CACHE``, e.g. the ray-tracing cache, default ``~/.cache/radioloc``) is pointed at
one temporary folder per test run (shared by the xdist workers of that run; the cache
writes atomically).
"""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _radioloc_cache_in_tmp(tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    root = base.parent if base.name.startswith("popen-gw") else base
    old = os.environ.get("RADIOLOC_CACHE")
    os.environ["RADIOLOC_CACHE"] = str(root / "radioloc-cache")
    yield
    if old is None:
        os.environ.pop("RADIOLOC_CACHE", None)
    else:
        os.environ["RADIOLOC_CACHE"] = old
