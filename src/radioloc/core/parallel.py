"""Calls spread over local processes or a Dask cluster, their results as they finish.

Used by ``radioloc reproduce`` (an experiment's blocks of runs) and by ``radioloc locate
--workers/--scheduler`` (a log's groups of nodes). Local workers are processes started with
``spawn``, each with its share of the cores for numba (:func:`share_cores`); a scheduler
needs dask.distributed (``pip install 'radioloc[cluster]'``), and the cluster's workers need
radioloc installed.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from typing import Any

from radioloc.core.errors import ConfigError

__all__ = ["completed", "share_cores"]


def share_cores(workers: int) -> None:
    """In a worker process: give numba's parallel kernels this process's share of the cores.

    ``workers`` processes each running numba's default of one thread per core would put
    ``workers`` threads on every core, where OpenMP threads spin while they wait for each
    other; each worker gets ``max(1, cores // workers)`` threads instead.
    """
    import numba

    numba.set_num_threads(max(1, min(numba.config.NUMBA_NUM_THREADS,
                                     (os.cpu_count() or 1) // workers)))


def completed(fn: Callable, calls: list[tuple], workers: int = 1,
              scheduler: str | None = None) -> Iterator[tuple[int, Any]]:
    """``(i, fn(*calls[i]))`` for every call, as each finishes.

    On the Dask cluster at ``scheduler``; else in ``workers`` local processes when
    ``workers > 1`` and there is more than one call; else in this process, in order.
    ``fn`` must be a top-level function (it is pickled).

    Raises
    ------
    ConfigError
        ``scheduler`` given without dask.distributed installed.
    """
    if scheduler:
        try:
            from dask.distributed import Client
            from dask.distributed import as_completed as dask_as_completed
        except ImportError:  # pragma: no cover - depends on the install
            raise ConfigError("--scheduler needs dask.distributed: pip install "
                              "'radioloc[cluster]'") from None
        with Client(scheduler) as client:
            futures = {client.submit(fn, *args, pure=False): i for i, args in enumerate(calls)}
            for fut in dask_as_completed(futures):
                yield futures[fut], fut.result()
    elif workers > 1 and len(calls) > 1:
        with ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"),
                                 initializer=share_cores, initargs=(workers,)) as pool:
            futures = {pool.submit(fn, *args): i for i, args in enumerate(calls)}
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
    else:
        for i, args in enumerate(calls):
            yield i, fn(*args)
