"""Start-up of the command line: CPU seconds of ``radioloc locate --method M`` on a small log
for every method, and of ``radioloc --help`` (a user who calls ``locate`` per file from a
script pays the start-up every time).

Inputs (about 40 rows each): a range log of :mod:`long_log` (2 tags, 4 anchors, no row
missing) for the methods that range to fixed anchors; two nodes ranged by one moving sensor
for ``closed-form`` and ``newton``; the fuzz suite's valid inputs
(``tests/fuzz/fuzz_harness.py``) for ``gmm``, ``grid-rssi`` (RSS and a calibration) and
``rls``, ``ekf`` (node priors and ranges between nodes). Each command runs once to fill
Python's bytecode cache (``PYTHONPYCACHEPREFIX`` in a temporary folder) and numba's, then
``REPEAT`` times; the row is the median CPU time (user + system) of those runs, the load
average is in its note. Compared with the ``at_most`` bounds of ``targets.py``.

Run alone: ``PYTHONPATH=src python benchmarks/bench_startup.py``.
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_locate import SRC, cpu_of_command  # noqa: E402
from long_log import write_long_log  # noqa: E402
from targets import STARTUP_PREFIX  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
REPEAT = 3
RANGE_METHODS = ("gn", "lsq", "localml", "ransac", "ekf-track", "pf", "smoother")
SENSOR_METHODS = ("closed-form", "newton")
FUZZ_METHODS = ("gmm", "grid-rssi", "rls", "ekf")
#: Every method of ``radioloc locate`` (``targets.py`` gives each the same budget).
METHODS = RANGE_METHODS + SENSOR_METHODS + FUZZ_METHODS


def startup_workload(method: str | None) -> str:
    """The row's name: ``--help`` for None."""
    if method is None:
        return "radioloc --help"
    return f"{STARTUP_PREFIX}{method}, small log (after the first run)"


def sensor_log(folder: Path, samples: int = 20) -> tuple[Path, Path]:
    """Two nodes on straight lines ranged by one sensor circling them (an anchors file with
    a ``time`` column): ``2 * samples`` rows."""
    t = 0.5 * np.arange(samples)
    sensor = 10 * np.c_[np.cos(1.3 * np.arange(samples)), np.sin(1.3 * np.arange(samples))]
    rows = []
    for node, start, v in (("n1", (-3.0, -2.0), (0.4, 0.2)), ("n2", (2.0, -3.0), (-0.3, 0.4))):
        d = np.linalg.norm(np.add(start, t[:, None] * v) - sensor, axis=1)
        rows.append(pd.DataFrame({"time": t, "node": node, "peer": "S", "kind": "range",
                                  "value": d}))
    folder.mkdir(parents=True, exist_ok=True)
    pd.concat(rows).to_csv(folder / "measurements.csv", index=False)
    pd.DataFrame({"id": "S", "time": t, "x": sensor[:, 0], "y": sensor[:, 1]}).to_csv(
        folder / "anchors.csv", index=False)
    return folder / "measurements.csv", folder / "anchors.csv"


def commands(tmp: Path) -> dict[str | None, list[str]]:
    """The command line of every row (``radioloc`` arguments)."""
    meas, anchors = write_long_log(40, tmp / "range", tags=2, anchors=4, missing=0.0)
    out = {None: ["--help"]}
    for m in RANGE_METHODS:
        skip = ["-o", "on_degenerate=skip"] if m in ("gn", "lsq", "localml", "ransac") else []
        out[m] = ["locate", str(meas), "--anchors", str(anchors), "--method", m, *skip]
    meas, anchors = sensor_log(tmp / "sensor")
    for m in SENSOR_METHODS:
        out[m] = ["locate", str(meas), "--anchors", str(anchors), "--method", m]
    sys.path.insert(0, str(ROOT / "tests" / "fuzz"))
    from fuzz_harness import build_scenarios

    (tmp / "fuzz").mkdir()
    scenarios = build_scenarios(tmp / "fuzz")
    for m in FUZZ_METHODS:
        sc = scenarios[m]
        path = tmp / "fuzz" / f"{m}.csv"
        path.write_text("\n".join(",".join(r) for r in sc.rows) + "\n")
        out[m] = sc.args(path)
    for m, args in out.items():
        if m is not None:
            args += ["--out", str(tmp / f"{m}-out.csv")]
    return out


def main(methods: tuple[str, ...] = METHODS) -> list[dict]:
    """One row per method (``methods``) and one for ``--help``."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
        env.update(PYTHONPATH=str(SRC), PYTHONPYCACHEPREFIX=str(tmp / "pycache"))
        for m, args in commands(tmp).items():
            if m is not None and m not in methods:
                continue
            cmd = [sys.executable, "-m", "radioloc.cli", *args]
            first, _ = cpu_of_command(cmd, env)
            runs = [cpu_of_command(cmd, env)[0] for _ in range(REPEAT)]
            cpu = statistics.median(runs)
            load = os.getloadavg()[0]
            print(f"{startup_workload(m)}: {cpu:.2f} s CPU (runs {', '.join(f'{r:.2f}' for r in runs)};"
                  f" first {first:.2f}; load {load:.1f})", flush=True)
            rows.append({"workload": startup_workload(m), "throughput": cpu, "unit": "s (CPU)",
                         "peer": None, "peer_throughput": None, "ratio": None,
                         "note": f"median of {REPEAT} runs ({min(runs):.2f} to {max(runs):.2f} s);"
                                 f" first run {first:.2f} s; load average {load:.1f} on "
                                 f"{os.cpu_count()} cores"})
    return rows


if __name__ == "__main__":
    main(tuple(sys.argv[1:]) or METHODS)
