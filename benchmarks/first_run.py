"""First run on a new machine: how long `radioloc locate` (each method) and
`radioloc reproduce all` take with an empty numba cache, and again once it is filled.

Each command runs in its own process with ``NUMBA_CACHE_DIR`` pointed at a new empty folder
(the first run compiles every kernel it uses), then once more with that folder filled. The
inputs are the fuzz suite's valid scenarios (``tests/fuzz/fuzz_harness.py``): a few anchors
and a few dozen rows per method. Prints a Markdown table for the README:

    PYTHONPATH=src python benchmarks/first_run.py [--no-demo]
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests" / "fuzz"))


def _timed(args: list[str], cache: Path) -> float:
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "NUMBA_CACHE_DIR": str(cache)}
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-m", "radioloc.cli", *args], cwd=ROOT, env=env,
                         capture_output=True, text=True)
    if res.returncode != 0:
        raise RuntimeError(f"radioloc {' '.join(args)} failed: {res.stderr.strip()[-500:]}")
    return time.perf_counter() - t0


def main(demo: bool = True) -> list[tuple[str, float, float]]:
    from fuzz_harness import build_scenarios

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scenarios = build_scenarios(tmp)
        for key, sc in scenarios.items():
            if key == "gn3":
                continue
            meas = tmp / f"{key}.csv"
            meas.write_text("\n".join(",".join(r) for r in sc.rows) + "\n")
            cache = tmp / f"cache-{key}"
            args = sc.args(meas) + ["--out", str(tmp / f"{key}-est.csv")]
            cold, warm = _timed(args, cache), _timed(args, cache)
            rows.append((f"radioloc locate --method {sc.method}", cold, warm))
            print(f"{rows[-1][0]}: {cold:.1f} s first, {warm:.1f} s after", flush=True)
        if demo:
            cache = tmp / "cache-demo"
            cold = _timed(["reproduce", "all", "--out", str(tmp / "demo1")], cache)
            warm = _timed(["reproduce", "all", "--out", str(tmp / "demo2")], cache)
            rows.append(("radioloc reproduce all (make demo)", cold, warm))
            print(f"{rows[-1][0]}: {cold:.0f} s first, {warm:.0f} s after", flush=True)
    print("\n| command | first run (empty numba cache) | after |\n|---|---|---|")
    for name, cold, warm in rows:
        print(f"| `{name}` | {cold:.1f} s | {warm:.1f} s |")
    return rows


if __name__ == "__main__":
    main(demo="--no-demo" not in sys.argv)
