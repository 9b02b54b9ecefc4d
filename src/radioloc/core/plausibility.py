"""Plausibility of a positioning problem: anchor geometry and unit slips.

One check, shared by every ``radioloc locate`` method and usable by the library's
estimators, refuses inputs that are well-formed but cannot describe a real scene, with a
one-line message that names the likely cause:

=======================  ==========================================================================
check                  refused (or warned) when
=======================  ==========================================================================
``geometry``           the anchors ranged to (or heard by RSS rows) coincide, are collinear (2-D)
                       or coplanar (3-D): the position and its mirror image fit every range
                       equally (or every calibration reading of a fingerprint was taken at one
                       place)
``anchor_units``       the anchors look like lat/lon degrees (every ``|x|, |y| <= 180``, a span of
                       a fraction of a degree) while the ranges are metres, or while RSS rows
                       are located from them
``range_units``        the ranges break the triangle inequality with the anchors by a large
                       factor: ``|r_i - r_j|`` far above the anchor distance ``d_ij`` (ranges in
                       mm or cm, anchors in km) or ``r_i + r_j`` far below it (ranges in km)
``anchor_ranges``      the ranges to one anchor break the triangle inequality with the others by
                       more than the anchor distance (median over epochs and partners), while
                       the rest agree: its coordinates or id are wrong; or the median over all
                       pairs does (the ranges fit no position with these anchors)
``rss_units``          the median RSS (of the log, or of a fingerprint calibration) is >= 0 dBm
                       (received power of a milliwatt or more: RSS written in mW or W)
``time_units``         the median time step within a node exceeds the method's ``max_gap_s``
                       (time in milliseconds: every step would restart the track)
``time_order``         time goes backwards within a node (a warning that counts the rows; they
                       are used in time order)
``tdoa_units``         the time differences break ``|tdoa| <= d(peer, reference)`` by a large
                       factor (median over the rows): tdoa in mm, cm or ns
``pseudorange_units``  two pseudoranges of one epoch break ``|rho_i - rho_j| <= d_ij`` by a large
                       factor (median over the pairs): pseudoranges in mm, cm or ns
``angle_units``        the median magnitude of an ``aoa``, ``aoa_elevation`` or ``heading`` column
                       is beyond any angle in radians: angles in degrees
=======================  ==========================================================================

A user overrules a check with ``-o no_check=NAME[,NAME...]`` (or ``no_check=all``), which
every locate method accepts. The value checks (the last three) also guard the library: an
:class:`~radioloc.models.measurement.Observation` of a tdoa, pseudorange or angle model
applies :func:`check_values` to its values (its ``no_check`` overrules them).

The triangle test needs no assumption about where the node is: for any position,
``|r_i - r_j| <= d_ij <= r_i + r_j`` for the true ranges to anchors ``i, j``. Noise and NLOS
bias move single pairs across the bound by a fraction; the test uses the median over the
pairs of many epochs and a factor of :data:`RANGE_FACTOR`, so a log with correct units never
trips it. When no epoch ranges two anchors at once, the median range is compared with the
anchors' span instead.

The tdoa and pseudorange bounds need no position either: a range difference in metres is at
most the distance between its two anchors, ``|d(x, a_i) - d(x, a_ref)| <= d(a_i, a_ref)``,
and a pseudorange's clock offset cancels in the difference of two of one epoch. The
statistic is the median over the rows (pairs) of ``|difference| / max(d, 1 m)``
(:func:`difference_ratio`; at most 1 for exact values, about 0.3 for a tag inside the
anchors), refused beyond :data:`DIFFERENCE_FACTOR`. Noise and NLOS bias push single rows
across the bound, the median stays far below the factor; a single row beyond it is left to
the estimator's innovation gate or robust loss (an NLOS bias larger than the anchor
distance is possible, a log whose rows mostly show one is not). A slip by 1000 (mm) or 100
(cm) is refused for any scene; ns (3.34 times metres) only where the tag is mostly well
outside the anchors (a median ratio above 0.6 in metres); inside, it is left to
``ekf-track``'s divergence test (:mod:`radioloc.locate.slips`). Pseudoranges in km, or a tdoa of the wrong
sign, break no bound: they stay the tracker's to name. The angle bound is
:attr:`~radioloc.core.kinds.Kind.bound` of the kind (``2 pi``: either convention,
``[-pi, pi]`` or ``[0, 2 pi)``; ``pi / 2`` for an elevation) times :data:`ANGLE_FACTOR`, on the
median magnitude.

Degenerate anchor sets are refused by every method, static or tracking: a motion prior
carries a tracker through an epoch that sees too few anchors, but no prior resolves the
mirror ambiguity of a whole anchor set on one line (or plane). Methods that read node
priors (cooperative ``rls``, ``ekf``) skip the geometry check: the priors and the
node-to-node ranges fix what the anchors leave open.
"""

from __future__ import annotations

import warnings
from collections.abc import Collection
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:              # pandas loads where a log is checked, not with the models
    import pandas as pd

from radioloc.core.constants import SPEED_OF_LIGHT_M_PER_S
from radioloc.core.errors import ConfigError, GeometryError, InputError

