"""Throughput of the batched network RLS and EKF (paper 000) against FilterPy's EKF.

Run-iterations per second: one run-iteration = every one of the K = 6 nodes updates once
in one Monte Carlo run. FilterPy's ``ExtendedKalmanFilter`` is driven run by run on the
same draws (the way one would use it), and its estimates are checked against ours. Both are
timed in the same process, by wall clock and by CPU time (``time.process_time``, which counts
both numba threads): on a shared machine the CPU-time ratio is the steadier one.

    /work/main/.venv/bin/python benchmarks/bench_network.py
"""

from __future__ import annotations

import time

import numpy as np
from filterpy.kalman import ExtendedKalmanFilter

from radioloc.core.geometry import pairwise_distances
from radioloc.estimators.ekf import NetworkEKF
from radioloc.estimators.rls import NetworkRLS

K, ITER, RANGE_VAR = 6, 20, 900.0


def draws(runs: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    truth = rng.uniform(0, 1000, (runs, K, 2))
    var = np.broadcast_to(np.where(np.arange(K) < 3, 100.0, 1e4)[None, :, None], truth.shape)
    prior = truth + rng.normal(size=truth.shape) * np.sqrt(var)
    rho = pairwise_distances(truth)[None] + np.sqrt(RANGE_VAR) * rng.normal(size=(ITER, runs, K, K))
    return prior, np.array(var), rho


def ours(prior, var, rho, method, clock=time.perf_counter):
    est = NetworkEKF(std_m=np.sqrt(RANGE_VAR)) if method == "ekf" else NetworkRLS()
    s = est.init(prior, var)
    t = clock()
    for n in range(ITER):
        s = est.iterate(s, rho[n])
    return s, clock() - t


def filterpy_runs(prior, var, rho, clock=time.perf_counter):
    runs = prior.shape[0]
    out = np.empty((runs, 2 * K))
    t = clock()
    for r in range(runs):                       # FilterPy filters one run at a time
        f = ExtendedKalmanFilter(dim_x=2 * K, dim_z=K - 1)
        f.x = prior[r].reshape(-1, 1).copy()
        f.P = np.diag(var[r].ravel())
        Rm = np.eye(K - 1) * RANGE_VAR
        for n in range(ITER):
            for k in range(K):
                others = np.arange(K) != k

                def hx(x, k=k, others=others):
                    p = x.reshape(K, 2)
                    return np.linalg.norm(p[others] - p[k], axis=1).reshape(-1, 1)

                def jac(x, k=k, others=others):       # plain numpy, as a FilterPy user writes it
                    p = x.reshape(K, 2)
                    u = (p[others] - p[k]) / np.linalg.norm(p[others] - p[k], axis=1)[:, None]
                    H = np.zeros((K - 1, K, 2))
                    H[np.arange(K - 1), np.flatnonzero(others)] = u
                    H[:, k] = -u
                    return H.reshape(K - 1, 2 * K)

                f.update(rho[n, r, k, others].reshape(-1, 1), jac, hx, R=Rm)
        out[r] = f.x.ravel()
    return out, clock() - t


def ekf_flops(k: int = K) -> float:
    """Floating-point operations of one run-iteration of the sequential EKF (k masters, each
    updating the 2k state with k rows): per master ``A = Sigma H'`` (4 n k), ``S = H A`` (4 k^2),
    Cholesky (k^3 / 3), the gain by two triangular solves (2 n k^2), ``L S - A`` (2 n k^2),
    the Joseph update of the upper triangle (2 n (n + 1) k) and the mean (2 n k), n = 2k."""
    n = 2 * k
    per_master = 4 * n * k + 4 * k * k + k**3 / 3 + 2 * n * k * k + 2 * n * k * k \
        + 2 * n * (n + 1) * k + 2 * n * k
    return k * per_master


def full_monte_carlo(runs: int = 5000, iterations: int = 50, measured_runs: int = 1000):
    """Estimator time of paper 000's full Monte Carlo: ``runs`` x 2 noise levels x {RLS, EKF}
    x ``iterations``, measured on ``measured_runs`` runs per batch and scaled by
    ``runs / measured_runs`` (the batch is independent run by run); the ranges are drawn
    before the clock starts."""
    total = 0.0
    for noise, seed in ((900.0, 1), (100.0, 2)):
        rng = np.random.default_rng(seed)
        truth = rng.uniform(0, 1000, (measured_runs, K, 2))
        var = np.broadcast_to(np.where(np.arange(K) < 3, 100.0, 1e4)[None, :, None], truth.shape)
        prior = truth + rng.normal(size=truth.shape) * np.sqrt(var)
        d = pairwise_distances(truth)
        for est in (NetworkRLS(), NetworkEKF(std_m=np.sqrt(noise))):
            # the simulated ranges are drawn before the clock starts (the simulator is not
            # the estimators' time)
            rho = d + np.sqrt(noise) * rng.normal(size=(iterations,) + d.shape)
            s = est.init(prior, np.array(var))
            t0 = time.perf_counter()
            for it in range(iterations):
                s = est.iterate(s, rho[it])
            total += time.perf_counter() - t0
    return total * runs / measured_runs


def main() -> list[dict]:
    """Time RLS, EKF and FilterPy and print run-iterations per second.

    Returns
    -------
    list of dict
        Rows ``{"workload", "throughput", "unit", "peer", "peer_throughput", "ratio"}``.
    """
    runs, peer_runs = 2000, 50
    prior, var, rho = draws(runs)
    ours(prior[:8], var[:8], rho[:, :8], "ekf")                  # compile
    for method in ("rls", "ekf"):
        _, dt = ours(prior, var, rho, method)
        print(f"{method.upper()} batched ({runs} runs x {ITER} iterations): "
              f"{runs * ITER / dt:,.0f} run-iterations/s")
    s, _ = ours(prior[:peer_runs], var[:peer_runs], rho[:, :peer_runs], "ekf")
    ref, dt_fp = filterpy_runs(prior[:peer_runs], var[:peer_runs], rho[:, :peer_runs])
    dt_fp = min(dt_fp, filterpy_runs(prior[:peer_runs], var[:peer_runs], rho[:, :peer_runs])[1])
    _, dt_big = ours(prior, var, rho, "ekf")
    _, cpu_fp = filterpy_runs(prior[:peer_runs], var[:peer_runs], rho[:, :peer_runs],
                              time.process_time)
    _, cpu_big = ours(prior, var, rho, "ekf", time.process_time)
    _, dt_big2 = ours(prior, var, rho, "ekf")
    dt_big = min(dt_big, dt_big2)
    ours_rate, fp_rate = runs * ITER / dt_big, peer_runs * ITER / dt_fp
    ours_cpu, fp_cpu = runs * ITER / cpu_big, peer_runs * ITER / cpu_fp
    print(f"FilterPy ExtendedKalmanFilter run by run ({peer_runs} runs): "
          f"{fp_rate:,.0f} run-iterations/s")
    print(f"max |ours - FilterPy| over {peer_runs} runs: {np.abs(s.mean - ref).max():.2e} m")
    print(f"EKF speed-up vs FilterPy, wall clock: {ours_rate / fp_rate:.1f}x")
    print(f"EKF per CPU second: ours {ours_cpu:,.0f}, FilterPy {fp_cpu:,.0f} run-iterations/s, "
          f"ratio {ours_cpu / fp_cpu:.1f}x")
    mc_s = full_monte_carlo()
    print(f"paper 000 full Monte Carlo, estimators only (5000 runs x 2 noise x RLS+EKF x 50 "
          f"iterations, measured on 1000 runs and scaled): {mc_s:.1f} s")
    flops = ekf_flops()
    return [{"workload": "paper 000 network EKF (K = 6)", "throughput": ours_rate,
             "unit": "run-iterations/s", "peer": "filterpy ExtendedKalmanFilter",
             "peer_throughput": fp_rate, "ratio": ours_rate / fp_rate, "flops_per_unit": flops},
            {"workload": "paper 000 network EKF (K = 6), per CPU second", "throughput": ours_cpu,
             "unit": "run-iterations/CPU-s", "peer": "filterpy ExtendedKalmanFilter",
             "peer_throughput": fp_cpu, "ratio": ours_cpu / fp_cpu, "flops_per_unit": flops},
            {"workload": "paper 000 full Monte Carlo, estimators (5000 runs x 2 noise x "
                         "RLS+EKF x 50 it.)", "throughput": 1e6 / mc_s,
             "unit": "run-iterations/s", "peer": None, "peer_throughput": None, "ratio": None,
             "flops_per_unit": flops / 2,        # half of them are RLS iterations (cheaper)
             "note": f"{mc_s:.1f} s of wall clock for the estimators (1e6 run-iterations; target "
                     "<= 2 s), measured on 1000 runs per batch and scaled by 5; the limit counts "
                     "the EKF's flops for half of them (a lower bound of the work)"}]


if __name__ == "__main__":
    main()
