"""CPU time of the closed-form iterative BLUE against Newton on the NLLS (paper 002, Fig. 3).

Both use the stopping rule |beta_{m+1} - beta_m|^2 <= 0.1 of section 5.2 and run batched over
Monte Carlo runs; Newton starts from the truth plus N(0, 1) per component (as in the
experiment). Prints tracks/s for each n and the ratio Newton time / BLUE time, for a batch
and for one track at a time (the paper's setting).

    PYTHONPATH=src python benchmarks/bench_closed_form.py
"""

from __future__ import annotations

import time

import numpy as np

from radioloc.estimators.closed_form import closed_form_track
from radioloc.estimators.nlls_newton import newton_track
from radioloc.models.track_noise import ConstantAcceleration
from timing import best_of


def cpu_best_of(fn, repeat=3):
    return best_of(fn, repeat, clock=time.process_time)


T, Q, XI = 0.1, 0.15, 0.1


def data(runs, n, rng):
    ang = np.arange(n) * 1.3
    sensor = 5.0 * np.stack([np.cos(ang), np.sin(ang)], -1)
    x0 = np.c_[rng.uniform(-2, 2, (runs, 2)), rng.normal(0, 1, (runs, 2))]
    tracks = ConstantAcceleration(T, Q).sample(x0, n, rng)
    h = np.sqrt(3 * XI)
    r = np.abs(np.linalg.norm(tracks[..., :2] - sensor, axis=-1) + rng.uniform(-h, h, (runs, n)))
    truth = tracks[:, -1][:, [1, 0, 3, 2]]
    return r, sensor, truth + rng.normal(0, 1, truth.shape)



def main():
    rng = np.random.default_rng(0)
    print(f"{'n':>4} {'mode':>8} {'BLUE tracks/s':>14} {'Newton tracks/s':>16} {'Newton/BLUE':>12}")
    for n in (10, 20, 30, 40, 50, 60):
        for mode, runs in (("batch", 1000), ("single", 50)):
            r, s, start = data(runs, n, rng)
            if mode == "batch":
                tb = cpu_best_of(lambda: closed_form_track(r, s, sample_period_s=T, accel_var=Q,
                                                       range_var=XI))
                tn = cpu_best_of(lambda: newton_track(r, s, start, sample_period_s=T))
            else:
                tb = cpu_best_of(lambda: [closed_form_track(r[i], s, sample_period_s=T, accel_var=Q,
                                                        range_var=XI) for i in range(runs)])
                tn = cpu_best_of(lambda: [newton_track(r[i], s, start[i], sample_period_s=T)
                                      for i in range(runs)])
            print(f"{n:>4} {mode:>8} {runs / tb:>14.0f} {runs / tn:>16.0f} {tn / tb:>12.2f}")


if __name__ == "__main__":
    main()
