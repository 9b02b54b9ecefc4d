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


#: Modules of the slow tier: reproductions, whole experiments, real data sets, subprocess
#: and signal tests, the fuzz suites. `make test-fast` deselects them (marker ``slow``);
#: `make test` runs everything.
SLOW_MODULES = {
    "test_experiment_contract", "test_repro_p000", "test_repro_p001", "test_repro_p002",
    "test_repro_p003", "test_repro_p004", "test_real_uwb", "test_runner",
    "test_reliability_interrupt", "test_datasets_tutorials", "test_particle_experiment",
    "test_locate_trackers", "test_mixture_locate", "test_sionna_rt", "test_report_browser",
    "test_rssi_tether", "test_channel_urban", "test_mixture_corridor_repro",
    "test_fingerprint_wifi", "test_p000_network", "test_closed_form_bounds",
    "test_docs_browser", "test_locate_outputs", "test_plausibility", "test_open_models_acceptance",
    "test_docs_snippets", "test_locate_methods_generic",
}


def pytest_collection_modifyitems(config, items):
    for item in items:
        path = item.path
        if path.stem in SLOW_MODULES or path.parent.name == "fuzz":
            item.add_marker(pytest.mark.slow)
