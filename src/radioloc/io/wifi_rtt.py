"""The WiFi RTT (IEEE 802.11mc fine timing measurement) data set of three venues.

Two phones (``M1``, ``M2``) walk loops ("circles") among 6 or 8 access points; for every AP
at each sample a phone logs the RTT range, the standard deviation it reports, and the RSS
(see the set's ``SOURCE.md``). This module reads one circle of one phone into arrays:
:func:`load_run`; and the phone-to-phone ranges of a circle, on their own clock:
:func:`load_peer_ranges`. The truth (the ``Ground Truth`` position and the ``True Distance``
columns) is returned apart, in ``truth_xy``, for scoring only; an AP not measured is written
as 0 in all its columns and is read as missing (NaN), never as a range of 0 m.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError

__all__ = ["WifiRttRun", "VENUES", "PHONES", "circles", "load_anchors", "load_run",
           "load_peer_ranges"]

#: Venue folder names of the set.
VENUES = ("Canteen", "Conference Room", "Library")
#: Phone ids and the file suffix of each phone's cleaned log (``<k>13.csv``, ``<k>24.csv``).
PHONES = {"M1": "13", "M2": "24"}
_IMU = ("AccX", "AccY", "AccZ", "GyroX", "GyroY", "GyroZ", "MagX", "MagY", "MagZ",
        "Azimuth", "Pitch", "Roll")


@dataclass(frozen=True)
class WifiRttRun:
    """One phone's walk of one circle.

    Attributes
    ----------
    venue, circle, phone : str
    time_s : ndarray, shape (T,)
        Seconds from the start of the log.
    ap_ids : list of str
        ``AP1, AP2, ...`` (columns of the arrays below).
    range_m : ndarray, shape (T, A)
        RTT ranges (NaN: not measured).
    range_std_m : ndarray, shape (T, A)
        The standard deviation the phone reports with each range (NaN where missing or 0).
    rss_dbm : ndarray, shape (T, A)
        RSS (NaN: not measured).
    imu : DataFrame
        Accelerometer, gyroscope, magnetometer and orientation columns, one row per sample.
    truth_xy : ndarray, shape (T, 2)
        Ground-truth position (interpolated along the path by the authors): for scoring only.
    """

    venue: str
    circle: str
    phone: str
    time_s: np.ndarray
    ap_ids: list[str]
    range_m: np.ndarray
    range_std_m: np.ndarray
    rss_dbm: np.ndarray
    imu: pd.DataFrame
    truth_xy: np.ndarray


def _venue_dir(root: Path | str, venue: str) -> Path:
    if venue not in VENUES:
        raise InputError(f"venue: {venue!r} is not one of {', '.join(VENUES)}")
    path = Path(root) / "raw_data" / venue
    if not path.is_dir():
        raise InputError(f"{path}: no such folder (is {root} the wifi-rtt-haiyaoyu data set?)")
    return path


def circles(root: Path | str, venue: str) -> list[str]:
    """The circle folders of a venue, in numeric order (e.g. ``["1", "2", ...]``)."""
    folder = _venue_dir(root, venue)
    return sorted((p.name for p in folder.iterdir() if p.is_dir() and p.name.isdigit()), key=int)


def load_anchors(root: Path | str, venue: str) -> pd.DataFrame:
    """The access points of a venue: ``id, x, y`` (metres).

    Parameters
    ----------
    root : path
        The data set folder.
    venue : str
        One of :data:`VENUES`.

    Returns
    -------
    DataFrame
    """
    path = _venue_dir(root, venue) / f"AP_idx_{venue}.csv"
    frame = pd.read_csv(path, encoding="utf-8-sig")
    frame = frame.rename(columns={frame.columns[0]: "id"})
    return frame[["id", "x", "y"]].astype({"id": str, "x": float, "y": float})


def _columns(frame: pd.DataFrame, what: str) -> dict[int, str]:
    pattern = re.compile(rf"AP(\d+) {re.escape(what)}")
    return {int(m.group(1)): c for c in frame.columns if (m := pattern.fullmatch(c.strip()))}


def load_run(root: Path | str, venue: str, circle: str | int, phone: str = "M1") -> WifiRttRun:
    """Read one phone's cleaned log of one circle.

    Parameters
    ----------
    root : path
        The data set folder.
    venue : str
        One of :data:`VENUES`.
    circle : str or int
        A circle folder of the venue (see :func:`circles`).
    phone : {"M1", "M2"}

    Returns
    -------
    WifiRttRun
    """
    if phone not in PHONES:
        raise InputError(f"phone: {phone!r} is not one of {', '.join(PHONES)}")
    circle = str(circle)
    folder = _venue_dir(root, venue) / circle
    path = folder / f"{circle}{PHONES[phone]}.csv"
    if not path.is_file():
        raise InputError(f"{path}: no such file (circles of {venue}: "
                         f"{', '.join(circles(root, venue))})")
    frame = pd.read_csv(path, encoding="utf-8-sig")
    rtt, std, rss = (_columns(frame, w) for w in ("RTT Distance (m)", "RTT std (m)", "RSS (dBm)"))
    true = _columns(frame, "True Distance (m)")
    aps = sorted(rtt)
    ranges = frame[[rtt[j] for j in aps]].to_numpy(dtype=float)
    # an AP not measured is 0 in all its columns (true distance included)
    missing = (ranges == 0.0) | (frame[[true[j] for j in aps]].to_numpy(dtype=float) == 0.0)
    ranges[missing] = np.nan
    stds = frame[[std[j] for j in aps]].to_numpy(dtype=float)
    stds[missing | (stds <= 0)] = np.nan
    rssv = frame[[rss[j] for j in aps]].to_numpy(dtype=float)
    rssv[missing | (rssv == 0)] = np.nan
    time_col = next(c for c in frame.columns if c.strip().endswith("Time Stamp (ms)"))
    truth_col = next(c for c in frame.columns if c.strip().endswith("Ground Truth"))
    truth = np.array([[float(v) for v in str(s).strip("[] ").split(",")]
                      for s in frame[truth_col]])
    imu = frame[[c for c in _IMU if c in frame.columns]].reset_index(drop=True)
    return WifiRttRun(venue, circle, phone, frame[time_col].to_numpy(dtype=float) / 1000.0,
                      [f"AP{j}" for j in aps], ranges, stds, rssv, imu, truth)


def load_peer_ranges(root: Path | str, venue: str, circle: str | int) -> pd.DataFrame:
    """Read the phone-to-phone RTT log of one circle (``rtt-log-*.csv``).

    Its clock starts at its own 0 and is not aligned with the phones' logs (the set's
    ``SOURCE.md``): see :func:`radioloc.locate.cooperative.align_peer_ranges`.

    Parameters
    ----------
    root : path
        The data set folder.
    venue : str
        One of :data:`VENUES`.
    circle : str or int
        A circle folder of the venue.

    Returns
    -------
    DataFrame
        ``time_s`` (the log's own clock), ``range_m``, ``range_std_m``, ``rss_dbm``; rows
        without a range (empty or 0) left out.
    """
    folder = _venue_dir(root, venue) / str(circle)
    files = sorted(folder.glob("rtt-log-*.csv")) if folder.is_dir() else []
    if not files:
        raise InputError(f"{folder}: no phone-to-phone log rtt-log-*.csv (circles of {venue}: "
                         f"{', '.join(circles(root, venue))})")
    frame = pd.read_csv(files[0], encoding="utf-8-sig")
    frame.columns = [c.strip() for c in frame.columns]
    out = pd.DataFrame({"time_s": pd.to_numeric(frame["Time Stamp (ms)"], errors="coerce") / 1000.0,
                        "range_m": pd.to_numeric(frame["M1-M2 RTT Distance (m)"], errors="coerce"),
                        "range_std_m": pd.to_numeric(frame["RTT std (m)"], errors="coerce"),
                        "rss_dbm": pd.to_numeric(frame["RSS (dBm)"], errors="coerce")})
    keep = np.isfinite(out["time_s"]) & np.isfinite(out["range_m"]) & (out["range_m"] > 0)
    return out[keep].reset_index(drop=True)
