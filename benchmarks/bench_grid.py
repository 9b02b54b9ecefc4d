"""Grid Bayes filter throughput on a 1000 x 1000 grid: one GridFilter step (BlurGrid, then
ProbabilityUpdate).

Prints cell-updates per second of radioloc's batched filter step with the recursive blur
(``GridFilter(blur="recursive")``, compiled kernels: the Young-van Vliet recursions along each
axis, then the floor and the trapezoid update), with the exact FFT blur, and of a peer
measured in the same process: the NumPy update followed by ``scipy.ndimage.gaussian_filter``
(one call per grid, the usual way to blur a single grid) and a renormalisation. Ratios are
taken within the run (the machine is shared: absolute numbers vary with the load). Run:
``PYTHONPATH=src python benchmarks/bench_grid.py``.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.ndimage import gaussian_filter

from radioloc.estimators.grid import GridFilter, GridGeometry, cell_distances
from radioloc.models.rssi_trapezoid import fit_trapezoid_model
from timing import best_of


def main(n: int = 1000, batch: int = 2, radius_m: float = 3.0, seed: int = 0) -> list[dict]:
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
    list of dict
        Rows ``{"workload", "throughput", "unit", "peer", "peer_throughput", "ratio"}``.
    """
    rng = np.random.default_rng(seed)
    d = rng.uniform(0, 200, 20000)
    model = fit_trapezoid_model(np.clip(np.rint(95 - 0.45 * d + rng.normal(0, 4, d.size)), 0, 100), d)
    geom = GridGeometry.centred(n, n, 0.2)
    eps = 1e-12
    fast = GridFilter(geom, model, epsilon=eps, blur_m=radius_m, blur="recursive")
    exact = GridFilter(geom, model, epsilon=eps, blur_m=radius_m)
    pos = rng.uniform(-20, 20, (batch, 2))
    rssi = rng.integers(40, 80, batch)
    state = fast.step(fast.init(batch), pos, rssi)
    p = state.p

    def peer():                                   # plain NumPy update + scipy blur
        lik = model.likelihood(cell_distances(geom, pos), rssi[:, None, None])
        q = np.maximum(p * lik, eps)
        q /= q.sum(axis=(1, 2), keepdims=True)
        out = np.empty_like(q)
        for b in range(batch):          # the peer blurs one grid per call
            out[b] = gaussian_filter(q[b], radius_m / geom.cell_m, mode="constant", truncate=4.0)
        out /= out.sum(axis=(1, 2), keepdims=True)

    cells = batch * n * n
    t_fast = best_of(lambda: fast.step(state, pos, rssi), 5)
    t_peer = best_of(peer)
    t_exact = best_of(lambda: exact.step(state, pos, rssi))
    t_fast = min(t_fast, best_of(lambda: fast.step(state, pos, rssi), 5))
    c_fast = best_of(lambda: fast.step(state, pos, rssi), 5, clock=time.process_time)
    c_peer = best_of(peer, clock=time.process_time)
    print(f"grid {n} x {n}, batch {batch}, blur radius {radius_m} m ({radius_m / geom.cell_m:.0f} cells)")
    print(f"GridFilter.step, recursive blur : {cells / t_fast:,.0f} cell-updates/s ({t_fast * 1e3:.1f} ms)")
    print(f"GridFilter.step, FFT blur       : {cells / t_exact:,.0f} cell-updates/s ({t_exact * 1e3:.0f} ms)")
    print(f"update + scipy gaussian_filter  : {cells / t_peer:,.0f} cell-updates/s ({t_peer * 1e3:.0f} ms)")
    print(f"ratio recursive / scipy peer    : {t_peer / t_fast:.1f}x")
    print(f"ratio FFT / scipy peer          : {t_peer / t_exact:.2f}x")
    print(f"per CPU second (both threads counted): recursive {cells / c_fast:,.0f}, "
          f"peer {cells / c_peer:,.0f} cell-updates/s, ratio {c_peer / c_fast:.1f}x")
    peer_name = "scipy.ndimage update + gaussian_filter"
    # the least work of a step: read the prior and write the posterior once (16 bytes per
    # cell in float64); flops as implemented: 28 of the four third-order recursions, 2 of the
    # floor's excess sum, 12 of the update (floor, distance with its square root, trapezoid
    # with its division, maximum, sum)
    work = {"bytes_per_unit": 16.0, "flops_per_unit": 42.0}
    return [{"workload": f"grid update + blur {n}x{n} (recursive)", "throughput": cells / t_fast,
             "unit": "cell-updates/s", "peer": peer_name, "peer_throughput": cells / t_peer,
             "ratio": t_peer / t_fast, **work},
            {"workload": f"grid update + blur {n}x{n} (exact FFT)", "throughput": cells / t_exact,
             "unit": "cell-updates/s", "peer": peer_name, "peer_throughput": cells / t_peer,
             "ratio": t_peer / t_exact, "bytes_per_unit": 16.0},
            {"workload": f"grid update + blur {n}x{n} (recursive), per CPU second",
             "throughput": cells / c_fast, "unit": "cell-updates/CPU-s", "peer": peer_name,
             "peer_throughput": cells / c_peer, "ratio": c_peer / c_fast, **work}]


if __name__ == "__main__":
    main()
