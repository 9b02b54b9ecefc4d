"""Live tracking through ``radioloc locate --follow`` on a pipe (``ekf-track``).

The log: 8 anchors around a 30 m x 20 m room, 10 tags walking loops, each ranging every
anchor at 10 Hz (8 rows per step; the tags' steps staggered by 10 ms).

- Throughput (sustained): the command is fed the first :data:`STEADY_S` seconds of the log
  and waited for until it has written their estimates (its start and the tracks' starts
  are behind it); then the rest of the log is written into its standard input as fast as
  it takes it: rows per second from that write to the command's exit (and per CPU-second
  the command used meanwhile: the machine is shared). The peer: the batch
  run (``locate`` without ``--follow``) of the same log as a file, rows per second of its
  wall time less the command's start (its run on a header alone).
- Latency: the log written in real time (each step's rows at its time stamp, in one
  write), with ``--reorder-s 0``, once the command has started; for each estimate after
  the tracks' start (the first :data:`STEADY_S` seconds of the log left out), the time
  from the arrival of the step's last row to its line read from the command's output
  (p50, p99). Two ways to release a step: by default a time is processed once a later one
  has come (the next tag's step, 10 ms later: the part after the arrival of that row is
  reported too); with ``--idle-s`` (:data:`IDLE_S`) also once the input has been idle.

Run alone: ``PYTHONPATH=src python benchmarks/bench_stream.py [SECONDS_THROUGHPUT
SECONDS_LATENCY]``.
"""

from __future__ import annotations

import os
import resource
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
#: Seconds of log left out of the measures: the tracks' start (init_s, 2 s) and after.
STEADY_S = 3.0
#: ``--idle-s`` of the second latency run, seconds.
IDLE_S = 0.001


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


class Follower:
    """``cmd`` running, its output lines read by a thread: ``read_at[(time, node)]`` the
    moment each estimate was read."""

    def __init__(self, cmd: list[str]) -> None:
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, text=True, bufsize=1)
        self.read_at: dict[tuple[float, str], float] = {}
        self.latest = -np.inf                        # latest time of an estimate read
        self.thread = threading.Thread(target=self._read)
        self.thread.start()

    def _read(self) -> None:
        header = None
        for line in self.proc.stdout:
            now = time.perf_counter()
            cells = line.split(",")
            if header is None:
                header = cells
                continue
            self.read_at[(float(cells[0]), cells[1])] = now
            self.latest = max(self.latest, float(cells[0]))

    def write(self, text: str) -> None:
        self.proc.stdin.write(text)
        self.proc.stdin.flush()

    def wait_for(self, t: float, timeout_s: float = 300.0) -> None:
        """Until an estimate at ``t`` or later has been read."""
        deadline = time.perf_counter() + timeout_s
        while self.latest < t:
            if time.perf_counter() > deadline or self.proc.poll() is not None:
                raise RuntimeError("the command wrote no estimate in time")
            time.sleep(0.01)

    def cpu_s(self) -> float:
        """CPU seconds the command has used so far (user and system)."""
        with open(f"/proc/{self.proc.pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")

    def end(self) -> None:
        self.proc.stdin.close()
        self.thread.join(timeout=300)
        self.proc.wait(timeout=300)


def throughput(anchors: Path, seconds: float) -> dict:
    rows = log(seconds)
    lines = rows.to_csv(index=False).splitlines(keepends=True)
    warm = int(np.searchsorted(rows["time"].to_numpy(), STEADY_S))
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    run = Follower(command(anchors))
    run.write("".join(lines[:1 + warm]))
    run.wait_for(STEADY_S - 1.0)                     # started, tracks running
    start, cpu_start = time.perf_counter(), run.cpu_s()
    run.write("".join(lines[1 + warm:]))
    run.end()
    wall = time.perf_counter() - start
    done = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (done.ru_utime + done.ru_stime - children.ru_utime - children.ru_stime) - cpu_start
    startup = run_piped(command(anchors), lines[0])
    whole = anchors.with_name("log.csv")
    whole.write_text("".join(lines))
    batch = command(anchors)
    batch[batch.index("-")] = str(whole)
    batch.remove("--follow")
    batch_wall = run_piped(batch, "")
    return {"rows": len(rows) - warm, "wall_s": wall, "startup_s": startup, "cpu_s": cpu,
            "rows_per_s": (len(rows) - warm) / wall, "rows_per_cpu_s": (len(rows) - warm) / cpu,
            "batch_rows_per_s": len(rows) / max(batch_wall - startup, 1e-9)}


