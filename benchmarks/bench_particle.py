"""Throughput of the peer-to-peer particle filter step (particle-link updates per second).

Compares :func:`radioloc.estimators.p2p_particle.filter_step` (batched over runs, vehicles,
particles and links; fused numba link kernel) with a straightforward implementation that
loops over vehicles and links in Python with numpy over particles, both measured here on
the same highway data. Run: ``PYTHONPATH=src python benchmarks/bench_particle.py``.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.special import logsumexp

from radioloc.estimators.p2p_particle import ParticleFilterSettings, filter_step, init_filter
from radioloc.estimators.resampling import systematic
from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain
from radioloc.sim.highway import HighwayScenario, simulate


def loop_step(particles, log_phi_prev, ins, ranges, in_range, nodes, model, settings, rng):
    """Per-vehicle, per-link reference step (one run). log_phi_prev: dict (k, j) -> (K, 2)."""
    chain = StickyLinkChain(model.alpha)
    n, k = particles.shape[:2]
    est = np.empty((n, 2))
    new_phi = {}
    for v in range(n):
        p = particles[v] + ins[v] + settings.ins_std_m * rng.standard_normal((k, 2))
        log_w = np.zeros(k)
        phis = {}
        for j in np.flatnonzero(in_range[v]):
            d = np.linalg.norm(p - nodes[j], axis=-1)
            ll = model.logpdf_by_state(ranges[v, j], d)
            if (v, j) in log_phi_prev:
                prior = logsumexp(log_phi_prev[(v, j)][:, :, None] + chain.log_transition, axis=1)
            else:
                prior = chain.log_stationary
            phi = ll + prior
            s = logsumexp(phi, axis=1)
            log_w += s
            phis[j] = phi - s[:, None]
        w = np.exp(log_w - log_w.max())
        w /= w.sum()
        est[v] = w @ p
        idx = systematic(w, rng)
        particles[v] = p[idx]
        for j, phi in phis.items():
            new_phi[(v, j)] = phi[idx]
    return est, new_phi


def main(runs: int = 4, steps: int = 20, particles: int = 900) -> None:
    rng = np.random.default_rng(0)
    model = LosNlosRange(0.05, 5.0, 0.3)
    sc = HighwayScenario(steps=steps, start_width_m=20.0)
    data = simulate(sc, model, runs, rng)
    settings = ParticleFilterSettings(particles=particles)
    anchors = np.broadcast_to(data.anchors, (runs,) + data.anchors.shape)
    links = int(data.in_range.sum())
    # warm-up (numba compile)
    st = init_filter(data.truth[:, 0], settings, rng)
    filter_step(st, data.ins[:, 0], data.ranges[:, 0], data.in_range[:, 0],
                np.concatenate([st.estimate, anchors], 1), model, settings, rng)
    st = init_filter(data.truth[:, 0], settings, rng)
    t0 = time.perf_counter()
    for t in range(steps):
        nodes = np.concatenate([st.estimate, anchors], axis=1)
        st, _ = filter_step(st, data.ins[:, t], data.ranges[:, t], data.in_range[:, t], nodes,
                            model, settings, rng)
    fast = time.perf_counter() - t0
    rate_fast = links * particles / fast

    loop_steps = max(steps // 4, 2)
    parts = data.truth[0, 0][:, None, :] + rng.standard_normal((sc.vehicles, particles, 2))
    phi, est = {}, data.truth[0, 0]
    t0 = time.perf_counter()
    for t in range(loop_steps):
        nodes = np.concatenate([est, data.anchors], axis=0)
        est, phi = loop_step(parts, phi, data.ins[0, t], data.ranges[0, t], data.in_range[0, t],
                             nodes, model, settings, rng)
    slow = time.perf_counter() - t0
    rate_slow = int(data.in_range[0, :loop_steps].sum()) * particles / slow
    print(f"highway N={sc.vehicles}, M={sc.anchors}, K={particles}, mean links/vehicle "
          f"{data.in_range.sum(-1).mean():.1f}")
    print(f"batched filter_step ({runs} runs x {steps} steps): {rate_fast / 1e6:8.2f} M particle-link updates/s")
    print(f"per-vehicle/per-link loop (1 run x {loop_steps} steps): {rate_slow / 1e6:8.2f} M particle-link updates/s")
    print(f"ratio batched / loop: {rate_fast / rate_slow:.1f}x")
    print(f"one full table-4(c) row (1 run x 700 steps) at this rate: "
          f"{700 * links / (runs * steps) * particles / rate_fast:.1f} s")


if __name__ == "__main__":
    main()
