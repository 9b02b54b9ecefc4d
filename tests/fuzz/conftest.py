"""Fuzz suite of `radioloc locate`: profiles and the scenario files.

Profiles (environment variable ``RADIOLOC_FUZZ_PROFILE``): ``fast`` (default, part of
``make test``: a few seconds, derandomized so that it is reproducible) and ``long``
(``make fuzz``: >= 10,000 generated cases over the tests of this folder).
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


def pytest_terminal_summary(terminalreporter):
    from fuzz_harness import TALLY

    if TALLY:
        terminalreporter.write_line("fuzz outcomes: " + ", ".join(
            f"{k}={v}" for k, v in sorted(TALLY.items())))
