"""The benchmark targets of benchmarks/targets.py: verdicts on known rows, and every target
naming a row that the committed benchmarks/results.json (written by `make bench`) holds, so a
renamed row cannot silently drop its target."""

import json
import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCH))
import targets  # noqa: E402


@pytest.mark.parametrize("throughput, ratio, expected", [
    (6e8, 25.0, True),      # both parts met
    (4.9e8, 25.0, False),   # throughput short
    (6e8, 19.9, False),     # ratio short
    (6e8, None, False),     # a ratio target with no peer measured is not met
])
def test_meets_needs_every_part_of_the_target(throughput, ratio, expected):
    target = {"throughput": 5e8, "ratio": 20.0}
    assert targets.meets({"throughput": throughput, "ratio": ratio}, target) is expected


@pytest.mark.parametrize("value, expected", [(59.0, True), (60.0, True), (61.0, False),
                                             (None, False)])
def test_an_at_most_target_is_an_upper_bound(value, expected):
    assert targets.meets({"throughput": value, "ratio": None}, {"at_most": 60.0}) is expected


def test_describe_reads_as_the_issue_states_it():
    assert targets.describe({"at_most": 2500}) == "<= 2,500"
    assert targets.describe({"throughput": 5e8, "ratio": 20.0}) == ">= 500 M/s, >= 20x"
    assert targets.describe({"throughput": 1e4}) == ">= 10 k/s"
    assert targets.describe({"throughput": 300.0}) == ">= 300/s"


def test_every_target_names_a_measured_row_and_every_bound_a_target():
    rows = json.loads((BENCH / "results.json").read_text())
    measured = {(r["workload"], r["peer"]) for r in rows}
    missing = [k for k in targets.TARGETS if k not in measured]
    assert not missing, f"targets with no row in results.json: {missing}"
    workloads = {w for w, _ in targets.TARGETS}
    assert set(targets.BOUNDS) <= workloads
    for r in rows:
        t = targets.target_of(r)
        if t is not None and "meets_target" in r:
            assert r["meets_target"] is targets.meets(r, t)
