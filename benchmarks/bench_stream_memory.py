"""Memory of ``radioloc locate --follow`` (``ekf-track``) over an endless stream: the
resident memory of the command as 1e7 rows go through it on a pipe.

The log of :mod:`bench_stream` (8 anchors, 10 tags at 10 Hz), generated block by block
(:data:`BLOCK_S` seconds of log at a time, its time stamps moved on each time) and written
into the command's standard input as fast as it takes it; its estimates are read and
dropped. The command's resident memory (``VmRSS``) is read after every block. The budget:
flat within 10 % over 1e7 rows, measured from the first reading after
:data:`WARM_ROWS` rows (imports, caches and the tracks' start are behind it) to the largest
reading after it.

Run alone: ``PYTHONPATH=src python benchmarks/bench_stream_memory.py [ROWS]`` (default 1e7;
about five minutes on two cores).
"""

from __future__ import annotations

import os
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_stream import ANCHORS, command, log

#: Seconds of log generated per block.
BLOCK_S = 200.0
#: Rows streamed before the first reading that counts.
WARM_ROWS = 1_000_000


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS")


def main(rows: int = 10_000_000) -> list[dict]:
    """The memory row: growth of the resident memory over ``rows`` streamed rows."""
    import subprocess

    block = log(BLOCK_S)
    text_rows = block.to_csv(index=False, header=False, float_format="%.6f").splitlines()
    times = block["time"].to_numpy()
    rest = [line.split(",", 1)[1] for line in text_rows]
    with tempfile.TemporaryDirectory() as tmp:
        anchors = Path(tmp) / "anchors.csv"
        ANCHORS.to_csv(anchors, index=False)
        env = dict(os.environ, PYTHONPATH=str(Path(__file__).resolve().parents[1] / "src"))
        proc = subprocess.Popen(command(anchors), stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                                env=env)
        drain = threading.Thread(target=lambda: [None for _ in proc.stdout], daemon=True)
        drain.start()
        proc.stdin.write("time,node,peer,kind,value\n")
        start, sent, k, readings = time.perf_counter(), 0, 0, []
        while sent < rows:
            offset = k * BLOCK_S
            proc.stdin.write("".join(f"{t + offset:.6f},{r}\n" for t, r in zip(times, rest)))
            proc.stdin.flush()
            sent += len(rest)
            k += 1
            readings.append((sent, rss_mb(proc.pid)))
        proc.stdin.close()
        proc.wait(timeout=600)
        wall = time.perf_counter() - start
    counted = [mb for n, mb in readings if n >= WARM_ROWS]
    first, peak = counted[0], max(counted)
    growth = peak / first - 1.0
    note = (f"{sent:,} rows in {wall:.0f} s; RSS {first:.0f} MB after {WARM_ROWS:,} rows, "
            f"at most {peak:.0f} MB after; readings every {len(rest):,} rows; load average "
            f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"memory growth {100 * growth:.1f} %: {note}", flush=True)
    return [{"workload": f"radioloc locate --follow ekf-track, {rows:.0e} streamed rows: "
                         "memory growth after the first 1e6 rows",
             "throughput": 100 * growth, "unit": "% (RSS)", "peer": None,
             "peer_throughput": None, "ratio": None, "note": note}]


if __name__ == "__main__":
    for r in main(*(int(float(a)) for a in sys.argv[1:2])):
        print(r)
