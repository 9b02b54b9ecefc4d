"""Loader of the Herald project's BLE "RSSI raw data at known distances" (Edison cable car).

Folder layout (as in ``herald-ble-rssi-distance/SOURCE.md``)::

    <root>/reference-data/rssi-raw-edison/<session>-A.csv   RSSI recorded by phone A
    <root>/reference-data/rssi-raw-edison/<session>-B.csv   RSSI recorded by phone B

columns ``time, rssi`` (dBm) ``, distance`` (cm).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import DataUnavailable, InputError

SUBDIR = Path("reference-data") / "rssi-raw-edison"


def session_files(root: Path | str, session: str) -> list[Path]:
    """The A and B files of ``session`` that exist.

    Parameters
    ----------
    root : path-like
        The data set folder.
    session : str
        Session name, e.g. ``"20210110-2247"``.

    Returns
    -------
    list of pathlib.Path
    """
    folder = Path(root) / SUBDIR
    files = [folder / f"{session}-{side}.csv" for side in "AB"]
    found = [f for f in files if f.is_file()]
    if not found:
        raise DataUnavailable(f"herald: no file {session}-A.csv or {session}-B.csv in {folder}")
    return found


@lru_cache(maxsize=8)
def _read(path: str) -> pd.DataFrame:
    try:
        df = pd.read_csv(path)
    except (OSError, pd.errors.ParserError) as exc:
        raise InputError(f"{path}: cannot read CSV ({exc})") from None
    missing = {"rssi", "distance"} - set(df.columns)
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(sorted(missing))}")
    rssi = pd.to_numeric(df["rssi"], errors="coerce").to_numpy(float)
    dist = pd.to_numeric(df["distance"], errors="coerce").to_numpy(float)
    bad = ~np.isfinite(rssi) | ~np.isfinite(dist) | (dist < 0)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise InputError(f"{path}: line {i + 2}: rssi/distance not a valid number "
                         f"({df['rssi'].iloc[i]!r}, {df['distance'].iloc[i]!r})")
    return pd.DataFrame({"rssi_dbm": rssi, "distance_m": dist / 100.0})


def load_session(root: Path | str, session: str) -> pd.DataFrame:
    """All readings of ``session``.

    Parameters
    ----------
    root : path-like
        The data set folder.
    session : str
        Session name, e.g. ``"20210110-2247"``.

    Returns
    -------
    pandas.DataFrame
        Columns ``rssi_dbm``, ``distance_m`` (casing to casing), ``phone`` (``"A"`` or
        ``"B"``: which phone recorded).
    """
    frames = []
    for f in session_files(root, session):
        df = _read(str(f)).copy()
        df["phone"] = f.stem[-1]
        frames.append(df)
    return pd.concat(frames, ignore_index=True)
