"""Peak memory and throughput of ``radioloc locate`` on long logs read in chunks.

Rows, for ``ekf-track`` (its defaults: the settings learned in a first pass), ``lsq`` and
``gn`` (``lsq`` and ``gn`` with ``-o on_degenerate=skip``: the log has a few epochs that do not
fix a position) on a log of :mod:`long_log` (10 tags,
6 anchors) written to a CSV file, each command in a process of its own:

- peak resident memory (MB, the process's ``ru_maxrss``) of the chunked run (the default
  ``--chunk-rows 200000``); its peer, the whole log at once (``--chunk-rows 0``), on the
  1e6-row log only (on 1e7 rows it needs several GB); the budget is 1 GB on 1e7 rows;
- rows per wall-clock second of the same commands (the machine is shared: the load average
  is in each row's note).

Each after an untimed run of the same method on a 400-row log (bytecode and numba caches).

Run alone: ``PYTHONPATH=src python benchmarks/bench_chunked.py [ROWS ...]`` (default 1e6
and 1e7, the budget's log; ``1e7`` takes about ten minutes a method on two cores).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_locate import SRC, ROOT, _locate  # noqa: E402
from long_log import write_long_log  # noqa: E402

METHODS = ("ekf-track", "lsq", "gn")
#: Rows of the logs whose whole run is measured too (the peer).
WHOLE_UP_TO = 1_000_000


#: Runs a command and writes its peak resident memory (kB) as the last line of standard
#: error. Linux keeps a process's peak across exec, so a command started by this (large)
#: process would report at least this process's memory; started by the small trampoline,
#: it reports its own.
TRAMPOLINE = ("import os, subprocess, sys\n"
              "child = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
              "_, status, usage = os.wait4(child.pid, 0)\n"
              "print(usage.ru_maxrss, file=sys.stderr)\n"
              "sys.exit(os.waitstatus_to_exitcode(status))\n")


def peak_of_command(args: list[str], env: dict) -> tuple[float, float]:
    """Wall-clock seconds and peak resident memory (MB) of one command (in a process
    started by :data:`TRAMPOLINE`)."""
    start = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", TRAMPOLINE, *args], cwd=ROOT, env=env,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, check=False)
    wall = time.perf_counter() - start
    err = res.stderr.decode(errors="replace").rstrip().splitlines()
    if res.returncode != 0 or not err:
        raise RuntimeError(f"{' '.join(args)} failed: {chr(10).join(err)}")
    return wall, int(err[-1]) / 1024.0


def _rows(method: str, n: int, chunked: tuple[float, float], whole: tuple[float, float] | None,
          note: str) -> list[dict]:
    name = f"radioloc locate {method} --chunk-rows 200000, {n:.0e}-row log (10 tags, 6 anchors)"
    peer = "the whole log at once (--chunk-rows 0)" if whole is not None else None
    out = []
    for what, unit, ours, theirs in (
            ("peak memory", "MB (peak RSS)", chunked[1], None if whole is None else whole[1]),
            ("throughput", "rows/s (wall)", n / chunked[0],
             None if whole is None else n / whole[0])):
        out.append({"workload": f"{name}: {what}", "throughput": ours, "unit": unit,
                    "peer": peer, "peer_throughput": theirs,
                    "ratio": None if theirs is None else ours / theirs, "note": note})
    return out


def main(sizes: tuple[int, ...] = (1_000_000, 10_000_000)) -> list[dict]:
    """The rows above for logs of ``sizes`` rows."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env.update(PYTHONPATH=str(SRC), PYTHONPYCACHEPREFIX=str(tmp / "pycache"))
        small = tmp / "log400"
        write_long_log(400, small)
        for n in sizes:
            folder = tmp / f"log{n}"
            write_long_log(n, folder)
            for method in METHODS:
                extra = ["-q"] + ([] if method == "ekf-track" else ["-o", "on_degenerate=skip"])
                peak_of_command(_locate(small, method, tmp / "warm.csv", extra), env)
                chunked = peak_of_command(_locate(folder, method, tmp / "c.csv", extra), env)
                whole = (peak_of_command(_locate(folder, method, tmp / "w.csv",
                                                 extra + ["--chunk-rows", "0"]), env)
                         if n <= WHOLE_UP_TO else None)
                load = os.getloadavg()[0]
                note = (f"load average {load:.1f} on {os.cpu_count()} cores; chunked "
                        f"{chunked[0]:.0f} s wall" + ("" if whole is None else
                                                      f", whole {whole[0]:.0f} s wall"))
                print(f"{method}, {n:.0e} rows: chunked {chunked[1]:.0f} MB, "
                      f"{n / chunked[0]:.0f} rows/s" + ("" if whole is None else
                      f"; whole {whole[1]:.0f} MB, {n / whole[0]:.0f} rows/s") +
                      f"; load {load:.1f}", flush=True)
                rows += _rows(method, n, chunked, whole, note)
            (folder / "measurements.csv").unlink()
    return rows


if __name__ == "__main__":
    for r in main(tuple(int(float(a)) for a in sys.argv[1:]) or (1_000_000, 10_000_000)):
        print(r)
