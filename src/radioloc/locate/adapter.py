"""The one adapter from a user's log to the generic estimators.

A log (:class:`~radioloc.io.measurements.Measurements`) and an anchors table become, per
node, the :class:`~radioloc.models.measurement.Observation` s that every generic estimator
takes: one per measurement kind, a ``(T, S)`` array over the node's time steps and slots
(a slot is an anchor, or an anchor and its reference anchor for a time difference), each
with its measurement model and its anchors' positions. Which model explains which kind is
:func:`default_models`' choice, from the method's options; a method may pass its own.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import pandas as pd

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.plausibility import VALUE_CHECKS
from radioloc.io.measurements import Measurements
from radioloc.models.measurement import Context, MeasurementModel, Observation

__all__ = ["clock_groups", "frame_settings", "DEFAULT_SIGMAS", "anchor_positions", "anchor_points", "moving_anchors", "node_observations",
           "anchor_ranges", "default_models", "MODEL_KINDS", "SELF_MODEL_KINDS"]

#: The measurement kinds the generic estimators read, and the option naming each one's sigma.
MODEL_KINDS = {
    "range": "range_std_m",
    "tdoa": "tdoa_std_m",
    "aoa": "aoa_std_rad",
    "aoa_elevation": "aoa_std_rad",
    "pseudorange": "pseudorange_std_m",
    "heading": "heading_std_rad",
    "speed": "speed_std_mps",
    "vertical_speed": "vertical_speed_std_mps",
    "yaw_rate": "yaw_rate_std_rps",
}
#: The sigma of each kind when its option is not given (:func:`default_models`).
DEFAULT_SIGMAS = {"range": 0.3, "tdoa": 0.3, "aoa": 0.05, "aoa_elevation": 0.05,
                  "pseudorange": 5.0, "heading": 0.3, "speed": 0.1, "vertical_speed": 0.1,
                  "yaw_rate": 0.01}
#: Kinds a node measures of itself (no anchor: ``peer`` names the sensor).
SELF_MODEL_KINDS = ("heading", "speed", "vertical_speed", "yaw_rate")


def anchor_positions(anchors: pd.DataFrame) -> np.ndarray:
    """The anchors' coordinates ``(A, D)`` in table order (``x, y[, z]``)."""
    dims = ["x", "y"] + (["z"] if "z" in anchors.columns else [])
    return anchors[dims].to_numpy(dtype=float)


def moving_anchors(anchors: pd.DataFrame | None) -> bool:
    """Whether the anchors table has a track (a ``time`` column with a time in it)."""
    return anchors is not None and "time" in anchors.columns and bool(anchors["time"].notna().any())


def anchor_points(anchors: pd.DataFrame, ids, times: np.ndarray,
                  measured: np.ndarray | None = None) -> np.ndarray:
    """Positions of the anchors ``ids`` at ``times``: ``(T, S, D)``.

    A fixed anchor (no ``time`` column, or an empty time) is where its row says; a moving
    one (rows at several times) is interpolated linearly between its two rows around each
    time, never extrapolated. Its track need only cover the times it is measured at
    (``measured``): elsewhere (a satellite below the horizon) the position is its track's
    nearest end, which no estimator reads (the slot's measurement is missing there).

    Parameters
    ----------
    anchors : DataFrame
        As read by :func:`radioloc.io.logs.read_anchors`.
    ids : sequence of str
        Anchor ids (slots).
    times : ndarray, shape (T,)
    measured : ndarray of bool, shape (T, S), optional
        Where each anchor is measured (default: at every time).

    Returns
    -------
    ndarray, shape (T, S, D)

    Raises
    ------
    InputError
        A measured time outside a moving anchor's track (naming the anchor and the time).
    """
    dims = ["x", "y"] + (["z"] if "z" in anchors.columns else [])
    times = np.asarray(times, dtype=float)
    out = np.empty((times.size, len(ids), len(dims)))
    tracked = "time" in anchors.columns
    for s, a in enumerate(ids):
        rows = anchors[anchors["id"] == a]
        xyz = rows[dims].to_numpy(dtype=float)
        if not tracked or rows["time"].isna().all():
            out[:, s] = xyz[0]
            continue
        t = rows["time"].to_numpy(dtype=float)
        outside = (times < t[0]) | (times > t[-1])
        if measured is not None:
            outside &= measured[:, s]
        if outside.any():
            raise InputError(f"anchor {a!r}: no position at time {float(times[outside][0])!r} "
                             f"(its track runs from {float(t[0])!r} to {float(t[-1])!r}; positions are "
                             "interpolated, never extrapolated)")
        for d in range(len(dims)):
            out[:, s, d] = np.interp(times, t, xyz[:, d])
    return out