#: The checks, by the name ``-o no_check=NAME`` uses.
CHECKS = {
    "geometry": "coincident, collinear (2-D) or coplanar (3-D) anchors",
    "anchor_units": "anchors in lat/lon degrees while ranges are metres",
    "range_units": "ranges impossible for the anchors' span (mm, cm or km)",
    "anchor_ranges": "the ranges to one anchor fit no position with the others (its id or "
                     "coordinates wrong)",
    "rss_units": "RSS at or above 0 dBm (written in mW or W)",
    "time_units": "median time step within a node above max_gap_s (milliseconds)",
    "time_order": "time going backwards within a node (warning)",
    "tdoa_units": "time differences beyond the distance of their two anchors (mm, cm or ns)",
    "pseudorange_units": "pseudorange differences within an epoch beyond the anchor distance "
                         "(mm, cm or ns)",
    "angle_units": "aoa, aoa_elevation or heading values beyond any angle in radians "
                   "(degrees)",
}


def value_checks() -> dict[str, str]:
    """The check of one kind's values (:func:`check_values`), by kind: each kind's
    :attr:`~radioloc.core.kinds.Kind.check` (:func:`radioloc.core.kinds.kinds`)."""
    from radioloc.core.kinds import kinds

    return {name: k.check for name, k in kinds().items() if k.check}


def known_checks() -> dict[str, str]:
    """:data:`CHECKS` and the checks the kinds declare, by name."""
    from radioloc.core.kinds import kinds

    extra = {k.check: f"{k.name} values beyond their bound (unit {k.unit})"
             for k in kinds().values() if k.check and k.check not in CHECKS}
    return {**CHECKS, **extra}


#: Median of ``|difference| / max(d, DIFFERENCE_FLOOR_M)`` (at most 1 for exact tdoa or
#: pseudorange differences) beyond which the rows are refused.
DIFFERENCE_FACTOR = 2.0
#: Anchor distances are floored here in the difference ratio: two anchors closer than the
#: noise of a difference would make noise look like a unit slip.
DIFFERENCE_FLOOR_M = 1.0
#: Median magnitude, as a multiple of its kind's bound (:attr:`radioloc.core.kinds.Kind.bound`:
#: ``2 pi`` for an azimuth in either convention, ``[-pi, pi]`` or ``[0, 2 pi)``, ``pi / 2``
#: for an elevation), beyond which a column is refused.
ANGLE_FACTOR = 1.25
#: Median triangle-inequality violation (as a factor) beyond which ranges are refused.
RANGE_FACTOR = 3.0
#: Smallest singular value ratio of the centred anchors below which they count as
#: collinear (2-D) or coplanar (3-D).
FLAT_RATIO = 1e-3
#: Median triangle-inequality ratio, ``max(|r_i - r_j| / d_ij, d_ij / (r_i + r_j))`` (at
#: most 1 for exact ranges), beyond which one anchor's ranges are refused.
ODD_FACTOR = 2.0
#: Epochs sampled (evenly) for the range statistics: bounds the work on long logs.
MAX_EPOCHS = 4000
_UNITS = ((1e3, "mm"), (1e2, "cm"), (1e-3, "km"))
#: Slips that lengthen a difference: mm, cm, ns (a time in ns is 1 / (c 1e-9) = 3.34 times
#: the distance in metres).
_DIFFERENCE_UNITS = ((1e3, "mm"), (1e2, "cm"), (1e9 / SPEED_OF_LIGHT_M_PER_S, "ns"))
#: Rows (pairs) sampled for the difference statistics.
MAX_ROWS = 2_000_000


def parse_skip(text: str | None) -> frozenset[str]:
    """The checks named by ``-o no_check=...``.

    Parameters
    ----------
    text : str or None
        Comma-separated check names, or ``all``.

    Returns
    -------
    frozenset of str

    Raises
    ------
    ConfigError
        An unknown name (the known ones are listed).
    """
    if text is None:
        return frozenset()
    names = {t.strip().lower() for t in str(text).split(",") if t.strip()}
    known = known_checks()
    if "all" in names:
        return frozenset(known)
    if bad := names - set(known):
        raise ConfigError(f"option no_check: unknown check(s) {', '.join(sorted(bad))}; known: "
                          f"{', '.join(known)}, all")
    return frozenset(names)


def _id_list(ids: list[str]) -> str:
    """`` (A1, A2, ...)``: the first eight ids, for a message."""
    return f" ({', '.join(ids[:8])}{', ...' if len(ids) > 8 else ''})"


def _hint(name: str) -> str:
    return f" (if this is right, overrule with -o no_check={name})"


def anchor_problem(anchors: np.ndarray, dim: int | None = None) -> tuple[str, str] | None:
    """Why an anchor set cannot fix a position, or None.

    Parameters
    ----------
    anchors : ndarray, shape (M, d)
        Anchor positions, d = 2 or 3.
    dim : int, optional
        Dimension of the positions sought (default d); 2 with 3-D anchors uses x, y only.

    Returns
    -------
    (kind, message) or None
        ``kind`` is "coincident", "collinear" or "coplanar"; None: the anchors fix a
        position.
    """
    a = np.asarray(anchors, dtype=float)
    d = a.shape[1] if dim is None else dim
    a = a[:, :d]
    m = a.shape[0]
    centred = a - a.mean(0)
    sv = np.linalg.svd(centred, compute_uv=False) if m > 1 else np.zeros(1)
    scale = max(float(np.abs(a).max(initial=0.0)), 1.0)
    if sv[0] <= 1e-9 * scale:
        return "coincident", f"the {m} anchor(s) ranged to coincide: any direction fits the ranges"
    if sv.size < d or sv[d - 1] <= FLAT_RATIO * sv[0]:
        shape = "collinear" if d == 2 else "coplanar"
        few = f" (only {m})" if m <= d else ""
        return shape, (f"the {m} anchors ranged to are {shape}{few}: the position and its mirror image "
                f"across them fit the ranges equally; {d + 1} anchors not "
                f"{'on one line' if d == 2 else 'in one plane'} are needed in {d}-D")
    return None


