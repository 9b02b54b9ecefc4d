"""Throughput of the peer-to-peer particle filter step (particle-link updates per second).

Compares :meth:`radioloc.estimators.p2p_particle.P2PParticleFilter.step` (batched over runs, vehicles,
particles and links; fused numba link kernel) with a straightforward implementation that
loops over vehicles and links in Python with numpy over particles, both measured here on
the same highway data. Run: ``PYTHONPATH=src python benchmarks/bench_particle.py``.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.special import logsumexp

from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.estimators.resampling import systematic
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import InputDriven
from radioloc.sim.highway import HighwayScenario, simulate


def loop_step(particles, log_phi_prev, ins, ranges, in_range, nodes, model, ins_std_m, rng):
    """Per-vehicle, per-link reference step (one run). log_phi_prev: dict (k, j) -> (K, 2).

    Parameters
    ----------
    particles : ndarray, shape (N, K, 2)
        Updated in place (resampled).
    log_phi_prev : dict
        Normalised link posteriors of the previous step.
    ins : ndarray, shape (N, 2)
    ranges : ndarray, shape (N, J)
    in_range : ndarray of bool, shape (N, J)
    nodes : ndarray, shape (J, 2)
    model : LosNlosRange
    ins_std_m : float
    rng : numpy.random.Generator

    Returns
    -------
    estimate : ndarray, shape (N, 2)
    log_phi : dict
    """
    chain = model.chain
    n, k = particles.shape[:2]
    est = np.empty((n, 2))
    new_phi = {}
    for v in range(n):
        p = particles[v] + ins[v] + ins_std_m * rng.standard_normal((k, 2))
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
    """Print the throughput of the batched step and of the loop reference.

    Parameters
    ----------
    runs, steps, particles : int
        Size of the measured problem.

    Returns
    -------
    None
    """
    rng = np.random.default_rng(0)
    model = LosNlosRange(0.05, 5.0, 0.3)
    sc = HighwayScenario(steps=steps, start_width_m=20.0)
    data = simulate(sc, model, runs, rng)
    pf = P2PParticleFilter(InputDriven(sc.ins_std_m), model, particles=particles)
    anchors = np.broadcast_to(data.anchors, (runs,) + data.anchors.shape)
    links = int(data.in_range.sum())

    def one_step(st, t):
        nodes = np.concatenate([pf.estimate(st).position, anchors], axis=1)
        return pf.step(st, data.ranges[:, :, t], nodes, rng, control=data.ins[:, :, t])
    # warm-up (numba compile)
    one_step(pf.init(data.truth[:, :, 0], rng), 0)
    st = pf.init(data.truth[:, :, 0], rng)
    t0 = time.perf_counter()
    for t in range(steps):
        st = one_step(st, t)
    fast = time.perf_counter() - t0
    rate_fast = links * particles / fast

    loop_steps = max(steps // 4, 2)
    parts = data.truth[0, :, 0][:, None, :] + rng.standard_normal((sc.vehicles, particles, 2))
    phi, est = {}, data.truth[0, :, 0]
    t0 = time.perf_counter()
    for t in range(loop_steps):
        nodes = np.concatenate([est, data.anchors], axis=0)
        est, phi = loop_step(parts, phi, data.ins[0, :, t], data.ranges[0, :, t],
                             data.in_range[0, :, t], nodes, model, sc.ins_std_m, rng)
    slow = time.perf_counter() - t0
    rate_slow = int(data.in_range[0, :, :loop_steps].sum()) * particles / slow
    print(f"highway N={sc.vehicles}, M={sc.anchors}, K={particles}, mean links/vehicle "
          f"{data.in_range.sum(-1).mean():.1f}")
    print(f"batched P2PParticleFilter.step ({runs} runs x {steps} steps): {rate_fast / 1e6:8.2f} M particle-link updates/s")
    print(f"per-vehicle/per-link loop (1 run x {loop_steps} steps): {rate_slow / 1e6:8.2f} M particle-link updates/s")
    print(f"ratio batched / loop: {rate_fast / rate_slow:.1f}x")
    print(f"one full table-4(c) row (1 run x 700 steps) at this rate: "
          f"{700 * links / (runs * steps) * particles / rate_fast:.1f} s")


if __name__ == "__main__":
    main()
