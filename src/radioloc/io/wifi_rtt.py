"""The WiFi RTT (IEEE 802.11mc fine timing measurement) data set, any of its venues.

Two phones (``M1``, ``M2``) walk loops ("circles") among 6 or 8 access points; for every AP
at each sample a phone logs the RTT range, the standard deviation it reports, and the RSS
(see the set's ``SOURCE.md``). This module reads one circle of one phone into arrays:
:func:`load_run`; and the phone-to-phone ranges of a circle, on their own clock:
:func:`load_peer_ranges`. The truth (the ``Ground Truth`` position and the ``True Distance``
columns) is returned apart, in ``truth_xy``, for scoring only; an AP not measured is written
as 0 in all its columns and is read as missing (NaN), never as a range of 0 m.

A venue is any folder ``raw_data/<venue>/`` of the set's layout that holds an AP coordinate
file ``AP_idx_<venue>.csv`` (:func:`venues`): the three venues of ``shared/data`` and the
others of the published set. The ground truth is read in either of the set's two layouts:
one ``M1 Ground Truth`` column of ``"[x, y]"`` text, or two columns ``M1 Ground Truth_x``
and ``M1 Ground Truth_y``. A file in another layout is refused naming the file and what is
missing.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import InputError

__all__ = ["WifiRttRun", "VENUES", "PHONES", "venues", "circles", "load_anchors", "load_run",
           "load_peer_ranges"]

#: Venue folder names of the copy in ``shared/data`` (:func:`venues` lists those of any copy).
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


def venues(root: Path | str) -> list[str]:
    """The venues of a copy of the set: folders of ``raw_data`` with an ``AP_idx_*.csv``."""
    base = Path(root) / "raw_data"
    if not base.is_dir():
        raise InputError(f"{base}: no such folder (is {root} the wifi-rtt-haiyaoyu data set?)")
    return sorted(p.name for p in base.iterdir() if p.is_dir() and any(p.glob("AP_idx*.csv")))


def _venue_dir(root: Path | str, venue: str) -> Path:
    path = Path(root) / "raw_data" / venue
    if path.is_dir() and not any(path.glob("AP_idx*.csv")):
        raise InputError(f"{path}: no AP coordinate file AP_idx_{venue}.csv: not a venue in "
                         f"the set's layout (venues: {', '.join(venues(root)) or 'none'})")
    if not path.is_dir():
        raise InputError(f"venue: {venue!r} is not a venue of {root} "
                         f"(venues: {', '.join(venues(root)) or 'none'})")
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
        A venue folder of the set (see :func:`venues`).

    Returns
    -------
    DataFrame
    """
    folder = _venue_dir(root, venue)
    named = [p for p in folder.glob("AP_idx*.csv") if p.stem.lower() == f"ap_idx_{venue}".lower()]
    found = named or sorted(folder.glob("AP_idx*.csv"))
    if len(found) != 1:
        raise InputError(f"{folder}: expected one AP coordinate file AP_idx_{venue}.csv, found "
                         f"{', '.join(p.name for p in found)}")
    frame = pd.read_csv(found[0], encoding="utf-8-sig")
    frame = frame.rename(columns={frame.columns[0]: "id"})
    if not {"x", "y"} <= set(frame.columns):
        raise InputError(f"{found[0]}: the AP coordinate file needs the columns x and y "
                         f"(has {', '.join(map(str, frame.columns))})")
    return frame[["id", "x", "y"]].astype({"id": str, "x": float, "y": float})


def _columns(frame: pd.DataFrame, what: str) -> dict[int, str]:
    pattern = re.compile(rf"AP(\d+) {re.escape(what)}")
    return {int(m.group(1)): c for c in frame.columns if (m := pattern.fullmatch(c.strip()))}


def _column(frame: pd.DataFrame, suffix: str, path: Path) -> str:
    found = [c for c in frame.columns if c.strip().endswith(suffix)]
    if not found:
        raise InputError(f"{path}: no column ending in {suffix!r}: not the per-phone layout of "
                         f"the WiFi RTT set")
    return found[0]


def _truth_xy(frame: pd.DataFrame, path: Path) -> np.ndarray:
    """The ground truth, from ``... Ground Truth`` ("[x, y]") or ``... Ground Truth_x/_y``."""
    names = {c.strip(): c for c in frame.columns}
    pair = [next((names[n] for n in names if n.endswith(f"Ground Truth_{axis}")), None)
            for axis in "xy"]
    if all(pair):
        return frame[pair].to_numpy(dtype=float)
    text = next((names[n] for n in names if n.endswith("Ground Truth")), None)
    if text is None:
        raise InputError(f"{path}: no ground-truth column ('M1 Ground Truth' as \"[x, y]\", or "
                         f"'M1 Ground Truth_x' and 'M1 Ground Truth_y')")
    try:
        xy = np.array([[float(v) for v in str(s).strip("[] ").split(",")]
                       for s in frame[text]])
    except ValueError:
        xy = np.empty((0, 0))
    if xy.shape != (len(frame), 2):
        raise InputError(f"{path}: column {text.strip()!r}: expected \"[x, y]\" on every row")
    return xy


def load_run(root: Path | str, venue: str, circle: str | int, phone: str = "M1") -> WifiRttRun:
    """Read one phone's cleaned log of one circle.

    Parameters
    ----------
    root : path
        The data set folder.
    venue : str
        A venue folder of the set (see :func:`venues`).
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
    if not aps or any(set(aps) - set(cols) for cols in (std, rss, true)):
        raise InputError(f"{path}: expected the columns 'APj RTT Distance (m)', 'APj RTT std "
                         f"(m)', 'APj RSS (dBm)' and 'APj True Distance (m)' for every AP j: "
                         f"not the per-phone layout of the WiFi RTT set")
    ranges = frame[[rtt[j] for j in aps]].to_numpy(dtype=float)
    # an AP not measured is 0 in all its columns (true distance included)
    missing = (ranges == 0.0) | (frame[[true[j] for j in aps]].to_numpy(dtype=float) == 0.0)
    ranges[missing] = np.nan
    stds = frame[[std[j] for j in aps]].to_numpy(dtype=float)
    stds[missing | (stds <= 0)] = np.nan
    rssv = frame[[rss[j] for j in aps]].to_numpy(dtype=float)
    rssv[missing | (rssv == 0)] = np.nan
    time_col = _column(frame, "Time Stamp (ms)", path)
    truth = _truth_xy(frame, path)
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
        A venue folder of the set (see :func:`venues`).
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
