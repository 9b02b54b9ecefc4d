"""One input for every estimator: :class:`Measurements`, a long table of what radios measured.

Each row is one measurement: ``time`` (s), ``node`` (who measured, the node to locate),
``kind`` (``range``, ``rss``, ``tdoa``, ``aoa``, ...), ``peer`` (the reference point: an
anchor id or another node), ``reference`` (the second reference point of a difference: the
reference anchor of a TDoA; empty otherwise), ``value`` (in the kind's unit), ``std`` (a
per-row standard deviation, NaN: the model's) and ``mask`` (False: left out). It is the
``radioloc locate`` CSV schema (:mod:`radioloc.io.logs`) held in memory.

Estimators take arrays: :meth:`Measurements.grid` turns the rows of one node and one kind
into a ``(T, S)`` array over time steps and *slots* (one slot per distinct peer, or per
``(peer, reference)`` pair), NaN where a slot has no measurement at a step, averaging
duplicates. The generic estimators' :class:`~radioloc.models.measurement.Observation` is
built from such a grid and the anchors' positions (see :mod:`radioloc.locate.adapter`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError

__all__ = ["Measurements", "Grid", "COLUMNS"]

#: The columns of a measurements table, in order.
COLUMNS = ("time", "node", "peer", "kind", "value", "std", "reference", "mask")


@dataclass(frozen=True)
class Grid:
    """The measurements of one node and kind on a time grid.

    Attributes
    ----------
    time : ndarray, shape (T,)
    value : ndarray, shape (T, S)
        NaN: no measurement of that slot at that step.
    std : ndarray, shape (T, S)
        Per-row standard deviations (NaN: the model's).
    peers : list of str
        The peer of each slot.
    references : list of str
        The reference of each slot ("" for none).
    """

    time: np.ndarray
    value: np.ndarray
    std: np.ndarray
    peers: list[str]
    references: list[str]


@dataclass(frozen=True)
class Measurements:
    """A long table of measurements (see the module docstring).

    Build it with :meth:`read` (a CSV in the ``locate`` schema), :meth:`from_frame` or
    :meth:`from_arrays`; :meth:`to_frame` and :meth:`write` give the schema back.
    """

    frame: pd.DataFrame

    def __post_init__(self) -> None:
        f = self.frame
        if not isinstance(f, pd.DataFrame):
            raise InputError(f"measurements: expected a DataFrame (or Measurements.read / "
                             f"from_arrays), got {type(f).__name__}")
        missing = [c for c in ("time", "node", "peer", "kind", "value") if c not in f.columns]
        if missing:
            raise InputError(f"measurements: missing column(s) {', '.join(missing)}")
        f = f.copy()
        if "std" not in f.columns:
            f["std"] = np.nan
        if "reference" not in f.columns:
            f["reference"] = ""
        if "mask" not in f.columns:
            f["mask"] = True
        for col in ("time", "value", "std"):
            arr = np.asarray(f[col])
            if arr.dtype.kind not in "fiu":
                raise InputError(f"measurements: column '{col}' must hold real numbers, got "
                                 f"{arr.dtype}")
            f[col] = arr.astype(float)
        if not np.all(np.isfinite(f["time"])):
            raise InputError(f"measurements: column 'time': row {int(np.flatnonzero(~np.isfinite(f['time']))[0])}"
                             " is not a finite number")
        if np.asarray(f["mask"]).dtype != bool:
            raise InputError("measurements: column 'mask' must hold booleans")
        for col in ("node", "peer", "kind", "reference"):
            f[col] = f[col].fillna("").astype(str)
        object.__setattr__(self, "frame", f.reset_index(drop=True))

    # ---- construction and the CSV schema -------------------------------------------------
    @classmethod
    def from_frame(cls, frame: pd.DataFrame) -> "Measurements":
        """From a table with (at least) ``time, node, peer, kind, value``."""
        return cls(frame)

    @classmethod
    def from_arrays(cls, time, node, peer, kind, value, std=None, reference=None,
                    mask=None) -> "Measurements":
        """From one array per column (scalars broadcast)."""
        n = np.size(value)
        cols = {"time": time, "node": node, "peer": peer, "kind": kind, "value": value,
                "std": np.nan if std is None else std, "reference": "" if reference is None else reference,
                "mask": True if mask is None else mask}
        return cls(pd.DataFrame({k: np.broadcast_to(np.asarray(v), (n,)) for k, v in cols.items()}))

    @classmethod
    def read(cls, path: Path | str, *, anchors: pd.DataFrame | None = None) -> "Measurements":
        """Read a measurements CSV (see :func:`radioloc.io.logs.read_measurements`)."""
        from radioloc.io.logs import read_measurements

        return cls(read_measurements(path, anchors=anchors))

    def to_frame(self) -> pd.DataFrame:
        """The table in the ``locate`` schema: ``time, node, peer, kind, value`` and ``std``
        / ``reference`` where any row has one; masked rows left out."""
        f = self.frame[self.frame["mask"]]
        cols = ["time", "node", "peer", "kind", "value"]
        if f["std"].notna().any():
            cols.append("std")
        if (f["reference"] != "").any():
            cols.append("reference")
        return f[cols].reset_index(drop=True)

    def write(self, path: Path | str) -> None:
        """Write the table as a ``locate`` CSV."""
        from radioloc.io.logs import write_estimates

        write_estimates(self.to_frame(), path)

    # ---- queries ----------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.frame)

    @property
    def nodes(self) -> list[str]:
        """The nodes that measured, sorted."""
        return sorted(self.frame.loc[self.frame["mask"], "node"].unique())

    @property
    def kinds(self) -> list[str]:
        """The kinds present, sorted."""
        return sorted(self.frame.loc[self.frame["mask"], "kind"].unique())

    def by_node(self) -> dict[str, "Measurements"]:
        """The rows of each node (masked rows left out, file order kept), nodes sorted: one
        pass over the table instead of a :meth:`select` per node.

        Returns
        -------
        dict of str to Measurements
        """
        f = self.frame
        codes, names = pd.factorize(f["node"], sort=True)
        codes = np.where(f["mask"].to_numpy(), codes, -1)          # -1: masked out
        order = np.argsort(codes, kind="stable")
        edges = np.searchsorted(codes[order], np.arange(len(names) + 1))
        return {str(n): Measurements(f.take(order[a:b]))
                for n, a, b in zip(names, edges[:-1], edges[1:]) if b > a}

    def select(self, *, kind: str | Sequence[str] | None = None,
               node: str | Sequence[str] | None = None) -> "Measurements":
        """The rows of some kinds and/or nodes."""
        f = self.frame
        keep = f["mask"].to_numpy().copy()
        if kind is not None:
            keep &= f["kind"].isin([kind] if isinstance(kind, str) else list(kind)).to_numpy()
        if node is not None:
            keep &= f["node"].isin([node] if isinstance(node, str) else list(node)).to_numpy()
        return Measurements(f[keep])

    def times(self, node: str | None = None) -> np.ndarray:
        """The distinct time stamps (of one node), sorted."""
        f = self.frame[self.frame["mask"]]
        if node is not None:
            f = f[f["node"] == node]
        return np.unique(f["time"].to_numpy())

    def grid(self, kind: str, node: str, *, times: np.ndarray | None = None,
             slots: Sequence[tuple[str, str]] | None = None) -> Grid:
        """The rows of one node and kind as ``(T, S)`` arrays (duplicates averaged).

        Parameters
        ----------
        kind, node : str
        times : ndarray, optional
            The time grid (default: this node's time stamps of any kind, so that grids of
            several kinds share their steps). Rows at other times are an error.
        slots : sequence of (peer, reference), optional
            The slots and their order (default: the distinct pairs, sorted).

        Returns
        -------
        Grid
        """
        sel = self.frame[self.frame["mask"] & (self.frame["node"] == node)
                         & (self.frame["kind"] == kind)]
        t = self.times(node) if times is None else np.asarray(times, dtype=float)
        g = sel.groupby(["time", "peer", "reference"], sort=False, as_index=False).agg(
            value=("value", "mean"), std=("std", "mean"))
        keys = pd.MultiIndex.from_arrays([g["peer"].astype(object), g["reference"].astype(object)])
        if slots is None:
            slots = sorted(keys.unique())
        slot = (pd.MultiIndex.from_tuples(slots, names=keys.names).get_indexer(keys)
                if slots else np.full(len(g), -1)).astype(int)
        if np.any(slot < 0):
            k = int(np.flatnonzero(slot < 0)[0])
            raise InputError(f"measurements: node {node!r}, kind {kind!r}: peer "
                             f"{g['peer'].iloc[k]!r} is not one of the slots given")
        step = np.searchsorted(t, g["time"].to_numpy())
        ok = (step < t.size) & (t[np.minimum(step, t.size - 1)] == g["time"].to_numpy())
        if not np.all(ok):
            raise InputError(f"measurements: node {node!r}, kind {kind!r}: time "
                             f"{g['time'].to_numpy()[~ok][0]!r} is not on the time grid")
        value = np.full((t.size, len(slots)), np.nan)
        std = np.full((t.size, len(slots)), np.nan)
        value[step, slot] = g["value"].to_numpy()
        std[step, slot] = g["std"].to_numpy()
        return Grid(t, value, std, [s[0] for s in slots], [s[1] for s in slots])
