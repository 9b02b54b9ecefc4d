"""``radioloc locate --method gn``: per-epoch Gauss-Newton multilateration to anchors
(:class:`radioloc.estimators.multilateration.Multilateration`).

Uncertainty: the covariance of each fix is ``s^2 (J' J)^-1`` with ``s`` the range error
standard deviation of the whole log: ``-o std_m`` when given, otherwise pooled over every
epoch the log fixes, ``s^2 = sum of squared residuals / sum of (ranges - D)``. One epoch's own
residuals are not used: an epoch of three anchors in 2-D has one degree of freedom, and its
residual can be centimetres for a fix metres off.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, GeometryError
from radioloc.estimators.multilateration import Multilateration
from radioloc.locate.base import LocateRequest, Option, locate_method
from radioloc.locate.epochs import (ON_DEGENERATE, epoch_error, epoch_table, range_epochs,
                                     solve_epochs)

#: Smallest pooled range standard deviation (exact ranges leave zero residuals), m.
STD_FLOOR_M = 1e-6


def pooled_std(pooled: dict) -> tuple[float, str]:
    """The range error standard deviation pooled over epochs, and where it came from.

    Parameters
    ----------
    pooled : dict
        ``sum_sq_m2`` (squared residuals summed over the epochs, m^2), ``dof`` (their
        ranges less the unknowns, summed) and ``epochs``: sums, so that the epochs of
        several parts of a log pool as one.

    Returns
    -------
    std_m : float
        ``sqrt(sum_sq_m2 / dof)``, at least :data:`STD_FLOOR_M`.
    source : str
    """
    std = max(float(np.sqrt(pooled["sum_sq_m2"] / pooled["dof"])), STD_FLOOR_M)
    return std, (f"pooled residuals of {pooled['epochs']} epochs ({pooled['dof']:g} degrees "
                 "of freedom)")


def _inverse_information(position: np.ndarray, anchors: np.ndarray, heard: np.ndarray,
                         skip: np.ndarray) -> np.ndarray:
    """``(J' J)^-1`` of each fix ``(E, D)`` from the unit vectors to the anchors it heard
    (``heard`` (E, M)); NaN for the ``skip`` epochs."""
    d = position[:, None, :] - anchors[None]
    u = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    u = np.where(heard[..., None], u, 0.0)
    info = np.einsum("emi,emj->eij", u, u)
    info = np.where(skip[:, None, None], np.eye(anchors.shape[1]), info)
    return np.where(skip[:, None, None], np.nan, np.linalg.inv(info))


def _exclude_faults(R: np.ndarray, anchors: np.ndarray, std: float | None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """The ranges ``(E, M)`` with the faults of each fix left out
    (:func:`radioloc.estimators.fault_exclusion.exclude_faults`), and the mask of those left
    out. Without a stated ``std``, the test's sigma is the median over the fixes of their
    residual rms (corrected for the unknowns): robust to the fixes that hold a fault."""
    from radioloc.estimators.fault_exclusion import exclude_faults
    from radioloc.models.measurement import Context, Observation
    from radioloc.models.ranging import RangeModel

    # the fits of the search judge convergence by their own residuals: a stated std would
    # call a fix with a fault in it still travelling, and no subset would be tried from it
    solver = Multilateration(on_degenerate="flag")
    if std is None:
        first = solver.locate(R, anchors)
        used = np.isfinite(R).sum(axis=1)
        spare = used - anchors.shape[1]
        ok = ~np.asarray(first.diagnostics["degenerate"]) & (spare > 0)
        if not ok.any():
            return R, np.zeros(R.shape, dtype=bool)
        rms = np.asarray(first.diagnostics["residual_rms_m"])[ok]
        std = max(float(np.median(rms * np.sqrt(used[ok] / spare[ok]))), STD_FLOOR_M)
    obs = Observation(RangeModel(std_m=std), R, Context(points=anchors))
    _, excluded, _ = exclude_faults(lambda o: solver.locate(o[0].z, anchors), [obs])
    return np.where(excluded[0], np.nan, R), excluded[0]


@locate_method("gn", "Gauss-Newton multilateration of each node at each time from its ranges "
                     "to anchors (options: std_m, on_degenerate)",
               options={"std_m": Option("range error standard deviation, m (default: pooled "
                                        "from the residuals of every epoch of the log)", float,
                                        min=0, min_exclusive=True, max=1e7),
                        "range_std_m": Option("the same as std_m (older name)", float, min=0,
                                              min_exclusive=True, max=1e7),
                        "exclude_faults": Option("1: a fix whose ranges fail their chi-square "
                                                 "test (99.9 %) is fitted again without its "
                                                 "worst range, while a range to spare is left "
                                                 "(for rare gross faults; with NLOS in many "
                                                 "rows it can keep a wrong subset); 0 "
                                                 "(default): every range kept", bool),
                        "on_degenerate": ON_DEGENERATE},
               kinds=("range",), inputs=("anchors",))
def locate_gn(request: LocateRequest) -> pd.DataFrame:
    """Locate every ``(time, node)`` epoch from its ranges to the anchors.

    Each epoch with at least ``d + 1`` anchor ranges is solved independently; all epochs
    go through one batched :class:`Multilateration` call (missing anchor ranges are NaN).
    Ranges to other nodes are not used by this method. An epoch that does not fix the
    position (fewer than ``d + 1`` ranges, collinear anchors, a mirror fix that fits the
    ranges as well, a singular information matrix) stops the method with a
    :class:`GeometryError`, or, with ``-o on_degenerate=skip``, is left out of the output
    with one warning that counts such epochs by cause and names the first.

    Parameters
    ----------
    request : LocateRequest
        The parsed measurements, the anchors and the ``-o`` options.

    Returns
    -------
    DataFrame
        Columns ``time, node, x, y[, z], uncertainty_m``, the covariance columns and
        ``ranges`` (anchor ranges used), one row per epoch fixed; ``attrs["summary"]``:
        epochs, epochs skipped by cause, ``std_m`` and where it came from.

    Raises
    ------
    GeometryError
        An epoch has too few anchor ranges or a degenerate geometry (without
        ``on_degenerate=skip``); the message names the node and the time.
    """
    if "std_m" in request.options and "range_std_m" in request.options:
        raise ConfigError("method gn: give std_m or range_std_m (the same option), not both")
    std = request.option("std_m", request.option("range_std_m"))
    ep = range_epochs(request, "gn")
    R_ok, a_xyz = ep.R[ep.solvable], ep.points
    excluded, fde = np.zeros(R_ok.shape, dtype=bool), request.option("exclude_faults", False, bool)
    if fde:
        R_ok, excluded = _exclude_faults(R_ok, a_xyz, std)
    try:
        fit = solve_epochs(ep, R_ok, a_xyz, Multilateration(
            std_m=std, on_degenerate="flag" if ep.skip else "raise").locate)
    except GeometryError as exc:
        raise epoch_error(ep, exc) from None
    bad = np.asarray(fit.diagnostics["degenerate"])
    source, pooled = "option std_m", None
    if std is None and not bad.all():
        used = np.isfinite(R_ok).sum(axis=1)
        rms = np.asarray(fit.diagnostics["residual_rms_m"])
        pooled = {"sum_sq_m2": float(np.sum((rms ** 2 * used)[~bad])),
                  "dof": float(np.sum((used - a_xyz.shape[1])[~bad])), "epochs": int((~bad).sum())}
        std, source = pooled_std(pooled)
    cov = None if std is None else std ** 2 * _inverse_information(
        fit.position, a_xyz, np.isfinite(R_ok), bad)
    out = epoch_table(ep, fit.position, cov, bad, fit.diagnostics["ambiguous"],
                      ranges=np.isfinite(R_ok).sum(axis=1),
                      **({"excluded": excluded.sum(axis=1)} if fde else {}))
    out.attrs["summary"].update(std_m=std, std_m_from=source)
    if pooled is not None:
        out.attrs["summary"]["pooled"] = pooled
    if fde:
        out.attrs["summary"].update(rows_excluded=int(excluded.sum()), excluded_by_row={
            f"range {ep.ids[a]}": int(n) for a, n in enumerate(excluded.sum(axis=0)) if n})
    return out