def clock_groups(anchors: pd.DataFrame | None, ids=None) -> np.ndarray:
    """The receiver clock of a pseudorange to each anchor of ``ids`` (all: None): the index
    of its ``group`` (a constellation) in the order the groups first appear in the anchors
    table; 0 for every anchor of a table without ``group``.

    Parameters
    ----------
    anchors : DataFrame or None
    ids : sequence of str, optional

    Returns
    -------
    ndarray of int
    """
    if anchors is None:
        return np.zeros(0 if ids is None else len(ids), dtype=int)
    first = anchors.drop_duplicates("id")
    ids = list(first["id"]) if ids is None else list(ids)
    if "group" not in first.columns:
        return np.zeros(len(ids), dtype=int)
    order = {g: k for k, g in enumerate(dict.fromkeys(first["group"]))}
    of = dict(zip(first["id"], first["group"].map(order)))
    return np.array([of.get(a, 0) for a in ids], dtype=int)


def default_models(kinds, options: Mapping[str, float], *, anchor_bias: bool = False,
                   range_noise=None, clocks: int = 1, earth_rotation: bool = False,
                   to_ecef=None, geocentric: bool = False) -> dict[str, MeasurementModel]:
    """The measurement model of each kind.

    Parameters
    ----------
    kinds : iterable of str
        Kinds present in the log (others are ignored here; the method refuses them).
    options : mapping
        Sigmas by the names of :data:`MODEL_KINDS` (``range_std_m`` ...); defaults
        :data:`DEFAULT_SIGMAS`.
    anchor_bias : bool
        Ranges carry a per-anchor bias to estimate (WiFi RTT offsets, antenna delays).
    range_noise : range-error model, optional
        E.g. a :class:`~radioloc.models.los_nlos.LosNlosRange` instead of a Gaussian.
    clocks, earth_rotation, to_ecef
        Of the pseudorange model (:class:`~radioloc.models.pseudorange.PseudorangeModel`):
        receiver clocks (one per anchor ``group``), the Sagnac term, the working frame's
        map to ECEF (see :func:`frame_settings`).
    geocentric : bool
        The working frame is ECEF: "up" of the speed and yaw-rate models is the direction
        from the Earth's centre.

    Returns
    -------
    dict of str to MeasurementModel
    """
    from radioloc.models.bearing import BearingModel
    from radioloc.models.body_rates import SpeedModel, VerticalSpeedModel, YawRateModel
    from radioloc.models.heading import HeadingModel
    from radioloc.models.pseudorange import PseudorangeModel
    from radioloc.models.ranging import RangeModel
    from radioloc.models.tdoa import TdoaModel

    def sigma(kind):
        return float(options.get(MODEL_KINDS[kind], DEFAULT_SIGMAS[kind]))

    out: dict[str, MeasurementModel] = {}
    for kind in kinds:
        if kind == "range":
            out[kind] = (RangeModel(noise=range_noise, anchor_bias=anchor_bias) if range_noise is not None
                         else RangeModel(std_m=sigma(kind), anchor_bias=anchor_bias))
        elif kind == "tdoa":
            out[kind] = TdoaModel(std_m=sigma(kind))
        elif kind in ("aoa", "aoa_elevation"):
            out[kind] = BearingModel(std_rad=sigma(kind),
                                     component="azimuth" if kind == "aoa" else "elevation")
        elif kind == "pseudorange":
            out[kind] = PseudorangeModel(std_m=sigma(kind), groups=clocks,
                                         earth_rotation=earth_rotation,
                                         to_ecef=None if to_ecef is None or not earth_rotation
                                         else to_ecef)
        elif kind == "heading":
            out[kind] = HeadingModel(std_rad=sigma(kind))
        elif kind == "speed":
            out[kind] = SpeedModel(std_mps=sigma(kind), geocentric=geocentric)
        elif kind == "vertical_speed":
            out[kind] = VerticalSpeedModel(std_mps=sigma(kind), geocentric=geocentric)
        elif kind == "yaw_rate":
            out[kind] = YawRateModel(std_rps=sigma(kind), geocentric=geocentric)
    return out


