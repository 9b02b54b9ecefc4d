"""The one adapter from a user's log to the generic estimators.

A log (:class:`~radioloc.io.measurements.Measurements`) and an anchors table become, per
node, the :class:`~radioloc.models.measurement.Observation` s that every generic estimator
takes: one per measurement kind, a ``(T, S)`` array over the node's time steps and slots
(a slot is an anchor, or an anchor and its reference anchor for a time difference), each
with its measurement model and its anchors' positions. Which model explains which kind is
:func:`default_models`' choice, from the method's options; a method may pass its own.
"""

from __future__ import annotations

from dataclasses import fields, is_dataclass, replace
from typing import Mapping

import numpy as np
import pandas as pd

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.kinds import kinds as declared_kinds
from radioloc.core.kinds import model_kinds
from radioloc.core.plausibility import value_checks
from radioloc.io.measurements import Measurements
from radioloc.locate.base import Option
from radioloc.models.measurement import Context, MeasurementModel, Observation

__all__ = ["anchor_positions", "anchor_points", "moving_anchors", "clock_groups",
           "node_observations", "slot_context", "log_observations", "anchor_ranges",
           "default_models", "frame_settings", "given_sigmas", "sigma_options"]


def sigma_options() -> dict[str, Option]:
    """The ``-o`` option of each kind's sigma (:attr:`radioloc.core.kinds.Kind.sigma_option`),
    by option name, for the methods that read the kinds' models."""
    out = {}
    for k in model_kinds().values():
        out.setdefault(k.sigma_option, Option(
            f"{k.sigma_help or k.name + ' error standard deviation, ' + k.unit} (default "
            f"{k.sigma_default:g})", float, min=0, min_exclusive=True, max=k.sigma_max))
    return out


def given_sigmas(request) -> dict[str, float]:
    """The sigma options (:func:`sigma_options`) the request gives, by name."""
    return {k: v for k in sigma_options() if (v := request.option(k)) is not None}


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
                   range_noise=None, settings: Mapping[str, object] | None = None
                   ) -> dict[str, MeasurementModel]:
    """The measurement model of each kind.

    Parameters
    ----------
    kinds : iterable of str
        Kinds present in the log (kinds without a model of their own are left out here;
        the method refuses them or builds their model).
    options : mapping
        Sigmas by the kinds' option names (:func:`sigma_options`: ``range_std_m`` ...);
        default each kind's :attr:`~radioloc.core.kinds.Kind.sigma_default`.
    anchor_bias : bool
        Ranges carry a per-anchor bias to estimate (WiFi RTT offsets, antenna delays).
    range_noise : range-error model, optional
        E.g. a :class:`~radioloc.models.los_nlos.LosNlosRange` instead of a Gaussian.
    settings : mapping, optional
        Fields of the models that follow from the working frame and the anchors
        (:func:`frame_settings`): each model takes those it has as fields (the
        pseudorange's ``groups``, ``earth_rotation``, ``to_ecef``; the body-frame rates'
        ``geocentric``).

    Returns
    -------
    dict of str to MeasurementModel
    """
    from radioloc.models.ranging import RangeModel

    settings = settings or {}
    declared = model_kinds()
    out: dict[str, MeasurementModel] = {}
    for kind in kinds:
        if kind not in declared:
            continue
        k = declared[kind]
        sigma = float(options.get(k.sigma_option, k.sigma_default))
        if kind == "range" and (anchor_bias or range_noise is not None):
            model = (RangeModel(noise=range_noise, anchor_bias=anchor_bias)
                     if range_noise is not None
                     else RangeModel(std_m=sigma, anchor_bias=anchor_bias))
        else:
            model = k.build(sigma)
        own = {f.name: settings[f.name] for f in (fields(model) if is_dataclass(model) else ())
               if f.name in settings}
        out[kind] = replace(model, **own) if own else model
    return out


