"""Grid Bayes filter throughput on a 1000 x 1000 grid: one GridFilter step (BlurGrid, then
ProbabilityUpdate).

Prints cell-updates per second of radioloc's batched filter step (FFT blur + update), and of a peer
measured in the same process: the same update followed by ``scipy.ndimage.gaussian_filter``
(one call per grid, the usual way to blur a single grid). Run:
``PYTHONPATH=src python benchmarks/bench_grid.py``.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.ndimage import gaussian_filter

from radioloc.estimators.grid import GridFilter, GridGeometry, probability_update
from radioloc.models.rssi_trapezoid import fit_trapezoid_model
from timing import best_of


def main(n: int = 1000, batch: int = 2, radius_m: float = 3.0, seed: int = 0) -> None:
    """Time one filter step against the scipy peer and print the throughputs.

    Parameters
    ----------
    n : int
        Grid side in cells.
    batch : int
        Grids filtered at once.
    radius_m : float
        Blur radius per step, metres.
    seed : int
        Seed of the synthetic model and readings.

    Returns
    -------
    None
    """
    rng = np.random.default_rng(seed)
    d = rng.uniform(0, 200, 20000)
    model = fit_trapezoid_model(np.clip(np.rint(95 - 0.45 * d + rng.normal(0, 4, d.size)), 0, 100), d)
    geom = GridGeometry.centred(n, n, 0.2)
    eps = 1e-12
    filt = GridFilter(geom, model, epsilon=eps, blur_m=radius_m)
    state = filt.init(batch)
    p = state.p
    pos = rng.uniform(-20, 20, (batch, 2))
    rssi = rng.integers(40, 80, batch)

    def ours():
        filt.step(state, pos, rssi)

    def peer():
        q = probability_update(p, geom, pos, rssi, model, eps)
        out = np.empty_like(q)
        for b in range(batch):          # the peer blurs one grid per call
            out[b] = gaussian_filter(q[b], radius_m / geom.cell_m, mode="constant", truncate=4.0)
        out /= out.sum(axis=(1, 2), keepdims=True)

    cells = batch * n * n
    t_ours, t_peer = best_of(ours), best_of(peer)
    print(f"grid {n} x {n}, batch {batch}, blur radius {radius_m} m ({radius_m / geom.cell_m:.0f} cells)")
    print(f"radioloc GridFilter.step        : {cells / t_ours:,.0f} cell-updates/s ({t_ours * 1e3:.0f} ms)")
    print(f"update + scipy gaussian_filter  : {cells / t_peer:,.0f} cell-updates/s ({t_peer * 1e3:.0f} ms)")
    print(f"ratio radioloc / scipy peer     : {t_peer / t_ours:.2f}x")


if __name__ == "__main__":
    main()