def frame_settings(request) -> dict:
    """The settings of a ``locate`` request that follow from its frame and anchors, for
    :func:`default_models`: a receiver clock per anchor ``group``; the Earth-rotation
    (Sagnac) term by option ``earth_rotation`` (default: on when the working frame is tied
    to the Earth, i.e. the anchors are in ECEF or WGS84 or an origin is given); the working
    frame's map to ECEF; whether "up" is geocentric (an ECEF working frame).

    Parameters
    ----------
    request : LocateRequest

    Returns
    -------
    dict
        ``clocks``, ``earth_rotation``, ``to_ecef``, ``geocentric``.

    Raises
    ------
    ConfigError
        ``earth_rotation=1`` in a frame with no place on the Earth.
    """
    from radioloc.core.errors import ConfigError

    frame = getattr(request, "frame", None)
    geo = frame is not None and frame.georeferenced
    rotation = request.option("earth_rotation", geo, bool)
    if rotation and not geo:
        raise ConfigError("option earth_rotation=1: "
                          + (frame.why_not_georeferenced() if frame is not None
                             else "the frame of the anchors is unknown"))
    groups = clock_groups(request.anchors)
    return {"clocks": int(groups.max()) + 1 if groups.size else 1,
            "earth_rotation": bool(rotation), "to_ecef": frame.to_ecef() if geo else None,
            "geocentric": geo and frame.kind == "ecef"}


def node_observations(measurements: Measurements, anchors: pd.DataFrame, node: str,
                      models: Mapping[str, MeasurementModel], *,
                      height_m: float | None = None,
                      checked: bool = False) -> tuple[np.ndarray, list[Observation]]:
    """The observations of one node, one per kind that ``models`` explains.

    Parameters
    ----------
    measurements : Measurements
    anchors : DataFrame
        ``id, x, y[, z]`` (as read by :func:`radioloc.io.logs.read_anchors`).
    node : str
    models : mapping of kind to MeasurementModel
    height_m : float, optional
        Known height of a 2-D node with 3-D anchors.
    checked : bool
        True: the log's values passed :func:`radioloc.core.plausibility.check_log` as a
        whole (a locate method, with the user's ``no_check``), so the observations leave out
        the value checks of :func:`~radioloc.core.plausibility.check_values` (one node's
        rows would judge them less surely, and an overruled check would refuse again).

    Returns
    -------
    time : ndarray, shape (T,)
        The node's time steps (over the kinds of ``models``).
    observations : list of Observation
        ``z`` of shape ``(T, S)``; NaN where a slot has no measurement at a step.

    Rows whose peer is another node (cooperative ranges) are left out: they are for the
    network methods. Rows of :data:`SELF_MODEL_KINDS` (a heading) have no anchor: one slot
    per sensor, points at the origin, index -1. With moving anchors (:func:`moving_anchors`) the context's points
    are ``(T, S, D)``: each anchor where it was at each step (:func:`anchor_points`).

    Raises
    ------
    InputError
        A reference that is not an anchor (naming it, the node and the kind).
    """
    moving = moving_anchors(anchors)
    no_check = frozenset(VALUE_CHECKS.values()) if checked else frozenset()
    ids = list(dict.fromkeys(anchors["id"]))
    points = None if moving else anchor_positions(anchors)
    index = {a: i for i, a in enumerate(ids)}
    sel = measurements.select(kind=list(models), node=node)
    sel = Measurements(sel.frame[sel.frame["peer"].isin(index)
                                 | sel.frame["kind"].isin(SELF_MODEL_KINDS)])
    time = sel.times(node)
    out = []
    for kind in sel.kinds:
        grid = sel.grid(kind, node, times=time)
        if kind in SELF_MODEL_KINDS:
            ctx = Context(points=np.zeros((len(grid.peers), 2 + ("z" in anchors.columns))),
                          index=np.full(len(grid.peers), -1))
            out.append(Observation(models[kind], grid.value, ctx,
                                   std=grid.std if np.isfinite(grid.std).any() else None,
                                   no_check=no_check))
            continue
        for what, ids in (("peer", grid.peers), ("reference", grid.references)):
            bad = [p for p in ids if p not in index and not (what == "reference" and p == "")]
            if bad:
                raise InputError(f"node {node!r}, kind {kind!r}: {what} {bad[0]!r} is not an "
                                 "anchor (this method locates from anchors only)")
        peer_idx = np.array([index[p] for p in grid.peers], dtype=int)
        ref_idx = (np.array([index[p] for p in grid.references], dtype=int)
                   if kind == "tdoa" else None)
        if moving:
            seen = np.isfinite(grid.value)
            pts = anchor_points(anchors, grid.peers, time, seen)
            ref = None if ref_idx is None else anchor_points(anchors, grid.references, time,
                                                             seen)
        else:
            pts = points[peer_idx]
            ref = None if ref_idx is None else points[ref_idx]
        ctx = Context(points=pts, index=peer_idx, reference=ref,
                      reference_index=ref_idx, height_m=height_m,
                      group=clock_groups(anchors, grid.peers) if kind == "pseudorange" else None)
        std = grid.std if np.isfinite(grid.std).any() else None
        out.append(Observation(models[kind], grid.value, ctx, std=std, no_check=no_check))
    return time, out