def latency(anchors: Path, seconds: float, startup_s: float, *more: str) -> dict:
    rows = log(seconds)
    lines = rows.to_csv(index=False).splitlines(keepends=True)
    run = Follower(command(anchors, "--reorder-s", "0", *more))
    run.write(lines[0])
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
        run.write("".join(lines[1 + i:1 + j]))
        written[i:j] = time.perf_counter()
        i = j
    run.end()
    steps = rows.assign(written=written).groupby(["time", "node"], sort=False)["written"].max()
    stamps = np.unique(times)
    first_written = pd.Series(written).groupby(times).min()
    release = {t: first_written.get(n, np.nan) for t, n in zip(stamps[:-1], stamps[1:])}
    total, after = [], []
    for (t, node), w in steps.items():
        steady = t > times[0] + STEADY_S                # after the tracks' start
        if steady and (t, node) in run.read_at and t in release:
            total.append(run.read_at[(t, node)] - w)
            after.append(run.read_at[(t, node)] - release[t])
    total_ms, after_ms = 1e3 * np.asarray(total), 1e3 * np.asarray(after)
    return {"estimates": len(total), "p50_ms": float(np.percentile(total_ms, 50)),
            "p99_ms": float(np.percentile(total_ms, 99)),
            "p50_after_release_ms": float(np.percentile(after_ms, 50)),
            "p99_after_release_ms": float(np.percentile(after_ms, 99))}


def main(seconds_throughput: float = 120.0, seconds_latency: float = 20.0) -> list[dict]:
    # the reader thread takes the moment a line arrives: it must not wait for the writing
    # thread's turn (5 ms by default)
    switch = sys.getswitchinterval()
    sys.setswitchinterval(1e-4)
    try:
        return measure(seconds_throughput, seconds_latency)
    finally:
        sys.setswitchinterval(switch)


def measure(seconds_throughput: float, seconds_latency: float) -> list[dict]:
    with tempfile.TemporaryDirectory() as folder:
        anchors = Path(folder) / "anchors.csv"
        ANCHORS.to_csv(anchors, index=False)
        load = os.getloadavg()[0]
        rate = throughput(anchors, seconds_throughput)
        lat = latency(anchors, seconds_latency, rate["startup_s"])
        idle = latency(anchors, seconds_latency, rate["startup_s"], "--idle-s", str(IDLE_S))
        load_end = os.getloadavg()[0]
    print(f"load average {load:.1f} at the start, {load_end:.1f} at the end")
    print(f"--follow on a pipe, sustained: {rate['rows']} rows in {rate['wall_s']:.2f} s: "
          f"{rate['rows_per_s']:.0f} rows/s ({rate['rows_per_cpu_s']:.0f} rows per CPU-second "
          f"of the command, {rate['cpu_s']:.2f} s); the batch run of the same log: "
          f"{rate['batch_rows_per_s']:.0f} rows/s (start {rate['startup_s']:.2f} s taken off)")
    feed = (f"real-time feed of {TAGS} tags x 8 anchors at {RATE_HZ:g} Hz, --reorder-s 0, "
            "arrival of a step's last row to its estimate read")
    print(f"latency, {feed}, {lat['estimates']} estimates: p50 {lat['p50_ms']:.1f} ms, "
          f"p99 {lat['p99_ms']:.1f} ms (after the releasing row, the next step's, "
          f"p50 {lat['p50_after_release_ms']:.1f} ms, p99 {lat['p99_after_release_ms']:.1f} ms)")
    print(f"latency, {feed}, --idle-s {IDLE_S:g}, {idle['estimates']} estimates: "
          f"p50 {idle['p50_ms']:.1f} ms, p99 {idle['p99_ms']:.1f} ms")
    loads = f"load average {load:.1f} at the start, {load_end:.1f} at the end"
    return [{"workload": "locate --follow ekf-track, 8 anchors x 10 tags at 10 Hz (pipe)",
             "throughput": rate["rows_per_s"], "unit": "rows/s",
             "peer": "locate --method ekf-track (batch, same log)",
             "peer_throughput": rate["batch_rows_per_s"],
             "ratio": rate["rows_per_s"] / rate["batch_rows_per_s"],
             "note": f"p99 latency {idle['p99_ms']:.1f} ms with --idle-s {IDLE_S:g}, "
                     f"{lat['p99_ms']:.1f} ms without (row arrival to estimate read); "
                     f"{loads}"},
            {"workload": f"locate --follow ekf-track, {feed}, --idle-s {IDLE_S:g}: p99 latency",
             "throughput": idle["p99_ms"], "unit": "ms", "peer": None,
             "peer_throughput": None, "ratio": None,
             "note": f"p50 {idle['p50_ms']:.1f} ms over {idle['estimates']} estimates; without "
                     f"--idle-s p99 {lat['p99_ms']:.1f} ms (a step waits for the next row, 10 "
                     f"ms later); {loads}"}]


if __name__ == "__main__":
    main(*(float(a) for a in sys.argv[1:3]))
