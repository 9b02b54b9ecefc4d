"""User budgets measured as whole commands, and the size of the compiled code.

Rows (each a time in seconds or a count, compared with an upper bound in ``targets.py``):

- warm ``make demo``: ``radioloc reproduce all`` at the quick size, timed after one run that
  fills numba's cache (the first run's time is printed too);
- cold kernel compile of the whole suite: ``tests/precompile.py`` with an empty numba cache
  (``NUMBA_CACHE_DIR`` pointed at a new folder);
- ``radioloc reproduce p001-highway --full --workers 2`` (about 5 minutes);
- the lines of every function that numba compiles in ``src/`` and the lines of ``src/``.

Run alone: ``PYTHONPATH=src python benchmarks/bench_budgets.py``.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SRC = ROOT / "src"
COMPILERS = ("njit", "jit", "vectorize", "guvectorize", "stencil", "cfunc", "overload",
             "intrinsic", "generated_jit")


def compiled_lines(root: Path = SRC) -> tuple[int, int, dict[str, int]]:
    """Lines of the functions a numba decorator compiles, under ``root``.

    Returns
    -------
    lines : int
        Lines of every decorated function (decorators, signature and body).
    functions : int
        How many such functions.
    per_file : dict
        Lines per file, relative to ``root``.
    """
    total, count, per_file = 0, 0, {}
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            names = {n.id if isinstance(n, ast.Name) else n.attr
                     for d in node.decorator_list for n in ast.walk(d)
                     if isinstance(n, (ast.Name, ast.Attribute))}
            if names & set(COMPILERS):
                n = node.end_lineno - min([node.lineno] + [d.lineno for d in node.decorator_list]) + 1
                total += n
                count += 1
                key = str(path.relative_to(root))
                per_file[key] = per_file.get(key, 0) + n
    return total, count, per_file


def source_lines(root: Path = SRC) -> int:
    """Lines of every ``.py`` file under ``root``."""
    return sum(len(p.read_text().splitlines()) for p in root.rglob("*.py"))


def _timed_run(args: list[str], env: dict | None = None) -> float:
    t0 = time.perf_counter()
    subprocess.run(args, check=True, cwd=ROOT, env={**os.environ, **(env or {})},
                   stdout=subprocess.DEVNULL)
    return time.perf_counter() - t0


def _radioloc(*args: str) -> list[str]:
    return [sys.executable, "-m", "radioloc.cli", *args]


def main() -> list[dict]:
    env = {"PYTHONPATH": str(SRC)}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        first = _timed_run(_radioloc("reproduce", "all", "--out", f"{tmp}/demo1"), env)
        warm = _timed_run(_radioloc("reproduce", "all", "--out", f"{tmp}/demo2"), env)
        print(f"reproduce all (quick): {first:.0f} s first, {warm:.0f} s warm")
        rows.append({"workload": "warm `make demo` (reproduce all, quick size)",
                     "throughput": warm, "unit": "s (wall)", "peer": None,
                     "peer_throughput": None, "ratio": None,
                     "note": f"the run before it, which filled numba's cache: {first:.0f} s"})
        cold = _timed_run([sys.executable, "tests/precompile.py"],
                          {**env, "NUMBA_CACHE_DIR": f"{tmp}/numba-cache"})
        print(f"cold compile (tests/precompile.py, empty cache): {cold:.0f} s")
        rows.append({"workload": "cold kernel compile, whole suite (tests/precompile.py)",
                     "throughput": cold, "unit": "s (wall)", "peer": None,
                     "peer_throughput": None, "ratio": None})
        full = _timed_run(_radioloc("reproduce", "p001-highway", "--full", "--workers", "2",
                                    "--out", f"{tmp}/p001"), env)
        print(f"p001-highway --full --workers 2: {full / 60:.1f} min")
        rows.append({"workload": "reproduce p001-highway --full --workers 2",
                     "throughput": full, "unit": "s (wall)", "peer": None,
                     "peer_throughput": None, "ratio": None})
    lines, functions, per_file = compiled_lines()
    top = ", ".join(f"{k} {v}" for k, v in sorted(per_file.items(), key=lambda kv: -kv[1]))
    rows.append({"workload": "lines compiled by numba in src/", "throughput": lines,
                 "unit": "lines", "peer": None, "peer_throughput": None, "ratio": None,
                 "note": f"{functions} functions: {top}"})
    rows.append({"workload": "lines of src/", "throughput": source_lines(), "unit": "lines",
                 "peer": None, "peer_throughput": None, "ratio": None})
    return rows


if __name__ == "__main__":
    for r in main():
        print(r)
