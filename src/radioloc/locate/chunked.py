"""``radioloc locate`` on a long log: read, estimate and write in chunks of rows, so that the
memory a run needs does not grow with the length of the log.

The measurements file is read in blocks of ``chunk_rows`` lines
(:func:`radioloc.io.logs.measurement_blocks`), each validated by the rules of
:func:`radioloc.io.read_measurements`. A chunk is a block less the rows of its last time
stamp, which join the next chunk: the rows of one ``(time, node)`` are never split. Each
chunk then goes through the method as a whole log would (:func:`~radioloc.locate.base.prepare_method`:
the option and plausibility checks; the method; :func:`~radioloc.locate.base.checked_output`:
the health check and the order of the rows), and its estimates are appended to the output
file, written under a temporary name and renamed at the end
(:func:`radioloc.core.atomic.atomic_open`). The methods:

- ``lsq`` fixes every ``(time, node)`` epoch on its own: a chunk's fixes are the whole
  run's;
- ``gn`` too, and the range error standard deviation that scales its covariances (pooled
  over every epoch of the log unless ``-o std_m`` is given) is pooled over the chunks in a
  first pass (:func:`radioloc.locate.gauss_newton.pooled_std`);
- ``ekf-track`` runs the streaming :class:`~radioloc.locate.stream.Tracker` (the batch
  causal run's filter step, its state carried from chunk to chunk), without reorder
  window: the chunks come in time order. The settings it learns from the log (``tune=1``,
  the default; :mod:`radioloc.locate.self_tuning`) are learned in a first pass, from the
  rows of each node's first :data:`~radioloc.locate.self_tuning.LEARN_STEPS` steps, the
  rows the whole run learns from (:func:`_learned`), and the Tracker runs each node with
  its own.

A chunked run gives the whole run's estimates (to rounding, 1e-9) with these differences,
which hold the same for a log in one chunk: the health check and the plausibility checks
judge each chunk on its own rows (a covariance inflated for a misfit is inflated by the
chunk's residuals); ``ekf-track`` starts a track as :class:`~radioloc.locate.stream.Tracker`
does (see there), and its divergence check (and the unit slips it names) is not made;
warnings are those of each chunk, each distinct message once (the first
:data:`MAX_WARNINGS`, the others counted); the summary's counts are
summed over the chunks and its figures are the largest over them (health findings are
listed chunk by chunk).

The whole run takes over, from the start and with nothing written, where a chunked run could
not give its result: a file that is not plain CSV (quotes, blank lines, a byte-order mark;
a Parquet file is read a batch at a time, its cells as CSV text), rows out of time order
across chunks, odometry rows (``ekf-track``), a log whose first steps are too few to learn
from while later rows of the node might not be, estimates of another set of columns in a
later chunk, a log that fits one chunk; and on any error
(:class:`~radioloc.core.errors.RadiolocError`): a log the whole run refuses is refused by
it, with its message, and a chunk whose rows alone would be refused (an all-degenerate
stretch, a check that a few rows fail) does not refuse a log the whole run takes.
"""

from __future__ import annotations

import itertools
import math
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Iterator

import numpy as np
import pandas as pd

from radioloc.core.errors import RadiolocError
from radioloc.io.logs import (MOTION_KINDS, measurement_blocks, measurements_of_cells,
                              refuse_unknown_peer, subtract_anchor_bias, write_csv_rows)
from radioloc.locate.base import LocateRequest, checked_output, prepare_method
from radioloc.locate.progress import progress, show_progress

__all__ = ["CHUNK_ROWS", "CHUNKED_METHODS", "locate_in_chunks"]

