"""Run the benchmarks whose ``main()`` returns result rows and write ``results.json`` and
``RESULTS.md`` beside this file.

Each row: ``{"workload", "throughput", "unit", "peer", "peer_throughput", "ratio", "limit",
"limit_fraction"}``; ``ratio`` is ours / peer measured in the same process (the machine is
shared, so ratios are what count). ``limit`` and ``limit_fraction`` are null until a
workload's machine bound is derived (see README.md). Run:
``PYTHONPATH=src python benchmarks/collect.py``.
"""

from __future__ import annotations

import importlib
import json
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
MODULES = ("bench_grid", "bench_network")       # the benchmarks that return rows


def main() -> list[dict]:
    """Run every benchmark of ``MODULES`` and write the two files.

    Returns
    -------
    list of dict
        All rows.
    """
    sys.path.insert(0, str(HERE))
    rows = []
    for name in MODULES:
        print(f"== {name}")
        for row in importlib.import_module(name).main() or []:
            rows.append({"limit": None, "limit_fraction": None, **row})
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    (HERE / "results.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = [f"Load average (1 min) at the end of the run: {load:.1f} on {os.cpu_count()} cores.", "",
             "| workload | throughput | unit | peer | peer throughput | ratio |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        peer = "-" if r["peer_throughput"] is None else f"{r['peer_throughput']:,.0f}"
        ratio = "-" if r["ratio"] is None else f"{r['ratio']:.1f}x"
        lines.append(f"| {r['workload']} | {r['throughput']:,.0f} | {r['unit']} | "
                     f"{r['peer'] or '-'} | {peer} | {ratio} |")
    (HERE / "RESULTS.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return rows


if __name__ == "__main__":
    main()
