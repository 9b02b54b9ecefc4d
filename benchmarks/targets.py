"""The performance targets of the benchmark rows, and what bounds a row that misses its own.

``collect.py`` compares every measured row with its target here (by workload name, and by
peer where the target is a ratio to that peer) and writes the verdict into ``RESULTS.md``
(columns "target" and "meets") and ``results.json`` (``target``, ``meets_target``). For a
row that misses its target, ``RESULTS.md`` lists below the table what bounds it, with the
fraction of the machine's limit measured in the same run.

A target is a dict with ``throughput`` (at least this many units per second) and/or
``ratio`` (at least this multiple of the peer named by ``peer``, measured in the same
process), or ``at_most`` (a row whose "throughput" is a time in seconds or a count: at most
this). Rows without a target (per-CPU-second rows, diagnostics) are informational.
"""

from __future__ import annotations

TARGETS: dict[tuple[str, str | None], dict] = {
    # user budgets: whole commands (bench_budgets.py)
    ("warm `make demo` (reproduce all, quick size)", None): {"at_most": 90.0},
    ("cold kernel compile, whole suite (tests/precompile.py)", None): {"at_most": 60.0},
    ("reproduce p001-highway --full --workers 2", None): {"at_most": 600.0},
    ("lines compiled by numba in src/", None): {"at_most": 2500},
    # radioloc locate on long logs, CPU seconds of the whole command (bench_locate.py)
    ("radioloc locate ekf-track, 1e+06-row log (10 tags, 6 anchors)", None): {"at_most": 10.0},
    ("radioloc locate gn, 1e+06-row log (10 tags, 6 anchors)", None): {"at_most": 8.0},
    ("radioloc locate pf, 1e+05-row log (10 tags, 6 anchors)", None): {"at_most": 10.0},
    ("radioloc locate smoother, 1e+05-row log (10 tags, 6 anchors)", None): {"at_most": 10.0},
    # start-up, CPU seconds (bench_startup.py); every method's row: below
    ("radioloc --help", None): {"at_most": 0.3},
    # paper 004's corridor at the quick size, wall seconds on 2 cores (bench_budgets.py)
    ("reproduce p004-corridor (quick size)", None): {"at_most": 120.0},
    # 5000 runs x 2 noise levels x 2 algorithms x 50 iterations = 1e6 run-iterations in 2 s
    ("paper 000 full Monte Carlo, estimators (5000 runs x 2 noise x RLS+EKF x 50 it.)", None):
        {"throughput": 5e5},
    # the same model at the same size as a peer, in the same run
    ("range-only bootstrap PF, 4 anchors, 2-D random walk, N=1e5", "Stone Soup"):
        {"ratio": 10.0},
    ("range-only bootstrap PF, 4 anchors, 2-D random walk, N=1e5", "particles (Chopin)"):
        {"ratio": 10.0},
    ("range-only bootstrap PF, generic ParticleFilter (Gaussian RangeModel), 4 anchors, 2-D "
     "random walk, N=1e5", "Stone Soup"): {"ratio": 10.0},
    ("range-only bootstrap PF, generic ParticleFilter (Gaussian RangeModel), 4 anchors, 2-D "
     "random walk, N=1e5", "particles (Chopin)"): {"ratio": 10.0},
    ("paper 000 network EKF (K = 6)", "filterpy ExtendedKalmanFilter"): {"ratio": 100.0},
    ("grid update + blur 1000x1000 (recursive)", "scipy.ndimage update + gaussian_filter"):
        {"ratio": 20.0},
    ("mixture reduction 64 -> 8 (West/Runnalls, 2-D), no exact ties",
     "NumPy (same greedy rule, vectorised over the batch)"): {"ratio": 10.0},
    ("paper 002 BLUE, n = 60, batched", "batched Newton (radioloc NewtonTracker)"):
        {"ratio": 3.0},
}

#: CPU seconds of ``radioloc locate`` on a small log, for every method (bench_startup.py).
STARTUP_S = 0.6
STARTUP_PREFIX = "radioloc locate start-up, --method "

