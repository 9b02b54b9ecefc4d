"""Particle-filter throughput: paper 001's peer-to-peer filter and a plain range-only
bootstrap filter, each against a peer measured in the same process.

Rows (returned by :func:`main`):

* highway P2P filter, the steps of ``P2PParticleFilter.run`` (a loop over ``step``) batched
  over runs, vehicles, particles and links (particle-link updates/s), against a
  per-vehicle, per-link NumPy loop of the same maths;
* range-only bootstrap PF, 4 anchors, 2-D random walk, N = 10^5 particles, systematic
  resampling at every step (particle-steps/s): ``P2PParticleFilter(RandomWalk(q),
  LosNlosRange(s, 1, alpha=1))`` with anchors only (alpha = 1: every link LOS, so the
  likelihood is the Gaussian range likelihood), the general filter with its default
  ``backend="numba"``, against Stone Soup's ``ParticlePredictor`` / ``ParticleUpdater`` +
  ``SystematicResampler`` and against ``particles`` (Chopin) ``SMC(Bootstrap)`` with
  ``ESSrmin=1`` (resampling at every step), same model and N. Ours is timed through
  ``run``, including the prior's draws; the generic ``ParticleFilter(RandomWalk(q))``
  with a Gaussian ``RangeModel`` (``ess_threshold=1``) on the same data, against the same
  peer runs; the generic filter with its default ``backend="numba"`` (the compiled Gaussian
  range likelihood, moments and systematic resampling of ``pf_compiled.py``, the draws in
  parts) and, for reference, with ``backend="numpy"``.

Ours: best of 3 (wall clock; the CPU-second rate is printed too); peers: one run.

Run: ``PYTHONPATH=src python benchmarks/bench_particle.py``.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.special import logsumexp

from radioloc.estimators.p2p_particle import P2PParticleFilter
from radioloc.estimators.resampling import systematic
from radioloc.models.los_nlos import LosNlosRange
from radioloc.models.motion import InputDriven, RandomWalk
from radioloc.sim.highway import HighwayScenario, simulate

ANCHORS = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]])


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


def _row(workload, rate, unit, peer=None, peer_rate=None):
    return {"workload": workload, "throughput": float(rate), "unit": unit, "peer": peer,
            "peer_throughput": None if peer_rate is None else float(peer_rate),
            "ratio": None if peer_rate is None else float(rate / peer_rate)}



#: Floating-point operations of one particle-link update as ``pf_compiled.link_update`` does
#: it (counting a square root, exponential, logarithm or erfc as 20): the residual (12), the
#: link prior from the carried posterior (10), the two state log-densities without the
#: NLOS term's ``log Phi`` (8), the other state's exponential (21), the posterior's division
#: and the weight's product (3), the pooled sums (24); ``log Phi`` (erfc and log, 42) where
#: ``u = z - lam s < 8.5``.
LINK_FLOPS = {"base": 78, "log_phi": 42}


def link_work(particles, node_xy, th, valid, los_std, nlos_mean):
    """Flops and least memory traffic (bytes) of one particle-link update on these inputs.

    Parameters
    ----------
    particles : ndarray, shape (..., K, 2+)
    node_xy : ndarray, shape (..., L, 2)
    th : ndarray, shape (..., L)
    valid : ndarray of bool, shape (..., L)
    los_std, nlos_mean : float

    Returns
    -------
    flops : float
        Mean over the particle-link updates.
    bytes : float
        The carried and the new LOS posterior (16 bytes) plus the particle's position
        read and its log weight written once per step, shared by its links.
    """
    e = th[..., None, :] - np.linalg.norm(particles[..., :, None, :2] - node_xy[..., None, :, :],
                                          axis=-1)                        # (..., K, L)
    need = e / los_std - los_std / nlos_mean < 8.5
    ok = np.broadcast_to(valid[..., None, :], e.shape)
    per_update = LINK_FLOPS["base"] + LINK_FLOPS["log_phi"] * need[ok].mean()
    links_per_filter = valid.sum(-1).mean()
    return float(per_update), 16.0 + 24.0 / float(links_per_filter)


def highway_rows(runs: int = 4, steps: int = 20, particles: int = 900) -> list[dict]:
    """The P2P filter step and its link kernel on highway data.

    Parameters
    ----------
    runs, steps, particles : int
        Size of the measured problem.

    Returns
    -------
    list of dict
        One row.
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

    def by_run():
        # init and every step (messages: the previous step's estimates, as one_step sends)
        return pf.run(data.ranges, data.truth[:, :, 0], rng, anchors=data.anchors,
                      controls=data.ins)
    one_step(pf.init(data.truth[:, :, 0], rng), 0)                       # compile
    by_run()
    best, cpu, cpu_step = np.inf, np.inf, np.inf
    for _ in range(3):                                                   # best of 3
        t0, c0 = time.perf_counter(), time.process_time()
        by_run()
        best = min(best, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
        st = pf.init(data.truth[:, :, 0], rng)
        c0 = time.process_time()
        for t in range(steps):
            st = one_step(st, t)
        cpu_step = min(cpu_step, time.process_time() - c0)
    rate_fast = links * particles / best
    print(f"batched P2PParticleFilter.run: {links * particles / cpu / 1e6:8.2f} M particle-link "
          f"updates per CPU second (step by step: {links * particles / cpu_step / 1e6:.2f} M)")

    loop_steps = max(steps // 4, 2)
    parts = data.truth[0, :, 0][:, None, :] + rng.standard_normal((sc.vehicles, particles, 2))
    phi, est = {}, data.truth[0, :, 0]
    t0 = time.perf_counter()
    for t in range(loop_steps):
        nodes = np.concatenate([est, data.anchors], axis=0)
        est, phi = loop_step(parts, phi, data.ins[0, :, t], data.ranges[0, :, t],
                             data.in_range[0, :, t], nodes, model, sc.ins_std_m, rng)
    rate_slow = int(data.in_range[0, :, :loop_steps].sum()) * particles / (time.perf_counter() - t0)

    print(f"highway N={sc.vehicles}, M={sc.anchors}, K={particles}, mean links/vehicle "
          f"{data.in_range.sum(-1).mean():.1f}, numba threads {_threads()}")
    print(f"batched P2PParticleFilter.run ({runs} runs x {steps} steps): {rate_fast / 1e6:8.2f} M particle-link updates/s")
    print(f"per-vehicle/per-link loop (1 run x {loop_steps} steps): {rate_slow / 1e6:8.2f} M particle-link updates/s")
    mask = np.isfinite(data.ranges[:, :, -1])
    from radioloc.core.links import gather_packed, pack_mask
    lk, valid = pack_mask(mask)
    nodes = np.concatenate([st.mean[..., :2], anchors], axis=1)
    node_xy = gather_packed(np.broadcast_to(nodes[:, None], mask.shape + (2,)), lk, axis=-2)
    th = gather_packed(np.where(mask, data.ranges[:, :, -1], 0.0), lk)
    flops, nbytes = link_work(st.particles, node_xy, th, valid, 0.05, 5.0)
    print(f"link update work on these inputs: {flops:.0f} flops, {nbytes:.1f} bytes per update")
    work = {"flops_per_unit": flops, "bytes_per_unit": nbytes}
    # the step row counts the link update's work only (a lower bound of the step's)
    return [dict(_row("P2P particle filter step, highway N=20 M=26 K=900", rate_fast,
                      "particle-link updates/s", "per-vehicle/per-link NumPy loop", rate_slow),
                 **work)]


def _threads() -> int:
    import numba
    return numba.get_num_threads()


def _bootstrap_data(steps, q, sigma, rng):
    x = np.cumsum(np.sqrt(q) * rng.standard_normal((steps + 1, 2)), axis=0) + 15.0
    d = np.linalg.norm(x[1:, None, :] - ANCHORS, axis=-1)
    return x, d + sigma * rng.standard_normal(d.shape)


def ours_bootstrap(n, steps, q, sigma, x, y, rng):
    """Particle-steps/s of P2PParticleFilter on the range-only random-walk model.

    Parameters
    ----------
    n, steps : int
    q, sigma : float
        Random-walk variance per step and range noise std.
    x, y : ndarray
        True path (steps + 1, 2) and ranges (steps, 4).
    rng : numpy.random.Generator

    Returns
    -------
    rate : float
        Particle-steps per second (wall clock, best of 3).
    error : float
        Mean position error (a check that the filter tracks).
    cpu_rate : float
        Particle-steps per CPU second (all threads, best of 3).
    """
    pf = P2PParticleFilter(RandomWalk(q), LosNlosRange(sigma, 1.0, 1.0), particles=n, init_std=1.0)
    ranges = np.concatenate([np.full((steps, 1), np.nan), y[:steps]], axis=-1)[None, None]
    pf.run(ranges[..., :2, :], x[None, None, 0], rng, anchors=ANCHORS)   # compile
    dt, cpu = np.inf, np.inf
    for _ in range(3):                                                   # best of 3
        t0, c0 = time.perf_counter(), time.process_time()
        tr = pf.run(ranges, x[None, None, 0], rng, anchors=ANCHORS)
        dt = min(dt, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    print(f"bootstrap PF, N={n}: ours {n * steps / cpu / 1e6:.2f} M particle-steps per CPU second "
          f"({cpu / steps * 1e3:.2f} ms CPU, {dt / steps * 1e3:.2f} ms wall per step)")
    return (n * steps / dt, float(np.linalg.norm(tr.position[0, 0] - x[1:steps + 1], axis=-1).mean()),
            n * steps / cpu)


def generic_bootstrap(n, steps, q, sigma, x, y, backend="numba"):
    """Particle-steps/s of the generic :class:`ParticleFilter` on the same model: a
    Gaussian :class:`RangeModel` to the 4 anchors, resampling at every step
    (``ess_threshold=1``), timed through ``run`` (the prior's draws included), by
    ``backend``.

    Returns
    -------
    rate, error, cpu_rate : float
        As :func:`ours_bootstrap`.
    """
    from radioloc.estimators.particle_filter import ParticleFilter
    from radioloc.models.measurement import Context, Observation
    from radioloc.models.ranging import RangeModel

    pf = ParticleFilter(RandomWalk(q), n_particles=n, ess_threshold=1.0, seed=1,
                        backend=backend)
    obs = Observation(RangeModel(std_m=sigma), y[:steps], Context(points=ANCHORS))
    kw = dict(time=np.arange(1.0, steps + 1.0), prior_mean=x[0], prior_cov=np.eye(2))
    pf.run(obs, **kw)
    dt, cpu = np.inf, np.inf
    for _ in range(3):                                                   # best of 3
        t0, c0 = time.perf_counter(), time.process_time()
        tr = pf.run(obs, **kw)
        dt = min(dt, time.perf_counter() - t0)
        cpu = min(cpu, time.process_time() - c0)
    print(f"generic ParticleFilter ({backend}), N={n}: {n * steps / cpu / 1e6:.2f} M "
          f"particle-steps per CPU second ({cpu / steps * 1e3:.2f} ms CPU, "
          f"{dt / steps * 1e3:.2f} ms wall per step)")
    return (n * steps / dt, float(np.linalg.norm(tr.position - x[1:steps + 1], axis=-1).mean()),
            n * steps / cpu)


def stonesoup_bootstrap(n, steps, q, sigma, x, y, repeat=3):
    """The same filter in Stone Soup (predictor, updater with systematic resampling):
    particle-steps per second (wall clock and per CPU second) and the mean error."""
    from datetime import datetime, timedelta

    from stonesoup.base import Property
    from stonesoup.models.measurement.nonlinear import NonLinearGaussianMeasurement
    from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel
    from stonesoup.models.transition.linear import RandomWalk as SSRandomWalk
    from stonesoup.predictor.particle import ParticlePredictor
    from stonesoup.resampler.particle import SystematicResampler
    from stonesoup.types.array import StateVector, StateVectors
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import ParticleState
    from stonesoup.updater.particle import ParticleUpdater

    class RangesToAnchors(NonLinearGaussianMeasurement):
        anchors: np.ndarray = Property(doc="anchor positions (M, 2)")

        @property
        def ndim_meas(self):
            return len(self.anchors)

        def function(self, state, noise=False, **kwargs):
            xy = np.asarray(state.state_vector[self.mapping, :], dtype=float)      # (2, N)
            d = np.sqrt(((xy[None, :, :] - self.anchors[:, :, None]) ** 2).sum(1))
            if noise is True:
                noise = self.rvs(num_samples=d.shape[1], **kwargs)
            return StateVectors(d) + (noise if not isinstance(noise, bool) else 0)

    tm = CombinedLinearGaussianTransitionModel([SSRandomWalk(q), SSRandomWalk(q)])
    mm = RangesToAnchors(ndim_state=2, mapping=(0, 1), noise_covar=sigma**2 * np.eye(4),
                         anchors=ANCHORS)
    predictor = ParticlePredictor(tm)
    updater = ParticleUpdater(mm, resampler=SystematicResampler())
    t0 = datetime(2024, 1, 1)
    rng = np.random.default_rng(1)
    start = x[0][:, None] + rng.standard_normal((2, n))

    def run(k):
        prior = ParticleState(StateVectors(start), weight=np.full(n, 1.0 / n), timestamp=t0)
        est = []
        for i in range(k):
            t = t0 + timedelta(seconds=i + 1)
            pred = predictor.predict(prior, timestamp=t)
            det = Detection(StateVector(y[i]), timestamp=t, measurement_model=mm)
            prior = updater.update(SingleHypothesis(pred, det))
            est.append(np.asarray(prior.mean, dtype=float).ravel())
        return np.array(est)
    run(1)
    dt, cpu = np.inf, np.inf
    for _ in range(repeat):                                              # best of `repeat`
        c, cc = time.perf_counter(), time.process_time()
        est = run(steps)
        dt, cpu = min(dt, time.perf_counter() - c), min(cpu, time.process_time() - cc)
    return (n * steps / dt, float(np.linalg.norm(est - x[1:steps + 1], axis=-1).mean()),
            n * steps / cpu)


def particles_bootstrap(n, steps, q, sigma, x, y, repeat=3):
    """The same filter in ``particles`` (Chopin): Bootstrap Feynman-Kac model, SMC with
    systematic resampling at every step (``ESSrmin=1``): particle-steps per second (wall clock
    and per CPU second, best of ``repeat`` runs of ``steps`` steps from the prior, as ours) and
    the mean error."""
    import particles
    from particles import distributions as dists
    from particles import state_space_models as ssm

    class RangeRW(ssm.StateSpaceModel):
        def PX0(self):
            return dists.MvNormal(loc=x[0], scale=1.0, cov=np.eye(2))

        def PX(self, t, xp):
            return dists.MvNormal(loc=xp, scale=np.sqrt(q), cov=np.eye(2))

        def PY(self, t, xp, xx):
            d = np.linalg.norm(xx[:, None, :] - ANCHORS, axis=-1)              # (N, 4)
            return dists.IndepProd(*[dists.Normal(loc=d[:, m], scale=sigma) for m in range(4)])

    data = [yy for yy in y[:steps]]
    fk = ssm.Bootstrap(ssm=RangeRW(), data=data)
    dt, cpu = np.inf, np.inf
    for _ in range(repeat):                                              # best of `repeat`
        alg = particles.SMC(fk=fk, N=n, resampling="systematic", ESSrmin=1.0,
                            collect=None, store_history=False, verbose=False)
        c, cc = time.perf_counter(), time.process_time()
        est = []
        for _ in range(steps):
            next(alg)
            est.append(np.average(alg.X, weights=alg.W, axis=0))
        dt, cpu = min(dt, time.perf_counter() - c), min(cpu, time.process_time() - cc)
    return (n * steps / dt, float(np.linalg.norm(np.array(est) - x[1:steps + 1], axis=-1).mean()),
            n * steps / cpu)


BOOTSTRAP_WORKLOAD = "range-only bootstrap PF, 4 anchors, 2-D random walk, N=1e5"
GENERIC_WORKLOAD = ("range-only bootstrap PF, generic ParticleFilter (Gaussian RangeModel), 4 "
                    "anchors, 2-D random walk, N=1e5")

#: Least memory traffic of one bootstrap particle-step (4 links) through the filter's passes:
#: the draws and the prediction (48 bytes), the link update (particle, carried and new link
#: posteriors, log weight: 88), the weights and moments (40), the resampling (cumulative
#: weight, the gathered particle, posteriors and ancestor: 136).
BOOTSTRAP_BYTES = 312.0


def bootstrap_flops(links: int = 4) -> float:
    """Floating-point operations of one bootstrap particle-step (alpha = 1) as the filter
    does it, counting a square root, exponential or logarithm as 20: two normal draws
    (about 30 each), the prediction 4, per link the residual 12, prior 10, Gaussian term
    4 and weight product 1 (no pooled sums: every link is certainly LOS), the weight's
    exponential 21, the moment sums 12, the resampling count and copies 6.

    Parameters
    ----------
    links : int
        Links (anchors) per particle.

    Returns
    -------
    float
    """
    return 103.0 + 27.0 * links


def bootstrap_rows(n: int = 100_000, steps: int = 30, peer_steps: int | None = None) -> list[dict]:
    """The range-only bootstrap PF (4 anchors, 2-D random walk) against Stone Soup and
    ``particles``.

    Parameters
    ----------
    n : int
        Particles.
    steps : int
        Steps of one timed run (ours and each peer: best of three runs each).
    peer_steps : int, optional
        Steps of a peer's run when fewer are wanted (default: ``steps``, the same work).

    Returns
    -------
    list of dict
        One row per peer.
    """
    q, sigma = 0.25, 0.3
    peer_steps = steps if peer_steps is None else peer_steps
    rng = np.random.default_rng(2)
    x, y = _bootstrap_data(steps, q, sigma, rng)
    ours, err, ours_cpu = ours_bootstrap(n, steps, q, sigma, x, y, rng)
    print(f"bootstrap PF, N={n}: ours {ours / 1e6:.2f} M particle-steps/s (mean error {err:.2f} m)")
    generic, g_err, generic_cpu = generic_bootstrap(n, steps, q, sigma, x, y)
    print(f"  generic ParticleFilter: {generic / 1e6:.2f} M particle-steps/s (mean error "
          f"{g_err:.2f} m)")
    slow, _, slow_cpu = generic_bootstrap(n, steps, q, sigma, x, y, backend="numpy")
    print(f"  generic ParticleFilter, backend='numpy': {slow / 1e6:.2f} M particle-steps/s; "
          f"numba/numpy {generic / slow:.1f}x, per CPU second {generic_cpu / slow_cpu:.1f}x")
    rows = []
    for name, fn in (("Stone Soup", stonesoup_bootstrap), ("particles (Chopin)", particles_bootstrap)):
        try:
            rate, perr, cpu_rate = fn(n, peer_steps, q, sigma, x, y)
        except ImportError as exc:
            print(f"{name}: not installed ({exc})")
            continue
        # the row is wall clock; per CPU second (all threads) is printed beside it: under
        # load the wall ratio swings with the second core's availability
        print(f"  {name}: {rate / 1e6:.3f} M particle-steps/s (mean error {perr:.2f} m), "
              f"ratio {ours / rate:.1f}x; per CPU second {cpu_rate / 1e6:.3f} M, "
              f"ratio {ours_cpu / cpu_rate:.1f}x")
        print(f"  generic ParticleFilter vs {name}: ratio {generic / rate:.1f}x; per CPU "
              f"second {generic_cpu / cpu_rate:.1f}x")
        for workload, rate_ours in ((BOOTSTRAP_WORKLOAD, ours), (GENERIC_WORKLOAD, generic)):
            row = _row(workload, rate_ours, "particle-steps/s", name, rate)
            row.update(bytes_per_unit=BOOTSTRAP_BYTES, flops_per_unit=bootstrap_flops(4))
            rows.append(row)
    return rows


def main() -> list[dict]:
    """Print and return every row.

    Returns
    -------
    list of dict
        ``{"workload", "throughput", "unit", "peer", "peer_throughput", "ratio"}``.
    """
    return highway_rows() + bootstrap_rows()


if __name__ == "__main__":
    main()
