"""Live tracking through ``radioloc locate --follow`` on a pipe (``ekf-track``).

The log: 8 anchors around a 30 m x 20 m room, 10 tags walking loops, each ranging every
anchor at 10 Hz (8 rows per step; the tags' steps staggered by 10 ms).

- Throughput: the whole log written into the command's standard input as fast as it takes
  it; rows per second of wall time, the command's start (its run on a header alone) taken
  off; the peer: the batch run (``locate`` without ``--follow``) of the same log as a file.
- Latency: the log written in real time (each step's rows at its time stamp), with
  ``--reorder-s 0``, once the command has started; for each estimate after the tracks'
  start (the first :data:`STEADY_S` seconds of the log left out), the time from the arrival of the step's last row to
  its line read from the command's output (p50, p99), and the part of it after the arrival
  of the row that releases the step (the next later time stamp: a time is processed once a
  later one has come).

Run alone: ``PYTHONPATH=src python benchmarks/bench_stream.py [SECONDS_THROUGHPUT
SECONDS_LATENCY]``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pandas as pd

ANCHORS = pd.DataFrame({"id": [f"A{i}" for i in range(8)],
                        "x": [0.0, 15.0, 30.0, 30.0, 30.0, 15.0, 0.0, 0.0],
                        "y": [0.0, 0.0, 0.0, 10.0, 20.0, 20.0, 20.0, 10.0]})
TAGS, RATE_HZ = 10, 10.0
#: Seconds of log left out of the latency: the tracks' start (init_s, 2 s) and after.
STEADY_S = 3.0


def log(seconds: float, seed: int = 0) -> pd.DataFrame:
    """Rows ``time, node, peer, kind, value`` of the benchmark's log, in time order."""
    rng = np.random.default_rng(seed)
    steps = int(seconds * RATE_HZ)
    frames = []
    for k in range(TAGS):
        t = np.round(np.arange(steps) / RATE_HZ + k * 0.01, 6)
        xy = np.stack([15 + 10 * np.cos(t / 8 + k), 10 + 6 * np.sin(t / 8 + k)], axis=-1)
        d = np.linalg.norm(xy[:, None, :] - ANCHORS[["x", "y"]].to_numpy()[None], axis=-1)
        d = d + 0.1 * rng.standard_normal(d.shape)
        frames.append(pd.DataFrame({"time": np.repeat(t, 8), "node": f"tag{k}",
                                    "peer": np.tile(ANCHORS["id"].to_numpy(), steps),
                                    "kind": "range", "value": d.ravel()}))
    return pd.concat(frames).sort_values(["time", "node"], kind="stable").reset_index(drop=True)


def command(anchors: Path, *more: str) -> list[str]:
    return [sys.executable, "-m", "radioloc.cli", "locate", "-", "--anchors", str(anchors),
            "--method", "ekf-track", "--follow", "-q", *more]