# What bounds each row that can miss its target. Printed under the table only when the row
# misses.
BOUNDS: dict[str, str] = {
    "range-only bootstrap PF, generic ParticleFilter (Gaussian RangeModel), 4 anchors, 2-D "
    "random walk, N=1e5":
        "the generic filter with backend='numba' (default): per step of 1e5 particles about "
        "4.3-5.5 ms of CPU on the loaded machine (one thread; the NumPy backend 25-36 ms), of "
        "which the 2e5 normal draws 0.85 ms (numba's Generator, 8 child streams), the "
        "compiled range likelihood 0.55, systematic resampling with the gather 0.55, the "
        "moment sums 0.42, and NumPy passes over the weights and the motion noise (exponential, "
        "maximum, normalisation) with Python about 1.5. `particles` takes 23-30 ms of CPU per "
        "step, so 10x per CPU second needs about 2.5 ms: beyond the draws and four passes "
        "over the particles on one core. On a loaded machine the two kernels' threads also "
        "wait for each other: wall time is about twice the CPU time, against 1.5 for the peer.",
    "radioloc --help": "imports typer, click and rich; typer 0.29 also imports pydantic.",
    "radioloc locate pf, 1e+05-row log (10 tags, 6 anchors)":
        "a profile (pyinstrument, quiet machine, 15.8 s in all): learning the settings 7.4 s "
        "(the trackers' EKF over every node's steps, 4.4 s, the start fits 0.8 s, the "
        "LOS/NLOS EM fits 1.5 s), the particle filter 4.0 s (its segments in one batch per "
        "learned q; drawing the motion noise 2.2 s of it), the health check, imports and the "
        "CSV the rest.",
    "radioloc locate ekf-track, 1e+06-row log (10 tags, 6 anchors)":
        "a profile (pyinstrument, quiet machine, 42 s with the profiler): learning the "
        "settings 14 s (13 filter runs over each node's first 5,000 steps), the tracks 10 s "
        "(every tag in one batch with its learned settings, 16 states: one sequential EKF "
        "update per row in NumPy, some 40 calls on the batch), the health check 13 s (the "
        "windows' robust fits 7 s: 31 IRLS passes over every row; the epoch fixes of the "
        "persistence test 4 s), reading, writing and imports 4 s.",
    "radioloc locate gn, 1e+06-row log (10 tags, 6 anchors)":
        "a profile (pyinstrument, 20 s of CPU with the profiler): the health check 15 s (the "
        "windows' robust fits 8.6 s, 31 IRLS passes over every row, which do not converge "
        "early on real logs; the epoch fixes of the persistence test 3.7 s); the method "
        "itself (the epochs table and the Gauss-Newton solve of 175k epochs) about 1 s, "
        "reading the CSV 1.5 s, imports 1.3 s.",
    "radioloc locate smoother, 1e+05-row log (10 tags, 6 anchors)":
        "a profile (pyinstrument, loaded machine, 31 s of CPU with the profiler): each "
        "node's batch smoother 21 s (its banded Gauss-Newton solves, scipy's solveh_banded, "
        "13 s; its own start filter 4 s), learning the settings 9 s.",
    "range-only bootstrap PF, 4 anchors, 2-D random walk, N=1e5":
        "the general particle filter's step, one kernel per part of Algorithm 2 (no fused "
        "step): 4.3 ms of wall per step of 1e5 particles on 2 cores in make bench, where 10x "
        "Stone Soup needs about 3.0 ms and 10x `particles` about 2.3 ms. A profile of the "
        "step (on a shared machine, 7.4 ms per step) splits it as: the link update 26 % (4 "
        "links, a scalar sqrt per particle-link, a log per particle), the systematic "
        "resampling with the gather of particles and link posteriors 17 %, the 2e5 normal "
        "draws 14 % (numba's Generator, about 8 ns per number per thread) and 3 % to spawn "
        "their 8 child generators, the motion prediction in NumPy 8 %, the weights' "
        "exponential and moments 8 %, the rest Python and fresh arrays. The fused kernel "
        "that met the ratios (a private random generator and vector math) was removed for "
        "one NumPy definition per part.",
}

