"""Run every benchmark of ``MODULES`` whose ``main()`` returns result rows and write
``results.json`` and ``RESULTS.md`` beside this file.

Each row: ``{"workload", "throughput", "unit", "peer", "peer_throughput", "ratio", "limit",
"limit_fraction"}``; ``ratio`` is ours / peer measured in the same process (the machine is
shared, so ratios are what count). ``limit`` is this machine's bound for the workload,
derived at run time (see README.md, "Machine limits"): a bench row declares the work of one
unit as ``"bytes_per_unit"`` (minimum bytes that must cross the memory bus) and/or
``"flops_per_unit"`` (floating-point operations), or the module exports ``BYTES_PER_UNIT`` /
``FLOPS_PER_UNIT`` dicts keyed by workload; ``limit = min(bandwidth / bytes_per_unit,
peak_flops / flops_per_unit)`` with the bandwidth and the peak measured below by wall clock
(by CPU time, ``time.process_time`` over all threads, for a row per CPU second: unit ending
in ``/CPU-s``). Rows with a target in ``targets.py`` also get ``target`` and
``meets_target``; those below target are listed under the table with what bounds them.
A module whose
``main()`` returns ``None`` (or fails) is listed and skipped. Run:
``PYTHONPATH=src python benchmarks/collect.py [--merge] [module ...]``; with ``--merge`` the
rows measured replace those of the same workload and peer in the existing ``results.json``
and the tables are written from all of them (the others keep their earlier measurement).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_WAIT_POLICY", "passive")   # see README.md: shared machine

import importlib  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import traceback  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from numba import njit, prange  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import targets  # noqa: E402

HERE = Path(__file__).resolve().parent
MODULES = ("bench_grid", "bench_network", "bench_closed_form", "bench_particle", "bench_channel",
           "bench_fingerprint", "bench_mixture", "bench_multilateration", "bench_budgets",
           "bench_locate", "bench_chunked", "bench_fleet", "bench_stream", "bench_stream_memory",
           "bench_startup",
           "bench_corridor")
FIELDS = ("workload", "throughput", "unit", "peer", "peer_throughput", "ratio", "limit",
          "limit_fraction")


@njit(parallel=True, cache=True)
def _triad(a, b, c, s):
    for i in prange(a.size):
        a[i] = b[i] + s * c[i]


def machine_limits(n_triad: int = 1 << 24, n_matmul: int = 1500, repeat: int = 5) -> dict:
    """Measure the memory bandwidth (STREAM triad) and the float64 peak (matmul).

    Parameters
    ----------
    n_triad : int
        Elements of each triad array (three float64 arrays, far larger than the caches).
    n_matmul : int
        Side of the square float64 matrices multiplied.
    repeat : int
        Best of this many timings.

    Returns
    -------
    dict
        ``bandwidth_Bps`` (24 bytes per triad element: read b and c, write a, STREAM's
        count; numba ``prange`` on every core), ``peak_flops`` (``2 n^3`` per product, NumPy's
        BLAS on every core), both per wall-clock second and per CPU second
        (``*_per_cpu_s``), and ``cores``.
    """
    a, b, c = np.zeros(n_triad), np.ones(n_triad), np.ones(n_triad)
    _triad(a, b, c, 3.0)
    t = [_timed(lambda: _triad(a, b, c, 3.0)) for _ in range(repeat)]
    x = np.random.default_rng(0).random((n_matmul, n_matmul))
    x @ x
    tm = [_timed(lambda: x @ x) for _ in range(repeat)]
    nbytes, flops = 24.0 * n_triad, 2.0 * n_matmul**3
    return {"bandwidth_Bps": nbytes / min(w for w, _ in t),
            "peak_flops": flops / min(w for w, _ in tm),
            "bandwidth_Bps_per_cpu_s": nbytes / min(c for _, c in t),
            "peak_flops_per_cpu_s": flops / min(c for _, c in tm),
            "cores": os.cpu_count() or 1}


def _timed(fn) -> tuple[float, float]:
    t0, c0 = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - t0, time.process_time() - c0


def row_limit(row: dict, limits: dict) -> float | None:
    """``min(bandwidth / bytes_per_unit, peak / flops_per_unit)`` (per core for ``/CPU-s``).

    Parameters
    ----------
    row : dict
        A bench row, with ``bytes_per_unit`` and/or ``flops_per_unit`` when known.
    limits : dict
        :func:`machine_limits`.

    Returns
    -------
    float or None
        Units per second (None when the row declares no work).
    """
    cpu = str(row.get("unit", "")).endswith("/CPU-s")
    bounds = []
    if row.get("bytes_per_unit"):
        bw = limits["bandwidth_Bps_per_cpu_s" if cpu else "bandwidth_Bps"]
        bounds.append(bw / row["bytes_per_unit"])
    if row.get("flops_per_unit"):
        fl = limits["peak_flops_per_cpu_s" if cpu else "peak_flops"]
        bounds.append(fl / row["flops_per_unit"])
    return min(bounds) if bounds else None


def _rows_of(name: str) -> list[dict] | None:
    mod = importlib.import_module(name)
    rows = mod.main()
    if rows is None:
        return None
    per_b = getattr(mod, "BYTES_PER_UNIT", {}) or {}
    per_f = getattr(mod, "FLOPS_PER_UNIT", {}) or {}
    out = []
    for r in rows:
        r = dict(r)
        r.setdefault("bytes_per_unit", per_b.get(r["workload"]))
        r.setdefault("flops_per_unit", per_f.get(r["workload"]))
        out.append(r)
    return out


def _verdict(row: dict) -> str:
    if "meets_target" not in row:
        return "-"
    return "yes" if row["meets_target"] else "**no**"


def main(modules=MODULES, merge: bool = False) -> list[dict]:
    """Run the benchmarks and write ``results.json`` and ``RESULTS.md``.

    Parameters
    ----------
    modules : sequence of str
        Bench modules (``benchmarks/<name>.py``) to run.
    merge : bool
        Keep the rows of ``results.json`` that this run does not measure.

    Returns
    -------
    list of dict
        All rows (the fields above, plus ``bytes_per_unit`` / ``flops_per_unit`` and any
        ``note`` a bench gave).
    """
    sys.path.insert(0, str(HERE))
    load0 = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    limits = machine_limits()
    print(f"memory bandwidth (triad) {limits['bandwidth_Bps'] / 1e9:.1f} GB/s, "
          f"float64 peak (matmul) {limits['peak_flops'] / 1e9:.1f} GFLOP/s, load {load0:.1f}")
    rows, skipped = [], []
    for name in modules:
        print(f"== {name}")
        if not (HERE / f"{name}.py").exists():
            skipped.append(f"{name} (no such file)")
            continue
        try:
            got = _rows_of(name)
        except Exception:                               # a broken bench must not hide the rest
            traceback.print_exc()
            skipped.append(f"{name} (failed: see the log)")
            continue
        if got is None:
            skipped.append(f"{name} (main() returned no rows)")
            continue
        for r in got:
            row = {k: r.get(k) for k in FIELDS}
            row["limit"] = row_limit(r, limits)
            row["limit_fraction"] = (None if row["limit"] is None
                                     else row["throughput"] / row["limit"])
            for extra in ("bytes_per_unit", "flops_per_unit", "note"):
                if r.get(extra) is not None:
                    row[extra] = r[extra]
            target = targets.target_of(row)
            if target is not None:
                row["target"] = target
                row["meets_target"] = targets.meets(row, target)
            rows.append(row)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    measured = f"{', '.join(modules)} measured in this run; " if merge else ""
    if merge and (HERE / "results.json").exists():
        new = {(r["workload"], r["peer"]): r for r in rows}
        old = json.loads((HERE / "results.json").read_text())
        kept = [new.pop((r["workload"], r["peer"]), r) for r in old]
        rows = kept + list(new.values())
        measured += "the other rows from an earlier run. "
    (HERE / "results.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = [f"{measured}Load average (1 min): {load0:.1f} at the start, {load:.1f} at the end of the run, "
             f"on {limits['cores']} cores. Measured in this run: memory bandwidth (STREAM "
             f"triad) {limits['bandwidth_Bps'] / 1e9:.1f} GB/s "
             f"({limits['bandwidth_Bps_per_cpu_s'] / 1e9:.1f} GB per CPU second), float64 peak "
             f"(matmul) {limits['peak_flops'] / 1e9:.1f} GFLOP/s "
             f"({limits['peak_flops_per_cpu_s'] / 1e9:.1f} GFLOP per CPU second); see README.md "
             "for `limit`.", "",
             "| workload | throughput | unit | peer | peer throughput | ratio | limit | "
             "fraction of limit | target | meets |", "|---|---|---|---|---|---|---|---|---|---|"]
    fmt = lambda v, f: "-" if v is None else format(v, f)     # noqa: E731
    for r in rows:
        value = r["throughput"]
        value = f"{value:.3g}" if abs(value) < 100 else f"{value:,.0f}"    # seconds: 0.612
        lines.append(f"| {r['workload']} | {value} | {r['unit']} | "
                     f"{r['peer'] or '-'} | {fmt(r['peer_throughput'], ',.0f')} | "
                     f"{fmt(r['ratio'], '.1f')}{'' if r['ratio'] is None else 'x'} | "
                     f"{fmt(r['limit'], ',.3g')} | {fmt(r['limit_fraction'], '.1%')} | "
                     f"{targets.describe(r['target']) if 'target' in r else '-'} | "
                     f"{_verdict(r)} |")
    missed = [r for r in rows if r.get("meets_target") is False]
    if missed:
        lines += ["", "Below target, and what bounds each (README.md, \"Where the time goes\", "
                  "has the measurements):"]
        for r in missed:
            frac = ("no declared work" if r["limit_fraction"] is None
                    else f"{r['limit_fraction']:.1%} of this machine's limit")
            lines.append(f"- {r['workload']} (vs {r['peer'] or 'its target'}): "
                         f"{targets.BOUNDS.get(r['workload'], 'not yet analysed.')} "
                         f"Measured: {frac}.")
    notes = [f"- {r['workload']}: {r['note']}" for r in rows if r.get("note")]
    if notes:
        lines += ["", "Notes:", *notes]
    if skipped:
        lines += ["", "Not in the table: " + "; ".join(skipped) + "."]
    (HERE / "RESULTS.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return rows


if __name__ == "__main__":
    args = [a for a in sys.argv[1:] if a != "--merge"]
    main(tuple(args) or MODULES, merge="--merge" in sys.argv[1:])
