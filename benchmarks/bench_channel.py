"""Channel layer throughput, each fast kernel against its plain reference in the same process.

* Ray tracing, order 3, the 1 km synthetic city of seed 0 (568 walls), the 15 links of 6
  street nodes: the compiled tracer (image-tree walk pruned by the wall visibility lists,
  grid blocking tests) against the NumPy/shapely reference (``backend="numpy"``, same
  paths), links/s. The scene's own structures (grid, convex-footprint grid, follower and
  visibility lists) are built once per scene and cached on it, so the timed calls do not
  include them; building the scene and these is the separate "scene build and preprocessing" row (scenes/s, no peer).
* OMP-SIC (the paper's GSIC step): 168 ACK sets of 5 users with 3 paths each, the compiled
  correlation-domain kernel against the NumPy reference (same detections), ACK sets/s;
  and against the NumPy matched filter (the issue's peer: 294 ACK sets/s on main).
* Matched filter: compiled OMP kernel against its NumPy reference.

``main()`` returns the rows ``{"workload", "throughput", "unit", "peer", "peer_throughput",
"ratio"}``. Run: ``PYTHONPATH=src python benchmarks/bench_channel.py``.
"""

import time

import numpy as np

from radioloc.channel.cdma import CDMAConfig, gold_codes, received_acks
from radioloc.channel.gsic import matched_filter_toa, omp_sic_toa
from radioloc.channel.raytrace import TraceConfig, trace_links
from radioloc.channel.scene import city_grid, street_positions
from timing import best_of


def _row(workload, ours, unit, peer, theirs):
    return {"workload": workload, "throughput": float(ours), "unit": unit, "peer": peer,
            "peer_throughput": None if theirs is None else float(theirs),
            "ratio": None if theirs is None else float(ours / theirs)}


def main() -> list[dict]:
    """Measure and print the channel rows.

    Returns
    -------
    list of dict
        One row per workload.
    """
    rows = []
    scene = city_grid(0)
    pos = street_positions(scene, 6, np.random.default_rng(1), half_width_m=300.0)
    i, j = np.triu_indices(6, 1)
    cfg = TraceConfig(max_order=3)
    fast = best_of(lambda: trace_links(scene, pos[i], pos[j], cfg), 3, warmup=True)
    ref = best_of(lambda: trace_links(scene, pos[i], pos[j], cfg, backend="numpy"), 1, warmup=True)
    rows.append(_row(f"ray tracing order 3, {len(scene.walls)} walls, 15 links",
                     i.size / fast, "links/s", "NumPy/shapely reference tracer", i.size / ref))
    # the same per CPU second (process time, both threads counted): on a shared machine
    # the wall clock mostly measures the other tenants
    fast_cpu = best_of(lambda: trace_links(scene, pos[i], pos[j], cfg), 3, clock=time.process_time)
    ref_cpu = best_of(lambda: trace_links(scene, pos[i], pos[j], cfg, backend="numpy"), 1,
                      clock=time.process_time)
    rows.append(_row(f"ray tracing order 3, {len(scene.walls)} walls, 15 links (per CPU second)",
                     i.size / fast_cpu, "links/CPU-s", "NumPy/shapely reference tracer",
                     i.size / ref_cpu))

    def prepare():
        s = city_grid(0)
        return s.grid, s.convex_grid, s.visible
    rows.append(_row(f"ray-tracing scene build and preprocessing (grids, visibility), {len(scene.walls)} walls",
                     1.0 / best_of(prepare, 3, warmup=True), "scenes/s", None, None))

    cd = CDMAConfig()
    codes = gold_codes(cd.code_degree)
    rng = np.random.default_rng(0)
    B, U = 168, 5
    s = np.sqrt(cd.noise_var / cd.tx_power_w)
    d = rng.uniform(0.5e-6, 12e-6, (B, U, 3))
    g = s * 10 ** rng.uniform(0, 3, (B, U, 3)) * np.exp(2j * np.pi * rng.random((B, U, 3)))
    ci = np.tile(np.arange(U), (B, 1))
    y = received_acks(d, g, ci, cd, rng, codes)
    t_sic = best_of(lambda: omp_sic_toa(y, ci, codes, cd), 3, warmup=True)
    t_sic_ref = best_of(lambda: omp_sic_toa(y, ci, codes, cd, backend="numpy"), 1, warmup=True)
    t_mf = best_of(lambda: matched_filter_toa(y, ci, codes, cd), 3, warmup=True)
    t_mf_ref = best_of(lambda: matched_filter_toa(y, ci, codes, cd, backend="numpy"), 3, warmup=True)
    rows.append(_row("OMP-SIC (GSIC step), 5 users x 3 paths", B / t_sic, "ACK sets/s",
                     "NumPy OMP-SIC reference", B / t_sic_ref))
    c_sic = best_of(lambda: omp_sic_toa(y, ci, codes, cd), 3, clock=time.process_time)
    c_mf_ref = best_of(lambda: matched_filter_toa(y, ci, codes, cd, backend="numpy"), 3,
                       clock=time.process_time)
    rows.append(_row("OMP-SIC (GSIC step), 5 users x 3 paths (per CPU second)", B / c_sic,
                     "ACK sets/CPU-s", "NumPy matched filter (no cancellation)", B / c_mf_ref))
    rows.append(_row("OMP-SIC (GSIC step), 5 users x 3 paths", B / t_sic, "ACK sets/s",
                     "NumPy matched filter (no cancellation)", B / t_mf_ref))
    rows.append(_row("matched filter, 5 users x 3 paths", B / t_mf, "ACK sets/s",
                     "NumPy matched filter", B / t_mf_ref))
    for r in rows:
        vs = "" if r["peer"] is None else (f" vs {r['peer']}: {r['peer_throughput']:10.1f}  "
                                           f"ratio {r['ratio']:.1f}x")
        print(f"{r['workload']:48s} {r['throughput']:10.1f} {r['unit']:11s}{vs}")
    return rows


if __name__ == "__main__":
    main()
