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
* ``"uniform"``: uniform at random (fixed seed 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from radioloc.core.errors import ConfigError
from radioloc.core.geometry import distances
from radioloc.core.validation import check_positive
from radioloc.models.los_nlos import LosNlosRange, StickyLinkChain

LAYOUTS = ("rows", "edges", "centre", "uniform")


@dataclass(frozen=True)
class HighwayScenario:
    """Geometry and sensing of the highway simulation (paper's Fig. 4 defaults)."""

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


def anchor_layout(layout: str, m: int, length_m: float, width_m: float) -> np.ndarray:
    """``(m, 2)`` anchor positions of the named layout."""
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
        g = np.random.default_rng(0)
        x, y = g.uniform(0, length_m, m), g.uniform(0, width_m, m)
    return np.stack([x, y], axis=-1)


@dataclass
class HighwayData:
    """One batch of simulated highway runs.

    truth : (R, T + 1, N, 2) positions, step 0 the start.
    ins : (R, T, N, 2) INS displacement readings of steps 1..T.
    anchors : (M, 2).
    ranges : (R, T, N, J) measured ranges, J = N + M (vehicles first), NaN where no link.
    in_range : (R, T, N, J) bool.
    los : (R, T, N, J) bool true link states.
    """

    truth: np.ndarray
    ins: np.ndarray
    anchors: np.ndarray
    ranges: np.ndarray
    in_range: np.ndarray
    los: np.ndarray


def trajectories(sc: HighwayScenario, runs: int, rng: np.random.Generator) -> np.ndarray:
    """True positions ``(runs, steps + 1, N, 2)``."""
    n = sc.vehicles
    x0 = rng.uniform(0.0, sc.start_width_m, (runs, 1, n))
    amp = rng.uniform(-sc.curve_amplitude_m, sc.curve_amplitude_m, (runs, 1, n))
    margin = sc.curve_amplitude_m + 1.0
    y0 = rng.uniform(margin, sc.width_m - margin, (runs, 1, n))
    x = x0 + sc.speed_m * np.arange(sc.steps + 1)[None, :, None]
    y = y0 + amp * np.sin(2 * np.pi * (x - x0) / sc.curve_period_m)
    return np.stack([x, y], axis=-1)


def simulate(sc: HighwayScenario, model: LosNlosRange, runs: int,
             rng: np.random.Generator) -> HighwayData:
    """Simulate ``runs`` independent highway runs at once."""
    truth = trajectories(sc, runs, rng)
    anchors = anchor_layout(sc.layout, sc.anchors, sc.length_m, sc.width_m)
    n, t = sc.vehicles, sc.steps
    ins = np.diff(truth, axis=1) + sc.ins_std_m * rng.standard_normal((runs, t, n, 2))
    cur = truth[:, 1:]                                                   # (R, T, N, 2)
    nodes = np.concatenate([cur, np.broadcast_to(anchors, (runs, t) + anchors.shape)], axis=2)
    d = distances(cur[..., :, None, :], nodes[..., None, :, :])          # (R, T, N, J)
    in_range = d < sc.radius_m
    in_range[..., np.arange(n), np.arange(n)] = False
    los = StickyLinkChain(model.alpha).sample(t, (runs, n, n + sc.anchors), rng)
    los = np.moveaxis(los, 0, 1)
    ranges = np.where(in_range, model.sample(d, los, rng), np.nan)
    return HighwayData(truth, ins, anchors, ranges, in_range, los)


def anchor_coverage(sc: HighwayScenario, runs: int, rng: np.random.Generator) -> dict[str, float]:
    """Mean number of anchors and vehicles in range and the fraction of epochs with < 2
    anchors in range, for the scenario's layout."""
    truth = trajectories(sc, runs, rng)[:, 1:]
    anchors = anchor_layout(sc.layout, sc.anchors, sc.length_m, sc.width_m)
    na = (distances(truth[..., None, :], anchors) < sc.radius_m).sum(-1)
    dv = distances(truth[..., :, None, :], truth[..., None, :, :])
    nv = (dv < sc.radius_m).sum(-1) - 1
    return {"anchors_in_range": float(na.mean()), "vehicles_in_range": float(nv.mean()),
            "fraction_below_2_anchors": float((na < 2).mean())}
