"""Live tracking: :class:`Tracker` takes measurement rows as they arrive and returns the
estimates it can make, the same numbers as the batch causal run of the method
(``radioloc locate --method ekf-track`` without ``smooth``) on the same rows.

Rows are held for a reorder window of ``reorder_s`` seconds behind the latest time seen:
rows that arrive out of order within it are placed where they belong; a row older than what
was already processed is late, left out and counted (:meth:`Tracker.summary`). Each node
runs the method's own filter step by step (:meth:`ExtendedKalmanFilter.predict` and
:meth:`~ExtendedKalmanFilter.update`, the gate's patience kept across calls as
:meth:`~ExtendedKalmanFilter.run` keeps it), so state survives pauses of any length (a gap
longer than ``max_gap_s`` restarts the track, as in the batch run).

A track's start needs its first ``init_s`` seconds (:func:`radioloc.locate.ekf_track.start_state`):
its rows are held until the window has passed, then the steps so far are estimated at once.
Where the batch run looks beyond the window, the stream cannot: a start window that hears
ranges to fewer than three anchors (the batch run widens it to the whole track; the stream
to the rows held when the window closes), and a kind that first appears in a track after
its start window (the batch run sizes the state for every kind of the log). The batch
run's checks of the whole log (plausibility, divergence, unit slips) do not apply to rows
that arrive one by one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from types import SimpleNamespace

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.kinds import kinds as declared_kinds
from radioloc.estimators.extended_kalman import FilterState, gate_streak
from radioloc.io.logs import MEASUREMENT_COLUMNS, MOTION_KINDS, subtract_anchor_bias
from radioloc.locate.adapter import anchor_positions, node_observations
from radioloc.locate.base import LocateRequest, check_request, method
from radioloc.locate.ekf_track import (log_models, observation_window, reads_clock,
                                       stack_tracks, tracker_filter, tracker_settings,
                                       track_prior, track_table)

#: Methods a :class:`Tracker` runs (causal trackers).
STREAM_METHODS = ("ekf-track",)
#: Default reorder window, seconds.
REORDER_S = 0.5
#: Options of the method that need the whole log, refused by the stream (live tracking
#: runs the fixed defaults and what -o gives: learn the settings on a recorded log first,
#: `radioloc.locate.self_tuning`).
OFFLINE_OPTIONS = ("smooth", "cooperative", "tune")


@dataclass
class _Track:
    """One track of a node: rows held for its start, then the filter's state."""

    restart: bool
    held: list = field(default_factory=list)     # DataFrames of rows before the start
    t0: float = math.nan                         # time of its first step
    last: float = math.nan                       # time of its latest step
    ekf: object = None
    state: object = None
    streak: int = 0


def row_name(frame: pd.DataFrame, i: int) -> str:
    """``line N`` (the frame's ``line`` column) or ``row i`` for messages."""
    return f"line {frame['line'].iloc[i]}" if "line" in frame.columns else f"row {i}"