def anchor_ranges(measurements: Measurements, anchors: pd.DataFrame, method: str
                  ) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """Each node's ranges to the anchors as one ``(T, A)`` array: a column per anchor.

    The range :class:`~radioloc.models.measurement.Observation` of each node
    (:func:`node_observations`) with its slots spread to the anchors' columns, in the order
    of the anchors table, for the methods whose filters index ranges by anchor (``pf``,
    ``smoother``). Duplicate ``(time, node, peer)`` rows are averaged; ranges to peers that
    are not anchors are left out, and so is a node with none.

    Parameters
    ----------
    measurements : Measurements
    anchors : DataFrame
        ``id, x, y[, z]``, fixed anchors.
    method : str
        For messages.

    Returns
    -------
    list of (node, times (T,), ranges (T, A))
        Nodes sorted; ``times`` the node's time stamps with a range to an anchor; NaN where
        an anchor has no range at a time.

    Raises
    ------
    InputError
        No range rows.
    GeometryError
        No range to an anchor.

    Examples
    --------
    >>> log = Measurements.from_arrays([0.0, 0.0, 1.0], "t", ["A", "B", "A"], "range",
    ...                                [1.0, 2.0, 1.5])
    >>> anchors = pd.DataFrame({"id": ["A", "B"], "x": [0.0, 3.0], "y": [0.0, 0.0]})
    >>> [(node, t.tolist(), r.tolist()) for node, t, r in anchor_ranges(log, anchors, "pf")]
    [('t', [0.0, 1.0], [[1.0, 2.0], [1.5, nan]])]
    """
    rows = measurements.select(kind="range")
    if not len(rows):
        raise InputError(f"method {method}: the measurements hold no 'range' rows")
    rows = Measurements(rows.frame.assign(reference=""))    # a range has one reference point
    models = default_models(["range"], {})
    width = len(anchor_positions(anchors))
    out = []
    for node, own in rows.by_node().items():
        times, obs = node_observations(own, anchors, node, models)
        if times.size:
            ranges = np.full((times.size, width), np.nan)
            ranges[:, obs[0].context.index] = obs[0].z
            out.append((node, times, ranges))
    if not out:
        raise GeometryError(f"method {method}: no range to an anchor in the measurements")
    return out