#: Rows read at a time by default (``locate --chunk-rows``).
CHUNK_ROWS = 200_000
#: The methods that run in chunks.
CHUNKED_METHODS = ("ekf-track", "lsq", "gn")
#: Distinct warnings of the chunks shown (the others are counted in one more).
MAX_WARNINGS = 10
#: Options of each method that need the whole log at once when on (with their defaults):
#: the smoother and the cooperative tracks of ``ekf-track``; ``gn``'s fault exclusion without
#: a stated noise, whose test takes its sigma from the fixes of the whole log.
WHOLE_LOG_OPTIONS = {"ekf-track": {"smooth": "0", "cooperative": "0"},
                     "gn": {"exclude_faults": "0"}}


_END = object()


class GiveWay(Exception):
    """The chunked run cannot give the whole run's result; the whole run takes over."""


def _chunks(path: Path, rows: int, anchors: pd.DataFrame | None, not_detected: float | None,
            unknown_peers: dict) -> Iterator[tuple[pd.DataFrame, pd.DataFrame]]:
    """The chunks of the log in file order: ``(rows as read, rows with the anchors' range
    biases subtracted)``; the rows of a block's last time stamp are held for the next (the
    last block is a chunk whole)."""
    carry, boundary = None, -math.inf
    blocks = measurement_blocks(path, rows)
    ahead = next(blocks, _END)
    if ahead is _END or (cells := next(blocks, _END)) is _END:
        raise GiveWay("the log fits one chunk")
    blocks = itertools.chain([ahead, cells], blocks)
    ahead = next(blocks)
    while ahead is not _END:
        cells, ahead = ahead, next(blocks, _END)
        if cells is None:
            raise GiveWay("not a plain CSV file")
        block = measurements_of_cells(cells, path, anchors=anchors, not_detected=not_detected,
                                      unknown_peers=unknown_peers)
        times = block["time"].to_numpy()
        if times.size and times.min() < boundary:
            raise GiveWay("rows out of time order across chunks")
        if carry is not None:
            block = pd.concat([carry, block], ignore_index=True)
            times = block["time"].to_numpy()
        if not times.size:
            continue
        boundary = float(times.max())
        held = (times == boundary) if ahead is not _END else np.zeros(times.size, dtype=bool)
        carry = block[held]
        if not held.all():
            chunk = block[~held].reset_index(drop=True)
            yield chunk, subtract_anchor_bias(chunk, anchors)


def rows_in(path: Path) -> int:
    """The rows of a measurements file, for the progress of a run in chunks: a CSV file's
    lines less its header (counted at disk speed), a Parquet file's rows (its metadata)."""
    if Path(path).suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        return int(pq.ParquetFile(path).metadata.num_rows)
    lines, last = 0, b"\n"
    with open(path, "rb") as fh:
        while block := fh.read(1 << 24):
            lines += block.count(b"\n")
            last = block[-1:]
    return max(lines + (last != b"\n") - 1, 0)


def merge_summaries(into: dict, more: dict) -> dict:
    """``more`` (one chunk's summary) added to ``into``: counts summed, figures the largest,
    lists joined, dictionaries merged key by key, anything else as first given."""
    for key, value in more.items():
        have = into.get(key)
        if key not in into:
            into[key] = value
        elif isinstance(value, dict) and isinstance(have, dict):
            merge_summaries(have, value)
        elif isinstance(value, list) and isinstance(have, list):
            into[key] = have + value
        elif isinstance(value, bool) or isinstance(have, bool):
            continue
        elif isinstance(value, (int, np.integer)) and isinstance(have, (int, np.integer)):
            into[key] = int(have) + int(value)
        elif isinstance(value, (float, int)) and isinstance(have, (float, int)):
            into[key] = max(have, value)
    return into


