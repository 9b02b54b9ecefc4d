"""Rows per second of ``radioloc locate --workers 2`` beside one process, on a log of many tags.

A log of :mod:`long_log` with ``tags`` tags (6 anchors, an epoch every 0.1 s per tag),
written to a CSV file; ``radioloc locate`` with ``--method lsq`` and ``--method ekf-track``
(its default, learning each node's settings from its rows), the whole log at once, in one
process and with ``--workers 2`` (:mod:`radioloc.locate.fleet`), each command in a process
of its own: rows per wall-clock second of the whole command (reading, the method, writing)
and its peak resident memory (MB). The two outputs are compared byte for byte. Each after
an untimed run on a 400-row log (bytecode and numba caches).

Run alone: ``PYTHONPATH=src python benchmarks/bench_fleet.py [ROWS TAGS]`` (default 1e5
rows of 100 tags; the issue's size, 1e7 rows of 1e4 tags, is ``1e7 1e4`` and needs several
GB and an hour or more on two cores).
"""

from __future__ import annotations

import filecmp
import os
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_chunked import peak_of_command
from bench_locate import SRC, _locate
from long_log import write_long_log

METHODS = ("lsq", "ekf-track")
#: Options: the whole log at once (the fleet does not read in chunks).
WHOLE = ["-q", "--chunk-rows", "0"]


def main(rows: int = 100_000, tags: int = 100) -> list[dict]:
    """Rows per wall-clock second (``--workers 2`` against one process) for each method."""
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env.update(PYTHONPATH=str(SRC), PYTHONPYCACHEPREFIX=str(tmp / "pycache"))
        small, folder = tmp / "log400", tmp / "log"
        write_long_log(400, small, tags=4)
        write_long_log(rows, folder, tags=tags)
        for method in METHODS:
            extra = WHOLE + (["-o", "on_degenerate=skip"] if method == "lsq" else [])
            peak_of_command(_locate(small, method, tmp / "warm.csv", extra), env)
            one = peak_of_command(_locate(folder, method, tmp / "one.csv", extra), env)
            two = peak_of_command(_locate(folder, method, tmp / "two.csv",
                                          extra + ["--workers", "2"]), env)
            same = filecmp.cmp(tmp / "one.csv", tmp / "two.csv", shallow=False)
            load = os.getloadavg()[0]
            note = (f"{one[0]:.0f} s and {two[0]:.0f} s wall, peak {one[1]:.0f} and "
                    f"{two[1]:.0f} MB; outputs {'equal' if same else 'DIFFERENT'} byte for "
                    f"byte; load average {load:.1f} on {os.cpu_count()} cores")
            print(f"{method}, {rows:.0e} rows, {tags} tags: one process {rows / one[0]:.0f} "
                  f"rows/s, --workers 2 {rows / two[0]:.0f} rows/s; {note}", flush=True)
            out.append({"workload": f"radioloc locate {method} --workers 2, {rows:.0e}-row log "
                                    f"({tags} tags, 6 anchors)",
                        "throughput": rows / two[0], "unit": "rows/s (wall)",
                        "peer": "one process", "peer_throughput": rows / one[0],
                        "ratio": one[0] / two[0], "note": note})
    return out


if __name__ == "__main__":
    args = [int(float(a)) for a in sys.argv[1:3]]
    for r in main(*args):
        print(r)
