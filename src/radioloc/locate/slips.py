"""Likely slips in a log's values: a sign, a unit or an axis convention that makes the rows of
one kind fit no track, and that a tracker can name when it diverges.

:func:`slips` lists, per kind, the slips a log is known to make (tdoa as reference minus
peer, angles clockwise, pseudoranges in km or ns, odometry in mm or of the wrong sign) as the
map that undoes each, as each kind declares them (:class:`radioloc.core.kinds.Kind`). :func:`likely_slip` undoes them one at a time and asks the tracker
whether the log is consistent then: a slip is named only when the log as given diverges and
the log with that one kind's values mapped back does not, so a consistent log is never
blamed.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Collection

import numpy as np
import pandas as pd

from radioloc.core.errors import RadiolocError

def slips() -> list[tuple[tuple[str, ...], Callable[[np.ndarray], np.ndarray], str, str]]:
    """``(kinds, undo, how, question)`` of every slip the kinds declare
    (:attr:`radioloc.core.kinds.Kind.slips`): the rows of ``kinds`` whose values ``undo``
    maps back to what the schema means (``how`` says what it does), and the question that
    names the slip."""
    from radioloc.core.kinds import kinds

    return [(s.kinds or (k.name,), s.undo, s.how, s.question)
            for k in kinds().values() for s in k.slips]


#: Shrink factor of a slip's map (mm: 1000) beyond which a kind whose values passed their
#: input bound is not blamed (1000 times too large, they break it for any position).
BOUND_FACTOR = 1e3
#: A unit slip's map must bring the fixes' residual scale below this share of what
#: scaling the errors alone would (:func:`likely_slip`).
UNIT_GAIN = 0.5


def undo_slip(measurements: pd.DataFrame, kinds: tuple[str, ...],
              undo: Callable[[np.ndarray], np.ndarray]) -> pd.DataFrame:
    """The log with the values of the rows of ``kinds`` mapped by ``undo``.

    Parameters
    ----------
    measurements : DataFrame
        Columns ``kind`` and ``value`` at least.
    kinds : tuple of str
    undo : callable
        Elementwise map of the values.

    Returns
    -------
    DataFrame
        A copy.
    """
    rows = measurements["kind"].isin(kinds).to_numpy()
    value = measurements["value"].to_numpy(dtype=float).copy()
    value[rows] = undo(value[rows])
    return measurements.assign(value=value)


def slip_scale(undo: Callable[[np.ndarray], np.ndarray]) -> float:
    """The factor by which a slip's map scales the values (1 for a sign or a convention,
    1000 for mm, 0.3 for ns)."""
    return abs(float(undo(np.ones(1))[0] - undo(np.zeros(1))[0]))


def likely_slip(measurements: pd.DataFrame, consistent: Callable[[pd.DataFrame], bool], *,
                bounded: Collection[str] = (), scales: bool = True,
                fit_scale: Callable[[pd.DataFrame], float] | None = None
                ) -> tuple[str, str, str] | None:
    """The slip of :func:`slips` whose undoing makes a diverged log consistent.

    A slip whose map shrinks the values of a ``bounded`` kind by :data:`BOUND_FACTOR` or
    more (tdoa or pseudoranges in mm) is not tried: values that many times too large
    break the kind's bound for any position, which the log passed. With ``scales`` False
    no unit slip is tried (only signs and conventions): shrinking the values shrinks their
    errors too, so a log whose stated noise is too small would be blamed on a unit.

    Parameters
    ----------
    measurements : DataFrame
        The log as given (which the caller found inconsistent).
    consistent : callable
        ``consistent(log) -> bool``: the tracker's verdict on a log (no track diverged). An
        error the toolkit raises on a mapped log counts as not consistent.
    bounded : collection of str
        Kinds whose values passed their bound
        (:func:`radioloc.core.plausibility.check_values`).
    scales : bool
        Try the unit slips (maps that scale the values, :func:`slip_scale`).
    fit_scale : callable, optional
        ``fit_scale(log, kinds) -> float``: the residual scale of a log at fixes of each
        epoch on its own (NaN when the fixes do not read ``kinds``). Given, a unit slip of
        such kinds that scales the values by ``s`` is named only when its map brings that
        scale below ``UNIT_GAIN * s`` times the log's own: shrinking values shrinks their
        errors by ``s`` alone; a unit put right restores the geometry.

    Returns
    -------
    (kinds, how, question) or None
        The first kind(s) whose slip explains the divergence, what undoes it, and the
        question naming it;
        None when no single slip does.
    """
    present = set(measurements["kind"].unique())
    before: dict = {}                  # the log's own fit scale, by the kinds mapped
    for kinds, undo, how, question in slips():
        if not present.intersection(kinds):
            continue
        scale = slip_scale(undo)
        if set(kinds) <= set(bounded) and scale <= 1 / BOUND_FACTOR:
            continue
        if not scales and not np.isclose(scale, 1.0):
            continue
        mapped = undo_slip(measurements, kinds, undo)
        if fit_scale is not None and not np.isclose(scale, 1.0):
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                if kinds not in before:
                    before[kinds] = fit_scale(measurements, kinds)
                own = before[kinds]
                after = fit_scale(mapped, kinds) if np.isfinite(own) else np.nan
            if np.isfinite(own) and not after < UNIT_GAIN * scale * own:
                continue
        try:
            with warnings.catch_warnings(), np.errstate(all="ignore"):
                warnings.simplefilter("ignore")
                ok = consistent(mapped)
        except (RadiolocError, ArithmeticError):
            ok = False
        if ok:
            return " and ".join(kinds), how, question
    return None
