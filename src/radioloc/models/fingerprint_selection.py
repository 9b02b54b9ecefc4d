"""Settings of the shared-place fingerprint model chosen by grouped cross-validation on the
calibration data only.

The temperature ``T``, the number of places kept ``M`` (:func:`place_weights`) and the
shrinkage ``lam`` of :meth:`FingerprintMixture.fit` depend on the building, the devices and
how densely the calibration was taken, so no fixed value carries over between sets. They are
chosen per calibration file by one rule: the candidate grid is evaluated by cross-validation
whose folds are groups of *spatial blocks* (squares of side ``block_m`` within each zone), so
that a held-out scan never has a calibration scan from a neighbouring spot (the same place,
or the next points of the same walk) in its training folds; the candidate with the lowest
mean 2-D error wins (ties: the first in grid order). Nothing of the test data is used.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from itertools import product as grid

import numpy as np
import pandas as pd

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.validation import as_float_array
from radioloc.models.fingerprint_mixture import FingerprintMixture, place_weights

__all__ = ["PlacesSettings", "select_knn_k", "select_places_settings", "spatial_folds"]

#: default candidate grid (our choice): temperatures, places kept (0 = all), shrinkage
TEMPERATURES = (1.0, 2.0, 4.0, 8.0)
TOP_PLACES = (5, 10, 20, 0)
SHRINKS = (1.0, 5.0)
#: default candidate ``k`` of (weighted) kNN (our choice)
KNN_KS = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20)


@dataclass(frozen=True)
class PlacesSettings:
    """The chosen settings and the cross-validation table.

    Attributes
    ----------
    temperature : float
        ``T``.
    top_places : int or None
        ``M`` (None = every place of the zone).
    shrink : float
        ``lam`` of :meth:`FingerprintMixture.fit`.
    table : pandas.DataFrame
        Columns ``temperature, top_places, shrink, cv_mean_error_m``, one row per candidate.
    """

    temperature: float
    top_places: int | None
    shrink: float
    table: pd.DataFrame = field(repr=False)


def spatial_folds(positions: np.ndarray, zones: np.ndarray, folds: int, block_m: float,
                  seed: int = 0) -> np.ndarray:
    """Fold of every scan: squares of side ``block_m`` (per zone) dealt to ``folds`` folds
    in a random order (``seed``), so neighbouring scans share a fold.

    Parameters
    ----------
    positions : ndarray, shape (N, D)
        Calibration positions, metres.
    zones : ndarray of int, shape (N, L)
        Zone labels (L may be 0).
    folds : int
        Number of folds (>= 2).
    block_m : float
        Side of the blocks, metres (> 0).
    seed : int
        Seed of the order in which blocks are dealt.

    Returns
    -------
    ndarray of int, shape (N,)
    """
    cell = np.floor(positions / block_m)
    _, block = np.unique(np.c_[zones, cell], axis=0, return_inverse=True)
    block = block.ravel()
    order = np.random.default_rng(seed).permutation(block.max() + 1)
    return order[block] % folds


def _checked_folds(pos: np.ndarray, zones: np.ndarray, folds: int, block_m: float,
                   seed: int) -> tuple[int, np.ndarray]:
    """The number of folds (at most the blocks) and the fold of every scan, after the checks
    of ``folds`` and ``block_m`` (:class:`ConfigError` naming the setting)."""
    if isinstance(folds, bool) or int(folds) != folds or folds < 2:
        raise ConfigError(f"folds: must be an integer >= 2, got {folds!r}")
    if not np.isfinite(block_m) or block_m <= 0:
        raise ConfigError(f"block_m: must be a finite number > 0, got {block_m!r}")
    blocks = np.unique(np.c_[zones, np.floor(pos / block_m)], axis=0).shape[0]
    if blocks < 2:
        raise ConfigError(f"block_m: the calibration spans one spatial block of {block_m:g} m; "
                          "cross-validation needs two or more")
    folds = min(int(folds), blocks)
    return folds, spatial_folds(pos, zones, folds, float(block_m), seed)


def select_knn_k(positions, rss, *, ks=KNN_KS, weights: str = "distance",
                 missing_dbm: float = -100.0, folds: int = 5, block_m: float = 3.0,
                 seed: int = 0) -> tuple[int, pd.DataFrame]:
    """Choose ``k`` of (weighted) kNN by the rule of :func:`select_places_settings`: the
    same spatially grouped folds, the lowest mean 2-D error (ties: the first ``k``).

    Parameters
    ----------
    positions : array_like, shape (N, D)
        Calibration positions, metres.
    rss : array_like, shape (N, S)
        Calibration signal strengths, dBm, NaN = not detected (read as ``missing_dbm``).
    ks : sequence of int
        Candidate ``k`` (each >= 1).
    weights : {"distance", "uniform"}
        scikit-learn's ``KNeighborsRegressor`` weights.
    missing_dbm : float
        Value of a not detected station.
    folds, block_m, seed
        As :func:`select_places_settings`.

    Returns
    -------
    k : int
        The chosen ``k``.
    table : pandas.DataFrame
        Columns ``k, cv_mean_error_m``, one row per candidate.

    Raises
    ------
    ConfigError
        No candidate, a ``k`` below 1, ``folds`` < 2, ``block_m`` <= 0, a calibration within
        one block.
    InputError
        ``rss`` rows not matching ``positions``.
    """
    from sklearn.neighbors import KNeighborsRegressor

    pos = as_float_array(positions, "positions", ndim=2)
    m = as_float_array(rss, "rss", ndim=2, allow_nan=True)
    if m.shape[0] != pos.shape[0]:
        raise InputError(f"rss: {m.shape[0]} rows, positions {pos.shape[0]}")
    ks = [int(k) for k in ks]
    if not ks or min(ks) < 1:
        raise ConfigError(f"ks: needs candidates >= 1, got {ks!r}")
    folds, fold = _checked_folds(pos, np.zeros((pos.shape[0], 0), np.int64), folds, block_m,
                                 seed)
    x = np.nan_to_num(m, nan=missing_dbm)
    err = np.zeros(len(ks))
    for f in range(folds):
        tr, te = fold != f, fold == f
        for i, k in enumerate(ks):
            knn = KNeighborsRegressor(n_neighbors=min(k, int(tr.sum())), weights=weights)
            est = knn.fit(x[tr], pos[tr]).predict(x[te])
            err[i] += np.linalg.norm(est - pos[te], axis=1).sum()
    table = pd.DataFrame({"k": ks, "cv_mean_error_m": err / pos.shape[0]})
    return ks[int(np.argmin(err))], table


def select_places_settings(positions, rss, zones=None, zone_names=(), *,
                           temperatures=TEMPERATURES, top_places=TOP_PLACES, shrinks=SHRINKS,
                           folds: int = 5, block_m: float = 3.0, seed: int = 0,
                           **fit_options) -> PlacesSettings:
    """Choose ``T``, ``M`` and ``lam`` by spatially grouped cross-validation.

    Parameters
    ----------
    positions : array_like, shape (N, D)
        Calibration positions, metres.
    rss : array_like, shape (N, S)
        Calibration signal strengths, dBm, NaN = not detected.
    zones : array_like of int, shape (N, L), optional
        Zone labels (as for :meth:`FingerprintMixture.fit`).
    zone_names : tuple of str
        Names of the zone levels.
    temperatures, top_places, shrinks : sequences
        The candidate grid (``top_places`` 0 = every place).
    folds : int
        Folds (>= 2; blocks are dealt to them; fewer when there are fewer blocks).
    block_m : float
        Side of the spatial blocks, metres.
    seed : int
        Seed of the fold assignment.
    **fit_options
        Further settings of :meth:`FingerprintMixture.fit` (``alpha``, ``var_min_db2``, ...).

    Returns
    -------
    PlacesSettings

    Raises
    ------
    ConfigError
        An empty grid, ``folds`` < 2, ``block_m`` <= 0, a calibration within one block.
    InputError
        Shapes (as :meth:`FingerprintMixture.fit`).
    """
    pos = as_float_array(positions, "positions", ndim=2)
    m = as_float_array(rss, "rss", ndim=2, allow_nan=True)
    if m.shape[0] != pos.shape[0]:
        raise InputError(f"rss: {m.shape[0]} rows, positions {pos.shape[0]}")
    n = pos.shape[0]
    z = np.zeros((n, 0), np.int64) if zones is None else np.asarray(zones).reshape(n, -1)
    if not (len(temperatures) and len(top_places) and len(shrinks)):
        raise ConfigError("temperatures, top_places, shrinks: each needs a candidate")
    folds, fold = _checked_folds(pos, z, folds, block_m, seed)
    err = np.zeros((len(shrinks), len(temperatures), len(top_places)))
    for f in range(folds):
        tr, te = fold != f, fold == f
        for i, lam in enumerate(shrinks):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", UserWarning)   # APs dropped in a fold
                model = FingerprintMixture.fit(pos[tr], m[tr], z[tr], tuple(zone_names),
                                               shrink=float(lam), **fit_options)
            ll = model.loglik(m[te])
            for (j, t), (k, top) in grid(enumerate(temperatures), enumerate(top_places)):
                w, _ = place_weights(model, ll, float(t), int(top) or None)
                err[i, j, k] += np.linalg.norm(w @ model.positions - pos[te], axis=1).sum()
    err /= n
    rows = [{"temperature": float(t), "top_places": int(top), "shrink": float(lam),
             "cv_mean_error_m": err[i, j, k]}
            for (i, lam), (j, t), (k, top) in grid(enumerate(shrinks), enumerate(temperatures),
                                                   enumerate(top_places))]
    table = pd.DataFrame(rows)
    best = table.iloc[int(np.argmin(table["cv_mean_error_m"].to_numpy()))]
    return PlacesSettings(float(best["temperature"]), int(best["top_places"]) or None,
                          float(best["shrink"]), table)
