"""Live tracking: :class:`Tracker` takes measurement rows as they arrive and returns the
estimates it can make, the same numbers as the batch causal run of the method
(``radioloc locate --method ekf-track`` without ``smooth``) on the same rows.

Rows are held for a reorder window of ``reorder_s`` seconds behind the latest time seen:
rows that arrive out of order within it are placed where they belong; a row older than what
was already processed is late, left out and counted (:meth:`Tracker.summary`). Each node
runs the method's own filter (:meth:`ExtendedKalmanFilter.run`, going on from the node's
last state and its gate's patience), so state survives pauses of any length (a gap longer
than ``max_gap_s`` restarts the track, as in the batch run).

The rows are kept as arrays, not tables: each row is resolved once, as it arrives, to its
node and its *slot* (its kind, anchor and reference anchor, whose model, anchor positions
and corrections are worked out the first time the slot is seen), and a node's steps are
built from its rows' times, slots and values (duplicates averaged as
:meth:`radioloc.io.Measurements.grid` averages them).

A track's start needs its first ``init_s`` seconds (:func:`radioloc.locate.ekf_track.start_state`):
its rows are held until the window has passed, then the steps so far are estimated at once.
Where the batch run looks beyond the window, the stream cannot: a start window that hears
ranges to fewer than three anchors (the batch run widens it to the whole track; the stream
to the rows held when the window closes), and a kind that first appears in a track after
its start window (the batch run sizes the state for every kind of the log). The batch
run's checks of the whole log (plausibility, divergence, unit slips, and the health check
that widens a covariance the whole log shows too small) do not apply to rows that arrive
one by one: the stream's numbers are the method's own.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.kinds import kinds as declared_kinds
from radioloc.core.plausibility import value_checks
from radioloc.estimators.extended_kalman import FilterState
from radioloc.io.logs import MEASUREMENT_COLUMNS, MOTION_KINDS, corrected_ranges
from radioloc.locate.adapter import anchor_positions, moving_anchors, slot_context
from radioloc.locate.base import LocateRequest, check_request, method
from radioloc.locate.ekf_track import (given_sigmas, log_models, reads_clock, stack_tracks,
                                       start_screened, track_columns, track_priors,
                                       tracker_filter, tracker_settings, tuned_prior)
from radioloc.locate.self_tuning import offsets_taken_off, tuned_observations
from radioloc.models.measurement import Observation

#: Methods a :class:`Tracker` runs (causal trackers).
STREAM_METHODS = ("ekf-track",)
#: Default reorder window, seconds.
REORDER_S = 0.5
#: Options of the method that need the whole log, refused by the stream (live tracking
#: runs the fixed defaults and what -o gives, or the settings learned on a recorded log:
#: ``Tracker(learned=...)``, :func:`radioloc.locate.ekf_track.learn_log`).
OFFLINE_OPTIONS = ("smooth", "cooperative", "tune")
#: The kinds in the order a step's observations are updated (the batch run's: by name).
KINDS = tuple(sorted(declared_kinds()))
#: Contexts of fixed anchors kept for sets of slots seen (a bound on memory).
CONTEXTS = 1024


class Rows(NamedTuple):
    """Measurement rows as arrays, one entry per row: ``time`` (s), ``node`` (index of the
    tracker's node), ``slot`` (index of the tracker's slot), ``value`` (corrected) and
    ``std`` (NaN: the model's)."""

    time: np.ndarray
    node: np.ndarray
    slot: np.ndarray
    value: np.ndarray
    std: np.ndarray

    def take(self, which) -> "Rows":
        return Rows(*(a[which] for a in self))

    @staticmethod
    def joined(parts: list["Rows"]) -> "Rows":
        return parts[0] if len(parts) == 1 else Rows(*(np.concatenate(c) for c in zip(*parts)))


@dataclass
class _Track:
    """One track of a node: rows held for its start, then the filter's state."""

    restart: bool
    held: list = field(default_factory=list)     # Rows before the start
    t0: float = math.nan                         # time of its first step
    last: float = math.nan                       # time of its latest step
    ekf: object = None                           # the filter, or the form of a learned one
    state: FilterState | None = None             # after its latest step
    streak: int = 0                              # the gate's (ExtendedKalmanFilter.run)
    settings: tuple | None = None                # learned: q, bias noise, bias time constants


def row_columns(rows) -> tuple[dict[str, list], int]:
    """The cells of ``rows`` by column, and the number of rows.

    Parameters
    ----------
    rows : DataFrame, mapping of column to sequence, or sequence of mappings

    Raises
    ------
    InputError
        Something else, or columns of different lengths.
    """
    if isinstance(rows, pd.DataFrame):
        return {str(c): rows[c].tolist() for c in rows.columns}, len(rows)
    if isinstance(rows, Mapping):
        if any(isinstance(v, (str, bytes)) or not hasattr(v, "__len__") for v in rows.values()):
            raise InputError("measurement rows: a mapping of columns needs a sequence of "
                             "cells per column (a list of mappings for rows)")
        columns = {str(c): list(v) for c, v in rows.items()}
        sizes = {len(v) for v in columns.values()}
        if len(sizes) > 1:
            raise InputError(f"measurement rows: columns of different lengths {sorted(sizes)}")
        return columns, sizes.pop() if sizes else 0
    records = list(rows)
    if not all(isinstance(r, Mapping) for r in records):
        raise InputError("measurement rows: expected a DataFrame, a mapping of columns or a "
                         "list of mappings (one per row)")
    keys = dict.fromkeys(k for r in records for k in r)
    return {str(k): [r.get(k) for r in records] for k in keys}, len(records)


def _blank(cell) -> bool:
    return cell is None or (isinstance(cell, str) and not cell.strip())


def _number(cell) -> float:
    """A cell as a float; inf for a cell that is not a number."""
    try:
        return float(cell)
    except (TypeError, ValueError):
        return math.inf


def number_column(cells: list, column: str, row_name, missing: bool = False) -> np.ndarray:
    """One column's cells as floats.

    Parameters
    ----------
    cells : list
    column : str
        For the message.
    row_name : callable
        Row index to its name in messages (``line 7``, ``row 3``).
    missing : bool
        An empty cell (or NaN) is allowed, as NaN.

    Raises
    ------
    InputError
        A cell that is not a finite number, naming the row and the column.
    """
    if missing:
        cells = [math.nan if _blank(c) else c for c in cells]
    try:
        out = np.fromiter(map(float, cells), dtype=float, count=len(cells))
    except (TypeError, ValueError):
        out = np.array([_number(c) for c in cells])
    bad = np.isinf(out) if missing else ~np.isfinite(out)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"measurement rows: {row_name(i)}, column {column!r}: {cells[i]!r} is "
                         "not a finite number")
    return out