def arrived_rows(rows) -> pd.DataFrame:
    """Rows in the measurement schema (``time, node, peer, kind, value[, reference][, std]``)
    from a DataFrame or a list of dicts, checked.

    Parameters
    ----------
    rows : DataFrame or list of dict
        A ``line`` column, when there is one, names the rows in messages.

    Returns
    -------
    DataFrame
        ``time`` and ``value`` (and ``std``) as floats, ``node, peer, kind[, reference]``
        as strings.

    Raises
    ------
    InputError
        A missing column, a cell that is not a finite number, an unknown kind (naming the
        row).
    """
    frame = pd.DataFrame(rows) if not isinstance(rows, pd.DataFrame) else rows
    if frame.empty and not len(frame.columns):     # nothing arrived
        frame = pd.DataFrame(columns=list(MEASUREMENT_COLUMNS))
    missing = [c for c in MEASUREMENT_COLUMNS if c not in frame.columns]
    if missing:
        raise InputError(f"measurement rows: missing column(s) {', '.join(missing)}")
    out = pd.DataFrame({"time": pd.to_numeric(frame["time"], errors="coerce"),
                        "node": frame["node"].astype(str).str.strip(),
                        "peer": frame["peer"].astype(str).str.strip(),
                        "kind": frame["kind"].astype(str).str.strip().str.lower(),
                        "value": pd.to_numeric(frame["value"], errors="coerce")})
    if "reference" in frame.columns:
        out["reference"] = frame["reference"].fillna("").astype(str).str.strip()
    if "std" in frame.columns:
        out["std"] = pd.to_numeric(frame["std"].replace("", np.nan), errors="coerce")
    for column in ("time", "value"):
        bad = ~np.isfinite(out[column].to_numpy(dtype=float))
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"measurement rows: {row_name(frame, i)}, column {column!r}: "
                             f"{frame[column].iloc[i]!r} is not a finite number")
    unknown = ~out["kind"].isin(declared_kinds())
    if unknown.any():
        i = int(np.argmax(unknown.to_numpy()))
        raise InputError(f"measurement rows: {row_name(frame, i)}, column 'kind': "
                         f"{out['kind'].iloc[i]!r} is not one of {', '.join(declared_kinds())}")
    if "line" in frame.columns:
        out["line"] = frame["line"].to_numpy()
    return out.reset_index(drop=True)


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
                 options: dict | None = None, reorder_s: float = REORDER_S):
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
        self._pending: list[pd.DataFrame] = []
        self._latest = -math.inf       # latest time seen
        self._done = -math.inf         # rows up to this time were processed
        self._tracks: dict[str, _Track] = {}
        self._anchor_ids = set(self._table["id"].astype(str))
        self._nodes: set[str] = set()
        self._counts = {"rows_in": 0, "rows_late": 0, "rows_out": 0, "restarts": 0}

    # ---- public --------------------------------------------------------------------
    def update(self, rows) -> pd.DataFrame:
        """Take the rows that arrived; return the estimates they complete.

        Parameters
        ----------
        rows : DataFrame or list of dict
            Measurement rows (``time, node, peer, kind, value[, reference][, std]``), in
            any order within the reorder window.

        Returns
        -------
        DataFrame
            The batch output's columns (``time, node, x, y[, z], uncertainty_m``,
            covariance columns, ``gated``, ``restart``), one row per ``(time, node)``
            estimated by this call, sorted by time then node; empty if none.
        """
        frame = arrived_rows(rows)
        if frame["kind"].isin(MOTION_KINDS).any():
            raise ConfigError("odometry rows: not with live tracking (the Tracker takes the "
                              "measurements to anchors)")
        if frame.empty:
            return self._table_of([])
        frame = subtract_anchor_bias(frame, self._table)
        if self._s["bias"]:
            frame = frame.assign(value=np.where(frame["kind"] == "range",
                                                frame["value"] - self._s["bias"],
                                                frame["value"]))
        self._check_peers(frame)
        self._counts["rows_in"] += len(frame)
        late = frame["time"].to_numpy() < self._done
        self._counts["rows_late"] += int(late.sum())
        if late.all():
            return self._table_of([])
        frame = frame[~late]
        self._pending.append(frame)
        self._latest = max(self._latest, float(frame["time"].max()))
        return self._release(self._latest - self.reorder_s)

    def close(self) -> pd.DataFrame:
        """Process every row held (the end of the input); returns the last estimates."""
        return self._release(math.inf)

    def summary(self) -> dict:
        """Counts so far: ``rows_in``, ``rows_late`` (older than the reorder window, left
        out), ``rows_out`` (estimates), ``nodes``, ``restarts``, ``reorder_s``."""
        return {**self._counts, "nodes": len(self._tracks), "reorder_s": self.reorder_s}

    # ---- steps ---------------------------------------------------------------------
    def _check_peers(self, frame: pd.DataFrame) -> None:
        """Refuse a row whose peer is neither an anchor nor a node seen so far (as
        :func:`radioloc.io.read_measurements` refuses it in a whole log)."""
        self._nodes.update(frame["node"].unique())
        own = [n for n, k in declared_kinds().items() if k.self_measured]
        unknown = ~frame["peer"].isin(self._anchor_ids | self._nodes) & ~frame["kind"].isin(own)
        if unknown.any():
            i = int(np.argmax(unknown.to_numpy()))
            raise InputError(f"measurement rows: {row_name(frame, i)}, column 'peer': unknown anchor or node "
                             f"{frame['peer'].iloc[i]!r} (not in the anchors file nor a node "
                             "seen so far)")

    def _release(self, until: float) -> pd.DataFrame:
        """Process the held rows older than ``until`` (rows of one time stamp that arrive
        apart are one step: a time is processed once a later one has come)."""
        if until <= self._done:
            return self._table_of([])
        pending = pd.concat(self._pending, ignore_index=True) if self._pending else None
        tables = []
        if pending is not None:
            due = pending["time"].to_numpy() < until
            self._pending = [pending[~due]] if (~due).any() else []
            ready = pending[due]          # node_observations orders the steps by time
            if len(ready):
                tables += self._advance(ready)
        self._done = until
        for node, track in self._tracks.items():
            if track.state is None and track.held and track.t0 + self._s["init_s"] < until:
                tables += self._start(node, track)
        return self._table_of(tables)

    def _observations(self, rows: pd.DataFrame):
        """Each node's ``(node, times, observations)`` of ``rows`` (the method's models)."""
        log, _, models = log_models(self._request, rows, self._table, self._s,
                                    self._anchor_bias)
        for node, own in log.by_node().items():
            times, obs = node_observations(own, self._table, node, models,
                                           height_m=self._s["height"], checked=True)
            if times.size:
                yield node, own, times, obs

    def _advance(self, rows: pd.DataFrame) -> list[pd.DataFrame]:
        """Steps of the rows released: held for a start, or filtered; a gap longer than
        ``max_gap_s`` after a node's latest step starts a new track."""
        tables, running = [], []
        for node, _, times, obs in self._observations(rows):
            track = self._tracks.get(node)
            prev = np.concatenate([[times[0] if track is None else track.last], times[:-1]])
            new = times - prev > self._s["max_gap_s"]
            new[0] |= track is None
            edges = np.concatenate([np.flatnonzero(new), [times.size]])
            if edges[0] != 0:
                edges = np.concatenate([[0], edges])
            for a, b in zip(edges[:-1], edges[1:]):
                if new[a]:
                    if track is not None and track.state is None:
                        tables += self._start(node, track)
                    track = _Track(restart=track is not None)
                    self._counts["restarts"] += int(track.restart)
                    self._tracks[node] = track
                t = times[a:b]
                if track.state is None:
                    track.t0 = track.t0 if track.held else float(t[0])
                    mine = rows[(rows["node"] == node) & (rows["time"] >= t[0])
                                & (rows["time"] <= t[-1])]
                    track.held.append(mine)
                    track.last = float(t[-1])
                else:
                    window = slice(int(a), int(b))
                    running.append((node, track, t, [observation_window(o, window) for o in obs]))
        return tables + self._filter(running)

    def _start(self, node: str, track: _Track) -> list[pd.DataFrame]:
        """Start a track from its held rows and filter them."""
        rows = pd.concat(track.held, ignore_index=True)
        track.held = []
        ((_, _, times, obs),) = list(self._observations(rows))
        s = dict(self._s, bias=0.0)      # the values are already without range_bias_m
        track.ekf = tracker_filter(self._anchors, s, self._gate, self._anchor_bias,
                                   self._request.option("bias_prior_std_m", 3.0),
                                   reads_clock(obs))
        mean, var = track_prior(track.ekf, times, obs, self._anchors, s, self._anchor_bias)
        track.state = track.ekf.init(mean, np.diag(var), float(times[0]), observations=obs)
        track.last = float(times[0])
        return self._filter([(node, track, times, obs)])

    def _filter(self, items: list) -> list[pd.DataFrame]:
        """Predict and update tracks through their new steps: ``items`` of ``(node, track,
        times, observations)``, the tracks of one state layout as one batch of the filter
        (aligned by step index, :func:`radioloc.locate.ekf_track.stack_tracks`, as the
        batch run aligns them)."""
        groups: dict = {}
        for item in items:
            groups.setdefault(repr(item[1].state.layout), []).append(item)
        return [table for group in groups.values() for table in self._filter_batch(group)]

    def _filter_batch(self, items: list) -> list[pd.DataFrame]:
        tracks = [it[1] for it in items]
        ekf = tracks[0].ekf
        t, obs = stack_tracks([it[2] for it in items], [it[3] for it in items])
        state = FilterState(np.stack([tr.state.mean for tr in tracks]),
                            np.stack([tr.state.covariance for tr in tracks]),
                            t[:, 0], tracks[0].state.layout)
        last = np.array([tr.last for tr in tracks])
        streak = np.array([tr.streak for tr in tracks])
        D = self._s["dim"]
        B, T = t.shape
        pos, cov = np.empty((B, T, D)), np.empty((B, T, D, D))
        gated = np.empty((B, T), dtype=np.int64)
        for k in range(T):
            pred = ekf.predict(state, t[:, k] - last)
            step = []
            heard = 0
            for o in obs:
                z, ctx = o.at(k)
                step.append(replace(o, z=z, context=ctx, std=None))
                heard = heard + np.isfinite(z).sum(axis=-1)
            state, info = ekf.update(pred, step, ungated=streak >= ekf.gate_patience)
            streak = gate_streak(streak, heard, info["gated"])
            last = t[:, k]
            pos[:, k], cov[:, k] = state.mean[:, :D], state.covariance[:, :D, :D]
            gated[:, k] = info["gated"]
        out = []
        for b, (node, track, times, _) in enumerate(items):
            track.state = FilterState(state.mean[b], state.covariance[b], float(last[b]),
                                      state.layout)
            track.last, track.streak = float(last[b]), int(streak[b])
            n = times.size
            one = SimpleNamespace(position=pos[b, :n], covariance=cov[b, :n],
                                  diagnostics={"gated": gated[b, :n]})
            out.append(track_table(node, times, one, restart=track.restart))
            track.restart = False
            self._counts["rows_out"] += n
        return out

    @staticmethod
    def _table_of(tables: list[pd.DataFrame]) -> pd.DataFrame:
        if not tables:
            return pd.DataFrame(columns=["time", "node", "x", "y"])
        out = pd.concat(tables, ignore_index=True).sort_values(["time", "node"], kind="stable")
        return out.reset_index(drop=True)