def frame_settings(request) -> dict:
    """The settings of a ``locate`` request that follow from its frame and anchors, for
    :func:`default_models`, named as the models' fields: a receiver clock per anchor
    ``group`` (``groups``); the Earth-rotation (Sagnac) term by option ``earth_rotation``
    (default: on when the working frame is tied to the Earth, i.e. the anchors are in ECEF
    or WGS84 or an origin is given) with the working frame's map to ECEF (``to_ecef``);
    whether "up" is geocentric (``geocentric``: an ECEF working frame).

    Parameters
    ----------
    request : LocateRequest

    Returns
    -------
    dict
        ``groups``, ``earth_rotation``, ``to_ecef``, ``geocentric``.

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
    return {"groups": int(groups.max()) + 1 if groups.size else 1,
            "earth_rotation": bool(rotation),
            "to_ecef": frame.to_ecef() if geo and rotation else None,
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
    network methods. Rows of a kind a node measures of itself
    (:attr:`~radioloc.core.kinds.Kind.self_measured`: a heading) have no anchor: one slot
    per sensor, points at the origin, index -1. The anchor-file columns a kind's model reads
    (:attr:`~radioloc.core.kinds.Kind.anchor_columns`) that the anchors table has are each
    row's anchor's values in the context's ``columns``. With moving anchors (:func:`moving_anchors`) the context's points
    are ``(T, S, D)``: each anchor where it was at each step (:func:`anchor_points`).

    Raises
    ------
    InputError
        A reference that is not an anchor (naming it, the node and the kind).
    """
    no_check = frozenset(value_checks().values()) if checked else frozenset()
    declared = declared_kinds()
    own = [n for n, k in declared.items() if k.self_measured]
    index = set(anchors["id"])
    sel = measurements.select(kind=list(models), node=node)
    sel = Measurements(sel.frame[sel.frame["peer"].isin(index)
                                 | sel.frame["kind"].isin(own)])
    time = sel.times(node)
    out = []
    for kind in sel.kinds:
        grid = sel.grid(kind, node, times=time)
        for what, ids in (("peer", grid.peers), ("reference", grid.references)):
            bad = [p for p in ids if p not in index and not (what == "reference" and p == "")]
            if bad and kind not in own:
                raise InputError(f"node {node!r}, kind {kind!r}: {what} {bad[0]!r} is not an "
                                 "anchor (this method locates from anchors only)")
        ctx = slot_context(anchors, kind, models[kind], grid.peers, grid.references, time,
                           np.isfinite(grid.value), height_m=height_m)
        std = grid.std if np.isfinite(grid.std).any() else None
        out.append(Observation(models[kind], grid.value, ctx, std=std, no_check=no_check))
    return time, out


def slot_context(anchors: pd.DataFrame, kind: str, model: MeasurementModel, peers, references,
                 times: np.ndarray, seen: np.ndarray, *, height_m: float | None = None) -> Context:
    """The context of one kind's slots (see :func:`node_observations`).

    Parameters
    ----------
    anchors : DataFrame
        ``id, x, y[, z]`` and the anchor-file columns ``kind`` reads.
    kind : str
    model : MeasurementModel
        The kind's model (a receiver clock per anchor group when it has several).
    peers, references : sequence of str
        Each slot's anchor and reference anchor (``""``: none); a sensor name for a kind a
        node measures of itself.
    times : ndarray, shape (T,)
        The steps (for moving anchors).
    seen : ndarray of bool, shape (T, S)
        Where a slot has a measurement (moving anchors need a position there only).
    height_m : float, optional

    Returns
    -------
    Context
        Points ``(S, D)``, or ``(T, S, D)`` with moving anchors.
    """
    declared = declared_kinds()
    if declared[kind].self_measured:
        return Context(points=np.zeros((len(peers), 2 + ("z" in anchors.columns))),
                       index=np.full(len(peers), -1))
    first = anchors.drop_duplicates("id")
    index = {a: i for i, a in enumerate(first["id"])}
    peer_idx = np.array([index[p] for p in peers], dtype=int)
    ref_idx = (np.array([index[p] for p in references], dtype=int)
               if declared[kind].reference else None)
    if moving_anchors(anchors):
        pts = anchor_points(anchors, peers, times, seen)
        ref = None if ref_idx is None else anchor_points(anchors, references, times, seen)
    else:
        points = anchor_positions(anchors)
        pts = points[peer_idx]
        ref = None if ref_idx is None else points[ref_idx]
    columns = {c: first[c].to_numpy(dtype=float)[peer_idx]
               for c in declared[kind].anchor_columns if c in first.columns}
    groups = getattr(model, "clock_groups", 1) > 1
    return Context(points=pts, index=peer_idx, reference=ref, reference_index=ref_idx,
                   height_m=height_m, columns=columns or None,
                   group=clock_groups(anchors, peers) if groups else None)


def log_observations(log: Measurements, anchors: pd.DataFrame,
                     models: Mapping[str, MeasurementModel], method: str,
                     height_m: float | None = None) -> list[tuple[str, np.ndarray, list]]:
    """Every node's observations (:func:`node_observations` of a checked log), for the
    nodes with at least one step.

    Parameters
    ----------
    log : Measurements
    anchors : DataFrame
    models : mapping of kind to MeasurementModel
    method : str
        For the message.
    height_m : float, optional

    Returns
    -------
    list of (node, times (T,), observations)

    Raises
    ------
    GeometryError
        No node has a measurement to an anchor.
    """
    out = []
    for node, rows in log.by_node().items():
        times, obs = node_observations(rows, anchors, node, models, height_m=height_m,
                                       checked=True)
        if times.size:
            out.append((node, times, obs))
    if not out:
        raise GeometryError(f"method {method}: no measurement to an anchor in the measurements")
    return out


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
