"""Throughput of mixture reduction and localization (paper 004).

Peer: a vectorised NumPy implementation of the same greedy West/Runnalls reduction (one
merge per iteration for the whole batch), measured in the same process against the compiled
kernel used by :func:`radioloc.models.mixture.reduce`.
"""

import time

import numpy as np

from radioloc.estimators.mixture_localization import MixtureLocalizer
from radioloc.models.mixture import DiagMixture, merge_moments, product, reduce, runnalls_cost
from timing import best_of


def numpy_reduce(mix: DiagMixture, kmax: int) -> DiagMixture:
    w, m, v = mix.weights.copy(), mix.means.copy(), mix.variances.copy()
    rows = np.arange(w.shape[0])
    while True:
        active = w > 0
        need = active.sum(-1) > kmax
        if not need.any():
            return DiagMixture(w, m, v)
        r = rows[need]
        i = np.argmin(np.where(active[r], w[r], np.inf), -1)
        cost = runnalls_cost(w[r, i][:, None], m[r, i][:, None], v[r, i][:, None], w[r], m[r], v[r])
        cost = np.where(active[r], cost, np.inf)
        cost[np.arange(r.size), i] = np.inf
        j = np.argmin(cost, -1)
        w[r, j], m[r, j], v[r, j] = merge_moments(w[r, i], m[r, i], v[r, i], w[r, j], m[r, j], v[r, j])
        w[r, i] = 0.0


def main():
    rng = np.random.default_rng(0)
    b, k, d = 500, 8, 2
    a = DiagMixture.create(rng.uniform(0.1, 1, (b, k)), rng.normal(0, 3, (b, k, d)),
                           rng.uniform(0.5, 2, (b, k, d)))
    prod = product(a, a)                                   # 64 components each
    reduce(prod, 8)                                        # compile
    t_kernel = best_of(lambda: reduce(prod, 8))
    t_numpy = best_of(lambda: numpy_reduce(prod, 8))
    print(f"reduce {b} mixtures 64 -> 8 components: compiled {b / t_kernel:,.0f} mixtures/s, "
          f"NumPy peer {b / t_numpy:,.0f} mixtures/s, ratio {t_numpy / t_kernel:.1f}x")
    models = DiagMixture.create(rng.uniform(0.1, 1, (6, 16)), rng.normal(0, 3, (6, 16, 3)),
                                rng.uniform(0.5, 4, (6, 16, 3)))
    rss = rng.normal(0, 3, (1000, 6))
    loc = MixtureLocalizer(models, 8)
    t_loc = best_of(lambda: loc.locate(rss))
    print(f"MixtureLocalizer.locate (6 stations x 16 components, eq. (2)): "
          f"{rss.shape[0] / t_loc:,.0f} rows/s")


if __name__ == "__main__":
    main()