class _Writer:
    """The output file's rows, appended as they come (CSV or Parquet) in the whole run's
    order: held until no earlier estimate can follow (:meth:`flush`); every part with the
    first one's columns and types.

    Parameters
    ----------
    fh : open file
    fmt : {"csv", "parquet"}
    nodes : dict
        The nodes in the order they first appear in the log (filled as it is read).
    frame : Frame
        The working frame (:func:`radioloc.locate.export.with_geodetic`).
    """

    def __init__(self, fh, fmt: str, nodes: dict, frame):
        self.fh, self.fmt, self.nodes, self.frame = fh, fmt, nodes, frame
        self.held: list[pd.DataFrame] = []
        self.dtypes: pd.Series | None = None
        self.parquet = None

    def add(self, estimates: pd.DataFrame) -> None:
        """Hold ``estimates`` (checked, one chunk's or one tracker update's)."""
        if len(estimates):
            self.held.append(estimates)

    def flush(self, before: float = math.inf) -> None:
        """Write the estimates held at times before ``before``, ordered as the whole run
        orders them (time, then node as first in the log)."""
        from radioloc.locate.export import with_geodetic
        from radioloc.locate.table import order_rows

        if not self.held:
            return
        held = pd.concat(self.held, ignore_index=True) if len(self.held) > 1 else self.held[0]
        due = held["time"].to_numpy() < before
        self.held = [held[~due]] if not due.all() else []
        if due.any():
            self._write(with_geodetic(order_rows(held[due], list(self.nodes)), self.frame))

    def _write(self, frame: pd.DataFrame) -> None:
        if self.dtypes is None:
            self.dtypes = frame.dtypes
        elif not frame.dtypes.equals(self.dtypes):
            raise GiveWay("estimates of other columns or types")
        if self.fmt == "csv":
            write_csv_rows(frame, self.fh, header=self.parquet is None)
            self.parquet = False
            return
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.Table.from_pandas(frame, preserve_index=False)
        if self.parquet is None:
            self.parquet = pq.ParquetWriter(self.fh, table.schema)
        self.parquet.write_table(table)

    def close(self) -> None:
        self.flush()
        if self.dtypes is None:
            raise GiveWay("no estimates")
        if self.fmt == "parquet":
            self.parquet.close()


def _pooled_std(path, rows, anchors, not_detected, opts, frame, n_rows: int
                ) -> tuple[float, str] | None:
    """``gn``'s range error standard deviation pooled over every chunk and where it came
    from (:func:`radioloc.locate.gauss_newton.pooled_std`; None: no epoch fixed), by a first
    pass of the method over the log (``n_rows``: the log's rows, for the progress)."""
    from radioloc.locate.gauss_newton import pooled_std

    total = {"sum_sq_m2": 0.0, "dof": 0.0, "epochs": 0}
    with warnings.catch_warnings(), progress(n_rows, "gn (noise pass)") as bar:
        warnings.simplefilter("ignore")
        for _, chunk in _chunks(path, rows, anchors, not_detected, {}):
            request = LocateRequest(chunk, anchors, options=chunk_options(opts), frame=frame)
            with show_progress(False):
                part = prepare_method("gn", request).fn(request).attrs["summary"].get("pooled")
            for key in total if part is not None else ():
                total[key] += part[key]
            bar.advance(len(chunk))
    return pooled_std(total) if total["epochs"] else None


