"""Loader of the Hanyang outdoor UWB data set (static and dynamic DW1000 two-way ranging).

Folder layout and columns: see ``SOURCE.md`` of the data set. Static files
``Static_measurements/{LOS,NLOS}/height_<H>cm/<D>m.csv`` give ranges at a known horizontal
distance D with the anchor at height H and the tag at 100 cm (true range
``sqrt(D^2 + ((H - 100) / 100)^2)``); each ends with summary rows, which are dropped.
Dynamic runs ``Dynamic_measurements/{LOS,NLOS}/Trajectory_<T>/Case_<c>/`` hold one range
file per anchor, the RTK reference ``trajectory.csv`` and the authors' ``LS.csv`` and
``ESKF.csv`` estimates.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from radioloc.core.errors import DataUnavailable, InputError

TAG_HEIGHT_OFFSET_M = 1.0   # tag z = trajectory z + 1 m (the data set authors' RMSE code)


def load_static(root: Path | str) -> pd.DataFrame:
    """All static range samples of the data set.

    Parameters
    ----------
    root : path
        Folder of the data set.

    Returns
    -------
    DataFrame
        ``condition, height_cm, distance_m, true_range_m, range_m, error_m, rssi_dbm``.
    """
    base = Path(root) / "Static_measurements"
    if not base.is_dir():
        raise DataUnavailable(f"{base}: static measurements not found")
    cols = {k: [] for k in ("condition", "height_cm", "distance_m", "true_range_m", "range_m",
                            "rssi_dbm")}
    for f in sorted(base.glob("*/height_*cm/*m.csv")):   # one frame at the end, not per file
        cond = f.parent.parent.name
        h = float(re.match(r"height_([\d.]+)cm", f.parent.name).group(1))
        dist = float(f.stem[:-1])
        raw = pd.read_csv(f, usecols=["timestamp", "Distance", "RSSI(dBm)"])
        t = pd.to_numeric(raw["timestamp"], errors="coerce")
        raw = raw[t.notna()]
        n = len(raw)
        cols["condition"].append(np.full(n, cond, dtype=object))
        cols["height_cm"].append(np.full(n, h))
        cols["distance_m"].append(np.full(n, dist))
        cols["true_range_m"].append(np.full(n, float(np.hypot(dist, (h - 100.0) / 100.0))))
        cols["range_m"].append(pd.to_numeric(raw["Distance"], errors="coerce").to_numpy(float))
        cols["rssi_dbm"].append(pd.to_numeric(raw["RSSI(dBm)"], errors="coerce")
                                .to_numpy(float))
    if not cols["range_m"]:
        raise DataUnavailable(f"{base}: no static files")
    out = pd.DataFrame({k: np.concatenate(v) for k, v in cols.items()})
    out.insert(5, "error_m", out["range_m"] - out["true_range_m"])
    return out[np.isfinite(out.range_m)].reset_index(drop=True)


@dataclass
class DynamicRun:
    """One moving-tag run.

    name : e.g. ``"LOS_A_Case_1"``.
    anchors : DataFrame ``id, x, y, z``.
    ranges : DataFrame ``time_s, anchor, range_m`` (time from the run start).
    reference : DataFrame ``time_s, x, y, z`` (RTK trajectory; tag at ``z + 1 m``).
    estimates : dict method -> DataFrame ``time_s, x, y, z`` (``"ls"``, ``"eskf"``).
    published : dict of the numbers in ``RMSD_results.txt`` (e.g. ``"ls_rmse_2d"``).
    """

    name: str
    anchors: pd.DataFrame
    ranges: pd.DataFrame
    reference: pd.DataFrame
    estimates: dict
    published: dict

    @property
    def trajectory(self) -> str:
        """The trajectory letter (``"A"`` or ``"B"``) from the run name."""
        return self.name.split("_")[1]


def dynamic_runs(root: Path | str) -> list[Path]:
    """Folders of the dynamic runs present, sorted.

    Parameters
    ----------
    root : path
        Folder of the data set.

    Returns
    -------
    list of Path
    """
    base = Path(root) / "Dynamic_measurements"
    runs = sorted(p for p in base.glob("*/Trajectory_*/Case_*") if (p / "trajectory.csv").exists())
    if not runs:
        raise DataUnavailable(f"{base}: no dynamic runs")
    return runs


def _published(path: Path) -> dict:
    out = {}
    if path.exists():
        for line in path.read_text().splitlines():
            m = re.match(r"\s*(\w+) (RMSE(?:_2d)?):\s*([-\d.eE+]+)", line)
            if m:
                out[f"{m.group(1).lower()}_{m.group(2).lower()}"] = float(m.group(3))
    return out


def load_dynamic(folder: Path | str) -> DynamicRun:
    """Read one dynamic run folder.

    Parameters
    ----------
    folder : path
        One ``Dynamic_measurements/<cond>/Trajectory_<T>/Case_<c>`` folder.

    Returns
    -------
    DynamicRun
    """
    folder = Path(folder)
    traj = pd.read_csv(folder / "trajectory.csv")
    t0 = float(traj["timestamp"].iloc[0])
    files = sorted(folder.glob("A*.csv"), key=lambda p: int(p.stem[1:]))
    if not files:
        raise InputError(f"{folder}: no anchor range files A<id>.csv")
    anchors, ranges = [], []
    for f in files:
        a = pd.read_csv(f)
        aid = int(f.stem[1:])
        anchors.append({"id": aid, "x": float(a["field.x"].iloc[0]), "y": float(a["field.y"].iloc[0]),
                        "z": float(a["field.z"].iloc[0])})
        ranges.append(pd.DataFrame({"time_s": (a["%time"].to_numpy(float) - t0) * 1e-9,
                                    "anchor": aid, "range_m": a["field.distanceFromTag"].to_numpy(float)}))
    est = {}
    for key, fname in (("ls", "LS.csv"), ("eskf", "ESKF.csv")):
        if (folder / fname).exists():
            e = pd.read_csv(folder / fname)
            est[key] = pd.DataFrame({"time_s": (e["timestamp"].to_numpy(float) - t0) * 1e-9,
                                     "x": e["x"], "y": e["y"], "z": e["z"]})
    ref = pd.DataFrame({"time_s": (traj["timestamp"].to_numpy(float) - t0) * 1e-9,
                        "x": traj["x"], "y": traj["y"], "z": traj["z"]})
    parts = folder.parts
    name = f"{parts[-3]}_{parts[-2].split('_')[-1]}_{parts[-1]}"
    return DynamicRun(name, pd.DataFrame(anchors), pd.concat(ranges, ignore_index=True), ref, est,
                      _published(folder / "RMSD_results.txt"))


def resample_epochs(run: DynamicRun, epoch_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Resample a run's range streams to a common epoch grid.

    At each epoch every anchor contributes its latest range of the last ``epoch_s``
    seconds (none: NaN); the RTK reference is interpolated to the epochs. The epochs run
    from ``epoch_s`` after the later of the first range and the first reference sample to
    the last reference sample.

    Parameters
    ----------
    run : DynamicRun
        From :func:`load_dynamic`.
    epoch_s : float
        Epoch length, seconds.

    Returns
    -------
    time_s : ndarray, shape (T,)
        Epoch times from the run start.
    ranges_m : ndarray, shape (T, A)
        Range to each anchor of ``run.anchors`` (in that order); NaN = none in the epoch.
    reference : ndarray, shape (T, 3)
        RTK reference ``(x, y, z)`` at the epochs.
    """
    if not np.isfinite(epoch_s) or epoch_s <= 0:
        raise InputError(f"epoch_s: must be > 0, got {epoch_s!r}")
    ref = run.reference
    start = max(float(run.ranges.time_s.min()), float(ref.time_s.min())) + epoch_s
    stop = float(ref.time_s.max())
    t = np.arange(start, stop, epoch_s)
    ids = run.anchors.id.to_numpy()
    epochs = pd.DataFrame({"epoch": np.repeat(np.arange(t.size), ids.size),
                           "time_s": np.repeat(t, ids.size), "anchor": np.tile(ids, t.size)})
    stream = run.ranges.sort_values("time_s", kind="stable").assign(
        range_time_s=lambda d: d.time_s)
    latest = pd.merge_asof(epochs, stream, on="time_s", by="anchor", direction="backward",
                           allow_exact_matches=True)
    fresh = (latest.time_s - latest.range_time_s) < epoch_s
    latest["range_m"] = latest.range_m.where(fresh)
    theta = latest.pivot(index="epoch", columns="anchor", values="range_m")
    theta = theta.reindex(index=np.arange(t.size), columns=ids).to_numpy(float)
    truth = np.stack([np.interp(t, ref.time_s, ref[c]) for c in ("x", "y", "z")], axis=-1)
    return t, theta, truth


