"""Highway scenario of paper 001, Sect. V and Fig. 4.

N vehicles start at random points near the left end of a ``length x width`` road and move
right by a constant ``speed_m`` per step with a smooth vertical curve
``y = y0 + A sin(2 pi (x - x0) / period)``; M anchors are fixed; every vehicle ranges to
every vehicle and anchor within ``radius_m`` through the LOS/NLOS mixture model, each
directed link carrying its own sticky link-state chain; the INS reads each step's
displacement with white Gaussian noise of std ``ins_std_m`` per axis.

Anchor layouts (the paper does not give one; ``anchor_coverage`` compares them):

* ``"rows"``: two rows at 1/4 and 3/4 of the width, anchors evenly spaced and staggered;
* ``"edges"``: two rows on the road edges (``y = 0`` and ``y = width``);
* ``"centre"``: one row along the centre line;
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

LAYOUTS = ("rows", "edges", "centre", "uniform")


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
    layout: str = "rows"

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
    layout : {"rows", "edges", "centre", "uniform"}
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
    """
    n = sc.vehicles
    x0 = rng.uniform(0.0, sc.start_width_m, (runs, 1, n))
    amp = rng.uniform(-sc.curve_amplitude_m, sc.curve_amplitude_m, (runs, 1, n))
    margin = sc.curve_amplitude_m + 1.0
    y0 = rng.uniform(margin, sc.width_m - margin, (runs, 1, n))
    x = x0 + sc.speed_m * np.arange(sc.steps + 1)[None, :, None]
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
        ``anchors_in_range`` and ``vehicles_in_range`` (means over vehicle-steps) and
        ``fraction_below_2_anchors``.
    """
    truth = trajectories(sc, runs, rng)[:, :, 1:]                        # (R, N, T, 2)
    if anchors is None:
        anchors = anchor_layout(sc.layout, sc.anchors, sc.length_m, sc.width_m, rng)
    na = (distances(truth[..., None, :], anchors) < sc.radius_m).sum(-1)
    cur = np.moveaxis(truth, 1, 2)                                       # (R, T, N, 2)
    dv = distances(cur[..., :, None, :], cur[..., None, :, :])
    nv = (dv < sc.radius_m).sum(-1) - 1
    return {"anchors_in_range": float(na.mean()), "vehicles_in_range": float(nv.mean()),
            "fraction_below_2_anchors": float((na < 2).mean())}
