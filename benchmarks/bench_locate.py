"""CPU budgets of ``radioloc locate`` on long logs, measured as whole commands.

Rows (CPU seconds, user + system, of the command's process; compared with ``at_most``
bounds in ``targets.py``), each on a log of :mod:`long_log` (10 tags, 6 anchors, default
options; ``gn`` leaves out the few epochs that do not fix a position):

- ``ekf-track`` and ``gn`` on a 1e6-row log;
- ``pf`` (default particle count) and ``smoother`` on a 1e5-row log.

Each after an untimed run of the same method on a 400-row log (which fills Python's
bytecode cache and numba's). CPU time, not wall time: the machine is shared. Peak memory and the load average are in
each row's note. The start-up on a small log is bench_startup.py.

Run alone: ``PYTHONPATH=src python benchmarks/bench_locate.py [method ...]``.
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from long_log import write_long_log  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src"


def cpu_of_command(args: list[str], env: dict) -> tuple[float, float]:
    """CPU seconds (user + system) and peak memory (MB) of a child command."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    subprocess.run(args, check=True, cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return cpu, after.ru_maxrss / 1024.0


#: (method, rows of the log, extra arguments)
RUNS = (("ekf-track", 1_000_000, []), ("gn", 1_000_000, ["-o", "on_degenerate=skip"]),
        ("pf", 100_000, []), ("smoother", 100_000, []))


def _locate(folder: Path, method: str, out: Path, extra: list[str]) -> list[str]:
    return [sys.executable, "-m", "radioloc.cli", "locate", str(folder / "measurements.csv"),
            "--anchors", str(folder / "anchors.csv"), "--method", method, "--out", str(out),
            *extra]


def _row(workload: str, cpu: float, note: str) -> dict:
    return {"workload": workload, "throughput": cpu, "unit": "s (CPU)", "peer": None,
            "peer_throughput": None, "ratio": None, "note": note}


def main(methods: tuple[str, ...] = tuple(m for m, _, _ in RUNS)) -> list[dict]:
    """The rows above (``methods`` chooses which are measured)."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env.update(PYTHONPATH=str(SRC), PYTHONPYCACHEPREFIX=str(tmp / "pycache"))
        for method, n, extra in RUNS:
            if method not in methods:
                continue
            folder, small = tmp / f"log{n}", tmp / "log400"
            for f, size in ((folder, n), (small, 400)):
                if not f.exists():
                    write_long_log(size, f)
            # untimed: fills the bytecode cache and numba's for this method
            cpu_of_command(_locate(small, method, tmp / "warm.csv", extra), env)
            cpu, mem = cpu_of_command(_locate(folder, method, tmp / f"{method}.csv", extra), env)
            load = os.getloadavg()[0]
            print(f"{method}, {n:.0e} rows: {cpu:.1f} s CPU, peak so far {mem:.0f} MB, "
                  f"load {load:.1f}", flush=True)
            rows.append(_row(f"radioloc locate {method}, {n:.0e}-row log (10 tags, 6 anchors)",
                             cpu, f"peak memory of the commands so far {mem:.0f} MB; load "
                                  f"average {load:.1f} on {os.cpu_count()} cores"))
    return rows


if __name__ == "__main__":
    for r in main(tuple(sys.argv[1:]) or tuple(m for m, _, _ in RUNS)):
        print(r)