def horizontal_ranges(ranges_m: np.ndarray, anchors: np.ndarray, tag_z: np.ndarray,
                      bias_m: float = 0.0) -> np.ndarray:
    """Bias-corrected ranges projected to the horizontal plane.

    The tag is at ``tag_z + TAG_HEIGHT_OFFSET_M`` (the data set authors' convention);
    ``sqrt(max((r - bias)^2 - dz^2, 0))`` with ``dz`` the height difference to each anchor.

    Parameters
    ----------
    ranges_m : ndarray, shape (T, A)
        Measured ranges (NaN = none).
    anchors : ndarray, shape (A, 3)
        Anchor positions.
    tag_z : ndarray, shape (T,)
        Reference height of the tag mount.
    bias_m : float
        Common ranging bias subtracted first.

    Returns
    -------
    ndarray, shape (T, A)
        Horizontal ranges (NaN where the range is NaN).
    """
    dz = np.asarray(tag_z, dtype=float)[:, None] + TAG_HEIGHT_OFFSET_M - np.asarray(anchors)[None, :, 2]
    corr = np.asarray(ranges_m, dtype=float) - bias_m
    return np.sqrt(np.maximum(corr**2 - dz**2, 0.0))


#: Scoring windows of the data set's authors, per trajectory: the reference rows from the
#: first one meeting ``start`` to the first later one meeting ``end`` (x, y in metres, the
#: trajectory's local frame). Trajectory A is scored on its return leg only, from the far
#: end (x > 49.3 m) back to x <= 12 m on the y > 3.4 m side.
AUTHORS_WINDOWS = {
    "A": (lambda x, y: (x > 49.3) & (y > -5.0), lambda x, y: (x <= 12.0) & (y > 3.4)),
    "B": (lambda x, y: (x < 8.6) & (y < -7.0), lambda x, y: (x > 8.6) & (y < -7.0)),
}
#: Reference rows with ``|z|`` at or above this (trajectory frame, m) are left out of the
#: authors' scoring.
AUTHORS_MAX_ABS_Z_M = 0.5


