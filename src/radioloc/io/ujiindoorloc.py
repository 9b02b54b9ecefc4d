"""Loader of UJIIndoorLoc (Torres-Sospedra et al., IPIN 2014): WiFi fingerprints of three
buildings with 4-5 floors.

Folder layout (``ujiindoorloc/SOURCE.md``)::

    <root>/trainingData.csv     19,937 scans
    <root>/validationData.csv    1,111 scans

Columns ``WAP001 .. WAP520`` (RSS in dBm, the sentinel ``100`` = not detected),
``LONGITUDE, LATITUDE`` (projected metres, EPSG:3857: one file unit is 0.766 ground metres
at this latitude; we report errors in file units, as published errors on this set are),
``FLOOR, BUILDINGID, SPACEID, RELATIVEPOSITION, USERID, PHONEID, TIMESTAMP``.

Reading choices (each counted in :attr:`UjiScans.counts`, nothing dropped silently):

- a cell equal to ``not_detected`` (default ``100``) reads as NaN, "not detected";
  any other value above ``+30 dBm`` or below ``-200 dBm`` is refused, naming the line and
  the column;
- 0 dBm readings (137 cells of the training file) are kept as readings;
- scans with no access point detected (76 in training) are kept here and counted
  (``empty_scans``); :meth:`UjiScans.without_empty` drops them;
- exact duplicate rows (637 in training) are kept and counted.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import DataUnavailable, InputError
from radioloc.io.logs import LIMITS, RSS_NOT_DETECTED_DBM

FILES = {"training": "trainingData.csv", "validation": "validationData.csv"}
META = ("LONGITUDE", "LATITUDE", "FLOOR", "BUILDINGID", "SPACEID", "RELATIVEPOSITION",
        "USERID", "PHONEID", "TIMESTAMP")
#: ground metres per file unit (EPSG:3857 at 39.99 deg N); see SOURCE.md
GROUND_M_PER_UNIT = 0.766


@dataclass(frozen=True)
class UjiScans:
    """Scans of one UJIIndoorLoc file.

    Attributes
    ----------
    rss : ndarray, shape (N, S)
        RSS in dBm, NaN = not detected.
    position : ndarray, shape (N, 2)
        ``LONGITUDE, LATITUDE`` in file units (EPSG:3857 metres).
    building, floor, phone, user : ndarray of int, shape (N,)
        ``BUILDINGID``, ``FLOOR``, ``PHONEID``, ``USERID``.
    timestamp : ndarray of int, shape (N,)
        Unix time, seconds.
    stations : list of str
        Access-point column names (``WAP001`` ...).
    lines : ndarray of int, shape (N,)
        File line of each scan (header = line 1).
    counts : dict of str to int
        ``not_detected_cells``, ``empty_scans``, ``zero_dbm_cells``, ``duplicate_rows``.
    """

    rss: np.ndarray
    position: np.ndarray
    building: np.ndarray
    floor: np.ndarray
    phone: np.ndarray
    user: np.ndarray
    timestamp: np.ndarray
    stations: list[str]
    lines: np.ndarray
    counts: dict[str, int] = field(default_factory=dict)

    def __len__(self) -> int:
        return self.rss.shape[0]

    @property
    def zones(self) -> np.ndarray:
        """``(N, 2)`` int: building, floor."""
        return np.stack([self.building, self.floor], axis=1)

    def subset(self, rows) -> "UjiScans":
        """The scans selected by ``rows`` (boolean mask or indices).

        Parameters
        ----------
        rows : array_like
            Mask or indices.

        Returns
        -------
        UjiScans
        """
        idx = np.asarray(rows)
        return replace(self, rss=self.rss[idx], position=self.position[idx],
                       building=self.building[idx], floor=self.floor[idx],
                       phone=self.phone[idx], user=self.user[idx],
                       timestamp=self.timestamp[idx], lines=self.lines[idx])

    def without_empty(self) -> "UjiScans":
        """The scans with at least one access point detected.

        Returns
        -------
        UjiScans
        """
        return self.subset(np.isfinite(self.rss).any(axis=1))


def read_scans(path: Path | str, not_detected: float | None = RSS_NOT_DETECTED_DBM) -> UjiScans:
    """Read one UJIIndoorLoc CSV.

    Parameters
    ----------
    path : path-like
        ``trainingData.csv`` or ``validationData.csv`` (or a file of the same columns).
    not_detected : float or None
        The cell value that means "not detected" (read as NaN). ``None``: no sentinel
        (then a ``100`` is refused as an implausible RSS).

    Returns
    -------
    UjiScans

    Raises
    ------
    InputError
        Unreadable file, missing column, a non-numeric cell, an RSS outside
        ``[-200, +30]`` dBm that is not the sentinel (naming line and column).
    """
    path = Path(path)
    try:            # numbers parse as numbers; a file with any other cell is read again as text
        frame = pd.read_csv(path, keep_default_na=False)
        numeric = all(pd.api.types.is_numeric_dtype(t) for t in frame.dtypes)
        if not numeric:
            frame = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (OSError, pd.errors.ParserError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read CSV ({exc})") from None
    if frame.columns.duplicated().any() or any("." in c for c in frame.columns):
        raise InputError(f"{path}: a column appears twice in the header")
    waps = [c for c in frame.columns if c.upper().startswith("WAP")]
    missing = [c for c in META if c not in frame.columns]
    if missing or not waps:
        raise InputError(f"{path}: missing column(s) {', '.join(missing or ['WAP001..'])}")
    if frame.empty:
        raise InputError(f"{path}: no data rows below the header")
    cols = frame[waps + list(META)]
    if numeric:
        values = cols.to_numpy(float)
    else:           # text cells: converted per column, so that the first bad cell is named
        values = cols.apply(pd.to_numeric, errors="coerce").to_numpy(float)
    bad = ~np.isfinite(values)
    if bad.any():
        i, j = (int(v) for v in np.argwhere(bad)[0])
        col = (waps + list(META))[j]
        raise InputError(f"{path}: line {i + 2}, column {col}: not a finite number: "
                         f"{frame[col].iloc[i]!r}")
    raw = values[:, :len(waps)]
    meta = values[:, len(waps):]
    sentinel = np.zeros(raw.shape, bool) if not_detected is None else raw == float(not_detected)
    out = ~sentinel & ((raw > LIMITS["rss_max_dbm"]) | (raw < LIMITS["rss_min_dbm"]))
    if out.any():
        i, j = (int(v) for v in np.argwhere(out)[0])
        hint = (" (the data set's 'not detected' sentinel is 100: read with not_detected=100)"
                if raw[i, j] == RSS_NOT_DETECTED_DBM else "")
        raise InputError(f"{path}: line {i + 2}, column {waps[j]}: RSS {raw[i, j]:g} dBm outside "
                         f"[{LIMITS['rss_min_dbm']:g}, {LIMITS['rss_max_dbm']:g}]{hint}")
    rss = np.where(sentinel, np.nan, raw)
    det = ~sentinel
    ints = meta[:, 2:].astype(np.int64)
    counts = {"not_detected_cells": int(sentinel.sum()),
              "empty_scans": int((~det.any(axis=1)).sum()),
              "zero_dbm_cells": int((raw == 0).sum()),
              "duplicate_rows": int(frame.duplicated().sum())}
    return UjiScans(rss=rss, position=meta[:, :2].copy(), building=ints[:, 1], floor=ints[:, 0],
                    phone=ints[:, 5], user=ints[:, 4], timestamp=ints[:, 6], stations=waps,
                    lines=np.arange(2, len(frame) + 2), counts=counts)


def load_split(root: Path | str, split: str,
               not_detected: float | None = RSS_NOT_DETECTED_DBM) -> UjiScans:
    """One file of the data set folder.

    Parameters
    ----------
    root : path-like
        The ``ujiindoorloc`` folder.
    split : {"training", "validation"}
        Which file.
    not_detected : float or None
        Sentinel read as "not detected" (see :func:`read_scans`).

    Returns
    -------
    UjiScans

    Raises
    ------
    DataUnavailable
        The file is not there.
    """
    if split not in FILES:
        raise InputError(f"split: expected one of {', '.join(FILES)}, got {split!r}")
    path = Path(root) / FILES[split]
    if not path.is_file():
        raise DataUnavailable(f"ujiindoorloc: {path} not found")
    return read_scans(path, not_detected)
