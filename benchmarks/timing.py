"""Shared timing helper of the benchmark scripts."""

from __future__ import annotations

import time
from typing import Callable


def best_of(fn: Callable[[], object], repeat: int = 3, *, warmup: bool = False,
            clock: Callable[[], float] = time.perf_counter) -> float:
    """Shortest of ``repeat`` timings of ``fn()`` in seconds (``clock``: wall by default,
    ``time.process_time`` for CPU time); ``warmup`` runs it once untimed first (JIT)."""
    if warmup:
        fn()
    best = float("inf")
    for _ in range(repeat):
        t0 = clock()
        fn()
        best = min(best, clock() - t0)
    return best
