"""Fuzz suite of `radioloc locate`: profiles and the scenario files.

Profiles (environment variable ``RADIOLOC_FUZZ_PROFILE``): ``fast`` (default, part of
``make test``: a few seconds, derandomized so that it is reproducible) and ``long``
(``make fuzz``: >= 10,000 generated cases over the tests of this folder).
``RADIOLOC_FUZZ_EXAMPLES=N`` sets the cases per test in place of the profile's.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fuzz_harness import build_scenarios  # noqa: E402


@pytest.fixture(scope="session")
def scenarios(tmp_path_factory):
    return build_scenarios(tmp_path_factory.mktemp("fuzz-scenarios"))


@pytest.fixture(scope="session")
def workdir(tmp_path_factory):
    return tmp_path_factory.mktemp("fuzz-cases")


def _tally():
    from collections import Counter

    from fuzz_harness import TALLY
    from library_harness import TALLY as LIBRARY

    return Counter(TALLY) + Counter(LIBRARY)


def pytest_sessionfinish(session):
    """With ``RADIOLOC_FUZZ_TALLY=<file>``, every process (each xdist worker) appends its
    outcome counts to that file as one JSON line."""
    import json
    import os

    path = os.environ.get("RADIOLOC_FUZZ_TALLY")
    tally = _tally()
    if path and tally:
        with open(path, "a") as fh:
            fh.write(json.dumps(dict(tally)) + "\n")


def pytest_terminal_summary(terminalreporter):
    import json
    import os
    from collections import Counter

    tally = _tally()
    path = os.environ.get("RADIOLOC_FUZZ_TALLY")
    if path and os.path.exists(path):
        tally = Counter()
        with open(path) as fh:
            for line in fh:
                tally.update(json.loads(line))
    if tally:
        terminalreporter.write_line(f"fuzz outcomes ({sum(tally.values()):,} cases): " + ", ".join(
            f"{k}={v}" for k, v in sorted(tally.items())))
