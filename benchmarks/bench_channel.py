"""Channel layer throughput: ray tracing (batched over links vs one link per call) and
GSIC vs the matched filter (ACK sets per second), measured in the same process."""

import time

import numpy as np

from radioloc.channel.cdma import CDMAConfig, gold_codes, received_acks
from radioloc.channel.gsic import gsic_toa, matched_filter_toa
from radioloc.channel.raytrace import TraceConfig, trace_links
from radioloc.channel.scene import city_grid, street_positions
from timing import best_of


def best_of_warm(fn, repeat=3):
    return best_of(fn, repeat, warmup=True)




def main():
    scene = city_grid(0)
    pos = street_positions(scene, 6, np.random.default_rng(1), half_width_m=300.0)
    i, j = np.triu_indices(6, 1)
    cfg = TraceConfig(max_order=3)
    batched = best_of_warm(lambda: trace_links(scene, pos[i], pos[j], cfg))
    single = best_of_warm(lambda: [trace_links(scene, pos[a:a + 1], pos[b:b + 1], cfg) for a, b in zip(i, j)], 1)
    print(f"ray tracing, order 3, {len(scene.walls)} walls: batched {i.size / batched:8.1f} links/s, "
          f"one link per call {i.size / single:8.1f} links/s, ratio {single / batched:.2f}")

    cd = CDMAConfig()
    codes = gold_codes(cd.code_degree)
    rng = np.random.default_rng(0)
    B, U = 168, 5
    s = np.sqrt(cd.noise_var / cd.tx_power_w)
    d = rng.uniform(0.5e-6, 12e-6, (B, U, 3))
    g = s * 10 ** rng.uniform(0, 3, (B, U, 3)) * np.exp(2j * np.pi * rng.random((B, U, 3)))
    ci = np.tile(np.arange(U), (B, 1))
    y = received_acks(d, g, ci, cd, rng, codes)
    tg = best_of_warm(lambda: gsic_toa(y, ci, codes, cd))
    tm = best_of_warm(lambda: matched_filter_toa(y, ci, codes, cd))
    ts = best_of_warm(lambda: received_acks(d, g, ci, cd, rng, codes))
    print(f"GSIC {B / tg:8.1f} ACK sets/s, matched filter {B / tm:8.1f} ACK sets/s (GSIC cost x{tg / tm:.1f}); "
          f"synthesis {B / ts:8.1f} ACK sets/s")


if __name__ == "__main__":
    main()
