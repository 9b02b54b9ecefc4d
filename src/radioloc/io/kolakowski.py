"""Loader of the Kolakowski BLE RSS fingerprinting data set (2021, preprocessed part).

Folder layout (see the data set's SOURCE.md): ``anchors.csv`` (``id, x, y, z``),
``calibration/calibration_df.csv`` and ``tests/test_robot_df.csv`` with columns ``ts`` (ns),
``x``, ``y`` (m, tag position), ``heading`` and ``rssi_1 .. rssi_6`` (dBm, empty = not
received).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import DataUnavailable, InputError

FILES = {"calibration": "calibration/calibration_df.csv", "robot": "tests/test_robot_df.csv"}


@dataclass(frozen=True)
class Fingerprints:
    """One fingerprint table.

    Attributes
    ----------
    time_s : ndarray, shape (N,)
        Seconds since the first row.
    position : ndarray, shape (N, 2)
        Tag positions ``(x, y)``, metres.
    rss : ndarray, shape (N, S)
        Signal strengths in dBm, NaN = not received.
    anchor_ids : tuple of int
        The anchor id of each ``rss`` column.
    """

    time_s: np.ndarray
    position: np.ndarray
    rss: np.ndarray
    anchor_ids: tuple[int, ...]


def load_fingerprints(folder, part: str) -> Fingerprints:
    """Read one part of the data set.

    Parameters
    ----------
    folder : str or Path
        The data set folder.
    part : {"calibration", "robot"}
        Which table.

    Returns
    -------
    Fingerprints
        The table as arrays.

    Raises
    ------
    DataUnavailable
        If the file is absent.
    InputError
        If ``part`` is unknown or columns are missing.
    """
    if part not in FILES:
        raise InputError(f"part: {part!r} is not one of {', '.join(FILES)}")
    path = Path(folder) / FILES[part]
    if not path.is_file():
        raise DataUnavailable(f"{path}: not found")
    frame = pd.read_csv(path)
    cols = sorted((c for c in frame.columns if c.startswith("rssi_")), key=lambda c: int(c[5:]))
    missing = {"ts", "x", "y"} - set(frame.columns)
    if missing or not cols:
        raise InputError(f"{path}: columns {sorted(missing) or ['rssi_*']} are missing")
    ts = frame["ts"].to_numpy(float)
    return Fingerprints((ts - ts[0]) * 1e-9, frame[["x", "y"]].to_numpy(float),
                        frame[cols].to_numpy(float), tuple(int(c[5:]) for c in cols))


def load_anchors(folder) -> pd.DataFrame:
    """Read the anchor positions.

    Parameters
    ----------
    folder : str or Path
        The data set folder.

    Returns
    -------
    pandas.DataFrame
        ``anchors.csv``: columns ``id, x, y, z``.
    """
    path = Path(folder) / "anchors.csv"
    if not path.is_file():
        raise DataUnavailable(f"{path}: not found")
    return pd.read_csv(path)