def authors_window(reference: pd.DataFrame, trajectory: str) -> tuple[float, float]:
    """Start and end time of the part of a run the data set's authors score.

    Parameters
    ----------
    reference : DataFrame
        ``time_s, x, y`` of the RTK reference (``DynamicRun.reference``), in time order.
    trajectory : {"A", "B"}
        Which trajectory the run follows (see :data:`AUTHORS_WINDOWS`).

    Returns
    -------
    start_s, end_s : float
        Times of the first reference row meeting the start condition and of the first
        later row meeting the end condition.

    Raises
    ------
    InputError
        Unknown trajectory, or the reference never meets a condition.
    """
    if trajectory not in AUTHORS_WINDOWS:
        raise InputError(f"trajectory: expected one of {', '.join(AUTHORS_WINDOWS)}, "
                         f"got {trajectory!r}")
    start, end = AUTHORS_WINDOWS[trajectory]
    x, y = reference["x"].to_numpy(float), reference["y"].to_numpy(float)
    t = reference["time_s"].to_numpy(float)
    first = np.flatnonzero(start(x, y))
    if first.size == 0:
        raise InputError(f"reference: never meets the start of the authors' window of "
                         f"trajectory {trajectory}")
    later = np.flatnonzero(end(x, y) & (np.arange(t.size) >= first[0]))
    if later.size == 0:
        raise InputError(f"reference: never meets the end of the authors' window of "
                         f"trajectory {trajectory}")
    return float(t[first[0]]), float(t[later[0]])


def authors_reference(reference: pd.DataFrame, times: np.ndarray, trajectory: str
                      ) -> tuple[np.ndarray, np.ndarray]:
    """The reference position the data set's authors compare an estimate of time ``t`` with.

    Inside the scoring window (:func:`authors_window`) the reference rows with
    ``|z| < 0.5 m`` are linearly interpolated to ``t`` (held at the first / last such row
    outside them); outside the window, where the authors do not score, all reference rows
    are interpolated (for other metrics).

    Parameters
    ----------
    reference : DataFrame
        ``time_s, x, y, z`` of the RTK reference, trajectory frame (``DynamicRun.reference``).
    times : ndarray, shape (T,)
        Estimate times, same clock.
    trajectory : {"A", "B"}

    Returns
    -------
    xyz : ndarray, shape (T, 3)
        Reference ``x, y, z`` (trajectory frame: add the tag offset to ``z``).
    in_window : ndarray of bool, shape (T,)
        Whether the authors score an estimate at that time.

    Raises
    ------
    InputError
        No reference row inside the window with ``|z| < 0.5 m``.
    """
    t0, t1 = authors_window(reference, trajectory)
    t = np.asarray(times, dtype=float)
    rt = reference["time_s"].to_numpy(float)
    keep = (rt >= t0) & (rt <= t1) & (np.abs(reference["z"].to_numpy(float)) < AUTHORS_MAX_ABS_Z_M)
    if not keep.any():
        raise InputError("reference: no row inside the authors' window with |z| < 0.5 m")
    inside = (t >= t0) & (t <= t1)
    out = np.empty((t.size, 3))
    for j, c in enumerate("xyz"):
        v = reference[c].to_numpy(float)
        out[:, j] = np.where(inside, np.interp(t, rt[keep], v[keep]), np.interp(t, rt, v))
    return out, inside


