"""Throughput of mixture reduction and localization (paper 004).

Peer: ``reduce(..., backend="numpy")``, the NumPy definition of the greedy West/Runnalls
reduction (one merge per iteration for the whole batch), measured in the same process
against the compiled kernel of :func:`radioloc.models.mixture.reduce` (the default
``backend="numba"``, the mixtures in parallel): wall time and, beside it, both per CPU second
(``time.process_time``, threads counted). The Progressive Bayes reduction
(:func:`radioloc.models.progressive_bayes.progressive_reduce`) is timed beside the compiled
West/Runnalls reduction it starts from (on a tenth of the batch). The tracker's continuous
default (fixed-structure merges) is timed against its greedy West/Runnalls option.
"""

import time

import numpy as np

from radioloc.estimators.mixture_localization import MixtureLocalizer, MixtureTracker
from radioloc.models.mixture import DiagMixture, product, reduce
from radioloc.models.motion import UniformDisk
from radioloc.models.progressive_bayes import progressive_reduce
from timing import best_of

#: floating-point operations per candidate partner of one West/Runnalls merge in 2-D: pass 1
#: of ``models.mixture_compiled._partner`` (the ratio ``y`` 18, its magnitude and the scale's
#: part 10, the logarithm-free bound 26); pass 2 adds about one ``log1p`` per merge, not
#: counted
FLOPS_PER_CANDIDATE = 54


def reduction_flops(k: int, kmax: int) -> float:
    """Pass-1 floating-point operations of one West/Runnalls reduction ``k -> kmax`` in 2-D.

    Parameters
    ----------
    k, kmax : int
        Components before and after (every merge at ``n`` components reads ``n``
        candidates, ``n = k, k - 1, ..., kmax + 1``).

    Returns
    -------
    float
        ``FLOPS_PER_CANDIDATE * sum(n)`` (2044 candidates for 64 -> 8).
    """
    return float(FLOPS_PER_CANDIDATE * sum(range(kmax + 1, k + 1)))


def localization_flops(stations: int = 6, k: int = 16, kmax: int = 8) -> float:
    """Floating-point operations of one row of eq. (2) in 2-D: per station the conditioning
    (about 12 per component) and its reduction ``k -> kmax``; per product after the first
    the ``kmax^2`` pairs (about 27 each) and their reduction ``kmax^2 -> kmax``.

    Parameters
    ----------
    stations, k, kmax : int
        Stations received, components per station model, the bound.

    Returns
    -------
    float
        Operations per row (about 5.9e5 for 6 x 16 -> 8).
    """
    pairs = kmax * min(k, kmax)
    return stations * (12.0 * k + reduction_flops(k, kmax)) \
        + (stations - 1) * (27.0 * pairs + reduction_flops(pairs, kmax))


