"""Paper 004's corridor at the quick size: wall seconds of ``radioloc reproduce
p004-corridor`` (the longest part of ``make demo``), after one run that fills numba's cache
(its time is in the note, with the load average). Compared with the ``at_most`` bound of
``targets.py``.

Run alone: ``PYTHONPATH=src python benchmarks/bench_corridor.py``.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_budgets import SRC, _radioloc, _timed_run  # noqa: E402


def main() -> list[dict]:
    env = {"PYTHONPATH": str(SRC)}
    with tempfile.TemporaryDirectory() as tmp:
        first = _timed_run(_radioloc("reproduce", "p004-corridor", "--out", f"{tmp}/a"), env)
        warm = _timed_run(_radioloc("reproduce", "p004-corridor", "--out", f"{tmp}/b"), env)
    load = os.getloadavg()[0]
    print(f"reproduce p004-corridor (quick): {first:.0f} s first, {warm:.0f} s warm, load {load:.1f}")
    return [{"workload": "reproduce p004-corridor (quick size)", "throughput": warm,
             "unit": "s (wall)", "peer": None, "peer_throughput": None, "ratio": None,
             "note": f"the run before it (numba's cache filled): {first:.0f} s; load average "
                     f"{load:.1f} on {os.cpu_count()} cores at its end"}]


if __name__ == "__main__":
    main()