# every method's start-up row (bench_startup.startup_workload), CPU seconds
for _method in ("closed-form", "ekf", "ekf-track", "gmm", "gn", "grid-rssi", "localml", "lsq",
                "newton", "pf", "ransac", "rls", "smoother"):
    _workload = f"{STARTUP_PREFIX}{_method}, small log (after the first run)"
    TARGETS[(_workload, None)] = {"at_most": STARTUP_S}
    BOUNDS[_workload] = (
        "the libraries' imports (README.md, \"Where the time goes (start-up and long logs)\"): "
        "pandas with pyarrow, numpy and typer with pydantic for every method; scipy and numba "
        "with its cached kernels for the methods that call them.")

def target_of(row: dict) -> dict | None:
    """The target of a bench row, if the issue set one.

    Parameters
    ----------
    row : dict
        A bench row (``workload`` and ``peer`` are used).

    Returns
    -------
    dict or None
        ``{"throughput": float}`` and/or ``{"ratio": float}``, or ``{"at_most": float}``.
    """
    return TARGETS.get((row.get("workload"), row.get("peer")))


def meets(row: dict, target: dict) -> bool:
    """Whether a measured row reaches every part of its target.

    Parameters
    ----------
    row : dict
        A bench row with ``throughput`` and ``ratio``.
    target : dict
        From :func:`target_of`.

    Returns
    -------
    bool
        True when the throughput and the ratio (where targeted) are at least the target, and
        an ``at_most`` row is at most its bound.
    """
    ok = True
    if "at_most" in target:
        ok &= row.get("throughput") is not None and row["throughput"] <= target["at_most"]
    if "throughput" in target:
        ok &= row.get("throughput") is not None and row["throughput"] >= target["throughput"]
    if "ratio" in target:
        ok &= row.get("ratio") is not None and row["ratio"] >= target["ratio"]
    return bool(ok)


def describe(target: dict) -> str:
    """The target as a short text for the table (``>= 500 M/s, >= 20x``).

    Parameters
    ----------
    target : dict
        From :func:`target_of`.

    Returns
    -------
    str
        The parts of the target, joined by a comma.
    """
    parts = []
    if "at_most" in target:
        parts.append(f"<= {target['at_most']:,g}")
    if "throughput" in target:
        v = target["throughput"]
        parts.append(f">= {v / 1e6:g} M/s" if v >= 1e6 else
                     f">= {v / 1e3:g} k/s" if v >= 1e3 else f">= {v:g}/s")
    if "ratio" in target:
        parts.append(f">= {target['ratio']:g}x")
    return ", ".join(parts)

# radioloc locate on a 1e7-row log read in chunks: peak memory of the command, MB
# (bench_chunked.py)
for _method in ("ekf-track", "lsq", "gn"):
    TARGETS[(f"radioloc locate {_method} --chunk-rows 200000, 1e+07-row log (10 tags, 6 "
             "anchors): peak memory", None)] = {"at_most": 1024.0}

# radioloc locate --follow, live: at least 50,000 rows/s sustained through a pipe and a p99
# of at most 5 ms from a row's arrival to its estimate (bench_stream.py)
TARGETS[("locate --follow ekf-track, 8 anchors x 10 tags at 10 Hz (pipe)",
         "locate --method ekf-track (batch, same log)")] = {"throughput": 5e4}
TARGETS[("locate --follow ekf-track, real-time feed of 10 tags x 8 anchors at 10 Hz, "
         "--reorder-s 0, arrival of a step's last row to its estimate read, --idle-s 0.001: "
         "p99 latency", None)] = {"at_most": 5.0}

# radioloc locate --follow over an endless stream: memory flat within 10 % over 1e7 rows
# (bench_stream_memory.py)
TARGETS[("radioloc locate --follow ekf-track, 1e+07 streamed rows: memory growth after the "
         "first 1e6 rows", None)] = {"at_most": 10.0}