def text_column(cells: list) -> list[str]:
    """One column's cells as stripped text (a missing cell: empty)."""
    try:
        return [c.strip() for c in cells]
    except AttributeError:                # not all text
        return ["" if c is None or (isinstance(c, float) and math.isnan(c)) else str(c).strip()
                for c in cells]


class Tracker:
    """Track nodes from measurement rows as they arrive.

    Parameters
    ----------
    method : str
        A causal tracker of ``radioloc locate`` (:data:`STREAM_METHODS`).
    anchors : DataFrame
        The anchors table (as read by :func:`radioloc.io.read_anchors`).
    options : dict, optional
        The method's ``-o`` options (``{"q": "0.5"}`` or ``{"q": 0.5}``); those that need the
        whole log (:data:`OFFLINE_OPTIONS`) are refused.
    reorder_s : float
        Reorder window, seconds: rows up to this much older than the latest time seen are
        placed; older ones are late (left out, counted).
    learned : dict of node to Learned, optional
        Settings learned from a recorded log of these nodes
        (:func:`radioloc.locate.ekf_track.learn_log`): each node named runs with its own, as
        the batch run that learned them (a node not named: the fixed defaults and ``-o``).

    Examples
    --------
    >>> import pandas as pd
    >>> anchors = pd.DataFrame({"id": ["A", "B", "C"], "x": [0.0, 10.0, 0.0],
    ...                         "y": [0.0, 0.0, 10.0]})
    >>> tracker = Tracker("ekf-track", anchors, {"init_s": 0})
    >>> rows = [{"time": 0.0, "node": "t", "peer": a, "kind": "range", "value": r}
    ...         for a, r in (("A", 5.0), ("B", 8.06), ("C", 6.71))]
    >>> tracker.update(rows).empty        # held for the reorder window
    True
    >>> tracker.close()[["x", "y"]].round(1).values.tolist()
    [[3.0, 4.0]]
    """

    def __init__(self, method_name: str = "ekf-track", anchors: pd.DataFrame | None = None,
                 options: dict | None = None, reorder_s: float = REORDER_S,
                 learned: Mapping | None = None):
        if method_name not in STREAM_METHODS:
            raise ConfigError(f"method {method_name!r}: not a streaming method; the Tracker "
                              f"takes {', '.join(STREAM_METHODS)}")
        if not (isinstance(reorder_s, (int, float)) and math.isfinite(reorder_s)
                and reorder_s >= 0):
            raise ConfigError(f"reorder_s: expected a finite number >= 0 of seconds, got "
                              f"{reorder_s!r}")
        empty = pd.DataFrame({c: pd.Series(dtype=float if c in ("time", "value") else str)
                              for c in MEASUREMENT_COLUMNS})
        request = LocateRequest(empty, anchors,
                                options={k: str(v) for k, v in (options or {}).items()})
        check_request(method(method_name), request)
        for key in OFFLINE_OPTIONS:
            if request.option(key, False, bool):
                raise ConfigError(f"option {key}: needs the whole log; not with live tracking")
        self.method = method_name
        self.reorder_s = float(reorder_s)
        self._request = request
        self._table = request.require_anchors(method_name)
        self._anchors = anchor_positions(self._table)
        self._s = tracker_settings(request, self._anchors)
        self._gate = request.option("gate", 16.0) or None
        self._anchor_bias = bool(request.option("anchor_bias", False, bool))
        self._learned = dict(learned or {})
        # the range models of a learning run read the anchor biases (ekf_track.track_log)
        self._model_bias = self._anchor_bias or (bool(self._learned)
                                                 and "range_std_m" not in given_sigmas(request))
        self._anchor_ids = set(self._table["id"].astype(str))
        self._moving = moving_anchors(self._table)
        self._no_check = frozenset(value_checks().values())
        self._pending: list[Rows] = []
        self._latest = -math.inf       # latest time seen
        self._done = -math.inf         # rows up to this time were processed
        self._tracks: dict[str, _Track] = {}
        self._nodes: dict[str, int] = {}                # node -> index
        self._slots: dict[tuple[str, str, str], int] = {}   # (kind, peer, reference) -> index
        self._slot_keys: list[tuple[str, str, str]] = []
        self._slot_kind = np.empty(0, dtype=np.int64)   # index in KINDS
        self._slot_bias = np.empty(0)                   # the anchor's bias_m (NaN: none)
        self._slot_bias_std = np.empty(0)
        self._models: dict[str, object] = {}
        self._contexts: dict[tuple, object] = {}
        self._filters: dict[bool, object] = {}
        self._counts = {"rows_in": 0, "rows_late": 0, "rows_out": 0, "restarts": 0}

    # ---- public --------------------------------------------------------------------
    def update(self, rows, as_frame: bool = True) -> pd.DataFrame | dict[str, np.ndarray]:
        """Take the rows that arrived; return the estimates they complete.

        Parameters
        ----------
        rows : DataFrame, mapping of column to sequence, or list of dict
            Measurement rows (``time, node, peer, kind, value[, reference][, std]``), in
            any order within the reorder window; a ``line`` column, when there is one,
            names the rows in messages.
        as_frame : bool
            False: the estimates as a dict of columns (arrays), empty if none, without
            building the table (for a writer that streams them).

        Returns
        -------
        DataFrame
            The batch output's columns (``time, node, x, y[, z], uncertainty_m``,
            covariance columns, ``gated``, ``restart``), one row per ``(time, node)``
            estimated by this call, sorted by time then node; empty if none.

        Raises
        ------
        InputError
            A missing column, a cell that is not a finite number, an unknown kind, a peer
            that is neither an anchor nor a node seen so far (naming the row).
        """
        arrived = self._arrived(rows)
        if arrived is not None:
            time = arrived.time
            self._counts["rows_in"] += time.size
            late = time < self._done
            self._counts["rows_late"] += int(late.sum())
            if not late.all():
                self._latest = max(self._latest, float(time[~late].max()))
                self._pending.append(arrived.take(~late & (arrived.slot >= 0)))
        return self._table_of(self._release(self._latest - self.reorder_s), as_frame)

    def close(self, as_frame: bool = True) -> pd.DataFrame | dict[str, np.ndarray]:
        """Process every row held (the end of the input); returns the last estimates (as
        :meth:`update` returns them)."""
        return self._table_of(self._release(math.inf), as_frame)

    def flush(self, as_frame: bool = True) -> pd.DataFrame | dict[str, np.ndarray]:
        """Process the rows held up to the reorder window behind the latest time seen, that
        time included, without waiting for a later one: for a caller that knows no more rows
        of those times will come (the input has been idle); a row of them that comes after
        is late. Returns the estimates (as :meth:`update` returns them)."""
        until = np.nextafter(self._latest - self.reorder_s, math.inf)
        return self._table_of(self._release(until), as_frame)

    def summary(self) -> dict:
        """Counts so far: ``rows_in``, ``rows_late`` (older than the reorder window, left
        out), ``rows_out`` (estimates), ``nodes``, ``restarts``, ``reorder_s``."""
        return {**self._counts, "nodes": len(self._tracks), "reorder_s": self.reorder_s}

    # ---- rows in -------------------------------------------------------------------
    def _arrived(self, rows) -> Rows | None:
        """The rows resolved to nodes and slots (slot -1: a row to another node, which is
        no step of this method), values corrected as the batch run corrects them (the
        anchors' ``bias_m``, option ``range_bias_m``); None when there is none."""
        columns, n = row_columns(rows)
        if not n:
            return None
        missing = [c for c in MEASUREMENT_COLUMNS if c not in columns]
        if missing:
            raise InputError(f"measurement rows: missing column(s) {', '.join(missing)}")
        lines = columns.get("line")

        def row_name(i: int) -> str:
            return f"line {lines[i]}" if lines is not None else f"row {i}"
        time = number_column(columns["time"], "time", row_name)
        value = number_column(columns["value"], "value", row_name)
        std = (number_column(columns["std"], "std", row_name, missing=True)
               if "std" in columns else np.full(n, np.nan))
        node = np.array([self._nodes.setdefault(v, len(self._nodes))
                         for v in text_column(columns["node"])], dtype=np.int64)
        keys = list(zip([k.lower() for k in text_column(columns["kind"])],
                        text_column(columns["peer"]),
                        text_column(columns["reference"]) if "reference" in columns
                        else [""] * n))
        codes = [self._slots.get(key) for key in keys]
        if None in codes:                         # slots first seen
            codes = [self._slot(key, row_name(i)) if code is None else code
                     for i, (key, code) in enumerate(zip(keys, codes))]
        slot = np.array(codes, dtype=np.int64)
        mine = np.maximum(slot, 0)
        if np.isfinite(self._slot_bias).any():
            peers = np.array([k[1] for k in self._slot_keys], dtype=object)
            bias = np.where(slot >= 0, self._slot_bias[mine], np.nan)
            value = corrected_ranges(value, std, bias, self._slot_bias_std[mine], peers[mine],
                                     lambda i: f"{row_name(i)}, ")
        if self._s["bias"] and self._slot_keys:
            ranges = (slot >= 0) & (self._slot_kind[mine] == KINDS.index("range"))
            value = np.where(ranges, value - self._s["bias"], value)
        return Rows(time, node, slot, value, std)

    def _slot(self, key: tuple[str, str, str], row: str) -> int:
        """The index of a slot (-1: a row to another node); the first time it is seen, its
        model is built and its anchors checked."""
        if key in self._slots:
            return self._slots[key]
        kind, peer, reference = key
        declared = declared_kinds()
        if kind not in declared:
            raise InputError(f"measurement rows: {row}, column 'kind': {kind!r} is not one of "
                             f"{', '.join(declared)}")
        if kind in MOTION_KINDS:
            raise ConfigError("odometry rows: not with live tracking (the Tracker takes the "
                              "measurements to anchors)")
        own = declared[kind].self_measured
        if not own and peer not in self._anchor_ids:
            if peer in self._nodes:
                self._slots[key] = -1            # a range to another node (not a step here)
                return -1
            raise InputError(f"measurement rows: {row}, column 'peer': unknown anchor or node "
                             f"{peer!r} (not in the anchors file nor a node seen so far)")
        if not own and (reference not in self._anchor_ids
                        and (reference or declared[kind].reference)):
            raise InputError(f"measurement rows: {row}, column 'reference': {reference!r} is "
                             "not an anchor")
        if kind not in self._models or kind == "rss":   # rss: the anchor's parameters checked
            one = pd.DataFrame({"time": [0.0], "node": [""], "peer": [peer], "kind": [kind],
                                "value": [0.0]})
            _, _, models = log_models(self._request, one, self._table, self._s,
                                      self._model_bias)
            self._models.setdefault(kind, models[kind])
        bias = bias_std = math.nan
        if kind == "range" and "bias_m" in self._table.columns:
            anchor = self._table[self._table["id"].astype(str) == peer].iloc[0]
            bias = float(anchor["bias_m"])
            bias_std = (float(anchor["bias_std_m"]) if "bias_std_m" in self._table.columns
                        else 0.0)
        self._slots[key] = len(self._slot_keys)
        self._slot_keys.append(key)
        self._slot_kind = np.append(self._slot_kind, KINDS.index(kind))
        self._slot_bias = np.append(self._slot_bias, bias)
        self._slot_bias_std = np.append(self._slot_bias_std, bias_std)
        return self._slots[key]

    # ---- steps ---------------------------------------------------------------------
    def _release(self, until: float) -> list[tuple]:
        """Process the held rows older than ``until`` (rows of one time stamp that arrive
        apart are one step: a time is processed once a later one has come); the estimates
        (parts of :meth:`_table_of`)."""
        if until <= self._done:
            return []
        items = []
        if self._pending:
            rows = Rows.joined(self._pending)
            due = rows.time < until
            self._pending = [] if due.all() else [rows.take(~due)]
            if due.any():
                items += self._advance(rows.take(due))
        self._done = until
        parts = self._filter(items)
        starts = [self._start(node, track) for node, track in self._tracks.items()
                  if track.state is None and track.held and track.t0 + self._s["init_s"] < until]
        return parts + self._filter(starts)

    def _advance(self, rows: Rows) -> list:
        """Steps of the rows released, by node: held for a start, or to filter (items of
        :meth:`_filter`); a gap longer than ``max_gap_s`` after a node's latest step
        starts a new track."""
        rows = rows.take(np.lexsort((rows.time, rows.node)))
        cuts = np.flatnonzero(np.diff(rows.node)) + 1
        names = list(self._nodes)
        items = []
        for a, b in zip(np.concatenate([[0], cuts]), np.concatenate([cuts, [rows.time.size]])):
            own = rows.take(slice(a, b))
            node = names[own.node[0]]
            times = np.unique(own.time)
            track = self._tracks.get(node)
            prev = np.concatenate([[times[0] if track is None else track.last], times[:-1]])
            new = times - prev > self._s["max_gap_s"]
            new[0] |= track is None
            edges = np.concatenate([[0], np.flatnonzero(new[1:]) + 1, [times.size]])
            for i, j in zip(edges[:-1], edges[1:]):
                if new[i]:
                    if track is not None and track.state is None:
                        items.append(self._start(node, track))
                    track = _Track(restart=track is not None)
                    self._counts["restarts"] += int(track.restart)
                    self._tracks[node] = track
                t = times[i:j]
                window = own.take((own.time >= t[0]) & (own.time <= t[-1]))
                if track.state is None:
                    track.t0 = track.t0 if track.held else float(t[0])
                    track.held.append(window)
                    track.last = float(t[-1])
                else:
                    steps, obs = self._observations(window)
                    items.append((node, track, steps, self._learned_rows(node, obs)[1]))
        return items

    def _observations(self, rows: Rows) -> tuple[np.ndarray, list[Observation]]:
        """A node's steps (its rows' distinct times) and an observation per kind, in
        :data:`KINDS` order: ``z`` ``(T, S)`` over the kind's slots of ``rows``."""
        times, step = np.unique(rows.time, return_inverse=True)
        kinds = self._slot_kind[rows.slot]
        out = []
        for k in np.unique(kinds):
            kind, mine = KINDS[k], kinds == k
            slots, col = np.unique(rows.slot[mine], return_inverse=True)
            shape = (times.size, slots.size)
            z = _cell_means(step[mine], col, rows.value[mine], shape)
            std = _cell_means(step[mine], col, rows.std[mine], shape)
            out.append(Observation(self._models[kind], z, self._context(kind, slots, times, z),
                                   std=std if np.isfinite(std).any() else None,
                                   no_check=self._no_check))
        return times, out

    def _context(self, kind: str, slots: np.ndarray, times: np.ndarray, z: np.ndarray):
        """The context of ``slots`` (:func:`radioloc.locate.adapter.slot_context`), kept for
        fixed anchors."""
        key = (kind, slots.tobytes())
        if key in self._contexts:
            return self._contexts[key]
        peers = [self._slot_keys[s][1] for s in slots]
        references = [self._slot_keys[s][2] for s in slots]
        ctx = slot_context(self._table, kind, self._models[kind], peers, references, times,
                           np.isfinite(z), height_m=self._s["height"])
        if not self._moving:
            if len(self._contexts) >= CONTEXTS:
                self._contexts.clear()
            self._contexts[key] = ctx
        return ctx

    def _start(self, node: str, track: _Track) -> tuple:
        """Start a track from its held rows: the item of :meth:`_filter` of its steps."""
        rows = Rows.joined(track.held)
        track.held = []
        times, obs = self._observations(rows)
        obs = [start_screened(times, o, self._s["init_s"]) for o in obs]
        clock = reads_clock(obs)
        obs, run_obs = self._learned_rows(node, obs)
        lr = self._learned.get(node)
        form = "fixed" if lr is None else "learned" if lr.offset_m is None else "wander"
        if (clock, form) not in self._filters:     # the shared filter, or a learned one's form
            self._filters[clock, form] = tracker_filter(
                self._anchors, self._s, self._gate, form == "wander" or self._anchor_bias,
                self._request.option("bias_prior_std_m", 3.0), clock,
                bias_terms=2 if form == "wander" else 1)
        track.ekf = self._filters[clock, form]
        s = dict(self._s, bias=0.0)      # the values are already without range_bias_m
        if form == "wander":
            bias_q, bias_tau, bias_cov = lr.bias_settings()
            mean, cov = tuned_prior(track.ekf, times, obs, self._anchors, s, bias_cov)
            mean, cov = mean[None], cov[None]
            track.settings = (lr.q, bias_q, bias_tau)
        else:
            label = f"node {node!r} from time {float(times[0])!r}"
            mean, cov = track_priors(track.ekf, [(label, times, obs)], self._anchors, s,
                                     self._anchor_bias)
            track.settings = None if lr is None else (lr.q, 0.0, None)
        track.state = track.ekf.init(mean[0], cov[0], float(times[0]), observations=run_obs)
        track.last = float(times[0])
        return node, track, times, run_obs

    def _learned_rows(self, node: str, obs: list) -> tuple[list, list]:
        """A node's observations with its learned noise and range offsets
        (:func:`radioloc.locate.self_tuning.tuned_observations`), and as its filter reads
        them (the offsets off the ranges, so that one range model serves a batch of
        nodes)."""
        lr = self._learned.get(node)
        if lr is None:
            return obs, obs
        obs = tuned_observations(obs, lr)
        return obs, offsets_taken_off(obs)

    def _batch_filter(self, tracks: list):
        """The filter of a batch of tracks: the shared one, or one with each track's learned
        process noise and anchor-bias settings (as the batch run makes it)."""
        if tracks[0].settings is None:
            return tracks[0].ekf
        wander = tracks[0].settings[2] is not None        # the anchor biases wander
        q = np.array([tr.settings[0] for tr in tracks])[:, None]            # (B, steps)
        bias = ((np.stack([tr.settings[1] for tr in tracks])[:, None, :],
                 np.stack([tr.settings[2] for tr in tracks])[:, None, :]) if wander
                else (0.0, None))
        return tracker_filter(self._anchors, dict(self._s, q=q), self._gate,
                              wander or self._anchor_bias,
                              self._request.option("bias_prior_std_m", 3.0),
                              tracks[0].state.layout.clock > 0, *bias,
                              bias_terms=2 if wander else 1)

    def _filter(self, items: list) -> list[tuple]:
        """Filter tracks through their new steps: ``items`` of ``(node, track, times,
        observations)``, the tracks of one filter and state layout as one batch of
        :meth:`ExtendedKalmanFilter.run` (aligned by step index,
        :func:`radioloc.locate.ekf_track.stack_tracks`, as the batch run aligns them)."""
        groups: dict = {}
        for item in items:
            track = item[1]
            groups.setdefault((id(track.ekf), repr(track.state.layout)), []).append(item)
        return [part for group in groups.values() for part in self._filter_batch(group)]

    def _filter_batch(self, items: list) -> list[tuple]:
        tracks = [it[1] for it in items]
        t, obs = stack_tracks([it[2] for it in items], [it[3] for it in items])
        state = FilterState(np.stack([tr.state.mean for tr in tracks]),
                            np.stack([tr.state.covariance for tr in tracks]),
                            np.array([tr.last for tr in tracks]), tracks[0].state.layout)
        run = self._batch_filter(tracks).run(obs, t, state=state,
                                             streak=np.array([tr.streak for tr in tracks]))
        d = run.diagnostics
        out = []
        for b, (node, track, times, _) in enumerate(items):
            n = times.size
            track.last, track.streak = float(times[-1]), int(d["gate_streak"][b])
            track.state = FilterState(d["state"][b, -1], d["state_covariance"][b, -1],
                                      track.last, state.layout)
            out.append((node, times, run.position[b, :n], run.covariance[b, :n],
                        d["gated"][b, :n], track.restart))
            track.restart = False
            self._counts["rows_out"] += n
        return out

    @staticmethod
    def _table_of(parts: list[tuple], as_frame: bool) -> pd.DataFrame | dict[str, np.ndarray]:
        """One table (or its columns) of the estimates ``parts`` (``node, times, position,
        covariance, gated, restart`` of a track's new steps), sorted by time then node."""
        if not parts:
            return pd.DataFrame(columns=["time", "node", "x", "y"]) if as_frame else {}
        node = np.concatenate([np.full(p[1].size, p[0]) for p in parts])
        time = np.concatenate([p[1] for p in parts])
        order = np.lexsort((node, time))
        restart = np.concatenate([np.arange(p[1].size) == 0 if p[5] else
                                  np.zeros(p[1].size, dtype=bool) for p in parts])
        one = SimpleNamespace(position=np.concatenate([p[2] for p in parts])[order],
                              covariance=np.concatenate([p[3] for p in parts])[order],
                              diagnostics={"gated": np.concatenate([p[4] for p in parts])[order]})
        out = track_columns(node[order].astype(object), time[order], one)
        out["restart"] = restart[order].astype(np.int64)
        return pd.DataFrame(out) if as_frame else out


def _cell_means(step: np.ndarray, col: np.ndarray, values: np.ndarray, shape) -> np.ndarray:
    """The mean of the finite ``values`` at each ``(step, col)`` cell of an array of
    ``shape`` (duplicate rows averaged); NaN where there is none."""
    total, count = np.zeros(shape), np.zeros(shape)
    ok = np.isfinite(values)
    np.add.at(total, (step[ok], col[ok]), values[ok])
    np.add.at(count, (step[ok], col[ok]), 1.0)
    with np.errstate(invalid="ignore"):
        return total / count
