"""Highway scenario of paper 001, Sect. V and Fig. 4.

N vehicles start at random points near the left end of a ``length x width`` road and move
right by a constant ``speed_m`` per step with a smooth vertical curve
``y = y0 + A sin(2 pi (x - x0) / period)``; a vehicle reaching an end of the road turns
round there (its x is reflected at ``0`` and ``length``; the curve, a function of x, is
retraced), so every vehicle stays on the road at every step and keeps moving at
``speed_m`` per step (wrapping round to the other end would make its INS reading jump by a
road length); M anchors are fixed; every vehicle ranges to
every vehicle and anchor within ``radius_m`` through the LOS/NLOS mixture model, each
directed link carrying its own sticky link-state chain; the INS reads each step's
displacement with white Gaussian noise of std ``ins_std_m`` per axis.

Anchor layouts (the paper does not give one; ``anchor_coverage`` compares them):

* ``"staggered"`` (default): three rows at 1/6, 1/2 and 5/6 of the width; the M anchors
  are shared ``M // 3`` per row, the remainder going to the outer rows (26 -> 9/8/9,
  30 -> 10/10/10, 36 -> 12/12/12); the middle row is evenly spaced with a half spacing at
  each end, the outer rows with 0.3 of their spacing at each end, so the rows are
  staggered and the ends of the middle lanes are reached too. On the paper's road
  (150 m x 30 m, vehicles' y in [1, 29] m) with R = 10 m every point a vehicle can occupy
  is within R of an anchor for M = 26, 27, 28, 30, 33, 36 (farthest point 9.6 m from an
  anchor at M = 26), tested;
* ``"rows"``: two rows at 1/4 and 3/4 of the width, anchors evenly spaced and staggered;
* ``"edges"``: two rows on the road edges (``y = 0`` and ``y = width``);
* ``"centre"``: one row along the centre line (the earlier default; vehicles in the outer
  lanes, more than R from it, hear no anchor: a labelled variant);
* ``"uniform"``: uniform at random (from a generator passed in).

Arrays follow the estimator contract: batch axes ``(runs, vehicles)`` lead, time follows.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import ConfigError, InputError
from radioloc.core.geometry import distances
from radioloc.core.validation import check_positive
from radioloc.models.los_nlos import LosNlosRange

LAYOUTS = ("staggered", "rows", "edges", "centre", "uniform")
STAGGERED_OUTER_INSET = 0.3
"""End inset of the outer rows of the ``"staggered"`` layout, in units of their spacing."""


@dataclass(frozen=True)
class HighwayScenario:
    """Geometry and sensing of the highway simulation (paper's Fig. 4 defaults).

    Attributes
    ----------
    vehicles, anchors : int
        N vehicles and M anchors.
    steps : int
        Time steps T after the start.
    length_m, width_m : float
        Road size.
    start_width_m : float
        Starting x uniform in ``[0, start_width_m]``.
    speed_m : float
        Forward motion per step.
    curve_amplitude_m, curve_period_m : float
        Vertical curve ``A sin(2 pi (x - x0) / period)``, ``A ~ U(-amplitude, amplitude)``.
    radius_m : float
        Communication radius R.
    ins_std_m : float
        INS noise per axis and step.
    layout : str
        Anchor layout (see :func:`anchor_layout`).
    """

    vehicles: int = 20
    anchors: int = 26
    steps: int = 700
    length_m: float = 150.0
    width_m: float = 30.0
    start_width_m: float = 10.0
    speed_m: float = 0.2
    curve_amplitude_m: float = 3.0
    curve_period_m: float = 150.0
    radius_m: float = 10.0
    ins_std_m: float = 0.1
    layout: str = "staggered"

    def __post_init__(self) -> None:
        if self.layout not in LAYOUTS:
            raise ConfigError(f"layout: unknown {self.layout!r}; choose from {LAYOUTS}")
        for name in ("length_m", "width_m", "speed_m", "radius_m", "ins_std_m"):
            check_positive(getattr(self, name), name)
        if self.vehicles < 1 or self.anchors < 0 or self.steps < 1:
            raise ConfigError("vehicles, steps must be >= 1 and anchors >= 0")


def anchor_layout(layout: str, m: int, length_m: float, width_m: float,
                  rng: np.random.Generator | None = None) -> np.ndarray:
    """Anchor positions of the named layout.

    Parameters
    ----------
    layout : {"staggered", "rows", "edges", "centre", "uniform"}
        See the module docstring.
    m : int
        Number of anchors.
    length_m, width_m : float
        Road size.
    rng : numpy.random.Generator, optional
        Source of the ``"uniform"`` layout (required for it; pass a named stream of the
        experiment, e.g. ``stream(seed, "anchor-layout")``, so that every block uses the
        same layout).

    Returns
    -------
    ndarray, shape (m, 2)
    """
    if layout not in LAYOUTS:
        raise ConfigError(f"layout: unknown {layout!r}; choose from {LAYOUTS}")
    i = np.arange(m)
    x = (i + 0.5) * length_m / max(m, 1)
    if layout == "staggered":
        return _staggered(m, length_m, width_m)
    if layout == "rows":
        y = np.where(i % 2 == 0, 0.25, 0.75) * width_m
    elif layout == "edges":
        y = np.where(i % 2 == 0, 0.0, width_m)
    elif layout == "centre":
        y = np.full(m, 0.5 * width_m)
    else:
        if rng is None:
            raise InputError("rng: the 'uniform' anchor layout needs a generator")
        x, y = rng.uniform(0, length_m, m), rng.uniform(0, width_m, m)
    return np.stack([x, y], axis=-1)


def _staggered(m: int, length_m: float, width_m: float) -> np.ndarray:
    """Three staggered rows (see the module docstring): (m, 2)."""
    base, extra = divmod(m, 3)
    counts = (base + (extra >= 1), base, base + (extra >= 2))
    out = []
    for row, n in enumerate(counts):
        if n == 0:
            continue
        f = 0.5 if row == 1 else STAGGERED_OUTER_INSET
        spacing = length_m / (n - 1 + 2 * f)
        x = (f + np.arange(n)) * spacing
        out.append(np.stack([x, np.full(n, (2 * row + 1) * width_m / 6)], axis=-1))
    return np.concatenate(out, axis=0) if out else np.zeros((0, 2))


def reflect(x: np.ndarray, length_m: float) -> np.ndarray:
    """Fold positions into ``[0, length_m]`` by reflection at both ends.

    Parameters
    ----------
    x : ndarray
        Unfolded positions (distance driven from the start, plus the start).
    length_m : float
        Road length.

    Returns
    -------
    ndarray
        Same shape, in ``[0, length_m]``: a vehicle reaching an end turns round.
    """
    r = np.mod(x, 2.0 * length_m)
    return np.where(r <= length_m, r, 2.0 * length_m - r)


@dataclass
class HighwayData:
    """One batch of simulated highway runs (batch axes lead, time follows).

    Attributes
    ----------
    truth : ndarray, shape (R, N, T + 1, 2)
        True positions, step 0 the start.
    ins : ndarray, shape (R, N, T, 2)
        INS displacement readings of steps 1..T.
    anchors : ndarray, shape (M, 2)
    ranges : ndarray, shape (R, N, T, J)
        Measured ranges of steps 1..T, ``J = N + M`` (vehicles first), NaN where no link.
    los : ndarray of bool, shape (R, N, T, J)
        True link states.
    """

    truth: np.ndarray
    ins: np.ndarray
    anchors: np.ndarray
    ranges: np.ndarray
    los: np.ndarray

    @property
    def in_range(self) -> np.ndarray:
        """Links that exist.

        Returns
        -------
        ndarray of bool, shape (R, N, T, J)
            ``isfinite(ranges)``.
        """
        return np.isfinite(self.ranges)

    def node_positions(self) -> np.ndarray:
        """True positions of every node at steps 1..T (the genie's view).

        Returns
        -------
        ndarray, shape (R, T, J, 2)
            The N vehicles first, then the M anchors.
        """
        cur = np.moveaxis(self.truth[:, :, 1:], 1, 2)                    # (R, T, N, 2)
        a = np.broadcast_to(self.anchors, cur.shape[:2] + self.anchors.shape)
        return np.concatenate([cur, a], axis=2)


def trajectories(sc: HighwayScenario, runs: int, rng: np.random.Generator) -> np.ndarray:
    """True positions of the vehicles.

    Parameters
    ----------
    sc : HighwayScenario
    runs : int
        Independent runs R.
    rng : numpy.random.Generator
        Source of the start points and curves.

    Returns
    -------
    ndarray, shape (runs, N, steps + 1, 2)
        x in ``[0, length_m]`` (reflected at the road ends, see :func:`reflect`).
    """
    n = sc.vehicles
    x0 = rng.uniform(0.0, sc.start_width_m, (runs, 1, n))
    amp = rng.uniform(-sc.curve_amplitude_m, sc.curve_amplitude_m, (runs, 1, n))
    margin = sc.curve_amplitude_m + 1.0
    y0 = rng.uniform(margin, sc.width_m - margin, (runs, 1, n))
    x = reflect(x0 + sc.speed_m * np.arange(sc.steps + 1)[None, :, None], sc.length_m)
    y = y0 + amp * np.sin(2 * np.pi * (x - x0) / sc.curve_period_m)
    return np.moveaxis(np.stack([x, y], axis=-1), 1, 2)


def simulate(sc: HighwayScenario, model: LosNlosRange, runs: int, rng: np.random.Generator,
             anchors: np.ndarray | None = None) -> HighwayData:
    """Simulate ``runs`` independent highway runs at once.

    Parameters
    ----------
    sc : HighwayScenario
    model : LosNlosRange
        Range model and link chain of every directed link.
    runs : int
        Independent runs R.
    rng : numpy.random.Generator
        Source of trajectories, INS noise, link states and ranges.
    anchors : ndarray, shape (M, 2), optional
        Anchor positions; default :func:`anchor_layout` of ``sc.layout`` (drawn from
        ``rng`` for the ``"uniform"`` layout).

    Returns
    -------
    HighwayData
    """
    truth = np.moveaxis(trajectories(sc, runs, rng), 1, 2)               # (R, T + 1, N, 2)
    if anchors is None:
        anchors = anchor_layout(sc.layout, sc.anchors, sc.length_m, sc.width_m, rng)
    anchors = np.asarray(anchors, dtype=float)
    if anchors.shape != (sc.anchors, 2):
        raise InputError(f"anchors: expected ({sc.anchors}, 2), got {anchors.shape}")
    n, t = sc.vehicles, sc.steps
    ins = np.diff(truth, axis=1) + sc.ins_std_m * rng.standard_normal((runs, t, n, 2))
    cur = truth[:, 1:]                                                   # (R, T, N, 2)
    nodes = np.concatenate([cur, np.broadcast_to(anchors, (runs, t) + anchors.shape)], axis=2)
    d = distances(cur[..., :, None, :], nodes[..., None, :, :])          # (R, T, N, J)
    in_range = d < sc.radius_m
    in_range[..., np.arange(n), np.arange(n)] = False
    los = model.chain.sample(t, (runs, n, n + sc.anchors), rng)          # (T, R, N, J)
    los = np.moveaxis(los, 0, 2)                                         # (R, N, T, J)
    ranges = np.where(in_range, model.sample(d, np.moveaxis(los, 2, 1), rng), np.nan)
    return HighwayData(np.moveaxis(truth, 1, 2), np.moveaxis(ins, 1, 2), anchors,
                       np.moveaxis(ranges, 1, 2), los)


def anchor_coverage(sc: HighwayScenario, runs: int, rng: np.random.Generator,
                    anchors: np.ndarray | None = None) -> dict[str, float]:
    """How many anchors and vehicles each vehicle hears, for the scenario's layout.

    Parameters
    ----------
    sc : HighwayScenario
    runs : int
        Independent runs drawn.
    rng : numpy.random.Generator
        Source of the trajectories (and of a ``"uniform"`` layout if ``anchors`` is None).
    anchors : ndarray, shape (M, 2), optional
        Anchor positions (default: :func:`anchor_layout` of ``sc.layout``).

    Returns
    -------
    dict
        ``anchors_in_range`` and ``vehicles_in_range`` (means over vehicle-steps),
        ``fraction_below_2_anchors``, ``fraction_no_anchor`` (vehicle-steps hearing no
        anchor) and ``fraction_vehicles_never_anchored`` (vehicles that hear no anchor in
        the whole run).
    """
    truth = trajectories(sc, runs, rng)[:, :, 1:]                        # (R, N, T, 2)
    if anchors is None:
        anchors = anchor_layout(sc.layout, sc.anchors, sc.length_m, sc.width_m, rng)
    na = (distances(truth[..., None, :], anchors) < sc.radius_m).sum(-1)
    cur = np.moveaxis(truth, 1, 2)                                       # (R, T, N, 2)
    dv = distances(cur[..., :, None, :], cur[..., None, :, :])
    nv = (dv < sc.radius_m).sum(-1) - 1
    return {"anchors_in_range": float(na.mean()), "vehicles_in_range": float(nv.mean()),
            "fraction_below_2_anchors": float((na < 2).mean()),
            "fraction_no_anchor": float((na == 0).mean()),
            "fraction_vehicles_never_anchored": float((na.max(-1) == 0).mean())}
