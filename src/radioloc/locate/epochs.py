"""Epochs of a log for the snapshot methods of ``radioloc locate`` (``gn``, ``localml``,
``ransac``, ``lsq``): one problem per ``(time, node)`` with its measurements to anchors.

:func:`range_epochs` builds the ``(E, M)`` array of ranges to anchors (duplicate
``(time, node, peer)`` rows averaged) and refuses, or with ``-o on_degenerate=skip`` sets
aside, the epochs with too few anchors; :func:`epoch_error` names an epoch that does not
fix the position; :func:`epoch_table` writes the fixes, leaves out the degenerate ones
(with one warning counting them) and fills the summary. The option ``on_degenerate`` is
:data:`ON_DEGENERATE`.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import numpy as np
import pandas as pd

from radioloc.core.errors import GeometryError, InputError
from radioloc.core.results import Estimate
from radioloc.locate.base import LocateRequest, Option
from radioloc.locate.progress import progress
from radioloc.locate.table import add_covariance

#: Epochs one call of a snapshot estimator solves (:func:`solve_epochs`): progress is
#: counted between calls; the fixes do not depend on it (every epoch is solved on its own).
EPOCH_CHUNK = 1 << 15

__all__ = ["ON_DEGENERATE", "Epochs", "range_epochs", "epoch_error", "epoch_table",
           "horizontal_ranges"]

#: The option ``on_degenerate`` of every snapshot method.
ON_DEGENERATE = Option("'error' (default): stop at the first epoch that does not fix the "
                       "position (too few measurements, collinear anchors, a mirror fix); "
                       "'skip': leave such epochs out and say how many", str,
                       choices=("error", "skip"))


#: The hint of a log whose epochs mostly have too few anchors.
ONE_AT_A_TIME = (" (ranges that arrive one anchor at a time: track them with --method "
                 "ekf-track or pf, or sample them on common epochs)")


@dataclass
class Epochs:
    """The ``(time, node)`` epochs of a log.

    Attributes
    ----------
    method : str
        For messages.
    epochs : DataFrame
        ``time, node``, one row per epoch.
    R : ndarray, shape (E, M), or None
        Range to each anchor (NaN: none), for the range methods.
    points : ndarray, shape (M, D)
        The anchors' coordinates.
    ids : list of str
        The anchors' ids.
    skip : bool
        ``on_degenerate=skip``.
    few : ndarray of bool, shape (E,)
        Epochs with fewer measurements than ``need`` (set aside by :meth:`set_few`).
    need : int
        Measurements an epoch needs.
    """

    method: str
    epochs: pd.DataFrame
    R: np.ndarray | None
    points: np.ndarray
    ids: list
    skip: bool
    few: np.ndarray
    need: int

    def set_few(self, counts: np.ndarray, need: int, what: str = "ranges to ",
                unit: str = "anchor(s)", hint: str = "") -> None:
        """Set aside the epochs with fewer than ``need`` measurements ``counts`` (E,).

        Raises
        ------
        GeometryError
            Such an epoch without ``on_degenerate=skip`` (naming it), or every epoch so.
        """
        self.need, self.few = need, np.asarray(counts) < need
        if not self.few.any():
            return
        i = int(np.flatnonzero(self.few)[0])
        dim = self.points.shape[1]
        text = (f"{self.where(i)} has {what}{int(counts[i])} {unit}; {need} are needed "
                f"in {dim}-D")
        if not self.skip:
            raise GeometryError(f"method {self.method}: {text}{hint}; -o on_degenerate=skip "
                                "leaves such epochs out")
        if self.few.all():
            raise GeometryError(f"method {self.method}: no epoch has {what}{need} {unit} "
                                f"(first: {text}){hint}")

    @property
    def solvable(self) -> np.ndarray:
        """Indices of the epochs with enough anchors."""
        return np.flatnonzero(~self.few)

    def where(self, i: int) -> str:
        """``node 'n' at time t`` of epoch ``i``."""
        return f"node {self.epochs['node'][i]!r} at time {float(self.epochs['time'][i])!r}"


def range_epochs(request: LocateRequest, method: str, need: int | None = None
                 ) -> Epochs:
    """The range epochs of ``request`` (module docstring).

    Parameters
    ----------
    request : LocateRequest
        Range rows, anchors, option ``on_degenerate``.
    method : str
        For messages.
    need : int, optional
        Anchors an epoch needs; default ``D + 1`` (D: the anchors' coordinates).

    Returns
    -------
    Epochs

    Raises
    ------
    GeometryError
        No range to an anchor; an epoch with fewer than ``need`` anchors (without
        ``on_degenerate=skip``), or every epoch so.
    """
    anchors = request.require_anchors(method)
    ranges = request.kind("range", method)
    between = ~ranges["peer"].isin(set(anchors["id"]))
    if between.any():
        first = ranges[between].iloc[0]
        warnings.warn(f"method {method}: {int(between.sum())} range row(s) between nodes not "
                      f"used (first: line {int(first['line'])}, {first['node']!r} to "
                      f"{first['peer']!r}); it locates each node from its ranges to anchors "
                      "(methods rls and ekf use ranges between nodes)", stacklevel=2)
        ranges = ranges[~between]
    dims = ["x", "y"] + (["z"] if "z" in anchors.columns else [])
    if ranges.empty:
        raise GeometryError(f"method {method}: no range to an anchor in the measurements")
    skip = request.option("on_degenerate", "error", str) == "skip"
    ranges = ranges.groupby(["time", "node", "peer"], sort=True, as_index=False).agg(
        value=("value", "mean"))
    epochs = ranges[["time", "node"]].drop_duplicates().reset_index(drop=True)
    anchor_index = {a: i for i, a in enumerate(anchors["id"])}
    e_idx = ranges.merge(epochs.reset_index(), on=["time", "node"])["index"].to_numpy()
    a_idx = ranges["peer"].map(anchor_index).to_numpy()
    R = np.full((len(epochs), len(anchors)), np.nan)
    R[e_idx, a_idx] = ranges["value"].to_numpy()
    need = len(dims) + 1 if need is None else need
    counts = np.isfinite(R).sum(axis=1)
    ep = Epochs(method, epochs, R, anchors[dims].to_numpy(dtype=float), list(anchors["id"]),
                skip, np.zeros(len(epochs), dtype=bool), need)
    ep.set_few(counts, need, hint=ONE_AT_A_TIME if np.median(counts) < need else "")
    return ep


def horizontal_ranges(request: LocateRequest, ep: Epochs) -> tuple[np.ndarray, np.ndarray]:
    """Ranges and anchors of the solvable epochs in the horizontal plane (2-D methods).

    With 3-D anchors the node height must be given (``-o tag_height_m``); each range is
    projected, ``sqrt(max(r^2 - (h - z_a)^2, 0))``.

    Returns
    -------
    R : ndarray, shape (E', M)
    points : ndarray, shape (M, 2)

    Raises
    ------
    InputError
        3-D anchors without ``tag_height_m``.
    """
    R = ep.R[ep.solvable]
    if ep.points.shape[1] == 2:
        return R, ep.points
    height = request.option("tag_height_m")
    if height is None:
        raise InputError(f"method {ep.method}: locates in 2-D; the anchors have z, so give the "
                         "node height (-o tag_height_m=METRES)")
    dz = height - ep.points[:, 2]
    return np.sqrt(np.maximum(R ** 2 - dz ** 2, 0.0)), ep.points[:, :2]


def solve_epochs(ep: Epochs, R: np.ndarray, points: np.ndarray,
                 locate: Callable[[np.ndarray, np.ndarray], Estimate]) -> Estimate:
    """``locate(R, points)`` of a snapshot estimator over chunks of :data:`EPOCH_CHUNK`
    epochs, the progress counting their rows, the estimates joined.

    Parameters
    ----------
    ep : Epochs
        For the progress's name.
    R : ndarray, shape (E, M)
        Ranges of the epochs to solve (NaN: none).
    points : ndarray, shape (M, D) or (E, M, D)
        The anchors (per epoch, or shared).
    locate : callable
        The estimator's ``locate``.

    Returns
    -------
    Estimate
        As one call on every epoch: ``position``, ``covariance`` and the per-epoch
        diagnostics concatenated.

    Raises
    ------
    GeometryError
        From ``locate``, its ``index`` counted in the whole of ``R``.
    """
    parts = []
    with progress(int(np.isfinite(R).sum()), ep.method) as bar:
        for i in range(0, max(len(R), 1), EPOCH_CHUNK):
            rows = slice(i, i + EPOCH_CHUNK)
            try:
                parts.append(locate(R[rows], points[rows] if points.ndim == 3 else points))
            except GeometryError as exc:
                if exc.index is not None:
                    exc.index = (exc.index[0] + i,) + tuple(exc.index[1:])
                raise
            bar.advance(int(np.isfinite(R[rows]).sum()))
    if len(parts) == 1:
        return parts[0]
    join = lambda v: None if v[0] is None else np.concatenate(v)     # noqa: E731
    return Estimate(join([p.position for p in parts]), join([p.covariance for p in parts]),
                    diagnostics={k: join([np.asarray(p.diagnostics[k]) for p in parts])
                                 for k in parts[0].diagnostics})


def epoch_error(ep: Epochs, exc: GeometryError) -> GeometryError:
    """The error of an estimator raised on the solvable epochs, naming the node and time
    (and the anchors by their ids) instead of the batch index."""
    if exc.index is None:
        return GeometryError(f"method {ep.method}: {exc}")
    i = int(ep.solvable[exc.index[0]])
    detail = exc.detail
    if exc.anchors is not None:
        from radioloc.estimators.multilateration import anchor_phrase

        detail = detail.replace(anchor_phrase(exc.anchors),
                                "anchors " + ", ".join(str(ep.ids[k]) for k in exc.anchors))
    return GeometryError(f"method {ep.method}: {ep.where(i)}: {detail}; -o on_degenerate=skip "
                         "leaves such epochs out")


def epoch_table(ep: Epochs, position: np.ndarray, cov: np.ndarray | None,
                bad: np.ndarray, ambiguous: np.ndarray | None = None, *,
                detail: str = "the measurements do not fix the position",
                what: str = "anchor ranges", misfit: np.ndarray | None = None, **columns
                ) -> pd.DataFrame:
    """The fixes of the solvable epochs, degenerate ones left out with a warning.

    Parameters
    ----------
    ep : Epochs
    position : ndarray, shape (E', D)
        One fix per solvable epoch.
    cov : ndarray, shape (E', D, D), optional
        Their covariances (columns ``uncertainty_m``, ``cov_*``).
    bad : ndarray of bool, shape (E',)
        Fixes that do not fix the position (left out).
    ambiguous : ndarray of bool, shape (E',), optional
        Of those, the mirror fixes (counted in the warning).
    detail : str
        Why a flagged epoch is refused (the message without ``on_degenerate=skip``).
    what : str
        What the epochs set aside had too few of (for the warning).
    misfit : ndarray of bool, shape (E',), optional
        Of the ``bad`` fixes, those left out because their rows fit no one position (not
        for their geometry): counted apart in the warning and the summary.
    **columns
        Further per-epoch columns ``(E',)``.

    Returns
    -------
    DataFrame
        ``time, node, x, y[, z]``, the covariance columns and ``columns``;
        ``attrs["summary"]``: ``epochs``, ``epochs_fixed``, ``epochs_skipped_few_ranges``,
        ``epochs_skipped_geometry``.

    Raises
    ------
    GeometryError
        Every solvable epoch is degenerate; or one is, without ``on_degenerate=skip``
        (naming it, with ``detail``).
    """
    bad = np.asarray(bad, dtype=bool)
    mirror = np.zeros_like(bad) if ambiguous is None else np.asarray(ambiguous, dtype=bool)
    solvable = ep.solvable
    if bad.any() and not ep.skip:
        i = int(solvable[np.flatnonzero(bad)[0]])
        raise GeometryError(f"method {ep.method}: {ep.where(i)}: {detail}; -o "
                            "on_degenerate=skip leaves such epochs out")
    if bad.all():
        raise GeometryError(f"method {ep.method}: no epoch has a geometry that fixes the "
                            f"position ({int(mirror.sum())} ambiguous mirror fixes; first: "
                            f"{ep.where(int(solvable[0]))})")
    out = ep.epochs.iloc[solvable].reset_index(drop=True)
    for k, c in enumerate("xyz"[: position.shape[-1]]):
        out[c] = position[:, k]
    if cov is not None:
        out = add_covariance(out, cov)
    for name, values in columns.items():
        out[name] = values
    lead = ["time", "node", *"xyz"[: position.shape[-1]]]      # the schema's column order
    out = out[lead + [c for c in out.columns if c not in lead]]
    n_e, n_few, n_bad = len(ep.epochs), int(ep.few.sum()), int(bad.sum())
    n_misfit = 0 if misfit is None else int(np.sum(np.asarray(misfit, dtype=bool) & bad))
    if n_few or n_bad:
        first = int(np.flatnonzero(ep.few)[0]) if n_few else int(solvable[np.flatnonzero(bad)[0]])
        rows = (f", {n_misfit} whose rows fit no one position (outliers, NLOS or noise larger "
                "than stated, not geometry)" if n_misfit else "")
        warnings.warn(f"method {ep.method}: {n_few + n_bad} of {n_e} epochs left out: {n_few} "
                      f"with fewer than {ep.need} {what}, {n_bad - n_misfit} whose geometry "
                      f"does not fix the position ({int(mirror.sum())} of them ambiguous: a "
                      f"mirror fix fits the ranges as well){rows}; first: {ep.where(first)}",
                      stacklevel=3)
        out = out[~bad].reset_index(drop=True)
    out.attrs["summary"] = {"epochs": n_e, "epochs_fixed": n_e - n_few - n_bad,
                            "epochs_skipped_few_ranges": n_few,
                            "epochs_skipped_geometry": n_bad - n_misfit,
                            "epochs_skipped_misfit": n_misfit}
    return out
