"""Compile the estimators' kernels before the test session, two processes side by side.

`make test` runs this before pytest. numba keeps each compiled kernel in its on-disk cache
(``cache=True``), so the test workers then load the kernels instead of compiling them; without
this step both workers compile the larger kernels at the same time early in the session (a
kernel a worker has not yet found in the cache is compiled again by the other), about 150 s
of CPU spent twice on a cold machine. Each process solves the valid problem of a share of
the estimators (the library fuzz's cases, the public API with the tests' array types) plus a
few paths those problems do not take (the recursive grid blur, the bootstrap particle
filter with parallel draws, the 2-D mixture reduction, the network EKF with a master per
run, the channel's ray tracer and GSIC ranging). A failure here is reported and skipped: the tests then
compile what they need themselves.

    python tests/precompile.py            # both shares in parallel
"""

from __future__ import annotations

import sys
import time
import traceback
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

HERE = Path(__file__).resolve().parent

#: The two shares, about equal in compile time on a cold cache (largest first).
SHARES = (
    ("+channel", "ClosedFormTracker", "LocalML", "NetworkRLS", "Multilateration", "Ransac",
     "RangeEKF", "NewtonTracker"),
    ("MixtureTracker", "P2PParticleFilter", "NetworkEKF", "+grid-recursive", "+bootstrap-pf",
     "MixtureLocalizer", "GridFilter", "+mixture-reduce", "+ekf-step"),
)


def _grid_recursive():
    import numpy as np

    from radioloc.estimators.grid import GridFilter, GridGeometry
    from radioloc.models.rssi_trapezoid import fit_trapezoid_model

    rng = np.random.default_rng(0)
    d = rng.uniform(0, 60, 2000)
    model = fit_trapezoid_model(np.clip(np.rint(95 - 0.45 * d + rng.normal(0, 4, d.size)),
                                        0, 100), d)
    filt = GridFilter(GridGeometry.centred(40, 40, 0.5), model, epsilon=1e-12, blur_m=1.0,
                      blur="recursive")
    state = filt.init(2)
    for _ in range(2):
        state = filt.step(state, rng.uniform(-5, 5, (2, 2)), rng.integers(40, 80, 2))
    filt.estimate(state)


def _bootstrap_pf():
    import numpy as np

    from radioloc.estimators.p2p_particle import P2PParticleFilter
    from radioloc.models.los_nlos import LosNlosRange
    from radioloc.models.motion import RandomWalk

    anchors = np.array([[0.0, 0.0], [30.0, 0.0], [0.0, 30.0], [30.0, 30.0]])
    rng = np.random.default_rng(0)
    x0 = np.array([10.0, 10.0])
    ranges = np.linalg.norm(x0 - anchors, axis=-1) + rng.normal(0, 0.3, (5, 4))
    ranges = np.concatenate([np.full((5, 1), np.nan), ranges], axis=-1)[None, None]
    pf = P2PParticleFilter(RandomWalk(0.25), LosNlosRange(0.3, 1.0, 1.0), particles=70_000,
                           init_std=1.0)
    pf.run(ranges, x0[None, None], rng, anchors=anchors)


def _ekf_step():
    import numpy as np

    from radioloc.core.geometry import pairwise_distances
    from radioloc.estimators.ekf import NetworkEKF

    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 100, (2, 6, 2))
    ekf = NetworkEKF(std_m=1.0)
    state = ekf.init(truth + rng.normal(0, 1, truth.shape), np.ones(truth.shape))
    masters = np.array([1, 4])
    rho = pairwise_distances(truth)[np.arange(2), masters]          # (runs, nodes)
    ekf.step(state, masters, rho, np.ones(rho.shape, bool))        # a master per run


def _mixture_reduce():
    import numpy as np

    from radioloc.models.mixture import DiagMixture, reduce
    from radioloc.models.progressive_bayes import progressive_reduce

    rng = np.random.default_rng(0)
    mix = DiagMixture.create(rng.uniform(0.1, 1, (40, 64)), rng.normal(0, 3, (40, 64, 2)),
                             rng.uniform(0.5, 4, (40, 64, 2)))
    reduce(mix, 8)
    progressive_reduce(DiagMixture.create(mix.weights[:2, :12], mix.means[:2, :12],
                                          mix.variances[:2, :12]), 3, steps=1)


def _channel():
    import numpy as np

    from radioloc.channel.cdma import CDMAConfig, gold_codes, received_acks
    from radioloc.channel.gsic import matched_filter_toa, omp_sic_toa
    from radioloc.channel.raytrace import TraceConfig, trace_links
    from radioloc.channel.scene import city_grid, street_positions

    rng = np.random.default_rng(0)
    scene = city_grid(rng, size_m=300.0)
    nodes = street_positions(scene, 4, rng, half_width_m=120.0)
    i, j = np.nonzero(~np.eye(4, dtype=bool))
    trace_links(scene, nodes[i], nodes[j], TraceConfig(max_order=2, max_excess_m=200.0))
    cdma = CDMAConfig()
    codes = gold_codes(cdma.code_degree)
    delays = rng.uniform(0, 0.5 * cdma.window_s, (2, 3, 2))
    y = received_acks(delays, np.ones(delays.shape, complex), rng.integers(0, 5, (2, 3)), cdma,
                      rng, codes)
    ci = np.tile(np.arange(3), (2, 1))
    omp_sic_toa(y, ci, codes, cdma)
    matched_filter_toa(y, ci, codes, cdma)


EXTRA = {"+grid-recursive": _grid_recursive, "+bootstrap-pf": _bootstrap_pf,
         "+mixture-reduce": _mixture_reduce, "+ekf-step": _ekf_step, "+channel": _channel}


def warm(names: tuple[str, ...]) -> list[str]:
    """Solve each named problem once (compiling its kernels into the on-disk cache).

    Parameters
    ----------
    names : tuple of str
        Keys of the library fuzz's ``CASES`` or of :data:`EXTRA`.

    Returns
    -------
    list of str
        One line per problem: its name and seconds, or the error it raised.
    """
    sys.path[:0] = [str(HERE / "fuzz"), str(HERE.parent / "src")]
    import warnings

    from library_harness import CASES

    out = []
    for name in names:
        t0 = time.perf_counter()
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if name in EXTRA:
                    EXTRA[name]()
                else:
                    case = CASES[name]()
                    case.solve(case.settings, case.args)
            out.append(f"{name} {time.perf_counter() - t0:.0f} s")
        except Exception as exc:                 # the tests compile it themselves then
            out.append(f"{name}: not compiled here ({type(exc).__name__}: {exc})"
                       .splitlines()[0][:200])
            traceback.print_exc()
    return out


def main() -> int:
    t0 = time.perf_counter()
    with ProcessPoolExecutor(len(SHARES)) as pool:
        done = list(pool.map(warm, SHARES))
    print(f"kernels compiled ahead of the tests in {time.perf_counter() - t0:.0f} s: "
          + "; ".join(line for share in done for line in share))
    return 0


if __name__ == "__main__":
    sys.exit(main())