def _learned(path, rows, anchors, not_detected, opts, frame, total: int
             ) -> tuple[dict, str | None]:
    """``ekf-track``'s settings learned from the log
    (:func:`radioloc.locate.ekf_track.learn_log`), by a first pass that keeps each node's
    rows up to its :data:`~radioloc.locate.self_tuning.LEARN_STEPS`-th time with a row to an
    anchor (or of a kind it measures itself): the steps the whole run learns from
    (``total``: the log's rows, for the progress)."""
    from radioloc.core.kinds import kinds as declared_kinds
    from radioloc.locate.ekf_track import learn_log
    from radioloc.locate.self_tuning import LEARN_STEPS

    ids = set(anchors["id"].astype(str)) if anchors is not None else set()
    own = {k for k, declared in declared_kinds().items() if declared.self_measured}
    kept, steps, beyond = [], {}, set()
    with progress(total, "ekf-track (learning pass)") as bar:
        for _, chunk in _chunks(path, rows, anchors, not_detected, {}):
            bar.advance(len(chunk))
            kept.append(_first_steps(chunk, ids, own, steps, beyond, LEARN_STEPS))
    log = pd.concat(kept, ignore_index=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        request = LocateRequest(log, anchors, options=chunk_options(opts), frame=frame)
        prepare_method("ekf-track", request)
        learned, short = learn_log(request)
    if beyond and short is not None:   # a node's later rows could teach what these do not
        raise GiveWay("whether the settings can be learned needs the whole log")
    return learned, short


def _first_steps(chunk: pd.DataFrame, ids: set, own: set, steps: dict, beyond: set,
                 limit: int) -> pd.DataFrame:
    """The rows of ``chunk`` within each node's first ``limit`` times with a row to an
    anchor (``ids``) or of a kind it measures itself (``own``); ``steps`` counts each node's
    times so far and ``beyond`` gathers the nodes with later rows (both updated)."""
    step = chunk["peer"].isin(ids) | chunk["kind"].isin(own)
    keep = np.zeros(len(chunk), dtype=bool)
    for node, where in chunk.groupby("node", sort=False).indices.items():
        times = np.unique(chunk["time"].to_numpy()[where[step.to_numpy()[where]]])
        room = limit - steps.get(node, 0)
        if room <= 0:
            beyond.add(node)
            continue
        last = times[room - 1] if times.size > room else np.inf
        keep[where] = chunk["time"].to_numpy()[where] <= last
        beyond.update([node] if times.size > room else [])
        steps[node] = steps.get(node, 0) + min(times.size, room)
    return chunk[keep]


def _rescaled(out: pd.DataFrame, pooled: tuple[float, str]) -> pd.DataFrame:
    """A ``gn`` chunk's estimates with the covariance of the log's pooled standard deviation
    in place of the chunk's own."""
    summary = out.attrs["summary"]
    ratio = pooled[0] / summary["std_m"]
    cov = [c for c in out.columns if c.startswith("cov_")]
    scaled = out.assign(**{c: out[c] * ratio ** 2 for c in cov},
                        **({"uncertainty_m": out["uncertainty_m"] * ratio}
                           if "uncertainty_m" in out else {}))
    scaled.attrs = {**out.attrs, "summary": {**summary, "std_m": pooled[0],
                                             "std_m_from": pooled[1]}}
    scaled.attrs["summary"].pop("pooled", None)
    return scaled


def locate_in_chunks(method_name: str, path: Path, anchors: pd.DataFrame | None, opts: dict,
                     frame, out: Path, fmt: str, rows: int = CHUNK_ROWS,
                     not_detected: float | None = None) -> dict | None:
    """Run ``radioloc locate`` in chunks of ``rows`` rows (see the module docstring).

    Parameters
    ----------
    method_name : str
    path : Path
        The measurements file.
    anchors : DataFrame or None
        In the working frame.
    opts : dict
        The ``-o`` options (text).
    frame : radioloc.locate.frames.Frame
        The working frame.
    out : Path
        The output file (CSV or Parquet), written atomically.
    fmt : {"csv", "parquet"}
    rows : int
        Rows per chunk.
    not_detected : float, optional
        As for :func:`radioloc.io.read_measurements`.

    Returns
    -------
    dict or None
        The run's summary (``rows_read``, ``rows_out``, ``chunks`` and the method's summary
        merged over the chunks); None where the whole run must be made instead, an error
        met included (nothing was written then).
    """
    from radioloc.core.atomic import atomic_open

    if (method_name not in CHUNKED_METHODS or fmt not in ("csv", "parquet")
            or rows < 1 or out is None
            or str(out) == "-" or (Path(out).exists() and not Path(out).is_file())):
        return None
    stated = {"std_m", "range_std_m"} & set(opts)
    if any(str(opts.get(k, default)).strip().lower() not in ("0", "false", "no", "off")
           for k, default in WHOLE_LOG_OPTIONS.get(method_name, {}).items()
           if not (method_name == "gn" and stated)):
        return None
    try:
        pooled = learned = None
        total = rows_in(path)
        if method_name == "gn" and not stated:
            pooled = _pooled_std(path, rows, anchors, not_detected, opts, frame, total)
        if method_name == "ekf-track" and str(opts.get("tune", "1")).strip().lower() not in (
                "0", "false", "no", "off"):
            learned = _learned(path, rows, anchors, not_detected, opts, frame, total)
        with warnings.catch_warnings(record=True) as seen, \
                atomic_open(out, "wb" if fmt == "parquet" else "w",
                            newline=None if fmt == "parquet" else "") as fh:
            warnings.simplefilter("always")
            with progress(total, method_name) as bar:
                summary = _run(method_name, path, rows, anchors, not_detected, opts, frame,
                               pooled, fh, fmt, learned, bar)
    except (GiveWay, RadiolocError):
        return None
    distinct = list({str(w.message): w for w in seen}.values())
    for w in distinct[:MAX_WARNINGS]:
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    if len(distinct) > MAX_WARNINGS:
        warnings.warn(f"{len(distinct) - MAX_WARNINGS} more warnings of the chunks, of the "
                      "kinds above", stacklevel=2)
    return summary


def _run(method_name, path, rows, anchors, not_detected, opts, frame, pooled, fh, fmt,
         learned=None, bar=None) -> dict:
    """The chunks of :func:`locate_in_chunks` through the method, written to ``fh``
    (``learned``: ``ekf-track``'s settings and why not, :func:`_learned`; ``bar``: the
    progress, advanced by each chunk's rows once they are estimated)."""
    unknown: dict = {}
    nodes: dict = {}
    summary = {"rows_read": 0, "rows_out": 0, "chunks": 0}
    writer = _Writer(fh, fmt, nodes, frame)
    heard: dict[str, set] = {"range": set(), "rss": set()}
    tracker, pending, previous = None, None, None
    settings, short = learned if learned is not None else ({}, None)
    reports = {"learned": {str(n): lr.report for n, lr in settings.items()}} if settings else {}

    def add(request, estimates, rerun):
        with show_progress(False):               # the run's progress counts the chunks
            estimates = checked_output(chosen, request, estimates, rerun=rerun,
                                       node_order=list(nodes))
        merge_summaries(summary, {k: v for k, v in estimates.attrs["summary"].items()
                                  if k != "learned"})           # the run's, added once
        summary["rows_out"] += len(estimates)
        estimates.attrs = {}          # pandas copies them with every slice the writer takes
        writer.add(estimates)

    for raw, chunk in _chunks(path, rows, anchors, not_detected, unknown):
        if bar is not None and previous is not None:
            bar.advance(len(previous))             # the chunk before is estimated
        previous = chunk
        summary["rows_read"] += len(chunk)
        summary["chunks"] += 1
        nodes.update(dict.fromkeys(chunk["node"].unique()))
        for kind, ids in heard.items():
            ids.update(chunk.loc[chunk["kind"] == kind, "peer"].unique())
        request = LocateRequest(chunk, anchors, options=chunk_options(opts), frame=frame)
        chosen = prepare_method(method_name, request)
        if method_name != "ekf-track":
            with show_progress(False):
                estimates = chosen.fn(request)
            if pooled is not None and "pooled" in estimates.attrs["summary"]:
                estimates = _rescaled(estimates, pooled)
            add(request, estimates, chosen.fn)
            writer.flush()
            continue
        if raw["kind"].isin(MOTION_KINDS).any():
            raise GiveWay("odometry rows")
        if not set(unknown).isdisjoint(raw["peer"].unique()):
            raise GiveWay("a peer that is a node of a later chunk")
        if tracker is None:
            from radioloc.locate.stream import Tracker

            tracker = Tracker(method_name, anchors, {k: v for k, v in opts.items()
                                                     if k not in ("no_check", "tune")},
                              reorder_s=0.0, learned=settings)
        pending = chunk if pending is None else pd.concat([pending, chunk], ignore_index=True)
        pending = _add_tracked(tracker.update(raw), pending, request, add, reports)
        # a later estimate is at the time of a row not yet estimated, or of a later chunk
        writer.flush(float(pending["time"].min()) if len(pending) else math.inf)
    if tracker is not None:
        _add_tracked(tracker.close(), pending, request, add, reports)
        counts = tracker.summary()
        summary.update(nodes=counts["nodes"], restarts=counts["restarts"], **reports,
                       **({"tune": short} if short else {}))
    if bar is not None and previous is not None:
        bar.advance(len(previous))
    _check_peers(unknown, nodes, path)
    check_geometry(heard, request, opts.get("no_check"))
    writer.close()
    return summary


def _add_tracked(estimates: pd.DataFrame, pending: pd.DataFrame, request: LocateRequest,
                 add, reports: dict) -> pd.DataFrame:
    """Check a tracker's estimates with the rows they are made of (each node's pending rows
    up to its latest estimate; ``request``: the latest chunk's; ``reports``: what was
    learned, which the health check judges them against) and hold them for writing; the
    rows not yet estimated are returned."""
    if estimates.empty:
        return pending
    latest = estimates.groupby("node")["time"].max()
    done = pending["time"].to_numpy() <= pending["node"].map(latest).to_numpy(dtype=float)
    estimates.attrs["summary"] = dict(reports)
    add(replace(request, measurements=pending[done].reset_index(drop=True)), estimates, None)
    return pending[~done].reset_index(drop=True)


def chunk_options(opts: dict) -> dict:
    """The options of a chunk's run: the anchor geometry is not checked chunk by chunk (a
    stretch of a log may hear anchors on one line), but once over the whole log
    (:func:`check_geometry`)."""
    return {**opts, "no_check": ",".join(filter(None, [opts.get("no_check"), "geometry"]))}


def check_geometry(heard: dict[str, set], request: LocateRequest, no_check: str | None
                   ) -> None:
    """The ``geometry`` check of :func:`radioloc.core.plausibility.check_log` over the
    anchors the whole log ranged to (``heard["range"]``) and heard (``heard["rss"]``);
    ``request``: a chunk's (its anchors and options); ``no_check``: the option's text."""
    from radioloc.core.plausibility import check_ranges, check_rss_anchors, known_checks, parse_skip
    from radioloc.locate.adapter import moving_anchors

    anchors = request.anchors
    if (anchors is None or moving_anchors(anchors)
            or "geometry" in parse_skip(no_check)):
        return
    placed = anchors.set_index("id")[["x", "y"] + (["z"] if "z" in anchors.columns else [])]
    dim = 3 if "z" in anchors.columns and request.option("tag_height_m") is None else 2
    others = set(known_checks()) - {"geometry"}
    for kind, check in (("range", check_ranges), ("rss", check_rss_anchors)):
        ids = sorted(heard[kind] & set(placed.index))
        if not ids:
            continue
        pos = placed.loc[ids].to_numpy(dtype=float)
        if kind == "range":
            check(np.full((1, len(ids)), np.nan), pos, dim=dim, skip=others,
                  where="measurements", ids=ids)
        else:
            check(pos, dim=dim, skip=others, where="measurements", ids=ids)


def _check_peers(unknown: dict, nodes: dict, path: Path) -> None:
    """Refuse a peer that is neither an anchor nor a node of the log, at its first line (as
    :func:`radioloc.io.read_measurements` refuses it)."""
    left = {peer: line for peer, line in unknown.items() if peer not in nodes}
    if left:
        peer, line = min(left.items(), key=lambda item: item[1])
        refuse_unknown_peer(path, line, peer)