def main(batch: int = 500, seed: int = 0) -> list[dict]:
    """Time the reductions and the localizer and print the throughputs.

    Parameters
    ----------
    batch : int
        Mixtures reduced at once (64 -> 8 components, 2-D).
    seed : int
        Seed of the random mixtures.

    Returns
    -------
    list of dict
        Rows ``{"workload", "throughput", "unit", "peer", "peer_throughput", "ratio"}``.
    """
    rng = np.random.default_rng(seed)
    b, k, d = batch, 8, 2
    a = DiagMixture.create(rng.uniform(0.1, 1, (b, k)), rng.normal(0, 3, (b, k, d)),
                           rng.uniform(0.5, 2, (b, k, d)))
    prod = product(a, a)                                   # 64 components each
    reduce(prod, 8)                                        # compile
    t_kernel = best_of(lambda: reduce(prod, 8), repeat=5)
    t_numpy = best_of(lambda: reduce(prod, 8, backend="numpy"))
    c_kernel = best_of(lambda: reduce(prod, 8), repeat=5, clock=time.process_time)
    c_numpy = best_of(lambda: reduce(prod, 8, backend="numpy"), repeat=2, clock=time.process_time)
    print(f"mixture reduction per CPU second: kernel {b / c_kernel:,.0f}, NumPy "
          f"{b / c_numpy:,.0f} mixtures/s, ratio {c_numpy / c_kernel:.2f}x")
    flops = reduction_flops(64, 8)
    rows = [{"workload": "mixture reduction 64 -> 8 (West/Runnalls, 2-D)",
             "throughput": b / t_kernel, "unit": "mixtures/s",
             "peer": "NumPy (same greedy rule, vectorised over the batch)",
             "peer_throughput": b / t_numpy, "ratio": t_numpy / t_kernel,
             "flops_per_unit": flops}]
    # without exact ties (a product of two different mixtures): the reference's tie handling,
    # which evaluates every tied row, does not inflate the ratio here
    a2 = DiagMixture.create(rng.uniform(0.1, 1, (b, k)), rng.normal(0, 3, (b, k, d)),
                            rng.uniform(0.5, 2, (b, k, d)))
    prod2 = product(a, a2)
    t_kernel2 = best_of(lambda: reduce(prod2, 8), repeat=5)
    t_numpy2 = best_of(lambda: reduce(prod2, 8, backend="numpy"))
    rows.append({"workload": "mixture reduction 64 -> 8 (West/Runnalls, 2-D), no exact ties",
                 "throughput": b / t_kernel2, "unit": "mixtures/s",
                 "peer": "NumPy (same greedy rule, vectorised over the batch)",
                 "peer_throughput": b / t_numpy2, "ratio": t_numpy2 / t_kernel2,
                 "flops_per_unit": flops})
    c_kernel2 = best_of(lambda: reduce(prod2, 8), repeat=5, clock=time.process_time)
    c_numpy2 = best_of(lambda: reduce(prod2, 8, backend="numpy"), repeat=2, clock=time.process_time)
    print(f"mixture reduction, no exact ties, per CPU second: kernel {b / c_kernel2:,.0f}, "
          f"NumPy {b / c_numpy2:,.0f} mixtures/s, ratio {c_numpy2 / c_kernel2:.2f}x")
    nb = max(1, b // 10)
    sub = prod[:nb]
    progressive_reduce(sub[:2], 8)                         # compile
    t_prog = best_of(lambda: progressive_reduce(sub, 8), repeat=2)
    t_west = best_of(lambda: reduce(sub, 8), repeat=5)
    rows.append({"workload": "mixture reduction 64 -> 8 (Progressive Bayes ISD homotopy, 2-D)",
                 "throughput": nb / t_prog, "unit": "mixtures/s",
                 "peer": "compiled West/Runnalls (its start)", "peer_throughput": nb / t_west,
                 "ratio": t_west / t_prog})
    models = DiagMixture.create(rng.uniform(0.1, 1, (6, 16)), rng.normal(0, 3, (6, 16, 3)),
                                rng.uniform(0.5, 4, (6, 16, 3)))
    rss = rng.normal(0, 3, (1000, 6))
    loc = MixtureLocalizer(models, 8)
    t_loc = best_of(lambda: loc.locate(rss))
    print(f"MixtureLocalizer.locate (6 stations x 16 components, eq. (2)): "
          f"{rss.shape[0] / t_loc:,.0f} rows/s")
    # tracking: 200 steps of 0.33 s, 4 stations x 16 components, 8 position components,
    # a batch of 8 runs; the continuous default against the greedy West/Runnalls option
    steps, runs = 200, 8
    tmod = DiagMixture.create(rng.uniform(0.1, 1, (4, 16)), rng.normal(0, 3, (4, 16, 3)),
                              rng.uniform(0.5, 4, (4, 16, 3)))
    trss = rng.normal(0, 3, (runs, steps, 4))
    times = 0.33 * np.arange(steps)
    cont = MixtureTracker(tmod, UniformDisk(1.5), 8)
    greedy = MixtureTracker(tmod, UniformDisk(1.5), 8, reduction="runnalls")
    cont.run(trss[:, :3], times[:3])
    greedy.run(trss[:, :3], times[:3])
    t_cont = best_of(lambda: cont.run(trss, times), repeat=2)
    t_greedy = best_of(lambda: greedy.run(trss, times), repeat=1)
    rows.append({"workload": "mixture tracking, 4 stations x 16 components, 8 position "
                             "components (continuous default)",
                 "throughput": runs * steps / t_cont, "unit": "run-steps/s",
                 "peer": "reduction='runnalls' (greedy West/Runnalls, same tracker)",
                 "peer_throughput": runs * steps / t_greedy, "ratio": t_greedy / t_cont})
    for r in rows:
        print(f"{r['workload']}: {r['throughput']:,.0f} {r['unit']}, {r['peer']} "
              f"{r['peer_throughput']:,.0f}, ratio {r['ratio']:.2f}x")
    return rows


if __name__ == "__main__":
    main()
