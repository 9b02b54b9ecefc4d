"""``radioloc locate --workers N`` and ``--scheduler tcp://HOST:PORT``: a log's nodes spread
over local processes or a Dask cluster.

The methods of :data:`FLEET_METHODS` estimate each node from its own rows, so a log's nodes
can be estimated apart: the nodes are dealt into groups of about equal rows
(:func:`node_groups`: the largest first, each to the lightest group; up to
:data:`GROUPS_PER_WORKER` groups a worker, so that one slow group does not hold the others),
each group's rows run through :func:`radioloc.locate.base.run_method` as a log of their own,
in a worker, and the estimates are put back in the one-process run's order
(:func:`radioloc.locate.table.order_rows`: by time, then the nodes as they first appear in
the log). The estimates are the one-process run's (the same CSV bytes:
``tests/test_locate_fleet.py``). What differs: the checks of a whole log (plausibility, unit
slips, the health check's) judge each group's rows; the summary's counts are summed over
the groups and its figures are the largest (:func:`radioloc.locate.chunked.merge_summaries`);
each distinct warning is shown once.

Refused, with the reason: a method not in :data:`FLEET_METHODS`, a log where a node ranges
to another node (their estimates depend on each other), ``-o cooperative=1``. The groups
run as :func:`radioloc.core.parallel.completed` runs calls.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError
from radioloc.core.parallel import completed
from radioloc.locate.base import LocateRequest, run_method
from radioloc.locate.progress import progress
from radioloc.locate.table import order_rows

__all__ = ["FLEET_METHODS", "GROUPS_PER_WORKER", "locate_fleet", "node_groups"]

#: Methods whose nodes are estimated from their own rows alone.
FLEET_METHODS = ("ekf-track", "smoother", "lsq")
#: Groups of nodes made per worker.
GROUPS_PER_WORKER = 4


def node_groups(meas: pd.DataFrame, groups: int) -> list[list[str]]:
    """The nodes of ``meas`` dealt into at most ``groups`` groups of about equal rows: the
    node with the most rows first, each to the group with the fewest rows so far (ties: the
    node first in the log, the first group); each group's nodes in the log's order."""
    order = list(meas["node"].unique())
    sizes = meas.groupby("node", sort=False).size()
    k = max(1, min(int(groups), len(order)))
    load, members = np.zeros(k), [[] for _ in range(k)]
    for node in sorted(order, key=lambda n: (-int(sizes[n]), order.index(n))):
        g = int(np.argmin(load))
        load[g] += int(sizes[node])
        members[g].append(node)
    rank = {n: i for i, n in enumerate(order)}
    return [sorted(m, key=rank.__getitem__) for m in members if m]


def run_group(method_name: str, request: LocateRequest) -> tuple[pd.DataFrame, list]:
    """One group's run, with the warnings it raised as ``(message, category)`` (a top-level
    function, so that it pickles)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = run_method(method_name, request)
    return out, [(str(w.message), w.category) for w in caught]


def _refuse(method_name: str, request: LocateRequest) -> None:
    if method_name not in FLEET_METHODS:
        raise ConfigError(f"--workers/--scheduler: method {method_name!r} estimates its nodes "
                          f"together; they run apart with {', '.join(FLEET_METHODS)}")
    if str(request.options.get("cooperative", "0")).lower() in ("1", "true", "yes", "on"):
        raise ConfigError("--workers/--scheduler: -o cooperative=1 estimates the nodes "
                          "together; leave it out to spread the nodes")
    meas = request.measurements
    between = meas["peer"].isin(set(meas["node"]))
    if between.any():
        row = meas[between].iloc[0]
        raise ConfigError(f"--workers/--scheduler: node {row['node']!r} ranges to node "
                          f"{row['peer']!r}, so their estimates depend on each other; "
                          "run in one process")


def locate_fleet(method_name: str, request: LocateRequest, workers: int = 2,
                 scheduler: str | None = None) -> pd.DataFrame:
    """``run_method(method_name, request)`` with the nodes spread over ``workers`` local
    processes or the Dask cluster at ``scheduler`` (module docstring).

    Parameters
    ----------
    method_name : str
        One of :data:`FLEET_METHODS`.
    request : LocateRequest
    workers : int
        Local worker processes (with ``scheduler``: how many groups to make per
        :data:`GROUPS_PER_WORKER`, the cluster's workers being unknown here).
    scheduler : str, optional
        A Dask scheduler's address.

    Returns
    -------
    DataFrame
        As :func:`radioloc.locate.base.run_method`, its ``attrs["summary"]`` merged over the
        groups, plus ``fleet`` (workers, scheduler, groups).

    Raises
    ------
    ConfigError
        ``workers`` below 1, or a method or log whose nodes cannot run apart.
    """
    from radioloc.locate.chunked import merge_summaries

    if workers < 1:
        raise ConfigError(f"--workers: must be >= 1, got {workers}")
    _refuse(method_name, request)
    meas = request.measurements
    groups = node_groups(meas, GROUPS_PER_WORKER * workers)
    requests = [LocateRequest(meas[meas["node"].isin(g)].reset_index(drop=True),
                              request.anchors, request.priors, request.calibration,
                              request.options, frame=request.frame) for g in groups]
    outs: list = [None] * len(groups)
    seen: set = set()
    with progress(len(meas), f"{method_name} on {workers} worker(s)") as bar:
        for i, (out, caught) in completed(run_group, [(method_name, r) for r in requests],
                                          workers, scheduler):
            outs[i] = out
            bar.advance(len(requests[i].measurements))
            for message, category in caught:
                if message not in seen:
                    seen.add(message)
                    warnings.warn(message, category, stacklevel=2)
    summary: dict = {}
    for out in outs:
        merge_summaries(summary, out.attrs.get("summary", {}))
    estimates = order_rows(pd.concat(outs, ignore_index=True),
                           list(meas["node"].unique()))
    summary["fleet"] = {"workers": workers, "scheduler": scheduler, "groups": len(groups)}
    estimates.attrs["summary"] = summary
    return estimates