def _sample(R: np.ndarray, m: int) -> np.ndarray:
    """An even sample of the epochs: at most :data:`MAX_EPOCHS`, and at most about 2e6
    anchor pairs in all (bounds time and memory for many anchors)."""
    n = min(MAX_EPOCHS, max(16, int(2e6 // max(m * m, 1))))
    return R[np.linspace(0, R.shape[0] - 1, n).astype(int)] if R.shape[0] > n else R


def _span(a: np.ndarray) -> float:
    return float(np.max(np.linalg.norm(a[:, None, :] - a[None, :, :], axis=-1)))


def _looks_like_degrees(a: np.ndarray) -> bool:
    x, y = np.abs(a[:, 0]), np.abs(a[:, 1])
    in_range = (np.all(x <= 180) and np.all(y <= 90)) or (np.all(x <= 90) and np.all(y <= 180))
    return bool(in_range and _span(a[:, :2]) < 1.0 and np.abs(a[:, :2]).max() > 1.0)


def range_ratios(R: np.ndarray, anchors: np.ndarray) -> tuple[float, float] | None:
    """How ranges compare with the anchor distances (triangle inequality).

    Parameters
    ----------
    R : ndarray, shape (E, M)
        Ranges of E epochs to M anchors (NaN: no range).
    anchors : ndarray, shape (M, d)

    Returns
    -------
    (long, short) or None
        ``long``: the median of ``|r_i - r_j| / d_ij`` over the pairs of anchors ranged in
        one epoch (at most 1 for exact ranges); ``short``: the median of
        ``(r_i + r_j) / d_ij`` (at least 1). When no epoch ranges two anchors, both are the
        median range over the anchors' span. None: no finite range.
    """
    R = np.asarray(R, dtype=float)
    a = np.asarray(anchors, dtype=float)
    R = _sample(R, a.shape[0])
    span = _span(a)
    d = np.linalg.norm(a[:, None, :] - a[None, :, :], axis=-1)
    i, j = np.triu_indices(a.shape[0], 1)
    keep = d[i, j] > 1e-9 * max(span, 1e-300)
    i, j, dij = i[keep], j[keep], d[i, j][keep]
    ri, rj = R[:, i], R[:, j]
    ok = np.isfinite(ri) & np.isfinite(rj)
    if ok.any():
        return (float(np.median((np.abs(ri - rj) / dij)[ok])),
                float(np.median(((ri + rj) / dij)[ok])))
    finite = R[np.isfinite(R)]
    if finite.size == 0 or span == 0:
        return None
    ratio = float(np.median(finite)) / span
    return ratio, ratio


def odd_anchors(R: np.ndarray, anchors: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Anchors whose ranges fit no position together with the other anchors' ranges.

    For each anchor ``i`` the triangle-inequality ratio with each partner ``j`` in one
    epoch, ``max(|r_i - r_j| / max(d_ij, 1 m), d_ij / (r_i + r_j))`` (at most 1 for exact
    ranges); its median over epochs and partners above :data:`ODD_FACTOR` flags the anchor
    (noise and NLOS bias stay far below the anchor distance). Flags are kept only when a
    minority of the anchors has them (otherwise the cause is global, and ``overall``, the
    median over every pair, says so).

    Parameters
    ----------
    R : ndarray, shape (E, M)
        Ranges (NaN: absent).
    anchors : ndarray, shape (M, d)

    Returns
    -------
    flagged : ndarray of bool, shape (M,)
    score : ndarray, shape (M,)
        The median ratio of each anchor (NaN: no pair).
    overall : float
        The median ratio over every pair (0: no pair).
    """
    R = np.asarray(R, dtype=float)
    a = np.asarray(anchors, dtype=float)
    m = a.shape[0]
    R = _sample(R, a.shape[0])
    d = np.linalg.norm(a[:, None, :] - a[None, :, :], axis=-1)
    ri, rj = R[:, :, None], R[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        viol = np.maximum(np.abs(ri - rj) / np.maximum(d, 1.0), d / np.maximum(ri + rj, 1e-9))
    viol = np.where(np.eye(m, dtype=bool), np.nan, viol)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)      # an anchor with no pair: NaN
        score = np.nanmedian(viol.transpose(1, 0, 2).reshape(m, -1), axis=1) if R.size \
            else np.full(m, np.nan)
        overall = float(np.nanmedian(viol)) if np.isfinite(viol).any() else 0.0
    flagged = np.nan_to_num(score, nan=0.0) > ODD_FACTOR
    if m < 3 or 2 * flagged.sum() >= m:
        flagged[:] = False
    return flagged, score, overall


def range_scale(R: np.ndarray, anchors: np.ndarray) -> float | None:
    """The factor by which the ranges are off the anchors' scale: 1.0 when consistent.

    Parameters
    ----------
    R : ndarray, shape (E, M)
        Ranges of E epochs to M anchors (NaN: no range).
    anchors : ndarray, shape (M, d)

    Returns
    -------
    float or None
        1.0: the ranges fit the anchors (within :data:`RANGE_FACTOR`, or within
        ``10 RANGE_FACTOR`` when no unit explains the misfit); otherwise the unit factor
        (1e3, 1e2, 1e-3) that makes them fit, or the median violation when none does (above
        1: too long, below: too short). None: no finite range.
    """
    ratios = range_ratios(R, anchors)
    if ratios is None:
        return None
    long_, short = ratios
    if long_ == short:                               # one range per epoch: median / span
        if 1 / (10 * RANGE_FACTOR) <= long_ <= 10 * RANGE_FACTOR:
            return 1.0
        fits = [k for k, _ in _UNITS if 1 / (10 * RANGE_FACTOR) <= long_ / k <= 10 * RANGE_FACTOR]
        return min(fits, key=lambda k: abs(np.log(long_ / k / 0.5)), default=max(long_, 1e-300))
    if long_ <= RANGE_FACTOR and short >= 1 / RANGE_FACTOR:
        return 1.0
    for k, _ in _UNITS:
        if long_ / k <= 1.2 and short / k >= 1 / 1.2:
            return k
    # no unit explains it: refuse only a gross violation (a few NLOS-heavy or hand-made
    # epochs off by less are left to the method's own per-epoch checks)
    if long_ > 10 * RANGE_FACTOR:
        return long_
    if short < 1 / (10 * RANGE_FACTOR):
        return max(short, 1e-300)
    return 1.0


def check_ranges(R: np.ndarray, anchors: np.ndarray, *, dim: int | None = None,
                 skip: Collection[str] = (), where: str = "ranges",
                 ids: list[str] | None = None) -> None:
    """Refuse ranges and anchors that cannot describe one scene.

    Array form of the checks ``geometry``, ``anchor_units`` and ``range_units`` (see the
    module docstring), for library estimators and the locate methods alike.

    Parameters
    ----------
    R : ndarray, shape (E, M)
        Ranges (metres) of E epochs to the M anchors (NaN: absent).
    anchors : ndarray, shape (M, 2) or (M, 3)
        The anchors ranged to.
    dim : int, optional
        Dimension of the positions sought (default: the anchors').
    skip : collection of str
        Checks to leave out.
    where : str
        What the ranges are, for the message.
    ids : list of str, optional
        The anchors' names, for the message.

    Returns
    -------
    None

    Raises
    ------
    GeometryError
        Coincident, collinear or coplanar anchors.
    InputError
        Anchors in degrees, ranges in the wrong unit.
    """
    a = np.asarray(anchors, dtype=float)
    problem = anchor_problem(a, dim)
    if problem is not None and ids is not None:
        problem = problem[0], problem[1].replace(" ranged to", " ranged to" + _id_list(ids), 1)
    if problem is not None and problem[0] == "coincident" and "geometry" not in skip:
        raise GeometryError(f"{where}: {problem[1]}{_hint('geometry')}")
    factor = range_scale(R, a) if a.shape[0] > 0 else None
    if factor is not None and factor != 1.0:
        if factor > 1 and _looks_like_degrees(a) and "anchor_units" not in skip:
            raise InputError(
                f"{where}: anchors in degrees? They span {_span(a[:, :2]):.3g} with every "
                f"|x|, |y| <= 180, while the ranges are far too long for that span: give the "
                f"anchors in metres (a local east/north frame or UTM){_hint('anchor_units')}")
        if "range_units" not in skip:
            unit = dict(_UNITS).get(factor)
            side = "longer" if factor > 1 else "shorter"
            cause = {"mm": "ranges in mm (or anchors in km)?", "cm": "ranges in cm?",
                     "km": "ranges in km?"}.get(unit, "ranges or anchors in the wrong unit?")
            if factor < 1e-12:
                raise InputError(f"{where}: the ranges are (nearly) all 0 m while the anchors "
                                 f"are {_span(a):.3g} m apart{_hint('range_units')}")
            raise InputError(
                f"{where}: {cause} The ranges are about {max(factor, 1 / factor):.3g} times "
                f"{side} than anchors {_span(a):.3g} m apart allow (triangle inequality); "
                f"ranges and anchors must both be metres{_hint('range_units')}")
    if "anchor_ranges" not in skip and a.shape[0] >= 3:
        flagged, score, overall = odd_anchors(R, a)
        if flagged.any():
            k = np.flatnonzero(flagged)
            names = [ids[i] if ids is not None else f"#{i}" for i in k]
            raise InputError(
                f"{where}: the ranges to anchor(s) {', '.join(names)} fit no position with the "
                f"other anchors' ranges (they break the triangle inequality by a factor "
                f"{score[k[0]]:.3g}, median): wrong coordinates or id of that anchor?"
                f"{_hint('anchor_ranges')}")
        if overall > ODD_FACTOR:
            raise InputError(
                f"{where}: the ranges fit no position with these anchors (they break the "
                f"triangle inequality by a factor {overall:.3g}, median): "
                f"an anchors file of another site, or ranges of another unit?"
                f"{_hint('anchor_ranges')}")
    if problem is not None and "geometry" not in skip:
        raise GeometryError(f"{where}: {problem[1]}{_hint('geometry')}")


def check_rss_anchors(anchors: np.ndarray, *, dim: int | None = None,
                      skip: Collection[str] = (), where: str = "rss",
                      ids: list[str] | None = None) -> None:
    """Refuse the anchors of RSS rows that cannot fix a position: the checks ``geometry``
    (coincident, collinear or coplanar anchors: the RSS of a position and of its mirror
    image are the same) and ``anchor_units`` (anchors that look like lat/lon degrees,
    where a path loss model needs metres).

    Parameters
    ----------
    anchors : ndarray, shape (M, 2) or (M, 3)
        The anchors heard.
    dim : int, optional
        Dimension of the positions sought (default: the anchors').
    skip : collection of str
        Checks to leave out.
    where : str
        What the rows are, for the message.
    ids : list of str, optional
        The anchors' names, for the message.

    Returns
    -------
    None

    Raises
    ------
    GeometryError
        Coincident, collinear or coplanar anchors.
    InputError
        Anchors in degrees.
    """
    a = np.asarray(anchors, dtype=float)
    problem = anchor_problem(a, dim)
    if problem is not None and "geometry" not in skip:
        heard = " heard" + ("" if ids is None else _id_list(ids))
        problem = problem[0], f"{where}: " + problem[1].replace(" ranged to", heard, 1).replace(
            "fit the ranges", "fit the RSS") + _hint("geometry")
        if problem[0] == "coincident":
            raise GeometryError(problem[1])
    if a.shape[0] > 1 and _looks_like_degrees(a) and "anchor_units" not in skip:
        raise InputError(f"{where}: anchors in degrees? They span {_span(a[:, :2]):.3g} with "
                         "every |x|, |y| <= 180, too small a site for received signal "
                         "strength: give the anchors in metres (a local east/north frame or "
                         f"UTM){_hint('anchor_units')}")
    if problem is not None and "geometry" not in skip:
        raise GeometryError(problem[1])


def check_node_ranges(ranges: np.ndarray, prior_distance_m: np.ndarray, *,
                      skip: Collection[str] = (), where: str = "ranges") -> None:
    """Node-to-node ranges against the distances between the nodes' prior means.

    Priors are metres off, so only a gross misfit is refused: a median ratio of range to
    prior distance beyond ``10 RANGE_FACTOR`` either way (ranges in mm, cm or km).

    Parameters
    ----------
    ranges : ndarray, shape (K,)
        Measured ranges between nodes.
    prior_distance_m : ndarray, shape (K,)
        Distance between the two nodes' prior means, per range.
    skip : collection of str
        Checks to leave out (``range_units``).
    where : str
        For the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming the likely unit.
    """
    r, d = np.asarray(ranges, dtype=float), np.asarray(prior_distance_m, dtype=float)
    ok = np.isfinite(r) & (d > 0)
    if "range_units" in skip or not ok.any():
        return
    ratio = float(np.median(r[ok] / d[ok]))
    if 1 / (10 * RANGE_FACTOR) <= ratio <= 10 * RANGE_FACTOR:
        return
    _, unit = min(_UNITS, key=lambda u: abs(np.log(ratio / u[0])))
    cause = {"mm": "ranges in mm?", "cm": "ranges in cm?", "km": "ranges in km?"}[unit]
    raise InputError(f"{where}: {cause} The ranges between nodes are about "
                     f"{max(ratio, 1 / ratio):.3g} times {'longer' if ratio > 1 else 'shorter'} than the distances between "
                     f"their prior positions; ranges and priors must both be metres"
                     f"{_hint('range_units')}")


def check_rss(values: np.ndarray, *, skip: Collection[str] = (), where: str = "rss") -> None:
    """Refuse RSS values written in mW or W (median >= 0 dBm).

    Parameters
    ----------
    values : ndarray
        RSS values as given.
    skip : collection of str
        Checks to leave out (``rss_units``).
    where : str
        For the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        The median RSS is >= 0 dBm.
    """
    v = np.asarray(values, dtype=float)
    v = v[np.isfinite(v)]
    if v.size and "rss_units" not in skip and np.median(v) >= 0:
        raise InputError(f"{where}: RSS in mW? The median RSS is {np.median(v):.3g}, i.e. a "
                         "received power of 1 mW or more; RSS must be dBm (negative, e.g. -70)"
                         f"{_hint('rss_units')}")


def check_calibration(positions: np.ndarray, rss: np.ndarray, *, skip: Collection[str] = (),
                      where: str = "calibration") -> None:
    """A fingerprint calibration: RSS in dBm (``rss_units``), places apart (``geometry``).

    Parameters
    ----------
    positions : ndarray, shape (N, d)
        Where the calibration readings were taken.
    rss : ndarray, shape (N, S)
        The readings (NaN: not received).
    skip : collection of str
        Checks to leave out.
    where : str
        For the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        RSS in mW (median >= 0 dBm), or every reading taken at one place.
    """
    check_rss(rss, skip=skip, where=where)
    pos = np.asarray(positions, dtype=float)
    if "geometry" not in skip and pos.shape[0] > 0 and np.all(np.ptp(pos, axis=0) == 0):
        raise InputError(f"{where}: every calibration reading was taken at one place "
                         f"({', '.join(f'{v:g}' for v in pos[0])}): a fingerprint cannot tell "
                         f"places apart{_hint('geometry')}")


def _flat_rows(values: np.ndarray, *points: np.ndarray, limit: int
               ) -> tuple[np.ndarray, list[np.ndarray]] | None:
    """``values (..., m)`` and their points ``(..., m, D)`` broadcast and flattened to
    ``(E, m)`` and ``(E, m, D)``: an even sample of at most ``limit`` of the E epochs.
    None: the shapes do not broadcast (left to the model's own checks)."""
    v = np.asarray(values, dtype=float)
    pts = [np.asarray(p, dtype=float) for p in points]
    if v.ndim == 0 or any(p.ndim == 0 for p in pts):
        return None
    try:
        shape = np.broadcast_shapes(v.shape + pts[0].shape[-1:], *(p.shape for p in pts))
    except ValueError:
        return None
    lead = shape[:-2]
    vb = np.broadcast_to(v[..., None], shape)[..., 0]
    pb = [np.broadcast_to(p, shape) for p in pts]
    if not lead:
        return vb[None], [p[None] for p in pb]
    n = int(np.prod(lead))
    pick = np.linspace(0, n - 1, limit).astype(int) if n > limit else np.arange(n)
    idx = np.unravel_index(pick, lead)
    return vb[idx], [p[idx] for p in pb]


def difference_ratio(differences: np.ndarray, points: np.ndarray,
                     reference: np.ndarray) -> tuple[float, int, int] | None:
    """How range differences compare with the distance of their two anchors.

    Parameters
    ----------
    differences : ndarray, shape (...,)
        Range differences, metres (NaN: absent).
    points, reference : ndarray, shape (..., D)
        The two anchors of each difference.

    Returns
    -------
    (ratio, beyond, rows) or None
        ``ratio``: the median of ``|difference| / max(d, DIFFERENCE_FLOOR_M)`` (at most 1
        for exact differences); ``beyond``: how many rows break ``|difference| <= d``;
        ``rows``: the finite rows. None: no finite row.
    """
    z = np.asarray(differences, dtype=float)
    d = np.linalg.norm(np.asarray(points, dtype=float) - np.asarray(reference, dtype=float),
                       axis=-1)
    ok = np.isfinite(z)
    if not ok.any():
        return None
    z, d = np.abs(z[ok]), np.broadcast_to(d, ok.shape)[ok]
    return (float(np.median(z / np.maximum(d, DIFFERENCE_FLOOR_M))), int(np.sum(z > d)),
            int(z.size))


def _refuse_differences(stats: tuple[float, int, int] | None, name: str, what: str,
                        bound: str, rows: str, where: str, skip: Collection[str]) -> None:
    """Refuse differences whose median ratio exceeds :data:`DIFFERENCE_FACTOR`, naming the
    unit that explains the ratio (mm, cm, ns)."""
    if stats is None or name in skip or stats[0] <= DIFFERENCE_FACTOR:
        return
    ratio, beyond, count = stats
    fits = [(k, u) for k, u in _DIFFERENCE_UNITS if ratio / k <= 1.0]
    unit = min(fits, key=lambda f: abs(np.log(ratio / f[0] / 0.4)))[1] if fits else None
    cause = f"{what} in {unit}?" if unit else f"{what} in the wrong unit?"
    raise InputError(f"{where}: {cause} {bound} for any position, but the {rows} break it by "
                     f"a factor {ratio:.3g} (median; {beyond} of {count} beyond it): give "
                     f"{what} in metres, as the anchors{_hint(name)}")


def check_tdoa(tdoa: np.ndarray, points: np.ndarray, reference: np.ndarray, *,
               skip: Collection[str] = (), where: str = "tdoa") -> None:
    """Refuse time differences in another unit than metres (check ``tdoa_units``).

    A range difference obeys ``|tdoa| <= d(peer, reference)`` for any position; the median
    of ``|tdoa| / max(d, 1 m)`` over the rows beyond :data:`DIFFERENCE_FACTOR` is a unit
    slip (see the module docstring).

    Parameters
    ----------
    tdoa : ndarray, shape (..., m)
        Range to the row's anchor minus range to its reference anchor, metres (NaN: absent).
    points : ndarray, shape (..., m, D)
        The rows' anchors (broadcast against ``tdoa``).
    reference : ndarray, shape (..., m, D)
        The rows' reference anchors.
    skip : collection of str
        Checks to leave out (``tdoa_units``).
    where : str
        What the values are, for the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming the likely unit (mm, cm, ns).
    """
    if "tdoa_units" in skip:
        return
    flat = _flat_rows(tdoa, points, reference,
                      limit=max(16, MAX_ROWS // max(np.shape(tdoa)[-1:] or (1,))))
    if flat is None:
        return
    z, (p, r) = flat
    _refuse_differences(difference_ratio(z, p, r), "tdoa_units", "tdoa values",
                        "A time difference obeys |tdoa| <= d(peer, reference)", "rows", where,
                        skip)


def check_pseudoranges(pseudoranges: np.ndarray, points: np.ndarray, *,
                       skip: Collection[str] = (), where: str = "pseudoranges") -> None:
    """Refuse pseudoranges in another unit than metres (check ``pseudorange_units``).

    Within one epoch the receiver's clock offset cancels: ``|rho_i - rho_j| <= d_ij`` for
    any position and offset; the median of ``|rho_i - rho_j| / max(d_ij, 1 m)`` over the
    pairs of every epoch beyond :data:`DIFFERENCE_FACTOR` is a unit slip. Pseudoranges in
    km shrink the differences: no bound tells them from a node equidistant from the anchors.

    Parameters
    ----------
    pseudoranges : ndarray, shape (..., m)
        The m pseudoranges of each epoch, metres (NaN: absent).
    points : ndarray, shape (..., m, D)
        Their anchors (broadcast against ``pseudoranges``).
    skip : collection of str
        Checks to leave out (``pseudorange_units``).
    where : str
        For the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        Naming the likely unit (mm, cm, ns).
    """
    m = np.shape(pseudoranges)[-1] if np.ndim(pseudoranges) else 0
    if "pseudorange_units" in skip or m < 2:
        return
    flat = _flat_rows(pseudoranges, points, limit=max(16, MAX_ROWS // (m * m)))
    if flat is None:
        return
    z, (p,) = flat
    i, j = np.triu_indices(m, 1)
    _refuse_differences(difference_ratio(z[:, i] - z[:, j], p[:, i], p[:, j]),
                        "pseudorange_units", "pseudoranges",
                        "Two pseudoranges of one epoch obey |rho_i - rho_j| <= d_ij",
                        "pairs of rows", where, skip)


def check_angles(values: np.ndarray, kind: str = "aoa", *, skip: Collection[str] = (),
                 where: str | None = None) -> None:
    """Refuse values beyond their kind's bound (its check, ``angle_units`` for the angles):
    angles in degrees.

    An angle in radians is within the :attr:`~radioloc.core.kinds.Kind.bound` of its kind
    (``2 pi``, ``pi / 2`` for an elevation); a column whose median magnitude exceeds
    :data:`ANGLE_FACTOR` times that bound is in degrees (one in a few degrees either way
    cannot be told).

    Parameters
    ----------
    values : ndarray
        Values of one kind (NaN: absent).
    kind : str
        A kind with a bound (``aoa``, ``aoa_elevation``, ``heading``).
    skip : collection of str
        Checks to leave out (``angle_units``).
    where : str, optional
        For the message (default: the kind).

    Returns
    -------
    None

    Raises
    ------
    InputError
        The median magnitude is beyond the bound.
    """
    from radioloc.core.kinds import kinds

    bounded = {n: k for n, k in kinds().items() if k.bound is not None}
    if kind not in bounded:
        raise ConfigError(f"kind: expected one of {', '.join(bounded)}, got {kind!r}")
    declared = bounded[kind]
    if declared.check in skip:
        return
    v = np.abs(np.asarray(values, dtype=float))
    v = v[np.isfinite(v)]
    bound = declared.bound
    if not v.size or np.median(v) <= ANGLE_FACTOR * bound:
        return
    unit = {"rad": "radians"}.get(declared.unit, declared.unit)
    cause = (f"{kind} values in degrees?" if declared.unit == "rad" and v.max() <= 360.0
             else f"{kind} values not in {unit}?")
    limit = {2 * np.pi: "2 pi", np.pi / 2: "pi / 2"}.get(bound, f"{bound:g}")
    raise InputError(f"{where or kind}: {cause} Their median magnitude is "
                     f"{float(np.median(v)):.3g}, beyond any {kind} in {unit} (|{kind}| <= "
                     f"{limit}; {int(np.sum(v > bound))} of "
                     f"{v.size} values beyond it): give {unit}{_hint(declared.check)}")


def check_values(kind: str, values: np.ndarray, points: np.ndarray | None = None,
                 reference: np.ndarray | None = None, *, skip: Collection[str] = (),
                 where: str | None = None) -> None:
    """The check of one measurement kind's values, as its declaration
    (:class:`~radioloc.core.kinds.Kind`) gives it: its ``check_values`` (``tdoa_units``,
    ``pseudorange_units``: they need the rows' anchors), else the bound of its values
    (``angle_units``); kinds that declare neither have none here.

    Parameters
    ----------
    kind : str
        The measurement kind.
    values : ndarray, shape (..., m)
        Its values (NaN: absent).
    points : ndarray, shape (..., m, D), optional
        Each row's anchor (tdoa, pseudorange; without them those checks are left out).
    reference : ndarray, shape (..., m, D), optional
        Each tdoa row's reference anchor.
    skip : collection of str
        Checks to leave out.
    where : str, optional
        What the values are, for the message (default: the kind).

    Returns
    -------
    None

    Raises
    ------
    InputError
        A unit slip, named.
    """
    from radioloc.core.kinds import kinds

    declared = kinds().get(kind)
    if declared is None or declared.check is None:
        return
    where = where or kind
    if declared.check_values is not None:
        if points is not None and (reference is not None or not declared.reference):
            declared.check_values(values, points, reference, skip=skip, where=where)
    elif declared.bound is not None:
        check_angles(values, kind, skip=skip, where=where)


def _epoch_matrix(rows: pd.DataFrame, ids: list[str]) -> np.ndarray:
    """Values (ranges, pseudoranges) as an (epochs, anchors) array, one row per (node, time);
    NaN: absent."""
    import pandas as pd
    node = pd.factorize(rows["node"])[0]
    time = rows["time"].to_numpy(dtype=float)
    order = np.lexsort((time, node))
    ts, ns = time[order], node[order]
    new = np.r_[True, (ts[1:] != ts[:-1]) | (ns[1:] != ns[:-1])]
    epoch = np.empty(order.size, dtype=np.int64)
    epoch[order] = np.cumsum(new) - 1
    peer, distinct = pd.factorize(rows["peer"])
    col = pd.Index(ids).get_indexer(distinct)[peer]
    n = int(epoch.max()) + 1
    if n > MAX_EPOCHS:                          # keep an even sample of the epochs
        pick = np.zeros(n, bool)
        pick[np.linspace(0, n - 1, MAX_EPOCHS).astype(int)] = True
        sel = pick[epoch]
        epoch = np.cumsum(pick)[epoch[sel]] - 1
        col, value = col[sel], rows["value"].to_numpy(dtype=float)[sel]
        n = MAX_EPOCHS
    else:
        value = rows["value"].to_numpy(dtype=float)
    R = np.full((n, len(ids)), np.nan)
    R[epoch, col] = value
    return R


def check_time(measurements: pd.DataFrame, *, max_gap_s: float | None = None,
               skip: Collection[str] = (), where: str = "measurements") -> None:
    """Time stamps: milliseconds for a tracker's ``max_gap_s`` (refused), time going backwards
    within a node (one warning that counts the rows).

    Parameters
    ----------
    measurements : DataFrame
        ``time, node`` and ``line`` (file order).
    max_gap_s : float, optional
        The method's gap that restarts a track (None: the method does not use time).
    skip : collection of str
        Checks to leave out (``time_units``, ``time_order``).
    where : str
        For the message.

    Returns
    -------
    None

    Raises
    ------
    InputError
        The median step within a node exceeds ``max_gap_s``.
    """
    import pandas as pd
    frame = measurements
    if "line" in frame.columns and not frame["line"].is_monotonic_increasing:
        frame = frame.sort_values("line", kind="stable")
    node, names = pd.factorize(frame["node"])
    time = frame["time"].to_numpy(dtype=float)
    order = np.argsort(node, kind="stable")          # file order within each node
    code_s, time_s = node[order], time[order]
    same = code_s[1:] == code_s[:-1]
    if "time_order" not in skip and same.any():
        running = pd.Series(time_s).groupby(code_s).cummax().to_numpy()
        back = np.zeros(time_s.size, bool)
        back[1:] = same & (time_s[1:] < running[:-1])
        if back.any():
            k = int(np.flatnonzero(back)[0])
            line = (float(frame["line"].to_numpy(dtype=float)[order[k]])
                    if "line" in frame.columns else np.nan)
            first = f"line {int(line)}" if np.isfinite(line) else f"row {int(order[k])}"
            warnings.warn(f"{where}: {int(back.sum())} row(s) go back in time within their node "
                          f"(first: {first}, node {names[code_s[k]]!r}, time "
                          f"{time_s[k]:g} after {running[k - 1]:g}); they are used in time order",
                          stacklevel=3)
    if max_gap_s is None or "time_units" in skip:
        return
    srt = np.lexsort((time, node))
    ts, ns = time[srt], node[srt]
    step = np.diff(ts)[(ns[1:] == ns[:-1]) & (ts[1:] != ts[:-1])]  # between distinct times
    if step.size and np.median(step) > max_gap_s:
        med = float(np.median(step))
        guess = "time in milliseconds? " if med / 1000 <= max_gap_s else ""
        raise InputError(f"{where}: {guess}The median time step within a node is {med:.3g} s, "
                         f"above max_gap_s = {max_gap_s:g} s, so every step would restart the "
                         "track; give time in seconds (or raise -o max_gap_s)"
                         f"{_hint('time_units')}")


def check_log(measurements: pd.DataFrame, anchors: pd.DataFrame | None, *,
              kinds: Collection[str] | None = None, dim: int | None = None,
              max_gap_s: float | None = None, geometry: bool = True,
              fixed_anchors: bool = True, skip: Collection[str] = ()) -> None:
    """Every plausibility check of a user's log (see the module docstring).

    Parameters
    ----------
    measurements : DataFrame
        From :func:`radioloc.io.read_measurements`.
    anchors : DataFrame or None
        From :func:`radioloc.io.read_anchors`.
    kinds : collection of str, optional
        Measurement kinds the method uses (None: all present).
    dim : int, optional
        Dimension of the positions sought (default: the anchors').
    max_gap_s : float, optional
        The method's track-restart gap, for ``time_units``.
    geometry : bool
        Check the anchor geometry (False for methods whose node priors fix it).
    fixed_anchors : bool
        False: the anchors move (``anchors`` holds each one's first position), so the tdoa
        and pseudorange bounds, which need the anchors where they were at each row, are
        left out.
    skip : collection of str
        Checks to leave out.

    Returns
    -------
    None

    Raises
    ------
    GeometryError, InputError
        One line naming the likely cause and the option that overrules it.
    """
    from radioloc.core.kinds import kinds as all_kinds

    kinds = set(measurements["kind"].unique()) if kinds is None else set(kinds)
    check_time(measurements, max_gap_s=max_gap_s, skip=skip)
    if "rss" in kinds:
        rss = measurements.loc[measurements["kind"] == "rss", "value"]
        if len(rss):
            check_rss(rss.to_numpy(), skip=skip, where="measurements")
    kind_of = measurements["kind"]
    for kind in sorted(kinds & {n for n, k in all_kinds().items() if k.bound is not None}):
        check_angles(measurements.loc[kind_of == kind, "value"].to_numpy(), kind, skip=skip,
                     where="measurements")
    if anchors is None:
        return
    cols = ["x", "y"] + (["z"] if "z" in anchors.columns else [])
    placed = anchors.set_index("id")[cols]
    known = measurements["peer"].isin(placed.index)
    if "tdoa" in kinds and fixed_anchors and "reference" in measurements.columns:
        rows = measurements[(kind_of == "tdoa") & known
                            & measurements["reference"].isin(placed.index)]
        if not rows.empty:
            check_tdoa(rows["value"].to_numpy(dtype=float),
                       placed.loc[rows["peer"]].to_numpy(dtype=float),
                       placed.loc[rows["reference"]].to_numpy(dtype=float), skip=skip,
                       where="measurements")
    if "pseudorange" in kinds and fixed_anchors:
        rows = measurements[(kind_of == "pseudorange") & known]
        if not rows.empty:
            ids = sorted(rows["peer"].unique())
            check_pseudoranges(_epoch_matrix(rows, ids),
                               placed.loc[ids].to_numpy(dtype=float), skip=skip,
                               where="measurements")
    rows = measurements[(kind_of == "rss") & known]
    if "rss" in kinds and not rows.empty:
        ids = sorted(rows["peer"].unique())
        check_rss_anchors(placed.loc[ids].to_numpy(dtype=float), dim=dim, where="measurements",
                          ids=ids, skip=set(skip) | (set() if geometry else {"geometry"}))
    rows = measurements[(kind_of == "range") & known]
    if "range" not in kinds or rows.empty:
        return
    ids = sorted(rows["peer"].unique())
    pos = placed.loc[ids].to_numpy(dtype=float)
    R = _epoch_matrix(rows, ids)
    check_ranges(R, pos, dim=dim, where="measurements", ids=ids,
                 skip=set(skip) | (set() if geometry else {"geometry"}))
