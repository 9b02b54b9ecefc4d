"""Fault detection and exclusion for snapshot fixes (receiver autonomous integrity
monitoring's residual test).

Each fix of a batch is tested by the sum of its squared standardised residuals against the
chi-square point of probability ``probability`` with as many degrees of freedom as rows beyond
the unknowns. A fix that fails has its worst row (largest standardised residual) left out
and is fitted again, as long as the rows left keep at least one more than the unknowns (the
fix stays determined and testable); the rows left out are returned.

The fit is any snapshot estimator's, given as a function of the observations (NaN rows are
missing): :class:`~radioloc.estimators.least_squares.LeastSquares`, a multilateration.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable, Sequence

import numpy as np
from scipy.special import gammaincinv

from radioloc.core.results import Estimate
from radioloc.estimators.observation_rows import RowStack, layout_for
from radioloc.models.measurement import Observation

__all__ = ["exclude_faults", "standardised_residuals"]



def chi2_quantile(probability: float, dof) -> np.ndarray:
    """The chi-square quantile ``probability`` for ``dof`` degrees of freedom
    (``scipy.special``: lighter to import than ``scipy.stats``)."""
    return 2.0 * gammaincinv(np.asarray(dof, dtype=float) / 2.0, probability)


def _take_fixes(observations: list[Observation], fixes: np.ndarray) -> list[Observation]:
    """The observations of the fixes ``fixes`` (a mask over the batch) as one batch axis:
    each fix is fitted on its own, so a trial exclusion refits only the fixes it changes."""
    def pick(a, tail):
        if a is None or np.ndim(a) == tail:
            return a
        a = np.asarray(a)
        return np.broadcast_to(a, fixes.shape + a.shape[a.ndim - tail:])[fixes]

    out = []
    for o in observations:
        c = o.context
        context = replace(c, points=pick(c.points, 2), reference=pick(c.reference, 2),
                          std=pick(c.std, 1))
        out.append(replace(o, z=pick(o.z, 1), std=pick(o.std, 1), context=context))
    return out


def standardised_residuals(observations: Sequence[Observation], estimate: Estimate) -> np.ndarray:
    """``(z - h(x) - noise mean) / std`` of every row at each fix, stacked ``(..., M)``.

    Parameters
    ----------
    observations : sequence of Observation
        Values ``(..., m)``.
    estimate : Estimate
        Its ``diagnostics["state"]`` when it has one (clock, biases), else its position.

    Returns
    -------
    ndarray, shape (..., M)
        NaN where a row is missing.
    """
    obs = list(observations)
    layout = layout_for(obs)
    state = estimate.diagnostics.get("state")
    if state is None or np.shape(state)[-1] != layout.size:
        state = np.asarray(estimate.position, dtype=float)
    rows = RowStack(obs, layout, "linear", 1.0)
    with np.errstate(all="ignore"):
        r, _ = rows.residuals(np.asarray(state, dtype=float))
        return rows.standardised(state, r)


def exclude_faults(fit: Callable[[list[Observation]], Estimate],
                   observations: Sequence[Observation], *, probability: float = 0.999,
                   max_excluded: int | None = None) -> tuple[Estimate, list[np.ndarray], np.ndarray]:
    """Fit, test each fix's residuals, leave out the worst row of each failing fix, refit.

    Parameters
    ----------
    fit : callable
        ``fit(observations) -> Estimate`` over the batch (NaN rows missing).
    observations : sequence of Observation
        Values ``z`` ``(..., m)``: one fix per batch entry.
    probability : float
        Of the chi-square point a fix must stay below.
    max_excluded : int, optional
        Most rows left out of one fix (default: as many as keep it testable).

    Returns
    -------
    estimate : Estimate
        The last fit.
    excluded : list of ndarray of bool
        Per observation, the rows left out (shape of its ``z``).
    failing : ndarray of bool
        Fixes that still fail the test with no row left to exclude.
    """
    obs = list(observations)
    unknowns = layout_for(obs).size
    excluded = [np.zeros(np.shape(o.z), dtype=bool) for o in obs]
    slots = [(i, s) for i, o in enumerate(obs) for s in range(np.shape(o.z)[-1])]

    def attempt(mask, fixes=None):
        current = [replace(o, z=np.where(ex, np.nan, o.z)) for o, ex in zip(obs, mask)]
        if fixes is not None:
            current = _take_fixes(current, fixes)
        estimate = fit(current)
        u = standardised_residuals(current, estimate)
        used = np.isfinite(u)
        spare = used.sum(-1) - unknowns
        ratio = (np.where(used, u, 0.0) ** 2).sum(-1) / chi2_quantile(probability, np.maximum(spare, 1))
        ok = np.all(np.isfinite(estimate.position), -1) & ~np.asarray(
            estimate.diagnostics.get("degenerate", False))
        return estimate, spare, np.where(ok, ratio, np.inf), u

    estimate, spare, ratio, u = attempt(excluded)
    rounds = 0
    stuck = np.zeros(np.shape(spare), dtype=bool)     # no row whose leaving out fits
    while True:
        failing = (spare >= 1) & (ratio > 1)
        can = failing & (spare >= 2) & ~stuck
        if max_excluded is not None:
            can &= rounds < max_excluded
        if not can.any():
            return estimate, excluded, failing
        # the row whose leaving out fits best (robust to a fault that hides behind another)
        best, best_ratio = np.full(can.shape, -1), np.full(can.shape, np.inf)
        for k, (i, s) in enumerate(slots):
            present = np.isfinite(obs[i].z[..., s]) & ~excluded[i][..., s]
            trial = can & present
            if not trial.any():
                continue
            mask = [ex.copy() for ex in excluded]
            mask[i][..., s] |= trial
            if trial.ndim:
                r = np.full(trial.shape, np.inf)
                r[trial] = attempt(mask, trial)[2]
            else:
                r = attempt(mask)[2]
            better = trial & (r < best_ratio)
            best, best_ratio = np.where(better, k, best), np.where(better, r, best_ratio)
        # no subset fits (the fit fails with two faults in): the largest residual goes
        worst = np.argmax(np.where(np.isfinite(u), np.abs(u), -1.0), axis=-1)
        fallback = can & ~np.isfinite(best_ratio)
        best = np.where(fallback, worst, best)
        stuck |= fallback & ~np.any(np.isfinite(u), axis=-1)
        for k, (i, s) in enumerate(slots):
            excluded[i][..., s] |= can & ~stuck & (best == k)
        estimate, spare, ratio, u = attempt(excluded)
        rounds += 1
