"""Throughput of batched Gauss-Newton multilateration (:class:`Multilateration`) against scipy.optimize.least_squares
solving the same problems one by one (same draws, same process).

Run: .venv/bin/python benchmarks/bench_multilateration.py [n_problems]
"""

from __future__ import annotations

import sys
import time

import numpy as np
from scipy.optimize import least_squares

from radioloc.core.geometry import distances
from radioloc.estimators.multilateration import Multilateration


def main(n: int = 20_000) -> list[dict]:
    """Time the batched solver and scipy one by one; print and return the row.

    Parameters
    ----------
    n : int
        Problems (scipy is timed on at most 2000 of them and scaled).

    Returns
    -------
    list of dict
        One row of ``collect.py``.
    """
    rng = np.random.default_rng(0)
    anchors = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0]])
    truth = rng.uniform(0, 100, (n, 2))
    ranges = np.abs(distances(truth[:, None], anchors) + rng.normal(0, 1.0, (n, 4)))

    t0 = time.perf_counter()
    fit = Multilateration(std_m=1.0).locate(ranges, anchors)
    t_ours = time.perf_counter() - t0

    m = min(n, 2000)
    t0 = time.perf_counter()
    peer = np.empty((m, 2))
    for i in range(m):
        sol = least_squares(lambda p, r=ranges[i]: np.hypot(*(p - anchors).T) - r,
                            x0=np.full(2, 50.0), method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12)
        peer[i] = sol.x
    t_peer = (time.perf_counter() - t0) * n / m

    agree = np.max(np.abs(peer - fit.position[:m]))
    print(f"problems: {n}; radioloc batched GN: {n / t_ours:,.0f} problems/s; "
          f"scipy least_squares one by one: {n / t_peer:,.0f} problems/s "
          f"(timed on {m}); ratio {t_peer / t_ours:.1f}x; max |difference| {agree:.1e} m")
    return [{"workload": "multilateration, 4 anchors, batched Gauss-Newton", "throughput": n / t_ours,
             "unit": "problems/s", "peer": "scipy.optimize.least_squares (lm) one by one",
             "peer_throughput": n / t_peer, "ratio": t_peer / t_ours,
             "note": f"max |difference| to scipy {agree:.1e} m"}]


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 20_000)
