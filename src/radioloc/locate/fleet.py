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

A log in parts (a folder of Parquet files, :func:`radioloc.io.logs.measurement_parts`, e.g.
partitioned by node) is read by part (:func:`locate_fleet_parts`): here only its ``node`` and
``peer`` columns, to deal the groups; each worker reads and checks the parts of its own
nodes.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError
from radioloc.core.parallel import completed
from radioloc.locate.base import LocateRequest, run_method
from radioloc.locate.progress import progress
from radioloc.locate.table import order_rows

__all__ = ["FLEET_METHODS", "GROUPS_PER_WORKER", "locate_fleet", "locate_fleet_parts",
           "node_groups", "part_index"]

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


def run_parts(method_name: str, parts: list, nodes: list[str], request: LocateRequest,
              not_detected: float | None) -> tuple[pd.DataFrame, list]:
    """One group's run from the parts of a log: its nodes' rows read and checked here, in
    the worker (``request`` without measurements)."""
    from radioloc.io.logs import read_measurement_parts, subtract_anchor_bias

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        meas = subtract_anchor_bias(read_measurement_parts(
            parts, nodes=set(nodes), anchors=request.anchors, not_detected=not_detected),
            request.anchors)
        out, more = run_group(method_name, replace(request, measurements=meas))
    out.attrs.setdefault("summary", {})["rows_read"] = len(meas)     # summed over the groups
    return out, [(str(w.message), w.category) for w in caught] + more


def part_index(parts: list) -> pd.DataFrame:
    """The ``node`` and ``peer`` columns of a log in parts, in its rows' order (pyarrow
    reads only those columns; a part whose partition names its node takes that node)."""
    import pyarrow.parquet as pq

    from radioloc.core.errors import InputError

    frames = []
    for path, node in parts:
        try:
            names = {n.strip().lower(): n for n in pq.read_schema(path).names}
            cols = [names[c] for c in ("node", "peer") if c in names]
            table = pq.read_table(path, columns=cols).to_pandas()
        except (OSError, ValueError) as exc:
            raise InputError(f"{path}: not a readable Parquet file ({exc})") from None
        table.columns = [c.strip().lower() for c in table.columns]
        if node is not None:
            table["node"] = node
        if "node" not in table or "peer" not in table:
            raise InputError(f"{path}: missing column(s) "
                             f"{', '.join(c for c in ('node', 'peer') if c not in table)}")
        frames.append(table[["node", "peer"]].astype(str).apply(lambda c: c.str.strip()))
    return pd.concat(frames, ignore_index=True)


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
    if workers < 1:
        raise ConfigError(f"--workers: must be >= 1, got {workers}")
    _refuse(method_name, request)
    meas = request.measurements
    groups = node_groups(meas, GROUPS_PER_WORKER * workers)
    calls = [(method_name, LocateRequest(meas[meas["node"].isin(g)].reset_index(drop=True),
                                         request.anchors, request.priors, request.calibration,
                                         request.options, frame=request.frame))
             for g in groups]
    return _gather(run_group, calls, meas, groups, method_name, workers, scheduler)


def locate_fleet_parts(method_name: str, parts: list, request: LocateRequest,
                       workers: int = 2, scheduler: str | None = None,
                       not_detected: float | None = None) -> pd.DataFrame:
    """:func:`locate_fleet` of a log in parts (module docstring): ``request`` holds the
    anchors and options, its measurements are left empty; each worker reads its nodes'
    parts (:func:`radioloc.io.logs.read_measurement_parts`). The estimates are those of one
    process reading the whole folder."""
    if workers < 1:
        raise ConfigError(f"--workers: must be >= 1, got {workers}")
    index = part_index(parts)
    _refuse(method_name, replace(request, measurements=index))
    groups = node_groups(index, GROUPS_PER_WORKER * workers)
    empty = replace(request, measurements=index.iloc[:0])
    calls = [(method_name, [p for p in parts if p[1] is None or p[1] in g], g, empty,
              not_detected) for g in groups]
    return _gather(run_parts, calls, index, groups, method_name, workers, scheduler)


def _gather(run, calls: list, meas: pd.DataFrame, groups: list, method_name: str,
            workers: int, scheduler: str | None) -> pd.DataFrame:
    """The groups' runs (``run(*call)``) spread and put back in the one-process order."""
    from radioloc.locate.chunked import merge_summaries

    sizes = meas.groupby("node", sort=False).size()
    outs: list = [None] * len(groups)
    seen: set = set()
    with progress(len(meas), f"{method_name} on {workers} worker(s)") as bar:
        for i, (out, caught) in completed(run, calls, workers, scheduler):
            outs[i] = out
            bar.advance(int(sizes[groups[i]].sum()))
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
