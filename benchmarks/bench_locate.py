"""CPU budgets of ``radioloc locate`` on long logs, measured as whole commands.

Rows (CPU seconds, user + system, of the command's process; compared with ``at_most``
bounds in ``targets.py``):

- ``ekf-track`` on a 1e6-row log of :mod:`long_log` (10 tags, 6 anchors, default options);
- ``pf`` (default particle count) on a 1e5-row log of the same kind;
- start-up: ``ekf-track`` on a 40-row log, after one run that fills Python's bytecode cache
  (``PYTHONPYCACHEPREFIX`` in a temporary folder) and numba's.

CPU time, not wall time: the machine is shared. Peak memory is in each row's note.

Run alone: ``PYTHONPATH=src python benchmarks/bench_locate.py``.
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


def _locate(folder: Path, method: str, out: Path) -> list[str]:
    return [sys.executable, "-m", "radioloc.cli", "locate", str(folder / "measurements.csv"),
            "--anchors", str(folder / "anchors.csv"), "--method", method, "--out", str(out)]


def _row(workload: str, cpu: float, note: str) -> dict:
    return {"workload": workload, "throughput": cpu, "unit": "s (CPU)", "peer": None,
            "peer_throughput": None, "ratio": None, "note": note}


def main(sizes: tuple[int, int] = (1_000_000, 100_000), startup: bool = True,
         methods: tuple[str, ...] = ("ekf-track", "pf")) -> list[dict]:
    """The rows above (``startup`` and ``methods`` choose which are measured)."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env.update(PYTHONPATH=str(SRC), PYTHONPYCACHEPREFIX=str(tmp / "pycache"))
        small = tmp / "log40"
        write_long_log(40, small, tags=2, anchors=4)
        first, _ = cpu_of_command(_locate(small, "ekf-track", tmp / "a.csv"), env)
        if startup:
            warm, mem = cpu_of_command(_locate(small, "ekf-track", tmp / "b.csv"), env)
            print(f"locate start-up (40 rows): {first:.2f} s CPU first run, {warm:.2f} s after")
            rows.append(_row("radioloc locate start-up, 40-row log (after the first run)", warm,
                             f"first run {first:.2f} s CPU (fills the bytecode cache); "
                             f"peak memory of the commands so far {mem:.0f} MB"))
        for method, n in (("ekf-track", sizes[0]), ("pf", sizes[1])):
            if method not in methods:
                continue
            folder = tmp / f"log{n}"
            write_long_log(n, folder)
            cpu, mem = cpu_of_command(_locate(folder, method, tmp / f"{method}.csv"), env)
            print(f"{method}, {n:.0e} rows: {cpu:.1f} s CPU, peak so far {mem:.0f} MB")
            rows.append(_row(f"radioloc locate {method}, {n:.0e}-row log (10 tags, 6 anchors)",
                             cpu, f"peak memory of the commands so far {mem:.0f} MB"))
    return rows


if __name__ == "__main__":
    for r in main():
        print(r)