def authors_rmse(reference: pd.DataFrame, estimate: pd.DataFrame, trajectory: str,
                 z_offset_m: float = TAG_HEIGHT_OFFSET_M) -> dict:
    """RMSE of an estimated track as the data set's authors compute ``RMSD_results.txt``.

    Read from ``Technical_validation/localization_error_analysis.py`` of the data set's
    repository and checked against every ``RMSD_results.txt`` (LS and ESKF, 2-D and 3-D,
    eight runs of trajectories A and B: equal to the printed digits). The steps:

    1. Window: only the times between :func:`authors_window` start and end count. On
       trajectory A this is the return leg from the far end (x > 49.3 m) to x <= 12 m,
       y > 3.4 m: 140-170 s of the 235-314 s runs; the outbound leg is not scored.
    2. Reference rows inside the window with ``|z| >= 0.5 m`` are dropped.
    3. Every estimate inside the window is compared with the remaining reference linearly
       interpolated to the estimate's time (:func:`authors_reference`).
    4. RMSE = ``sqrt(mean(dx^2 + dy^2))`` over the estimates (2-D); 3-D adds
       ``(z_ref + z_offset_m - z)^2``. Every estimate row weighs the same (a method that
       outputs 40 rows per second is averaged over 40 samples per second).

    Parameters
    ----------
    reference : DataFrame
        ``time_s, x, y, z`` of the RTK reference, trajectory frame (``DynamicRun.reference``).
    estimate : DataFrame
        ``time_s, x, y`` and optionally ``z`` of the track to score, same clock.
    trajectory : {"A", "B"}
    z_offset_m : float
        Tag height above the reference ``z`` (the authors' 1 m).

    Returns
    -------
    dict
        ``rmse_2d`` and ``rmse_3d`` (NaN without a ``z`` column) in metres, ``samples``
        (estimates scored), ``start_s`` and ``end_s`` (the window).

    Raises
    ------
    InputError
        No estimate inside the window, or no reference row left in it.
    """
    t0, t1 = authors_window(reference, trajectory)
    te = estimate["time_s"].to_numpy(float)
    ref, inside = authors_reference(reference, te, trajectory)
    if not inside.any():
        raise InputError(f"estimate: no row between {t0:.3f} s and {t1:.3f} s (the authors' "
                         "window)")
    ref = ref[inside]
    est = estimate[inside]
    d2 = (ref[:, 0] - est["x"].to_numpy(float)) ** 2 + (ref[:, 1] - est["y"].to_numpy(float)) ** 2
    rmse_3d = np.nan
    if "z" in est.columns:
        dz = ref[:, 2] + z_offset_m - est["z"].to_numpy(float)
        rmse_3d = float(np.sqrt(np.mean(d2 + dz ** 2)))
    return {"rmse_2d": float(np.sqrt(np.mean(d2))), "rmse_3d": rmse_3d, "samples": int(inside.sum()),
            "start_s": t0, "end_s": t1}


def measurement_rows(run: DynamicRun) -> tuple[pd.DataFrame, pd.DataFrame]:
    """A run's ranges as they arrive, in the ``radioloc locate`` measurements schema.

    No resampling: one row per range of the anchor files, at its own time stamp (the
    anchors answer one at a time, so most time stamps hold one anchor). The node is
    ``"tag"``, anchors are named ``A<id>``.

    Parameters
    ----------
    run : DynamicRun
        From :func:`load_dynamic`.

    Returns
    -------
    measurements : DataFrame
        ``time, node, peer, kind, value`` sorted by time (seconds from the run start).
    anchors : DataFrame
        ``id, x, y, z`` (3-D; track in 2-D with ``-o tag_height_m=H``).
    """
    r = run.ranges.sort_values(["time_s", "anchor"], kind="stable")
    meas = pd.DataFrame({"time": r["time_s"].to_numpy(float), "node": "tag",
                         "peer": [f"A{a}" for a in r["anchor"]], "kind": "range",
                         "value": r["range_m"].to_numpy(float)})
    anchors = run.anchors.assign(id=[f"A{a}" for a in run.anchors["id"]])[["id", "x", "y", "z"]]
    return meas.reset_index(drop=True), anchors.reset_index(drop=True)
