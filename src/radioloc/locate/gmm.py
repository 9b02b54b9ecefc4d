"""``radioloc locate --method gmm``: Gaussian-mixture RSS fingerprinting (paper 004).

Calibration file (``--calibration``), CSV: columns ``x, y`` (metres), optionally
``building`` and ``floor`` (integer zone labels), and one column per base station, named
with the station id used as ``peer`` in the measurements (names keep their case); a cell is
the signal strength in dBm, empty when that station was not received::

    x,y,ap1,ap2,ap3
    0.0,0.0,-45.2,-61.0,
    0.5,0.0,-46.0,-60.1,-72.3

Data sets that write a sentinel for "not detected" (UJIIndoorLoc: ``100``) are read with
``-o not_detected=100``: such calibration cells count as empty and such measurement rows
are left out (a warning gives their count).

Models (``-o model=``):

- ``places`` (default: the lower mean error on both fingerprint sets here, Kolakowski BLE
  and UJIIndoorLoc WiFi; also WiFi scale: hundreds of stations, most not detected,
  several floors): the
  shared-place model :class:`~radioloc.models.fingerprint_mixture.FingerprintMixture`,
  "not detected" an explicit outcome, the building and floor decided first when the
  calibration has those columns (output columns ``building``, ``floor``); ``-o
  temperature=T`` tempers the product over stations, ``-o top_places=M`` keeps the ``M``
  heaviest places, ``-o shrink`` sets the shrinkage of the place statistics. Those not
  given are chosen by spatially grouped cross-validation on the calibration file
  (:func:`~radioloc.models.fingerprint_selection.select_places_settings`). See
  docs/fingerprinting.md. ``-o track=1`` tracks each node over the places
  (:func:`~radioloc.estimators.place_tracking.track_places`, uniform disk of ``v_max``).
- ``stations`` (paper 004 as written): one mixture per station fitted by EM, eq. (1);
  one-shot localization by eq. (2) or tracking (``-o track=1``).

Measurements: ``rss`` rows, ``node`` = the mobile, ``peer`` = the base station id; all
rows of one ``(time, node)`` form one measurement vector (duplicates are averaged). A
reading of a station the calibration does not have, or that was dropped for having fewer
than ``min_samples`` calibration readings, is ignored with a warning and counted in the
output column ``stations_ignored``; a ``(time, node)`` with no reading left is left out, with
a warning. ``-o device_offset=auto`` subtracts from each node's readings its label-free
offset against the calibration readings
(:func:`radioloc.models.rssi_logdistance.device_offset`); a number subtracts that many dB.

The EM initialisation draws from a generator seeded by the content of the calibration file,
so the same file always gives the same models.
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.plausibility import check_calibration
from radioloc.estimators.mixture_localization import MixtureLocalizer, MixtureTracker
from radioloc.estimators.place_tracking import track_places
from radioloc.io.logs import LIMITS, RSS_NOT_DETECTED_DBM, _line, read_cells
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.progress import counted
from radioloc.locate.table import add_covariance
from radioloc.models.fingerprint_mixture import FingerprintMixture
from radioloc.models.fingerprint_selection import select_places_settings
from radioloc.models.mixture_calibration import em_calibration
from radioloc.models.motion import UniformDisk
from radioloc.models.rssi_logdistance import device_offset

RESERVED = ("x", "y", "building", "floor")


def read_calibration(path, not_detected: float | None = None, *, with_zones: bool = False):
    """Read a calibration file.

    Parameters
    ----------
    path : str or Path
        The CSV file (columns ``x, y``, optionally ``building, floor``, and one per base
        station; reserved names match in any case, station ids keep theirs).
    not_detected : float, optional
        A cell value that means "not detected" (read as empty), e.g. 100.
    with_zones : bool
        Also return the zone labels.

    Returns
    -------
    positions : ndarray, shape (N, 2)
        Calibration positions, metres.
    rss : ndarray, shape (N, S)
        Signal strengths, NaN = not received.
    ids : list of str
        The station ids (column names).
    zones : ndarray of int, shape (N, L), and names : tuple of str
        Only with ``with_zones``: the ``building``/``floor`` labels present (L = 0..2).
    """
    frame = read_cells(path, "calibration")
    lower = {c.lower(): c for c in frame.columns if c.lower() in RESERVED}
    twice = [c for c in frame.columns if c.lower() in RESERVED and lower[c.lower()] != c]
    if twice:
        raise InputError(f"{path}: column {twice[0]!r} appears twice (names of x, y, building, "
                         "floor are read in any case)")
    missing = [c for c in ("x", "y") if c not in lower]
    if missing:
        raise InputError(f"{path}: calibration column(s) {', '.join(missing)} missing")
    ids = [c for c in frame.columns if c.lower() not in RESERVED]
    if not ids:
        raise InputError(f"{path}: no base station column besides x, y")

    def numbers(cols, allow_empty):
        raw = frame[cols].apply(lambda c: c.str.strip())
        val = raw.apply(pd.to_numeric, errors="coerce").to_numpy(float)
        empty = (raw == "").to_numpy()
        bad = np.isnan(val) & ~(empty & allow_empty) & ~(raw.apply(
            lambda c: c.str.lower() == "nan").to_numpy() & allow_empty)
        if bad.any():
            i, j = (int(k) for k in np.argwhere(bad)[0])
            raise InputError(f"{path}: line {_line(frame, i)}, column {cols[j]}: not a number: "
                             f"{raw.iloc[i, j]!r}")
        return val

    pos = numbers([lower["x"], lower["y"]], False)
    if not np.all(np.isfinite(pos)):
        i = int(np.flatnonzero(~np.isfinite(pos).all(1))[0])
        raise InputError(f"{path}: line {_line(frame, i)}: x, y must be finite")
    far = np.abs(pos) > LIMITS["coordinate_m"]
    if far.any():
        i, j = (int(k) for k in np.argwhere(far)[0])
        raise InputError(f"{path}: line {_line(frame, i)}, column {'xy'[j]}: |{pos[i, j]:g}| m "
                         f"exceeds {LIMITS['coordinate_m']:g} m")
    rss = numbers(ids, True)
    if not_detected is not None:
        rss = np.where(rss == float(not_detected), np.nan, rss)
    if np.isinf(rss).any():
        i, j = (int(k) for k in np.argwhere(np.isinf(rss))[0])
        raise InputError(f"{path}: line {_line(frame, i)}, column {ids[j]}: RSS must be finite "
                         "(leave the cell empty for a station not received)")
    got = np.isfinite(rss)
    out = got & ((rss > LIMITS["rss_max_dbm"]) | (rss < LIMITS["rss_min_dbm"]))
    if out.any():
        i, j = (int(k) for k in np.argwhere(out)[0])
        hint = (" (+100 is the 'not detected' sentinel of WiFi sets: read it with "
                "-o not_detected=100, or leave such cells empty)"
                if rss[i, j] == RSS_NOT_DETECTED_DBM else "")
        raise InputError(f"{path}: line {_line(frame, i)}, column {ids[j]}: RSS {rss[i, j]:g} dBm "
                         f"outside [{LIMITS['rss_min_dbm']:g}, {LIMITS['rss_max_dbm']:g}]{hint}")
    if not with_zones:
        return pos, rss, ids
    names = tuple(n for n in ("building", "floor") if n in lower)
    zones = numbers([lower[n] for n in names], False) if names else np.zeros((len(pos), 0))
    if names and np.any(zones != np.round(zones)):
        i, j = (int(k) for k in np.argwhere(zones != np.round(zones))[0])
        raise InputError(f"{path}: line {_line(frame, i)}, column {names[j]}: a zone label must "
                         "be a whole number")
    return pos, rss, ids, zones.astype(np.int64), names


def _by_node(out: pd.DataFrame):
    """The nodes of ``out``, progress counting their rows."""
    rows = out["node"].value_counts()
    return counted(out["node"].unique(), len(out), lambda node: int(rows[node]), "gmm")


def _offset_option(request: LocateRequest) -> str | float | None:
    text = request.option("device_offset", None, str)
    if text is None:
        return None
    text = str(text).strip().lower()
    if text == "auto":
        return "auto"
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"option device_offset: expected 'auto' or a number of dB, got "
                          f"{text!r}") from None
    if not math.isfinite(value) or abs(value) > 100:
        raise ConfigError(f"option device_offset: must be 'auto' or a finite number within "
                          f"+-100 dB, got {text!r}")
    return value


def apply_device_offset(meas: np.ndarray, nodes: np.ndarray, reference: np.ndarray,
                        option) -> np.ndarray:
    """Subtract each node's device offset from its readings.

    Parameters
    ----------
    meas : ndarray, shape (N, S)
        Readings (NaN = none), one row per measurement vector.
    nodes : ndarray, shape (N,)
        The node of each row.
    reference : ndarray
        The calibration readings (NaN ignored): the reference distribution of ``"auto"``.
    option : "auto", float or None
        ``"auto"``: the label-free offset per node; a number: that offset for every node.

    Returns
    -------
    ndarray, shape (N, S)
        Corrected readings.
    """
    if option is None:
        return meas
    if option != "auto":
        return meas - float(option)
    ref = reference[np.isfinite(reference)]
    out = meas.copy()
    for node in pd.unique(nodes):          # one offset per device
        rows = nodes == node
        out[rows] = meas[rows] - device_offset(meas[rows], ref)
    return out


@locate_method("gmm", "Gaussian-mixture RSS fingerprinting (paper 004) from a calibration file "
                      "(options: model=stations/places, components, position_components, track, "
                      "v_max, not_detected, min_samples, temperature, top_places, shrink, "
                      "device_offset)",
               options={"model": Option("places: shared places with not-detected outcome "
                                        "(default); stations: per-station mixtures, eq. (2) "
                                        "(paper 004 as written)", str,
                                        choices=("stations", "places")),
                        "components": Option("mixture components per station model (16)", int,
                                             min=1, max=256),
                        "position_components": Option("components kept in position densities (8)",
                                                      int, min=1, max=256),
                        "track": Option("1: recursive tracking, 0: one-shot per row (0)", bool),
                        "v_max": Option("maximum speed when tracking, m/s (1.5)", float, min=0,
                                        max=1e3),
                        "not_detected": Option("RSS value meaning 'not detected' in the calibration "
                                               "and the measurements, e.g. 100 (none)", float, min=-1e4, max=1e4),
                        "min_samples": Option("stations with fewer calibration readings are "
                                              "dropped, with a warning (3)", int, min=2, max=1e6),
                        "temperature": Option("places model: tempering T >= 1 of the product "
                                              "over stations (chosen by grouped CV on the "
                                              "calibration)", float, min=1, max=1e3),
                        "top_places": Option("places model: heaviest places kept per estimate, "
                                             "0 = all (chosen by grouped CV)", int, min=0,
                                             max=10**6),
                        "shrink": Option("places model: pseudo-samples of the shrinkage of "
                                         "place statistics (chosen by grouped CV)", float,
                                         min=0, max=1e6),
                        "device_offset": Option("'auto': label-free per-node RSS offset against "
                                                "the calibration; or dB to subtract (none)", str)},
               kinds=("rss",), inputs=("calibration",))
def locate_gmm(request: LocateRequest) -> pd.DataFrame:
    """Fingerprint localization with mixture models fitted to a calibration file.

    With ``-o model=stations`` each base station's model is fitted by EM to the calibration
    file and each ``(time, node)`` measurement vector is localized by eq. (2); with
    ``-o track=1`` each node is tracked over time with the uniform-disk motion model of
    radius ``v_max * dt``. With ``-o model=places`` the shared-place model is fitted and
    every vector is localized (zone first, then position).

    Parameters
    ----------
    request : LocateRequest
        Measurements (``rss`` rows), the calibration file and the options.

    Returns
    -------
    pandas.DataFrame
        Columns ``time, node, x, y, uncertainty_m, stations_ignored`` (and ``building``,
        ``floor`` from a places model whose calibration has them), one row per
        ``(time, node)``.
    """
    if request.calibration is None:
        raise InputError("method gmm: needs a calibration file (--calibration)")
    kind = request.option("model", "places", str)
    nd = request.option("not_detected", None)
    pos, cal_rss, ids, zones, zone_names = read_calibration(request.calibration, nd,
                                                            with_zones=True)
    check_calibration(pos, cal_rss, skip=request.parsed.get("no_check", ()),
                      where=str(request.calibration))
    min_samples = int(request.option("min_samples", 3))
    offset = _offset_option(request)
    for name in ("temperature", "top_places", "shrink"):
        if kind != "places" and name in request.options:
            raise ConfigError(f"method gmm: -o {name} applies to -o model=places")
    counts = np.isfinite(cal_rss).sum(0)
    keep = counts >= min_samples
    if not keep.any():
        raise InputError(f"{request.calibration}: no base station has {min_samples} or more "
                         "calibration readings")
    if not keep.all():
        warnings.warn(f"method gmm: {int((~keep).sum())} of {len(ids)} base stations dropped "
                      f"(fewer than {min_samples} calibration readings: "
                      f"{', '.join(np.asarray(ids)[~keep][:5])}{' ...' if (~keep).sum() > 5 else ''})"
                      "; their readings are ignored", UserWarning, stacklevel=2)
    ids = [i for i, k in zip(ids, keep) if k]
    cal_rss = cal_rss[:, keep]

    rss = request.kind("rss", "gmm")
    epochs = rss[["time", "node"]].drop_duplicates()
    known = rss["peer"].isin(ids)
    ignored = rss[~known].groupby(["node", "time"]).size()
    if (~known).any():
        first = rss[~known].iloc[0]
        warnings.warn(f"method gmm: {int((~known).sum())} reading(s) of "
                      f"{rss.loc[~known, 'peer'].nunique()} base station(s) not in the "
                      f"calibration (or dropped) ignored, e.g. line {first['line']}: peer "
                      f"{first['peer']!r}; counted in column stations_ignored",
                      UserWarning, stacklevel=2)
    rss = rss[known]
    if rss.empty:
        raise InputError("method gmm: no rss reading of a base station of the calibration file")
    rss = rss.groupby(["time", "node", "peer"], sort=True, as_index=False)["value"].mean()
    table = rss.pivot_table(index=["node", "time"], columns="peer", values="value")
    table = table.reindex(columns=ids).sort_index()
    lost = len(epochs) - len(table)
    if lost:
        warnings.warn(f"method gmm: {lost} (time, node) measurement vector(s) left out: none of "
                      "their readings is of a calibrated base station", UserWarning, stacklevel=2)
    meas = table.to_numpy(float)
    out = table.index.to_frame(index=False)[["time", "node"]]
    meas = apply_device_offset(meas, out["node"].to_numpy(), cal_rss, offset)
    kmax = int(request.option("position_components", 8))
    extra = {}
    if kind == "places":
        given = {name: request.option(name, None) for name in ("temperature", "top_places",
                                                                "shrink")}
        if any(v is None for v in given.values()):
            defaults = {"temperature": 1.0, "top_places": 0, "shrink": 5.0}
            try:
                chosen = select_places_settings(
                    pos, cal_rss, zones, zone_names, min_samples=1,
                    **{grid: (v,) for grid, v in zip(("temperatures", "top_places", "shrinks"),
                                                      given.values()) if v is not None})
                given = {"temperature": chosen.temperature,
                         "top_places": chosen.top_places or 0, "shrink": chosen.shrink}
            except ConfigError as err:           # a calibration too small to split
                warnings.warn(f"method gmm: {err}; settings not given are T=1, all places, "
                              "shrink 5", UserWarning, stacklevel=2)
                given = {k: defaults[k] if v is None else v for k, v in given.items()}
        model = FingerprintMixture.fit(pos, cal_rss, zones, zone_names, min_samples=1,
                                       shrink=float(given["shrink"]))
        t_best, top = float(given["temperature"]), int(given["top_places"]) or None
        if request.option("track", 0.0):
            mean = np.empty((len(out), 2))
            cov = np.empty((len(out), 2, 2))
            for node in _by_node(out):                # nodes have different time axes
                idx = np.flatnonzero(out["node"].to_numpy() == node)
                res = track_places(model, meas[idx], out["time"].to_numpy()[idx],
                                   float(request.option("v_max", 1.5)), t_best, top)
                mean[idx], cov[idx] = res.position, res.covariance
        else:
            est = MixtureLocalizer(model, kmax, temperature=t_best, top_places=top).locate(meas)
            mean, cov = est.position, est.covariance
            for j, name in enumerate(zone_names):
                extra[name] = est.diagnostics["zone"][:, j]
    else:
        content = np.nan_to_num(np.c_[pos, cal_rss], nan=-1e9)
        rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence(
            np.frombuffer(content.tobytes(), dtype=np.uint32))))
        models = em_calibration(pos, cal_rss, int(request.option("components", 16)), rng=rng)
        if request.option("track", 0.0):
            mean = np.empty((len(out), 2))
            cov = np.empty((len(out), 2, 2))
            tracker = MixtureTracker(models, UniformDisk(float(request.option("v_max", 1.5)),
                                                         dim=2), kmax)
            for node in _by_node(out):                # nodes have different time axes
                idx = np.flatnonzero(out["node"].to_numpy() == node)
                res = tracker.run(meas[idx], out["time"].to_numpy()[idx])
                mean[idx], cov[idx] = res.position, res.covariance
        else:
            est = MixtureLocalizer(models, kmax).locate(meas)
            mean, cov = est.position, est.covariance
    out["x"], out["y"] = mean[:, 0], mean[:, 1]
    out = add_covariance(out, cov)
    out["stations_ignored"] = ignored.reindex(
        pd.MultiIndex.from_frame(out[["node", "time"]]), fill_value=0).to_numpy()
    for name, values in extra.items():
        out[name] = values
    return out