def run_piped(cmd: list[str], text: str) -> float:
    """Wall seconds of ``cmd`` with ``text`` written into its standard input."""
    start = time.perf_counter()
    subprocess.run(cmd, input=text, text=True, check=True, stdout=subprocess.DEVNULL,
                   stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def throughput(anchors: Path, seconds: float) -> dict:
    rows = log(seconds)
    text = rows.to_csv(index=False)
    startup = run_piped(command(anchors), text.splitlines(keepends=True)[0])
    wall = run_piped(command(anchors), text)
    whole = anchors.with_name("log.csv")
    whole.write_text(text)
    batch = command(anchors)
    batch[batch.index("-")] = str(whole)
    batch.remove("--follow")
    batch_wall = run_piped(batch, "")
    return {"rows": len(rows), "wall_s": wall, "startup_s": startup,
            "rows_per_s": len(rows) / max(wall - startup, 1e-9),
            "batch_rows_per_s": len(rows) / max(batch_wall - startup, 1e-9)}


def latency(anchors: Path, seconds: float, startup_s: float) -> dict:
    rows = log(seconds)
    lines = rows.to_csv(index=False).splitlines(keepends=True)
    proc = subprocess.Popen(command(anchors, "--reorder-s", "0"), stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            bufsize=1)
    read_at: dict[tuple[float, str], float] = {}

    def reader() -> None:
        header = None
        for line in proc.stdout:
            now = time.perf_counter()
            cells = line.split(",")
            if header is None:
                header = cells
                continue
            read_at[(float(cells[0]), cells[1])] = now

    thread = threading.Thread(target=reader)
    thread.start()
    proc.stdin.write(lines[0])
    proc.stdin.flush()
    time.sleep(startup_s + 1.0)                       # the command's start
    written = np.empty(len(rows))
    times = rows["time"].to_numpy()
    start = time.perf_counter() - times[0]
    i = 0
    while i < len(rows):                              # one write per time stamp, on time
        j = int(np.searchsorted(times, times[i], side="right"))
        delay = start + times[i] - time.perf_counter()
        if delay > 0:
            time.sleep(delay)
        proc.stdin.write("".join(lines[1 + i:1 + j]))
        proc.stdin.flush()
        written[i:j] = time.perf_counter()
        i = j
    proc.stdin.close()
    thread.join(timeout=120)
    proc.wait(timeout=120)
    steps = rows.assign(written=written).groupby(["time", "node"], sort=False)["written"].max()
    stamps = np.unique(times)
    first_written = pd.Series(written).groupby(times).min()
    release = {t: first_written.get(n, np.nan) for t, n in zip(stamps[:-1], stamps[1:])}
    total, after = [], []
    for (t, node), w in steps.items():
        steady = t > times[0] + STEADY_S                # after the tracks' start
        if steady and (t, node) in read_at and t in release:
            total.append(read_at[(t, node)] - w)
            after.append(read_at[(t, node)] - release[t])
    total_ms, after_ms = 1e3 * np.asarray(total), 1e3 * np.asarray(after)
    return {"estimates": len(total), "p50_ms": float(np.percentile(total_ms, 50)),
            "p99_ms": float(np.percentile(total_ms, 99)),
            "p50_after_release_ms": float(np.percentile(after_ms, 50)),
            "p99_after_release_ms": float(np.percentile(after_ms, 99))}


def main(seconds_throughput: float = 30.0, seconds_latency: float = 20.0) -> list[dict]:
    with tempfile.TemporaryDirectory() as folder:
        anchors = Path(folder) / "anchors.csv"
        ANCHORS.to_csv(anchors, index=False)
        load = os.getloadavg()[0]
        rate = throughput(anchors, seconds_throughput)
        lat = latency(anchors, seconds_latency, rate["startup_s"])
    print(f"load average {load:.1f}")
    print(f"--follow on a pipe: {rate['rows']} rows in {rate['wall_s']:.2f} s "
          f"(start {rate['startup_s']:.2f} s): {rate['rows_per_s']:.0f} rows/s; the batch "
          f"run of the same log: {rate['batch_rows_per_s']:.0f} rows/s")
    print(f"latency, real-time feed of {TAGS} tags x 8 anchors at {RATE_HZ:g} Hz, "
          f"--reorder-s 0, {lat['estimates']} estimates: arrival of a step's last row to its "
          f"estimate read p50 {lat['p50_ms']:.1f} ms, p99 {lat['p99_ms']:.1f} ms; after the "
          f"releasing row p50 {lat['p50_after_release_ms']:.1f} ms, "
          f"p99 {lat['p99_after_release_ms']:.1f} ms")
    return [{"workload": "locate --follow ekf-track, 8 anchors x 10 tags at 10 Hz (pipe)",
             "throughput": rate["rows_per_s"], "unit": "rows/s",
             "peer": "locate --method ekf-track (batch, same log)",
             "peer_throughput": rate["batch_rows_per_s"],
             "ratio": rate["rows_per_s"] / rate["batch_rows_per_s"],
             "note": f"p99 latency {lat['p99_ms']:.1f} ms (row arrival to estimate read)"}]


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:3]))
